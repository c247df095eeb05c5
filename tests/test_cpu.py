"""The CPU path: the bvh-packet traversal (packets of rays in SIMD lanes), its host
layout, its launch shapes, and `rtlab bench cpu` against Embree.

The packet traversal is also in tests/test_traversal.py's VARIANTS (camera, random and split-plane
rays on the paper's scenes against the stack traversal and the float64 reference, any-hit against
closest-hit, renders) and in the robustness suite through rtlab.device.kernels.TRAVERSALS. Here: what is
particular to packets, namely partial packets, lanes without a ray next to lanes with one, per-lane
tmin/tmax, the single-ray path the shading kernels take, and the host layout checked against the
mesh independently of the builder.
"""
from __future__ import annotations

import numpy as np
import pytest

import rtlab
from rtlab.accel.bvh import LEAF_BITS, build_bvh
from rtlab.accel.bvh_wide import EMPTY, block_rows, node_rows, wide_node_data
from rtlab.device.kernels import PACKET_LANES, SceneFeatures, Variant, build_defines, primary_step, rays_per_work_item
from rtlab.device.rendering import render
from rtlab.device.tracing import trace
from rtlab.errors import VariantError
from rtlab.reference import compare_hits, reference_trace
from rtlab.reference.check import check_render
from rtlab.scene.model import camera_rays

PACKET = Variant.paper(traversal="bvh-packet")


@pytest.fixture(scope="module")
def default_scene():
    return rtlab.load_scene("default", size=40)


def _random_rays(scene, n, seed):
    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds().astype(np.float64)
    ext = hi - lo
    o = rng.uniform(lo - 0.3 * ext, hi + 0.3 * ext, size=(n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    return o, d


def _assert_matches_reference(scene, got, o, d, where, tmin=0.0, tmax=np.inf):
    ref = reference_trace(scene.vertices, scene.faces, o, d, tmin=tmin, tmax=tmax)
    c = compare_hits(ref, got.tri, got.t, scene.vertices, scene.faces, o, d, tmin=tmin, tmax=tmax)
    assert c.n_mismatch == 0, f"{where}: {c.summary()}"
    assert c.t_rel_err_max <= 1e-5, f"{where}: {c.summary()}"
    return ref


@pytest.mark.parametrize("n", [1, PACKET_LANES - 1, PACKET_LANES, PACKET_LANES + 1, 1001])
def test_partial_packets_and_rays_without_hits(backend, default_scene, n):
    """Any ray count (the last packet partly empty); NaN/Inf origins and directions and zero
    directions inside a packet of good rays are misses and do not disturb their neighbours."""
    scene = default_scene
    o, d = _random_rays(scene, n, seed=n)
    cam_o, cam_d = camera_rays(scene.camera)
    pick = np.random.default_rng(1).choice(len(cam_o), n)
    o[::2], d[::2] = cam_o[pick[::2]], cam_d[pick[::2]]          # every other ray a camera ray: hits
    bad = np.arange(n) % 5 == 3
    o_bad, d_bad = o.copy(), d.copy()
    for j, i in enumerate(np.flatnonzero(bad)):
        kind, axis = j % 5, j % 3
        if kind == 0:
            o_bad[i, axis] = np.nan
        elif kind == 1:
            o_bad[i, axis] = -np.inf
        elif kind == 2:
            d_bad[i, axis] = np.inf
        elif kind == 3:
            d_bad[i, axis] = np.nan
        else:
            d_bad[i] = 0.0
    got = trace(scene, o_bad, d_bad, backend=backend, variant=PACKET)
    assert np.all(got.tri[bad] == -1)
    good = ~bad
    _assert_matches_reference(scene, trace(scene, o[good], d[good], backend=backend, variant=PACKET),
                              o[good], d[good], f"{n} rays")
    alone = trace(scene, o[good], d[good], backend=backend, variant=PACKET)
    assert np.array_equal(got.tri[good], alone.tri), "a bad ray changed the hits of good rays in its packet"
    if n >= PACKET_LANES:
        assert np.mean(got.tri[good] >= 0) > 0.2


def test_per_ray_intervals(backend, default_scene):
    """tmin and tmax differ from lane to lane: each lane keeps its own interval."""
    scene = default_scene
    o, d = camera_rays(scene.camera)
    full = trace(scene, o, d, backend=backend, variant=PACKET)
    hit = full.tri >= 0
    rng = np.random.default_rng(5)
    # per ray: a window that holds the first hit, one that ends before it, one that starts after it
    which = rng.integers(0, 3, len(o))
    t = np.where(hit, full.t, 1.0).astype(np.float64)
    tmin = np.where(which == 2, t * 1.001, 0.0).astype(np.float32)
    tmax = np.where(which == 1, t * 0.999, np.inf).astype(np.float32)
    got = trace(scene, o, d, backend=backend, variant=PACKET, tmin=tmin, tmax=tmax)
    _assert_matches_reference(scene, got, o, d, "per-ray windows", tmin=tmin, tmax=tmax)
    assert np.array_equal(got.tri[which == 0], full.tri[which == 0])
    cut = hit & (which != 0)
    assert cut.sum() > 100 and np.all((got.tri[cut] != full.tri[cut]) | (got.t[cut] != full.t[cut]))


def test_render_any_width_and_the_single_ray_path(backend, default_scene):
    """render_primary takes 8 pixels of a row a work-item: a width that is no multiple of 8 and
    a block narrower than a packet. The shadow kernels (lab step 04) send one ray at a time
    through the packet traversal (one lane): same image as the scalar BVH there."""
    from rtlab.device.whitted import render_whitted
    scene = default_scene
    for width, block in ((37, (32, 4)), (21, (4, 2))):
        result = render(scene, backend, Variant.paper(traversal="bvh-packet", block=block), size=width, write_hits=True)
        cam = scene.camera.with_size(width)
        assert result.image.shape[:2] == (cam.height, cam.width)
        report = check_render(scene, result, cam)
        assert report.hits.n_mismatch == 0, report.summary()
        assert report.hits.n_hits_ref > 0
    a = render_whitted(scene, backend, Variant.paper(traversal="bvh"), shadows="two-pass", write_hits=True)
    b = render_whitted(scene, backend, Variant.paper(traversal="bvh-packet"), shadows="two-pass", write_hits=True)
    same = np.all(a.image == b.image, axis=-1)
    assert same.mean() > 0.99, f"{(~same).sum()} pixels differ between bvh and bvh-packet shadows"


@pytest.mark.parametrize("lanes", [4, 8])
def test_wide_layout_matches_the_mesh(lanes):
    """The CPU BVH's layout, checked against the mesh and not the builder: nodes of up to `lanes`
    children, used slots first, unused ones inverted boxes; each child box holds the triangles below
    it; no inner child holds as few triangles as one block (those are leaves); leaves: blocks of the
    mesh's own vertices and ids, the last block filled up with the leaf's first triangle, every usable
    triangle once; the stack holds what a walk down the deepest path pushes."""
    scene = rtlab.load_scene("default", size=16)
    v, f = scene.vertices, scene.faces
    bvh = build_bvh(v, f)
    rows, stack = wide_node_data(bvh, v, f, lanes)
    ints = rows.view(np.int32)
    q, per_node, per_block = lanes // 4, node_rows(lanes), block_rows(lanes)
    vec = lambda row, k: rows[row:row + q].reshape(-1)[k]                   # lane k of a lane vector
    ivec = lambda row, k: int(ints[row:row + q].reshape(-1)[k])
    seen = np.zeros(len(f), np.int64)

    def children(node):
        base = per_node * node
        refs = [ivec(base + 6 * q, c) for c in range(lanes)]
        used = [r != EMPTY for r in refs]
        assert all(used[:2]) and used == sorted(used, reverse=True), f"node {node}: slots {refs}"
        for c in range(lanes):
            if not used[c]:
                assert all(vec(base + 2 * a * q, c) == np.inf and vec(base + (2 * a + 1) * q, c) == -np.inf
                           for a in range(3))
        return [(c, r) for c, r in enumerate(refs) if r != EMPTY]

    def walk(ref):
        """(triangles below ref, collapsed nodes on its longest path)"""
        if ref >= 0:
            kids = children(ref)
            parts = [walk(r) for _, r in kids]
            for (c, r), (tris, _) in zip(kids, parts):
                corners = v[f[tris]].reshape(-1, 3)
                base = per_node * ref
                lo = np.array([vec(base + 2 * a * q, c) for a in range(3)])
                hi = np.array([vec(base + (2 * a + 1) * q, c) for a in range(3)])
                assert np.all(lo <= corners.min(0)) and np.all(hi >= corners.max(0))
                assert r < 0 or len(tris) > lanes, f"an inner child of {len(tris)} triangles"
            return np.concatenate([t for t, _ in parts]), 1 + max(d for _, d in parts)
        bits = ~ref
        first, count = bits >> LEAF_BITS, bits & ((1 << LEAF_BITS) - 1)
        assert 1 <= count <= (1 << LEAF_BITS) - 1
        ids = []
        for i in range(-(-count // lanes) * lanes):
            row, k = first + (i // lanes) * per_block, i % lanes
            tri = ivec(row + 9 * q, k)
            corners = np.array([[vec(row + (3 * j + a) * q, k) for a in range(3)] for j in range(3)])
            assert np.array_equal(corners, v[f[tri]])
            if i < count:
                ids.append(tri)
            else:
                assert tri == ids[0], "a block is filled up with the leaf's first triangle"
        return np.array(ids, np.int64), 0

    tris, depth = walk(0)
    np.add.at(seen, tris, 1)
    assert np.all(seen == 1)
    assert stack >= (lanes - 1) * depth + 1
    assert depth < build_bvh(v, f).depth, "collapsing did not make the tree shallower"


@pytest.mark.parametrize("n_tris", [1, 2, 9])
def test_cpu_traversals_on_the_smallest_meshes(backend, n_tris):
    """Meshes of 1, 2 and 9 triangles (a root holding one leaf twice, a leaf in one block): the
    packet and the wide traversal find the float64 reference's hits, coherent rays and any rays."""
    from rtlab.scene.model import Camera, Material, Scene
    rng = np.random.default_rng(n_tris)
    v = rng.random((3 * n_tris, 3)).astype(np.float32)
    f = np.arange(3 * n_tris, dtype=np.int32).reshape(-1, 3)
    scene = Scene("small", v, f, np.zeros(n_tris, np.int32), [Material()],
                  Camera((2.0, 1.5, 2.5), (0.5, 0.5, 0.5), width=24, height=24), source="procedural")
    o_cam, d_cam = camera_rays(scene.camera)
    o_any, d_any = _random_rays(scene, 500, seed=n_tris)
    o, d = np.concatenate([o_cam, o_any]), np.concatenate([d_cam, d_any])
    for traversal in ("bvh-packet", "bvh-wide"):
        got = trace(scene, o, d, backend=backend, variant=Variant(traversal, "watertight"))
        _assert_matches_reference(scene, got, o, d, f"{traversal}, {n_tris} triangles")
        assert np.any(got.tri >= 0)


def test_loader_shapes_and_refusals():
    features = SceneFeatures(stack_size=20, near_origin=True)
    defines = build_defines(PACKET, features)
    assert defines["RT_LANES"] == PACKET_LANES and defines["RT_TRAVERSAL"] == 6 and defines["RT_BVH_BOX_FMA"] == 1
    assert rays_per_work_item(PACKET) == PACKET_LANES and rays_per_work_item(Variant.paper(traversal="bvh")) == 1
    assert primary_step(PACKET) == "00_primary"
    for v in (Variant.paper(traversal="bvh-packet", constants="global"), Variant.paper(traversal="bvh-packet", ray_order="morton")):
        with pytest.raises(VariantError, match="bvh-packet"):
            primary_step(v)


def test_fused_box_test_needs_coordinates_below_the_overflow_bound():
    """b inv with inv up to 2^64 must stay finite in float32: huge scenes keep the exact form."""
    from rtlab.device.device_scene import near_origin
    from rtlab.scene.model import Camera, Material, Scene
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    mk = lambda s: Scene("s", tri * s, np.array([[0, 1, 2]], np.int32), np.zeros(1, np.int32), [Material()],
                         Camera((2.0, 2.0, 2.0), (0.0, 0.0, 0.0)), source="procedural")
    assert near_origin(mk(1.0)) and near_origin(mk(1e17))
    assert not near_origin(mk(1e20))


def test_compiler_output_stays_off_the_terminal(backend, capfd, monkeypatch, tmp_path):
    """PoCL's compiler prints its warnings to the process's stderr itself ("1 warning generated."):
    a successful build keeps them in its log and off the terminal unless RTLAB_VERBOSE asks; a
    failed build shows its messages in the error."""
    from rtlab.errors import KernelBuildError
    if backend.name != "opencl":
        pytest.skip("the OpenCL backend's builds")
    token = np.random.default_rng().integers(1 << 62)      # a source no cache has seen
    def source(name, directive):
        path = tmp_path / name
        path.write_text(f'{directive} "build output {token} {name}"\n'
                        f"__kernel void k_{name}(__global float *a) {{ a[get_global_id(0)] = {token}.0f; }}\n")
        return path
    monkeypatch.delenv("RTLAB_VERBOSE", raising=False)
    capfd.readouterr()
    quiet = backend.compile(source("quiet", "#warning"), {})
    out, err = capfd.readouterr()
    assert f"build output {token} quiet" in quiet.build_log and "warning" not in out + err
    monkeypatch.setenv("RTLAB_VERBOSE", "1")
    backend.compile(source("loud", "#warning"), {})
    assert f"build output {token} loud" in capfd.readouterr().err
    with pytest.raises(KernelBuildError, match=f"build output {token} failed"):
        backend.compile(source("failed", "#error"), {})


def test_cpu_device_by_type():
    import pyopencl as cl
    from rtlab.backends import backend_status, get_backend
    from rtlab.errors import BackendError
    if not any(r["ok"] and r["backend"] == "opencl" for r in backend_status()):
        pytest.skip("no OpenCL device")
    try:
        be = get_backend("opencl", "cpu")
    except BackendError as e:
        assert "no OpenCL CPU device" in str(e)
        return
    assert be.device.type & cl.device_type.CPU


@pytest.mark.skipif(not __import__("rtlab.backends.nvcc", fromlist=["x"]).nvcc_available(), reason="nvcc not on PATH")
def test_packet_kernels_compile_as_cuda():
    """The lane helpers have a CUDA form (arrays and loops): lab step 00 compiles with the packet and
    the wide traversal, for the fused and the exact box test."""
    from rtlab.device.kernels import kernel_source
    from rtlab.backends.nvcc import nvcc_resources
    for v in (PACKET, Variant("bvh-packet", intersection="watertight"), Variant("bvh-wide", intersection="watertight"),
              Variant("bvh-wide", intersection="moller")):
        for near in (True, False):
            report = nvcc_resources(kernel_source("00_primary", "cuda"),
                                    build_defines(v, SceneFeatures(stack_size=30, near_origin=near)))
            assert set(report) == {"trace_rays", "trace_ray_grid", "render_primary"}


def test_bench_cpu_against_embree(backend):
    """`rtlab bench cpu`'s measurement on a small view: both tracers agree with the reference, the
    figures are positive and the table renders."""
    pytest.importorskip("embreex")
    if backend.name != "opencl":
        pytest.skip("rtlab bench cpu measures the OpenCL CPU device")
    from rtlab.benches.cpu import EmbreeTracer, bench_cpu, cpu_markdown
    from rtlab.benches.rays import make_rays
    batch = make_rays("default", "primary", 48)
    embree = EmbreeTracer(batch.scene.vertices, batch.scene.faces)
    tri, t, seconds, cpu = embree.trace(batch.origins, batch.directions)
    c = compare_hits(batch.reference, tri[batch.check_index], t[batch.check_index], batch.scene.vertices,
                     batch.scene.faces, batch.origins[batch.check_index], batch.directions[batch.check_index])
    assert c.n_mismatch == 0 and seconds > 0 and cpu >= 0
    row = bench_cpu(batch, backend, PACKET, rounds=2, embree=embree)
    assert len(row.rtlab_ms) == len(row.embree_ms) == 2
    assert row.rtlab_mrays > 0 and row.embree_mrays > 0 and row.threads >= 1
    assert len(row.rtlab_cpu_ms) == len(row.embree_cpu_ms) == 2 and min(row.rtlab_cpu_ms) >= 0
    assert row.rtlab_error["mismatches"] == 0 and row.embree_error["mismatches"] == 0
    assert row.rtlab_error["rays"] == batch.check_index.size
    md = cpu_markdown([row], "rtlab bench cpu", 2)
    assert "| default |" in md and "Embree" in md


def test_cpu_default_in_a_student_tree_is_the_scalar_test(tmp_path):
    """A student tree stubs the watertight test's lane form (it would show lab 02's solution): there the
    CPU default is the scalar test, which calls the student's own intersect_ray_tri_watertight."""
    from rtlab.backends import get_backend
    from rtlab.device.tracing import DEFAULT_VARIANT, SCALAR_CPU_VARIANT, default_variant
    from rtlab.course.kernel_sources import copy_stubbed
    from rtlab.paths import REFERENCE_KERNEL_DIR, use_kernel_dir
    backend = get_backend("opencl", "cpu")
    assert default_variant(backend) == DEFAULT_VARIANT
    copy_stubbed(REFERENCE_KERNEL_DIR, tmp_path / "kernels", None)
    before = use_kernel_dir(tmp_path / "kernels")
    try:
        assert default_variant(backend) == SCALAR_CPU_VARIANT
    finally:
        use_kernel_dir(before)
