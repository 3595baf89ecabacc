#!/usr/bin/env bash
# Render a manifest's dataset as a Slurm job array: one array task per worker, all writing to
# one shared output directory; a dependent job joins the index and verifies.
#
# One command submits both (prints the two job ids):
#   scripts/datagen_slurm_submit.sh manifests/datasets/paper-pretrain.toml /shared/out/paper-pretrain 32
# or by hand:
#   jid=$(sbatch --parsable --array=0-31 scripts/datagen_slurm.sh M OUT)
#   sbatch --dependency=afterany:$jid --wrap "target/release/datagen join OUT && target/release/datagen verify OUT"
# `afterany`, not `afterok`: a task that was cancelled and requeued never counts as "ok" to
# Slurm, yet its data are complete; `datagen join` itself refuses an incomplete dataset.
#
# Which worker a task is: the run has N workers, W = 0..N-1.
#   - By default N and W come from the array's own bounds, so any range and step work:
#     --array=0-31, --array=1-32 (W = ID-1), --array=0-62:2 (W = ID/2), throttled (%4) or not.
#   - Re-submitting some tasks of a run (a failed index, say) must state the whole run:
#     WORKERS=32 sbatch --array=7,12 scripts/datagen_slurm.sh M OUT      (IDs are worker indices)
#     WORKERS=32 FIRST=1 sbatch --array=8 scripts/datagen_slurm.sh M OUT  (the run was --array=1-32)
#   (sbatch passes the environment on to the job.)
# A task that is preempted, cancelled or killed can be requeued (`scontrol requeue`): `datagen
# run` resumes, skipping the shards that are complete, byte-identical to an uninterrupted run.
#
# Sizing the request: rendering uses every CPU it is given (RAYON_NUM_THREADS follows
# --cpus-per-task); memory is about 1 GB plus 50 MB per thread at 256². The header asks for the
# cluster's defaults; ask for more on the command line, e.g. `sbatch --cpus-per-task=16
# --mem=16G ...` (a request larger than any node pends forever with reason PartitionConfig).
# Logs: Slurm writes them where you submit from unless told otherwise; pass
# `--output=/shared/logs/%x-%A_%a.log` (the submit script puts them in OUT/logs/).
#SBATCH --job-name=matedit-datagen
#SBATCH --time=24:00:00
#SBATCH --requeue
#SBATCH --open-mode=append
set -euo pipefail
usage="usage: sbatch --array=0-N scripts/datagen_slurm.sh MANIFEST OUT_DIR"
manifest=${1:?$usage}
out=${2:?$usage}
id=${SLURM_ARRAY_TASK_ID:?run as a job array ($usage)}
if [ -n "${WORKERS:-}" ]; then
  count=$WORKERS
  index=$(( id - ${FIRST:-0} ))
else
  min=${SLURM_ARRAY_TASK_MIN:?no SLURM_ARRAY_TASK_MIN: set WORKERS=N}
  max=${SLURM_ARRAY_TASK_MAX:?no SLURM_ARRAY_TASK_MAX: set WORKERS=N}
  step=${SLURM_ARRAY_TASK_STEP:-1}
  if [ -n "${SLURM_ARRAY_TASK_COUNT:-}" ] && [ "$(( (max - min) / step + 1 ))" != "$SLURM_ARRAY_TASK_COUNT" ]; then
    echo "error: array ${SLURM_ARRAY_TASK_MIN}-${SLURM_ARRAY_TASK_MAX}:${step} is not a plain range; give WORKERS=N (and FIRST)" >&2
    exit 2
  fi
  count=$(( (max - min) / step + 1 ))
  if [ "$count" = 1 ]; then
    echo "error: a one-task array does not say how many workers the run has; give WORKERS=N (and FIRST, see the header)" >&2
    exit 2
  fi
  if [ $(( (id - min) % step )) != 0 ]; then
    echo "error: task $id is not on the array's step $step from $min; give WORKERS=N (and FIRST)" >&2
    exit 2
  fi
  index=$(( (id - min) / step ))
fi
if [ "$index" -lt 0 ] || [ "$index" -ge "$count" ]; then
  echo "error: array task $id is worker $index, outside 0..$((count - 1)) (WORKERS=$count, FIRST=${FIRST:-0})" >&2
  exit 2
fi
dg=${DATAGEN:-target/release/datagen}
export RAYON_NUM_THREADS=${SLURM_CPUS_PER_TASK:-0}
echo "task $id: worker $index/$count of $manifest into $out (restart ${SLURM_RESTART_COUNT:-0})" >&2
exec "$dg" run "$manifest" --out "$out" --worker "$index/$count"
