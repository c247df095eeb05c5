#!/bin/bash
# Whitted frames on the GPU machine: SPONZA (shadows + 3 bounces at 1024²) for every schedule,
# a per-level profile, and Table 5 (`rtlab bench shading`) for CUDA and NVIDIA OpenCL.
# Usage (device run, carry .device; stage sponza kitchen bunny.ply):
#   source .device/setup.sh && bash experiments/gpu_whitted.sh
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
for be in cuda opencl; do
  for sched in "--schedule wavefront" "--schedule tree --compact" "--schedule tree"; do
    echo "== $be $sched" >> "$OUT/target.txt"
    python -m rtlab render sponza --backend $be --device NVIDIA --size 1024 --bounces 3 --materials paper \
      --shadows one-pass --traversal bvh $sched --repeats 50 --out "$OUT/sponza_${be}.png" >> "$OUT/target.txt" 2>&1
  done
done
cat "$OUT/target.txt"
python experiments/profile_whitted.py --repeats 50 --per-launch --configs bvh:wavefront,stack:wavefront > "$OUT/profile.txt" 2>&1
cat "$OUT/profile.txt"
python -m rtlab bench shading --backends cuda,opencl --device NVIDIA --size 1024 --repeats 20 \
  --md "$OUT/table5.md" > "$OUT/table5.txt" 2>&1
tail -30 "$OUT/table5.md"
