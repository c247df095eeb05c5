"""What rtlab inspect draws of the scene: the kd-tree's cells to a depth (decoded from the tree the
kernels traverse, each child's box cut from its parent's at the split), boxes and segments as line
polydata, the camera frustum, and the leaves a ray visits (the stack traversal walked on the host in
float64)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InspectError

BOX_EDGES = np.array([[0, 1], [1, 3], [3, 2], [2, 0], [4, 5], [5, 7], [7, 6], [6, 4],
                      [0, 4], [1, 5], [2, 6], [3, 7]])


def kd_cells(tree, depth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tree's cells down to ``depth``: every node at that depth and every leaf above it, as
    (node ids, boxes (N, 2, 3) float64, depths). Boxes are cut from the root box (tree.bounds) at
    each split on the way down, exactly as the traversal splits its ray segments."""
    if depth < 0:
        raise InspectError(f"depth must be >= 0, got {depth}")
    is_leaf, axis, split, child = tree.is_leaf(), tree.split_axis(), tree.split_pos(), tree.child_or_count()
    nodes = np.array([0])
    boxes = np.asarray(tree.bounds, np.float64)[None].copy()
    out_nodes, out_boxes, out_depth = [], [], []
    for level in range(depth + 1):
        stop = is_leaf[nodes] | (level == depth)
        out_nodes.append(nodes[stop])
        out_boxes.append(boxes[stop])
        out_depth.append(np.full(int(stop.sum()), level))
        inner, inner_boxes = nodes[~stop], boxes[~stop]
        if inner.size == 0:
            break
        ax = axis[inner]
        pos = split[inner].astype(np.float64)
        left, right = inner_boxes.copy(), inner_boxes.copy()
        rows = np.arange(inner.size)
        left[rows, 1, ax] = pos
        right[rows, 0, ax] = pos
        nodes = np.concatenate([child[inner], child[inner] + 1])
        boxes = np.concatenate([left, right])
    return np.concatenate(out_nodes), np.concatenate(out_boxes), np.concatenate(out_depth)


def box_corners(boxes: np.ndarray) -> np.ndarray:
    """(N, 8, 3): corner k takes x from bit 0, y from bit 1, z from bit 2 (0 = min, 1 = max)."""
    b = np.asarray(boxes, np.float64)
    bits = (np.arange(8)[:, None] >> np.arange(3)[None, :]) & 1
    return np.where(bits[None] == 1, b[:, 1][:, None, :], b[:, 0][:, None, :])


def boxes_polydata(boxes: np.ndarray):
    """All boxes' edges as ONE line PolyData (one actor however many cells)."""
    import pyvista as pv
    n = len(boxes)
    points = box_corners(boxes).reshape(-1, 3)
    seg = (BOX_EDGES[None] + 8 * np.arange(n)[:, None, None]).reshape(-1, 2)
    lines = np.hstack([np.full((len(seg), 1), 2), seg]).ravel()
    return pv.PolyData(points, lines=lines)


def segments_polydata(starts: np.ndarray, ends: np.ndarray):
    import pyvista as pv
    starts, ends = np.atleast_2d(starts), np.atleast_2d(ends)
    n = len(starts)
    points = np.stack([starts, ends], axis=1).reshape(-1, 3)
    lines = np.hstack([np.full((n, 1), 2), np.arange(2 * n).reshape(n, 2)]).ravel()
    return pv.PolyData(points, lines=lines)


def frustum_segments(camera, length: float) -> tuple[np.ndarray, np.ndarray]:
    """The view frustum as line segments: eye to the four image corners at ``length`` along the
    view direction, and the rectangle they span (same basis as camera_ray in rt_types.h)."""
    eye, u, v, w = (r.astype(np.float64) for r in camera.basis())
    corners = np.array([eye + length * (w + sx * u + sy * v) for sx, sy in ((-1, 1), (1, 1), (1, -1), (-1, -1))])
    starts = np.concatenate([np.repeat(eye[None], 4, 0), corners])
    ends = np.concatenate([corners, np.roll(corners, -1, axis=0)])
    return starts, ends


def mesh_polydata(scene):
    import pyvista as pv
    faces = np.hstack([np.full((scene.n_triangles, 1), 3), scene.faces]).ravel()
    return pv.PolyData(np.asarray(scene.vertices, np.float64), faces=faces)


@dataclass
class VisitedLeaf:
    node: int
    t_enter: float
    t_exit: float
    box: np.ndarray           # (2, 3)
    triangles: np.ndarray     # the leaf's object list


def clip_segment(o, inv_d, box, t0, t1) -> tuple[float, float]:
    """The part of [t0, t1] inside ``box`` (rtlab.geometry.slab_interval)."""
    from ..geometry import slab_interval
    box = np.asarray(box, np.float64)
    lo, hi = slab_interval(np.asarray(o, np.float64), np.asarray(inv_d, np.float64), box[0], box[1], float(t0), float(t1))
    return float(lo), float(hi)


def visited_leaves(tree, origin, direction, t_hit: float = np.inf, tmin: float = 0.0) -> list[VisitedLeaf]:
    """Leaves the stack traversal (traverse_kd_stack) visits along the ray, front to back, in
    float64: every leaf whose part of the ray starts no later than the hit (the traversal stops
    once the hit is nearer than every pending cell)."""
    o = np.asarray(origin, np.float64)
    d = np.asarray(direction, np.float64)
    with np.errstate(divide="ignore"):
        inv_d = 1.0 / d
    is_leaf, axis, split, child = tree.is_leaf(), tree.split_axis(), tree.split_pos(), tree.child_or_count()
    root = np.asarray(tree.bounds, np.float64)
    t0, t1 = clip_segment(o, inv_d, root, tmin, np.inf)
    out: list[VisitedLeaf] = []
    if t0 > t1:
        return out
    stack = [(0, root, t0, t1)]
    while stack:
        node, box, a, b = stack.pop()
        if a > t_hit:
            continue
        if is_leaf[node]:
            start, count = int(tree.nodes[node, 1]), int(child[node])
            out.append(VisitedLeaf(int(node), a, b, box, tree.objects[start:start + count].copy()))
            continue
        ax, pos, left = int(axis[node]), float(split[node]), int(child[node])
        lbox, rbox = box.copy(), box.copy()
        lbox[1, ax] = pos
        rbox[0, ax] = pos
        below_first = o[ax] < pos or (o[ax] == pos and d[ax] <= 0.0)
        near, far = ((left, lbox), (left + 1, rbox)) if below_first else ((left + 1, rbox), (left, lbox))
        if d[ax] == 0.0:
            ts = np.nan if o[ax] == pos else np.inf
        else:
            ts = (pos - o[ax]) * inv_d[ax]
        if np.isnan(ts):                        # the ray lies in the split plane: both cells
            stack.append((far[0], far[1], a, b))
            stack.append((near[0], near[1], a, b))
        elif ts > b or ts <= 0.0:
            stack.append((near[0], near[1], a, b))
        elif ts < a:
            stack.append((far[0], far[1], a, b))
        else:
            stack.append((far[0], far[1], ts, b))
            stack.append((near[0], near[1], a, ts))
    return out
