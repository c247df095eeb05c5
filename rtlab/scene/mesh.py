"""A triangle mesh as read from a file (:class:`MeshData`), and what the loader checks and derives
from its geometry: zero-area triangles, area-weighted vertex normals, whether it looks smooth, the
warnings a tracer should see."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtlab.scene.model import Material, Scene, scale_warnings

NORMAL_MODES = ("auto", "file", "smooth", "flat")
# "auto" normals are smooth when at most this share of triangles has a corner whose smooth normal
# is over 30 deg off the face normal (measured: bunny 1.3 %, dragon 0.6 %, kitchen 9 %, sponza 24 %).
SMOOTH_CREASE_SHARE = 0.03
CREASE_COS = float(np.cos(np.radians(30.0)))
# Twice the area below this fraction of the longest edge squared counts as zero area: far below
# any real sliver, above float rounding of exactly collinear float32 corners.
DEGENERATE_RATIO = 1e-12
FALLBACK_NORMAL = (0.0, 1.0, 0.0)  # for vertices touched only by zero-area triangles


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
    return unit_rows(summed)


def unit_rows(vectors: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    unit = np.where(length > 0, vectors / np.where(length > 0, length, 1.0), FALLBACK_NORMAL)
    return unit.astype(np.float32)


def mesh_looks_smooth(faces: np.ndarray, normals: np.ndarray, cross: np.ndarray) -> bool:
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
    """:func:`mesh_warnings` for a loaded scene (the Scene keeps no load-time notes), whether its
    coordinates leave the range where float32 ray tests mean anything, and its objects too small for
    float32 where they lie (:func:`rtlab.scene.model.scale_warnings`)."""
    where = scene.source or scene.name
    return mesh_warnings(scene.vertices, scene.faces, where) + scale_warnings(scene.vertices, scene.faces, where)
