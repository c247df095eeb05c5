#!/bin/bash
# The closest-hit numerics on the GPU machine, CUDA and NVIDIA OpenCL: what the watertight test's
# refined t costs through trace() on the benchmark rays (RT_REFINE_T 0 against 1, alternating on the
# same rays, error columns beside; with and without a cap of 64 registers on CUDA), the robustness
# suite's families 13-15 and the watertight rows of the others at bench size, and the tests of the
# refined t, the tie rule, the input checks and spawn_rays on both backends (gpu-marked ones included).
# Usage (device run, carry .device):  source .device/setup.sh && bash experiments/gpu_closest_hit.sh [step ...]
# Steps: tests, refine, robust (all three by default). Each step is capped by STEP_TIMEOUT seconds.
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
MD="$OUT/closest_hit.md"
LOG="$OUT/closest_hit.log"
log() { echo "\$ $*" | tee -a "$LOG"; timeout ${STEP_TIMEOUT:-560} "$@" >> "$LOG" 2>&1; echo "exit $?" | tee -a "$LOG"; }
[ $# -gt 0 ] || set -- tests refine robust
for step in "$@"; do
  case $step in
    tests)
      RTLAB_TEST_BACKENDS=cuda,opencl:NVIDIA log python -m pytest -q -rfEs tests/test_robustness.py tests/test_spawn.py \
        tests/test_trace_api.py -k "gpu or brute_force or refined_t or spawn or directions or interval or variant or 13- or 14- or 15-"
      RTLAB_TEST_BACKENDS=cuda,opencl:NVIDIA log python -m pytest -q -rfEs tests/test_traversal.py tests/test_intersect.py ;;
    refine)
      log python experiments/bench_t_refine.py --backend cuda --size 1024 --rounds 7 --repeats 9 --max-registers 0,64 --md "$MD"
      log python experiments/bench_t_refine.py --backend opencl --device NVIDIA --size 1024 --rounds 7 --repeats 9 \
        --no-slivers --md "$MD" ;;
    robust)
      log python -m rtlab bench robustness --backends cuda,opencl --device NVIDIA --size bench --isects watertight \
        --families 13,14,15 --md "$MD"
      log python -m rtlab bench robustness --backends cuda --size bench --isects watertight --families 1,2,3,4,5,6,7,8,9,10,12 \
        --md "$MD" ;;
  esac
done
tail -80 "$LOG"
