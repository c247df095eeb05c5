#!/bin/bash
# A/B of trace_rays on the GPU machine in one run: the code under .ab/base (an export of the commit
# to compare against) and the working tree, same rays, same device, CUDA and NVIDIA OpenCL.
# Usage (device run, carry .device and .ab):  source .device/setup.sh && bash experiments/gpu_ab_trace.sh [BVH-PARAM-SETS...]
#   e.g. bash experiments/gpu_ab_trace.sh "" max_leaf_size=4 max_leaf_size=12
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"; L=$(mktemp -d)
export PYTHONUNBUFFERED=1
CASES=${CASES:-bunny/far:primary,bunny/fill:primary,sponza/inside:primary,conference/inside:primary,sponza/inside:diffuse,conference/inside:diffuse}
common="--sweep --cases $CASES --traversals bvh --backends cuda,opencl:NVIDIA --nvcc-options= --max-registers 0 --blocks 128"
[ -d .ab/base ] && (cd .ab/base && PYTHONPATH=$PWD:$PYTHONPATH python experiments/profile_trace.py $common --label base --out "$L" >> "$L/ab.txt" 2>&1)
sets=("$@"); [ ${#sets[@]} -eq 0 ] && sets=("")
for b in "${sets[@]}"; do
  python experiments/profile_trace.py $common --label new --bvh "$b" --out "$L" >> "$L/ab.txt" 2>&1
done
tar czf "$OUT/ab.tgz" -C "$L" .
grep -h '^{' "$L/ab.txt" | python -c '
import json, sys
for l in sys.stdin:
    r = json.loads(l)
    print("%-5s %-22s %-18s %-8s %-6s %6d Mrays/s regs %s mism %d" % (r["label"], r["bvh"] or "-", r["view"], r["kind"],
          r["backend"], r["mrays"], r.get("registers", "-"), r["mismatches"]))'
grep -h -i "error\|traceback" "$L/ab.txt" | head -5
