#!/usr/bin/env bash
# The main job on the embedded default data: the whole small pipeline of the paper.
#   1. `datagen plan`    counts per split, disk and time estimate (manifests/datasets/quickstart.toml:
#                        procedural cars, chairs, sofas and monitors, library materials,
#                        procedural skies, studios and rooms);
#   2. `datagen run`     renders the train and test splits into out/quickstart/ (resumable:
#                        rerunning continues where an interrupted run stopped);
#   3. `datagen verify`  checksums, schema and split integrity;
#   4. `datagen inspect` a contact sheet out/quickstart/inspect.png;
#   5. `trainer run`     manifests/train/quickstart.toml: pretrains the normal and material
#                        modules (L2), trains the illumination module through the rendering
#                        layer, then all three jointly (Eq. 5); evaluates every stage on the
#                        held-out test split and prints the tables (out/train/quickstart/eval.md,
#                        eval.json, eval.png, loss.png). Its perceptual loss is VGG16's where
#                        ImageNet's weights are there (`bash scripts/fetch_vgg16.sh`, or
#                        VGG16_WEIGHTS), the documented fallback otherwise; it says which;
#   6. a first edit      `datagen render` makes a photo of a car the dataset does not hold (teal
#                        plastic, under a procedural sky) and the truths of two targets (red car
#                        paint, varnished oak); `matedit edit` edits the photo to each with the
#                        model just trained and scores the edit, and the unchanged photo, against
#                        its truth (out/first-edit/TARGET/edited.png, sheet.png, report.json).
# Rerunning the script continues both steps where a killed run stopped (`--resume` starts a
# fresh training run when there is none, and re-evaluates a finished one).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --workspace --quiet
dg=target/release/datagen
tr=target/release/trainer
manifest=manifests/datasets/quickstart.toml
out=out/quickstart
"$dg" plan "$manifest"
"$dg" run "$manifest" --out "$out"
"$dg" verify "$out"
"$dg" inspect "$out" --samples 8
echo "quickstart: $(wc -l < "$out/index.jsonl") samples in $out/ (index.jsonl, dataset.json, shards/, inspect.png)"
# VGG16's weights where scripts/fetch_vgg16.sh put them, unless VGG16_WEIGHTS says otherwise (an
# empty one: the fallback); a run already started keeps the loss it started with.
vgg=${MATEDIT_CACHE:-$HOME/.cache/matedit}/vgg16/vgg16-imagenet.safetensors
run=out/train/quickstart
if [ -z "${VGG16_WEIGHTS+set}" ] && [ -f "$vgg" ]; then
  if [ ! -e "$run/latest.json" ] || grep -qs '"perceptual": "vgg16' "$run"/checkpoints/*/state.json; then
    export VGG16_WEIGHTS=$vgg
  fi
fi
if [ -n "${VGG16_WEIGHTS:-}" ]; then
  echo "quickstart: perceptual loss: VGG16 ($VGG16_WEIGHTS)"
else
  echo "quickstart: perceptual loss: the fallback (bash scripts/fetch_vgg16.sh fetches VGG16's ImageNet weights)"
fi
"$tr" run manifests/train/quickstart.toml --out "$run" --resume
echo "quickstart: model, metrics and tables in out/train/quickstart/ (eval.md, eval.json, eval.png, loss.png)"
# A first edit: a photo the network has not seen, edited to two targets, each scored against the
# picture it should make.
mt=target/release/matedit
fe=out/first-edit
mkdir -p "$fe"
view=(--shape procedural:car:1000 --yaw 35 --env builtin:sky --res 256)
"$dg" render "${view[@]}" --brdf library:plastic-teal-smooth --out "$fe/photo.exr" --png "$fe/photo.png" >/dev/null 2>>"$fe/render.log"
for target in carpaint-red-gloss wood-oak-varnished; do
  "$dg" render "${view[@]}" --brdf "library:$target" --out "$fe/truth-$target.exr" --png "$fe/truth-$target.png" >/dev/null 2>>"$fe/render.log"
  "$mt" edit --model "$run" --image "$fe/photo.png" --material "library:$target" \
    --truth "$fe/truth-$target.png" --out "$fe/$target" 2>&1 | grep -E "^against the truth|edited in"
done
echo "quickstart: a first edit in $fe/ (photo.png; each target's edited.png, sheet.png and report.json)"
