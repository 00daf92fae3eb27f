#!/bin/bash
# Issue 17, bandai2: autoguidance of MODEL by GUIDE (its own tenth-of-the-time checkpoint) at a
# few gentle weights, each over sample seeds 1–8 (64 one-person scenes of 96 frames, DDIM 50),
# scored against the train split (to choose) and the test split (to report);
# scripts/seed_summary.py prints each setting's mean over the seeds.
# Usage: scripts/guidance_spread.sh OUT_DIR MODEL GUIDE   (SOCDIFF=…, default target/release/socdiff)
set -uo pipefail
O=${1:?usage: scripts/guidance_spread.sh OUT_DIR MODEL GUIDE}; M=${2:?model}; W=${3:?guide}; B=${SOCDIFF:-target/release/socdiff}
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
G=()
for w in 1.25 1.5 2; do for from in 700 900; do for s in 1 2 3 4 5 6 7 8; do
  n="w$w-from$from-s$s"
  "$B" generate --model "$M" --guide "$W" --guidance $w --guide-from $from --persons 1 --frames 96 --samples 64 --seed $s \
    --out "$O/gen-$n" > "$O/gen-$n.log" 2>&1 || { echo "generate failed: see $O/gen-$n.log"; exit 1; }
  G+=("$n=$O/gen-$n")
done; done; done
for split in train test; do
  "$B" eval --split $split --generated "$(IFS=,; echo "${G[*]}")" "${bandai_scores[@]}" --out "$O/eval-$split" > "$O/eval-$split.log" 2>&1 \
    || { echo "eval failed: see $O/eval-$split.log"; exit 1; }
  echo "against the $split split:"; python3 "$(dirname "$0")/seed_summary.py" "$O/eval-$split" | tee "$O/summary-$split.txt"
done
