"""What a grading test checks: one :class:`Kind` per ``kind`` in grading.toml.

A kind works in three stages, so that the grader can give each stage its own time limit:

* ``prepare`` runs in the grader (host only, no kernels): loads the scene, builds rays and the
  float64 reference answers (rtlab.reference). The result, a picklable dict, is the test's fixture.
* ``setup`` runs in the test's own process: uploads the scene and compiles the submission's kernel.
* ``run`` runs in the same process: launches the kernel and compares with the fixture.

Messages say what was expected and what came, with the first pixel or ray that differs.
"""
from __future__ import annotations

from .base import HARNESS_DIR, Kind, Outcome, on_setup_compile
from .hits import CameraRaysKind, CompileKind, IntersectLoopKind, RenderKind, TraceRaysKind, check_camera_rays
from .memory import FetchSceneKind, NvccKind, PlacementKind
from .speed import SpeedKind, speed_score
from .whitted import WhittedKind

KINDS: dict[str, Kind] = {k.name: k for k in (CompileKind(), CameraRaysKind(), TraceRaysKind(), RenderKind(),
                                              IntersectLoopKind(), WhittedKind(), SpeedKind(),
                                              FetchSceneKind(), PlacementKind(), NvccKind())}

__all__ = ["HARNESS_DIR", "KINDS", "Kind", "Outcome", "check_camera_rays", "on_setup_compile", "speed_score"]
