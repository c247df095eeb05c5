#!/bin/bash
# The library's own programs (kernels/{cuda,opencl}/library_*.{cu,cl}, entry kernels written once in
# kernels/shared/rt_entry_*.h) on the GPU machine, to compare with the figures of docs/results.md:
#   tests     the gpu-marked tests, then the registry's, the programs' and lab step 01's (the ray in shared
#             memory runs on CUDA only) on CUDA and NVIDIA OpenCL
#   primary   rtlab bench rays --kind primary, the GPU default (bvh, watertight, 8x16), every view of
#             ../shared/bench at 1024², CUDA and NVIDIA OpenCL, with the render kernel beside trace()
#   diffuse   the same with --kind diffuse (the peers' diffuse views)
#   whitted   SPONZA 1024², shadows + 3 bounces, paper materials, wavefront: README's command (bvh, Moller,
#             8x8) and the library default (bvh, watertight, 8x16), CUDA and NVIDIA OpenCL; fps
#   nvcc      registers, stack, spills and SASS counts of the library's kernels for the GPU variants
#             (experiments/nvcc_kernel_report.py; cuobjdump from the CUDA toolkit)
# Usage (device run, carry .device; stage: ../shared/device/stage.sh bunny.ply dragon.ply sponza kitchen conference):
#   source .device/setup.sh && bash experiments/gpu_library_programs.sh [PART ...]
# PARTs in order (default: all); a device call runs 10 minutes at most: give `tests` and `primary` a call each.
# Environment: BACKENDS (cuda,opencl), DEVICE (NVIDIA), VIEWS, DIFFUSE_VIEWS, SIZE (1024), REPEATS (22), FRAMES (50);
# a dry run on PoCL: DEVICE=cpu BACKENDS=opencl SIZE=64 REPEATS=2 FRAMES=2 VIEWS=bunny/fill DIFFUSE_VIEWS=bunny/fill
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 COLUMNS=250
BACKENDS=${BACKENDS:-cuda,opencl}
DEVICE=${DEVICE:-NVIDIA}
VIEWS=${VIEWS:-bunny/far,bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside}
DIFFUSE_VIEWS=${DIFFUSE_VIEWS:-bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside}
SIZE=${SIZE:-1024}
REPEATS=${REPEATS:-22}
FRAMES=${FRAMES:-50}
PARTS=${*:-tests primary diffuse whitted nvcc}
nvidia-smi --query-gpu=name,clocks.sm,clocks.max.sm --format=csv,noheader 2>/dev/null | head -1

for part in $PARTS; do
  echo "== $part"
  case $part in
  tests)
    RTLAB_TEST_BACKENDS=${TEST_BACKENDS:-cuda,opencl:NVIDIA} timeout 580 python -m pytest -q -rfEs -p no:cacheprovider \
      -m gpu tests/ > "$OUT/pytest_gpu.txt" 2>&1
    echo "pytest -m gpu exit $?" >> "$OUT/pytest_gpu.txt"
    tail -8 "$OUT/pytest_gpu.txt"
    RTLAB_TEST_BACKENDS=${TEST_BACKENDS:-cuda,opencl:NVIDIA} timeout 300 python -m pytest -q -rfEs -p no:cacheprovider \
      tests/test_variants.py tests/test_kernel_sources.py tests/test_memory.py > "$OUT/pytest_variants.txt" 2>&1
    echo "pytest variants exit $?" >> "$OUT/pytest_variants.txt"
    tail -5 "$OUT/pytest_variants.txt"
    ;;
  primary|diffuse)
    views=$VIEWS; [ $part = diffuse ] && views=$DIFFUSE_VIEWS
    rm -f "$OUT/rays_$part.md"
    timeout 590 python -m rtlab bench rays --kind $part --views "$views" --sizes "$SIZE" --traversals bvh \
      --isect watertight --block 8x16 --backends "$BACKENDS" --device "$DEVICE" --repeats "$REPEATS" \
      --md "$OUT/rays_$part.md" > "$OUT/rays_$part.log" 2>&1 || echo "bench rays $part: exit $?"
    grep -v "^\s*$" "$OUT/rays_$part.md" | tail -14
    grep -E "Traceback|Error:" "$OUT/rays_$part.log" | head -5
    ;;
  whitted)
    for be in ${BACKENDS//,/ }; do
      for v in "--traversal bvh --isect moller --block 8x8" "--traversal bvh --isect watertight --block 8x16"; do
        line=$(timeout 200 python -m rtlab render sponza --backend $be --device "$DEVICE" --size "$SIZE" --bounces 3 \
          --materials paper --shadows one-pass --schedule wavefront $v --repeats "$FRAMES" \
          --out "$OUT/sponza_$be.png" 2>&1 | tr '\n' ' ' | grep -o "[0-9.,]* ms a frame ([0-9.,]* fps)")
        echo "whitted sponza ${SIZE}² $be $v: ${line:-failed}"
      done
    done | tee "$OUT/whitted.txt"
    ;;
  nvcc)
    for v in bvh/watertight/8x16 bvh4/watertight/8x16 bvh8/watertight/8x16 stack/moller/32x4; do
      timeout 300 python experiments/nvcc_kernel_report.py kernels/cuda/library_trace.cu $v
    done | tee "$OUT/nvcc.txt"
    ;;
  *) echo "unknown part $part (tests primary diffuse whitted nvcc)" ;;
  esac
done
