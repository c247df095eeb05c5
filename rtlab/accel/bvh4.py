"""A 4-wide BVH with float child boxes for the GPU traversal of kernels/shared/rt_bvh4.h.

Built as rtlab.accel.bvh8 builds its tree, with 4 slots a node: the binary SAH trees of
rtlab.accel.bvh (plain and spatial-split, from their disk cache) refined to one triangle a leaf, then
collapsed by Ylitie, Karras & Laine's dynamic programme (HPG 2017, §3.1) with leaves of up to
``leaf_max`` triangles; the spatial-split tree kept where its cost is SPLIT_MIN_GAIN lower. Child
boxes stay float32 (exact), so the traversal's box test is rt_bvh.h's fused one; triangles in leaf
order after the nodes, as in the BVH8 (the scene's own vertex floats, the id in the first row's w).

Device layout (sync with rt_bvh4.h), node_data float4 rows; node at rows r .. r + 6 = 112 B:
  r + 0 .. r + 5  lo.x, hi.x, lo.y, hi.y, lo.z, hi.z of the four children (one float4 a plane)
  r + 6           child refs (int32 bits): >= 0 the row of an inner node; a leaf is
                  ~((first triangle row << LEAF_BITS) | count); an empty slot has the box
                  (+inf, -inf) and ref ~0
Triangles: three rows each, (v0.xyz, id bits), (v1.xyz, 0), (v2.xyz, 0). The root is row 0.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import paths
from ..errors import RtlabError, SceneError
from ..kernel_constants import kernel_constant
from .bvh import LEAF_BITS as BIN_LEAF_BITS, MAX_LEAF as BIN_MAX_LEAF, Bvh, _usable_boxes, load_or_build_bvh
from .bvh8 import PLAIN_BUILD, SPLIT_BUILD, SPLIT_MIN_GAIN, TRI_ROWS, _collapse_costs, _full_tree, _half_area, _wide_nodes
from .cache import atomic_savez, cache_key, load_or_build

FORMAT_VERSION = "bvh4f-v1"
WIDTH = 4
NODE_ROWS = int(kernel_constant("BVH4_NODE_ROWS"))
LEAF_BITS = int(kernel_constant("BVH4_LEAF_BITS"))
MAX_COORD = 1e18                 # rt_bvh.h's fused box test stays finite below this (FUSED_BOX_MAX_COORD)
MAX_ROW = (1 << (31 - LEAF_BITS)) - 2   # a leaf ref addresses rows below this (BVH4_NONE is the next)


@dataclass(frozen=True)
class Bvh4BuildParams:
    """Collapse costs (a 4-wide node test costs about one triangle test: cost_prim 0.8), leaves of up
    to ``leaf_max`` triangles (<= 15), and which binary tree: "auto", "plain" or "split"."""
    cost_node: float = 1.0
    cost_prim: float = 0.8
    leaf_max: int = 8
    binary: str = "auto"

    def __post_init__(self):
        if self.binary not in ("auto", "plain", "split"):
            raise RtlabError(f"Bvh4BuildParams.binary must be 'auto', 'plain' or 'split', got {self.binary!r}")
        if not 1 <= self.leaf_max <= (1 << LEAF_BITS) - 1:
            raise RtlabError(f"BVH4 leaf_max must be 1..{(1 << LEAF_BITS) - 1}, got {self.leaf_max}")
        if not (self.cost_node > 0.0 and self.cost_prim > 0.0):
            raise RtlabError(f"BVH4 costs must be positive, got {self.cost_node}, {self.cost_prim}")

    def key(self) -> str:
        return (f"{FORMAT_VERSION}-cn{self.cost_node}-cp{self.cost_prim}-lm{self.leaf_max}-{self.binary}-"
                f"{PLAIN_BUILD.key()}-{SPLIT_BUILD.key()}")


@dataclass
class Bvh4:
    rows: np.ndarray         # (R, 4) float32: nodes, then triangles
    n_nodes: int
    tri_ids: np.ndarray      # (T,) int32 triangle ids in leaf order
    bounds: np.ndarray       # (2, 3) float32 root box
    depth: int               # nodes on the longest root-to-leaf path
    cost: float
    binary: str
    params: Bvh4BuildParams
    build_seconds: float = 0.0

    @property
    def tri_row0(self) -> int:
        return NODE_ROWS * self.n_nodes

    def planes(self) -> np.ndarray:
        """(M, 6, 4) float32: lo.x, hi.x, lo.y, hi.y, lo.z, hi.z of each node's four slots."""
        return self.rows[:self.tri_row0].reshape(self.n_nodes, NODE_ROWS, 4)[:, :6]

    def refs(self) -> np.ndarray:
        """(M, 4) int32 child refs."""
        return self.rows[:self.tri_row0].reshape(self.n_nodes, NODE_ROWS, 4)[:, 6].view(np.int32)


def decode_leaf(ref: int) -> tuple[int, int]:
    """(first triangle row, count) of a leaf ref."""
    bits = ~int(ref)
    return bits >> LEAF_BITS, bits & ((1 << LEAF_BITS) - 1)


def collapse4(bvh: Bvh, vertices, faces, params: Bvh4BuildParams = Bvh4BuildParams()):
    """(wide-tree arrays of rtlab.accel.bvh8._wide_nodes with 4 slots, cost)."""
    vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    tri_lo, tri_hi, _ = _usable_boxes(vertices, faces)
    lo, hi, left, right, tri, count = _full_tree(bvh.child_lo, bvh.child_hi, bvh.child_ref.astype(np.int64),
                                                 np.asarray(bvh.objects, np.int64), tri_lo, tri_hi, BIN_LEAF_BITS,
                                                 BIN_MAX_LEAF)
    cost, leaf, split, inner_k = _collapse_costs(lo, hi, left, right, count, float(params.cost_node),
                                                 float(params.cost_prim), int(params.leaf_max), WIDTH)
    wide = _wide_nodes(lo, hi, left, right, tri, count, leaf, split, inner_k, WIDTH, int(count[0]) + 1)
    area = _half_area(lo[0].astype(np.float64), hi[0].astype(np.float64))
    if left[0] < 0:
        root = float(cost[0, 1])
    else:
        k = int(inner_k[0])
        root = area * params.cost_node + float(cost[left[0], k] + cost[right[0], WIDTH - k])
    return wide, (root / area if area > 0 else 0.0)


def _pack(vertices, faces, wide) -> tuple[np.ndarray, int, np.ndarray]:
    (n_lo, n_hi, kind, c_lo, c_hi, c_node, c_count, c_offset, child_base, tri_base, tris, _) = wide
    m = len(n_lo)
    tri_row0 = NODE_ROWS * m
    n_rows = tri_row0 + TRI_ROWS * len(tris)
    if n_rows > MAX_ROW:
        raise SceneError(f"BVH4: {n_rows:,} rows, more than a leaf ref addresses ({MAX_ROW:,})")
    rows = np.zeros((n_rows, 4), np.float32)
    nodes = rows[:tri_row0].reshape(m, NODE_ROWS, 4)
    valid = kind > 0
    for a in range(3):
        nodes[:, 2 * a, :] = np.where(valid, c_lo[:, :, a], np.float32(np.inf))
        nodes[:, 2 * a + 1, :] = np.where(valid, c_hi[:, :, a], np.float32(-np.inf))
    first = tri_row0 + TRI_ROWS * (tri_base[:, None] + c_offset)
    refs = np.where(kind == 1, NODE_ROWS * c_node, ~((first << LEAF_BITS) | c_count))
    refs = np.where(valid, refs, ~0)
    nodes.view(np.int32)[:, 6, :] = refs.astype(np.int32)
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)[tris]
    t = rows[tri_row0:].reshape(len(tris), TRI_ROWS, 4)
    for k in range(3):
        t[:, k, :3] = v[f[:, k]]
    t.view(np.int32)[:, 0, 3] = tris.astype(np.int32)
    return rows, m, tris.astype(np.int32)


def build_bvh4(vertices: np.ndarray, faces: np.ndarray, params: Bvh4BuildParams = Bvh4BuildParams(),
               cache_dir=None) -> Bvh4:
    """The 4-wide BVH of a mesh (module docstring), from the binary trees in the disk cache."""
    t0 = time.perf_counter()
    vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    candidates = []
    for name, bparams in (("plain", PLAIN_BUILD), ("split", SPLIT_BUILD)):
        if params.binary in ("auto", name):
            binary, _ = load_or_build_bvh(vertices, faces, bparams, cache_dir)
            candidates.append((name, binary) + collapse4(binary, vertices, faces, params))
    if len(candidates) == 2 and not candidates[1][3] <= (1.0 - SPLIT_MIN_GAIN) * candidates[0][3]:
        candidates = candidates[:1]
    name, binary, wide, cost = candidates[-1]
    used = wide[-2]
    if len(used) and np.abs(vertices[faces[used]]).max() > MAX_COORD:
        raise SceneError("BVH4: coordinates beyond 1e18, where its fused box test could overflow: use the bvh "
                         "traversal")
    rows, n_nodes, tri_ids = _pack(vertices, faces, wide)
    return Bvh4(rows, n_nodes, tri_ids, binary.bounds.astype(np.float32), int(wide[-1]), float(cost), name, params,
                time.perf_counter() - t0)


def _save(path: Path, b: Bvh4) -> None:
    atomic_savez(path, rows=b.rows, n_nodes=np.int64(b.n_nodes), tri_ids=b.tri_ids, bounds=b.bounds,
                 depth=np.int64(b.depth), cost=np.float64(b.cost), binary=np.str_(b.binary),
                 build_seconds=np.float64(b.build_seconds), format=np.str_(FORMAT_VERSION))


def _load(path: Path, params: Bvh4BuildParams) -> Bvh4:
    with np.load(path, allow_pickle=False) as z:
        if str(z["format"]) != FORMAT_VERSION:
            raise ValueError(f"{path.name}: format {z['format']}, expected {FORMAT_VERSION}")
        rows, n_nodes, tri_ids = z["rows"], int(z["n_nodes"]), z["tri_ids"]
        if (rows.dtype != np.float32 or rows.ndim != 2 or rows.shape[1] != 4 or tri_ids.dtype != np.int32
                or rows.shape[0] != NODE_ROWS * n_nodes + TRI_ROWS * len(tri_ids)):
            raise ValueError(f"{path.name}: unexpected array shapes or types")
        return Bvh4(rows, n_nodes, tri_ids, z["bounds"], int(z["depth"]), float(z["cost"]), str(z["binary"]), params,
                    float(z["build_seconds"]))


def load_or_build_bvh4(vertices: np.ndarray, faces: np.ndarray, params: Bvh4BuildParams = Bvh4BuildParams(),
                       cache_dir: str | os.PathLike | None = None) -> tuple[Bvh4, bool]:
    """The mesh's BVH4 from the on-disk cache, else built and stored. Returns (bvh4, from_cache)."""
    if not paths.cache_enabled():
        return build_bvh4(vertices, faces, params, cache_dir), False
    directory = Path(cache_dir) if cache_dir is not None else paths.accel_cache_dir()
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{cache_key(vertices, faces, params, FORMAT_VERSION)}.npz"
    return load_or_build(path, lambda p: _load(p, params), lambda: build_bvh4(vertices, faces, params, cache_dir),
                         _save, "BVH4")


# ---- host mirror of the traversal: counts and hits (tests, benchmarks/bench_wide_bvh_quality.py) -------
from numba import njit  # noqa: E402

from .bvh_stats import _clip, _moller  # noqa: E402


@njit(cache=True)
def _count_bvh4(planes, refs, tri_rows_ids, tri_row0, vertices, faces, scene_lo, scene_hi, depth, origins,
                directions, tmin, node_rows, tri_rows, leaf_bits):
    """Per ray: (nodes visited, child boxes tested (non-empty slots), triangle tests, closest triangle
    or -1, its t), in rt_bvh4.h's order (nearest child first, the others pushed farthest first with
    their entry distances, popped ones beyond the closest hit dropped), exact boxes in float64,
    Moller-Trumbore in float64."""
    n = origins.shape[0]
    n_nodes = np.zeros(n, np.int64)
    n_boxes = np.zeros(n, np.int64)
    n_tris = np.zeros(n, np.int64)
    hit_tri = np.full(n, -1, np.int64)
    hit_t = np.full(n, np.inf)
    lo = np.empty(3)
    hi = np.empty(3)
    for i in range(n):
        o, d = origins[i], directions[i]
        inv = np.empty(3)
        if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d)) and d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > 0.0):
            continue
        for a in range(3):
            inv[a] = 1.0 / d[a] if d[a] != 0.0 else np.inf
        t0, t1 = _clip(o, inv, scene_lo, scene_hi, tmin, np.inf)
        if not t0 <= t1:
            continue
        stack_ref = np.empty(3 * depth + 4, np.int64)
        stack_t = np.empty(3 * depth + 4)
        sp = 0
        ref = 0
        best_t, best = np.inf, -1
        keys = np.empty(4)
        kref = np.empty(4, np.int64)
        while True:
            while ref >= 0:
                node = ref // node_rows
                n_nodes[i] += 1
                k = 0
                for s in range(4):
                    for a in range(3):
                        lo[a], hi[a] = planes[node, 2 * a, s], planes[node, 2 * a + 1, s]
                    if not lo[0] <= hi[0]:
                        continue
                    n_boxes[i] += 1
                    e0, x0 = _clip(o, inv, lo, hi, tmin, np.inf)
                    if e0 <= x0 and e0 <= best_t:
                        keys[k], kref[k] = e0, refs[node, s]
                        k += 1
                if k == 0:
                    ref = -(1 << 31)
                    break
                order = np.argsort(keys[:k])
                for j in range(k - 1, 0, -1):
                    stack_ref[sp], stack_t[sp] = kref[order[j]], keys[order[j]]
                    sp += 1
                ref = kref[order[0]]
            if ref != -(1 << 31):
                bits = ~ref
                first, count = bits >> leaf_bits, bits & ((1 << leaf_bits) - 1)
                for j in range(count):
                    tri = tri_rows_ids[(first - tri_row0) // tri_rows + j]
                    n_tris[i] += 1
                    t = _moller(o, d, vertices, faces[tri])
                    if t > tmin and (t < best_t or (t == best_t and tri < best)):
                        best_t, best = t, tri
            ref = -(1 << 31)
            while sp > 0:
                sp -= 1
                if stack_t[sp] <= best_t:
                    ref = stack_ref[sp]
                    break
            if ref == -(1 << 31):
                break
        hit_tri[i], hit_t[i] = best, best_t
    return n_nodes, n_boxes, n_tris, hit_tri, hit_t


def traversal_counts_bvh4(b: Bvh4, vertices, faces, origins, directions, tmin: float = 0.0):
    """_count_bvh4 of ``b`` for rays (origins, directions): (nodes, boxes, tris, tri ids, t) per ray."""
    bounds = np.asarray(b.bounds, np.float64)          # grown as rtlab.device.scene.padded_bounds does
    pad = np.abs(bounds).max() * 2.0 ** -20 + (bounds[1] - bounds[0]).max() * 1e-6 + 1e-30
    return _count_bvh4(b.planes().astype(np.float64), b.refs().astype(np.int64), np.asarray(b.tri_ids, np.int64),
                       b.tri_row0, np.asarray(vertices, np.float32).astype(np.float64), np.asarray(faces, np.int64),
                       bounds[0] - pad, bounds[1] + pad, int(b.depth), np.asarray(origins, np.float32).astype(np.float64),
                       np.asarray(directions, np.float32).astype(np.float64), float(tmin), NODE_ROWS, TRI_ROWS,
                       LEAF_BITS)
