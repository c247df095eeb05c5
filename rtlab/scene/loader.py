"""Loading scenes: mesh files (PLY, OBJ+MTL, glTF/GLB) through trimesh, presets, the default scene.

``load_mesh_file`` reads a file with ``process=False`` (no vertex merging, no face removal), keeps one
material per OBJ ``usemtl`` group, validates what the kernels rely on, and caches the parsed arrays as
``.npz`` + ``.json`` under ``user_cache_dir()/meshes`` (``RTLAB_NO_CACHE=1`` turns that off).
``load_scene`` turns a name or a path into a :class:`Scene` with camera, light and materials.

Triangles of zero area are kept (the kernels must cope with them); how many there are is reported in
``MeshData.warnings``, logged, and available for any scene through :func:`scene_warnings`.
"""
from __future__ import annotations

import io
import hashlib
import json
import logging
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import trimesh

from rtlab.errors import SceneError
from rtlab.paths import find_scene_file, scene_search_dirs, user_cache_dir
from rtlab.scene import presets as _presets
from rtlab.scene.model import Camera, Light, Material, Scene, scale_warning
from rtlab.scene.procedural import default_scene

log = logging.getLogger(__name__)

# Bump when parsing or the cache layout changes: old cache entries are then ignored.
LOADER_VERSION = 1
MESH_SUFFIXES = (".ply", ".obj", ".gltf", ".glb", ".stl", ".off")
NORMAL_MODES = ("auto", "file", "smooth", "flat")
DEFAULT_NAMES = ("default", "procedural")
# "auto" normals are smooth when at most this share of triangles has a corner whose smooth normal
# is over 30 deg off the face normal (measured: bunny 1.3 %, dragon 0.6 %, kitchen 9 %, sponza 24 %).
SMOOTH_CREASE_SHARE = 0.03
CREASE_COS = float(np.cos(np.radians(30.0)))
# Twice the area below this fraction of the longest edge squared counts as zero area: far below
# any real sliver, above float rounding of exactly collinear float32 corners.
DEGENERATE_RATIO = 1e-12
FALLBACK_NORMAL = (0.0, 1.0, 0.0)  # for vertices touched only by zero-area triangles
SLOW_PARSE_BYTES = 4_000_000
GROUP_NAMES_LIBRARY = "__rtlab_group_names__.mtl"
# For files without materials (PLY scans, the conference room): grey-white.
DEFAULT_MATERIAL = Material(name="default", diffuse=(0.8, 0.8, 0.8))

Progress = Callable[[str], None]


@dataclass
class MeshData:
    """One triangle mesh as read from a file, before a camera and lights make it a Scene."""
    source: Path
    vertices: np.ndarray                  # (V, 3) float32
    faces: np.ndarray                     # (F, 3) int32
    material_ids: np.ndarray              # (F,) int32
    materials: list[Material]
    file_normals: np.ndarray | None       # (V, 3) float32 when the file has vertex normals
    smooth_normals: np.ndarray | None     # (V, 3) float32 area-weighted, when it has none
    looks_smooth: bool                    # few creases: a scanned or organic surface
    n_degenerate: int
    warnings: list[str] = field(default_factory=list)
    from_cache: bool = False
    seconds: float = 0.0

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0])

    def bounds(self) -> np.ndarray:
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    def vertex_normals(self, mode: str = "auto") -> np.ndarray | None:
        """Shading normals for ``mode``: "file" (the file's or None), "smooth" (the file's, else
        area-weighted), "flat" (None), "auto" (the file's, else smooth if the mesh looks smooth)."""
        if mode not in NORMAL_MODES:
            raise ValueError(f"normals must be one of {NORMAL_MODES}, not {mode!r}")
        if mode == "flat":
            return None
        if self.file_normals is not None or mode == "file":
            return self.file_normals
        if mode == "smooth" or self.looks_smooth:
            return self.smooth_normals
        return None


# ---- geometry helpers --------------------------------------------------------------------------

def face_cross(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) float64 (b - a) x (c - a): the face normal scaled by twice the area."""
    v = vertices.astype(np.float64)
    a = v[faces[:, 0]]
    e1, e2 = v[faces[:, 1]] - a, v[faces[:, 2]] - a
    cross = np.empty_like(e1)  # by components: np.cross is several times slower here
    cross[:, 0] = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
    cross[:, 1] = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
    cross[:, 2] = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    return cross


def _longest_edge_squared(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    v = vertices.astype(np.float64)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    return np.maximum.reduce([np.einsum("ij,ij->i", d, d) for d in (b - a, c - b, a - c)])


def degenerate_mask(vertices: np.ndarray, faces: np.ndarray, cross: np.ndarray | None = None) -> np.ndarray:
    """(F,) bool: triangles of zero area (repeated corners, or corners on one line)."""
    cross = face_cross(vertices, faces) if cross is None else cross
    twice_area_sq = np.einsum("ij,ij->i", cross, cross)
    return twice_area_sq <= DEGENERATE_RATIO**2 * _longest_edge_squared(vertices, faces) ** 2


def smooth_vertex_normals(vertices: np.ndarray, faces: np.ndarray, cross: np.ndarray | None = None) -> np.ndarray:
    """(V, 3) float32 area-weighted vertex normals; vertices with none get +Y."""
    cross = face_cross(vertices, faces) if cross is None else cross
    corner_vertex = faces.ravel()
    summed = np.stack([np.bincount(corner_vertex, weights=np.repeat(cross[:, axis], 3),
                                   minlength=len(vertices)) for axis in range(3)], axis=1)
    return _unit_rows(summed)


def _unit_rows(vectors: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    unit = np.where(length > 0, vectors / np.where(length > 0, length, 1.0), FALLBACK_NORMAL)
    return unit.astype(np.float32)


def _looks_smooth(faces: np.ndarray, normals: np.ndarray, cross: np.ndarray) -> bool:
    # A fixed stride over the triangles: the share is what matters, and big scans stay fast.
    sample = slice(None, None, max(1, len(faces) // 200_000))
    faces, cross = faces[sample], cross[sample]
    length = np.linalg.norm(cross, axis=1)
    real = length > 0
    if not real.any():
        return False
    face_normal = cross[real] / length[real, None]
    corner_cos = np.stack([np.einsum("ij,ij->i", normals[faces[real, k]], face_normal) for k in range(3)], 1)
    return float((corner_cos.min(1) < CREASE_COS).mean()) <= SMOOTH_CREASE_SHARE


def mesh_warnings(vertices: np.ndarray, faces: np.ndarray, where: str,
                  degenerate: np.ndarray | None = None) -> list[str]:
    """What a tracer should know about a valid mesh: zero-area triangles, unused vertices."""
    warnings = []
    degenerate = np.flatnonzero(degenerate_mask(vertices, faces) if degenerate is None else degenerate)
    if degenerate.size:
        warnings.append(f"{where}: {degenerate.size} of {len(faces)} triangles have zero area "
                        f"(first: triangle {degenerate[0]}); kept as they are")
    unused = len(vertices) - np.count_nonzero(np.bincount(faces.ravel(), minlength=len(vertices)))
    if unused:
        warnings.append(f"{where}: {unused} of {len(vertices)} vertices are used by no triangle")
    return warnings


def scene_warnings(scene: Scene) -> list[str]:
    """:func:`mesh_warnings` for a loaded scene (the Scene keeps no load-time notes), and whether its
    coordinates leave the range where float32 ray tests mean anything (:func:`scale_warning`)."""
    where = scene.source or scene.name
    scale = scale_warning(scene.vertices, where)
    return mesh_warnings(scene.vertices, scene.faces, where) + ([scale] if scale else [])


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


# ---- OBJ / MTL details trimesh does not give us exactly -----------------------------------------

def _mtl_floats(values: list[str]) -> tuple[float, float, float] | None:
    try:
        numbers = [float(x) for x in values[:3]]
    except ValueError:  # "Kd spectral file.rfl" and similar: not supported, keep the default
        return None
    if len(numbers) == 1:
        numbers *= 3
    return tuple(numbers) if len(numbers) == 3 else None


def parse_mtl(path: Path) -> dict[str, Material]:
    """Materials of an MTL file, as exact floats (trimesh's materials round colours to 8 bits)."""
    materials: dict[str, Material] = {}
    current: Material | None = None
    dissolve_seen = False
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        key, values = parts[0], parts[1:]
        if key == "newmtl":
            current = Material(name=" ".join(values))
            materials[current.name] = current
            dissolve_seen = False
        elif current is None or not values:
            continue
        elif key in ("Kd", "Ks") and (rgb := _mtl_floats(values)) is not None:
            setattr(current, "diffuse" if key == "Kd" else "specular", rgb)
        elif key == "Ns":
            current.shininess = float(values[0])
        elif key == "d" and values[0] != "-halo":
            current.transparency = 1.0 - float(values[0])
            dissolve_seen = True
        elif key == "Tr" and not dissolve_seen:  # d wins where a file has both
            current.transparency = float(values[0])
        elif key == "Ni":
            current.ior = float(values[0])
    return materials


def _obj_directives(data: bytes, keyword: bytes) -> list[str]:
    pattern = rb"^[ \t]*" + keyword + rb"[ \t]+(.+?)[ \t]*\r?$"
    return [m.group(1).decode("utf-8", "replace") for m in re.finditer(pattern, data, re.MULTILINE)]


def _obj_material_libraries(path: Path, data: bytes) -> list[Path]:
    libraries = []
    for entry in _obj_directives(data, b"mtllib"):
        candidates = [entry] + entry.split()  # one name with spaces, or several names
        found = next((path.parent / c for c in candidates if (path.parent / c).is_file()), None)
        libraries.append(found if found else path.parent / entry)
    return libraries


def _first_bad_obj_face(path: Path) -> str | None:
    """Where an OBJ face refers to a vertex that does not exist (only run after a failed parse)."""
    n_vertices = 0
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    n_total = sum(1 for line in lines if line.startswith("v "))
    for line_no, line in enumerate(lines, 1):
        if line.startswith("v "):
            n_vertices += 1
        elif line.startswith("f "):
            for token in line.split()[1:]:
                try:
                    index = int(token.split("/")[0])
                except ValueError:
                    return f"line {line_no}: cannot read face corner {token!r}"
                resolved = index - 1 if index > 0 else n_vertices + index
                if not 0 <= resolved < n_total:
                    return (f"line {line_no}: face refers to vertex {index}, but the file has "
                            f"{n_total} vertices (valid: 1..{n_total})")
    return None


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
        detail = _first_bad_obj_face(path) if isinstance(exc, IndexError) and obj_text is not None else None
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


def _point_count(tm_scene) -> int:
    return sum(len(getattr(g, "vertices", ())) for g in tm_scene.geometry.values())


def _apply_mtl(path: Path, obj_text: bytes, usemtl_names: list[str], parts: list[_Part],
               warnings: list[str]) -> list[Path]:
    """Give OBJ groups their exact MTL materials, in order of first use in the file."""
    libraries = _obj_material_libraries(path, obj_text)
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
    usemtl_names = _obj_directives(obj_text, b"usemtl") if is_obj else []
    tm_scene = _trimesh_scene(path, obj_text, usemtl_names)
    parts = _scene_parts(tm_scene)
    if not parts:
        raise SceneError(f"{path}: no triangles (the file holds {_point_count(tm_scene)} vertices and 0 faces)")
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
    file_normals = None if normals is None else _unit_rows(normals)
    smooth = smooth_vertex_normals(vertices, faces, cross) if file_normals is None else None
    mesh = MeshData(source=path, vertices=vertices, faces=faces, material_ids=material_ids,
                    materials=materials, file_normals=file_normals, smooth_normals=smooth,
                    looks_smooth=_looks_smooth(faces, smooth if file_normals is None else file_normals, cross),
                    n_degenerate=int(np.count_nonzero(degenerate)), warnings=warnings,
                    seconds=time.perf_counter() - start)
    return mesh, dependencies


# ---- cache -------------------------------------------------------------------------------------

def cache_enabled() -> bool:
    return os.environ.get("RTLAB_NO_CACHE", "").strip().lower() in ("", "0", "false", "no")


def _file_stamp(path: Path) -> list:
    stat = path.stat()
    return [str(path.resolve()), stat.st_size, stat.st_mtime_ns]


def _cache_paths(path: Path) -> tuple[Path, Path]:
    stamp = json.dumps([LOADER_VERSION, trimesh.__version__, np.__version__[:1], _file_stamp(path)])
    key = hashlib.sha256(stamp.encode()).hexdigest()[:24]
    directory = user_cache_dir() / "meshes"
    return directory / f"{path.stem}-{key}.npz", directory / f"{path.stem}-{key}.json"


_CACHED_ARRAYS = ("vertices", "faces", "material_ids", "file_normals", "smooth_normals")


def _read_cache(path: Path) -> MeshData | None:
    arrays_file, meta_file = _cache_paths(path)
    if not (arrays_file.is_file() and meta_file.is_file()):
        return None
    start = time.perf_counter()
    try:
        meta = json.loads(meta_file.read_text(encoding="utf-8"))
        if any(not Path(dep[0]).is_file() or _file_stamp(Path(dep[0])) != dep for dep in meta["dependencies"]):
            return None  # the MTL (or a glTF buffer) changed since
        with np.load(arrays_file) as stored:
            arrays = {name: (stored[name] if name in stored.files else None) for name in _CACHED_ARRAYS}
        materials = [Material(**{**m, "diffuse": tuple(m["diffuse"]), "specular": tuple(m["specular"])})
                     for m in meta["materials"]]
    except Exception as exc:  # a broken cache entry is only a slower load
        log.debug("ignoring mesh cache entry %s: %s", arrays_file, exc)
        return None
    return MeshData(source=path, materials=materials, looks_smooth=meta["looks_smooth"],
                    n_degenerate=meta["n_degenerate"], warnings=meta["warnings"], from_cache=True,
                    seconds=time.perf_counter() - start, **arrays)


def _write_atomically(target: Path, write) -> None:
    temporary = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        with open(temporary, "wb") as f:
            write(f)
        os.replace(temporary, target)  # readers in other processes never see half a file
    finally:
        temporary.unlink(missing_ok=True)


def _write_cache(mesh: MeshData, dependencies: list[Path]) -> None:
    arrays_file, meta_file = _cache_paths(mesh.source)
    arrays = {name: getattr(mesh, name) for name in _CACHED_ARRAYS if getattr(mesh, name) is not None}
    meta = {"loader_version": LOADER_VERSION, "source": str(mesh.source),
            "dependencies": [_file_stamp(d) for d in dependencies],
            "materials": [vars(m) for m in mesh.materials], "looks_smooth": mesh.looks_smooth,
            "n_degenerate": mesh.n_degenerate, "warnings": mesh.warnings}
    try:
        arrays_file.parent.mkdir(parents=True, exist_ok=True)
        _write_atomically(arrays_file, lambda f: np.savez(f, **arrays))
        # The JSON is written last: its presence says the arrays are complete.
        _write_atomically(meta_file, lambda f: f.write(json.dumps(meta, indent=1).encode()))
        _drop_stale_entries(mesh.source, meta_file)
    except OSError as exc:
        log.debug("could not write mesh cache %s: %s", arrays_file, exc)


def _drop_stale_entries(source: Path, current_meta: Path) -> None:
    """Entries for an older version of the same file would only fill the disk."""
    for meta_file in current_meta.parent.glob(f"{source.stem}-*.json"):
        if meta_file == current_meta:
            continue
        try:
            if json.loads(meta_file.read_text(encoding="utf-8")).get("source") == str(source):
                meta_file.unlink(missing_ok=True)
                meta_file.with_suffix(".npz").unlink(missing_ok=True)
        except (OSError, ValueError):
            continue


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
    return path.resolve()


def load_mesh_file(path: str | os.PathLike, progress: Progress | None = None) -> MeshData:
    """Read and validate a mesh file (cached on disk; see the module docstring). Raises SceneError."""
    path = _mesh_file(path)
    use_cache = cache_enabled()
    mesh = _read_cache(path) if use_cache else None
    if mesh is None:
        mesh, dependencies = _parse(path, progress)
        if use_cache:
            _write_cache(mesh, dependencies)
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
    """Any mesh file, framed like the benchmark `far` views, lit from above and in front."""
    mesh = load_mesh_file(path, progress)
    bounds = mesh.bounds()
    return _scene_from_mesh(mesh, mesh.source.stem, _presets.framing_camera(bounds, size or _presets.DEFAULT_SIZE),
                            [_presets.model_light(bounds)], "auto")


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
    text = os.fspath(name_or_path)
    key = text.strip().lower()
    if key in DEFAULT_NAMES:
        return default_scene(size or _presets.DEFAULT_SIZE)
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
