"""The speed kind: a submission's time against the reference kernel's on the same device, every
timed launch checked (after Stanford CS149's checker)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import Kind, Outcome
from .hits import IntersectLoopKind, RenderKind
from .whitted import WhittedKind

# The kinds whose work a speed test times (each renders, times and compares a result)
TIMEABLE: dict[str, Kind] = {k.name: k for k in (RenderKind(), IntersectLoopKind(), WhittedKind())}


class SpeedKind(Kind):
    """Time against the reference kernel on the same device in the same process (after Stanford
    CS149's checker: relative to a reference on the same machine, never fixed times). ``of`` names
    the kind whose work is timed (render, intersect_loop, whitted).

    Only a correct result is timed (the float64 check of the base kind, first). Then ``warmup`` + ``repeats``
    pairs of launches, reference and submission in an order drawn at random for each pair, each
    launch on its own camera (the view moved a little at random) with output buffers that start as
    random bytes, and each scene uploaded separately for the two. Every launch's output is compared
    with the reference kernel's on the same camera: a kernel that notices it is being timed (counts
    its launches, keeps results between them) cannot return early or replay an answer. The score
    uses the median of the pairs' time ratios, which a busy machine (graders share cores) disturbs
    far less than the ratio of the two best times, reported beside it. Full points up to
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

    def setup(self, spec, fixture, backend):
        import random
        base = self.base(spec)
        rng = np.random.default_rng(random.SystemRandom().getrandbits(64))
        ref_backend, sub_backend = FreshOutputs(backend, rng), FreshOutputs(backend, rng)
        with use_kernel_tree(fixture["reference_tree"]):
            ref_state = base.setup(spec, fixture, ref_backend)
        return base, ref_state, base.setup(spec, fixture, sub_backend), rng

    def launch(self, base, state, who: str):
        if who == "reference":
            with use_kernel_tree(state[1]["reference_tree"]):
                return base.render(state)
        return base.render(state)

    def run(self, state):
        import random
        base, ref_state, state, rng = state
        spec, fx = state[0], state[1]
        checked = base.check(state, base.render(state))
        if checked.fraction < 1.0:
            return Outcome(0.0, "not timed: the result is not correct\n" + checked.output, {"correct": False})
        warmup, repeats = int(spec.params["warmup"]), int(spec.params["repeats"])
        coin = random.SystemRandom()
        scene = fx["scene"]
        camera = scene.camera
        ref, sub = [], []
        try:
            for k in range(warmup + repeats):
                scene.camera = jitter_camera(camera, rng, self.camera_jitter)
                order = ("reference", "submission") if coin.random() < 0.5 else ("submission", "reference")
                results = {who: self.launch(base, ref_state if who == "reference" else state, who) for who in order}
                ok, why = base.agree(state, results["submission"], results["reference"])
                if not ok:
                    return Outcome(0.0, f"timed launch {k + 1} of {warmup + repeats} (each on its own camera, output "
                                        f"buffers filled with random bytes first) does not match the reference "
                                        f"kernel's output on the same rays:\n{why}\nevery timed launch is checked",
                                   {"correct": False, "launch": k + 1})
                if k >= warmup:
                    ref.append(base.time_of(results["reference"]))
                    sub.append(base.time_of(results["submission"]))
        finally:
            scene.camera = camera
        ref, sub = np.array(ref), np.array(sub)
        ratio = float(np.median(sub / ref))
        fraction, msg = speed_score(ratio, spec.tolerance)
        msg = (f"{np.median(sub):.3f} ms (best {sub.min():.3f}), reference {np.median(ref):.3f} ms "
               f"(best {ref.min():.3f}), {warmup + repeats} pairs in random order on the same device, every "
               f"launch checked: {msg}")
        return Outcome(fraction, msg, {"correct": True, "best_ms": float(sub.min()), "reference_ms": float(ref.min()),
                                       "median_ms": float(np.median(sub)),
                                       "reference_median_ms": float(np.median(ref)), "ratio": ratio})


def jitter_camera(camera, rng, amount: float):
    """The camera with eye and target moved at random by about ``amount`` of their distance."""
    from ...scene.model import Camera
    eye, target = np.asarray(camera.eye, np.float64), np.asarray(camera.target, np.float64)
    dist = float(np.linalg.norm(target - eye))
    eye = eye + rng.normal(size=3) * amount * dist
    target = target + rng.normal(size=3) * amount * dist
    return Camera(tuple(float(x) for x in eye), tuple(float(x) for x in target), camera.up, camera.fov_deg,
                  camera.width, camera.height)


class FreshOutputs:
    """A backend whose every new buffer starts as random bytes (a kernel that skips its work leaves
    noise, never an earlier answer), and which gets its own scene uploads (device scenes are kept per
    backend object): the reference and the submission share no buffer."""

    def __init__(self, backend, rng):
        self._backend = backend
        self._rng = rng

    def __getattr__(self, name):
        return getattr(self._backend, name)

    def empty(self, nbytes):
        buf = self._backend.empty(nbytes)
        self._backend.fill(buf, self._rng.integers(0, 256, max(int(nbytes), 4), dtype=np.uint8))
        return buf


class use_kernel_tree:
    """Compile from another kernel tree in this process (the reference, beside the submission that
    $RTLAB_KERNEL_DIR names). The backends search a kernel's own tree first (rtlab.paths.include_dirs)."""

    def __init__(self, root):
        self.root = Path(root)

    def __enter__(self):
        from ...paths import use_kernel_dir
        self.saved = use_kernel_dir(self.root)
        return self

    def __exit__(self, *exc):
        from ...paths import use_kernel_dir
        use_kernel_dir(self.saved)


def speed_score(ratio: float, tol: dict) -> tuple[float, str]:
    """Points (0..1) for a submission taking ``ratio`` times the reference's time."""
    lo, hi = tol["full_ratio"], tol["zero_ratio"]
    if not ratio > 0 or not np.isfinite(ratio):
        return 0.0, f"no valid timing (ratio {ratio})"
    fraction = 1.0 if ratio <= lo else 0.0 if ratio >= hi else (hi - ratio) / (hi - lo)
    return fraction, f"{ratio:.2f}x the reference (median of pairs); full points up to {lo:g}x, none from {hi:g}x"
