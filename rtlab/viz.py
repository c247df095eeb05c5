"""Scene inspection in pyvista: the mesh, the kd-tree's cells, the camera frustum, and for one pixel
its ray tree and the kd-tree leaves its primary ray visits.

    view = inspect_scene("bunny", depth=6, pixel=(64, 40), size=128, screenshot="bunny.png")
    view.rays[0].hit_point, view.visited           # what the tracer returned; leaves front to back

Everything drawn is computed from what rtlab itself uses: the cells are decoded from the kd-tree the
kernels traverse (rtlab.accel.kdtree's helpers, each child's box cut from its parent's at the
split), the pixel's rays are traced on a backend (primary hits with rtlab.trace; shadow,
reflection and refraction rays through the shading kernels' own spawn functions,
rtlab.device.probes, where the scene has lights and such materials), and the visited leaves come
from walking the tree along the primary ray in float64 on the host.

Headless (tests, notebooks, ``--screenshot``): VTK draws off-screen through EGL (Debian
``libegl1 libgl1-mesa-dri``) or OSMesa (``libosmesa6``). VTK 9.4+ wheels pick the window class
from ``$VTK_DEFAULT_OPENGL_WINDOW``; :func:`ensure_headless_gl` tries each in a subprocess first
(a machine with neither would segfault in-process) and sets it before pyvista is imported.
``$RTLAB_VTK_WINDOW`` names the class to use without probing.
"""
from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .errors import RtlabError


class InspectError(RtlabError):
    """Scene inspection cannot run (no OpenGL for off-screen rendering, a pixel outside the image...)."""


# --------------------------------------------------------------------------------------------------
# headless OpenGL
# --------------------------------------------------------------------------------------------------
HEADLESS_WINDOWS = ("vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow")
_PROBE = """
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the OpenGL classes)
from vtkmodules.vtkRenderingCore import vtkRenderWindow, vtkRenderer
w = vtkRenderWindow()
w.SetOffScreenRendering(1)
w.AddRenderer(vtkRenderer())
w.SetSize(8, 8)
w.Render()
print("RTLAB-GL-OK", w.GetClassName())
"""
_headless: str | None = None


def _probe_window(cls: str, timeout: float = 120.0) -> tuple[bool, str]:
    env = dict(os.environ, VTK_DEFAULT_OPENGL_WINDOW=cls)
    try:
        r = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False, f"{cls}: no answer in {timeout:g} s"
    ok = r.returncode == 0 and f"RTLAB-GL-OK {cls}" in r.stdout
    why = "" if ok else (f"{cls}: exit status {r.returncode}" +
                         (f" (signal {-r.returncode})" if r.returncode < 0 else "") +
                         (f": {r.stderr.strip().splitlines()[-1][:200]}" if r.stderr.strip() else ""))
    return ok, why


def ensure_headless_gl() -> str:
    """The VTK window class for off-screen rendering, set in $VTK_DEFAULT_OPENGL_WINDOW; raises
    InspectError (never segfaults) when neither EGL nor OSMesa works."""
    global _headless
    if _headless:
        return _headless
    chosen = os.environ.get("RTLAB_VTK_WINDOW")
    if not chosen:
        reasons = []
        for cls in HEADLESS_WINDOWS:
            ok, why = _probe_window(cls)
            if ok:
                chosen = cls
                break
            reasons.append(why)
        if not chosen:
            raise InspectError("no OpenGL for off-screen rendering: install EGL (apt-get install libegl1 "
                               "libgl1-mesa-dri) or OSMesa (apt-get install libosmesa6). Tried: " + "; ".join(reasons))
    os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = chosen
    os.environ["RTLAB_VTK_WINDOW"] = chosen      # child processes (notebook kernels) skip the probe
    _headless = chosen
    return chosen


def _pyvista(off_screen: bool):
    if off_screen:
        ensure_headless_gl()
    elif not os.environ.get("DISPLAY") and sys.platform.startswith("linux"):
        raise InspectError("no display ($DISPLAY is not set): use --screenshot out.png for an image file")
    try:
        import pyvista as pv
    except ImportError:
        raise InspectError("pyvista is not installed: pip install -e '.[viz]'") from None
    return pv


# --------------------------------------------------------------------------------------------------
# geometry: kd-tree cells, boxes as lines, the camera frustum
# --------------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------------
# leaves a ray visits: the stack traversal, walked on the host in float64
# --------------------------------------------------------------------------------------------------
@dataclass
class VisitedLeaf:
    node: int
    t_enter: float
    t_exit: float
    box: np.ndarray           # (2, 3)
    triangles: np.ndarray     # the leaf's object list


def clip_segment(o, inv_d, box, t0, t1) -> tuple[float, float]:
    with np.errstate(invalid="ignore", divide="ignore"):
        a = (box[0] - o) * inv_d
        b = (box[1] - o) * inv_d
    lo, hi = np.fmin(a, b), np.fmax(a, b)          # fmin/fmax drop the NaN of 0 * inf
    return max(t0, float(np.nanmax(lo))), min(t1, float(np.nanmin(hi)))


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


# --------------------------------------------------------------------------------------------------
# a pixel's ray tree
# --------------------------------------------------------------------------------------------------
@dataclass
class RaySegment:
    kind: str                 # primary, shadow, reflection, refraction
    origin: np.ndarray
    direction: np.ndarray
    t: float                  # distance to the hit (or to the light for a shadow ray)
    tri: int                  # triangle hit; -1 a miss (shadow ray: -1 = the light is visible)
    depth: int = 0
    parent: int = -1          # index of the parent segment in the tree's list
    note: str = ""
    u: float = 0.0
    v: float = 0.0

    @property
    def hit(self) -> bool:
        return self.tri >= 0

    @property
    def hit_point(self) -> np.ndarray:
        return self.origin + self.t * self.direction

    def end(self, miss_length: float) -> np.ndarray:
        t = self.t if np.isfinite(self.t) else miss_length
        return self.origin + t * self.direction


RAY_COLORS = {"primary": "#ffd400", "shadow": "#4a90e2", "shadow-blocked": "#303030",
              "reflection": "#e2474a", "refraction": "#29b36b"}


def _trace_hits(scene, backend, o, d):
    from .device.tracing import trace
    return trace(scene, np.atleast_2d(o), np.atleast_2d(d), backend=backend)


def expand_shadow(scene, backend, seg: RaySegment, index: int, depth: int) -> list[RaySegment]:
    """Shadow rays from a hit to each light, decided by the shading kernels' own light_visible."""
    if not seg.hit or not scene.lights or seg.kind == "shadow":
        return []
    from .device.tracing import TraceResult
    from .device.probes import probe_shadow_rays
    hits = TraceResult(np.array([seg.t], np.float32), np.array([seg.tri], np.int32),
                       np.array([seg.u], np.float32), np.array([seg.v], np.float32), 0.0)
    p = seg.hit_point
    out = []
    for light in scene.lights:
        target = np.asarray(light.position, np.float64)
        visible = bool(probe_shadow_rays(scene, backend, seg.direction[None], hits, target[None])[0])
        dist = float(np.linalg.norm(target - p))
        out.append(RaySegment("shadow", p, (target - p) / max(dist, 1e-30), dist, -1 if visible else 0,
                              depth, index, "light visible" if visible else "blocked"))
    return out


def _expand_secondary(kind: str):
    def expand(scene, backend, seg: RaySegment, index: int, depth: int) -> list[RaySegment]:
        if not seg.hit or seg.kind == "shadow":
            return []
        from .device.tracing import TraceResult
        from .device.probes import probe_secondary_rays
        hits = TraceResult(np.array([seg.t], np.float32), np.array([seg.tri], np.int32),
                           np.array([seg.u], np.float32), np.array([seg.v], np.float32), 0.0)
        o, w, d, child = probe_secondary_rays(scene, backend, seg.direction[None].astype(np.float32), hits, kind)
        if not w[0] > 0.0:
            return []
        return [RaySegment(kind, o[0].astype(np.float64), d[0].astype(np.float64), float(child.t[0]),
                           int(child.tri[0]), depth, index, f"weight {w[0]:.3g}", float(child.u[0]), float(child.v[0]))]
    expand.__doc__ = f"The {kind} ray the kernel tree (lab 05) spawns from a hit, with its closest hit."
    return expand


# kind -> expander(scene, backend, parent segment, parent index, depth) -> child segments. A new ray
# kind (e.g. a path tracer's bounce) plugs in here.
RAY_EXPANDERS: dict[str, Callable] = {"shadow": expand_shadow, "reflection": _expand_secondary("reflection"),
                                      "refraction": _expand_secondary("refraction")}


def _wanted_kinds(scene) -> list[str]:
    """Ray kinds the scene calls for: shadows with lights, reflection from mirrors and glass
    (Fresnel), refraction through glass."""
    reflective = any(m.reflectivity > 0 or m.transparency > 0 for m in scene.materials)
    transparent = any(m.transparency > 0 for m in scene.materials)
    return [k for k, on in (("shadow", bool(scene.lights)), ("reflection", reflective),
                            ("refraction", transparent)) if on]


def pixel_ray_tree(scene, x: int, y: int, backend=None, kinds=None, max_depth: int = 3,
                   notes: list | None = None) -> list[RaySegment]:
    """The ray tree of pixel (x, y) of the scene's camera: the primary ray (rtlab.trace on the
    camera ray rtlab.camera_rays builds, the same as camera_ray on the device), then the rays each
    hit spawns, per :data:`RAY_EXPANDERS` (default: what the scene's lights and materials call
    for), down to ``max_depth`` bounces. Segment 0 is the primary ray."""
    from .scene.model import camera_rays
    cam = scene.camera
    if not (0 <= x < cam.width and 0 <= y < cam.height):
        raise InspectError(f"pixel ({x}, {y}) is outside the {cam.width}x{cam.height} image")
    o, d = camera_rays(cam)
    i = y * cam.width + x
    hit = _trace_hits(scene, backend, o[i], d[i])
    tree = [RaySegment("primary", o[i].astype(np.float64), d[i].astype(np.float64), float(hit.t[0]), int(hit.tri[0]),
                       0, -1, "", float(hit.u[0]), float(hit.v[0]))]
    kinds = _wanted_kinds(scene) if kinds is None else list(kinds)
    frontier = [0]
    for depth in range(1, max_depth + 1):
        nxt = []
        for idx in frontier:
            for kind in kinds:
                try:
                    children = RAY_EXPANDERS[kind](scene, backend, tree[idx], idx, depth)
                except Exception as e:  # an expander that cannot run here (a kernel not built yet)
                    if notes is not None:
                        notes.append(f"{kind} rays not shown: {type(e).__name__}: {e}")
                    kinds = [k for k in kinds if k != kind]
                    continue
                for c in children:
                    tree.append(c)
                    if c.kind != "shadow":
                        nxt.append(len(tree) - 1)
        frontier = nxt
        if not frontier:
            break
    return tree


# --------------------------------------------------------------------------------------------------
# the view
# --------------------------------------------------------------------------------------------------
@dataclass
class SceneView:
    scene: object
    tree: object
    depth: int
    cell_nodes: np.ndarray
    cell_boxes: np.ndarray
    pixel: tuple[int, int] | None = None
    rays: list[RaySegment] = field(default_factory=list)
    visited: list[VisitedLeaf] = field(default_factory=list)
    screenshot: Path | None = None
    image: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)

    def summary(self) -> list[str]:
        s = self.scene
        lines = [f"{s.name}: {s.n_triangles:,} triangles, kd-tree depth {self.tree.depth}, "
                 f"{len(self.tree.nodes):,} nodes; {len(self.cell_boxes):,} cells drawn to depth {self.depth}"]
        if self.pixel is not None:
            x, y = self.pixel
            p = self.rays[0]
            what = f"hits triangle {p.tri} at t = {p.t:.6g}, point {np.round(p.hit_point, 5).tolist()}" if p.hit else "misses"
            lines.append(f"pixel ({x}, {y}) of {s.camera.width}x{s.camera.height}: primary ray {what}")
            lines.append(f"  visits {len(self.visited)} leaves front to back: "
                         + ", ".join(f"{v.node} [{v.t_enter:.4g}, {v.t_exit:.4g}] ({len(v.triangles)} tris)"
                                     for v in self.visited[:12]) + (" ..." if len(self.visited) > 12 else ""))
            for seg in self.rays[1:]:
                what = (seg.note if seg.kind == "shadow" else
                        f"hits triangle {seg.tri} at t = {seg.t:.6g}" if seg.hit else "misses")
                lines.append(f"  {'  ' * seg.depth}{seg.kind} (from segment {seg.parent}): {what}"
                             + (f", {seg.note}" if seg.note and seg.kind != "shadow" else ""))
        lines += [f"note: {n}" for n in self.notes]
        return lines

    def plotter(self, off_screen: bool = True, window_size=(1024, 768)):
        """A pyvista Plotter with everything added (one actor for all the cells)."""
        pv = _pyvista(off_screen)
        s = self.scene
        extent = float(np.linalg.norm(np.ptp(self.tree.bounds, axis=0))) or 1.0
        p = pv.Plotter(off_screen=off_screen, window_size=list(window_size))
        p.set_background("white")
        p.add_mesh(mesh_polydata(s), color="#c8ccd4", smooth_shading=False, name="mesh")
        p.add_mesh(boxes_polydata(self.cell_boxes), color="#5b6b8c", line_width=1, opacity=0.6, name="kd-cells")
        eye = np.asarray(s.camera.basis()[0], np.float64)
        dist = float(np.linalg.norm(eye - np.mean(self.tree.bounds, axis=0)))
        fs, fe = frustum_segments(s.camera, 0.35 * dist)
        p.add_mesh(segments_polydata(fs, fe), color="#222222", line_width=2, name="frustum")
        if self.visited:
            p.add_mesh(boxes_polydata(np.array([v.box for v in self.visited])), color="#ff7f0e", line_width=3,
                       name="visited-leaves")
        by_kind: dict = {}
        for seg in self.rays:
            kind = "shadow-blocked" if seg.kind == "shadow" and seg.hit else seg.kind
            by_kind.setdefault(kind, []).append((seg.origin, seg.end(0.4 * extent)))
        for kind, segs in by_kind.items():
            p.add_mesh(segments_polydata(np.array([a for a, _ in segs]), np.array([b for _, b in segs])),
                       color=RAY_COLORS.get(kind, "black"), line_width=4, name=f"rays-{kind}")
        hits = [seg.hit_point for seg in self.rays if seg.hit and seg.kind != "shadow"]
        if hits:
            p.add_mesh(pv.PolyData(np.array(hits)), color="#d62728", point_size=14, render_points_as_spheres=True,
                       name="hit-points")
        p.add_legend([[k.replace("-blocked", " (blocked)"), RAY_COLORS.get(k, "black")] for k in by_kind]
                     + [["visited leaves", "#ff7f0e"]]
                     if by_kind else [["kd-tree cells", "#5b6b8c"]], bcolor="white", size=(0.2, 0.2))
        self._side_view(p, eye)
        return p

    def _side_view(self, p, eye) -> None:
        """Look at the scene and the camera from the side (the camera's eye turned 60 degrees about
        the scene centre around its up axis, and raised), so primary rays are seen along their length."""
        centre = np.mean(np.asarray(self.tree.bounds, np.float64), axis=0)
        up = np.asarray(self.scene.camera.up, np.float64)
        up /= np.linalg.norm(up)
        r = eye - centre
        a = np.radians(60.0)
        # Rodrigues' rotation of r about up
        r = r * np.cos(a) + np.cross(up, r) * np.sin(a) + up * np.dot(up, r) * (1 - np.cos(a))
        r += 0.35 * np.linalg.norm(r) * up
        p.camera_position = [tuple(centre + 1.2 * r), tuple(0.5 * (centre + eye)), tuple(up)]
        box = np.asarray(self.tree.bounds, np.float64)
        lo, hi = np.minimum(box[0], eye), np.maximum(box[1], eye)
        p.reset_camera(bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
        p.camera.zoom(1.1)


def build_view(scene, depth: int = 6, pixel: tuple[int, int] | None = None, backend=None,
               ray_kinds=None, max_depth: int = 3) -> SceneView:
    """Everything to draw, without drawing it (no OpenGL needed)."""
    from .device.scene import scene_kdtree
    tree = scene_kdtree(scene)
    nodes, boxes, _ = kd_cells(tree, depth)
    view = SceneView(scene, tree, depth, nodes, boxes, pixel)
    if pixel is not None:
        x, y = int(pixel[0]), int(pixel[1])
        view.pixel = (x, y)
        view.rays = pixel_ray_tree(scene, x, y, backend, ray_kinds, max_depth, view.notes)
        prim = view.rays[0]
        view.visited = visited_leaves(tree, prim.origin, prim.direction, prim.t if prim.hit else np.inf)
    return view


def inspect_scene(scene, depth: int = 6, pixel: tuple[int, int] | None = None, size: int = 128,
                  screenshot=None, backend=None, window_size=(1024, 768), show: bool = True) -> SceneView:
    """Build the view of a scene (a Scene or a preset name); write a PNG (``screenshot``) or open a
    window (``show``)."""
    if isinstance(scene, str):
        from .scene import load_scene
        scene = load_scene(scene, size=size)
    elif size and (scene.camera.width, scene.camera.height) != (size, size):
        scene.camera = scene.camera.with_size(size)
    view = build_view(scene, depth, pixel, backend)
    if screenshot is not None:
        p = view.plotter(off_screen=True, window_size=window_size)
        view.image = p.screenshot(str(screenshot), return_img=True)
        p.close()
        view.screenshot = Path(screenshot)
    elif show:
        view.plotter(off_screen=False, window_size=window_size).show()
    return view
