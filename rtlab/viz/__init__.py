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

Headless (tests, notebooks, ``--screenshot``): rtlab.viz.headless. The cells and visited leaves:
rtlab.viz.geometry; the pixel's rays: rtlab.viz.rays.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InspectError  # noqa: F401  (raised below here)
from .geometry import (VisitedLeaf, box_corners, boxes_polydata, clip_segment, frustum_segments, kd_cells,  # noqa: F401
                       mesh_polydata, segments_polydata, visited_leaves)
from .headless import ensure_headless_gl, pyvista_module  # noqa: F401
from .rays import RAY_COLORS, RaySegment, pixel_ray_tree

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
        pv = pyvista_module(off_screen)
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
    from ..device.device_scene import scene_kdtree
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
        from ..scene import load_scene
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
