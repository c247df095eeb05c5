"""Camera rays launched costliest tiles first (rtlab.accel.tile_costs, rtlab.device.tile_orders,
trace_ray_grid_ordered): the projected boxes against rays traced through them in float64, and the
ordered launch's hits against row order's, bit for bit."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import rtlab
from rtlab.accel import tile_costs as tc
from rtlab.device import tracing
from rtlab.device.kernels import Variant
from rtlab.device.tile_orders import orders_tiles
from rtlab.device.tracing import trace
from rtlab.scene.model import Camera, camera_rays


def _covered_tiles(camera, lo, hi, tile):
    """Float64 brute force: the tiles holding a pixel whose camera ray enters box [lo, hi] (t > 0)."""
    o, d = camera_rays(camera)
    o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - o) / d, (hi - o) / d
    near = np.nanmax(np.minimum(t0, t1), axis=1)
    far = np.nanmin(np.maximum(t0, t1), axis=1)
    hit = (near <= far) & (far > 0)
    y, x = np.divmod(np.arange(len(o)), camera.width)
    across = -(-camera.width // tile[0])
    return set(((y // tile[1]) * across + x // tile[0])[hit].tolist())


@pytest.mark.parametrize("seed", range(4))
def test_a_box_adds_its_weight_to_every_tile_whose_rays_enter_it(seed):
    """Each box's projection (clipped where it reaches behind the eye) covers every tile with a pixel
    whose ray enters the box: boxes in front, beside the camera, around the eye and behind it."""
    rng = np.random.default_rng(seed)
    camera = Camera(eye=(0.0, 0.0, 0.0), target=(0.3, -0.2, -1.0), fov_deg=50.0, width=48, height=40)
    eye, u, v, w = (np.asarray(r, np.float64) for r in camera.basis())
    tile = (8, 16)
    for _ in range(40):
        center = rng.normal(size=3) * rng.choice([0.3, 2.0, 6.0])
        size = rng.uniform(0.05, 3.0, size=3)
        lo, hi = center - size, center + size
        grid = np.zeros((-(-40 // 16) + 1, 48 // 8 + 1))
        tc._accumulate(lo[None], hi[None], np.ones(1), eye, u, v, w, 48.0, 40.0, 8.0, 16.0, grid)
        costs = grid.cumsum(0).cumsum(1)[:-1, :-1].ravel()
        expected = _covered_tiles(camera, lo, hi, tile)
        assert expected <= set(np.flatnonzero(costs == 1.0).tolist()), (lo, hi)
        assert set(np.unique(costs).tolist()) <= {0.0, 1.0}


def test_tile_costs_weigh_nodes_and_triangles():
    """A scene's estimate: every tile is covered by the root's children (cost >= one node), and the
    total is at least each leaf's triangles times the triangle cost over the tiles it covers."""
    from rtlab.accel.bvh4 import load_or_build_bvh4
    scene = rtlab.load_scene("default", size=32)
    bvh4 = load_or_build_bvh4(scene.vertices, scene.faces)[0]
    costs = tc.tile_costs(bvh4, scene.camera.basis(), 32, 32, (8, 16))
    assert costs.shape == (2, 4) and costs.min() > 0
    count = (~bvh4.refs()[bvh4.refs() < 0]) & 15
    assert costs.max() <= tc.NODE_COST * (bvh4.refs() >= 0).sum() + tc.TRI_COST * count.sum()


@pytest.mark.parametrize("size", [(64, 64), (37, 29)])
def test_the_ordered_launch_gives_row_orders_hits(backend, size, monkeypatch):
    """trace_ray_grid_ordered (forced on every backend) gives trace_ray_grid's hits bit for bit, on an
    image whose sides are not multiples of the block; the hit buffer is first filled by other rays, so
    a tile the order skipped would show."""
    scene = rtlab.load_scene("default", size=32)
    camera = replace(scene.camera, width=size[0], height=size[1])
    o, d = camera_rays(camera)
    variant = Variant(traversal="bvh4")
    rows = trace(scene, np.asarray(o), np.asarray(d), backend, variant, width=size[0])
    trace(scene, np.asarray(o)[::-1].copy(), np.asarray(d)[::-1].copy(), backend, variant)
    monkeypatch.setattr(tracing, "orders_tiles", lambda *a: True)
    ordered = trace(scene, o, d, backend, variant)
    assert ordered.tile_order is not None and ordered.tile_order.build_seconds >= 0
    assert np.array_equal(rows.tri, ordered.tri) and np.array_equal(rows.t, ordered.t)
    assert np.array_equal(rows.u, ordered.u) and np.array_equal(rows.v, ordered.v)


def test_tiles_are_ordered_only_for_the_libraries_4_wide_walk_on_a_gpu(backend):
    bvh4 = Variant(traversal="bvh4", intersection="watertight", block=(8, 16))
    assert orders_tiles(backend, bvh4, "library_trace") == backend.has_warp_votes()
    assert not orders_tiles(backend, bvh4, "00_primary")                    # the labs' kernels
    assert not orders_tiles(backend, bvh4.with_(traversal="bvh"), "library_trace")
    assert not orders_tiles(backend, bvh4.with_(count_work=True), "library_trace")


def test_camera_rays_carry_their_camera_and_the_default_takes_the_order_on_a_gpu(backend):
    scene = rtlab.load_scene("default", size=32)
    o, d = camera_rays(scene.camera)
    assert o.camera is scene.camera and d.camera is scene.camera
    assert getattr(o[::2], "camera", None) is None and getattr(o + d, "camera", None) is None
    result = trace(scene, o, d, backend)
    assert (result.tile_order is not None) == (backend.has_warp_votes() and
                                              tracing.default_variant(backend, rays=True).traversal == "bvh4")
