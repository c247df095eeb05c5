"""The speed kind: a submission's time against the reference kernel's on the same device, every
timed launch checked (after Stanford CS149's checker)."""
from __future__ import annotations

import random

import numpy as np

from .base import Kind, Outcome
from .hits import IntersectLoopKind, RenderKind
from .ray_trees import WhittedKind

# The kinds whose work a speed test times (each renders, times and compares a result)
TIMEABLE: dict[str, Kind] = {k.name: k for k in (RenderKind(), IntersectLoopKind(), WhittedKind())}


class SpeedKind(Kind):
    """Time against the reference kernel on the same device (after Stanford CS149's checker:
    relative to a reference on the same machine, never fixed times). ``of`` names the kind whose
    work is timed (render, intersect_loop, whitted).

    The submission and the reference run in two processes (the reference's never loads submitted
    code), driven by the grader (:func:`time_against_reference`). Only a correct result is timed
    (the float64 check of the base kind, first). Then ``warmup`` + ``repeats`` pairs of launches,
    reference and submission in an order drawn at random for each pair, each launch on its own
    camera (the view moved a little at random) with output buffers that start as random bytes;
    the submission's process is stopped (SIGSTOP) while the reference's runs. Every launch's output
    is compared with the reference kernel's on the same camera: a kernel that notices it is being
    timed cannot return early or replay an answer. A launch's time is the device time its process
    reports, but never less than the grader's own wall clock around the request minus the most
    the reference's process ever spent outside its kernel (a process cannot report a time it did
    not take). The score uses the median of the pairs' time ratios. Full points up to
    ``full_ratio``, none from ``zero_ratio``, linear in between."""
    name = "speed"
    timed = True
    params = {"of": "render", "repeats": 15, "warmup": 2, **RenderKind.params, **IntersectLoopKind.params,
              **WhittedKind.params}
    tolerance = {**RenderKind.tolerance, **IntersectLoopKind.tolerance, **WhittedKind.tolerance,
                 "full_ratio": 1.25, "zero_ratio": 3.0}
    camera_jitter = 0.02     # of the eye-target distance, for eye and target

    def base(self, spec) -> Kind:
        from ...errors import RtlabError
        kind = TIMEABLE.get(spec.params["of"])
        if kind is None:
            raise RtlabError(f"speed: cannot time '{spec.params['of']}'; use {', '.join(TIMEABLE)}")
        return kind

    def prepare(self, spec, scene):
        return self.base(spec).prepare(spec, scene)

    def variants(self, spec, inputs):
        return self.base(spec).variants(spec, inputs)

    def setup(self, spec, inputs, backend, count_work=False):
        return self.base(spec).setup(spec, inputs, backend, False)

    def produce(self, state, request):
        return self.base(state[0]).produce(state, request)

    def outputs(self, spec, inputs, camera=None):
        return self.base(spec).outputs(spec, inputs, camera)


def camera_dict(camera) -> dict:
    return {"eye": [float(x) for x in camera.eye], "target": [float(x) for x in camera.target],
            "up": [float(x) for x in camera.up], "fov_deg": float(camera.fov_deg), "width": int(camera.width),
            "height": int(camera.height)}


def time_against_reference(spec, inputs, expected, submission, reference) -> Outcome:
    """A speed test, driven from the grader: ``submission`` and ``reference`` are the two processes
    (``.produce(request, camera) -> (Produced, wall_ms)``; the submission's also ``.pause()`` and
    ``.resume()``). Raises what they raise (a crash, a timeout, a broken reply)."""
    kind = SpeedKind()
    base = kind.base(spec)
    scene = inputs["scene"]
    first, _ = submission.produce({}, scene.camera)
    checked = base.check(spec, inputs, expected, first)
    if checked.fraction < 1.0:
        return Outcome(0.0, "not timed: the result is not correct\n" + checked.output, {"correct": False})
    warmup, repeats = int(spec.params["warmup"]), int(spec.params["repeats"])
    coin = random.SystemRandom()
    rng = np.random.default_rng(coin.getrandbits(64))
    runs = {"reference": [], "submission": []}
    for k in range(warmup + repeats):
        camera = jitter_camera(scene.camera, rng, kind.camera_jitter)
        request = {"camera": camera_dict(camera), "fresh": True}
        order = ("reference", "submission") if coin.random() < 0.5 else ("submission", "reference")
        results = {}
        for who in order:
            if who == "reference":
                submission.pause()
                try:
                    results[who] = reference.produce(request, camera)
                finally:
                    submission.resume()
            else:
                results[who] = submission.produce(request, camera)
        ok, why = base.agree(spec, inputs, camera, results["submission"][0], results["reference"][0])
        if not ok:
            return Outcome(0.0, f"timed launch {k + 1} of {warmup + repeats} (each on its own camera, output "
                                f"buffers filled with random bytes first) does not match the reference "
                                f"kernel's output on the same rays:\n{why}\nevery timed launch is checked",
                           {"correct": False, "launch": k + 1})
        if k >= warmup:
            for who in runs:
                out, wall = results[who]
                runs[who].append((base.time_of(out), wall))
    ref_ms = np.array([t for t, _ in runs["reference"]])
    ref_overhead = max(max(0.0, wall - t) for t, wall in runs["reference"])
    # a process reports its own device time; it cannot have taken less than the grader saw it take
    sub_ms = np.array([max(t, wall - ref_overhead) if np.isfinite(t) else wall - ref_overhead
                       for t, wall in runs["submission"]])
    ratio = float(np.median(sub_ms / ref_ms))
    fraction, msg = speed_score(ratio, spec.tolerance)
    msg = (f"{np.median(sub_ms):.3f} ms (best {sub_ms.min():.3f}), reference {np.median(ref_ms):.3f} ms "
           f"(best {ref_ms.min():.3f}), {warmup + repeats} pairs in random order on the same device, every "
           f"launch checked: {msg}")
    reported = np.array([t for t, _ in runs["submission"]])
    return Outcome(fraction, msg, {"correct": True, "best_ms": float(sub_ms.min()), "reference_ms": float(ref_ms.min()),
                                   "median_ms": float(np.median(sub_ms)),
                                   "reference_median_ms": float(np.median(ref_ms)), "ratio": ratio,
                                   "reported_median_ms": float(np.median(reported)),
                                   "reference_overhead_ms": float(ref_overhead)})


def jitter_camera(camera, rng, amount: float):
    """The camera with eye and target moved at random by about ``amount`` of their distance."""
    from ...scene.model import Camera
    eye, target = np.asarray(camera.eye, np.float64), np.asarray(camera.target, np.float64)
    dist = float(np.linalg.norm(target - eye))
    eye = eye + rng.normal(size=3) * amount * dist
    target = target + rng.normal(size=3) * amount * dist
    return Camera(tuple(float(x) for x in eye), tuple(float(x) for x in target), camera.up, camera.fov_deg,
                  camera.width, camera.height)


def speed_score(ratio: float, tol: dict) -> tuple[float, str]:
    """Points (0..1) for a submission taking ``ratio`` times the reference's time."""
    lo, hi = tol["full_ratio"], tol["zero_ratio"]
    if not ratio > 0 or not np.isfinite(ratio):
        return 0.0, f"no valid timing (ratio {ratio})"
    fraction = 1.0 if ratio <= lo else 0.0 if ratio >= hi else (hi - ratio) / (hi - lo)
    return fraction, f"{ratio:.2f}x the reference (median of pairs); full points up to {lo:g}x, none from {hi:g}x"
