#!/bin/bash
# Issue 17, bandai2: one recipe (generation_recipe.sh's bandai2 model with FLAGS) trained alone on
# both cores (two threads) for 30 minutes, and for 3 minutes with TENTH_FLAGS (the tenth-of-the-time
# reference); scripts/seed_spread.sh scores 8 × 64 scenes of 96 frames from each (seeds 1–8, η 0
# and 1), and 64 scenes of 150 frames from each are scored against the test split.
# Usage: scripts/two_threads.sh OUT_DIR NAME "FLAGS" "TENTH_FLAGS"
#   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -uo pipefail
O=${1:?usage: scripts/two_threads.sh OUT_DIR NAME FLAGS TENTH_FLAGS}; B=${SOCDIFF:-target/release/socdiff}
N=${2:?name} F=${3:?flags} FT=${4:?flags of the tenth}
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
export RAYON_NUM_THREADS=2
# shellcheck disable=SC2086 # the flags are word lists
train "$N" 1800 "${bandai[@]}" $F
# shellcheck disable=SC2086
train "$N-tenth" 180 "${bandai[@]}" $FT
"$(dirname "$0")/seed_spread.sh" "$O/spread" "$N=$O/$N" "$N-tenth=$O/$N-tenth" || exit 1
for m in "$N" "$N-tenth"; do
  "$B" generate --model "$O/$m" --persons 1 --frames 150 --samples 64 --seed 1 --out "$O/gen-$m-f150" > "$O/gen-$m-f150.log" 2>&1
done
"$B" eval --split test --generated "$N-f150=$O/gen-$N-f150,$N-tenth-f150=$O/gen-$N-tenth-f150" \
  "${bandai_scores[@]}" --out "$O/eval-f150" > "$O/eval-f150.log" 2>&1
touch "$O/DONE"
