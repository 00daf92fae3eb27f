#!/bin/bash
# Issue 17, bandai2: how much one set of 64 generated scenes says. For each NAME=MODEL, 8 sets of
# 64 one-person scenes of 96 frames (sample seeds 1–8, DDIM 50, η 0 and η 1), scored in one
# `socdiff eval --generated` against the test split; scripts/seed_summary.py then prints each
# model's mean and spread over the seeds.
# Usage: scripts/seed_spread.sh OUT_DIR NAME=MODEL [NAME=MODEL ...]
#   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -uo pipefail
O=${1:?usage: scripts/seed_spread.sh OUT_DIR NAME=MODEL ...}; shift; B=${SOCDIFF:-target/release/socdiff}
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
G=()
for pair in "$@"; do
  name=${pair%%=*} model=${pair#*=}
  for e in 0 1; do for s in 1 2 3 4 5 6 7 8; do
    "$B" generate --model "$model" --persons 1 --frames 96 --samples 64 --seed $s --eta $e --out "$O/gen-$name-eta$e-s$s" > "$O/gen-$name-eta$e-s$s.log" 2>&1 \
      || { echo "generate failed: see $O/gen-$name-eta$e-s$s.log"; exit 1; }
    G+=("$name-eta$e-s$s=$O/gen-$name-eta$e-s$s")
  done; done
done
"$B" eval --split test --generated "$(IFS=,; echo "${G[*]}")" "${bandai_scores[@]}" --out "$O/eval" > "$O/eval.log" 2>&1 \
  || { echo "eval failed: see $O/eval.log"; exit 1; }
python3 "$(dirname "$0")/seed_summary.py" "$O/eval" | tee "$O/summary.txt"
