#!/bin/bash
# Issue 17, bandai2: what the NDMS of generated scenes responds to (docs/recipes.md §9,
# "What NDMS rewards"). For a bandai2 model RUN, 64 scenes of 96 frames (seed 1, as in
# scripts/autoguidance_probe.sh) and, all scored against the test split:
#  - the real train split cut by motion kind (the real level, 0.456, is a mix of these);
#  - the samples smoothed over time (σ 1 and 2 frames): is jitter the gap?
#  - the samples split at a mean root speed of 0.6 m/s: moving against still;
#  - other samplers: ancestral DDPM, DDIM 50 at η 0.5 and 1, DDIM 250 at η 1.
# Usage: scripts/ndms_diagnostics.sh RUN OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -euo pipefail
R=${1:?usage: scripts/ndms_diagnostics.sh RUN OUT_DIR}; O=${2:?usage: scripts/ndms_diagnostics.sh RUN OUT_DIR}
B=${SOCDIFF:-target/release/socdiff}; D=../shared/data/bandai2; S=$(dirname "$0")
mkdir -p "$O"
for kind in walk:walk turn:walk-turn-left,walk-turn-right run:run wave:wave-both-hands,wave-left-hand,wave-right-hand \
            raise:raise-up-both-hands,raise-up-left-hand,raise-up-right-hand; do
  python3 "$S/subset_dataset.py" $D "$O/real-${kind%%:*}" --motions "${kind#*:}" --max-mb 1000
done
"$B" eval --reference $D --split test --generated-split train --metrics ndms,speed,jerk --out "$O/eval-real-kinds" \
  --generated "walk=$O/real-walk,walk-turn=$O/real-turn,run=$O/real-run,wave=$O/real-wave,raise-up=$O/real-raise"
gen() { "$B" generate --model "$R" --persons 1 --frames 96 --samples 64 --seed 1 --out "$O/$1" "${@:2}" > /dev/null; }
gen gen
python3 "$S/dataset_probe.py" smooth "$O/gen" "$O/gen-smooth1" 1
python3 "$S/dataset_probe.py" smooth "$O/gen" "$O/gen-smooth2" 2
python3 "$S/dataset_probe.py" split-speed "$O/gen" 0.6
gen gen-ddpm --sampler ddpm
gen gen-eta05 --eta 0.5
gen gen-eta1 --eta 1
gen gen-ddim250-eta1 --steps 250 --eta 1
"$B" eval --reference $D --split test --kinds-data $D --metrics ndms,apd,bone-length,speed,jerk,coverage,kinds --out "$O/eval-samples" \
  --generated "ddim50=$O/gen,smooth-1=$O/gen-smooth1,smooth-2=$O/gen-smooth2,fast=$O/gen-fast,slow=$O/gen-slow,ddpm=$O/gen-ddpm,ddim50-eta0.5=$O/gen-eta05,ddim50-eta1=$O/gen-eta1,ddim250-eta1=$O/gen-ddim250-eta1"
