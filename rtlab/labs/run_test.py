"""One grading test in its own process: ``python -m rtlab.labs.run_test TEST_DIR``.

The grader starts this with ``RTLAB_KERNEL_DIR`` pointing at the submission's kernel tree and
watches it. TEST_DIR/spec.json says what to run. Before anything else the process caps its own
memory (RLIMIT_DATA: the heap and every private writable mapping, which is what a compiler stuck
on a preprocessor bomb grows; unlike RLIMIT_AS it does not count the address space PoCL, LLVM and
glibc reserve without using). Then it writes:

* TEST_DIR/setup: a counter, bumped before each kernel compile (the setup limit is per compile);
* TEST_DIR/programs.json: every program it compiles (source, defines) and the kernels it launches,
  for the grader's note on unfinished functions, even when the process dies later;
* TEST_DIR/phase: "run" once its scene is uploaded and its kernel compiled (the run phase has the
  test's own time limit);
* TEST_DIR/result.json at the end.

A crash, a hang, a memory blow-up or a kernel that does not compile ends here and costs this test only.
"""
from __future__ import annotations

import json
import pickle
import resource
import sys
import time
import traceback
from pathlib import Path


def _write(path: Path, obj) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(obj, default=float))
    tmp.replace(path)


FILE_LIMIT = 256 * 2 ** 20     # bytes a test process may write to one file (its log: a kernel printing without end)


def limit_resources(megabytes: int) -> None:
    limit = int(megabytes) * 2 ** 20
    resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_LIMIT, FILE_LIMIT))


class Recorder:
    """Wraps the backend's compile (and the programs' launch) to keep the setup heartbeat and
    programs.json current."""

    def __init__(self, test_dir: Path):
        self.dir = test_dir
        self.compiles = 0
        self.programs: list[dict] = []

    def tick(self) -> None:
        self.compiles += 1
        (self.dir / "setup").write_text(str(self.compiles))

    def save(self) -> None:
        _write(self.dir / "programs.json", self.programs)

    def wrap(self, backend) -> None:
        compile_ = backend.compile

        def compile(path, defines, options=()):
            self.tick()
            key = {"path": str(path), "defines": {k: str(v) for k, v in dict(defines).items()}}
            entry = next((e for e in self.programs if e["path"] == key["path"] and e["defines"] == key["defines"]),
                         None)
            if entry is None:
                entry = {**key, "kernels": []}
                self.programs.append(entry)
                self.save()
            program = compile_(path, defines, options)
            if not getattr(program, "_recorded", False):
                launch = program.launch

                def recorded_launch(name, *args, **kwargs):
                    if name not in entry["kernels"]:
                        entry["kernels"].append(name)
                        self.save()
                    return launch(name, *args, **kwargs)

                program.launch = recorded_launch
                program._recorded = True
            return program

        backend.compile = compile


def main(test_dir: str) -> int:
    d = Path(test_dir)
    job = json.loads((d / "spec.json").read_text())
    if job.get("memory_limit_mb"):
        limit_resources(job["memory_limit_mb"])
    from rtlab.backends import get_backend
    from rtlab.errors import KernelBuildError
    from rtlab.labs import checks
    from rtlab.labs.config import TestSpec
    spec = TestSpec.from_dict(job["spec"])
    kind = checks.KINDS[spec.kind]
    t0 = time.perf_counter()
    with open(job["fixture"], "rb") as f:
        fixture = pickle.load(f)
    fixture["step"] = job["step"]
    backend = get_backend(job["backend"], job.get("device"))
    recorder = Recorder(d)
    recorder.wrap(backend)
    checks.on_setup_compile(recorder.tick)
    try:
        state = kind.setup(spec, fixture, backend)
    except KernelBuildError as e:
        _write(d / "result.json", {"fraction": 0.0, "status": "compile_error", "output": str(e),
                                   "setup_s": time.perf_counter() - t0})
        return 0
    (d / "phase").write_text("run")
    t1 = time.perf_counter()
    try:
        outcome = kind.run(state)
    except KernelBuildError as e:   # a kernel the run compiles on first use
        _write(d / "result.json", {"fraction": 0.0, "status": "compile_error", "output": str(e),
                                   "setup_s": t1 - t0})
        return 0
    _write(d / "result.json", {"fraction": float(outcome.fraction), "status": "skipped" if outcome.skipped else "ok",
                               "output": outcome.output,
                               "data": outcome.data, "setup_s": t1 - t0, "run_s": time.perf_counter() - t1,
                               "device": backend.device_name})
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv[1]))
    except MemoryError:
        traceback.print_exc()
        print("rtlab: out of memory (MemoryError)", file=sys.stderr)
        sys.exit(4)
    except Exception:
        traceback.print_exc()
        sys.exit(3)
