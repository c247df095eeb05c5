"""A grading test's fixture, made on the host before its process starts (rtlab.labs.grader): the
scene, the rays (a hidden test's drawn from the bundle's secret) and the float64 reference answers,
pickled once per process and shared by the gradings in it."""
from __future__ import annotations

import hashlib
import json
import pickle
import shutil
import tempfile
import threading
from dataclasses import replace
from pathlib import Path

from ..errors import LabError
from .config import TestSpec

_fixture_lock = threading.Lock()
_fixture_dir: Path | None = None
_fixtures: dict = {}
_scenes: dict = {}
# Scenes made in code for grading, beside load_scene's presets: name -> "module:function(size)"
SCENE_FACTORIES = {"glass": "rtlab.scene.materials:glass_scene"}


def hidden_seed(secret: str, test: str) -> int:
    """The seed of a hidden test's rays: from the bundle's secret and the test's name."""
    return int.from_bytes(hashlib.sha256(f"{secret}\0{test}".encode()).digest()[:4], "little")


def spec_for_run(spec: TestSpec, secret: str) -> TestSpec:
    """A hidden test with its seed replaced by one drawn from ``secret`` (visible tests unchanged)."""
    if spec.visibility == "visible" or "seed" not in spec.params:
        return spec
    return replace(spec, params={**spec.params, "seed": hidden_seed(secret, spec.name)})


def read_secret(path) -> str:
    try:
        secret = Path(path).read_text().strip()
    except OSError as e:
        raise LabError(f"cannot read the grading secret {path}: {e.strerror}") from None
    if len(secret) < 16:
        raise LabError(f"the grading secret {path} is too short (write 32 random hex digits)")
    return secret


def grading_scene(name: str, size: tuple[int, int]):
    """A test's scene at its size, its kd-tree built; made once per process."""
    key = (name, size)
    if key not in _scenes:
        from ..device.scene import scene_kdtree
        from ..scene import load_scene
        if name in SCENE_FACTORIES:
            import importlib
            mod, fn = SCENE_FACTORIES[name].split(":")
            scene = getattr(importlib.import_module(mod), fn)(size[0])
        else:
            scene = load_scene(name, size=size[0])
        scene.camera = scene.camera.with_size(size[0], size[1])
        scene_kdtree(scene)        # build or load the kd-tree once here, not in every test process
        _scenes[key] = scene
    return _scenes[key]


def prepare_fixture(spec: TestSpec, **extra) -> Path:
    """The pickled fixture of a test (scene, rays, reference answers, and ``extra``); made once per
    process."""
    global _fixture_dir
    from .checks import KINDS
    key = json.dumps([spec.as_dict(), extra], sort_keys=True, default=str)
    with _fixture_lock:
        if key in _fixtures and _fixtures[key].is_file():
            return _fixtures[key]
        if _fixture_dir is None or not _fixture_dir.is_dir():
            _fixture_dir = Path(tempfile.mkdtemp(prefix="rtlab-fixtures-"))
            import atexit
            atexit.register(shutil.rmtree, _fixture_dir, True)
        scene = grading_scene(spec.scene, spec.size)
        # a kind may grade on its own version of the scene (returned as "scene")
        fixture = {"scene": scene, **KINDS[spec.kind].prepare(spec, scene), **{k: str(v) for k, v in extra.items()}}
        path = _fixture_dir / f"{len(_fixtures)}-{spec.name}.pkl"
        with open(path, "wb") as f:
            pickle.dump(fixture, f, protocol=pickle.HIGHEST_PROTOCOL)
        _fixtures[key] = path
        return path
