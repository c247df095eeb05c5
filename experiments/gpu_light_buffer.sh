#!/usr/bin/env bash
# The Whitted frame with the library's light buffer defaults (512² cells a face, lists up to 126 refs, 96 MiB a light) and level 0's packing: the table on CUDA and NVIDIA OpenCL against the traversal, the 256² check, rtlab render, and the GPU tests of the frames. Run on the GPU machine; logs under $OUT.
set -u
OUT=${OUT:-/tmp/lb}; mkdir -p $OUT
cd experiments
M=bvh:wavefront:block8x8:isect=moller
W=bvh:wavefront:block8x16:isect=watertight
python profile_whitted.py --scene sponza --size 1024 --bounces 3 --backend cuda --repeats 30 --per-launch --configs "$M,$M:RT_LIGHT_BUFFER=0,$W,$W:RT_LIGHT_BUFFER=0,$M,$M:RT_LIGHT_BUFFER=0,$W,$W:RT_LIGHT_BUFFER=0" > $OUT/final_cuda.log 2>&1
python profile_whitted.py --scene sponza --size 1024 --bounces 3 --backend opencl --device NVIDIA --repeats 30 --configs "$M,$M:RT_LIGHT_BUFFER=0,$W,$W:RT_LIGHT_BUFFER=0,$M,$W" > $OUT/final_ocl.log 2>&1
cd ..
for B in "cuda" "opencl --device NVIDIA"; do
python -m rtlab render sponza --backend $B --size 256 --bounces 3 --materials paper --shadows one-pass --traversal bvh --isect moller --schedule wavefront --block 8x8 --check >> $OUT/final_check.log 2>&1
python -m rtlab render sponza --backend $B --size 1024 --bounces 3 --materials paper --shadows one-pass --traversal bvh --isect moller --schedule wavefront --block 8x8 --repeats 50 >> $OUT/final_check.log 2>&1
done
grep -v "^    trace_wavefront\|^    pack" $OUT/final_cuda.log $OUT/final_ocl.log; cat $OUT/final_check.log
TEST_TIMEOUT=560 bash experiments/gpu_tests.sh tests/test_light_buffer.py tests/test_shading.py > /dev/null; tail -4 $OUT/pytest_gpu.txt
