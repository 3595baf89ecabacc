#!/usr/bin/env bash
# Submit a dataset as a Slurm array of N workers plus the join that waits for all of them:
#   scripts/datagen_slurm_submit.sh MANIFEST OUT_DIR N [extra sbatch options, e.g. --cpus-per-task=16 --mem=16G]
# Logs go to OUT_DIR/logs/. Prints the array's and the join's job ids.
set -euo pipefail
usage="usage: scripts/datagen_slurm_submit.sh MANIFEST OUT_DIR N [SBATCH_OPTION ...]"
manifest=${1:?$usage}
out=${2:?$usage}
n=${3:?$usage}
shift 3
case $n in ''|*[!0-9]*|0) echo "error: N must be a positive integer, not '$n'" >&2; exit 2 ;; esac
here=$(cd "$(dirname "$0")/.." && pwd)
dg=${DATAGEN:-$here/target/release/datagen}
mkdir -p "$out/logs"
# The environment passes on: WORKERS fixes N for later re-submissions of single tasks.
array=$(WORKERS=$n FIRST=0 DATAGEN=$dg sbatch --parsable --chdir="$here" --output="$out/logs/%x-%A_%a.log" \
  --array="0-$((n - 1))" "$@" "$here/scripts/datagen_slurm.sh" "$manifest" "$out")
array=${array%%;*}
join=$(sbatch --parsable --chdir="$here" --job-name=matedit-datagen-join --output="$out/logs/%x-%j.log" \
  --dependency="afterany:$array" --kill-on-invalid-dep=yes \
  --wrap "'$dg' join '$out' && '$dg' verify '$out'")
echo "array $array ($n workers), join $join; logs in $out/logs/"
echo "re-run one worker K of this run: WORKERS=$n FIRST=0 DATAGEN=$dg sbatch --array=K --output=$out/logs/%x-%A_%a.log scripts/datagen_slurm.sh $manifest $out"
