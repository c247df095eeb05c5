"""The autograder: a submission compiled in a tree of its own, each test in a sandboxed process.

    report = grade("00_primary", "path/to/submission")          # on PoCL by default
    report.score, report.max_score; write_report(report, "results.json")

How a grading run goes:
1. The submission's files (``[[files]]`` of grading.toml, found by path or by name anywhere in the
   submission) are checked by the rule of rtlab.course.submission and laid over a copy of the kernels
   in which every solution of this step and the later ones is stubbed (rtlab.course.kernel_sources). A file
   that is refused stands there as an ``#error``: the tests whose kernels include it score 0 and say
   why, the others run. A file not handed in is graded as the template's (stubbed) version.
2. The grader prepares each test on the host: the inputs (scene, rays; a hidden test's drawn from
   the bundle's secret) and the float64 reference's answers, which it keeps.
3. Each test runs in its own process (rtlab.course.run_test), which holds nothing worth taking: its
   inputs, the submission's compile tree, a scratch folder. It runs as an unprivileged user when
   the grader is root, confined by Landlock and, once its kernels are built, by a system-call filter
   (rtlab.course.sandbox), with limits on setup, run time and memory. It hands back raw outputs
   (rtlab.course.channel); the grader checks them. A compile error, a refused include (the
   preprocessor's own list, rtlab.course.deps), a crash, a hang or a forbidden system call costs that
   test only. The whole run has a deadline: tests not done by then score 0.
4. Tests that walk the scene with the student's traversal run an instrumented build and are held
   to a work budget: their reads of the tree and of triangles against the reference kernel's on
   the same inputs, counted by the reference worker (a process of the grader's that never loads
   submitted code).
5. Speed tests run last and alone: the submission's process against the reference worker, pairs of
   launches in random order, every timed launch checked (rtlab.course.checks.speed).
6. ``on_update(report)`` gets the report at the start and after every test (pending tests at 0), so
   results.json exists from the first second and a run killed from outside still reports.
"""
from __future__ import annotations

import json
import os
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
from .execution import TestExecution
from .messages import _clean, compile_message, note_text, used_functions
from .processes import ChildResult, default_jobs, shorten
from .submission import REFUSED_MARK
from .kernel_sources import StudentTree, build_student_tree
from .workers import ReferenceWorker, SharedBuilds

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
# a grading run
# --------------------------------------------------------------------------------------------------
class GradingRun(TestExecution):
    """One grading of one submission: the trees, the tests' processes, the report as it grows."""

    # Why many parameters: rtlab grade's options, kept for the run.
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
        from .kernel_sources import has_reference
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
        return "; ".join(f"{', '.join(fs)} in {rel} still hold{'s' if len(fs) == 1 else ''} the template's stub"
                         for rel, fs in by_file.items())

    # -- tests ----------------------------------------------------------------------------------
    def blocked(self, spec: TestSpec) -> list[str]:
        return [r for r in spec.requires if r in self.results and not self.results[r].passed]

    def past_deadline(self, spec: TestSpec) -> bool:
        if time.monotonic() < self.deadline_at:
            return False
        self.finish(spec, ChildResult("deadline", f"not run: the grading run reached its deadline of "
                                                  f"{self.deadline:g} s (grading.toml deadline)"))
        return True

    # Why long: the grading sequence (note, build, prepare, run, check, report) in the order it happens.
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


# Why many parameters: rtlab grade's options, handed to Grader.
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
        raise LabError(f"submission {submission} is not a folder: hand in the folder that holds the kernel files"
                       if submission.exists() else f"submission folder {submission} does not exist")
    if tests is not None and not tests:
        raise LabError(f"no test named: choose from {', '.join(t.name for t in config.tests)}")
    if deadline is not None and not deadline > 0:
        raise LabError(f"the deadline must be a positive number of seconds, got {deadline:g}")
    if tests:
        unknown = sorted(set(tests) - {t.name for t in config.tests})
        if unknown:
            raise LabError(f"lab {config.step} has no test {', '.join(unknown)}")
    specs = [t for t in config.tests if tests is None or t.name in tests]
    run = GradingRun(config, submission, specs, backend, device, jobs or default_jobs(config.memory_limit_mb),
                     time_scale, secret or secrets.token_hex(16), config.deadline if deadline is None else deadline,
                     progress, on_update)
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
