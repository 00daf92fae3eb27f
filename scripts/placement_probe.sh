#!/bin/bash
# Issue 17: where a generated scene's placement sits. With the 12-minute bandai2 model of
# ndms_probe.sh (MODEL, default OUT_DIR/b12), 64 scenes at 96 and 150 frames (DDIM 50) with the
# placement at frame 0 (the behaviour until e9d7701) and at the model's anchor frame (the
# default), scored through `socdiff eval --generated` with the train split as the real level.
# Usage: scripts/placement_probe.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -uo pipefail
O=${1:?usage: scripts/placement_probe.sh OUT_DIR}; B=${SOCDIFF:-target/release/socdiff}; M=${MODEL:-$O/b12}
D=../shared/data
export RAYON_NUM_THREADS=2
G=()
for f in 96 150; do
  "$B" generate --model "$M" --persons 1 --frames $f --samples 64 --seed 1 --placement-frame 0 --out "$O/place0-f$f" > "$O/place0-f$f.log" 2>&1
  "$B" generate --model "$M" --persons 1 --frames $f --samples 64 --seed 1 --out "$O/anchor-f$f" > "$O/anchor-f$f.log" 2>&1
  G+=("frame0-f$f=$O/place0-f$f" "anchor-f$f=$O/anchor-f$f")
done
X=(--metrics ndms,apd,bone-length,speed,acceleration,jerk)
"$B" eval --reference $D/bandai2 --split test --generated "$(IFS=,; echo "${G[*]}")" "${X[@]}" --out "$O/eval-placement" > "$O/eval-placement.log" 2>&1
"$B" eval --reference $D/bandai2 --split test --generated real-train=$D/bandai2 --generated-split train "${X[@]}" --out "$O/eval-placement-real" > "$O/eval-placement-real.log" 2>&1
