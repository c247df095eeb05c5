"""Scene inspection (rtlab.viz): kd-tree cells that partition the root box, drawn as one line
PolyData; the leaves a primary ray visits, checked against the tree and the hit; a pixel's ray tree
against the renderer's own hit buffer and the float64 reference; a headless screenshot that is not
blank; a clear error where no OpenGL works."""
from __future__ import annotations

import numpy as np
import pytest

import rtlab
from rtlab.viz import (InspectError, boxes_polydata, build_view, clip_segment, ensure_headless_gl, kd_cells,
                           visited_leaves)

pv = pytest.importorskip("pyvista")


@pytest.fixture(scope="module")
def scene():
    return rtlab.load_scene("default", size=64)


@pytest.fixture(scope="module")
def tree(scene):
    from rtlab.device.device_scene import scene_kdtree
    return scene_kdtree(scene)


def _volume(boxes):
    return float(np.prod(boxes[:, 1] - boxes[:, 0], axis=1).sum())


@pytest.mark.parametrize("depth", [0, 3, 7])
def test_cells_partition_the_root_box(tree, depth):
    nodes, boxes, depths = kd_cells(tree, depth)
    root = np.asarray(tree.bounds, np.float64)
    assert np.all(depths <= depth)
    assert np.all(boxes[:, 0] >= root[0]) and np.all(boxes[:, 1] <= root[1])
    assert np.all(boxes[:, 1] >= boxes[:, 0])
    assert _volume(boxes) == pytest.approx(float(np.prod(root[1] - root[0])), rel=1e-9)
    # a cell above the depth limit is a leaf
    assert np.all(tree.is_leaf()[nodes[depths < depth]])
    if depth == 0:
        assert nodes.tolist() == [0]


def test_cells_at_full_depth_are_the_leaves(tree):
    nodes, _, _ = kd_cells(tree, tree.depth)
    assert sorted(nodes.tolist()) == np.flatnonzero(tree.is_leaf()).tolist()


def test_cells_are_one_line_polydata(tree):
    _, boxes, _ = kd_cells(tree, 5)
    poly = boxes_polydata(boxes)
    assert poly.n_points == 8 * len(boxes)
    assert poly.n_lines == 12 * len(boxes)
    # every edge is axis-aligned and joins two corners of its own box
    seg = poly.lines.reshape(-1, 3)[:, 1:]
    d = poly.points[seg[:, 1]] - poly.points[seg[:, 0]]
    assert np.all(np.count_nonzero(np.abs(d) > 0, axis=1) <= 1)
    assert np.all(seg[:, 0] // 8 == seg[:, 1] // 8)


@pytest.fixture(scope="module")
def view(scene, backend):
    # a pixel looking at the big sphere of the default scene
    return build_view(scene, depth=5, pixel=(30, 36), backend=backend)


def test_primary_ray_matches_render_hit_buffer_and_reference(view, scene, backend):
    from rtlab.reference import reference_trace
    from rtlab.scene.model import camera_rays
    x, y = view.pixel
    prim = view.rays[0]
    assert prim.kind == "primary" and prim.hit
    rendered = rtlab.render(scene, backend, write_hits=True).hits
    i = y * scene.camera.width + x
    assert prim.tri == int(rendered.tri[i])
    assert prim.t == pytest.approx(float(rendered.t[i]), rel=1e-6)
    o, d = camera_rays(scene.camera)
    ref = reference_trace(scene.vertices, scene.faces, o[i:i + 1], d[i:i + 1])
    assert prim.tri == int(ref.tri[0])
    assert np.allclose(prim.hit_point, o[i] + ref.t[0] * d[i].astype(np.float64), rtol=0, atol=1e-5 * ref.t[0])


def test_visited_leaves_follow_the_ray_to_its_hit(view, tree):
    prim = view.rays[0]
    leaves = view.visited
    assert leaves, "the primary ray visits no leaf"
    root = np.asarray(tree.bounds, np.float64)
    with np.errstate(divide="ignore"):
        t0, _ = clip_segment(prim.origin, 1.0 / prim.direction, root, 0.0, np.inf)
    # front to back, back to back, from where the ray enters the tree to the hit
    assert leaves[0].t_enter == pytest.approx(t0, rel=1e-9)
    for a, b in zip(leaves, leaves[1:]):
        assert b.t_enter == pytest.approx(a.t_exit, rel=1e-9, abs=1e-12)
    assert leaves[-1].t_enter <= prim.t <= leaves[-1].t_exit * (1 + 1e-7)
    # each leaf's box holds the middle of its part of the ray; the last one holds the hit triangle
    for leaf in leaves:
        mid = prim.origin + 0.5 * (leaf.t_enter + min(leaf.t_exit, 1e30)) * prim.direction
        assert np.all(mid >= leaf.box[0] - 1e-6) and np.all(mid <= leaf.box[1] + 1e-6)
        assert tree.is_leaf()[leaf.node]
    assert any(prim.tri in leaf.triangles for leaf in leaves if leaf.t_enter <= prim.t <= leaf.t_exit * (1 + 1e-7))


def test_visited_leaves_of_a_missing_ray(tree):
    box = np.asarray(tree.bounds, np.float64)
    outside = box[1] + 10.0 * (box[1] - box[0])
    assert visited_leaves(tree, outside, np.array([1.0, 0.0, 0.0])) == []
    # a ray along an axis through the whole box (zero direction components) visits leaves back to back
    centre = box.mean(axis=0)
    leaves = visited_leaves(tree, np.array([box[0, 0] - 1.0, centre[1], centre[2]]), np.array([1.0, 0.0, 0.0]))
    assert leaves and leaves[-1].t_exit == pytest.approx(box[1, 0] - box[0, 0] + 1.0)


def test_screenshot_is_not_blank(view, tmp_path):
    path = tmp_path / "inspect.png"
    p = view.plotter(off_screen=True, window_size=(400, 300))
    names = set(p.actors)
    img = p.screenshot(str(path), return_img=True)
    p.close()
    assert path.is_file() and img.shape == (300, 400, 3)
    assert {"mesh", "kd-cells", "frustum", "visited-leaves", "rays-primary", "hit-points"} <= names
    assert img.std() > 10.0
    rgb = img.astype(int)
    gray = (np.abs(rgb[..., 0] - rgb[..., 1]) < 12) & (np.abs(rgb[..., 1] - rgb[..., 2]) < 24)
    mesh = gray & (rgb[..., 0] > 50) & (rgb[..., 0] < 235)
    assert mesh.mean() > 0.02, "too few mesh pixels"
    yellow = (rgb[..., 0] > 200) & (rgb[..., 1] > 170) & (rgb[..., 2] < 90)
    assert yellow.sum() > 20, "the primary ray is not drawn"


def test_cli_inspect_writes_screenshot(tmp_path):
    from rtlab.cli import main
    out = tmp_path / "cli.png"
    assert main(["inspect", "default", "--depth", "3", "--pixel", "30", "36", "--size", "64", "--backend", "opencl",
                 "--screenshot", str(out), "--window", "320x240"]) == 0
    from PIL import Image
    img = np.asarray(Image.open(out))
    assert img.shape[:2] == (240, 320) and img.std() > 10.0


def test_no_opengl_is_a_clear_error(monkeypatch):
    import rtlab.viz.headless as ins
    monkeypatch.setattr(ins, "_headless", None)
    monkeypatch.setattr(ins, "HEADLESS_WINDOWS", ("vtkNoSuchRenderWindow",))
    monkeypatch.delenv("RTLAB_VTK_WINDOW", raising=False)
    monkeypatch.setenv("VTK_DEFAULT_OPENGL_WINDOW", "")
    with pytest.raises(InspectError, match="libegl1 libgl1-mesa-dri.*libosmesa6"):
        ensure_headless_gl()


def test_pixel_outside_the_image_is_an_error(scene, backend):
    with pytest.raises(InspectError, match="outside the 64x64 image"):
        build_view(scene, depth=2, pixel=(64, 3), backend=backend)


def test_secondary_rays_start_where_their_parent_hit(backend):
    """On a scene with glass and a mirror: shadow, reflection and refraction rays, each starting at
    its parent's hit point (the kernels' own spawn functions)."""
    from rtlab.scene.materials import glass_scene
    s = glass_scene(size=64)
    v = build_view(s, depth=3, pixel=(32, 30), backend=backend)
    assert not v.notes, v.notes
    kinds = {seg.kind for seg in v.rays}
    assert {"primary", "shadow", "refraction"} <= kinds
    extent = float(np.linalg.norm(np.ptp(v.tree.bounds, axis=0)))
    for seg in v.rays[1:]:
        parent = v.rays[seg.parent]
        assert parent.hit and seg.depth >= 1
        assert np.linalg.norm(seg.origin - parent.hit_point) < 1e-3 * extent, seg
