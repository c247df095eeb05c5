"""The stiff/extreme-case suite (rtlab.robustness) at its small "test" size: every
triangle test x every traversal in rtlab.device.kernels.TRAVERSALS on every family, against the float64
reference. The watertight test with the conservative traversal must reach the suite's goals (0
where the goal is 0); the other tests' leak and error rates are bounded at about twice what was
measured on PoCL, so that a regression fails while the lesson (they leak) stays visible.
The full sizes (127² stairs, 10^5 rays) run in `rtlab bench robustness`."""
from __future__ import annotations

import numpy as np
import pytest

from rtlab.device import kernels
from rtlab.robustness import FAMILY_NAMES, GOALS, family_cases, run_robustness, trace_case

from .conftest import require_scene_file

FAMILIES = sorted(FAMILY_NAMES)
TRAVERSALS = list(kernels.TRAVERSALS)

# Traversals that still let rays through with the watertight test and RT_CONSERVATIVE on. Empty
# since ropes walks from the root through the whole tie range of an edge/corner exit
# (rt_kd_ropes.h); before that it leaked 41 of 10^5 (family 1) and 9 of 1.5 10^5 (family 2).
# A traversal listed here is expected to leak (strict xfail), so the entry goes once it is fixed.
KNOWN_LEAKING = set()

# Leak rates (leaks / rays, worst case and traversal of a family) measured on PoCL 3.1 on
# 2026-11-22: family 1 Möller 0.150, Wald 0.030, Plücker 0.004; family 2 Möller 0.107, Wald 0.038,
# Plücker 0.004. Bounded at about twice that (rounding differs on devices with fused multiply-add).
LEAK_RATE_BOUND = {(1, "moller"): 0.30, (1, "wald"): 0.065, (1, "plucker"): 0.01,
                   (2, "moller"): 0.22, (2, "wald"): 0.08, (2, "plucker"): 0.008,
                   # family 10's 1e-3 sphere 2.8e3 from the origin is 8 ulps across: measured on PoCL 3.1,
                   # 2026-11-23, Moller 0.025, Wald 0.020, Plucker 0.021 (kd and BVH alike)
                   (10, "moller"): 0.05, (10, "wald"): 0.05, (10, "plucker"): 0.05}
# Mismatches (beyond ties) and false hits of the other tests: none measured on PoCL in families
# 3-9; a small allowance for devices that contract into fused multiply-adds.
OTHER_RATE_BOUND = 0.005
# Family 13 (grazing slivers with blockers 2e-5 of t away) is where the other tests' t errors show:
# measured on PoCL 3.1, 2026-11-25, mismatches Moller 12.7 %, Plucker 6.7 %, Wald 5.3 % of the made
# slivers' rays, false hits (a spawned ray back on its sliver) 0.2 % with Moller; bounded at about twice.
OTHER_RATE_BOUND_BY_FAMILY = {13: 0.3}
# Families whose test-size cases need a scene file (a case whose file is missing is left out)
FAMILY_SCENE_FILES = {9: "bunny.ply", 13: "sponza/sponza.obj", 14: "sponza/sponza.obj"}

_rows_cache: dict = {}


def family_rows(backend, family: int):
    """Rows of one family for every test and traversal (run once per backend and family; family 8
    in a child process, so a crash or hang is counted, not fatal)."""
    key = (backend, family)
    if family in FAMILY_SCENE_FILES:
        require_scene_file(FAMILY_SCENE_FILES[family])    # the family leaves out a scene whose file is missing
    if key not in _rows_cache:
        _rows_cache[key] = run_robustness(backend, families=[family], size="test", timeout_s=300)
    return _rows_cache[key]


def _describe(r) -> str:
    return (f"family {r.family} '{r.case}' {r.isect}/{r.traversal} (RT_CONSERVATIVE={r.conservative}): "
            f"{r.rays} rays, leaks {r.leaks}, misses {r.misses}, mismatches {r.mismatches}, ties {r.ties}, "
            f"differs {r.differs}, false hits {r.false_hits}, NaN t {r.nan_t}, t off {r.t_off}, "
            f"failure '{r.failure}', first bad rays {r.first_bad}")


def _goal_marks(family, traversal):
    if family == 11 and traversal == "packet":
        return [pytest.mark.skip(reason="family 11 renders Whitted frames: the packet traversal has no such kernels")]
    if family in GOALS["leaks"] and traversal in KNOWN_LEAKING:
        return [pytest.mark.xfail(strict=True, reason=f"{traversal} leaks a few rays (see KNOWN_LEAKING)")]
    return []


@pytest.mark.parametrize("family,traversal", [pytest.param(f, t, marks=_goal_marks(f, t), id=f"{f}-{FAMILY_NAMES[f]}-{t}")
                                              for f in FAMILIES for t in TRAVERSALS])
def test_watertight_conservative_meets_goals(backend, family, traversal):
    """0 leaks/misses (1-2, 10), 0 mismatches beyond ties (3-5, 9, 10, 12-15), 0 false hits (6, 8, 13,
    15), no NaN t, no crash or hang, the same ids in every traversal and t within RT_T_ERR of the
    float64 reference (every traced family), for the watertight test with RT_CONSERVATIVE on."""
    rows = [r for r in family_rows(backend, family) if r.isect == "watertight" and r.traversal == traversal]
    assert rows and all(r.conservative == 1 for r in rows)
    bad = [_describe(r) + f" -> {r.goal_violations()}" for r in rows if r.goal_violations()]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("family,traversal", [pytest.param(f, t, marks=_goal_marks(f, t), id=f"{f}-{FAMILY_NAMES[f]}-{t}")
                                              for f in FAMILIES for t in TRAVERSALS])
def test_other_tests_stay_within_measured_rates(backend, family, traversal):
    """Möller–Trumbore, Wald and Plücker: leak rates bounded (families 1-2), mismatches and false
    hits rare elsewhere; no NaN t, no crash, no hang, and no hit for a NaN/Inf ray, for any test."""
    rows = [r for r in family_rows(backend, family) if r.isect != "watertight" and r.traversal == traversal]
    assert rows
    for r in rows:
        print(_describe(r))
        assert not r.failure and r.nan_t == 0, _describe(r)
        if family == 8:
            assert r.false_hits == 0 and r.mismatches == 0, _describe(r)
        bound = LEAK_RATE_BOUND.get((family, r.isect))
        if bound is not None:
            assert r.leaks <= bound * r.rays, _describe(r)
        elif family not in GOALS["leaks"]:
            rate = OTHER_RATE_BOUND_BY_FAMILY.get(family, OTHER_RATE_BOUND)
            assert r.mismatches <= rate * r.rays, _describe(r)
            assert r.false_hits <= max(OTHER_RATE_BOUND, rate / 30) * r.rays, _describe(r)


def test_refined_t_is_what_keeps_slivers_right(backend):
    """The suite must be able to fail: family 13's grazing slivers with Woop et al.'s own t
    (RT_REFINE_T=0) pick the wrong one of a sliver and a blocker 2e-5 of t away, and their t is off
    by more than RT_T_ERR; with the plane distance in double (the default) neither happens."""
    from rtlab.robustness import count_case, trace_case, RobustnessRow
    require_scene_file("sponza/sponza.obj")
    case = family_cases(13, "test")[0]
    counts = {}
    for refine in (0, 1):
        tri, t, _ = trace_case(case, backend, "watertight", "stack", RT_REFINE_T=refine)
        row = count_case(case, case.reference(), tri, t, RobustnessRow(13, case.label, "watertight", "stack", 1,
                                                                       backend.name, backend.device_name, case.n_rays))
        counts[refine] = (row.mismatches, row.t_off)
    assert counts[1] == (0, 0) and counts[0][0] > 0 and counts[0][1] > case.n_rays // 10, counts


@pytest.mark.parametrize("traversal", ["stack", "bvh", "bvh-packet", "bvh4"])
def test_tmin_just_before_a_grazing_sliver_keeps_it(backend, traversal):
    """Family 13's made slivers at grazing angles, traced with tmin 2e-5 of t before the float64 hit
    (the sliver must be hit) and 2e-5 after it (it must not be), on the rays where the kernel names
    the reference's triangle (the others graze an edge: ties): Woop et al.'s t, off by up to 0.5 %
    there, dropped hits just beyond tmin; the plane distance in double keeps every one."""
    from rtlab.device.kernels import Variant
    from rtlab.device.tracing import trace
    require_scene_file("sponza/sponza.obj")
    case = family_cases(13, "test")[0]
    ref = case.reference()
    variant = Variant(traversal, "watertight")
    full = trace(case.scene, case.origins, case.directions, backend=backend, variant=variant)
    hit = np.flatnonzero((ref.tri >= 0) & (full.tri == ref.tri))
    assert hit.size > 0.9 * np.sum(ref.tri >= 0)
    o, d, t_ref, want = case.origins[hit], case.directions[hit], ref.t[hit], ref.tri[hit]
    lost = {}
    for refine in (1, 0):
        before = trace(case.scene, o, d, backend=backend, variant=variant, tmin=t_ref * (1 - 2e-5),
                       defines={"RT_REFINE_T": refine})
        after = trace(case.scene, o, d, backend=backend, variant=variant, tmin=t_ref * (1 + 2e-5),
                      defines={"RT_REFINE_T": refine})
        lost[refine] = (int(np.sum(before.tri != want)), int(np.sum(after.tri == want)))
    assert lost[1] == (0, 0), f"{traversal}: {lost[1][0]} hits dropped just beyond tmin, {lost[1][1]} kept before it"
    assert sum(lost[0]) > 0, "Woop's own t should get some of these wrong (the test would not notice a regression)"


def test_leaks_are_the_lesson(backend):
    """The suite must be able to fail: on the far-away sphere and the jittered plane, Möller–Trumbore
    with the stack traversal lets rays through where the watertight test lets none."""
    rows = family_rows(backend, 1) + family_rows(backend, 2)
    leaks = {isect: sum(r.leaks for r in rows if r.isect == isect and r.traversal == "stack")
             for isect in ("moller", "watertight")}
    assert leaks["moller"] > 0 and leaks["watertight"] == 0, leaks


# ---- the generators themselves --------------------------------------------------------------
def test_every_family_has_cases_the_reference_agrees_with():
    """Rays that must hit (closed sphere, interior of the plane) do in float64; bad rays miss;
    the stairs rays all hit something; the scenes far away really are far away."""
    require_scene_file("bunny.ply")
    for family in FAMILIES:
        cases = family_cases(family, "test")
        assert cases, f"family {family} has no case"
        for case in cases:
            ref = case.reference()
            if case.render is not None:          # family 11: a float64 Whitted render
                assert ref.image.shape == (case.scene.camera.height, case.scene.camera.width, 3)
                assert len(np.unique(ref.image.reshape(-1, 3), axis=0)) > 50, case.label
                continue
            assert ref.tri.shape == (case.n_rays,)
            if case.must_hit is not None:
                assert ref.tri[case.must_hit].min() >= 0, case.label
                if case.target_tris is not None:
                    assert np.isin(ref.tri[case.must_hit], case.target_tris).all(), case.label
            if case.bad is not None:
                assert np.all(ref.tri[case.bad] < 0), case.label
            if family in (4, 5):
                assert np.all(ref.tri >= 0), case.label
    sphere = family_cases(1, "test")[0]
    assert np.abs(sphere.scene.vertices).max() > 1e5
    from rtlab.device.device_scene import near_origin
    assert all(near_origin(c.scene) for c in family_cases(10, "test")), "family 10 must take the fused box test"
    glass = [c for c in family_cases(11, "test") if c.label.startswith("glass")]
    assert np.abs(glass[-1].scene.vertices).max(axis=1).min() > 0.9e5
    lengths = [np.linalg.norm(c.directions.astype(np.float64), axis=1) for c in family_cases(12, "test")]
    assert min(x.min() for x in lengths) < 1e-29 and max(x.max() for x in lengths) > 1e29
    offsets = [np.abs(c.scene.vertices).min() for c in family_cases(5, "test")]
    assert max(offsets) >= 1e4 - 1


def test_stairs_grid_puts_rays_in_riser_planes():
    """With 127² rays (the benchmark), every sixth column lies exactly in a riser's plane x = i."""
    from rtlab.robustness import STAIR_STEPS, stairs_rays
    o, _ = stairs_rays(127)
    xs = np.unique(o[:, 0].astype(np.float32))
    on_risers = np.intersect1d(xs, np.arange(STAIR_STEPS, dtype=np.float32))
    assert len(on_risers) == STAIR_STEPS


def test_bench_robustness_command(backend, tmp_path):
    """`rtlab bench robustness` prints the table; here one family, two tests, the stack traversal."""
    from typer.testing import CliRunner
    from rtlab.cli import app
    md = tmp_path / "robust.md"
    args = ["bench", "robustness", "--backends", backend.name, "--size", "test", "--families", "4",
            "--isects", "moller,watertight", "--traversals", "stack", "--md", str(md)]
    if backend.name == "opencl":
        args += ["--device", backend.device_name]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    text = md.read_text()
    assert "| 4 | stairs | moller | stack |" in text and "| 4 | stairs | watertight | stack | 1 |" in text


# ---- families 10-12: box planes, spawn offsets, direction lengths -------------------------------
def test_fused_box_test_keeps_what_the_exact_kd_traversal_keeps(backend):
    """Family 10 (box planes, a small sphere in a large room; the BVH on its fused box test): for
    every triangle test the BVH misses and leaks no more than the stack kd traversal, whose box
    and split tests are exact."""
    rows = family_rows(backend, 10)
    for r in rows:
        if r.traversal != "bvh":
            continue
        stack = next(s for s in rows if s.case == r.case and s.isect == r.isect and s.traversal == "stack")
        assert r.misses <= stack.misses and r.leaks <= stack.leaks, _describe(r) + " | stack: " + _describe(stack)


# Family 11: pixels more than 16/255 off the float64 Whitted render, as a share of all pixels, per
# case. Measured on PoCL 3.1 (40², 2026-11-23) with offsets from the rounding bound: 0 up to 1e3,
# <= 0.25 % at 1e4, <= 2.4 % at 1e5, <= 0.07 % (acne) on the mirror floor; with the former fixed
# 256-ulp offsets 0.2 %, 5.4 %, 14 % and, for the watertight test, 4 % of acne on the mirror floor.
SPAWN_PIXEL_SHARE = {"glass scene at 0": 0.0, "glass scene at 10": 0.0, "glass scene at 1000": 0.003,
                     "glass scene at 10000": 0.01, "glass scene at 100000": 0.05,
                     "mirror floor 2000 wide at the origin": 0.003}


def test_spawn_offsets_neither_acne_nor_speckles(backend):
    """Family 11: every test and traversal renders the glass scene within SPAWN_PIXEL_SHARE of the
    float64 reference from the origin to 1e5, and the mirror floor at the origin without acne."""
    rows = family_rows(backend, 11)
    assert {r.case for r in rows} == set(SPAWN_PIXEL_SHARE)
    bad = [_describe(r) + f", {r.px_off} pixels off" for r in rows
           if r.failure or r.px_off < 0 or r.px_off > SPAWN_PIXEL_SHARE[r.case] * r.rays]
    assert not bad, "\n".join(bad)


def test_direction_length_changes_nothing(backend):
    """Family 12: directions of length 1e-30..1e30, every test and traversal: no mismatch, and t
    in the caller's units: within 1e-3 of the reference (grazing hits on the tessellated sphere
    reach 1e-4 at any length, unit length included; a t not scaled back is off by the length)."""
    rows = family_rows(backend, 12)
    bad = [_describe(r) + f", max rel dt {r.t_rel_err_max:.1e}" for r in rows
           if r.failure or r.mismatches or not r.t_rel_err_max <= 1e-3]
    assert not bad, "\n".join(bad)


# ---- families 13-15: which hit the closest-hit choice takes ------------------------------------
def test_every_traversal_returns_the_brute_force_ids_at_ties(backend):
    """Families 14 (SPONZA: rays exactly through vertices on kd split planes with triangles on both
    sides, exactly through shared edges, at coplanar copies and halves at random ids) and 13 (grazing
    slivers with blockers): every traversal returns, ray for ray, the triangle and the t of the brute
    force in the kernels' own arithmetic (every triangle in a loop, closer_hit's tie rule), for the
    watertight test. The kd traversals culled the far cell at the unpadded hit t and lost the lower id
    there, the BVH packet a box entered at that t."""
    from rtlab.device.probes import probe_brute_force
    require_scene_file("sponza/sponza.obj")
    cases = family_cases(14, "test") + family_cases(13, "test")[:1]
    for case in cases:
        brute = probe_brute_force(case.scene, backend, case.origins, case.directions, "watertight")
        assert np.mean(brute.tri >= 0) > 0.5, case.label
        for traversal in TRAVERSALS:
            tri, t, _ = trace_case(case, backend, "watertight", traversal)
            wrong = np.flatnonzero((tri != brute.tri) | ((tri >= 0) & (t != brute.t)))
            assert wrong.size == 0, (f"{case.label}, {traversal}: {wrong.size} of {case.n_rays} rays differ from the "
                                     f"brute force, e.g. ray {wrong[0]}: triangle {tri[wrong[0]]} at t {t[wrong[0]]!r}, "
                                     f"brute force {brute.tri[wrong[0]]} at {brute.t[wrong[0]]!r}")


# Families of plain rays (8: bad rays, run in a child process; 11: Whitted frames) whose scene files
# are not needed or are found
DEFAULT_FAMILIES = (1, 2, 3, 4, 5, 6, 7, 10, 12, 13, 14, 15)


def _coherent_packets(directions: np.ndarray, lanes: int, cone: float = 0.9) -> int:
    """Packets of `lanes` consecutive rays that rt_bvh_packet.h's packet_is_coherent takes together
    (one octant, within `cone` of the first ray's direction), counted on the host: a check that the
    families below exercise the packet path and not only the ray-by-ray one."""
    d = np.asarray(directions, np.float64)
    n = len(d) // lanes * lanes
    if n == 0:
        return 0
    g = d[:n].reshape(-1, lanes, 3)
    first = g[:, :1, :]
    same_octant = np.all(np.signbit(g) == np.signbit(first), axis=(1, 2))
    cos = np.einsum("pki,pki->pk", g, np.broadcast_to(first, g.shape)) / (
        np.linalg.norm(g, axis=2) * np.linalg.norm(first, axis=2))
    return int(np.sum(same_octant & np.all(cos >= cone, axis=1)))


def test_default_cpu_variant_is_the_watertight_packet_traversal_with_the_scalar_ids(backend):
    """On a CPU the library traces with the packet traversal and the watertight test (nothing
    named: trace()'s default), and on every family of plain rays it returns, ray for ray, the
    triangle and t of the scalar kd stack and BVH traversals with the same test. The families hold
    coherent packets (traced together) and incoherent ones (ray by ray), and forcing every packet
    ray by ray (RT_PACKET_CONE above 1) changes nothing either."""
    from rtlab.device.kernels import PACKET_LANES
    from rtlab.device.tracing import default_variant, trace
    if backend.is_gpu():
        pytest.skip("the CPU default")
    chosen = default_variant(backend)
    assert (chosen.traversal, chosen.intersection) == ("bvh-packet", "watertight"), chosen
    coherent = incoherent = 0
    for family in DEFAULT_FAMILIES:
        if family in FAMILY_SCENE_FILES:
            require_scene_file(FAMILY_SCENE_FILES[family])
        for case in family_cases(family, "test"):
            got = trace(case.scene, case.origins, case.directions, backend=backend, min_stack_size=64)
            alone = trace(case.scene, case.origins, case.directions, backend=backend, min_stack_size=64,
                          defines={"RT_PACKET_CONE": 2})
            packets = _coherent_packets(case.directions, PACKET_LANES)
            coherent += packets
            incoherent += case.n_rays // PACKET_LANES - packets
            for other, (tri, t) in [("ray by ray", (alone.tri, alone.t))] + [
                    (traversal, trace_case(case, backend, "watertight", traversal)[:2]) for traversal in ("stack", "bvh")]:
                wrong = np.flatnonzero((tri != got.tri) | ((tri >= 0) & (t != got.t)))
                assert wrong.size == 0, (f"family {family} {case.label}: the default and {other} differ on {wrong.size} of "
                                         f"{case.n_rays} rays, e.g. ray {wrong[0]}: {got.tri[wrong[0]]} at "
                                         f"{got.t[wrong[0]]!r} against {tri[wrong[0]]} at {t[wrong[0]]!r}")
    assert coherent > 100 and incoherent > 100, (coherent, incoherent)


@pytest.mark.gpu
def test_gpu_closest_hit_families_on_cuda_and_nvidia_opencl():
    """On the GPU machine (fused multiply-adds, NVIDIA's 2.5-ulp reciprocal in OpenCL): families 13-15
    meet the watertight goals with every traversal on both backends, and both name the same triangles."""
    from rtlab.backends import get_backend
    require_scene_file("sponza/sponza.obj")
    backends = [get_backend("cuda"), get_backend("opencl", "NVIDIA")]
    ids = {}
    for be in backends:
        rows = run_robustness(be, ["watertight"], None, families=[13, 14, 15], size="test", isolate=())
        bad = [_describe(r) + f" -> {r.goal_violations()}" for r in rows if r.goal_violations()]
        assert not bad, "\n".join(bad)
        for family in (13, 14, 15):
            for ci, case in enumerate(family_cases(family, "test")):
                ids[be.name, family, ci] = trace_case(case, be, "watertight", "bvh")[0]
    for key in [k for k in ids if k[0] == "cuda"]:
        other = ids[("opencl",) + key[1:]]
        assert np.array_equal(ids[key], other), f"family {key[1]} case {key[2]}: {np.sum(ids[key] != other)} rays differ"
