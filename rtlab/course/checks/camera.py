"""The kind that checks camera_ray() (lab step 00) pixel by pixel through a harness kernel, and names
the common mistake a wrong camera made."""
from __future__ import annotations

import numpy as np

from .base import HARNESS_DIR, Kind, Outcome, Prepared, Produced, percent_text, pixel_namer, vec_text


class CameraRaysKind(Kind):
    """camera_ray() against the host's float32 camera rays (rtlab.scene.model.camera_rays), pixel by pixel,
    through a harness kernel: catches a wrong camera before any traversal runs."""
    name = "camera_rays"
    tolerance = {"direction_abs": 1e-5, "origin_rel": 1e-6}

    def prepare(self, spec, scene):
        return Prepared({"scene": scene})

    def setup(self, spec, inputs, backend, count_work=False):
        path = HARNESS_DIR / f"camera_rays{backend.extension}"
        return backend, backend.compile(path, {}), inputs["scene"]

    def produce(self, state, request):
        from ...device.device_scene import frame_constants
        backend, program, scene = state
        cam = scene.camera
        w, h = cam.width, cam.height
        n = w * h
        program.set_constant("frame", frame_constants(cam, scene.bounds(), len(scene.lights), len(scene.materials)))
        bufs = [backend.empty(n * 16) for _ in range(3)]
        program.launch("camera_rays", (w, h), (8, 8), bufs, constants=("frame",))
        o4, d4, inv4 = (backend.to_host(b, np.float32, 4 * n).reshape(n, 4) for b in bufs)
        return Produced({"origins": o4, "directions": d4, "inv_d": inv4})

    def outputs(self, spec, inputs):
        n = inputs["scene"].camera.width * inputs["scene"].camera.height
        return {k: (np.float32, (n, 4)) for k in ("origins", "directions", "inv_d")}

    def check(self, spec, inputs, expected, out):
        from ...scene.model import camera_rays
        cam = inputs["scene"].camera
        a = out.arrays
        return check_camera_rays(cam, a["origins"], a["directions"], a["inv_d"], camera_rays(cam), spec.tolerance)


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
    with np.errstate(divide="ignore", invalid="ignore"):
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
