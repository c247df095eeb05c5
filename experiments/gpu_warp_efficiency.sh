#!/bin/bash
# SIMD efficiency of the library's kernels on the H100 (Nsight Compute metrics): threads active per
# executed warp instruction (of 32), instructions executed, SM cycles active, achieved occupancy;
# trace() on primary and diffuse rays (GPU default, CUDA) and the kernels of one Whitted frame
# (SPONZA, shadows + 3 bounces, wavefront, bvh/Moller/8x8). Says whether divergence (what
# speculative traversal and ray reordering address) or instruction count bounds a kernel.
# Usage (device run, carry .device): source .device/setup.sh && bash experiments/gpu_warp_efficiency.sh
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
METRICS=smsp__thread_inst_executed_per_inst_executed.ratio,smsp__inst_executed.sum,sm__cycles_active.avg,gpu__time_duration.sum,sm__warps_active.avg.pct_of_peak_sustained_active
cat > /tmp/one_trace.py <<'PY'
import sys
from rtlab.benches.rays import make_rays
from rtlab.device.tracing import trace
view, kind = sys.argv[1].split(":")
b = make_rays(view, kind, 1024, check_rays=1)
trace(b.scene, b.origins, b.directions, "cuda", width=1024 if kind == "primary" else None, repeats=2,
      defines={k: int(v) for k, v in (a.split("=") for a in sys.argv[2:])} or None)
PY
for c in ${CASES:-sponza/inside:primary sponza/inside:diffuse conference/inside:diffuse dragon/fill:diffuse}; do
  tag=$(echo "$c" | tr '/:' '__')
  timeout 200 ncu --kernel-name regex:trace_ray --launch-skip 1 --launch-count 1 --metrics $METRICS \
      python /tmp/one_trace.py "$c" ${DEFINES:-} > "$OUT/warp_$tag.txt" 2>&1
  echo "== $c ${DEFINES:-}"; grep -E "^\s+(smsp|sm__|gpu__)" "$OUT/warp_$tag.txt" | sed 's/  */ /g'
done
if [ -z "${NO_WHITTED:-}" ]; then
timeout 200 ncu --kernel-name regex:. --launch-skip 10 --launch-count 5 --metrics $METRICS \
  python -m rtlab render sponza --backend cuda --size 1024 --bounces 3 --materials paper --shadows one-pass \
  --schedule wavefront --traversal bvh --isect moller --block 8x8 --repeats 3 --out /tmp/w.png > "$OUT/warp_whitted.txt" 2>&1
echo "== whitted sponza"; grep -E "^  [a-z_]+.*Context|^\s+(smsp|sm__|gpu__)" "$OUT/warp_whitted.txt" | sed 's/  */ /g'
fi
