#!/bin/bash
# Issue 17, bandai2: the L2 lookahead recipe of scripts/loss_probe.sh (λ = 0.25) trained alone on
# both cores (two threads) for 30 minutes, and for 3 minutes (the tenth-of-the-time reference);
# scripts/seed_spread.sh scores 8 × 64 scenes of 96 frames from each (seeds 1–8, η 0 and 1), and
# 64 scenes of 150 frames from each are scored against the test split.
# Usage: scripts/loss_two_threads.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -uo pipefail
O=${1:?usage: scripts/loss_two_threads.sh OUT_DIR}; B=${SOCDIFF:-target/release/socdiff}
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
export RAYON_NUM_THREADS=2
R="--input-scaling wiener --sigma-data 1 --balance sequences --causality lookahead --loss l2 --velocity-loss 0.25"
# shellcheck disable=SC2086 # the flags are a word list
train l2-2t 1800 "${bandai[@]}" $R
# shellcheck disable=SC2086
train l2-2t-tenth 180 "${bandai[@]}" $R
"$(dirname "$0")/seed_spread.sh" "$O/spread" l2-2t="$O/l2-2t" l2-2t-tenth="$O/l2-2t-tenth" || exit 1
for m in l2-2t l2-2t-tenth; do
  "$B" generate --model "$O/$m" --persons 1 --frames 150 --samples 64 --seed 1 --out "$O/gen-$m-f150" > "$O/gen-$m-f150.log" 2>&1
done
"$B" eval --split test --generated "l2-2t-f150=$O/gen-l2-2t-f150,l2-2t-tenth-f150=$O/gen-l2-2t-tenth-f150" \
  "${bandai_scores[@]}" --out "$O/eval-f150" > "$O/eval-f150.log" 2>&1
touch "$O/DONE"
