"""A grading test's fixture, made by the grader before its process starts (rtlab.course.grader): the
scene, the rays (a hidden test's drawn from the bundle's secret) and the float64 reference answers.
The process gets the inputs (pickled by the grader), never the answers; both are made once per
grading process and shared by the gradings in it."""
from __future__ import annotations

import hashlib
import json
import pickle
import threading
from dataclasses import replace
from pathlib import Path

from ..errors import LabError
from .config import TestSpec

_fixture_lock = threading.Lock()
_fixtures: dict = {}
FIXTURES_KEPT = 48            # the most recent tests' fixtures kept (a grading process grades many submissions)
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
        from ..device.device_scene import scene_kdtree
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


def prepare_test(spec: TestSpec):
    """A test's Prepared (rtlab.course.checks.base): the inputs for its process, with everything its
    scene's upload builds on the host (kd-tree, BVHs, per-triangle rows: the process builds nothing),
    and the expected answers the grader keeps. Made once per process for the same spec."""
    from ..device.device_scene import host_scene_data
    from .checks import KINDS
    key = json.dumps(spec.as_dict(), sort_keys=True, default=str)
    with _fixture_lock:
        if key in _fixtures:
            return _fixtures[key]
        scene = grading_scene(spec.scene, spec.size)
        kind = KINDS[spec.kind]
        prepared = kind.prepare(spec, scene)
        inputs = prepared.inputs
        if "scene" in inputs:
            inputs["host"] = host_scene_data(inputs["scene"], kind.variants(spec, inputs))
        _fixtures[key] = prepared
        while len(_fixtures) > FIXTURES_KEPT:
            _fixtures.pop(next(iter(_fixtures)))
        return prepared


def input_bytes(prepared) -> bytes:
    """The pickled inputs of a Prepared, made once."""
    data = getattr(prepared, "_pickled", None)
    if data is None:
        data = pickle.dumps(prepared.inputs, protocol=pickle.HIGHEST_PROTOCOL)
        prepared._pickled = data
    return data
