"""One test of a grading run, from the grader's side: its folder (job, inputs, a scratch the
sandbox user owns), its process (rtlab.course.run_test, sandboxed), the check of what it hands back
against the answers the grader keeps, the work budget (counts against the reference worker's on the
same rays) and the speed test (the submission's process against the reference worker).
:class:`rtlab.course.grader.GradingRun` schedules these and keeps the report."""
from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import replace
from pathlib import Path

from .config import TestSpec
from .fixtures import input_bytes, prepare_test, spec_for_run
from .processes import ChildResult, Limits, ProcessFailed, TestProcess, run_once
from .workers import ReferenceWorker, process_env


def returned_hits(arrays: dict) -> int:
    """How many hits the test process returned (its ``tri`` output; 0 where a test returns none)."""
    import numpy as np
    tri = arrays.get("tri")
    return int((np.asarray(tri) >= 0).sum()) if tri is not None else 0


class TestExecution:
    """What GradingRun does for one test (GradingRun sets config, work, tree, user, sandboxed,
    builds, secret, deadline_at, time_scale, has_reference and the locks these read)."""

    # -- a test's folder and processes ------------------------------------------------------------
    def limits(self, spec: TestSpec) -> Limits:
        return Limits(self.config.setup_limit, spec.time_limit * self.time_scale, self.config.memory_limit_mb,
                      self.deadline_at)

    def job(self, spec: TestSpec, mode: str = "once", count_work: bool = False) -> dict:
        from .checks import HARNESS_DIR
        from .kernel_sources import reference_kernels
        from .lab_calls import lab_call_rules
        from .one_text import runtime_tested_macros
        run_spec = spec.as_dict()
        run_spec["params"] = {k: v for k, v in run_spec["params"].items() if k != "seed"}   # rays come made
        return {"spec": run_spec, "step": self.config.step, "backend": self.backend, "device": self.device,
                "mode": mode, "count_work": count_work, "memory_limit_mb": self.config.memory_limit_mb,
                "sandbox": self.sandboxed, "read": [str(self.tree.root), str(HARNESS_DIR)],
                "lab_calls": lab_call_rules(self.config.step), "structure": self.structure_rules(),
                "runtime_macros": runtime_tested_macros(reference_kernels())}

    def structure_rules(self) -> dict:
        """rtlab.course.structure's allowances for this step, for every function it grades: none is let
        off because its text looks like the stub (a decoy region in a comment did that); the one
        allowance a stub needs, the packet's stub writing no local memory, is read from the IR
        (rtlab.course.structure.straight_line)."""
        from .structure import structure_rules
        return structure_rules(self.config.step)

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
                    reference = self.reference_counts(spec, prepared)[0]
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
        own launch, so known even when that one crashes or never ends) and in the launch whose hits
        were checked, each against the reference kernel's on the same rays; and in that launch at
        least one triangle read through the lab's loaders for each hit it returned."""
        from .channel import ChannelError, expect_arrays
        from .checks import work_budget_problem, work_floor_problem
        try:
            work = expect_arrays({"work": r.info.get("work")} if r.info.get("work") is not None else {},
                                 {"work": ("int64", (2,))})["work"]
            run = expect_arrays(r.arrays, {"work_run": ("int64", (2,))})["work_run"] if r.status == "ok" else None
        except ChannelError as e:
            if r.status != "ok":
                return r
            return replace(r, status="error", fraction=0.0, output=f"{r.output}\nbut the work count is missing: {e}")
        try:
            reference, reference_run = self.reference_counts(spec, prepared)
        except ProcessFailed as e:
            return replace(r, status="error", fraction=0.0, output="grader error (not your code): the reference "
                                                                   f"kernel's count failed: {e.result.output}")
        data = {**r.data, "work": [int(x) for x in work], "reference_work": [int(x) for x in reference]}
        budget = float(spec.tolerance["work_budget"])
        problem = work_budget_problem(work, reference, budget)
        where = "its first rays"
        if not problem and run is not None:
            data.update(work_run=[int(x) for x in run], reference_work_run=[int(x) for x in reference_run])
            where = "the rays it was checked on"
            problem = (work_budget_problem(run, reference_run, budget)
                       or work_floor_problem(run, returned_hits(r.arrays)))
        if problem:
            head = {"ok": f"{r.output}\nbut on", "budget": "stopped: on"}.get(r.status, f"({r.output})\non")
            return replace(r, status="ok", fraction=0.0, data=data, output=f"{head} {where} it {problem}")
        if r.status == "budget":
            return replace(r, status="error", data=data, output="grader error (not your code): stopped for a work "
                                                                 "budget it keeps")
        if r.status != "ok":
            return replace(r, data=data)
        ratio = max(int(a) / max(int(b), 1) for a, b in zip(work, reference))
        return replace(r, data=data, output=f"{r.output}; reads {ratio:.2f}x the reference kernel's on its first rays")

    def reference_counts(self, spec: TestSpec, prepared):
        """(tree reads, triangle reads) of the reference kernel on the test's first rays, and on all of
        them: (first, all)."""
        if spec.name in self.ref_counts:
            return self.ref_counts[spec.name]
        worker = self.reference_worker()
        job = {**self.job(spec, count_work=True), "sandbox": False, "check_includes": False}
        header, arrays, _ = worker.produce(spec.name + ".work", job, input_bytes(prepared), {"counts_only": True}, 120.0)
        from .channel import expect_arrays
        counts = expect_arrays(arrays, {"work": ("int64", (2,)), "work_run": ("int64", (2,))})
        self.ref_counts[spec.name] = (counts["work"], counts["work_run"])
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

