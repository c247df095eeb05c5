"""Traversal variants of the paper's Table 4 (lab step 03) and the BVH, on every available backend.

Every variant must find the hits of the stack traversal and of the float64 reference: triangle ids
exact apart from reported ties, t within 1e-5 of the reference. Against the stack traversal (the
same triangle test) a variant may only differ in which of two triangles at the same t it reports:
hit or miss is the same, t equal to rounding. Cases: camera and random rays on BUNNY, SPONZA,
KITCHEN; rays lying in split planes; a deliberately deep tree with every short-stack size; any-hit
against closest-hit. Host invariants of ropes and the BVH are checked against boxes recomputed here.
"""
from __future__ import annotations

import numpy as np
import pytest

import rtlab
from rtlab.accel.bvh import MAX_LEAF, build_bvh, decode_leaf
from rtlab.accel.kdtree import KdBuildParams, build_kdtree
from rtlab.accel.ropes import build_ropes
from rtlab.device.kernels import SceneFeatures, TRAVERSALS, Variant, build_defines, kernel_source, primary_step
from rtlab.device.layout import float4_rows
from rtlab.device.rendering import render
from rtlab.device.device_scene import DeviceScene, device_scene, padded_bounds, scene_kdtree
from rtlab.device.tracing import trace
from rtlab.errors import VariantError
from rtlab.reference import compare_hits, reference_trace
from rtlab.scene.model import Camera, Material, Scene, camera_rays

from .conftest import require_scene_file

# t against the float64 reference (as tests/test_primary.py) and against the stack traversal: the
# same float32 test, but each kernel may contract multiply-adds differently, which grazing hits
# amplify; a missed cell shows as a far larger difference (another surface behind)
T_REL_TOL = 1e-5
VARIANTS = ["packet", "restart", "shortstack", "ropes", "bvh", "bvh-packet", "bvh8", "bvh4", "bvh-wide"]
BVH_VARIANTS = ("bvh", "bvh-packet", "bvh8", "bvh4", "bvh-wide")
SCENES = {"bunny": "bunny.ply", "sponza": "sponza/sponza.obj", "kitchen": "kitchen/kitchen.obj"}
SIZE = 48


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------
def _preset(name):
    require_scene_file(SCENES[name])
    return rtlab.load_scene(name, size=SIZE)


def _scene_from_mesh(name, vertices, faces):
    return Scene(name, np.asarray(vertices, np.float32), np.asarray(faces, np.int32),
                 np.zeros(len(faces), np.int32), [Material()], Camera((2.0, 2.0, 2.0), (0.0, 0.0, 0.0)),
                 source="procedural")


def _use_tree(scene, backend, tree):
    """Trace ``scene`` on ``backend`` with this kd-tree instead of the cached default build."""
    device_scene(scene, backend, tree=tree)


def _random_rays(scene, n, seed):
    """Rays from random points inside and around the scene box, any direction."""
    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds().astype(np.float64)
    ext = hi - lo
    o = rng.uniform(lo - 0.5 * ext, hi + 0.5 * ext, size=(n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d.astype(np.float32)


def _split_plane_rays(scene, tree, n, seed):
    """Rays lying in split planes of the kd-tree (zero direction component along the split axis,
    origin on the plane), a third of them along a coordinate axis."""
    rng = np.random.default_rng(seed)
    inner = np.flatnonzero(~tree.is_leaf())
    pick = rng.choice(inner, n)
    axis, pos = tree.split_axis()[pick], tree.split_pos()[pick]
    lo, hi = scene.bounds()
    rows = np.arange(n)
    o = rng.uniform(lo, hi, size=(n, 3)).astype(np.float32)
    o[rows, axis] = pos
    d = rng.normal(size=(n, 3))
    d[rows, axis] = 0.0
    along = rng.uniform(size=n) < 0.3
    other = (axis + 1 + rng.integers(0, 2, n)) % 3
    d[along, other[along]] = 0.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d.astype(np.float32)
    d[rows, axis] = 0.0
    return o, d


class Case:
    """Rays of one scene with their float64 reference and stack-traversal hits."""

    def __init__(self, scene, o, d, backend, t_tol=T_REL_TOL):
        self.scene, self.o, self.d, self.t_tol = scene, o, d, t_tol
        self.ref = reference_trace(scene.vertices, scene.faces, o, d)
        self.stack = trace(scene, o, d, backend=backend, variant=Variant.paper(traversal="stack"))

    def compare(self, got, where):
        s = self.scene
        c = compare_hits(self.ref, got.tri, got.t, s.vertices, s.faces, self.o, self.d)
        assert c.n_mismatch == 0, f"{where}: {c.summary()}"
        assert c.t_rel_err_max <= self.t_tol, f"{where}: {c.summary()}"
        return c
        return c

    def assert_like_stack(self, got, where, same_tree=True):
        """No mismatch against the reference (so a triangle other than the stack's is a tie),
        the same hit or miss as the stack traversal, t equal to rounding. A traversal of the same
        kd-tree tests the same triangles in the same cells, only in another order, so this holds
        for every ray; the BVH tests whole triangles where the kd-tree tests them clipped to
        cells, so near an edge float32 can hit one and not the other: there only where the
        reference calls the ray a tie."""
        c = self.compare(got, where)
        stack = self.stack
        hit, stack_hit = got.tri >= 0, stack.tri >= 0
        with np.errstate(invalid="ignore"):
            dt = np.abs(got.t - stack.t) / np.abs(stack.t)
        differ = (hit != stack_hit) | (hit & stack_hit & ~(dt <= self.t_tol))
        if not same_tree:
            differ &= ~c.tie
        bad = np.flatnonzero(differ)
        assert bad.size == 0, (f"{where}: {bad.size} rays differ from the stack traversal, e.g. ray {bad[0]}: "
                               f"tri {got.tri[bad[0]]} t {got.t[bad[0]]} against tri {stack.tri[bad[0]]} t {stack.t[bad[0]]}")


_cases: dict = {}


def _case(kind, name, backend):
    key = (kind, name, id(backend))
    if key not in _cases:
        scene = _preset(name)
        if kind == "camera+random":
            o, d = camera_rays(scene.camera)
            o2, d2 = _random_rays(scene, 1500, seed=7)
            o, d = np.concatenate([o, o2]), np.concatenate([d, d2])
            _cases[key] = Case(scene, o, d, backend)
        else:
            # Rays in a plane meet many surfaces at grazing angles, where the float32 test's t
            # is off by more (the stack traversal's too)
            o, d = _split_plane_rays(scene, scene_kdtree(scene), 1500, seed=11)
            _cases[key] = Case(scene, o, d, backend, t_tol=1e-4)
    return _cases[key]


# ------------------------------------------------------------------------------------------------
# every variant against the stack traversal and the float64 reference
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("scene_name", list(SCENES))
def test_variant_matches_stack_and_reference(backend, scene_name, variant):
    """Camera rays and random rays from inside and outside the scene."""
    case = _case("camera+random", scene_name, backend)
    case.compare(case.stack, f"{scene_name} stack")
    got = trace(case.scene, case.o, case.d, backend=backend, variant=Variant.paper(traversal=variant))
    case.assert_like_stack(got, f"{scene_name} {variant}", same_tree=variant not in BVH_VARIANTS)
    assert np.mean(case.ref.tri >= 0) > 0.1


@pytest.mark.parametrize("variant", VARIANTS)
def test_rays_in_split_planes(backend, variant):
    """Axis-aligned walls put split planes where rays lie in them: both sides must be searched
    (the stackless traversals make one pass per side)."""
    case = _case("split-planes", "sponza", backend)
    case.compare(case.stack, "sponza stack, rays in split planes")
    got = trace(case.scene, case.o, case.d, backend=backend, variant=Variant.paper(traversal=variant))
    case.assert_like_stack(got, f"sponza {variant}, rays in split planes", same_tree=variant not in BVH_VARIANTS)


@pytest.mark.parametrize("variant", ["stack"] + VARIANTS)
def test_render_matches_reference(backend, variant):
    """The renderer's kernel (2D blocks: one packet per block for the packet traversal)."""
    from rtlab.reference.check import check_render
    scene = _preset("bunny")
    result = render(scene, backend, Variant.paper(traversal=variant, block=(16, 4)), write_hits=True)
    report = check_render(scene, result, scene.camera)
    assert report.hits.n_mismatch == 0, report.summary()
    assert report.hits.t_rel_err_max <= T_REL_TOL, report.summary()
    assert report.hits.n_hits_ref > 0


@pytest.mark.parametrize("variant", ["stack"] + VARIANTS)
def test_single_triangle_scene(backend, variant):
    """The smallest trees: a kd root that is a leaf, a BVH whose root holds one leaf twice."""
    scene = _scene_from_mesh("one", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    o = np.array([[0.2, 0.2, 1], [0.9, 0.9, 1], [0.25, 0.25, -1], [0, 0, 1]], np.float32)
    d = np.array([[0, 0, -1], [0, 0, -1], [0, 0, 1], [0, 0, -1]], np.float32)
    got = trace(scene, o, d, backend=backend, variant=Variant.paper(traversal=variant))
    assert got.tri.tolist() == [0, -1, 0, 0]
    assert np.allclose(got.t[[0, 2, 3]], 1.0)


# ------------------------------------------------------------------------------------------------
# a deep tree: short stacks far smaller than the depth, falling back to restarts
# ------------------------------------------------------------------------------------------------
DEEP_LEVELS, DEEP_SHRINK = 48, 0.6


@pytest.fixture(scope="module")
def deep_scene():
    """Triangle pairs in boxes shrinking by 0.6 toward the origin, level after level: the SAH
    cuts one level off at a time, so the tree is as deep as there are levels."""
    rng = np.random.default_rng(1)
    corners = [rng.uniform(DEEP_SHRINK, 1.0, size=(3, 3)) * DEEP_SHRINK ** k
               for k in range(DEEP_LEVELS) for _ in range(2)]
    vertices = np.concatenate(corners).astype(np.float32)
    faces = np.arange(len(vertices), dtype=np.int32).reshape(-1, 3)
    scene = _scene_from_mesh("deep", vertices, faces)
    tree = build_kdtree(scene.vertices, scene.faces, KdBuildParams(max_depth=63))
    assert tree.depth > 30, f"the deep scene only made a tree of depth {tree.depth}"
    # Rays at every scale, most aimed at a triangle of their level or a few levels deeper
    n = 3000
    level = rng.integers(0, DEEP_LEVELS, size=n)
    s = (DEEP_SHRINK ** level)[:, None]
    o = (rng.uniform(-0.2, 1.3, size=(n, 3)) * s).astype(np.float32)
    tri = 2 * np.minimum(level + rng.integers(0, 4, size=n), DEEP_LEVELS - 1) + rng.integers(0, 2, size=n)
    target = np.where(rng.uniform(size=(n, 1)) < 0.7, scene.vertices[scene.faces[tri]].mean(1),
                      rng.uniform(0, 1, size=(n, 3)) * s)
    d = target - o
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    return scene, tree, o, d


@pytest.mark.parametrize("variant", [Variant.paper(traversal="shortstack", short_stack=k) for k in (1, 2, 4, 8)]
                         + [Variant.paper(traversal=v) for v in ("restart", "ropes", "packet")], ids=lambda v: v.label().split("/")[0])
def test_deep_tree(backend, deep_scene, variant):
    scene, tree, o, d = deep_scene
    _use_tree(scene, backend, tree)
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    stack = trace(scene, o, d, backend=backend, variant=Variant.paper(traversal="stack"))
    got = trace(scene, o, d, backend=backend, variant=variant)
    assert np.mean(stack.tri >= 0) > 0.5
    # Tiny, steep triangles: the float32 test's t is off by up to ~1e-4 (the stack's too), and by
    # more between two kernels that contract multiply-adds differently; the triangle ids are exact
    for name, r in (("stack", stack), (variant.label(), got)):
        c = compare_hits(ref, r.tri, r.t, scene.vertices, scene.faces, o, d)
        assert c.n_mismatch == 0, f"deep tree (depth {tree.depth}) {name}: {c.summary()}"
    assert np.array_equal(got.tri, stack.tri), f"{variant.label()}: {np.sum(got.tri != stack.tri)} rays differ from the stack"
    hit = stack.tri >= 0
    assert np.all(np.abs(got.t[hit] - stack.t[hit]) <= 1e-3 * stack.t[hit])


def test_stack_size_follows_tree_depth(backend, deep_scene):
    """The per-thread (and the packet's shared) stack is sized from the tree: depth + 1."""
    scene, tree, _, _ = deep_scene
    ds = DeviceScene.upload(backend, scene, tree)
    assert ds.features(Variant.paper(traversal="stack")).stack_size == tree.depth + 1
    assert ds.features(Variant.paper(traversal="packet")).stack_size == tree.depth + 1
    bvh_stack = ds.features(Variant.paper(traversal="bvh")).stack_size
    assert bvh_stack == build_bvh(scene.vertices, scene.faces).depth + 1


# ------------------------------------------------------------------------------------------------
# any hit (shadow rays) agrees with closest hit on whether something is hit
# ------------------------------------------------------------------------------------------------
ANY_HIT_KERNEL = r"""
#define RT_PACKET_KERNELS 1
#include "rt_traverse.h"
#if RT_TRAVERSAL == RT_TRAVERSAL_PACKET
#include "rt_packet.h"
#endif
RT_KERNEL void any_hits(RT_SCENE_PARAMS, RT_GLOBAL const float4 *box, RT_GLOBAL const float4 *origins,
                        RT_GLOBAL const float4 *directions, RT_GLOBAL int *blocked, int n)
{
    int i = rt_global_id(0);
    int valid = i < n;
    int j = valid ? i : 0;
    Ray ray = make_ray(xyz(origins[j]), xyz(directions[j]), origins[j].w, directions[j].w);
#if RT_TRAVERSAL == RT_TRAVERSAL_PACKET
    RT_SHARED KdPacketShared packet;
    Hit hit = make_miss(ray.tmax);
    traverse_kd_packet(RT_SCENE_ARGS, box[0], box[1], &ray, valid, &hit, 1, &packet, rt_local_id(0));
    int any = hit.tri >= 0;
#else
    int any = trace_any(RT_SCENE_ARGS, box[0], box[1], &ray);
#endif
    if (valid)
        blocked[i] = any;
}
"""


@pytest.mark.parametrize("variant", ["stack"] + VARIANTS)
def test_any_hit_agrees_with_closest_hit(backend, variant, tmp_path):
    """Shadow-ray segments (finite tmax) and whole rays: blocked exactly when a closest hit exists."""
    case = _case("camera+random", "sponza", backend)
    scene = case.scene
    n = len(case.o)
    tmax = np.where(np.arange(n) % 2 == 0, np.inf, np.random.default_rng(3).uniform(0.1, 20.0, n)).astype(np.float32)
    v = Variant.paper(traversal=variant)
    closest = trace(scene, case.o, case.d, backend=backend, variant=v, tmax=tmax)
    src = tmp_path / ("any_hit" + backend.extension)
    src.write_text(ANY_HIT_KERNEL)
    ds = device_scene(scene, backend)
    program = backend.compile(src, build_defines(v, ds.features(v)))
    box = np.zeros((2, 4), np.float32)
    box[:, :3] = padded_bounds(scene.bounds())
    out = backend.empty(4 * n)
    program.launch("any_hits", (n,), (64,),
                   ds.scene_args(v) + [backend.to_device(box), backend.to_device(float4_rows(case.o, 0.0)),
                                       backend.to_device(float4_rows(case.d, tmax)), out, np.int32(n)])
    blocked = backend.to_host(out, np.int32, n).astype(bool)
    assert 0.2 < blocked.mean() < 0.95
    differ = np.flatnonzero(blocked != (closest.tri >= 0))
    assert differ.size == 0, f"{variant}: any-hit and closest-hit disagree on {differ.size} rays, e.g. {differ[:5]}"


# ------------------------------------------------------------------------------------------------
# host structures: ropes, BVH
# ------------------------------------------------------------------------------------------------
def _node_boxes(tree):
    """Cell box of every kd node, level by level from the root box (independent of ropes.py)."""
    n = len(tree.nodes)
    boxes = np.zeros((n, 2, 3), np.float32)
    boxes[0] = tree.bounds
    leaf = tree.is_leaf()
    axis, split, child = tree.split_axis(), tree.split_pos(), tree.child_or_count()
    level = np.array([0])
    while level.size:
        level = level[~leaf[level]]
        lo, hi = child[level], child[level] + 1
        boxes[lo] = boxes[level]
        boxes[hi] = boxes[level]
        boxes[lo, 1, axis[level]] = split[level]
        boxes[hi, 0, axis[level]] = split[level]
        level = np.concatenate([lo, hi])
    return boxes


def test_ropes_point_to_nodes_covering_each_leaf_face():
    """Every rope of every leaf face points to a node whose box touches that face and covers it;
    -1 only on the scene boundary, where a rope leads only to a flat cell lying in the boundary
    (the ground's triangles cut off by a split on the root's face). Leaf records hold the leaf's
    box and objects."""
    scene = rtlab.load_scene("default", size=16)
    tree = scene_kdtree(scene)
    boxes = _node_boxes(tree)
    ropes = build_ropes(tree)
    leaves = np.flatnonzero(tree.is_leaf())
    assert np.array_equal(ropes.leaf_nodes, leaves)
    rec = ropes.records.reshape(-1, 4, 4)
    bits = rec.view(np.int32)
    assert np.array_equal(rec[:, 0, :3], boxes[leaves, 0]) and np.array_equal(rec[:, 1, :3], boxes[leaves, 1])
    assert np.array_equal(bits[:, 3, 0], tree.nodes[leaves, 1])
    assert np.array_equal(ropes.nodes[leaves, 1], np.arange(len(leaves)))
    leaf_ropes = np.stack([bits[:, 0, 3], bits[:, 1, 3], bits[:, 2, 0], bits[:, 2, 1], bits[:, 2, 2], bits[:, 2, 3]], 1)
    n_checked = 0
    for face in range(6):
        axis, upper = face // 2, face % 2
        r = leaf_ropes[:, face]
        face_coord = boxes[leaves, upper, axis]
        on_boundary = face_coord == tree.bounds[upper, axis]
        assert np.all(on_boundary[r < 0]), f"face {face}: ropes missing"
        flat_beyond = boxes[r[on_boundary & (r >= 0)]]
        assert np.all(flat_beyond[:, 0, axis] == tree.bounds[upper, axis]), f"face {face}: rope leaves the scene"
        assert np.all(flat_beyond[:, 1, axis] == tree.bounds[upper, axis]), f"face {face}: rope leaves the scene"
        inside = r >= 0
        nb = boxes[r[inside]]
        lb = boxes[leaves[inside]]
        # The neighbour's opposite face lies in the leaf's face plane ...
        assert np.array_equal(nb[:, 1 - upper, axis], face_coord[inside])
        # ... and covers the leaf's face in the two other axes
        for other in {0, 1, 2} - {axis}:
            assert np.all(nb[:, 0, other] <= lb[:, 0, other]) and np.all(nb[:, 1, other] >= lb[:, 1, other])
        n_checked += int(inside.sum())
    assert n_checked > len(leaves)


def test_bvh_invariants():
    """Every usable triangle in exactly one leaf; child boxes contain their triangles and the
    boxes of their children; leaves within the device encoding; depth as the stack needs it."""
    scene = rtlab.load_scene("default", size=16)
    v = scene.vertices.copy()
    f = np.concatenate([scene.faces, [[0, 0, 1]], [[0, 1, 1]]]).astype(np.int32)   # two zero-area triangles
    bvh = build_bvh(v, f)
    tri_lo, tri_hi = v[f].min(axis=1), v[f].max(axis=1)
    seen = np.zeros(len(f), np.int64)
    max_depth = 0
    todo = [(0, 1)]
    while todo:
        node, depth = todo.pop()
        for c in range(2):
            ref = int(bvh.child_ref[node, c])
            lo, hi = bvh.child_lo[node, c], bvh.child_hi[node, c]
            if ref >= 0:
                assert np.all(bvh.child_lo[ref] >= lo) and np.all(bvh.child_hi[ref] <= hi)
                todo.append((ref, depth + 1))
                continue
            first, count = decode_leaf(ref)
            assert 1 <= count <= MAX_LEAF
            tris = bvh.objects[first:first + count]
            seen[tris] += 1
            assert np.all(tri_lo[tris] >= lo) and np.all(tri_hi[tris] <= hi)
            max_depth = max(max_depth, depth)
    assert np.all(seen[:-2] == 1), "a usable triangle is missing or referenced twice"
    assert np.all(seen[-2:] == 0), "a zero-area triangle was referenced"
    assert bvh.depth == max_depth
    assert np.array_equal(bvh.bounds, np.stack([tri_lo[:-2].min(0), tri_hi[:-2].max(0)]))
    node_data = bvh.node_data().reshape(-1, 4, 4)
    assert np.array_equal(node_data.view(np.int32)[:, 3, :2], bvh.child_ref)
    assert np.array_equal(node_data[:, 0, [0, 2]], bvh.child_lo[:, 0, :2])
    assert np.array_equal(node_data[:, 2, [1, 3]], bvh.child_hi[:, :, 2])


def test_bvh_cache_round_trip(tmp_path):
    from rtlab.accel.bvh import load_or_build_bvh
    scene = rtlab.load_scene("default", size=16)
    a, cached_a = load_or_build_bvh(scene.vertices, scene.faces, cache_dir=tmp_path)
    b, cached_b = load_or_build_bvh(scene.vertices, scene.faces, cache_dir=tmp_path)
    assert (cached_a, cached_b) == (False, True)
    for name in ("child_lo", "child_hi", "child_ref", "objects", "bounds"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert a.depth == b.depth


# ------------------------------------------------------------------------------------------------
# kernels and loader
# ------------------------------------------------------------------------------------------------
def test_packet_runs_in_the_trace_programs_and_single_ray_programs_refuse_it(backend):
    """The kd packet's stack lives in block-wide memory that only the entry kernels of closest hits and
    primary rays declare: lab step 03 (the labs') and the library's trace program run it; a program of
    single-ray kernels (shadows) is a build error, not a silent fallback to another traversal."""
    from rtlab.device.variants import program_for
    from rtlab.errors import KernelBuildError
    packet = Variant.paper(traversal="packet")
    assert primary_step(packet) == "03_traversal" and program_for("trace", packet) == "library_trace"
    assert {primary_step(Variant.paper(traversal=v)) for v in TRAVERSALS if v != "packet"} == {"00_primary"}
    defines = build_defines(packet, SceneFeatures(stack_size=32))
    backend.compile(kernel_source("library_trace", backend.language), defines)
    with pytest.raises(KernelBuildError, match="block-wide shared stack"):
        backend.compile(kernel_source("library_shadows", backend.language), defines)
    with pytest.raises(VariantError, match="no shadow or secondary-ray kernels"):
        program_for("shadows", packet)


@pytest.mark.parametrize("variant", ["restart", "shortstack", "ropes"])
def test_stackless_traversals_refuse_trees_deeper_than_their_tie_bits(backend, variant):
    """The stackless descents keep one bit per tree level (64 bits): a deeper tree is a build
    error naming the limit, never a silent loss of hits."""
    from rtlab.errors import KernelBuildError
    defines = build_defines(Variant.paper(traversal=variant), SceneFeatures(stack_size=65))
    with pytest.raises(KernelBuildError, match="deeper than 63"):
        backend.compile(kernel_source(primary_step(Variant.paper(traversal=variant)), backend.language), defines)
    backend.compile(kernel_source(primary_step(Variant.paper(traversal=variant)), backend.language),
                    build_defines(Variant.paper(traversal=variant), SceneFeatures(stack_size=64)))


@pytest.mark.skipif(not __import__("rtlab.backends.nvcc", fromlist=["x"]).nvcc_available(), reason="nvcc not on PATH")
@pytest.mark.parametrize("variant", list(TRAVERSALS))
def test_traversal_step_compiles_for_sm90(variant):
    """03_traversal.cu with every traversal: compiles with nvcc; registers, stack and shared
    memory reported (the paper's "Reg. usage" and occupancy rows)."""
    from rtlab.backends.nvcc import nvcc_resources
    defines = build_defines(Variant.paper(traversal=variant), SceneFeatures(stack_size=30, n_lights=2, n_materials=8))
    report = nvcc_resources(kernel_source("03_traversal", "cuda"), defines)
    assert set(report) == {"trace_rays", "render_primary"}
    for name, r in report.items():
        print(f"{variant}:{name}: {r.registers} registers, {r.local_bytes} B stack, {r.shared_bytes} B shared, "
              f"{r.spill_bytes} B spills, occupancy {r.occupancy:.0%} at 128 threads")
        assert 0 < r.registers <= 255
        assert (r.shared_bytes > 0) == (variant == "packet")


def test_fused_box_test_only_for_scenes_near_the_origin():
    """The BVH's fused slab form (RT_BVH_BOX_FMA) pads by the rounding of the origin's coordinates,
    which loosens its culling far from the origin: the loader takes it only where those stay within
    a few extents of the scene."""
    from rtlab.device.device_scene import near_origin, scene_features
    from rtlab.device.kernels import build_defines
    near = _scene_from_mesh("near", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    far = _scene_from_mesh("far", [[1e5, 0, 0], [1e5 + 1, 0, 0], [1e5, 1, 0]], [[0, 1, 2]])
    assert near_origin(near) and not near_origin(far)
    assert build_defines(Variant.paper(traversal="bvh"), scene_features(near, 8))["RT_BVH_BOX_FMA"] == 1
    assert build_defines(Variant.paper(traversal="bvh"), scene_features(far, 8))["RT_BVH_BOX_FMA"] == 0
    assert "RT_BVH_BOX_FMA" not in build_defines(Variant.paper(traversal="stack"), scene_features(near, 8))


# ------------------------------------------------------------------------------------------------
# ties, the fused box test, stale uploads, the ray interval, extreme direction lengths
# ------------------------------------------------------------------------------------------------
ISECTS = ["moller", "wald", "plucker", "watertight"]


@pytest.fixture(scope="module")
def duplicated_scene():
    """A sphere over a floor with every triangle there three times, the copies at random ids (so a
    copy with a lower id comes before or after in any traversal's order); rays at random points,
    at vertices and at points on edges (ties between neighbours as well as between copies)."""
    import trimesh
    rng = np.random.default_rng(13)
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    floor_v = np.array([[-3, -1, -3], [3, -1, -3], [3, -1, 3], [-3, -1, 3]], np.float64)
    vertices = np.concatenate([sphere.vertices, floor_v])
    base = np.concatenate([sphere.faces, len(sphere.vertices) + np.array([[0, 1, 2], [0, 2, 3]])])
    copies = np.concatenate([base, base, base])
    order = rng.permutation(len(copies))
    faces = copies[order]
    group = np.empty(len(faces), np.int64)
    group[:] = order % len(base)                       # which original triangle each id copies
    lowest = np.full(len(base), len(faces))
    np.minimum.at(lowest, group, np.arange(len(faces)))
    scene = _scene_from_mesh("copies", vertices, faces)
    n = 1500
    o = np.column_stack([rng.uniform(-2.5, 2.5, n), rng.uniform(1.5, 3.0, n), rng.uniform(-2.5, 2.5, n)])
    edges = sphere.edges_unique[rng.integers(0, len(sphere.edges_unique), n)]
    k = rng.uniform(0, 1, (n, 1))
    targets = np.where(rng.uniform(size=(n, 1)) < 0.5, sphere.vertices[rng.integers(0, len(sphere.vertices), n)],
                       sphere.vertices[edges[:, 0]] * (1 - k) + sphere.vertices[edges[:, 1]] * k)
    d = targets - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return scene, o.astype(np.float32), d.astype(np.float32), lowest[group]


@pytest.mark.parametrize("isect", ISECTS)
def test_ties_go_to_the_lowest_triangle_id_in_every_traversal(backend, duplicated_scene, isect):
    """At exactly equal t the lowest id wins: a duplicated triangle is always reported as its
    lowest copy, in every traversal. The kd traversals that visit the stack's cells (restart,
    short stack, ropes) return exactly its ids, shared edges too; so do all traversals with the
    watertight test and its conservative traversal. The packet (it visits the cells its neighbours
    need) and the BVH (whole triangles, not clipped to cells) may report the other triangle of an
    edge only where the non-watertight tests' float32 t differ by rounding: ties to the reference."""
    scene, o, d, lowest = duplicated_scene
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    hit_ref = ref.tri >= 0
    assert np.array_equal(ref.tri[hit_ref], lowest[ref.tri[hit_ref]]), "the reference breaks ties alike"
    stack = trace(scene, o, d, backend=backend, variant=Variant("stack", isect))
    assert np.mean(stack.tri >= 0) > 0.9
    for traversal in ["stack"] + VARIANTS:
        got = stack if traversal == "stack" else trace(scene, o, d, backend=backend, variant=Variant(traversal, isect))
        hit = got.tri >= 0
        higher = np.flatnonzero(hit & (got.tri != lowest[np.maximum(got.tri, 0)]))
        assert higher.size == 0, f"{traversal}/{isect}: {higher.size} rays report a higher copy, e.g. ray {higher[0]}"
        c = compare_hits(ref, got.tri, got.t, scene.vertices, scene.faces, o, d)
        assert c.n_mismatch == 0, f"{traversal}/{isect}: {c.summary()}"
        if isect == "watertight" or traversal in ("restart", "shortstack", "ropes"):
            differ = np.flatnonzero(got.tri != stack.tri)
            assert differ.size == 0, (f"{traversal}/{isect}: {differ.size} rays report another triangle than the "
                                      f"stack, e.g. ray {differ[0]}: {got.tri[differ[0]]} against {stack.tri[differ[0]]}")


def _cube_grid(cubes, lo):
    from rtlab.robustness import box_mesh, merge_meshes
    v, f = merge_meshes([box_mesh((lo + i, lo + j, lo + k), (lo + i + 1, lo + j + 1, lo + k + 1))
                   for i in range(cubes) for j in range(cubes) for k in range(cubes)])
    return _scene_from_mesh("cubes", v, f)


@pytest.mark.parametrize("lo", [0, -2])
def test_fused_box_test_keeps_rays_in_box_planes(backend, lo):
    """A grid of unit cubes near the origin (the BVH takes its fused box test, RT_BVH_BOX_FMA):
    axis-aligned rays lying in the grid's planes, the outer ones included, with +0 and -0 in their
    zero components, hit exactly as the exact box test and the float64 reference say."""
    from rtlab.device.device_scene import near_origin
    scene = _cube_grid(4, lo)
    assert near_origin(scene)
    planes = np.arange(lo, lo + 5, dtype=np.float32)
    gy, gz = np.meshgrid(planes, planes, indexing="ij")
    o = np.stack([np.full(gy.size, lo - 1.0, np.float32), gy.ravel(), gz.ravel()], 1)
    rays_o, rays_d = [], []
    for zero in (np.float32(0.0), np.float32(-0.0)):
        for axis in range(3):
            oo = np.roll(o, axis, axis=1)
            dd = np.full_like(oo, zero)
            dd[:, axis] = 1.0
            rays_o.append(oo)
            rays_d.append(dd)
    o, d = np.concatenate(rays_o), np.concatenate(rays_d)
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    assert np.all(ref.tri >= 0)
    for isect in ISECTS:
        for fused in (0, 1):
            got = trace(scene, o, d, backend=backend, variant=Variant("bvh", isect), defines={"RT_BVH_BOX_FMA": fused})
            c = compare_hits(ref, got.tri, got.t, scene.vertices, scene.faces, o, d)
            assert np.all(got.tri >= 0) and c.n_mismatch == 0, f"bvh/{isect} fused={fused}: {np.sum(got.tri < 0)} missed"


def test_fused_box_test_does_not_cull_small_objects_far_from_the_origin(backend):
    """A 1e-3 sphere 2.8e3 from the origin inside a 1e5 room (so near_origin holds): rays from inside
    the sphere that the BVH's fused box test loses must not outnumber the exact test's."""
    from rtlab.robustness import family_cases, trace_case
    case = family_cases(10, "test")[1]
    for isect in ("moller", "wald", "plucker"):
        lost = {}
        for fused in (0, 1):
            tri, _, _ = trace_case(case, backend, isect, "bvh", RT_BVH_BOX_FMA=fused)
            lost[fused] = int(np.sum(~np.isin(tri, case.target_tris)))
        stack_tri, _, _ = trace_case(case, backend, isect, "stack")
        kd = int(np.sum(~np.isin(stack_tri, case.target_tris)))
        assert lost[1] <= lost[0] and lost[1] <= kd, f"{isect}: fused {lost[1]}, exact {lost[0]}, kd stack {kd} leaks"


def test_edited_scene_is_uploaded_again(backend):
    """The device upload is keyed by content: an in-place edit of the vertices, new faces or new
    material ids give the new geometry's hits, never the old upload's; equal content shares it."""
    import dataclasses
    scene = rtlab.load_scene("default", size=24)
    o, d = camera_rays(scene.camera)
    before = trace(scene, o, d, backend=backend)
    scene.vertices[:, 1] += np.float32(0.25)                    # in place: same array object
    moved = trace(scene, o, d, backend=backend)
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    assert compare_hits(ref, moved.tri, moved.t, scene.vertices, scene.faces, o, d).n_mismatch == 0
    assert np.mean(moved.t != before.t) > 0.3
    keep = np.arange(0, scene.n_triangles, 2)
    scene.faces, scene.material_ids = scene.faces[keep], scene.material_ids[keep]   # assigned anew
    fewer = trace(scene, o, d, backend=backend)
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    assert compare_hits(ref, fewer.tri, fewer.t, scene.vertices, scene.faces, o, d).n_mismatch == 0
    hits = render(scene, backend, size=24, write_hits=True).hits
    assert np.array_equal(hits.tri, fewer.tri)
    twin = dataclasses.replace(scene, vertices=scene.vertices.copy(), faces=scene.faces.copy())
    assert device_scene(twin, backend) is device_scene(scene, backend)


def test_reassigned_materials_are_checked_before_launch(backend):
    """Material ids beyond the materials list crashed the renderers; now a SceneError names the face."""
    from rtlab.errors import SceneError
    from rtlab.device.whitted import render_whitted
    scene = rtlab.load_scene("default", size=16)
    trace(scene, *camera_rays(scene.camera), backend=backend)       # uploaded with valid ids
    scene.materials = scene.materials[:2]
    for run in (lambda: render(scene, backend), lambda: render_whitted(scene, backend),
                lambda: trace(scene, *camera_rays(scene.camera), backend=backend)):
        with pytest.raises(SceneError, match=r"face \d+ has material id \d+, but the scene has 2 materials"):
            run()


def test_negative_tmin_is_refused(backend):
    """A negative tmin was answered differently by each traversal; it is an error saying what to do."""
    from rtlab.errors import RtlabError
    scene = _scene_from_mesh("one", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    o = np.array([[0.2, 0.2, -1.0], [0.2, 0.2, 1.0]], np.float32)
    d = np.array([[0, 0, 1], [0, 0, 1]], np.float32)
    with pytest.raises(RtlabError, match="tmin must be >= 0, got -1"):
        trace(scene, o, d, backend=backend, tmin=-1.0)
    with pytest.raises(RtlabError, match=r"ray 1"):
        trace(scene, o, d, backend=backend, tmin=np.array([0.0, -0.5]))
    ok = trace(scene, o, d, backend=backend, tmin=np.array([0.0, 0.5]), tmax=np.array([5.0, 5.0]))
    assert ok.tri.tolist() == [0, -1]


@pytest.mark.parametrize("variant", ["stack", "bvh", "ropes"])
def test_direction_length_does_not_change_the_answer(backend, variant):
    """Directions of length 2^-100 .. 2^100 (and 1e-30 .. 1e30): the same hits as unit directions,
    t in the caller's units (t * |d| the same distance). A power of two scales exactly."""
    scene = rtlab.load_scene("default", size=24)
    o, d = camera_rays(scene.camera)
    unit = trace(scene, o, d, backend=backend, variant=Variant.paper(traversal=variant))
    hit = unit.tri >= 0
    for scale in (2.0 ** -100, 2.0 ** -64, 2.0 ** 64, 2.0 ** 100):
        got = trace(scene, o, (d * scale).astype(np.float32), backend=backend, variant=Variant.paper(traversal=variant))
        assert np.array_equal(got.tri, unit.tri), f"length {scale:g}: {np.sum(got.tri != unit.tri)} rays differ"
        assert np.array_equal(got.t[hit] * np.float32(scale), unit.t[hit])
    for length in (1e-30, 1e30):
        dl = (d.astype(np.float64) * length).astype(np.float32)
        got = trace(scene, o, dl, backend=backend, variant=Variant.paper(traversal=variant))
        ref = reference_trace(scene.vertices, scene.faces, o, dl)
        c = compare_hits(ref, got.tri, got.t, scene.vertices, scene.faces, o, dl)
        assert c.n_mismatch == 0 and c.t_rel_err_max <= T_REL_TOL, f"length {length:g}: {c.summary()}"


@pytest.mark.gpu
def test_gpu_ties_and_box_planes_agree_across_cuda_and_nvidia_opencl(duplicated_scene):
    """On the GPU machine (fused multiply-adds in hardware, not PoCL's): exact ties go to the lowest
    copy, rays lying in the planes of a cube grid near the origin keep their hits with the BVH's
    fused box test, and with the watertight test CUDA and NVIDIA OpenCL name the same triangles."""
    from rtlab.backends import get_backend
    backends = [get_backend("cuda"), get_backend("opencl", "NVIDIA")]
    scene, o, d, lowest = duplicated_scene
    grid = _cube_grid(4, -2)
    planes = np.arange(-2, 3, dtype=np.float32)
    gy, gz = np.meshgrid(planes, planes, indexing="ij")
    go = np.stack([np.full(gy.size, -3.0, np.float32), gy.ravel(), gz.ravel()], 1)
    go = np.concatenate([go, go])
    gd = np.zeros_like(go)
    gd[:, 0] = 1.0
    gd[len(gd) // 2:, 1:] = np.float32(-0.0)
    ids = {}
    for be in backends:
        for traversal in ["stack"] + VARIANTS:
            for isect in ISECTS:
                got = trace(scene, o, d, backend=be, variant=Variant(traversal, isect))
                hit = got.tri >= 0
                assert np.array_equal(got.tri[hit], lowest[got.tri[hit]]), f"{be.name} {traversal}/{isect}"
                ids[be.name, traversal, isect] = got.tri
        box = trace(grid, go, gd, backend=be, variant=Variant("bvh", "moller"))
        assert np.all(box.tri >= 0), f"{be.name}: {np.sum(box.tri < 0)} rays in box planes lost"
    for traversal in ["stack"] + VARIANTS:
        assert np.array_equal(ids["cuda", traversal, "watertight"], ids["opencl", traversal, "watertight"]), traversal
