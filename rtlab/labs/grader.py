"""The autograder: a submission compiled in a tree of its own, each test in a sandboxed process.

    report = grade("00_primary", "path/to/submission")          # on PoCL by default
    report.score, report.max_score; write_report(report, "results.json")

How a grading run goes:
1. The submission's files (``[[files]]`` of grading.toml, found by path or by name anywhere in the
   submission) are checked by the rule of rtlab.labs.submission and laid over a copy of the kernels
   in which every solution of this step and the later ones is stubbed (rtlab.labs.trees). A file
   that is refused stands there as an ``#error``: the tests whose kernels include it score 0 and say
   why, the others run. A file not handed in is graded as the template's (stubbed) version.
2. The grader prepares each test on the host: the inputs (scene, rays; a hidden test's drawn from
   the bundle's secret) and the float64 reference's answers, which it keeps.
3. Each test runs in its own process (rtlab.labs.run_test), which holds nothing worth taking: its
   inputs, the submission's compile tree, a scratch folder. It runs as an unprivileged user when
   the grader is root, confined by Landlock and, once its kernels are built, by a system-call filter
   (rtlab.labs.sandbox), with limits on setup, run time and memory. It hands back raw outputs
   (rtlab.labs.channel); the grader checks them. A compile error, a refused include (the
   preprocessor's own list, rtlab.labs.deps), a crash, a hang or a forbidden system call costs that
   test only. The whole run has a deadline: tests not done by then score 0.
4. Tests that walk the scene with the student's traversal run an instrumented build and are held
   to a work budget: their reads of the tree and of triangles against the reference kernel's on
   the same inputs, counted by the reference worker (a process of the grader's that never loads
   submitted code).
5. Speed tests run last and alone: the submission's process against the reference worker, pairs of
   launches in random order, every timed launch checked (rtlab.labs.checks.speed).
6. ``on_update(report)`` gets the report at the start and after every test (pending tests at 0), so
   results.json exists from the first second and a run killed from outside still reports.
"""
from __future__ import annotations

import json
import os
import re
import secrets
import shutil
import tempfile
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..errors import LabError
from .config import LabConfig, TestSpec, load_config
from .fixtures import input_bytes, prepare_test, spec_for_run
from .processes import ChildResult, Limits, ProcessFailed, TestProcess, default_jobs, run_once, shorten
from .submission import REFUSED_MARK
from .trees import StudentTree, build_student_tree

MAX_NOTE = 2000          # characters of one note in the report
MAX_NOTES = 30


@dataclass
class TestResult:
    name: str
    score: float
    max_score: float
    output: str
    visibility: str
    status: str          # passed, partial, failed, compile_error, refused, crashed, timeout, memory, error, skipped, pending
    seconds: float = 0.0
    data: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return self.status == "passed"


@dataclass
class GradeReport:
    step: str
    submission: str
    backend: str
    device: str
    tests: list[TestResult]
    execution_time: float
    notes: list[str] = field(default_factory=list)

    @property
    def score(self) -> float:
        return float(sum(t.score for t in self.tests))

    @property
    def max_score(self) -> float:
        return float(sum(t.max_score for t in self.tests))

    def test(self, name: str) -> TestResult:
        return next(t for t in self.tests if t.name == name)


# --------------------------------------------------------------------------------------------------
# messages
# --------------------------------------------------------------------------------------------------
def _clean(text: str, roots: list[tuple[Path, str]]) -> str:
    """Paths of the grader's folders read as the student's: kernels/shared/rt_types.h:57:5."""
    from .checks import HARNESS_DIR
    for root, to in [*roots, (HARNESS_DIR, "rtlab/labs/harness/")]:
        text = text.replace(str(root) + os.sep, to)
    return text


BUILD_RE = re.compile(r"^kernel (?P<file>\S+) failed to compile \(defines: (?P<defines>[^)]*)\):\s*$")
PLACE_RE = re.compile(r"^\s*(?P<sev>error|warning|fatal error):\s*(?P<place>\S+:\d+:\d+):\s*(?P<msg>.*)$")


def compile_message(text: str) -> str:
    """A KernelBuildError as a student reads it: file:line:col: error: message first, then what was built."""
    lines = text.splitlines()
    head = BUILD_RE.match(lines[0]) if lines else None
    body = []
    for ln in lines[1:] if head else lines:
        m = PLACE_RE.match(ln)
        body.append(f"  {m['place']}: {m['sev']}: {m['msg']}" if m else ln)
    out = ["does not compile:", *body]
    if head:
        out.append(f"(while building {head['file']} with {head['defines'] or 'no defines'})")
    return "\n".join(out)


def used_functions(programs: list[dict], tree: Path) -> set[str] | None:
    """Functions the kernels of ``programs`` call (through the tree's headers and macros under each
    program's defines); None when the process recorded no program."""
    from .cpp import Preprocessor
    if not programs:
        return None
    used: set[str] = set()
    for p in programs:
        try:
            pp = Preprocessor([Path(tree) / "shared"], p["defines"]).run(p["path"])
        except (OSError, RecursionError, ValueError):
            return None
        roots = p["kernels"] or pp.kernels()
        used |= pp.reachable(roots)
    return used


def note_text(note: str) -> str:
    return note if len(note) <= MAX_NOTE else note[:MAX_NOTE - 60] + f" ... ({len(note) - MAX_NOTE + 60:,} more characters cut)"


# --------------------------------------------------------------------------------------------------
# the processes
# --------------------------------------------------------------------------------------------------
ENV_PASSED = ("PATH", "LANG", "LC_ALL", "PYTHONPATH", "PYOPENCL_CTX", "OCL_ICD_VENDORS", "OCL_ICD_FILENAMES",
              "CUDA_HOME", "CUDA_PATH", "CUDA_VISIBLE_DEVICES", "LD_LIBRARY_PATH", "RTLAB_DEVICE",
              "POCL_DEVICES", "POCL_MAX_PTHREAD_COUNT", "POCL_CPU_MAX_CU_COUNT", "NUMBA_DISABLE_JIT")


def process_env(test_dir: Path, kernel_root: Path | None, constants: Path, extra: dict | None = None) -> dict:
    """What a test process's environment holds: nothing of the grader's but the search paths and
    device choices above (no secret, no token a grading service sets)."""
    env = {k: os.environ[k] for k in ENV_PASSED if k in os.environ}
    env.update(HOME=str(test_dir), TMPDIR=str(test_dir), XDG_CACHE_HOME=str(test_dir / "cache"),
               PYTHONUNBUFFERED="1", PYTHONDONTWRITEBYTECODE="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               MKL_NUM_THREADS="1", NUMBA_CACHE_DIR=str(test_dir / "cache" / "numba"),
               RTLAB_CACHE=str(test_dir / "cache"), RTLAB_NO_CACHE="1", POCL_CACHE_DIR=str(test_dir / "pocl"),
               RTLAB_KERNEL_CONSTANTS=str(constants))
    if kernel_root is not None:
        env["RTLAB_KERNEL_DIR"] = str(kernel_root)
    env.update(extra or {})
    return env


class ReferenceWorker:
    """The grader's reference process (``run_test --reference``): the installation's kernels, never a
    submission's, for the speed tests' reference launches and the work budgets' reference counts.
    Its kernel cache persists between gradings ($RTLAB_CACHE/grader/pocl-reference)."""

    def __init__(self, work: Path, limits: Limits):
        from ..paths import user_cache_dir
        self.dir = work / "reference"
        self.dir.mkdir(mode=0o700, exist_ok=True)
        self.lock = threading.Lock()
        self.ready: set[str] = set()
        cache = user_cache_dir() / "grader" / "pocl-reference"
        cache.mkdir(parents=True, exist_ok=True)
        env = {k: v for k, v in os.environ.items() if k not in ("RTLAB_KERNEL_DIR", "RTLAB_KERNEL_CONSTANTS")}
        env.update(POCL_CACHE_DIR=str(cache), PYTHONUNBUFFERED="1")
        self.proc = TestProcess(self.dir, env, limits, argv=["--reference"], sandboxed=False)
        self.proc.ready = True          # no sandbox to close: every request has the run limit

    def _setup(self, name: str, job: dict, inputs: bytes, run_limit: float) -> None:
        if name in self.ready:
            return
        d = self.dir / name
        d.mkdir(exist_ok=True)
        (d / "job.json").write_text(json.dumps(job, default=str))
        (d / "inputs.pkl").write_bytes(inputs)
        self.proc.request({"op": "setup", "test": name, "dir": str(d)})
        self.proc.wait_for(("ready",), run_limit)
        self.ready.add(name)

    def produce(self, name: str, job: dict, inputs: bytes, request: dict, run_limit: float):
        """(header, arrays, wall ms) of the reference's launch for test ``name``."""
        with self.lock:
            self._setup(name, job, inputs, run_limit)
            t0 = time.perf_counter()
            self.proc.request({"op": "produce", "test": name, "request": request})
            header, arrays = self.proc.wait_for(("result",), run_limit)
            return header, arrays, (time.perf_counter() - t0) * 1e3

    def close(self) -> None:
        self.proc.close()


class SharedBuilds:
    """The kernel binaries of a grading run's test processes, compiled once a run: the grader copies
    what a process has just built (its PoCL cache) at the instant between its build and its first
    launch of submitted code (the process waits for the grader's go), so nothing the submission's
    code did can be in them, and seeds each new test process's cache with copies. Kept where the
    test processes cannot write (root's folder, or outside their Landlock domain); off where
    neither holds."""

    def __init__(self, root: Path, enabled: bool):
        self.root, self.enabled = root, enabled
        self.lock = threading.Lock()
        if enabled:
            root.mkdir(mode=0o700, exist_ok=True)

    def take(self, cache: Path) -> None:
        if not self.enabled or not cache.is_dir():
            return
        with self.lock:
            for program in cache.glob("*/*"):
                target = self.root / program.relative_to(cache)
                if program.is_dir() and not program.is_symlink() and not target.exists():
                    shutil.copytree(program, target, symlinks=False,
                                    ignore=lambda d, names: [n for n in names if (Path(d) / n).is_symlink()])

    def seed(self, cache: Path, user) -> None:
        if not self.enabled or not any(self.root.iterdir()):
            return
        with self.lock:
            shutil.copytree(self.root, cache, dirs_exist_ok=True)
        if user is not None:
            for p in [cache, *cache.rglob("*")]:
                os.chown(p, user.uid, user.gid, follow_symlinks=False)


# --------------------------------------------------------------------------------------------------
# a grading run
# --------------------------------------------------------------------------------------------------
class GradingRun:
    """One grading of one submission: the trees, the tests' processes, the report as it grows."""

    def __init__(self, config: LabConfig, submission: Path, specs: list[TestSpec], backend: str, device,
                 jobs: int, time_scale: float, secret: str, deadline: float, progress, on_update):
        from . import sandbox
        self.config, self.submission, self.specs = config, submission, specs
        self.backend, self.device, self.jobs, self.time_scale = backend, device, jobs, time_scale
        self.secret = secret
        self.progress, self.on_update = progress, on_update
        self.t_start = time.monotonic()
        self.deadline = deadline
        self.deadline_at = self.t_start + deadline
        self.work = Path(tempfile.mkdtemp(prefix="rtlab-grade-"))
        os.chmod(self.work, 0o711)             # others may pass through to what is theirs, never list it
        from ..kernel_constants import kernel_constants
        self.constants = self.work / "constants.json"
        self.constants.write_text(json.dumps(kernel_constants()))
        os.chmod(self.constants, 0o644)
        self.sandboxed = sandbox.sandbox_enabled()
        self.user = sandbox.sandbox_user({"RTLAB_KERNEL_CONSTANTS": str(self.constants)}) if self.sandboxed else None
        if self.sandboxed:
            why = sandbox.problem(self.user)
            if why:
                shutil.rmtree(self.work, ignore_errors=True)
                raise LabError(f"the grader cannot sandbox submitted code here: {why}")
            sandbox.make_undumpable()
        self.builds = SharedBuilds(self.work / "pocl-shared", enabled=self.user is not None or sandbox.landlock_abi() > 0)
        self.tree: StudentTree | None = None
        self.results: dict[str, TestResult] = {}
        self.notes: list[str] = []
        self.device_name = ""
        self.reference: ReferenceWorker | None = None
        self.reference_lock = threading.Lock()
        self.ref_counts: dict = {}
        self.first_builds: dict[str, threading.Event] = {}     # a test's program signature -> its binaries taken
        from .trees import has_reference
        self.has_reference = has_reference(config.step)

    # -- report ---------------------------------------------------------------------------------
    def report(self) -> GradeReport:
        tests = []
        for s in self.specs:
            r = self.results.get(s.name)
            tests.append(r if r is not None else TestResult(
                s.name, 0.0, s.points, "not graded: the grading run stopped before this test finished (a time or "
                                       "memory limit of the grading machine?)", s.visibility, "pending"))
        notes = [note_text(n) for n in self.notes[:MAX_NOTES]]
        if len(self.notes) > MAX_NOTES:
            notes.append(f"... and {len(self.notes) - MAX_NOTES} more notes")
        return GradeReport(self.config.step, str(self.submission), self.backend, self.device_name, tests,
                           round(time.monotonic() - self.t_start, 2), notes)

    def _updated(self) -> None:
        if self.on_update:
            self.on_update(self.report())

    def _roots(self):
        from ..paths import REFERENCE_KERNEL_DIR
        return [(REFERENCE_KERNEL_DIR.parent, "reference/"), (self.work / "submission", ""), (self.work, "")]

    def finish(self, spec: TestSpec, r: ChildResult) -> TestResult:
        self.device_name = self.device_name or str(r.info.get("device", ""))[:200]
        status = {"ok": "passed" if r.fraction >= 1.0 else "failed", "deadline": "timeout"}.get(r.status, r.status)
        if r.status == "ok" and 0 < r.fraction < 1.0:
            status = "partial"
        output = _clean(r.output, self._roots())
        if r.status == "compile_error" and REFUSED_MARK in output:
            status = "refused"
            files = [rel for rel in self.tree.refused if rel in output]
            if files or self.tree.refused:
                output = "not graded: a file this test compiles was refused:\n" + "\n".join(
                    f"  {x}" for rel in (files or self.tree.refused) for x in self.tree.refused[rel][:20])
            else:
                output = "not graded: " + output[output.index(REFUSED_MARK) + len(REFUSED_MARK):]
        elif r.status == "compile_error":
            output = compile_message(output)
        output = shorten(output)
        if status not in ("passed", "refused", "skipped", "pending"):
            note = self.stub_note(r.programs)
            if note:
                output = shorten(output + "\nnote: " + note)
        data = dict(r.data)
        if r.programs:
            data["programs"] = [{"source": _clean(p["path"], self._roots()), "kernels": p["kernels"]}
                                for p in r.programs]
        res = TestResult(spec.name, round(spec.points * r.fraction, 3), spec.points, output,
                         spec.visibility, status, round(r.seconds, 2), data)
        self.results[spec.name] = res
        if self.progress:
            self.progress(res)
        self._updated()
        return res

    def stub_note(self, programs: list[dict]) -> str:
        """The unfinished functions of the lab this test uses (all of them when that is unknown)."""
        stubs = {f: rel for rel, fs in self.tree.stubs.items() for f in fs}
        if not stubs:
            return ""
        used = used_functions(programs, self.tree.root)
        names = [f for f in stubs if used is None or f in used]
        if not names:
            return ""
        by_file: dict[str, list[str]] = {}
        for f in names:
            by_file.setdefault(stubs[f], []).append(f)
        return "; ".join(f"{', '.join(fs)} in {rel} still hold{'s' if len(fs) == 1 else ''} the template's stub (TODO)"
                         for rel, fs in by_file.items())

    # -- a test's folder and processes ------------------------------------------------------------
    def limits(self, spec: TestSpec) -> Limits:
        return Limits(self.config.setup_limit, spec.time_limit * self.time_scale, self.config.memory_limit_mb,
                      self.deadline_at)

    def job(self, spec: TestSpec, mode: str = "once", count_work: bool = False) -> dict:
        from .checks import HARNESS_DIR
        run_spec = spec.as_dict()
        run_spec["params"] = {k: v for k, v in run_spec["params"].items() if k != "seed"}   # rays come made
        return {"spec": run_spec, "step": self.config.step, "backend": self.backend, "device": self.device,
                "mode": mode, "count_work": count_work, "memory_limit_mb": self.config.memory_limit_mb,
                "sandbox": self.sandboxed, "read": [str(self.tree.root), str(HARNESS_DIR)]}

    def test_dir(self, spec: TestSpec, prepared, job: dict, suffix: str = "") -> Path:
        from . import sandbox
        d = self.work / "tests" / (spec.name + suffix)
        (self.work / "tests").mkdir(exist_ok=True)
        os.chmod(self.work / "tests", 0o711)
        sandbox.give_to(d, self.user)
        self.builds.seed(d / "pocl", self.user)
        for name, data in (("job.json", json.dumps(job, default=str).encode()), ("inputs.pkl", input_bytes(prepared))):
            (d / name).write_bytes(data)
            if self.user:
                os.chmod(d / name, 0o644)
        return d

    def start_env(self, test_dir: Path) -> dict:
        return process_env(test_dir, self.tree.root, self.constants)

    def reference_worker(self) -> ReferenceWorker:
        with self.reference_lock:
            if self.reference is None:
                self.reference = ReferenceWorker(self.work, Limits(self.config.setup_limit * 4, 120.0,
                                                                   self.config.memory_limit_mb, self.deadline_at))
            return self.reference

    # -- tests ----------------------------------------------------------------------------------
    def prepared_or_error(self, spec: TestSpec):
        try:
            prepared = prepare_test(spec_for_run(spec, self.secret))
        except Exception as e:  # a grader problem, not the student's: say so
            return None, ChildResult("error", f"grader error while preparing this test (not your code): "
                                              f"{type(e).__name__}: {e}")
        return prepared, None

    def expected(self, prepared) -> dict:
        """What a check compares with: the prepared answers, and what this grading knows of the
        submission (its step, the functions it left as stubs)."""
        return {**prepared.expected, "step": self.config.step,
                "stubs": sorted({f for fs in self.tree.stubs.values() for f in fs})}

    def run_one(self, spec: TestSpec, prepared) -> ChildResult:
        """A plain test: its process, then the grader's check of what came back; a process whose
        work count breaks the budget is stopped there."""
        from .checks import KINDS, work_budget_problem
        kind = KINDS[spec.kind]
        count = kind.counts_work(spec) and self.has_reference
        job = self.job(spec, count_work=count)
        d = self.test_dir(spec, prepared, job)
        # a test that builds what a running test is building waits for that one's binaries
        signature = json.dumps([spec.kind, spec.scene, list(spec.size), count,
                                {k: v for k, v in spec.params.items() if k not in ("seed", "rays", "count")}],
                               sort_keys=True, default=str)
        with self.reference_lock:
            built = self.first_builds.get(signature)
            mine = built is None
            if mine:
                built = self.first_builds[signature] = threading.Event()
        if not mine:
            built.wait(timeout=self.config.setup_limit * 2)
        over = None
        if count:
            def over(work):
                try:
                    reference = self.reference_counts(spec, prepared)
                except ProcessFailed:
                    return False          # check_budget reports it
                return work_budget_problem(work, reference, float(spec.tolerance["work_budget"])) is not None
        def ready():
            self.builds.take(d / "pocl")
            built.set()

        try:
            r = run_once(d, self.start_env(d), self.limits(spec), self.user, self.sandboxed, on_ready=ready,
                         on_work=over)
        finally:
            built.set()
        if r.status == "ok":
            r = self.check(spec, kind, prepared, r)
        if count and r.status not in ("compile_error", "error", "skipped", "deadline"):
            r = self.check_budget(spec, prepared, r)
        elif kind.counts_work(spec) and not self.has_reference and r.status == "ok":
            r = replace(r, output=f"{r.output}\n(work budget not checked: this installation has no reference "
                                  f"kernels, a student release)")
        return r

    def check(self, spec, kind, prepared, r: ChildResult) -> ChildResult:
        from .channel import ChannelError, expect_arrays
        from .checks import Produced
        try:
            arrays = expect_arrays(r.arrays, kind.outputs(spec, prepared.inputs))
            extra = {k: v for k, v in r.arrays.items() if k not in arrays}
            outcome = kind.check(spec, prepared.inputs, self.expected(prepared), Produced({**extra, **arrays}, r.info))
        except ChannelError as e:
            return replace(r, status="error", output=f"the test process's output is not what the test asked for: {e}")
        status = "skipped" if outcome.skipped else "ok"
        return replace(r, status=status, fraction=float(min(max(outcome.fraction, 0.0), 1.0)), output=outcome.output,
                       data={**r.data, **outcome.data})

    def check_budget(self, spec: TestSpec, prepared, r: ChildResult) -> ChildResult:
        """The work budget: the reads the process counted on the test's first rays (sent before its
        own launch, so known even when that one crashes or never ends) against the reference
        kernel's on the same rays."""
        from .channel import ChannelError, expect_arrays
        from .checks import work_budget_problem
        try:
            work = expect_arrays({"work": r.info.get("work")} if r.info.get("work") is not None else {},
                                 {"work": ("int64", (2,))})["work"]
        except ChannelError as e:
            if r.status != "ok":
                return r
            return replace(r, status="error", fraction=0.0, output=f"{r.output}\nbut the work count is missing: {e}")
        try:
            reference = self.reference_counts(spec, prepared)
        except ProcessFailed as e:
            return replace(r, status="error", fraction=0.0, output="grader error (not your code): the reference "
                                                                   f"kernel's count failed: {e.result.output}")
        data = {**r.data, "work": [int(x) for x in work], "reference_work": [int(x) for x in reference]}
        problem = work_budget_problem(work, reference, float(spec.tolerance["work_budget"]))
        if problem:
            head = {"ok": f"{r.output}\nbut on", "budget": "stopped: on"}.get(r.status, f"({r.output})\non")
            return replace(r, status="ok", fraction=0.0, data=data, output=f"{head} its first rays it {problem}")
        if r.status == "budget":
            return replace(r, status="error", data=data, output="grader error (not your code): stopped for a work "
                                                                 "budget it keeps")
        if r.status != "ok":
            return replace(r, data=data)
        ratio = max(int(a) / max(int(b), 1) for a, b in zip(work, reference))
        return replace(r, data=data, output=f"{r.output}; reads {ratio:.2f}x the reference kernel's on its first rays")

    def reference_counts(self, spec: TestSpec, prepared):
        """(tree reads, triangle reads) of the reference kernel on the test's first rays."""
        if spec.name in self.ref_counts:
            return self.ref_counts[spec.name]
        worker = self.reference_worker()
        job = {**self.job(spec, count_work=True), "sandbox": False, "check_includes": False}
        header, arrays, _ = worker.produce(spec.name + ".work", job, input_bytes(prepared), {"probe_only": True}, 120.0)
        from .channel import expect_arrays
        self.ref_counts[spec.name] = expect_arrays(arrays, {"work": ("int64", (2,))})["work"]
        return self.ref_counts[spec.name]

    def run_speed(self, spec: TestSpec, prepared) -> ChildResult:
        from .channel import ChannelError, expect_arrays
        from .checks import KINDS, Produced, time_against_reference
        kind = KINDS[spec.kind]
        job = self.job(spec, mode="serve")
        d = self.test_dir(spec, prepared, job)
        limits = self.limits(spec)
        worker = self.reference_worker()
        ref_job = {**self.job(spec), "sandbox": False, "check_includes": False}
        t0 = time.monotonic()
        proc = TestProcess(d, self.start_env(d), limits, self.user, sandboxed=self.sandboxed)
        run_limit = max(5.0, limits.run / 4)

        class Side:
            def __init__(self, produce, pause=lambda: None, resume=lambda: None):
                self.produce, self.pause, self.resume = produce, pause, resume

        def valid(header, arrays, camera):
            out = expect_arrays(arrays, kind.outputs(spec, prepared.inputs, camera))
            extra = {k: v for k, v in arrays.items() if k not in out}
            info = header.get("info") if isinstance(header.get("info"), dict) else {}
            ms = info.get("kernel_ms")
            info = {"kernel_ms": float(ms) if isinstance(ms, (int, float)) and not isinstance(ms, bool) else float("nan")}
            return Produced({**extra, **out}, info)

        def submission_produce(request, camera):
            t = time.perf_counter()
            proc.request({"op": "produce", "request": request})
            header, arrays = proc.wait_for(("result",), run_limit)
            return valid(header, arrays, camera), (time.perf_counter() - t) * 1e3

        def reference_produce(request, camera):
            header, arrays, wall = worker.produce(spec.name, ref_job, input_bytes(prepared), request, 120.0)
            return valid(header, arrays, camera), wall

        try:
            proc.wait_for(("ready",), None)
            self.builds.take(d / "pocl")
            worker.produce(spec.name, ref_job, input_bytes(prepared), {}, 120.0)      # compile and warm up
            outcome = time_against_reference(spec, prepared.inputs, self.expected(prepared),
                                             Side(submission_produce, proc.pause, proc.resume), Side(reference_produce))
            return ChildResult("ok", outcome.output, data={**proc._data(), **outcome.data}, seconds=time.monotonic() - t0,
                               programs=proc.programs, fraction=outcome.fraction)
        except ProcessFailed as e:
            return replace(e.result, programs=e.result.programs or proc.programs)
        except ChannelError as e:
            return ChildResult("error", f"the test process's output is not what the test asked for: {e}",
                               seconds=time.monotonic() - t0, programs=proc.programs)
        finally:
            proc.resume()
            proc.close()

    def blocked(self, spec: TestSpec) -> list[str]:
        return [r for r in spec.requires if r in self.results and not self.results[r].passed]

    def past_deadline(self, spec: TestSpec) -> bool:
        if time.monotonic() < self.deadline_at:
            return False
        self.finish(spec, ChildResult("deadline", f"not run: the grading run reached its deadline of "
                                                  f"{self.deadline:g} s (grading.toml deadline)"))
        return True

    def run(self) -> GradeReport:
        from . import sandbox
        from .checks import KINDS
        self.notes.append("sandbox: " + (sandbox.describe(self.user) if self.sandboxed else
                                         f"OFF (${sandbox.SANDBOX_OFF_ENV}): submitted code ran unconfined"))
        self._updated()
        self.tree = build_student_tree(self.config, self.submission, self.work / "submission",
                                       deadline_at=self.deadline_at)
        self.notes += self.tree.notes
        for rel, refusals in self.tree.refused.items():
            shown = "; ".join(str(r) for r in refusals[:10])
            more = f"; and {len(refusals) - 10} more" if len(refusals) > 10 else ""
            self.notes.append(f"{rel} was refused (its tests score 0): {shown}{more}")
        self._updated()
        names = {s.name for s in self.specs}
        plain = [s for s in self.specs if not KINDS[s.kind].timed]
        timed = [s for s in self.specs if KINDS[s.kind].timed]
        pending = list(plain)
        try:
            with ThreadPoolExecutor(max_workers=self.jobs) as pool:
                running = {}
                while pending or running:
                    for spec in list(pending):
                        if any(r not in self.results for r in spec.requires if r in names):
                            continue
                        pending.remove(spec)
                        if self.past_deadline(spec):
                            continue
                        if self.blocked(spec):
                            self.finish(spec, ChildResult("skipped", f"not run: needs {', '.join(self.blocked(spec))} "
                                                                     f"to pass first"))
                            continue
                        prepared, err = self.prepared_or_error(spec)
                        if err:
                            self.finish(spec, err)
                            continue
                        running[pool.submit(self.run_one, spec, prepared)] = spec
                    if not running:
                        if pending:   # load_config lets a test require only earlier, untimed tests
                            raise LabError(f"tests {', '.join(s.name for s in pending)} wait on tests that never run")
                        continue
                    done, _ = wait(running, return_when=FIRST_COMPLETED)
                    for fut in done:
                        self.finish(running.pop(fut), fut.result())
            for spec in timed:
                if self.past_deadline(spec):
                    continue
                if self.blocked(spec):
                    self.finish(spec, ChildResult("skipped", f"not run: needs {', '.join(self.blocked(spec))} to "
                                                             f"pass first"))
                    continue
                prepared, err = self.prepared_or_error(spec)
                if err:
                    self.finish(spec, err)
                    continue
                self.finish(spec, self.run_speed(spec, prepared))
        finally:
            if self.reference is not None:
                self.reference.close()
        self.compile_everything()
        return self.report()

    def compile_everything(self) -> None:
        """The compile test stands for every kernel the run built: a test that hit a compile error
        or a refused file fails it too (its own kernel is only one variant)."""
        from .checks import KINDS
        compile_specs = [s for s in self.specs if s.kind == "compile" and self.results.get(s.name)
                         and self.results[s.name].passed]
        broken = [(s, self.results[s.name]) for s in self.specs if s.name in self.results
                  and self.results[s.name].status in ("compile_error", "refused") and KINDS[s.kind].name != "compile"]
        if not compile_specs or not broken:
            return
        spec, first = broken[0]
        who = f"test {spec.name}" if spec.visibility == "visible" else "a test hidden until the due date"
        for c in compile_specs:
            old = self.results[c.name]
            self.results[c.name] = replace(old, score=0.0, status=first.status,
                                           output=shorten(f"{old.output}\nbut the kernel of {who} does not build:\n"
                                                          f"{first.output}"))
        self._updated()


def grade(step: str, submission, backend: str = "opencl", device: str | None = None,
          tests: list[str] | None = None, jobs: int | None = None, time_scale: float = 1.0,
          keep: bool = False, progress=None, config: LabConfig | None = None, secret: str | None = None,
          deadline: float | None = None, on_update=None) -> GradeReport:
    """Grade ``submission`` (a folder) on lab ``step``; ``tests`` limits to some tests by name;
    ``time_scale`` multiplies every test's run limit; ``secret`` seeds the hidden tests (a fresh
    seed when None); ``deadline`` overrides the config's. ``progress(TestResult)`` is called as each
    test ends, ``on_update(GradeReport)`` with the whole report so far."""
    config = config or load_config(step)
    submission = Path(submission)
    if not submission.is_dir():
        raise LabError(f"submission folder {submission} does not exist")
    if tests:
        unknown = sorted(set(tests) - {t.name for t in config.tests})
        if unknown:
            raise LabError(f"lab {config.step} has no test {', '.join(unknown)}")
    specs = [t for t in config.tests if tests is None or t.name in tests]
    run = GradingRun(config, submission, specs, backend, device, jobs or default_jobs(config.memory_limit_mb),
                     time_scale, secret or secrets.token_hex(16), deadline or config.deadline, progress, on_update)
    try:
        report = run.run()
    finally:
        if not keep:
            shutil.rmtree(run.work, ignore_errors=True)
    if keep:
        report.notes.append(f"work directory kept: {run.work}")
    return report


def grading_failure_report(step: str, submission, backend: str, error: Exception) -> GradeReport:
    """What the grader writes when it cannot grade at all (a broken config, a missing device): every
    test at zero with the reason, so results.json always exists."""
    try:
        config = load_config(step)
        tests = [TestResult(t.name, 0.0, t.points, f"not graded: {error}", t.visibility, "error")
                 for t in config.tests]
    except Exception:
        tests = []
    return GradeReport(step, str(submission), backend, "", tests, 0.0,
                       [f"the grader could not run: {type(error).__name__}: {note_text(str(error))}"])
