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

# a loop on a volatile read of global memory, which no compiler may drop (NVIDIA's OpenCL compiler
# drops a loop on a volatile local), and a write far past the node array
HANG = "{ volatile RT_GLOBAL int *w = (volatile RT_GLOBAL int *)nodes; int first = w[0]; while (w[0] == first) { } }"
CRASH = "{ long idx = 400000000L * (long)(rt_global_id(0) + 1); ((RT_GLOBAL int *)nodes)[idx] = 7; }"


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


# On a GPU: students run their kernels there. The process must end with its line, and the device must
# serve the next process (the driver tears the kernel down with the process's context).
GPU_BACKENDS = {"cuda": ["--backend", "cuda"], "opencl-nvidia": ["--backend", "opencl", "--device", "NVIDIA"]}


def _gpu_render(backend: str) -> list[str]:
    return [*RENDER[:RENDER.index("--backend")], *GPU_BACKENDS[backend]]


@pytest.mark.gpu
@pytest.mark.parametrize("gpu_backend", sorted(GPU_BACKENDS))
def test_an_endless_loop_on_a_gpu_ends_with_a_message_and_frees_the_device(tmp_path, gpu_backend):
    r = _run(_gpu_render(gpu_backend), _student_tree(tmp_path, HANG))
    assert r.returncode == 3, r.stderr
    assert "kernel render_primary still ran after 4 s" in r.stderr and "Traceback" not in r.stderr
    after = subprocess.run([sys.executable, *_gpu_render(gpu_backend)], capture_output=True, text=True, timeout=240,
                           env={k: v for k, v in os.environ.items() if k != "RTLAB_KERNEL_DIR"})
    assert after.returncode == 0, after.stderr


@pytest.mark.gpu
@pytest.mark.parametrize("gpu_backend", sorted(GPU_BACKENDS))
def test_a_kernel_that_faults_on_a_gpu_is_named(tmp_path, gpu_backend):
    r = _run(_gpu_render(gpu_backend), _student_tree(tmp_path, CRASH))
    assert r.returncode == 2 and "Traceback" not in r.stderr and "this is a bug" not in r.stderr, r.stderr
    assert "kernel render_primary failed on the device" in r.stderr and "an index past an array's end" in r.stderr


def test_a_failure_the_device_reports_is_a_one_line_error(tmp_path, monkeypatch):
    """CUDA's and NVIDIA OpenCL's reports of a faulting kernel, raised by a wait or a poll, with and
    without the time limit, become a KernelRunError naming the kernel and the likely cause."""
    from rtlab import paths
    from rtlab.backends import waiting
    from rtlab.errors import KernelRunError

    def fails():
        raise RuntimeError("cuEventSynchronize failed: an illegal memory access was encountered")

    with pytest.raises(KernelRunError, match=r"kernel trace_rays failed on the device \(cuEventSynchronize failed: "
                                             r"an illegal memory access was encountered\): this installation's own"):
        waiting.wait_for_kernel("trace_rays", fails)
    monkeypatch.setattr(paths, "_kernel_dir", _student_tree(tmp_path, ""))
    for kwargs in ({"done": fails}, {}):
        with pytest.raises(KernelRunError, match=r"kernel render_primary failed on the device .* an index past an "
                                                 r"array's end in your code\?.* restart its kernel"):
            waiting.wait_for_kernel("render_primary", fails, **kwargs)
