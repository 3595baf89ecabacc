#!/usr/bin/env bash
# Median wall time of `datagen render` (sphere, 256², builtin:sky at 64x128, fast path) per BRDF,
# over N runs (default 5). Usage: bash scripts/bench_render.sh [N]
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:-5}
cargo build --release -p matedit-datagen --quiet
dg=target/release/datagen
out=$(mktemp -d)
echo "| BRDF | median wall time (s), $n runs |"
echo "|---|---|"
for spec in "lambert:0.8,0.35,0.2" "ggx:0.25:0.95,0.64,0.54" "plastic:0.15:0.1,0.3,0.8" \
            "dsbrdf:assets/materials/red_plastic.dsbrdf.json"; do
  times=()
  for _ in $(seq "$n"); do
    s=$(date +%s.%N)
    "$dg" render --brdf "$spec" --env builtin:sky --res 256 --env-res 64x128 --out "$out/x.exr" 2>/dev/null
    e=$(date +%s.%N)
    times+=("$(echo "$e - $s" | bc -l)")
  done
  med=$(printf '%s\n' "${times[@]}" | sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}')
  printf '| %s | %.3f |\n' "${spec%%:*}" "$med"
done
rm -rf "$out"
