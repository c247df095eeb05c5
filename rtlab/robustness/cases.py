"""The robustness suite's cases (rtlab.robustness): what a family generator returns, the sizes of the
"test" and "bench" suites, the counts' goals, and the mesh helpers the families build scenes with."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from ..scene.model import Camera, Light, Material, Scene

U32 = 2.0 ** -24                # float32 unit roundoff
SPHERE_CENTRE = (1.5e5, 1.2e3, -2.2e5)
STAIR_STEPS = 20
STAIR_RISE = 0.5
STAIR_WIDTH = 10.0
# One program per (test, traversal) serves every generated scene: the traversal stack is sized for
# the deepest tree any of them (or BUNNY/SPONZA) can have, instead of each tree's own depth + 1.
ROBUST_STACK_SIZE = 64
# compare_hits slack for float32 kernels: 16 ulps of the largest coordinate in play (positions of
# vertices and ray origins), as its docstring suggests
TIE_ULPS = 16.0

FAMILY_NAMES = {1: "sphere", 2: "plane", 3: "splits", 4: "stairs", 5: "stairs_scaled", 6: "slivers",
                7: "grazing", 8: "bad_rays", 9: "random", 10: "box_planes", 11: "spawn_offsets", 12: "dir_lengths",
                13: "slivers_grazing", 14: "ties", 15: "spawned"}
ALL_FAMILIES = tuple(sorted(FAMILY_NAMES))
TRACED_FAMILIES = tuple(f for f in ALL_FAMILIES if f != 11)     # family 11 renders images
# count -> families where the watertight test with the conservative traversal must reach 0
GOALS = {"leaks": (1, 2, 10), "misses": (1, 2, 10), "mismatches": (3, 4, 5, 9, 10, 12, 13, 14, 15),
         "false_hits": (6, 8, 13, 15), "nan_t": ALL_FAMILIES, "failures": ALL_FAMILIES,
         "differs": TRACED_FAMILIES, "t_off": TRACED_FAMILIES}
# Family 11: a pixel is "off" when a channel differs from the float64 reference by more than this
PIXEL_OFF = 16
GLASS_OFFSETS = (0.0, 1.0, 1e1, 1e2, 1e3, 1e4, 1e5)
GLASS_BOUNCES = 3
ROOM_HALF = 5.0e4
SMALL_SPHERE = (1e-3, (1234.5, -987.25, 2345.125))   # radius, centre
DIRECTION_LENGTHS = (1e-30, 1e-20, 1e-10, 1.0, 1e10, 1e20, 1e30)   # t of 1e-40 would overflow float32

# Sizes: "test" keeps PoCL runs short; "bench" is the full suite (127² stairs, 10^5 rays).
SIZES = {
    "test": dict(sphere_subdiv=4, sphere_rays=5000, plane_quads=8, plane_rays=5000, split_rays=1500,
                 stairs_grid=43, scaled_grid=22, slivers=60, sliver_rays=1500, grazing_rays=1500,
                 bad_ray_sets=4, random_rays=1500, random_scenes=("bunny",), grid_cubes=3, plane_rays_axis=1500,
                 room_rays=1500, glass_size=40, glass_offsets=(0.0, 1e1, 1e3, 1e4, 1e5), length_rays=300,
                 grazing_sliver_rays=600, sliver_scenes=("sponza",), tie_rays=900, tie_scenes=("sponza",),
                 spawned_rays=300),
    "bench": dict(sphere_subdiv=5, sphere_rays=100_000, plane_quads=64, plane_rays=50_000,
                  split_rays=50_000, stairs_grid=127, scaled_grid=127, slivers=2000, sliver_rays=50_000,
                  grazing_rays=50_000, bad_ray_sets=40, random_rays=100_000,
                  random_scenes=("bunny", "sponza"), grid_cubes=6, plane_rays_axis=50_000, room_rays=50_000,
                  glass_size=128, glass_offsets=GLASS_OFFSETS, length_rays=10_000,
                  grazing_sliver_rays=20_000, sliver_scenes=("sponza", "kitchen", "conference"), tie_rays=30_000,
                  tie_scenes=("sponza", "kitchen", "conference"), spawned_rays=10_000),
}


@dataclass
class Case:
    """One scene with its rays: what a family generator returns (a family may give several)."""
    family: int
    label: str
    scene: Scene
    origins: np.ndarray          # (N, 3) float32
    directions: np.ndarray       # (N, 3) float32, not necessarily unit length
    counts: tuple[str, ...]      # what this family is about (the counts its goals name)
    must_hit: np.ndarray | None = None   # (N,) bool: rays that cannot escape (closed mesh, plane interior)
    bad: np.ndarray | None = None        # (N,) bool: NaN/Inf/zero-direction rays (must miss)
    target_tris: np.ndarray | None = None  # ids a must_hit ray must hit (None: any); others are leaks
    render: dict | None = None           # family 11: render_whitted options; rays are the camera's pixels
    tie_eps: float = 1e-4                # compare_hits' relative t slack for a tie (family 13: tighter)
    _reference: object = field(default=None, repr=False)

    @property
    def n_rays(self) -> int:
        return int(self.origins.shape[0])

    def reference(self):
        """float64 closest hits (computed once): brute force where it is cheap, else the
        bit-identical BVH tracer; for a render case (family 11) the float64 Whitted render."""
        if self._reference is None and self.render is not None:
            from ..reference.whitted import reference_whitted
            self._reference = reference_whitted(self.scene, bounces=self.render["bounces"])
        if self._reference is None:
            from ..reference import brute_force_trace, reference_trace
            v, f = self.scene.vertices, self.scene.faces
            trace_f64 = brute_force_trace if self.n_rays * f.shape[0] <= 2e7 else reference_trace
            self._reference = trace_f64(v, f, self.origins, self.directions)
        return self._reference

    def tie_abs(self) -> float:
        """World-space slack for compare_hits: TIE_ULPS float32 ulps of the largest coordinate."""
        o = self.origins[np.isfinite(self.origins).all(1)]
        scale = max(float(np.abs(self.scene.vertices).max()), float(np.abs(o).max()) if o.size else 0.0)
        ext = float(np.ptp(self.scene.vertices, axis=0).max())
        return TIE_ULPS * U32 * (scale + ext)


def case_scene(name: str, vertices, faces) -> Scene:
    """A robustness scene: one material, one light, a camera on the box (only rays given are traced).
    Every generated scene has the same shading features, so they share compiled programs."""
    v = np.ascontiguousarray(np.asarray(vertices, np.float64).astype(np.float32))
    f = np.ascontiguousarray(np.asarray(faces, np.int64).astype(np.int32))
    lo, hi = v.min(0).astype(np.float64), v.max(0).astype(np.float64)
    centre, ext = (lo + hi) / 2, float((hi - lo).max()) or 1.0
    eye = centre + np.array([0.3, 0.5, 1.0]) * 2.0 * ext
    cam = Camera(tuple(eye), tuple(centre), width=64, height=64)
    return Scene(name, v, f, np.zeros(f.shape[0], np.int32), [Material("grey")], cam,
                 [Light(tuple(eye))], None, "procedural")


def quads_mesh(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Q, 4, 3) quad corners in order -> vertices (4Q, 3), faces (2Q, 3): triangles (0,1,2), (0,2,3)."""
    q = corners.shape[0]
    base = 4 * np.arange(q)[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3)
    return corners.reshape(-1, 3), faces


def merge_meshes(parts: Iterable[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    vs, fs, n = [], [], 0
    for v, f in parts:
        vs.append(np.asarray(v, np.float64))
        fs.append(np.asarray(f, np.int64) + n)
        n += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def box_mesh(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """12 triangles of an axis-aligned box, corners shared."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
             [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return c, np.array(faces)


def unit_rows(d: np.ndarray) -> np.ndarray:
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def f32(a) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, np.float64).astype(np.float32))
