"""A compressed 8-wide BVH for the GPU traversal of kernels/shared/rt_bvh8.h, after Ylitie, Karras &
Laine, "Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs" (HPG 2017).

Build, from the binary SAH trees of rtlab.accel.bvh (their disk cache, plain and spatial-split):
 1-3. rtlab.accel.bvh_collapse: binary leaves split down to one triangle, Ylitie et al.'s optimal
    collapse to 8 children a node with leaves of at most 3 triangles (the 3-bit unary count
    of the encoding), child slots ordered by octant: the traversal visits slot s ^ octinv
    first, so a ray of octant s starts with the child furthest along -(signs of s).
 4. Child boxes quantised to 8 bits a plane, rounded outward with a slack (below), relative to a
    node origin p and a power-of-two step 2^e per axis.
 5. Triangles in leaf order after the nodes, three float4 rows each (v0 with the triangle id in w, v1,
    v2: the very floats the scene's tris buffer holds, so the triangle tests give the same bits as
    the binary BVH's), so a node's leaves read contiguous rows and no object list.

Device layout (sync with rt_bvh8.h), node_data float4 rows; node i at rows 5 i .. 5 i + 4 = 80 B:
  row 0  p.x, p.y, p.z (float), w: bytes e.x + 127, e.y + 127, e.z + 127, imask (bit s: slot s is
         an inner node)                                                                  16 B
  row 1  x: row of the first inner child; y: row of the node's first triangle;
         z, w: meta of slots 0-3, 4-7 (a byte a slot)                                    16 B
  rows 2-4  q_lo.x[8], q_lo.y[8], q_lo.z[8], q_hi.x[8], q_hi.y[8], q_hi.z[8]             48 B
meta of an inner child in slot s: 0b001 << 5 | (24 + s), its node at row x + 5 popc(imask below s);
of a leaf child: (unary triangle count 0b1, 0b11, 0b111) << 5 | offset (0-21), its triangles at rows
y + 3 (offset + k); an empty slot: 0. A node holds at most 24 triangles. Child box in slot s, axis a:
[p_a + q_lo[a][s] 2^e_a, p_a + q_hi[a][s] 2^e_a]. The root is node 0 and always inner (an empty
mesh: no children).

Quantisation slack. The kernel computes a plane distance as one fma, (2^15 + q) s + P', from
s = 2^e / d and P' = (p - o) / d - 2^15 s per node and axis (rt_bvh8.h); that errs by a few ulps of
the distance (the 1 + RT_T_PAD exit scale covers those, as in rt_bvh.h) plus up to ~2^-9 of one
step's distance, whatever the distance. Every quantised plane therefore lies SLACK_STEPS = 2^-6 of
a step outside the exact child box: eight times that bound, so no box the exact test keeps is
culled. The same slack covers a zero direction component, which the kernel gives the inverse
+-2^64 (rt_bvh.h's bvh_inverse): a ray lying in a slab is then inside it by at least the slack and
its interval there spans +-2^64 x slack, at least 2^17 scene extents in t since no step is below
MIN_STEP_EXP (2^-40 of the scene's extent): the whole segment of a ray starting within 2^16 extents
of the scene with a direction of length >= 1 (rt_bvh8.h, hazard 2). The kernel's numbers stay finite
for coordinates up to MAX_COORD (2^50).
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np

from ..errors import RtlabError, SceneError
from ..kernel_constants import kernel_constant
from .bvh import Bvh
from .bvh_collapse import PLAIN_BUILD, SPLIT_BUILD, collapse_best
from .wide_store import WideBvh

FORMAT_VERSION = "cwbvh8-v1"    # bump when the builder's output for the same inputs changes
WIDTH = 8
NODE_ROWS = int(kernel_constant("BVH8_NODE_ROWS"))       # float4 rows a node (80 B)
TRI_ROWS = int(kernel_constant("BVH8_TRI_ROWS"))         # float4 rows a triangle (48 B)
LEAF_MAX = 3                    # triangles a leaf child: the 3-bit unary count of the meta byte
NODE_TRIS = 24                  # triangles a node: the low 24 bits of the traversal's hit mask
SLACK_STEPS = 2.0 ** -6         # quantised planes lie this many steps outside the exact box
MIN_STEP_EXP = -40              # no step below 2^-40 of the scene's extent (zero-direction rays)
MAX_COORD = 2.0 ** 50           # coordinates beyond this could overflow the kernel's box test

NODE_DTYPE = np.dtype([("p", "<f4", 3), ("e", "u1", 3), ("imask", "u1"), ("child_row", "<i4"),
                       ("tri_row", "<i4"), ("meta", "u1", 8), ("qlo", "u1", (3, 8)), ("qhi", "u1", (3, 8))])
assert NODE_DTYPE.itemsize == 16 * NODE_ROWS


@dataclass(frozen=True)
class Bvh8BuildParams:
    """Ylitie et al.'s collapse costs (their c_node = 1, c_prim = 0.3: one 8-wide node test costs
    about three triangle tests) and which binary tree to collapse: "auto" (both; the spatial-split
    one where it is SPLIT_MIN_GAIN cheaper), "plain" or "split"."""
    cost_node: float = 1.0
    cost_prim: float = 0.3
    binary: str = "auto"

    def __post_init__(self):
        if self.binary not in ("auto", "plain", "split"):
            raise RtlabError(f"Bvh8BuildParams.binary must be 'auto', 'plain' or 'split', got {self.binary!r}")
        if not (self.cost_node > 0.0 and self.cost_prim > 0.0):
            raise RtlabError(f"BVH8 costs must be positive, got {self.cost_node}, {self.cost_prim}")

    def key(self) -> str:
        return f"{FORMAT_VERSION}-cn{self.cost_node}-cp{self.cost_prim}-{self.binary}-{PLAIN_BUILD.key()}-{SPLIT_BUILD.key()}"


class Bvh8(WideBvh):
    node_rows = NODE_ROWS
    tri_rows = TRI_ROWS
    format_version = FORMAT_VERSION

    def nodes(self) -> np.ndarray:
        """The node rows as NODE_DTYPE records (a view)."""
        return self.rows[:NODE_ROWS * self.n_nodes].reshape(self.n_nodes, 4 * NODE_ROWS).view(NODE_DTYPE).reshape(-1)


# ---- 4. quantisation ---------------------------------------------------------------------------------
def _round_down_f32(x: np.ndarray) -> np.ndarray:
    """The largest float32 <= x (float64 in)."""
    f = x.astype(np.float32)
    return np.where(f.astype(np.float64) > x, np.nextafter(f, np.float32(-np.inf)), f)


def quantise(node_lo, node_hi, child_lo, child_hi, valid, scene_extent: float):
    """Per node and axis the origin p (float32), exponent e and per slot q_lo, q_hi (0..255) with
    p + q_lo 2^e <= child lo - SLACK_STEPS 2^e and p + q_hi 2^e >= child hi + SLACK_STEPS 2^e,
    computed in float64 (module docstring). Empty slots get q_lo = q_hi = 0."""
    finite = np.isfinite(node_lo).all(axis=1) & np.isfinite(node_hi).all(axis=1)   # an empty mesh's root is not
    lo = np.where(finite[:, None], node_lo, 0.0).astype(np.float64)
    hi = np.where(finite[:, None], node_hi, 0.0).astype(np.float64)
    ext = np.maximum(hi - lo, 0.0)
    e_min = np.floor(np.log2(scene_extent)) + MIN_STEP_EXP if scene_extent > 0 else -100.0
    e_min = max(e_min, -100.0)
    with np.errstate(divide="ignore"):
        e = np.ceil(np.log2(np.where(ext > 0, ext / 253.0, 0.0)))
    e = np.maximum(np.where(np.isfinite(e), e, e_min), e_min)
    clo, chi = child_lo.astype(np.float64), child_hi.astype(np.float64)   # (W, 8, 3)
    for _ in range(200):
        step = np.exp2(e)
        p = _round_down_f32(lo - 0.5 * step)
        q_lo = np.floor((clo - p[:, None, :]) / step[:, None, :] - SLACK_STEPS)
        q_hi = np.ceil((chi - p[:, None, :]) / step[:, None, :] + SLACK_STEPS)
        ok = ~valid[:, :, None] | ((q_lo >= 0) & (q_hi <= 255))
        bad = ~ok.all(axis=1)                                  # (W, 3)
        if not bad.any():
            break
        e = np.where(bad, e + 1, e)
    else:
        raise SceneError("BVH8 quantisation did not converge (coordinates beyond float range?)")
    if e.max(initial=0) > 126 or e.min(initial=0) < -126:
        raise SceneError(f"BVH8 quantisation: a step of 2^{int(e.max())} or 2^{int(e.min())} is outside float range")
    q_lo = np.where(valid[:, :, None], q_lo, 0).astype(np.uint8)
    q_hi = np.where(valid[:, :, None], q_hi, 0).astype(np.uint8)
    return p.astype(np.float32), e.astype(np.int64), q_lo, q_hi


def decoded_boxes(bvh8: Bvh8) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) of every slot's quantised box, (W, 8, 3) float64, exactly as the node encodes them."""
    nodes = bvh8.nodes()
    step = np.exp2(nodes["e"].astype(np.float64) - 127.0)                       # (W, 3)
    p = nodes["p"].astype(np.float64)
    lo = p[:, None, :] + nodes["qlo"].transpose(0, 2, 1).astype(np.float64) * step[:, None, :]
    hi = p[:, None, :] + nodes["qhi"].transpose(0, 2, 1).astype(np.float64) * step[:, None, :]
    return lo, hi


# ---- 5. the device rows --------------------------------------------------------------------------------
def _pack(vertices, faces, wide, scene_extent: float) -> tuple[np.ndarray, int, np.ndarray]:
    (n_lo, n_hi, kind, c_lo, c_hi, c_node, c_count, c_offset, child_base, tri_base, tris, _) = wide
    w = len(n_lo)
    p, e, q_lo, q_hi = quantise(n_lo, n_hi, c_lo, c_hi, kind > 0, scene_extent)
    tri_row0 = NODE_ROWS * w
    rows = np.zeros((tri_row0 + TRI_ROWS * len(tris), 4), np.float32)
    nodes = rows[:tri_row0].reshape(w, 4 * NODE_ROWS).view(NODE_DTYPE).reshape(-1)
    nodes["p"] = p
    nodes["e"] = (e + 127).astype(np.uint8)
    slots = np.arange(WIDTH)
    inner = kind == 1
    nodes["imask"] = (inner.astype(np.int64) << slots).sum(axis=1).astype(np.uint8)
    nodes["child_row"] = NODE_ROWS * child_base
    nodes["tri_row"] = tri_row0 + TRI_ROWS * tri_base
    unary = np.array([0, 0b001, 0b011, 0b111])
    meta = np.where(inner, (1 << 5) | (24 + slots), 0)
    meta = np.where(kind == 2, (unary[np.minimum(c_count, 3)] << 5) | c_offset, meta)
    nodes["meta"] = meta.astype(np.uint8)
    nodes["qlo"] = q_lo.transpose(0, 2, 1)
    nodes["qhi"] = q_hi.transpose(0, 2, 1)
    # The inner children of a node are consecutive, in slot order (rt_bvh8.h finds them by popcount)
    order = np.cumsum(inner, axis=1) - 1
    assert np.all(np.where(inner, c_node == child_base[:, None] + order, True)), "inner children not consecutive"
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)[tris]
    t = rows[tri_row0:].reshape(len(tris), TRI_ROWS, 4)
    for k in range(3):
        t[:, k, :3] = v[f[:, k]]
    t.view(np.int32)[:, 0, 3] = tris.astype(np.int32)
    return rows, w, tris.astype(np.int32)


def _scene_extent(bounds) -> float:
    b = np.asarray(bounds, np.float64)
    return float((b[1] - b[0]).max()) if b.size else 0.0


def collapse8(bvh: Bvh, vertices, faces, params: Bvh8BuildParams = Bvh8BuildParams()):
    """(wide-tree arrays, cost) of the binary BVH collapsed to 8 children a node (rtlab.accel.bvh_collapse)."""
    from .bvh_collapse import collapse
    return collapse(bvh, vertices, faces, WIDTH, LEAF_MAX, params.cost_node, params.cost_prim)


def build_bvh8(vertices: np.ndarray, faces: np.ndarray, params: Bvh8BuildParams = Bvh8BuildParams(),
               cache_dir=None) -> Bvh8:
    """The compressed 8-wide BVH of a mesh (module docstring), from the binary trees in the disk cache."""
    t0 = time.perf_counter()
    vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    with np.errstate(invalid="ignore"):
        big = np.abs(vertices[np.isfinite(vertices)]).max(initial=0.0)
    name, binary, wide, cost = collapse_best(vertices, faces, params.binary, WIDTH, LEAF_MAX, params.cost_node,
                                             params.cost_prim, cache_dir)
    used = wide[-2]
    if len(used) and np.abs(vertices[np.asarray(faces)[used]]).max() > MAX_COORD:
        raise SceneError(f"BVH8: coordinates up to {big:.3g}, beyond the 2^50 its box test keeps finite: use the "
                         "bvh traversal")
    rows, n_nodes, tri_ids = _pack(vertices, faces, wide, _scene_extent(binary.bounds))
    return Bvh8(rows, n_nodes, tri_ids, binary.bounds.astype(np.float32), int(wide[-1]), float(cost), name, params,
                time.perf_counter() - t0)


def load_or_build_bvh8(vertices: np.ndarray, faces: np.ndarray, params: Bvh8BuildParams = Bvh8BuildParams(),
                       cache_dir: str | os.PathLike | None = None) -> tuple[Bvh8, bool]:
    """The mesh's BVH8 from the on-disk cache, else built and stored. Returns (bvh8, from_cache)."""
    return Bvh8.cached(vertices, faces, params, lambda: build_bvh8(vertices, faces, params, cache_dir), "BVH8",
                        cache_dir)
