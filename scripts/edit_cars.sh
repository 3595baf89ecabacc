#!/usr/bin/env bash
# The README's figure of real photos edited: each car photo of the evaluation assets (with the
# alpha matte rembg wrote as its mask) edited to a diffuse, a glossy paint and a metal with each
# composite: the paper's `render` (O' at the photo's resolution), `ratio`, `detail` (the default
# until 2026-11-29) and the default `structure`.
#   scripts/edit_cars.sh MODEL [ASSETS] [OUT]
# MODEL: a `trainer run` output folder (e.g. out/train/quickstart) or a checkpoint folder;
# ASSETS: the folder holding photos/rembg_cars/ (default ../shared/eval-assets, or $MATEDIT_EVAL_ASSETS);
# OUT: default out/edit-cars. Writes OUT/car-N/COMPOSITE/MATERIAL/ (every output of `matedit
# edit`) and OUT/cars.png and a smaller OUT/cars.jpg (rows: each car with each composite;
# columns: the photo and the three edits); then OUT/car-N/known/MATERIAL/ and OUT/known.png and
# .jpg: cars 1 and 2 edited by default and with the object's own material given
# (`--input-material`, a user's guess: car-1's silver as aluminium's F0, car-2's white paint as a
# white plastic; the composite is then `ratio`).
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
    for how in render ratio detail structure; do
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

known_rows=()
for entry in "1 ggx:0.1:0.9116,0.9206,0.9239" "2 plastic:0.05:0.8,0.8,0.8"; do
    n=${entry%% *}
    own=${entry#* }
    photo="$assets/photos/rembg_cars/car-$n.jpg"
    mask="$assets/photos/rembg_cars/car-$n.out.png"
    plain="car-$n, default::$photo"
    known="car-$n, --input-material $own::$photo"
    for m in $materials; do
        plain="$plain,$out/car-$n/structure/$m/edited.png"
        "$bin" edit --model "$model" --image "$photo" --mask "$mask" --material "library:$m" \
            --input-material "$own" --out "$out/car-$n/known/$m" >/dev/null
        known="$known,$out/car-$n/known/$m/edited.png"
    done
    known_rows+=("$plain" "$known")
done
for fig in "$out/known.png" "$out/known.jpg"; do
    target/release/examples/edit_figure "$fig" \
        "photo,fabric-felt-green,carpaint-red-gloss,gold-polished" "${known_rows[@]}"
done
