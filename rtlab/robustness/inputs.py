"""Families 6-9 and 12 of the robustness suite: awkward inputs (needles, slivers and zero-area
triangles, grazing rays, NaN/Inf and zero directions, random rays on the paper's scenes, directions
of any length): no false hits, no NaN t, no crash, the same hits whatever the direction's length."""
from __future__ import annotations

import numpy as np

from .cases import DIRECTION_LENGTHS, Case, box_mesh, case_scene, f32, merge_meshes, quads_mesh, unit_rows

def family_slivers(n_tris: int, n_rays: int, seed: int = 6) -> list[Case]:
    """6. Needles (1e-4 thin), slivers (1e-7 thin, often exactly flat once rounded to float32) and
    zero-area triangles (repeated corners, exactly collinear corners), over a large backdrop;
    half the rays aimed at points of those triangles."""
    rng = np.random.default_rng(seed)
    k = n_tris // 3
    p0 = rng.uniform(-10, 10, (n_tris, 3))
    axis = unit_rows(rng.normal(size=(n_tris, 3)))
    perp = unit_rows(np.cross(axis, rng.normal(size=(n_tris, 3))))
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
    back = quads_mesh(np.array([[[-30, -30, -40], [30, -30, -40], [30, 30, -40], [-30, 30, -40]]], float))
    v, f = merge_meshes([(tris, faces), back])
    scene = case_scene("slivers", v, f)
    o = np.column_stack([rng.uniform(-15, 15, (n_rays, 2)), np.full(n_rays, 40.0)])
    half = n_rays // 2
    t = rng.integers(0, n_tris, half)
    w = rng.dirichlet([1, 1, 1], half)
    target = np.empty((n_rays, 3))
    target[:half] = np.einsum("ij,ijk->ik", w, np.stack([p0[t], p1[t], p2[t]], 1))
    target[half:] = np.column_stack([rng.uniform(-12, 12, (n_rays - half, 2)), np.full(n_rays - half, -40.0)])
    return [Case(6, f"{k} needles, {k} slivers, {n_tris - 2 * k} zero-area", scene, f32(o),
                 f32(unit_rows(target - o)), ("false_hits", "nan_t"))]


def family_grazing(n_rays: int, seed: int = 7) -> list[Case]:
    """7. A 1000 x 1000 ground (two triangles) and a wall behind it; rays 10^-6..10^-1 rad above
    the ground, aimed at random ground points from 100 to 1000 units away."""
    rng = np.random.default_rng(seed)
    ground = [[-500, 0, -500], [-500, 0, 500], [500, 0, 500], [500, 0, -500]]
    wall = [[-500, -50, 520], [500, -50, 520], [500, 200, 520], [-500, 200, 520]]
    v, f = quads_mesh(np.array([ground, wall], float))
    scene = case_scene("grazing", v, f)
    theta = 10.0 ** rng.uniform(-6, -1, n_rays)
    phi = rng.uniform(0, 2 * np.pi, n_rays)
    d = np.column_stack([np.cos(theta) * np.cos(phi), -np.sin(theta), np.cos(theta) * np.sin(phi)])
    target = np.column_stack([rng.uniform(-400, 400, n_rays), np.zeros(n_rays), rng.uniform(-400, 400, n_rays)])
    o = target - d * rng.uniform(100, 1000, (n_rays, 1))
    return [Case(7, "1e-6..1e-1 rad over a 1000² ground", scene, f32(o), f32(d), ("mismatches",))]


def bad_rays(n_sets: int, seed: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Valid rays interleaved with rays that have NaN/Inf components or a zero direction."""
    rng = np.random.default_rng(seed)
    specials = [np.nan, np.inf, -np.inf]
    os_, ds, bad = [], [], []
    for _ in range(n_sets):
        o = np.array([rng.uniform(-1, 3), rng.uniform(1, 4), 6.0])
        d = unit_rows((np.array([rng.uniform(0, 2), rng.uniform(0, 1), 0.5]) - o)[None])[0]
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
    return f32(os_), f32(ds), np.array(bad)


def family_bad_rays(n_sets: int) -> list[Case]:
    """8. NaN/Inf/zero-direction rays mixed with valid ones: no crash, no hang, all bad rays miss."""
    v, f = merge_meshes([box_mesh((0, 0, 0), (2, 1, 0.5)),
                   quads_mesh(np.array([[[-3, -0.5, -3], [4, -0.5, -3], [4, -0.5, 4], [-3, -0.5, 4]]], float))])
    o, d, bad = bad_rays(n_sets)
    return [Case(8, f"{int(bad.sum())} bad rays among {len(bad)}", case_scene("bad_rays", v, f), o, d,
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
        scene = case_scene(name, loaded.vertices, loaded.faces)
        rng = np.random.default_rng(seed)
        lo, hi = scene.bounds().astype(np.float64)
        ext = hi - lo
        o = rng.uniform(lo - 0.5 * ext, hi + 0.5 * ext, (n_rays, 3))
        d = unit_rows(rng.normal(size=(n_rays, 3)))
        cases.append(Case(9, f"{name}, {n_rays} random rays", scene, f32(o), f32(d), ("mismatches",)))
    return cases


def family_dir_lengths(n_rays: int, lengths=DIRECTION_LENGTHS, seed: int = 12) -> list[Case]:
    """12. Rays into a unit sphere over a floor (half aimed at the sphere's vertices) with their
    directions scaled to each length in ``lengths`` (rounded to float32 once): the hits must not
    depend on the length."""
    import trimesh
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    floor = quads_mesh(np.array([[[-4, -1, -4], [4, -1, -4], [4, -1, 4], [-4, -1, 4]]], float))
    v, f = merge_meshes([(mesh.vertices, mesh.faces), floor])
    scene = case_scene("sphere_floor", v, f)
    o = np.column_stack([rng.uniform(-3, 3, n_rays), rng.uniform(0.5, 3, n_rays), rng.uniform(-3, 3, n_rays)])
    o[::2] *= 1.5
    target = np.where(rng.uniform(size=(n_rays, 1)) < 0.5, mesh.vertices[rng.integers(0, len(mesh.vertices), n_rays)],
                      rng.uniform(-2, 2, (n_rays, 3)) * [1, 0, 1] + [0, -1, 0])
    unit = unit_rows(target - o)
    return [Case(12, f"direction length {length:g}", scene, f32(o), f32(unit * length), ("mismatches",))
            for length in lengths]
