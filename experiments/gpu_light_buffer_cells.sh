#!/usr/bin/env bash
# Light buffers of 256², 512² (the library's for SPONZA) and 1024² cells a face in the Whitted frame (SPONZA 1024², 3 bounces, CUDA), against 256² and no shadow rays. Run on the GPU machine; logs under $OUT.
set -u
OUT=${OUT:-/tmp/lb}; mkdir -p $OUT
cd experiments
M=bvh:wavefront:block8x8:isect=moller
python profile_whitted.py --scene sponza --size 1024 --bounces 3 --backend cuda --repeats 30 --per-launch --configs "$M,$M:lb256,$M:lb1024,$M:noshadows,$M,$M:lb256,$M:lb1024" > $OUT/cells.log 2>&1
tail -n 80 $OUT/cells.log
