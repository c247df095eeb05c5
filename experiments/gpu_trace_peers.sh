#!/bin/bash
# trace() against the peers, with its numerics and the Whitted frame, on the GPU machine in one call
# (CUDA and NVIDIA OpenCL):
#  1. the robustness suite's families 10-12 (box planes, spawn offsets, direction lengths), markdown
#  2. the default triangle test on the bench views, CUDA: rays through edges and vertices, and time
#  3. rays through trace() on the peers' views: primary 1024² and 2048², diffuse 1024², the BVH with
#     the library's watertight default and with Moller (the peers' kind of test), error beside time
#  4. the Whitted frame (SPONZA, 3 bounces, wavefront, 8x8) with every launch timed alone
# Figures: docs/results.md (GPU: trace() against the peers; GPU: Whitted frames; Numerics).
# Usage (device run, carry .device; stage bunny.ply sponza kitchen conference dragon.ply):
#   source .device/setup.sh && bash experiments/gpu_trace_peers.sh      -> $OUT/trace_peers.tgz
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"; L=$(mktemp -d)
export PYTHONUNBUFFERED=1 COLUMNS=250
step() { local t=$1; shift; echo "\$ $*" >> "$L/log.txt"; timeout "$t" "$@" >> "$L/log.txt" 2>&1; echo "exit $?" >> "$L/log.txt"; }
step 150 python -m rtlab bench robustness --backends cuda,opencl --device NVIDIA --size bench --families 10,11,12 --md "$L/robustness.md"
step 120 python experiments/bench_default_isect.py --backend cuda --size 1024 --leak-rays 50000 --repeat 5 --md "$L/default_isect.md"
for isect in watertight moller; do
  step 200 python -m rtlab bench rays --backends cuda,opencl --device NVIDIA --kind primary --sizes 1024,2048 \
      --traversals bvh --isect $isect --block 8x16 --md "$L/rays.md"
  step 90 python -m rtlab bench rays --backends cuda,opencl --device NVIDIA --kind diffuse --sizes 1024 \
      --views bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside --traversals bvh --isect $isect \
      --md "$L/rays.md"
done
for be in cuda opencl; do
  step 60 python -m rtlab render sponza --backend $be --device NVIDIA --size 1024 --bounces 3 --materials paper \
      --shadows one-pass --traversal bvh --isect moller --schedule wavefront --block 8x8 --repeats 50 --out "$L/sponza_$be.png"
done
tar czf "$OUT/trace_peers.tgz" -C "$L" .
grep -E "^\\$|^exit|fps|Mrays" "$L/log.txt" | grep -v "^│" | tail -40
