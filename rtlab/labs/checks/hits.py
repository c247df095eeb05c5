"""Kinds that check a kernel's hits: it compiles, its camera rays, arbitrary rays through
trace_rays, the render of a view, and the paper's Table 3 loop (lab steps 00, 02, 03)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .base import (HARNESS_DIR, Kind, Outcome, describe_hit_errors, describe_image_error, device_scene_of,
                   hits_agree, percent_text, pixel_namer, primary_step_of, ray_namer, require_hits, spec_variant,
                   vec_text)


class CompileKind(Kind):
    """The step's kernel (``kernel`` = another step's, if set) compiles with the submission."""
    name = "compile"
    params = {"kernel": "", "traversal": "", "intersection": "", "node_memory": "", "block": None,
              "defines": {}}

    def setup(self, spec, fixture, backend):
        from ...device.kernels import load_program
        variant = spec_variant(spec)
        ds = device_scene_of(fixture["scene"], backend)
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
        from ...device.scene import frame_constants
        from ...scene.model import camera_rays
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
    where = pixel_namer(cam.width)
    problems = []
    d = d4[:, :3].astype(np.float64)
    err = np.abs(d - exp_d).max(axis=1)
    err = np.where(np.isnan(err), np.inf, err)
    bad = err > tol["direction_abs"]
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        msg = (f"{percent_text(int(bad.sum()), n)} of pixels get a wrong direction ({int(bad.sum())} of {n}); "
               f"first at {where(i)}: expected {vec_text(exp_d[i])}, got {vec_text(d[i])}")
        for hint, alt in _camera_variants(cam).items():
            if np.nanmax(np.abs(d - alt)) < 1e-4:
                msg += f"\nhint: this looks like {hint}"
                break
        problems.append(msg)
    o_err = np.abs(o4[:, :3] - exp_o).max(axis=1) / max(np.abs(exp_o).max(), 1e-30)
    o_err = np.where(np.isnan(o_err), np.inf, o_err)
    if (o_err > tol["origin_rel"]).any():
        i = int(np.flatnonzero(o_err > tol["origin_rel"])[0])
        problems.append(f"ray origins must be the eye {vec_text(exp_o[i])}; at {where(i)} got {vec_text(o4[i, :3])}")
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
                        f"{vec_text(exp_inv[i])}, got {vec_text(inv[i])}")
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
        from ...reference import reference_trace
        o, d = make_rays(scene, spec.params["rays"], int(spec.params["count"]), int(spec.params["seed"]))
        p = spec.params
        ref = reference_trace(scene.vertices, scene.faces, o, d, tmin=p["tmin"], tmax=p["tmax"])
        require_hits(ref, spec)
        return {"origins": o, "directions": d, "ref": ref}

    def setup(self, spec, fixture, backend):
        from ...device.kernels import load_program
        variant = spec_variant(spec)
        ds = device_scene_of(fixture["scene"], backend)
        load_program(backend, primary_step_of(variant), variant, ds.features(variant))
        return spec, fixture, backend, variant

    def run(self, state):
        from ...reference import compare_hits
        from ...device.tracing import trace
        spec, fx, backend, variant = state
        scene, o, d, ref = fx["scene"], fx["origins"], fx["directions"], fx["ref"]
        p = spec.params
        got = trace(scene, o, d, backend=backend, variant=variant, tmin=p["tmin"], tmax=p["tmax"])
        cmp_ = compare_hits(ref, got.tri, got.t, scene.vertices, scene.faces, o, d, tmin=p["tmin"], tmax=p["tmax"])
        ok, msg = describe_hit_errors(cmp_, ref, got.tri, got.t, spec.tolerance, ray_namer(o, d), origins=o)
        return Outcome(1.0 if ok else 0.0, msg, {"mismatches": cmp_.n_mismatch, "rays": cmp_.n_rays,
                                                "kernel_ms": got.kernel_ms})


def make_rays(scene, kind: str, count: int, seed: int):
    """Test rays as float32 (origins, directions)."""
    from ...errors import RtlabError
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
        from ...device.scene import scene_kdtree
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
        from ...reference.shading import reference_shade, to_rgb8
        from ...reference.check import reference_camera_hits
        o, d, ref = reference_camera_hits(scene, scene.camera)
        require_hits(ref, spec)
        img = to_rgb8(reference_shade(scene, o, d, ref.tri, ref.t, ref.u, ref.v))
        return {"origins": o, "directions": d, "ref": ref,
                "ref_image": img.reshape(scene.camera.height, scene.camera.width, 3)}

    def setup(self, spec, fixture, backend):
        from ...device.kernels import load_program
        variant = spec_variant(spec)
        ds = device_scene_of(fixture["scene"], backend)
        load_program(backend, primary_step_of(variant), variant, ds.features(variant), RT_WRITE_HITS=1)
        return spec, fixture, backend, variant

    def render(self, state):
        from ...device.rendering import render
        spec, fx, backend, variant = state
        return render(fx["scene"], backend, variant, write_hits=True)

    def time_of(self, result) -> float:
        return float(result.kernel_ms[0])

    def check(self, state, result) -> Outcome:
        from ...reference import compare_hits
        spec, fx, _, _ = state
        scene, ref = fx["scene"], fx["ref"]
        tri, t = result.hits.tri, result.hits.t
        cmp_ = compare_hits(ref, tri, t, scene.vertices, scene.faces, fx["origins"], fx["directions"])
        ok, msg = describe_hit_errors(cmp_, ref, tri, t, spec.tolerance, pixel_namer(scene.camera.width))
        img_ok, img_msg, psnr = describe_image_error(result.image, fx["ref_image"], spec.tolerance["min_psnr"],
                                                     "the reference shading")
        return Outcome(1.0 if ok and img_ok else 0.0, msg + img_msg,
                       {"mismatches": cmp_.n_mismatch, "pixels": cmp_.n_rays, "psnr": psnr})

    def agree(self, state, got, want) -> tuple[bool, str]:
        """Whether a render matches the reference kernel's render of the same view (speed tests)."""
        spec, fx = state[0], state[1]
        scene = fx["scene"]
        ok, why = hits_agree(got.hits.tri, got.hits.t, want.hits.tri, want.hits.t, want.hits.u, want.hits.v, scene,
                             scene.faces, scene.camera, spec.tolerance, pixel_namer(scene.camera.width))
        if not ok:
            return ok, why
        img_ok, img_msg, _ = describe_image_error(got.image, want.image, spec.tolerance["min_psnr"],
                                                  "the reference kernel's image")
        return img_ok, img_msg.strip()

    def run(self, state):
        return self.check(state, self.render(state))


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
        from ...errors import RtlabError
        from ...reference import reference_trace
        from ...scene.model import camera_rays
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
        require_hits(ref, spec)
        if spec.params["triangles"] == "visible":
            from ...device.scene import scene_kdtree
            scene_kdtree(scene)    # the test process uploads this scene: build its kd-tree once, here
        return {"scene": scene, "origins": o, "directions": d, "ref": ref}

    def setup(self, spec, fixture, backend):
        from ...benches.intersect import INTERSECT_STEP
        from ...device.kernels import load_program
        variant = spec_variant(spec)
        ds = device_scene_of(fixture["scene"], backend)
        load_program(backend, INTERSECT_STEP, variant, ds.features(variant))
        return spec, fixture, backend, variant

    def render(self, state):
        from ...benches.intersect import intersect_loop
        spec, fx, backend, variant = state
        return intersect_loop(fx["scene"], backend, variant.intersection, int(spec.params["n_tris"]),
                              camera=fx["scene"].camera)

    def time_of(self, result) -> float:
        return float(result.kernel_ms[0])

    def check(self, state, result) -> Outcome:
        from ...reference import compare_hits
        spec, fx, _, _ = state
        scene, ref = fx["scene"], fx["ref"]
        faces = scene.faces[:result.n_tris]
        cmp_ = compare_hits(ref, result.tri, result.t, scene.vertices, faces, fx["origins"], fx["directions"])
        ok, msg = describe_hit_errors(cmp_, ref, result.tri, result.t, spec.tolerance,
                                      pixel_namer(scene.camera.width))
        return Outcome(1.0 if ok else 0.0, f"{result.isect}, {result.n_tris} triangles in a loop: {msg}",
                       {"mismatches": cmp_.n_mismatch, "pixels": cmp_.n_rays})

    def agree(self, state, got, want) -> tuple[bool, str]:
        spec, fx = state[0], state[1]
        scene = fx["scene"]
        nan = np.full(len(want.tri), np.nan)     # the loop keeps no barycentrics: ties by equal t only
        return hits_agree(got.tri, got.t, want.tri, want.t, nan, nan, scene, scene.faces[:want.n_tris],
                          scene.camera, spec.tolerance, pixel_namer(scene.camera.width))

    def run(self, state):
        return self.check(state, self.render(state))
