#!/bin/bash
# Numerics on the GPU machine, CUDA and NVIDIA OpenCL: the robustness suite with families
# 10-12 (box planes under the BVH's fused box test, spawn offsets far from the origin, direction
# lengths 1e-30..1e30) and the default triangle test (Moller against watertight on the benchmark
# views: rays through edges and vertices, trace and render time). Markdown into $OUT/numerics.md.
# Usage (device run, carry .device):  source .device/setup.sh && bash experiments/gpu_numerics.sh
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
MD="$OUT/numerics.md"
log() { echo "\$ $*" | tee -a "$OUT/numerics.log"; timeout ${STEP_TIMEOUT:-900} "$@" >> "$OUT/numerics.log" 2>&1; echo "exit $?" >> "$OUT/numerics.log"; }
log python -m rtlab bench robustness --backends cuda,opencl --device NVIDIA --size bench --families 10,11,12 --md "$MD"
log python experiments/bench_default_isect.py --backend cuda --size 1024 --leak-rays 100000 --repeat 9 --md "$MD"
log python experiments/bench_default_isect.py --backend opencl --device NVIDIA --size 1024 --leak-rays 100000 --repeat 9 --md "$MD"
# the wavefront Whitted kernel: the padded fused box test (more registers) against the exact one, and the watertight default
log python experiments/profile_whitted.py --scene sponza --size 1024 --bounces 3 --backend cuda --repeats 20 \
    --configs bvh:wavefront:block8x8:isect=moller:fma1,bvh:wavefront:block8x8:isect=moller:fma0,bvh:wavefront:block8x8
RTLAB_TEST_BACKENDS=cuda,opencl:NVIDIA log python -m pytest -q -rfEs tests/test_robustness.py tests/test_traversal.py -k "ties or fused_box or spawn or direction or gpu"
tail -60 "$OUT/numerics.log"
