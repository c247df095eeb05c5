#!/bin/bash
# What becomes of a student's kernel that never ends on the GPU (rtlab.backends.waiting): does the
# process end with its line after $RTLAB_KERNEL_TIMEOUT, does it leave the process table, and does
# the GPU serve the next process? Every step is bounded (timeout -k), so a stuck driver costs minutes,
# not the run. Usage (device machine): bash experiments/gpu_student_hang.sh OUT_DIR [hang|crash] [backends]
set -u
out=${1:-/tmp/hang}; what=${2:-hang}; backends=${3:-"cuda opencl-nvidia"}
mkdir -p "$out"
tree=/tmp/student_tree_$what
python - "$tree" "$what" <<'PY'
import shutil, sys
from pathlib import Path
from rtlab.paths import REFERENCE_KERNEL_DIR
root, what = Path(sys.argv[1]), sys.argv[2]
shutil.rmtree(root, ignore_errors=True); shutil.copytree(REFERENCE_KERNEL_DIR, root)
sys.path.insert(0, ".")
from tests.test_student_kernels import CRASH, HANG
code = {"hang": HANG, "crash": CRASH}[what]
h = root / "shared" / "rt_kdtree.h"; t = h.read_text()
at = t.index("/* BEGIN SOLUTION */", t.index("traverse_kd_stack(")) + len("/* BEGIN SOLUTION */")
h.write_text(t[:at] + "\n    " + code + "\n" + t[at:])
PY
for b in $backends; do
  case $b in cuda) args="--backend cuda";; opencl-nvidia) args="--backend opencl --device NVIDIA";; esac
  log=$out/$what-$b.log
  echo "== $b: student tree ($what), RTLAB_KERNEL_TIMEOUT=4" > "$log"
  t0=$(date +%s.%N)
  RTLAB_KERNEL_DIR=$tree RTLAB_KERNEL_TIMEOUT=4 timeout -k 5 60 python -m rtlab render default --size 16 \
      --traversal stack --isect moller $args >> "$log" 2>&1 &
  pid=$!
  for i in $(seq 1 60); do kill -0 $pid 2>/dev/null || break; sleep 1; done
  if kill -0 $pid 2>/dev/null; then
    echo "still alive after 60 s: $(ps -o pid,stat,etime,cmd --ppid $pid | tail -n +2)" >> "$log"
  fi
  wait $pid; rc=$?
  echo "rc=$rc after $(python -c "import sys; print(round(float(sys.argv[2]) - float(sys.argv[1]), 1))" $t0 $(date +%s.%N)) s" >> "$log"
  nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader >> "$log" 2>&1
  nvidia-smi --query-compute-apps=pid,used_memory --format=csv,noheader >> "$log" 2>&1
  echo "== the next process, the reference kernels" >> "$log"
  t0=$(date +%s.%N)
  timeout -k 5 90 python -m rtlab render default --size 16 --traversal stack --isect moller $args >> "$log" 2>&1
  echo "rc=$? after $(python -c "import sys; print(round(float(sys.argv[2]) - float(sys.argv[1]), 1))" $t0 $(date +%s.%N)) s" >> "$log"
  cat "$log"
done
