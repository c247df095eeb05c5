"""The "edges" ray set of the trace_rays kind (rtlab.course.checks.hits): rays aimed at shared edges and
vertices of a scene's closed meshes, from far away and many at grazing angles, where a triangle test
that is not watertight leaks through the crack between two triangles (float32 Moller-Trumbore: about
a quarter of them on the default scene; Woop et al.'s watertight test: none). Each ray crosses the
surface right at its target, so it must hit one of the triangles that meet there: a miss, or a
triangle behind, is a leak, however near the edge, where compare_hits' rule (b) sees a silhouette
graze and a tie. The grader makes the rays (prepare) and keeps the triangles around each target; the
test process gets the rays alone."""
from __future__ import annotations

import numpy as np

from .base import hit_text, percent_text, ray_namer

EDGE_DISTANCES = (2.0, 200.0)   # origins this many scene extents from their target (log-uniform)
EDGE_GRAZING_SHARE = 0.5        # the share of rays whose cosine to the surface is in EDGE_GRAZING_COS
EDGE_GRAZING_COS = (0.01, 0.1)  # (the others from there to head-on); every triangle around the
                                # target faces the ray at a cosine of at least the first
EDGE_ROUNDING_ULPS = 16.0       # float32 units of (distance + coordinates) a ray may pass off its target
EDGE_DRIFT_SHARE = 0.1          # ... which, stretched along the surface by 1 / cos, stays within this
                                # share of the smallest altitude of the triangles around the target


def closed_mesh_targets(vertices, faces):
    """The shared geometry of a scene's closed meshes: (v (V, 3) float64, faces (F, 3), edges (E, 2)
    vertex ids with their two triangles edge_faces (E, 2), vertices (W,) ids, and every vertex's
    triangles as CSR rows fan_faces[fan_start[i]:fan_start[i + 1]]). A closed mesh: triangles joined
    by edges each shared by exactly two usable triangles that run along it in opposite directions, and
    no other edge (a sphere, a torus; not a ground plane, which has a border, nor a box whose corners
    are not shared)."""
    from ...reference.watertight import mesh_f64, usable_triangle_mask
    v, f = mesh_f64(vertices, faces)
    n_f, n_v = f.shape[0], v.shape[0]
    usable = usable_triangle_mask(v[f[:, 0]], v[f[:, 1]], v[f[:, 2]])
    a, b = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)        # directed edges, three a triangle
    face_of = np.repeat(np.arange(n_f), 3)
    key = np.minimum(a, b) * n_v + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    _, start, counts = np.unique(key[order], return_index=True, return_counts=True)
    i0, i1 = order[start[counts == 2]], order[start[counts == 2] + 1]
    shared = (a[i0] == b[i1]) & (b[i0] == a[i1]) & usable[face_of[i0]] & usable[face_of[i1]]
    i0, i1 = i0[shared], i1[shared]
    edge_faces = np.stack([face_of[i0], face_of[i1]], 1)
    good = np.zeros(a.shape[0], bool)
    good[i0] = good[i1] = True
    # meshes: triangles joined through shared edges, each labelled with its lowest triangle id
    label = np.arange(n_f)
    while True:
        low = np.minimum(label[edge_faces[:, 0]], label[edge_faces[:, 1]])
        new = label.copy()
        np.minimum.at(new, edge_faces[:, 0], low)
        np.minimum.at(new, edge_faces[:, 1], low)
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    closed = ~np.isin(label, label[face_of[~good]]) & usable
    keep = closed[edge_faces[:, 0]]
    by_vertex = np.argsort(a, kind="stable")
    fan_start = np.searchsorted(a[by_vertex], np.arange(n_v + 1))
    return (v, f, np.stack([a[i0], b[i0]], 1)[keep], edge_faces[keep], np.unique(a[closed[face_of]]), fan_start,
            face_of[by_vertex])


def edge_rays(scene, count: int, seed: int, tmin=0.0, tmax=np.inf, test: str = ""):
    """``count`` rays aimed at shared edges and vertices of the scene's closed meshes
    (closed_mesh_targets): half at vertices, half at points 5..95 % along edges, each target rounded
    to float32 and the direction taken from the float32 origin to it, so the ray passes as near its
    target as float32 can. Origins lie EDGE_DISTANCES scene extents away; each direction enters every
    triangle around its target, half of them grazing (EDGE_GRAZING_COS). A ray is kept where float32
    rounding cannot carry its crossing out of the triangles around its target (EDGE_DRIFT_SHARE) and
    the float64 reference's closest hit is one of them (nothing stands in front). Returns origins and
    directions (float32), the triangles around each target ((N, K) ids, -1 padded: the answers a
    watertight test may give, which the grader keeps) and the reference's hits."""
    from ...errors import RtlabError
    from ...reference import reference_trace
    from ...reference.tracer import RefHits
    targets = closed_mesh_targets(scene.vertices, scene.faces)
    if not len(targets[2]):
        raise RtlabError(f"test {test}: scene {scene.name} has no closed mesh whose shared edges and vertices "
                         f"rays could be aimed at; choose another scene")
    v, f = targets[0], targets[1]
    normal = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area2 = np.maximum(np.linalg.norm(normal, axis=1), 1e-300)
    normal /= area2[:, None]
    altitude = area2 / np.linalg.norm(v[f] - v[f[:, [1, 2, 0]]], axis=2).max(axis=1)
    lo, hi = scene.bounds().astype(np.float64)
    extent = float((hi - lo).max())
    rng = np.random.default_rng(seed)
    parts, kept = [], 0
    for _ in range(8):
        o, d, fans = _edge_ray_candidates(rng, 2 * (count - kept) + 64, targets, normal, altitude, extent)
        ref = reference_trace(scene.vertices, scene.faces, o, d, tmin=tmin, tmax=tmax)
        first = ((fans == ref.tri[:, None]) & (fans >= 0)).any(axis=1)
        parts.append((o[first], d[first], fans[first], ref.t[first], ref.tri[first], ref.u[first], ref.v[first]))
        kept += int(first.sum())
        if kept >= count:
            break
    if kept < count:
        raise RtlabError(f"test {test}: only {kept} of the rays aimed at shared edges and vertices of scene "
                         f"{scene.name} reach them unblocked; ask for fewer or choose another scene")
    width = max(p[2].shape[1] for p in parts)
    fans = np.concatenate([np.pad(p[2], ((0, 0), (0, width - p[2].shape[1])), constant_values=-1) for p in parts])
    o, d, t, tri, u, v = (np.concatenate([p[i] for p in parts])[:count] for i in (0, 1, 3, 4, 5, 6))
    return o, d, fans[:count], RefHits(t, tri, u, v)


def _edge_ray_candidates(rng, n: int, targets, normal, altitude, extent: float):
    """``n`` candidate rays for edge_rays (before the reference's check): origins, directions, fans."""
    v, _, edges, edge_faces, verts, fan_start, fan_faces = targets
    n_v = n // 2
    pv = verts[rng.integers(0, len(verts), n_v)]
    pe = rng.integers(0, len(edges), n - n_v)
    valence = fan_start[pv + 1] - fan_start[pv]
    fans = np.full((n, max(int(valence.max(initial=0)), 2)), -1, np.int64)
    col = np.arange(fans.shape[1])
    in_fan = col[None, :] < valence[:, None]
    fans[:n_v][in_fan] = fan_faces[(fan_start[pv][:, None] + col[None, :])[in_fan]]
    fans[n_v:, :2] = edge_faces[pe]
    s = rng.uniform(0.05, 0.95, (n - n_v, 1))
    target = np.concatenate([v[pv], v[edges[pe, 0]] * (1.0 - s) + v[edges[pe, 1]] * s])
    target = target.astype(np.float32).astype(np.float64)
    around = fans >= 0
    fan_normal = np.where(around[..., None], normal[np.maximum(fans, 0)], 0.0)
    mean = fan_normal.sum(axis=1)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
    # a direction into every triangle around the target: against the mean normal, tilted at random
    d = np.full((n, 3), np.nan)
    cos_min = np.zeros(n)
    todo = np.arange(n)
    for _ in range(64):
        if not todo.size:
            break
        k, m = todo.size, mean[todo]
        grazing = rng.uniform(0.0, 1.0, k) < EDGE_GRAZING_SHARE
        cos = np.where(grazing, rng.uniform(*EDGE_GRAZING_COS, k), rng.uniform(EDGE_GRAZING_COS[1], 1.0, k))
        side = rng.normal(size=(k, 3))
        side -= np.einsum("ij,ij->i", side, m)[:, None] * m
        side /= np.linalg.norm(side, axis=1, keepdims=True)
        dk = -cos[:, None] * m + np.sqrt(1.0 - cos ** 2)[:, None] * side
        facing = np.where(around[todo], -np.einsum("ikj,ij->ik", fan_normal[todo], dk), np.inf).min(axis=1)
        ok = facing >= EDGE_GRAZING_COS[0]
        d[todo[ok]], cos_min[todo[ok]] = dk[ok], facing[ok]
        todo = todo[~ok]
    # far, but not so far that float32 rounding carries the crossing away from the target's triangles
    smallest = np.where(around, altitude[np.maximum(fans, 0)], np.inf).min(axis=1)
    reach = np.abs(target).max(axis=1)
    near = EDGE_DISTANCES[0] * extent
    far = np.minimum(EDGE_DISTANCES[1] * extent,
                     (EDGE_DRIFT_SHARE * smallest * cos_min / (EDGE_ROUNDING_ULPS * 2.0 ** -24) - 2.0 * reach) / 2.0)
    usable = np.isfinite(d).all(axis=1) & (far > near)
    dist = np.exp(rng.uniform(np.log(near), np.log(np.maximum(far, near))))
    o = (target - dist[:, None] * np.nan_to_num(d)).astype(np.float32)
    d = target - o.astype(np.float64)
    d = (d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)).astype(np.float32)
    return o[usable], d[usable], fans[usable]


def leaks(fans, tri) -> np.ndarray:
    """(N,) bool: rays whose kernel answer is not one of the triangles around their target (a miss included)."""
    tri = np.asarray(tri).astype(np.int64)
    return ~((fans == tri[:, None]) & (fans >= 0)).any(axis=1)


def edge_ray_namer(origins, directions):
    where = ray_namer(origins, directions)
    return lambda i: "rays aimed at shared edges and vertices" if i is None else where(i)


def describe_leaks(leaked, fans, ref, tri, t, where_of) -> str:
    """The message of rays aimed at shared edges and vertices of closed meshes that got through."""
    n, n_leak = len(leaked), int(leaked.sum())
    tri, t = np.asarray(tri), np.asarray(t, np.float64)
    missed = int((leaked & (tri < 0)).sum())
    with np.errstate(invalid="ignore"):
        behind = int((leaked & (tri >= 0) & (t > ref.t)).sum())   # the kernel's own t: wording only
    kinds = [f"{missed} missed", f"{behind} went on to a triangle behind",
             f"{n_leak - missed - behind} hit another triangle"]
    i = int(np.flatnonzero(leaked)[0])
    around = ", ".join(str(int(x)) for x in fans[i] if x >= 0)
    return (f"{percent_text(n_leak, n)} of rays aimed at shared edges and vertices of closed meshes leaked through "
            f"the surface ({n_leak} of {n}: {', '.join(k for k in kinds if not k.startswith('0 '))}); "
            f"a watertight test hits one of the triangles that meet where a ray crosses; first at {where_of(i)}: "
            f"expected one of triangles {around} (the reference: {hit_text(ref.tri[i], ref.t[i])}), "
            f"got {hit_text(tri[i], t[i])}")
