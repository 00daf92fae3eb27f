#!/bin/bash
# Issue 17, bandai2: the loss's velocity term (train --velocity-loss) at weights 1 and 0.25,
# through scripts/bandai_pair.sh (30 minutes each, one thread each, both at once).
# Usage: scripts/velocity_probe.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
exec "$(dirname "$0")/bandai_pair.sh" "${1:?usage: scripts/velocity_probe.sh OUT_DIR}" bandai-30-vel1 "--velocity-loss 1" bandai-30-vel025 "--velocity-loss 0.25"
