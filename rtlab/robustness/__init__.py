"""Stiff and extreme cases for every triangle test and traversal (issue 4's robustness suite).

Nine families of scenes and rays, each checked against the float64 reference
(:func:`rtlab.reference.brute_force_trace`, or the bit-identical BVH :func:`reference_trace` when
brute force would be slow):

1. ``sphere``: a closed, finely tessellated sphere far from the origin (centre (1.5e5, 1.2e3,
   -2.2e5)), rays from inside, aimed at random directions, at vertices and at points on edges:
   **leaks** (a ray from inside a closed mesh that hits nothing escaped through a crack).
2. ``plane``: a tiled (tilted) plane, rays through interior vertices and points on interior edges:
   exactly (integer directions, dyadic coordinates, at offsets 0 and 1e4), and as a renderer aims
   them (a jittered height field at 1e4, d = p - o rounded in float32): **misses**.
3. ``splits``: axis-aligned rays whose origins lie on the kd-tree's split planes and box faces,
   triangles lying in split planes; a flat scene whose every cell has zero thickness: **mismatches**.
4. ``stairs``: 20 axis-aligned steps, rays straight down on a grid (127² in the benchmark) that puts
   every sixth column exactly in a riser's plane, onto a tread's edge: closest hit and t.
5. ``stairs_scaled``: the same at scales 1e-3, 1, 1e3 and offsets up to 1e4: mismatches.
6. ``slivers``: slivers, needles and zero-area triangles: **no false hits, no NaN t**.
7. ``grazing``: rays 1e-1 to 1e-6 rad off large triangles: mismatches.
8. ``bad_rays``: NaN/Inf in origin or direction, zero directions: **no crash, no hang**, all misses.
9. ``random``: random rays on BUNNY and SPONZA (10^5 in the benchmark): mismatches.

Issue 13 added three:

10. ``box_planes``: a grid of unit cubes around the origin, axis-aligned rays (and rays with one
    zero component) lying in its planes, zeros of both signs; a 1e-3 sphere in a 1e5 room, rays
    from inside the sphere: **misses** and **leaks** (the BVH's fused box test, RT_BVH_BOX_FMA, on
    near the origin: it must keep what the exact box test keeps).
11. ``spawn_offsets``: the glass scene (:func:`rtlab.scene.materials.glass_scene`) moved to offsets 0
    and 1e0..1e5, and spheres on a 2000-wide mirror floor at the origin, rendered with shadows and 3
    bounces against the float64 Whitted reference: **pixels more than 16/255 off** (spawn offsets
    too small give acne on large triangles, too large ones speckle scenes far from the origin).
12. ``dir_lengths``: the same rays with directions of length 1e-30..1e30: **mismatches** (trace()
    scales directions by powers of two; t comes back in the caller's units).

Counts per row (one row per case x test x traversal):
  leaks       rays that must hit (closed mesh, interior of the plane) and report no hit
  misses      rays the reference hits and the kernel does not (ties at silhouettes included)
  mismatches  closest hit differs and it is not a tie (:func:`rtlab.reference.compare_hits`)
  ties        differs, but the ray cannot decide (shared edge, graze); reported, not an error
  false_hits  a hit on a zero-area triangle, on a triangle the float64 test misses even with the
              tie slack, or any hit of a NaN/Inf/zero-direction ray
  nan_t       a NaN t written by the kernel
  px_off      (family 11) pixels whose colour is more than 16/255 off the float64 reference
  failure     "crash: ..." or "hang (> N s)" when the case ran in a child process and died or stalled

Goals with the watertight test and the conservative traversal (``GOALS``): 0 leaks and 0 misses in
families 1-2 for every traversal, 0 mismatches in 3-5 and 9, 0 false hits and NaN t in 6, no
failure in 8. The other tests' counts are the lesson: they are reported, not hidden.

    rows = run_robustness(get_backend("opencl"), isects=["moller", "watertight"])
    print(rows_table(rows))
"""
from __future__ import annotations

import multiprocessing as mp
import queue as queue_mod
import time
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Callable, Iterable

import numpy as np

from ..errors import RtlabError
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
                7: "grazing", 8: "bad_rays", 9: "random", 10: "box_planes", 11: "spawn_offsets", 12: "dir_lengths"}
# count -> families where the watertight test with the conservative traversal must reach 0
GOALS = {"leaks": (1, 2, 10), "misses": (1, 2, 10), "mismatches": (3, 4, 5, 9, 10, 12), "false_hits": (6, 8),
         "nan_t": tuple(range(1, 13)), "failures": tuple(range(1, 13))}
# Family 11: a pixel is "off" when a channel differs from the float64 reference by more than this
PIXEL_OFF = 16
GLASS_OFFSETS = (0.0, 1.0, 1e1, 1e2, 1e3, 1e4, 1e5)
GLASS_BOUNCES = 3
ROOM_HALF = 5.0e4
SMALL_SPHERE = (1e-3, (1234.5, -987.25, 2345.125))   # radius, centre
DIRECTION_LENGTHS = (1e-30, 1e-20, 1e-10, 1.0, 1e10, 1e20, 1e30)   # t of 1e-40 would overflow float32

# Sizes: "test" keeps PoCL runs short; "bench" is the issue's full suite (127² stairs, 10^5 rays).
SIZES = {
    "test": dict(sphere_subdiv=4, sphere_rays=5000, plane_quads=8, plane_rays=5000, split_rays=1500,
                 stairs_grid=43, scaled_grid=22, slivers=60, sliver_rays=1500, grazing_rays=1500,
                 bad_ray_sets=4, random_rays=1500, random_scenes=("bunny",), grid_cubes=3, plane_rays_axis=1500,
                 room_rays=1500, glass_size=40, glass_offsets=(0.0, 1e1, 1e3, 1e4, 1e5), length_rays=300),
    "bench": dict(sphere_subdiv=5, sphere_rays=100_000, plane_quads=64, plane_rays=50_000,
                  split_rays=50_000, stairs_grid=127, scaled_grid=127, slivers=2000, sliver_rays=50_000,
                  grazing_rays=50_000, bad_ray_sets=40, random_rays=100_000,
                  random_scenes=("bunny", "sponza"), grid_cubes=6, plane_rays_axis=50_000, room_rays=50_000,
                  glass_size=128, glass_offsets=GLASS_OFFSETS, length_rays=10_000),
}


@dataclass
class Case:
    """One scene with its rays: what a family generator returns (a family may give several)."""
    family: int
    label: str
    scene: Scene
    origins: np.ndarray          # (N, 3) float32
    directions: np.ndarray       # (N, 3) float32, not necessarily unit length
    counts: tuple[str, ...]      # what this family is about (the issue's wording)
    must_hit: np.ndarray | None = None   # (N,) bool: rays that cannot escape (closed mesh, plane interior)
    bad: np.ndarray | None = None        # (N,) bool: NaN/Inf/zero-direction rays (must miss)
    target_tris: np.ndarray | None = None  # ids a must_hit ray must hit (None: any); others are leaks
    render: dict | None = None           # family 11: render_whitted options; rays are the camera's pixels
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


@dataclass
class RobustnessRow:
    family: int
    case: str
    isect: str
    traversal: str
    conservative: int
    backend: str
    device: str
    rays: int
    ref_hits: int = 0
    leaks: int = 0
    misses: int = 0
    mismatches: int = 0
    ties: int = 0
    false_hits: int = 0
    nan_t: int = 0
    px_off: int = -1                    # family 11 only
    failure: str = ""
    t_rel_err_max: float = float("nan")
    kernel_ms: float = 0.0
    first_bad: list = field(default_factory=list)   # a few ray indices of mismatches/leaks, for debugging

    @property
    def failures(self) -> int:
        return int(bool(self.failure))

    def goal_violations(self) -> dict[str, int]:
        """Counts that miss the issue's goal (meaningful for the watertight, conservative rows)."""
        return {k: getattr(self, k) for k, fams in GOALS.items() if self.family in fams and getattr(self, k)}


# ---------------------------------------------------------------------------------------------
# Scene helpers
# ---------------------------------------------------------------------------------------------
def _scene(name: str, vertices, faces) -> Scene:
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


def _quads(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Q, 4, 3) quad corners in order -> vertices (4Q, 3), faces (2Q, 3): triangles (0,1,2), (0,2,3)."""
    q = corners.shape[0]
    base = 4 * np.arange(q)[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3)
    return corners.reshape(-1, 3), faces


def _merge(parts: Iterable[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    vs, fs, n = [], [], 0
    for v, f in parts:
        vs.append(np.asarray(v, np.float64))
        fs.append(np.asarray(f, np.int64) + n)
        n += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def _box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """12 triangles of an axis-aligned box, corners shared."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
             [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return c, np.array(faces)


def _unit(d: np.ndarray) -> np.ndarray:
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _f32(a) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, np.float64).astype(np.float32))


# ---------------------------------------------------------------------------------------------
# The nine families
# ---------------------------------------------------------------------------------------------
def family_sphere(n_rays: int, subdivisions: int, seed: int = 1) -> list[Case]:
    """1. Closed icosphere (radius 100) centred at SPHERE_CENTRE; origins within half the radius
    of the centre; a third of the rays in random directions, a third aimed at vertices, a third at
    random points of edges. Every ray starts inside, so every ray must hit."""
    import trimesh
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=100.0)
    centre = np.array(SPHERE_CENTRE)
    scene = _scene("sphere_far", mesh.vertices + centre, mesh.faces)
    v = scene.vertices.astype(np.float64)
    dirs = rng.normal(size=(n_rays, 3))
    r = 50.0 * rng.uniform(0, 1, n_rays) ** (1 / 3)
    o = _f32(centre + _unit(rng.normal(size=(n_rays, 3))) * r[:, None]).astype(np.float64)
    third = n_rays // 3
    dirs[third:2 * third] = v[rng.integers(0, len(v), third)] - o[third:2 * third]
    edges = mesh.edges_unique
    e = edges[rng.integers(0, len(edges), n_rays - 2 * third)]
    s = rng.uniform(0, 1, (len(e), 1))
    dirs[2 * third:] = v[e[:, 0]] * (1 - s) + v[e[:, 1]] * s - o[2 * third:]
    return [Case(1, f"icosphere {len(mesh.faces)} tris at (1.5e5, 1.2e3, -2.2e5)", scene, _f32(o),
                 _f32(_unit(dirs)), ("leaks",), must_hit=np.ones(n_rays, bool))]


def _tilted_grid(n: int, offset: float) -> tuple[np.ndarray, np.ndarray, Callable]:
    """n x n unit quads on z = 0.5 x + 0.25 y + 3 (every vertex and edge midpoint exact in float32
    for offsets up to 1e4), diagonals alternating in a checkerboard."""
    height = lambda x, y: 0.5 * x + 0.25 * y + 3.0
    xs = offset + np.arange(n + 1, dtype=np.float64)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    verts = np.stack([gx.ravel(), gy.ravel(), height(gx, gy).ravel()], 1)
    idx = lambda i, j: i * (n + 1) + j
    faces = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            faces += [[a, b, c], [a, c, d]] if (i + j) % 2 == 0 else [[a, b, d], [b, c, d]]
    return verts, np.array(faces), height


def _plane_targets(rng, verts, faces, n_rays, inner) -> np.ndarray:
    """Interior vertices (a third) and points k/8 along interior edges (edges of two triangles)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    inner_edges = uniq[counts == 2]
    n_vert = n_rays // 3
    targets = np.empty((n_rays, 3))
    targets[:n_vert] = verts[rng.choice(inner, n_vert)]
    pick = inner_edges[rng.integers(0, len(inner_edges), n_rays - n_vert)]
    k = rng.integers(1, 8, (len(pick), 1)) / 8.0
    targets[n_vert:] = verts[pick[:, 0]] * (1 - k) + verts[pick[:, 1]] * k
    return targets


def family_plane(n_rays: int, quads: int, seed: int = 2) -> list[Case]:
    """2. Rays aimed at interior vertices and at points k/8 along interior edges of a tiled plane,
    from both sides. "exact": small integer directions and dyadic coordinates, so o = p - s d is
    exact in float32 and every ray passes exactly through a shared vertex or edge at t = s.
    "jittered": interior vertices moved off the grid (a closed height field), origins random and
    d = p - o rounded in float32, so each ray passes within an ulp of the vertex or edge, the
    rounding a renderer's rays have."""
    cases = []
    for offset in (0.0, 1.0e4):
        rng = np.random.default_rng(seed)
        verts, faces, height = _tilted_grid(quads, offset)
        scene = _scene(f"plane_{offset:g}", verts, faces)
        inner = np.flatnonzero((verts[:, 0] > offset) & (verts[:, 0] < offset + quads)
                               & (verts[:, 1] > offset) & (verts[:, 1] < offset + quads))
        targets = _plane_targets(rng, verts, faces, n_rays, inner)
        d = rng.integers(-3, 4, (n_rays, 3)).astype(np.float64)
        d[:, 2] = rng.choice([-4.0, -3.0, -2.0, -1.0, 1.0, 2.0, 3.0, 4.0], n_rays)
        # a direction in the plane (d_z = 0.5 d_x + 0.25 d_y) runs along it and rightly misses
        in_plane = d[:, 2] == height(d[:, 0], d[:, 1]) - 3.0
        d[in_plane, 2] += 1.0
        s = rng.integers(1, 5, (n_rays, 1)).astype(np.float64)
        o = targets - s * d
        assert np.array_equal(_f32(o).astype(np.float64), o) and np.array_equal(_f32(targets), targets)
        cases.append(Case(2, f"exact, {quads}x{quads} quads, offset {offset:g}", scene, _f32(o), _f32(d),
                          ("misses",), must_hit=np.ones(n_rays, bool)))
    rng = np.random.default_rng(seed + 100)
    offset = 1.0e4
    verts, faces, height = _tilted_grid(quads, offset)
    inner = np.flatnonzero((verts[:, 0] > offset) & (verts[:, 0] < offset + quads)
                           & (verts[:, 1] > offset) & (verts[:, 1] < offset + quads))
    verts[inner] += rng.uniform(-0.25, 0.25, (len(inner), 3))
    scene = _scene(f"plane_jittered_{offset:g}", verts, faces)
    verts = scene.vertices.astype(np.float64)
    targets = _plane_targets(rng, verts, faces, n_rays, inner)
    normal = _unit(np.array([[-0.5, -0.25, 1.0]]))[0]
    d = _unit(rng.normal(size=(n_rays, 3)))
    d += normal * (np.sign(d @ normal) * 0.6)[:, None]          # at least ~35 degrees off the plane
    o = _f32(targets - d * rng.uniform(1, 20, (n_rays, 1)))
    dirs = _f32(targets) - o                                     # rounded in float32
    cases.append(Case(2, f"jittered, {quads}x{quads} quads, offset {offset:g}", scene, o, dirs,
                      ("misses",), must_hit=np.ones(n_rays, bool)))
    return cases


def _split_planes(scene: Scene) -> list[np.ndarray]:
    """Per axis: the kd-tree's split positions and the box faces (vertex coordinates) of the scene."""
    from ..device.scene import scene_kdtree
    tree = scene_kdtree(scene)
    inner = ~tree.is_leaf()
    axis, pos = tree.split_axis()[inner], tree.split_pos()[inner]
    out = []
    for a in range(3):
        faces = np.unique(scene.vertices[:, a])
        out.append(np.unique(np.concatenate([pos[axis == a], faces, tree.bounds[:, a]])).astype(np.float64))
    return out


def _axis_rays(rng, n: int, planes: list[np.ndarray], lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned rays: the two other coordinates on split planes/box faces (80 %) or random;
    the start outside the box, or on a split plane of the ray's own axis."""
    o = np.empty((n, 3))
    d = np.zeros((n, 3))
    axis = rng.integers(0, 3, n)
    sign = rng.choice([-1.0, 1.0], n)
    for i in range(n):
        a = axis[i]
        for b in range(3):
            if b == a:
                continue
            o[i, b] = rng.choice(planes[b]) if rng.uniform() < 0.8 else rng.uniform(lo[b], hi[b])
        if rng.uniform() < 0.5:
            o[i, a] = (lo[a] - 1.0) if sign[i] > 0 else (hi[a] + 1.0)
        else:
            o[i, a] = rng.choice(planes[a])
        d[i, a] = sign[i]
    return o, d


def family_splits(n_rays: int, seed: int = 3) -> list[Case]:
    """3. Boxes sharing faces, quads in split planes, and a flat scene (all triangles in z = 0, so
    every kd cell is flat); axis-aligned rays on split planes and faces, and for the flat scene
    also rays lying in the plane (parallel: must miss) and oblique rays through its vertices."""
    rng = np.random.default_rng(seed)
    parts = [_box((0, 0, 0), (2, 2, 2)), _box((2, 0, 0), (3, 1, 1)), _box((0.5, 2, 0.5), (1.5, 2.5, 1.5))]
    parts.append(_quads(np.array([[[-2, -1, -2], [5, -1, -2], [5, -1, 5], [-2, -1, 5]],       # floor
                                  [[-1, 0, 3], [4, 0, 3], [4, 3, 3], [-1, 3, 3]],         # wall in z = 3
                                  [[0, 0.5, 3], [1, 0.5, 3], [1, 1.5, 3], [0, 1.5, 3]],   # card on the wall
                                  [[1, 1, -1], [1, 2, -1], [1, 2, 2], [1, 1, 2]]], float)))  # fin in x = 1
    v, f = _merge(parts)
    boxes = _scene("split_planes", v, f)
    planes = _split_planes(boxes)
    lo, hi = boxes.vertices.min(0).astype(np.float64), boxes.vertices.max(0).astype(np.float64)
    o, d = _axis_rays(rng, n_rays, planes, lo, hi)
    cases = [Case(3, "boxes, quads in split planes", boxes, _f32(o), _f32(d), ("mismatches",))]

    n = 8
    xs = np.arange(n + 1, dtype=np.float64)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    verts = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    idx = lambda i, j: i * (n + 1) + j
    faces = np.array([t for i in range(n) for j in range(n) for t in
                      ([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)], [idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)])])
    flat = _scene("flat", verts, faces)
    planes = _split_planes(flat)
    k = n_rays // 3
    o1 = np.stack([rng.choice(planes[0], k), rng.choice(planes[1], k), rng.choice([-1.0, 1.0], k)], 1)
    d1 = np.zeros((k, 3))
    d1[:, 2] = -np.sign(o1[:, 2])
    o2 = np.stack([rng.choice(planes[0], k), rng.choice(planes[1], k), np.zeros(k)], 1)
    d2 = np.zeros((k, 3))
    d2[np.arange(k), rng.integers(0, 2, k)] = rng.choice([-1.0, 1.0], k)
    m = n_rays - 2 * k
    target = np.stack([rng.integers(1, n, m), rng.integers(1, n, m), np.zeros(m)], 1).astype(np.float64)
    d3 = rng.integers(-2, 3, (m, 3)).astype(np.float64)
    d3[:, 2] = rng.choice([-2.0, -1.0, 1.0, 2.0], m)
    o3 = target - 2.0 * d3
    cases.append(Case(3, "flat scene (flat cells)", flat, _f32(np.concatenate([o1, o2, o3])),
                      _f32(np.concatenate([d1, d2, d3])), ("mismatches",)))
    return cases


def stairs_geometry() -> tuple[np.ndarray, np.ndarray]:
    """STAIR_STEPS axis-aligned steps along x (tread i: x in [i, i+1] at y = (i+1) STAIR_RISE; riser i
    in the plane x = i), z in [0, STAIR_WIDTH], on a floor at y = 0."""
    quads = [[[-1, 0, -1], [-1, 0, STAIR_WIDTH + 1], [STAIR_STEPS + 1, 0, STAIR_WIDTH + 1],
              [STAIR_STEPS + 1, 0, -1]]]
    for i in range(STAIR_STEPS):
        y0, y1 = i * STAIR_RISE, (i + 1) * STAIR_RISE
        quads.append([[i, y1, 0], [i + 1, y1, 0], [i + 1, y1, STAIR_WIDTH], [i, y1, STAIR_WIDTH]])
        quads.append([[i, y0, 0], [i, y1, 0], [i, y1, STAIR_WIDTH], [i, y0, STAIR_WIDTH]])
    return _quads(np.array(quads, np.float64))


def stairs_rays(grid: int) -> tuple[np.ndarray, np.ndarray]:
    """grid² rays straight down from above the top step; x from -0.5 to 20.5 (with grid = 127 every
    sixth column lies exactly in a riser's plane and lands on a tread's edge), z over the width."""
    xs = -0.5 + (STAIR_STEPS + 1.0) * np.arange(grid) / (grid - 1)
    zs = STAIR_WIDTH * np.arange(grid) / (grid - 1)
    gx, gz = np.meshgrid(xs, zs, indexing="ij")
    o = np.stack([gx.ravel(), np.full(gx.size, STAIR_STEPS * STAIR_RISE + 2.0), gz.ravel()], 1)
    d = np.tile([0.0, -1.0, 0.0], (o.shape[0], 1))
    return o, d


def family_stairs(grid: int) -> list[Case]:
    """4. The stairs scene, grid² rays straight down: closest hit and t."""
    v, f = stairs_geometry()
    o, d = stairs_rays(grid)
    return [Case(4, f"{STAIR_STEPS} steps, {grid}² rays down", _scene("stairs", v, f), _f32(o), _f32(d),
                 ("mismatches",))]


def family_stairs_scaled(grid: int, scales=(1e-3, 1.0, 1e3), offsets=(0.0, 1e2, 1e4)) -> list[Case]:
    """5. The stairs scaled by s and moved by (off, off, off): vertices and ray origins are
    transformed in float64 and rounded to float32 once, so far from the origin the steps' edges
    snap to the float32 grid as any scene's would."""
    v, f = stairs_geometry()
    o, d = stairs_rays(grid)
    cases = []
    for s in scales:
        for off in offsets:
            cases.append(Case(5, f"scale {s:g}, offset {off:g}", _scene(f"stairs_{s:g}_{off:g}", v * s + off, f),
                              _f32(o * s + off), _f32(d), ("mismatches",)))
    return cases


def family_slivers(n_tris: int, n_rays: int, seed: int = 6) -> list[Case]:
    """6. Needles (1e-4 thin), slivers (1e-7 thin, often exactly flat once rounded to float32) and
    zero-area triangles (repeated corners, exactly collinear corners), over a large backdrop;
    half the rays aimed at points of those triangles."""
    rng = np.random.default_rng(seed)
    k = n_tris // 3
    p0 = rng.uniform(-10, 10, (n_tris, 3))
    axis = _unit(rng.normal(size=(n_tris, 3)))
    perp = _unit(np.cross(axis, rng.normal(size=(n_tris, 3))))
    length = rng.uniform(2, 10, (n_tris, 1))
    p1 = p0 + axis * length
    p2 = (p0 + p1) / 2
    p2[:k] += perp[:k] * 1e-4 * length[:k]                 # needles
    p2[k:2 * k] += perp[k:2 * k] * 1e-7 * length[k:2 * k]  # slivers
    deg = np.arange(2 * k, n_tris)                          # zero area, three kinds
    p0[deg], p1[deg] = np.round(p0[deg]), np.round(p1[deg])
    p2[deg] = np.where((deg % 3 == 0)[:, None], p1[deg],
                       np.where((deg % 3 == 1)[:, None], 2 * p1[deg] - p0[deg], p0[deg]))
    p1[deg[deg % 3 == 2]] = p0[deg[deg % 3 == 2]]
    tris = np.stack([p0, p1, p2], 1).reshape(-1, 3)
    faces = np.arange(3 * n_tris).reshape(-1, 3)
    back = _quads(np.array([[[-30, -30, -40], [30, -30, -40], [30, 30, -40], [-30, 30, -40]]], float))
    v, f = _merge([(tris, faces), back])
    scene = _scene("slivers", v, f)
    o = np.column_stack([rng.uniform(-15, 15, (n_rays, 2)), np.full(n_rays, 40.0)])
    half = n_rays // 2
    t = rng.integers(0, n_tris, half)
    w = rng.dirichlet([1, 1, 1], half)
    target = np.empty((n_rays, 3))
    target[:half] = np.einsum("ij,ijk->ik", w, np.stack([p0[t], p1[t], p2[t]], 1))
    target[half:] = np.column_stack([rng.uniform(-12, 12, (n_rays - half, 2)), np.full(n_rays - half, -40.0)])
    return [Case(6, f"{k} needles, {k} slivers, {n_tris - 2 * k} zero-area", scene, _f32(o),
                 _f32(_unit(target - o)), ("false_hits", "nan_t"))]


def family_grazing(n_rays: int, seed: int = 7) -> list[Case]:
    """7. A 1000 x 1000 ground (two triangles) and a wall behind it; rays 10^-6..10^-1 rad above
    the ground, aimed at random ground points from 100 to 1000 units away."""
    rng = np.random.default_rng(seed)
    ground = [[-500, 0, -500], [-500, 0, 500], [500, 0, 500], [500, 0, -500]]
    wall = [[-500, -50, 520], [500, -50, 520], [500, 200, 520], [-500, 200, 520]]
    v, f = _quads(np.array([ground, wall], float))
    scene = _scene("grazing", v, f)
    theta = 10.0 ** rng.uniform(-6, -1, n_rays)
    phi = rng.uniform(0, 2 * np.pi, n_rays)
    d = np.column_stack([np.cos(theta) * np.cos(phi), -np.sin(theta), np.cos(theta) * np.sin(phi)])
    target = np.column_stack([rng.uniform(-400, 400, n_rays), np.zeros(n_rays), rng.uniform(-400, 400, n_rays)])
    o = target - d * rng.uniform(100, 1000, (n_rays, 1))
    return [Case(7, "1e-6..1e-1 rad over a 1000² ground", scene, _f32(o), _f32(d), ("mismatches",))]


def bad_rays(n_sets: int, seed: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Valid rays interleaved with rays that have NaN/Inf components or a zero direction."""
    rng = np.random.default_rng(seed)
    specials = [np.nan, np.inf, -np.inf]
    os_, ds, bad = [], [], []
    for _ in range(n_sets):
        o = np.array([rng.uniform(-1, 3), rng.uniform(1, 4), 6.0])
        d = _unit((np.array([rng.uniform(0, 2), rng.uniform(0, 1), 0.5]) - o)[None])[0]
        os_.append(o), ds.append(d), bad.append(False)
        for which in (0, 1):
            for c in range(3):
                for s in specials:
                    oo, dd = o.copy(), d.copy()
                    (oo if which == 0 else dd)[c] = s
                    os_.append(oo), ds.append(dd), bad.append(True)
        for dd in (np.zeros(3), -np.zeros(3), np.full(3, np.nan), np.full(3, np.inf)):
            os_.append(o), ds.append(dd), bad.append(True)
        os_.append(np.full(3, np.nan)), ds.append(d), bad.append(True)
    return _f32(os_), _f32(ds), np.array(bad)


def family_bad_rays(n_sets: int) -> list[Case]:
    """8. NaN/Inf/zero-direction rays mixed with valid ones: no crash, no hang, all bad rays miss."""
    v, f = _merge([_box((0, 0, 0), (2, 1, 0.5)),
                   _quads(np.array([[[-3, -0.5, -3], [4, -0.5, -3], [4, -0.5, 4], [-3, -0.5, 4]]], float))])
    o, d, bad = bad_rays(n_sets)
    return [Case(8, f"{int(bad.sum())} bad rays among {len(bad)}", _scene("bad_rays", v, f), o, d,
                 ("failures", "false_hits"), bad=bad)]


def family_random(n_rays: int, scenes=("bunny", "sponza"), size: int = 64, seed: int = 9) -> list[Case]:
    """9. Random rays from points in and around the scene box, any direction, on the paper's scenes
    (a scene whose file is missing is left out)."""
    from ..scene import load_scene
    from ..paths import find_scene_file
    from ..scene.presets import PRESETS
    cases = []
    for name in scenes:
        preset = PRESETS.get(name)
        if preset is not None and find_scene_file(preset.relpath) is None:
            continue
        # only the geometry matters here: one material and flat normals share compiled programs
        loaded = load_scene(name, size=size)
        scene = _scene(name, loaded.vertices, loaded.faces)
        rng = np.random.default_rng(seed)
        lo, hi = scene.bounds().astype(np.float64)
        ext = hi - lo
        o = rng.uniform(lo - 0.5 * ext, hi + 0.5 * ext, (n_rays, 3))
        d = _unit(rng.normal(size=(n_rays, 3)))
        cases.append(Case(9, f"{name}, {n_rays} random rays", scene, _f32(o), _f32(d), ("mismatches",)))
    return cases


def _signed_zeros(rng, d: np.ndarray) -> np.ndarray:
    """d with each zero component given a random sign (+0 or -0)."""
    d = np.asarray(d, np.float32).copy()
    zero = d == 0.0
    d[zero] = np.where(rng.uniform(size=int(zero.sum())) < 0.5, np.float32(0.0), np.float32(-0.0))
    return d


def family_box_planes(n_rays: int, cubes: int, room_rays: int, seed: int = 10) -> list[Case]:
    """10. (a) cubes^3 unit cubes filling [-cubes/2, cubes/2]^3 (cubes even) or [0, cubes]^3, each
    closed on its own; rays along an axis (60 %) or with one zero component (40 %), lying in grid
    planes (every zero component's coordinate on a plane, 0 included), zeros of random sign: every
    ray whose coordinates lie within the grid hits. (b) a 1e-3 sphere (SMALL_SPHERE) inside a
    closed 1e5 room centred on the origin; rays from inside the sphere as family 1: every ray must
    hit the sphere, not the room behind it. Both scenes lie near the origin, so the BVH takes its
    fused box test (rtlab.device.scene.near_origin)."""
    import trimesh
    rng = np.random.default_rng(seed)
    lo = -(cubes // 2) if cubes % 2 == 0 else 0
    v, f = _merge([_box((lo + i, lo + j, lo + k), (lo + i + 1, lo + j + 1, lo + k + 1))
                   for i in range(cubes) for j in range(cubes) for k in range(cubes)])
    grid = _scene(f"cube_grid_{cubes}", v, f)
    planes = np.arange(lo, lo + cubes + 1, dtype=np.float64)
    axis = rng.integers(0, 3, n_rays)
    o = np.empty((n_rays, 3))
    d = np.zeros((n_rays, 3))
    rows = np.arange(n_rays)
    oblique = rng.uniform(size=n_rays) < 0.4        # moves along a second axis too: one zero component
    second = (axis + 1 + rng.integers(0, 2, n_rays)) % 3
    for b in range(3):                              # on a grid plane (edges where two are), or anywhere
        on_plane = rng.uniform(size=n_rays) < 0.75
        o[:, b] = np.where(on_plane, rng.choice(planes, n_rays), rng.uniform(lo - 0.5, lo + cubes + 0.5, n_rays))
    sign = rng.choice([-1.0, 1.0], n_rays)
    o[rows, axis] = np.where(sign > 0, lo - 1.0, lo + cubes + 1.0)   # outside, heading in
    d[rows, axis] = sign
    # an oblique ray also moves along a second axis, through a point inside the grid halfway across
    start2 = rng.uniform(lo, lo + cubes, n_rays)
    s2 = rng.choice([-1.0, 1.0], n_rays)
    o[oblique, second[oblique]] = start2[oblique] - s2[oblique] * (1.0 + cubes / 2.0)
    d[oblique, second[oblique]] = s2[oblique]
    d32 = _signed_zeros(rng, d)
    o32 = _f32(o)
    inside = np.ones(n_rays, bool)
    for b in range(3):
        lies = d32[:, b] == 0.0
        inside &= ~lies | ((o32[:, b] >= lo) & (o32[:, b] <= lo + cubes))
    cases = [Case(10, f"{cubes}^3 unit cubes, rays in their planes, zeros of both signs", grid, o32, d32,
                  ("misses",), must_hit=inside)]

    radius, centre = SMALL_SPHERE
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    room_v, room_f = _box((-ROOM_HALF,) * 3, (ROOM_HALF,) * 3)
    sv = mesh.vertices + np.asarray(centre)
    v, f = _merge([(sv, mesh.faces), (room_v, room_f)])
    room = _scene("small_sphere_room", v, f)
    vs = room.vertices[:len(sv)].astype(np.float64)
    o = _f32(np.asarray(centre) + _unit(rng.normal(size=(room_rays, 3))) * (0.5 * radius
                                                                             * rng.uniform(0, 1, (room_rays, 1)) ** (1 / 3)))
    o = o.astype(np.float64)
    dirs = rng.normal(size=(room_rays, 3))
    third = room_rays // 3
    dirs[third:2 * third] = vs[rng.integers(0, len(vs), third)] - o[third:2 * third]
    edges = mesh.edges_unique[rng.integers(0, len(mesh.edges_unique), room_rays - 2 * third)]
    k = rng.uniform(0, 1, (len(edges), 1))
    dirs[2 * third:] = vs[edges[:, 0]] * (1 - k) + vs[edges[:, 1]] * k - o[2 * third:]
    cases.append(Case(10, f"{radius:g} sphere at {centre} in a {2 * ROOM_HALF:g} room", room, _f32(o),
                      _f32(_unit(dirs)), ("leaks",), must_hit=np.ones(room_rays, bool),
                      target_tris=np.arange(len(mesh.faces))))
    return cases


def moved_scene(scene: Scene, offset) -> Scene:
    """The scene, its camera and its lights moved by ``offset`` (float64, rounded to float32 once)."""
    off = np.asarray(offset, np.float64)
    cam = scene.camera
    camera = Camera(tuple(np.asarray(cam.eye) + off), tuple(np.asarray(cam.target) + off), cam.up, cam.fov_deg,
                    cam.width, cam.height)
    lights = [Light(tuple(np.asarray(light.position) + off), light.color, light.intensity) for light in scene.lights]
    return Scene(f"{scene.name}_at_{off.max():g}", _f32(scene.vertices.astype(np.float64) + off), scene.faces,
                 scene.material_ids, scene.materials, camera, lights, scene.vertex_normals, scene.source)


def mirror_floor_scene(size: int, half: float = 1000.0) -> Scene:
    """Spheres (glass, chrome) and a box on a 2 half-wide floor of two triangles that half-mirrors,
    lit from low and from high: shadow and reflection rays leave points of huge triangles near the
    origin, where a spawn offset below the triangle test's t error shows as acne."""
    import trimesh
    floor = _quads(np.array([[[-half, 0, -half], [-half, 0, half], [half, 0, half], [half, 0, -half]]], float))
    glass = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    glass.apply_translation([0.0, 1.0, 0.0])
    chrome = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    chrome.apply_translation([1.8, 0.7, -0.5])
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    box.apply_translation([-1.7, 0.5, -0.3])
    parts = [floor, (glass.vertices, glass.faces), (chrome.vertices, chrome.faces), (box.vertices, box.faces)]
    v, f = _merge(parts)
    ids = np.concatenate([np.full(len(p[1]), i) for i, p in enumerate(parts)]).astype(np.int32)
    materials = [Material("floor", diffuse=(0.7, 0.7, 0.7), specular=(0.3, 0.3, 0.3), shininess=30.0, reflectivity=0.5),
                 Material("glass", diffuse=(0.9, 0.95, 1.0), specular=(0.8, 0.8, 0.8), shininess=80.0,
                          transparency=0.9, ior=1.5),
                 Material("chrome", diffuse=(0.7, 0.7, 0.7), reflectivity=0.85),
                 Material("red", diffuse=(0.8, 0.2, 0.2))]
    camera = Camera((0.3, 1.6, 5.5), (0.0, 0.6, 0.0), fov_deg=50.0, width=size, height=size)
    return Scene(f"mirror_floor_{2 * half:g}", _f32(v), f.astype(np.int32), ids, materials, camera,
                 [Light((6.0, 0.8, 3.0), intensity=0.9), Light((-5.0, 6.0, 2.0), intensity=0.5)], None, "procedural")


def family_spawn_offsets(size: int, offsets=GLASS_OFFSETS) -> list[Case]:
    """11. The glass scene (a glass sphere and cube, a chrome ball, a checker floor) moved by
    (s, s/2, -s) for s in ``offsets``, and the mirror floor scene at the origin, rendered size x size
    with shadows and GLASS_BOUNCES bounces: pixels more than PIXEL_OFF/255 off the float64 Whitted
    reference."""
    from ..scene.materials import glass_scene
    from ..scene.model import camera_rays
    base = glass_scene(size)
    scenes = [(f"glass scene at {s:g}", moved_scene(base, (s, 0.5 * s, -s))) for s in offsets]
    scenes.append(("mirror floor 2000 wide at the origin", mirror_floor_scene(size)))
    cases = []
    for label, scene in scenes:
        o, d = camera_rays(scene.camera)
        cases.append(Case(11, label, scene, o, d, ("px_off",), render={"bounces": GLASS_BOUNCES}))
    return cases


def family_dir_lengths(n_rays: int, lengths=DIRECTION_LENGTHS, seed: int = 12) -> list[Case]:
    """12. Rays into a unit sphere over a floor (half aimed at the sphere's vertices) with their
    directions scaled to each length in ``lengths`` (rounded to float32 once): the hits must not
    depend on the length."""
    import trimesh
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    floor = _quads(np.array([[[-4, -1, -4], [4, -1, -4], [4, -1, 4], [-4, -1, 4]]], float))
    v, f = _merge([(mesh.vertices, mesh.faces), floor])
    scene = _scene("sphere_floor", v, f)
    o = np.column_stack([rng.uniform(-3, 3, n_rays), rng.uniform(0.5, 3, n_rays), rng.uniform(-3, 3, n_rays)])
    o[::2] *= 1.5
    target = np.where(rng.uniform(size=(n_rays, 1)) < 0.5, mesh.vertices[rng.integers(0, len(mesh.vertices), n_rays)],
                      rng.uniform(-2, 2, (n_rays, 3)) * [1, 0, 1] + [0, -1, 0])
    unit = _unit(target - o)
    return [Case(12, f"direction length {length:g}", scene, _f32(o), _f32(unit * length), ("mismatches",))
            for length in lengths]


def family_cases(family: int, size: str = "test") -> list[Case]:
    """The cases of one family (1-9) at size "test" (PoCL-friendly) or "bench" (the issue's sizes).
    Memoised: the same Scene objects come back, so their device uploads and trees are reused."""
    return _family_cases(int(family), size)


@lru_cache(maxsize=None)
def _family_cases(family: int, size: str) -> list[Case]:
    if size not in SIZES:
        raise RtlabError(f"unknown robustness size '{size}'; choose one of: {', '.join(SIZES)}")
    s = SIZES[size]
    makers = {
        1: lambda: family_sphere(s["sphere_rays"], s["sphere_subdiv"]),
        2: lambda: family_plane(s["plane_rays"], s["plane_quads"]),
        3: lambda: family_splits(s["split_rays"]),
        4: lambda: family_stairs(s["stairs_grid"]),
        5: lambda: family_stairs_scaled(s["scaled_grid"]),
        6: lambda: family_slivers(s["slivers"], s["sliver_rays"]),
        7: lambda: family_grazing(s["grazing_rays"]),
        8: lambda: family_bad_rays(s["bad_ray_sets"]),
        9: lambda: family_random(s["random_rays"], s["random_scenes"]),
        10: lambda: family_box_planes(s["plane_rays_axis"], s["grid_cubes"], s["room_rays"]),
        11: lambda: family_spawn_offsets(s["glass_size"], s["glass_offsets"]),
        12: lambda: family_dir_lengths(s["length_rays"]),
    }
    if family not in makers:
        raise RtlabError(f"unknown robustness family {family}; families: "
                         + ", ".join(f"{k} {v}" for k, v in FAMILY_NAMES.items()))
    return makers[family]()


# ---------------------------------------------------------------------------------------------
# Tracing and counting
# ---------------------------------------------------------------------------------------------
def trace_case(case: Case, backend, isect: str, traversal: str, conservative: int | None = None, **defines):
    """Closest hits of the case's rays: (tri, t, kernel ms). ``conservative`` None keeps the test's
    default RT_CONSERVATIVE (on for watertight), 0/1 forces it; ``defines`` add -D switches
    (e.g. RT_HAS_FP64=0 for the watertight test's float-only path). One stack size for every scene
    (ROBUST_STACK_SIZE), so that a program serves all cases."""
    from ..device.kernels import Variant
    from ..device.tracing import trace
    extra = dict(defines)
    if conservative is not None:
        extra["RT_CONSERVATIVE"] = int(conservative)
    result = trace(case.scene, case.origins, case.directions, backend=backend,
                   variant=Variant(traversal=traversal, intersection=isect), defines=extra,
                   min_stack_size=ROBUST_STACK_SIZE)
    return result.tri, result.t, result.kernel_ms


def count_case(case: Case, ref, tri: np.ndarray, t: np.ndarray, row: RobustnessRow) -> RobustnessRow:
    """Fill the counts of ``row`` from the kernel's hits against the reference."""
    from ..reference import compare_hits, intersect_ray_triangles_f64, usable_triangle_mask
    v, f = case.scene.vertices, case.scene.faces
    tri = np.where(np.asarray(tri) < 0, -1, tri).astype(np.int64)
    cmp = compare_hits(ref, tri, t, v, f, case.origins, case.directions, tie_abs=case.tie_abs())
    k_hit, r_hit = tri >= 0, ref.tri >= 0
    row.ref_hits = int(r_hit.sum())
    row.misses = int((r_hit & ~k_hit).sum())
    row.mismatches, row.ties = cmp.n_mismatch, cmp.n_ties
    row.t_rel_err_max = cmp.t_rel_err_max
    row.nan_t = int(np.isnan(t).sum())
    reached = k_hit if case.target_tris is None else np.isin(tri, case.target_tris)
    if case.must_hit is not None:
        row.leaks = int((case.must_hit & ~reached).sum())
    false = np.zeros(case.n_rays, bool)
    if case.bad is not None:
        false |= case.bad & k_hit
    known = k_hit & (tri < f.shape[0])
    false |= k_hit & ~known
    if known.any():
        idx = np.flatnonzero(known)
        vv = v.astype(np.float64)
        ff = f[tri[idx]]
        usable = usable_triangle_mask(vv[ff[:, 0]], vv[ff[:, 1]], vv[ff[:, 2]])
        # the kernel's triangle in float64 with the same slack compare_hits gives a tie
        from ..reference.metrics import _barycentric_slack
        eps = _barycentric_slack(tri[idx], case.directions[idx].astype(np.float64), v, f, 1e-4, case.tie_abs())
        t64, _, _ = intersect_ray_triangles_f64(case.origins[idx], case.directions[idx], tri[idx], v, f, eps=eps)
        false[idx] |= ~usable | ~np.isfinite(t64)
    row.false_hits = int(false.sum())
    bad_idx = np.flatnonzero(cmp.mismatch | false | ((case.must_hit if case.must_hit is not None else False) & ~reached))
    row.first_bad = bad_idx[:5].tolist()
    return row


# ---------------------------------------------------------------------------------------------
# Isolation: a case whose kernel may crash or hang runs in a child process
# ---------------------------------------------------------------------------------------------
def render_case(case: Case, backend, isect: str, traversal: str, conservative: int | None = None):
    """Family 11: the case's Whitted render, (image, primary hit ids, kernel ms). Shadows one-pass,
    case.render["bounces"] bounces; ``conservative`` as in trace_case (passed as a define)."""
    from ..device.kernels import Variant
    from ..device.whitted import render_whitted
    variant = Variant(traversal=traversal, intersection=isect)
    extra = {} if conservative is None else {"RT_CONSERVATIVE": int(conservative)}
    result = render_whitted(case.scene, backend, variant, bounces=case.render["bounces"], defines=extra)
    return result.image, result.median_ms


def count_render(case: Case, ref, image: np.ndarray, row: RobustnessRow) -> RobustnessRow:
    """Family 11: pixels more than PIXEL_OFF/255 off the float64 reference."""
    delta = np.abs(image.astype(np.int32) - ref.image.astype(np.int32)).max(axis=2)
    row.px_off = int((delta > PIXEL_OFF).sum())
    row.first_bad = np.flatnonzero(delta.reshape(-1) > PIXEL_OFF)[:5].tolist()
    return row


def _trace_or_failure(case, backend, isect, traversal, conservative):
    """trace_case (render_case for family 11), or the error as a failure string (a build error
    fails this combination only)."""
    try:
        if case.render is not None:
            return render_case(case, backend, isect, traversal, conservative)
        return trace_case(case, backend, isect, traversal, conservative)
    except Exception as e:
        return f"error: {type(e).__name__}: {e}"


def _isolated_worker(spec, family, size, case_index, combos, out):
    """Child process: trace one case for each (isect, traversal, conservative), reporting each."""
    from ..backends import get_backend
    backend = get_backend(*spec)
    case = family_cases(family, size)[case_index]
    for i, (isect, traversal, cons) in enumerate(combos):
        out.put(("start", i))
        result = _trace_or_failure(case, backend, isect, traversal, cons)
        out.put(("error", i, result) if isinstance(result, str) else ("done", i, *result))


def _run_isolated(backend, family, size, case_index, combos, timeout_s):
    """Results per combo: (tri, t, ms) or a failure string, surviving crashes and hangs."""
    from ..backends import backend_spec
    ctx = mp.get_context("spawn")
    results: dict[int, object] = {}
    pending = list(range(len(combos)))
    while pending:
        q = ctx.Queue()
        todo = [combos[i] for i in pending]
        proc = ctx.Process(target=_isolated_worker, args=(backend_spec(backend), family, size, case_index,
                                                          todo, q), daemon=True)
        proc.start()
        current, deadline = None, time.monotonic() + timeout_s
        while True:
            try:
                msg = q.get(timeout=max(0.1, min(1.0, deadline - time.monotonic())))
            except queue_mod.Empty:
                if not proc.is_alive() and q.empty():
                    failed = pending[current] if current is not None else pending[0]
                    results[failed] = f"crash: child exited with code {proc.exitcode}"
                    break
                if time.monotonic() > deadline:
                    failed = pending[current] if current is not None else pending[0]
                    results[failed] = f"hang (> {timeout_s:.0f} s)"
                    proc.terminate()
                    proc.join(5)
                    if proc.is_alive():
                        proc.kill()
                    break
                continue
            kind, local = msg[0], msg[1]
            if kind == "start":
                current, deadline = local, time.monotonic() + timeout_s
            elif kind == "done":
                results[pending[local]] = msg[2:]
            else:
                results[pending[local]] = msg[2]
            if len([p for p in pending if p in results]) == len(pending):
                break
        proc.join(5)
        if proc.is_alive():
            proc.kill()
        pending = [p for p in pending if p not in results]
    return [results[i] for i in range(len(combos))]


# ---------------------------------------------------------------------------------------------
# The runner
# ---------------------------------------------------------------------------------------------
def run_robustness(backend, isects: Iterable[str] | None = None, traversals: Iterable[str] | None = None,
                   families: Iterable[int] = tuple(range(1, 10)), size: str = "test",
                   conservative: Iterable[int | None] = (None,), isolate: Iterable[int] = (8,),
                   timeout_s: float = 300.0, progress: Callable[[str], None] | None = None) -> list[RobustnessRow]:
    """Every case of ``families`` x every test x every traversal on ``backend``; one row each.

    isects/traversals default to every name in rtlab.device.kernels.INTERSECTIONS/TRAVERSALS, read at
    call time. ``conservative``: RT_CONSERVATIVE settings to run (None = the test's default).
    Families in ``isolate`` run in a child process, so a crash or a hang (``timeout_s`` per test
    and traversal, compile included) is counted instead of ending the run."""
    from ..device import kernels
    from ..backends import get_backend
    if not hasattr(backend, "compile"):
        backend = get_backend(backend)
    isects = list(isects) if isects is not None else list(kernels.INTERSECTIONS)
    traversals = list(traversals) if traversals is not None else list(kernels.TRAVERSALS)
    for name in isects:
        kernels._lookup(kernels.INTERSECTIONS, name, "intersection test")
    for name in traversals:
        kernels._lookup(kernels.TRAVERSALS, name, "traversal")
    all_combos = [(i, tr, c) for i in isects for tr in traversals for c in conservative]
    isolate = set(isolate)
    rows = []
    for family in families:
        for ci, case in enumerate(family_cases(family, size)):
            if progress:
                progress(f"family {family} ({FAMILY_NAMES[family]}): {case.label}")
            # the packet traversal has no Whitted kernels (its shared stack lives in lab step 03's)
            combos = [c for c in all_combos if case.render is None or c[1] != "packet"]
            ref = case.reference()
            if family in isolate:
                outcomes = _run_isolated(backend, family, size, ci, combos, timeout_s)
            else:
                outcomes = [_trace_or_failure(case, backend, i, tr, c) for i, tr, c in combos]
            for (isect, traversal, cons), out in zip(combos, outcomes):
                eff = int(cons) if cons is not None else int(isect == "watertight")
                row = RobustnessRow(family, case.label, isect, traversal, eff, backend.name, backend.device_name,
                                    case.n_rays)
                if isinstance(out, str):
                    row.failure = out
                elif case.render is not None:
                    image, row.kernel_ms = out
                    count_render(case, ref, image, row)
                else:
                    tri, t, row.kernel_ms = out
                    count_case(case, ref, tri, t, row)
                rows.append(row)
    return rows


def aggregate(rows: list[RobustnessRow]) -> list[RobustnessRow]:
    """Rows summed over the cases of each family (per test, traversal, RT_CONSERVATIVE, backend)."""
    out: dict[tuple, RobustnessRow] = {}
    for r in rows:
        key = (r.family, r.isect, r.traversal, r.conservative, r.backend)
        a = out.get(key)
        if a is None:
            out[key] = replace(r, case=FAMILY_NAMES[r.family], first_bad=list(r.first_bad))
            continue
        for k in ("rays", "ref_hits", "leaks", "misses", "mismatches", "ties", "false_hits", "nan_t"):
            setattr(a, k, getattr(a, k) + getattr(r, k))
        if r.px_off >= 0:                                      # -1: not counted (families other than 11)
            a.px_off = max(a.px_off, 0) + r.px_off
        a.failure = a.failure or r.failure
        a.kernel_ms += r.kernel_ms
        a.t_rel_err_max = float(np.nanmax([a.t_rel_err_max, r.t_rel_err_max]))
    return list(out.values())


TABLE_COLUMNS = ("family", "case", "test", "traversal", "cons.", "rays", "leaks", "misses", "mismatches",
                 "ties", "false hits", "NaN t", "px off", "failure", "max rel dt", "ms")


def row_cells(r: RobustnessRow) -> list[str]:
    dt = "-" if np.isnan(r.t_rel_err_max) else f"{r.t_rel_err_max:.1e}"
    return [str(r.family), r.case, r.isect, r.traversal, str(r.conservative), f"{r.rays:,}", str(r.leaks),
            str(r.misses), str(r.mismatches), str(r.ties), str(r.false_hits), str(r.nan_t),
            "-" if r.px_off < 0 else str(r.px_off), r.failure or "-",
            dt, f"{r.kernel_ms:.1f}"]


def rows_table(rows: list[RobustnessRow]) -> str:
    """A markdown table of the rows (leaks, misses ... per family, test and traversal)."""
    out = ["| " + " | ".join(TABLE_COLUMNS) + " |", "|" + "---|" * len(TABLE_COLUMNS)]
    out += ["| " + " | ".join(row_cells(r)) + " |" for r in rows]
    return "\n".join(out) + "\n"
