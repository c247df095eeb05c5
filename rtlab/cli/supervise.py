"""Commands that run a student's kernels run in a child process, so that a kernel that crashes it (an
out-of-bounds write: SIGSEGV in the OpenCL runtime) ends the child, not the command: the parent says
what happened in one line, as the grader does (rtlab.course.processes.signal_text), where the shell
said only "Segmentation fault". A kernel that never ends is rtlab.backends.waiting's to stop.

The child is forked before anything is imported that starts threads or opens a device (the command
line's modules import those lazily), and the parent only waits for it.
"""
from __future__ import annotations

import os
import signal
import sys
import time
from typing import Callable

from .. import settings

# Commands that never run a student's kernels in this process: the grader isolates each test itself
UNSUPERVISED = ("grade", "lab", "info", "scenes", "variants", "--help", "-h")


def _runs_student_kernels(argv: list[str]) -> bool:
    command = next((a for a in argv if not a.startswith("-")), "")
    if command in UNSUPERVISED or settings.get("RTLAB_RESULT_FD"):
        return False
    if "--kernels" in argv or any(a.startswith("--kernels=") for a in argv) or settings.get("RTLAB_KERNEL_DIR"):
        return True
    from ..backends.waiting import student_tree
    return student_tree()


def run_supervised(argv: list[str], run: Callable[[], int]) -> int:
    """``run()``'s exit status, run in a forked child where ``argv`` runs a student's kernels."""
    if not hasattr(os, "fork") or not _runs_student_kernels(argv):
        return run()
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:                                     # the child runs the command
        status = 1
        try:
            status = run()
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(status)
    status, interrupted = None, False
    while status is None:
        try:
            status = os.waitpid(pid, 0)[1]
        except KeyboardInterrupt:
            interrupted = True
            status = _stop(pid)
    if interrupted:
        return 130
    if os.WIFSIGNALED(status):
        from ..course.processes import signal_text
        print(f"rtlab: the command's process died while running your kernels: {signal_text(os.WTERMSIG(status))}",
              file=sys.stderr)
        return 1
    return os.WEXITSTATUS(status)


def _stop(pid: int) -> int:
    """Ctrl-C reached the child too: a moment for it to say what it was running, then SIGKILL. Its status."""
    end = time.monotonic() + 3.0
    while time.monotonic() < end:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return status
        time.sleep(0.05)
    os.kill(pid, signal.SIGKILL)
    return os.waitpid(pid, 0)[1]
