#!/usr/bin/env bash
# Samples per second of a shadow-heavy dataset of real meshes with each ray-query backend, in
# one run, alternating (obvhs, embree, obvhs, embree): 4 chairs and 3 sofas of the evaluation
# assets, 96 samples at 128², shadows on. Prints each time and the ratio of the medians.
#   scripts/bench_embree.sh            (MATEDIT_EVAL_ASSETS: default ../shared/eval-assets)
#   QUALITY=fast scripts/bench_embree.sh   (the shading quality; default zonal, the factory's)
set -euo pipefail
cd "$(dirname "$0")/.."
assets=${MATEDIT_EVAL_ASSETS:-../shared/eval-assets}/meshes
quality=${QUALITY:-zonal}
[ -d "$assets" ] || { echo "no evaluation meshes at $assets (set MATEDIT_EVAL_ASSETS)" >&2; exit 1; }
eval "$(scripts/install_embree.sh)"
cargo build --release --quiet -p matedit-datagen --features embree --bin datagen
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/chairs" "$work/sofas"
ln -s "$(realpath "$assets/codeyeJR-Models/chair.obj")" "$work/chairs/chair-a.obj"
ln -s "$(realpath "$assets/Azdepredador-binvox/silla.obj")" "$work/chairs/chair-b.obj"
ln -s "$(realpath "$assets/pix2shape/chair.obj")" "$work/chairs/chair-c.obj"
ln -s "$(realpath "$assets/pix2shape/desk_chair.obj")" "$work/chairs/chair-d.obj"
ln -s "$(realpath "$assets/LENKFF-P2M/sofa.obj")" "$work/sofas/sofa-a.obj"
ln -s "$(realpath "$assets/LENKFF-P2M/oldsofa.obj")" "$work/sofas/sofa-b.obj"
ln -s "$(realpath "$assets/Azdepredador-binvox/sofa.obj")" "$work/sofas/sofa-c.obj"
for accel in obvhs embree; do
  cat > "$work/$accel.toml" <<TOML
[dataset]
name = "real-shadows"
seed = 5
output = "unused"
shard_size = 8

[render]
resolution = 128
env_resolution = "32x64"
quality = "$quality"
shadows = "on"
accel = "$accel"

[views]
azimuths = 24
elevation_deg = 20.0
per_combination = 2

[[shapes]]
source = "folder"
category = "chair"
path = "$work/chairs"

[[shapes]]
source = "folder"
category = "sofa"
path = "$work/sofas"

[[materials]]
source = "library"
families = ["plastic", "metal"]

[[environments]]
source = "procedural"
family = "sunsky"
count = 2

[[splits]]
name = "train"
shapes = { chair = 3, sofa = 2 }
materials = 4

[[splits]]
name = "test"
shapes = { chair = 1, sofa = 1 }
materials = 2
TOML
done
declare -A times
for run in 1 2; do
  for accel in obvhs embree; do
    rm -rf "$work/out"
    start=$(date +%s%N)
    target/release/datagen run "$work/$accel.toml" --out "$work/out" 2>"$work/log" || { tail -3 "$work/log" >&2; exit 1; }
    t=$(awk "BEGIN { print ($(date +%s%N) - $start) / 1e9 }")
    times[$accel]="${times[$accel]:-} $t"
    printf '%s run %d: %.1f s (%s samples)\n' "$accel" "$run" "$t" "$(wc -l < "$work/out/index.jsonl")"
  done
done
python3 - "${times[obvhs]}" "${times[embree]}" "$quality" <<'PY'
import statistics, sys
o, e = (statistics.median(map(float, a.split())) for a in sys.argv[1:3])
print(f"median: obvhs {o:.1f} s, embree {e:.1f} s: embree {o / e:.2f}x the samples/s of obvhs ({sys.argv[3]} quality)")
PY
