#!/bin/bash
# Issue 17, bandai2: autoguidance (generate --guide). Two variants of the recipe's model
# (generation_recipe.sh), both at once on one thread each: 180 s of training, a copy of that
# checkpoint (NAME-tenth: the "tenth of the time" model, and the guide), then the same run
# resumed up to 1800 s in all. 64 scenes of 96 frames (DDIM 50) for every guidance weight w and
# lowest guided level of the grid, unguided, and from the tenth model; all scored against the
# train split (where the setting is chosen) and the test split (where it is reported).
# Usage: scripts/autoguidance_probe.sh OUT_DIR NAME_A "FLAGS_A" NAME_B "FLAGS_B"
#   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -uo pipefail
O=${1:?usage: scripts/autoguidance_probe.sh OUT_DIR NAME_A FLAGS_A NAME_B FLAGS_B}; B=${SOCDIFF:-target/release/socdiff}
NA=$2 FA=$3 NB=$4 FB=$5
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
export RAYON_NUM_THREADS=1
run() { # name flags: 180 s, snapshot, resume to 1800 s
  # shellcheck disable=SC2086 # the flags are a word list
  train "$1" 180 "${bandai[@]}" $2
  cp -r "$O/$1" "$O/$1-tenth"
  timeout -s INT 1620 "$B" train --data $D/bandai2 --out "$O/$1" --resume --steps 100000000 --save-every 200 --val-every 0 >> "$O/$1.log" 2>&1
}
run "$NA" "$FA" & run "$NB" "$FB" & wait
export RAYON_NUM_THREADS=2
for m in "$NA" "$NB"; do
  G=("$m=$O/gen-$m" "$m-tenth=$O/gen-$m-tenth")
  "$B" generate --model "$O/$m" --persons 1 --frames 96 --samples 64 --seed 1 --out "$O/gen-$m" > /dev/null
  "$B" generate --model "$O/$m-tenth" --persons 1 --frames 96 --samples 64 --seed 1 --out "$O/gen-$m-tenth" > /dev/null
  for w in 2 4 6 8 10; do for l in 600 700 800 900; do
    n="$m-w$w-from$l"
    "$B" generate --model "$O/$m" --guide "$O/$m-tenth" --guidance $w --guide-from $l --persons 1 --frames 96 --samples 64 --seed 1 --out "$O/gen-$n" > /dev/null
    G+=("$n=$O/gen-$n")
  done; done
  for split in train test; do
    "$B" eval --split $split --generated "$(IFS=,; echo "${G[*]}")" "${bandai_scores[@]}" --out "$O/eval-$m-$split" > "$O/eval-$m-$split.log" 2>&1
  done
done
touch "$O/DONE"
