#!/bin/bash
# trace() on the GPU machine, timed three ways per backend (launch / plain / amortised),
# then a sweep of CUDA's trace_rays over nvcc precision options, register caps and block sizes beside
# NVIDIA OpenCL, with mismatches against the float64 reference. Logs in $OUT/sweep.tgz.
# Usage (device run, carry .device; stage bunny.ply sponza conference):
#   source .device/setup.sh && bash experiments/gpu_sweep_trace.sh
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"; L=$(mktemp -d)
export PYTHONUNBUFFERED=1
python experiments/profile_trace.py --cases bunny/far:primary,sponza/inside:primary,bunny/fill:diffuse \
    --traversals bvh,stack --backends cuda,opencl:NVIDIA --out "$L" > "$L/timing.txt" 2>&1
python experiments/profile_trace.py --sweep --out "$L" \
    --cases bunny/far:primary,sponza/inside:primary,bunny/fill:diffuse,conference/inside:diffuse \
    --traversals bvh,stack --backends cuda,opencl:NVIDIA --nvcc-options ";--prec-div=false --prec-sqrt=false" \
    --max-registers 0,40 --blocks 64,128,256 > "$L/sweep.txt" 2>&1
tar czf "$OUT/sweep.tgz" -C "$L" .
grep -h '^{' "$L/timing.txt" | python -c '
import json, sys
for l in sys.stdin:
    r = json.loads(l); print(r["view"], r["kind"], r["backend"], r["traversal"], "launch %.0f" % r["launch_mrays"],
        "plain %.0f" % r.get("plain_mrays", 0), "amortised %.0f" % r["amortised_mrays"])'
tail -2 "$L/sweep.txt"
