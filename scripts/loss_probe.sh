#!/bin/bash
# Issue 17, bandai2: the lookahead recipe (x0, Wiener input scaling σ_d = 1, take balance,
# `--causality lookahead`) trained on the mean squared error (`--loss l2`) instead of the
# paper's L1, with the velocity term (λ = 0.25) and without it, through scripts/bandai_pair.sh
# (30 minutes each, one thread each, both at once). The L1 run of the same recipe is the
# lookahead side of scripts/causality_probe.sh.
# Usage: scripts/loss_probe.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
source "$(dirname "$0")/generation_recipe.sh"
R=$bandai_l2
exec "$(dirname "$0")/bandai_pair.sh" "${1:?usage: scripts/loss_probe.sh OUT_DIR}" \
  l2-la-vel025 "$R --velocity-loss 0.25" l2-la-vel0 "$R"
