#!/bin/bash
# tests/test_robustness.py on the GPU machine, one pytest process a family and backend, JOBS at a time
# (each case compiles its own kernels, so one process in a row takes longer than a device session).
# Usage (device run, carry .device):  source .device/setup.sh && bash experiments/gpu_robustness.sh
#   BACKENDS (default "cuda opencl:NVIDIA"), JOBS (8), FAMILIES (default: every family), logs under $OUT.
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT/robustness"
JOBS=${JOBS:-8}
BACKENDS=${BACKENDS:-cuda opencl:NVIDIA}
FAMILIES=${FAMILIES:-$(python -c "from rtlab.robustness import FAMILY_NAMES as F; print(' '.join(f'{k}-{v}' for k, v in sorted(F.items())))")}
for be in $BACKENDS; do for fam in $FAMILIES; do echo "$be $fam"; done; done |
  xargs -P "$JOBS" -L 1 bash -c 'RTLAB_TEST_BACKENDS=$0 python -m pytest -q -p no:cacheprovider tests/test_robustness.py \
    -k "$1-" > "'"$OUT"'/robustness/${0//:/_}_$1.txt" 2>&1; echo "$0 $1: $(tail -1 "'"$OUT"'/robustness/${0//:/_}_$1.txt")"'
for be in $BACKENDS; do
  RTLAB_TEST_BACKENDS=$be python -m pytest -q -p no:cacheprovider tests/test_robustness.py -k "refined_t" \
    > "$OUT/robustness/${be//:/_}_refined.txt" 2>&1
  echo "$be refined_t: $(tail -1 "$OUT/robustness/${be//:/_}_refined.txt")"
done
