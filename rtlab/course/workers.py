"""The grader's helper processes and shared files: the environment a test process gets, the
reference worker (the speed tests' and work budgets' reference, a process that never loads submitted
code) and the binaries a grading run compiles once and shares between its test processes."""
from __future__ import annotations

import json
import os
import shutil
import threading
import time
from pathlib import Path

from .processes import Limits, TestProcess


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


