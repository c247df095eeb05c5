"""The on-disk cache of parsed mesh files: ``.npz`` arrays + a ``.json`` description under
``user_cache_dir()/meshes``, keyed by the file's path, size and mtime (and those of its MTL or glTF
buffers), the loader's version and trimesh's; ``RTLAB_NO_CACHE=1`` turns it off (rtlab.paths)."""
from __future__ import annotations

import hashlib
import json
import logging
import time
from pathlib import Path

import numpy as np
import trimesh

from rtlab.paths import user_cache_dir, write_atomically
from rtlab.scene.mesh import MeshData
from rtlab.scene.model import Material

log = logging.getLogger("rtlab.scene.loader")

# Bump when parsing or the cache layout changes: old cache entries are then ignored.
LOADER_VERSION = 2             # 2: an OBJ face corner of vertex 0 is refused (it was read as another vertex)


def _file_stamp(path: Path) -> list:
    stat = path.stat()
    return [str(path.resolve()), stat.st_size, stat.st_mtime_ns]


def _cache_paths(path: Path) -> tuple[Path, Path]:
    stamp = json.dumps([LOADER_VERSION, trimesh.__version__, np.__version__[:1], _file_stamp(path)])
    key = hashlib.sha256(stamp.encode()).hexdigest()[:24]
    directory = user_cache_dir() / "meshes"
    return directory / f"{path.stem}-{key}.npz", directory / f"{path.stem}-{key}.json"


_CACHED_ARRAYS = ("vertices", "faces", "material_ids", "file_normals", "smooth_normals")


def read_cached_mesh(path: Path) -> MeshData | None:
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


def write_cached_mesh(mesh: MeshData, dependencies: list[Path]) -> None:
    arrays_file, meta_file = _cache_paths(mesh.source)
    arrays = {name: getattr(mesh, name) for name in _CACHED_ARRAYS if getattr(mesh, name) is not None}
    meta = {"loader_version": LOADER_VERSION, "source": str(mesh.source),
            "dependencies": [_file_stamp(d) for d in dependencies],
            "materials": [vars(m) for m in mesh.materials], "looks_smooth": mesh.looks_smooth,
            "n_degenerate": mesh.n_degenerate, "warnings": mesh.warnings}
    try:
        arrays_file.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(arrays_file, lambda f: np.savez(f, **arrays))
        # The JSON is written last: its presence says the arrays are complete.
        write_atomically(meta_file, lambda f: f.write(json.dumps(meta, indent=1).encode()))
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
