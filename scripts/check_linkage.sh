#!/usr/bin/env bash
# The release binaries need only libc-level libraries, so that the README's set-up (the Rust
# toolchain, nothing else) is true: no font, image or compression library is linked (the plots
# draw with an embedded font). Prints each binary's libraries; exits 1 naming any other.
#
#   scripts/check_linkage.sh [TARGET_DIR]      # default: target
set -euo pipefail
cd "$(dirname "$0")/.."
target=${1:-${CARGO_TARGET_DIR:-target}}
allowed='^(linux-vdso\.so\.[0-9]+|libc\.so\.6|libm\.so\.6|libgcc_s\.so\.1|libpthread\.so\.0|libdl\.so\.2|librt\.so\.1|/lib64/ld-linux-x86-64\.so\.2|/lib/ld-linux-aarch64\.so\.1)$'
bad=0
for bin in datagen trainer matedit; do
  f=$target/release/$bin
  [ -x "$f" ] || { echo "error: $f is not built (cargo build --release)" >&2; exit 1; }
  libs=$(ldd "$f" | awk '{print $1}')
  echo "$bin: $(echo "$libs" | tr '\n' ' ')"
  extra=$(echo "$libs" | grep -v -E "$allowed" || true)
  if [ -n "$extra" ]; then
    echo "error: $bin links $(echo "$extra" | tr '\n' ' ')beyond libc-level libraries" >&2
    bad=1
  fi
done
exit $bad
