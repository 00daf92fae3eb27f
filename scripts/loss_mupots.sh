#!/bin/bash
# Issue 17, MuPoTS (groups): the lookahead MuPoTS model of scripts/causality_mupots.sh trained on
# the squared error (`--loss l2`), alone and with the bandai2 recipe's Wiener input scaling
# (σ_d 1) and velocity term (λ 0.25); 25 minutes each, side by side (one thread each); 3 × 64
# generated 3-person scenes of 150 frames from each (sample seeds 1–3, DDIM 50), scored against
# the test split; scripts/seed_summary.py prints the means.
# Usage: scripts/loss_mupots.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -uo pipefail
O=${1:?usage: scripts/loss_mupots.sh OUT_DIR}; B=${SOCDIFF:-target/release/socdiff}
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
export RAYON_NUM_THREADS=1
L="--causality lookahead --loss l2"
V="--input-scaling wiener --sigma-data 1 --velocity-loss 0.25"
# shellcheck disable=SC2086 # the flags are word lists
train mupots-l2 1500 "${mupots[@]}" $L & train mupots-l2-vel 1500 "${mupots[@]}" $L $V & wait
export RAYON_NUM_THREADS=2
G=()
for m in mupots-l2 mupots-l2-vel; do for s in 1 2 3; do
  "$B" generate --model "$O/$m" --persons 3 --frames 150 --samples 64 --seed $s --out "$O/gen-$m-s$s" > "$O/gen-$m-s$s.log" 2>&1
  G+=("$m-s$s=$O/gen-$m-s$s")
done; done
"$B" eval --reference $D/mupots3d --split test --generated "$(IFS=,; echo "${G[*]}")" \
  --metrics ndms,apd,bone-length,foot-sliding,speed,acceleration,jerk,coverage --out "$O/eval" > "$O/eval.log" 2>&1
python3 "$(dirname "$0")/seed_summary.py" "$O/eval" | tee "$O/summary.txt"
touch "$O/DONE"
