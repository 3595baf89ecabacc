#!/usr/bin/env bash
# The one-call GPU check: everything the first lent GPU should measure, prepared here
# and run there in one call.
#
#   bash scripts/gpu_check.sh prepare        # here (CPU, ~15 min the first time): builds and
#                                            # packs into .gpu/ (git-ignored, carried)
#   bash scripts/gpu_check.sh run            # on the device: writes every figure and log to
#                                            # $OUT (default out/gpu-check), at most 8 files
#   bash scripts/gpu_check.sh run --tiny     # the same path on Mesa's lavapipe, tiny sizes
#
# With the device tool: run(command="bash scripts/gpu_check.sh run", carry=[".gpu"],
# timeout_s=540). The device is a bare machine (an NVIDIA H100 or H200, 16 cores, no Rust, no
# network): `run` unpacks the Vulkan loader, refuses a software adapter, renders a 256² dataset
# with `datagen`, checks the GPU rendering layer and loss against the CPU ones on the device
# (the lib's own tests, built here), times `trainer bench --device wgpu` at the paper's
# configuration and at cpu-small, trains the paper configuration for a fixed time (stopped by
# SIGTERM like a Slurm time limit) and scores the checkpoint it leaves.
#
# Every step has its own time limit (GPU_CHECK_*_S below), so a step that hangs costs its limit
# and the rest still runs; the whole run took 471 s on an H100 (2026-11-27), so give the call
# timeout_s=540. summary.md lists each step's exit status and time. GPU_CHECK_STEPS="datagen
# train" reruns only those steps (the adapter check always runs).
set -uo pipefail
cd "$(dirname "$0")/.."
PACK=.gpu

prepare() {
  set -e
  mkdir -p "$PACK/bin" "$PACK/debs"
  echo "== release builds: trainer --features wgpu, its lib tests, datagen"
  cargo build --release -p matedit-datagen --bin datagen
  cp target/release/datagen "$PACK/bin/datagen"
  cargo build --release -p matedit-trainer --features wgpu --bin trainer
  cp target/release/trainer "$PACK/bin/trainer"
  local tests
  tests=$(cargo test --release -p matedit-trainer --features wgpu --lib --no-run --message-format=json 2>/dev/null \
    | python3 -c 'import json,sys
for l in sys.stdin:
    m=json.loads(l)
    if m.get("reason")=="compiler-artifact" and m.get("executable") and m["target"]["kind"]==["lib"]: print(m["executable"])' | tail -1)
  [ -n "$tests" ] || { echo "no lib test executable found" >&2; exit 1; }
  cp "$tests" "$PACK/bin/trainer-tests"
  strip "$PACK"/bin/datagen "$PACK"/bin/trainer "$PACK"/bin/trainer-tests
  # xz: the stripped binaries are ~110 MB each, over the 64 MiB a device call carries.
  rm -f "$PACK"/bin/*.xz
  xz -T0 -9 "$PACK"/bin/datagen "$PACK"/bin/trainer "$PACK"/bin/trainer-tests
  # Restore the default (CPU-only) trainer binary for the rest of this checkout's work.
  cargo build --release -p matedit-trainer --bin trainer
  echo "== the Vulkan loader (and GL/EGL) for the device, as .debs"
  local o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64-lists'
  mkdir -p /tmp/amd64-lists/partial
  # shellcheck disable=SC2086
  apt-get $o update -qq
  # shellcheck disable=SC2086
  (cd "$PACK/debs" && rm -f ./*.deb && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
  # The binaries need only libc-level libraries (their plots draw with an embedded font; CI
  # checks this with ldd), so no library of theirs is carried.
  echo "== packed"
  du -ab "$PACK" | sort -n | tail -12
  local total
  total=$(du -sb "$PACK" | cut -f1)
  echo "carried folder: $((total / 1024 / 1024)) MiB (limit: 64 MiB with the working tree, $(git ls-files -z | du -cb --files0-from=- | tail -1 | cut -f1) bytes tracked)"
}

run_check() {
  local tiny=0 allow_software=0
  for a in "$@"; do
    case "$a" in
      --tiny) tiny=1; allow_software=1 ;;
      --allow-software) allow_software=1 ;;
      *) echo "unknown option $a" >&2; exit 2 ;;
    esac
  done
  local out=${OUT:-out/gpu-check}
  mkdir -p "$out"
  out=$(cd "$out" && pwd)
  local work
  work=$(mktemp -d /tmp/gpu-check.XXXXXX)
  local log=$out/log.txt summary=$out/summary.md
  : >"$log"
  local size=256 widths=paper batch=16 bench_train="paper:256:16,cpu-small:64:8" bench_size=256
  local train_s=${GPU_CHECK_TRAIN_S:-120}
  if [ $tiny = 1 ]; then
    size=32 widths=cpu-small batch=2 bench_train="cpu-small:32:2" bench_size=32
    train_s=${GPU_CHECK_TRAIN_S:-240}
  fi
  {
    echo "# GPU check, $(date -u +%Y-%m-%dT%H:%MZ)"
    echo
    echo "host: $(uname -n), $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo)"
    echo "mode: $([ $tiny = 1 ] && echo "tiny ($size², $widths, batch $batch)" || echo "paper ($size², $widths, batch $batch)")"
    echo
    echo "| step | exit | seconds |"
    echo "|---|---|---|"
  } >"$summary"

  # step NAME LIMIT_S COMMAND...: run with a time limit, output to the log and to $out/NAME.txt
  # when the name is one of the kept files, and a row in the summary.
  step() {
    local name=$1 limit=$2
    shift 2
    # GPU_CHECK_STEPS="datagen train …" runs only those (a rerun within a device lease).
    if [ -n "${GPU_CHECK_STEPS:-}" ] && [ "$name" != adapter ] && [[ " $GPU_CHECK_STEPS " != *" $name "* ]]; then
      return 0
    fi
    echo "== $name (limit ${limit}s): $*" | tee -a "$log"
    local t0 rc
    t0=$(date +%s%N)
    # The training run answers SIGTERM with a checkpoint and exit 75: keep its own status.
    # It gets 90 s to write that checkpoint (the paper's widths; an H100's first run once took
    # longer than 30 s to stop); other steps are killed 30 s after their TERM.
    local keep=(-k 30)
    [ "$name" = train ] && keep=(--preserve-status -k 90)
    timeout "${keep[@]}" -s TERM "$limit" "$@" 2>&1 | tee -a "$log" "$work/$name.txt" >/dev/null
    rc=${PIPESTATUS[0]}
    local dt
    dt=$(awk -v a="$t0" -v b="$(date +%s%N)" 'BEGIN {printf "%.1f", (b - a) / 1e9}')
    printf '| %s | %s | %s |\n' "$name" "$rc" "$dt" >>"$summary"
    echo "== $name: exit $rc in ${dt}s" | tee -a "$log"
    return "$rc"
  }

  local bin=$work/bin
  mkdir -p "$bin"
  for b in datagen trainer trainer-tests; do
    [ -f "$PACK/bin/$b.xz" ] || { echo "no $PACK/bin/$b.xz: run 'bash scripts/gpu_check.sh prepare' first" | tee -a "$log"; exit 1; }
    # xz may be missing on a bare image; Python's lzma is not.
    xz -dc "$PACK/bin/$b.xz" >"$bin/$b" 2>/dev/null \
      || python3 -c 'import lzma, shutil, sys; shutil.copyfileobj(lzma.open(sys.argv[1]), open(sys.argv[2], "wb"))' "$PACK/bin/$b.xz" "$bin/$b"
    chmod +x "$bin/$b"
  done

  # The loader: a bare device image may lack libvulkan; unpack the carried .debs into /.
  if ! ldconfig -p 2>/dev/null | grep -q libvulkan.so.1; then
    if [ "$(id -u)" = 0 ] && ls "$PACK"/debs/*.deb >/dev/null 2>&1; then
      for f in "$PACK"/debs/*.deb; do dpkg -x "$f" /; done
      ldconfig
      echo "unpacked the Vulkan loader from $PACK/debs" | tee -a "$log"
    else
      echo "no libvulkan.so.1 and no way to install the carried one (not root or no .debs)" | tee -a "$log"
    fi
  fi
  if LD_LIBRARY_PATH= ldd "$bin/trainer" | grep -q "not found"; then
    echo "the trainer needs libraries this image lacks: $(ldd "$bin/trainer" | grep "not found" | tr -s ' ' | tr '\n' ';')" | tee -a "$log"
  fi
  local icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f "$icd" ] && ! ls /usr/share/vulkan/icd.d/nvidia_icd.json /etc/vulkan/icd.d/nvidia_icd.json >/dev/null 2>&1; then
    export VK_DRIVER_FILES=$icd
    echo "VK_DRIVER_FILES=$icd" | tee -a "$log"
  fi
  if command -v nvidia-smi >/dev/null; then
    step nvidia-smi 30 nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.sm --format=csv
  fi

  local require=(--require-hardware)
  [ $allow_software = 1 ] && require=()
  if ! step adapter 60 "$bin/trainer" gpu-info "${require[@]}"; then
    echo "no hardware GPU for wgpu: stopping (the log says which adapter it would take)" | tee -a "$log"
    return 1
  fi

  # A 256² dataset: the 252 samples of bench-256 (tiny: the same plan at 32²).
  local dm=$work/dataset.toml
  sed -e "s/^resolution = 256 /resolution = $size /" manifests/datasets/bench-256.toml >"$dm"
  step datagen "${GPU_CHECK_DATAGEN_S:-90}" "$bin/datagen" run "$dm" --out "$work/data"

  # The GPU layer, the loss and three training steps against the CPU device, on this device: the
  # lib's own tests (bounds 1e-4 / 1e-2, docs/PERFORMANCE.md), plus the structural loss at 256²
  # (the TF32 question).
  MATEDIT_REQUIRE_GPU=1 step device-tests "${GPU_CHECK_TESTS_S:-120}" "$bin/trainer-tests" gpu --test-threads=1 --nocapture

  # Speed: the layer at batch × size², the training steps of the paper and cpu-small networks.
  step bench-wgpu "${GPU_CHECK_BENCH_S:-150}" "$bin/trainer" bench --device wgpu --batch "$batch" --size "$bench_size" \
    --runs 5 --no-reference --train "$bench_train"
  step bench-cpu "${GPU_CHECK_BENCH_CPU_S:-60}" "$bin/trainer" bench --device cpu --batch "$batch" --size "$bench_size" \
    --runs 1 --no-reference --train ""

  # Training for a fixed time, then the score of the checkpoint it leaves.
  local tm=$work/train.toml
  sed -e "s|^dataset = .*|dataset = \"$work/data\"|" -e "s/^input_size = 256 /input_size = $size /" \
    -e "s/^widths = \"paper\"/widths = \"$widths\"/" -e "s/^batch_size = 16/batch_size = $batch/" \
    manifests/train/gpu-check.toml >"$tm"
  # A speed measurement: train even where `trainer run` would refuse the device's reductions
  # (the adapter step has printed whether they are exact).
  # The device's memory in use while it trains, every half second (its peak is the figure).
  local poller=
  if command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits -lms 500 >"$work/gpu-memory.txt" 2>/dev/null &
    poller=$!
  fi
  MATEDIT_ALLOW_INEXACT_REDUCTIONS=1 step train "$train_s" "$bin/trainer" run "$tm" --out "$work/train" --quiet
  [ -n "$poller" ] && kill "$poller" 2>/dev/null
  # The checkpoint the stopped run left (latest.json names it).
  local ck
  ck=$(grep -o '"checkpoints/[^"]*"' "$work/train/latest.json" 2>/dev/null | tr -d '"')
  if [ -n "$ck" ] && [ -d "$work/train/$ck" ]; then
    ck=$work/train/$ck
    step eval "${GPU_CHECK_EVAL_S:-60}" "$bin/trainer" eval --checkpoint "$ck" --data "$work/data" --split test \
      --max-samples 64 --batch "$batch" --out "$work/train/eval/METRICS.json" --quiet
  fi

  # What comes back: summary.md, log.txt, the step outputs that carry figures, and the run's
  # metrics, plots and tables (no weights) as one archive.
  for f in adapter device-tests bench-wgpu bench-cpu; do
    [ -f "$work/$f.txt" ] && cp "$work/$f.txt" "$out/$f.txt"
  done
  (cd "$work" && tar czf "$out/train.tar.gz" --exclude='*.bpk' --exclude='*.mpk' --exclude='.lock*' \
    train/ train.toml dataset.toml data/MANIFEST* data/*.json 2>/dev/null) || true
  {
    echo
    echo "## Figures"
    echo
    grep -hiE "the wgpu device takes|Burn's reductions|images/s|reserved|structural loss at|test result|FAILED|panicked|warning" \
      "$work"/adapter.txt "$work"/bench-wgpu.txt "$work"/bench-cpu.txt "$work"/device-tests.txt 2>/dev/null | sed 's/^/    /'
    if [ -s "$work/gpu-memory.txt" ]; then
      echo
      echo "GPU memory in use while training (nvidia-smi, every 0.5 s): peak $(sort -n "$work/gpu-memory.txt" | tail -1) MiB, before the run $(head -1 "$work/gpu-memory.txt") MiB"
    fi
    if [ -f "$work/train/log.jsonl" ]; then
      echo
      echo "Training (\`trainer run\`, batch $batch at $size², $widths widths; medians after each stage's first 3 steps):"
      echo
      python3 - "$work/train/log.jsonl" <<'PY'
import json, statistics, sys
stages = {}
for line in open(sys.argv[1]):
    r = json.loads(line)
    if "images_per_second" in r:
        stages.setdefault(r["stage"], []).append(r["images_per_second"])
for stage, ips in stages.items():
    kept = ips[3:] or ips
    m = statistics.median(kept)
    print(f"- {stage}: {len(ips)} steps, median {m:.2f} images/s"
          f" (720,000 images would take {720000 / m / 3600:.1f} h at this rate)")
PY
    fi
    echo
    grep -hE "^\| " "$work/train/eval/METRICS.md" 2>/dev/null | head -20
  } >>"$summary"
  echo "wrote $(ls "$out" | tr '\n' ' ')in $out" | tee -a "$log"
  rm -rf "$work"
}

case "${1:-}" in
  prepare) prepare ;;
  run) shift; run_check "$@" ;;
  *) echo "usage: bash scripts/gpu_check.sh prepare | run [--tiny] [--allow-software]" >&2; exit 2 ;;
esac
