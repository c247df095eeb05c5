#!/usr/bin/env bash
# System packages rtlab needs on Debian/Ubuntu: PoCL (OpenCL on the CPU) and Mesa/EGL for headless
# pyvista. Skips what is already installed; needs root (or sudo).
set -euo pipefail
pkgs=(pocl-opencl-icd ocl-icd-libopencl1 libegl1 libgl1-mesa-dri libosmesa6)
missing=()
for p in "${pkgs[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
# Debian's own python3 needs python3-venv for `python3 -m venv`
python3 -c "import ensurepip" 2>/dev/null || missing+=(python3-venv)
[ ${#missing[@]} -eq 0 ] && exit 0
sudo=""
[ "$(id -u)" -ne 0 ] && sudo="sudo"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
