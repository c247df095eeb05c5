"""Scene loading: the real scene files (counts, bounds, materials, checksums), the procedural default
scene, the mesh cache, and clear SceneErrors for bad input."""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from rtlab.errors import SceneError
from rtlab.paths import find_scene_file, scene_search_dirs
from rtlab.scene import (PRESETS, Camera, Material, Scene, bench_camera, list_scenes, load_mesh_file,
                         load_scene, scene_warnings)
from rtlab.scene.loader import load_preset, parse_mtl
from rtlab.scene.presets import Preset

# From ../shared/scenes/SOURCES.md (trimesh 4.x, process=False): triangles, vertices, bbox.
SOURCES = {
    "bunny": (69_451, 35_947, (-0.0946899, 0.0329874, -0.0618736), (0.0610091, 0.187321, 0.0587997)),
    "sponza": (66_450, 61_014, (-17.409, -0.999001, -7.801), (17.411, 15.561, 7.799)),
    "kitchen": (103_343, 54_838, (-2, -1.1, -3.75), (6, 2.9, 4.33)),
    "dragon": (871_414, 437_645, (-0.108324, 0.0527295, -0.0504143), (0.0965662, 0.197173, 0.0412075)),
    "conference": (331_179, 194_399, (-1020.13, -2.7924, -1055.66), (1685.81, 650.293, 668.489)),
}


def _scene_file_or_skip(name: str) -> Path:
    preset = PRESETS[name]
    path = find_scene_file(preset.relpath)
    if path is None:
        reason = (f"scene file {preset.relpath} not found in any of "
                  f"{', '.join(str(d) for d in scene_search_dirs())}")
        if os.environ.get("CI") == "true":
            pytest.fail(reason)
        pytest.skip(reason)
    return path


@pytest.fixture(scope="module")
def preset_scenes():
    """Each preset loaded once for the whole module (parsed once, then from the mesh cache)."""
    loaded: dict[str, Scene] = {}

    def get(name: str) -> Scene:
        _scene_file_or_skip(name)
        if name not in loaded:
            loaded[name] = load_scene(name)
        return loaded[name]
    return get


# ---- the real scene files ----------------------------------------------------------------------

@pytest.mark.parametrize("name", list(SOURCES))
def test_preset_counts_and_bounds(preset_scenes, name):
    n_triangles, n_vertices, lo, hi = SOURCES[name]
    scene = preset_scenes(name)
    assert scene.n_triangles == n_triangles == PRESETS[name].file_triangles
    assert len(scene.vertices) == n_vertices
    assert scene.vertices.dtype == np.float32 and scene.vertices.shape == (n_vertices, 3)
    assert scene.faces.dtype == np.int32 and scene.faces.shape == (n_triangles, 3)
    assert scene.material_ids.dtype == np.int32 and scene.material_ids.shape == (n_triangles,)
    assert 0 <= scene.material_ids.min() and scene.material_ids.max() < len(scene.materials)
    diagonal = np.linalg.norm(np.subtract(hi, lo))
    np.testing.assert_allclose(scene.bounds(), [lo, hi], atol=1e-5 * diagonal)


@pytest.mark.parametrize("name", list(SOURCES))
def test_preset_camera_light_and_normals(preset_scenes, name):
    scene = preset_scenes(name)
    preset = PRESETS[name]
    assert scene.camera == bench_camera(preset.view, 1024)
    assert (scene.camera.width, scene.camera.height, scene.camera.fov_deg) == (1024, 1024, 40.0)
    assert len(scene.lights) == 1
    light = np.array(scene.lights[0].position)
    lo, hi = scene.bounds()
    if preset.light_position is not None:  # indoor scenes: the light is inside the scene's box
        assert np.all(light > lo) and np.all(light < hi)
    if preset.smooth_normals:
        assert scene.vertex_normals is not None and scene.vertex_normals.shape == scene.vertices.shape
        np.testing.assert_allclose(np.linalg.norm(scene.vertex_normals, axis=1), 1.0, atol=1e-5)
    else:
        assert scene.vertex_normals is None


def test_paper_triangle_counts():
    assert {n: p.paper_triangles for n, p in PRESETS.items()} == {
        "bunny": 69_451, "sponza": 66_454, "kitchen": 103_343, "dragon": 871_414, "conference": 331_179}


def _mtl_transparent_names(mtl_path: Path) -> set[str]:
    """Names whose MTL `d` is below 1, read straight from the file."""
    names, current = set(), None
    for line in mtl_path.read_text().splitlines():
        parts = line.split()
        if parts[:1] == ["newmtl"]:
            current = parts[1]
        elif parts[:1] == ["d"] and float(parts[1]) < 1.0:
            names.add(current)
    return names


@pytest.mark.parametrize("name, n_materials", [("sponza", 20), ("kitchen", 19)])
def test_mtl_materials_kept(preset_scenes, name, n_materials):
    scene = preset_scenes(name)
    assert len({m.name for m in scene.materials}) == n_materials
    assert set(np.unique(scene.material_ids)) == set(range(n_materials))
    mtl = parse_mtl(Path(scene.source).with_suffix(".mtl"))
    for material in scene.materials:
        assert material == mtl[material.name]  # exact MTL floats, not 8-bit colours
    transparent = _mtl_transparent_names(Path(scene.source).with_suffix(".mtl"))
    assert {m.name for m in scene.materials if m.transparency > 0} == transparent
    if name == "kitchen":
        assert transparent == {"m15_glass", "m18_glass_dragon"}
        glass = next(m for m in scene.materials if m.name == "m15_glass")
        assert glass.transparency == pytest.approx(0.85) and glass.ior == pytest.approx(1.55)
        assert glass.diffuse == (0.065, 0.065, 0.065)


def test_ply_presets_get_one_grey_white_material(preset_scenes):
    scene = preset_scenes("bunny")
    assert len(scene.materials) == 1 and scene.materials[0].diffuse == (0.8, 0.8, 0.8)


def test_scene_warnings_report_degenerate_triangles(preset_scenes):
    warnings = scene_warnings(preset_scenes("kitchen"))
    assert any("5 of 103343 triangles have zero area" in w for w in warnings)


def test_cached_reload_is_fast(preset_scenes):
    if os.environ.get("RTLAB_NO_CACHE", "") not in ("", "0"):
        pytest.skip("RTLAB_NO_CACHE is set")
    path = Path(preset_scenes("conference").source)
    start = time.perf_counter()
    mesh = load_mesh_file(path)
    assert mesh.from_cache and time.perf_counter() - start < 1.0


def test_checksums_match_sources():
    for row in list_scenes():
        _scene_file_or_skip(row["name"])
        assert row["sha256"] == "ok", row
        assert row["path"] and row["searched"] == [str(d) for d in scene_search_dirs()]


def test_file_path_is_framed_like_the_far_view():
    path = _scene_file_or_skip("bunny")
    scene = load_scene(path, size=256)
    far = bench_camera("bunny/far", 256)
    np.testing.assert_allclose(scene.camera.eye, far.eye, atol=1e-5)
    np.testing.assert_allclose(scene.camera.target, far.target, atol=1e-5)
    assert scene.vertex_normals is not None  # "auto": a scan looks smooth
    assert scene.name == "bunny" and len(scene.lights) == 1


def test_preset_names_are_case_insensitive_and_size_applies(preset_scenes):
    _scene_file_or_skip("bunny")
    scene = load_scene("BUNNY", size=300)
    assert (scene.camera.width, scene.camera.height) == (300, 300)
    assert scene.n_triangles == preset_scenes("bunny").n_triangles


# ---- the procedural default scene --------------------------------------------------------------

def test_default_scene_shape_and_determinism():
    scene = load_scene()
    again = load_scene("procedural")
    assert 40_000 <= scene.n_triangles <= 80_000
    for field in ("vertices", "faces", "material_ids", "vertex_normals"):
        assert np.array_equal(getattr(scene, field), getattr(again, field))
    assert scene.materials == again.materials and scene.camera == again.camera
    assert scene.vertices.dtype == np.float32 and scene.faces.dtype == np.int32
    assert scene.material_ids.dtype == np.int32 and scene.material_ids.max() < len(scene.materials)
    assert np.isfinite(scene.vertices).all()
    np.testing.assert_allclose(np.linalg.norm(scene.vertex_normals, axis=1), 1.0, atol=1e-5)
    assert not scene_warnings(scene)
    assert all(m.reflectivity == 0 and m.transparency == 0 for m in scene.materials)
    assert len(scene.lights) == 1 and (scene.camera.width, scene.camera.height) == (1024, 1024)
    ground = scene.material_ids[: 2 * 128 * 128]
    assert len(np.unique(ground)) == 2


def test_default_scene_size():
    assert load_scene("default", size=64).camera == Camera(
        eye=(0.0, 5.0, 14.0), target=(0.0, 0.8, 0.0), width=64, height=64)


# ---- bad input ---------------------------------------------------------------------------------

@pytest.fixture
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("RTLAB_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("RTLAB_NO_CACHE", raising=False)
    return tmp_path / "cache" / "meshes"


def _ply(vertices, faces) -> str:
    header = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x",
              "property float y", "property float z", f"element face {len(faces)}",
              "property list uchar int vertex_indices", "end_header"]
    body = [" ".join(map(str, v)) for v in vertices] + [" ".join(map(str, [len(f), *f])) for f in faces]
    return "\n".join(header + body) + "\n"


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


TRIANGLE = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]


def _load_error(path) -> str:
    with pytest.raises(SceneError) as caught:
        load_mesh_file(path)
    assert caught.value.__cause__ is None  # one line for the user, no trimesh traceback
    return str(caught.value)


def test_missing_file(tmp_path, private_cache):
    message = _load_error(tmp_path / "nothing.ply")
    assert str(tmp_path / "nothing.ply") in message


def test_missing_preset_file_lists_every_directory_searched(private_cache):
    preset = Preset(name="ghost", relpath="ghost/ghost.ply", sha256="0" * 64, paper_triangles=1,
                    file_triangles=1, file_vertices=3, view="bunny/far", smooth_normals=False,
                    light_position=None, description="not there")
    with pytest.raises(SceneError) as caught:
        load_preset(preset)
    for directory in scene_search_dirs():
        assert str(directory / "ghost/ghost.ply") in str(caught.value)


def test_unknown_scene_names_the_scene_and_the_presets(private_cache):
    with pytest.raises(SceneError) as caught:
        load_scene("teapot")
    message = str(caught.value)
    assert "'teapot'" in message and all(name in message for name in PRESETS)


def test_unknown_bench_view_lists_the_valid_ones():
    with pytest.raises(SceneError) as caught:
        bench_camera("bunny/close", 64)
    assert "bunny/far" in str(caught.value) and "sponza/inside" in str(caught.value)


@pytest.mark.parametrize("name, text", [
    ("empty.ply", _ply(TRIANGLE, [])),
    ("points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n"),
    ("zero_bytes.obj", ""),
])
def test_empty_mesh(tmp_path, private_cache, name, text):
    path = _write(tmp_path, name, text)
    message = _load_error(path)
    assert str(path) in message and "no triangles" in message


@pytest.mark.parametrize("name, text", [
    ("nan.ply", _ply([(0, 0, 0), (1, 0, "nan"), (0, 1, 0)], [(0, 1, 2)])),
    ("inf.obj", "v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n"),
])
def test_non_finite_vertex(tmp_path, private_cache, name, text):
    path = _write(tmp_path, name, text)
    message = _load_error(path)
    assert str(path) in message and "vertex 1" in message and ("NaN" in message)


def test_ply_without_a_coordinate_names_it(tmp_path, private_cache):
    """A PLY whose vertices lack a coordinate says which property is missing, not trimesh's KeyError."""
    path = _write(tmp_path, "no_z.ply", _ply(TRIANGLE, [(0, 1, 2)]).replace("property float z\n", ""))
    message = _load_error(path)
    assert str(path) in message and "'z'" in message and "KeyError" not in message


def test_face_index_out_of_range_ply(tmp_path, private_cache):
    path = _write(tmp_path, "oor.ply", _ply(TRIANGLE, [(0, 1, 2), (0, 1, 5)]))
    message = _load_error(path)
    assert str(path) in message and "triangle 1" in message and "0..2" in message


def test_face_index_out_of_range_obj(tmp_path, private_cache):
    path = _write(tmp_path, "oor.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 7\n")
    message = _load_error(path)
    assert str(path) in message and "line 5" in message and "vertex 7" in message


def test_all_degenerate_mesh(tmp_path, private_cache):
    path = _write(tmp_path, "flat.ply", _ply([(0, 0, 0), (1, 1, 1), (2, 2, 2)], [(0, 1, 2), (0, 0, 1)]))
    message = _load_error(path)
    assert str(path) in message and "all 2 triangles have zero area" in message


def test_some_degenerate_triangles_are_kept(tmp_path, private_cache):
    path = _write(tmp_path, "some.ply", _ply([*TRIANGLE, (2, 0, 0)], [(0, 1, 2), (0, 1, 3), (2, 2, 1)]))
    mesh = load_mesh_file(path)
    assert mesh.n_triangles == 3 and mesh.n_degenerate == 2
    assert any("2 of 3 triangles have zero area (first: triangle 1)" in w for w in mesh.warnings)


def test_malformed_and_unsupported_files(tmp_path, private_cache):
    garbage = _write(tmp_path, "garbage.ply", "this is not a ply file\n")
    message = _load_error(garbage)
    assert message.startswith(f"cannot read {garbage}")
    unsupported = _write(tmp_path, "mesh.xyz", "1 2 3\n")
    assert "unsupported file type '.xyz'" in _load_error(unsupported)


# ---- OBJ+MTL details, glTF, the cache ----------------------------------------------------------

MTL = """newmtl red
Kd 0.7 0.1 0.1
Ks 0.2 0.2 0.2
Ns 30
newmtl glass
Kd 0.1 0.1 0.1
d 0.25
Ni 1.45
newmtl tinted
Kd 0.5
Tr 0.4
"""
OBJ = """mtllib two.mtl
v 0 0 0
v 1 0 0
v 0 1 0
v 1 1 0
v 0 0 1
usemtl glass
f 2 4 3
usemtl red
f 1 2 3
f 1 3 5
usemtl tinted
f 1 5 2
"""


def test_obj_groups_and_mtl_values(tmp_path, private_cache):
    _write(tmp_path, "two.mtl", MTL)
    mesh = load_mesh_file(_write(tmp_path, "two.obj", OBJ))
    assert [m.name for m in mesh.materials] == ["glass", "red", "tinted"]  # order of first use
    glass, red, tinted = mesh.materials
    assert red == Material("red", diffuse=(0.7, 0.1, 0.1), specular=(0.2, 0.2, 0.2), shininess=30.0)
    assert glass.transparency == pytest.approx(0.75) and glass.ior == pytest.approx(1.45)
    assert tinted.diffuse == (0.5, 0.5, 0.5) and tinted.transparency == pytest.approx(0.4)
    assert mesh.n_triangles == 4 and mesh.material_ids.tolist() == [0, 1, 1, 2]
    assert mesh.vertex_normals("flat") is None and mesh.smooth_normals.shape == mesh.vertices.shape


def test_obj_with_missing_mtl_keeps_groups_with_default_materials(tmp_path, private_cache):
    mesh = load_mesh_file(_write(tmp_path, "two.obj", OBJ))
    assert mesh.n_triangles == 4 and mesh.material_ids.tolist() == [0, 1, 1, 2]
    assert mesh.materials == [Material("glass"), Material("red"), Material("tinted")]
    assert [w for w in mesh.warnings if "material" in w] == [
        f"{tmp_path / 'two.obj'}: material library {tmp_path / 'two.mtl'} not found; using default materials"]


def test_file_normals_are_kept_and_normalised(tmp_path, private_cache):
    header = _ply(TRIANGLE, [(0, 1, 2)]).replace("property float z\n", "property float z\nproperty float nx\n"
                                                   "property float ny\nproperty float nz\n")
    text = header.replace("0 0 0\n", "0 0 0 0 0 2\n").replace("1 0 0\n", "1 0 0 0 0 2\n", 1)
    text = text.replace("0 1 0\n", "0 1 0 0 0 2\n")
    mesh = load_mesh_file(_write(tmp_path, "normals.ply", text))
    np.testing.assert_allclose(mesh.file_normals, [[0, 0, 1]] * 3)
    assert mesh.vertex_normals("auto") is mesh.file_normals and mesh.vertex_normals("flat") is None


def test_relative_path_is_found_in_the_scene_directories(preset_scenes):
    _scene_file_or_skip("kitchen")
    scene = load_scene("kitchen/kitchen.obj", size=128)
    assert scene.name == "kitchen" and scene.n_triangles == preset_scenes("kitchen").n_triangles
    assert scene.camera.width == 128 and scene.vertex_normals is None  # architecture: flat


def test_gltf_base_colour_becomes_diffuse(tmp_path, private_cache):
    trimesh = pytest.importorskip("trimesh")
    box = trimesh.creation.box(extents=(1, 2, 3))
    box.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        name="paint", baseColorFactor=[0.2, 0.4, 0.6, 1.0]))
    path = tmp_path / "box.glb"
    box.export(path)
    mesh = load_mesh_file(path)
    assert mesh.n_triangles == 12
    np.testing.assert_allclose(mesh.materials[0].diffuse, (0.2, 0.4, 0.6), atol=1 / 255)
    np.testing.assert_allclose(mesh.bounds(), [(-0.5, -1, -1.5), (0.5, 1, 1.5)])


def test_cache_roundtrip_and_invalidation(tmp_path, private_cache):
    mtl = _write(tmp_path, "two.mtl", MTL)
    obj = _write(tmp_path, "two.obj", OBJ)
    first = load_mesh_file(obj)
    second = load_mesh_file(obj)
    assert not first.from_cache and second.from_cache
    assert len(list(private_cache.glob("two-*.npz"))) == 1
    for field in ("vertices", "faces", "material_ids", "smooth_normals"):
        assert np.array_equal(getattr(first, field), getattr(second, field))
    assert first.materials == second.materials and first.warnings == second.warnings
    mtl.write_text(MTL.replace("Kd 0.7 0.1 0.1", "Kd 0.1 0.7 0.1"))
    os.utime(mtl, ns=(time.time_ns(), time.time_ns() + 10**9))
    changed = load_mesh_file(obj)
    assert not changed.from_cache and changed.materials[1].diffuse == (0.1, 0.7, 0.1)
    assert load_mesh_file(obj).from_cache
    os.utime(obj, ns=(time.time_ns(), time.time_ns() + 2 * 10**9))
    assert not load_mesh_file(obj).from_cache
    assert len(list(private_cache.glob("two-*.npz"))) == 1  # the entry for the old file is gone


def test_no_cache_env(tmp_path, private_cache, monkeypatch):
    monkeypatch.setenv("RTLAB_NO_CACHE", "1")
    path = _write(tmp_path, "tri.ply", _ply(TRIANGLE, [(0, 1, 2)]))
    assert not load_mesh_file(path).from_cache and not load_mesh_file(path).from_cache
    assert not private_cache.exists()


# ---- a Scene and a Camera check themselves -------------------------------------------------------
def _tri_scene(vertices=TRIANGLE, faces=((0, 1, 2),), material_ids=(0,), materials=None, **kw):
    return Scene("probe", np.asarray(vertices, np.float32) if np.ndim(vertices) else vertices,
                 np.asarray(faces), np.asarray(material_ids), materials if materials is not None else [Material()],
                 Camera((0.0, 0.0, 3.0), (0.0, 0.0, 0.0)), **kw)


@pytest.mark.parametrize("kw, expected", [
    (dict(material_ids=(3,)), ["face 0 has material id 3", "1 materials", "valid ids 0..0"]),
    (dict(faces=((0, 1, 2), (2, 1, 0)), material_ids=(0, -1)), ["face 1 has material id -1"]),
    (dict(faces=((0, 1, 2), (2, 1, 0)), material_ids=(0,)), ["material_ids", "one id per face", "(2,)", "(1,)"]),
    (dict(materials=[]), ["no materials"]),
    (dict(faces=((0, 1, 2), (0, 1, 3))), ["face 1 = [0, 1, 3]", "valid indices 0..2"]),
    (dict(faces=((0, 1, 2), (-1, 1, 2))), ["face 1 = [-1, 1, 2]"]),
    (dict(faces=((0, 1, 2, 0),)), ["faces must have shape (N, 3)", "(1, 4)"]),
    (dict(vertices=np.zeros((3, 2), np.float32)), ["vertices must have shape (N, 3)", "(3, 2)"]),
    (dict(faces=np.zeros((0, 3), np.int32), material_ids=np.zeros(0, np.int32)), ["no triangles", "nothing to trace"]),
    (dict(faces=((0.0, 1.0, 2.0),)), ["faces must hold integers"]),
    (dict(vertex_normals=np.zeros((2, 3), np.float32)), ["vertex_normals", "one normal per vertex"]),
])
def test_bad_scene_is_one_clear_error(kw, expected):
    """Wrong shapes, missing vertices, out-of-range material ids, an empty mesh: one SceneError
    naming the first bad face, index or id (not a numpy error, a segfault or a silent misread)."""
    with pytest.raises(SceneError) as caught:
        _tri_scene(**kw)
    message = str(caught.value)
    assert "scene 'probe'" in message and all(e in message for e in expected), message


def test_scene_stores_arrays_as_the_kernels_read_them():
    scene = _tri_scene(vertices=np.asarray(TRIANGLE, np.float64), faces=np.array([[0, 1, 2]], np.int64),
                       material_ids=np.array([0], np.uint8))
    assert scene.vertices.dtype == np.float32 and scene.faces.dtype == np.int32
    assert scene.material_ids.dtype == np.int32 and scene.vertices.flags.c_contiguous


@pytest.mark.parametrize("kw, expected", [
    (dict(eye=(1, 2, 3), target=(1, 2, 3)), "same point"),
    (dict(eye=(0, 5, 0), target=(0, 0, 0)), "parallel to the view direction"),
    (dict(eye=(0, -5, 0), target=(0, 0, 0), up=(0, -2, 0)), "parallel to the view direction"),
    (dict(eye=(0, 0, 5), target=(0, 0, 0), up=(0, 0, 0)), "zero vector"),
    (dict(eye=(0, 0, 5), target=(0, 0, 0), fov_deg=0.0), "fov_deg"),
    (dict(eye=(0, 0, 5), target=(0, 0, 0), fov_deg=180.0), "fov_deg"),
    (dict(eye=(0, 0, 5), target=(0, 0, 0), width=0), "width"),
    (dict(eye=(0, 0, float("nan")), target=(0, 0, 0)), "finite"),
    (dict(eye=(0, 0), target=(0, 0, 0)), "three"),
])
def test_degenerate_camera_is_refused(kw, expected):
    """A camera whose basis does not exist (up along the view, eye on the target) rendered an
    all-background image; now it is an error when it is made, saying why."""
    with pytest.raises(SceneError, match=expected):
        Camera(**kw)


def test_camera_up_nearly_but_not_parallel_is_fine():
    cam = Camera((0.0, 5.0, 0.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 1e-3))
    eye, u, v, w = cam.basis()
    assert np.all(np.isfinite(u)) and abs(float(np.dot(u, w))) < 1e-6


@pytest.mark.parametrize("scale", [1e-14, 1e15])
def test_out_of_range_coordinates_warn(scale):
    """Coordinates all below 1e-12, or beyond 1e13, make float32 ray tests meaningless: a
    ScaleWarning when the scene is made (and in scene_warnings), none for ordinary scales."""
    from rtlab.scene.model import ScaleWarning
    with pytest.warns(ScaleWarning, match="float32 ray tests"):
        scene = _tri_scene(vertices=np.asarray(TRIANGLE, np.float64) * scale)
    assert any("coordinates are" in w for w in scene_warnings(scene))
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error", ScaleWarning)
        for ok in (1e-9, 1.0, 1e12):
            _tri_scene(vertices=np.asarray(TRIANGLE, np.float64) * ok)


def test_tiny_mesh_file_warns_at_load(tmp_path, private_cache):
    from rtlab.scene.model import ScaleWarning
    path = _write(tmp_path, "tiny.ply", _ply([(0, 0, 0), (1e-14, 0, 0), (0, 1e-14, 0)], [(0, 1, 2)]))
    with pytest.warns(ScaleWarning, match=str(path.stem)):
        load_scene(str(path), size=16)


# ---- a scene from arrays, and what float32 can hold where an object lies ---------------------

def _unit_box(offset=0.0):
    import trimesh
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    return box.vertices + offset, box.faces


def test_scene_from_arrays_in_one_call():
    """(vertices, faces) alone make a scene that renders: one material, a camera with the whole mesh
    in view, a light above; a trimesh works as well (rtlab.scene_from_arrays, Scene.from_mesh)."""
    import trimesh
    import warnings
    import rtlab
    from rtlab.scene.model import camera_rays
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=2.0)
    mesh.apply_translation([10.0, -3.0, 4.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = rtlab.scene_from_arrays(mesh.vertices, mesh.faces.tolist(), size=48)
    assert scene.n_triangles == len(mesh.faces) and scene.vertices.dtype == np.float32
    assert len(scene.materials) == 1 and np.all(scene.material_ids == 0) and len(scene.lights) == 1
    assert scene.camera.width == scene.camera.height == 48
    # every vertex projects inside the image, and the middle pixel sees the sphere
    eye, u, v, w = [x.astype(np.float64) for x in scene.camera.basis()]
    rel = mesh.vertices - eye
    depth = rel @ w
    assert np.all(depth > 0)
    assert np.all(np.abs(rel @ u / (depth * np.dot(u, u))) < 1) and np.all(np.abs(rel @ v / (depth * np.dot(v, v))) < 1)
    light = np.asarray(scene.lights[0].position)
    assert light[1] > mesh.vertices[:, 1].max()
    from rtlab.reference import reference_trace
    o, d = camera_rays(scene.camera)
    ref = reference_trace(scene.vertices, scene.faces, o, d)
    assert ref.tri[(24 * 48) + 24] >= 0 and 0.05 < np.mean(ref.tri >= 0) < 0.95
    same = Scene.from_mesh(mesh, size=48)
    assert np.array_equal(same.vertices, scene.vertices) and np.array_equal(same.faces, scene.faces)
    mats = [Material("a"), Material("b", diffuse=(1, 0, 0))]
    two = rtlab.scene_from_arrays(mesh, materials=mats, material_ids=np.arange(len(mesh.faces)) % 2)
    assert two.materials == mats and two.material_ids[1] == 1


@pytest.mark.parametrize("kw, message", [
    (dict(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 3]]), "refers to a vertex that does not exist"),
    (dict(vertices=[[0, 0, 0], [1, np.nan, 0], [0, 1, 0]], faces=[[0, 1, 2]]), "vertex 1 .* must be finite"),
    (dict(vertices=[[0, 0], [1, 0], [0, 1]], faces=[[0, 1, 2]]), r"shape \(V, 3\)"),
    (dict(vertices=[["a", "b", "c"]] * 3, faces=[[0, 1, 2]]), "must hold real numbers"),
    (dict(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0.0, 1.0, 2.0]]), "faces must hold integers"),
    (dict(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]]), "needs faces"),
    (dict(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]], material_ids=[1]), "need the materials"),
    (dict(vertices=[[0, 0, 0], [1e39, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]]), r"vertex 1 .* beyond float32's range"),
    (dict(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[["a", "b", "c"]]), "faces must hold integers"),
    (dict(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2], [0, 1]]), "faces is not an array"),
    (dict(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]], lights="light"), "lights must be a list of "
                                                                                           "rtlab Lights, got str"),
    (dict(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]], lights=[(1, 1, 1)]), "got tuple"),
    (dict(vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0]], faces=[[0, 1, 2]]), "all 1 triangles have zero area"),
])
def test_scene_from_arrays_says_what_is_wrong(kw, message):
    import warnings

    import rtlab
    with warnings.catch_warnings():
        warnings.simplefilter("error")                 # no numpy warning on the way (overflow in a cast)
        with pytest.raises(SceneError, match=message):
            rtlab.scene_from_arrays(**kw)


@pytest.mark.parametrize("bad", [None, 3, ["bunny"]])
def test_a_scene_that_is_neither_a_name_nor_a_path_is_one_error(bad):
    with pytest.raises(SceneError, match="a preset name or a mesh file's path"):
        load_scene(bad)


def test_objects_too_small_for_their_distance_from_the_origin_warn():
    """A unit box at 1e8 collapses to a point in float32; at 1e6 a ray leaving it starts 0.7 off its
    surface: both warn with the numbers (the old check looked only at |coordinates| > 1e13). A unit box
    at 1e3, a 40-wide floor at 1e6 beside nothing small, and the real scenes do not warn."""
    import warnings
    import rtlab
    from rtlab.scene.model import ScaleWarning
    from rtlab.scene.scale import object_scale_warnings
    with pytest.warns(ScaleWarning) as caught:
        rtlab.scene_from_arrays(*_unit_box(1e8))
    text = " ".join(str(w.message) for w in caught)
    assert "12 of 12 triangles (the first is triangle 0) have an area in the given coordinates but none once" in text
    assert "collapsed to zero area" in text and "float32 spacing is 8" in text
    with pytest.warns(ScaleWarning, match=r"an object of 12 triangles .* 1\.73 across, reaches 1e\+06 .* spacing is "
                                          r"0\.0625: a ray leaving it starts up to 0\.723 off its surface \(42 %"):
        scene = rtlab.scene_from_arrays(*_unit_box(1e6))
    assert any("off its surface" in w for w in scene_warnings(scene))
    floor_v = np.array([[-20, 0, -20], [-20, 0, 20], [20, 0, 20], [20, 0, -20]], np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ScaleWarning)
        rtlab.scene_from_arrays(*_unit_box(1e3))
        rtlab.scene_from_arrays(floor_v * 100 + 1e5, [[0, 1, 2], [0, 2, 3]])
        for name in ("bunny", "sponza"):
            if find_scene_file(PRESETS[name].relpath) is not None:
                s = load_scene(name, size=16)
                assert object_scale_warnings(s.vertices, s.faces, name) == []
    v, f = _unit_box(1e6)
    both = object_scale_warnings(np.concatenate([v, floor_v * 100 + 1e6]),
                                 np.concatenate([f, len(v) + np.array([[0, 1, 2], [0, 2, 3]])]), "two")
    assert len(both) == 1 and "an object of 12 triangles" in both[0]


def test_vertex_components_join_triangles_by_shared_vertices():
    from rtlab.scene.scale import vertex_components
    faces = np.array([[0, 1, 2], [2, 3, 4], [5, 6, 7], [8, 9, 10], [10, 7, 11]])
    label = vertex_components(13, faces)
    assert len(set(label[[0, 1, 2, 3, 4]])) == 1 and len(set(label[[5, 6, 7, 8, 9, 10, 11]])) == 1
    assert label[0] != label[5] and label[12] == 12
    rng = np.random.default_rng(3)
    chain = np.stack([np.arange(2000), np.arange(1, 2001), np.arange(2, 2002)], 1)[rng.permutation(2000)]
    assert np.all(vertex_components(2002, chain) == 0)


def test_scene_search_dirs_name_each_folder_once(tmp_path, monkeypatch):
    """RTLAB_SCENES naming a folder twice, or again through a link, is searched (and reported) once,
    in the order first given."""
    first, second = tmp_path / "a", tmp_path / "b"
    first.mkdir()
    second.mkdir()
    (tmp_path / "link").symlink_to(first)
    monkeypatch.setenv("RTLAB_SCENES", os.pathsep.join(str(p) for p in (first, second, tmp_path / "link", first)))
    dirs = scene_search_dirs()
    assert dirs[:2] == [first, second]
    resolved = [d.resolve() for d in dirs]
    assert len(resolved) == len(set(resolved))


def test_camera_sizes_are_whole_numbers():
    """with_size(2.5) rendered 2 pixels wide without a word; a whole float (256.0) stays accepted."""
    camera = load_scene("default", size=16).camera
    assert camera.with_size(8.0).width == 8 and camera.with_size(8, 4).height == 4
    with pytest.raises(SceneError, match="camera width must be a positive integer, got 2.5"):
        camera.with_size(2.5)


@pytest.mark.parametrize("size", [2.5, 0, True, "64"])
def test_load_scene_passes_its_size_to_the_camera_check(tmp_path, private_cache, size):
    """load_scene(size=2.5) was truncated to 2, 0 became 1024, True 1 and "64" 64, without a word:
    the default scene, a preset and a file all give the size to Camera's check as it came."""
    path = _write(tmp_path, "tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    names = ["default", str(path)] + (["bunny"] if find_scene_file(PRESETS["bunny"].relpath) else [])
    for name in names:
        with pytest.raises(SceneError, match="camera width must be a positive integer"):
            load_scene(name, size=size)
    assert load_scene(str(path), size=None).camera.width == 1024


@pytest.mark.parametrize("text, expected", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 2 3 4\nf 0 2 3\n", "line 6: face corner '0' refers to vertex 0; OBJ "
                                                                 "indices start at 1"),
    ("v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "line 1: vertex 'v 0 0' has fewer than 3 coordinates"),
    ("v 0 0 0\nv 1 0 0\nv 0 1\nf 1 2 3\n", "line 3: vertex 'v 0 1' has fewer than 3 coordinates"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "line 4: cannot read face corner 'x'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "the file holds 3 vertices and 0 faces"),
])
def test_obj_lines_trimesh_reads_wrongly_are_named(tmp_path, private_cache, text, expected):
    """Vertex 0 was read as another triangle without a word, a vertex of two coordinates and a bad
    face token gave an IndexError or a ValueError without the line, a face of two corners counted the
    vertices trimesh kept (2), not the file's (3)."""
    path = _write(tmp_path, "bad.obj", text)
    message = _load_error(path)
    assert str(path) in message and expected in message, message


def test_non_utf8_file_names_are_one_error(tmp_path, private_cache):
    """trimesh's scene graph raised a UnicodeEncodeError on a name that is not UTF-8."""
    path = Path(os.fsdecode(bytes(tmp_path) + b"/caf\xe9.obj"))
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(SceneError, match=r"caf\\xe9\.obj: file names must be UTF-8"):
        load_scene(str(path))


def test_a_mesh_file_read_anyway_warns_at_load(tmp_path, private_cache):
    """What load_mesh_file(...).warnings held went to an INFO log nobody saw: a file loaded by its
    path says it in a MeshWarning (the CLI prints it as one line)."""
    from rtlab.scene.model import MeshWarning
    path = _write(tmp_path, "two.obj", OBJ)
    with pytest.warns(MeshWarning, match=r"material library .*two\.mtl not found"):
        load_scene(str(path), size=16)
    degenerate = _write(tmp_path, "some.ply", _ply([*TRIANGLE, (2, 0, 0)], [(0, 1, 2), (0, 1, 3), (2, 2, 1)]))
    with pytest.warns(MeshWarning, match="2 of 3 triangles have zero area"):
        load_scene(str(degenerate), size=16)
