#!/bin/bash
# Nsight Compute on CUDA's trace_rays for given view:kind cases: full set with source counters; the
# details page and the per-instruction source page (SASS) as text. Logs in $OUT/ncu.tgz.
# Usage (device run, carry .device): source .device/setup.sh && bash experiments/gpu_ncu_trace.sh sponza/inside:primary ...
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"; L=$(mktemp -d)
export PYTHONUNBUFFERED=1 RTLAB_NVCC_OPTIONS=-lineinfo
TRAV=${TRAV:-bvh}
for c in "$@"; do
  tag=$(echo "$c" | tr '/:' '__')_$TRAV
  timeout 250 ncu --kernel-name regex:trace_rays --launch-skip 1 --launch-count 1 --set full --import-source yes \
      -o "$L/$tag" python experiments/profile_trace.py --ncu --cases "$c" --traversals $TRAV --backends cuda > "$L/$tag.log" 2>&1
  ncu --import "$L/$tag.ncu-rep" --page details > "$L/$tag.details.txt" 2>&1
  ncu --import "$L/$tag.ncu-rep" --page source --csv --print-source sass > "$L/$tag.sass.csv" 2>&1
  rm -f "$L/$tag.ncu-rep"
  grep -E "Duration|Achieved Occupancy|Theoretical Occupancy|Avg. Active Threads|Warp Cycles Per Issued|Registers Per" "$L/$tag.details.txt" | sed "s/^/$tag /"
done
tar czf "$OUT/ncu.tgz" -C "$L" .
