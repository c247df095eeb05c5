"""The trace API as a library user and the benchmarks call it: repeated launches on the same rays,
device buffers reused between calls, CUDA launch timing, and the benchmark rays of
../shared/bench/README.md (`rtlab bench rays`)."""
from __future__ import annotations

import math

import numpy as np
import pytest

import rtlab
from rtlab.benches.rays import RaysRow, diffuse_rays, make_rays, peer_figures, peer_source, rays_markdown
from rtlab.device.kernels import Variant
from rtlab.device.tracing import ray_buffers, trace
from rtlab.reference import compare_hits, reference_trace
from rtlab.scene.model import camera_rays

from .conftest import require_scene_file


@pytest.fixture(scope="module")
def small_scene():
    scene = rtlab.load_scene("default", size=32)
    return scene


def test_repeats_time_every_launch_and_give_the_same_hits(backend, small_scene):
    o, d = camera_rays(small_scene.camera)
    once = trace(small_scene, o, d, backend, Variant.paper(traversal="bvh"))
    many = trace(small_scene, o, d, backend, Variant.paper(traversal="bvh"), repeats=5, warmup=2)
    assert len(once.launches_ms) == 1 and len(many.launches_ms) == 5
    assert many.kernel_ms == pytest.approx(float(np.median(many.launches_ms)))
    assert all(ms > 0 for ms in many.launches_ms)
    assert np.array_equal(once.tri, many.tri) and np.array_equal(once.t, many.t)


def test_ray_buffers_are_reused_for_the_same_count_only(backend, small_scene):
    o, d = camera_rays(small_scene.camera)
    trace(small_scene, o, d, backend)
    first = ray_buffers(backend, len(o))
    assert ray_buffers(backend, len(o)) is first
    # a second batch of the same size overwrites the buffers: its own hits, not the first batch's
    shifted = trace(small_scene, o[::-1].copy(), d[::-1].copy(), backend)
    ref = reference_trace(small_scene.vertices, small_scene.faces, o[::-1], d[::-1])
    cmp = compare_hits(ref, shifted.tri, shifted.t, small_scene.vertices, small_scene.faces, o[::-1], d[::-1])
    assert cmp.n_mismatch == 0, cmp.summary()
    half = len(o) // 2
    part = trace(small_scene, o[:half], d[:half], backend)
    assert len(part.tri) == half and ray_buffers(backend, half) is not first


@pytest.mark.parametrize("variant", [Variant.paper(traversal="bvh", block=(8, 16)), Variant.paper(block=(32, 4)),
                                     Variant.paper(traversal="bvh", block=(8, 8), ray_order="morton")],
                         ids=lambda v: v.label())
def test_image_shaped_launch_gives_the_same_hits(backend, small_scene, variant):
    """trace(width=) takes the rays in tiles of the block (a warp traces neighbours), hits unchanged;
    an image whose sides are not multiples of the block included."""
    scene = rtlab.load_scene("default", size=8)
    scene.camera = small_scene.camera.with_size(37, 21)
    o, d = camera_rays(scene.camera)
    plain = trace(scene, o, d, backend, variant)
    grid = trace(scene, o, d, backend, variant, width=37)
    assert np.array_equal(plain.tri, grid.tri) and np.array_equal(plain.t, grid.t)
    with pytest.raises(rtlab.RtlabError, match="rows"):
        trace(scene, o, d, backend, variant, width=36)


def _diffuse_ray_by_the_readme(p_hit, n, incoming, u1, u2, diagonal):
    """One bounce ray, written out from ../shared/bench/README.md's text, scalar by scalar."""
    n = np.asarray(n, float) / math.sqrt(float(np.dot(n, n)))
    if float(np.dot(n, incoming)) > 0:
        n = -n
    origin = np.asarray(p_hit, float) + n * 1e-4 * diagonal
    r, phi = math.sqrt(u1), 2 * math.pi * u2
    a = np.array([0.0, 1.0, 0.0]) if abs(n[0]) > 0.9 else np.array([1.0, 0.0, 0.0])
    t1 = np.cross(n, a)
    t1 /= math.sqrt(float(np.dot(t1, t1)))
    t2 = np.cross(n, t1)
    d = t1 * r * math.cos(phi) + t2 * r * math.sin(phi) + n * math.sqrt(1 - u1)
    return origin, d


def test_diffuse_rays_follow_the_benchmark_recipe(small_scene):
    o, d = camera_rays(small_scene.camera)
    ref = reference_trace(small_scene.vertices, small_scene.faces, o, d)
    o2, d2 = diffuse_rays(small_scene, o, d, ref.t, ref.tri)
    hits = np.flatnonzero(ref.tri >= 0)
    assert len(o2) == len(hits) > 0
    rng = np.random.default_rng(1)
    u1, u2 = rng.random(len(hits)), rng.random(len(hits))
    lo, hi = small_scene.bounds().astype(float)
    diagonal = float(np.linalg.norm(hi - lo))
    v = small_scene.vertices.astype(float)
    for k in (0, 1, len(hits) // 2, len(hits) - 1):
        i = hits[k]
        a, b, c = v[small_scene.faces[ref.tri[i]]]
        p = o[i].astype(float) + d[i].astype(float) * float(ref.t[i])
        want_o, want_d = _diffuse_ray_by_the_readme(p, np.cross(b - a, c - a), d[i], u1[k], u2[k], diagonal)
        assert np.allclose(o2[k], want_o, rtol=1e-6, atol=1e-6 * diagonal)
        assert np.allclose(d2[k], want_d, atol=1e-6)
        assert abs(float(np.linalg.norm(d2[k])) - 1.0) < 1e-5


def test_bench_batch_checks_an_even_subsample(tmp_path):
    require_scene_file("bunny.ply")
    batch = make_rays("bunny/far", "primary", 64, check_rays=1000)
    assert batch.n == 64 * 64
    assert len(batch.check_index) <= 1000 and batch.check_index[0] == 0
    assert np.all(np.diff(batch.check_index) == batch.check_index[1])
    far = peer_figures()[("bunny/far", "primary", 1024)]
    assert far["best"] == max(far["warp"], far["optix"], far["tinybvh"]) == far[far["best_name"]]


def test_bench_rays_says_which_machine_its_peer_ratio_spans():
    """The "× best peer" column divides this run's figure by a figure the peers' README took on its
    own machine: the table names that machine, and says so where a row ran on another one."""
    device, date = peer_source()

    def markdown(devices, size=1024):
        rows = [RaysRow("bunny/far", "primary", size, "cuda", d, "bvh4", size * size, 0.1, 1e4, (0.1, 0.1),
                        peer=peer_figures().get(("bunny/far", "primary", size))) for d in devices]
        return rays_markdown(rows, "rtlab bench rays")

    same = markdown([device])
    assert f"measured on the {device} ({date})" in same and "two machines" not in same
    other = markdown([device, "NVIDIA H200"])
    assert "NVIDIA H200 is another device" in other and "two machines" in other
    assert "best peer:" not in markdown(["NVIDIA H200"], size=64)    # no peer figure, no note


@pytest.mark.gpu
def test_cuda_launch_time_leaves_out_the_host():
    """A kernel of a few microseconds: the events bracket the kernel, not pycuda's launch overhead
    (timed around pycuda's call, that overhead, ~25 us, would be inside every CUDA time). The rays start outside the
    scene's box and point away from it, so each thread loads its ray, fails the box clip and writes
    a miss: the kernel's own time does not depend on the scene's depth or the GPU's latency."""
    from rtlab.backends import get_backend
    try:
        be = get_backend("cuda")
    except Exception as e:
        pytest.skip(f"no CUDA: {e}")
    scene = rtlab.load_scene("default", size=16)
    far = float(np.abs(scene.vertices).max()) * 4.0
    n = 256
    o = np.full((n, 3), far, np.float32)
    d = np.full((n, 3), 1.0 / math.sqrt(3.0), np.float32)
    r = trace(scene, o, d, be, Variant.paper(traversal="bvh"), repeats=20, warmup=3)
    assert not r.hit.any()
    assert r.kernel_ms < 0.010, f"{n} rays that miss the scene's box took {r.kernel_ms * 1e3:.1f} us of device time"


# ---- what trace() is given ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def sphere_scene():
    import trimesh
    return rtlab.scene_from_arrays(trimesh.creation.icosphere(subdivisions=2, radius=1.0), name="sphere")


RAYS_O = np.array([[0.0, 0.0, 5.0], [0.3, 0.2, 5.0], [9.0, 9.0, 5.0]])
RAYS_D = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])


@pytest.mark.parametrize("kw,message", [
    (dict(tmin=None), "tmin must be a number"),
    (dict(tmin=np.nan), r"tmin must be a finite number >= 0, got nan \(ray 0\)"),
    (dict(tmin=np.inf), "tmin must be a finite number"),
    (dict(tmin=np.array([0.0, np.nan, 0.0])), r"\(ray 1\)"),
    (dict(tmax=None), "tmax must be a number"),
    (dict(tmax=np.nan), r"tmax must be a number \(numpy.inf for no limit\), got nan"),
    (dict(tmin=2.0, tmax=1.0), r"tmax must be >= tmin, got tmin 2 and tmax 1 \(ray 0\)"),
    (dict(tmax="far"), "tmax must hold real numbers"),
    (dict(tmin=-1.0), "tmin must be >= 0"),
])
def test_bad_ray_intervals_are_errors(backend, sphere_scene, kw, message):
    """None and NaN passed the old check and every ray missed (the docstring promised an error)."""
    with pytest.raises(rtlab.RtlabError, match=message):
        trace(sphere_scene, RAYS_O, RAYS_D, backend=backend, **kw)


def test_an_empty_interval_misses_and_inf_is_no_limit(backend, sphere_scene):
    got = trace(sphere_scene, RAYS_O, RAYS_D, backend=backend, tmin=1.0, tmax=1.0)
    assert np.all(got.tri < 0)
    assert trace(sphere_scene, RAYS_O, RAYS_D, backend=backend, tmax=np.inf).tri[:2].min() >= 0


UNIT_T = (np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], np.float32), np.array([[0, 1, 2]]))


@pytest.mark.parametrize("tmin,tmax,hits", [
    (0.0, 1.0 + 1e-12, True), (1.0 - 1e-12, np.inf, True), (1.0 - 2.0 ** -25, 5.0, True),
    (0.0, 1.0 - 2.0 ** -25, False), (0.0, 1.0, False), (1.0, 5.0, False), (1.0 + 2.0 ** -24, 5.0, False)])
@pytest.mark.parametrize("variant", [None, "bvh", "bvh-wide", "stack"])
def test_ray_bounds_keep_every_t_of_the_callers_interval(backend, tmin, tmax, hits, variant):
    """A hit at exactly t = 1 against float64 bounds that lie within a float32 step of it: the kernels
    hit where the float64 reference does. Rounded to nearest, tmax = 1 + 1e-12 became 1.0 and tmin =
    1 - 1e-12 became 1.0, and both dropped the hit."""
    vertices, faces = UNIT_T
    scene = rtlab.scene_from_arrays(vertices, faces)
    o, d = np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, -1.0]])
    ref = reference_trace(vertices, faces, o, d, tmin, tmax, cache=False)
    got = trace(scene, o, d, backend=backend, variant=variant, tmin=tmin, tmax=tmax)
    assert (ref.tri[0] == 0) == hits and got.tri[0] == ref.tri[0]
    if hits:
        assert got.t[0] == 1.0


def test_float32_bounds_round_away_from_the_interval():
    from rtlab.device.tracing import float32_outward
    x = np.array([0.0, 1e-50, 1.0, 1.0 + 1e-12, 1.0 - 1e-12, 1e39, np.inf])
    down, up = float32_outward(x, -1).astype(np.float64), float32_outward(x, +1).astype(np.float64)
    assert np.all(down <= x) and np.all(up >= x)
    assert down[0] == 0.0 and down[2] == up[2] == 1.0 and up[5] == np.inf and down[5] == np.finfo(np.float32).max
    assert np.all(np.nextafter(down[:5].astype(np.float32), np.float32(np.inf)).astype(np.float64) > x[:5])


@pytest.mark.parametrize("variant", [None, "bvh", "bvh-wide", "bvh-packet", "stack"])
def test_edge_functions_that_overflow_miss_rather_than_hit(backend, variant):
    """A scene at 1e20 (beyond the range the ScaleWarning names): the float32 edge products overflow
    to inf - inf = NaN, which passed the old sign test, and a ray well outside the triangle hit it."""
    import warnings
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64) * 1e20
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = rtlab.scene_from_arrays(vertices, np.array([[0, 1, 2]]))
    o, d = np.array([[0.7, 0.7, 1.0]]) * 1e20, np.array([[0.0, 0.0, -1.0]])     # x + y = 1.4: outside
    assert reference_trace(scene.vertices, scene.faces, o, d, cache=False).tri[0] == -1
    try:
        assert trace(scene, o, d, backend=backend, variant=variant).tri[0] == -1
    except rtlab.RtlabError as e:        # the wide BVHs (a GPU's default) refuse such a scene outright
        assert variant is None and "coordinates" in str(e), e


@pytest.mark.parametrize("bad,kind", [
    (RAYS_D.astype(complex), "complex numbers"), (RAYS_D.astype(str), "strings"),
    (np.array([[0, 0, None]] * 3), "Python objects"), (RAYS_D.astype(bool), "booleans"),
    ([["a", "b", "c"]] * 3, "strings")])
def test_non_numeric_arrays_are_errors(backend, sphere_scene, bad, kind):
    """Complex, string and object arrays ended in ComplexWarning/ValueError deep inside."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(rtlab.RtlabError, match=f"directions must hold real numbers .*{kind}"):
            trace(sphere_scene, RAYS_O, bad, backend=backend)
        with pytest.raises(rtlab.RtlabError, match=f"origins must hold real numbers .*{kind}"):
            trace(sphere_scene, bad, RAYS_D, backend=backend)


def test_a_scene_given_by_name_says_how_to_load_it(backend):
    with pytest.raises(rtlab.RtlabError, match=r"scene must be an rtlab Scene, got str 'bunny'.*rtlab.load_scene\('bunny'\)"):
        trace("bunny", RAYS_O, RAYS_D, backend=backend)
    with pytest.raises(rtlab.RtlabError, match="scene must be an rtlab Scene, got ndarray"):
        trace(RAYS_O, RAYS_O, RAYS_D, backend=backend)


def test_the_other_api_calls_check_what_they_are_given(backend, sphere_scene):
    """spawn_rays and hit_points on a scene name, camera_rays on a string, repeats 0 or -1 (one launch
    was timed anyway) and width=2.5 (rows of 2) gave AttributeErrors or were taken without a word."""
    from rtlab.errors import SceneError
    hits = trace(sphere_scene, RAYS_O, RAYS_D, backend=backend)
    with pytest.raises(rtlab.RtlabError, match=r"scene must be an rtlab Scene, got str 'bunny'"):
        rtlab.spawn_rays("bunny", hits, RAYS_D)
    with pytest.raises(rtlab.RtlabError, match="scene must be an rtlab Scene, got str"):
        rtlab.hit_points("bunny", hits)
    with pytest.raises(SceneError, match="camera_rays takes an rtlab Camera .*got str"):
        rtlab.camera_rays("cam")
    for repeats in (0, -1, 2.5):
        with pytest.raises(rtlab.RtlabError, match=f"repeats must be a whole number >= 1, got {repeats}"):
            trace(sphere_scene, RAYS_O, RAYS_D, backend=backend, repeats=repeats)
    with pytest.raises(rtlab.RtlabError, match="repeats must be a whole number >= 1, got 0"):
        rtlab.render(sphere_scene, backend=backend, size=8, repeats=0)
    o, d = camera_rays(sphere_scene.camera.with_size(4))
    with pytest.raises(rtlab.RtlabError, match="width must be a whole number >= 1, got 2.5"):
        trace(sphere_scene, o, d, backend=backend, width=2.5)


def test_a_block_beyond_the_device_is_one_error_before_the_launch(backend, sphere_scene):
    """A block of more work-items than the device takes ended in the launch's bare
    INVALID_WORK_GROUP_SIZE ("this is a bug" at the command line); every launch checks it first."""
    from rtlab.errors import BackendError
    with pytest.raises(BackendError, match=r"block 4097x1 = 4097 work-items for render_primary: .* takes at most \d+"):
        rtlab.render(sphere_scene, backend=backend, size=8, variant=Variant(traversal="stack", block=(4097, 1)))
    rtlab.render(sphere_scene, backend=backend, size=8, variant=Variant(traversal="stack", block=(16, 2)))


def test_a_variant_given_by_name_keeps_the_default_test(backend, sphere_scene):
    """variant="bvh" is the default variant with the BVH traversal (the watertight test stays);
    "bvh/moller" names both; an unknown name is a VariantError listing the names."""
    from rtlab.device.tracing import default_variant, resolve_variant
    from rtlab.errors import VariantError
    assert resolve_variant("bvh", backend) == default_variant(backend).with_(traversal="bvh")
    assert resolve_variant("bvh", backend).intersection == "watertight"
    assert resolve_variant("BVH/Moller", backend) == default_variant(backend).with_(traversal="bvh", intersection="moller")
    assert resolve_variant("plucker", backend).intersection == "plucker"
    ref = trace(sphere_scene, RAYS_O, RAYS_D, backend=backend, variant=Variant("bvh", "watertight"))
    got = trace(sphere_scene, RAYS_O, RAYS_D, backend=backend, variant="bvh")
    assert np.array_equal(got.tri, ref.tri) and np.array_equal(got.t, ref.t)
    for bad in ("bvhx", "bvh/stack", "a/b/c", ""):
        with pytest.raises(VariantError, match="traversal"):
            trace(sphere_scene, RAYS_O, RAYS_D, backend=backend, variant=bad)
    with pytest.raises(VariantError, match="Variant or a name"):
        trace(sphere_scene, RAYS_O, RAYS_D, backend=backend, variant=5)


@pytest.mark.parametrize("length", [1e-300, 1e-45, 1e-40, 1e39, 1e300])
def test_directions_are_rescaled_in_their_own_dtype(backend, sphere_scene, length):
    """float64 directions beyond float32's range became inf or 0 before the power-of-two rescaling
    (every ray a silent miss), and a float32 subnormal direction returned a hit at t = inf. Now the
    hits are those of the unit directions and t * |d| the same distance (t float64 where it leaves
    float32's range)."""
    unit = trace(sphere_scene, RAYS_O, RAYS_D, backend=backend)
    assert unit.tri[:2].min() >= 0 and unit.tri[2] < 0
    f32 = np.finfo(np.float32)
    for dtype in (np.float64, np.float32):
        d = RAYS_D.astype(np.float64) * length
        # compared as Python floats: against a float32 bound NumPy would cast `length` to float32 first
        if dtype == np.float32 and not float(f32.smallest_subnormal) <= length <= float(f32.max):
            continue
        d = d.astype(dtype)
        assert np.any(d != 0)
        got = trace(sphere_scene, RAYS_O, d, backend=backend)
        assert np.array_equal(got.tri, unit.tri), f"length {length:g} {np.dtype(dtype).name}: {got.tri} vs {unit.tri}"
        hit = got.tri >= 0
        dh = d[hit].astype(np.float64)
        big = np.abs(dh).max(axis=1, keepdims=True)              # |d| without squares that underflow
        dist = got.t[hit].astype(np.float64) * (np.linalg.norm(dh / big, axis=1) * big[:, 0])
        np.testing.assert_allclose(dist, unit.t[hit], rtol=1e-6)
        assert np.all(np.isfinite(got.t[hit]))


def test_a_t_beyond_float64_and_long_doubles_beyond_float64_are_errors(backend, sphere_scene):
    """A direction so short that a hit's t overflows even float64 (5e-324), and a long double origin
    or direction beyond float64's range (inf or 0 in the cast: a silent miss), are RtlabErrors naming
    the ray, with no numpy warning; a long double within range traces as its float64 value."""
    import warnings
    for length in (5e-324, 1e-310):
        with warnings.catch_warnings():
            warnings.simplefilter("error")           # no numpy overflow warning either
            with pytest.raises(rtlab.RtlabError, match=r"ray 0 hits triangle \d+ at a t beyond float64's range"):
                trace(sphere_scene, RAYS_O[:1], RAYS_D[:1].astype(np.float64) * length, backend=backend)
    unit = trace(sphere_scene, RAYS_O, RAYS_D, backend=backend)
    long_o, long_d = RAYS_O.astype(np.longdouble), RAYS_D.astype(np.longdouble)
    got = trace(sphere_scene, long_o, long_d, backend=backend)
    assert np.array_equal(got.tri, unit.tri) and np.array_equal(got.t, unit.t)
    for value, which in ((np.longdouble("1e4000"), "origin"), (np.longdouble("1e4000"), "direction"),
                         (np.longdouble("1e-4000"), "direction")):
        o, d = long_o.copy(), long_d.copy()
        (o if which == "origin" else d)[1, 2] = value
        with pytest.raises(rtlab.RtlabError, match=rf"{which} of ray 1 has a component beyond float64's range"):
            trace(sphere_scene, o, d, backend=backend)


def test_an_origin_beyond_float32_is_an_error(backend, sphere_scene):
    with pytest.raises(rtlab.RtlabError, match=r"origin of ray 1 .* beyond float32's range"):
        trace(sphere_scene, RAYS_O * np.array([[1], [1e39], [1]]), RAYS_D, backend=backend)
    nan_o = RAYS_O.copy()
    nan_o[0] = np.nan                                    # NaN and inf origins stay misses, as documented
    assert trace(sphere_scene, nan_o, RAYS_D, backend=backend).tri[0] < 0


def test_camera_rays_go_in_tiles_without_being_asked(backend, small_scene, monkeypatch):
    """Rays made by camera_rays carry their image's width: trace() takes them in tiles (the grid
    launch) with no width= given, and gives the hits of the same rays as plain arrays in row order.
    What is no longer the image (a subset, o + t d) goes in the order given."""
    from rtlab.device import tracing
    grids = []
    real = tracing._grid_launch
    monkeypatch.setattr(tracing, "_grid_launch", lambda *a, **k: grids.append(a[5]) or real(*a, **k))
    o, d = camera_rays(small_scene.camera)
    assert o.image_width == d.image_width == small_scene.camera.width
    variant = Variant(traversal="bvh")          # one ray a work-item: the variant that tiles
    tiled = trace(small_scene, o, d, backend, variant)
    assert grids == [small_scene.camera.width]
    rows = trace(small_scene, np.asarray(o), np.asarray(d), backend, variant)
    half = trace(small_scene, o[: len(o) // 2 + 1], d[: len(d) // 2 + 1], backend, variant)
    moved = trace(small_scene, o + 0.0 * d, d, backend, variant)    # plain origins, directions still the image
    assert grids == [small_scene.camera.width] * 2, "a subset goes in order; the image's directions still tile"
    assert np.array_equal(tiled.tri, rows.tri) and np.array_equal(tiled.t, rows.t)
    assert np.array_equal(half.tri, rows.tri[: len(o) // 2 + 1]) and np.array_equal(moved.tri, rows.tri)
    assert type(o + d) is np.ndarray and getattr(o[::2], "image_width", None) is None


@pytest.mark.parametrize("traversal,isect,defines", [("bvh", "watertight", None), ("bvh", "moller", None),
                                                     ("bvh4", "watertight", None), ("bvh4", "moller", None),
                                                     ("bvh4", "watertight", {"RT_FETCH_VISIT_EXIT_EACH": 1}),
                                                     ("bvh4", "watertight", {"RT_FETCH_VISIT_EXIT": 1}),
                                                     ("bvh4", "watertight", {"RT_FETCH_PUSH_REFS": 0}),
                                                     ("bvh4", "watertight", {"RT_FETCH_PUSH_REFS": 0,
                                                                             "RT_FETCH_VISIT_EXIT_EACH": 1})])
def test_rays_fetched_as_lanes_free_up_give_trace_rays_hits(backend, traversal, isect, defines, monkeypatch):
    """trace_rays_fetch (a lane takes the next ray when its own is done; the walk resumes after each
    refill) returns trace_rays' hits bit for bit, on incoherent rays of a real scene, rays that miss
    the scene box and an empty tail of threads. Forced on every backend: on PoCL (no warps) each lane
    stops after every leaf and resumes, which exercises the saved walk hardest; with
    RT_FETCH_VISIT_EXIT_EACH the 4-wide walk also leaves its visit loop after every node, as a lane
    does whose warp leaves it early (rt_bvh4.h, RT_FETCH_VISIT_EXIT), and resumes between nodes; with
    RT_FETCH_VISIT_EXIT=1 it takes Aila & Laine's plain while-while schedule (no early exit, no pops in
    the visit loop); with RT_FETCH_PUSH_REFS=0 its stack holds node rows, as the closest-hit walk's
    does, instead of the children's refs."""
    from rtlab.device import tracing
    scene = rtlab.load_scene("default", size=24)
    o, d = camera_rays(scene.camera)
    first = reference_trace(scene.vertices, scene.faces, o, d)
    bo, bd = diffuse_rays(scene, o, d, first.t, first.tri)
    rng = np.random.default_rng(3)
    away = rng.normal(size=(257, 3)).astype(np.float32)                   # from far outside, most miss
    bo = np.concatenate([bo, np.full((257, 3), 1e3, np.float32)])
    bd = np.concatenate([bd, away])
    variant = Variant(traversal=traversal, intersection=isect)
    launched = []
    real = tracing._fetch_launch
    monkeypatch.setattr(tracing, "_fetch_launch", lambda *a, **k: launched.append(1) or real(*a, **k))
    monkeypatch.setattr(type(backend), "has_warp_votes", lambda self: False)
    plain = trace(scene, bo, bd, backend, variant)
    monkeypatch.setattr(type(backend), "has_warp_votes", lambda self: True)
    fetched = trace(scene, bo, bd, backend, variant, repeats=3, defines=defines)
    assert launched == [1]
    assert np.array_equal(plain.tri, fetched.tri) and np.array_equal(plain.t, fetched.t, equal_nan=True)
    assert np.array_equal(plain.u, fetched.u) and np.array_equal(plain.v, fetched.v)
    ref = reference_trace(scene.vertices, scene.faces, bo, bd)
    cmp = compare_hits(ref, fetched.tri, fetched.t, scene.vertices, scene.faces, bo, bd)
    assert cmp.n_mismatch == 0, cmp.summary()


@pytest.mark.parametrize("traversal", ["bvh", "bvh4"])
def test_a_student_tree_keeps_trace_hits_on_a_device_with_warps(backend, traversal, tmp_path, monkeypatch):
    """A student tree stubs the course's own regions, among them the binary BVH's walk as resumable steps
    (the ray fetch's): there trace() on a device with warps walks with trace_rays instead, and with either
    default traversal its hits stay the reference's, through the lab steps the student has passed."""
    from rtlab.course.kernel_sources import copy_stubbed
    from rtlab.device import tracing
    from rtlab.paths import REFERENCE_KERNEL_DIR, use_kernel_dir
    scene = rtlab.load_scene("default", size=24)
    o, d = camera_rays(scene.camera)
    first = reference_trace(scene.vertices, scene.faces, o, d)
    bo, bd = diffuse_rays(scene, o, d, first.t, first.tri)
    variant = Variant(traversal=traversal, intersection="watertight")
    monkeypatch.setattr(type(backend), "has_warp_votes", lambda self: True)
    copy_stubbed(REFERENCE_KERNEL_DIR, tmp_path / "kernels", "05_kernel_tree")   # a lab 05 student's tree
    before = use_kernel_dir(tmp_path / "kernels")
    try:
        fetched = tracing.fetches_rays(backend, variant, "library_trace")
        hits = trace(scene, bo, bd, backend, variant)
    finally:
        use_kernel_dir(before)
    assert fetched == (traversal == "bvh4"), "the 4-wide fetch walk reads no course region; the binary one does"
    cmp = compare_hits(reference_trace(scene.vertices, scene.faces, bo, bd), hits.tri, hits.t, scene.vertices,
                       scene.faces, bo, bd)
    assert cmp.n_mismatch == 0, cmp.summary()


def test_rays_are_fetched_only_by_the_library_where_the_device_has_warps(backend):
    from rtlab.device.tracing import fetches_rays
    bvh = Variant(traversal="bvh", intersection="watertight", block=(8, 16))
    assert fetches_rays(backend, bvh, "library_trace") == backend.has_warp_votes()
    assert fetches_rays(backend, bvh.with_(traversal="bvh4"), "library_trace") == backend.has_warp_votes()
    assert not fetches_rays(backend, bvh, "03_traversal")                  # the labs' kernels: trace_rays
    assert not fetches_rays(backend, bvh.with_(count_work=True), "library_trace")
    assert not fetches_rays(backend, bvh.with_(traversal="stack"), "library_trace")


@pytest.mark.parametrize("variant", [None, "bvh", "bvh-wide", "bvh-packet", "stack", "bvh4"])
def test_small_triangles_hit_where_exact_arithmetic_says(backend, variant):
    """A right triangle of legs 1e-19 .. 1e-35 at the origin beside a unit one (no scale warning: float32
    resolves them): its edge products underflow float32. Rays inside it hit with the exact
    barycentrics, rays outside (1 % of a leg beyond an edge) miss. Before, 1/det overflowed (u, v inf)
    and the double fallback underflowed again as it was rounded to float (rays through the middle
    missed, rays outside hit)."""
    from fractions import Fraction
    points = np.array([[0.25, 0.25], [0.1, 0.8], [0.6, 0.35], [-0.01, 0.5], [0.5, -0.01], [0.5, 0.51], [0.6, 0.6]])
    for s in (1e-19, 3e-20, 1e-22, 1e-23, 1e-30, 1e-35):
        vertices = np.array([[5, 0, 0], [6, 0, 0], [5, 1, 0], [0, 0, 0], [s, 0, 0], [0, s, 0]], np.float64)
        scene = rtlab.scene_from_arrays(vertices, np.array([[0, 1, 2], [3, 4, 5]]))
        leg = Fraction(float(scene.vertices[4, 0]))
        o = np.concatenate([points * s, np.ones((len(points), 1))], axis=1).astype(np.float32)
        d = np.tile(np.float32([0.0, 0.0, -1.0]), (len(points), 1))
        got = trace(scene, o, d, backend=backend, variant=variant)
        assert np.array_equal(got.tri, reference_trace(scene.vertices, scene.faces, o, d, cache=False).tri)
        for k, (x, y) in enumerate(o[:, :2].astype(np.float64)):
            u, v = Fraction(x) / leg, Fraction(y) / leg
            inside = u >= 0 and v >= 0 and u + v <= 1
            where = f"legs {s:g}, ray at {points[k].tolist()} legs"
            assert got.tri[k] == (1 if inside else -1), where
            if inside:
                assert got.t[k] == 1.0 and abs(got.u[k] - float(u)) < 1e-6 and abs(got.v[k] - float(v)) < 1e-6, \
                    f"{where}: u, v = {got.u[k]}, {got.v[k]}, exact {float(u)}, {float(v)}"
