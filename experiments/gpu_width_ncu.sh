#!/bin/bash
# Why 8 float children a node lose to 4 on the ray fetch: Nsight Compute metrics of trace_rays_fetch
# (the second launch of trace()) on the benchmark's diffuse rays at 1024², "bvh4" against "bvh8f".
# "bvh8f" is a traversal only with experiments/prototypes/bvh8f_traversal.patch applied: this script
# applies it to a copy of the tree. Usage (device run, carry .device):
#   source .device/setup.sh && bash experiments/gpu_width_ncu.sh [VIEW ...]   (default dragon/fill conference/inside)
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
ROOT=$(cd "$(dirname "$0")/.." && pwd)
TREE=$(mktemp -d)
(cd "$ROOT" && tar --exclude=./.device --exclude=./.git --exclude=./.venv -cf - .) | tar -xf - -C "$TREE"
patch -s -p1 -d "$TREE" < "$ROOT/experiments/prototypes/bvh8f_traversal.patch" || { echo "the patch does not apply"; exit 1; }
cat > "$TREE/one_fetch.py" <<'PY'
import sys
from rtlab.benches.rays import make_rays
from rtlab.device.tracing import trace
b = make_rays(sys.argv[1], "diffuse", 1024, check_rays=1)
trace(b.scene, b.origins, b.directions, "cuda", variant=sys.argv[2], repeats=2)
PY
METRICS=gpu__time_duration.sum,smsp__inst_executed.sum,smsp__thread_inst_executed_per_inst_executed.ratio,\
sm__inst_issued.avg.pct_of_peak_sustained_active,sm__cycles_active.avg,gpc__cycles_elapsed.max,\
smsp__average_warps_issue_stalled_long_scoreboard_per_issue_active.ratio,\
smsp__average_warps_issue_stalled_math_pipe_throttle_per_issue_active.ratio,\
smsp__average_warps_issue_stalled_not_selected_per_issue_active.ratio,\
l1tex__t_sector_hit_rate.pct,lts__t_sector_hit_rate.pct,dram__throughput.avg.pct_of_peak_sustained_elapsed,\
l1tex__t_sectors_pipe_lsu_mem_global_op_ld.sum,smsp__warps_active.avg.pct_of_peak_sustained_active
[ $# -gt 0 ] || set -- dragon/fill conference/inside
for view in "$@"; do
  for trav in bvh4 bvh8f; do
    echo "== $view $trav"
    (cd "$TREE" && PYTHONPATH=$TREE:${PYTHONPATH:-} ncu --metrics $METRICS -k trace_rays_fetch --launch-skip 1 --launch-count 1 \
      python one_fetch.py "$view" "$trav" 2>&1) | tee "$OUT/ncu_${view//\//_}_$trav.txt" | grep -E "^\s+(gpu__|smsp__|sm__|l1tex__|lts__|dram__|gpc__)"
  done
done
