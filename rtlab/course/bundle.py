"""A Gradescope autograder for one lab step: ``rtlab grade --bundle STEP --out DIR``.

DIR (and DIR/autograder.zip, what Gradescope takes) holds rtlab itself (pyproject, rtlab/,
kernels/, labs/), the scene files the step's tests load, a ``grading-secret`` (drawn for this
bundle: the seed of the rays of the tests hidden until the due date), AUTOGRADER.md for the instructor
and Gradescope's two scripts:

* ``setup.sh`` (run once when the image is built: PoCL from apt, Python >= 3.11, rtlab in a venv,
  then a self-check that grades the reference with the bundle's secret and fails the build unless
  it scores full marks; it also warms the kd-tree and kernel caches);
* ``run_autograder`` (per submission: grades /autograder/submission, writes
  /autograder/results/results.json after every test, and one even when the grader cannot start).

Both take the Gradescope root from ``$AUTOGRADER_ROOT`` (default /autograder) and the venv from
``$RTLAB_VENV`` (default /opt/rtlab), so the layout can be simulated elsewhere.
"""
from __future__ import annotations

import secrets
import shutil
import stat
import zipfile
from pathlib import Path

from ..errors import LabError
from ..paths import IN_CHECKOUT, PROJECT_DIR, find_scene_file
from .config import load_config

VENV = "/opt/rtlab"
ROOT = "/autograder"

SETUP_SH = """#!/usr/bin/env bash
# Gradescope runs this once, as root, when it builds the autograder image (Ubuntu). Written by
# `rtlab grade --bundle {step}`.
set -euo pipefail
ROOT="${{AUTOGRADER_ROOT:-{root}}}"
VENV="${{RTLAB_VENV:-{venv}}}"
SOURCE="$ROOT/source"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
# PoCL: OpenCL on the CPU, where the grader runs every test (Debian's and Ubuntu's bring clang, whose
# preprocessor lists what a submission includes); libseccomp2: the test processes' system-call filter
apt-get install -y -qq --no-install-recommends pocl-opencl-icd ocl-icd-libopencl1 libseccomp2 python3 python3-venv python3-pip
command -v clang >/dev/null || ls /usr/bin/clang-[0-9]* >/dev/null 2>&1 || apt-get install -y -qq --no-install-recommends clang
# rtlab needs Python >= 3.11 (Ubuntu 22.04's python3 is 3.10). The system's, which the unprivileged
# user that runs submissions can read (a Python under /root could not be)
PY=""
for p in /usr/bin/python3.13 /usr/bin/python3.12 /usr/bin/python3.11 /usr/bin/python3; do
  if [ -x "$p" ] && "$p" -c 'import sys; sys.exit(sys.version_info < (3, 11))'; then PY="$p"; break; fi
done
if [ -z "$PY" ]; then
  apt-get install -y -qq --no-install-recommends python3.11 python3.11-venv
  PY=/usr/bin/python3.11
fi
"$PY" -m venv "$VENV"
"$VENV/bin/pip" install -q --upgrade pip
"$VENV/bin/pip" install -q -e "$SOURCE"
# No OpenCL platform from apt (an old image)? PoCL from PyPI instead
"$VENV/bin/python" -c 'import pyopencl as cl; assert cl.get_platforms()' 2>/dev/null || \\
  {{ apt-get install -y -qq --no-install-recommends build-essential clang; "$VENV/bin/pip" install -q pocl-binary-distribution; }}
# The sandbox: submissions run as this user; what they must not read is root's alone
id rtlab-sandbox >/dev/null 2>&1 || useradd --system --no-create-home --shell /usr/sbin/nologin rtlab-sandbox
chmod 755 "$ROOT" "$SOURCE"
chmod -R go-rwx "$SOURCE/kernels" "$SOURCE/labs" "$SOURCE/scenes" "$SOURCE/grading-secret"
# Self-check: the reference must score full marks with this bundle's secret (it also builds the
# kd-trees and fills the caches). Anything less fails the image build: do not grade with it.
export RTLAB_SCENES="$SOURCE/scenes" RTLAB_CACHE="$ROOT/cache"
mkdir -p "$ROOT/cache"
chmod 700 "$ROOT/cache"
"$VENV/bin/rtlab" info
# One retry: the reference's speed against itself can pass 1.25x on a builder loaded by other work.
self_check() {{
  "$VENV/bin/rtlab" grade {step} "$SOURCE" --backend opencl --format table --secret-file "$SOURCE/grading-secret" \\
      --out "$ROOT/cache/self-check.json" --require-full-marks
}}
self_check || self_check
"""

RUN_AUTOGRADER = """#!/usr/bin/env bash
# Gradescope runs this for every submission (files in /autograder/submission). Written by
# `rtlab grade --bundle {step}`. The grader writes results.json after every test (a run stopped
# from outside still reports) and even when a test crashes or hangs; the fallback below covers a
# grader that cannot start at all.
ROOT="${{AUTOGRADER_ROOT:-{root}}}"
VENV="${{RTLAB_VENV:-{venv}}}"
SOURCE="$ROOT/source"
export RTLAB_SCENES="$SOURCE/scenes" RTLAB_CACHE="$ROOT/cache" RTLAB_BACKEND=opencl
mkdir -p "$ROOT/results"
chmod 700 "$ROOT/results"
cd "$SOURCE"
"$VENV/bin/rtlab" grade {step} "$ROOT/submission" --backend opencl --format gradescope \\
    --secret-file "$SOURCE/grading-secret" --out "$ROOT/results/results.json"
status=$?
if [ ! -s "$ROOT/results/results.json" ]; then
  printf '{{"score": 0, "output": "The autograder could not start (exit status %s). This is not your code: please tell the course staff.", "tests": []}}\\n' "$status" \\
    > "$ROOT/results/results.json"
fi
"""

# Measured on the course's lab machine (2 CPU cores, PoCL 3.1, caches warm as after setup.sh, the
# sandbox on): `rtlab grade STEP .` of the reference, seconds for one submission (README has the table).
# 2026-11-24, the development machine under a load of ~3 (two other jobs), reference graded as root:
# 10-12, 11.5, 17.6, 28-31 (five speed tests), 11.7, 17.0 s; rounded up for a Gradescope machine.
MEASURED_SECONDS = {"00_primary": 15, "01_memory": 15, "02_intersect": 22, "03_traversal": 35,
                    "04_shadows": 15, "05_kernel_tree": 22}

README = """# Gradescope autograder for rtlab lab {step}

Written by `rtlab grade --bundle {step}` from the course's repository (the reference). Upload
`autograder.zip` as the assignment's autograder (Ubuntu 22.04 base image or newer).

What it needs (set these in the assignment's autograder settings):
- **Memory:** each test runs in its own process capped at {memory} MB (grading.toml
  `memory_limit_mb`; the reference's test processes peak at 300-560 MB), and up to {jobs_hint} of them run at once beside
  the grading process and its reference worker (about 1.5 GB together: scenes, fixtures, the reference kernels). With one
  CPU, 3.5 GB is enough; with N CPUs, N x {memory} MB + 1.5 GB. The grader starts no more tests at once than the memory
  it sees allows.
- **Time:** one grading takes about {seconds} s on 2 CPU cores with the sandbox on (more on a loaded machine; the
  first submission after the image build pays no compile or kd-tree build for the reference: setup.sh warmed the
  caches). Every test has its own limits (a setup limit of {setup:g} s per kernel compile, a run
  limit per test) and the whole run stops at {deadline:g} s (grading.toml `deadline`; Gradescope's
  own default limit is 600 s): what is not done by then scores 0 with a message.
- `setup.sh` grades the reference solution with this bundle's secret and fails the image build if
  it scores less than full marks.

**The sandbox.** A kernel on PoCL is native code in the process that runs it, so every test runs in a
process of its own that holds nothing worth taking: the submission's compile tree, the test's inputs
(scene, rays), a scratch folder; never the expected answers (the grader keeps them and checks what the
process hands back), the secret or the reference kernels. setup.sh creates the user `rtlab-sandbox`, which
runs every submission, and leaves `source/kernels`, `source/labs`, `source/scenes` and `grading-secret`
readable by root alone. Each test process is also confined by Landlock (it may write only its scratch
folder) and, from its first launch of submitted code, by a seccomp filter (no programs, processes,
sockets or signals to others); the reference kernel a speed test times against runs in a process of
the grader's that never loads submitted code.

The tests hidden until the due date draw their rays from `grading-secret`, drawn for this bundle:
make a new bundle each term. Students get `rtlab lab release` (no solutions, visible tests only).
"""

PROJECT_ITEMS = ("pyproject.toml", "README.md", "rtlab", "kernels", "labs")
SECRET_FILE = "grading-secret"


def scene_files(step: str) -> list[tuple[str, Path]]:
    """(relpath, found path) of every scene file the step's tests load."""
    from ..scene.presets import PRESETS
    config = load_config(step)
    out = []
    for name in sorted({t.scene for t in config.tests}):
        preset = PRESETS.get(name)
        if preset is None:
            continue   # the procedural default scene needs no file
        for rel in (preset.relpath, *(r for r, _ in preset.companions)):
            path = find_scene_file(rel)
            if path is None:
                raise LabError(f"lab {step} needs scene file {rel}, not found; see `rtlab scenes`")
            out.append((rel, path))
    return out


def write_bundle(step: str, out: Path | None = None) -> Path:
    """Write the autograder folder and its zip; returns the zip's path."""
    from .kernel_sources import has_reference
    config = load_config(step)
    if not IN_CHECKOUT:
        raise LabError("rtlab grade --bundle copies rtlab's sources: run it from a checkout of rtlab (the "
                       "course's repository), not an installed wheel")
    if not has_reference():
        raise LabError("this installation's kernels hold template stubs, not the reference (a student "
                       "release?): make the autograder from the course's repository")
    out = Path(out or f"autograder-{step}")
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info", "template")
    for item in PROJECT_ITEMS:
        src = PROJECT_DIR / item
        if src.is_dir():
            shutil.copytree(src, out / item, ignore=ignore)
        elif src.is_file():
            shutil.copy2(src, out / item)
    for rel, path in scene_files(step):
        dst = out / "scenes" / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, dst)
    (out / SECRET_FILE).write_text(secrets.token_hex(32) + "\n")
    fmt = {"step": step, "venv": VENV, "root": ROOT}
    for name, text in (("setup.sh", SETUP_SH), ("run_autograder", RUN_AUTOGRADER)):
        p = out / name
        p.write_text(text.format(**fmt))
        p.chmod(p.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    (out / "AUTOGRADER.md").write_text(README.format(
        step=step, memory=config.memory_limit_mb, setup=config.setup_limit, deadline=config.deadline,
        seconds=MEASURED_SECONDS.get(step, 60), jobs_hint="one per CPU"))
    zpath = out / "autograder.zip"
    with zipfile.ZipFile(zpath, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(out.rglob("*")):
            if f.is_file() and f != zpath:
                info = zipfile.ZipInfo.from_file(f, f.relative_to(out).as_posix())
                with open(f, "rb") as fh:
                    z.writestr(info, fh.read(), zipfile.ZIP_DEFLATED)
    return zpath
