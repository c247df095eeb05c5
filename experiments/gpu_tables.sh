#!/bin/bash
# The paper's Tables 3, 4, 5 and the robustness table on the GPU machine, CUDA and NVIDIA OpenCL,
# 1024², error against the float64 reference beside every time. Markdown into $OUT/tables.md.
# Usage (device run, carry .device):  source .device/setup.sh && bash experiments/gpu_tables.sh
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
MD="$OUT/tables.md"
run() { echo "\$ rtlab $*" | tee -a "$OUT/tables.log"; timeout ${STEP_TIMEOUT:-300} python -m rtlab "$@" >> "$OUT/tables.log" 2>&1; echo "exit $?" >> "$OUT/tables.log"; }
run bench traversal --scenes bunny,sponza,kitchen,dragon --backends cuda,opencl --device NVIDIA --size 1024 --repeats 25 --md "$MD"
run bench shading --backends cuda,opencl --device NVIDIA --size 1024 --repeats 10 --md "$MD"
run bench intersect --scenes bunny,sponza --backends cuda,opencl --device NVIDIA --size 1024 --render-size 1024 --md "$MD"
run bench robustness --backends cuda,opencl --device NVIDIA --size bench --md "$MD"
tail -60 "$OUT/tables.log"
