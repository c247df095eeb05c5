"""The kernel loader: lab step + variant + scene features -> source file and -D define set.

Every lab step is a pair ``kernels/cuda/<step>.cu`` / ``kernels/opencl/<step>.cl``; algorithm code
lives once in ``kernels/shared/*.h``. Variant names map to the integer codes listed atop
``kernels/shared/rt_port.h``. Scene features switch code off that a scene does not need.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from .errors import VariantError
from .paths import KERNEL_DIR

# name -> code; the codes are the RT_* constants atop kernels/shared/rt_port.h. A name is listed
# here once its kernels exist in both languages.
TRAVERSALS = {"stack": 0}
INTERSECTIONS = {"moller": 0}
NODE_MEMORY = {"global": 0}

DEFAULT_BLOCK = (32, 4)   # threads in x (along a row) by y; the paper's Fig. 4 sweeps it


def lab_steps() -> list[str]:
    """Lab steps that have kernels in either language, sorted."""
    cu = {p.stem for p in (KERNEL_DIR / "cuda").glob("*.cu")}
    cl = {p.stem for p in (KERNEL_DIR / "opencl").glob("*.cl")}
    return sorted(cu | cl)


def unpaired_steps() -> dict[str, list[str]]:
    """Steps that exist in one language only (a defect: every step exists as .cu and .cl)."""
    cu = {p.stem for p in (KERNEL_DIR / "cuda").glob("*.cu")}
    cl = {p.stem for p in (KERNEL_DIR / "opencl").glob("*.cl")}
    return {"cuda_only": sorted(cu - cl), "opencl_only": sorted(cl - cu)}


def kernel_source(step: str, language: str) -> Path:
    ext = {"cuda": ".cu", "opencl": ".cl"}[language]
    path = KERNEL_DIR / language / f"{step}{ext}"
    if not path.is_file():
        raise VariantError(f"lab step '{step}' has no {language} kernel ({path}); steps: {', '.join(lab_steps())}")
    return path


def _lookup(table: dict, name: str, what: str) -> int:
    try:
        return table[name]
    except KeyError:
        raise VariantError(f"unknown {what} '{name}'; choose one of: {', '.join(table)}") from None


@dataclass(frozen=True)
class Variant:
    """What the paper varies (§3.1, §4). Each field becomes a -D define or the launch shape."""
    traversal: str = "stack"
    intersection: str = "moller"
    node_memory: str = "global"
    block: tuple[int, int] = DEFAULT_BLOCK

    def __post_init__(self):
        _lookup(TRAVERSALS, self.traversal, "traversal")
        _lookup(INTERSECTIONS, self.intersection, "intersection test")
        _lookup(NODE_MEMORY, self.node_memory, "memory placement")
        if len(self.block) != 2 or min(self.block) < 1:
            raise VariantError(f"block must be two positive sizes (x, y), got {self.block}")

    def with_(self, **kw) -> "Variant":
        return replace(self, **kw)

    def label(self) -> str:
        return f"{self.traversal}/{self.intersection}/{self.node_memory}/{self.block[0]}x{self.block[1]}"


@dataclass(frozen=True)
class SceneFeatures:
    """What a scene needs compiled in; derived by :func:`rtlab.device_scene.scene_features`."""
    stack_size: int = 64          # kd-tree depth + 1
    smooth_normals: bool = False
    n_lights: int = 1
    n_materials: int = 1


def build_defines(variant: Variant, features: SceneFeatures, **extra) -> dict[str, int]:
    """The -D set for one variant on one scene; ``extra`` adds step-specific defines."""
    defines = {
        "RT_TRAVERSAL": _lookup(TRAVERSALS, variant.traversal, "traversal"),
        "RT_ISECT": _lookup(INTERSECTIONS, variant.intersection, "intersection test"),
        "RT_NODE_MEM": _lookup(NODE_MEMORY, variant.node_memory, "memory placement"),
        "RT_STACK_SIZE": max(1, int(features.stack_size)),
        "RT_SMOOTH_NORMALS": int(features.smooth_normals),
        "RT_MAX_LIGHTS": max(1, int(features.n_lights)),
        "RT_MAX_MATERIALS": max(1, int(features.n_materials)),
    }
    defines.update({k: int(v) for k, v in extra.items()})
    return defines


def load_program(backend, step: str, variant: Variant, features: SceneFeatures, **extra):
    """Compile (or fetch from the backend's cache) the step's kernel for this variant and scene."""
    return backend.compile(kernel_source(step, backend.language), build_defines(variant, features, **extra))
