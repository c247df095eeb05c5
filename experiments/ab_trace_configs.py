"""A/B of trace() configurations on the benchmark rays, alternating round by round on the same rays
(drift hits every configuration alike), with the error column and the ratio to the best peer.

    python experiments/ab_trace_configs.py --backend cuda --kinds primary,diffuse --size 1024 \
        --configs "bvh;bvh,call;bvh,r64;bvh,call,r64;bvh4,call" [--views ...] [--rounds 5] [--repeats 5]

A configuration is a traversal, then any of: ``call`` (RT_REFINE_CALL=1: the refined t a call, not
inlined), ``woop`` (RT_REFINE_T=0: Woop's t, to bound what the refinement costs), ``rNN`` (a cap of NN
registers), ``bWxH`` (block), ``carveN`` (CUDA: N % of L1 preferred as shared memory, -1 the
driver's choice), ``l2keepN`` (CUDA: N MiB of L2 set aside for persisting lines while the
configuration runs, l2_set_aside: what the launch loses with that much less L2 for normal lines),
``tex`` (the tree and triangles read through textures: node_memory "texture"), ``nofetch`` (trace_rays,
not trace_rays_fetch, for rays in no image order),
``sortK`` (the rays permuted on the host before trace(), hits mapped back; K: ``oct``, stable by
direction octant; ``morton``, by octant then the origin's Morton code; ``dir``, by octant then the
direction's quantised spherical angles; ``originB``, by the origin's Morton code alone on 2^B cells an
axis (B = 10 where not given); ``tileWxH``, camera rays tile by tile, so trace() takes them
as a list (trace_rays_fetch) in tiles; ``heavyP``, 8x4 tiles with the costliest P % first (heavy_first):
what ordering could gain, the sort itself not timed; ``probeP``, the same ranked by one probe ray a tile;
``odP``, ranked by the library's estimate from the camera and the BVH, overdraw_first; ``wheavyP``
and ``wproxyP``, diffuse rays in warps of 32 with P % of the warps first, ranked by the host mirror's
cost or by a grid estimate, warps_first),
``noorder`` (camera rays as plain arrays: row order, no tile order, rtlab.device.tile_orders),
``tree=DIR`` (the kernel sources of DIR, or of DIR/kernels: another commit's tree timed against
the project's on the same rays), ``D=V`` (any -D). Time: median over the rounds of each round's best of
--repeats launches. Primary rays go in tiles (trace(width=)), as the bench's do.
"""
from __future__ import annotations

import argparse
import contextlib
from pathlib import Path
from unittest import mock

import numpy as np

from rtlab.backends import get_backend
from rtlab.benches.rays import make_rays, peer_figures
from rtlab.device import tracing
from rtlab.device.tracing import default_variant, trace
from rtlab.paths import use_kernel_dir
from rtlab.reference import compare_hits


def parse_config(text: str, base):
    parts = [p.strip() for p in text.split(",") if p.strip()]
    variant, defines = base.with_(traversal=parts[0]), {}
    for p in parts[1:]:
        if p == "call":
            defines["RT_REFINE_CALL"] = 1
        elif p == "woop":
            defines["RT_REFINE_T"] = 0
        elif p.startswith("r") and p[1:].isdigit():
            variant = variant.with_(max_registers=int(p[1:]))
        elif p.startswith("b") and "x" in p:
            w, h = p[1:].split("x")
            variant = variant.with_(block=(int(w), int(h)))
        elif p == "tex":
            variant = variant.with_(node_memory="texture")
        elif p == "nofetch":
            defines["nofetch"] = 1
        elif p == "noorder":
            defines["noorder"] = 1
        elif p in ("sortoct", "sortmorton", "sortdir") or p.startswith(("sortorigin", "sorttile", "sortheavy", "sortprobe", "sortod", "sortwheavy", "sortwproxy")):
            defines["sort"] = p[4:]
        elif p.startswith("tree="):
            defines["tree"] = p[5:]
        elif p.startswith("carve") and p[5:].lstrip("-").isdigit():
            defines["carveout"] = int(p[5:])
        elif p.startswith("l2keep") and p[6:].isdigit():
            defines["l2keep"] = int(p[6:])
        elif "=" in p:
            k, v = p.split("=")
            defines[k] = int(v)
        else:
            raise SystemExit(f"unknown configuration part {p!r}")
    return variant, defines


def print_row(batch, best: dict, last: dict, peer: float | None) -> None:
    """One table row: each configuration's Mrays/s (median of its rounds' best launches; the ratio to
    the best peer beside it) and the mismatches of its last run against the float64 reference."""
    cells, errors = [], []
    for c in best:
        mrays = len(batch.origins) / (float(np.median(best[c])) * 1e-3) / 1e6
        cells.append(f"{mrays:,.0f}" + (f" ({mrays / peer:.2f}x)" if peer else ""))
        idx = batch.check_index
        cmp_ = compare_hits(batch.reference, last[c].tri[idx], last[c].t[idx], batch.scene.vertices,
                            batch.scene.faces, batch.origins[idx], batch.directions[idx])
        if cmp_.n_mismatch:
            errors.append(f"{c}: {cmp_.n_mismatch} mism.")
    print(f"| {batch.view} | {batch.kind} | " + " | ".join(cells) + f" | {'; '.join(errors) or '0 mism.'} |",
          flush=True)


def morton3(q: np.ndarray) -> np.ndarray:
    """Morton codes of (n, 3) integer coordinates in [0, 1024)."""
    def spread(v):
        v = v.astype(np.uint64) & 0x3FF
        v = (v | (v << 16)) & 0x030000FF
        v = (v | (v << 8)) & 0x0300F00F
        v = (v | (v << 4)) & 0x030C30C3
        return (v | (v << 2)) & 0x09249249
    return spread(q[:, 0]) << 2 | spread(q[:, 1]) << 1 | spread(q[:, 2])


def tile_order(width: int, height: int, tw: int, th: int) -> np.ndarray:
    """The pixels of a width x height image, row-major, permuted tile by tile: tiles of tw x th in
    row-major order, each tile's pixels row-major (32 consecutive rays an 8x4 tile: a warp's)."""
    y, x = np.divmod(np.arange(width * height), width)
    tiles_x = -(-width // tw)
    key = ((y // th) * tiles_x + x // tw) * (tw * th) + (y % th) * tw + x % tw
    return np.argsort(key, kind="stable")


HEAVY_SCENE = {}     # the batch's scene, set by main for heavy_first


def heavy_first(percent: float, origins, directions, probe: bool = False) -> np.ndarray:
    """Camera rays in 8x4 tiles (tile_order), the costliest ``percent`` % of the tiles first (costliest
    first), the rest in row order: an oracle of what starting the slow tiles first could gain. A tile's
    cost: its costliest ray's node visits x 121 + triangle tests x 75 (the 4-wide walk on the host);
    with ``probe`` the cost of one ray of it (row 2, column 4), as a probe launch would see it."""
    from rtlab.accel.bvh4 import load_or_build_bvh4
    from rtlab.accel.bvh_wide_stats import traversal_counts_bvh4
    scene = HEAVY_SCENE["scene"]
    side = int(round(len(origins) ** 0.5))
    order = tile_order(side, side, 8, 4)
    b, _ = load_or_build_bvh4(scene.vertices, scene.faces)
    nodes, _, tris = traversal_counts_bvh4(b, scene.vertices, scene.faces, origins, directions)[:3]
    ray_cost = (np.asarray(nodes) * 121 + np.asarray(tris) * 75)[order].reshape(-1, 32)
    tile_cost = ray_cost[:, 20] if probe else ray_cost.max(axis=1)   # probe: one ray, row 2 column 4
    k = int(round(len(tile_cost) * percent / 100))
    heavy = np.argsort(-tile_cost, kind="stable")[:k]
    rest = np.setdiff1d(np.arange(len(tile_cost)), heavy)       # ascending: row order
    tiles = np.concatenate([heavy, rest])
    return order.reshape(-1, 32)[tiles].ravel()


def overdraw_first(percent: float, origins) -> np.ndarray:
    """heavy_first's order with each 8x4 tile ranked by the library's estimate, known before any ray is
    traced (rtlab.accel.tile_costs: the 4-wide BVH's boxes projected with the view's camera)."""
    from rtlab.accel.bvh4 import load_or_build_bvh4
    from rtlab.accel.tile_costs import tile_boxes, tile_costs
    scene = HEAVY_SCENE["scene"]
    side = int(round(len(origins) ** 0.5))
    order = tile_order(side, side, 8, 4)
    boxes = tile_boxes(load_or_build_bvh4(scene.vertices, scene.faces)[0])
    tile_cost = tile_costs(boxes, scene.camera.basis(), side, side, (8, 4)).ravel()
    k = int(round(len(tile_cost) * percent / 100))
    heavy = np.argsort(-tile_cost, kind="stable")[:k]
    rest = np.setdiff1d(np.arange(len(tile_cost)), heavy)
    return order.reshape(-1, 32)[np.concatenate([heavy, rest])].ravel()


def ray_order(kind: str, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """A permutation of the rays: stable by direction octant, then (morton) the origin's Morton code or
    (dir) the direction's quantised angles; ``tileWxH``: camera rays (a square image) tile by tile."""
    if kind.startswith("tile"):
        side = int(round(len(origins) ** 0.5))
        tw, th = (int(v) for v in kind[4:].split("x"))
        return tile_order(side, side, tw, th)
    if kind.startswith("heavy"):
        return heavy_first(float(kind[5:]), origins, directions)
    if kind.startswith("probe"):
        return heavy_first(float(kind[5:]), origins, directions, probe=True)
    if kind.startswith("od"):
        return overdraw_first(float(kind[2:]), origins)
    if kind.startswith("wheavy") or kind.startswith("wproxy"):
        return warps_first(kind[:6], float(kind[6:]), origins, directions)
    if kind.startswith("origin"):
        return origin_order(origins, int(kind[6:] or 10))
    d = np.asarray(directions, np.float64)
    octant = ((d[:, 0] < 0) * 4 + (d[:, 1] < 0) * 2 + (d[:, 2] < 0)).astype(np.uint64)
    if kind == "oct":
        return np.argsort(octant, kind="stable")
    if kind == "morton":
        return np.argsort(octant << 30 | origin_morton(origins, 10), kind="stable")
    theta = np.arccos(np.clip(d[:, 2], -1, 1)) / np.pi
    phi = (np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi)) % 1.0
    key = (theta * 1023).astype(np.uint64) << 10 | (phi * 1023).astype(np.uint64)
    return np.argsort(octant << 20 | key, kind="stable")


def origin_morton(origins: np.ndarray, bits: int) -> np.ndarray:
    """Morton codes of the origins on a grid of 2^bits cells an axis over their box (bits <= 10)."""
    if not 1 <= bits <= 10:
        raise SystemExit(f"origin grid of 2^{bits} cells an axis: 1 to 10 bits")
    o = np.asarray(origins, np.float64)
    lo, hi = o.min(0), o.max(0)
    q = ((o - lo) / np.maximum(hi - lo, 1e-30) * ((1 << bits) - 1)).astype(np.int64)
    return morton3(q)


def origin_order(origins: np.ndarray, bits: int) -> np.ndarray:
    """Stable by the Morton code of the origin alone (directions left as they are): rays from one patch
    of surface together, the given order kept inside a cell."""
    return np.argsort(origin_morton(origins, bits), kind="stable")


def warps_first(rank: str, percent: float, origins, directions) -> np.ndarray:
    """Rays in no image order (diffuse) in groups of 32 as given, the ``percent`` % of the groups ranked
    first moved to the front (ranked order), the rest as given: ``wheavy`` ranks a group by its costliest
    ray on the host mirror of the 4-wide walk (an oracle: what starting the costliest rays first could
    gain against the ray fetch's tail), ``wproxy`` by the triangles in the grid cells along its rays
    (experiments/diffuse_cost_proxies.py: an estimate a device could make before the walk)."""
    from diffuse_cost_proxies import NODE_INSTR, TRI_INSTR, WARP, proxies
    from rtlab.accel.bvh4 import load_or_build_bvh4
    from rtlab.accel.bvh_wide_stats import traversal_counts_bvh4
    scene = HEAVY_SCENE["scene"]
    o, d = np.asarray(origins, np.float64), np.asarray(directions, np.float64)
    if rank == "wheavy":
        b, _ = load_or_build_bvh4(scene.vertices, scene.faces)
        nodes, _, tris = traversal_counts_bvh4(b, scene.vertices, scene.faces, o, d)[:3]
        ray_key = NODE_INSTR * np.asarray(nodes, np.float64) + TRI_INSTR * np.asarray(tris, np.float64)
    else:
        ray_key = proxies(scene, o, d)["triangles along ray"]
    n = len(o)
    groups = -(-n // WARP)
    key = np.zeros(groups * WARP)
    key[:n] = ray_key
    key = key.reshape(groups, WARP).max(1) if rank == "wheavy" else key.reshape(groups, WARP).sum(1)
    heavy = np.argsort(-key, kind="stable")[:int(round(groups * percent / 100))]
    order = np.concatenate([heavy, np.setdiff1d(np.arange(groups), heavy)])
    rays = (order[:, None] * WARP + np.arange(WARP)).ravel()
    return rays[rays < n]


class Unpermuted:
    """A trace result's hits back in the rays' own order."""
    def __init__(self, r, perm):
        self.tri = np.empty_like(r.tri)
        self.t = np.empty_like(r.t)
        self.tri[perm] = r.tri
        self.t[perm] = r.t


@contextlib.contextmanager
def kernel_tree(root: str | None):
    """Compile from the kernel sources at ``root`` (another commit's kernels/, e.g. from `git archive
    COMMIT kernels | tar -x -C DIR`) inside, from the project's outside; None: the project's."""
    if root is None:
        yield
        return
    previous = use_kernel_dir(Path(root) / "kernels" if (Path(root) / "kernels").is_dir() else root)
    try:
        yield
    finally:
        use_kernel_dir(previous)


def carveout(backend, percent: int):
    """CUDA only: every kernel launched inside prefers ``percent`` of the SM's L1/shared memory as
    shared memory (CU_FUNC_ATTRIBUTE_PREFERRED_SHARED_MEMORY_CARVEOUT; -1 the driver's choice, 0 the
    most L1)."""
    if backend.name != "cuda":
        return mock.patch.dict({})
    from rtlab.backends.cuda import CudaProgram
    prepared = CudaProgram.prepared

    def with_carveout(self, kernel, args):
        f = prepared(self, kernel, args)
        f.set_attribute(self.backend.drv.function_attribute.PREFERRED_SHARED_MEMORY_CARVEOUT, percent)
        return f
    return mock.patch.object(CudaProgram, "prepared", with_carveout)


@contextlib.contextmanager
def l2_set_aside(backend, mib: int):
    """CUDA only: ``mib`` MiB of L2 set aside for persisting lines (CU_LIMIT_PERSISTING_L2_CACHE_SIZE,
    capped at the device's maximum) while the block runs: lines a kernel marks persisting (an L2
    evict_last policy, experiments/prototypes/cache_hints.patch) stay there, and the other lines have
    that much less L2. Afterwards every persisting line is made normal again and the set-aside is none.
    pycuda's `limit` has no such member and it wraps no cuCtxResetPersistingL2Cache, so both go
    through the driver library. 0: nothing set."""
    if backend.name != "cuda" or not mib:
        yield
        return
    import ctypes
    drv = backend.drv
    most = backend.cuda_device.get_attribute(drv.device_attribute.MAX_PERSISTING_L2_CACHE_SIZE)
    size = min(mib << 20, most)
    cuda = ctypes.CDLL("libcuda.so.1")
    persisting_l2 = 6                                  # CU_LIMIT_PERSISTING_L2_CACHE_SIZE (cuda.h)
    if cuda.cuCtxSetLimit(persisting_l2, ctypes.c_size_t(size)) != 0:
        raise SystemExit(f"cuCtxSetLimit(CU_LIMIT_PERSISTING_L2_CACHE_SIZE, {size}) failed")
    if size not in L2_SET_ASIDE:
        L2_SET_ASIDE.add(size)
        print(f"L2 set aside for persisting lines: {size / 2**20:.1f} MiB (the device allows "
              f"{most / 2**20:.1f})", flush=True)
    try:
        yield
    finally:
        if cuda.cuCtxResetPersistingL2Cache() != 0 or cuda.cuCtxSetLimit(persisting_l2, ctypes.c_size_t(0)) != 0:
            raise SystemExit("cuCtxResetPersistingL2Cache or the set-aside's reset failed: the L2 stays split")


L2_SET_ASIDE: set = set()    # sizes already reported


def ab_arguments(description: str, configs: str, rounds: int) -> argparse.ArgumentParser:
    """The options every A/B tool here takes (each adds its own)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--backend", default="cuda")
    ap.add_argument("--device", default=None)
    ap.add_argument("--views", default="bunny/far,bunny/fill,dragon/fill,sponza/inside,kitchen/inside,conference/inside")
    ap.add_argument("--kinds", default="primary,diffuse")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--configs", default=configs)
    ap.add_argument("--rounds", type=int, default=rounds)
    ap.add_argument("--repeats", type=int, default=5)
    return ap


def ab_batches(a, backend, label: str, names: list[str]):
    """Print the table's head, then yield the benchmark rays of each view and kind asked for (diffuse
    rays need hits: none for bunny/far)."""
    print(f"device: {backend.name}: {backend.device_name}; {label}; {a.rounds} rounds x best of {a.repeats}")
    print("| view | kind | " + " | ".join(names) + " | errors |")
    print("|---|---|" + "---:|" * len(names) + "---|")
    for kind in a.kinds.split(","):
        for view in a.views.split(","):
            if kind == "diffuse" and view == "bunny/far":
                continue
            yield make_rays(view, kind, a.size)


def main(argv=None) -> None:
    ap = ab_arguments(__doc__.split("\n")[0], "bvh", 5)
    ap.add_argument("--rows", action="store_true", help="primary rays as plain rows (no width=): trace()'s list path")
    a = ap.parse_args(argv)
    backend = get_backend(a.backend, a.device)
    base = default_variant(backend)
    configs = [(c, *parse_config(c, base)) for c in a.configs.split(";")]
    peers = peer_figures()
    for batch in ab_batches(a, backend, f"base variant {base.label()}", [c for c, _, _ in configs]):
        width = batch.size if batch.kind == "primary" else None
        best = {c: [] for c, _, _ in configs}
        last = {}
        HEAVY_SCENE["scene"] = batch.scene
        perms = {c: ray_order(d["sort"], batch.origins, batch.directions) for c, _, d in configs if "sort" in d}
        for _ in range(a.rounds):
            for c, variant, defines in configs:
                d = {k: v for k, v in defines.items() if k not in ("nofetch", "carveout", "sort", "noorder", "tree", "l2keep")}
                perm = perms.get(c)
                o, dirs = (batch.origins, batch.directions) if perm is None else \
                    (np.ascontiguousarray(batch.origins[perm]), np.ascontiguousarray(batch.directions[perm]))
                if "noorder" in defines:            # plain arrays: no camera, so row order
                    o, dirs = np.asarray(o).view(np.ndarray), np.asarray(dirs).view(np.ndarray)
                with mock.patch.object(tracing, "fetches_rays", (lambda *_: False) if "nofetch" in defines
                                       else tracing.fetches_rays), \
                        carveout(backend, defines.get("carveout", -1)), kernel_tree(defines.get("tree")), \
                        l2_set_aside(backend, defines.get("l2keep", 0)):
                    r = trace(batch.scene, o, dirs, backend, variant, repeats=a.repeats, warmup=1,
                              width=None if (a.rows or perm is not None) else width, defines=d)
                best[c].append(min(r.launches_ms))
                last[c] = r if perm is None else Unpermuted(r, perm)
        print_row(batch, best, last, peers.get((batch.view, batch.kind, a.size), {}).get("best"))


if __name__ == "__main__":
    main()
