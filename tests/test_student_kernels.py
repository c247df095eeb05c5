"""A student's kernels that hang or crash, run outside the grader (rtlab render, a script, a notebook):
one line says what happened and the process ends; nothing hangs for good or dies unexplained
(rtlab.backends.waiting, rtlab.cli.supervise). The library's own kernels are awaited as before."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from rtlab.paths import REFERENCE_KERNEL_DIR

HANG = "{ volatile int spin = 0; while (spin == 0) { } }"
CRASH = "{ long idx = 400000000L * (long)(get_global_id(0) + 1); ((RT_GLOBAL int *)nodes)[idx] = 7; }"


def _student_tree(tmp_path: Path, code: str) -> Path:
    """The kernels with ``code`` first in traverse_kd_stack's solution region (lab 00's traversal)."""
    root = tmp_path / "mykernels"
    shutil.copytree(REFERENCE_KERNEL_DIR, root)
    header = root / "shared" / "rt_kdtree.h"
    text = header.read_text()
    at = text.index("/* BEGIN SOLUTION */", text.index("traverse_kd_stack(")) + len("/* BEGIN SOLUTION */")
    header.write_text(text[:at] + "\n    " + code + "\n" + text[at:])
    return root


def _run(args: list[str], kernels: Path, timeout_s: str = "4") -> subprocess.CompletedProcess:
    env = {**os.environ, "RTLAB_KERNEL_DIR": str(kernels), "RTLAB_KERNEL_TIMEOUT": timeout_s}
    return subprocess.run([sys.executable, *args], env=env, capture_output=True, text=True, timeout=240)


# On PoCL (the CPU): a GPU's driver, not the process, decides what becomes of a kernel that never ends
RENDER = ["-m", "rtlab", "render", "default", "--size", "16", "--traversal", "stack", "--isect", "moller",
          "--backend", "opencl", "--device", "cpu"]


def test_an_endless_loop_in_rtlab_render_ends_with_a_message(tmp_path):
    r = _run(RENDER, _student_tree(tmp_path, HANG))
    assert r.returncode == 3, r.stderr
    assert "kernel render_primary still ran after 4 s" in r.stderr and "an endless loop in your code?" in r.stderr


def test_an_endless_loop_in_a_script_ends_with_a_message(tmp_path):
    script = ("import rtlab; scene = rtlab.load_scene('default', size=16); "
              "rtlab.render(scene, backend='opencl', device='cpu', variant=rtlab.Variant.paper(traversal='stack'))")
    r = _run(["-c", script], _student_tree(tmp_path, HANG))
    assert r.returncode == 3 and "kernel render_primary still ran after 4 s" in r.stderr, r.stderr


def test_a_kernel_that_crashes_rtlab_render_is_named(tmp_path):
    r = _run(RENDER, _student_tree(tmp_path, CRASH))
    assert r.returncode == 1, r.stderr
    assert "died while running your kernels: SIGSEGV (segmentation fault: a memory access out of bounds" in r.stderr


def test_only_a_students_kernels_get_a_time_limit(tmp_path, monkeypatch):
    from rtlab import paths
    from rtlab.backends import waiting
    assert waiting.kernel_time_limit() is None                    # the installation's own kernels
    tree = _student_tree(tmp_path, "")
    monkeypatch.setattr(paths, "_kernel_dir", tree)
    assert waiting.kernel_time_limit() == waiting.KERNEL_TIMEOUT_S
    monkeypatch.setenv("RTLAB_KERNEL_TIMEOUT", "0")
    assert waiting.kernel_time_limit() is None
    monkeypatch.setenv("RTLAB_KERNEL_TIMEOUT", "soon")
    with pytest.raises(waiting.RtlabError, match="RTLAB_KERNEL_TIMEOUT must be a number of seconds"):
        waiting.kernel_time_limit()
    monkeypatch.setenv("RTLAB_KERNEL_TIMEOUT", "9")
    monkeypatch.setenv("RTLAB_RESULT_FD", "5")                   # a grading test process: the grader's limits
    assert waiting.kernel_time_limit() is None
