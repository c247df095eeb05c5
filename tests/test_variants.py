"""The variant registry (rtlab.device.variants): each name's code, source and program; what a Variant
leaves out is the library's default for the device; the paper's variant is named where it is meant;
the library's programs run the same entry kernels as the lab steps."""
from __future__ import annotations

import re

import numpy as np
import pytest

import rtlab
from rtlab.backends.nvcc import nvcc_available, nvcc_resources
from rtlab.device.kernels import SceneFeatures, TRACE_THREADS, build_defines, kernel_source, load_program
from rtlab.device.variants import (CPU_DEFAULT_VARIANT, GPU_DEFAULT_VARIANT, GPU_RAYS_VARIANT, ISECT_FUNCTIONS,
                                   LAB_PROGRAMS, LIBRARY_PROGRAMS, PAPER_VARIANT, SCALAR_CPU_VARIANT,
                                   TRAVERSAL_SPECS, TRAVERSALS, Variant, default_variant, program_for,
                                   resolve_variant)
from rtlab.errors import VariantError
from rtlab.kernel_constants import kernel_constant
from rtlab.paths import REFERENCE_KERNEL_DIR

SHARED = REFERENCE_KERNEL_DIR / "shared"


def _defines_function(header: str, function: str) -> bool:
    return re.search(rf"^RT_FN\s+[\w\s\*]+?\b{function}\s*\(", (SHARED / header).read_text(), re.M) is not None


def _chain_blocks() -> dict[str, str]:
    """rt_traverse.h's #if chain: RT_TRAVERSAL_<NAME> -> the text of its block."""
    text = (SHARED / "rt_traverse.h").read_text()
    parts = re.split(r"^#(?:el)?if RT_TRAVERSAL == (RT_TRAVERSAL_\w+)\s*$", text, flags=re.M)
    return {parts[k]: parts[k + 1].split("\n#else")[0] for k in range(1, len(parts) - 1, 2)}


@pytest.mark.parametrize("name", list(TRAVERSAL_SPECS))
def test_each_traversal_is_where_the_registry_says(name):
    """Its header defines its function, and rt_traverse.h's block for its code includes that header
    (the kd-tree's, which every kd traversal needs, above the chain)."""
    spec = TRAVERSAL_SPECS[name]
    assert _defines_function(spec.header, spec.function), f"{spec.header} defines no {spec.function}"
    define = "RT_TRAVERSAL_" + name.upper().replace("-", "_")
    assert spec.code == int(kernel_constant(define))
    block = _chain_blocks()[define]
    top = (SHARED / "rt_traverse.h").read_text().split("#if RT_TRAVERSAL ==")[0]
    assert f'#include "{spec.header}"' in block or f'#include "{spec.header}"' in top, \
        f"rt_traverse.h does not include {spec.header} for {define}"
    assert set(_chain_blocks()) == {"RT_TRAVERSAL_" + n.upper().replace("-", "_") for n in TRAVERSALS}


def test_each_triangle_test_is_where_the_registry_says():
    for name, function in ISECT_FUNCTIONS.items():
        assert _defines_function("rt_intersect.h", function), function


def test_a_variant_leaves_the_rest_to_the_device():
    assert Variant().unresolved() == ["traversal", "intersection", "block"]
    assert resolve_variant(Variant(), "gpu") == GPU_DEFAULT_VARIANT == resolve_variant(None, "gpu")
    assert resolve_variant(Variant(), "cpu") == CPU_DEFAULT_VARIANT == default_variant("cpu")
    assert resolve_variant(Variant(traversal="stack"), "gpu") == Variant("stack", "watertight", block=(8, 16))
    assert resolve_variant(Variant(intersection="moller", block=(16, 4)), "cpu") == \
        Variant("bvh-packet", "moller", block=(16, 4))
    assert resolve_variant("bvh4", "gpu") == GPU_DEFAULT_VARIANT.with_(traversal="bvh4")
    # rays through trace() on a GPU: the 4-wide BVH where the traversal is left open, frames the binary one
    assert resolve_variant(None, "gpu", rays=True) == GPU_RAYS_VARIANT == GPU_DEFAULT_VARIANT.with_(traversal="bvh4")
    assert resolve_variant("moller", "gpu", rays=True) == Variant("bvh4", "moller", block=(8, 16))
    assert resolve_variant("stack", "gpu", rays=True) == Variant("stack", "watertight", block=(8, 16))
    assert resolve_variant(None, "cpu", rays=True) == CPU_DEFAULT_VARIANT
    assert SCALAR_CPU_VARIANT.unresolved() == CPU_DEFAULT_VARIANT.unresolved() == []
    with pytest.raises(VariantError, match="leaves its traversal to the device"):
        build_defines(Variant(), SceneFeatures())


def test_the_papers_variant_is_named():
    assert Variant.paper() == PAPER_VARIANT == Variant("stack", "moller", block=(32, 4))
    assert Variant.paper(traversal="ropes").label() == "ropes/moller/global/32x4"
    from rtlab.course.checks.base import spec_variant
    from rtlab.course.config import load_config
    # a grading test that names no variant runs the paper's, whatever the library's default is
    spec = next(t for t in load_config("00_primary").tests if t.kind == "trace_rays")
    assert spec_variant(spec) == PAPER_VARIANT
    spec = next(t for t in load_config("03_traversal").tests if t.params.get("traversal") == "bvh")
    assert spec_variant(spec) == Variant("bvh", "moller", block=(32, 4))


def test_a_field_or_define_the_variant_cannot_take_is_one_error():
    """Variant.paper(bogus=1) was dataclasses' TypeError; a define "1 +" (trace(defines=...)) was
    int()'s ValueError, and 1.5 was taken as 1."""
    with pytest.raises(VariantError, match=r"Variant has no field 'bogus'; fields: traversal, intersection, .*block"):
        Variant.paper(bogus=1)
    with pytest.raises(VariantError, match="no field 'bogus'"):
        GPU_DEFAULT_VARIANT.with_(bogus=1)
    for bad in ("1 +", 1.5, None, float("inf")):
        with pytest.raises(VariantError, match=r"define RT_FOO=.*: a -D switch's value must be an integer"):
            build_defines(Variant.paper(), SceneFeatures(), RT_FOO=bad)
    defines = build_defines(Variant.paper(), SceneFeatures(), RT_A="2", RT_B=True, RT_C=3.0, RT_D=np.int64(4))
    assert [defines[k] for k in ("RT_A", "RT_B", "RT_C", "RT_D")] == [2, 1, 3, 4]


def test_programs_by_purpose():
    v = GPU_DEFAULT_VARIANT
    assert [program_for(p, v) for p in ("trace", "loop", "shadows", "bounces")] == \
        ["library_trace", "library_trace", "library_shadows", "library_bounces"]
    assert [program_for(p, v, lab=True) for p in LAB_PROGRAMS] == list(LAB_PROGRAMS.values())
    assert program_for("trace", Variant.paper(constants="global"), lab=True) == "01_memory"
    assert program_for("trace", Variant.paper(traversal="packet"), lab=True) == "03_traversal"
    with pytest.raises(VariantError, match="placement study"):
        program_for("trace", Variant.paper(ray_memory="shared"))
    with pytest.raises(VariantError, match="lab=True"):
        program_for("fetch", v)
    assert set(LIBRARY_PROGRAMS.values()) == {"library_trace", "library_shadows", "library_bounces"}


def test_trace_threads_is_the_headers():
    """The block trace_rays is launched with sizes the kernel's block-wide ray array: one value, the
    header's, passed back to the kernel by the loader."""
    assert TRACE_THREADS == int(kernel_constant("RT_TRACE_THREADS"))
    assert build_defines(PAPER_VARIANT, SceneFeatures())["RT_TRACE_THREADS"] == TRACE_THREADS
    assert build_defines(PAPER_VARIANT, SceneFeatures(), trace_threads=256)["RT_TRACE_THREADS"] == 256


def test_library_and_lab_kernels_give_the_same_hits(backend):
    """trace() and render() on the library's program and on the lab step's (lab=True): the same entry
    kernels, so the same hits and image, for the default variant and the paper's."""
    scene = rtlab.load_scene("default", size=40)
    o, d = rtlab.camera_rays(scene.camera)
    for variant in (None, Variant.paper(), Variant.paper(traversal="packet")):
        lib = rtlab.trace(scene, o, d, backend, variant)
        lab = rtlab.trace(scene, o, d, backend, variant, lab=True)
        assert np.array_equal(lib.tri, lab.tri) and np.array_equal(lib.t, lab.t)
        a = rtlab.render(scene, backend, variant)
        b = rtlab.render(scene, backend, variant, lab=True)
        assert np.array_equal(a.image, b.image)


def test_whitted_runs_the_librarys_program_or_the_labs(backend):
    from rtlab.device.whitted import render_whitted
    scene = rtlab.load_scene("default", size=24)
    lib = render_whitted(scene, backend, bounces=1)
    lab = render_whitted(scene, backend, bounces=1, lab=True)
    assert (lib.step, lab.step) == ("library_bounces", "05_kernel_tree")
    assert np.array_equal(lib.image, lab.image)
    assert render_whitted(scene, backend, Variant.paper(), lab=True).step == "04_shadows"


def test_the_library_compiles_every_traversal(backend):
    """Every traversal of the registry builds in the library's trace program, with its default test."""
    from rtlab.device.device_scene import device_scene
    ds = device_scene(rtlab.load_scene("default", size=8), backend)
    for name in TRAVERSALS:
        v = resolve_variant(Variant(traversal=name), backend)
        load_program(backend, program_for("trace", v), v, ds.features(v))


@pytest.mark.skipif(not nvcc_available(), reason="nvcc not on PATH")
def test_library_trace_kernels_are_lab_step_00s():
    """The library's closest-hit kernels are lab step 00's, compiled from the same entry kernels:
    the same registers, stack and spills for the GPU default (nvcc sm_90)."""
    defines = build_defines(GPU_DEFAULT_VARIANT, SceneFeatures(stack_size=40, near_origin=True))
    lib = nvcc_resources(kernel_source("library_trace", "cuda"), defines)
    lab = nvcc_resources(kernel_source("00_primary", "cuda"), defines)
    for name in ("trace_rays", "trace_ray_grid", "render_primary"):
        a, b = lib[name], lab[name]
        assert (a.registers, a.local_bytes, a.spill_bytes) == (b.registers, b.local_bytes, b.spill_bytes), name
