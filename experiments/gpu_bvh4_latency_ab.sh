#!/bin/bash
# A/B on the H100 of the 4-wide walk's launch and layout around its memory latency, CUDA,
# configurations alternating round by round on the same rays, each part's table under $OUT.
# Usage (device run, carry .device):  source .device/setup.sh && bash experiments/gpu_bvh4_latency_ab.sh [PART ...]
#   fetch    the ray fetch's refill threshold (RT_FETCH_THRESHOLD, 20 kept), diffuse 1024²
#   stride   nodes padded to 8 rows, one 128-B line each (ab_bvh_builds.py stride8; not kept), 1024²
#   big      camera rays at 2048² in 8x16 (kept) and 16x8 blocks
# The refs row loaded with the planes and the stack's top in registers (rt_bvh4.h) were measured with
# prototype switches against the code before them: docs/results.md says which columns.
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
cd "$(dirname "$0")"
V5=bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside
AB="--backend cuda --rounds 3 --repeats 5"
[ $# -gt 0 ] || set -- fetch stride big
for part in "$@"; do
  case $part in
    fetch) timeout 110 python ab_trace_configs.py $AB --kinds diffuse --size 1024 --views $V5 \
             --configs "bvh4;bvh4,RT_FETCH_THRESHOLD=16;bvh4,RT_FETCH_THRESHOLD=24" ;;
    stride) timeout 110 python ab_bvh_builds.py $AB --family bvh4 --kinds primary,diffuse --size 1024 \
             --configs "base;stride8" ;;
    big)   timeout 120 python ab_trace_configs.py $AB --kinds primary --size 2048 --configs "bvh4;bvh4,b16x8" ;;
  esac > "$OUT/ab_$part.txt" 2>&1
  echo "== $part (exit $?)"; grep "^|" "$OUT/ab_$part.txt"
done
