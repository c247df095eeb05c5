#!/bin/bash
# How far the library's kernels are from what the GPU (a Hopper chip: H100 or H200) can do, by Nsight Compute, for trace()
# (primary rays in tiles, diffuse rays; the GPU default, CUDA) and the kernels of one Whitted frame
# (SPONZA, shadows + 3 bounces, wavefront, bvh/Moller/8x8). Parts:
#   limit (default): speed-of-light, compute-workload and occupancy sections, then the camera rays of
#     trace() with and without their image's width (tiles unasked, rows, width=);
#   stalls: the warp-state statistics (the cycles a warp spends between two issued instructions, by
#     stall reason) and the L1 and L2 hit rates;
#   lanes: threads active per executed warp instruction (of 32), instructions, SM cycles, warps active:
#     whether divergence or instruction count bounds a kernel. CASES and DEFINES (-D NAME=V for the
#     trace cases), SIZE (the trace cases' image side, 1024 by default) and NO_WHITTED=1 narrow it;
#   frames: the limit sections for the frames' kernels: render_primary and render_shadows (the frames'
#     GPU default, SCENES, 1024²) and the Whitted frame's.
# Usage (device run, carry .device): source .device/setup.sh && bash experiments/gpu_distance_to_limit.sh [stalls|lanes|frames]
set -u
PART=${1:-limit}
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
cat > /tmp/one_trace.py <<'PY'
import os, sys
from rtlab.benches.rays import make_rays
from rtlab.device.tracing import trace
view, kind = sys.argv[1].split(":")
size = int(os.environ.get("SIZE", "1024"))
b = make_rays(view, kind, size, check_rays=1)
trace(b.scene, b.origins, b.directions, "cuda", width=size if kind == "primary" else None, repeats=2,
      defines={k: int(v) for k, v in (a.split("=") for a in sys.argv[2:])} or None)
PY
case "$PART" in
limit)
  SECTIONS="--section SpeedOfLight --section ComputeWorkloadAnalysis --section Occupancy --section LaunchStats"
  KEYS="Duration|Elapsed Cycles|SM Active Cycles|Compute \(SM\) Throughput|Memory Throughput|DRAM Throughput|L1/TEX Cache Throughput|L2 Cache Throughput|Issue Slots Busy|Issued Ipc Active|Executed Ipc Active|Achieved Occupancy|Theoretical Occupancy|Registers Per Thread|Block Size"
  DEFAULT_CASES="sponza/inside:primary sponza/inside:diffuse conference/inside:primary conference/inside:diffuse"
  WHITTED_SKIP=10; WHITTED_KERNELS=. ;;
frames)
  SECTIONS="--section SpeedOfLight --section ComputeWorkloadAnalysis --section Occupancy --section LaunchStats"
  KEYS="Duration|Elapsed Cycles|SM Active Cycles|DRAM Throughput|L1/TEX Cache Throughput|L2 Cache Throughput|Issued Ipc Active|Achieved Occupancy|Theoretical Occupancy|Registers Per Thread|Block Size"
  SCENES=${SCENES:-sponza conference kitchen}; [ "$SCENES" = none ] && SCENES=
  for scene in $SCENES; do
    for shading in "" "--shadows one-pass"; do
      tag="frames_${scene}${shading:+_shadows}"
      timeout 240 ncu --kernel-name regex:render_ --launch-skip 1 --launch-count 1 $SECTIONS \
          python -m rtlab render $scene --backend cuda --size 1024 $shading --repeats 3 --out /tmp/f.png > "$OUT/$tag.txt" 2>&1
      echo "== $scene ${shading:-primary}"; grep -E "^  [a-z_]+ \(|^ *($KEYS) " "$OUT/$tag.txt" | sed 's/  */ /g'
    done
  done
  CASES=none; WHITTED_SKIP=8; WHITTED_KERNELS=trace_wavefront ;;   # a frame's 4 trace launches (rt_spin between)
stalls)
  SECTIONS="--section WarpStateStats --section MemoryWorkloadAnalysis --section SpeedOfLight --page raw"
  KEYS="gpu__time_duration.sum|smsp__average_warp_latency_per_inst_issued.ratio|smsp__average_warps_issue_stalled_[a-z_]+_per_issue_active.ratio|l1tex__t_sector_hit_rate.pct|lts__t_sector_hit_rate.pct|smsp__thread_inst_executed_per_inst_executed.ratio"
  DEFAULT_CASES="sponza/inside:primary conference/inside:primary conference/inside:diffuse dragon/fill:diffuse"
  WHITTED_SKIP=8; WHITTED_KERNELS=trace ;;   # the trace launches of the third frame
lanes)
  SECTIONS="--metrics smsp__thread_inst_executed_per_inst_executed.ratio,smsp__inst_executed.sum,sm__cycles_active.avg,gpu__time_duration.sum,sm__warps_active.avg.pct_of_peak_sustained_active"
  KEYS="smsp__[a-z_.]+|sm__[a-z_.]+|gpu__[a-z_.]+"
  DEFAULT_CASES="sponza/inside:primary sponza/inside:diffuse conference/inside:diffuse dragon/fill:diffuse"
  WHITTED_SKIP=10; WHITTED_KERNELS=. ;;
*) echo "unknown part $PART: limit, stalls, lanes or frames" >&2; exit 2 ;;
esac
CASES=${CASES:-$DEFAULT_CASES}
[ "$CASES" = none ] && CASES=
for c in $CASES; do
  tag=$(echo "$c" | tr '/:' '__')
  timeout 240 ncu --kernel-name regex:trace_ray --launch-skip 1 --launch-count 1 $SECTIONS \
      python /tmp/one_trace.py "$c" ${DEFINES:-} > "$OUT/${PART}_$tag.txt" 2>&1
  echo "== $c ${DEFINES:-}"; grep -E "^ *($KEYS) " "$OUT/${PART}_$tag.txt" | sed 's/  */ /g'
done
[ -n "${NO_WHITTED:-}" ] && exit 0
timeout 240 ncu --kernel-name regex:$WHITTED_KERNELS --launch-skip $WHITTED_SKIP --launch-count 5 $SECTIONS \
  python -m rtlab render sponza --backend cuda --size 1024 --bounces 3 --materials paper --shadows one-pass \
  --schedule wavefront --traversal bvh --isect moller --block 8x8 --repeats 3 --out /tmp/w.png > "$OUT/${PART}_whitted.txt" 2>&1
echo "== whitted sponza"; grep -E "^  [a-z_]+ \(|^ *($KEYS) " "$OUT/${PART}_whitted.txt" | sed 's/  */ /g'
[ "$PART" = limit ] || exit 0
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
