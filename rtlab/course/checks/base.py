"""What the kinds of grading test share (rtlab.course.checks): the base class of a kind, what crosses
between the grader and a test process, and how hits and images are compared with the reference and
described in a message."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

HARNESS_DIR = Path(__file__).resolve().parent.parent / "harness"
_SETUP_TICK: Callable[[], None] | None = None    # set in a test process (run_test)
DEFAULT_WORK_BUDGET = 4.0     # a traversal may read this many times the tree (or triangles) the reference reads


def on_setup_compile(tick: Callable[[], None] | None) -> None:
    """Call ``tick`` before each compile the backend does not see (nvcc's offline report): the test
    process's time limit for setup counts from the last tick (rtlab.course.run_test)."""
    global _SETUP_TICK
    _SETUP_TICK = tick


def setup_tick() -> None:
    if _SETUP_TICK is not None:
        _SETUP_TICK()


@dataclass
class Outcome:
    fraction: float              # of the test's points, 0..1
    output: str
    data: dict = field(default_factory=dict)
    skipped: bool = False        # not graded on this machine (a missing tool); scores 0, says why


@dataclass
class Prepared:
    """A test's fixture, made by the grader: ``inputs`` go to the test process (the scene, rays,
    camera: what the kernel needs, never an answer); ``expected`` (the float64 reference's answers)
    stays with the grader, which checks the process's outputs against it."""
    inputs: dict
    expected: dict = field(default_factory=dict)


@dataclass
class Produced:
    """What a test process hands back: raw arrays and a few numbers (kernel_ms...). Untrusted: the
    grader checks every array's dtype and shape (Kind.outputs) before a check reads it."""
    arrays: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)


class Kind:
    """A kind of grading test in four stages: ``prepare`` (grader: scene, rays, reference answers),
    ``setup`` (test process, before any submitted code runs: compile, upload), ``produce`` (test
    process, runs the submission's kernels, returns raw outputs) and ``check`` (grader: the outputs
    against the reference). ``counts_work`` kinds also run an instrumented build whose reads are
    held against the reference kernel's on the same inputs (the work budget)."""
    name = ""
    params: dict = {}            # keys a test of this kind may set, with defaults
    tolerance: dict = {}         # tolerance keys with defaults
    timed = False                # speed tests: run alone, against the reference, after the others

    def prepare(self, spec, scene) -> Prepared:
        return Prepared({})

    def variants(self, spec, inputs) -> list:
        """The variants whose host data (trees, per-triangle rows) the test process uploads."""
        return [spec_variant(spec)]

    def setup(self, spec, inputs, backend, count_work: bool = False):
        raise NotImplementedError

    def produce(self, state, request: dict) -> Produced:
        raise NotImplementedError

    def outputs(self, spec, inputs) -> dict:
        """name -> (dtype, shape) of every array ``produce`` returns."""
        return {}

    def check(self, spec, inputs, expected, out: Produced) -> Outcome:
        raise NotImplementedError

    def counts_work(self, spec) -> bool:
        """Whether the test holds the kernel's reads to a budget (an instrumented build)."""
        return False


def work_budget_applies(spec) -> bool:
    """Tests whose kernel walks the scene with the student's traversal on the global placement, with a
    budget > 0 (tolerance ``work_budget``)."""
    return (float(spec.tolerance.get("work_budget", 0) or 0) > 0
            and (spec.params.get("node_memory") or "global") == "global")


def work_budget_problem(counts, reference, budget: float) -> str | None:
    """Why the kernel's reads (tree, triangles) exceed ``budget`` times the reference's, or None."""
    names = ("the tree (nodes, node data, object lists)", "triangle data")
    for got, want, what in zip(counts, reference, names):
        got, want = int(got), int(want)
        if got > budget * max(want, 1):
            ratio = got / max(want, 1)
            return (f"reads {ratio:.0f}x as much of {what} as the reference kernel on the same rays ({got:,} against "
                    f"{want:,}; allowed {budget:g}x): a traversal visits the nodes its ray crosses, in order, "
                    f"and stops at the first hit it can no longer beat; walking every node is brute force")
    return None


def work_floor_problem(counts, hits: int) -> str | None:
    """Why a launch that returned ``hits`` hits read fewer triangles through the lab's loaders than
    that, or None. Each hit needs its own triangle's rows read, so fewer counted reads mean the kernel
    read the scene some other way (a raw pointer past the loaders): its reads cannot be counted, and a
    walk the budget cannot count does not pass it."""
    got = int(counts[1])
    if got >= hits:
        return None
    return (f"returned {hits:,} hits but read triangle data {got:,} times through the lab's loaders "
            f"(load_tri_vertex, load_tri_data): a hit needs its triangle read, so it reads the scene some "
            f"other way, past the loaders that count the work budget; read the scene through them")


def spec_variant(spec):
    """A test's variant: the paper's (kd stack, Moller-Trumbore, 32x4), as the labs are, with what the
    test names replaced."""
    from ...device.variants import Variant
    p = spec.params
    kw = {k: p[k] for k in ("traversal", "intersection", "node_memory", "constants", "ray_memory") if p.get(k)}
    if p.get("block"):
        kw["block"] = tuple(p["block"])
    return Variant.paper(**kw)


def vec_text(a) -> str:
    return "(" + ", ".join(f"{float(x):.6g}" for x in np.asarray(a).reshape(-1)) + ")"


def hit_text(tri, t) -> str:
    return "a miss" if tri < 0 else f"triangle {int(tri)} at t = {float(t):.6g}"


def percent_text(n, total) -> str:
    p = 100.0 * n / max(total, 1)
    return f"{p:.2g} %" if p < 1 else f"{p:.1f} %"


def describe_hit_errors(comparison, ref, tri, t, tol, where_of, origins=None) -> tuple[bool, str]:
    """(ok, message) for a kernel's hits against the reference; where_of(i) names ray i.
    With the rays' origins (unit directions), t errors are relative to max(t, |origin|): float32
    places a hit point only to within its coordinates' rounding, so a hit at t = 0.001 from an
    origin at 2.5 is off by ~1e-7 (4e-5 of t) in any correct kernel."""
    n = comparison.n_rays
    allowed = int(np.floor(tol["mismatch_fraction"] * n))
    lines = []
    ok = True
    if comparison.n_mismatch > allowed:
        ok = False
        i = comparison.first_mismatch_index
        lines.append(f"{percent_text(comparison.n_mismatch, n)} of {where_of(None)} hit another triangle "
                     f"({comparison.n_mismatch} of {n}); first at {where_of(i)}: expected "
                     f"{hit_text(ref.tri[i], ref.t[i])}, got {hit_text(tri[i], t[i])}")
    same = (np.asarray(tri) == ref.tri) & (ref.tri >= 0)
    if same.any():
        scale = np.abs(ref.t[same])
        if origins is not None:
            scale = np.maximum(scale, np.abs(np.asarray(origins, np.float64)[same]).max(axis=1))
        rel = np.abs(np.asarray(t, np.float64)[same] - ref.t[same]) / np.maximum(scale, 1e-300)
        rel = np.where(np.isnan(rel), np.inf, rel)
        worst = int(np.argmax(rel))
        if rel[worst] > tol["t_rel"]:
            ok = False
            i = int(np.flatnonzero(same)[worst])
            lines.append(f"hit distances are off by up to {rel[worst]:.2e} (relative; allowed {tol['t_rel']:.0e}); "
                         f"worst at {where_of(i)}: expected t = {ref.t[i]:.9g}, got {float(t[i]):.9g}")
    if ok:
        tmax = comparison.t_rel_err_max
        lines.append(f"all {n} {where_of(None)} hit the expected triangle"
                     + (f" ({comparison.n_ties} ties at shared edges)" if comparison.n_ties else "")
                     + (f", max relative t error {tmax:.1e}" if np.isfinite(tmax) else ""))
    return ok, "\n".join(lines)


def require_hits(ref, spec, least: float = 0.05) -> None:
    """A test whose rays hit (almost) nothing cannot tell a kernel that returns misses from a
    correct one: refuse it (a grading config problem)."""
    from ...errors import RtlabError
    share = float(np.mean(ref.tri >= 0)) if len(ref.tri) else 0.0
    if share < least:
        raise RtlabError(f"test {spec.name}: only {100 * share:.1f} % of its rays hit anything in the reference; "
                         f"a kernel that returns misses would pass. Choose another scene, size or ray set")


def pixel_namer(width):
    def where(i):
        return "pixels" if i is None else f"({int(i) % width}, {int(i) // width})"
    return where


def ray_namer(origins, directions):
    def where(i):
        return "rays" if i is None else f"ray {int(i)} from {vec_text(origins[i])} along {vec_text(directions[i])}"
    return where


def primary_step_of(variant) -> str:
    """The lab step whose kernels render(..., lab=True) and trace(..., lab=True) compile for this variant."""
    from ...device.kernels import primary_step
    return primary_step(variant)


def device_scene_of(scene, backend):
    from ...device.device_scene import device_scene
    return device_scene(scene, backend)


def describe_image_error(image, ref_image, min_psnr: float, what: str) -> tuple[bool, str, float]:
    from ...reference import image_rmse_psnr
    _, psnr = image_rmse_psnr(image, ref_image)
    if psnr >= min_psnr:
        return True, f"; image PSNR {'inf' if np.isinf(psnr) else f'{psnr:.1f}'} dB", psnr
    diff = np.abs(image.astype(int) - ref_image.astype(int)).max(axis=2)
    y, x = np.unravel_index(int(np.argmax(diff)), diff.shape)
    return False, (f"\nimage PSNR {psnr:.1f} dB against {what}, needs {min_psnr:.0f} dB; largest difference at "
                   f"({x}, {y}): expected rgb {tuple(int(c) for c in ref_image[y, x])}, "
                   f"got {tuple(int(c) for c in image[y, x])}"), psnr


# Why many parameters: the kernel's raw outputs, the expected hits and the test's tolerances, all the check
# needs.
def hits_agree(got_tri, got_t, ref_tri, ref_t, ref_u, ref_v, scene, faces, camera, tol, where_of) -> tuple[bool, str]:
    """Whether a kernel's hits of a camera's rays match the reference kernel's on the same rays (same
    device), by the rules of the float64 check (rtlab.reference.compare_hits) with the reference
    kernel's answers in the float64 reference's place: the same triangle at the same t, or another one
    the ray cannot tell from it (a shared edge, a graze)."""
    from ...reference import compare_hits
    from ...reference.tracer import RefHits
    from ...scene.model import camera_rays
    ref_tri = np.asarray(ref_tri).astype(np.int64)
    hit = ref_tri >= 0
    ref = RefHits(np.where(hit, np.asarray(ref_t, np.float64), np.inf), np.where(hit, ref_tri, -1),
                  np.where(hit, np.asarray(ref_u, np.float64), np.nan), np.where(hit, np.asarray(ref_v, np.float64), np.nan))
    o, d = camera_rays(camera)
    cmp_ = compare_hits(ref, got_tri, got_t, scene.vertices, faces, o, d)
    return describe_hit_errors(cmp_, ref, got_tri, got_t, tol, where_of)


# --------------------------------------------------------------------------------------------------
# what produce() shares: the work counts, a moved camera, fresh output buffers
# --------------------------------------------------------------------------------------------------
PROBE_RAYS = 256               # rays of a trace test whose reads are counted (the work budget)
PROBE_IMAGE = (24, 24)         # the image of a render test whose reads are counted


def counted_produce(variant, ds, request: dict, probe, probe_items: int, run, run_items: int) -> "Produced":
    """The test's launch ``run()`` (-> Produced), and with a counting build (``variant.count_work``) the
    work budget's counts: first ``probe()`` on a few of the test's rays, its counts sent to
    ``request["emit"]`` before the run (so the grader has them even if the run never ends), then the
    run's own counts as the output ``work_run``: the launch whose hits the grader checks is counted
    too, so a kernel that walks differently when it is probed gains nothing. The reference worker
    asks with ``request["counts_only"]``: both counts, as the result."""
    if not variant.count_work:
        return run()
    ds.reserve_work_counters(probe_items)
    probe()
    work = ds.take_work_counts()
    if request.get("emit"):
        request["emit"]({"work": work})
    ds.reserve_work_counters(run_items)
    out = run()
    counts = ds.take_work_counts()
    if request.get("counts_only"):
        return Produced({"work": work, "work_run": counts})
    return Produced({**out.arrays, "work_run": counts}, out.info)


def camera_scene(scene, request: dict):
    """The scene seen through ``request["camera"]`` (a speed test's moved view), or as it is."""
    cam = request.get("camera")
    if cam is None:
        return scene
    from ...scene.model import Camera
    return replace(scene, camera=Camera(tuple(cam["eye"]), tuple(cam["target"]), tuple(cam["up"]), cam["fov_deg"],
                                        cam["width"], cam["height"]))


def fresh_outputs(backend, request: dict):
    """The backend, or (speed tests: ``request["fresh"]``) one whose new buffers start as random
    bytes, so a kernel that skips its work leaves noise, never an earlier answer."""
    if not request.get("fresh"):
        return backend
    if backend not in _fresh:
        _fresh[backend] = FreshOutputs(backend, np.random.default_rng())
    return _fresh[backend]


_fresh: dict = {}


class FreshOutputs:
    """A backend whose every new buffer starts as random bytes."""

    def __init__(self, backend, rng):
        self._backend = backend
        self._rng = rng

    def __getattr__(self, name):
        return getattr(self._backend, name)

    def empty(self, nbytes):
        buf = self._backend.empty(nbytes)
        self._backend.fill(buf, self._rng.integers(0, 256, max(int(nbytes), 4), dtype=np.uint8))
        return buf
