"""float64 reference of Whitted ray tracing as the kernels define it (kernels/shared/rt_whitted.h):
point lights with Lambert and a Blinn-Phong highlight, shadow rays, reflection and refraction to a
given number of bounces, Schlick's Fresnel or a fixed split, total internal reflection.

It shares no code with the kernels: the same model written again in numpy float64, with rays cast by
:func:`rtlab.reference.reference_trace` (a float64 BVH and the watertight test). Secondary and
shadow rays start exactly on the surface and skip a tiny ``tmin`` instead of the kernels' spawn
offset. Meant for small images (a few thousand pixels).

The model (keep in sync with the comment atop rt_whitted.h):
  local   c = wd kd ambient + sum_lights V L [wd kd (ns.l) + ks max(ns.h, 0)^shininess],
          wd = max(0, 1 - reflectivity - transparency), for lights with ns.l > 0 and ng.l > 0
  split   kr = reflectivity + transparency F, kt = transparency (1 - F); F = Schlick (R0 from the
          ior, cosine on the less dense side) or 0 (fixed split), 1 under total internal reflection
  child   weight x kr or kt, spawned when >= MIN_WEIGHT; reflection about ns, refraction by
          eta = 1/ior through a front face (counter-clockwise seen from the ray), ior through a back face
  pixel   sum over the ray tree of weight x local colour (background for a miss), clamped, RGBA8
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..kernel_constants import kernel_constant
from ..scene.materials import AMBIENT, BACKGROUND, MIN_WEIGHT
from ..scene.model import Camera, Scene
from .metrics import image_rmse_psnr
from .shading import to_rgb8
from .tracer import reference_trace

# Tree entry of a node whose ray was not spawned (-1: spawned, missed): the kernels' RT_NO_RAY, so that
# the two trees compare entry by entry
NO_RAY = int(kernel_constant("RT_NO_RAY"))
# A shadow segment ends short of the light by the kernels' RT_SHADOW_GAP_ULPS float32 ulps of the segment's and
# the light's largest |component| (rt_whitted.h's shadow_segment_end says why)
SHADOW_GAP_ULPS = kernel_constant("RT_SHADOW_GAP_ULPS")


def shadow_segment_end(light: np.ndarray, d: np.ndarray) -> np.ndarray:
    """t where each shadow segment p + t d (d = light - p, one a row) ends: rt_whitted.h's, in float64."""
    span = np.abs(d).max(axis=1)
    return 1.0 - SHADOW_GAP_ULPS * 2.0 ** -24 * (1.0 + np.abs(light).max() / span)
# Secondary and shadow rays leave the surface exactly; hits nearer than this, relative to the
# scene's coordinates, are the ray's own surface (float64 rounding is ~1e-16 of them).
TMIN_REL = 1e-9


@dataclass
class ReferenceWhitted:
    color: np.ndarray                  # (N, 3) float64, unclamped sum over the ray tree
    image: np.ndarray                  # (H, W, 3) uint8 as the kernels pack it
    tree: dict                         # node ("P", "PR", "PRT", ...) -> (N,) int64 triangle ids
    n_tir: int = 0                     # refraction rays lost to total internal reflection
    rays: dict = field(default_factory=dict)   # node -> rays traced


@dataclass
class _Rays:
    pixel: np.ndarray   # (R,) int64
    o: np.ndarray       # (R, 3) float64
    d: np.ndarray       # (R, 3) float64
    w: np.ndarray       # (R,) float64
    tmin: np.ndarray    # (R,) float64


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


class _Tracer:
    def __init__(self, scene: Scene, shadows: bool, fresnel: str, min_weight: float):
        if fresnel not in ("schlick", "fixed"):
            raise ValueError(f"fresnel must be 'schlick' or 'fixed', not {fresnel!r}")
        self.scene = scene
        self.shadows = shadows
        self.schlick = fresnel == "schlick"
        self.min_weight = min_weight
        self.v = scene.vertices.astype(np.float64)
        self.f = scene.faces.astype(np.int64)
        self.vn = None if scene.vertex_normals is None else scene.vertex_normals.astype(np.float64)
        mats = scene.materials
        self.kd = np.array([m.diffuse for m in mats], np.float64)
        self.ks = np.array([m.specular for m in mats], np.float64)
        self.shininess = np.array([m.shininess for m in mats], np.float64)
        self.refl = np.array([m.reflectivity for m in mats], np.float64)
        self.trans = np.array([m.transparency for m in mats], np.float64)
        self.ior = np.array([m.ior for m in mats], np.float64)
        self.lights = [(np.asarray(l.position, np.float64),
                        np.asarray(l.color, np.float64) * float(l.intensity)) for l in scene.lights]
        self.scale = float(np.abs(self.v).max()) if self.v.size else 1.0
        self.n_tir = 0

    def trace(self, o, d, tmin, tmax=np.inf):
        return reference_trace(self.scene.vertices, self.scene.faces, o, d, tmin, tmax)

    def surface(self, d, tri, u, v):
        """Hit point, geometric and shading normals facing the ray, front face, material."""
        c = self.v[self.f[tri]]
        b0 = (1.0 - u - v)[:, None]
        p = c[:, 0] * b0 + c[:, 1] * u[:, None] + c[:, 2] * v[:, None]
        ng = _unit(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]))
        front = _dot(ng, d) < 0.0
        ng[~front] *= -1.0
        if self.vn is None:
            ns = ng.copy()
        else:
            nv = self.vn[self.f[tri]]
            ns = nv[:, 0] * b0 + nv[:, 1] * u[:, None] + nv[:, 2] * v[:, None]
            # no direction (a file's "vn 0 0 0", normals that cancel): the flat normal, as rt_shade.h
            ns = np.where((np.linalg.norm(ns, axis=1) > 0.0)[:, None], ns, ng)
            ns = _unit(ns)
            ns[_dot(ns, d) > 0.0] *= -1.0
        return p, ng, ns, front, self.scene.material_ids[tri]

    def local(self, d, p, ng, ns, mat):
        wd = np.maximum(1.0 - self.refl[mat] - self.trans[mat], 0.0)
        kd = self.kd[mat] * wd[:, None]
        c = kd * AMBIENT
        tmin = TMIN_REL * (self.scale + np.abs(p).max(axis=1))
        for position, color in self.lights:
            to_light = position[None, :] - p
            reach = (_dot(ns, to_light) > 0.0) & (_dot(ng, to_light) > 0.0)
            if self.shadows and reach.any():
                idx = np.flatnonzero(reach)
                length = np.linalg.norm(to_light[idx], axis=1)
                blocked = self.trace(p[idx], to_light[idx], tmin[idx] / length, shadow_segment_end(position, to_light[idx])).tri >= 0
                reach[idx[blocked]] = False
            l = _unit(to_light)
            h = _unit(l - d)
            with np.errstate(invalid="ignore"):
                spec = np.maximum(_dot(ns, h), 0.0) ** self.shininess[mat]
            lit = kd * _dot(ns, l)[:, None] + self.ks[mat] * spec[:, None]
            c += np.where(reach[:, None], lit * color[None, :], 0.0)
        return c

    def split(self, d, ns, front, mat):
        """kr, kt, the refracted directions (NaN under total internal reflection), TIR mask."""
        r, t, ior = self.refl[mat], self.trans[mat], self.ior[mat]
        eta = np.where(front, 1.0 / ior, ior)
        cos_i = -_dot(d, ns)
        sin2_t = eta * eta * np.maximum(1.0 - cos_i * cos_i, 0.0)
        tir = (t > 0.0) & (sin2_t > 1.0)
        cos_t = np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
        refracted = eta[:, None] * d + (eta * cos_i - cos_t)[:, None] * ns
        if self.schlick:
            r0 = ((1.0 - ior) / (1.0 + ior)) ** 2
            cos = np.where(eta > 1.0, cos_t, cos_i)
            fresnel = r0 + (1.0 - r0) * (1.0 - cos) ** 5
        else:
            fresnel = np.zeros_like(r)
        fresnel = np.where(tir, 1.0, fresnel)
        transmits = t > 0.0
        kr = r + np.where(transmits, t * fresnel, 0.0)
        kt = np.where(transmits, t * (1.0 - fresnel), 0.0)
        return kr, kt, refracted, tir


def reference_whitted(scene: Scene, camera: Camera | None = None, bounces: int = 0, shadows: bool = True,
                      fresnel: str = "schlick", min_weight: float = MIN_WEIGHT) -> ReferenceWhitted:
    """Render the scene's (or ``camera``'s) view: the image, the unclamped colours and the ray tree
    (triangle id of every node's ray per pixel; NO_RAY where a node spawned none)."""
    from ..scene.model import camera_rays
    camera = camera or scene.camera
    tracer = _Tracer(scene, shadows, fresnel, min_weight)
    o32, d32 = camera_rays(camera)
    n = o32.shape[0]
    color = np.zeros((n, 3))
    tree: dict = {}
    counts: dict = {}
    stack = [("P", _Rays(np.arange(n), o32.astype(np.float64), d32.astype(np.float64), np.ones(n), np.zeros(n)))]
    while stack:
        node, rays = stack.pop()
        hits = tracer.trace(rays.o, rays.d, rays.tmin)
        ids = np.full(n, NO_RAY, np.int64)
        ids[rays.pixel] = hits.tri
        tree[node] = ids
        counts[node] = len(rays.pixel)
        hit = hits.tri >= 0
        c = np.tile(np.asarray(BACKGROUND, np.float64), (len(rays.pixel), 1))
        if hit.any():
            d = rays.d[hit]
            p, ng, ns, front, mat = tracer.surface(d, hits.tri[hit], hits.u[hit], hits.v[hit])
            c[hit] = tracer.local(d, p, ng, ns, mat)
        np.add.at(color, rays.pixel, c * rays.w[:, None])
        level = len(node) - 1
        if level >= bounces or not hit.any():
            continue
        kr, kt, refracted, tir = tracer.split(d, ns, front, mat)
        w = rays.w[hit]
        children = []
        for letter, k, direction in (("R", kr, d - 2.0 * _dot(d, ns)[:, None] * ns), ("T", kt, refracted)):
            wc = w * k
            spawn = wc >= min_weight
            if letter == "T":
                tracer.n_tir += int(np.count_nonzero(tir & (w * tracer.trans[mat] >= min_weight)))
                spawn &= ~tir
            if spawn.any():
                tmin = TMIN_REL * (tracer.scale + np.abs(p[spawn]).max(axis=1))
                children.append((node + letter, _Rays(rays.pixel[hit][spawn], p[spawn], direction[spawn],
                                                      wc[spawn], tmin)))
        stack.extend(reversed(children))   # reflection subtree first, as the host walks it
    image = to_rgb8(color).reshape(camera.height, camera.width, 3)
    return ReferenceWhitted(color, image, tree, tracer.n_tir, counts)


@dataclass
class WhittedAccuracy:
    """A kernel image against the reference: image error and ray-tree agreement."""
    rmse: float
    psnr: float
    tree_pixels: int                 # pixels where some node of the ray tree hit another triangle
    pixels: int
    color_max_same_tree: int         # largest 8-bit difference where the trees agree
    color_p99_same_tree: float       # its 99th percentile

    def summary(self) -> str:
        psnr = "inf" if np.isinf(self.psnr) else f"{self.psnr:.1f} dB"
        return (f"PSNR {psnr}, RMSE {self.rmse:.2e}, ray tree differs in {self.tree_pixels} of {self.pixels} "
                f"pixels; same tree: max |d| {self.color_max_same_tree}/255, p99 {self.color_p99_same_tree:.0f}/255")

    def as_dict(self) -> dict:
        return dict(vars(self))


def node_ids(tree: dict, node: str, n: int) -> np.ndarray:
    """(N,) int64 triangle ids of one node of a ray tree: NO_RAY where the node is missing or spawned
    no ray, -1 where its ray missed."""
    ids = np.asarray(tree.get(node, np.full(n, NO_RAY)), np.int64)
    return np.where(ids < 0, np.maximum(ids, NO_RAY), ids)


def tree_differs(tree_a: dict, tree_b: dict, n: int) -> np.ndarray:
    """(N,) bool: pixels whose ray trees differ (a node missing on one side counts as NO_RAY)."""
    differ = np.zeros(n, bool)
    for node in set(tree_a) | set(tree_b):
        differ |= node_ids(tree_a, node, n) != node_ids(tree_b, node, n)
    return differ


def first_tree_difference(tree: dict, ref_tree: dict, n: int) -> tuple[str, int, int, int] | None:
    """The first pixel whose ray tree differs from the reference's, at the shallowest node that
    differs there ("P" primary, "PR" its reflection, ...): (node, pixel, expected id, got id)."""
    first = None
    for node in sorted(set(tree) | set(ref_tree), key=lambda s: (len(s), s)):
        got, expected = node_ids(tree, node, n), node_ids(ref_tree, node, n)
        bad = np.flatnonzero(got != expected)
        if bad.size and (first is None or bad[0] < first[1]):
            first = (node, int(bad[0]), int(expected[bad[0]]), int(got[bad[0]]))
    return first


def whitted_error(image: np.ndarray, tree: dict | None, ref: ReferenceWhitted) -> WhittedAccuracy:
    """Image error of a kernel render against the reference; with the kernel's ray tree (a render
    made with write_hits), the pixels whose trees differ and the colour error where they agree."""
    rmse, psnr = image_rmse_psnr(image, ref.image)
    n = ref.image.shape[0] * ref.image.shape[1]
    differ = tree_differs(tree, ref.tree, n) if tree is not None else np.zeros(n, bool)
    delta = np.abs(image.astype(np.int32) - ref.image.astype(np.int32)).max(axis=2).reshape(-1)[~differ]
    return WhittedAccuracy(rmse, psnr, int(differ.sum()) if tree is not None else -1, n,
                        int(delta.max()) if delta.size else 0,
                        float(np.percentile(delta, 99)) if delta.size else 0.0)
