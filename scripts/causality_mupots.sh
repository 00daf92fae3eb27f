#!/bin/bash
# Issue 17, MuPoTS (groups): the recipe's MuPoTS model (generation_recipe.sh) with the paper's
# causal denoiser and with `--causality lookahead`, 25 minutes each, side by side (one thread
# each); 64 generated 3-person scenes of 150 frames from each, scored through `socdiff eval`
# against the test split.
# Usage: scripts/causality_mupots.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default
#   target/release/socdiff: build it with `cargo build --release -p socdiff-cli`)
set -uo pipefail
O=${1:?usage: scripts/causality_mupots.sh OUT_DIR}; B=${SOCDIFF:-target/release/socdiff}
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
export RAYON_NUM_THREADS=1
train mupots-causal 1500 "${mupots[@]}" & train mupots-lookahead 1500 "${mupots[@]}" --causality lookahead & wait
export RAYON_NUM_THREADS=2
for m in mupots-causal mupots-lookahead; do
  "$B" generate --model "$O/$m" --persons 3 --frames 150 --samples 64 --seed 1 --out "$O/gen-$m" > "$O/gen-$m.log" 2>&1
done
"$B" eval --reference $D/mupots3d --split test --generated causal=$O/gen-mupots-causal,lookahead=$O/gen-mupots-lookahead \
  --metrics ndms,apd,bone-length,foot-sliding,speed,acceleration,jerk,coverage --out "$O/eval" > "$O/eval.log" 2>&1
touch "$O/DONE"
