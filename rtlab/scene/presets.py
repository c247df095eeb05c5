"""Scene presets: the paper's test scenes (Fig. 3: BUNNY, SPONZA, KITCHEN, DRAGON) plus CONFERENCE.

A preset names the file (relative to the scene directories, see :func:`rtlab.paths.scene_search_dirs`),
its expected sha256 and triangle counts (``../shared/scenes/SOURCES.md``), a benchmark camera from
``bench_views.json`` (the same rays as the measured peers in ``../shared/bench``), one point light,
and whether shading normals are smooth or flat.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from rtlab.errors import SceneError
from rtlab.paths import find_scene_file, scene_search_dirs
from rtlab.scene.model import Camera, Light

BENCH_VIEWS_FILE = Path(__file__).with_name("bench_views.json")
DEFAULT_SIZE = 1024


@dataclass(frozen=True)
class Preset:
    name: str
    relpath: str                      # main file, relative to a scene directory
    sha256: str
    paper_triangles: int              # Table 2 of the paper (CONFERENCE: McGuire's archive)
    file_triangles: int               # what the file holds (SOURCES.md)
    file_vertices: int
    view: str                         # key in bench_views.json
    smooth_normals: bool              # scanned surfaces: interpolated normals; architecture: flat
    light_position: tuple[float, float, float] | None  # None: above and in front of the model
    description: str
    companions: tuple[tuple[str, str], ...] = ()  # other files it needs: (relpath, sha256)


PRESETS: dict[str, Preset] = {p.name: p for p in (
    Preset(
        name="bunny", relpath="bunny.ply",
        sha256="e6d5978036051f0ce3a0f2a749a1e8d1aabf07594b14ef4bb7125a5089d6a072",
        paper_triangles=69_451, file_triangles=69_451, file_vertices=35_947,
        view="bunny/fill", smooth_normals=True, light_position=None,
        description="Stanford bunny (bun_zipper.ply), scanned, smooth normals"),
    Preset(
        name="sponza", relpath="sponza/sponza.obj",
        sha256="34963e05f8662455e7c94e5e09fd88fd73dba650d551fb362a7eccb7875d53f5",
        paper_triangles=66_454, file_triangles=66_450, file_vertices=61_014,
        view="sponza/inside", smooth_normals=False,
        # Under the open roof of the atrium, off its symmetry planes.
        light_position=(1.0, 12.0, 0.5),
        description="Dabrovic Sponza atrium (3DS original as OBJ+MTL), 20 materials",
        companions=(("sponza/sponza.mtl",
                     "48fe70988c308da99fb00f8d8a998565fc25209af007b5d7c9f329ff129cad1e"),)),
    Preset(
        name="kitchen", relpath="kitchen/kitchen.obj",
        sha256="634a382bfce92d42cc5024b2bb2b73d6b366eb9bcae5549ee36677c246db4e0f",
        paper_triangles=103_343, file_triangles=103_343, file_vertices=54_838,
        view="kitchen/inside", smooth_normals=False,
        # Centre of the room (4.63 x 4.22, ceiling 2.32), just under the ceiling.
        light_position=(2.3, 2.1, 2.1),
        description="BART kitchen, static geometry (no toy car), 19 materials incl. glass",
        companions=(("kitchen/kitchen.mtl",
                     "4c71648d2f53390a6ea39b9a6d1e44bd5bda004e7cfe10d59b9c86422c44ff5c"),)),
    Preset(
        name="dragon", relpath="dragon.ply",
        sha256="dbc7b119fe87b8730da74b218d38ee9b1a2aad3da91da36d5e6bbcbd2b5730f8",
        paper_triangles=871_414, file_triangles=871_414, file_vertices=437_645,
        view="dragon/fill", smooth_normals=True, light_position=None,
        description="Stanford dragon (dragon_vrip.ply), scanned, smooth normals"),
    Preset(
        name="conference", relpath="conference/conference.obj",
        sha256="00a11d8591de0da656e63d7ec402ab11cd0f521a06cdebea83f2244a0043be6f",
        paper_triangles=331_179, file_triangles=331_179, file_vertices=194_399,
        view="conference/inside", smooth_normals=False,
        # Over the middle of the room, below the ceiling (units as in the file, ~3 mm).
        light_position=(300.0, 560.0, -150.0),
        description="Greg Ward's conference room (Lamar re-creation, 331K), geometry only"),
)}


def get_preset(name: str) -> Preset | None:
    return PRESETS.get(name.strip().lower())


# ---- cameras and lights ------------------------------------------------------------------------

@lru_cache(maxsize=1)
def _bench_views() -> dict:
    with open(BENCH_VIEWS_FILE, encoding="utf-8") as f:
        return json.load(f)


def bench_view_names() -> list[str]:
    return sorted(_bench_views()["views"])


def bench_camera(view: str, size: int = DEFAULT_SIZE) -> Camera:
    """The benchmark camera ``scene/view`` (e.g. ``"bunny/far"``) at ``size`` x ``size`` pixels."""
    views = _bench_views()
    entry = views["views"].get(view)
    if entry is None:
        raise SceneError(f"unknown benchmark view {view!r}; valid views: {', '.join(bench_view_names())}")
    return Camera(eye=tuple(map(float, entry["eye"])), target=tuple(map(float, entry["target"])),
                  up=tuple(map(float, views["up"])), fov_deg=float(views["fov_deg"]),
                  width=size, height=size)       # unconverted: Camera refuses 2.5 rather than take 2


def _centre_and_diagonal(bounds: np.ndarray) -> tuple[np.ndarray, float]:
    lo, hi = np.asarray(bounds, np.float64)
    return (lo + hi) / 2.0, float(np.linalg.norm(hi - lo))


def framing_camera(bounds: np.ndarray, size: int = DEFAULT_SIZE, distance: float = 1.6) -> Camera:
    """Looks at the bounding-box centre from +Z at ``distance`` x the box diagonal, 40 deg, +Y up:
    the construction of the benchmark ``far`` (1.6) and ``fill`` (0.9) views."""
    centre, diagonal = _centre_and_diagonal(bounds)
    eye = centre + np.array([0.0, 0.0, distance * max(diagonal, 1e-6)])
    return Camera(eye=tuple(map(float, eye)), target=tuple(map(float, centre)), width=size, height=size)


def model_light(bounds: np.ndarray) -> Light:
    """A point light above, right of and in front of a model, so a +Z camera sees shading and shadows."""
    centre, diagonal = _centre_and_diagonal(bounds)
    position = centre + max(diagonal, 1e-6) * np.array([0.5, 0.9, 1.2])
    return Light(position=tuple(map(float, position)))


def preset_camera(preset: Preset, size: int | None = None) -> Camera:
    return bench_camera(preset.view, DEFAULT_SIZE if size is None else size)


def preset_light(preset: Preset, bounds: np.ndarray) -> Light:
    if preset.light_position is None:
        return model_light(bounds)
    return Light(position=preset.light_position)


# ---- what is installed -------------------------------------------------------------------------

def file_sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def _checksum_status(preset: Preset, main_file: Path | None) -> str:
    """'ok', 'mismatch' (some file differs from SOURCES.md) or 'missing' (some file not found)."""
    if main_file is None:
        return "missing"
    scene_dir = main_file.parent
    checks = [(main_file, preset.sha256)]
    for relpath, sha in preset.companions:
        # Companions sit beside the main file (an OBJ finds its MTL relative to itself).
        checks.append((scene_dir / Path(relpath).name, sha))
    if not all(p.is_file() for p, _ in checks):
        return "missing"
    return "ok" if all(file_sha256(p) == sha for p, sha in checks) else "mismatch"


def list_scenes() -> list[dict]:
    """One dict per preset: where its file is (or where it was looked for) and whether it checks out."""
    searched = [str(d) for d in scene_search_dirs()]
    rows = []
    for preset in PRESETS.values():
        found = find_scene_file(preset.relpath)
        rows.append({
            "name": preset.name,
            "description": preset.description,
            "paper_triangles": preset.paper_triangles,
            "file_triangles": preset.file_triangles,
            "relpath": preset.relpath,
            "file": preset.relpath,
            "path": str(found) if found else None,
            "searched": searched,
            "sha256": _checksum_status(preset, found),
        })
    return rows

