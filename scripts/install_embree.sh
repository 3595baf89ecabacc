#!/usr/bin/env bash
# Provides Embree 4 for the optional `embree` feature of matedit-datagen, on a machine that
# reaches only the package registries: Debian 12 has only Embree 3, so the library comes from
# the PyPI wheel `embreex==4.4.0.post1` (libembree4 and its libtbb, manylinux_2_28), and
# libclang (Debian's libclang-dev) lets embree4-sys generate its bindings. Prints the variable
# the build needs; the default build is untouched.
#   eval "$(scripts/install_embree.sh)"      # sets EMBREE_DIR
#   cargo test --release -p matedit-datagen --features embree
set -euo pipefail
cd "$(dirname "$0")/.."
dir=${EMBREE_DIR:-$(pwd)/target/embree}
if [ ! -e "$dir/libembree4.so" ]; then
  tmp=$(mktemp -d)
  trap 'rm -rf "$tmp"' EXIT
  python3 -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: \
    --python-version 3.12 --platform manylinux_2_28_x86_64 embreex==4.4.0.post1 -d "$tmp" >&2
  mkdir -p "$dir"
  python3 - "$tmp" "$dir" <<'PY'
import pathlib, sys, zipfile
tmp, out = map(pathlib.Path, sys.argv[1:])
wheel = next(tmp.glob("embreex-*.whl"))
with zipfile.ZipFile(wheel) as z:
    for n in z.namelist():
        if n.startswith("embreex.libs/") and ".so" in n:
            (out / pathlib.Path(n).name).write_bytes(z.read(n))
PY
  lib=$(cd "$dir" && ls libembree4-*.so.4 | head -1)
  ln -sf "$lib" "$dir/libembree4.so"
fi
if ! ls /usr/lib/llvm-*/lib/libclang*.so >/dev/null 2>&1; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libclang-dev) >&2
  else
    echo "install libclang (Debian: libclang-dev) for embree4-sys's bindings" >&2
    exit 1
  fi
fi
echo "export EMBREE_DIR=$dir"
