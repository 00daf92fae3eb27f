#!/bin/bash
# Issue 17, bandai2: the velocity term (λ = 0.25, the better weight of velocity_probe.sh) together
# with take balance (--balance sequences, which raised recall and the interpolated run's speed in
# balance_probe.sh), at the recipe's width 64 and at width 96, through scripts/bandai_pair.sh
# (30 minutes each, one thread each, both at once).
# Usage: scripts/velocity_balance_probe.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
exec "$(dirname "$0")/bandai_pair.sh" "${1:?usage: scripts/velocity_balance_probe.sh OUT_DIR}" \
  bandai-30-vel025-bal "--velocity-loss 0.25 --balance sequences" \
  bandai-30-vel025-bal-h96 "--velocity-loss 0.25 --balance sequences --hidden 96"
