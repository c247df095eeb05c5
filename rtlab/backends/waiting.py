"""Waiting for a launched kernel of a student's code without hanging for good.

A kernel runs to its end: neither OpenCL nor CUDA can stop one, and PoCL's wait blocks in C, where
Python's signal handlers never run, so Ctrl-C went unheard and an endless loop hung ``rtlab render``,
a notebook or a script for good. Where the kernels are a student's (a tree other than this
installation's, or one that still holds a template stub: a student release), a launch is awaited
with a time limit ($RTLAB_KERNEL_TIMEOUT seconds, default KERNEL_TIMEOUT_S; 0: none) and Ctrl-C is
heard. Either ends the process with one line saying what ran: the device stays busy with the kernel,
so nothing after it could run (on PoCL the process's end stops it; on a GPU the driver tears the
kernel down with the process's context, and the next process finds the GPU free: measured on the H200,
CUDA and NVIDIA OpenCL, experiments/gpu_student_hang.sh). A fault the device reports (CUDA's illegal
memory access) is a KernelRunError naming the kernel, the library's own kernels' too. A kernel that crashes the process (an out-of-bounds write) is named by
the command line's child process (rtlab.cli.supervise); in a script or notebook, faulthandler's dump
shows the launch it died in. The library's own kernels are awaited directly (no thread, no polling:
their launch overhead is measured), and so are the grader's test processes, which the grader times
and stops itself (rtlab.course.processes).
"""
from __future__ import annotations

import faulthandler
import os
import sys
import threading
import time
from functools import lru_cache
from pathlib import Path
from typing import Callable

from .. import settings
from ..errors import KernelRunError, RtlabError

KERNEL_TIMEOUT_S = 120.0     # one launch of a student's kernel; the reference's take well under a second


@lru_cache(maxsize=None)
def _student_tree(root: Path) -> bool:
    from ..paths import REFERENCE_KERNEL_DIR, tree_has_stubs
    if root.resolve() != REFERENCE_KERNEL_DIR.resolve():
        return True
    return any(tree_has_stubs(f"shared/{p.name}") for p in sorted((root / "shared").glob("*.h")))


def student_tree() -> bool:
    """Whether the kernels this process compiles are a student's (see the module docstring)."""
    from ..paths import kernel_dir
    return _student_tree(kernel_dir())


def kernel_time_limit() -> float | None:
    """Seconds a launch may take before the process gives up on it, or None: wait as long as it takes."""
    if settings.get("RTLAB_RESULT_FD") or not student_tree():
        return None
    text = settings.get("RTLAB_KERNEL_TIMEOUT")
    if text is None:
        return KERNEL_TIMEOUT_S
    try:
        limit = float(text)
    except ValueError:
        raise RtlabError(f"$RTLAB_KERNEL_TIMEOUT must be a number of seconds (0: no limit), not {text!r}") from None
    return limit if limit > 0 else None


def _give_up(message: str, status: int) -> None:
    """The kernel still runs on the device: say so and end the process (nothing after it could run)."""
    from .base import terminal_stderr_fd
    line = f"rtlab: {message}\n"
    try:
        sys.stderr.flush()
        os.write(terminal_stderr_fd(), line.encode())
    except (OSError, ValueError):
        pass
    if sys.stderr is not sys.__stderr__:          # a notebook: its stderr goes to the page, by a thread
        try:
            sys.stderr.write(line)
            sys.stderr.flush()
            time.sleep(0.2)
        except (OSError, ValueError):
            pass
    os._exit(status)


def run_failure(kernel: str, error: BaseException) -> KernelRunError:
    """The error to raise when the device reports that ``kernel`` failed (CUDA's "an illegal memory
    access was encountered", NVIDIA OpenCL's -9999 or CL_OUT_OF_RESOURCES): what failed, what the
    device said, the likely cause, and that the device context is lost (CUDA's such errors stick to
    it), so the process must start again."""
    said = " ".join(str(error).split())[:300] or type(error).__name__
    cause = ("an index past an array's end in your code? (a stack that overflows, a node or triangle index "
             "read wrong)" if student_tree() else "this installation's own kernel: a bug, please report it")
    return KernelRunError(f"kernel {kernel} failed on the device ({said}): {cause}. The device's context is lost: "
                          f"start the process again (in a notebook, restart its kernel)")


def _device_wait(kernel: str, call: Callable):
    """``call()`` (a wait or a query on the launch), its failures as :func:`run_failure`."""
    try:
        return call()
    except (RtlabError, KeyboardInterrupt):
        raise
    except Exception as e:         # pycuda's or pyopencl's error: the kernel failed on the device
        raise run_failure(kernel, e) from None


def wait_for_kernel(kernel: str, wait: Callable[[], None], done: Callable[[], bool] | None = None) -> None:
    """Wait for the launch of ``kernel`` to end: by ``wait`` (a blocking call) where no limit applies;
    where one does, by polling ``done`` when given (CUDA: its events are tied to the thread that made
    them), else by ``wait`` in a thread of its own. Gives up as the module docstring says; a failure the
    device reports is a KernelRunError (:func:`run_failure`)."""
    limit = kernel_time_limit()
    if limit is None:
        _device_wait(kernel, wait)
        return
    if not faulthandler.is_enabled():     # a crash in a script or notebook then shows where it ran
        faulthandler.enable()
    hint = (f"an endless loop in your code? (a traversal that never empties its stack or never leaves a leaf, a "
            f"loop counter that never advances; $RTLAB_KERNEL_TIMEOUT sets the limit, now {limit:g} s)")
    start = time.monotonic()
    try:
        if done is not None:
            while not _device_wait(kernel, done):
                if time.monotonic() - start > limit:
                    _give_up(f"kernel {kernel} still ran after {limit:g} s, so this process stops: {hint}", 3)
                time.sleep(1e-4)
            return
        finished, failure = threading.Event(), []

        def waiter():
            try:
                _device_wait(kernel, wait)
            except BaseException as e:      # handed to the caller's thread below
                failure.append(e)
            finally:
                finished.set()
        threading.Thread(target=waiter, name=f"rtlab-wait-{kernel}", daemon=True).start()
        if not finished.wait(limit):
            _give_up(f"kernel {kernel} still ran after {limit:g} s, so this process stops: {hint}", 3)
        if failure:
            raise failure[0]
    except KeyboardInterrupt:
        _give_up(f"interrupted while kernel {kernel} ran ({time.monotonic() - start:.1f} s); the device cannot "
                 f"stop a kernel, so this process stops", 130)
