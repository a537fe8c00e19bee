#!/usr/bin/env bash
# The GPU checks of issue 32 on an NVIDIA machine with no network (see bench/bench_gpu_paths.py): the GPU tests
# (COLMAP PatchMatch keeps held-out photos out; gsplat against the CPU rasteriser), PatchMatch on a dense workspace
# prepared on the CPU, and the same Gaussians through gsplat and the CPU rasteriser.
#
#   bash bench/run_gpu_paths.sh CARRY OUT
#
# CARRY is prepared on a machine with pip (the GPU machine's python3 is 3.12 with torch, numpy, scipy, opencv, numba):
#   core.so.xz      pycolmap-cuda12's pycolmap/_core*.so, xz-compressed (the wheel is over the 64 MiB a call carries)
#   site.tar.xz     the rest of that wheel (pycolmap/, pycolmap_cuda12.libs/), cudart/libcudart.so.12 from
#                   nvidia-cuda-runtime-cu12, and gsplat 1.5.3's wheel contents without glm's doc/ and test/
#   debs/*.deb      libsm6 libice6 libx11-6 libxext6 libxcb1 libxau6 libxdmcp6 libbsd0 libmd0 (pycolmap links X11)
#   ws/demo/        images/ and sparse/ of `make demo`'s dense workspace (project/dense)
#   merged.spz      the demo's export/merged.ply as SPZ (`hybridsplat export ... --out merged.spz`)
set -uo pipefail
CARRY=${1:?CARRY folder}
OUT=${2:?OUT folder}
mkdir -p /tmp/site /tmp/xlibs "$OUT"
tar -C /tmp/site -xJf "$CARRY/site.tar.xz"
xz -dc "$CARRY/core.so.xz" >/tmp/site/pycolmap/_core.cpython-312-x86_64-linux-gnu.so
for f in "$CARRY"/debs/*.deb; do dpkg -x "$f" /tmp/xlibs; done
curand=$(find / -name 'libcurand.so.10*' -not -path '/proc/*' 2>/dev/null | head -1)
export LD_LIBRARY_PATH=/tmp/site/cudart:$(dirname "${curand:-/x/x}"):/tmp/xlibs/usr/lib/x86_64-linux-gnu:/tmp/xlibs/lib/x86_64-linux-gnu:${LD_LIBRARY_PATH:-}
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 TORCH_CUDA_ARCH_LIST=9.0 MAX_JOBS=14
nvidia-smi -L
nvcc --version | tail -2
python3 -c "import pycolmap, torch; print('pycolmap', pycolmap.__version__, 'has_cuda', pycolmap.has_cuda, 'torch', torch.__version__)"
# gsplat's CUDA extension is built by nvcc on first import (minutes): in the background while PatchMatch runs.
(time timeout 330 python3 -c "from gsplat.cuda._backend import _C; print('gsplat extension:', _C)") >"$OUT/gsplat_build.log" 2>&1
tail -4 "$OUT/gsplat_build.log"
# each GPU test in its own process: a crash (signal) of one is reported and the others still run
python3 -m pytest -q -m gpu --collect-only -p no:cacheprovider tests/test_mvs_held_out.py tests/test_render_backends.py |
    grep '::' >/tmp/gpu_tests.txt
while read -r t; do
    timeout 120 python3 -m pytest -q -p no:cacheprovider --tb=short -rA "$t" >/tmp/one.log 2>&1
    echo "exit $? $t" | tee -a "$OUT/gpu_tests.log"
    grep -v '^I20' /tmp/one.log | grep -E 'Error|error|assert|FAILED|PASSED|SKIPPED|^E ' | head -12 >>"$OUT/gpu_tests.log"
done </tmp/gpu_tests.txt
python3 bench/bench_gpu_paths.py device --gaussians "$CARRY/merged.spz" --cameras "$CARRY/ws/demo/sparse" --out "$OUT"
# PatchMatch after the build (nothing else on the CPUs), twice: the first run of a process pays CUDA's start-up
python3 bench/bench_gpu_paths.py device --repeat 2 --workspace "demo=$CARRY/ws/demo" --out "$OUT" 2>&1 |
    grep -v '^I20' | grep -v '^Writing'
# FOUNTAIN=0003.jpg,0007.jpg (its held-out photos): the fountain's dense workspace at 1000 px, if carried
if [ -n "${FOUNTAIN:-}" ]; then
    mkdir -p "$OUT/fountain"
    timeout 240 python3 bench/bench_gpu_paths.py device --workspace "fountain=$CARRY/ws/fountain:$FOUNTAIN" --no-maps \
        --out "$OUT/fountain" 2>&1 | grep -v '^I20' | grep -v '^Writing'
fi
