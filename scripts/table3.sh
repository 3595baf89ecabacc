#!/usr/bin/env bash
# Table 3 of the paper (Sec. 4.5) on the quickstart data, every method on the same 288 test
# samples and targets, O' against O (L2 on tone-mapped [0, 255] images, SSIM):
#   Lombardi      material and light optimised given the true normals, under priors
#                 (trainer/src/baseline/lombardi.rs);
#   Baseline 1    the encoder-decoder of manifests/train/baseline1.toml (after Kulkarni et al.);
#   Baseline 2    three networks trained with L2 losses only: the main job's pretrain stage;
#   ours          the main job's network after joint training through the rendering layer;
#   each network of Fig. 2 also after the post-optimisation of Eq. 6 ("+ Eq. 6").
# Then the multi-material row (Sec. 4.4): two-region chairs (manifests/datasets/quickstart-multimaterial.toml),
# the network finetuned on them (manifests/train/quickstart-multimaterial.toml), per-region edits
# scored on their test split before and after the finetuning.
# Steps: the README's main job (scripts/quickstart.sh: rendering and training, resumed or skipped
# when done), Baseline 1's training, one `trainer eval` writing out/table3/eval.json and eval.md
# (Tables 1-3), then the multi-material dataset, finetuning and out/table3/multi-material.json
# and .md. Everything resumes: rerun after an interruption. Extra arguments go to the Table 3
# `trainer eval` (e.g. --max-samples 32 for a quick look). Measured times: docs/PERFORMANCE.md
# ("Table 3").
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/quickstart.sh
tr=target/release/trainer
"$tr" run manifests/train/baseline1.toml --out out/train/baseline1 --resume
mkdir -p out/table3
"$tr" eval --data out/quickstart --split test \
  --checkpoint "Baseline 1=out/train/baseline1/checkpoints/baseline1" \
  --checkpoint "Baseline 2=out/train/quickstart/checkpoints/pretrain" \
  --checkpoint "ours=out/train/quickstart/checkpoints/joint" \
  --eq6 --lombardi "$@" --out out/table3/eval.json
dg=target/release/datagen
"$dg" run manifests/datasets/quickstart-multimaterial.toml --out out/quickstart-multimaterial
"$dg" verify out/quickstart-multimaterial
"$tr" run manifests/train/quickstart-multimaterial.toml --out out/train/quickstart-multimaterial --resume
"$tr" eval --data out/quickstart-multimaterial --split test \
  --checkpoint "ours, before=out/train/quickstart/checkpoints/joint" \
  --checkpoint "ours, multi-material finetune=out/train/quickstart-multimaterial/checkpoints/multi-material" \
  --out out/table3/multi-material.json
echo "table3: out/table3/eval.md and eval.json (Tables 1-3), multi-material.md and .json (Sec. 4.4)"
