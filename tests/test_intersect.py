"""Triangle tests (lab step 02, the paper's Table 3) against the float64 reference: the
precomputed data on the host, the 1000-triangle loop and the renderer with every test, frozen
rays that slip between Möller–Trumbore's triangles, the RT_CONSERVATIVE default, nvcc registers."""
from __future__ import annotations

import numpy as np
import pytest

import rtlab
from rtlab.accel.tri_data import (PLUCKER_ROWS, WALD_ROWS, plucker_tri_data, tri_bytes_read, tri_data_bytes,
                                  wald_tri_data)
from rtlab.benches.intersect import check_loop, intersect_loop, nvcc_registers
from rtlab.device.kernels import INTERSECTIONS, Variant
from rtlab.device.rendering import render
from rtlab.reference import compare_hits
from rtlab.reference.check import check_render
from rtlab.scene.model import Camera

from .conftest import require_scene_file

ISECTS = list(INTERSECTIONS)
# Relative t error against float64 near the origin: the vertex-based tests round a few times;
# Wald's plane offset n_d and the Plücker moments are products of coordinates and cancel.
T_REL_TOL = {"moller": 1e-5, "watertight": 1e-5, "wald": 1e-4, "plucker": 1e-4}

# Rays that Möller–Trumbore lets through a crack on PoCL (found by rtlab.robustness, families 2
# and 1): the triangles the ray passes next to (a vertex fan), the ray. Watertight must hit.
BAD_CASES = [
    (np.array([[10004.087890625, 10001.8974609375, 7505.4091796875], [10004.16015625, 10002.80859375, 7505.51953125],
               [10002.9248046875, 10003.0673828125, 7505.33154296875], [10002.9248046875, 10003.0673828125, 7505.33154296875],
               [10004.16015625, 10002.80859375, 7505.51953125], [10004.1650390625, 10004.201171875, 7506.08837890625],
               [10004.087890625, 10001.8974609375, 7505.4091796875], [10004.93359375, 10003.001953125, 7506.087890625],
               [10004.16015625, 10002.80859375, 7505.51953125], [10004.16015625, 10002.80859375, 7505.51953125],
               [10004.93359375, 10003.001953125, 7506.087890625], [10004.1650390625, 10004.201171875, 7506.08837890625]],
              np.float32),
     np.array([9995.3369140625, 10011.0947265625, 7516.40234375], np.float32),
     np.array([8.8232421875, -8.2861328125, -10.8828125], np.float32)),
    (np.array([[10002.1572265625, 10005.8818359375, 7505.3212890625], [10002.9169921875, 10006.1513671875, 7505.93896484375],
               [10003.1396484375, 10006.7890625, 7506.10009765625], [10003.248046875, 10004.9619140625, 7505.912109375],
               [10003.8076171875, 10005.9375, 7506.47021484375], [10002.9169921875, 10006.1513671875, 7505.93896484375],
               [10003.248046875, 10004.9619140625, 7505.912109375], [10002.9169921875, 10006.1513671875, 7505.93896484375],
               [10002.1572265625, 10005.8818359375, 7505.3212890625], [10002.9169921875, 10006.1513671875, 7505.93896484375],
               [10003.8076171875, 10005.9375, 7506.47021484375], [10003.1396484375, 10006.7890625, 7506.10009765625]],
              np.float32),
     np.array([9984.349609375, 10008.6220703125, 7508.5146484375], np.float32),
     np.array([18.5673828125, -2.470703125, -2.57568359375], np.float32)),
    (np.array([[149942.796875, 1118.0792236328125, -219995.9375], [149944.8125, 1117.2890625, -219989.34375],
               [149938.4375, 1121.61572265625, -219991.890625], [149944.8125, 1117.2890625, -219989.34375],
               [149940.515625, 1120.9830322265625, -219985.265625], [149938.4375, 1121.61572265625, -219991.890625],
               [149938.4375, 1121.61572265625, -219991.890625], [149938.234375, 1121.356689453125, -220000.0],
               [149942.796875, 1118.0792236328125, -219995.9375], [149933.90625, 1125.061279296875, -219995.9375],
               [149938.234375, 1121.356689453125, -220000.0], [149938.4375, 1121.61572265625, -219991.890625],
               [149938.4375, 1121.61572265625, -219991.890625], [149940.515625, 1120.9830322265625, -219985.265625],
               [149934.375, 1125.52734375, -219987.890625], [149934.375, 1125.52734375, -219987.890625],
               [149933.90625, 1125.061279296875, -219995.9375], [149938.4375, 1121.61572265625, -219991.890625]],
              np.float32),
     np.array([149990.90625, 1205.6239013671875, -219995.21875], np.float32),
     np.array([-0.5294361114501953, -0.8476848602294922, 0.03358245640993118], np.float32)),
]


@pytest.fixture(scope="module")
def default_scene():
    return rtlab.load_scene("default", size=48)


@pytest.fixture(scope="module")
def sphere_scene():
    """An icosphere of 1280 triangles filling much of a 48² view: Table 3's loop over its first
    1000 triangles hits on most pixels."""
    import trimesh
    from rtlab.robustness import case_scene
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    scene = case_scene("icosphere", mesh.vertices, mesh.faces)
    scene.camera = Camera((0.4, 0.8, 2.6), (0.0, 0.0, 0.0), width=48, height=48)
    return scene


def _random_triangles(rng, n, scale=10.0, offset=0.0):
    v = (rng.uniform(-scale, scale, (3 * n, 3)) + offset).astype(np.float32)
    return v, np.arange(3 * n).reshape(n, 3)


# ---- precomputed data (host) -------------------------------------------------------------------
def test_wald_data_reproduces_plane_and_barycentrics():
    """Evaluated in float64, the float32 TriAccel gives back the plane and the barycentrics of
    known points of each triangle (Wald 2004, §7.1.3)."""
    rng = np.random.default_rng(11)
    v, f = _random_triangles(rng, 500)
    data = wald_tri_data(v, f).reshape(-1, WALD_ROWS, 4).astype(np.float64)
    k = data[:, 0, 3].astype(np.float32).view(np.int32)
    assert set(np.unique(k)) <= {0, 1, 2}
    u, w = rng.uniform(0, 0.5, (2, len(f)))
    c = v[f].astype(np.float64)
    p = (1 - u - w)[:, None] * c[:, 0] + u[:, None] * c[:, 1] + w[:, None] * c[:, 2]
    order = (k[:, None] + np.arange(3)) % 3
    pk, pu, pv = np.take_along_axis(p, order, axis=1).T
    scale = np.abs(c).max(axis=(1, 2))
    np.testing.assert_allclose(pk + data[:, 0, 0] * pu + data[:, 0, 1] * pv, data[:, 0, 2],
                               atol=1e-5 * scale.max() * 10)
    np.testing.assert_allclose(data[:, 1, 0] * pu + data[:, 1, 1] * pv + data[:, 1, 2], u, atol=1e-4)
    np.testing.assert_allclose(data[:, 2, 0] * pu + data[:, 2, 1] * pv + data[:, 2, 2], w, atol=1e-4)


def test_plucker_data_side_products_and_shared_edges():
    """A ray through a triangle's interior sees one sign on all three edges; the two triangles of a
    shared edge store exactly negated coordinates, so no ray can fall between them."""
    rng = np.random.default_rng(12)
    v, f = _random_triangles(rng, 400)
    data = plucker_tri_data(v, f).reshape(-1, PLUCKER_ROWS, 4).astype(np.float64)
    c = v[f].astype(np.float64)
    w = rng.dirichlet([2, 2, 2], len(f))
    p = np.einsum("ij,ijk->ik", w, c)
    o = p + rng.normal(size=p.shape) * 20
    d = p - o
    m = np.cross(o, d)
    sides = np.stack([np.einsum("ij,ij->i", d, data[:, 2 * e + 1, :3]) + np.einsum("ij,ij->i", data[:, 2 * e, :3], m)
                      for e in range(3)], 1)
    assert np.all((sides > 0).all(1) | (sides < 0).all(1))
    # shared edge a-b in (a, b, c) and (b, a, d): edge 0 of each
    quad = rng.uniform(-1e4, 1e4, (4, 3)).astype(np.float32)
    pair = plucker_tri_data(quad, np.array([[0, 1, 2], [1, 0, 3]])).reshape(2, PLUCKER_ROWS, 4)
    assert np.array_equal(pair[0, 0, :3], -pair[1, 0, :3]) and np.array_equal(pair[0, 1, :3], -pair[1, 1, :3])


def test_unhittable_triangles_stored_as_nan():
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [np.nan, 0, 0]], np.float32)
    f = np.array([[0, 1, 2], [0, 0, 3], [0, 1, 3], [0, 1, 4]])   # collinear, repeated, good, NaN corner
    wald = wald_tri_data(v, f).reshape(-1, WALD_ROWS, 4)
    plucker = plucker_tri_data(v, f).reshape(-1, PLUCKER_ROWS, 4)
    for i, good in enumerate([False, False, True, False]):
        assert np.isfinite(wald[i, :, :3]).all() == good and np.isnan(wald[i, :, :3]).all() != good
        assert np.isfinite(plucker[i]).all() == good


def test_bytes_per_triangle_and_registration():
    from rtlab.device.device_scene import TRI_DATA_BUILDERS
    from rtlab.errors import VariantError
    assert {t: tri_data_bytes(t) for t in ISECTS} == {"moller": 0, "wald": 48, "plucker": 96, "watertight": 0}
    assert {t: tri_bytes_read(t) for t in ISECTS} == {"moller": 48, "wald": 48, "plucker": 96, "watertight": 48}
    scene = rtlab.load_scene("default", size=8)
    for name, rows in (("wald", WALD_ROWS), ("plucker", PLUCKER_ROWS)):
        data = TRI_DATA_BUILDERS[name](scene)
        assert data.shape == (rows * scene.n_triangles, 4) and data.dtype == np.float32
        assert data.nbytes == tri_data_bytes(name) * scene.n_triangles
    with pytest.raises(VariantError, match="unknown intersection test 'nope'"):
        tri_data_bytes("nope")


# ---- on the device ---------------------------------------------------------------------------
@pytest.mark.parametrize("isect", ISECTS)
def test_table3_loop_matches_reference(backend, isect, sphere_scene):
    """Lab step 02: every pixel's ray against the first 1000 triangles, closest hit as the float64
    reference finds it over the same triangles."""
    result = intersect_loop(sphere_scene, backend, isect, n_tris=1000)
    assert result.n_tris == 1000 and result.tri.max() < 1000
    comparison = check_loop(sphere_scene, result)
    assert comparison.n_hits_ref > 0.2 * comparison.n_rays, comparison.summary()
    assert comparison.n_mismatch == 0, comparison.summary()
    assert comparison.t_rel_err_max <= T_REL_TOL[isect], comparison.summary()


def test_table3_loop_on_bunny(backend):
    """The paper's setting on BUNNY's first 1000 triangles, with the paper's fastest test."""
    require_scene_file("bunny.ply")
    scene = rtlab.load_scene("bunny", size=32)
    result = intersect_loop(scene, backend, "wald", n_tris=1000)
    comparison = check_loop(scene, result)
    assert comparison.n_hits_ref > 0 and comparison.n_mismatch == 0, comparison.summary()


@pytest.mark.parametrize("isect", ISECTS)
def test_render_with_each_test_matches_reference(backend, isect, default_scene):
    """The whole renderer with each test (RT_ISECT through intersect_tri)."""
    result = render(default_scene, backend, Variant(intersection=isect), write_hits=True)
    report = check_render(default_scene, result, default_scene.camera)
    assert report.hits.n_mismatch == 0, report.summary()
    assert report.hits.t_rel_err_max <= T_REL_TOL[isect], report.summary()
    assert report.psnr > 40.0, report.summary()


@pytest.mark.parametrize("fp64", [1, 0], ids=["fp64", "float-only"])
@pytest.mark.parametrize("case", range(len(BAD_CASES)))
def test_watertight_closes_cracks_of_frozen_rays(backend, case, fp64):
    """Rays that pass next to a shared vertex: the float64 reference and the watertight test hit a
    triangle of the fan, with or without the double-precision fallback."""
    from rtlab.robustness import Case, case_scene, trace_case
    corners, o, d = BAD_CASES[case]
    faces = np.arange(len(corners)).reshape(-1, 3)
    scene = case_scene(f"bad_case_{case}", corners, faces)
    c = Case(0, "frozen", scene, o[None], d[None], ("leaks",))
    assert c.reference().tri[0] >= 0
    defines = {} if fp64 else {"RT_HAS_FP64": 0}     # the default shares the suite's program
    tri, t, _ = trace_case(c, backend, "watertight", "stack", **defines)
    moller, _, _ = trace_case(c, backend, "moller", "stack")
    print(f"case {case}: watertight -> {tri[0]}, moller -> {moller[0]}")
    assert tri[0] >= 0 and np.isfinite(t[0])
    cmp = compare_hits(c.reference(), tri, t, scene.vertices, scene.faces, c.origins, c.directions)
    assert cmp.n_mismatch == 0, cmp.summary()


DEFINES_KERNEL = """
#include "rt_intersect.h"
RT_KERNEL void read_defines(RT_GLOBAL int *out)
{
    out[0] = RT_CONSERVATIVE;
    out[1] = RT_HAS_FP64;
}
"""


@pytest.mark.parametrize("isect,extra,want", [(i, {}, int(i == "watertight")) for i in ISECTS]
                         + [("moller", {"RT_CONSERVATIVE": 1}, 1), ("watertight", {"RT_CONSERVATIVE": 0}, 0)])
def test_conservative_traversal_defaults_on_for_watertight(backend, tmp_path, isect, extra, want):
    """RT_CONSERVATIVE follows RT_ISECT unless set; RT_HAS_FP64 is 1 where the device has doubles
    (always in CUDA; in OpenCL where the device lists cl_khr_fp64)."""
    src = tmp_path / ("defines" + backend.extension)
    src.write_text(DEFINES_KERNEL)
    out = backend.empty(8)
    backend.compile(src, {"RT_ISECT": INTERSECTIONS[isect], **extra}).launch("read_defines", (1,), (1,), [out])
    conservative, fp64 = backend.to_host(out, np.int32, 2)
    assert conservative == want
    assert fp64 == int(backend.language == "cuda" or "cl_khr_fp64" in backend.device.extensions.split())


@pytest.mark.parametrize("isect", ISECTS)
def test_cuda_table3_kernel_registers(isect):
    """`nvcc -cubin -arch=sm_90 -Xptxas -v` on the Table 3 kernel: compiles, registers reported
    (the paper's "Reg. usage" row), nothing spilled."""
    report = nvcc_registers(isect)
    if report is None:
        pytest.skip("nvcc not on PATH")
    print(f"02_intersect/{isect}: {report}")
    assert 0 < report["registers"] <= 255
    assert report["spill_bytes"] == 0


def test_bench_intersect_command(backend, tmp_path):
    """`rtlab bench intersect` end to end on the procedural scene at a tiny size."""
    from typer.testing import CliRunner
    from rtlab.cli import app
    md = tmp_path / "table3.md"
    args = ["bench", "intersect", "--scenes", "default", "--backends", backend.name, "--size", "24",
            "--isects", "wald", "--triangles", "200", "--repeats", "1", "--render-size", "24", "--md", str(md)]
    if backend.name == "opencl":
        args += ["--device", backend.device_name]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    text = md.read_text()
    assert "Table 3" in text and "| default | wald | " in text
