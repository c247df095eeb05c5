#!/bin/bash
# A/B on the GPU of the 4-wide walk's changes that no GPU has timed yet, configurations alternating
# round by round on the same rays (ab_trace_configs.py), each part's table under $OUT.
# Usage (device run, carry .device):  source .device/setup.sh && bash experiments/gpu_bvh4_open_ab.sh [PART ...]
#   untimed    the tree against the kernels the last bench timed: BASE_TREE (a folder holding kernels/,
#              made before the run with `git archive 95d4399 kernels | tar -x -C .device/base_tree`),
#              camera rays at 1024² and 2048², diffuse rays at 1024², CUDA and NVIDIA OpenCL
#   shear      experiments/prototypes/fetch_shear_per_ray.patch applied to a copy of the tree: the ray
#              fetch's watertight axes and shear as in the tree (RT_BVH4_AXES=0), once a ray (1), once a
#              leaf (2); diffuse rays at 1024², CUDA and NVIDIA OpenCL
#   tailorder  diffuse rays with the costliest warps first, ranked by the host mirror (sortwheavyP: the
#              bound) or by the grid estimate (sortwproxyP), the permutation not timed; CUDA
#   visitexit  the ray fetch's visit loop left once fewer than K lanes are still in it (RT_FETCH_VISIT_EXIT=K;
#              1: at its last lane, as before), diffuse rays at 1024², CUDA (five views) and NVIDIA OpenCL
#              (DRAGON and CONFERENCE)
#   leafexit   experiments/prototypes/fetch_leaf_exit.patch applied to a copy of the kernels: the ray fetch's
#              triangle loop left once fewer than L lanes still test (RT_FETCH_LEAF_EXIT=L), the rest of a
#              leaf in the next round; diffuse rays at 1024², CUDA (five views) and NVIDIA OpenCL (DRAGON,
#              CONFERENCE)
#   pushrefs   the ray fetch's stack holding the children's refs (RT_FETCH_PUSH_REFS=1, the default: a pop
#              reads no node) against node rows (0) and its own register cap of 64 (the default) against
#              the program's 72 (RT_FETCH_MAX_REGISTERS=0; CUDA only, NVIDIA's OpenCL caps programs) and
#              56; diffuse rays at 1024², CUDA and NVIDIA OpenCL (five views)
#   wide8      the same walk on 8 float children a node ("bvh8f") against 4 ("bvh4"): diffuse rays at
#              1024² (the ray fetch), CUDA and NVIDIA OpenCL; "bvh8f" is a traversal only with
#              experiments/prototypes/bvh8f_traversal.patch applied (`git apply` it before the run)
#   threshold  the ray fetch's refill threshold (RT_FETCH_THRESHOLD: the lanes still tracing stop after a
#              leaf when fewer are left) swept on the 4-wide walk: diffuse rays at 1024², CUDA (five
#              views) and NVIDIA OpenCL (DRAGON and CONFERENCE)
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT/experiments"
V5=bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside
R="--rounds 3 --repeats 5"
BASE_TREE=${BASE_TREE:-$ROOT/.device/base_tree}
[ $# -gt 0 ] || set -- untimed shear tailorder
for part in "$@"; do
  case $part in
    untimed)
      [ -d "$BASE_TREE/kernels" ] || { echo "no $BASE_TREE/kernels (see the usage above)"; continue; }
      for be in "--backend cuda" "--backend opencl --device NVIDIA"; do
        timeout 150 python ab_trace_configs.py $be $R --kinds primary,diffuse --size 1024 \
          --configs "bvh4,tree=$BASE_TREE;bvh4"
        timeout 90 python ab_trace_configs.py $be $R --kinds primary --size 2048 \
          --configs "bvh4,tree=$BASE_TREE;bvh4"
      done ;;
    shear)
      tree=$(mktemp -d)
      cp -r "$ROOT/kernels" "$tree/" && patch -s -p1 -d "$tree" < "$ROOT/experiments/prototypes/fetch_shear_per_ray.patch" \
        || { echo "the shear patch does not apply"; continue; }
      for be in "--backend cuda" "--backend opencl --device NVIDIA"; do
        timeout 150 python ab_trace_configs.py $be $R --kinds diffuse --size 1024 --views $V5 \
          --configs "bvh4;bvh4,tree=$tree,RT_BVH4_AXES=0;bvh4,tree=$tree,RT_BVH4_AXES=1;bvh4,tree=$tree,RT_BVH4_AXES=2"
      done ;;
    tailorder)
      timeout 300 python ab_trace_configs.py --backend cuda $R --kinds diffuse --size 1024 --views $V5 \
        --configs "bvh4;bvh4,sortwheavy10;bvh4,sortwheavy30;bvh4,sortwproxy10;bvh4,sortwproxy30" ;;
    threshold)
      T="bvh4;bvh4,RT_FETCH_THRESHOLD=12;bvh4,RT_FETCH_THRESHOLD=16;bvh4,RT_FETCH_THRESHOLD=24;bvh4,RT_FETCH_THRESHOLD=28"
      timeout 260 python ab_trace_configs.py --backend cuda $R --kinds diffuse --size 1024 --views $V5 --configs "$T"
      timeout 150 python ab_trace_configs.py --backend opencl --device NVIDIA $R --kinds diffuse --size 1024 \
        --views dragon/fill,conference/inside --configs "$T" ;;
    visitexit)
      E="bvh4,RT_FETCH_VISIT_EXIT=1;bvh4,RT_FETCH_VISIT_EXIT=4;bvh4,RT_FETCH_VISIT_EXIT=6;bvh4,RT_FETCH_VISIT_EXIT=8;bvh4,RT_FETCH_VISIT_EXIT=12"
      timeout 260 python ab_trace_configs.py --backend cuda $R --kinds diffuse --size 1024 --views $V5 --configs "$E"
      timeout 150 python ab_trace_configs.py --backend opencl --device NVIDIA $R --kinds diffuse --size 1024 \
        --views dragon/fill,conference/inside --configs "$E" ;;
    leafexit)
      tree=$(mktemp -d)
      cp -r "$ROOT/kernels" "$tree/" && (cd "$tree" && git apply --include='kernels/*' \
        "$ROOT/experiments/prototypes/fetch_leaf_exit.patch") || { echo "the leaf-exit patch does not apply"; continue; }
      L="bvh4;bvh4,tree=$tree,RT_FETCH_LEAF_EXIT=4;bvh4,tree=$tree,RT_FETCH_LEAF_EXIT=6;bvh4,tree=$tree,RT_FETCH_LEAF_EXIT=8"
      timeout 200 python ab_trace_configs.py --backend cuda $R --kinds diffuse --size 1024 --views $V5 --configs "$L"
      timeout 120 python ab_trace_configs.py --backend opencl --device NVIDIA $R --kinds diffuse --size 1024 \
        --views dragon/fill,conference/inside --configs "$L" ;;
    pushrefs)
      timeout 200 python ab_trace_configs.py --backend cuda $R --kinds diffuse --size 1024 --views $V5 --configs \
        "bvh4,RT_FETCH_PUSH_REFS=0,RT_FETCH_MAX_REGISTERS=0;bvh4,RT_FETCH_MAX_REGISTERS=0;bvh4;bvh4,RT_FETCH_MAX_REGISTERS=56"
      timeout 120 python ab_trace_configs.py --backend opencl --device NVIDIA $R --kinds diffuse --size 1024 \
        --views $V5 --configs "bvh4,RT_FETCH_PUSH_REFS=0;bvh4" ;;
    wide8)
      python -c "from rtlab.device.variants import TRAVERSALS; assert 'bvh8f' in TRAVERSALS" 2>/dev/null \
        || { echo "no bvh8f traversal: git apply experiments/prototypes/bvh8f_traversal.patch first"; continue; }
      for be in "--backend cuda" "--backend opencl --device NVIDIA"; do
        timeout 200 python ab_trace_configs.py $be $R --kinds diffuse --size 1024 --views $V5 --configs "bvh4;bvh8f"
      done ;;
  esac > "$OUT/ab_$part.txt" 2>&1
  echo "== $part (exit $?)"; grep "^|\|^device\|does not\|^no " "$OUT/ab_$part.txt"
done
