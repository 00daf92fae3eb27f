#!/bin/bash
# Issue 17, where the bandai2 NDMS gap comes from: a 12-minute bandai2 model on both cores (the
# generation_runs.sh recipe otherwise), 64 scenes generated at the training window (96 frames)
# and at 150 frames, with 50 and 200 DDIM steps, scored through `socdiff eval --generated`.
# Usage: scripts/ndms_probe.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -uo pipefail
O=${1:?usage: scripts/ndms_probe.sh OUT_DIR}; B=${SOCDIFF:-target/release/socdiff}
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
export RAYON_NUM_THREADS=2
train b12 720 "${bandai[@]}"
for f in 96 150; do for s in 50 200; do
  $B generate --model $O/b12 --persons 1 --frames $f --samples 64 --steps $s --seed 1 --out $O/gen-f$f-s$s > $O/gen-f$f-s$s.log 2>&1
done; done
$B eval --reference $D/bandai2 --split test --generated f96s50=$O/gen-f96-s50,f96s200=$O/gen-f96-s200,f150s50=$O/gen-f150-s50,f150s200=$O/gen-f150-s200 --metrics ndms,apd,bone-length,speed --out $O/eval > $O/eval.log 2>&1

