"""What a grading test checks: one :class:`Kind` per ``kind`` in grading.toml.

A kind works in four stages; the grader keeps what a submission must not see (the reference's
answers, the secret, the reference kernels) out of the process that runs it:

* ``prepare`` runs in the grader (host only, no kernels): loads the scene, builds rays and the
  float64 reference answers (rtlab.reference): the test's ``inputs`` (for the test process) and
  ``expected`` (kept by the grader).
* ``setup`` runs in the test's own process before any submitted code runs: uploads the scene and
  compiles the kernels (then the process closes its sandbox, rtlab.course.sandbox).
* ``produce`` runs in the same process: launches the kernels and returns raw outputs.
* ``check`` runs in the grader: the outputs, checked for shape and type, against ``expected``.

Messages say what was expected and what came, with the first pixel or ray that differs.
"""
from __future__ import annotations

from .base import HARNESS_DIR, Kind, Outcome, Prepared, Produced, on_setup_compile, work_budget_problem, work_floor_problem
from .camera import CameraRaysKind, check_camera_rays
from .hits import CompileKind, IntersectLoopKind, RenderKind, TraceRaysKind
from .memory import FetchSceneKind, PlacementKind
from .nvcc import NvccKind
from .ray_trees import WhittedKind
from .speed import SpeedKind, speed_score, time_against_reference

KINDS: dict[str, Kind] = {k.name: k for k in (CompileKind(), CameraRaysKind(), TraceRaysKind(), RenderKind(),
                                              IntersectLoopKind(), WhittedKind(), SpeedKind(),
                                              FetchSceneKind(), PlacementKind(), NvccKind())}

__all__ = ["HARNESS_DIR", "KINDS", "Kind", "Outcome", "Prepared", "Produced", "check_camera_rays", "on_setup_compile",
           "speed_score", "time_against_reference", "work_budget_problem", "work_floor_problem"]
