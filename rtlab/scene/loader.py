"""Loading scenes: mesh files (PLY, OBJ+MTL, glTF/GLB) through trimesh, presets, the default scene.

``load_mesh_file`` reads a file with ``process=False`` (no vertex merging, no face removal), keeps one
material per OBJ ``usemtl`` group, validates what the kernels rely on, and caches the parsed arrays as
``.npz`` + ``.json`` under ``user_cache_dir()/meshes`` (``RTLAB_NO_CACHE=1`` turns that off).
``load_scene`` turns a name or a path into a :class:`Scene` with camera, light and materials.

Triangles of zero area are kept (the kernels must cope with them); how many there are is reported in
``MeshData.warnings`` (a MeshWarning for a file loaded by its path), and available for any scene through
:func:`rtlab.scene.mesh.scene_warnings`.
The geometry checks live in rtlab.scene.mesh, the OBJ/MTL details in rtlab.scene.obj, the cache in
rtlab.scene.mesh_cache.
"""
from __future__ import annotations

import io
import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable
from warnings import warn

import numpy as np
import trimesh

from rtlab.errors import SceneError
from rtlab.paths import cache_enabled, find_scene_file, scene_search_dirs
from rtlab.scene import presets as _presets
from rtlab.scene.mesh import (MeshData, degenerate_mask, face_cross, mesh_looks_smooth, mesh_warnings,
                              smooth_vertex_normals, unit_rows)
from rtlab.scene.mesh_cache import read_cached_mesh, write_cached_mesh
from rtlab.scene.model import Camera, Light, Material, MeshWarning, Scene
from rtlab.scene.obj import first_bad_obj_face, obj_directives, obj_has_zero_index, obj_material_libraries, parse_mtl
from rtlab.scene.procedural import default_scene

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".ply", ".obj", ".gltf", ".glb", ".stl", ".off")
DEFAULT_NAMES = ("default", "procedural")
SLOW_PARSE_BYTES = 4_000_000
GROUP_NAMES_LIBRARY = "__rtlab_group_names__.mtl"
# For files without materials (PLY scans, the conference room): grey-white.
DEFAULT_MATERIAL = Material(name="default", diffuse=(0.8, 0.8, 0.8))

Progress = Callable[[str], None]


# ---- validation --------------------------------------------------------------------------------

def _check_faces(path: Path, n_vertices: int, faces: np.ndarray) -> None:
    if len(faces) == 0:
        raise SceneError(f"{path}: no triangles (the file holds {n_vertices} vertices and 0 faces)")
    bad = np.flatnonzero(((faces < 0) | (faces >= n_vertices)).any(axis=1))
    if bad.size:
        raise SceneError(
            f"{path}: {bad.size} triangles refer to vertices that do not exist (first: triangle "
            f"{bad[0]} = {faces[bad[0]].tolist()}, but valid vertex indices are 0..{n_vertices - 1})")


def _check_vertices(path: Path, vertices: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if bad.size:
        raise SceneError(
            f"{path}: {bad.size} vertices have NaN or infinite coordinates (or beyond float32 range)"
            f" (first: vertex {bad[0]} = {vertices[bad[0]].tolist()})")


def _check_not_all_degenerate(path: Path, faces: np.ndarray, degenerate: np.ndarray) -> None:
    if degenerate.all():
        raise SceneError(f"{path}: all {len(faces)} triangles have zero area (first: triangle 0 = "
                         f"{faces[0].tolist()}); there is nothing to hit")


# ---- reading through trimesh -------------------------------------------------------------------

@dataclass
class _Part:
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    material: Material | None
    material_name: str | None


class _GroupNameResolver(trimesh.resolvers.FilePathResolver):
    """Serves an MTL that only names every ``usemtl`` material. trimesh then labels each group with
    its material name whatever the real MTL holds (trimesh drops all materials of an MTL it cannot
    parse, e.g. ``Kd 0.5``); the real MTL is read by :func:`parse_mtl`."""

    def __init__(self, obj_path: Path, material_names: list[str]):
        super().__init__(str(obj_path))
        self._names_only = "".join(f"newmtl {name}\n" for name in dict.fromkeys(material_names)).encode()

    def get(self, name: str) -> bytes:
        return self._names_only if name == GROUP_NAMES_LIBRARY else super().get(name)


def _trimesh_scene(path: Path, obj_text: bytes | None, usemtl_names: list[str]):
    if obj_text is None:
        source = {"file_obj": str(path)}
    else:  # trimesh reads only the first mtllib line: ours
        source = {"file_obj": io.BytesIO(b"mtllib " + GROUP_NAMES_LIBRARY.encode() + b"\n" + obj_text),
                  "file_type": "obj", "resolver": _GroupNameResolver(path, usemtl_names)}
    try:
        return trimesh.load_scene(**source, process=False, group_material=True)
    except Exception as exc:  # trimesh raises many kinds; the user needs the file and the reason
        readable = isinstance(exc, (IndexError, ValueError)) and obj_text is not None   # a face or vertex line
        detail = first_bad_obj_face(path) if readable else None
        if isinstance(exc, KeyError) and path.suffix.lower() == ".ply":    # trimesh's reader looks up the properties
            detail = (f"its header lacks the property {exc.args[0]!r} (a vertex needs x, y and z; a face, "
                      f"vertex_indices)")
        reason = detail or f"{type(exc).__name__}: {exc}"
        raise SceneError(f"cannot read {path}: {reason}") from None


def _trimesh_material(visual) -> Material | None:
    material = getattr(visual, "material", None)
    if material is None:
        return None
    name = str(getattr(material, "name", None) or "material")
    base = getattr(material, "baseColorFactor", None)
    if base is not None:  # glTF PBR: base colour is the diffuse colour, alpha the opacity
        rgba = np.asarray(base, np.float64) / (255.0 if np.asarray(base).dtype == np.uint8 else 1.0)
        blend = getattr(material, "alphaMode", None) == "BLEND"
        return Material(name=name, diffuse=tuple(map(float, rgba[:3])),
                        transparency=float(1.0 - rgba[3]) if blend and len(rgba) > 3 else 0.0)
    diffuse = getattr(material, "diffuse", None)
    if diffuse is not None:
        return Material(name=name, diffuse=tuple(float(x) / 255.0 for x in np.asarray(diffuse)[:3]))
    return Material(name=name)


def _file_normals(geometry) -> np.ndarray | None:
    # trimesh keeps normals read from the file in its cache; asking `vertex_normals` would compute them.
    cached = geometry._cache.cache.get("vertex_normals") if hasattr(geometry, "_cache") else None
    if cached is None or np.shape(cached) != np.shape(geometry.vertices):
        return None
    return np.asarray(cached, np.float64)


def _scene_parts(tm_scene) -> list[_Part]:
    parts = []
    for node in tm_scene.graph.nodes_geometry:
        transform, geometry_name = tm_scene.graph[node]
        geometry = tm_scene.geometry[geometry_name]
        faces = getattr(geometry, "faces", None)
        if faces is None or len(faces) == 0:
            continue
        vertices = np.asarray(geometry.vertices, np.float64)
        normals = _file_normals(geometry)
        if not np.allclose(transform, np.eye(4)):
            vertices = vertices @ transform[:3, :3].T + transform[:3, 3]
            if normals is not None:
                normals = normals @ np.linalg.inv(transform[:3, :3])
        material = _trimesh_material(getattr(geometry, "visual", None))
        parts.append(_Part(vertices, np.asarray(faces, np.int64), normals, material,
                           material.name if material else None))
    return parts


def _point_count(tm_scene, obj_text: bytes | None) -> int:
    """The vertices the file holds: an OBJ's ``v`` lines (trimesh keeps only those a face uses)."""
    if obj_text is not None:
        return len(obj_directives(obj_text, b"v"))
    return sum(len(getattr(g, "vertices", ())) for g in tm_scene.geometry.values())


def _check_obj_corners(path: Path, obj_text: bytes | None, parts: list[_Part]) -> None:
    """What trimesh reads without a word: a face corner of vertex 0 (taken for another vertex), vertices
    of fewer than three coordinates (an array of two columns); the line from first_bad_obj_face."""
    short = any(p.vertices.ndim != 2 or p.vertices.shape[1] != 3 for p in parts)
    if short or (obj_text is not None and obj_has_zero_index(obj_text)):
        detail = first_bad_obj_face(path) if obj_text is not None else None
        raise SceneError(f"cannot read {path}: {detail or 'a vertex without three coordinates (x, y and z)'}")


def _apply_mtl(path: Path, obj_text: bytes, usemtl_names: list[str], parts: list[_Part],
               warnings: list[str]) -> list[Path]:
    """Give OBJ groups their exact MTL materials, in order of first use in the file."""
    libraries = obj_material_libraries(path, obj_text)
    missing = [library for library in libraries if not library.is_file()]
    for library in missing:
        warnings.append(f"{path}: material library {library} not found; using default materials")
    mtl: dict[str, Material] = {}
    for library in libraries:
        if library not in missing:
            mtl.update(parse_mtl(library))
    for part in parts:
        if part.material_name in mtl:
            part.material = mtl[part.material_name]
        elif part.material_name is not None:  # keep the group apart, so it can be given a material
            part.material = Material(name=part.material_name)
            if libraries and not missing:
                warnings.append(f"{path}: material {part.material_name!r} is not in its MTL; using a default")
    first_use = {name: rank for rank, name in reversed(list(enumerate(usemtl_names)))}
    parts.sort(key=lambda p: first_use.get(p.material_name, -1))
    return [library for library in libraries if library not in missing]


def _gltf_buffers(path: Path) -> list[Path]:
    if path.suffix.lower() != ".gltf":
        return []
    try:
        buffers = json.loads(path.read_text(encoding="utf-8")).get("buffers", [])
    except (OSError, ValueError):
        return []
    uris = [b.get("uri", "") for b in buffers]
    return [path.parent / u for u in uris if u and not u.startswith("data:") and (path.parent / u).is_file()]


def _combine(parts: list[_Part], default_material: Material) -> tuple:
    materials: list[Material] = []
    material_ids, offsets = [], np.cumsum([0] + [len(p.vertices) for p in parts])
    for part in parts:
        material = part.material or default_material
        if material not in materials:
            materials.append(material)
        material_ids.append(np.full(len(part.faces), materials.index(material), np.int32))
    vertices = np.concatenate([p.vertices for p in parts])
    faces = np.concatenate([p.faces + off for p, off in zip(parts, offsets)])
    has_normals = all(p.normals is not None for p in parts)
    normals = np.concatenate([p.normals for p in parts]) if has_normals else None
    return vertices, faces, np.concatenate(material_ids), materials, normals


def _report(progress: Progress | None, message: str) -> None:
    if progress is not None:
        progress(message)
    else:
        log.info(message)


def _parse(path: Path, progress: Progress | None) -> tuple[MeshData, list[Path]]:
    size = path.stat().st_size
    if size >= SLOW_PARSE_BYTES:
        _report(progress, f"parsing {path.name} ({size / 1e6:.1f} MB), cached afterwards")
    start = time.perf_counter()
    is_obj = path.suffix.lower() == ".obj"
    obj_text = path.read_bytes() if is_obj else None
    usemtl_names = obj_directives(obj_text, b"usemtl") if is_obj else []
    tm_scene = _trimesh_scene(path, obj_text, usemtl_names)
    parts = _scene_parts(tm_scene)
    if not parts:
        n_points = _point_count(tm_scene, obj_text)
        raise SceneError(f"{path}: no triangles (the file holds {n_points} vertices and 0 faces)")
    _check_obj_corners(path, obj_text, parts)
    warnings: list[str] = []
    if is_obj:
        dependencies = _apply_mtl(path, obj_text, usemtl_names, parts, warnings)
    else:
        dependencies = _gltf_buffers(path)
    vertices64, faces64, material_ids, materials, normals = _combine(parts, DEFAULT_MATERIAL)
    _check_faces(path, len(vertices64), faces64)
    vertices, faces = vertices64.astype(np.float32), faces64.astype(np.int32)
    _check_vertices(path, vertices)
    cross = face_cross(vertices, faces)
    degenerate = degenerate_mask(vertices, faces, cross)
    _check_not_all_degenerate(path, faces, degenerate)
    warnings += mesh_warnings(vertices, faces, str(path), degenerate)
    file_normals = None if normals is None else unit_rows(normals)
    smooth = smooth_vertex_normals(vertices, faces, cross) if file_normals is None else None
    mesh = MeshData(source=path, vertices=vertices, faces=faces, material_ids=material_ids,
                    materials=materials, file_normals=file_normals, smooth_normals=smooth,
                    looks_smooth=mesh_looks_smooth(faces, smooth if file_normals is None else file_normals, cross),
                    n_degenerate=int(np.count_nonzero(degenerate)), warnings=warnings,
                    seconds=time.perf_counter() - start)
    return mesh, dependencies


# ---- public entry points -----------------------------------------------------------------------

def _mesh_file(path: str | os.PathLike) -> Path:
    path = Path(path).expanduser()
    if not path.exists():
        raise SceneError(f"no such file: {path}")
    if not path.is_file():
        raise SceneError(f"not a file: {path}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(f"cannot load {path}: unsupported file type {path.suffix or '(none)'!r} "
                         f"(supported: {' '.join(MESH_SUFFIXES)})")
    path = path.resolve()
    try:        # trimesh's scene graph and pyopencl's build take names as UTF-8 text
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        shown = os.fsencode(path).decode("utf-8", "backslashreplace")
        raise SceneError(f"cannot load {shown}: file names must be UTF-8 (rename the file or its folder)") from None
    return path


def load_mesh_file(path: str | os.PathLike, progress: Progress | None = None) -> MeshData:
    """Read and validate a mesh file (cached on disk; see the module docstring). Raises SceneError."""
    path = _mesh_file(path)
    use_cache = cache_enabled()
    mesh = read_cached_mesh(path) if use_cache else None
    if mesh is None:
        mesh, dependencies = _parse(path, progress)
        if use_cache:
            write_cached_mesh(mesh, dependencies)
    for warning in mesh.warnings:
        log.info(warning)
    return mesh


def _scene_from_mesh(mesh: MeshData, name: str, camera: Camera, lights: list[Light],
                     normals: str) -> Scene:
    return Scene(name=name, vertices=mesh.vertices, faces=mesh.faces, material_ids=mesh.material_ids,
                 materials=list(mesh.materials), camera=camera, lights=lights,
                 vertex_normals=mesh.vertex_normals(normals), source=str(mesh.source))


def _missing_preset_error(preset: _presets.Preset) -> SceneError:
    searched = "\n".join(f"  {d / preset.relpath}" for d in scene_search_dirs())
    return SceneError(f"scene {preset.name!r} needs {preset.relpath}, which was not found; looked for:\n"
                      f"{searched}\nput the file in one of these places or point RTLAB_SCENES at its folder")


def load_preset(preset: _presets.Preset, size: int | None = None, progress: Progress | None = None) -> Scene:
    path = find_scene_file(preset.relpath)
    if path is None:
        raise _missing_preset_error(preset)
    mesh = load_mesh_file(path, progress)
    if mesh.n_triangles != preset.file_triangles:
        log.warning("%s: %d triangles where %d were expected; not the file SOURCES.md describes?",
                    path, mesh.n_triangles, preset.file_triangles)
    return _scene_from_mesh(mesh, preset.name, _presets.preset_camera(preset, size),
                            [_presets.preset_light(preset, mesh.bounds())],
                            "smooth" if preset.smooth_normals else "flat")


def load_file_scene(path: str | os.PathLike, size: int | None = None, progress: Progress | None = None) -> Scene:
    """Any mesh file, framed like the benchmark `far` views, lit from above and in front. What the file
    holds that is read anyway (MeshData.warnings: zero-area triangles, a missing MTL) is a MeshWarning.
    A preset (load_preset) says nothing: its files' quirks are known (SOURCES.md) and would be said at
    every load."""
    mesh = load_mesh_file(path, progress)
    for warning in mesh.warnings:
        warn(warning, MeshWarning, stacklevel=3)
    bounds = mesh.bounds()
    camera = _presets.framing_camera(bounds, _presets.DEFAULT_SIZE if size is None else size)
    return _scene_from_mesh(mesh, mesh.source.stem, camera, [_presets.model_light(bounds)], "auto")


def _unknown_scene_error(name: str) -> SceneError:
    names = ", ".join([*DEFAULT_NAMES, *_presets.PRESETS])
    dirs = ", ".join(str(d) for d in scene_search_dirs())
    return SceneError(f"unknown scene {name!r}: not a preset ({names}) and no such file "
                      f"(looked in the current directory and in {dirs})")


def load_scene(name_or_path: str | os.PathLike = "default", size: int | None = None,
               progress: Progress | None = None) -> Scene:
    """A scene by preset name (case-insensitive), "default"/"procedural", or mesh file path.

    ``size`` sets the camera's width and height (default 1024). Raises SceneError with what was
    looked for and where."""
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise SceneError(f"a scene is a preset name or a mesh file's path, got {type(name_or_path).__name__} "
                         f"{name_or_path!r}")
    text = os.fspath(name_or_path)
    key = text.strip().lower()
    if key in DEFAULT_NAMES:
        return default_scene(_presets.DEFAULT_SIZE if size is None else size)
    preset = _presets.get_preset(key)
    if preset is not None:
        return load_preset(preset, size, progress)
    path = Path(text).expanduser()
    if path.exists():
        return load_file_scene(path, size, progress)
    found = None if path.is_absolute() else find_scene_file(text)
    if found is not None:
        return load_file_scene(found, size, progress)
    raise _unknown_scene_error(text)
