"""Shadow rays through light buffers (rtlab.accel.light_buffer, kernels/shared/rt_light_buffer.h):
the buffer's answer against brute force over every triangle, and the frames that take it against the
same frames through the traversal (the image to the byte)."""
from __future__ import annotations

import numpy as np
import pytest

from rtlab.accel import light_buffer
from rtlab.accel.light_buffer import build_light_buffer, cell_records, decode_refs, light_buffer_stats
from rtlab.device.light_buffers import light_buffer_defines
from rtlab.device.variants import Variant
from rtlab.device.whitted import render_whitted
from rtlab.errors import RtlabError
from rtlab.reference.whitted import shadow_segment_end
from rtlab.scene import load_scene
from rtlab.scene.materials import apply_materials
from rtlab.scene.procedural import default_scene, with_secondary_materials

from .conftest import require_scene_file

BVH = Variant(traversal="bvh")      # a traversal whose frames take light buffers on every device


def _segment_blocked(o, light, tris):
    """Brute force, float64: whether segment o -> light crosses any triangle (Moller-Trumbore, t in
    (0, shadow_segment_end): the shading's segment stops short of the light)."""
    d = light - o
    v0, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    p = np.cross(d, e2)
    det = (e1 * p).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = o - v0
        u = (s * p).sum(1) / det
        q = np.cross(s, e1)
        v = (q @ d) / det
        t = (e2 * q).sum(1) / det
    end = shadow_segment_end(light, d[None])[0]
    return bool(np.any((det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < end)))


def _distance_to_triangle(p, tri):
    """Float64 distance from point p to triangle tri (3 x 3): to its plane where p projects inside it,
    else to the nearest of its edges."""
    a, b, c = tri
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    q = p - np.dot(p - a, n) * n
    inside = all(np.dot(np.cross(v1 - v0, q - v0), n) >= 0 for v0, v1 in ((a, b), (b, c), (c, a)))
    if inside:
        return abs(np.dot(p - a, n))
    def to_segment(v0, v1):
        s = np.clip(np.dot(p - v0, v1 - v0) / np.dot(v1 - v0, v1 - v0), 0.0, 1.0)
        return np.linalg.norm(p - (v0 + s * (v1 - v0)))
    return min(to_segment(a, b), to_segment(b, c), to_segment(c, a))


def _buffer_blocked(words, o, light, tris):
    """What rt_light_buffer.h answers for the shadow ray o -> light, in float64; None: the traversal."""
    res = int(words[0])
    w = o - light
    axis = int(np.argmax(np.abs(w)))
    m = abs(w[axis])
    u, v = w[(axis + 1) % 3] / m, w[(axis + 2) % 3] / m
    cell = ((2 * axis + (w[axis] < 0)) * res + min(int((v + 1) * 0.5 * res), res - 1)) * res \
        + min(int((u + 1) * 0.5 * res), res - 1)
    first, count, blocked_bits = cell_records(words)[cell]
    blocked = np.int32(blocked_bits).view(np.float32)
    if count < 0:
        return None
    reach = np.linalg.norm(w)
    if reach > blocked:
        return True
    for tri, dist in zip(*decode_refs(words, first, count)):
        if dist > reach:
            break
        if _segment_blocked(o, light, tris[tri:tri + 1]):
            return True
    return False


def _answers_as_brute_force(words, receivers, light, tris) -> dict:
    """How often the buffer answered blocked (True), free (False) or "ask the traversal" (None) for the
    receivers' shadow rays, each answer checked against brute force."""
    answered = {True: 0, False: 0, None: 0}
    for o in receivers:
        got = _buffer_blocked(words, o, light, tris)
        answered[got] += 1
        if got is not None:
            assert got == _segment_blocked(o, light, tris), o
    return answered


def test_buffer_answers_as_brute_force():
    """Random triangles around a light; receivers anywhere and on the triangles themselves (the full
    occlusion path): the buffer answers as a test of every triangle does, for every receiver."""
    rng = np.random.default_rng(7)
    centres = rng.uniform(-4, 4, (400, 3))
    tris = centres[:, None, :] + rng.normal(0, 0.6, (400, 3, 3))
    big = np.array([[[-6, -3, -6], [6, -3, -6], [0, -3, 9]], [[-6, 3.5, -6], [0, 3.5, 9], [6, 3.5, -6]]], float)
    tris = np.concatenate([tris, big])
    vertices, faces = tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3)
    light = np.array([0.3, 0.2, -0.1])
    words = build_light_buffer(vertices, faces, light)
    stats = light_buffer_stats(words)
    bary = rng.dirichlet((1, 1, 1), 1500)
    on_tris = np.einsum("nk,nkc->nc", bary, tris[rng.integers(0, len(tris), 1500)])
    receivers = np.concatenate([rng.uniform(-8, 8, (1500, 3)), on_tris + rng.normal(0, 1e-3, on_tris.shape)])
    answered = _answers_as_brute_force(words, receivers, light, tris)
    assert answered[True] > 300 and answered[False] > 300, answered
    assert stats["cells_blocked_beyond"] > 0 and stats["resolution"] == light_buffer.RESOLUTIONS[0]


def test_a_triangle_at_the_light_blocks_no_cell_whole():
    """A wide triangle a hair from the light (within the gap that shadow segments leave before the
    light, shadow_segment_end) blocks no shadow ray; the buffer must not answer "blocked beyond" for the
    cells it covers, and answers as brute force for receivers beyond it and around it."""
    rng = np.random.default_rng(29)
    light = np.array([0.25, 0.5, -0.75])
    lid = light + np.array([[-50.0, 1e-6, -50.0], [0.0, 1e-6, 80.0], [50.0, 1e-6, -50.0]])
    others = rng.uniform(-4, 4, (200, 3))[:, None, :] + rng.normal(0, 0.5, (200, 3, 3))
    tris = np.concatenate([lid[None], others])
    words = build_light_buffer(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3), light)
    receivers = np.concatenate([light + rng.uniform(-6, 6, (1500, 3)) * [1, 0, 1] + [0, 1, 0] * rng.uniform(0.1, 6, (1500, 1)),
                                rng.uniform(-8, 8, (1500, 3))])
    answered = _answers_as_brute_force(words, receivers, light, tris)
    assert answered[False] > 1000, answered


def test_lists_are_short_and_long_ones_go_to_the_traversal():
    rng = np.random.default_rng(3)
    tris = rng.uniform(-1, 1, (3000, 3, 3)) * 0.05 + np.array([2.0, 0.0, 0.0])      # a dense clump
    words = build_light_buffer(tris.reshape(-1, 3), np.arange(9000).reshape(-1, 3), np.zeros(3))
    records = cell_records(words)
    counts = records[:, 1]
    assert counts.max() <= light_buffer.MAX_LIST and (counts < 0).any()
    # the refs: every triangle id of a list is one of the scene's, their distances never above the true
    # ones (float64) and rising along the list
    exact = np.array([_distance_to_triangle(np.zeros(3), t) for t in tris])
    for first, count, _ in records[counts > 0][::97]:
        ids, dist = decode_refs(words, first, count)
        assert (ids < len(tris)).all() and (dist <= exact[ids]).all() and (np.diff(dist) >= 0).all()
        assert (dist >= exact[ids] * (1 - 2.0 ** -10)).all()      # 12 id bits leave 12 of the mantissa
    assert build_light_buffer(tris.reshape(-1, 3), np.arange(9000).reshape(-1, 3), np.zeros(3), max_words=1000) is None


def _sponza(size):
    require_scene_file("sponza/sponza.obj")
    return apply_materials(load_scene("sponza", size=size), "paper")


@pytest.mark.parametrize("mode", [dict(bounces=3, schedule="wavefront"), dict(bounces=2),
                                  dict(shadows="two-pass"), dict(shadows="one-pass")],
                         ids=["wavefront", "tree", "two-pass", "one-pass"])
def test_frames_equal_the_traversals(backend, mode):
    for scene in (with_secondary_materials(default_scene(64)), _sponza(64)):
        buffered = render_whitted(scene, backend, BVH, **mode)
        traversed = render_whitted(scene, backend, BVH, defines={"RT_LIGHT_BUFFER": 0}, **mode)
        assert buffered.defines.get("RT_LIGHT_BUFFER") == 1 and buffered.light_buffer["lights"]
        assert "RT_LIGHT_BUFFER" not in traversed.defines or traversed.defines["RT_LIGHT_BUFFER"] == 0
        np.testing.assert_array_equal(buffered.image, traversed.image)


def test_a_light_without_a_block_takes_the_traversal(backend, monkeypatch):
    scene = _sponza(48)
    monkeypatch.setattr(light_buffer, "MAX_WORDS", 1000)
    buffered = render_whitted(scene, backend, BVH, bounces=2)
    assert buffered.defines.get("RT_LIGHT_BUFFER") == 1 and buffered.light_buffer["lights"] == []
    monkeypatch.undo()
    np.testing.assert_array_equal(buffered.image, render_whitted(scene, backend, BVH, bounces=2,
                                                                 defines={"RT_LIGHT_BUFFER": 0}).image)


def test_the_cpus_lane_traversals_keep_the_traversal(backend):
    """bvh-wide and bvh-packet (the CPU default) walk shadow rays in SIMD lanes, faster on PoCL than a
    list walked a ref at a time: their frames take no buffer, and the backend's default frame is the
    buffer's or the traversal's as its variant says."""
    for traversal in ("bvh-wide", "bvh-packet"):
        assert light_buffer_defines(Variant.paper(traversal=traversal), 1, lab=False) == {}
    frame = render_whitted(with_secondary_materials(default_scene(32)), backend, bounces=1)
    takes = not frame.variant.spec.lanes
    assert bool(frame.defines.get("RT_LIGHT_BUFFER")) == takes and (frame.light_buffer is not None) == takes


def test_the_papers_shadow_rays_keep_the_traversal(backend):
    """The labs' programs, the kd-tree variants and the texture placement trace shadow rays as the
    paper does; a light buffer asked for there is an error, not a silent mix."""
    assert light_buffer_defines(Variant.paper(traversal="bvh"), 1, lab=False) == {"RT_LIGHT_BUFFER": 1}
    assert light_buffer_defines(Variant.paper(traversal="bvh"), 0, lab=False) == {}
    assert light_buffer_defines(Variant.paper(traversal="bvh"), 1, lab=True) == {}
    assert light_buffer_defines(Variant.paper(traversal="stack"), 1, lab=False) == {}
    assert light_buffer_defines(Variant.paper(traversal="bvh", node_memory="texture"), 1, lab=False) == {}
    scene = with_secondary_materials(default_scene(32))
    lab = render_whitted(scene, backend, Variant.paper(traversal="stack"), bounces=1)
    assert lab.light_buffer is None and not lab.defines.get("RT_LIGHT_BUFFER")
    with pytest.raises(RtlabError, match="light buffers need"):
        render_whitted(scene, backend, Variant.paper(traversal="stack"), bounces=1, defines={"RT_LIGHT_BUFFER": 1})
