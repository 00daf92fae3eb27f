#!/usr/bin/env bash
# The whole pipeline on the bundled CMU clip, no downloads: import → train a small model →
# forecast 4 futures → HTML viewer and PNG filmstrip. Usage: bash examples/demo.sh [OUT_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-/tmp/socdiff-demo}
rm -rf "$out" && mkdir -p "$out"
cargo build --release -p socdiff-cli
sd=target/release/socdiff
$sd data convert examples/data/cmu_18_01.bvh --bvh-scale cmu --out "$out/data"
$sd data inspect "$out/data"
$sd train --data "$out/data" --out "$out/model" --steps 300 --hidden 32 --batch 8 --window 64 --stride 2 --save-every 100 --val-every 0 --seed 1
$sd forecast --model "$out/model" --input "$out/data" --observe 64 --horizon 120 --samples 4 --sampler ddim --steps 20 --seed 1 --out "$out/forecast"
$sd view "$out/forecast" --out "$out/forecast.html"
$sd export "$out/forecast" --format png --sequence cmu_18_01 --out "$out/forecast.png"
echo "open $out/forecast.html in a browser; filmstrip: $out/forecast.png"
