#!/usr/bin/env bash
# The Whitted frame (SPONZA 1024², 3 bounces, 512² light buffer cells) with the packing launch's block and register caps varied. Run on the GPU machine; logs under $OUT.
set -u
OUT=${OUT:-/tmp/lb}; mkdir -p $OUT
cd experiments
B=bvh:wavefront:block8x8:isect=moller
python profile_whitted.py --scene sponza --size 1024 --bounces 3 --backend cuda --repeats 30 --configs "$B,$B:pack64,$B:pack128,$B:pack512,$B:regs56,$B:regs48,$B,$B:pack64,$B:regs56" > $OUT/blocks_cuda.log 2>&1
python profile_whitted.py --scene sponza --size 1024 --bounces 3 --backend opencl --device NVIDIA --repeats 30 --configs "$B,$B:pack64,$B,$B:pack64" > $OUT/blocks_ocl.log 2>&1
grep -v "^    trace_wavefront\|^    pack\|light buffers" $OUT/blocks_cuda.log $OUT/blocks_ocl.log
