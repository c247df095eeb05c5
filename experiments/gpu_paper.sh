#!/bin/bash
# The paper's evaluation on the lent H100 in ONE device call (10-minute limit): CUDA and NVIDIA's
# OpenCL at 1024x1024 - Tables 2-5, Figs. 4-5 and the memory placement study (rtlab bench paper,
# whose memory/fig4/fig5 sections are `rtlab bench memory` and `rtlab bench launch`).
#
# Here, once:   ../shared/device/stage.sh bunny.ply sponza kitchen dragon.ply
# Device run:   carry [".device"], timeout_s 600, command:
#               source .device/setup.sh && bash experiments/gpu_paper.sh
#
# Comes back in $OUT (the tool returns at most 8 files): paper_h100.tar.gz (every section's markdown,
# CSV, JSON and PNG plots for both backends), paper_cuda.md, paper_opencl.md, error_vs_time_cuda.png,
# commands.txt (the exact commands run) and log.txt. Unpack the archive into the checkout
# (tar xzf paper_h100.tar.gz) and commit docs/paper_h100/.
#
# Time: each backend gets a budget; `bench paper` starts no section past it, and `timeout` stops it
# outright near the limit; finished sections are written as they finish. A section that did not fit
# is listed as skipped in paper.md: run the same command again with docs/paper_h100/ in the tree
# (untracked files travel) and it continues where it stopped, keeping what is there.
set -u
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
RES=${RTLAB_PAPER_DIR:-docs/paper_h100}
SIZE=${RTLAB_PAPER_SIZE:-1024}
REPEATS=${RTLAB_PAPER_REPEATS:-10}
SCENES=${RTLAB_PAPER_SCENES:-bunny,sponza,kitchen,dragon}
LIMIT=${RTLAB_PAPER_LIMIT_S:-570}          # stop everything by this many seconds after the start
START=$(date +%s)
LOG="$OUT/log.txt"
CMDS="$OUT/commands.txt"
: >"$LOG"
: >"$CMDS"
export PYTHONUNBUFFERED=1 COLUMNS=200

elapsed() { echo $(( $(date +%s) - START )); }
left() { echo $(( LIMIT - $(elapsed) )); }
# run SECONDS CMD...: log the command, run it with a hard time limit, keep its output in the log
run() {
  local limit=$1; shift
  if [ "$limit" -le 5 ]; then echo "# skipped (no time left): $*" | tee -a "$CMDS" "$LOG"; return 0; fi
  echo "$*" >>"$CMDS"
  echo "=== [$(elapsed) s] $* (limit ${limit} s)" | tee -a "$LOG"
  timeout --signal=INT --kill-after=10 "$limit" "$@" 2>&1 | tee -a "$LOG"
  echo "=== [$(elapsed) s] exit ${PIPESTATUS[0]}" | tee -a "$LOG"
}

{ echo "# $(date -u +%FT%TZ) on $(hostname); git $(git rev-parse --short HEAD 2>/dev/null)$(git diff --quiet 2>/dev/null || echo '+local changes')"
  nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv,noheader 2>/dev/null | sed 's/^/# GPU: /'
  echo "# env: RES=$RES SIZE=$SIZE REPEATS=$REPEATS SCENES=$SCENES"; } >>"$CMDS"

run 30 python -m rtlab info
# kd-trees of every scene first (built once, cached), so the timed sections do not pay for them
run 120 python -c "
import sys, time
from rtlab.scene import load_scene
from rtlab.device.device_scene import scene_kdtree
for name in sys.argv[1].split(','):
    t = time.time(); scene_kdtree(load_scene(name)); print(name, 'kd-tree', round(time.time() - t, 1), 's')
" "$SCENES"
# The new memory paths on the GPU before timing them: texture objects (ctypes on libcuda), images,
# the shared-memory ray, every placement's hits equal to the global variant's (CUDA, NVIDIA OpenCL)
export RTLAB_TEST_BACKENDS=${RTLAB_TEST_BACKENDS:-cuda,opencl:NVIDIA}
run 90 python -m pytest -q -rfEs tests/test_memory.py -k "placements or round_trip or trace_rays_through or descriptors"

# Most wanted first: the sections never measured on a GPU, then the speed table, then the rest
FIRST_SECTIONS=memory,fig4,fig5,table4,table3,table5,table2
SECOND_SECTIONS=table4,memory,fig4,fig5,table3,table5,table2
# backend[:device] pairs; the first gets 55% of the time left, the second the rest
BACKENDS=${RTLAB_PAPER_BACKENDS:-cuda opencl:NVIDIA}
n=$(echo $BACKENDS | wc -w)
i=0
for pair in $BACKENDS; do
  be=${pair%%:*}; dev=${pair#*:}; [ "$dev" = "$pair" ] && dev=""
  sections=$FIRST_SECTIONS; [ $i -gt 0 ] && sections=$SECOND_SECTIONS
  if [ $i -eq 0 ] && [ "$n" -gt 1 ]; then
    budget=$(( ( $(left) - 20 ) * 55 / 100 )); limit=$(( budget + 90 ))
  else
    budget=$(( $(left) - 100 )); limit=$(( $(left) - 20 ))
  fi
  [ "$budget" -lt 0 ] && budget=0
  run "$limit" python -m rtlab bench paper --backend "$be" ${dev:+--device "$dev"} --out "$RES" --size "$SIZE" \
      --scenes "$SCENES" --repeats "$REPEATS" --sections "$sections" --budget-s "$budget"
  i=$(( i + 1 ))
done

# Pack: one archive plus the two summaries (the tool returns at most 8 files)
tar czf "$OUT/paper_h100.tar.gz" "$RES" 2>>"$LOG"
for be in cuda opencl; do
  d=$(ls -d "$RES"/"$be"-* 2>/dev/null | head -1)
  [ -n "$d" ] && cp "$d/paper.md" "$OUT/paper_$be.md" 2>/dev/null
  [ -n "$d" ] && [ "$be" = cuda ] && cp "$d/error_vs_time.png" "$OUT/error_vs_time_cuda.png" 2>/dev/null
done
echo "=== done in $(elapsed) s; results in $RES (archived as paper_h100.tar.gz)" | tee -a "$LOG"
