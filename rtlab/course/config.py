"""Lab step configs: ``labs/<step>/grading.toml``.

A config names the files a submission provides (and the marked functions in each that the student
writes) and the tests: name, points, kind, scene and size, tolerances, time limit, visibility.
Kinds are the checks in :mod:`rtlab.course.checks`; each lists the keys it accepts.

    step = "00_primary"
    [[files]]
    path = "kernels/shared/rt_types.h"
    functions = ["camera_ray"]
    [[tests]]
    name = "camera_rays"; kind = "camera_rays"; points = 15; scene = "default"; size = [80, 48]
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import LabError
from ..paths import LABS_DIR

VISIBILITIES = ("visible", "after_due_date", "after_published", "hidden")
DEFAULT_TIME_LIMIT = 20.0     # seconds for a test's own work: kernel launches and checks
# Seconds for a test process to start and load its scene, and again for each kernel it compiles. The
# reference needs at most ~7 s for one (ropes, cold caches, the 2-core lab machine under load).
DEFAULT_SETUP_LIMIT = 30.0
DEFAULT_MEMORY_LIMIT_MB = 2048  # per test process (RLIMIT_DATA); the reference peaks near 320 MB
DEFAULT_DEADLINE = 480.0      # seconds for the whole grading run; tests not finished by then score 0
DEFAULT_GRADER_MEMORY_MB = 4096   # the grading process itself (RLIMIT_DATA, set by `rtlab grade`)


@dataclass(frozen=True)
class LabFile:
    path: str                   # relative to the project root, e.g. kernels/shared/rt_types.h
    functions: tuple[str, ...]  # marked functions the student writes in it


@dataclass(frozen=True)
class TestSpec:
    name: str
    kind: str
    points: float
    visibility: str = "visible"
    scene: str = "default"
    size: tuple[int, int] = (64, 64)
    tolerance: dict = field(default_factory=dict)
    params: dict = field(default_factory=dict)     # kind-specific: rays, seed, traversal, repeats...
    time_limit: float = DEFAULT_TIME_LIMIT
    requires: tuple[str, ...] = ()                 # tests that must pass first (speed needs correct output)
    description: str = ""

    def as_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "points": self.points, "visibility": self.visibility,
                "scene": self.scene, "size": list(self.size), "tolerance": dict(self.tolerance),
                "params": dict(self.params), "time_limit": self.time_limit, "requires": list(self.requires),
                "description": self.description}

    @classmethod
    def from_dict(cls, d: dict) -> "TestSpec":
        d = dict(d)
        d["size"] = tuple(d.get("size", (64, 64)))
        d["requires"] = tuple(d.get("requires", ()))
        return cls(**d)


@dataclass(frozen=True)
class LabConfig:
    step: str
    title: str
    paper: str
    files: tuple[LabFile, ...]
    tests: tuple[TestSpec, ...]
    setup_limit: float = DEFAULT_SETUP_LIMIT
    memory_limit_mb: int = DEFAULT_MEMORY_LIMIT_MB
    deadline: float = DEFAULT_DEADLINE
    grader_memory_mb: int = DEFAULT_GRADER_MEMORY_MB
    path: Path | None = None

    @property
    def max_score(self) -> float:
        return float(sum(t.points for t in self.tests))

    def test(self, name: str) -> TestSpec:
        for t in self.tests:
            if t.name == name:
                return t
        raise LabError(f"lab {self.step} has no test '{name}'; tests: {', '.join(t.name for t in self.tests)}")

    @property
    def folder(self) -> Path:
        return self.path.parent if self.path else LABS_DIR / self.step


def lab_names() -> list[str]:
    """Lab steps with a grading config, sorted."""
    return sorted(p.parent.name for p in LABS_DIR.glob("*/grading.toml"))


def lab_dir(step: str) -> Path:
    d = LABS_DIR / step
    if not (d / "grading.toml").is_file():
        have = ", ".join(lab_names()) or "none"
        raise LabError(f"no lab step '{step}' ({d / 'grading.toml'} not found); lab steps: {have}")
    return d


def _size(value, where: str) -> tuple[int, int]:
    if isinstance(value, int):
        return (value, value)
    if isinstance(value, list) and len(value) == 2 and all(isinstance(v, int) and v > 0 for v in value):
        return (value[0], value[1])
    raise LabError(f"{where}: size must be an integer or [width, height], got {value!r}")


TEST_KEYS = {"name", "kind", "points", "visibility", "scene", "size", "tolerance", "time_limit", "requires",
             "description"}


# Why long: every key of grading.toml checked with its own message, in the order the file is written.
def load_config(step_or_path: str | Path) -> LabConfig:
    """Read and check a lab's grading.toml (by step name or path)."""
    from .checks import KINDS
    path = Path(step_or_path)
    if not path.suffix:
        path = lab_dir(str(step_or_path)) / "grading.toml"
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise LabError(f"{path}: {e}") from None
    where = str(path)
    step = raw.get("step") or path.parent.name
    defaults = raw.get("defaults", {})
    files = []
    for f in raw.get("files", []):
        if "path" not in f:
            raise LabError(f"{where}: every [[files]] entry needs a path")
        files.append(LabFile(f["path"], tuple(f.get("functions", ()))))
    if not files:
        raise LabError(f"{where}: no [[files]]: which files does a submission provide?")
    tests, names = [], set()
    for i, t in enumerate(raw.get("tests", [])):
        tw = f"{where}: test {t.get('name', i)}"
        for key in ("name", "kind", "points"):
            if key not in t:
                raise LabError(f"{tw}: missing '{key}'")
        if t["name"] in names:
            raise LabError(f"{tw}: duplicate test name")
        names.add(t["name"])
        kind = KINDS.get(t["kind"])
        if kind is None:
            raise LabError(f"{tw}: unknown kind '{t['kind']}'; kinds: {', '.join(KINDS)}")
        params = {k: v for k, v in t.items() if k not in TEST_KEYS}
        unknown = sorted(set(params) - set(kind.params))
        if unknown:
            raise LabError(f"{tw}: kind '{t['kind']}' takes no {', '.join(unknown)}; "
                           f"it takes: {', '.join(sorted(kind.params)) or 'nothing extra'}")
        tol = {**kind.tolerance, **t.get("tolerance", {})}
        unknown_tol = sorted(set(tol) - set(kind.tolerance))
        if unknown_tol:
            raise LabError(f"{tw}: unknown tolerance {', '.join(unknown_tol)}; "
                           f"kind '{t['kind']}' has: {', '.join(kind.tolerance)}")
        vis = t.get("visibility", defaults.get("visibility", "visible"))
        if vis not in VISIBILITIES:
            raise LabError(f"{tw}: visibility must be one of {', '.join(VISIBILITIES)}, got '{vis}'")
        requires = tuple(t.get("requires", ()))
        for r in requires:
            if r not in {x.name for x in tests}:
                raise LabError(f"{tw}: requires '{r}', which is not an earlier test")
            if KINDS[next(x for x in tests if x.name == r).kind].timed:
                raise LabError(f"{tw}: requires '{r}', a timed test (those run last)")
        tests.append(TestSpec(
            name=t["name"], kind=t["kind"], points=float(t["points"]), visibility=vis,
            scene=t.get("scene", defaults.get("scene", "default")),
            size=_size(t.get("size", defaults.get("size", 64)), tw), tolerance=tol,
            params={**kind.params, **params},
            time_limit=float(t.get("time_limit", defaults.get("time_limit", DEFAULT_TIME_LIMIT))),
            requires=requires, description=t.get("description", "")))
    if not tests:
        raise LabError(f"{where}: no [[tests]]")
    limits = {}
    for key, default, kind in (("setup_limit", DEFAULT_SETUP_LIMIT, float), ("deadline", DEFAULT_DEADLINE, float),
                               ("memory_limit_mb", DEFAULT_MEMORY_LIMIT_MB, int),
                               ("grader_memory_mb", DEFAULT_GRADER_MEMORY_MB, int)):
        value = defaults.get(key, default)
        if not isinstance(value, (int, float)) or isinstance(value, bool) or value <= 0:
            raise LabError(f"{where}: [defaults] {key} must be a positive number, got {value!r}")
        limits[key] = kind(value)
    return LabConfig(step=step, title=raw.get("title", step), paper=raw.get("paper", ""), files=tuple(files),
                     tests=tuple(tests), path=path, **limits)
