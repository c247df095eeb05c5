"""The ropes traversal (rt_kd_ropes.h) at cell edges and corners: the tie rule of rtlab.trace (the
closest hit; at equal t the lowest triangle id; edges inclusive) gives every traversal the same ids.

A leaf whose box the ray touches only at its exit point (entered through an edge: its entry distance
on another axis ties with the exit distance, e.g. where the ray enters the scene box through an edge
and the descent's segment starts in the box's padding) leaves through a point on an edge of its exit
face: cells across that edge hold the point but not the face's rope (flat cells on the scene box's
faces, which the rope optimisation steps past). The two rays below are such cases; the property test
walks many more on small scenes whose coordinates are multiples of 0.25, with rays through cell
edges and corners, and wants the ropes traversal's ids and t to be the kd stack traversal's.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import rtlab
from rtlab.accel.kdtree import build_kdtree
from rtlab.device.device_scene import device_scene
from rtlab.device.kernels import Variant
from rtlab.device.tracing import trace
from rtlab.reference import reference_trace

ISECTS = ["watertight", "moller"]
T_REL_TOL = 1e-6


def _scene(vertices):
    """One triangle per three vertices; the kd-tree built here (no on-disk cache)."""
    v = np.asarray(vertices, np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")       # ScaleWarning for far-off coordinates
        scene = rtlab.scene_from_arrays(v, np.arange(len(v)).reshape(-1, 3))
    return scene


def _upload(scene, backend):
    device_scene(scene, backend, tree=build_kdtree(scene.vertices, scene.faces))


def _trace(scene, o, d, backend, traversal, isect):
    return trace(scene, o, d, backend=backend, variant=Variant(traversal, isect))


# Both triangles 0 and 1 hit at exactly t = 2, where the ray enters the scene box through its edge
# x = 1, y = 1; both lie in planes through that edge (flat cells on the box's faces)
EDGE_TIE_VERTICES = [
    [1.0, 1.0, 0.75], [0.25, 1.0, 0.75], [1.0, 1.0, 0.0], [1.0, 1.0, 0.5], [1.0, 1.0, 0.0], [1.0, 0.0, 0.75],
    [1.0, 0.0, 0.25], [1.0, 1.0, 0.5], [1.0, 0.25, 0.0], [0.25, 0.25, 1.0], [0.75, 0.5, 1.0], [0.75, 0.0, 1.0],
    [0.5, 1.0, 0.0], [0.5, 0.5, 1.0], [0.5, 0.5, 0.5], [0.5, 0.75, 0.25], [1.0, 1.0, 0.25], [0.5, 0.5, 0.25],
    [0.5, 0.75, 0.25], [0.5, 0.5, 0.75], [0.5, 1.0, 0.75], [0.5, 1.0, 0.0], [1.0, 1.0, 0.25], [0.25, 1.0, 0.25]]

# Triangle 2, corners (0,0,0), (0,1,0), (0,0,0.25) on the box's face x = 0, is hit at t = 0.5 on its
# edge z = 0, where the ray enters the scene box through its edge x = 0, z = 0
EDGE_HIT_VERTICES = [
    [1.0, 0.0, 0.0], [0.5, 0.25, 0.0], [1.0, 0.5, 0.0], [0.0, 0.0, 0.0], [0.25, 0.5, 0.0], [0.25, 0.5, 0.75],
    [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.25], [1.0, 0.75, 0.25], [1.0, 0.25, 0.25], [0.75, 0.25, 0.25],
    [0.0, 0.5, 0.5], [0.0, 0.75, 0.0], [0.0, 0.5, 1.0], [1.0, 0.25, 0.25], [0.75, 0.75, 0.0], [1.0, 0.75, 0.5],
    [0.5, 0.25, 1.0], [0.5, 0.75, 1.0], [0.5, 1.0, 0.5], [0.0, 0.5, 0.75], [0.75, 0.75, 0.25], [0.5, 0.75, 0.0],
    [0.75, 0.0, 0.0], [0.5, 0.5, 0.0], [0.0, 0.5, 0.0]]

EDGE_CASES = {
    "tie-at-box-edge": (EDGE_TIE_VERTICES, 0.0, [1.5, 1.5, 0.375], [-0.25, -0.25, 1e-7], 0, 2.0),
    "edge-hit-at-box-edge": (EDGE_HIT_VERTICES, 0.0, [-0.5, 0.125, -0.5], [1.0, 0.0, 1.0], 2, 0.5),
    "edge-hit-just-inside": (EDGE_HIT_VERTICES, 0.0, [-0.5, 0.125, -0.5], [1.0, 0.0, 1.0000001], 2, 0.5),
    "edge-hit-tiny-direction": (EDGE_HIT_VERTICES, 0.0, [-0.5, 0.125, -0.5], [1e-7, 0.0, 1e-7], 2, 5e6),
    "edge-hit-far-from-origin": (EDGE_HIT_VERTICES, 1000.0, [999.5, 1000.125, 999.5], [1.0, 0.0, 1.0], 2, 0.5),
}


@pytest.mark.parametrize("isect", ISECTS)
@pytest.mark.parametrize("case", list(EDGE_CASES))
def test_ropes_hit_at_box_edge_is_the_stacks(backend, case, isect):
    """Rays entering the scene box through an edge, onto triangles in the box's faces: ropes names the
    triangle and t of the kd stack traversal and of the float64 reference."""
    vertices, shift, o, d, want_tri, want_t = EDGE_CASES[case]
    scene = _scene(np.asarray(vertices) + shift)
    _upload(scene, backend)
    o, d = np.array([o], np.float32), np.array([d], np.float32)
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    stack = _trace(scene, o, d, backend, "stack", isect)
    ropes = _trace(scene, o, d, backend, "ropes", isect)
    assert ref.tri[0] == want_tri and ref.t[0] == pytest.approx(want_t, rel=T_REL_TOL)
    assert stack.tri[0] == want_tri, f"stack: tri {stack.tri[0]} t {stack.t[0]}"
    assert (ropes.tri[0], ropes.t[0]) == (stack.tri[0], stack.t[0]), \
        f"ropes: tri {ropes.tri[0]} t {ropes.t[0]!r}; stack: tri {stack.tri[0]} t {stack.t[0]!r}"


# ------------------------------------------------------------------------------------------------
# property: random grid scenes, rays through cell edges and corners
# ------------------------------------------------------------------------------------------------
GRID = 0.25
N_SCENES, N_RAYS = 48, 512


def _grid_scene(rng, n):
    """n small triangles with corners on the grid of [0, 1]^3 (multiples of 0.25): two thirds
    axis-aligned (often on the scene box's faces: flat cells there), the rest diagonal, half of them
    in a plane x = y (or another pair of axes). Splits then lie on the grid, and the kd builder
    cuts flat cells around the axis-aligned triangles."""
    tris = []
    while len(tris) < n:
        base = rng.integers(0, 4, size=3)
        p = np.minimum(base + rng.integers(0, 3, size=(3, 3)), 4) * GRID
        kind = rng.integers(0, 3)
        if kind < 2:
            p[:, rng.integers(0, 3)] = rng.choice([0, 4, rng.integers(0, 5)]) * GRID
        elif rng.random() < 0.5:
            a, b = rng.choice(3, 2, replace=False)
            p[:, b] = p[:, a]
        if np.any(np.cross(p[1] - p[0], p[2] - p[0])):
            tris.append(p)
    return np.concatenate(tris)


def _edge_rays(rng, n):
    """Rays whose direction has equal magnitudes in two axes and a tiny or zero third component,
    from origins on the grid in those two axes (on the half grid in the third, so the ray does
    not lie in a grid plane): they pass exactly through cell edges and corners, and enter the
    scene box through its edges."""
    o = rng.integers(-2, 7, size=(n, 3)) * GRID
    d = np.empty((n, 3))
    for i in range(n):
        a, b = rng.choice(3, 2, replace=False)
        c = 3 - a - b
        o[i, c] = rng.integers(-4, 13) * GRID / 2
        d[i, a], d[i, b] = rng.choice([-1.0, 1.0], size=2)
        d[i, c] = 0.0 if rng.random() < 0.2 else rng.choice([-1.0, 1.0]) * rng.choice([1e-7, 1e-6, 0.25, 1.0])
    return o.astype(np.float32), d.astype(np.float32)


def test_ropes_ids_equal_stack_ids_through_cell_edges(backend):
    """Every ray: the ropes traversal's triangle id (and t) is the kd stack traversal's on the same
    tree and triangle test. The watertight test (RT_CONSERVATIVE): with Moller-Trumbore the stack
    traversal, whose segments run on through the scene box's padding, also takes Moller's false
    hits a hair outside the box that the ropes traversal, leaving by the leaves' own boxes, never
    tests (the float64 reference misses those rays too)."""
    bad = []
    for seed in range(N_SCENES):
        rng = np.random.default_rng(seed)
        scene = _scene(_grid_scene(rng, int(rng.integers(6, 20))))
        _upload(scene, backend)
        o, d = _edge_rays(rng, N_RAYS)
        stack = _trace(scene, o, d, backend, "stack", "watertight")
        ropes = _trace(scene, o, d, backend, "ropes", "watertight")
        differ = np.flatnonzero((ropes.tri != stack.tri) | ((stack.tri >= 0) & (ropes.t != stack.t)))
        bad += [f"scene {seed} o={o[i].tolist()} d={d[i].tolist()}: ropes tri {ropes.tri[i]} t {ropes.t[i]}, "
                f"stack tri {stack.tri[i]} t {stack.t[i]}" for i in differ]
    assert not bad, f"{len(bad)} of {N_SCENES * N_RAYS} rays differ, e.g.\n" + "\n".join(bad[:5])
