#!/usr/bin/env bash
# The Python package (python/) against the Rust build: a fresh virtual environment, `pip install
# ./python[test]` (numpy, OpenEXR, blake3, safetensors, pytest, webdataset, tensorboardX and
# TensorBoard's reader from PyPI) and PyTorch,
# then python/tests with the datagen and trainer of this build. Where PyTorch installs, its tests
# must run (MATEDIT_REQUIRE_TORCH); where it cannot (PyPI's Linux wheel with its CUDA libraries is
# about 3 GB unpacked), they skip, saying so. The environment is removed at the end.
#
#   scripts/test_python.sh [TARGET_DIR]      # default: target (the release build's folder)
set -euo pipefail
cd "$(dirname "$0")/.."
target=${1:-${CARGO_TARGET_DIR:-target}}
case $target in /*) ;; *) target=$PWD/$target ;; esac
for bin in datagen trainer; do
  [ -x "$target/release/$bin" ] || { echo "error: $target/release/$bin is not built (cargo build --release)" >&2; exit 1; }
done
py=${PYTHON:-python3}
venv=$(mktemp -d "${TMPDIR:-/tmp}/matedit-python.XXXXXX")
trap 'rm -rf "$venv"' EXIT
"$py" -m venv "$venv"
export PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
"$venv/bin/python" -m pip install --quiet "./python[test]"
export MATEDIT_REQUIRE_TENSORBOARD=1
if "$venv/bin/python" -m pip install --quiet torch >"$venv/torch.log" 2>&1; then
  export MATEDIT_REQUIRE_TORCH=1
else
  echo "note: could not install PyTorch (see below); its tests skip" >&2
  tail -3 "$venv/torch.log" >&2 || true
fi
# Run from outside the checkout, so that the installed package is what is tested.
cd python/tests
MATEDIT_DATAGEN=$target/release/datagen MATEDIT_TRAINER=$target/release/trainer \
  "$venv/bin/python" -m pytest -q -p no:cacheprovider .
