#!/usr/bin/env bash
# The light buffer's list cap (lblistN: 126, the library's, against 96, 64, 32) on the Whitted frame (SPONZA 1024², 3 bounces, CUDA)
# (docs/results.md, "Shadow rays through a light buffer").
set -u
OUT=${OUT:-/tmp/lb}; mkdir -p $OUT
M=bvh:wavefront:block8x8:isect=moller
(cd experiments && python profile_whitted.py --scene sponza --size 1024 --bounces 3 --backend cuda --repeats 30 \
  --configs "$M,$M:lblist96,$M:lblist64,$M:lblist32,$M:RT_LIGHT_BUFFER=0,$M,$M:lblist96,$M:lblist64,$M:lblist32,$M:RT_LIGHT_BUFFER=0") > $OUT/lists.log 2>&1
grep -v "^    " $OUT/lists.log
