#!/usr/bin/env bash
# The GPU measurements of docs/gpu.md, as one script for the device machine (one H200, 16 CPU
# cores, CUDA 13.0, PyTorch, no Rust). Prepare here, then run there:
#
#   scripts/gpu_prepare.sh                      # here: .gpu/ = CUDA binary (gz) + data subset + twin
#   scripts/gpu_check.sh                        # there, in a copy of the checkout holding .gpu/
#
# Writes every output under $OUT (or ./gpu-out). Each section has its own time limit so one
# slow part cannot eat the others; the whole script stays under ~9 minutes.
set -uo pipefail
G=.gpu
O=${OUT:-gpu-out}; mkdir -p "$O"
exec > >(tee "$O/gpu_check.log") 2>&1
B=$G/socdiff
[ -x "$B" ] || { gunzip -kf "$G/socdiff.gz" && chmod +x "$B"; }
TWIN=$G/torch_unet.py
PY=${PY:-python3}
sec() { echo; echo "== $1 ($(date +%T))"; }
nvidia-smi -L; nproc; "$PY" -c 'import torch; print("torch", torch.__version__, torch.cuda.is_available())'
ldd "$B" | grep -E 'cuda|cublas|curand|not found'

sec "smoke: one tiny training step and one denoising step on the GPU"
timeout 120 "$B" bench train --device cuda --hidden 16 --batch 2 --persons 2 --frames 64 --steps 1 || echo "SMOKE FAILED"

sec "training step on the GPU: socdiff f32 / bf16, then the PyTorch twin fp32 / bf16"
for prec in f32 bf16; do
  timeout 90 "$B" bench train --device cuda --precision $prec --hidden 128 --batch 16 --persons 3 --frames 256 --steps 5
  timeout 120 "$B" bench train --device cuda --precision $prec --hidden 192 --batch 64 --persons 3 --frames 512 --steps 5
done
for prec in fp32 bf16; do
  timeout 60 "$PY" "$TWIN" --mode train --device cuda --precision $prec --hidden 128 --cin 61 --batch 16 --persons 3 --t 256 --iters 5 | grep RESULT
  timeout 90 "$PY" "$TWIN" --mode train --device cuda --precision $prec --hidden 192 --cin 61 --batch 64 --persons 3 --t 512 --iters 5 | grep RESULT
done

sec "denoising step on the GPU (1 scene × 1,928 frames) and a minute-long 3-person forecast at H = 192, DDIM 50"
timeout 150 "$B" bench sample --device cuda --hidden 128,256 --persons 3,7 --observe 128 --horizon 1800 --steps 5 --forecast-hidden 192 --no-ddpm
for h in 128 256; do for p in 3 7; do
  timeout 40 "$PY" "$TWIN" --mode sample --device cuda --hidden $h --cin 61 --batch 1 --persons $p --t 1928 --iters 5 | grep RESULT
done; done

sec "the 16-core CPU: training step at 2, 4, 8, 16 threads, socdiff then the twin (H = 128, 16 × 3 × 256)"
for t in 2 4 8 16; do
  timeout 60 "$B" bench train --hidden 128 --steps 3 --threads $t | awk '$1 == 128'
  OMP_NUM_THREADS=$t timeout 60 "$PY" "$TWIN" --mode train --hidden 128 --cin 61 --batch 16 --persons 3 --t 256 --iters 3 --threads $t | grep RESULT
done

sec "4 minutes of training at H = 192, 64 windows of 256 frames (1.5 min pre-training on MuPoTS + bandai2), scored on MuPoTS test"
timeout 330 "$B" bench quality --device cuda --minutes 4 --pretrain-minutes 1.5 --hidden 192 --batch 64 --window 256 \
  --data $G/data/mupots3d --pretrain-data $G/data/bandai2 --out "$O/quality"
echo "done $(date +%T)"
