"""Families 1-5 and 10 of the robustness suite: where a ray meets shared edges and vertices of closed
meshes, split planes and box faces, so a crack or a tie decides between a hit, a miss and another
triangle (leaks, misses, mismatches)."""
from __future__ import annotations

from typing import Callable

import numpy as np

from ..scene.model import Scene
from .cases import (SPHERE_CENTRE, ROOM_HALF, SMALL_SPHERE, STAIR_RISE, STAIR_STEPS, STAIR_WIDTH, Case, box_mesh,
                    case_scene, f32, merge_meshes, quads_mesh, unit_rows)

def family_sphere(n_rays: int, subdivisions: int, seed: int = 1) -> list[Case]:
    """1. Closed icosphere (radius 100) centred at SPHERE_CENTRE; origins within half the radius
    of the centre; a third of the rays in random directions, a third aimed at vertices, a third at
    random points of edges. Every ray starts inside, so every ray must hit."""
    import trimesh
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=100.0)
    centre = np.array(SPHERE_CENTRE)
    scene = case_scene("sphere_far", mesh.vertices + centre, mesh.faces)
    v = scene.vertices.astype(np.float64)
    dirs = rng.normal(size=(n_rays, 3))
    r = 50.0 * rng.uniform(0, 1, n_rays) ** (1 / 3)
    o = f32(centre + unit_rows(rng.normal(size=(n_rays, 3))) * r[:, None]).astype(np.float64)
    third = n_rays // 3
    dirs[third:2 * third] = v[rng.integers(0, len(v), third)] - o[third:2 * third]
    edges = mesh.edges_unique
    e = edges[rng.integers(0, len(edges), n_rays - 2 * third)]
    s = rng.uniform(0, 1, (len(e), 1))
    dirs[2 * third:] = v[e[:, 0]] * (1 - s) + v[e[:, 1]] * s - o[2 * third:]
    return [Case(1, f"icosphere {len(mesh.faces)} tris at (1.5e5, 1.2e3, -2.2e5)", scene, f32(o),
                 f32(unit_rows(dirs)), ("leaks",), must_hit=np.ones(n_rays, bool))]


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
        scene = case_scene(f"plane_{offset:g}", verts, faces)
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
        assert np.array_equal(f32(o).astype(np.float64), o) and np.array_equal(f32(targets), targets)
        cases.append(Case(2, f"exact, {quads}x{quads} quads, offset {offset:g}", scene, f32(o), f32(d),
                          ("misses",), must_hit=np.ones(n_rays, bool)))
    rng = np.random.default_rng(seed + 100)
    offset = 1.0e4
    verts, faces, height = _tilted_grid(quads, offset)
    inner = np.flatnonzero((verts[:, 0] > offset) & (verts[:, 0] < offset + quads)
                           & (verts[:, 1] > offset) & (verts[:, 1] < offset + quads))
    verts[inner] += rng.uniform(-0.25, 0.25, (len(inner), 3))
    scene = case_scene(f"plane_jittered_{offset:g}", verts, faces)
    verts = scene.vertices.astype(np.float64)
    targets = _plane_targets(rng, verts, faces, n_rays, inner)
    normal = unit_rows(np.array([[-0.5, -0.25, 1.0]]))[0]
    d = unit_rows(rng.normal(size=(n_rays, 3)))
    d += normal * (np.sign(d @ normal) * 0.6)[:, None]          # at least ~35 degrees off the plane
    o = f32(targets - d * rng.uniform(1, 20, (n_rays, 1)))
    dirs = f32(targets) - o                                     # rounded in float32
    cases.append(Case(2, f"jittered, {quads}x{quads} quads, offset {offset:g}", scene, o, dirs,
                      ("misses",), must_hit=np.ones(n_rays, bool)))
    return cases


def _split_planes(scene: Scene) -> list[np.ndarray]:
    """Per axis: the kd-tree's split positions and the box faces (vertex coordinates) of the scene."""
    from ..device.device_scene import scene_kdtree
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
    parts = [box_mesh((0, 0, 0), (2, 2, 2)), box_mesh((2, 0, 0), (3, 1, 1)), box_mesh((0.5, 2, 0.5), (1.5, 2.5, 1.5))]
    parts.append(quads_mesh(np.array([[[-2, -1, -2], [5, -1, -2], [5, -1, 5], [-2, -1, 5]],       # floor
                                  [[-1, 0, 3], [4, 0, 3], [4, 3, 3], [-1, 3, 3]],         # wall in z = 3
                                  [[0, 0.5, 3], [1, 0.5, 3], [1, 1.5, 3], [0, 1.5, 3]],   # card on the wall
                                  [[1, 1, -1], [1, 2, -1], [1, 2, 2], [1, 1, 2]]], float)))  # fin in x = 1
    v, f = merge_meshes(parts)
    boxes = case_scene("split_planes", v, f)
    planes = _split_planes(boxes)
    lo, hi = boxes.vertices.min(0).astype(np.float64), boxes.vertices.max(0).astype(np.float64)
    o, d = _axis_rays(rng, n_rays, planes, lo, hi)
    cases = [Case(3, "boxes, quads in split planes", boxes, f32(o), f32(d), ("mismatches",))]

    n = 8
    xs = np.arange(n + 1, dtype=np.float64)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    verts = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    idx = lambda i, j: i * (n + 1) + j
    faces = np.array([t for i in range(n) for j in range(n) for t in
                      ([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)], [idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)])])
    flat = case_scene("flat", verts, faces)
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
    cases.append(Case(3, "flat scene (flat cells)", flat, f32(np.concatenate([o1, o2, o3])),
                      f32(np.concatenate([d1, d2, d3])), ("mismatches",)))
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
    return quads_mesh(np.array(quads, np.float64))


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
    return [Case(4, f"{STAIR_STEPS} steps, {grid}² rays down", case_scene("stairs", v, f), f32(o), f32(d),
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
            cases.append(Case(5, f"scale {s:g}, offset {off:g}", case_scene(f"stairs_{s:g}_{off:g}", v * s + off, f),
                              f32(o * s + off), f32(d), ("mismatches",)))
    return cases


def _signed_zeros(rng, d: np.ndarray) -> np.ndarray:
    """d with each zero component given a random sign (+0 or -0)."""
    d = np.asarray(d, np.float32).copy()
    zero = d == 0.0
    d[zero] = np.where(rng.uniform(size=int(zero.sum())) < 0.5, np.float32(0.0), np.float32(-0.0))
    return d


# Why long: the two scenes and their rays that make family 10 together, each part a few lines.
def family_box_planes(n_rays: int, cubes: int, room_rays: int, seed: int = 10) -> list[Case]:
    """10. (a) cubes^3 unit cubes filling [-cubes/2, cubes/2]^3 (cubes even) or [0, cubes]^3, each
    closed on its own; rays along an axis (60 %) or with one zero component (40 %), lying in grid
    planes (every zero component's coordinate on a plane, 0 included), zeros of random sign: every
    ray whose coordinates lie within the grid hits. (b) a 1e-3 sphere (SMALL_SPHERE) inside a
    closed 1e5 room centred on the origin; rays from inside the sphere as family 1: every ray must
    hit the sphere, not the room behind it. Both scenes lie near the origin, so the BVH takes its
    fused box test (rtlab.device.device_scene.near_origin)."""
    import trimesh
    rng = np.random.default_rng(seed)
    lo = -(cubes // 2) if cubes % 2 == 0 else 0
    v, f = merge_meshes([box_mesh((lo + i, lo + j, lo + k), (lo + i + 1, lo + j + 1, lo + k + 1))
                   for i in range(cubes) for j in range(cubes) for k in range(cubes)])
    grid = case_scene(f"cube_grid_{cubes}", v, f)
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
    o32 = f32(o)
    inside = np.ones(n_rays, bool)
    for b in range(3):
        lies = d32[:, b] == 0.0
        inside &= ~lies | ((o32[:, b] >= lo) & (o32[:, b] <= lo + cubes))
    cases = [Case(10, f"{cubes}^3 unit cubes, rays in their planes, zeros of both signs", grid, o32, d32,
                  ("misses",), must_hit=inside)]

    radius, centre = SMALL_SPHERE
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    room_v, room_f = box_mesh((-ROOM_HALF,) * 3, (ROOM_HALF,) * 3)
    sv = mesh.vertices + np.asarray(centre)
    v, f = merge_meshes([(sv, mesh.faces), (room_v, room_f)])
    room = case_scene("small_sphere_room", v, f)
    vs = room.vertices[:len(sv)].astype(np.float64)
    o = f32(np.asarray(centre) + unit_rows(rng.normal(size=(room_rays, 3))) * (0.5 * radius
                                                                             * rng.uniform(0, 1, (room_rays, 1)) ** (1 / 3)))
    o = o.astype(np.float64)
    dirs = rng.normal(size=(room_rays, 3))
    third = room_rays // 3
    dirs[third:2 * third] = vs[rng.integers(0, len(vs), third)] - o[third:2 * third]
    edges = mesh.edges_unique[rng.integers(0, len(mesh.edges_unique), room_rays - 2 * third)]
    k = rng.uniform(0, 1, (len(edges), 1))
    dirs[2 * third:] = vs[edges[:, 0]] * (1 - k) + vs[edges[:, 1]] * k - o[2 * third:]
    cases.append(Case(10, f"{radius:g} sphere at {centre} in a {2 * ROOM_HALF:g} room", room, f32(o),
                      f32(unit_rows(dirs)), ("leaks",), must_hit=np.ones(room_rays, bool),
                      target_tris=np.arange(len(mesh.faces))))
    return cases
