#!/usr/bin/env bash
# Train as a preemptible Slurm job that requeues itself and resumes where it stopped:
#   sbatch --output=OUT.log scripts/train_slurm.sh manifests/train/paper.toml /shared/runs/paper
#
# Five minutes before the time limit (or when an administrator or a preempting job sends it,
# `scancel --batch --signal=USR1 JOB`) Slurm signals this shell; the trainer is told, finishes
# its step, writes a checkpoint and exits with status 75; this script then requeues the job,
# which starts again with --resume and continues to the same losses as an uninterrupted run. A
# plain SIGTERM (preemption, `scancel`) does the same while the grace time (KillWait) lasts.
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
"$trainer" run "$manifest" --out "$out" --resume &
pid=$!
trap 'kill -USR1 "$pid" 2>/dev/null' USR1 TERM
# `wait` returns early when a trapped signal arrives; wait again until the trainer has exited.
while :; do
  wait "$pid"
  status=$?
  kill -0 "$pid" 2>/dev/null || break
done
if [ "$status" = 75 ]; then
  echo "job ${SLURM_JOB_ID:-?}: checkpoint written on the signal; requeueing" >&2
  if [ -n "${SLURM_JOB_ID:-}" ] && scontrol requeue "$SLURM_JOB_ID"; then
    exit 0
  fi
  echo "could not requeue; resubmit this script (it resumes)" >&2
fi
exit "$status"
