#!/bin/bash
# Issue 17, bandai2: two variants of the L2 lookahead recipe (scripts/loss_probe.sh; each variant's
# flags give its --velocity-loss) trained for 30 minutes on one thread each, both at once, then
# scored by scripts/seed_spread.sh (8 sets of 64 scenes of 96 frames per model, seeds 1–8, η 0 and 1).
# Usage: scripts/lever_pair.sh OUT_DIR NAME_A "FLAGS_A" NAME_B "FLAGS_B"
#   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -uo pipefail
O=${1:?usage: scripts/lever_pair.sh OUT_DIR NAME_A FLAGS_A NAME_B FLAGS_B}; B=${SOCDIFF:-target/release/socdiff}
NA=$2 FA=$3 NB=$4 FB=$5
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
export RAYON_NUM_THREADS=1
# shellcheck disable=SC2086 # the flags are word lists
train "$NA" 1800 "${bandai[@]}" $bandai_l2 $FA & train "$NB" 1800 "${bandai[@]}" $bandai_l2 $FB & wait
export RAYON_NUM_THREADS=2
"$(dirname "$0")/seed_spread.sh" "$O/spread" "$NA=$O/$NA" "$NB=$O/$NB" || exit 1
touch "$O/DONE"
