#!/usr/bin/env bash
# The light buffer's list cap (lblistN) on the Whitted frame (SPONZA 1024², 3 bounces, CUDA), and the GPU tests of
# the frames that take it, on CUDA and NVIDIA OpenCL (docs/results.md, "Shadow rays through a light buffer").
set -u
OUT=${OUT:-/tmp/lb}; mkdir -p $OUT
M=bvh:wavefront:block8x8:isect=moller
(cd experiments && python profile_whitted.py --scene sponza --size 1024 --bounces 3 --backend cuda --repeats 30 \
  --configs "$M,$M:lblist32,$M:lblist128,$M:lblist256,$M:RT_LIGHT_BUFFER=0,$M,$M:lblist32,$M:lblist128,$M:lblist256,$M:RT_LIGHT_BUFFER=0") > $OUT/lists.log 2>&1
TEST_TIMEOUT=400 bash experiments/gpu_tests.sh tests/test_light_buffer.py tests/test_shading.py > $OUT/tests.log 2>&1
grep -v "^    " $OUT/lists.log; tail -n 8 $OUT/pytest_gpu.txt
