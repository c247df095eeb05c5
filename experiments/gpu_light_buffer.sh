#!/usr/bin/env bash
# Shadow rays through light buffers against the traversal: the Whitted frame (SPONZA 1024², 3 bounces) on CUDA and NVIDIA OpenCL, and the 256² check (docs/results.md, "Shadow rays through a light buffer"). Run on the GPU machine; logs under $OUT.
set -u
OUT=${OUT:-/tmp/lb}; mkdir -p $OUT
cd experiments
M=bvh:wavefront:block8x8:isect=moller
W=bvh:wavefront:block8x16:isect=watertight
python profile_whitted.py --scene sponza --size 1024 --bounces 3 --backend cuda --repeats 30 --per-launch --configs "$M,$M:RT_LIGHT_BUFFER=0,$M:lb128,$M,$M:RT_LIGHT_BUFFER=0,$M:lb128,$W,$W:RT_LIGHT_BUFFER=0" > $OUT/cuda.log 2>&1
python profile_whitted.py --scene sponza --size 1024 --bounces 3 --backend opencl --device NVIDIA --repeats 30 --configs "$M,$M:RT_LIGHT_BUFFER=0,$M:lb128,$M,$M:RT_LIGHT_BUFFER=0,$W,$W:RT_LIGHT_BUFFER=0" > $OUT/ocl.log 2>&1
cd ..
python -m rtlab render sponza --backend cuda --size 256 --bounces 3 --materials paper --shadows one-pass --traversal bvh --isect moller --schedule wavefront --block 8x8 --check > $OUT/check.log 2>&1
python -m rtlab render sponza --backend cuda --size 1024 --bounces 3 --materials paper --shadows one-pass --traversal bvh --isect moller --schedule wavefront --block 8x8 --repeats 50 >> $OUT/check.log 2>&1
tail -n 40 $OUT/*.log
