#!/usr/bin/env bash
# The cluster scripts on a real scheduler: starts a one-node Slurm here (Debian's slurm-wlm and
# munge, installed when missing and apt works), renders a small dataset as job arrays of several
# shapes (0-3, 1-4, stepped 0-6:2, throttled %2, a requeued task, a failed index re-submitted
# alone) and checks each joined dataset is byte-identical to a single-process run; then trains
# under scripts/train_slurm.sh, signals the job mid-run (as a time limit would) and checks the
# requeued job resumes to the same metrics.jsonl as an uninterrupted run; then trains as 2 tasks
# (MPI ranks, with an MPI trainer), signals and requeues that job too, and checks it equals the
# one-process run within the rank tests' tolerance. Stops only the daemons it started. Skips (exit 0, with a message) where Slurm cannot be installed or started.
#   scripts/test_slurm.sh            (as root; ~2 minutes on 2 cores after the build)
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)
skip() { echo "test_slurm: skipped: $*" >&2; exit 0; }
fail() { echo "test_slurm: FAILED: $*" >&2; exit 1; }

if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
  command -v apt-get >/dev/null && [ "$(id -u)" = 0 ] || skip "no slurm-wlm/munge and no apt as root"
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge) \
    >/tmp/matedit-apt-slurm.log 2>&1 || skip "could not install slurm-wlm and munge (see /tmp/matedit-apt-slurm.log)"
fi
[ "$(id -u)" = 0 ] || skip "needs root to start slurmd"
cargo build --release --quiet -p matedit-datagen -p matedit-trainer --bins
target=${CARGO_TARGET_DIR:-$repo/target}
case $target in /*) ;; *) target=$repo/$target ;; esac
dg=$target/release/datagen
tr=$target/release/trainer

root=$(mktemp -d /tmp/matedit-slurm.XXXXXX)
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  sleep 1
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null || true; done
  [ -n "${KEEP:-}" ] || rm -rf "$root"
}
trap cleanup EXIT

# --- a one-node cluster ------------------------------------------------------------------------
host=$(hostname -s)
mkdir -p "$root"/{state,spool,munge,run}
chmod 700 "$root/munge"
dd if=/dev/urandom of="$root/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$root/munge/munge.key"
munged --force --key-file="$root/munge/munge.key" --socket="$root/run/munge.socket" \
  --pid-file="$root/run/munged.pid" --log-file="$root/munge/munged.log" --seed-file="$root/munge/seed" \
  || skip "munged did not start"
pids+=("$(cat "$root/run/munged.pid")")
mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 ))
port=$(( 17000 + RANDOM % 2000 ))
cat > "$root/slurm.conf" <<CONF
ClusterName=matedit-test
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$root/run/munge.socket
CredType=cred/munge
StateSaveLocation=$root/state
SlurmdSpoolDir=$root/spool
SlurmctldPidFile=$root/run/slurmctld.pid
SlurmdPidFile=$root/run/slurmd.pid
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmctldLogFile=$root/slurmctld.log
SlurmdLogFile=$root/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
JobRequeue=1
KillWait=30
MinJobAge=600
SchedulerParameters=defer
NodeName=$host CPUs=$(nproc) RealMemory=$mem State=UNKNOWN
PartitionName=test Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF=$root/slurm.conf
slurmctld -f "$SLURM_CONF" || skip "slurmctld did not start ($root/slurmctld.log)"
sleep 1
pids+=("$(cat "$root/run/slurmctld.pid")")
slurmd -f "$SLURM_CONF" || skip "slurmd did not start ($root/slurmd.log)"
sleep 1
pids+=("$(cat "$root/run/slurmd.pid")")
for _ in $(seq 60); do
  sinfo -h -o %T 2>/dev/null | grep -qE '^(idle|mixed)' && break
  sleep 1
done
sinfo -h -o %T | grep -qE '^(idle|mixed)' || fail "the node never became idle: $(sinfo 2>&1)"
echo "test_slurm: one-node Slurm up ($host, $(nproc) CPUs)" >&2

# --- a small dataset, rendered once in one process -------------------------------------------------
cp "$repo/tests/fixtures/manifests/jobs-dataset.toml" "$root/data.toml"
"$dg" run "$root/data.toml" --out "$root/ref" >"$root/ref.log" 2>&1 || fail "single-process run ($root/ref.log)"

# Every file of a dataset but logs and locks, with its hash.
digest() { (cd "$1" && find . -type f ! -path './logs/*' ! -name '*.lock' ! -name '.lock*' -print0 | sort -z | xargs -0 sha256sum); }
digest "$root/ref" > "$root/ref.sha"
same() {
  digest "$1" > "$1.sha"
  diff -q "$root/ref.sha" "$1.sha" >/dev/null || { diff "$root/ref.sha" "$1.sha" | head -5 >&2; fail "$2: the dataset differs from the single-process run"; }
  echo "test_slurm: $2: byte-identical to the single-process run" >&2
}
wait_job() {  # waits until job $1 (and its array tasks) left the queue
  for _ in $(seq 600); do
    [ -z "$(squeue -h -j "$1" 2>/dev/null)" ] && return 0
    sleep 1
  done
  fail "job $1 still queued after 10 minutes: $(squeue -j "$1")"
}
join() {  # join job for array $1 over $2; waits; checks it succeeded
  local j
  j=$(sbatch --parsable --output="$2/logs/join-%j.log" --dependency="afterany:$1" --kill-on-invalid-dep=yes \
      --wrap "'$dg' join '$2' && '$dg' verify '$2'")
  wait_job "$j"
  [ "$(sacct_state "$j")" = COMPLETED ] || fail "join of $2 did not succeed: $(cat "$2"/logs/join-*.log | tail -5)"
}
sacct_state() { scontrol show job "$1" 2>/dev/null | grep -o 'JobState=[A-Z_]*' | head -1 | cut -d= -f2; }
# Slurm holds a requeued job back for a while (Reason=BeginTime); a test need not wait for that.
release_requeued() {
  for _ in $(seq 600); do
    local info
    info=$(scontrol show job "$1" 2>/dev/null || true)
    if grep -q 'JobState=PENDING' <<<"$info" && grep -q 'Reason=BeginTime' <<<"$info"; then
      scontrol update JobId="$1" StartTime=now
      return 0
    fi
    grep -qE 'JobState=(COMPLETED|FAILED|CANCELLED|TIMEOUT)' <<<"$info" && return 0
    sleep 0.2
  done
}
array() {  # name, sbatch options...: submits scripts/datagen_slurm.sh over OUT=$root/NAME, joins, compares
  local name=$1; shift
  local out=$root/$name
  mkdir -p "$out/logs"
  local jid
  jid=$(DATAGEN=$dg sbatch --parsable --output="$out/logs/%x-%A_%a.log" "$@" scripts/datagen_slurm.sh "$root/data.toml" "$out")
  echo "${jid%%;*}"
}

for spec in 0-3 1-4 0-6:2 0-3%2; do
  name=array-${spec//[:%]/_}
  jid=$(array "$name" --array="$spec")
  wait_job "$jid"
  join "$jid" "$root/$name"
  same "$root/$name" "--array=$spec"
done

# A task requeued while it runs (held up by a wrapper that sleeps first, so that it is caught
# running): the afterany join still runs, and the data are whole.
cat > "$root/slow-datagen" <<SLOW
#!/bin/sh
sleep 4
exec '$dg' "\$@"
SLOW
chmod +x "$root/slow-datagen"
out=$root/requeue
mkdir -p "$out/logs"
jid=$(DATAGEN=$root/slow-datagen sbatch --parsable --output="$out/logs/%x-%A_%a.log" --array=0-3 \
      scripts/datagen_slurm.sh "$root/data.toml" "$out")
jid=${jid%%;*}
for _ in $(seq 300); do
  [ "$(sacct_state "${jid}_2")" = RUNNING ] && break
  sleep 0.1
done
[ "$(sacct_state "${jid}_2")" = RUNNING ] || fail "task ${jid}_2 was never seen running"
sleep 1
scontrol requeue "${jid}_2" || fail "could not requeue ${jid}_2"
release_requeued "${jid}_2"
wait_job "$jid"
restarts=$(scontrol show job "${jid}_2" | grep -o 'Restarts=[0-9]*' | cut -d= -f2)
[ "${restarts:-0}" -ge 1 ] || fail "task ${jid}_2 did not restart"
join "$jid" "$out"
same "$out" "--array=0-3 with task 2 requeued while running"

# A failed index re-submitted alone into the same run.
jid=$(WORKERS=4 array resubmit --array=0,1,3)
wait_job "$jid"
jid2=$(WORKERS=4 array resubmit --array=2)
wait_job "$jid2"
join "$jid2" "$root/resubmit"
same "$root/resubmit" "--array=0,1,3 then --array=2 (WORKERS=4)"

# A one-task array without WORKERS is refused, not rendered as the whole run.
jid=$(array refused --array=2)
wait_job "$jid"
grep -q "WORKERS=N" "$root"/refused/logs/*.log || fail "a one-task array without WORKERS was not refused"

# --- preemptible training -------------------------------------------------------------------------
sed "s#@DATASET@#$root/ref#" "$repo/tests/fixtures/manifests/jobs-training.toml" > "$root/train.toml"
"$tr" run "$root/train.toml" --out "$root/train-ref" --quiet >"$root/train-ref.log" 2>&1 || fail "uninterrupted training ($root/train-ref.log)"
for at in 7 180; do
  out=$root/train-$at
  jid=$(TRAINER=$tr MATEDIT_PROGRESS_SECS=1 sbatch --parsable --output="$root/train-$at.log" scripts/train_slurm.sh "$root/train.toml" "$out")
  for _ in $(seq 600); do
    [ -f "$out/metrics.jsonl" ] && [ "$(wc -l < "$out/metrics.jsonl")" -ge "$at" ] && break
    sleep 0.1
  done
  scancel --batch --signal=USR1 "$jid"
  release_requeued "$jid"
  wait_job "$jid"
  [ "$(sacct_state "$jid")" = COMPLETED ] || fail "training job $jid: $(sacct_state "$jid"); $(tail -5 "$root/train-$at.log")"
  grep -q "requeueing" "$root/train-$at.log" || fail "training job $jid was not requeued ($root/train-$at.log)"
  restarts=$(scontrol show job "$jid" | grep -o 'Restarts=[0-9]*' | cut -d= -f2)
  [ "${restarts:-0}" -ge 1 ] || fail "training job $jid did not restart"
  cmp -s "$root/train-ref/metrics.jsonl" "$out/metrics.jsonl" || fail "signal after $at steps: metrics.jsonl differs from the uninterrupted run"
  grep -q "steps: .*/s, .* elapsed" "$root/train-$at.log" || fail "no plain progress line in the batch log"
  echo "test_slurm: training signalled after $at steps, requeued, resumed: metrics.jsonl identical" >&2
done
# --- data-parallel training: 2 tasks (MPI ranks under srun --mpi=pmix) -----------------------------
# Needs a trainer built with `--features mpi` (MPI_TRAINER, default target/mpi/trainer, which
# .ci/run builds) and Slurm's PMIx plugin; skipped, saying so, without them.
mpi_trainer=${MPI_TRAINER:-$target/mpi/trainer}
if [ ! -x "$mpi_trainer" ]; then
  echo "test_slurm: 2-task training skipped: no MPI trainer at $mpi_trainer (cargo build --release -p matedit-trainer --features mpi)" >&2
elif ! srun --mpi=list 2>&1 | grep -q pmix; then
  echo "test_slurm: 2-task training skipped: this Slurm has no PMIx plugin (srun --mpi=list)" >&2
else
  # 200 steps: W ranks sum in another order than one process, and on this run a near-tie in
  # the forward pass amplifies that rounding past the tolerance after about 205 steps
  # (docs/PERFORMANCE.md, "Training on several ranks").
  awk '/^steps = 150$/ && ++n == 2 {print "steps = 50"; next} {print}' "$root/train.toml" > "$root/train-short.toml"
  "$tr" run "$root/train-short.toml" --out "$root/train-short-ref" --quiet >"$root/train-short-ref.log" 2>&1 \
    || fail "uninterrupted short training ($root/train-short-ref.log)"
  out=$root/train-2tasks
  jid=$(TRAINER=$mpi_trainer MATEDIT_PROGRESS_SECS=1 sbatch --parsable --ntasks=2 --output="$root/train-2tasks.log" \
        scripts/train_slurm.sh "$root/train-short.toml" "$out")
  for _ in $(seq 600); do
    [ -f "$out/metrics.jsonl" ] && [ "$(wc -l < "$out/metrics.jsonl")" -ge 100 ] && break
    sleep 0.1
  done
  scancel --batch --signal=USR1 "$jid"
  release_requeued "$jid"
  wait_job "$jid"
  [ "$(sacct_state "$jid")" = COMPLETED ] || fail "2-task training job $jid: $(sacct_state "$jid"); $(tail -5 "$root/train-2tasks.log")"
  grep -q "requeueing" "$root/train-2tasks.log" || fail "2-task training job $jid was not requeued ($root/train-2tasks.log)"
  grep -q "rank 1 of 2" "$root/train-2tasks.log" || fail "2-task training job $jid did not run as 2 ranks ($root/train-2tasks.log)"
  restarts=$(scontrol show job "$jid" | grep -o 'Restarts=[0-9]*' | cut -d= -f2)
  [ "${restarts:-0}" -ge 1 ] || fail "2-task training job $jid did not restart"
  # Equal to the one-process run within the rank tests' tolerance (tests/ranks.rs: 1e-4 relative).
  python3 - "$root/train-short-ref/metrics.jsonl" "$out/metrics.jsonl" <<'PY' || fail "2 tasks: metrics.jsonl differs from the one-process run beyond 1e-4"
import json, sys
a, b = ([json.loads(l) for l in open(p)] for p in sys.argv[1:3])
assert len(a) == len(b), f"{len(a)} against {len(b)} steps"
worst = 0.0
for x, y in zip(a, b):
    assert (x["stage"], x["step"]) == (y["stage"], y["step"])
    for k, v in x["losses"].items():
        w = y["losses"][k]
        d = abs(v - w) / max(abs(v), abs(w), 1e-30)
        assert d <= 1e-4 or abs(v - w) <= 1e-9, f"{k} at {x['stage']}/{x['step']}: {v} against {w}"
        worst = max(worst, d)
print(f"test_slurm: 2 tasks, signalled after 100 steps, requeued, resumed: {len(a)} steps equal to one process (worst relative difference {worst:.1e})", file=sys.stderr)
PY
fi
echo "test_slurm: all passed" >&2
