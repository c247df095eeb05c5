"""The scene model shared by every part of rtlab: geometry, materials, lights and a camera.

Geometry is an indexed triangle mesh in float32 (the precision the kernels see); the float64
reference promotes these same float32 values, so both trace the very same triangles.

A Scene checks itself when it is made (:meth:`Scene.validate`; the device upload checks again, since
fields can be reassigned): array shapes, face indices, material ids. Every builder and kernel may
then take the data as valid. A bad scene is one SceneError naming the first bad face, index or id;
coordinates outside the range where float32 ray tests mean anything, and objects too small for
their distance from the origin (rtlab.scene.scale), give a :class:`ScaleWarning`.
A Camera checks itself the same way (:meth:`Camera.__post_init__`).
"""
from __future__ import annotations

import hashlib
import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import RtlabWarning, SceneError

# Largest coordinate magnitude of a scene within which float32 ray tests stay meaningful. Below the
# low end, the products of three coordinate differences that every test forms (Moller-Trumbore's
# t = e2.(s x e1) / det, the watertight test's edge functions times z) fall below float32's normal
# range (1.2e-38) and flush or lose their digits; above the high end they overflow (3.4e38), and
# float32 spacing exceeds 1e6. The watertight test held wherever it was tried inside this range when
# the range was set (CHANGELOG.md, numerics and bad input, second round).
MEANINGFUL_COORDINATES = (1e-12, 1e13)


class ScaleWarning(RtlabWarning):
    """A scene's coordinates lie outside MEANINGFUL_COORDINATES, or an object is too small for float32
    where it lies (rtlab.scene.scale): rays may silently miss."""


class MeshWarning(RtlabWarning):
    """What a mesh file holds that rtlab reads anyway: zero-area triangles, unused vertices, a missing
    material library (rtlab.scene.loader: MeshData.warnings)."""


@dataclass
class Material:
    name: str = "default"
    diffuse: tuple[float, float, float] = (0.8, 0.8, 0.8)   # MTL Kd
    specular: tuple[float, float, float] = (0.0, 0.0, 0.0)  # MTL Ks
    shininess: float = 0.0                                  # MTL Ns
    reflectivity: float = 0.0                               # fraction of light reflected (mirror)
    transparency: float = 0.0                               # MTL 1-d or Tr: fraction transmitted
    ior: float = 1.0                                        # MTL Ni


def material_problem(m: "Material") -> str | None:
    """Why a material's numbers are not ones the shading can use, or None: every number finite, colours
    and shininess >= 0, reflectivity and transparency shares in [0, 1] summing to at most 1, and an
    index of refraction > 0 where the material transmits (MTL files write Ni 0 on opaque ones)."""
    numbers = [*m.diffuse, *m.specular, m.shininess, m.reflectivity, m.transparency, m.ior]
    try:
        if not all(math.isfinite(float(x)) for x in numbers):
            return "its numbers must be finite"
    except (TypeError, ValueError):
        return "its numbers must be numbers"
    if min(*m.diffuse, *m.specular, m.shininess) < 0:
        return "colours and shininess must be >= 0"
    if not (0 <= m.reflectivity <= 1 and 0 <= m.transparency <= 1 and m.reflectivity + m.transparency <= 1 + 1e-6):
        return (f"reflectivity ({m.reflectivity:g}) and transparency ({m.transparency:g}) are shares of the light: "
                f"each in [0, 1], together at most 1")
    if m.transparency > 0 and not m.ior > 0:
        return f"a transparent material's index of refraction must be > 0, got {m.ior:g}"
    return None


@dataclass
class Light:
    """A point light."""
    position: tuple[float, float, float]
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = 1.0


def _vector3(value, what: str) -> np.ndarray:
    try:
        v = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{what} must be three numbers, got {value!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise SceneError(f"{what} must be three finite numbers, got {value!r}")
    return v


# Largest |coordinate| of a light: the shading squares a light's distance in float32 (normalize3), which
# overflows past 1.8e19
LIGHT_MAX_COORDINATE = 1e18


# Smallest sine of the angle between a camera's view direction and its up vector: below it the
# camera's right axis, up x view, is a rounding artefact (the image would be all background).
CAMERA_MIN_UP_SINE = 1e-6


@dataclass
class Camera:
    """Pinhole camera: +Y up by default, vertical field of view in degrees, square pixels.
    Checked when made: finite eye, target and up, eye != target, up not parallel to the view
    direction, 0 < fov_deg < 180, width and height at least 1 (a SceneError says which)."""
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_deg: float = 40.0
    width: int = 1024
    height: int = 1024

    def __post_init__(self):
        eye = _vector3(self.eye, "camera eye")
        view = _vector3(self.target, "camera target") - eye
        up = _vector3(self.up, "camera up")
        if not np.any(view):
            raise SceneError(f"camera eye and target are the same point {tuple(self.eye)}: no view direction")
        if not np.any(up):
            raise SceneError("camera up is the zero vector")
        sine = np.linalg.norm(np.cross(view / np.linalg.norm(view), up / np.linalg.norm(up)))
        if not sine > CAMERA_MIN_UP_SINE:
            raise SceneError(f"camera up {tuple(self.up)} is parallel to the view direction {tuple(view.tolist())} "
                             f"(eye {tuple(self.eye)} -> target {tuple(self.target)}): choose another up")
        if not (isinstance(self.fov_deg, (int, float, np.number)) and 0.0 < float(self.fov_deg) < 180.0):
            raise SceneError(f"camera fov_deg must be between 0 and 180 degrees (exclusive), got {self.fov_deg!r}")
        for name in ("width", "height"):
            size = getattr(self, name)
            if isinstance(size, bool) or not (isinstance(size, (int, np.integer)) and size >= 1):   # True is an int
                raise SceneError(f"camera {name} must be a positive integer, got {size!r}")

    def with_size(self, width: int, height: int | None = None) -> "Camera":
        """The camera at another image size: whole numbers (256 or 256.0); 2.5 is an error, not 2."""
        def whole(x):
            return int(x) if isinstance(x, (float, np.floating)) and float(x).is_integer() else x
        return Camera(self.eye, self.target, self.up, self.fov_deg, whole(width),
                      whole(height if height is not None else width))

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


def _array(value, kind: str, what: str, where: str) -> np.ndarray:
    """``value`` as a numpy array of ``kind`` ("f": real numbers, "i": integers), or a SceneError."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError) as e:
        raise SceneError(f"{where}: {what} is not an array ({e})") from None
    if a.dtype == object or a.dtype.kind not in ("iu" if kind == "i" else "iuf"):
        wanted = "integers" if kind == "i" else "real numbers"
        raise SceneError(f"{where}: {what} must hold {wanted}, got dtype {a.dtype}")
    return a


def _rows3(value, kind: str, what: str, where: str) -> np.ndarray:
    a = _array(value, kind, what, where)
    if a.ndim != 2 or a.shape[1] != 3:
        raise SceneError(f"{where}: {what} must have shape (N, 3), got {a.shape}")
    return a


def finite_magnitude(vertices: np.ndarray) -> float:
    """Largest finite |coordinate| of the vertices (0 when there is none)."""
    a = np.abs(np.asarray(vertices, np.float64))
    finite = a[np.isfinite(a)]
    return float(finite.max()) if finite.size else 0.0


def scale_warning(vertices: np.ndarray, where: str) -> str | None:
    """Why the vertices' coordinates are outside MEANINGFUL_COORDINATES, or None."""
    low, high = MEANINGFUL_COORDINATES
    m = finite_magnitude(vertices)
    if m == 0.0 or low <= m <= high:
        return None
    side = f"all below {low:g}" if m < low else f"as large as {m:.3g}, beyond {high:g}"
    return (f"{where}: coordinates are {side} (largest |coordinate| {m:.3g}); float32 ray tests are only "
            f"meaningful within [{low:g}, {high:g}]: rays may miss silently. Rescale or recentre the scene")


def scale_warnings(vertices: np.ndarray, faces: np.ndarray, where: str) -> list[str]:
    """scale_warning, and the objects float32 cannot hold where they are (rtlab.scene.scale: spawn
    offsets beyond a share of an object's size, triangles collapsed to zero area)."""
    from .scale import object_scale_warnings
    message = scale_warning(vertices, where)
    return ([message] if message else []) + object_scale_warnings(vertices, faces, where)


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

    def __post_init__(self):
        self.validate()
        for message in scale_warnings(self.vertices, self.faces, f"scene {self.name!r}"):
            warnings.warn(message, ScaleWarning, stacklevel=3)

    def validate(self) -> "Scene":
        """Check what every builder and kernel relies on, and store the arrays as the kernels read
        them (float32 vertices and normals, int32 faces and material ids, C order). Raises a
        SceneError naming the first bad face, index or material id. Returns the scene."""
        where = f"scene {self.name!r}"
        vertices = _rows3(self.vertices, "f", "vertices", where)
        faces = _rows3(self.faces, "i", "faces", where)
        if len(faces) == 0:
            raise SceneError(f"{where}: no triangles ({len(vertices)} vertices, 0 faces): there is nothing to trace")
        bad = np.flatnonzero(((faces < 0) | (faces >= len(vertices))).any(axis=1))
        if bad.size:
            raise SceneError(f"{where}: face {bad[0]} = {faces[bad[0]].tolist()} refers to a vertex that does not "
                             f"exist (valid indices 0..{len(vertices) - 1}; {bad.size} of {len(faces)} faces do)")
        ids = _array(self.material_ids, "i", "material_ids", where)
        if ids.shape != (len(faces),):
            raise SceneError(f"{where}: material_ids must hold one id per face, shape ({len(faces)},), got {ids.shape}")
        n_materials = len(self.materials)
        if n_materials == 0:
            raise SceneError(f"{where}: no materials; every face needs one (material_ids index into materials)")
        self.check_materials()
        bad = np.flatnonzero((ids < 0) | (ids >= n_materials))
        if bad.size:
            raise SceneError(f"{where}: face {bad[0]} has material id {ids[bad[0]]}, but the scene has {n_materials} "
                             f"materials (valid ids 0..{n_materials - 1}; {bad.size} of {len(faces)} faces are out of range)")
        if self.vertex_normals is not None:
            normals = _rows3(self.vertex_normals, "f", "vertex_normals", where)
            if len(normals) != len(vertices):
                raise SceneError(f"{where}: vertex_normals must hold one normal per vertex, shape "
                                 f"({len(vertices)}, 3), got {normals.shape}")
            bad = np.flatnonzero(~np.isfinite(normals).all(axis=1))
            if bad.size:
                raise SceneError(f"{where}: vertex normal {bad[0]} is {tuple(normals[bad[0]].tolist())}: normals must be "
                                 f"finite ({bad.size} of {len(normals)} are not; a zero normal is taken as the face's)")
            self.vertex_normals = np.ascontiguousarray(normals, np.float32)
        if not isinstance(self.camera, Camera):
            raise SceneError(f"{where}: camera must be an rtlab Camera, got {type(self.camera).__name__}")
        if not isinstance(self.lights, (list, tuple)) or not all(isinstance(x, Light) for x in self.lights):
            got = next((x for x in self.lights if not isinstance(x, Light)), None) \
                if isinstance(self.lights, (list, tuple)) else self.lights
            raise SceneError(f"{where}: lights must be a list of rtlab Lights, got {type(got).__name__} {got!r:.40}")
        for i, light in enumerate(self.lights):
            _vector3(light.position, f"{where}: light {i}'s position")
        self.vertices = np.ascontiguousarray(vertices, np.float32)
        self.faces = np.ascontiguousarray(faces, np.int32)
        self.material_ids = np.ascontiguousarray(ids, np.int32)
        return self

    def check_lights(self) -> None:
        """SceneError naming the first light too far for the shading (LIGHT_MAX_COORDINATE). The renders
        check it, not the scene: a scene far out still traces (rtlab.trace), lit or not."""
        for i, light in enumerate(self.lights):
            position = _vector3(light.position, f"scene {self.name!r}: light {i}'s position")
            if np.abs(position).max() > LIGHT_MAX_COORDINATE:
                raise SceneError(f"scene {self.name!r}: light {i} at {tuple(position.tolist())} lies beyond "
                                 f"{LIGHT_MAX_COORDINATE:g} from the origin, where float32 squares of its distance "
                                 f"overflow and it lights nothing: move it nearer (so far, a point light is a direction)")

    def check_materials(self) -> None:
        """SceneError naming the first material whose numbers the shading cannot use (material_problem);
        the renders call it again, since materials may be changed after the scene is made."""
        for i, m in enumerate(self.materials):
            why = material_problem(m) if isinstance(m, Material) else f"is a {type(m).__name__}, not an rtlab Material"
            if why:
                raise SceneError(f"scene {self.name!r}: material {i} ({getattr(m, 'name', '?')!r}): {why}")

    @classmethod
    def from_mesh(cls, mesh, **options) -> "Scene":
        """A trimesh.Trimesh (anything with .vertices and .faces) as a scene with a default material,
        a camera framing it and a light: :func:`rtlab.scene_from_arrays` (``options`` are its)."""
        from .arrays import scene_from_arrays
        return scene_from_arrays(mesh, **options)

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0])

    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float32 corner positions."""
        return self.vertices[self.faces]

    def bounds(self) -> np.ndarray:
        """(2, 3) float32 min and max corner."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])


def scene_fingerprint(scene: Scene) -> bytes:
    """Digest of what a device upload holds: vertices, faces, material ids and vertex normals
    (dtype, shape and bytes). The device-scene cache and the reference's camera hits are keyed by it,
    so an edited scene is uploaded and traced again. sha1 for speed, not security: about 15 ms for the 871K-triangle dragon."""
    h = hashlib.sha1(usedforsecurity=False)
    for a in (scene.vertices, scene.faces, scene.material_ids, scene.vertex_normals):
        if a is None:
            h.update(b"none|")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}|".encode())
        h.update(a.reshape(-1).view(np.uint8))
    return h.digest()


class CameraRays(np.ndarray):
    """An (N, 3) array of camera rays that remembers the width of its image (``image_width``), so that
    rtlab.trace takes such rays in tiles without being told ``width=`` (a warp then traces
    neighbouring pixels). Otherwise a plain ndarray. Only what is still the whole image keeps the
    width (a copy, a view of the same shape): arithmetic (``o + t * d``) and a subset give plain
    arrays, which trace() takes in the order given. The hits are the same either way. They also carry
    their ``camera``, from which trace() may launch a GPU's costliest tiles first (rtlab.device.tile_orders):
    that steers the launch order only, never the hits."""
    image_width: int | None
    camera: "Camera | None"

    def __array_finalize__(self, obj):
        same = obj is not None and getattr(obj, "shape", None) == self.shape
        self.image_width = getattr(obj, "image_width", None) if same else None
        self.camera = getattr(obj, "camera", None) if same else None

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        plain = [x.view(np.ndarray) if isinstance(x, CameraRays) else x for x in inputs]
        if "out" in kwargs:
            kwargs["out"] = tuple(x.view(np.ndarray) if isinstance(x, CameraRays) else x for x in kwargs["out"])
        return getattr(ufunc, method)(*plain, **kwargs)


def image_width_of(*arrays) -> int | None:
    """The image width the first of ``arrays`` that is CameraRays carries, else None."""
    for a in arrays:
        w = getattr(a, "image_width", None)
        if w:
            return int(w)
    return None


def image_camera_of(*arrays) -> "Camera | None":
    """The camera the first of ``arrays`` that is CameraRays with a camera carries, else None."""
    for a in arrays:
        c = getattr(a, "camera", None)
        if isinstance(c, Camera):
            return c
    return None


def camera_rays(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """The primary rays of every pixel in float32, row-major from the top-left pixel, built with the
    same operations as camera_ray() in kernels/shared/rt_types.h (the kernels' own rays). Both are
    :class:`CameraRays`: they carry the image's width, which rtlab.trace uses to trace them in tiles."""
    if not isinstance(camera, Camera):
        raise SceneError(f"camera_rays takes an rtlab Camera (scene.camera), got {type(camera).__name__}")
    eye, u, v, w = camera.basis()
    x = np.arange(camera.width, dtype=np.float32)
    y = np.arange(camera.height, dtype=np.float32)
    one, two, half = np.float32(1), np.float32(2), np.float32(0.5)
    sx = two * (x + half) / np.float32(camera.width) - one
    sy = one - two * (y + half) / np.float32(camera.height)
    sx, sy = np.meshgrid(sx, sy)
    d = (w[None, None, :] + u[None, None, :] * sx[..., None]) + v[None, None, :] * sy[..., None]
    d = d * (one / np.sqrt((d * d).sum(axis=-1, dtype=np.float32)))[..., None]
    d = d.reshape(-1, 3).astype(np.float32)
    o = np.broadcast_to(eye, d.shape).astype(np.float32)
    o, d = o.view(CameraRays), d.view(CameraRays)
    o.image_width = d.image_width = int(camera.width)
    o.camera = d.camera = camera
    return o, d
