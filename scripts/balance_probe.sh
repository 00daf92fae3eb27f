#!/bin/bash
# Issue 17, bandai2: windows drawn per window (the paper) against per sequence (--balance
# sequences), through scripts/bandai_pair.sh (30 minutes each, one thread each, both at once).
# Usage: scripts/balance_probe.sh OUT_DIR   (SOCDIFF=path/to/socdiff, default target/release/socdiff)
exec "$(dirname "$0")/bandai_pair.sh" "${1:?usage: scripts/balance_probe.sh OUT_DIR}" bandai-30 "" bandai-30-bal "--balance sequences"
