#!/usr/bin/env bash
# Fills .gpu/ (ignored by git, ≤ 64 MiB) with what scripts/gpu_check.sh needs on the device
# machine: the CUDA binary (scripts/build-cuda.sh), MuPoTS and a bandai2 subset (licensed data:
# never committed), and the PyTorch twin.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd); cd "$ROOT"
G=.gpu; rm -rf $G; mkdir -p $G/data
BIN=target/cuda/release/socdiff
[ -f $BIN.gz ] || { echo "error: $BIN.gz missing: run scripts/build-cuda.sh first" >&2; exit 1; }
cp $BIN.gz $G/socdiff.gz
cp -r ../shared/data/mupots3d $G/data/mupots3d
python3 scripts/subset_dataset.py ../shared/data/bandai2 $G/data/bandai2 --split train --min-frames 0 --max-mb ${BANDAI_MB:-30}
cp ../shared/bench/torch_unet.py $G/
du -sh $G; du -sb $G | awk '{ if ($1 > 64*1024*1024) { print "error: .gpu is over 64 MiB"; exit 1 } }'
