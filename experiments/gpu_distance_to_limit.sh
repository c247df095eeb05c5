#!/bin/bash
# How far the library's kernels are from what the H100 can do: Nsight Compute's speed-of-light,
# compute-workload and occupancy sections for trace() (primary rays in tiles, diffuse rays; the GPU
# default, CUDA) and the kernels of one Whitted frame (SPONZA, shadows + 3 bounces, wavefront), and
# the camera rays of trace() with and without their image's width (tiles unasked, rows, width=);
# with `stalls`, in place of those, the warp-state statistics (the cycles a warp spends between two
# issued instructions, by stall reason) and the L1 and L2 hit rates of the same kernels.
# Usage (device run, carry .device): source .device/setup.sh && bash experiments/gpu_distance_to_limit.sh [stalls]
set -u
PART=${1:-limit}
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
SECTIONS="--section SpeedOfLight --section ComputeWorkloadAnalysis --section Occupancy --section LaunchStats"
KEYS="Duration|Compute \(SM\) Throughput|Memory Throughput|DRAM Throughput|L1/TEX Cache Throughput|L2 Cache Throughput|Issue Slots Busy|Issued Ipc Active|Executed Ipc Active|Achieved Occupancy|Theoretical Occupancy|Registers Per Thread|Block Size"
cat > /tmp/one_trace.py <<'PY'
import sys
from rtlab.benches.rays import make_rays
from rtlab.device.tracing import trace
view, kind = sys.argv[1].split(":")
b = make_rays(view, kind, 1024, check_rays=1)
trace(b.scene, b.origins, b.directions, "cuda", width=1024 if kind == "primary" else None, repeats=2)
PY
CASES="sponza/inside:primary sponza/inside:diffuse conference/inside:primary conference/inside:diffuse"
TAG=ncu; WHITTED_SKIP=10; WHITTED_KERNELS=.
if [ "$PART" = stalls ]; then
  SECTIONS="--section WarpStateStats --section MemoryWorkloadAnalysis --section SpeedOfLight --page raw"
  KEYS="gpu__time_duration.sum|smsp__average_warp_latency_per_inst_issued.ratio|smsp__average_warps_issue_stalled_[a-z_]+_per_issue_active.ratio|l1tex__t_sector_hit_rate.pct|lts__t_sector_hit_rate.pct|smsp__thread_inst_executed_per_inst_executed.ratio"
  CASES="sponza/inside:primary conference/inside:primary conference/inside:diffuse dragon/fill:diffuse"
  TAG=stall; WHITTED_SKIP=8; WHITTED_KERNELS=trace   # the trace launches of the third frame
fi
for c in $CASES; do
  tag=$(echo "$c" | tr '/:' '__')
  timeout 240 ncu --kernel-name regex:trace_ray --launch-skip 1 --launch-count 1 $SECTIONS \
      python /tmp/one_trace.py "$c" > "$OUT/${TAG}_$tag.txt" 2>&1
  echo "== $c"; grep -E "^ *($KEYS) " "$OUT/${TAG}_$tag.txt" | sed 's/  */ /g'
done
timeout 240 ncu --kernel-name regex:$WHITTED_KERNELS --launch-skip $WHITTED_SKIP --launch-count 5 $SECTIONS \
  python -m rtlab render sponza --backend cuda --size 1024 --bounces 3 --materials paper --shadows one-pass \
  --schedule wavefront --traversal bvh --isect moller --block 8x8 --repeats 3 --out /tmp/w.png > "$OUT/${TAG}_whitted.txt" 2>&1
echo "== whitted sponza"; grep -E "^  [a-z_]+ \(|^ *($KEYS) " "$OUT/${TAG}_whitted.txt" | sed 's/  */ /g'
[ "$PART" = stalls ] && exit 0
cat > /tmp/tiles.py <<'PY'
import numpy as np, rtlab
from rtlab.benches.rays import view_scene
from rtlab.device.tracing import trace
for view in ("sponza/inside", "kitchen/inside", "conference/inside", "bunny/fill"):
    s = view_scene(view, 1024)
    o, d = rtlab.camera_rays(s.camera)
    po, pd = np.asarray(o), np.asarray(d)
    ms = {"camera_rays (unasked)": [], "plain rows": [], "width=": []}
    for _ in range(5):
        ms["camera_rays (unasked)"].append(trace(s, o, d, "cuda", repeats=10, warmup=2).kernel_ms)
        ms["plain rows"].append(trace(s, po, pd, "cuda", repeats=10, warmup=2).kernel_ms)
        ms["width="].append(trace(s, po, pd, "cuda", repeats=10, warmup=2, width=1024).kernel_ms)
    print(view, "  ".join(f"{k}: {1048576 / np.median(v) / 1e3:,.0f} Mrays/s" for k, v in ms.items()))
PY
echo "== camera rays, 1024², CUDA, default variant, median of 5 rounds of 10 launches"
timeout 200 python /tmp/tiles.py 2>&1 | grep -v Warning | tee "$OUT/tiles.txt"
