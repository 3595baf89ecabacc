#!/usr/bin/env bash
# The main job on the embedded default data: builds the workspace, then runs the dataset factory
# on manifests/quickstart.toml (procedural cars and chairs, library materials, procedural skies):
#   1. `datagen plan`    counts per split, disk and time estimate;
#   2. `datagen run`     renders the train and test splits into out/quickstart/ (resumable:
#                        rerunning continues where an interrupted run stopped);
#   3. `datagen verify`  checksums, schema and split integrity;
#   4. `datagen inspect` a contact sheet out/quickstart/inspect.png (I, O, normals, mask,
#                        regions, environment per sample).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --workspace --quiet
dg=target/release/datagen
manifest=manifests/quickstart.toml
out=${1:-out/quickstart}
"$dg" plan "$manifest"
"$dg" run "$manifest" --out "$out"
"$dg" verify "$out"
"$dg" inspect "$out" --samples 8
echo "quickstart: $(wc -l < "$out/index.jsonl") samples in $out/ (index.jsonl, dataset.json, shards/, inspect.png)"
