#!/usr/bin/env bash
# The long fuzz run of every reader (tests/common/fuzz/): SCALE times each reader's CI cases
# (default 100: 30,000 for most readers, 2,400 for the 33 MB MERL tables) from RNG seed SEED
# (default: a new one each run), the three harnesses (tests/fuzz.rs, tests/fuzz_trainer.rs, edit/tests/fuzz.rs), one line per reader ("fuzz NAME: N cases (A
# accepted, R refused) in S s, seed SEED") appended to LOG.
#   scripts/fuzz_long.sh [SCALE] [SEED] [LOG]
# A failure stops its harness with the minimal input under target/fuzz-failures/ (make it a
# regression test). Real assets join the seeds where ../shared/eval-assets (or
# $MATEDIT_EVAL_ASSETS) exists.
set -euo pipefail
cd "$(dirname "$0")/.."
scale=${1:-100}
seed=${2:-$(date +%s)}
log=${3:-out/fuzz-long.log}
mkdir -p "$(dirname "$log")"
echo "# $(date -u +%FT%TZ) $(git rev-parse --short HEAD 2>/dev/null || echo '?') scale=$scale seed=$seed" >> "$log"
status=0
for target in "-p matedit --test fuzz" "-p matedit --test fuzz_trainer" "-p matedit-edit --test fuzz"; do
    out=$(mktemp)
    # shellcheck disable=SC2086
    MATEDIT_FUZZ_SCALE=$scale MATEDIT_FUZZ_SEED=$seed cargo test --release $target -- --nocapture --skip harness \
        >"$out" 2>&1 || status=1
    cat "$out"
    grep -E '^fuzz ' "$out" >> "$log" || true
    rm -f "$out"
done
echo "wrote $log"
exit $status
