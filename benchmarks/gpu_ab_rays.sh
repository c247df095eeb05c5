#!/bin/bash
# A/B of `rtlab bench rays` on the GPU machine in one run: the code under .ab/base (an export of the
# commit to compare against: git archive HEAD | tar x -C .ab/base) and the working tree, on the same
# rays and device, each test and kind in turn (base, then new), then one table of both.
# Usage (device run, carry .device and .ab):  source .device/setup.sh && bash benchmarks/gpu_ab_rays.sh
# Environment: NEW_DIR (the tree to compare, default .), ISECTS (moller,watertight), BACKENDS (cuda), VIEWS, SIZES (1024), DIFFUSE_VIEWS
set -u
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"; L=$(mktemp -d)
export PYTHONUNBUFFERED=1 COLUMNS=250
ISECTS=${ISECTS:-moller,watertight}; BACKENDS=${BACKENDS:-cuda}; SIZES=${SIZES:-1024}
VIEWS=${VIEWS:-bunny/far,dragon/fill,sponza/inside,conference/inside}
DIFFUSE_VIEWS=${DIFFUSE_VIEWS:-sponza/inside,conference/inside}
run() {  # label dir isect kind views sizes
  local label=$1 dir=$2 isect=$3 kind=$4 views=$5 sizes=$6
  (cd "$dir" && PYTHONPATH=$PWD:${PYTHONPATH#*:} timeout 300 python -m rtlab bench rays --backends "$BACKENDS" \
      --device NVIDIA --kind "$kind" --views "$views" --sizes "$sizes" --traversals bvh --isect "$isect" \
      --md "$L/$label.md" >> "$L/log.txt" 2>&1) || echo "$label $isect $kind: exit $?" >> "$L/log.txt"
}
for isect in ${ISECTS//,/ }; do
  for kind in primary diffuse; do
    views=$VIEWS; sizes=$SIZES; [ $kind = diffuse ] && views=$DIFFUSE_VIEWS && sizes=1024
    [ -d .ab/base ] && run base .ab/base $isect $kind "$views" "$sizes"
    run new "${NEW_DIR:-.}" $isect $kind "$views" "$sizes"
  done
done
cp "$L"/*.md "$L/log.txt" "$OUT/" 2>/dev/null
python - "$L" <<'PY'
import sys, pathlib
rows = {}
for label in ("base", "new"):
    p = pathlib.Path(sys.argv[1]) / f"{label}.md"
    if not p.exists():
        continue
    for line in p.read_text().splitlines():
        c = [x.strip() for x in line.strip().strip("|").split("|")]
        if len(c) < 12 or c[0] in ("view",) or c[0].startswith("-"):
            continue
        key = (c[0], c[1], c[2], c[3], c[4].split("/")[1])
        rows.setdefault(key, {})[label] = (c[6], c[7], c[10], c[11])
print(f"{'view':18} {'kind':8} {'size':6} {'be':6} {'isect':10} {'base':>8} {'new':>8} {'new/base':>8} {'render':>8} {'x peer':>6}  error (new)")
for k, v in rows.items():
    b, n = v.get("base"), v.get("new")
    f = lambda s: float(s.replace(",", "")) if s and s != "-" else float("nan")
    ratio = f(n[0]) / f(b[0]) if b and n else float("nan")
    print(f"{k[0]:18} {k[1]:8} {k[2]:6} {k[3]:6} {k[4]:10} {b[0] if b else '-':>8} {n[0] if n else '-':>8} {ratio:8.3f} "
          f"{n[1] if n else '-':>8} {n[2] if n else '-':>6}  {n[3] if n else ''}")
PY
grep -i "error\|traceback\|exit [1-9]" "$L/log.txt" | head -5
