#!/usr/bin/env bash
# Fits the paper's DSBRDF to each of MERL's 100 materials given as neural BRDFs:
#   bash scripts/fit_merl_nbrdf.sh [DIR] [OUT]
# DIR: the *.nbrdf.json folder (default ../shared/eval-assets/brdfs/merl-nbrdf); OUT: where the
# fitted materials and their .fit.json reports go (default out/merl-fits). Prints a Markdown table
# of every material's fit errors, worst rendered error first, and writes it to OUT/fits.md.
set -euo pipefail
cd "$(dirname "$0")/.."
dir=${1:-../shared/eval-assets/brdfs/merl-nbrdf}
out=${2:-out/merl-fits}
[ -d "$dir" ] || { echo "no folder $dir (the MERL neural BRDFs: ../shared/eval-assets/brdfs/merl-nbrdf)" >&2; exit 1; }
cargo build --release -q -p matedit-datagen --bin datagen
mkdir -p "$out"
n=0
for f in "$dir"/*.nbrdf.json; do
  name=$(basename "$f" .nbrdf.json)
  if [ ! -s "$out/$name.fit.json" ]; then
    target/release/datagen fit --brdf "nbrdf:$f" --out "$out/$name.json" >/dev/null
  fi
  n=$((n + 1))
done
python3 - "$out" <<'PY' | tee "$out/fits.md"
import glob, json, os, statistics, sys
rows = []
for p in sorted(glob.glob(os.path.join(sys.argv[1], "*.fit.json"))):
    r = json.load(open(p))
    errs = r["rendered_rel_rmse"]
    rows.append((max(errs.values()), os.path.basename(p)[:-len(".fit.json")], r["brdf_log_rmse"], errs))
rows.sort(reverse=True)
envs = list(rows[0][3].keys())
print(f"{len(rows)} MERL materials (neural BRDFs) fitted to the DSBRDF; rendered relative RMSE per environment, worst first\n")
print("| material | BRDF-space log RMSE | " + " | ".join(envs) + " | worst |")
print("|---|---|" + "---|" * (len(envs) + 1))
for worst, name, log_rmse, errs in rows:
    print(f"| {name} | {log_rmse:.4f} | " + " | ".join(f"{100 * errs[e]:.2f} %" for e in envs) + f" | {100 * worst:.2f} % |")
w = [r[0] for r in rows]
print(f"\nworst rendered error: median {100 * statistics.median(w):.2f} %, mean {100 * statistics.mean(w):.2f} %, "
      f"max {100 * max(w):.2f} % ({rows[0][1]}); {sum(x > 0.10 for x in w)} of {len(w)} above 10 %")
PY
