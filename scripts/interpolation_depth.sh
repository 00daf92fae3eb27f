#!/bin/bash
# Issue 17: the bandai2 walk → run interpolation (8 steps, DDIM 50, refined inversion, N = 10)
# with the motions inverted to noise levels 1, 50, 150, 300 and 999 (`interpolate --invert-to`),
# then the motions of each scored through `socdiff eval --generated` against the test split.
# Level 1 is nearly a plain spherical blend of the two motions' features (the baseline any
# deeper level must beat on plausibility); 999 is pure noise, the method of the issue.
# Usage: scripts/interpolation_depth.sh RUN OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -euo pipefail
M=${1:?usage: scripts/interpolation_depth.sh RUN OUT_DIR}; O=${2:?usage: scripts/interpolation_depth.sh RUN OUT_DIR}
B=${SOCDIFF:-target/release/socdiff}; D=../shared/data
mkdir -p "$O"
G=()
for level in 1 50 150 300 999; do
  steps=$(( level + 1 < 50 ? level + 1 : 50 ))
  "$B" interpolate --model "$M" --from $D/bandai2 --from-sequence dataset-2_walk_normal_001 \
    --to $D/bandai2 --to-sequence dataset-2_run_active_001 --steps 8 --ddim-steps $steps \
    --refine-inversion 10 --invert-to $level --out "$O/level$level" | tee "$O/level$level.log"
  G+=("level$level=$O/level$level")
done
"$B" eval --reference $D/bandai2 --split test --generated "$(IFS=,; echo "${G[*]}")" \
  --metrics ndms,bone-length,speed,jerk --out "$O/eval" | tee "$O/eval.log"
