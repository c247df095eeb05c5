"""The wide BVHs: the compressed 8-wide one (rtlab.accel.bvh8, kernels/shared/rt_bvh8.h) and the
4-wide one with float boxes (rtlab.accel.bvh4, rt_bvh4.h). Host invariants of the builds (every
triangle reachable, quantised boxes holding the exact child boxes with the slack, leaf ranges and
child rows in bounds, one-triangle and empty meshes), the host mirror of the 8-wide traversal against
the float64 reference, and the "bvh8" and "bvh4" traversals on every backend against the reference
and against the binary "bvh" traversal (the same triangle tests on the same floats: the same ids and
t) on real scenes, closest and any hit (Whitted shadows), and their counting builds.
"""
from __future__ import annotations

import numpy as np
import pytest

import rtlab
from rtlab.accel.bvh import build_bvh
from rtlab.accel.bvh8 import (NODE_ROWS, NODE_TRIS, SLACK_STEPS, TRI_ROWS, Bvh8BuildParams, build_bvh8, collapse8,
                              decoded_boxes, quantise, _scene_extent)
from rtlab.accel.bvh_collapse import PLAIN_BUILD, SPLIT_BUILD
from rtlab.accel.bvh_wide_stats import traversal_counts_bvh4, traversal_counts_bvh8
from rtlab.accel.bvh4 import NODE_ROWS as NODE_ROWS4, Bvh4BuildParams, build_bvh4, collapse4, decode_leaf as decode_leaf4
from rtlab.device.kernels import Variant
from rtlab.device.tracing import trace
from rtlab.reference import compare_hits, reference_trace
from rtlab.scene.model import Camera, Material, Scene, camera_rays

from .conftest import require_scene_file

SCENES = {"bunny": "bunny.ply", "sponza": "sponza/sponza.obj", "kitchen": "kitchen/kitchen.obj"}


def _mesh_scene(name, v, f):
    return Scene(name, np.asarray(v, np.float32), np.asarray(f, np.int32), np.zeros(len(f), np.int32), [Material()],
                 Camera((2.0, 2.0, 2.0), (0.0, 0.0, 0.0)), source="procedural")


def _slivers(n=300, seed=3):
    """Long thin triangles across a unit box, crossing each other: spatial splits happen."""
    rng = np.random.default_rng(seed)
    a, b = rng.random((n, 3)), rng.random((n, 3))
    axis = rng.integers(0, 3, n)
    a[np.arange(n), axis], b[np.arange(n), axis] = 0.0, 1.0
    c = a + rng.normal(scale=0.01, size=(n, 3))
    return np.stack([a, b, c], axis=1).reshape(-1, 3).astype(np.float32), np.arange(3 * n).reshape(n, 3)


def _meshes():
    d = rtlab.load_scene("default", size=16)
    f = np.concatenate([d.faces, [[0, 0, 1]], [[0, 1, 1]]])           # two zero-area triangles
    one = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), np.array([[0, 1, 2]]))
    far = (d.vertices.astype(np.float64) + [1.5e4, 1.2e3, -2.2e4]).astype(np.float32)
    return {"default": (d.vertices, f), "slivers": _slivers(), "one": one, "far": (far, d.faces),
            "flat": (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32), np.array([[0, 1, 2], [1, 3, 2]]))}


def _reachable(b):
    """Triangle ids reachable from the root through inner slots and leaf ranges; checks rows in bounds."""
    nodes = b.nodes()
    seen, todo, rows = [], [0], len(b.rows)
    while todo:
        i = todo.pop()
        node = nodes[i]
        inner = 0
        for s in range(8):
            m = int(node["meta"][s])
            if (node["imask"] >> s) & 1:
                assert m == (1 << 5) | (24 + s), f"node {i} slot {s}: inner meta {m:#x}"
                row = int(node["child_row"]) + NODE_ROWS * inner
                assert row % NODE_ROWS == 0 and 0 < row < NODE_ROWS * b.n_nodes
                todo.append(row // NODE_ROWS)
                inner += 1
            elif m:
                count, offset = {1: 1, 3: 2, 7: 3}[m >> 5], m & 31
                assert offset + count <= NODE_TRIS
                first = int(node["tri_row"]) + TRI_ROWS * offset
                assert b.tri_row0 <= first and first + TRI_ROWS * count <= rows
                for k in range(count):
                    seen.append(int(b.rows[first + TRI_ROWS * k].view(np.int32)[3]))
    return np.array(seen, np.int64)


@pytest.mark.parametrize("name", ["default", "slivers", "one", "far", "flat"])
@pytest.mark.parametrize("binary", ["plain", "split"])
def test_build_reaches_every_triangle_with_rows_in_bounds(name, binary):
    v, f = _meshes()[name]
    b = build_bvh8(v, f, Bvh8BuildParams(binary=binary))
    reached = _reachable(b)
    usable = np.flatnonzero(np.linalg.norm(np.cross(v[f[:, 1]].astype(np.float64) - v[f[:, 0]],
                                                    v[f[:, 2]].astype(np.float64) - v[f[:, 0]]), axis=1) > 0)
    assert set(reached.tolist()) == set(usable.tolist())
    assert np.array_equal(np.sort(reached), np.sort(b.tri_ids.astype(np.int64)))   # no triangle row unreachable
    t = b.rows[b.tri_row0:].reshape(-1, TRI_ROWS, 4)
    ids = t[:, 0, 3].view(np.int32)
    for k in range(3):                                                  # the scene's own floats
        assert np.array_equal(t[:, k, :3], v[f[ids, k]])
    assert b.depth >= 1 and b.nodes()["e"].min() >= 1


@pytest.mark.parametrize("name", ["default", "slivers", "far", "flat"])
@pytest.mark.parametrize("binary", [PLAIN_BUILD, SPLIT_BUILD])
def test_quantised_boxes_hold_the_exact_child_boxes_with_the_slack(name, binary):
    v, f = _meshes()[name]
    bvh = build_bvh(v, f, binary)
    wide, _ = collapse8(bvh, v, f)
    n_lo, n_hi, kind, c_lo, c_hi = wide[:5]
    valid = kind > 0
    p, e, q_lo, q_hi = quantise(n_lo, n_hi, c_lo, c_hi, valid, _scene_extent(bvh.bounds))
    step = np.exp2(e.astype(np.float64))[:, None, :]
    lo = p.astype(np.float64)[:, None, :] + q_lo * step
    hi = p.astype(np.float64)[:, None, :] + q_hi * step
    slack = SLACK_STEPS * step * (1 - 1e-9)
    assert np.all((lo <= c_lo - slack)[valid]) and np.all((hi >= c_hi + slack)[valid])
    # the nodes' exact boxes nest: an inner child's node box is its slot's exact box
    inner = np.argwhere(kind == 1)
    child = wide[5][kind == 1]
    assert np.array_equal(n_lo[child], c_lo[inner[:, 0], inner[:, 1]])
    # and the device rows decode to the same boxes
    b = build_bvh8(v, f, Bvh8BuildParams(binary="plain" if binary is PLAIN_BUILD else "split"))
    dlo, dhi = decoded_boxes(b)
    assert dlo.shape == lo.shape and np.array_equal(dlo[valid], lo[valid]) and np.array_equal(dhi[valid], hi[valid])


def _reachable4(b):
    """Triangle ids reachable from the root of a BVH4; checks refs in bounds and child boxes nested."""
    planes, refs = b.planes(), b.refs()
    seen, todo = [], [0]
    while todo:
        i = todo.pop()
        for s in range(4):
            ref = int(refs[i, s])
            lo, hi = planes[i, 0::2, s], planes[i, 1::2, s]
            if not np.all(lo <= hi):
                assert np.all(lo == np.inf) and np.all(hi == -np.inf) and ref == ~0, f"node {i} slot {s}"
                continue
            if ref >= 0:
                assert ref % NODE_ROWS4 == 0 and 0 < ref < b.tri_row0
                child = ref // NODE_ROWS4
                live = planes[child, 0] <= planes[child, 1]
                assert np.all(planes[child, 0::2][:, live] >= lo[:, None]), "child box not nested"
                assert np.all(planes[child, 1::2][:, live] <= hi[:, None]), "child box not nested"
                todo.append(child)
                continue
            first, count = decode_leaf4(ref)
            assert 1 <= count <= b.params.leaf_max and b.tri_row0 <= first
            assert (first - b.tri_row0) % TRI_ROWS == 0 and first + TRI_ROWS * count <= len(b.rows)
            for k in range(count):
                row = b.rows[first + TRI_ROWS * k]
                assert np.all(row[:3] >= lo) and np.all(row[:3] <= hi) or b.binary == "split"
                seen.append(int(row.view(np.int32)[3]))
    return np.array(seen, np.int64)


@pytest.mark.parametrize("name", ["default", "slivers", "one", "far", "flat"])
@pytest.mark.parametrize("binary", ["plain", "split"])
def test_bvh4_build_reaches_every_triangle_with_refs_in_bounds(name, binary):
    v, f = _meshes()[name]
    b = build_bvh4(v, f, Bvh4BuildParams(binary=binary))
    reached = _reachable4(b)
    usable = np.flatnonzero(np.linalg.norm(np.cross(v[f[:, 1]].astype(np.float64) - v[f[:, 0]],
                                                    v[f[:, 2]].astype(np.float64) - v[f[:, 0]]), axis=1) > 0)
    assert set(reached.tolist()) == set(usable.tolist())
    assert np.array_equal(np.sort(reached), np.sort(b.tri_ids.astype(np.int64)))
    # the slots' boxes are the collapse's exact float32 child boxes
    wide, _ = collapse4(build_bvh(v, f, PLAIN_BUILD if binary == "plain" else SPLIT_BUILD), v, f, b.params)
    kind, c_lo, c_hi = wide[2], wide[3], wide[4]
    planes = b.planes()
    for a in range(3):
        assert np.array_equal(planes[:, 2 * a][kind > 0], c_lo[:, :, a][kind > 0])
        assert np.array_equal(planes[:, 2 * a + 1][kind > 0], c_hi[:, :, a][kind > 0])


@pytest.mark.parametrize("traversal", ["bvh8", "bvh4"])
def test_empty_mesh_builds_and_traces_to_misses(backend, traversal):
    v = np.zeros((3, 3), np.float32)
    f = np.array([[0, 0, 0]])                                           # one zero-area triangle: nothing usable
    b = build_bvh8(v, f)
    assert b.n_nodes == 1 and len(b.tri_ids) == 0 and b.nodes()["meta"].max() == 0
    b4 = build_bvh4(v, f)
    assert b4.n_nodes == 1 and len(b4.tri_ids) == 0 and np.all(b4.refs() == ~0)
    scene = _mesh_scene("empty", v, f)
    o = np.zeros((4, 3), np.float32)
    d = np.eye(3, dtype=np.float32)[[0, 1, 2, 0]]
    assert np.all(trace(scene, o, d, backend=backend, variant=traversal).tri == -1)


@pytest.mark.parametrize("traversal", ["bvh8", "bvh4"])
def test_one_triangle_meshes_trace_like_the_reference(backend, traversal):
    for name in ("one", "flat", "far"):
        v, f = _meshes()[name]
        scene = _mesh_scene(name, v, f)
        rng = np.random.default_rng(2)
        target = v[f[rng.integers(0, len(f), 500)]].astype(np.float64)
        w = rng.dirichlet([1, 1, 1], 500)
        p = np.einsum("nk,nkc->nc", w, target)
        o = (p + rng.normal(size=(500, 3))).astype(np.float32)
        d = (p - o).astype(np.float32)
        got = trace(scene, o, d, backend=backend, variant=Variant(traversal, "watertight"))
        ref = reference_trace(v, f, o, d)
        c = compare_hits(ref, got.tri, got.t, v, f, o, d)
        assert c.n_mismatch == 0, f"{name}: {c.summary()}"


@pytest.mark.parametrize("name", ["default", "slivers", "one", "far", "flat"])
def test_host_mirrors_find_the_reference_hits(name):
    v, f = _meshes()[name]
    scene = _mesh_scene(name, v, f)
    rng = np.random.default_rng(5)
    lo, hi = scene.bounds().astype(np.float64)
    o = rng.uniform(lo - 0.3 * (hi - lo), hi + 0.3 * (hi - lo), (600, 3)).astype(np.float32)
    target = v[f[rng.integers(0, len(f), 600)]].mean(axis=1)
    d = (target - o).astype(np.float32)
    ref = reference_trace(v, f, o, d)
    for counts in (traversal_counts_bvh8(build_bvh8(v, f), v, f, o, d), traversal_counts_bvh4(build_bvh4(v, f), v, f, o, d)):
        _, _, _, tri, t = counts
        c = compare_hits(ref, tri, t.astype(np.float32), v, f, o, d)
        assert c.n_mismatch == 0, c.summary()


def test_bvh4_mirror_rounds_add_up_to_its_counts():
    """The rounds the 4-wide mirror records (experiments/fetch_lane_model.py's input: each round the inner
    nodes visited, the leaf's triangles, the entries popped) add up to its own visit and test counts
    and end where the walk does (-1 after); rays that miss the scene box have none."""
    v, f = _meshes()["default"]
    rng = np.random.default_rng(9)
    lo, hi = v.min(0).astype(np.float64), v.max(0).astype(np.float64)
    o = rng.uniform(lo - 0.3 * (hi - lo), hi + 0.3 * (hi - lo), (800, 3)).astype(np.float32)
    d = (v[f[rng.integers(0, len(f), 800)]].mean(axis=1) - o).astype(np.float32)
    d[:50] = -d[:50]                                             # some point away and miss
    b = build_bvh4(v, f)
    rounds = np.zeros((len(o), 64, 3), np.int64)
    nodes, _, tris, _, _ = traversal_counts_bvh4(b, v, f, o, d, rounds=rounds)
    used = rounds[:, :, 0] >= 0
    assert np.array_equal(np.where(used, rounds[:, :, 0], 0).sum(1), nodes)
    assert np.array_equal(np.where(used, rounds[:, :, 1], 0).sum(1), tris)
    assert np.all(np.diff(used.astype(int), axis=1) <= 0), "a round after the walk's end"
    assert np.all(rounds[~used] == -1) and used[:, 0].sum() < len(o) and used[:, 0].sum() > len(o) // 2
    assert np.all(rounds[used][:, 2] >= 0)


# ---- the traversal on the backends -------------------------------------------------------------------
_cases: dict = {}


def _case(name):
    if name not in _cases:
        require_scene_file(SCENES[name])
        scene = rtlab.load_scene(name, size=48)
        o, d = camera_rays(scene.camera)
        rng = np.random.default_rng(11)
        lo, hi = scene.bounds().astype(np.float64)
        o2 = rng.uniform(lo - 0.3 * (hi - lo), hi + 0.3 * (hi - lo), (1500, 3)).astype(np.float32)
        d2 = rng.normal(size=(1500, 3))
        d2 = (d2 / np.linalg.norm(d2, axis=1, keepdims=True)).astype(np.float32)
        o, d = np.concatenate([o, o2]), np.concatenate([d, d2])
        _cases[name] = (scene, o, d, reference_trace(scene.vertices, scene.faces, o, d))
    return _cases[name]


@pytest.mark.parametrize("traversal", ["bvh8", "bvh4"])
@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("isect", ["watertight", "moller"])
def test_wide_bvh_matches_the_reference_and_the_binary_bvh(backend, traversal, name, isect):
    """0 mismatches against the float64 reference; against "bvh" with the same test the very same ids,
    and with the watertight test (t from the plane, in double) the very same t."""
    scene, o, d, ref = _case(name)
    got = trace(scene, o, d, backend=backend, variant=Variant(traversal, isect))
    c = compare_hits(ref, got.tri, got.t, scene.vertices, scene.faces, o, d)
    assert c.n_mismatch == 0 and c.t_rel_err_max <= 1e-5, c.summary()
    binary = trace(scene, o, d, backend=backend, variant=Variant("bvh", isect))
    assert np.array_equal(got.tri, binary.tri), f"{np.sum(got.tri != binary.tri)} ids differ from bvh"
    if isect == "watertight":
        assert np.array_equal(got.t, binary.t)


OCTANT_WALKS = {"RT_BVH4_OCTANT_WALKS": 2}      # rt_bvh4.h: the walk inlined per octant, for every ray


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("isect", ["watertight", "moller"])
def test_bvh4_octant_walks_give_the_plain_walks_hits(backend, name, isect):
    """The 4-wide walk inlined once per ray octant (RT_BVH4_OCTANT_WALKS: the library's camera rays,
    where a warp shares the octant) gives the plain walk's t, ids and barycentrics bit for bit, in
    every octant. Forced on every ray: PoCL has no warps to ask, and a GPU warp may take either walk."""
    scene, o, d, _ = _case(name)
    octants = np.unique(4 * (d[:, 0] < 0) + 2 * (d[:, 1] < 0) + (d[:, 2] < 0))
    assert len(octants) == 8, "the rays should cover every octant"
    variant = Variant("bvh4", isect)
    plain = trace(scene, o, d, backend=backend, variant=variant, defines={"RT_BVH4_OCTANT_WALKS": 0})
    walks = trace(scene, o, d, backend=backend, variant=variant, defines=OCTANT_WALKS)
    for field in ("t", "tri", "u", "v"):
        a, b = getattr(plain, field), getattr(walks, field)
        assert np.array_equal(a.view(np.uint32), b.view(np.uint32)), f"{field}: {np.sum(a != b)} rays differ"


@pytest.mark.parametrize("traversal", ["bvh8", "bvh4"])
def test_wide_bvh_shadows_and_bounces_match_the_binary_bvh(backend, traversal):
    """Any-hit (shadow rays) and closest hit of secondary rays through the Whitted path (shadows, two
    bounces, both schedules): the same image as the binary BVH."""
    from rtlab.device.whitted import render_whitted
    scene = rtlab.load_scene("default", size=48)
    for schedule, shadows in (("tree", "two-pass"), ("wavefront", "one-pass")):
        a = render_whitted(scene, backend, Variant("bvh", "watertight"), shadows=shadows, bounces=2,
                           schedule=schedule)
        b = render_whitted(scene, backend, Variant(traversal, "watertight"), shadows=shadows, bounces=2,
                           schedule=schedule)
        assert np.array_equal(a.image, b.image), schedule
        if traversal == "bvh4":          # any hit and secondary rays through the per-octant walks
            c = render_whitted(scene, backend, Variant(traversal, "watertight"), shadows=shadows, bounces=2,
                               schedule=schedule, defines=OCTANT_WALKS)
            assert np.array_equal(a.image, c.image), f"{schedule}, per-octant walks"


@pytest.mark.parametrize("traversal", ["bvh8", "bvh4"])
def test_wide_bvh_counting_build_counts_its_reads(backend, traversal):
    """The grader's counting build (RT_COUNT_WORK) compiles with the traversal and counts its reads."""
    from rtlab.device.device_scene import device_scene
    scene = rtlab.load_scene("default", size=16)
    o, d = camera_rays(scene.camera)
    ds = device_scene(scene, backend)
    ds.reserve_work_counters(len(o))
    got = trace(scene, o, d, backend=backend, variant=Variant(traversal, "watertight", count_work=True))
    plain = trace(scene, o, d, backend=backend, variant=Variant(traversal, "watertight"))
    assert np.array_equal(got.tri, plain.tri)
    tree, tris = ds.take_work_counts()
    assert tree > 0 and tree % 1 == 0 and tris >= 0


@pytest.mark.parametrize("name", ["sponza", "kitchen"])
def test_bvh4_per_ray_windows_match_the_reference(backend, name):
    """tmin and tmax per ray (a window holding the first hit, one ending before it, one starting past
    it, one starting far inside the scene): the 4-wide walk clamps its boxes' entries at 0, not at
    tmin, so boxes that end before tmin are entered and their hits refused by the triangle test.
    0 mismatches against the float64 reference with the same windows, and the binary BVH's ids."""
    scene, o, d, ref = _case(name)
    rng = np.random.default_rng(7)
    which = rng.integers(0, 4, len(o))
    t = np.where(ref.tri >= 0, ref.t, 1.0)
    tmin = np.select([which == 2, which == 3], [t * 1.001, t * rng.uniform(0.3, 0.9, len(o))], 0.0).astype(np.float32)
    tmax = np.where(which == 1, t * 0.999, np.inf).astype(np.float32)
    got = trace(scene, o, d, backend=backend, variant=Variant("bvh4", "watertight"), tmin=tmin, tmax=tmax)
    want = reference_trace(scene.vertices, scene.faces, o, d, tmin=tmin, tmax=tmax)
    c = compare_hits(want, got.tri, got.t, scene.vertices, scene.faces, o, d, tmin=tmin, tmax=tmax)
    assert c.n_mismatch == 0 and c.t_rel_err_max <= 1e-5, c.summary()
    binary = trace(scene, o, d, backend=backend, variant=Variant("bvh", "watertight"), tmin=tmin, tmax=tmax)
    assert np.array_equal(got.tri, binary.tri), f"{np.sum(got.tri != binary.tri)} ids differ from bvh"


@pytest.mark.parametrize("name", list(SCENES))
def test_bvh4_walk_reads_the_nodes_its_float64_mirror_visits(backend, name):
    """The 4-wide walk's culling and order, counted: its counting build reads 7 rows a node visit, 3 a
    triangle test and one ref a popped child, so over the rays its reads lie between 7 V + 3 T and
    8 V + 3 T for the V visits and T tests of the float64 host mirror of rt_bvh4.h's order (a few %
    either way for float ties). A walk that kept the same hits but culled or sorted worse (the box
    distances in the wrong units, a cut not applied) reads many times more."""
    from rtlab.accel.bvh4 import load_or_build_bvh4
    from rtlab.device.device_scene import device_scene
    scene, o, d, _ = _case(name)
    ds = device_scene(scene, backend)
    ds.reserve_work_counters(len(o))
    trace(scene, o, d, backend=backend, variant=Variant("bvh4", "watertight", count_work=True))
    reads = ds.take_work_counts()[0]
    b4, _ = load_or_build_bvh4(scene.vertices, scene.faces)
    visits, _, tests, _, _ = traversal_counts_bvh4(b4, scene.vertices, scene.faces, o, d)
    lo, hi = 7 * visits.sum() + 3 * tests.sum(), 8 * visits.sum() + 3 * tests.sum()
    assert 0.97 * lo <= reads <= 1.03 * hi, f"{reads} reads, mirror {lo}..{hi}"


@pytest.mark.gpu
def test_gpu_wide_bvhs_match_bvh_on_the_benchmark_views():
    """On the GPU machine, CUDA and NVIDIA OpenCL: the benchmark views' primary and diffuse rays at
    256², bvh8 and bvh4 against the float64 reference (0 mismatches) and against bvh (the same ids)."""
    from rtlab.backends import get_backend
    from rtlab.benches.rays import make_rays
    for view in ("bunny/far", "dragon/fill", "sponza/inside", "kitchen/inside", "conference/inside"):
        for kind in ("primary", "diffuse"):
            batch = make_rays(view, kind, 256, check_rays=4096)
            for be in (get_backend("cuda"), get_backend("opencl", "NVIDIA")):
                binary = trace(batch.scene, batch.origins, batch.directions, be, Variant("bvh", "watertight"))
                for traversal in ("bvh8", "bvh4"):
                    got = trace(batch.scene, batch.origins, batch.directions, be, Variant(traversal, "watertight"))
                    e = batch.error(got.tri, got.t)
                    assert e["mismatches"] == 0, f"{view} {kind} {be.name} {traversal}: {e}"
                    differ = int(np.sum(got.tri != binary.tri))
                    assert differ == 0, f"{view} {kind} {be.name} {traversal}: {differ} ids differ from bvh"
                if kind == "primary":   # per-octant walks where a warp shares the octant (got), in every warp, in none
                    for defines in (OCTANT_WALKS, {"RT_BVH4_OCTANT_WALKS": 0}):
                        other = trace(batch.scene, batch.origins, batch.directions, be, Variant("bvh4", "watertight"),
                                      defines=defines)
                        assert all(np.array_equal(getattr(got, f), getattr(other, f)) for f in ("t", "tri", "u", "v")), \
                            f"{view} {be.name} {defines}"


@pytest.mark.parametrize("traversal", ["bvh8", "bvh4", "bvh", "stack"])
def test_axis_aligned_rays_from_far_away_hit_small_triangles(backend, traversal):
    """Rays along +z (two zero direction components) from up to 3e38 away, through the inside of
    triangles of size 2^-20 in a unit grid: well-conditioned hits (barycentrics 0.4 and 0.2, exact in
    any arithmetic), so every traversal must return the reference's ids exactly: bvh8's quantised slab
    for a zero component spans only 2^64 x the slack in t unless padded by the ray's length."""
    n, size = 8, 2.0 ** -20
    grid = [(i / n, j / n) for i in range(n) for j in range(n)]
    v = np.array([[x + dx * size, y + dy * size, 0.0] for x, y in grid for dx, dy in ((0, 0), (1, 0), (0, 1))])
    f = np.arange(len(v)).reshape(-1, 3)
    scene = _mesh_scene("tiny-grid", v, f)
    start = np.array([1e3, 2.0 ** 30, 2.0 ** 43, 1e18, 3e38])
    at = np.array([[x + 0.4 * size, y + 0.2 * size] for x, y in grid[::5]])
    o = np.array([[a[0], a[1], -z] for z in start for a in at], np.float32)
    d = np.tile(np.float32([0.0, 0.0, 1.0]), (len(o), 1))
    got = trace(scene, o, d, backend=backend, variant=Variant(traversal, "watertight"))
    ref = reference_trace(v, f, o, d)
    assert np.all(ref.tri >= 0)
    assert np.array_equal(got.tri, ref.tri), f"{np.count_nonzero(got.tri != ref.tri)} of {len(o)} rays differ"
