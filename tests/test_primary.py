"""Primary rays (lab step 00) on every available backend against the float64 reference:
triangle ids exact apart from reported ties, t within 1e-5 relative, images close."""
from __future__ import annotations

import numpy as np
import pytest

import rtlab
from rtlab.device.kernels import Variant
from rtlab.device.rendering import render
from rtlab.device.tracing import trace
from rtlab.reference import compare_hits, reference_trace
from rtlab.reference.check import check_render
from rtlab.scene.model import camera_rays

from .conftest import require_scene_file

T_REL_TOL = 1e-5


@pytest.fixture(scope="module")
def default_scene():
    return rtlab.load_scene("default", size=96)


def _preset(name, relpath, size):
    require_scene_file(relpath)
    return rtlab.load_scene(name, size=size)


@pytest.fixture(scope="module")
def bunny():
    return _preset("bunny", "bunny.ply", 128)


@pytest.fixture(scope="module")
def sponza():
    return _preset("sponza", "sponza/sponza.obj", 128)


def assert_matches_reference(comparison, where: str):
    assert comparison.n_mismatch == 0, f"{where}: {comparison.summary()}"
    assert comparison.t_rel_err_max <= T_REL_TOL, f"{where}: {comparison.summary()}"


def test_default_scene_render_matches_reference(backend, default_scene):
    result = render(default_scene, backend, write_hits=True)
    report = check_render(default_scene, result, default_scene.camera)
    assert_matches_reference(report.hits, "default scene")
    assert report.hits.n_hits_ref > 0.3 * report.hits.n_rays
    # Colours differ only by float32 rounding and tie pixels
    assert report.psnr > 40.0, report.summary()


@pytest.mark.parametrize("scene_fixture", ["bunny", "sponza"])
def test_paper_scene_render_matches_reference(backend, scene_fixture, request):
    scene = request.getfixturevalue(scene_fixture)
    result = render(scene, backend, write_hits=True)
    report = check_render(scene, result, scene.camera)
    print(f"{scene.name} {backend.name}: {report.summary()}")
    assert_matches_reference(report.hits, scene.name)
    assert report.hits.n_hits_ref > 0


@pytest.mark.parametrize("scene_fixture", ["bunny", "sponza"])
def test_random_rays_inside_and_outside(backend, scene_fixture, request):
    """Not only camera rays: rays from random points inside and around the scene box, any direction."""
    scene = request.getfixturevalue(scene_fixture)
    rng = np.random.default_rng(7)
    lo, hi = scene.bounds().astype(np.float64)
    ext = hi - lo
    n = 6000
    o = rng.uniform(lo - 0.5 * ext, hi + 0.5 * ext, size=(n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d.astype(np.float32)
    got = trace(scene, o, d, backend=backend)
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    comparison = compare_hits(ref, got.tri, got.t, scene.vertices, scene.faces, o, d)
    assert_matches_reference(comparison, f"{scene.name} random rays")
    assert 0.05 * n < comparison.n_hits_ref


def test_render_hits_equal_trace_api(backend, default_scene):
    """The renderer's camera rays and the trace API's give the same hits (same traversal)."""
    result = render(default_scene, backend, write_hits=True)
    o, d = camera_rays(default_scene.camera)
    got = trace(default_scene, o, d, backend=backend)
    same = (got.tri == result.hits.tri).mean()
    assert same > 0.999, f"only {same:.4%} of pixels agree"


def test_ray_interval_and_bad_rays(backend, default_scene):
    """tmin/tmax are honoured; NaN, Inf and zero-length directions come back as misses."""
    o, d = camera_rays(default_scene.camera)
    o, d = o[::37].copy(), d[::37].copy()
    full = trace(default_scene, o, d, backend=backend)
    hit = full.tri >= 0
    assert hit.any()
    cut = np.float32(np.median(full.t[hit]))
    near = trace(default_scene, o, d, backend=backend, tmax=float(cut))
    assert np.all(near.t[near.tri >= 0] < cut)
    far = trace(default_scene, o, d, backend=backend, tmin=float(cut))
    assert np.all(far.t[far.tri >= 0] > cut)
    bad_o, bad_d = o[:4].copy(), d[:4].copy()
    bad_o[0, 1] = np.nan
    bad_d[1, 0] = np.inf
    bad_d[2] = 0.0
    bad_d[3, 2] = np.nan
    bad = trace(default_scene, bad_o, bad_d, backend=backend)
    assert np.all(bad.tri == -1)


def test_variant_names_are_checked():
    from rtlab.errors import VariantError
    with pytest.raises(VariantError, match="unknown traversal 'nope'"):
        Variant.paper(traversal="nope")


@pytest.mark.gpu
def test_cuda_and_nvidia_opencl_agree_on_bunny():
    """On the GPU machine: both backends give the same hits on BUNNY at 256²."""
    from rtlab.backends import get_backend
    scene = _preset("bunny", "bunny.ply", 256)
    a = render(scene, get_backend("cuda"), write_hits=True)
    b = render(scene, get_backend("opencl", "NVIDIA"), write_hits=True)
    o, d = camera_rays(scene.camera)
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    for r in (a, b):
        assert_matches_reference(compare_hits(ref, r.hits.tri, r.hits.t, scene.vertices, scene.faces, o, d), r.backend)
    assert (a.hits.tri == b.hits.tri).mean() > 0.999
