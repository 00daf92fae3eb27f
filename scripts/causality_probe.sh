#!/bin/bash
# Issue 17, bandai2: the best unguided recipe (x0, Wiener input scaling σ_d = 1, velocity term
# λ = 0.25, take balance) with the paper's causal denoiser and with `--causality lookahead`
# (each output frame also reads the next 30 noisy frames), through scripts/bandai_pair.sh
# (30 minutes each, one thread each, both at once: the same wall time and machine).
# Usage: scripts/causality_probe.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
R="--input-scaling wiener --sigma-data 1 --velocity-loss 0.25 --balance sequences"
exec "$(dirname "$0")/bandai_pair.sh" "${1:?usage: scripts/causality_probe.sh OUT_DIR}" \
  x0-wiener1-vel025-bal-causal "$R" x0-wiener1-vel025-bal-lookahead "$R --causality lookahead"
