#!/usr/bin/env bash
# The main job on the embedded default data: builds the workspace and renders a preview gallery
# (the analytic unit sphere, one image per BRDF model) under the builtin environments,
# into out/quickstart/ as EXR (linear radiance, normals, mask) and tone-mapped PNG.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --workspace --quiet
out=out/quickstart
mkdir -p "$out"
dg=target/release/datagen
for env in sky studio; do
  for spec in "lambert:0.8,0.35,0.2" "ggx:0.25:0.95,0.64,0.54" "plastic:0.15:0.1,0.3,0.8" \
              "dsbrdf:assets/materials/red_plastic.dsbrdf.json"; do
    name="${env}_$(echo "${spec%%:*}")"
    "$dg" render --shape sphere --brdf "$spec" --env "builtin:$env" --res 256 \
      --out "$out/$name.exr" --png "$out/$name.png"
  done
done
echo "quickstart: wrote $(ls "$out"/*.png | wc -l) previews to $out/"
