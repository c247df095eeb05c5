"""Test processes from the grader's side (rtlab.labs.grader): how many run at once (the CPUs and
memory this process may use, containers' cgroup limits included) and one test process
(``python -m rtlab.labs.run_test``) started and watched: its setup limit (restarted at each kernel
compile), its run limit, its memory and the run's deadline, and what it left, as a ChildResult."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

POLL_S = 0.05
GRADER_OVERHEAD_MB = 1024       # the grading process itself (scenes, fixtures, numba) beside its tests
MAX_OUTPUT = 6000     # characters of a test's message (a compiler can print thousands of errors)
MEMORY_SIGNS = ("MemoryError", "bad_alloc", "out of memory", "Cannot allocate memory", "Allocation failed")


def _read(path: str) -> str:
    try:
        with open(path) as f:
            return f.read().strip()
    except OSError:
        return ""


def available_cpus() -> int:
    """CPUs this process may use: its affinity mask, capped by a cgroup CPU quota (containers)."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    quota = _read("/sys/fs/cgroup/cpu.max").split()            # cgroup v2: "max 100000" or "200000 100000"
    if len(quota) == 2 and quota[0] != "max":
        n = min(n, max(1, -(-int(quota[0]) // int(quota[1]))))
    else:                                                      # cgroup v1
        q, p = _read("/sys/fs/cgroup/cpu/cpu.cfs_quota_us"), _read("/sys/fs/cgroup/cpu/cpu.cfs_period_us")
        if q.lstrip("-").isdigit() and p.isdigit() and int(q) > 0:
            n = min(n, max(1, -(-int(q) // int(p))))
    return max(1, n)


def available_memory_mb() -> int | None:
    """Memory this process may use: a cgroup limit, else the machine's total (None if unknown)."""
    limits = []
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        v = _read(path)
        if v.isdigit() and int(v) < 1 << 60:
            limits.append(int(v) // 2 ** 20)
    for line in _read("/proc/meminfo").splitlines():
        if line.startswith("MemTotal:"):
            limits.append(int(line.split()[1]) // 1024)
    return min(limits) if limits else None


def default_jobs(memory_limit_mb: int) -> int:
    """Tests run at once: one per usable CPU, no more than the memory holds at the per-test limit."""
    n = available_cpus()
    mem = available_memory_mb()
    if mem is not None:
        n = min(n, max(1, (mem - GRADER_OVERHEAD_MB) // max(1, memory_limit_mb)))
    return max(1, n)


@dataclass
class ChildResult:
    status: str                 # ok, compile_error, crashed, timeout, memory, error, skipped, deadline
    fraction: float = 0.0
    output: str = ""
    data: dict = field(default_factory=dict)
    seconds: float = 0.0
    device: str = ""
    programs: list = field(default_factory=list)     # what the process compiled and launched


@dataclass(frozen=True)
class Limits:
    setup: float            # seconds to start, and again for each kernel compile
    run: float              # seconds for the test's own work
    memory_mb: int          # the process's RLIMIT_DATA
    deadline_at: float      # time.monotonic() when the whole grading run must end


def _signal_text(sig: int) -> str:
    try:
        name = signal.Signals(sig).name
    except ValueError:
        name = f"signal {sig}"
    what = {"SIGSEGV": "segmentation fault: a memory access out of bounds (a wrong node, triangle or "
                       "stack index?) or a stack overflow",
            "SIGBUS": "bus error: a misaligned or out-of-bounds memory access",
            "SIGFPE": "arithmetic exception (integer division by zero?)",
            "SIGABRT": "aborted (the OpenCL runtime gave up, often after an out-of-bounds write)",
            "SIGILL": "illegal instruction",
            "SIGKILL": "killed (out of memory?)",
            "SIGXFSZ": "wrote more than a test process may (a kernel printing without end?)"}.get(name, "")
    return f"{name} ({what})" if what else name


def _log_tail(path: Path, lines: int = 8, max_bytes: int = 1 << 16) -> str:
    try:
        with open(path, "rb") as f:
            f.seek(max(0, f.seek(0, os.SEEK_END) - max_bytes))
            text = f.read().decode("utf-8", "replace").strip().splitlines()
    except OSError:
        return ""
    return "\n".join(text[-lines:])


def shorten(text: str) -> str:
    if len(text) <= MAX_OUTPUT:
        return text
    return text[:MAX_OUTPUT - 200] + f"\n... ({len(text) - MAX_OUTPUT + 200:,} more characters cut)"


def _vm_kb(pid: int) -> dict:
    out = {}
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key in ("VmHWM", "VmData"):
                    out[key] = int(value.split()[0])
    except (OSError, ValueError):
        pass
    return out


def run_child(test_dir: Path, job: dict, kernel_root: Path, limits: Limits) -> ChildResult:
    """Run one test process and watch its limits: setup (restarted at each kernel compile), run,
    memory (the process caps itself; the peak is watched here for the message) and the run's deadline."""
    test_dir.mkdir(parents=True, exist_ok=True)
    (test_dir / "spec.json").write_text(json.dumps({**job, "memory_limit_mb": limits.memory_mb}, default=str))
    env = dict(os.environ, RTLAB_KERNEL_DIR=str(kernel_root), PYTHONUNBUFFERED="1")
    env.setdefault("POCL_CACHE_DIR", str(test_dir.parent.parent / "pocl-cache"))
    t0 = time.monotonic()
    peak_kb = 0
    with open(test_dir / "log.txt", "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "rtlab.labs.run_test", str(test_dir)], env=env,
                                stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True, cwd=test_dir)
        run_start = None
        step_start, step = t0, ""
        stopped = None
        while proc.poll() is None:
            now = time.monotonic()
            if run_start is None:
                if (test_dir / "phase").exists():
                    run_start = now
                else:
                    try:
                        mark = (test_dir / "setup").read_text()
                    except OSError:
                        mark = ""
                    if mark != step:
                        step, step_start = mark, now
            vm = _vm_kb(proc.pid)
            peak_kb = max(peak_kb, vm.get("VmHWM", 0))
            if now >= limits.deadline_at:
                stopped = ("deadline", 0.0)
            elif run_start is None and now - step_start > limits.setup:
                stopped = ("setup", limits.setup)
            elif run_start is not None and now - run_start > limits.run:
                stopped = ("run", limits.run)
            if stopped:
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                proc.wait()
                break
            time.sleep(POLL_S)
    seconds = time.monotonic() - t0
    programs = []
    try:
        programs = json.loads((test_dir / "programs.json").read_text())
    except (OSError, ValueError):
        pass
    data = {"peak_memory_mb": round(peak_kb / 1024, 1)} if peak_kb else {}
    if stopped:
        phase, limit = stopped
        if phase == "deadline":
            return ChildResult("deadline", 0.0, "stopped: the grading run reached its deadline (see the note)",
                               data, seconds=seconds, programs=programs)
        if phase == "setup":
            what = "compiling a kernel" if step else "starting and loading its scene"
            msg = (f"stopped after {limit:g} s {what} (the setup limit; the reference needs a few seconds): "
                   f"a compiler stuck on the source (a macro that expands without end?), or an overloaded machine")
        else:
            msg = (f"timed out: still running after {limit:g} s (the reference needs a small fraction of that), "
                   f"killed. An endless loop? (a traversal that never empties its stack or never leaves a "
                   f"leaf, a loop counter that never advances)")
        return ChildResult("timeout", 0.0, msg, data, seconds=seconds, programs=programs)
    result_file = test_dir / "result.json"
    if result_file.is_file():
        r = json.loads(result_file.read_text())
        return ChildResult(r["status"], float(r["fraction"]), r["output"], {**r.get("data", {}), **data}, seconds,
                           r.get("device", ""), programs)
    rc = proc.returncode
    phase = "running its kernel" if (test_dir / "phase").exists() else "starting (compiling or loading)"
    tail = _log_tail(test_dir / "log.txt")
    if any(sign in tail for sign in MEMORY_SIGNS):
        return ChildResult("memory", 0.0, f"ran out of memory while {phase}: a test process may use "
                                          f"{limits.memory_mb} MB (grading.toml memory_limit_mb; the reference needs "
                                          f"a fraction of that). A macro that expands without end, or a huge array?",
                           data, seconds=seconds, programs=programs)
    if rc < 0:
        return ChildResult("crashed", 0.0, f"crashed while {phase}: {_signal_text(-rc)}", data, seconds=seconds,
                           programs=programs)
    return ChildResult("error", 0.0, f"the test process failed while {phase} (exit status {rc}):\n{tail}", data,
                       seconds=seconds, programs=programs)
