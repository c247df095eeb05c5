#!/usr/bin/env bash
# A non-editable install works from any directory: build rtlab's wheel from a copy of this tree,
# install it into a fresh venv, then from another directory (cold numba and rtlab caches) run
#   rtlab render --size 32        and        rtlab lab template 00_primary --out <dir>
# and fail on a non-zero exit, a missing output or a traceback. Used by CI (.ci/run).
# PY picks the Python (default python3); needs PoCL (scripts/install_system_deps.sh) and pip's index.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
PY="${PY:-python3}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

# A copy without build leftovers: a stale build/ would put deleted files into the wheel
mkdir -p "$work/src" "$work/dist" "$work/elsewhere"
tar -C "$repo" --exclude=./.git --exclude=./.venv --exclude=./build --exclude=./dist \
    --exclude='*.egg-info' --exclude=__pycache__ -cf - . | tar -C "$work/src" -xf -
"$PY" -m venv "$work/venv"
"$work/venv/bin/pip" install -q --upgrade pip
"$work/venv/bin/pip" wheel -q --no-deps -w "$work/dist" "$work/src"
"$work/venv/bin/pip" install -q "$work"/dist/rtlab-*.whl
echo "check_wheel: installed $(basename "$work"/dist/rtlab-*.whl) into a fresh venv"

cd "$work/elsewhere"
export RTLAB_CACHE="$work/cache" NUMBA_CACHE_DIR="$work/numba" POCL_CACHE_DIR="$work/pocl"
unset PYTHONPATH RTLAB_KERNEL_DIR
run() {
    echo "check_wheel: $*"
    local status=0
    "$@" > "$work/log" 2>&1 || status=$?
    cat "$work/log"
    if [ "$status" -ne 0 ] || grep -q Traceback "$work/log"; then
        echo "check_wheel: FAILED ($*: exit status $status)" >&2
        exit 1
    fi
}
run "$work/venv/bin/python" -c "import rtlab.paths as p; assert not p.IN_CHECKOUT, p.DATA_ROOT; print('kernels and labs from', p.DATA_ROOT)"
run "$work/venv/bin/rtlab" render --size 32 --out "$work/elsewhere/render.png"
run "$work/venv/bin/rtlab" lab template 00_primary --out "$work/elsewhere/template"
test -s "$work/elsewhere/render.png"
test -s "$work/elsewhere/template/kernels/shared/rt_types.h"
echo "check_wheel: ok"
