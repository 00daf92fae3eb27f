#!/bin/bash
# Issue 17, bandai2: two variants of the recipe's model (generation_recipe.sh), each trained
# for 30 minutes on one thread, both at once (the two cores); 64 scenes generated from each at
# the training window (96 frames) and at 150 frames (DDIM 50, placement at the model's anchor
# frame), scored through `socdiff eval --generated` against the test split; then the
# walk → run interpolation with each model (DDIM 50 and 250, plain and refined inversion).
# Usage: scripts/bandai_pair.sh OUT_DIR NAME_A "FLAGS_A" NAME_B "FLAGS_B"
#   (SOCDIFF=path/to/socdiff, default target/release/socdiff: build it with
#   `cargo build --release -p socdiff-cli`; a plain `cargo build` at the root builds the facade only)
set -uo pipefail
O=${1:?usage: scripts/bandai_pair.sh OUT_DIR NAME_A FLAGS_A NAME_B FLAGS_B}; B=${SOCDIFF:-target/release/socdiff}
NA=$2 FA=$3 NB=$4 FB=$5
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
export RAYON_NUM_THREADS=1
# shellcheck disable=SC2086 # the flags are word lists
train "$NA" 1800 "${bandai[@]}" $FA & train "$NB" 1800 "${bandai[@]}" $FB & wait
export RAYON_NUM_THREADS=2
G=()
for m in "$NA" "$NB"; do for f in 96 150; do
  "$B" generate --model "$O/$m" --persons 1 --frames $f --samples 64 --seed 1 --out "$O/gen-$m-f$f" > "$O/gen-$m-f$f.log" 2>&1
  G+=("$m-f$f=$O/gen-$m-f$f")
done; done
"$B" eval --split test --generated "$(IFS=,; echo "${G[*]}")" "${bandai_scores[@]}" --out "$O/eval" > "$O/eval.log" 2>&1
for m in "$NA" "$NB"; do for s in 50 250; do for r in 0 10; do
  # r: fixed-point iterations per inversion step (--refine-inversion; 0 = plain DDIM inversion)
  w="walk-run-$m-ddim$s"; [ "$r" = 0 ] || w="$w-refine$r"
  "$B" interpolate --model "$O/$m" --from $D/bandai2 --from-sequence dataset-2_walk_normal_001 \
    --to $D/bandai2 --to-sequence dataset-2_run_active_001 --steps 8 --ddim-steps $s --refine-inversion $r --out "$O/$w" > "$O/$w.log" 2>&1
done; done; done
touch "$O/DONE"
