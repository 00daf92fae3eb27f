#!/bin/bash
# `socdiff bench realtime` beside the PyTorch twin (../shared/bench/torch_unet.py) making the same
# number of network calls on the same machine, one after the other: for each DDIM step count, the
# p50 and p99 of socdiff's whole forecasts (3 persons, 30 + 90 frames, K = 8) and the twin's
# median seconds per call (8 samples × 3 persons × 120 frames) times the calls.
# Usage: scripts/bench_realtime_vs_torch.sh MODEL [STEPS] [THREADS]
#   STEPS: comma-separated DDIM step counts (default 50,20,8,4,2); THREADS: default every CPU.
# Env: SOCDIFF (default target/release/socdiff), VENV (default .venv-torch: created with
#      `pip install torch` when missing), TWIN (default ../shared/bench/torch_unet.py),
#      HIDDEN and CIN (the twin's width and input dims; default 64 and 49, the bundled model's).
set -euo pipefail
model=$1
steps=${2:-50,20,8,4,2}
threads=${3:-$(nproc)}
bin=${SOCDIFF:-target/release/socdiff}
venv=${VENV:-.venv-torch}
twin=${TWIN:-../shared/bench/torch_unet.py}
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import torch" 2>/dev/null; then
  python3 -m venv "$venv" && "$venv/bin/pip" install -q torch numpy
fi
export RAYON_NUM_THREADS=$threads OMP_NUM_THREADS=$threads
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "threads $threads; $(nproc) CPUs; load $(cut -d' ' -f1 /proc/loadavg)"
"$bin" bench realtime --model "$model" --steps "$steps" --no-quality --repeats 30 --threads "$threads" --out "$out/r" >/dev/null 2>&1
# The twin's call costs the same at every step count: measured once.
med=$("$venv/bin/python" "$twin" --mode sample --hidden "${HIDDEN:-64}" --cin "${CIN:-49}" --batch 8 --persons 3 --t 120 --iters 30 --threads "$threads" 2>/dev/null | sed -n 's/.*step_median=\([0-9.]*\)s.*/\1/p')
echo "PyTorch twin: ${med} s per call (median of 30)"
printf '%6s %14s %14s %18s %10s\n' steps "socdiff p50 ms" "socdiff p99 ms" "torch calls×med ms" "ratio p50"
for s in ${steps//,/ }; do
  read -r p50 p99 < <(python3 -c "import json,sys; r=[r for r in json.load(open(sys.argv[1]))['rows'] if r['steps']==int(sys.argv[2])][0]['latency']; print(r['p50_ms'], r['p99_ms'])" "$out/r/realtime.json" "$s")
  python3 -c "import sys; s,p50,p99,m=int(sys.argv[1]),float(sys.argv[2]),float(sys.argv[3]),float(sys.argv[4]); t=s*m*1e3; print(f'{s:6d} {p50:14.1f} {p99:14.1f} {t:18.1f} {p50/t:10.2f}')" "$s" "$p50" "$p99" "$med"
done
