#!/usr/bin/env bash
# `mpirun ARGS...` that a scheduler can preempt without losing work: a SIGTERM (a pod's
# eviction, a node drain) or SIGUSR1 sent to this script reaches every rank as SIGUSR1 (OpenMPI's
# mpirun passes SIGUSR1 on to all processes of the job), so `trainer run` finishes its step on
# every rank, rank 0 writes a checkpoint, and all exit with status 75; this script then exits
# with mpirun's status. A SIGTERM given to mpirun itself would be followed by SIGKILL after a
# few seconds, before a long step could end. The launcher of scripts/train_k8s_mpijob.yaml.
#   scripts/mpirun_preemptible.sh -np 8 --bind-to none trainer run M --out OUT --resume
set -uo pipefail
mpirun "$@" &
pid=$!
trap 'kill -USR1 "$pid" 2>/dev/null' USR1 TERM
# `wait` returns early when a trapped signal arrives; wait again until mpirun has exited.
while :; do
  wait "$pid"
  status=$?
  kill -0 "$pid" 2>/dev/null || break
done
exit "$status"
