#!/bin/bash
# NDMS of 60-s forecasts of the five MuPoTS test scenes from their first second, through
# `socdiff eval` (database: the test split's own words, its real-motion level against the train
# split is 0.276), with the means over frames 30–120 and 1,300–1,800.
# Usage: scripts/ndms_minute.sh MODEL_DIR OUT_DIR [SAMPLES=8] [DATA=../shared/data/mupots3d]
set -euo pipefail
model=$1; out=$2; k=${3:-8}; data=${4:-../shared/data/mupots3d}
bin=${SOCDIFF:-target/release/socdiff}
for ts in TS16 TS17 TS18 TS19 TS20; do
  "$bin" forecast --model "$model" --input "$data" --sequence $ts --observe 30 --horizon 1800 \
    --samples "$k" --steps 50 --seed 1 --out "$out/fc/$ts" | tail -1
done
"$bin" eval --reference "$data" --split test --observe 30 --forecasts ours="$out/fc" \
  --score-past-recording --metrics ndms,mpjpe,bone-length --out "$out/report" | tail -12
python3 - "$out/report/report.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
for m in r["methods"]:
    v = [x for x in m["ndms"]["per_frame"]["values"]]
    def mean(a, b):
        x = [t for t in v[a:b + 1] if t is not None]
        return sum(x) / len(x)
    a, b = mean(30, 120), mean(1300, 1800)
    print(f'{m["label"]}: NDMS {m["ndms"]["mean"]:.3f}; frames 30–120 {a:.3f}, 1300–1800 {b:.3f} (ratio {b / a:.2f})')
PY
