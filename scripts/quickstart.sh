#!/usr/bin/env bash
# The main job on the embedded default data: builds the workspace, then
#   1. renders the unit sphere with each BRDF model under the builtin environments,
#   2. writes contact sheets of the procedural shapes (both regions coloured) and environments,
#   3. renders procedural chairs, sofas, cars and monitors in library materials, as measured-style
#      ground truth (library:NAME) and as its fitted 108-parameter DSBRDF (fit:NAME),
# into out/quickstart/ as EXR (linear radiance, normals, mask, regions) and tone-mapped PNG.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --workspace --quiet
out=out/quickstart
mkdir -p "$out"
dg=target/release/datagen
for env in sky studio; do
  for spec in "lambert:0.8,0.35,0.2" "ggx:0.25:0.95,0.64,0.54" "plastic:0.15:0.1,0.3,0.8" \
              "dsbrdf:assets/materials/red_plastic.dsbrdf.json"; do
    "$dg" render --shape sphere --brdf "$spec" --env "builtin:$env" --res 256 \
      --out "$out/sphere_${env}_${spec%%:*}.exr" --png "$out/sphere_${env}_${spec%%:*}.png" 2>/dev/null
  done
done
"$dg" assets shapes --out "$out/shapes" --count 3
"$dg" assets envmaps --out "$out/envmaps" --count 3 --height 128
for job in "chair:1:carpaint-red-gloss:30:20" "sofa:2:fabric-denim:25:15" "car:3:gold-brushed:25:12" \
           "monitor:4:plastic-black-smooth:30:10"; do
  IFS=: read -r cat seed mat yaw pitch <<<"$job"
  for kind in library fit; do
    "$dg" render --shape "procedural:$cat:$seed" --yaw "$yaw" --pitch "$pitch" --brdf "$kind:$mat" \
      --env builtin:sunsky:7 --res 256 --shadows on \
      --out "$out/${cat}_${kind}.exr" --png "$out/${cat}_${kind}.png" 2>/dev/null
  done
done
echo "quickstart: wrote $(find "$out" -name '*.png' | wc -l) PNG and $(find "$out" -name '*.exr' | wc -l) EXR files to $out/"
