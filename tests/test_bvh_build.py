"""The BVH builder with spatial splits (SBVH, rtlab.accel.bvh_splits): host invariants checked on
the tree as built, against points sampled on every triangle, and the "bvh" traversal's hits on a
spatially split tree against the float64 reference.

Cases: the default scene (with two zero-area triangles appended) and a box of long thin
triangles crossing each other, where spatial splits must happen.
"""
from __future__ import annotations

import numpy as np
import pytest

import rtlab
from rtlab.accel.bvh import MAX_LEAF, BvhBuildParams, build_bvh, decode_leaf
from rtlab.accel.bvh_stats import sah_cost, traversal_counts
from rtlab.reference import compare_hits, reference_trace
from rtlab.scene.model import Camera, Material, Scene

SBVH = BvhBuildParams(spatial_alpha=1e-5)
GRID = 8                         # barycentric steps of 1/GRID: corners, edges, inside


def _slivers(n=400, seed=3):
    """Long thin triangles from one side of a unit box to the other, crossing each other."""
    rng = np.random.default_rng(seed)
    a = rng.random((n, 3))
    b = rng.random((n, 3))
    axis = rng.integers(0, 3, n)
    a[np.arange(n), axis], b[np.arange(n), axis] = 0.0, 1.0
    c = a + rng.normal(scale=0.01, size=(n, 3))
    v = np.stack([a, b, c], axis=1).reshape(-1, 3).astype(np.float32)
    return v, np.arange(3 * n, dtype=np.int32).reshape(n, 3)


def _default_with_degenerates():
    scene = rtlab.load_scene("default", size=16)
    f = np.concatenate([scene.faces, [[0, 0, 1]], [[0, 1, 1]]]).astype(np.int32)  # two zero-area triangles
    return scene.vertices.copy(), f, len(scene.faces)


def _leaves(bvh):
    """(first, count, [boxes from the root's child down to the leaf]) of every leaf; the depth."""
    out, max_depth = [], 0
    todo = [(0, 1, [])]
    while todo:
        node, depth, path = todo.pop()
        for c in range(2):
            ref = int(bvh.child_ref[node, c])
            box = (bvh.child_lo[node, c], bvh.child_hi[node, c])
            if ref >= 0:
                assert np.all(bvh.child_lo[ref] >= box[0]) and np.all(bvh.child_hi[ref] <= box[1]), "child box not nested"
                todo.append((ref, depth + 1, path + [box]))
                continue
            first, count = decode_leaf(ref)
            out.append((first, count, path + [box]))
            max_depth = max(max_depth, depth)
    return out, max_depth


def _barycentric_points(v, f):
    """(F, P, 3) float64 points on each triangle at barycentrics i/GRID, j/GRID."""
    w = np.array([(i, j, GRID - i - j) for i in range(GRID + 1) for j in range(GRID + 1 - i)], np.float64) / GRID
    corners = v.astype(np.float64)[f]                          # (F, 3, 3)
    return np.einsum("pk,fkm->fpm", w, corners)


def _check_tree(v, f, bvh, usable):
    """Every invariant of the brief: references, leaves, depth, and each sampled point of each
    usable triangle inside a leaf box that references it and inside all that leaf's ancestors."""
    leaves, depth = _leaves(bvh)
    assert bvh.depth == depth
    seen = np.zeros(len(f), np.int64)
    covered = np.zeros((len(f), (GRID + 1) * (GRID + 2) // 2), bool)
    points = _barycentric_points(v, f)
    for first, count, path in leaves:
        assert 1 <= count <= MAX_LEAF
        tris = bvh.objects[first:first + count]
        assert len(np.unique(tris)) == count, "a triangle twice in one leaf"
        seen[tris] += 1
        inside = np.ones((count, points.shape[1]), bool)
        for lo, hi in path:
            p = points[tris]
            inside &= np.all((p >= lo) & (p <= hi), axis=2)
        covered[tris] |= inside
    assert np.all(seen[usable] >= 1), "a usable triangle is not referenced"
    assert np.all(seen[~usable] == 0), "an unusable triangle was referenced"
    missing = np.argwhere(~covered[usable])
    assert len(missing) == 0, f"{len(missing)} sampled points outside every leaf that references their triangle"
    assert np.array_equal(bvh.bounds, np.stack([v[f[usable]].min((0, 1)), v[f[usable]].max((0, 1))]))
    return seen


def test_sbvh_invariants_default_scene():
    v, f, n_good = _default_with_degenerates()
    bvh = build_bvh(v, f, SBVH)
    usable = np.arange(len(f)) < n_good
    _check_tree(v, f, bvh, usable)
    assert len(bvh.objects) <= (1 + SBVH.spatial_growth) * n_good


def test_sbvh_invariants_slivers_split():
    v, f = _slivers()
    plain = build_bvh(v, f)
    bvh = build_bvh(v, f, SBVH)
    seen = _check_tree(v, f, bvh, np.ones(len(f), bool))
    assert seen.max() > 1 and len(bvh.objects) > len(f), "no reference was split on crossing slivers"
    assert len(bvh.objects) <= (1 + SBVH.spatial_growth) * len(f)
    assert sah_cost(bvh) < sah_cost(plain)


def test_sbvh_reference_budget():
    v, f = _slivers()
    for growth in (0.05, 0.3):
        bvh = build_bvh(v, f, BvhBuildParams(spatial_alpha=1e-5, spatial_growth=growth))
        assert len(f) < len(bvh.objects) <= int((1 + growth) * len(f))


def test_sbvh_off_by_default():
    v, f, _ = _default_with_degenerates()
    a, b = build_bvh(v, f), build_bvh(v, f, BvhBuildParams(spatial_alpha=0.0))
    for name in ("child_lo", "child_hi", "child_ref", "objects"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert BvhBuildParams().key() != SBVH.key()


def _sliver_scene():
    v, f = _slivers()
    return Scene("slivers", v, f, np.zeros(len(f), np.int32), [Material()],
                 Camera((2.2, 1.7, 2.5), (0.5, 0.5, 0.5)), source="procedural")


def _rays(n=4000, seed=5):
    """Rays from points around the unit box through points inside it."""
    rng = np.random.default_rng(seed)
    o = rng.uniform(-1.0, 2.0, (n, 3))
    d = rng.uniform(0.1, 0.9, (n, 3)) - o
    return o.astype(np.float32), d.astype(np.float32)


def test_sbvh_counting_traversal_finds_reference_hits():
    scene = _sliver_scene()
    o, d = _rays()
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    for params in (BvhBuildParams(), SBVH):
        bvh = build_bvh(scene.vertices, scene.faces, params)
        nodes, tris, tri, t = traversal_counts(bvh, scene.vertices, scene.faces, o, d)
        c = compare_hits(ref, tri, np.where(tri >= 0, t, np.inf).astype(np.float32), scene.vertices, scene.faces, o, d)
        assert c.n_mismatch == 0 and nodes.min() >= 1


@pytest.mark.parametrize("scene_name", ["slivers", "default"])
def test_sbvh_trace_matches_reference(backend, scene_name, monkeypatch):
    """The "bvh" traversal on the spatially split tree (uploaded in place of the default build, after
    a trace on that: the leaf-ordered triangles follow the new tree) finds the float64 reference's hits."""
    import rtlab.device.device_scene as device_scene_module
    from rtlab.device.kernels import Variant
    from rtlab.device.tracing import trace
    scene = _sliver_scene() if scene_name == "slivers" else rtlab.load_scene("default", size=16)
    bvh = build_bvh(scene.vertices, scene.faces, SBVH)
    assert len(bvh.objects) > np.unique(bvh.objects).size, "nothing was split"
    arrays = device_scene_module.AccelArrays(device_scene_module.NO_NODES, bvh.node_data(), bvh.objects, bvh.bounds,
                                             bvh.depth + 1)
    o, d = _rays(seed=7) if scene_name == "slivers" else _default_rays(scene)
    trace(scene, o, d, backend, Variant.paper(traversal="bvh"))   # the default build's leaf data, then a new tree
    monkeypatch.setitem(device_scene_module.ACCEL_BUILDERS, "bvh", lambda s, tree: arrays)
    ds = device_scene_module.device_scene(scene, backend)
    ds.accel.pop("bvh", None)
    try:
        got = trace(scene, o, d, backend, Variant.paper(traversal="bvh"))
        assert ds.accel["bvh"][0] is arrays
    finally:
        ds.accel.pop("bvh", None)            # later tests get the default build again
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    c = compare_hits(ref, got.tri, got.t, scene.vertices, scene.faces, o, d)
    assert c.n_mismatch == 0, f"{c.n_mismatch} of {len(o)} rays differ from the reference"
    assert np.sum(got.tri >= 0) > len(o) // 10


def _default_rays(scene):
    from rtlab.scene.model import camera_rays
    return camera_rays(scene.camera)


def _big_triangles_over_small_ones(n_small=2000, n_big=20, seed=3):
    """Small triangles scattered in a unit box, crossed by big slanted ones spanning it (the case
    spatial splits were made for: the SAH gain is about 20 %)."""
    rng = np.random.default_rng(seed)
    small = rng.random((n_small, 1, 3)) + rng.normal(scale=0.01, size=(n_small, 3, 3))
    y = np.linspace(0.05, 0.95, n_big)
    zero, one = np.zeros(n_big), np.ones(n_big)
    big = np.stack([np.stack([zero, y, zero], 1), np.stack([one, y, one], 1), np.stack([one, y + 0.02, zero + 0.9], 1)], 1)
    v = np.concatenate([small, big]).reshape(-1, 3).astype(np.float32)
    return v, np.arange(len(v), dtype=np.int32).reshape(-1, 3)


def test_traversal_bvh_keeps_spatial_splits_only_where_they_lower_the_sah(tmp_path):
    """The "bvh" traversal's tree (bvh_stats.traversal_bvh, read by device.scene.bvh_accel): the
    spatially split build where its SAH cost is SPLIT_MIN_GAIN lower (big triangles across small
    ones), the plain build otherwise (the default scene, whose cost the splits barely move)."""
    from rtlab.accel.bvh_stats import SPLIT_BUILD, SPLIT_MIN_GAIN, traversal_bvh
    from rtlab.device.device_scene import bvh_accel
    for (v, f), want_split in ((_big_triangles_over_small_ones(), True), (_default_with_degenerates()[:2], False)):
        plain, split = build_bvh(v, f), build_bvh(v, f, SPLIT_BUILD)
        gain = 1.0 - sah_cost(split) / sah_cost(plain)
        assert (gain >= SPLIT_MIN_GAIN) == want_split, f"SAH gain {gain:.3f}"
        chosen = traversal_bvh(v, f, cache_dir=tmp_path)
        assert chosen.params.spatial == want_split
        assert np.array_equal(chosen.objects, (split if want_split else plain).objects)
    v, f = _big_triangles_over_small_ones()
    scene = Scene("crossed", v, f, np.zeros(len(f), np.int32), [Material()],
                  Camera((2.2, 1.7, 2.5), (0.5, 0.5, 0.5)), source="procedural")
    arrays = bvh_accel(scene, None)
    assert np.array_equal(arrays.objects, traversal_bvh(v, f).objects)
    assert len(arrays.objects) > len(f), "the device scene did not get the split tree"


def test_cpu_bvh_keeps_spatial_splits_where_they_lower_the_sah_and_packets_trace_them(backend, tmp_path):
    """The CPU traversals' tree (bvh_wide.cpu_bvh, read by "bvh-packet" and "bvh-wide") chooses as
    the GPU's does, with its own costs; the packet and the wide traversal find the float64
    reference's hits on the split tree, camera rays (packets) and rays in every direction (ray by
    ray) alike."""
    from rtlab.accel.bvh_stats import SPLIT_MIN_GAIN
    from rtlab.accel.bvh_wide import CPU_BUILD, CPU_SPLIT_BUILD, cpu_bvh
    from rtlab.device.kernels import Variant
    from rtlab.device.tracing import trace
    from rtlab.scene.model import camera_rays
    for (v, f), want_split in ((_big_triangles_over_small_ones(), True), (_default_with_degenerates()[:2], False)):
        plain, split = build_bvh(v, f, CPU_BUILD), build_bvh(v, f, CPU_SPLIT_BUILD)
        gain = 1.0 - sah_cost(split) / sah_cost(plain)
        assert (gain >= SPLIT_MIN_GAIN) == want_split, f"SAH gain {gain:.3f}"
        assert cpu_bvh(v, f, cache_dir=tmp_path).params.spatial == want_split
    v, f = _big_triangles_over_small_ones()
    scene = Scene("crossed", v, f, np.zeros(len(f), np.int32), [Material()],
                  Camera((2.2, 1.7, 2.5), (0.5, 0.5, 0.5), width=48, height=48), source="procedural")
    o_cam, d_cam = camera_rays(scene.camera)
    o_any, d_any = _rays(seed=11)
    o, d = np.concatenate([o_cam, o_any]), np.concatenate([d_cam, d_any])
    ref = reference_trace(v, f, o, d)
    for traversal in ("bvh-packet", "bvh-wide"):
        got = trace(scene, o, d, backend, Variant(traversal, "watertight"))
        c = compare_hits(ref, got.tri, got.t, v, f, o, d)
        assert c.n_mismatch == 0, f"{traversal}: {c.summary()}"
        assert np.sum(got.tri >= 0) > len(o) // 10


@pytest.mark.parametrize("n_tris", [0, 1, 2, 3])
@pytest.mark.parametrize("params", [BvhBuildParams(), SBVH], ids=["plain", "sbvh"])
def test_every_leaf_range_lies_inside_the_object_list(n_tris, params):
    """The smallest meshes (a one-triangle mesh gets a root holding its leaf twice): no leaf may
    name objects past the end of the list (the kernel reads them unchecked)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1], [1, 0, 1]], np.float32)
    f = np.array([[0, 1, 2], [1, 3, 2], [0, 4, 5]], np.int32)[:n_tris]
    bvh = build_bvh(v, f, params)
    leaves = bvh.child_ref[bvh.child_ref < 0]
    ends = [sum(decode_leaf(r)) for r in leaves]
    assert max(ends) <= len(bvh.objects)
    assert len(bvh.objects) == n_tris or params.spatial
