"""Secondary rays from Python (rtlab.spawn_rays, rtlab.hit_points): the kernels' own offset, origins on
the side the new ray leaves in exact arithmetic, no ray back on the triangle it leaves at any scale,
where naive spawns (o + t d with tmin 0 or a fixed tmin) fail."""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

import rtlab
from rtlab.device.spawn import hit_points, offset_ray_origins, position_error, spawn_rays, spawn_ulps
from rtlab.device.tracing import trace
from rtlab.scene.model import Material, camera_rays


def _box_on_floor(scale=1.0, offset=0.0, reflective=0.0, size=48):
    """A unit box and a sphere on a 40-wide floor, scaled and moved (float64, rounded once)."""
    import trimesh
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    box.apply_translation([-1.0, 0.5, 0.0])
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.6)
    ball.apply_translation([1.0, 0.6, 0.3])
    floor_v = np.array([[-20, 0, -20], [-20, 0, 20], [20, 0, 20], [20, 0, -20]], np.float64)
    v = np.concatenate([box.vertices, ball.vertices, floor_v])
    f = np.concatenate([box.faces, len(box.vertices) + ball.faces,
                        len(box.vertices) + len(ball.vertices) + np.array([[0, 1, 2], [0, 2, 3]])])
    shift = np.array([offset, offset / 2.0, -offset])
    cam = rtlab.scene.Camera(tuple(np.array([0.5, 3.0, 6.0]) * scale + shift), tuple(np.array([0.0, 0.3, 0.0]) * scale + shift),
                             width=size, height=size)
    return rtlab.scene_from_arrays(v * scale + shift, f, camera=cam, name=f"box_{scale:g}_{offset:g}",
                                   material=Material("mirror", reflectivity=reflective))


def _reflect(d, n):
    d = d.astype(np.float64)
    n = n.astype(np.float64)
    return (d - 2.0 * np.einsum("ij,ij->i", d, n)[:, None] * n).astype(np.float32)


def test_spawn_rays_give_the_kernels_own_origins(backend):
    """The reflection rays the kernels spawn (probe_secondary_rays: surface_at, spawn_origin) and
    spawn_rays on the same hits and directions: the same origins, within 3 ulps of each coordinate
    (the kernels' three multiply-adds, hit_position's two and the offset's, may each be fused where numpy
    rounds twice), from the one constant RT_SPAWN_ULPS."""
    from rtlab.device.probes import probe_secondary_rays
    from rtlab.kernel_constants import kernel_constant
    assert spawn_ulps() == kernel_constant("RT_SPAWN_ULPS") >= 1
    scene = _box_on_floor(offset=1e3, reflective=0.8)
    o, d = camera_rays(scene.camera)
    hits = trace(scene, o, d, backend=backend)
    k_o, k_w, k_d, _ = probe_secondary_rays(scene, backend, d, hits, "reflection")
    spawned = k_w > 0
    assert spawned.sum() > 0.5 * len(o)
    p_o, p_d = spawn_rays(scene, hits, k_d)
    same_o, _ = hits.spawn(scene, k_d)
    assert np.array_equal(same_o, p_o, equal_nan=True)
    assert np.array_equal(p_d[spawned], k_d[spawned])
    ulp = np.spacing(np.abs(k_o[spawned]).astype(np.float32))
    assert np.all(np.abs(p_o[spawned] - k_o[spawned]) <= 3 * ulp), np.max(np.abs(p_o[spawned] - k_o[spawned]) / ulp)
    pts = hit_points(scene, hits)
    moved = np.abs(p_o[spawned] - pts.p[spawned]).max(axis=1)
    assert np.all(moved > 0) and np.all(moved <= 2.0 * pts.p_err[spawned] + 2 * ulp.max(axis=1))


def test_spawned_origins_lie_on_the_side_the_ray_leaves():
    """In exact arithmetic (fractions of the float32 values): each origin lies strictly on the side of
    its triangle's plane that its direction points to, and within the offset of the plane."""
    rng = np.random.default_rng(5)
    scene = _box_on_floor(offset=1e4)
    v = scene.vertices
    n = 400
    tri = rng.integers(0, scene.n_triangles, n)
    w = rng.dirichlet([1, 1, 1], n).astype(np.float32)

    class Hits:
        pass
    hits = Hits()
    hits.tri, hits.u, hits.v = tri.astype(np.int32), w[:, 1], w[:, 2]
    d = rng.normal(size=(n, 3)).astype(np.float32)
    o, _ = spawn_rays(scene, hits, d)
    for i in range(n):
        a, b, c = (tuple(map(Fraction, map(float, v[scene.faces[tri[i], k]]))) for k in range(3))
        e1 = [b[k] - a[k] for k in range(3)]
        e2 = [c[k] - a[k] for k in range(3)]
        nn = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0])
        side = sum(nn[k] * (Fraction(float(o[i, k])) - a[k]) for k in range(3))
        leaves = sum(nn[k] * Fraction(float(d[i, k])) for k in range(3))
        assert side != 0 and (side > 0) == (leaves > 0), f"ray {i}: origin on the wrong side"


@pytest.mark.parametrize("scale,offset", [(1e-4, 0.0), (1.0, 1e4), (1.0, 1e5), (1e3, 0.0)])
def test_spawned_rays_do_not_hit_what_they_leave(backend, scale, offset):
    """Reflections off the kernel's own hits: none comes back to its triangle with spawn_rays, at
    scales 1e-4..1e3 and 1e5 from the origin, and they find what the float64 reference finds from
    the same origins. Naive origins o + t d with tmin 0 hit their own triangle there (the lesson)."""
    from rtlab.reference import compare_hits, reference_trace
    scene = _box_on_floor(scale, offset)
    o, d = camera_rays(scene.camera)
    hits = trace(scene, o, d, backend=backend)
    h = hits.tri >= 0
    assert h.mean() > 0.5
    r = _reflect(d, hit_points(scene, hits).normal)
    o2, d2 = spawn_rays(scene, hits, r)
    assert np.all(np.isnan(o2[~h]))
    bounce = trace(scene, o2[h], d2[h], backend=backend)
    own = hits.tri[h]
    assert np.sum(bounce.tri == own) == 0
    ref = reference_trace(scene.vertices, scene.faces, o2[h], d2[h])
    c = compare_hits(ref, bounce.tri, bounce.t, scene.vertices, scene.faces, o2[h], d2[h])
    assert c.n_mismatch == 0, c.summary()
    if offset >= 1e4:
        naive_o = (o.astype(np.float64) + d * hits.t[:, None].astype(np.float64)).astype(np.float32)
        naive = trace(scene, naive_o[h], r[h], backend=backend)
        assert np.sum(naive.tri == own) > 0.01 * h.sum()


def test_misses_give_nan_origins_that_miss_again(backend):
    scene = _box_on_floor()
    o = np.array([[0.0, 50.0, 0.0], [0.0, 3.0, 0.0]], np.float32)
    d = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]], np.float32)
    hits = trace(scene, o, d, backend=backend)
    assert hits.tri.tolist()[0] == -1 and hits.tri[1] >= 0
    o2, d2 = spawn_rays(scene, hits, d)
    assert np.all(np.isnan(o2[0])) and np.all(np.isfinite(o2[1]))
    assert trace(scene, o2, d2, backend=backend).tri[0] == -1
    with pytest.raises(rtlab.RtlabError, match="one per hit"):
        spawn_rays(scene, hits, d[:1])
    with pytest.raises(rtlab.RtlabError, match="what rtlab.trace returns"):
        spawn_rays(scene, "hits", d)


def test_offset_follows_the_triangle_coordinates():
    """position_error is gamma(RT_SPAWN_ULPS) times the largest |coordinate| of the triangle; the
    offset moves each coordinate by at least one float and is zero along a zero normal component."""
    corners = np.array([[[1e4, 0, 0], [1e4 + 1, 0, 0], [1e4, 1, 0]]], np.float32)
    u = spawn_ulps() * 2.0 ** -24
    assert position_error(corners)[0] == pytest.approx((1e4 + 1) * u / (1 - u), rel=1e-6)
    p = np.array([[1e4 + 0.25, 0.25, 0.0]], np.float32)
    o = offset_ray_origins(p, position_error(corners), np.array([[0, 0, 1]], np.float32), np.array([[0, 0, -1]], np.float32))
    assert o[0, 0] == p[0, 0] and o[0, 1] == p[0, 1] and o[0, 2] < -position_error(corners)[0] * 0.99
