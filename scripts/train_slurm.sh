#!/usr/bin/env bash
# Train as a preemptible Slurm job that requeues itself and resumes where it stopped:
#   sbatch --output=OUT.log scripts/train_slurm.sh manifests/train/paper.toml /shared/runs/paper
# On several GPUs or nodes (data-parallel, one MPI rank a task; a trainer built with
# `cargo build --release -p matedit-trainer --features mpi`):
#   sbatch --ntasks=8 --gpus-per-task=1 --output=OUT.log scripts/train_slurm.sh M OUT
#   sbatch --nodes=2 --ntasks-per-node=8 --gpus-per-task=1 ... (OUT on a filesystem every node sees)
# With more than one task the trainer is started by `srun --mpi=pmix --kill-on-bad-exit=1`: a
# task that dies ends the step at once instead of leaving the others waiting. Each rank takes
# the GPU SLURM_LOCALID names (MATEDIT_GPU overrides) and, on the CPU, its share of the
# node's cores (MATEDIT_THREADS overrides); every stage's batch_size must be a multiple of
# the task count (the trainer says so otherwise).
#
# Five minutes before the time limit (or when an administrator or a preempting job sends it,
# `scancel --batch --signal=USR1 JOB`) Slurm signals this shell; the trainer is told (srun
# passes the signal on to every task), finishes its step, writes a checkpoint and exits with
# status 75; this script then requeues the job, which starts again with --resume and continues
# to the same losses as an uninterrupted run (on as many tasks as the job then has). A plain
# SIGTERM (preemption, `scancel`) does the same while the grace time (KillWait) lasts.
# Progress goes to the log as a plain line every MATEDIT_PROGRESS_SECS seconds (default 30).
#SBATCH --job-name=matedit-train
#SBATCH --time=24:00:00
#SBATCH --requeue
#SBATCH --signal=B:USR1@300
#SBATCH --open-mode=append
set -uo pipefail
usage="usage: sbatch scripts/train_slurm.sh TRAINING_MANIFEST OUT_DIR"
manifest=${1:?$usage}
out=${2:?$usage}
trainer=${TRAINER:-target/release/trainer}
echo "job ${SLURM_JOB_ID:-?} start $(date -u +%FT%TZ), restart ${SLURM_RESTART_COUNT:-0}: $manifest into $out" >&2
launch=()
if [ "${SLURM_NTASKS:-1}" -gt 1 ]; then
  launch=(srun --mpi=pmix --kill-on-bad-exit=1 --ntasks="$SLURM_NTASKS")
  [ -n "${SLURM_GPUS_PER_TASK:-}" ] && launch+=(--gpus-per-task="$SLURM_GPUS_PER_TASK")
  echo "job ${SLURM_JOB_ID:-?}: $SLURM_NTASKS ranks: ${launch[*]}" >&2
fi
# (`${a[@]+"${a[@]}"}`: an empty array under `set -u` on bash before 4.4.)
${launch[@]+"${launch[@]}"} "$trainer" run "$manifest" --out "$out" --resume &
pid=$!
asked=0
trap 'asked=1; kill -USR1 "$pid" 2>/dev/null' USR1 TERM
# `wait` returns early when a trapped signal arrives; wait again until the trainer has exited.
while :; do
  wait "$pid"
  status=$?
  kill -0 "$pid" 2>/dev/null || break
done
# Several tasks: every rank exits 75 once rank 0 has written the checkpoint, but srun's
# --kill-on-bad-exit may kill a slower rank first (status 128 + 9 or 15): after our own stop
# request that is the same preemption.
if [ "$status" != 75 ] && [ "$asked" = 1 ] && [ "${#launch[@]}" -gt 0 ] && { [ "$status" = 137 ] || [ "$status" = 143 ]; }; then
  echo "job ${SLURM_JOB_ID:-?}: srun ended with $status after the stop request; the checkpoint was written first" >&2
  status=75
fi
if [ "$status" = 75 ]; then
  echo "job ${SLURM_JOB_ID:-?}: checkpoint written on the signal; requeueing" >&2
  if [ -n "${SLURM_JOB_ID:-}" ] && scontrol requeue "$SLURM_JOB_ID"; then
    exit 0
  fi
  echo "could not requeue; resubmit this script (it resumes)" >&2
fi
exit "$status"
