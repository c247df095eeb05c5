"""Every environment variable rtlab reads, what it means, and the tolerances its checks share: one
place to look (README's table of settings is checked against :data:`SETTINGS`).

    from rtlab import settings
    settings.get("RTLAB_BACKEND")        # the value, or None when unset (or empty)
    settings.flag("RTLAB_VERBOSE")       # set and not 0/off/no/false

Reading goes through here only (tests/test_architecture.py checks): a variable read at one place is
documented at one place. Imports nothing from rtlab.
"""
from __future__ import annotations

import os
from dataclasses import dataclass


@dataclass(frozen=True)
class Setting:
    name: str
    meaning: str
    external: bool = False      # a variable of another tool that rtlab honours (not prefixed RTLAB_)


SETTINGS: dict[str, Setting] = {s.name: s for s in (
    Setting("RTLAB_BACKEND", "backend when none is named: opencl, cuda or auto (the default)"),
    Setting("RTLAB_DEVICE", "device when none is named: a name substring, P:D indices, cpu or gpu"),
    Setting("RTLAB_CUDA_DEVICE", "CUDA device index or name substring when none is named"),
    Setting("RTLAB_SCENES", "folders searched first for scene files (os.pathsep-separated)"),
    Setting("RTLAB_CACHE", "folder of rtlab's caches (acceleration structures, scenes); default the per-user cache"),
    Setting("RTLAB_NO_CACHE", "1: build acceleration structures afresh, never read or write the disk cache"),
    Setting("RTLAB_KERNEL_DIR", "another folder of kernel sources to compile from (a student's; the grader sets it)"),
    Setting("RTLAB_KERNEL_CONSTANTS", "a JSON file of the kernels' constants, read instead of the headers (the "
                                      "grader gives its test processes one)"),
    Setting("RTLAB_KERNEL_TIMEOUT", "seconds one launch of a student's kernels may run before the process stops "
                                    "with a message (default 120; 0: no limit)"),
    Setting("RTLAB_CL_OPTIONS", "extra OpenCL build options, space-separated"),
    Setting("RTLAB_NVCC_OPTIONS", "extra nvcc options, space-separated"),
    Setting("RTLAB_VERBOSE", "1: show compiler output of successful builds (rtlab --verbose sets it)"),
    Setting("RTLAB_TRACEBACK", "1: show the traceback of an unexpected error instead of one line"),
    Setting("RTLAB_VTK_WINDOW", "pyvista's off-screen window kind, once probed (egl or osmesa)"),
    Setting("RTLAB_GRADER_SANDBOX", "off: grade without the sandbox (debugging the grader only, never grading)"),
    Setting("RTLAB_SANDBOX_USER", "the unprivileged user a root grader runs submissions as"),
    Setting("RTLAB_RESULT_FD", "the pipe a grading test process writes its results to (set by the grader)"),
    Setting("RTLAB_TEST_BACKENDS", "the test suite's backends, e.g. cuda,opencl:NVIDIA (tests only)"),
    Setting("RTLAB_GRADE_ALL", "1: the grading tests grade every stored submission on every test (tests only)"),
    Setting("RTLAB_NOTEBOOK_SIZE", "the notebooks' image size in pixels (the test suite runs them at 64)"),
    Setting("RTLAB_VENV", "the grading bundle's virtual environment (setup.sh and run_autograder; default /opt/rtlab)"),
    Setting("RTLAB_PAPER_BACKENDS", "the backends experiments/gpu_paper.sh measures (default: cuda opencl:NVIDIA)"),
    Setting("PYOPENCL_CTX", "pyopencl's device choice, honoured when RTLAB_DEVICE is unset", external=True),
)}

# The relative error in t a hit may have against the float64 reference (a few float32 roundings of
# the distance: the checks of the labs, the benches and the tests)
HIT_T_REL_TOL = 1e-5


def get(name: str, default: str | None = None) -> str | None:
    """The variable's value (stripped), or ``default`` when it is unset or empty."""
    if name not in SETTINGS:
        raise KeyError(f"{name} is not one of rtlab's settings (rtlab.settings.SETTINGS)")
    value = os.environ.get(name, "").strip()
    return value if value else default


def flag(name: str) -> bool:
    """Whether the variable is set to something other than 0, off, no or false."""
    return (get(name) or "0").lower() not in ("0", "off", "no", "false")


def setenv(name: str, value: str) -> None:
    """Set a variable for this process and the ones it starts (rtlab --verbose, the probed VTK window)."""
    if name not in SETTINGS:
        raise KeyError(f"{name} is not one of rtlab's settings (rtlab.settings.SETTINGS)")
    os.environ[name] = value
