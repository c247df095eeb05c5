#!/bin/bash
# The GPU machine's test run: every backend test on CUDA and NVIDIA OpenCL (PoCL is CI's job).
# Usage (device run, carry .device):  source .device/setup.sh && bash experiments/gpu_tests.sh
# (tests/test_robustness.py takes longer than one command may run: experiments/gpu_robustness.sh runs it in parallel)
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
export RTLAB_TEST_BACKENDS=${RTLAB_TEST_BACKENDS:-cuda,opencl:NVIDIA}
[ $# -gt 0 ] || set -- tests/test_primary.py tests/test_traversal.py tests/test_shading.py tests/test_intersect.py
timeout ${TEST_TIMEOUT:-540} python -m pytest -q -rfEs --durations=15 "$@" \
  > "$OUT/pytest_gpu.txt" 2>&1
echo "pytest exit $?" >> "$OUT/pytest_gpu.txt"
tail -40 "$OUT/pytest_gpu.txt"
