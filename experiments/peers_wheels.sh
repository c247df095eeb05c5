#!/usr/bin/env bash
# Stage Warp 1.19.0 and Mitsuba 3.9.1 (with Dr.Jit 1.5.0) for experiments/peers_same_run.py on the lent GPU
# machine, which reaches no registry. Warp's wheel alone (149 MB) is over a device call's 64 MiB, so the
# wheels are unpacked here, stripped of what a CUDA run does not load (Warp's CPU compiler, examples and
# tests; Mitsuba's LLVM, scalar-spectral and other CUDA variants, headers), xz-compressed (113 MB) and
# split into two halves, .peersA/ and .peersB/ (git-ignored), for two back-to-back calls (a machine goes
# back 30 s after a call):
#   run 1, carry [".peersA"]: mkdir -p /tmp/peers && cp .peersA/part00 /tmp/peers/
#   run 2, carry [".peersB"]: set -e; cp .peersB/part01 /tmp/peers/ && cd /tmp/peers && cat part00 part01 | tar -x
#          && mkdir -p site/warp/bin && tar -xJf peers_py.tar.xz -C site && xz -T8 -dc warpso.xz > site/warp/bin/warp.so
#   run 3, carry [".device"]: source .device/setup.sh && export PYTHONPATH=$PYTHONPATH:/tmp/peers/site
#          && cd experiments && python peers_same_run.py --md $OUT/peers.md
# Usage (from the project root): bash experiments/peers_wheels.sh
set -euo pipefail
root=$(pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
    -d "$work/whl" warp-lang==1.19.0 mitsuba==3.9.1 drjit==1.5.0
mkdir -p "$work/site" "$work/blob"
(cd "$work/site" && for w in "$work"/whl/*.whl; do unzip -q "$w"; done)
xz -9 -T0 -c "$work/site/warp/bin/warp.so" > "$work/blob/warpso.xz"
rm -rf "$work"/site/warp/bin "$work"/site/warp/examples "$work"/site/warp/tests \
    "$work"/site/mitsuba/llvm_* "$work"/site/mitsuba/scalar_spectral* "$work"/site/mitsuba/cuda_ad_mono* \
    "$work"/site/mitsuba/cuda_ad_spectral* "$work"/site/mitsuba/include "$work"/site/mitsuba/cmake \
    "$work"/site/mitsuba/mitsuba_stubs "$work"/site/mitsuba/pkgconfig "$work"/site/drjit/include
tar -cJf "$work/blob/peers_py.tar.xz" -C "$work/site" .
tar -cf "$work/blob.tar" -C "$work/blob" warpso.xz peers_py.tar.xz
split -n 2 -d "$work/blob.tar" "$work/part"
mkdir -p "$root/.peersA" "$root/.peersB"
mv "$work/part00" "$root/.peersA/part00"
mv "$work/part01" "$root/.peersB/part01"
grep -qx '/.peersA/' "$root/.git/info/exclude" || printf '/.peersA/\n/.peersB/\n' >> "$root/.git/info/exclude"
ls -la "$root/.peersA" "$root/.peersB"
