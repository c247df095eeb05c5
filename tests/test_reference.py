"""The float64 reference tracer and the error metrics.

The BVH tracer is checked against brute force (which does the same float64 operations on every
triangle, so any culling mistake shows), and both against cases whose answers are known exactly:
rays through shared vertices and edges, axis-aligned rays, degenerate triangles, NaN/Inf rays.
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rtlab.paths import find_scene_file
from rtlab.reference import (
    RefHits,
    brute_force_trace,
    build_reference_bvh,
    cached_reference_bvh,
    compare_hits,
    image_rmse_psnr,
    intersect_ray_triangles_f64,
    pixels_differing,
    reference_trace,
)


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
def triangle_soup(rng, n, spread=1.0, size=0.3, center=(0.0, 0.0, 0.0)):
    centers = rng.uniform(-spread, spread, (n, 1, 3))
    corners = centers + size * rng.normal(size=(n, 3, 3)) + np.asarray(center)
    vertices = corners.reshape(-1, 3).astype(np.float32)
    faces = np.arange(3 * n, dtype=np.int32).reshape(n, 3)
    return vertices, faces


def random_unit(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def assert_matches_brute_force(vertices, faces, origins, directions, tmin=0.0, tmax=np.inf):
    """BVH vs brute force: no mismatch (ties allowed), same-triangle t to 1e-12 relative."""
    bvh = reference_trace(vertices, faces, origins, directions, tmin, tmax)
    brute = brute_force_trace(vertices, faces, origins, directions, tmin, tmax)
    cmp = compare_hits(brute, bvh.tri, bvh.t, vertices, faces, origins, directions,
                       tmin=tmin, tmax=tmax)
    assert cmp.n_mismatch == 0, cmp.summary()
    assert cmp.n_same >= 0.999 * cmp.n_rays, cmp.summary()
    if cmp.n_hits_ref:
        assert cmp.t_rel_err_max <= 1e-12, cmp.summary()
    same = bvh.hit & (bvh.tri == brute.tri)
    np.testing.assert_allclose(bvh.u[same], brute.u[same], rtol=0, atol=1e-12)
    np.testing.assert_allclose(bvh.v[same], brute.v[same], rtol=0, atol=1e-12)
    return bvh


def tiled_plane(n=6, step=0.25):
    """An n x n grid of squares in z = 0, two triangles each; coordinates exact in float32."""
    xs = np.arange(n + 1) * step
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1).astype(np.float32)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    return vertices, faces


# ---------------------------------------------------------------------------------------------
# BVH vs brute force
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bvh_matches_brute_force_on_triangle_soup(seed):
    rng = np.random.default_rng(seed)
    vertices, faces = triangle_soup(rng, 400)
    origins = rng.uniform(-2.0, 2.0, (3000, 3))
    hits = assert_matches_brute_force(vertices, faces, origins, random_unit(rng, 3000))
    assert 0.1 < hits.hit.mean() < 0.95


@pytest.mark.parametrize("scale, offset", [(1e-6, 0.0), (1e6, 0.0), (1.0, 1e4), (1e-3, -3e3)])
def test_bvh_matches_brute_force_at_extreme_scales(scale, offset):
    rng = np.random.default_rng(7)
    vertices, faces = triangle_soup(rng, 200)
    vertices = (vertices.astype(np.float64) * scale + offset).astype(np.float32)
    origins = rng.uniform(-2.0, 2.0, (1500, 3)) * scale + offset
    hits = assert_matches_brute_force(vertices, faces, origins, random_unit(rng, 1500))
    assert hits.hit.any()


def test_bvh_matches_brute_force_on_icosphere_inside_and_outside():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices = np.asarray(sphere.vertices, np.float32)
    faces = np.asarray(sphere.faces, np.int32)
    rng = np.random.default_rng(3)
    inside = random_unit(rng, 1500) * rng.uniform(0.0, 0.9, (1500, 1))
    outside = random_unit(rng, 1500) * 3.0
    toward = random_unit(rng, 1500) * rng.uniform(0.0, 1.2, (1500, 1)) - outside
    origins = np.concatenate([inside, outside])
    directions = np.concatenate([random_unit(rng, 1500), toward])
    hits = assert_matches_brute_force(vertices, faces, origins, directions)
    # closed mesh: every ray from inside leaves through some triangle
    assert hits.hit[:1500].all()


def test_rays_from_sphere_centre_through_every_vertex_and_edge_midpoint_hit():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    vertices = np.asarray(sphere.vertices, np.float32)
    faces = np.asarray(sphere.faces, np.int32)
    edges = np.asarray(sphere.edges_unique)
    targets = np.concatenate([vertices, 0.5 * (vertices[edges[:, 0]] + vertices[edges[:, 1]])])
    origins = np.zeros_like(targets)
    hits = assert_matches_brute_force(vertices, faces, origins, targets)
    assert hits.hit.all(), "a ray through a shared vertex or edge leaked"
    # through a vertex the hit is the vertex itself
    np.testing.assert_allclose(hits.t[:len(vertices)], 1.0, rtol=1e-12)


def test_bunny_sample_matches_brute_force():
    path = find_scene_file("bunny.ply")
    if path is None:
        pytest.skip("bunny.ply not found")
    mesh = trimesh.load(path, process=False, force="mesh")
    vertices = np.asarray(mesh.vertices, np.float32)
    faces = np.asarray(mesh.faces, np.int32)
    rng = np.random.default_rng(5)
    eye = np.array([-0.017, 0.11, 0.224])
    targets = vertices[rng.choice(len(vertices), 160)] + rng.normal(0, 2e-3, (160, 3))
    hits = assert_matches_brute_force(vertices, faces, np.broadcast_to(eye, targets.shape),
                                      targets - eye)
    assert hits.hit.mean() > 0.5


# ---------------------------------------------------------------------------------------------
# exact cases
# ---------------------------------------------------------------------------------------------
def lowest_touching_triangle(vertices, faces, point):
    """Lowest id among plane triangles whose closed area contains a point of the z = 0 grid."""
    ids = []
    for i, f in enumerate(faces):
        a, b, c = vertices[f, :2].astype(np.float64)
        m = np.array([b - a, c - a]).T
        s, t = np.linalg.solve(m, point[:2] - a)
        if s >= -1e-12 and t >= -1e-12 and s + t <= 1 + 1e-12:
            ids.append(i)
    return min(ids)


@pytest.mark.parametrize("slant", [(0.0, 0.0), (0.5, 0.25), (-0.75, 0.5)])
def test_rays_through_shared_vertices_and_edges_of_tiled_plane_hit(slant):
    vertices, faces = tiled_plane()
    step = 0.25
    # every grid vertex and every edge midpoint (axis edges and diagonals), all exact in float32
    g = np.arange(0, 6 * step + 1e-9, step / 2)
    px, py = np.meshgrid(g, g, indexing="ij")
    points = np.stack([px.ravel(), py.ravel(), np.zeros(px.size)], 1)
    direction = np.array([-slant[0], -slant[1], -1.0])
    origins = points - direction  # exact: every value is a multiple of 1/8
    directions = np.broadcast_to(direction, origins.shape)
    hits = reference_trace(vertices, faces, origins, directions)
    assert hits.hit.all(), "ray through a shared edge or vertex leaked"
    np.testing.assert_array_equal(hits.t, 1.0)
    np.testing.assert_allclose(hits.points(vertices, faces), points, atol=1e-15)
    expected = [lowest_touching_triangle(vertices, faces, p) for p in points]
    np.testing.assert_array_equal(hits.tri, expected)  # tie-break: lowest id
    brute = brute_force_trace(vertices, faces, origins, directions)
    np.testing.assert_array_equal(brute.tri, hits.tri)


def test_stacked_copies_of_one_triangle_pick_the_lowest_id():
    rng = np.random.default_rng(11)
    one = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    vertices = np.tile(one, (300, 1))
    faces = np.arange(900, dtype=np.int32).reshape(300, 3)
    faces = faces[rng.permutation(300)]  # the lowest id sits anywhere in the tree
    origins = np.column_stack([rng.uniform(0, 0.45, 50), rng.uniform(0, 0.45, 50), np.ones(50)])
    hits = reference_trace(vertices, faces, origins, np.broadcast_to([0, 0, -1.0], (50, 3)))
    np.testing.assert_array_equal(hits.tri, 0)
    assert build_reference_bvh(vertices, faces).depth < 40


def test_copies_of_a_tilted_triangle_in_any_vertex_order_pick_the_lowest_id():
    """Copies of one tilted triangle listed with their corners rotated or reversed lie at the same t
    exactly, so the tie rule gives the lowest id: the reference's plane t starts from the least corner
    (canonical_corners), in the numpy and numba twins alike, so every copy's double t is the same to
    the bit (from the first-listed corner, a rotated copy's t differs in its last bits)."""
    from rtlab.reference.watertight import plane_t_numpy
    rng = np.random.default_rng(3)
    v = np.array([[0.1, 0.2, 0.3], [1.3, -0.4, 0.7], [-0.2, 0.9, -0.5]], np.float32)
    orders = [[0, 1, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0], [0, 2, 1], [1, 0, 2]]
    for first in range(len(orders)):                    # each order in turn holds the lowest id
        ids = orders[first:] + orders[:first]
        vertices = np.concatenate([v[o] for o in ids])
        faces = np.arange(len(vertices), dtype=np.int32).reshape(-1, 3)
        w = rng.dirichlet([1, 1, 1], 200)
        target = w @ v.astype(np.float64)
        origins = (target + rng.normal(size=(200, 3))).astype(np.float32)
        directions = (target - origins).astype(np.float32)
        hits = reference_trace(vertices, faces, origins, directions)
        assert np.all(hits.tri == 0), f"order {ids[0]} first: {np.count_nonzero(hits.tri != 0)} rays pick another id"
        a = [vertices[faces[:, k]][None].astype(np.float64) - origins[:, None].astype(np.float64) for k in range(3)]
        t = plane_t_numpy(*a, directions[:, None].astype(np.float64))
        assert np.all(t == t[:, :1])                     # the same t to the bit for every copy


@pytest.mark.parametrize("axis", range(3))
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_axis_aligned_rays_hit_a_box_from_inside_and_outside(axis, sign):
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))  # faces lie in the planes +-1
    vertices = np.asarray(box.vertices, np.float32)
    faces = np.asarray(box.faces, np.int32)
    rng = np.random.default_rng(axis)
    direction = np.zeros(3)
    direction[axis] = sign
    inside = rng.uniform(-0.9, 0.9, (200, 3))
    outside = inside.copy()
    outside[:, axis] = -sign * 5.0
    # also along the box's own edges and corners (other coordinates exactly +-1)
    on_edges = outside[:20].copy()
    others = [a for a in range(3) if a != axis]
    on_edges[:, others] = rng.choice([-1.0, 1.0], (20, 2))
    origins = np.concatenate([inside, outside, on_edges])
    directions = np.broadcast_to(direction, origins.shape)
    hits = assert_matches_brute_force(vertices, faces, origins, directions)
    assert hits.hit.all()
    expected_t = np.concatenate([1.0 - sign * inside[:, axis], np.full(220, 4.0)])
    np.testing.assert_allclose(hits.t, expected_t, rtol=1e-14)
    # rays beside the box never enter it (zero components must not produce NaN boxes)
    beside = outside.copy()
    beside[:, others[0]] = 1.5
    miss = reference_trace(vertices, faces, beside, directions[:len(beside)])
    assert not miss.hit.any()


def test_degenerate_triangles_are_never_hit():
    vertices = np.array([
        [0, 0, 0], [1, 0, 0], [2, 0, 0],        # collinear
        [0, 1, 0], [0, 1, 0], [1, 1, 0],        # repeated corner
        [0.5, 0.5, 0], [0.5, 0.5, 0], [0.5, 0.5, 0],  # a point
        [-1, -1, -1], [3, -1, -1], [-1, 3, -1],  # a real triangle behind them
    ], np.float32)
    faces = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11]], np.int32)
    targets = np.array([[0.5, 0, 0], [1.5, 0, 0], [0, 1, 0], [0.5, 1, 0], [0.5, 0.5, 0]])
    for direction in ([0, 0, -1.0], [0.3, -0.2, -1.0], [1.0, 0.0, 0.0]):
        d = np.broadcast_to(direction, targets.shape)
        origins = targets - 2.0 * d
        for hits in (reference_trace(vertices, faces, origins, d),
                     brute_force_trace(vertices, faces, origins, d)):
            assert not np.isin(hits.tri, [0, 1, 2]).any()
        t, _, _ = intersect_ray_triangles_f64(origins, d, np.zeros(5, int), vertices, faces,
                                              eps=0.1)
        assert np.isinf(t).all()
        # a mesh of nothing but degenerate triangles
        hits = reference_trace(vertices[:9], faces[:3], origins, d)
        assert not hits.hit.any()


def test_nan_inf_and_zero_rays_miss_without_crashing():
    vertices, faces = tiled_plane()
    good_o, good_d = [0.3, 0.3, 1.0], [0.0, 0.0, -1.0]
    origins = np.array([good_o, [np.nan, 0.3, 1.0], [0.3, np.inf, 1.0], good_o, good_o, good_o])
    directions = np.array([good_d, good_d, good_d, [0.0, np.nan, -1.0], [0.0, 0.0, -np.inf],
                           [0.0, 0.0, 0.0]])
    for trace in (reference_trace, brute_force_trace):
        hits = trace(vertices, faces, origins, directions)
        assert hits.tri[0] >= 0 and hits.t[0] == 1.0
        np.testing.assert_array_equal(hits.tri[1:], -1)
        assert np.isinf(hits.t[1:]).all() and np.isnan(hits.u[1:]).all()


def test_triangles_with_nan_corners_are_never_hit():
    vertices, faces = tiled_plane(2)
    vertices = np.concatenate([vertices, [[np.nan, 0, 0]]]).astype(np.float32)
    faces = np.concatenate([[[len(vertices) - 1, 0, 1]], faces]).astype(np.int32)
    o = np.array([[0.1, 0.05, 1.0]])
    hits = reference_trace(vertices, faces, o, [[0, 0, -1.0]])
    assert hits.tri[0] > 0


def test_tmin_tmax_are_strict_and_per_ray():
    plane_v, plane_f = tiled_plane(2)
    # two parallel planes at z = 0 and z = -1
    lower = plane_v.copy()
    lower[:, 2] = -1.0
    vertices = np.concatenate([plane_v, lower])
    faces = np.concatenate([plane_f, plane_f + len(plane_v)]).astype(np.int32)
    n = len(plane_f)
    o = np.array([[0.1, 0.2, 1.0]] * 5)
    d = np.array([[0.0, 0.0, -1.0]] * 5)
    tmin = np.array([0.0, 1.0, 0.5, 0.0, 2.0])
    tmax = np.array([1.0, np.inf, 1.5, 2.0, 3.0])
    for trace in (reference_trace, brute_force_trace):
        hits = trace(vertices, faces, o, d, tmin, tmax)
        assert hits.tri[0] == -1                      # t = 1 is not < tmax = 1
        assert hits.tri[1] >= n and hits.t[1] == 2.0  # t = 1 is not > tmin = 1
        assert hits.tri[2] < n and hits.t[2] == 1.0
        assert hits.tri[3] < n and hits.t[3] == 1.0
        assert hits.tri[4] == -1                      # t = 2 is not > tmin = 2
    # scalar limits; origin on the surface: t = 0 is not > tmin = 0
    hits = reference_trace(vertices, faces, [[0.1, 0.2, 0.0]], [[0, 0, -1.0]])
    assert hits.tri[0] >= n and hits.t[0] == 1.0


def test_intersect_ray_triangles_f64_agrees_and_takes_slack():
    vertices, faces = tiled_plane(2)
    rng = np.random.default_rng(2)
    o = np.column_stack([rng.uniform(0, 0.5, 100), rng.uniform(0, 0.5, 100), np.ones(100)])
    d = np.broadcast_to([0.0, 0.0, -1.0], (100, 3))
    hits = reference_trace(vertices, faces, o, d)
    t, u, v = intersect_ray_triangles_f64(o, d, hits.tri, vertices, faces)
    np.testing.assert_array_equal(t, hits.t)
    np.testing.assert_array_equal(u, hits.u)
    np.testing.assert_array_equal(v, hits.v)
    # a point 1e-3 (in barycentric units) beyond the edge of triangle 0: only slack catches it
    a, b, c = vertices[faces[0]].astype(np.float64)
    outside = a + 0.5 * (b - a) - 1e-3 * (c - a)
    args = (outside + [0, 0, 1.0], [0, 0, -1.0], 0, vertices, faces)
    assert np.isinf(intersect_ray_triangles_f64(*args)[0]).all()
    assert intersect_ray_triangles_f64(*args, eps=2e-3)[0][0] == pytest.approx(1.0)
    assert np.isinf(intersect_ray_triangles_f64(*args, eps=5e-4)[0]).all()
    # unknown ids miss
    assert np.isinf(intersect_ray_triangles_f64(o[:2], d[:2], [-1, 99], vertices, faces)[0]).all()


def test_bvh_is_cached_by_mesh_content():
    rng = np.random.default_rng(9)
    vertices, faces = triangle_soup(rng, 50)
    first = cached_reference_bvh(vertices, faces)
    assert cached_reference_bvh(vertices.copy(), faces.copy()) is first
    moved = vertices.copy()
    moved[0, 0] += 1.0
    assert cached_reference_bvh(moved, faces) is not first


def test_empty_inputs():
    vertices, faces = tiled_plane(1)
    hits = reference_trace(vertices, faces, np.zeros((0, 3)), np.zeros((0, 3)))
    assert len(hits) == 0
    hits = reference_trace(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32),
                           [[0, 0, 1.0]], [[0, 0, -1.0]])
    assert hits.tri[0] == -1


# ---------------------------------------------------------------------------------------------
# metrics
# ---------------------------------------------------------------------------------------------
def metric_scene():
    """A unit square in z = 0 made of triangles 0 and 1 (shared diagonal), a far square in z = -1
    (triangles 2, 3) and, off to the side, an unrelated triangle 4."""
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    big = np.array([[-2, -2, -1], [3, -2, -1], [3, 3, -1], [-2, 3, -1]], np.float32)
    other = np.array([[5, 5, 0], [6, 5, 0], [5, 6, 0]], np.float32)
    vertices = np.concatenate([square, big, other])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [8, 9, 10]], np.int32)
    return vertices, faces


def test_compare_hits_tells_ties_from_mismatches():
    vertices, faces = metric_scene()
    points = np.array([
        [0.5, 0.5],      # 0 on the shared diagonal
        [0.7, 0.2],      # 1 inside triangle 0
        [0.7, 0.2],      # 2 inside triangle 0
        [1.0 - 1e-6, 0.5],  # 3 a hair inside triangle 0's outer edge (a silhouette)
        [1.0 + 1e-6, 0.5],  # 4 a hair outside the square
        [1.5, 0.5],      # 5 far outside the square
        [1.0 - 1e-6, 0.5],  # 6 silhouette, kernel goes through to the far square
        [0.5, 0.2],      # 7 centre of triangle 0, kernel goes through to the far square
        [0.7, 0.2],      # 8 kernel names an id that does not exist
        [0.7, 0.2],      # 9 kernel names a triangle the ray does not pass
        [0.7, 0.2],      # 10 agreement
    ])
    origins = np.column_stack([points, np.ones(len(points))])
    directions = np.broadcast_to([0.0, 0.0, -1.0], origins.shape)
    ref = reference_trace(vertices, faces, origins, directions)
    np.testing.assert_array_equal(ref.tri, [0, 0, 0, 0, 2, 2, 0, 0, 0, 0, 0])
    kernel_tri = np.array([1, -1, 1, -1, 0, 0, 2, 2, 99, 4, 0])
    kernel_t = np.array([1, np.inf, 1, np.inf, 1, 1, 2, 2, 1, 1, 1.0 + 3e-7])
    cmp = compare_hits(ref, kernel_tri, kernel_t, vertices, faces, origins, directions)
    expect_tie = [True, False, False, True, True, False, True, False, False, False, False]
    expect_mismatch = [False, True, True, False, False, True, False, True, True, True, False]
    np.testing.assert_array_equal(cmp.tie, expect_tie)
    np.testing.assert_array_equal(cmp.mismatch, expect_mismatch)
    assert (cmp.n_rays, cmp.n_same, cmp.n_ties, cmp.n_mismatch) == (11, 1, 4, 6)
    assert cmp.n_hits_ref == 11
    assert cmp.first_mismatch_index == 1
    assert cmp.t_rel_err_max == pytest.approx(3e-7) and cmp.t_rel_err_median == pytest.approx(3e-7)
    assert cmp.summary().startswith("11 rays, 100.0% hit: 6 mismatches, 4 ties")


def test_compare_hits_all_agree_and_miss_counts():
    vertices, faces = metric_scene()
    origins = np.array([[0.3, 0.1, 1.0], [10.0, 10.0, 1.0]])
    directions = np.array([[0, 0, -1.0], [0, 0, -1.0]])
    ref = reference_trace(vertices, faces, origins, directions)
    cmp = compare_hits(ref, ref.tri.astype(np.int32), ref.t.astype(np.float32), vertices,
                       faces, origins, directions)
    assert cmp.ok and cmp.n_same == 2 and cmp.n_ties == 0 and cmp.first_mismatch_index == -1
    assert cmp.n_hits_ref == 1 and cmp.t_rel_err_max == 0.0
    assert "2 rays, 50.0% hit: 0 mismatches, 0 ties" in cmp.summary()
    with pytest.raises(ValueError):
        compare_hits(ref, ref.tri[:1], ref.t[:1], vertices, faces, origins, directions)


def test_compare_hits_tie_abs_widens_edge_slack_for_grazing_hits():
    vertices, faces = metric_scene()
    # a grazing ray (cos 0.01 to the normal) that meets the square 1e-3 inside its edge x = 1:
    # beyond tie_eps = 1e-4, but within 1e-5 world units / (altitude 0.707 x cos 0.01)
    d = np.array([[-1.0, 0.0, -0.01]])
    o = np.array([[1.0 - 1e-3, 0.5, 0.0]]) - d
    ref = reference_trace(vertices, faces, o, d)
    assert ref.tri[0] == 0
    strict = compare_hits(ref, [-1], [np.inf], vertices, faces, o, d)
    assert strict.n_mismatch == 1
    loose = compare_hits(ref, [-1], [np.inf], vertices, faces, o, d, tie_abs=1e-5)
    assert loose.n_ties == 1


def test_image_rmse_psnr():
    rng = np.random.default_rng(4)
    img = rng.uniform(0.2, 0.8, (32, 32, 3))
    assert image_rmse_psnr(img, img) == (0.0, float("inf"))
    rmse, psnr = image_rmse_psnr(img + 0.1, img)
    assert rmse == pytest.approx(0.1) and psnr == pytest.approx(20.0)
    half = img.copy()
    half[:16] += 0.2
    rmse, psnr = image_rmse_psnr(half, img)
    assert rmse == pytest.approx(np.sqrt(0.5 * 0.04))
    assert psnr == pytest.approx(-20.0 * np.log10(np.sqrt(0.02)))
    as_u8 = np.round(img * 255).astype(np.uint8)
    rmse, _ = image_rmse_psnr(as_u8, img)
    assert rmse <= 0.5 / 255 + 1e-12
    assert image_rmse_psnr(as_u8, as_u8)[1] == float("inf")
    with pytest.raises(ValueError):
        image_rmse_psnr(img, img[:8])


def test_pixels_differing():
    a = np.array([[0, 1, -1], [3, 4, 5]])
    b = np.array([[0, 2, -7], [3, 4, -1]])
    assert pixels_differing(a, b) == 2
    assert pixels_differing(a, a.astype(np.int32)) == 0


def test_refhits_points():
    vertices, faces = tiled_plane(2)
    hits = RefHits(np.array([1.0, np.inf]), np.array([0, -1]), np.array([0.25, np.nan]),
                   np.array([0.5, np.nan]))
    p = hits.points(vertices, faces)
    a, b, c = vertices[faces[0]].astype(np.float64)
    np.testing.assert_allclose(p[0], 0.25 * a + 0.25 * b + 0.5 * c)
    assert np.isnan(p[1]).all()


def test_a_ray_parallel_to_a_triangle_that_the_shear_lets_through_misses():
    """The rounded shear let this ray through the edges of a triangle it runs parallel to (n . d = 0
    exactly); the reference's plane divided by zero and numba raised ZeroDivisionError (as SystemError)
    out of reference_trace. It misses, as the brute force and the kernels say."""
    v = np.array([[2.75, 1.25, 0.0], [3.0, 1.25, 0.25], [3.0, 1.5, 1.0]], np.float32)
    f = np.array([[0, 1, 2]])
    o, d = np.array([[3.875, 1.25, 1.125]]), np.array([[-0.4375, 0.125, -0.0625]])
    assert np.cross(v[1].astype(float) - v[0], v[2].astype(float) - v[0]) @ d[0] == 0.0
    assert reference_trace(v, f, o, d, cache=False).tri[0] == -1
    assert brute_force_trace(v, f, o, d).tri[0] == -1
