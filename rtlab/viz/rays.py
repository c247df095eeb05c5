"""A pixel's ray tree for rtlab inspect: its primary ray traced on a backend (rtlab.trace), then its
shadow, reflection and refraction rays through the shading kernels' own spawn functions
(rtlab.device.probes), where the scene has lights and such materials."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import InspectError

@dataclass
class RaySegment:
    kind: str                 # primary, shadow, reflection, refraction
    origin: np.ndarray
    direction: np.ndarray
    t: float                  # distance to the hit (or to the light for a shadow ray)
    tri: int                  # triangle hit; -1 a miss (shadow ray: -1 = the light is visible)
    depth: int = 0
    parent: int = -1          # index of the parent segment in the tree's list
    note: str = ""
    u: float = 0.0
    v: float = 0.0

    @property
    def hit(self) -> bool:
        return self.tri >= 0

    @property
    def hit_point(self) -> np.ndarray:
        return self.origin + self.t * self.direction

    def end(self, miss_length: float) -> np.ndarray:
        t = self.t if np.isfinite(self.t) else miss_length
        return self.origin + t * self.direction


RAY_COLORS = {"primary": "#ffd400", "shadow": "#4a90e2", "shadow-blocked": "#303030",
              "reflection": "#e2474a", "refraction": "#29b36b"}


def _trace_hits(scene, backend, o, d):
    from ..device.tracing import trace
    return trace(scene, np.atleast_2d(o), np.atleast_2d(d), backend=backend)


def expand_shadow(scene, backend, seg: RaySegment, index: int, depth: int) -> list[RaySegment]:
    """Shadow rays from a hit to each light, decided by the shading kernels' own light_visible."""
    if not seg.hit or not scene.lights or seg.kind == "shadow":
        return []
    from ..device.tracing import TraceResult
    from ..device.probes import probe_shadow_rays
    hits = TraceResult(np.array([seg.t], np.float32), np.array([seg.tri], np.int32),
                       np.array([seg.u], np.float32), np.array([seg.v], np.float32), 0.0)
    p = seg.hit_point
    out = []
    for light in scene.lights:
        target = np.asarray(light.position, np.float64)
        visible = bool(probe_shadow_rays(scene, backend, seg.direction[None], hits, target[None])[0])
        dist = float(np.linalg.norm(target - p))
        out.append(RaySegment("shadow", p, (target - p) / max(dist, 1e-30), dist, -1 if visible else 0,
                              depth, index, "light visible" if visible else "blocked"))
    return out


def _expand_secondary(kind: str):
    def expand(scene, backend, seg: RaySegment, index: int, depth: int) -> list[RaySegment]:
        if not seg.hit or seg.kind == "shadow":
            return []
        from ..device.tracing import TraceResult
        from ..device.probes import probe_secondary_rays
        hits = TraceResult(np.array([seg.t], np.float32), np.array([seg.tri], np.int32),
                           np.array([seg.u], np.float32), np.array([seg.v], np.float32), 0.0)
        o, w, d, child = probe_secondary_rays(scene, backend, seg.direction[None].astype(np.float32), hits, kind)
        if not w[0] > 0.0:
            return []
        return [RaySegment(kind, o[0].astype(np.float64), d[0].astype(np.float64), float(child.t[0]),
                           int(child.tri[0]), depth, index, f"weight {w[0]:.3g}", float(child.u[0]), float(child.v[0]))]
    expand.__doc__ = f"The {kind} ray the kernel tree (lab 05) spawns from a hit, with its closest hit."
    return expand


# kind -> expander(scene, backend, parent segment, parent index, depth) -> child segments. A new ray
# kind (e.g. a path tracer's bounce) plugs in here.
RAY_EXPANDERS: dict[str, Callable] = {"shadow": expand_shadow, "reflection": _expand_secondary("reflection"),
                                      "refraction": _expand_secondary("refraction")}


def _wanted_kinds(scene) -> list[str]:
    """Ray kinds the scene calls for: shadows with lights, reflection from mirrors and glass
    (Fresnel), refraction through glass."""
    reflective = any(m.reflectivity > 0 or m.transparency > 0 for m in scene.materials)
    transparent = any(m.transparency > 0 for m in scene.materials)
    return [k for k, on in (("shadow", bool(scene.lights)), ("reflection", reflective),
                            ("refraction", transparent)) if on]


def pixel_ray_tree(scene, x: int, y: int, backend=None, kinds=None, max_depth: int = 3,
                   notes: list | None = None) -> list[RaySegment]:
    """The ray tree of pixel (x, y) of the scene's camera: the primary ray (rtlab.trace on the
    camera ray rtlab.camera_rays builds, the same as camera_ray on the device), then the rays each
    hit spawns, per :data:`RAY_EXPANDERS` (default: what the scene's lights and materials call
    for), down to ``max_depth`` bounces. Segment 0 is the primary ray."""
    from ..scene.model import camera_rays
    cam = scene.camera
    if not (0 <= x < cam.width and 0 <= y < cam.height):
        raise InspectError(f"pixel ({x}, {y}) is outside the {cam.width}x{cam.height} image")
    o, d = camera_rays(cam)
    i = y * cam.width + x
    hit = _trace_hits(scene, backend, o[i], d[i])
    tree = [RaySegment("primary", o[i].astype(np.float64), d[i].astype(np.float64), float(hit.t[0]), int(hit.tri[0]),
                       0, -1, "", float(hit.u[0]), float(hit.v[0]))]
    kinds = _wanted_kinds(scene) if kinds is None else list(kinds)
    frontier = [0]
    for depth in range(1, max_depth + 1):
        nxt = []
        for idx in frontier:
            for kind in kinds:
                try:
                    children = RAY_EXPANDERS[kind](scene, backend, tree[idx], idx, depth)
                except Exception as e:  # an expander that cannot run here (a kernel not built yet)
                    if notes is not None:
                        notes.append(f"{kind} rays not shown: {type(e).__name__}: {e}")
                    kinds = [k for k in kinds if k != kind]
                    continue
                for c in children:
                    tree.append(c)
                    if c.kind != "shadow":
                        nxt.append(len(tree) - 1)
        frontier = nxt
        if not frontier:
            break
    return tree
