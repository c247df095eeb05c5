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


def test_a_trees_estimate_holds_the_weight_of_every_box_its_rays_enter():
    """tile_costs over a real 4-wide tree (random triangles): each tile's estimate is at least the sum
    of the weights (a node's cost, a leaf's triangles x the triangle cost) of the boxes that some ray of
    the tile enters, by float64 brute force, and the root's children cover every tile."""
    from rtlab.accel.bvh4 import build_bvh4
    rng = np.random.default_rng(5)
    centers = rng.uniform(-1.0, 1.0, size=(60, 1, 3))
    vertices = (centers + rng.normal(scale=0.15, size=(60, 3, 3))).reshape(-1, 3).astype(np.float32)
    faces = np.arange(180, dtype=np.int32).reshape(-1, 3)
    bvh4 = build_bvh4(vertices, faces)
    camera = Camera(eye=(0.2, 0.3, 3.0), target=(0.0, 0.0, 0.0), width=32, height=24)
    boxes = tc.tile_boxes(bvh4)
    costs = tc.tile_costs(boxes, camera.basis(), 32, 24, (8, 16)).ravel()
    floor = np.zeros_like(costs)
    lo, hi, weight = boxes
    for b in np.flatnonzero(lo[:, 0] <= hi[:, 0]):
        floor[sorted(_covered_tiles(camera, lo[b], hi[b], (8, 16)))] += weight[b]
    refs = bvh4.refs()
    assert set(np.unique(weight).tolist()) <= {tc.NODE_COST, *(tc.TRI_COST * np.arange(1, 16)).tolist()}
    assert (weight == tc.NODE_COST).sum() == (refs.reshape(-1) >= 0).sum()
    assert np.all(costs >= floor - 1e-9) and floor.min() > 0


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


def test_an_uploaded_scene_keeps_its_last_orders_only(backend, monkeypatch):
    """A camera that moves every frame makes an order a frame: the scene keeps the last KEPT_ORDERS."""
    from rtlab.device import tile_orders
    from rtlab.device.device_scene import device_scene
    scene = rtlab.load_scene("default", size=16)
    monkeypatch.setattr(tracing, "orders_tiles", lambda *a: True)
    monkeypatch.setattr(tile_orders, "KEPT_ORDERS", 2)
    for step in range(4):
        camera = replace(scene.camera, eye=tuple(np.asarray(scene.camera.eye) + 0.01 * step))
        trace(scene, *camera_rays(camera), backend, Variant(traversal="bvh4"))
    kept = [k for k in device_scene(scene, backend).tile_orders if k != "boxes"]
    assert len(kept) == 2 and kept[-1][1] == tuple(float(x) for x in camera.basis()[0])
