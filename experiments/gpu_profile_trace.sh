#!/bin/bash
# Where trace()'s time goes on the GPU machine: timed three ways on both backends (the same rays),
# Nsight Compute on each backend's trace_rays for one view, the OpenCL PTX for offline comparison,
# then the trace-API benchmark table.
# Usage (device run, carry .device; stage bunny.ply sponza):
#   source .device/setup.sh && bash experiments/gpu_profile_trace.sh
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
export COLUMNS=240
python experiments/profile_trace.py --cases bunny/far:primary,sponza/inside:primary,bunny/fill:diffuse \
    --traversals bvh,stack --backends cuda,opencl:NVIDIA --out "$OUT" > "$OUT/timing.txt" 2>&1
tail -3 "$OUT/timing.txt"
SECTIONS="--section SpeedOfLight --section LaunchStats --section Occupancy --section WarpStateStats --section InstructionStats --section MemoryWorkloadAnalysis --section SchedulerStats"
for be in cuda opencl:NVIDIA; do
  timeout 240 ncu --kernel-name regex:trace_rays --launch-skip 1 --launch-count 1 $SECTIONS \
      python experiments/profile_trace.py --ncu --cases bunny/far:primary --traversals bvh --backends $be \
      > "$OUT/ncu_${be%%:*}.txt" 2>&1
  echo "ncu $be: $?"; grep -E "Duration|Registers Per|Executed Ipc A|Achieved Occ|Local Memory|Executed Instructions  " "$OUT/ncu_${be%%:*}.txt" | head -12
done
