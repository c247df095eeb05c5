"""One grading test in its own process: ``python -m rtlab.labs.run_test TEST_DIR``.

The grader starts this with ``RTLAB_KERNEL_DIR`` pointing at the submission's kernel tree and
watches it: TEST_DIR/spec.json says what to run; the process writes TEST_DIR/phase ("run") once
its scene is uploaded and its kernel compiled (the run phase has the test's own time limit) and
TEST_DIR/result.json at the end. A crash, a hang or a kernel that does not compile ends here, and
costs this test only.
"""
from __future__ import annotations

import json
import pickle
import sys
import time
import traceback
from pathlib import Path


def _write(path: Path, obj) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(obj, default=float))
    tmp.replace(path)


def main(test_dir: str) -> int:
    d = Path(test_dir)
    job = json.loads((d / "spec.json").read_text())
    from rtlab.backends import get_backend
    from rtlab.errors import KernelBuildError
    from rtlab.labs.checks import KINDS
    from rtlab.labs.config import TestSpec
    spec = TestSpec.from_dict(job["spec"])
    kind = KINDS[spec.kind]
    t0 = time.perf_counter()
    with open(job["fixture"], "rb") as f:
        fixture = pickle.load(f)
    fixture["step"] = job["step"]
    backend = get_backend(job["backend"], job.get("device"))
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
    except Exception:
        traceback.print_exc()
        sys.exit(3)
