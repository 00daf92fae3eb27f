#!/usr/bin/env bash
# Training at scale on mixed sources (issue: recipes, part 5): trains a MuPoTS-only model and a
# MuPoTS + bandai2 model (bandai2's single-person clips mapped onto MuPoTS-17 by joint names and
# stitched into synthetic groups around a shared centre) side by side for the same wall time
# and the same settings; the mixed model spends its last FT_SECONDS fine-tuning on MuPoTS alone
# (`socdiff train --resume` with other data). Then it forecasts MuPoTS's test split with
# MuPoTS-only, mixed (before fine-tuning) and mixed + fine-tuned, and writes one comparison table
# (NDMS, MPJPE at 1/2/3 s, plausibility) to $OUT/comparison.md.
#
# Usage: OUT=/path/to/out bash scripts/scale_runs.sh [SOCDIFF_BINARY]
#   SOCDIFF_BINARY  release binary (default target/release/socdiff)
# Environment (defaults: the 16-core run; tiny values make a smoke test):
#   DATA=../shared/data        folder with mupots3d/ and bandai2/ (or set MUPOTS and BANDAI)
#   THREADS=8                  RAYON_NUM_THREADS of each of the two trainings
#   TRAIN_SECONDS=420          wall time of each training (stopped by SIGINT, which saves)
#   FT_SECONDS=140             of which the mixed model fine-tunes on MuPoTS alone (0: none)
#   MAX_STEPS=100000           step cap of each training
#   HIDDEN=64 WINDOW=160 STRIDE=5 BATCH=32 LR=2e-4 SEED=0
#   SYN_GROUPS=150 REPEAT=3        synthetic bandai2 groups; MuPoTS train scenes counted REPEAT
#                              times in the mix (≈ 1/3 real windows)
#   SAMPLES=4 DDIM=50 OBSERVE=60 HORIZON=90 WINDOW_STRIDE=30   evaluation protocol
#
# On the device machine only the checkout travels (64 MiB at most, ../shared does not): copy the
# binary, mupots3d (4 MB) and a bandai2 subset (scripts/subset_dataset.py, 35 MB) into a folder
# that .git/info/exclude ignores, carry it, and point MUPOTS/BANDAI there, e.g.
#   echo /.scale/ >> .git/info/exclude; mkdir -p .scale; cp target/release/socdiff .scale/
#   cp -r ../shared/data/mupots3d .scale/
#   python3 scripts/subset_dataset.py ../shared/data/bandai2 .scale/bandai2 --split train --min-frames 96 --max-mb 40
#   (device) OUT=$OUT MUPOTS=.scale/mupots3d BANDAI=.scale/bandai2 bash scripts/scale_runs.sh .scale/socdiff
set -euo pipefail
cd "$(dirname "$0")/.."
sd=${1:-target/release/socdiff}
out=${OUT:?set OUT to the output folder}
data=${DATA:-../shared/data}
threads=${THREADS:-8}
secs=${TRAIN_SECONDS:-420}
ft=${FT_SECONDS:-140}
steps=${MAX_STEPS:-100000}
hidden=${HIDDEN:-64}; window=${WINDOW:-160}; stride=${STRIDE:-5}; batch=${BATCH:-32}; lr=${LR:-2e-4}; seed=${SEED:-0}
groups=${SYN_GROUPS:-150}; repeat=${REPEAT:-3}
samples=${SAMPLES:-4}; ddim=${DDIM:-50}; observe=${OBSERVE:-60}; horizon=${HORIZON:-90}; wstride=${WINDOW_STRIDE:-30}
mupots=${MUPOTS:-$data/mupots3d}
bandai=${BANDAI:-$data/bandai2}
for d in "$mupots" "$bandai"; do
  [ -f "$d/dataset.json" ] || { echo "error: $d/dataset.json not found (set DATA)" >&2; exit 1; }
done
[ -x "$sd" ] || { echo "error: $sd is not an executable socdiff binary" >&2; exit 1; }
mkdir -p "$out"
{ echo "# scale runs $(date -u +%FT%TZ)"; echo "host: $(nproc) cores; $(uptime)"; "$sd" --version; } > "$out/env.txt"

common=(--steps "$steps" --hidden "$hidden" --window "$window" --stride "$stride" --batch "$batch"
        --lr "$lr" --seed "$seed" --save-every 100 --val-every 0 --aggregator mean)
train() { # name, seconds, then extra arguments
  local name=$1 t=$2; shift 2
  # One SIGINT after $t seconds makes socdiff save and stop (not `timeout`, which signals the
  # child and then its whole process group: a second SIGINT quits without saving).
  RAYON_NUM_THREADS=$threads "$sd" train --out "$out/$name" "${common[@]}" "$@" >> "$out/$name.log" 2>&1 &
  local pid=$!
  ( sleep "$t"; kill -INT "$pid" 2>/dev/null ) &
  local watchdog=$!
  wait "$pid" || true
  kill "$watchdog" 2>/dev/null || true
  grep -q "saved" "$out/$name.log" || { echo "error: training $name failed:" >&2; tail -5 "$out/$name.log" >&2; exit 1; }
}
echo "training both models for ${secs} s each ($threads threads each; the mixed one fine-tunes on MuPoTS for the last ${ft} s)…"
train mupots_only "$secs" --data "$mupots" &
p1=$!
(
  train mixed "$((secs - ft))" --data "$mupots" --data "$bandai" --synthetic-groups "$groups" --repeat-first "$repeat"
  if [ "$ft" -gt 0 ]; then
    cp -r "$out/mixed" "$out/mixed_ft"
    train mixed_ft "$ft" --resume --data "$mupots"
  fi
) &
p2=$!
wait $p1; wait $p2
models=(mupots_only mixed)
[ "$ft" -gt 0 ] && models+=(mixed_ft)
for n in "${models[@]}"; do
  echo "$n: $(grep -c '"loss"' "$out/$n/train_log.jsonl") steps, last: $(tail -1 "$out/$n/train_log.jsonl")"
done | tee "$out/steps.txt"

echo "forecasting MuPoTS test with ${models[*]}…"
model_args=(); for n in "${models[@]}"; do model_args+=(--model "$out/$n"); done
RAYON_NUM_THREADS=$((2 * threads)) "$sd" ablate --data "$mupots" "${model_args[@]}" \
  --samplers "ddim$ddim" --samples "$samples" --observe "$observe" --horizon "$horizon" --window-stride "$wstride" \
  --seed "$seed" --out "$out/eval" > "$out/eval.log" 2>&1 || { tail -5 "$out/eval.log" >&2; exit 1; }
{ echo "## MuPoTS-only vs MuPoTS + bandai2 (synthetic groups), evaluated on MuPoTS test"; echo;
  cat "$out/eval/table.md"; echo; cat "$out/steps.txt"; echo; grep -h "^data \|joints mapped\|←" "$out/mixed.log" || true; } > "$out/comparison.md"
cat "$out/comparison.md"
