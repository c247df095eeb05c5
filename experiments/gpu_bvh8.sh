#!/bin/bash
# The wide BVHs against the binary one on the GPU machine: "bvh" (the trace() default's traversal),
# "bvh8" (compressed 8-wide, rt_bvh8.h) and "bvh4" (4-wide float boxes, rt_bvh4.h), watertight test,
# on the same rays of every view in ../shared/bench, CUDA and NVIDIA OpenCL, with the error column;
# the GPU tests of the wide BVHs; Whitted SPONZA (1024², shadows + 3 bounces, wavefront) per traversal.
# Usage (device run, carry .device; stage: ../shared/device/stage.sh bunny.ply dragon.ply sponza kitchen conference):
#   source .device/setup.sh && bash experiments/gpu_bvh8.sh [PART ...]
# PARTs, in order (default: all). A device call runs 10 minutes at most: give each part its own call, build
# first; a warm machine keeps the accel cache and the compiled kernels (each scene's stack depth is a
# define, so every scene x traversal x backend compiles once, the first time it is timed):
#   build        build (or load) every scene's bvh, bvh8 and bvh4 and print their sizes, depths, costs
#   tests        pytest of the wide BVHs on cuda and NVIDIA OpenCL (the gpu-marked ones included)
#   primary      rtlab bench rays --kind primary at each of SIZES (one bench call a size), every view
#   primary1024, primary2048   the same at one size
#   diffuse      rtlab bench rays --kind diffuse, 1024², the peers' diffuse views
#   whitted      rtlab render sponza --bounces 3 --materials paper --schedule wavefront, per traversal and
#                backend, and PSNR against the float64 reference at 256²
# Prints one table: Mrays/s per traversal and its ratio to bvh, x best peer, and any mismatch against the
# float64 reference. Environment: TRAVERSALS (bvh,bvh8,bvh4), BACKENDS (cuda,opencl), VIEWS, DIFFUSE_VIEWS,
# SIZES (1024,2048), REPEATS (22), BLOCK (8x16), DEVICE (NVIDIA).
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 COLUMNS=250
TRAVERSALS=${TRAVERSALS:-bvh,bvh8,bvh4}
BACKENDS=${BACKENDS:-cuda,opencl}
VIEWS=${VIEWS:-bunny/far,bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside}
DIFFUSE_VIEWS=${DIFFUSE_VIEWS:-bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside}
SIZES=${SIZES:-1024,2048}
REPEATS=${REPEATS:-22}
BLOCK=${BLOCK:-8x16}
DEVICE=${DEVICE:-NVIDIA}             # NVIDIA: the GPU for both backends (a PoCL run for a dry test: DEVICE=cpu)
PARTS=${*:-build tests primary diffuse whitted}
nvidia-smi --query-gpu=name,clocks.sm,clocks.max.sm --format=csv,noheader 2>/dev/null | head -1

for part in $PARTS; do
  echo "== $part"
  case $part in
  build)
    timeout 580 python - "$VIEWS" <<'PY' 2>&1 | grep -v "Warning\|return Scene" | tee "$OUT/build.txt"
import sys, time
from rtlab.benches.rays import view_scene
from rtlab.accel.bvh_stats import traversal_bvh
from rtlab.accel.bvh8 import load_or_build_bvh8
from rtlab.accel.bvh4 import load_or_build_bvh4
for name in dict.fromkeys(v.split("/")[0] for v in sys.argv[1].split(",")):
    s = view_scene(name + ("/inside" if name in ("sponza", "kitchen", "conference") else "/fill"), 64)
    t = time.perf_counter(); b2 = traversal_bvh(s.vertices, s.faces); t2 = time.perf_counter() - t
    t = time.perf_counter(); b8, _ = load_or_build_bvh8(s.vertices, s.faces); t8 = time.perf_counter() - t
    t = time.perf_counter(); b4, _ = load_or_build_bvh4(s.vertices, s.faces); t4 = time.perf_counter() - t
    print(f"{name:11} {s.n_triangles:8,} tris | bvh {b2.n_nodes:8,} nodes, {len(b2.objects):8,} refs, depth {b2.depth:3} "
          f"({t2:5.1f} s) | bvh8 {b8.n_nodes:7,} nodes, {len(b8.tri_ids):8,} refs, depth {b8.depth:2}, {b8.binary:5}, "
          f"{b8.rows.nbytes / 2**20:5.1f} MiB ({t8:5.1f} s) | bvh4 {b4.n_nodes:7,} nodes, depth {b4.depth:2}, {b4.binary:5}, "
          f"{b4.rows.nbytes / 2**20:5.1f} MiB ({t4:5.1f} s)", flush=True)
PY
    ;;
  tests)
    RTLAB_TEST_BACKENDS=${TEST_BACKENDS:-cuda,opencl:NVIDIA} timeout 580 python -m pytest -q -rfEs -p no:cacheprovider \
      tests/test_wide_bvh.py "tests/test_traversal.py::test_gpu_ties_and_box_planes_agree_across_cuda_and_nvidia_opencl" \
      > "$OUT/pytest_wide.txt" 2>&1
    echo "pytest exit $?" >> "$OUT/pytest_wide.txt"
    grep -v "Warning\|return Scene\|^  " "$OUT/pytest_wide.txt" | tail -15
    ;;
  primary|primary[0-9]*|diffuse)
    kind=${part%%[0-9]*}; views=$VIEWS; sizes=${part#primary}; [ -z "$sizes" ] && sizes=$SIZES
    [ $kind = diffuse ] && views=$DIFFUSE_VIEWS && sizes=1024
    rm -f "$OUT/rays_$part.md"
    for size in ${sizes//,/ }; do
      timeout 590 python -m rtlab bench rays --kind $kind --views "$views" --sizes "$size" --traversals "$TRAVERSALS" \
        --isect watertight --backends "$BACKENDS" --device "$DEVICE" --block "$BLOCK" --repeats "$REPEATS" \
        --no-render --md "$OUT/rays_$part.md" >> "$OUT/rays_$part.log" 2>&1 || echo "bench rays $kind $size: exit $?"
    done
    python - "$OUT/rays_$part.md" <<'PY'
import sys, pathlib
rows, order = {}, []
for line in pathlib.Path(sys.argv[1]).read_text().splitlines():
    c = [x.strip() for x in line.strip().strip("|").split("|")]
    if len(c) < 12 or c[0] == "view" or c[0].startswith("-"):
        continue
    trav = c[4].split("/")[0]
    key = (c[0], c[1], c[2], c[3])
    if key not in rows:
        order.append(key)
    rows.setdefault(key, {})[trav] = (float(c[6].replace(",", "")), c[10], c[11])
travs = list(dict.fromkeys(t for r in rows.values() for t in r))
print(f"{'view':18} {'kind':8} {'size':6} {'backend':7} " + " ".join(f"{t:>22}" for t in travs) + "   (Mrays/s  x bvh  x best peer)")
for key in order:
    r = rows[key]
    base = r.get("bvh", (float("nan"),))[0]
    cells = [f"{r[t][0]:9,.0f} {r[t][0] / base:5.2f} {r[t][1]:>6}" if t in r else f"{'-':>22}" for t in travs]
    bad = [f"{t}: {r[t][2]}" for t in travs if t in r and not r[t][2].startswith("0 mism")]
    print(f"{key[0]:18} {key[1]:8} {key[2]:6} {key[3]:7} " + " ".join(cells) + ("   MISMATCH " + "; ".join(bad) if bad else ""))
PY
    grep -E "Traceback|Error:" "$OUT/rays_$part.log" | head -5
    ;;
  whitted)
    for be in ${BACKENDS//,/ }; do
      for t in ${TRAVERSALS//,/ }; do
        line=$(timeout 200 python -m rtlab render sponza --backend $be --device "$DEVICE" --size 1024 --bounces 3 \
          --materials paper --shadows one-pass --schedule wavefront --traversal $t --block 8x8 --repeats 50 \
          --out "$OUT/sponza_${be}_$t.png" 2>&1 | tr '\n' ' ' | grep -o "[0-9.,]* ms a frame ([0-9.,]* fps)")
        echo "whitted sponza 1024² $be $t: ${line:-failed}"
      done
    done | tee "$OUT/whitted.txt"
    # PSNR against the float64 reference at 256² (the Whitted frame's check), the wide traversals
    for t in ${TRAVERSALS//,/ }; do
      psnr=$(timeout 200 python -m rtlab render sponza --backend cuda --device "$DEVICE" --size 256 --bounces 3 \
        --materials paper --shadows one-pass --schedule wavefront --traversal $t --check --out "$OUT/sponza_check.png" 2>&1 \
        | tr '\n' ' ' | grep -o "PSNR [0-9.inf]* dB")
      echo "whitted sponza 256² cuda $t: ${psnr:-failed}"
    done | tee -a "$OUT/whitted.txt"
    ;;
  *) echo "unknown part $part (build tests primary primary1024 primary2048 diffuse whitted)" ;;
  esac
done
