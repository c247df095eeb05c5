"""The scene model shared by every part of rtlab: geometry, materials, lights and a camera.

Geometry is an indexed triangle mesh in float32 (the precision the kernels see); the float64
reference promotes these same float32 values, so both trace the very same triangles.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Material:
    name: str = "default"
    diffuse: tuple[float, float, float] = (0.8, 0.8, 0.8)   # MTL Kd
    specular: tuple[float, float, float] = (0.0, 0.0, 0.0)  # MTL Ks
    shininess: float = 0.0                                  # MTL Ns
    reflectivity: float = 0.0                               # fraction of light reflected (mirror)
    transparency: float = 0.0                               # MTL 1-d or Tr: fraction transmitted
    ior: float = 1.0                                        # MTL Ni


@dataclass
class Light:
    """A point light."""
    position: tuple[float, float, float]
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = 1.0


@dataclass
class Camera:
    """Pinhole camera: +Y up by default, vertical field of view in degrees, square pixels."""
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_deg: float = 40.0
    width: int = 1024
    height: int = 1024

    def with_size(self, width: int, height: int | None = None) -> "Camera":
        return Camera(self.eye, self.target, self.up, self.fov_deg, int(width),
                      int(height if height is not None else width))

    def basis(self) -> np.ndarray:
        """(4, 3) float32 rows: eye, u, v, w. A pixel (x, y) (y down) gets the direction
        normalize(w + (2(x+.5)/W - 1) u + (1 - 2(y+.5)/H) v), computed the same way on host and device."""
        eye = np.asarray(self.eye, np.float64)
        fwd = np.asarray(self.target, np.float64) - eye
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, np.asarray(self.up, np.float64))
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        half_h = np.tan(np.radians(self.fov_deg) / 2.0)
        half_w = half_h * self.width / self.height
        return np.stack([eye, right * half_w, up * half_h, fwd]).astype(np.float32)


@dataclass
class Scene:
    name: str
    vertices: np.ndarray                    # (V, 3) float32
    faces: np.ndarray                       # (F, 3) int32
    material_ids: np.ndarray                # (F,) int32 index into materials
    materials: list[Material]
    camera: Camera
    lights: list[Light] = field(default_factory=list)
    vertex_normals: np.ndarray | None = None  # (V, 3) float32, for interpolated shading; None: flat
    source: str = ""                        # file it came from, or "procedural"

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0])

    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float32 corner positions."""
        return self.vertices[self.faces]

    def bounds(self) -> np.ndarray:
        """(2, 3) float32 min and max corner."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])
