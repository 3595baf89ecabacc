#!/usr/bin/env bash
# Render a manifest's dataset as a Slurm job array: one array task per worker, all writing to
# one shared output directory, then a dependent job joins the index and verifies.
#
#   sbatch --array=0-31 scripts/datagen_slurm.sh manifests/paper-pretrain.toml /shared/out/paper-pretrain
#   # when every task has finished (or submit with a dependency, see below):
#   datagen join /shared/out/paper-pretrain && datagen verify /shared/out/paper-pretrain
#
# A dependent join job can be chained at submission:
#   jid=$(sbatch --parsable --array=0-31 scripts/datagen_slurm.sh M OUT)
#   sbatch --dependency=afterok:$jid --wrap "target/release/datagen join OUT && target/release/datagen verify OUT"
#
# A task that is preempted or killed can simply be requeued: `datagen run` resumes, skipping the
# shards that are complete, and the result is byte-identical to an uninterrupted run.
#SBATCH --job-name=matedit-datagen
#SBATCH --cpus-per-task=16
#SBATCH --mem=16G
#SBATCH --time=24:00:00
#SBATCH --requeue
#SBATCH --output=datagen-%A_%a.log
set -euo pipefail
manifest=${1:?usage: sbatch --array=0-N scripts/datagen_slurm.sh MANIFEST OUT_DIR}
out=${2:?usage: sbatch --array=0-N scripts/datagen_slurm.sh MANIFEST OUT_DIR}
index=${SLURM_ARRAY_TASK_ID:?run as a job array (sbatch --array=0-N)}
count=${SLURM_ARRAY_TASK_COUNT:?run as a job array (sbatch --array=0-N)}
dg=${DATAGEN:-target/release/datagen}
export RAYON_NUM_THREADS=${SLURM_CPUS_PER_TASK:-0}
"$dg" run "$manifest" --out "$out" --worker "$index/$count"
