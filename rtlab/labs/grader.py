"""The autograder: a submission compiled in a tree of its own, each test in its own process.

    report = grade("00_primary", "path/to/submission")          # on PoCL by default
    report.score, report.max_score; write_report(report, "results.json")

How a grading run goes:
1. The submission's files (``[[files]]`` of grading.toml, found by path or by name anywhere in the
   submission) are checked by the rule of rtlab.labs.submission and laid over a copy of the kernels
   in which every solution of this step and the later ones is stubbed (rtlab.labs.trees). A file
   that is refused stands there as an ``#error``: the tests whose kernels include it score 0 and say
   why, the others run. A file not handed in is graded as the template's (stubbed) version.
2. The grader prepares each test's fixture on the host (scene, rays, float64 reference answers).
   Tests hidden until the due date draw their rays from a secret (the bundle's), or from a seed
   drawn for this run when there is none.
3. Each test runs in its own process (``python -m rtlab.labs.run_test``) with ``RTLAB_KERNEL_DIR`` on
   the submission's tree, a memory limit, a setup limit per kernel compile and its own run limit.
   A compile error (file and line of the student's source), a crash, a hang or a memory blow-up
   costs that test only. The whole run has a deadline: tests not done by then score 0.
4. Speed tests run last and alone, against the reference kernels (a copy in a folder of their own):
   pairs of launches in random order, every timed launch checked, scored by the median of the
   pairs' time ratios (rtlab.labs.checks.speed).
5. ``on_update(report)`` gets the report after every test (pending tests at 0), so results.json
   can be written as the run goes and a run killed from outside still reports.
"""
from __future__ import annotations

import os
import re
import secrets
import shutil
import tempfile
import time
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..errors import LabError
from .config import LabConfig, TestSpec, load_config
from .fixtures import prepare_fixture, spec_for_run
from .processes import ChildResult, Limits, default_jobs, run_child, shorten
from .submission import REFUSED_MARK
from .trees import StudentTree, build_student_tree, reference_tree


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
    """Functions the launched kernels of ``programs`` call (through the tree's headers and macros
    under each program's defines); None when the process recorded no program."""
    from .cpp import Preprocessor
    if not programs:
        return None
    used: set[str] = set()
    for p in programs:
        try:
            pp = Preprocessor([Path(tree) / "shared"], p["defines"]).run(p["path"])
        except (OSError, RecursionError):
            return None
        roots = p["kernels"] or pp.kernels()
        used |= pp.reachable(roots)
    return used


# --------------------------------------------------------------------------------------------------
# a grading run
# --------------------------------------------------------------------------------------------------
class GradingRun:
    """One grading of one submission: the trees, the tests' processes, the report as it grows."""

    def __init__(self, config: LabConfig, submission: Path, specs: list[TestSpec], backend: str, device,
                 jobs: int, time_scale: float, secret: str, deadline: float, progress, on_update):
        self.config, self.submission, self.specs = config, submission, specs
        self.backend, self.device, self.jobs, self.time_scale = backend, device, jobs, time_scale
        self.secret = secret
        self.progress, self.on_update = progress, on_update
        self.t_start = time.monotonic()
        self.deadline = deadline
        self.deadline_at = self.t_start + deadline
        self.work = Path(tempfile.mkdtemp(prefix="rtlab-grade-"))
        self.ref_tree: Path | None = None
        self.tree: StudentTree | None = None
        self.results: dict[str, TestResult] = {}
        self.notes: list[str] = []
        self.device_name = ""

    # -- report ---------------------------------------------------------------------------------
    def report(self) -> GradeReport:
        tests = []
        for s in self.specs:
            r = self.results.get(s.name)
            tests.append(r if r is not None else TestResult(
                s.name, 0.0, s.points, "not graded: the grading run stopped before this test finished (a time or "
                                       "memory limit of the grading machine?)", s.visibility, "pending"))
        return GradeReport(self.config.step, str(self.submission), self.backend, self.device_name, tests,
                           round(time.monotonic() - self.t_start, 2), list(self.notes))

    def _updated(self) -> None:
        if self.on_update:
            self.on_update(self.report())

    def _roots(self):
        roots = [(self.work / "submission", ""), (self.work, "")]
        if self.ref_tree is not None:
            roots.insert(0, (self.ref_tree.parent, "reference/"))
        return roots

    def finish(self, spec: TestSpec, r: ChildResult) -> TestResult:
        self.device_name = self.device_name or r.device
        status = {"ok": "passed" if r.fraction >= 1.0 else "failed", "deadline": "timeout"}.get(r.status, r.status)
        if r.status == "ok" and 0 < r.fraction < 1.0:
            status = "partial"
        output = _clean(r.output, self._roots())
        if r.status == "compile_error" and REFUSED_MARK in output:
            status = "refused"
            files = [rel for rel in self.tree.refused if rel in output]
            output = "not graded: a file this test compiles was refused:\n" + "\n".join(
                f"  {x}" for rel in (files or self.tree.refused) for x in self.tree.refused[rel])
        elif r.status == "compile_error":
            output = compile_message(output)
        output = shorten(output)
        if status != "passed" and status not in ("refused", "skipped", "pending"):
            note = self.stub_note(r.programs)
            if note:
                output += "\nnote: " + note
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

    # -- tests ----------------------------------------------------------------------------------
    def job_for(self, spec: TestSpec, fixture: Path) -> dict:
        return {"spec": spec.as_dict(), "step": self.config.step, "backend": self.backend, "device": self.device,
                "fixture": str(fixture)}

    def run_one(self, spec: TestSpec, fixture: Path) -> ChildResult:
        limits = Limits(self.config.setup_limit, spec.time_limit * self.time_scale, self.config.memory_limit_mb,
                        self.deadline_at)
        return run_child(self.work / "tests" / spec.name, self.job_for(spec, fixture), self.tree.root, limits)

    def fixture_or_error(self, spec: TestSpec, **extra):
        try:
            return prepare_fixture(spec_for_run(spec, self.secret), **extra), None
        except Exception as e:  # a grader problem, not the student's: say so
            return None, ChildResult("error", 0.0, f"grader error while preparing this test "
                                                   f"(not your code): {type(e).__name__}: {e}")

    def blocked(self, spec: TestSpec) -> list[str]:
        return [r for r in spec.requires if r in self.results and not self.results[r].passed]

    def past_deadline(self, spec: TestSpec) -> bool:
        if time.monotonic() < self.deadline_at:
            return False
        self.finish(spec, ChildResult("deadline", 0.0, f"not run: the grading run reached its deadline of "
                                                       f"{self.deadline:g} s (grading.toml deadline)"))
        return True

    def run(self) -> GradeReport:
        from .checks import KINDS
        self.tree = build_student_tree(self.config, self.submission, self.work / "submission")
        self.notes += self.tree.notes
        for rel, refusals in self.tree.refused.items():
            self.notes.append(f"{rel} was refused (its tests score 0): " + "; ".join(str(r) for r in refusals))
        self._updated()
        names = {s.name for s in self.specs}
        plain = [s for s in self.specs if not KINDS[s.kind].timed]
        timed = [s for s in self.specs if KINDS[s.kind].timed]
        pending = list(plain)
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
                        self.finish(spec, ChildResult("skipped", 0.0, f"not run: needs {', '.join(self.blocked(spec))} "
                                                                      f"to pass first"))
                        continue
                    fixture, err = self.fixture_or_error(spec)
                    if err:
                        self.finish(spec, err)
                        continue
                    running[pool.submit(self.run_one, spec, fixture)] = spec
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
                self.finish(spec, ChildResult("skipped", 0.0, f"not run: needs {', '.join(self.blocked(spec))} to "
                                                              f"pass first"))
                continue
            if self.ref_tree is None:
                self.ref_tree = reference_tree()
            fixture, err = self.fixture_or_error(spec, reference_tree=self.ref_tree)
            if err:
                self.finish(spec, err)
                continue
            self.finish(spec, self.run_one(spec, fixture))
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
                                           output=f"{old.output}\nbut the kernel of {who} does not build:\n"
                                                  f"{first.output}")
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
        if run.ref_tree is not None:
            shutil.rmtree(run.ref_tree.parent, ignore_errors=True)
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
                       [f"the grader could not run: {type(error).__name__}: {error}"])


