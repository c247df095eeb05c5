#!/bin/bash
# A/B of `rtlab bench rays` on the GPU machine in one run: the code under .ab/base (an export of the
# commit to compare against: git archive HEAD | tar x -C .ab/base) and the working tree (or other
# trees, TREES), on the same rays and device, each test and kind in turn, then one table of all,
# each against the first.
# Usage (device run, carry .device and .ab):  source .device/setup.sh && bash experiments/gpu_ab_rays.sh
# Environment: TREES (label:dir ..., default "base:.ab/base new:."), ISECTS (moller,watertight), BACKENDS (cuda), VIEWS, SIZES (1024), DIFFUSE_VIEWS
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
    for t in ${TREES:-base:.ab/base new:.}; do
      [ -d "${t#*:}" ] && run "${t%%:*}" "${t#*:}" $isect $kind "$views" "$sizes"
    done
  done
done
cp "$L"/*.md "$L/log.txt" "$OUT/" 2>/dev/null
python - "$L" ${TREES:-base:.ab/base new:.} <<'PY'
import sys, pathlib
rows = {}
labels = [t.split(":")[0] for t in sys.argv[2:]]
labels = [l for l in labels if (pathlib.Path(sys.argv[1]) / f"{l}.md").exists()]
for label in labels:
    p = pathlib.Path(sys.argv[1]) / f"{label}.md"
    for line in p.read_text().splitlines():
        c = [x.strip() for x in line.strip().strip("|").split("|")]
        if len(c) < 12 or c[0] in ("view",) or c[0].startswith("-"):
            continue
        key = (c[0], c[1], c[2], c[3], c[4].split("/")[1])
        rows.setdefault(key, {})[label] = (c[6], c[7], c[10], c[11])
f = lambda s: float(s.replace(",", "")) if s and s != "-" else float("nan")
print(f"{'view':18} {'kind':8} {'size':6} {'be':6} {'isect':10} " + " ".join(f"{l:>16}" for l in labels) + "  (Mrays/s, ratio to the first; x best peer)")
for k, v in rows.items():
    first = v.get(labels[0])
    cells = []
    for l in labels:
        r = v.get(l)
        cells.append(f"{r[0]:>7} {f(r[0]) / f(first[0]) if first else float('nan'):.3f} {r[2]:>4}" if r else f"{'-':>16}")
    worst = [r[3] for r in v.values() if "0 mism" not in r[3]]
    print(f"{k[0]:18} {k[1]:8} {k[2]:6} {k[3]:6} {k[4]:10} " + " ".join(cells) + ("  MISMATCH: " + worst[0] if worst else ""))
PY
grep -i "error\|traceback\|exit [1-9]" "$L/log.txt" | head -5
