"""Test processes from the grader's side (rtlab.course.grader): how many run at once (the CPUs and
memory this process may use, containers' cgroup limits included) and one test process
(``python -m rtlab.course.run_test``) started and watched: its setup limit (restarted at each kernel
compile), its run limit, its memory and the run's deadline, and what it left, as a ChildResult."""
from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from .sandbox import SIGSYS_TEXT

POLL_S = 0.05
GRADER_OVERHEAD_MB = 1536       # the grading process (scenes, fixtures, numba) and its reference worker
MAX_OUTPUT = 6000     # characters of a test's message (a compiler can print thousands of errors; Gradescope shows 8 KB)
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
    status: str                 # ok, compile_error, crashed, timeout, memory, error, skipped, deadline, budget
    output: str = ""
    arrays: dict = field(default_factory=dict)      # raw outputs (untrusted until a kind's check reads them)
    info: dict = field(default_factory=dict)
    data: dict = field(default_factory=dict)        # the grader's own observations (peak memory)
    seconds: float = 0.0
    programs: list = field(default_factory=list)    # what the process compiled (sent before its sandbox closed)
    fraction: float = 0.0                           # set by the grader's check, never by the process


@dataclass(frozen=True)
class Limits:
    setup: float            # seconds to start, and again for each kernel compile
    run: float              # seconds for the test's own work (each request of a serving process)
    memory_mb: int          # the process's RLIMIT_DATA
    deadline_at: float      # time.monotonic() when the whole grading run must end


def signal_text(sig: int) -> str:
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
            "SIGSYS": SIGSYS_TEXT,
            "SIGXFSZ": "wrote more than a test process may (a kernel printing without end?)"}.get(name, "")
    return f"{name} ({what})" if what else name


def _log_tail(log, lines: int = 8, max_bytes: int = 1 << 16) -> str:
    """The last lines of a test process's log, read through the grader's own open file: the process
    owns the folder and could put a link where the log's name was."""
    try:
        size = os.fstat(log.fileno()).st_size
        data = os.pread(log.fileno(), max_bytes, max(0, size - max_bytes))
    except (OSError, ValueError):
        return ""
    text = data.decode("utf-8", "replace").strip().splitlines()
    return "\n".join(text[-lines:])


def shorten(text: str, limit: int = MAX_OUTPUT) -> str:
    if len(text) <= limit:
        return text
    return text[:limit - 200] + f"\n... ({len(text) - limit + 200:,} more characters cut)"


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


class ProcessFailed(Exception):
    """A test process ended or was stopped without its answer: ``result`` says how."""

    def __init__(self, result: ChildResult):
        super().__init__(result.output)
        self.result = result


class TestProcess:
    """One test process (rtlab.course.run_test) and what it sends: started with its result channel on
    channel (a pipe) and commands on stdin, watched for its setup limit (restarted at each compile it announces
    before its sandbox closes), each request's run limit, its memory and the run's deadline."""

    def __init__(self, test_dir: Path, env: dict, limits: Limits, user=None, argv=None, sandboxed: bool = True):
        from .channel import FrameReader
        self.dir, self.limits, self.sandboxed = Path(test_dir), limits, sandboxed
        self.frames: "queue.Queue" = queue.Queue()
        self.reader = FrameReader()
        self.programs: list = []
        self.peak_kb = 0
        self.t0 = time.monotonic()
        self.ready = False
        self.paused = False
        self.work = None                # the work budget's counts, once the process sent them
        self.on_work = None             # on_work(counts) -> True stops the process there
        r, w = os.pipe()
        self.log = open(self.dir / "log.txt", "w+b")
        kwargs = {}
        if user is not None:
            kwargs.update(user=user.uid, group=user.gid, extra_groups=[])
        self.proc = subprocess.Popen([sys.executable, "-m", "rtlab.course.run_test", *(argv or [str(self.dir)])],
                                     env={**env, "RTLAB_RESULT_FD": str(w)}, stdout=self.log,
                                     stderr=subprocess.STDOUT, stdin=subprocess.PIPE, pass_fds=(w,),
                                     start_new_session=True, cwd=self.dir, umask=0o077, **kwargs)
        os.close(w)
        self.rfd = r
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        from .channel import ChannelError
        try:
            while True:
                data = os.read(self.rfd, 1 << 16)
                if not data:
                    break
                for frame in self.reader.feed(data):
                    self.frames.put(frame)
        except ChannelError as e:
            self.frames.put(({"event": "broken", "output": str(e)}, {}))
        except OSError:
            pass
        finally:
            self.frames.put(None)

    # -- watching ---------------------------------------------------------------------------------
    def _failure(self, phase: str, stopped: tuple | None) -> ChildResult:
        """What to say when the process ended (or was stopped) without an answer."""
        data = self._data()
        seconds = time.monotonic() - self.t0
        if stopped:
            why, limit = stopped
            if why == "deadline":
                return ChildResult("deadline", "stopped: the grading run reached its deadline (see the note)", data=data,
                                   seconds=seconds, programs=self.programs)
            if why == "setup":
                what = "compiling a kernel" if self.programs else "starting and loading its scene"
                msg = (f"stopped after {limit:g} s {what} (the setup limit; the reference needs a few seconds): a "
                       f"compiler stuck on the source (a macro that expands without end?), or an overloaded machine")
            else:
                msg = (f"timed out: still running after {limit:g} s (the reference needs a small fraction of that), "
                       f"killed. An endless loop? (a traversal that never empties its stack or never leaves a "
                       f"leaf, a loop counter that never advances)")
            return ChildResult("timeout", msg, data=data, seconds=seconds, programs=self.programs)
        rc = self.proc.returncode
        tail = _log_tail(self.log)
        if any(sign in tail for sign in MEMORY_SIGNS):
            return ChildResult("memory", self._memory_text(phase), data=data, seconds=seconds, programs=self.programs)
        if rc is not None and rc < 0:
            return ChildResult("crashed", f"crashed while {phase}: {signal_text(-rc)}", data=data, seconds=seconds,
                               programs=self.programs)
        return ChildResult("error", f"the test process ended while {phase} (exit status {rc}):\n{tail}", data=data,
                           seconds=seconds, programs=self.programs)

    def _memory_text(self, phase: str) -> str:
        return (f"ran out of memory while {phase}: a test process may use {self.limits.memory_mb} MB (grading.toml "
                f"memory_limit_mb; the reference needs a fraction of that). A macro that expands without end, or a "
                f"huge array?")

    def _data(self) -> dict:
        return {"peak_memory_mb": round(self.peak_kb / 1024, 1)} if self.peak_kb else {}

    def kill(self) -> None:
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        self.proc.wait()

    # Why long: one event loop over frames, limits and the process's state; the cases share its timers.
    def wait_for(self, events: tuple[str, ...], run_limit: float | None) -> tuple[dict, dict]:
        """The next frame whose event is one of ``events`` (``error`` frames raise), watching the
        limits: the setup limit until the process is ready, then ``run_limit`` from now. ``work``
        frames on the way are kept in :attr:`work`."""
        step_start = time.monotonic()
        run_start = time.monotonic() if self.ready else None
        while True:
            now = time.monotonic()
            self.peak_kb = max(self.peak_kb, _vm_kb(self.proc.pid).get("VmHWM", 0))
            stopped = None
            if now >= self.limits.deadline_at:
                stopped = ("deadline", 0.0)
            elif run_start is None and now - step_start > self.limits.setup:
                stopped = ("setup", self.limits.setup)
            elif run_start is not None and run_limit is not None and now - run_start > run_limit:
                stopped = ("run", run_limit)
            if stopped:
                self.kill()
                raise ProcessFailed(self._failure("running its kernel" if self.ready else "starting", stopped))
            try:
                item = self.frames.get(timeout=POLL_S)
            except queue.Empty:
                continue
            if item is None:                    # the channel closed: the process is ending
                try:
                    self.proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    self.kill()
                raise ProcessFailed(self._failure("running its kernel" if self.ready else
                                                  "starting (compiling or loading)", None))
            header, arrays = item
            event = header.get("event")
            if event == "broken":
                self.kill()
                raise ProcessFailed(ChildResult("error", f"the test process broke the grader's protocol: "
                                                         f"{header.get('output')}", data=self._data(),
                                                programs=self.programs))
            if not self.ready:
                # before its sandbox closes the process runs only the grader's code: its word counts
                if event == "compile":
                    step_start = time.monotonic()
                elif event == "programs":
                    self.programs = _clean_programs(header.get("programs"))
                elif event == "ready":
                    self.ready = True
                    run_start = time.monotonic()
            if event == "error":
                from .channel import clean_text
                status = header.get("status") if header.get("status") in ("compile_error", "error", "memory") \
                    else "error"
                self.kill()
                if status == "memory":
                    raise ProcessFailed(replace(self._failure("compiling a kernel", None), status="memory",
                                                output=self._memory_text("compiling a kernel")))
                raise ProcessFailed(ChildResult(status, clean_text(header.get("output"), 20000), data=self._data(),
                                                seconds=time.monotonic() - self.t0, programs=self.programs))
            if event == "work" and "work" in arrays:
                self.work = arrays["work"]
                if self.on_work is not None and self.on_work(self.work):
                    self.kill()
                    raise ProcessFailed(ChildResult("budget", "", data=self._data(), seconds=time.monotonic() - self.t0,
                                                    programs=self.programs))
            if event in events:
                return header, arrays

    def request(self, command: dict) -> None:
        self.proc.stdin.write((json.dumps(command) + "\n").encode())
        self.proc.stdin.flush()

    def pause(self) -> None:
        """Stop the process (and every thread of it) until :meth:`resume`: it cannot run while the
        reference kernel is timed. Returns once the kernel reports it stopped."""
        if self.paused:
            return
        os.killpg(self.proc.pid, signal.SIGSTOP)
        self.paused = True
        for _ in range(200):
            try:
                with open(f"/proc/{self.proc.pid}/stat") as f:
                    if f.read().rsplit(")", 1)[1].split()[0] in ("T", "t", "Z", "X"):
                        return
            except OSError:
                return
            time.sleep(0.001)

    def resume(self) -> None:
        if self.paused:
            try:
                os.killpg(self.proc.pid, signal.SIGCONT)
            except ProcessLookupError:
                pass
            self.paused = False

    def close(self) -> None:
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout=2)
        except subprocess.TimeoutExpired:
            self.kill()
        self.log.close()
        try:
            os.close(self.rfd)
        except OSError:
            pass


def _clean_programs(programs) -> list:
    out = []
    if isinstance(programs, list):
        for p in programs[:64]:
            if isinstance(p, dict) and isinstance(p.get("path"), str) and isinstance(p.get("defines"), dict):
                out.append({"path": p["path"], "defines": {str(k): str(v) for k, v in p["defines"].items()},
                            "kernels": []})
    return out


def _merge_launched(programs: list, launched) -> None:
    """The kernels a process says it launched, into the programs it compiled (for the note on
    unfinished functions only: said after its sandbox closed, so nothing else trusts it)."""
    import re
    if not isinstance(launched, dict):
        return
    for p in programs:
        names = launched.get(p["path"])
        if isinstance(names, list):
            p["kernels"] = [n for n in names[:32] if isinstance(n, str) and re.fullmatch(r"[A-Za-z_]\w{0,63}", n)]


def run_once(test_dir: Path, env: dict, limits: Limits, user=None, sandboxed: bool = True,
             on_ready=None, on_work=None) -> ChildResult:
    """Run a one-shot test process to its result (or its failure). ``on_ready()`` runs when its
    kernels are built and before it runs any submitted code (it waits for the grader's go);
    ``on_work(counts)`` when it sends its work count, and stops it (status "budget") if true."""
    proc = TestProcess(test_dir, env, limits, user, sandboxed=sandboxed)
    proc.on_work = on_work
    try:
        proc.wait_for(("ready",), None)
        if on_ready is not None:
            on_ready()
        proc.request({"op": "go"})
        header, arrays = proc.wait_for(("result",), limits.run)
        from .channel import clean_text
        info = header.get("info") if isinstance(header.get("info"), dict) else {}
        info = {str(k)[:64]: (clean_text(v, 500) if isinstance(v, str) else v) for k, v in list(info.items())[:64]}
        _merge_launched(proc.programs, header.get("launched"))
        info["work"] = proc.work
        return ChildResult("ok", arrays=arrays, info=info, data=proc._data(), seconds=time.monotonic() - proc.t0,
                           programs=proc.programs)
    except ProcessFailed as e:
        return replace(e.result, info={**e.result.info, "work": proc.work})
    finally:
        proc.close()
