"""The kernel loader: program + variant + scene features -> source file and -D define set.

A program is a kernel pair ``kernels/cuda/<name>.cu`` / ``kernels/opencl/<name>.cl``: the library's
(``library_*``) or a lab step's (``00_primary``...), which program runs what is the variant registry's
choice (rtlab.device.variants.program_for). Entry kernels and algorithm code live once in
``kernels/shared/*.h``. Variant names map to the integer codes listed atop
``kernels/shared/rt_port.h``, read from there (rtlab.kernel_constants). Scene features switch code
off that a scene does not need.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from ..errors import VariantError
from ..kernel_constants import kernel_constant
from ..paths import kernel_dir
from .variants import (CONST_MEMORY, INTERSECTIONS, LIBRARY_PROGRAMS, MEMORY_STEP, NODE_MEMORY, PACKET_LANES,  # noqa: F401
                       PAPER_BLOCK, RAY_MEMORY, RAY_ORDERS, TRAVERSALS, Variant, lookup, program_for)

# threads a block of trace_rays: the launch (rtlab.device.tracing) and, passed back as RT_TRACE_THREADS,
# the size of the kernel's block-wide ray array (a ray in shared memory); the header's default
TRACE_THREADS = int(kernel_constant("RT_TRACE_THREADS"))
DEFAULT_BLOCK = PAPER_BLOCK


def primary_step(variant: Variant) -> str:
    """The lab step with ``trace_rays`` / ``render_primary`` for this variant (the grader's and the
    paper benches' kernels): 01 for its memory placements, 03 for the kd packet, else 00."""
    return program_for("trace", variant, lab=True)


def _stems(language: str) -> set[str]:
    ext = {"cuda": ".cu", "opencl": ".cl"}[language]
    return {p.stem for p in (kernel_dir() / language).glob(f"*{ext}")}


def kernel_programs() -> list[str]:
    """Every program (kernel pair) in either language, sorted: lab steps, then the library's."""
    return sorted(_stems("cuda") | _stems("opencl"))


def lab_steps() -> list[str]:
    """Lab steps that have kernels in either language, sorted (the programs but the library's)."""
    return [p for p in kernel_programs() if p not in LIBRARY_PROGRAMS.values()]


def unpaired_steps() -> dict[str, list[str]]:
    """Programs that exist in one language only (a defect: every program exists as .cu and .cl)."""
    cu, cl = _stems("cuda"), _stems("opencl")
    return {"cuda_only": sorted(cu - cl), "opencl_only": sorted(cl - cu)}


def kernel_source(program: str, language: str) -> Path:
    ext = {"cuda": ".cu", "opencl": ".cl"}[language]
    path = kernel_dir() / language / f"{program}{ext}"
    if not path.is_file():
        raise VariantError(f"program '{program}' has no {language} kernel ({path}); programs: {', '.join(kernel_programs())}")
    return path


@dataclass(frozen=True)
class SceneFeatures:
    """What a scene needs compiled in; derived by :func:`rtlab.device.device_scene.scene_features`."""
    stack_size: int = 64          # kd-tree depth + 1
    smooth_normals: bool = False
    n_lights: int = 1
    n_materials: int = 1
    near_origin: bool = False     # RT_BVH_BOX_FMA: the BVH may use the fused box test (scene.near_origin)
    # Shading features (§3.2): the defaults are the general kernel, which compiles everything in.
    # A scene-specialised kernel leaves out what its scene cannot use; the image does not change.
    has_lights: bool = True       # RT_LIGHTS, RT_SHADOWS: no lights, no lighting loop, no shadow rays
    reflective: bool = True       # RT_REFLECTION: some material reflects (mirror, Fresnel or TIR)
    transparent: bool = True      # RT_REFRACTION: some material transmits
    max_bounces: int = 16         # RT_MAX_DEPTH cap: deepest secondary ray with weight left

    def general(self) -> "SceneFeatures":
        """The same scene without shading specialisation (every shading feature compiled in)."""
        return replace(self, has_lights=True, reflective=True, transparent=True,
                       max_bounces=SceneFeatures.max_bounces)


# The tests that read the three vertices (the others read their own rows of tri_data)
VERTEX_TESTS = ("moller", "watertight")


def uses_leaf_tris(variant: Variant) -> bool:
    """Whether the variant's leaves read a leaf-ordered copy of their triangles from tri_data
    (rt_bvh.h's RT_BVH_LEAF_TRIS, rtlab.accel.tri_data.leaf_tris) in place of objects[] then tris: a
    traversal that offers it, a test that reads vertices, and not a counting build (the work counts
    keep the paper's layout, objects then triangles, which students' loops read too)."""
    return variant.spec.leaf_tris and variant.intersection in VERTEX_TESTS and not variant.count_work


def build_defines(variant: Variant, features: SceneFeatures, trace_threads: int = TRACE_THREADS,
                  **extra) -> dict[str, int]:
    """The -D set for one variant on one scene (the variant resolved for a device: rtlab.device.variants
    .resolve_variant); ``trace_threads`` is the block trace_rays is launched with; ``extra`` adds
    program-specific defines."""
    spec = variant.spec
    defines = {
        "RT_TRAVERSAL": spec.code,
        "RT_ISECT": lookup(INTERSECTIONS, variant.require("intersection"), "intersection test"),
        "RT_NODE_MEM": lookup(NODE_MEMORY, variant.node_memory, "memory placement"),
        "RT_CONST_MEM": lookup(CONST_MEMORY, variant.constants, "constant placement"),
        "RT_RAY_MEM": lookup(RAY_MEMORY, variant.ray_memory, "ray placement"),
        "RT_RAY_ORDER": lookup(RAY_ORDERS, variant.ray_order, "ray order"),
        "RT_STACK_SIZE": max(1, int(features.stack_size)),
        "RT_SHORT_STACK_SIZE": int(variant.short_stack),
        "RT_SMOOTH_NORMALS": int(features.smooth_normals),
        "RT_MAX_LIGHTS": max(1, int(features.n_lights)),
        "RT_MAX_MATERIALS": max(1, int(features.n_materials)),
        "RT_LIGHTS": int(features.has_lights),
        "RT_SHADOWS": int(features.has_lights),
        "RT_REFLECTION": int(features.reflective),
        "RT_REFRACTION": int(features.transparent),
        "RT_MAX_DEPTH": max(0, int(features.max_bounces)),
        "RT_TRACE_THREADS": int(trace_threads),
    }
    if variant.count_work:
        defines["RT_COUNT_WORK"] = 1
    if spec.box_fma:
        defines["RT_BVH_BOX_FMA"] = int(features.near_origin)
    if spec.lanes:
        defines["RT_LANES"] = PACKET_LANES
    if uses_leaf_tris(variant):
        defines["RT_BVH_LEAF_TRIS"] = 1
    if variant.ray_memory == "shared":
        # shared-memory ray slots: one a thread of a render block (a trace_rays block: RT_TRACE_THREADS)
        block = variant.require("block")
        defines["RT_BLOCK_THREADS"] = block[0] * block[1]
    defines.update({k: _define_value(k, v) for k, v in extra.items()})
    return defines


def _define_value(name: str, value) -> int:
    """A -D switch's value as the integer the kernels' #if reads (1, True, "1"); anything else (1.5,
    "1 +", None) is a VariantError naming the switch, not int()'s ValueError or a silent truncation."""
    try:
        number = int(value)
    except (TypeError, ValueError, OverflowError):
        number = None
    if number is None or (isinstance(value, float) and number != value):
        raise VariantError(f"define {name}={value!r}: a -D switch's value must be an integer")
    return number


def rays_per_work_item(variant: Variant) -> int:
    """Rays one work-item of trace_rays takes, and pixels of a row one work-item of render_primary
    takes (the launches cover n / this work-items)."""
    return variant.spec.rays_per_item


# Register caps of library programs where the variant names none. library_bounces (the Whitted frames
# with bounces): 64, the occupancy step of a 128-thread block (32 warps an SM). With the watertight test
# its kernels take more uncapped; capped, they spill only around the test's rarely taken double
# refinement and run faster (docs/results.md, "Whitted: a register cap"). library_trace with the 4-wide
# BVH: 72, under which ptxas schedules its kernels faster than under 64, on CUDA and NVIDIA's OpenCL
# alike (docs/results.md, "trace()'s register cap"); only there, since ptxas reads a cap above a
# kernel's count as leave to use more (the binary BVH's trace_ray_grid takes more under it). Keys: a
# program, or (program, traversal), the more specific first.
LIBRARY_REGISTER_CAPS = {"library_bounces": 64, ("library_trace", "bvh4"): 72}


def build_options(variant: Variant, backend, program: str | None = None) -> tuple[str, ...]:
    """Compiler options beyond the defines: the register cap of the paper's Fig. 5 study, or where the
    variant names none, ``program``'s LIBRARY_REGISTER_CAPS. ``backend`` is a Backend or a language
    name ("cuda" for nvcc). PoCL has no register file to cap: none there. On CUDA a variant's own cap
    binds every kernel, also the one kernel that otherwise takes a cap of its own (the ray fetch,
    rt_entry_trace.h's RT_FETCH_MAX_REGISTERS)."""
    language = backend if isinstance(backend, str) else backend.language
    n = int(variant.max_registers or LIBRARY_REGISTER_CAPS.get((program, variant.traversal))
            or LIBRARY_REGISTER_CAPS.get(program, 0))
    if not n:
        return ()
    if language == "cuda":
        return (f"-maxrregcount={n}",) + (("-DRT_FETCH_MAX_REGISTERS=0",) if variant.max_registers else ())
    if not isinstance(backend, str) and getattr(backend, "is_nvidia", lambda: False)():
        return (f"-cl-nv-maxrregcount={n}",)
    return ()


def load_program(backend, program: str, variant: Variant, features: SceneFeatures, **extra):
    """Compile (or fetch from the backend's cache) ``program``'s kernels for this variant and scene."""
    if variant.needs_memory_kernels() and program != MEMORY_STEP:
        raise VariantError(f"{variant.label()} needs lab step {MEMORY_STEP}'s kernels (constants in global "
                           f"memory or a shared-memory ray), not {program}'s")
    if variant.ray_memory == "shared" and backend.language != "cuda":
        raise VariantError("a ray in shared (OpenCL: local) memory is CUDA only: OpenCL C 1.2 cannot pass a "
                           "__local ray to the shared device functions (no generic address space on PoCL 3.1 or "
                           "NVIDIA's OpenCL)")
    return backend.compile(kernel_source(program, backend.language), build_defines(variant, features, **extra),
                           build_options(variant, backend, program))
