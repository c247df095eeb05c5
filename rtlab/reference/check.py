"""Error against the float64 reference: the "error" half of every error-against-run-time report."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene.model import Camera, Scene, scene_fingerprint


@dataclass
class RenderCheck:
    hits: object            # rtlab.reference.metrics.HitComparison
    rmse: float             # image RMSE in [0, 1] units against the reference shading
    psnr: float
    reference_image: np.ndarray

    def summary(self) -> str:
        psnr = "inf" if np.isinf(self.psnr) else f"{self.psnr:.1f} dB"
        return f"{self.hits.summary()}; image RMSE {self.rmse:.2e}, PSNR {psnr}"

    def as_dict(self) -> dict:
        h = self.hits
        return {"rays": h.n_rays, "mismatches": h.n_mismatch, "ties": h.n_ties,
                "mismatch_rate": h.n_mismatch / max(h.n_rays, 1),
                "t_rel_err_max": h.t_rel_err_max, "rmse": self.rmse, "psnr": self.psnr}


_camera_hits: dict = {}
_CAMERA_HITS_KEPT = 4


def reference_camera_hits(scene: Scene, camera: Camera):
    """float64 reference hits of the camera's primary rays (the same float32 rays the kernels trace).
    Kept for the last few (geometry, camera) pairs: a bench compares many variants against one view."""
    from . import reference_trace
    from ..scene.model import camera_rays
    # keyed by content, not id(): an edited scene must not get the hits of its old geometry
    key = (scene_fingerprint(scene), tuple(camera.eye), tuple(camera.target), tuple(camera.up), camera.fov_deg,
           camera.width, camera.height)
    hit = _camera_hits.get(key)
    if hit is not None:
        return hit
    o, d = camera_rays(camera)
    result = (o, d, reference_trace(scene.vertices, scene.faces, o, d))
    if len(_camera_hits) >= _CAMERA_HITS_KEPT:
        _camera_hits.pop(next(iter(_camera_hits)))
    _camera_hits[key] = result
    return result


def check_hits(scene: Scene, origins, directions, tri, t, ref=None):
    from . import compare_hits, reference_trace
    if ref is None:
        ref = reference_trace(scene.vertices, scene.faces, origins, directions)
    return compare_hits(ref, tri, t, scene.vertices, scene.faces, origins, directions)


def check_render(scene: Scene, result, camera: Camera) -> RenderCheck:
    """Compare a render made with ``write_hits=True`` against the float64 reference."""
    from . import compare_hits, image_rmse_psnr
    from .shading import reference_shade, to_rgb8
    o, d, ref = reference_camera_hits(scene, camera)
    comparison = compare_hits(ref, result.hits.tri, result.hits.t, scene.vertices, scene.faces, o, d)
    ref_rgb = to_rgb8(reference_shade(scene, o, d, ref.tri, ref.t, ref.u, ref.v))
    ref_img = ref_rgb.reshape(camera.height, camera.width, 3)
    rmse, psnr = image_rmse_psnr(result.image, ref_img)
    return RenderCheck(comparison, float(rmse), float(psnr), ref_img)
