"""Camera rays launched costliest tiles first (trace_ray_grid_ordered, kernels/shared/rt_entry_ray_grid.h).

A launch of camera rays in tiles runs about eight waves of blocks, and it lasts at least as long as
its costliest tile takes from whenever that tile starts. In row order the costly tiles (a stool's
rings, a dragon's head) start wherever they sit in the image, and the SMs idle behind them at the
end. Launched first, they overlap the cheap ones (docs/results.md, "Camera rays, costliest tiles
first"). The order comes from the camera and the 4-wide BVH alone (rtlab.accel.tile_costs: the
boxes projected onto the tiles), before any ray is traced: it is built once per uploaded scene,
camera, image size and block, and kept with the uploaded scene (the last KEPT_ORDERS of them), as
light buffers are. The hits are
the same in any order. Where the costs are nearly even (SPONZA's inside view) the order neither gains
nor loses (docs/results.md), so every such launch takes it.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..accel.bvh4 import load_or_build_bvh4
from ..accel.tile_costs import tile_boxes, tile_costs

KEPT_ORDERS = 8         # orders kept with an uploaded scene: a camera that moves every frame makes one a frame

@dataclass
class TileOrder:
    """A launch's tile order: ``tiles`` (a device buffer of int32 pairs, each tile's column and row in
    blocks, costliest first), the estimate's spread (coefficient of variation of the tiles' costs) and
    what building it took."""
    tiles: object
    spread: float
    build_seconds: float

    def summary(self) -> str:
        return f"tiles costliest first: cost spread {self.spread:.2f}, ordered in {self.build_seconds * 1e3:.0f} ms"


def orders_tiles(backend, variant, program_name: str) -> bool:
    """Whether trace() launches camera rays with their camera's tile order: the library's program on a
    GPU (warps; a CPU runs work-groups as they come), with the 4-wide BVH the estimate reads."""
    return (program_name == "library_trace" and variant.traversal == "bvh4" and not variant.count_work
            and backend.has_warp_votes())


def tile_order(ds, camera, width: int, height: int, block: tuple[int, int]) -> TileOrder:
    """The tile order of ``camera``'s width x height rays in ``block`` tiles, kept with the uploaded scene."""
    eye, u, v, w = (tuple(float(x) for x in row) for row in camera.basis())
    key = ("order", eye, u, v, w, int(width), int(height), tuple(block))
    made = ds.tile_orders.get(key)
    if made is None:
        start = time.perf_counter()
        boxes = ds.tile_orders.get("boxes")
        if boxes is None:
            boxes = ds.tile_orders["boxes"] = tile_boxes(load_or_build_bvh4(ds.scene.vertices, ds.scene.faces)[0])
        orders = [k for k in ds.tile_orders if k != "boxes"]
        for old in orders[:max(0, len(orders) - KEPT_ORDERS + 1)]:      # oldest first (dicts keep insertion order)
            del ds.tile_orders[old]
        costs = tile_costs(boxes, camera.basis(), width, height, block)
        mean = costs.mean()
        spread = float(costs.std() / mean) if mean > 0 else 0.0
        rows, cols = np.divmod(np.argsort(-costs.ravel(), kind="stable"), costs.shape[1])
        tiles = ds.backend.to_device(np.stack([cols, rows], 1).astype(np.int32))
        made = ds.tile_orders[key] = TileOrder(tiles, spread, time.perf_counter() - start)
    return made
