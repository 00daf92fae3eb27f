#!/bin/bash
# Issue 17, bandai2: v prediction (train --prediction v: the network outputs v = √ᾱ·ε − √(1 − ᾱ)·x0,
# trained on |v̂ − v|, sampled with x̂0 = √ᾱ·x_t − √(1 − ᾱ)·v̂), with the best recipe so far
# (velocity term λ = 0.25 with take balance, width 64; velocity_balance_probe.sh) and with the
# plain recipe, through scripts/bandai_pair.sh (30 minutes each, one thread each, both at once).
# The x0 row to compare with: scripts/velocity_balance_probe.sh (or bandai_pair.sh with
# "--velocity-loss 0.25 --balance sequences").
# Usage: scripts/prediction_probe.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
exec "$(dirname "$0")/bandai_pair.sh" "${1:?usage: scripts/prediction_probe.sh OUT_DIR}" \
  bandai-30-v-vel025-bal "--prediction v --velocity-loss 0.25 --balance sequences" \
  bandai-30-v "--prediction v"
