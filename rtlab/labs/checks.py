"""What a grading test checks: one :class:`Kind` per ``kind`` in grading.toml.

A kind works in three stages, so that the grader can give each stage its own time limit:

* ``prepare`` runs in the grader (host only, no kernels): loads the scene, builds rays and the
  float64 reference answers (rtlab.reference). The result, a picklable dict, is the test's fixture.
* ``setup`` runs in the test's own process: uploads the scene and compiles the submission's kernel.
* ``run`` runs in the same process: launches the kernel and compares with the fixture.

Messages say what was expected and what came, with the first pixel or ray that differs.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

HARNESS_DIR = Path(__file__).resolve().parent / "harness"
SETUP_TICK = None    # set in a test process (run_test): called before each compile the backend does not see


def _tick() -> None:
    if SETUP_TICK is not None:
        SETUP_TICK()


@dataclass
class Outcome:
    fraction: float              # of the test's points, 0..1
    output: str
    data: dict = field(default_factory=dict)
    skipped: bool = False        # not graded on this machine (a missing tool); scores 0, says why


class Kind:
    name = ""
    params: dict = {}            # keys a test of this kind may set, with defaults
    tolerance: dict = {}         # tolerance keys with defaults
    timed = False                # speed tests: run alone, against the reference, after the others

    def prepare(self, spec, scene) -> dict:
        return {}

    def setup(self, spec, fixture, backend):
        raise NotImplementedError

    def run(self, state) -> Outcome:
        raise NotImplementedError


# --------------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------------
def spec_variant(spec):
    from ..device.kernels import Variant
    p = spec.params
    kw = {k: p[k] for k in ("traversal", "intersection", "node_memory", "constants", "ray_memory") if p.get(k)}
    if p.get("block"):
        kw["block"] = tuple(p["block"])
    return Variant(**kw)


def _vec(a) -> str:
    return "(" + ", ".join(f"{float(x):.6g}" for x in np.asarray(a).reshape(-1)) + ")"


def _hit_text(tri, t) -> str:
    return "a miss" if tri < 0 else f"triangle {int(tri)} at t = {float(t):.6g}"


def _pct(n, total) -> str:
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
        lines.append(f"{_pct(comparison.n_mismatch, n)} of {where_of(None)} hit another triangle "
                     f"({comparison.n_mismatch} of {n}); first at {where_of(i)}: expected "
                     f"{_hit_text(ref.tri[i], ref.t[i])}, got {_hit_text(tri[i], t[i])}")
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


def _require_hits(ref, spec, least: float = 0.05) -> None:
    """A test whose rays hit (almost) nothing cannot tell a kernel that returns misses from a
    correct one: refuse it (a grading config problem)."""
    from ..errors import RtlabError
    share = float(np.mean(ref.tri >= 0)) if len(ref.tri) else 0.0
    if share < least:
        raise RtlabError(f"test {spec.name}: only {100 * share:.1f} % of its rays hit anything in the reference; "
                         f"a kernel that returns misses would pass. Choose another scene, size or ray set")


def _pixel_namer(width):
    def where(i):
        return "pixels" if i is None else f"({int(i) % width}, {int(i) // width})"
    return where


def _ray_namer(origins, directions):
    def where(i):
        return "rays" if i is None else f"ray {int(i)} from {_vec(origins[i])} along {_vec(directions[i])}"
    return where


def _primary_step(variant) -> str:
    """The kernel pair render() and trace() compile for this variant (packet traversal has its own)."""
    try:
        from ..device.kernels import primary_step
        return primary_step(variant)
    except ImportError:
        from ..device.tracing import PRIMARY_STEP
        return PRIMARY_STEP


def _device_scene(scene, backend):
    from ..device.scene import device_scene
    return device_scene(scene, backend)


# --------------------------------------------------------------------------------------------------
# kinds
# --------------------------------------------------------------------------------------------------
class CompileKind(Kind):
    """The step's kernel (``kernel`` = another step's, if set) compiles with the submission."""
    name = "compile"
    params = {"kernel": "", "traversal": "", "intersection": "", "node_memory": "", "block": None,
              "defines": {}}

    def setup(self, spec, fixture, backend):
        from ..device.kernels import load_program
        variant = spec_variant(spec)
        ds = _device_scene(fixture["scene"], backend)
        step = spec.params["kernel"] or fixture["step"]
        program = load_program(backend, step, variant, ds.features(variant), **spec.params["defines"])
        return program, step

    def run(self, state):
        program, step = state
        return Outcome(1.0, f"{step}{program.backend.extension} compiles on {program.backend.device_name}")


class CameraRaysKind(Kind):
    """camera_ray() against the host's float32 camera rays (rtlab.scene.model.camera_rays), pixel by pixel,
    through a harness kernel: catches a wrong camera before any traversal runs."""
    name = "camera_rays"
    tolerance = {"direction_abs": 1e-5, "origin_rel": 1e-6}

    def setup(self, spec, fixture, backend):
        path = HARNESS_DIR / f"camera_rays{backend.extension}"
        return backend, backend.compile(path, {}), fixture["scene"], spec.tolerance

    def run(self, state):
        from ..device.scene import frame_constants
        from ..scene.model import camera_rays
        backend, program, scene, tol = state
        cam = scene.camera
        w, h = cam.width, cam.height
        n = w * h
        program.set_constant("frame", frame_constants(cam, scene.bounds(), len(scene.lights), len(scene.materials)))
        bufs = [backend.empty(n * 16) for _ in range(3)]
        program.launch("camera_rays", (w, h), (8, 8), bufs, constants=("frame",))
        o4, d4, inv4 = (backend.to_host(b, np.float32, 4 * n).reshape(n, 4) for b in bufs)
        return check_camera_rays(cam, o4, d4, inv4, camera_rays(cam), tol)


def _camera_variants(cam):
    """Directions of common camera mistakes, to name the one a submission made."""
    eye, u, v, w = (r.astype(np.float64) for r in cam.basis())
    W, H = cam.width, cam.height
    x, y = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))

    def dirs(sx, sy, normalize=True):
        d = w + u * sx[..., None] + v * sy[..., None]
        if normalize:
            d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return d.reshape(-1, 3)

    sx, sy = 2 * (x + .5) / W - 1, 1 - 2 * (y + .5) / H
    return {
        "image upside down: row y = 0 must be the top of the image (sy = 1 - 2 (y + 0.5) / H)": dirs(sx, -sy),
        "image mirrored left-right (sx = 2 (x + 0.5) / W - 1)": dirs(-sx, sy),
        "no half-pixel offset: rays must go through pixel centres, (x + 0.5) and (y + 0.5)":
            dirs(2 * x / W - 1, 1 - 2 * y / H),
        "width and height swapped": dirs(2 * (x + .5) / H - 1, 1 - 2 * (y + .5) / W),
        "the direction is not normalised (normalize3)": dirs(sx, sy, normalize=False),
        "off by one: divide by W and H, not W - 1 and H - 1": dirs(2 * (x + .5) / (W - 1) - 1, 1 - 2 * (y + .5) / (H - 1)),
    }


def check_camera_rays(cam, o4, d4, inv4, expected, tol) -> Outcome:
    exp_o, exp_d = expected
    n = exp_d.shape[0]
    where = _pixel_namer(cam.width)
    problems = []
    d = d4[:, :3].astype(np.float64)
    err = np.abs(d - exp_d).max(axis=1)
    err = np.where(np.isnan(err), np.inf, err)
    bad = err > tol["direction_abs"]
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        msg = (f"{_pct(int(bad.sum()), n)} of pixels get a wrong direction ({int(bad.sum())} of {n}); "
               f"first at {where(i)}: expected {_vec(exp_d[i])}, got {_vec(d[i])}")
        for hint, alt in _camera_variants(cam).items():
            if np.nanmax(np.abs(d - alt)) < 1e-4:
                msg += f"\nhint: this looks like {hint}"
                break
        problems.append(msg)
    o_err = np.abs(o4[:, :3] - exp_o).max(axis=1) / max(np.abs(exp_o).max(), 1e-30)
    o_err = np.where(np.isnan(o_err), np.inf, o_err)
    if (o_err > tol["origin_rel"]).any():
        i = int(np.flatnonzero(o_err > tol["origin_rel"])[0])
        problems.append(f"ray origins must be the eye {_vec(exp_o[i])}; at {where(i)} got {_vec(o4[i, :3])}")
    if not np.all(o4[:, 3] == 0.0):
        i = int(np.flatnonzero(o4[:, 3] != 0.0)[0])
        problems.append(f"tmin must be 0 (nothing is in front of the eye); at {where(i)} got {o4[i, 3]:.6g}")
    if not np.all(np.isposinf(d4[:, 3])):
        i = int(np.flatnonzero(~np.isposinf(d4[:, 3]))[0])
        problems.append(f"tmax must be RT_INF (every hit along the ray counts); at {where(i)} got {d4[i, 3]:.6g}")
    with np.errstate(divide="ignore"):
        exp_inv = (np.float32(1) / d4[:, :3]).astype(np.float64)
    inv = inv4[:, :3].astype(np.float64)
    same = (inv == exp_inv) | (np.abs(inv - exp_inv) <= 1e-6 * np.abs(exp_inv))
    if not bad.any() and not same.all():
        i = int(np.flatnonzero(~same.all(axis=1))[0])
        problems.append(f"inv_d must hold 1/d (build rays with make_ray); at {where(i)} expected "
                        f"{_vec(exp_inv[i])}, got {_vec(inv[i])}")
    if problems:
        return Outcome(0.0, "\n".join(problems))
    return Outcome(1.0, f"all {n} camera rays ({cam.width}x{cam.height}) match: origin at the eye, "
                        f"directions within {tol['direction_abs']:.0e}, tmin 0, tmax inf")


class TraceRaysKind(Kind):
    """Closest hits of rays that are not camera rays (the trace_rays kernel: traversal and triangle
    test on their own), against the float64 reference.
    rays = "random": origins inside and around the scene box, directions uniform on the sphere;
    rays = "axis": axis-aligned directions, and rays lying in the kd-tree's split planes."""
    name = "trace_rays"
    params = {"rays": "random", "count": 4000, "seed": 7, "tmin": 0.0, "tmax": float("inf"),
              "traversal": "", "intersection": "", "node_memory": "", "block": None}
    tolerance = {"mismatch_fraction": 0.0, "t_rel": 1e-5}

    def prepare(self, spec, scene):
        from ..reference import reference_trace
        o, d = make_rays(scene, spec.params["rays"], int(spec.params["count"]), int(spec.params["seed"]))
        p = spec.params
        ref = reference_trace(scene.vertices, scene.faces, o, d, tmin=p["tmin"], tmax=p["tmax"])
        _require_hits(ref, spec)
        return {"origins": o, "directions": d, "ref": ref}

    def setup(self, spec, fixture, backend):
        from ..device.kernels import load_program
        variant = spec_variant(spec)
        ds = _device_scene(fixture["scene"], backend)
        load_program(backend, _primary_step(variant), variant, ds.features(variant))
        return spec, fixture, backend, variant

    def run(self, state):
        from ..reference import compare_hits
        from ..device.tracing import trace
        spec, fx, backend, variant = state
        scene, o, d, ref = fx["scene"], fx["origins"], fx["directions"], fx["ref"]
        p = spec.params
        got = trace(scene, o, d, backend=backend, variant=variant, tmin=p["tmin"], tmax=p["tmax"])
        cmp_ = compare_hits(ref, got.tri, got.t, scene.vertices, scene.faces, o, d, tmin=p["tmin"], tmax=p["tmax"])
        ok, msg = describe_hit_errors(cmp_, ref, got.tri, got.t, spec.tolerance, _ray_namer(o, d), origins=o)
        return Outcome(1.0 if ok else 0.0, msg, {"mismatches": cmp_.n_mismatch, "rays": cmp_.n_rays,
                                                "kernel_ms": got.kernel_ms})


def make_rays(scene, kind: str, count: int, seed: int):
    """Test rays as float32 (origins, directions)."""
    from ..errors import RtlabError
    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds().astype(np.float64)
    ext = hi - lo
    if kind == "random":
        o = rng.uniform(lo - 0.5 * ext, hi + 0.5 * ext, size=(count, 3))
        d = rng.normal(size=(count, 3))
    elif kind == "axis":
        # half: axis-aligned directions (two zero components: inv_d = +-inf) from random origins
        half = count // 2
        o1 = rng.uniform(lo - 0.25 * ext, hi + 0.25 * ext, size=(half, 3))
        axis = rng.integers(0, 3, half)
        d1 = np.zeros((half, 3))
        d1[np.arange(half), axis] = rng.choice([-1.0, 1.0], half)
        # half: rays lying in a split plane of the kd-tree (origin on the plane, no component across it)
        from ..device.scene import scene_kdtree
        tree = scene_kdtree(scene)
        interior = np.flatnonzero(~tree.is_leaf())
        pick = interior[rng.integers(0, interior.size, count - half)]
        ax = tree.split_axis()[pick]
        pos = tree.split_pos()[pick].astype(np.float64)
        o2 = rng.uniform(lo, hi, size=(count - half, 3))
        o2[np.arange(count - half), ax] = pos
        d2 = rng.normal(size=(count - half, 3))
        d2[np.arange(count - half), ax] = 0.0
        o, d = np.concatenate([o1, o2]), np.concatenate([d1, d2])
    else:
        raise RtlabError(f"unknown ray set '{kind}'; use random or axis")
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o.astype(np.float32), d.astype(np.float32)


class RenderKind(Kind):
    """The step's render of the scene's camera view (primary rays, simple shading): every pixel's
    hit (the render's hit buffer) against the float64 reference, and the image against the
    reference shading (PSNR)."""
    name = "render"
    params = {"traversal": "", "intersection": "", "node_memory": "", "block": None}
    tolerance = {"mismatch_fraction": 0.0, "t_rel": 1e-5, "min_psnr": 40.0}

    def prepare(self, spec, scene):
        from ..reference.shading import reference_shade, to_rgb8
        from ..reference.check import reference_camera_hits
        o, d, ref = reference_camera_hits(scene, scene.camera)
        _require_hits(ref, spec)
        img = to_rgb8(reference_shade(scene, o, d, ref.tri, ref.t, ref.u, ref.v))
        return {"origins": o, "directions": d, "ref": ref,
                "ref_image": img.reshape(scene.camera.height, scene.camera.width, 3)}

    def setup(self, spec, fixture, backend):
        from ..device.kernels import load_program
        variant = spec_variant(spec)
        ds = _device_scene(fixture["scene"], backend)
        load_program(backend, _primary_step(variant), variant, ds.features(variant), RT_WRITE_HITS=1)
        return spec, fixture, backend, variant

    def render(self, state):
        from ..device.rendering import render
        spec, fx, backend, variant = state
        return render(fx["scene"], backend, variant, write_hits=True)

    def time_of(self, result) -> float:
        return float(result.kernel_ms[0])

    def check(self, state, result) -> Outcome:
        from ..reference import compare_hits
        spec, fx, _, _ = state
        scene, ref = fx["scene"], fx["ref"]
        tri, t = result.hits.tri, result.hits.t
        cmp_ = compare_hits(ref, tri, t, scene.vertices, scene.faces, fx["origins"], fx["directions"])
        ok, msg = describe_hit_errors(cmp_, ref, tri, t, spec.tolerance, _pixel_namer(scene.camera.width))
        img_ok, img_msg, psnr = describe_image_error(result.image, fx["ref_image"], spec.tolerance["min_psnr"],
                                                     "the reference shading")
        return Outcome(1.0 if ok and img_ok else 0.0, msg + img_msg,
                       {"mismatches": cmp_.n_mismatch, "pixels": cmp_.n_rays, "psnr": psnr})

    def agree(self, state, got, want) -> tuple[bool, str]:
        """Whether a render matches the reference kernel's render of the same view (speed tests)."""
        spec, fx = state[0], state[1]
        scene = fx["scene"]
        ok, why = hits_agree(got.hits.tri, got.hits.t, want.hits.tri, want.hits.t, want.hits.u, want.hits.v, scene,
                             scene.faces, scene.camera, spec.tolerance, _pixel_namer(scene.camera.width))
        if not ok:
            return ok, why
        img_ok, img_msg, _ = describe_image_error(got.image, want.image, spec.tolerance["min_psnr"],
                                                  "the reference kernel's image")
        return img_ok, img_msg.strip()

    def run(self, state):
        return self.check(state, self.render(state))


def describe_image_error(image, ref_image, min_psnr: float, what: str) -> tuple[bool, str, float]:
    from ..reference import image_rmse_psnr
    _, psnr = image_rmse_psnr(image, ref_image)
    if psnr >= min_psnr:
        return True, f"; image PSNR {'inf' if np.isinf(psnr) else f'{psnr:.1f}'} dB", psnr
    diff = np.abs(image.astype(int) - ref_image.astype(int)).max(axis=2)
    y, x = np.unravel_index(int(np.argmax(diff)), diff.shape)
    return False, (f"\nimage PSNR {psnr:.1f} dB against {what}, needs {min_psnr:.0f} dB; largest difference at "
                   f"({x}, {y}): expected rgb {tuple(int(c) for c in ref_image[y, x])}, "
                   f"got {tuple(int(c) for c in image[y, x])}"), psnr


class IntersectLoopKind(Kind):
    """The paper's Table 3 kernel (lab step 02): every pixel's camera ray against the first
    ``n_tris`` triangles in a loop, no acceleration structure (rtlab.benches.intersect), against the
    float64 reference over the same triangles. ``triangles = "visible"`` (the default) grades on a
    scene of the first ``n_tris`` triangles the camera sees, in file order: the first 1000 of a
    file (the paper's timing setup, ``"first"``) may cover no pixel of a small image."""
    name = "intersect_loop"
    params = {"intersection": "moller", "n_tris": 1000, "triangles": "visible", "block": None}
    tolerance = {"mismatch_fraction": 0.0, "t_rel": 1e-5}

    def prepare(self, spec, scene):
        from ..errors import RtlabError
        from ..reference import reference_trace
        from ..scene.model import camera_rays
        o, d = camera_rays(scene.camera)
        n = int(spec.params["n_tris"])
        if spec.params["triangles"] == "visible":
            seen = np.unique(reference_trace(scene.vertices, scene.faces, o, d).tri)
            keep = seen[seen >= 0][:n]
            scene = replace(scene, name=f"{scene.name}-visible{len(keep)}", faces=scene.faces[keep],
                            material_ids=scene.material_ids[keep])
        elif spec.params["triangles"] != "first":
            raise RtlabError(f"triangles must be 'visible' or 'first', not {spec.params['triangles']!r}")
        n = min(n, scene.n_triangles)
        ref = reference_trace(scene.vertices, scene.faces[:n], o, d)
        _require_hits(ref, spec)
        if spec.params["triangles"] == "visible":
            from ..device.scene import scene_kdtree
            scene_kdtree(scene)    # the test process uploads this scene: build its kd-tree once, here
        return {"scene": scene, "origins": o, "directions": d, "ref": ref}

    def setup(self, spec, fixture, backend):
        from ..benches.intersect import INTERSECT_STEP
        from ..device.kernels import load_program
        variant = spec_variant(spec)
        ds = _device_scene(fixture["scene"], backend)
        load_program(backend, INTERSECT_STEP, variant, ds.features(variant))
        return spec, fixture, backend, variant

    def render(self, state):
        from ..benches.intersect import intersect_loop
        spec, fx, backend, variant = state
        return intersect_loop(fx["scene"], backend, variant.intersection, int(spec.params["n_tris"]),
                              camera=fx["scene"].camera)

    def time_of(self, result) -> float:
        return float(result.kernel_ms[0])

    def check(self, state, result) -> Outcome:
        from ..reference import compare_hits
        spec, fx, _, _ = state
        scene, ref = fx["scene"], fx["ref"]
        faces = scene.faces[:result.n_tris]
        cmp_ = compare_hits(ref, result.tri, result.t, scene.vertices, faces, fx["origins"], fx["directions"])
        ok, msg = describe_hit_errors(cmp_, ref, result.tri, result.t, spec.tolerance,
                                      _pixel_namer(scene.camera.width))
        return Outcome(1.0 if ok else 0.0, f"{result.isect}, {result.n_tris} triangles in a loop: {msg}",
                       {"mismatches": cmp_.n_mismatch, "pixels": cmp_.n_rays})

    def agree(self, state, got, want) -> tuple[bool, str]:
        spec, fx = state[0], state[1]
        scene = fx["scene"]
        nan = np.full(len(want.tri), np.nan)     # the loop keeps no barycentrics: ties by equal t only
        return hits_agree(got.tri, got.t, want.tri, want.t, nan, nan, scene, scene.faces[:want.n_tris],
                          scene.camera, spec.tolerance, _pixel_namer(scene.camera.width))

    def run(self, state):
        return self.check(state, self.render(state))


class WhittedKind(Kind):
    """Whitted ray tracing (labs 04, 05; rtlab.device.whitted.render_whitted): shadows one-pass, two-pass
    or none, ``bounces`` levels of the reflection/refraction kernel tree, against the float64
    Whitted reference (rtlab.reference.whitted): the ray tree of every pixel (triangle hit by each
    node) and the colour where the trees agree."""
    name = "whitted"
    params = {"shadows": "one-pass", "bounces": 0, "fresnel": "schlick", "compact": False,
              "traversal": "", "intersection": "", "node_memory": "", "block": None}
    tolerance = {"tree_fraction": 0.005, "color_max": 2, "min_psnr": 30.0}

    def prepare(self, spec, scene):
        from ..reference.whitted import reference_whitted
        p = spec.params
        return {"ref": reference_whitted(scene, bounces=int(p["bounces"]), shadows=p["shadows"] != "none",
                                         fresnel=p["fresnel"])}

    def setup(self, spec, fixture, backend):
        from ..errors import KernelBuildError
        from ..device.kernels import load_program
        variant = spec_variant(spec)
        p = spec.params
        try:   # compile here, as render_whitted will, so the test's time limit covers only the run
            from ..device.whitted import SHADOWS_STEP, TREE_STEP, shading_defines
            ds = _device_scene(fixture["scene"], backend)
            features = ds.features(variant)
            tree = int(p["bounces"]) > 0
            extra = shading_defines(features, p["shadows"], int(p["bounces"]), p["fresnel"], bool(p["compact"]),
                                    True, tree)
            load_program(backend, TREE_STEP if tree else SHADOWS_STEP, variant, features, **extra)
        except KernelBuildError:
            raise
        except Exception:   # the run compiles what it needs anyway
            pass
        return spec, fixture, backend, variant

    def render(self, state):
        from ..device.whitted import render_whitted
        spec, fx, backend, variant = state
        p = spec.params
        return render_whitted(fx["scene"], backend, variant, shadows=p["shadows"], bounces=int(p["bounces"]),
                              compact=bool(p["compact"]), fresnel=p["fresnel"], write_hits=True)

    def time_of(self, result) -> float:
        return float(result.frame_ms[0])

    def check(self, state, result) -> Outcome:
        from ..reference.whitted import NO_RAY, whitted_error
        spec, fx, _, _ = state
        ref, tol = fx["ref"], spec.tolerance
        tree = result.tree if result.tree is not None else {"P": result.hits.tri}
        err = whitted_error(result.image, tree, ref)
        w = fx["scene"].camera.width
        problems = []
        if err.tree_pixels > tol["tree_fraction"] * err.pixels:
            # the first pixel and ray-tree node that differ ("P" primary, "PR" its reflection, ...)
            first = None
            for node in sorted(set(tree) | set(ref.tree), key=lambda s: (len(s), s)):
                a = np.asarray(tree.get(node, np.full(err.pixels, NO_RAY)), np.int64)
                b = np.asarray(ref.tree.get(node, np.full(err.pixels, NO_RAY)), np.int64)
                bad = np.flatnonzero(np.where(a < 0, np.maximum(a, NO_RAY), a) != np.where(b < 0, np.maximum(b, NO_RAY), b))
                if bad.size and (first is None or bad[0] < first[1]):
                    first = (node, int(bad[0]), int(b[bad[0]]), int(a[bad[0]]))
            what = lambda tri: "no ray" if tri == NO_RAY else "a miss" if tri < 0 else f"triangle {tri}"
            node, i, exp, got = first
            problems.append(f"{_pct(err.tree_pixels, err.pixels)} of pixels trace another ray tree than the "
                            f"reference ({err.tree_pixels} of {err.pixels}); first at ({i % w}, {i // w}), ray {node} "
                            f"({describe_node(node)}): expected {what(exp)}, got {what(got)}")
        if err.color_max_same_tree > tol["color_max"]:
            problems.append(f"where the ray trees agree, colours are off by up to {err.color_max_same_tree}/255 "
                            f"(allowed {tol['color_max']}/255; 99th percentile {err.color_p99_same_tree:.0f}/255)")
        img_ok, img_msg, psnr = describe_image_error(result.image, ref.image, tol["min_psnr"], "the float64 reference")
        if not img_ok:
            problems.append(img_msg.strip())
        data = {"tree_pixels": err.tree_pixels, "pixels": err.pixels, "color_max": err.color_max_same_tree, "psnr": psnr}
        if problems:
            return Outcome(0.0, "\n".join(problems), data)
        return Outcome(1.0, f"{err.summary()}", data)

    def agree(self, state, got, want) -> tuple[bool, str]:
        from types import SimpleNamespace
        from ..reference.whitted import whitted_error
        tol = state[0].tolerance

        def tree_of(result):
            return result.tree if result.tree is not None else {"P": result.hits.tri}

        err = whitted_error(got.image, tree_of(got), SimpleNamespace(image=want.image, tree=tree_of(want)))
        problems = []
        if err.tree_pixels > tol["tree_fraction"] * err.pixels:
            problems.append(f"{err.tree_pixels} of {err.pixels} pixels trace another ray tree than the reference kernel")
        if err.color_max_same_tree > tol["color_max"]:
            problems.append(f"where the ray trees agree, colours differ by up to {err.color_max_same_tree}/255 "
                            f"(allowed {tol['color_max']}/255)")
        if not err.psnr >= tol["min_psnr"]:
            problems.append(f"image PSNR {err.psnr:.1f} dB against the reference kernel's, needs {tol['min_psnr']:.0f} dB")
        return not problems, "\n".join(problems)

    def run(self, state):
        return self.check(state, self.render(state))


def describe_node(node: str) -> str:
    names = {"R": "reflection", "T": "refraction"}
    return "primary" if node == "P" else " of the ".join(names[c] for c in reversed(node[1:])) + " of the primary"


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
        from ..errors import RtlabError
        kind = KINDS.get(spec.params["of"])
        if kind is None or not hasattr(kind, "render"):
            raise RtlabError(f"speed: cannot time '{spec.params['of']}'; use render, intersect_loop or whitted")
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
    from ..scene.model import Camera
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


def hits_agree(got_tri, got_t, ref_tri, ref_t, ref_u, ref_v, scene, faces, camera, tol, where_of) -> tuple[bool, str]:
    """Whether a kernel's hits of a camera's rays match the reference kernel's on the same rays (same
    device), by the rules of the float64 check (rtlab.reference.compare_hits) with the reference
    kernel's answers in the float64 reference's place: the same triangle at the same t, or another one
    the ray cannot tell from it (a shared edge, a graze)."""
    from ..reference import compare_hits
    from ..reference.tracer import RefHits
    from ..scene.model import camera_rays
    ref_tri = np.asarray(ref_tri).astype(np.int64)
    hit = ref_tri >= 0
    ref = RefHits(np.where(hit, np.asarray(ref_t, np.float64), np.inf), np.where(hit, ref_tri, -1),
                  np.where(hit, np.asarray(ref_u, np.float64), np.nan), np.where(hit, np.asarray(ref_v, np.float64), np.nan))
    o, d = camera_rays(camera)
    cmp_ = compare_hits(ref, got_tri, got_t, scene.vertices, faces, o, d)
    return describe_hit_errors(cmp_, ref, got_tri, got_t, tol, where_of)


class use_kernel_tree:
    """Compile from another kernel tree in this process (the reference, beside the submission that
    $RTLAB_KERNEL_DIR names). The backends search a kernel's own tree first (rtlab.device.kernels.include_dirs)."""

    def __init__(self, root):
        self.root = Path(root)

    def __enter__(self):
        from ..device import kernels
        self.saved = kernels.use_kernel_dir(self.root)
        return self

    def __exit__(self, *exc):
        from ..device import kernels
        kernels.KERNEL_DIR = self.saved


def speed_score(ratio: float, tol: dict) -> tuple[float, str]:
    """Points (0..1) for a submission taking ``ratio`` times the reference's time."""
    lo, hi = tol["full_ratio"], tol["zero_ratio"]
    if not ratio > 0 or not np.isfinite(ratio):
        return 0.0, f"no valid timing (ratio {ratio})"
    fraction = 1.0 if ratio <= lo else 0.0 if ratio >= hi else (hi - ratio) / (hi - lo)
    return fraction, f"{ratio:.2f}x the reference (median of pairs); full points up to {lo:g}x, none from {hi:g}x"


# --------------------------------------------------------------------------------------------------
# lab step 01: memory placement (§3.1.1)
# --------------------------------------------------------------------------------------------------
SCENE_BUFFERS = ("nodes", "node_data", "objects", "tris", "tri_data", "normals", "tri_materials")


def _fetch_function(dtype, channels, language: str) -> str:
    """The rt_memory.h fetch function that reads a buffer of this element type through the placement."""
    base = {(np.dtype(np.int32), 2): "fetch_int2", (np.dtype(np.float32), 4): "fetch_float4",
            (np.dtype(np.int32), 1): "fetch_int"}[(np.dtype(dtype), channels)]
    return base + ("_texture" if language == "cuda" else "_image")


def _path_name(backend) -> str:
    return "texture path" if backend.language == "cuda" else "image path"


def _fetch_test_arrays(count: int, seed: int) -> list[np.ndarray]:
    """One host array a scene buffer (RT_SCENE_PARAMS order): random bits with the float specials
    (NaN, infinities, -0, a denormal, the largest float) up front, an odd node count (the OpenCL node
    image packs two nodes a texel) and a one-element buffer."""
    from ..device.scene import SCENE_ELEMENTS
    rng = np.random.default_rng(seed)
    info = np.iinfo(np.int32)
    out = []
    for k, (dtype, ch) in enumerate(SCENE_ELEMENTS):
        n = 1 if SCENE_BUFFERS[k] == "tri_data" else count | 1
        if np.dtype(dtype) == np.float32:
            a = (rng.normal(size=(n, ch)) * 1e3).astype(np.float32)
            a.flat[:6] = [np.inf, -np.inf, np.nan, -0.0, np.float32(1e-42), np.finfo(np.float32).max][:a.size]
        else:
            a = rng.integers(info.min, info.max, (n, ch), dtype=np.int32)
            a.flat[:2] = [info.min, info.max][:a.size]
        out.append(a.reshape(n) if ch == 1 else a)
    return out


class FetchSceneKind(Kind):
    """Every scene buffer read back through a placement's fetch functions (lab step 01's
    ``fetch_scene`` kernel, any element of any buffer by index) against the host array, bit for bit:
    a placement moves data, it never changes a bit of it."""
    name = "fetch_scene"
    params = {"node_memory": "texture", "count": 1001, "seed": 3}

    def prepare(self, spec, scene):
        return {"arrays": _fetch_test_arrays(int(spec.params["count"]), int(spec.params["seed"]))}

    def setup(self, spec, fixture, backend):
        from ..device.scene import SCENE_ELEMENTS
        from ..device.kernels import MEMORY_STEP, SceneFeatures, build_defines, kernel_source
        variant = spec_variant(spec)
        program = backend.compile(kernel_source(MEMORY_STEP, backend.language),
                                  build_defines(variant, SceneFeatures()))
        arrays = fixture["arrays"]
        buffers = [backend.to_device(a) for a in arrays]
        if variant.node_memory == "texture":
            args = [backend.texture(b, dt, ch, len(a)).arg for b, a, (dt, ch) in zip(buffers, arrays, SCENE_ELEMENTS)]
        else:
            args = buffers
        return backend, program, args, arrays, buffers

    def run(self, state):
        from ..device.scene import SCENE_ELEMENTS
        backend, program, args, arrays, _ = state
        problems, total = [], 0
        for which, a in enumerate(arrays):
            n = len(a)
            out = backend.empty(n * 16)
            program.launch("fetch_scene", (n,), (64,), list(args) + [np.int32(which), np.int32(n), out])
            got = backend.to_host(out, np.int32, 4 * n).reshape(n, 4)
            want = a.view(np.int32).reshape(n, -1)
            got = got[:, :want.shape[1]]
            bad = np.flatnonzero(np.any(got != want, axis=1))
            total += n
            if bad.size:
                i = int(bad[0])
                dtype, ch = SCENE_ELEMENTS[which]
                fmt = (lambda r: _vec(r.view(np.float32))) if np.dtype(dtype) == np.float32 else \
                      (lambda r: "(" + ", ".join(str(int(x)) for x in r) + ")")
                problems.append(f"{SCENE_BUFFERS[which]} ({_fetch_function(dtype, ch, backend.language)}): "
                                f"{bad.size} of {n} elements differ; first, element {i}: expected {fmt(want[i])}, "
                                f"got {fmt(got[i])}")
        if problems:
            return Outcome(0.0, f"reading the scene buffers through the {_path_name(backend)}:\n" + "\n".join(problems))
        return Outcome(1.0, f"all {total} elements of the 7 scene buffers read back bit for bit through the "
                            f"{_path_name(backend)} (NaN, infinities, -0 and denormals included; {len(arrays[0])} "
                            f"nodes, an odd count)")


def _hit_diff_text(base, got, width: int, what: str) -> tuple[bool, str]:
    """(same, message): a placement's render against the global variant's, bit for bit."""
    tri_b, tri_g = base.hits.tri, got.hits.tri
    t_b, t_g = base.hits.t.view(np.int32), got.hits.t.view(np.int32)
    differ = (tri_b != tri_g) | (t_b != t_g)
    px = np.any(base.image != got.image, axis=-1).reshape(-1)
    if not differ.any() and not px.any():
        return True, f"0 of {differ.size} pixels differ from the global variant (hits bit for bit, image)"
    where = _pixel_namer(width)
    if differ.any():
        i = int(np.flatnonzero(differ)[0])
        return False, (f"{int(differ.sum())} of {differ.size} pixels differ from the global variant; first at "
                       f"{where(i)}: global variant: {_hit_text(tri_b[i], base.hits.t[i])}, {what}: "
                       f"{_hit_text(tri_g[i], got.hits.t[i])}")
    i = int(np.flatnonzero(px)[0])
    return False, (f"the hits match the global variant but {int(px.sum())} pixels' colours differ; first at "
                   f"{where(i)} (normals or materials read wrongly?)")


class PlacementKind(RenderKind):
    """A memory placement (lab step 01) rendering the scene's camera view: every pixel's hit and
    colour identical, bit for bit, to the global-memory variant's (a placement moves data, never a
    result), and the hits right against the float64 reference."""
    name = "placement"
    params = {**RenderKind.params, "node_memory": "texture", "constants": "", "ray_memory": ""}

    def setup(self, spec, fixture, backend):
        from ..device.kernels import load_program
        spec_, fx, backend, variant = super().setup(spec, fixture, backend)
        base = self.global_variant(variant)
        load_program(backend, _primary_step(base), base, _device_scene(fx["scene"], backend).features(base),
                     RT_WRITE_HITS=1)
        return spec_, fx, backend, variant

    @staticmethod
    def global_variant(variant):
        return variant.with_(node_memory="global", constants="constant", ray_memory="registers")

    def run(self, state):
        from ..device.rendering import render
        spec, fx, backend, variant = state
        got = self.render(state)
        base = render(fx["scene"], backend, self.global_variant(variant), write_hits=True)
        what = _path_name(backend) if variant.node_memory == "texture" else variant.label()
        same, diff_msg = _hit_diff_text(base, got, fx["scene"].camera.width, what)
        checked = self.check(state, got)
        data = {**checked.data, "differ_from_global": int(not same)}
        fraction = 1.0 if same and checked.fraction >= 1.0 else 0.0
        return Outcome(fraction, f"{variant.label()}: {diff_msg}\nagainst the float64 reference: {checked.output}",
                       data)


class NvccKind(Kind):
    """The step's CUDA kernel compiled offline by nvcc (graders have no NVIDIA GPU; the lab asks for
    the API in both languages): it must compile, the listed student ``functions`` must be written (not
    the template's stub), and the PTX must show the placement: texture fetches of int and float data
    for node_memory = "texture", the ray stored in shared memory for ray_memory = "shared".
    Reports registers, stack, spills and shared memory per kernel (ptxas -v). Without nvcc on the
    grading machine the test is skipped (0 points) and says so."""
    name = "nvcc"
    params = {"kernel": "", "traversal": "", "intersection": "", "node_memory": "", "constants": "",
              "ray_memory": "", "block": None, "functions": [], "arch": "sm_90"}

    def setup(self, spec, fixture, backend):
        from ..device.scene import scene_features, scene_kdtree
        from ..device.kernels import build_defines, build_options, kernel_source
        from ..backends.nvcc import nvcc_available, nvcc_ptx, nvcc_resources
        if not nvcc_available():
            return None
        variant = spec_variant(spec)
        scene = fixture["scene"]
        defines = build_defines(variant, scene_features(scene, scene_kdtree(scene).depth + 1))
        path = kernel_source(spec.params["kernel"] or fixture["step"], "cuda")
        options = build_options(variant, "cuda")
        arch = spec.params["arch"]
        _tick()
        resources = nvcc_resources(path, defines, arch=arch, block_threads=variant.block[0] * variant.block[1],
                                   extra_options=options)
        _tick()
        return spec, variant, path, resources, nvcc_ptx(path, defines, arch=arch, extra_options=options)

    def run(self, state):
        if state is None:
            return Outcome(0.0, "skipped: nvcc (the CUDA toolkit) is not on PATH on this grading machine, so the "
                                "CUDA kernel was not compiled; the course's grader has it", skipped=True)
        from ..device import kernels
        from .regions import stubbed_functions
        spec, variant, path, resources, ptx = state
        problems = []
        wanted = set(spec.params["functions"])
        stubs = sorted({f for src in [*sorted((kernels.KERNEL_DIR / "shared").glob("*.h")), path]
                        for f in stubbed_functions(src.read_text()) if f in wanted})
        if stubs:
            problems.append(f"{', '.join(stubs)} still hold{'s' if len(stubs) == 1 else ''} the template's stub")
        if variant.node_memory == "texture":
            body = _ptx_entry(ptx, "fetch_scene")
            for kind, pattern in (("int", r"\btex\.1d\.v4\.s32\.s32\b"), ("float", r"\btex\.1d\.v4\.f32\.s32\b")):
                if not re.search(pattern, body):
                    problems.append(f"fetch_scene reads no {kind} data through a texture fetch (no tex.1d ... in its "
                                    f"PTX): the fetch_*_texture functions must read with tex1Dfetch")
        if variant.ray_memory == "shared":
            for kernel in ("render_primary", "trace_rays"):
                r = resources.get(kernel)
                # the ray must be stored into the block's slots (nvcc may then forward the stored values
                # to registers instead of loading them back: no ld.shared is required)
                if r is None or not re.search(r"\bst\.shared\b", _ptx_entry(ptx, kernel)) or not r.shared_bytes:
                    problems.append(f"{kernel} does not store its ray in shared memory (no st.shared in its PTX, "
                                    f"or no shared memory): place_ray_shared must copy the ray into its slot "
                                    f"and return the slot's address")
        report = "; ".join(f"{k}: {r.registers} registers, {r.local_bytes} B stack, {r.spill_bytes} B spills, "
                           f"{r.shared_bytes} B shared" for k, r in sorted(resources.items())
                           if k in ("render_primary", "trace_rays"))
        head = f"{path.name} ({variant.label()}) compiles with nvcc for {spec.params['arch']}: {report}"
        data = {k: {"registers": r.registers, "local_bytes": r.local_bytes, "spill_bytes": r.spill_bytes,
                    "shared_bytes": r.shared_bytes} for k, r in resources.items()}
        if problems:
            return Outcome(0.0, head + "\n" + "\n".join(problems), data)
        return Outcome(1.0, head, data)


def _ptx_entry(ptx: str, kernel: str) -> str:
    m = re.search(rf"\.entry {re.escape(kernel)}\b.*?\n}}", ptx, re.S)
    return m.group(0) if m else ""


KINDS: dict[str, Kind] = {k.name: k for k in (CompileKind(), CameraRaysKind(), TraceRaysKind(), RenderKind(),
                                              IntersectLoopKind(), WhittedKind(), SpeedKind(),
                                              FetchSceneKind(), PlacementKind(), NvccKind())}
