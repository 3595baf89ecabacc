#!/usr/bin/env bash
# The README's figure of real photos edited: each car photo of the evaluation assets (with the
# alpha matte rembg wrote as its mask) edited to a diffuse, a glossy paint and a metal with each
# composite: the paper's `render` (O' at the photo's resolution), `ratio`, and the default
# `detail`.
#   scripts/edit_cars.sh MODEL [ASSETS] [OUT]
# MODEL: a `trainer run` output folder (e.g. out/train/quickstart) or a checkpoint folder;
# ASSETS: the folder holding photos/rembg_cars/ (default ../shared/eval-assets, or $MATEDIT_EVAL_ASSETS);
# OUT: default out/edit-cars. Writes OUT/car-N/COMPOSITE/MATERIAL/ (every output of `matedit
# edit`) and OUT/cars.png and a smaller OUT/cars.jpg (rows: each car with each composite;
# columns: the photo and the three edits).
set -euo pipefail
cd "$(dirname "$0")/.."
model=${1:?usage: scripts/edit_cars.sh MODEL [ASSETS] [OUT]}
assets=${2:-${MATEDIT_EVAL_ASSETS:-../shared/eval-assets}}
out=${3:-out/edit-cars}
cargo build --release -p matedit-edit --bin matedit --example edit_figure --quiet
bin=target/release/matedit
materials="fabric-felt-green carpaint-red-gloss gold-polished"
rows=()
for n in 1 2 3; do
    photo="$assets/photos/rembg_cars/car-$n.jpg"
    mask="$assets/photos/rembg_cars/car-$n.out.png"
    for how in render ratio detail; do
        args=(--composite "$how")
        row="car-$n, $how::$photo"
        for m in $materials; do
            "$bin" edit --model "$model" --image "$photo" --mask "$mask" --material "library:$m" "${args[@]}" \
                --out "$out/car-$n/$how/$m" >/dev/null
            row="$row,$out/car-$n/$how/$m/edited.png"
        done
        rows+=("$row")
    done
done
for fig in "$out/cars.png" "$out/cars.jpg"; do
    target/release/examples/edit_figure "$fig" \
        "photo,fabric-felt-green,carpaint-red-gloss,gold-polished" "${rows[@]}"
done
