#!/bin/bash
# socdiff against its PyTorch twin (../shared/bench/torch_unet.py), in one session on one machine:
# training steps (16 × 3 × 256 frames) at H = 128 and 256, denoising steps (1 scene × 1,928
# frames) at H = 128 and 256 with 3 and 7 persons; prints each side's median seconds per step,
# peak memory and the ratios socdiff / PyTorch of time and of peak memory (< 1: socdiff is faster
# or smaller; socdiff prints GB = 10^9 bytes, the twin MB = 2^20 bytes, compared in bytes).
# Usage: scripts/bench_vs_torch.sh [THREADS]   (default: every CPU)
# Env: SOCDIFF (binary, default target/release/socdiff), VENV (default .venv-torch: created with
#      `pip install torch` when missing), TWIN (default ../shared/bench/torch_unet.py).
set -euo pipefail
threads=${1:-$(nproc)}
bin=${SOCDIFF:-target/release/socdiff}
venv=${VENV:-.venv-torch}
twin=${TWIN:-../shared/bench/torch_unet.py}
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import torch" 2>/dev/null; then
  python3 -m venv "$venv" && "$venv/bin/pip" install -q torch numpy
fi
py="$venv/bin/python"
export RAYON_NUM_THREADS=$threads OMP_NUM_THREADS=$threads
echo "threads $threads; $(nproc) CPUs; load $(cut -d' ' -f1 /proc/loadavg)"
ratio() { python3 -c "import sys; a,b=float(sys.argv[1]),float(sys.argv[2]); print(f'{a/b:.2f}')" "$1" "$2"; }
# peak memory ratio: socdiff's "X GB" (10^9 bytes) over the twin's MB (2^20 bytes)
mem_ratio() { python3 -c "import sys; a,b=float(sys.argv[1])*1e9,float(sys.argv[2])*2**20; print(f'{a/b:.2f}')" "$1" "$2"; }
field() { sed -n "s/.*$1=\([0-9.]*\).*/\1/p"; }
printf '%-34s %12s %12s %8s %12s %12s %8s\n' "bench" "socdiff s" "torch s" "ratio" "socdiff RSS" "torch RSS" "RSS ratio"
for h in 128 256; do
  out=$("$bin" bench train --hidden $h --batch 16 --persons 3 --frames 256 --steps 3 --threads "$threads")
  d=$(echo "$out" | sed -n 's/.*(δ = \([0-9]*\)).*/\1/p' | head -1)
  ours=$(echo "$out" | awk -v h=$h '$1 == h {print $4, $7, $8}')
  t=$("$py" "$twin" --mode train --hidden $h --cin "$d" --batch 16 --persons 3 --t 256 --iters 3 --threads "$threads" 2>/dev/null | grep '^RESULT')
  ts=$(echo "$t" | field step_median); tm=$(echo "$t" | field peak_rss)
  set -- $ours
  printf '%-34s %12s %12s %8s %12s %12s %8s\n' "train H=$h 16x3x256" "$1" "$ts" "$(ratio "$1" "$ts")" "$2 $3" "${tm} MB" "$(mem_ratio "${2%\*}" "$tm")"
done
for h in 128 256; do
  for p in 3 7; do
    out=$("$bin" bench sample --hidden $h --persons $p --observe 128 --horizon 1800 --steps 5 --no-forecast --threads "$threads")
    d=$(echo "$out" | sed -n 's/.*δ = \([0-9]*\),.*/\1/p' | head -1)
    ours=$(echo "$out" | awk -v h=$h -v p=$p '$1 == h && $2 == p {print $4, $7, $8}')
    t=$("$py" "$twin" --mode sample --hidden $h --cin "$d" --batch 1 --persons $p --t 1928 --iters 5 --threads "$threads" 2>/dev/null | grep '^RESULT')
    ts=$(echo "$t" | field step_median); tm=$(echo "$t" | field peak_rss)
    set -- $ours
    printf '%-34s %12s %12s %8s %12s %12s %8s\n' "sample H=$h P=$p 1928 frames" "$1" "$ts" "$(ratio "$1" "$ts")" "$2 $3" "${tm} MB" "$(mem_ratio "${2%\*}" "$tm")"
  done
done
