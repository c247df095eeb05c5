#!/bin/bash
# First check on the GPU machine: backends visible, one render per backend checked against the
# float64 reference, then the primary-ray tests on every backend there.
# Usage (device run, carry .device):  source .device/setup.sh && bash experiments/gpu_smoke.sh
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
python -m rtlab info 2>&1 | tee "$OUT/info.txt"
for be in cuda opencl; do
  python -m rtlab render bunny --backend $be --size 256 --check --out "$OUT/bunny_$be.png" 2>&1 | tee -a "$OUT/smoke.txt"
done
python -m pytest -q tests/test_primary.py tests/test_kernel_sources.py -x 2>&1 | tail -25 | tee "$OUT/pytest.txt"
