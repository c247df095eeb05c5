"""Shadows (lab step 04) and the reflection/refraction kernel tree (lab step 05) on every available
backend, against the float64 Whitted reference (rtlab.reference.whitted) and against themselves:
one-pass = two-pass, specialised = general, compacted = not; spawned rays never re-hit their own
surface at any scale or distance from the origin; shadow rays between facing surfaces are not
falsely occluded; total internal reflection.

Tolerances, against the float64 reference on the glass scene (rtlab.scene.materials.glass_scene):
at most TREE_PIXELS_MAX of the pixels may have a ray tree that hits other triangles (rays through
shared edges pick either side), and where the trees agree the 8-bit colours differ by at most
COLOR_TOL (float32 shading and Schlick against float64).
"""
from __future__ import annotations

import numpy as np
import pytest

from rtlab.device.kernels import SceneFeatures, Variant, build_defines, kernel_source
from rtlab.device.probes import probe_refraction, probe_secondary_rays, probe_shadow_rays
from rtlab.device.tracing import trace
from rtlab.device.whitted import NO_RAY, render_whitted, shading_defines
from rtlab.errors import RtlabError
from rtlab.reference.whitted import reference_whitted, whitted_error
from rtlab.scene.materials import apply_materials, glass_scene, mtl_materials, reachable_bounces, shading_features
from rtlab.scene.arrays import scene_from_arrays
from rtlab.scene.model import Camera, Light, Material, Scene

from .conftest import require_scene_file

SIZE = 64
COLOR_TOL = 2              # 8-bit steps, where the ray trees agree
TREE_PIXELS_MAX = 0.005    # share of pixels whose ray tree may differ (edge ties)
SCALES = (1e-3, 1.0, 1e3)
OFFSETS = (0.0, 1e2, 1e4)


@pytest.fixture(scope="module")
def glass():
    return glass_scene(SIZE)


def _opaque(scene: Scene) -> Scene:
    """The scene with every transparent material made a plain mirror (no refraction anywhere)."""
    mats = [Material(**vars(m)) for m in scene.materials]
    for m in mats:
        if m.transparency > 0:
            m.reflectivity, m.transparency = 0.5, 0.0
    return Scene(**{**vars(scene), "materials": mats})


def _unlit(scene: Scene) -> Scene:
    return Scene(**{**vars(scene), "lights": []})


# ---- one-pass vs two-pass, compaction, specialisation: the same image -----------------------------

def test_one_pass_and_two_pass_shadows_give_the_same_image(backend, glass):
    one = render_whitted(glass, backend, shadows="one-pass", write_hits=True)
    two = render_whitted(glass, backend, shadows="two-pass", write_hits=True)
    none = render_whitted(glass, backend, shadows="none")
    assert [l.kernel for l in two.launches] == ["trace_primary_hits", "shade_hits"]
    np.testing.assert_array_equal(one.hits.tri, two.hits.tri)
    np.testing.assert_array_equal(one.image, two.image)
    # and there are shadows to agree on
    assert np.count_nonzero(np.any(none.image != one.image, axis=2)) > 0.02 * SIZE * SIZE


@pytest.mark.parametrize("bounces", [2])
def test_tree_modes_give_the_same_image(backend, glass, bounces):
    """One-pass or two-pass shading in the tree, compacted or not: one image."""
    base = render_whitted(glass, backend, bounces=bounces)
    for shadows, compact in (("one-pass", True), ("two-pass", False), ("two-pass", True)):
        other = render_whitted(glass, backend, bounces=bounces, shadows=shadows, compact=compact)
        np.testing.assert_array_equal(base.image, other.image, err_msg=f"{shadows} compact={compact}")
    # a tree with nothing to reflect or refract is lab step 04's one-pass image
    plain = Scene(**{**vars(glass), "materials": [Material(m.name, m.diffuse, m.specular, m.shininess)
                                                    for m in glass.materials]})
    tree = render_whitted(plain, backend, bounces=bounces)
    assert tree.step == "library_bounces" and tree.depth == 0
    np.testing.assert_array_equal(tree.image, render_whitted(plain, backend, bounces=0).image)


def test_compaction_launches_only_live_rays(backend, glass):
    full = render_whitted(glass, backend, bounces=3)
    compact = render_whitted(glass, backend, bounces=3, compact=True)
    n = SIZE * SIZE
    assert all(l.rays == n for l in full.launches if l.kernel.startswith("trace_"))
    secondary = [l for l in compact.launches if l.level > 0]
    assert secondary and all(0 < l.rays < n for l in secondary)
    assert compact.rays_launched() < full.rays_launched()


# ---- the wavefront schedule: the tree's rays level by level ---------------------------------------

def _all_glass(scene: Scene) -> Scene:
    """Every material half glass, half mirror: most hits spawn both children, so a level holds
    more rays than the frame has pixels and the queues must grow."""
    mats = [Material(**{**vars(m), "reflectivity": 0.3, "transparency": 0.6, "ior": 1.5}) for m in scene.materials]
    return Scene(**{**vars(scene), "materials": mats})


@pytest.mark.parametrize("make", [lambda s: s, _all_glass], ids=["glass", "all-glass"])
def test_wavefront_traces_the_trees_rays(backend, glass, make):
    """One launch per level, the same ray tree as the depth-first kernel tree, the same image up to
    the order of float additions into a pixel (one 8-bit step at most, in few pixels)."""
    scene = make(glass)
    n = SIZE * SIZE
    for bounces in (1, 3):
        tree = render_whitted(scene, backend, bounces=bounces, write_hits=True)
        wave = render_whitted(scene, backend, bounces=bounces, write_hits=True, schedule="wavefront")
        assert [l.kernel for l in wave.launches] == (["trace_wavefront_primary"] + ["trace_wavefront"] * bounces
                                                      + ["pack_pending"])
        assert sorted(k for k, v in tree.tree.items() if np.any(v != NO_RAY)) == sorted(wave.tree)
        for node, ids in wave.tree.items():
            np.testing.assert_array_equal(ids, tree.tree[node], err_msg=node)
        np.testing.assert_array_equal(wave.hits.tri, tree.hits.tri)
        diff = np.abs(wave.image.astype(np.int32) - tree.image.astype(np.int32)).max(axis=2)
        assert diff.max() <= 1 and np.count_nonzero(diff) <= 0.001 * n, (bounces, diff.max(), np.count_nonzero(diff))
        # the queue holds every spawned ray of a level and nothing else
        for launch in wave.launches[1:-1]:
            level_nodes = [ids for node, ids in wave.tree.items() if len(node) == launch.level + 1]
            assert launch.rays == sum(int(np.count_nonzero(ids != NO_RAY)) for ids in level_nodes)
    if make is _all_glass:
        assert max(l.rays for l in wave.launches[1:-1]) > n, "no level outgrew the first queue"


def test_wavefront_matches_reference(backend, glass):
    result = render_whitted(glass, backend, bounces=3, write_hits=True, schedule="wavefront")
    _check_against_reference(result, reference_whitted(glass, bounces=3), "wavefront, 3 bounces")


def test_wavefront_rejects_two_pass_shadows():
    with pytest.raises(RtlabError, match="one-pass or none"):
        shading_defines(SceneFeatures(), "two-pass", 2, "schlick", tree=True, schedule="wavefront")
    with pytest.raises(RtlabError, match="schedule must be one of"):
        shading_defines(SceneFeatures(), "one-pass", 2, "schlick", tree=True, schedule="breadth")


@pytest.mark.parametrize("make", [_opaque, _unlit, lambda s: _unlit(_opaque(s))], ids=["no-glass", "no-lights", "neither"])
def test_specialised_and_general_kernels_give_the_same_image(backend, glass, make):
    scene = make(glass)
    special = render_whitted(scene, backend, bounces=2)
    general = render_whitted(scene, backend, bounces=2, specialise=False)
    features = shading_features(scene)
    assert special.defines["RT_REFRACTION"] == int(features["transparent"])
    assert special.defines["RT_SHADOWS"] == special.defines["RT_LIGHTS"] == int(features["has_lights"])
    assert general.defines["RT_REFRACTION"] == general.defines["RT_SHADOWS"] == 1
    assert special.defines != general.defines
    np.testing.assert_array_equal(special.image, general.image)


def test_bounce_depth_is_cut_to_what_the_scene_can_reach(backend, glass):
    weak = Scene(**{**vars(glass), "materials": [Material(**{**vars(m), "reflectivity": 0.0, "transparency": 0.0})
                                                   for m in glass.materials]})
    weak.materials[3].reflectivity = 0.05            # chrome: 0.05^2 < 1/512 < 0.05
    assert reachable_bounces(weak.materials) == 2
    special = render_whitted(weak, backend, bounces=4)
    general = render_whitted(weak, backend, bounces=4, specialise=False)
    assert special.depth == 2 and general.depth == 4
    assert len(special.launches) < len(general.launches)
    np.testing.assert_array_equal(special.image, general.image)


# ---- against the float64 reference ---------------------------------------------------------------

def _check_against_reference(result, ref, where):
    err = whitted_error(result.image, result.tree if result.tree is not None else {"P": result.hits.tri}, ref)
    print(f"{where}: {err.summary()}")
    assert err.tree_pixels <= TREE_PIXELS_MAX * err.pixels, f"{where}: {err.summary()}"
    assert err.color_max_same_tree <= COLOR_TOL, f"{where}: {err.summary()}"
    return err


@pytest.mark.parametrize("shadows", ["one-pass", "none"])
def test_shadows_match_reference(backend, glass, shadows):
    result = render_whitted(glass, backend, shadows=shadows, write_hits=True)
    ref = reference_whitted(glass, bounces=0, shadows=shadows != "none")
    _check_against_reference(result, ref, f"shadows {shadows}")


@pytest.mark.parametrize("bounces", [1, 2, 3, 4])
def test_bounces_match_reference(backend, glass, bounces):
    result = render_whitted(glass, backend, bounces=bounces, write_hits=True, compact=bounces % 2 == 0)
    ref = reference_whitted(glass, bounces=bounces)
    _check_against_reference(result, ref, f"{bounces} bounces")
    # every level adds something the reference sees: a missing level would fail above
    shallower = reference_whitted(glass, bounces=bounces - 1)
    assert np.count_nonzero(np.any(shallower.image != ref.image, axis=2)) > 0
    assert max(len(node) for node in ref.tree) == bounces + 1


def test_fixed_split_matches_reference(backend, glass):
    result = render_whitted(glass, backend, bounces=3, fresnel="fixed", write_hits=True)
    _check_against_reference(result, reference_whitted(glass, bounces=3, fresnel="fixed"), "fixed split")


# ---- total internal reflection ------------------------------------------------------------------

def _refract64(d, n, eta):
    cos_i = -(d * n).sum(1)
    sin2_t = eta**2 * (1 - cos_i**2)
    cos_t = np.sqrt(np.maximum(1 - sin2_t, 0))
    return eta[:, None] * d + (eta * cos_i - cos_t)[:, None] * n, sin2_t > 1, cos_i, cos_t


def test_refraction_and_total_internal_reflection_directions(backend):
    """refract_dir and fresnel_schlick against float64, on both sides of the critical angle."""
    rng = np.random.default_rng(5)
    m = 4000
    ior = np.float32(1.5)
    theta = np.concatenate([rng.uniform(0, np.pi / 2, m), np.arcsin(1 / 1.5) + rng.uniform(-2e-3, 2e-3, 200)])
    n = len(theta)
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    phi = rng.uniform(0, 2 * np.pi, n)
    d = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)], 1)
    front = rng.random(n) < 0.5
    got_t, got_f = probe_refraction(backend, d.astype(np.float32), normal.astype(np.float32), ior, front.astype(np.float32))
    eta = np.where(front, 1 / 1.5, 1.5)
    want_t, want_tir, cos_i, cos_t = _refract64(d.astype(np.float32).astype(np.float64), normal, eta)
    sin2 = eta**2 * (1 - cos_i**2)
    clear = np.abs(sin2 - 1) > 1e-5                  # float32 may decide either way right at the angle
    got_tir = got_f == 1.0
    assert want_tir[clear].sum() > 100 and (~want_tir[clear]).sum() > 100
    np.testing.assert_array_equal(got_tir[clear], want_tir[clear])
    ok = ~want_tir & clear
    # float32 rounding of sin^2 (~1e-7) moves cos_t = sqrt(1 - sin^2) by ~1e-7 / cos_t near the angle
    tol = 1e-5 + 1e-6 / cos_t[ok]
    assert np.all(np.abs(got_t[ok] - want_t[ok]).max(axis=1) <= tol)
    r0 = (0.5 / 2.5) ** 2
    want_f = r0 + (1 - r0) * (1 - np.where(eta > 1, cos_t, cos_i)) ** 5
    assert np.all(np.abs(got_f[ok] - want_f[ok]) <= tol)
    np.testing.assert_array_equal(got_t[want_tir & clear], 0.0)


def test_total_internal_reflection_in_the_glass_cube(backend, glass):
    """Rays inside the cube meeting a face beyond the critical angle: no refraction ray, the whole
    transmitted share reflected; and the reference's TIR count is not zero on the rendered view."""
    cube = np.flatnonzero(glass.material_ids == 4)
    centre = glass.vertices[glass.faces[cube]].reshape(-1, 3).mean(0)
    rng = np.random.default_rng(3)
    d = rng.normal(size=(800, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.tile(centre, (len(d), 1)).astype(np.float32)
    hits = trace(glass, o, d.astype(np.float32), backend=backend)
    assert np.all(np.isin(hits.tri, cube))
    n = glass.vertices[glass.faces[hits.tri]]
    ng = np.cross(n[:, 1] - n[:, 0], n[:, 2] - n[:, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    cos = np.abs((ng * d).sum(1))
    sin2_t = 1.5**2 * (1 - cos**2)
    tir = sin2_t > 1 + 1e-4
    clear = tir | (sin2_t < 1 - 1e-4)
    assert tir.sum() > 100
    _, w_t, _, child_t = probe_secondary_rays(glass, backend, d, hits, "refraction")
    _, w_r, _, child_r = probe_secondary_rays(glass, backend, d, hits, "reflection")
    assert np.all(child_t.tri[tir] == NO_RAY) and np.all(w_t[tir] == 0)
    assert np.all(child_t.tri[~tir & clear] != NO_RAY)
    np.testing.assert_allclose(w_r[tir], glass.materials[4].transparency, rtol=1e-6)
    # reflected rays stay inside and hit the cube again
    assert np.all(np.isin(child_r.tri[tir], cube))
    assert reference_whitted(glass, bounces=2).n_tir > 0


# ---- robust spawning: no self-intersection, no false occlusion -----------------------------------

def _scene(vertices, faces, material: Material, normals=None) -> Scene:
    c = np.asarray(vertices, np.float64).mean(0)
    return Scene("probe", np.asarray(vertices, np.float32), np.asarray(faces, np.int32),
                 np.zeros(len(faces), np.int32), [material], Camera(tuple(c + 1), tuple(c), width=8, height=8),
                 [Light(tuple(c + 2))], normals, "procedural")


SPAWN_MATERIAL = Material("half-glass", reflectivity=0.5, transparency=0.5, ior=1.5)


def _ulp(x) -> float:
    return float(np.spacing(np.float32(x)))


def _triangles(scale, offset, rng, count=8):
    """``count`` randomly oriented triangles of size ``scale`` around a point at distance
    ``offset`` from the origin, 10 sizes (and at least 2048 ulps of the offset) apart."""
    centre = rng.normal(size=3)
    centre = centre / np.linalg.norm(centre) * offset
    spacing = max(10.0 * scale, 2048 * _ulp(offset))
    grid = np.stack(np.meshgrid(*[np.arange(2)] * 3, indexing="ij"), -1).reshape(-1, 3)[:count] * spacing
    tris = []
    for g in grid:
        basis, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        corners = np.array([[0.0, 0.0], [1.0, 0.1], [0.3, 0.9]]) * scale
        tris.append(centre + g + corners @ basis[:2])
    return np.asarray(tris).reshape(-1, 3), np.arange(3 * count).reshape(-1, 3)


def _rays_at(vertices, faces, scale, rng, per_tri=64):
    """Rays from both sides at angles down to grazing, aimed at points inside each triangle."""
    v = np.asarray(vertices, np.float32).astype(np.float64)
    o, d, which, aim, normal = [], [], [], [], []
    for i, f in enumerate(faces):
        a, b, c = v[f]
        bary = rng.dirichlet([2.0, 2.0, 2.0], per_tri)
        q = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
        n = np.cross(b - a, c - a)
        n /= np.linalg.norm(n)
        tangent = rng.normal(size=(per_tri, 3))
        tangent -= (tangent @ n)[:, None] * n
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        cos = 10.0 ** rng.uniform(-2.5, 0, per_tri)                     # down to 0.2 deg from grazing
        side = np.where(rng.random(per_tri) < 0.5, 1.0, -1.0)
        dirs = -side[:, None] * cos[:, None] * n + np.sqrt(1 - cos**2)[:, None] * tangent
        start = (q - dirs * 2.0 * scale).astype(np.float32).astype(np.float64)
        dirs = q - start                                # aim from the rounded origin
        o.append(start)
        d.append(dirs / np.linalg.norm(dirs, axis=1, keepdims=True))
        which.append(np.full(per_tri, i))
        aim.append(q)
        normal.append(np.tile(n, (per_tri, 1)))
    return tuple(np.concatenate(a) for a in (o, d, which, aim, normal))


@pytest.mark.parametrize("offset", OFFSETS)
@pytest.mark.parametrize("scale", SCALES)
def test_spawned_rays_do_not_hit_their_own_triangle(backend, scale, offset):
    """Reflection, refraction and shadow rays spawned on triangles of every size and distance from
    the origin never hit the triangle they start on."""
    if scale < 64 * _ulp(offset):
        pytest.skip(f"a triangle of size {scale:g} at {offset:g} is under 64 float32 ulps: not a shape")
    rng = np.random.default_rng(int(np.log10(scale) + 10 * np.log10(offset + 1)) + 100)
    vertices, faces = _triangles(scale, offset, rng)
    scene = _scene(vertices, faces, SPAWN_MATERIAL)
    o, d, which, aim, normal = _rays_at(scene.vertices, faces, scale, rng)
    hits = trace(scene, o.astype(np.float32), d.astype(np.float32), backend=backend)
    on = hits.tri == which
    assert on.mean() > 0.9, "the probe rays should hit the triangle they aim at"
    d32 = d.astype(np.float32)
    for kind in ("reflection", "refraction"):
        _, w, _, child = probe_secondary_rays(scene, backend, d32, hits, kind)
        spawned = on & (child.tri != NO_RAY)
        assert spawned.sum() > 0.3 * on.sum()
        self_hits = spawned & (child.tri == hits.tri)
        assert self_hits.sum() == 0, f"{kind}: {self_hits.sum()} of {spawned.sum()} re-hit their own triangle"
    # Shadow rays to points on either side reach them: nothing else is near. The points lie up to
    # three sizes off the plane, but at least 64 ulps of the coordinates: nearer than their own
    # rounding a point is on neither side.
    height = np.maximum(scale * rng.uniform(0.1, 3.0, len(d)), 64 * _ulp(np.abs(aim).max()))
    height *= np.where(rng.random(len(d)) < 0.5, 1.0, -1.0)
    along = rng.normal(size=(len(d), 3)) * scale
    along -= (along * normal).sum(1)[:, None] * normal
    targets = aim + normal * height[:, None] + along
    visible = probe_shadow_rays(scene, backend, d32, hits, targets)
    assert visible[on].all(), f"{(~visible[on]).sum()} of {on.sum()} shadow rays occluded by their own triangle"


@pytest.mark.parametrize("scale,offset", [(s, o) for s in SCALES for o in OFFSETS
                                          if s >= 1e3 * np.spacing(np.float32(o + s))])
def test_rays_spawned_on_a_sphere_leave_or_cross_it(backend, scale, offset):
    """A convex closed mesh: reflection rays from its outside hit nothing; refraction rays cross
    to the far side (a chord of at least 1.49 radii for ior 1.5), never the near side."""
    import trimesh
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=scale)
    centre = np.array([1.0, -2.0, 2.0]) / 3.0 * offset
    vertices = np.asarray(sphere.vertices) + centre
    scene = _scene(vertices, sphere.faces, Material("glass", reflectivity=0.2, transparency=0.8, ior=1.5))
    rng = np.random.default_rng(11)
    n = 1500
    aim = rng.normal(size=(n, 3))
    aim /= np.linalg.norm(aim, axis=1, keepdims=True)
    start = rng.normal(size=(n, 3))
    start /= np.linalg.norm(start, axis=1, keepdims=True)
    o = centre + start * 3.0 * scale
    target = centre + aim * scale * rng.uniform(0.0, 0.98, (n, 1))
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    hits = trace(scene, o32, d32, backend=backend)
    assert hits.hit.mean() > 0.99
    _, _, _, refl = probe_secondary_rays(scene, backend, d32, hits, "reflection")
    spawned = hits.hit & (refl.tri != NO_RAY)
    assert spawned.sum() > 0.9 * hits.hit.sum()
    assert np.all(refl.tri[spawned] == -1), f"{np.count_nonzero(refl.tri[spawned] >= 0)} reflection rays re-hit the sphere"
    origin, _, _, refr = probe_secondary_rays(scene, backend, d32, hits, "refraction")
    spawned = hits.hit & (refr.tri != NO_RAY)
    assert spawned.sum() > 0.9 * hits.hit.sum()
    crossed = (refr.tri[spawned] >= 0) & (refr.tri[spawned] != hits.tri[spawned]) & (refr.t[spawned] > 0.5 * scale)
    assert crossed.all(), f"{np.count_nonzero(~crossed)} of {spawned.sum()} refraction rays did not cross the sphere"


FACING_CASES = [(s, o) for s in SCALES for o in OFFSETS if s >= 1e3 * np.spacing(np.float32(o + s))]


def _floor_under_ceiling(backend, gap, offset, rng, m=2000):
    """A floor and a ceiling ``gap`` above it, facing each other, ``offset`` from the origin, and the hits
    of m rays from between them down on the floor: (scene, base point, half width, directions, hits)."""
    base = np.array([0.6, 0.8, 0.0]) * offset
    half = 5.0 * gap
    floor = base + np.array([[-half, 0, -half], [half, 0, -half], [0, 0, 2 * half]])
    ceiling = base + np.array([[-half, gap, -half], [0, gap, 2 * half], [half, gap, -half]])
    scene = _scene(np.concatenate([floor, ceiling]), np.arange(6).reshape(2, 3), Material("wall"))
    xz = rng.uniform(-0.3, 0.3, (m, 2)) * half
    o = base + np.stack([xz[:, 0], np.full(m, 0.5 * gap), xz[:, 1]], 1)
    d = np.stack([rng.normal(0, 0.5, m), -np.ones(m), rng.normal(0, 0.5, m)], 1)
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    hits = trace(scene, o.astype(np.float32), d, backend=backend)
    assert np.all(hits.tri == 0)
    return scene, base, half, d, hits


@pytest.mark.parametrize("gap,offset", FACING_CASES)
def test_shadow_rays_between_facing_surfaces_are_not_occluded(backend, gap, offset):
    """Floor and ceiling facing each other: lights between them, up to a thousandth of the gap
    under the ceiling, reach every point of the floor; lights above the ceiling reach none."""
    rng = np.random.default_rng(17)
    scene, base, half, d, hits = _floor_under_ceiling(backend, gap, offset, rng)
    m = len(d)
    lxz = rng.uniform(-0.3, 0.3, (m, 2)) * half
    height = np.concatenate([rng.uniform(0.01, 0.99, m // 2), 1.0 - 10.0 ** rng.uniform(-3, -1, m - m // 2)])
    between = base + np.stack([lxz[:, 0], height * gap, lxz[:, 1]], 1)
    visible = probe_shadow_rays(scene, backend, d, hits, between)
    assert visible.all(), f"{np.count_nonzero(~visible)} of {m} shadow rays falsely occluded"
    above = base + np.stack([lxz[:, 0], np.full(m, 1.5 * gap), lxz[:, 1]], 1)
    assert not probe_shadow_rays(scene, backend, d, hits, above).any()


@pytest.mark.parametrize("gap,offset", FACING_CASES)
def test_a_light_on_a_surface_is_not_shadowed_by_it(backend, gap, offset):
    """Lights lying on the ceiling (exactly in its plane, and within a millionth of the gap above or
    below it) reach every point of the floor: a shadow segment stops short of its light
    (shadow_segment_end), so the surface holding a light does not block it even where o + (light - o)
    rounds past the light."""
    rng = np.random.default_rng(23)
    scene, base, half, d, hits = _floor_under_ceiling(backend, gap, offset, rng)
    m = len(d)
    plane = float(scene.vertices[3, 1])                 # the ceiling's plane, as stored (float32)
    lxz = base[[0, 2]] + rng.uniform(-0.3, 0.3, (m, 2)) * half
    nudge = np.where(np.arange(m) < m // 2, 0.0, gap * 1e-6 * rng.uniform(-1, 1, m))
    lights = np.stack([lxz[:, 0], np.float32(plane + nudge), lxz[:, 1]], 1).astype(np.float32)
    visible = probe_shadow_rays(scene, backend, d, hits, lights.astype(np.float64))
    assert visible.all(), f"{np.count_nonzero(~visible)} of {m} lights on the ceiling shadowed by it"


def test_a_light_in_the_floors_plane_lights_a_sphere_as_the_reference_does(backend):
    """A lamp standing on a tilted floor, in its plane: the floor does not shadow the sphere above it,
    in the kernels as in the float64 reference."""
    import trimesh
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    ball = np.asarray(sphere.vertices) + [0.0, 1.3, 0.0]
    floor = np.array([[-6.0, 0, -6], [6, 0, -6], [6, 0, 6], [-6, 0, 6]])
    turn = np.linalg.qr(np.random.default_rng(5).normal(size=(3, 3)))[0]     # a rotation (or reflection)
    vertices = np.concatenate([ball, floor]) @ turn.T
    faces = np.concatenate([sphere.faces, len(ball) + np.array([[0, 2, 1], [0, 3, 2]])])
    eye, at, up, lamp = np.array([[0.3, 2.5, 6.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [2.7, 0.0, 1.9]]) @ turn.T
    scene = Scene("lamp on the floor", vertices.astype(np.float32), faces.astype(np.int32),
                  np.zeros(len(faces), np.int32), [Material("matte")],
                  Camera(tuple(eye), tuple(at), up=tuple(up), width=SIZE, height=SIZE),
                  [Light(tuple(lamp))], None, "procedural")
    result = render_whitted(scene, backend, shadows="one-pass", write_hits=True)
    ref = reference_whitted(scene, bounces=0, shadows=True)
    _check_against_reference(result, ref, "a light in the floor's plane")


@pytest.mark.parametrize("inside", [1e-2, 1e-4])
def test_a_light_just_inside_a_closed_box_lights_nothing_outside(backend, inside):
    """A light 1e-2 and 1e-4 (of the box's size) inside a closed box's wall: nothing outside is lit, in
    the kernels (tree, wavefront, the light buffer) and the float64 reference: a shadow segment stops a
    few float ulps short of its light (shadow_segment_end), not a fixed share of its length, which lets
    the floor see a light that near the wall through it."""
    import trimesh
    box = trimesh.creation.box(bounds=[(-1, 0, -1), (1, 2, 1)])
    v, f = np.asarray(box.vertices, float), np.asarray(box.faces)
    floor = np.array([[-10, 0, -10], [10, 0, -10], [10, 0, 10], [-10, 0, 10]], float)
    vertices, faces = np.r_[v, floor], np.r_[f, [[8, 10, 9], [8, 11, 10]]]
    camera = Camera((0, 12, 14), (0, 0, 0), width=48, height=48)
    dark = scene_from_arrays(vertices, faces, lights=[], camera=camera)
    lit = scene_from_arrays(vertices, faces, lights=[Light((1 - inside, 1.0, 0.2))], camera=camera)
    ambient = reference_whitted(dark).image
    assert np.array_equal(reference_whitted(lit, shadows=True).image, ambient)
    for how in (dict(), dict(schedule="wavefront"), dict(variant=Variant(traversal="bvh"))):
        image = render_whitted(lit, backend, **how).image
        assert np.array_equal(image, render_whitted(dark, backend, **how).image), \
            f"{how}: {np.count_nonzero(np.any(image != ambient, axis=2))} pixels lit through the wall"


def test_zero_vertex_normals_shade_as_the_face(backend):
    """A floor whose vertex normals are all zero ("vn 0 0 0"): the kernels (Whitted and the primary
    shading) and both float64 references shade it with its flat normal, as if it had none. The
    interpolated normal was NaN: black in the Whitted kernels, ambient in their reference, and the
    other way round in the primary pair."""
    from rtlab.device.rendering import render
    from rtlab.reference.shading import reference_shade
    floor = np.array([[-4.0, 0, -4], [4, 0, -4], [4, 0, 4], [-4, 0, 4]])
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    camera = Camera((0.5, 3.0, 5.0), (0.0, 0.0, 0.0), width=32, height=32)
    light = [Light((0.3, 2.0, 0.4))]
    flat = scene_from_arrays(floor, faces, camera=camera, lights=light)
    zero = scene_from_arrays(floor, faces, camera=camera, lights=light, vertex_normals=np.zeros((4, 3)))
    for scene in (flat, zero):
        frame = render_whitted(scene, backend, write_hits=True)
        _check_against_reference(frame, reference_whitted(scene, bounces=0, shadows=True), scene.name)
    assert np.array_equal(render_whitted(zero, backend).image, render_whitted(flat, backend).image)
    primary = render(zero, backend, write_hits=True)
    assert np.array_equal(primary.image, render(flat, backend).image)
    hits = primary.hits
    from rtlab.scene.model import camera_rays
    o, d = camera_rays(camera)
    ref = reference_shade(zero, o, d, hits.tri, hits.t, hits.u, hits.v)
    assert np.abs(ref * 255 - primary.image.reshape(-1, 3)).max() <= COLOR_TOL + 1


def test_lights_and_normals_the_shading_cannot_use_are_errors():
    floor = np.array([[-4.0, 0, -4], [4, 0, -4], [4, 0, 4], [-4, 0, 4]])
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    far = scene_from_arrays(floor, faces, lights=[Light((2e19, 1.0, 0.0))])     # traces; renders refuse it
    from rtlab.device.rendering import render
    for draw in (render_whitted, render):
        with pytest.raises(RtlabError, match="light 0 at .* lies beyond 1e\\+18 from the origin"):
            draw(far, size=8)
    with pytest.raises(RtlabError, match="vertex normal 1 is .*normals must be finite"):
        scene_from_arrays(floor, faces, vertex_normals=[[0, 1, 0], [np.nan, 1, 0], [0, 1, 0], [0, 1, 0]])


# ---- features, defines and what they leave out ---------------------------------------------------

def test_scene_features(glass):
    f = shading_features(glass)
    assert f == {"has_lights": True, "reflective": True, "transparent": True, "max_bounces": 16}
    f = shading_features(_unlit(_opaque(glass)))
    assert not f["has_lights"] and not f["transparent"] and f["reflective"]
    plain = Scene(**{**vars(glass), "materials": [Material(m.name, m.diffuse) for m in glass.materials]})
    assert shading_features(plain)["max_bounces"] == 0 and not shading_features(plain)["reflective"]
    # a material no triangle uses does not count
    unused = Scene(**{**vars(plain), "materials": plain.materials + [Material("spare", transparency=1.0)]})
    assert not shading_features(unused)["transparent"]


def test_shading_defines_reject_bad_modes(glass):
    with pytest.raises(RtlabError, match="shadows"):
        shading_defines(SceneFeatures(), "three-pass", 0, "schlick")
    with pytest.raises(RtlabError, match="fresnel"):
        shading_defines(SceneFeatures(), "one-pass", 0, "exact")
    with pytest.raises(RtlabError, match="bounces"):
        shading_defines(SceneFeatures(), "one-pass", -1, "schlick")


@pytest.mark.parametrize("step", ["04_shadows", "05_kernel_tree"])
def test_specialised_kernels_leave_code_out(step):
    """No lights and no transparency: no shadow traversal and no refraction kernel in the cubin,
    and the primary kernel needs fewer registers."""
    from rtlab.backends.nvcc import nvcc_available, nvcc_resources
    if not nvcc_available():
        pytest.skip("nvcc not on PATH")
    base = SceneFeatures(stack_size=24, n_lights=1, n_materials=5)
    special = build_defines(Variant.paper(), SceneFeatures(**{**vars(base), "has_lights": False, "transparent": False}))
    general = build_defines(Variant.paper(), base)
    assert (special["RT_SHADOWS"], special["RT_LIGHTS"], special["RT_REFRACTION"]) == (0, 0, 0)
    r_special = nvcc_resources(kernel_source(step, "cuda"), special)
    r_general = nvcc_resources(kernel_source(step, "cuda"), general)
    primary = "render_shadows" if step == "04_shadows" else "trace_primary_tree"
    print({k: v.registers for k, v in r_general.items()}, {k: v.registers for k, v in r_special.items()})
    assert r_special[primary].registers < r_general[primary].registers
    if step == "05_kernel_tree":
        assert "trace_refraction" in r_general and "trace_refraction" not in r_special


# ---- materials from MTL ----------------------------------------------------------------------------

def test_kitchen_glass_and_metal_from_its_mtl():
    from rtlab.scene.loader import parse_mtl
    mats = parse_mtl(require_scene_file("kitchen/kitchen.mtl"))
    by_name = {m.name: m for m in mtl_materials(list(mats.values()))}
    glass = by_name["m15_glass"]
    assert (round(glass.transparency, 6), glass.ior, glass.reflectivity) == (0.85, 1.55, 0.0)
    assert by_name["m03_shiny_metal"].reflectivity == pytest.approx(0.9)
    assert by_name["m12_metal"].reflectivity == pytest.approx(0.8)
    assert by_name["m00_floor"].reflectivity == 0.0        # Kd > 0: not a metal
    bart = {m.name: m for m in mtl_materials(list(mats.values()), mirror_all_specular=True)}
    assert bart["m00_floor"].reflectivity == pytest.approx(0.5)
    assert all(m.reflectivity + m.transparency <= 1.0 for m in bart.values())


def test_material_presets(glass):
    from rtlab.errors import SceneError
    assert apply_materials(glass, "file").materials[2].transparency == pytest.approx(0.9)
    refraction_only = apply_materials(glass, "paper-refraction")
    assert all(m.reflectivity == 0 for m in refraction_only.materials)
    with pytest.raises(SceneError, match="unknown material preset"):
        apply_materials(glass, "mirror-world")


def test_student_regions_are_marked():
    from rtlab.paths import SHARED_KERNEL_DIR
    text = (SHARED_KERNEL_DIR / "rt_whitted.h").read_text()
    for fn in ("light_visible", "shade_local", "spawn_reflection", "spawn_refraction"):
        body = text[text.index(f" {fn}("):]
        body = body[body.index("{"):body.index("\n}\n")]
        assert body.count("/* BEGIN SOLUTION */") == 1 and body.count("/* END SOLUTION */") == 1, fn


def test_table5_bounce_rows_measure_every_schedule(backend, glass):
    """`rtlab bench shading`'s bounce rows: the tree, compacted, and the wavefront schedule, each
    row naming its backend, the wavefront image within one 8-bit step of the tree's."""
    from rtlab.benches.shadows_bounces import bench_bounces, table5_markdown
    row = bench_bounces(glass, backend, 2, size=32, repeats=1, check_size=16, materials="file")
    e = row.extra
    assert e["same_image"] and e["wave_max_diff"] <= 1
    assert e["wave_launches"] == 4 and e["compact_launches"] == row.launches == 8
    assert 0 < e["wave_rays"] <= e["compact_rays"] < row.rays
    md = table5_markdown([row], "test")
    assert "wavefront fps" in md and f"| {row.backend} | 2 bounces |" in md


@pytest.mark.parametrize("bounces", ["2", None, 2.0, True, -1, 17])
def test_bounces_that_are_not_a_whole_number_in_range_are_errors(bounces):
    """bounces="2" or None raised a raw TypeError (``bounces > 0``) before the check that names it."""
    with pytest.raises(RtlabError, match="bounces must be a whole number from 0 to 16"):
        render_whitted(glass_scene(size=8), "opencl", bounces=bounces)


@pytest.mark.parametrize("change, message", [
    (dict(reflectivity=float("nan")), "its numbers must be finite"),
    (dict(reflectivity=2.0), "shares of the light"),
    (dict(reflectivity=0.6, transparency=0.6), "together at most 1"),
    (dict(transparency=0.9, ior=0.0), "index of refraction must be > 0, got 0"),
    (dict(transparency=0.9, ior=-1.0), "index of refraction must be > 0, got -1"),
    (dict(diffuse=(0.5, -0.1, 0.5)), "colours and shininess must be >= 0"),
])
def test_materials_the_shading_cannot_use_are_errors(change, message):
    """A material changed after the scene was made: NaN reflectivity raised ValueError deep in the bounce
    count, and ior <= 0 or reflectivity 2 rendered without a word. The scene's check names the material;
    an opaque material may keep MTL's Ni 0."""
    scene = glass_scene(size=8)
    scene.materials[2] = Material("glass", **change)
    with pytest.raises(RtlabError, match=rf"material 2 \('glass'\): .*{message}"):
        render_whitted(scene, "opencl", bounces=1)
    scene.materials[2] = Material("opaque", ior=0.0)
    scene.check_materials()
