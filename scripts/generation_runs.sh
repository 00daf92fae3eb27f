#!/bin/bash
# Issue 17's generation runs (docs/recipes.md §9): a bandai2 model (single persons) and a MuPoTS
# model (groups), each trained for 30 minutes and for a tenth of that (one thread each, the
# bandai2 and MuPoTS runs side by side on the two cores), 64 generated scenes of 150 frames per
# model (placement at the model's anchor frame), scored through `socdiff eval` against
# each dataset's test split together with the real-motion level (the train split scored as if
# generated); then the bandai2 walk → run interpolation.
# Usage: scripts/generation_runs.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
set -uo pipefail
O=$1; B=${SOCDIFF:-target/release/socdiff}
source "$(dirname "$0")/generation_recipe.sh"
mkdir -p "$O"
export RAYON_NUM_THREADS=1
train bandai-30 1800 "${bandai[@]}" & train mupots-30 1800 "${mupots[@]}" & wait
train bandai-3 180 "${bandai[@]}" & train mupots-3 180 "${mupots[@]}" & wait
for m in bandai-30 bandai-3; do "$B" generate --model "$O/$m" --persons 1 --frames 150 --samples 64 --seed 1 --out "$O/gen-$m"; done
for m in mupots-30 mupots-3; do "$B" generate --model "$O/$m" --persons 3 --frames 150 --samples 64 --seed 1 --out "$O/gen-$m"; done
M=ndms,apd,bone-length,foot-sliding,speed,coverage,kinds
K=(--kinds-data $D/bandai2 --metrics $M)
"$B" eval --reference $D/bandai2 --split test --generated b30=$O/gen-bandai-30,b3=$O/gen-bandai-3 "${K[@]}" --out $O/eval-bandai
"$B" eval --reference $D/bandai2 --split test --generated real-train=$D/bandai2 --generated-split train "${K[@]}" --out $O/eval-bandai-real
"$B" eval --reference $D/mupots3d --split test --generated m30=$O/gen-mupots-30,m3=$O/gen-mupots-3 "${K[@]}" --out $O/eval-mupots
"$B" eval --reference $D/mupots3d --split test --generated real-train=$D/mupots3d --generated-split train "${K[@]}" --out $O/eval-mupots-real
for s in 50 250; do
  "$B" interpolate --model "$O/bandai-30" --from $D/bandai2 --from-sequence dataset-2_walk_normal_001 \
    --to $D/bandai2 --to-sequence dataset-2_run_active_001 --steps 8 --ddim-steps $s --out "$O/walk-run-ddim$s"
done
