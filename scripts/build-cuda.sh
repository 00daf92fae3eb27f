#!/usr/bin/env bash
# Builds the CUDA binary of socdiff on a machine without a GPU (docs/gpu.md), from PyPI's CUDA
# 13.0 wheels (the GPU machine's driver is CUDA 13.0: newer PTX would not load there).
#
#   scripts/build-cuda.sh            # → target/cuda/release/socdiff (+ .gz beside it)
#   R=/scratch/cuda scripts/build-cuda.sh
#
# R (default ~/cuda-build) holds the wheels' venv, a CUDA tree laid out as the build scripts
# expect, and a libcuda stub to link against (the real libcuda.so.1 comes with the driver).
# Run here the binary stops in the loader (libcuda.so.1 missing, exit 127): that is expected.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
R=${R:-$HOME/cuda-build}
COMPUTE_CAP=${CUDA_COMPUTE_CAP:-90}   # H200 / H100: sm_90
mkdir -p "$R"

if [ ! -x "$R/venv/bin/pip" ]; then
    python3 -m venv "$R/venv"
fi
# Every wheel pinned: nvcc alone would pull the newest nvvm and crt.
"$R/venv/bin/pip" install -q nvidia-cuda-nvcc==13.0.88 nvidia-nvvm==13.0.88 nvidia-cuda-crt==13.0.88 \
    nvidia-cuda-runtime==13.0.96 nvidia-cuda-cccl==13.0.85 nvidia-cublas==13.0.2.14 \
    nvidia-curand==10.4.0.35 nvidia-cuda-nvrtc==13.0.88
W=$("$R/venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/nvidia/cu13

# The CUDA 13 wheels share one tree; nvcc wants ../nvvm and ../include beside bin/, candle's
# kernel build wants lib64/, cudarc also looks in lib64/stubs.
C=$R/cuda
rm -rf "$C"; mkdir -p "$C/lib64/stubs"
ln -s "$W/bin" "$C/bin"; ln -s "$W/include" "$C/include"; ln -s "$W/nvvm" "$C/nvvm"
for f in "$W"/lib/*; do ln -s "$f" "$C/lib64/"; done
(cd "$C/lib64" && for f in libcublas libcublasLt libcudart libnvrtc; do ln -sf $f.so.13 $f.so; done && ln -sf libcurand.so.10 libcurand.so)

# libcuda stub: every driver function cudarc declares, each returning an error.
(cd "$ROOT" && cargo fetch -q)
CUDARC=$(ls -d "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/cudarc-0.* | sort -V | tail -1)
grep -ohE 'fn cu[A-Za-z0-9_]+\(' "$CUDARC/src/driver/sys/mod.rs" | sed 's/fn //; s/(//' | sort -u \
    | awk '{print "int " $1 "(void){return 999;}"}' > "$R/cuda_stub.c"
gcc -shared -fPIC -Wl,-soname,libcuda.so.1 -o "$C/lib64/stubs/libcuda.so" "$R/cuda_stub.c"

export CUDA_HOME=$C CUDA_PATH=$C CUDA_ROOT=$C PATH=$C/bin:$PATH
export CUDA_COMPUTE_CAP=$COMPUTE_CAP CUDARC_CUDA_VERSION=13000
export CARGO_BUILD_JOBS=${CARGO_BUILD_JOBS:-$(nproc)} CUDAFORGE_THREADS=${CUDAFORGE_THREADS:-$(nproc)}
export LIBRARY_PATH=$C/lib64/stubs:$C/lib64${LIBRARY_PATH:+:$LIBRARY_PATH}
cd "$ROOT"
CARGO_TARGET_DIR=$ROOT/target/cuda cargo build --release -p socdiff-cli --features cuda
BIN=$ROOT/target/cuda/release/socdiff
strip "$BIN"
gzip -kf9 "$BIN"
ls -l "$BIN" "$BIN.gz"
echo "needs at run time: libcuda.so.1 (driver), libcudart.so.13, libcublas(Lt).so.13, libcurand.so.10 (the toolkit's, or lib/ beside the binary)"
readelf -d "$BIN" | grep -E 'NEEDED|RUNPATH|RPATH' || true
