#!/bin/bash
# Issue 17, bandai2: the L2 lookahead recipe of scripts/loss_probe.sh (λ = 0.25) trained alone on
# both cores (two threads) for 30 minutes, and for 3 minutes (the tenth-of-the-time reference),
# each scored by scripts/two_threads.sh (8 × 64 scenes of 96 frames, and 64 of 150 frames).
# Usage: scripts/loss_two_threads.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
source "$(dirname "$0")/generation_recipe.sh"
R="$bandai_l2 --velocity-loss 0.25"
exec "$(dirname "$0")/two_threads.sh" "${1:?usage: scripts/loss_two_threads.sh OUT_DIR}" l2-2t "$R" "$R"
