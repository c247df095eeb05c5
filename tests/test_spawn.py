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
from rtlab.scene.model import Camera, Light, Material, camera_rays


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



def _slivers(rng, count, length=10.0, width=0.01, offset=0.0, spacing=12.0):
    """``count`` randomly turned length x width slivers around a point ``offset`` from the origin,
    ``spacing`` apart so that nothing but the sliver a ray leaves lies near it; float32 corners, as
    float64, and their float64 unit normals (exact to double rounding)."""
    tris = []
    for k in range(count):
        q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        local = np.array([[0.0, 0.0, 0.0], [length, 0.0, 0.0], [0.5 * length, width, 0.0]]) - [0.5 * length, 0.0, 0.0]
        tris.append(local @ q.T + [offset + spacing * (k - count // 2), offset, -offset])
    v = np.asarray(tris, np.float32).astype(np.float64)
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return v, n / np.linalg.norm(n, axis=1, keepdims=True)


def _sliver_scene(v):
    return rtlab.scene_from_arrays(v.reshape(-1, 3), np.arange(3 * len(v)).reshape(-1, 3), name="slivers")


def _along(rng, tris, normal):
    """Unit directions in each triangle's plane, along its first edge (either way) within a
    milliradian: the way a grazing ray stays longest over a sliver."""
    e = tris[:, 1] - tris[:, 0]
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    t = e * np.where(rng.random(len(e)) < 0.5, 1.0, -1.0)[:, None] + rng.normal(0, 1e-3, e.shape)
    t -= (t * normal).sum(1)[:, None] * normal
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def _angle_to_plane(d, normal):
    """Signed angle (float64) each direction makes with the plane of its unit normal."""
    d = np.asarray(d, np.float64)
    return np.arcsin((d * normal).sum(1) / np.linalg.norm(d, axis=1))


@pytest.mark.parametrize("offset", [0.0, 1e3])
def test_rays_spawned_off_a_sliver_at_grazing_angles_leave_it(backend, offset):
    """spawn_rays with directions 0.5 to 4 microradians off the plane of 10 x 0.01 slivers, above and
    below: each origin lies on the side its direction leaves and no ray comes back. The float cross
    product's normal is 17 microradians off on such a sliver: a third of these origins were on the
    wrong side (rt_shade.h's geometric_normal)."""
    rng = np.random.default_rng(41)
    v, normal = _slivers(rng, 8, offset=offset)
    scene = _sliver_scene(v)
    which = np.repeat(np.arange(len(v)), 400)
    aim = np.einsum("nk,nkc->nc", rng.dirichlet([1, 1, 1], len(which)), v[which])
    o = (aim + 0.5 * normal[which]).astype(np.float32)
    d = aim - o.astype(np.float64)
    hits = trace(scene, o, (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32), backend=backend)
    assert np.all(hits.tri == which), "the probe rays should hit the sliver they aim at"
    t = _along(rng, v[which], normal[which])
    dips = np.where(rng.random(len(which)) < 0.5, 1.0, -1.0) * 10.0 ** rng.uniform(np.log10(5e-7), np.log10(4e-6), len(which))
    new_d = (np.cos(dips)[:, None] * t + np.sin(dips)[:, None] * normal[which]).astype(np.float32)
    angle = _angle_to_plane(new_d, normal[which])
    keep = np.abs(angle) >= 4e-7                       # rounding the direction may move it nearer the plane
    assert keep.mean() > 0.95
    o2, d2 = spawn_rays(scene, hits, new_d)
    side = ((o2.astype(np.float64) - v[which, 0]) * normal[which]).sum(1)
    wrong = keep & ((side > 0) != (angle > 0))
    assert not wrong.any(), f"{wrong.sum()} of {keep.sum()} origins on the side their ray does not leave"
    again = trace(scene, o2[keep], d2[keep], backend=backend)
    assert np.all(again.tri == -1), f"{np.count_nonzero(again.tri >= 0)} of {keep.sum()} rays came back to a sliver"


def test_reflections_off_a_sliver_at_grazing_angles_leave_it(backend):
    """Rays meeting 10 x 0.01 slivers 0.5 to 20 microradians off their plane: the kernels' reflection
    rays (surface_at's normal, spawn_origin's side) leave and hit nothing. With the float cross
    product's normal, 17 microradians off, some reflected into the sliver's other side, started on
    the wrong one and came back."""
    from rtlab.device.probes import probe_secondary_rays
    from rtlab.device.whitted import NO_RAY
    rng = np.random.default_rng(43)
    v, normal = _slivers(rng, 4, spacing=12.0)
    scene = _sliver_scene(v)
    scene.materials[0].reflectivity = 0.9
    which = np.repeat(np.arange(len(v)), 1500)
    aim = np.einsum("nk,nkc->nc", rng.dirichlet([1, 1, 1], len(which)), v[which])
    t = _along(rng, v[which], normal[which])
    dips = np.where(rng.random(len(which)) < 0.5, 1.0, -1.0) * 10.0 ** rng.uniform(np.log10(5e-7), np.log10(2e-5), len(which))
    o = (aim - 10.0 * (np.cos(dips)[:, None] * t - np.sin(dips)[:, None] * normal[which])).astype(np.float32)
    d = aim - o.astype(np.float64)
    d32 = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    hits = trace(scene, o, d32, backend=backend)
    grazing = (hits.tri == which) & (np.abs(_angle_to_plane(d32, normal[which])) >= 5e-7)
    assert grazing.sum() > 0.25 * len(which)
    _, w, _, child = probe_secondary_rays(scene, backend, d32, hits, "reflection")
    spawned = grazing & (child.tri != NO_RAY)
    assert spawned.sum() == grazing.sum()
    back = spawned & (child.tri >= 0)
    assert not back.any(), f"{back.sum()} of {spawned.sum()} reflections came back to a sliver"


def test_small_and_thin_triangles_have_unit_normals_and_spawn_off_them(backend):
    """Triangles of legs 1e-12 and 1e-20, and a unit sliver 1e-25 wide, over a floor: hit_points'
    normal is the unit +z (the squared length of the cross product underflowed float32: NaN normals,
    NaN origins), the spawned ray down through the triangle reaches the floor, and the kernels shade
    the triangle as lit as a 1e-6 one (its NaN normal left it unlit)."""
    floor = [[-5, -5, -3], [10, -5, -3], [-5, 10, -3]]
    lit = None
    for s, sliver in ((1e-6, False), (1e-12, False), (1e-20, False), (1e-25, True)):
        tri = [[0, 0, 0], [1, 0, 0], [0.5, s, 0]] if sliver else [[0, 0, 0], [s, 0, 0], [0, s, 0]]
        at = np.array([0.5, s / 2]) if sliver else np.array([0.3 * s, 0.3 * s])
        height = 1.0 if sliver else 2 * s
        cam = Camera((at[0], at[1], height), (at[0], at[1], 0.0), fov_deg=1e-3 if sliver else 60,
                                 width=8, height=8)
        scene = rtlab.scene_from_arrays(np.array(tri + floor, np.float64), np.array([[0, 1, 2], [3, 4, 5]]), camera=cam,
                                        lights=[Light((at[0], at[1], 1.5 * height))])
        hits = trace(scene, np.array([[at[0], at[1], height]]), np.array([[0.0, 0.0, -1.0]]), backend=backend)
        assert hits.tri[0] == 0
        normal = hit_points(scene, hits).normal[0]
        assert np.allclose(np.abs(normal), [0, 0, 1], atol=1e-6), f"size {s:g}: normal {normal}"
        o2, d2 = spawn_rays(scene, hits, np.array([[0.0, 0.0, -1.0]]))
        assert trace(scene, o2, d2, backend=backend).tri[0] == 1, f"size {s:g}: the spawned ray should reach the floor"
        if not sliver:
            frame = rtlab.render(scene, backend=backend, size=8, write_hits=True)
            assert frame.hits.tri[27] == 0
            pixel = frame.image.reshape(-1, 3)[27]
            lit = pixel if lit is None else lit
            assert np.array_equal(pixel, lit), f"size {s:g}: pixel {pixel.tolist()}, lit as {lit.tolist()} at 1e-6"
