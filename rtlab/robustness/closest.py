"""Families 13-15 of the robustness suite: which hit the closest-hit choice takes.

13. ``slivers_grazing``: slivers (SPONZA's own, and made ones) seen at grazing angles, each ray with
    a small square-on blocker just before or just after the sliver (2e-5 of t), and rays spawned off
    the slivers (rtlab.spawn_rays) along them: a t that errs by more than that picks the wrong one, a
    tmin-side error drops the sliver, and a spawned ray hits the sliver it leaves.
14. ``ties``: on the real scenes, rays exactly through vertices lying on the kd-tree's split planes,
    exactly through points of shared edges, and at coplanar overlaps (copies of triangles and halves
    of triangles added at random ids): every traversal must name the very same triangle, the lowest
    id at equal t (count ``differs``).
15. ``spawned``: a box, a sphere and a mirror floor at scales 1e-4..1e3 and offsets up to 1e4, rays
    reflected off the float64 reference's hits through rtlab.spawn_rays: no ray hits the triangle it
    leaves.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from .cases import Case, box_mesh, case_scene, f32, merge_meshes, quads_mesh, unit_rows

# Family 13: a blocker sits this far (relative) before or after the sliver along the ray; the
# comparison's tie slack is a tenth of it, far above a float32 t's rounding (RT_T_ERR)
BLOCKER_GAP = 2e-5
SLIVER_TIE_EPS = 2e-6
SLIVER_ASPECTS = (100.0, 1000.0)       # long side / height of the made slivers


def _scene_geometry(name: str):
    """(vertices, faces) of a scene preset whose file is present, else None (its cases are left out)."""
    from ..paths import find_scene_file
    from ..scene import load_scene
    from ..scene.presets import PRESETS
    preset = PRESETS.get(name)
    if preset is not None and find_scene_file(preset.relpath) is None:
        return None
    s = load_scene(name, size=16)
    return s.vertices, s.faces


def _unit_normals(c: np.ndarray) -> np.ndarray:
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _plane_t(o, d, c) -> np.ndarray:
    """float64 distance along d from o to the plane of corners c (the reference's plane_t)."""
    from ..reference.watertight import plane_t_numpy
    o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
    return plane_t_numpy(c[:, 0] - o, c[:, 1] - o, c[:, 2] - o, d)


def _blockers(o, d, t, which) -> tuple[np.ndarray, np.ndarray]:
    """Small triangles square to each ray o + t d at t (1 - BLOCKER_GAP) (which = -1) or at
    t (1 + BLOCKER_GAP) (+1), none for which = 0; circumradius 1e-3 of the distance, centred on the ray."""
    rows = np.flatnonzero(which != 0)
    o, d = np.asarray(o, np.float64)[rows], np.asarray(d, np.float64)[rows]
    tb = t[rows] * (1.0 + BLOCKER_GAP * which[rows])
    centre = o + d * tb[:, None]
    unit = unit_rows(d)
    a = unit_rows(np.cross(unit, np.where(np.abs(unit[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])))
    b = np.cross(unit, a)
    r = (1e-3 * tb * np.linalg.norm(d, axis=1))[:, None]
    corners = np.stack([centre + r * a, centre + r * (-0.5 * a + 0.866 * b), centre + r * (-0.5 * a - 0.866 * b)], 1)
    return corners.reshape(-1, 3), np.arange(3 * len(rows)).reshape(-1, 3)


def _grazing_rays(rng, c: np.ndarray, n: int):
    """Rays at random points of triangles c (K, 3, 3), along their longest edge (within 0.3 rad in
    the plane) and 10^-3.5..10^-1.5 off the plane, from 0.5..4 sliver lengths away: (o, d) float32."""
    k = rng.integers(0, len(c), n)
    ck = c[k]
    p = np.einsum("ij,ijk->ik", rng.dirichlet([1, 1, 1], n), ck)
    nrm = _unit_normals(ck)
    edges = np.stack([ck[:, 1] - ck[:, 0], ck[:, 2] - ck[:, 1], ck[:, 0] - ck[:, 2]], 1)
    longest = edges[np.arange(n), np.argmax(np.linalg.norm(edges, axis=2), axis=1)]
    length = np.linalg.norm(longest, axis=1)
    along = longest / length[:, None] * rng.choice([-1.0, 1.0], (n, 1))
    side = np.cross(nrm, along)
    turn = rng.uniform(-0.3, 0.3, (n, 1))
    in_plane = along * np.cos(turn) + side * np.sin(turn)
    cos = 10.0 ** rng.uniform(-3.5, -1.5, (n, 1))
    d = in_plane * np.sqrt(1.0 - cos ** 2) + nrm * cos * rng.choice([-1.0, 1.0], (n, 1))
    o = p - d * (length[:, None] * rng.uniform(0.5, 4.0, (n, 1)))
    return f32(o), f32(d), k


def _made_slivers(rng, n: int) -> np.ndarray:
    """(n, 3, 3) slivers 1..5 long, SLIVER_ASPECTS times longer than high, anywhere in [-15, 15]^3."""
    axis = unit_rows(rng.normal(size=(n, 3)))
    perp = unit_rows(np.cross(axis, rng.normal(size=(n, 3))))
    length = rng.uniform(1.0, 5.0, (n, 1))
    height = length / rng.choice(SLIVER_ASPECTS, (n, 1))
    p0 = rng.uniform(-15.0, 15.0, (n, 3))
    p1 = p0 + axis * length
    p2 = p0 + axis * length * rng.uniform(0.2, 0.8, (n, 1)) + perp * height
    return f32(np.stack([p0, p1, p2], 1).reshape(-1, 3)).astype(np.float64).reshape(n, 3, 3)


def _sliver_case(label, rng, vertices, faces, sliver_ids, n_rays, seed_offset=0) -> list[Case]:
    """Grazing rays at the given slivers of a mesh, a third with a blocker before the sliver, a third
    after; and rays spawned off the slivers' float64 hit points along them (the shadow case)."""
    from ..device.spawn import spawn_rays
    from ..reference import reference_trace
    v = np.asarray(vertices, np.float32).astype(np.float64)
    f = np.asarray(faces, np.int64)
    c = v[f[sliver_ids]]
    o, d, k = _grazing_rays(rng, c, n_rays)
    target = sliver_ids[k]
    ref = reference_trace(v, f, o, d)
    on_target = ref.tri == target
    t = _plane_t(o, d, c[k])
    which = np.where(on_target, rng.choice([-1, 0, 1], n_rays), 0)
    bv, bf = _blockers(o, d, t, which)
    mv, mf = merge_meshes([(v, f), (bv, bf)])
    scene = case_scene(f"{label}_blocked", mv, mf)
    cases = [Case(13, f"{label}: {n_rays} grazing rays, {int(np.sum(which != 0))} blockers {BLOCKER_GAP:g} before/after",
                  scene, o, d, ("mismatches", "t_off"), tie_eps=SLIVER_TIE_EPS)]
    # spawned off the slivers along them, to the side the ray arrived from (a light at grazing angle)
    hit = np.flatnonzero(on_target)
    if hit.size:
        hits = SimpleNamespace(tri=ref.tri[hit], u=ref.u[hit].astype(np.float32), v=ref.v[hit].astype(np.float32))
        plain = case_scene(label, v, f)
        out = -np.asarray(d[hit], np.float64)             # back towards the side the ray came from
        nrm = _unit_normals(c[k[hit]])
        facing = np.sign(np.einsum("ij,ij->i", out, nrm))[:, None]
        cos = 10.0 ** rng.uniform(-3.0, -1.0, (hit.size, 1))
        tangent = unit_rows(out - nrm * np.einsum("ij,ij->i", out, nrm)[:, None])
        leave = f32(tangent * np.sqrt(1.0 - cos ** 2) + nrm * facing * cos)
        so, sd = spawn_rays(plain, hits, leave)
        cases.append(Case(13, f"{label}: {hit.size} rays spawned along the slivers", plain, so, sd,
                          ("false_hits", "mismatches"), tie_eps=SLIVER_TIE_EPS))
    return cases


def family_slivers_grazing(n_rays: int, scenes=("sponza",), seed: int = 13) -> list[Case]:
    """13. Made slivers, and each named scene's own (longest edge > 1 % of the scene's extent, height
    below 1 % of it), at grazing angles, with blockers, and spawned rays (see the module docstring)."""
    rng = np.random.default_rng(seed)
    made = _made_slivers(rng, max(16, n_rays // 8))
    cases = _sliver_case("made slivers", rng, made.reshape(-1, 3), np.arange(3 * len(made)).reshape(-1, 3),
                         np.arange(len(made)), n_rays)
    for name in scenes:
        geometry = _scene_geometry(name)
        if geometry is None:
            continue
        v, f = geometry
        c = np.asarray(v, np.float64)[np.asarray(f, np.int64)]
        edges = np.linalg.norm(c - np.roll(c, 1, axis=1), axis=2).max(axis=1)
        area2 = np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
        extent = float(np.ptp(np.asarray(v, np.float64), axis=0).max())
        slivers = np.flatnonzero((edges > 0.01 * extent) & (area2 > 0) & (area2 / edges < 0.01 * edges))
        if slivers.size:
            cases += _sliver_case(f"{name} slivers", rng, v, f, slivers, n_rays)
    return cases


# ---- family 14 ---------------------------------------------------------------------------------

def _exact_rays_through(rng, points: np.ndarray, reach: float, n: int):
    """Rays passing exactly through float32 points, from 0.2..1 ``reach`` away in random directions:
    d in quarters, o = p - d exactly representable in float32 (rays whose o would round are drawn
    again), so the ray meets the point at t = 1 exactly."""
    out_o, out_d = [], []
    p = np.asarray(points, np.float64)
    for _ in range(32):
        k = rng.integers(0, len(p), 4 * n)
        away = unit_rows(rng.normal(size=(4 * n, 3))) * (reach * rng.uniform(0.2, 1.0, (4 * n, 1)))
        d = np.round(away * 4.0) / 4.0
        d[~np.any(d != 0.0, axis=1)] = 0.25
        o = p[k] - d
        ok = np.all(f32(o).astype(np.float64) == o, axis=1)
        out_o.append(o[ok])
        out_d.append(d[ok])
        if sum(len(x) for x in out_o) >= n:
            break
    o, d = np.concatenate(out_o)[:n], np.concatenate(out_d)[:n]
    return f32(o), f32(d)


def _split_vertices(v: np.ndarray, f: np.ndarray, tree) -> np.ndarray:
    """Vertices on a split plane of the kd-tree (a coordinate equal to a split position on that axis)
    with triangles on both sides of it: the kd builder keeps a triangle that only touches a plane on
    its own side, so a ray through such a vertex meets triangles of two cells at the same t."""
    inner = ~tree.is_leaf()
    axis, pos = tree.split_axis()[inner], tree.split_pos()[inner].astype(np.float64)
    corners = v[f]                                             # (F, 3, 3)
    found = np.zeros(len(v), bool)
    for a in range(3):
        on_plane = np.isin(v[:, a], np.unique(pos[axis == a]))
        if not on_plane.any():
            continue
        lo, hi = corners[:, :, a].min(axis=1), corners[:, :, a].max(axis=1)
        below = np.zeros(len(v), bool)
        above = np.zeros(len(v), bool)
        for k in range(3):
            vk = f[:, k]
            at = v[vk, a]
            below[vk[lo < at]] = True                          # a triangle reaching below the vertex's plane
            above[vk[hi > at]] = True
        found |= on_plane & below & above
    return np.flatnonzero(found)


def _shared_edge_midpoints(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Midpoints of edges shared by two triangles that float32 represents exactly."""
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    inner = uniq[counts == 2]
    m = (v[inner[:, 0]] + v[inner[:, 1]]) / 2.0
    return m[np.all(f32(m).astype(np.float64) == m, axis=1)]


def _with_overlaps(rng, v: np.ndarray, f: np.ndarray, k: int):
    """The mesh plus, for k random triangles, an exact copy and the two halves cut at an exactly
    representable edge midpoint, all put at random ids (a copy may come before its original); and
    the triangles so covered twice or three times (new ids)."""
    pick = rng.choice(len(f), k, replace=False)
    extra_v, extra_f = [], []
    nv = len(v)
    for t in pick:
        a, b, c = f[t]
        extra_f.append([a, b, c])
        m = (v[b] + v[c]) / 2.0
        if np.all(f32(m).astype(np.float64) == m):
            extra_v.append(m)
            mi = nv + len(extra_v) - 1
            extra_f += [[a, b, mi], [a, mi, c]]
    allv = np.concatenate([v, np.asarray(extra_v).reshape(-1, 3)])
    allf = np.concatenate([f, np.asarray(extra_f, np.int64)])
    order = rng.permutation(len(allf))
    new_id = np.empty(len(allf), np.int64)
    new_id[order] = np.arange(len(allf))
    covered = new_id[np.concatenate([pick, np.arange(len(f), len(allf))])]
    return allv, allf[order], covered


def family_ties(n_rays: int, scenes=("sponza",), seed: int = 14) -> list[Case]:
    """14. Per named scene whose file is present: rays exactly through vertices on the kd-tree's split
    planes, exactly through shared edges' midpoints, and aimed at coplanar overlaps (see the module
    docstring); origins anywhere in the scene's box. Counted: ``differs`` (ids not the same in every
    traversal) and mismatches against the float64 reference."""
    from ..device.device_scene import scene_kdtree
    rng = np.random.default_rng(seed)
    cases = []
    for name in scenes:
        geometry = _scene_geometry(name)
        if geometry is None:
            continue
        v32, f = geometry
        v, f = np.asarray(v32, np.float64), np.asarray(f, np.int64)
        scene = case_scene(name, v32, f)
        lo, hi = v.min(0), v.max(0)
        inset = 0.05 * (hi - lo)
        reach = 0.05 * float(np.linalg.norm(hi - lo))
        third = n_rays // 3
        split_v = _split_vertices(v, f, scene_kdtree(scene))
        if split_v.size:
            o, d = _exact_rays_through(rng, v[split_v], reach, third)
            cases.append(Case(14, f"{name}: rays exactly through vertices on split planes", scene, o, d,
                              ("differs", "mismatches")))
        mids = _shared_edge_midpoints(v, f)
        if len(mids):
            o, d = _exact_rays_through(rng, mids, reach, third)
            cases.append(Case(14, f"{name}: rays exactly through shared edges", scene, o, d, ("differs", "mismatches")))
        ov, of, covered = _with_overlaps(rng, v, f, max(8, third // 4))
        overlaps = case_scene(f"{name}_overlaps", ov, of)
        m = n_rays - 2 * third
        tri = covered[rng.integers(0, len(covered), m)]
        p = np.einsum("ij,ijk->ik", rng.dirichlet([1, 1, 1], m), ov[of[tri]])
        o = f32(rng.uniform(lo + inset, hi - inset, (m, 3)))
        cases.append(Case(14, f"{name}: coplanar copies and halves at random ids", overlaps, o,
                          f32(p - o.astype(np.float64)), ("differs", "mismatches")))
    return cases


# ---- family 15 ---------------------------------------------------------------------------------

def _spawn_scene_mesh():
    """A unit box standing on a 40-wide floor beside a sphere of radius 0.7."""
    import trimesh
    floor = quads_mesh(np.array([[[-20, 0, -20], [-20, 0, 20], [20, 0, 20], [20, 0, -20]]], float))
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    return merge_meshes([floor, box_mesh((-1.5, 0.0, -0.5), (-0.5, 1.0, 0.5)),
                         (sphere.vertices + [1.0, 0.7, 0.0], sphere.faces)])


def family_spawned(n_rays: int, scales=(1e-4, 1.0, 1e3), offsets=(0.0, 1e2, 1e4), seed: int = 15) -> list[Case]:
    """15. The box, sphere and floor scaled by s and moved by (off, off/2, -off), rays from a camera
    position at random points of the box and sphere, reflected about the geometric normal at the
    float64 reference's hits and spawned there by rtlab.spawn_rays: no self hits (false hits),
    no mismatches."""
    from ..device.spawn import spawn_rays
    from ..reference import reference_trace
    rng = np.random.default_rng(seed)
    v0, f = _spawn_scene_mesh()
    cases = []
    for s in scales:
        for off in offsets:
            shift = np.array([off, off / 2.0, -off])
            scene = case_scene(f"spawn_{s:g}_{off:g}", v0 * s + shift, f)
            v = scene.vertices.astype(np.float64)
            eye = f32(np.array([0.5, 2.5, 6.0]) * s + shift).astype(np.float64)
            targets = v[f[rng.integers(2, len(f), n_rays)]]
            p = np.einsum("ij,ijk->ik", rng.dirichlet([1, 1, 1], n_rays), targets)
            o = f32(np.broadcast_to(eye, p.shape))
            d = f32(p - o.astype(np.float64))
            ref = reference_trace(v, f, o, d)
            hits = SimpleNamespace(tri=ref.tri, u=np.nan_to_num(ref.u).astype(np.float32),
                                   v=np.nan_to_num(ref.v).astype(np.float32))
            c = v[f[np.maximum(ref.tri, 0)]]
            n = _unit_normals(c)
            dd = unit_rows(d.astype(np.float64))
            r = dd - 2.0 * np.einsum("ij,ij->i", dd, n)[:, None] * n
            so, sd = spawn_rays(scene, hits, f32(r))
            cases.append(Case(15, f"scale {s:g}, offset {off:g}: reflections spawned off the hits", scene,
                              so, sd, ("false_hits", "mismatches"), bad=ref.tri < 0))
    return cases
