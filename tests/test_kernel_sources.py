"""Every program (lab step or the library's) exists in both languages, compiles in both, and the shared
structs agree in size."""
from __future__ import annotations

import re
import subprocess

import numpy as np
import pytest

from rtlab.backends.nvcc import nvcc_available, nvcc_resources
from rtlab.device.kernels import (SceneFeatures, Variant, build_defines, build_options, kernel_programs,
                                  kernel_source, lab_steps, unpaired_steps)
from rtlab.device.variants import GPU_RAYS_VARIANT
from rtlab.device.layout import STRUCT_SIZES
from rtlab.paths import PACKAGE_DIR

DEFAULT_DEFINES = build_defines(Variant.paper(), SceneFeatures(stack_size=32, n_lights=2, n_materials=8))


def test_every_step_exists_in_both_languages():
    assert lab_steps(), "no lab step has kernels"
    assert set(kernel_programs()) - set(lab_steps()) == {"library_trace", "library_shadows", "library_bounces"}
    assert unpaired_steps() == {"cuda_only": [], "opencl_only": []}


@pytest.mark.skipif(not nvcc_available(), reason="nvcc not on PATH")
@pytest.mark.parametrize("step", kernel_programs())
def test_cuda_step_compiles_for_sm90(step):
    """`nvcc -cubin -arch=sm_90 -Xptxas -v`: compiles; registers, stack and spills reported."""
    report = nvcc_resources(kernel_source(step, "cuda"), DEFAULT_DEFINES)
    assert report, f"no kernels found in {step}.cu"
    for name, r in report.items():
        print(f"{step}:{name}: {r.registers} registers, {r.local_bytes} B stack, {r.spill_bytes} B spills, "
              f"occupancy {r.occupancy:.0%} at 128 threads")
        assert 0 < r.registers <= 255


@pytest.mark.skipif(not nvcc_available(), reason="nvcc not on PATH")
def test_cuda_ray_fetch_takes_its_own_register_cap():
    """trace()'s ray fetch on the 4-wide tree is built in at most 64 registers (32 warps an SM) with
    nothing spilled, under the library program's cap of 72 that its other kernels still use: the cap
    is the kernel's own (rt_entry_trace.h, RT_FETCH_BOUNDS), not the program's."""
    features = SceneFeatures(stack_size=32, n_lights=0, n_materials=1)
    report = nvcc_resources(kernel_source("library_trace", "cuda"), build_defines(GPU_RAYS_VARIANT, features),
                            extra_options=build_options(GPU_RAYS_VARIANT, "cuda", "library_trace"))
    fetch = report["trace_rays_fetch"]
    release = re.search(r"release (\d+)\.(\d+)", subprocess.run(["nvcc", "--version"], capture_output=True,
                                                                 text=True).stdout)
    if release and (int(release[1]), int(release[2])) < (12, 4):       # no __maxnreg__: the program's cap
        assert fetch.registers <= 72, fetch
        return
    assert fetch.registers <= 64 and fetch.spill_bytes == 0, fetch
    assert max(r.registers for r in report.values()) > 64, "the other kernels keep the program's cap of 72"


@pytest.mark.skipif(not nvcc_available(), reason="nvcc not on PATH")
def test_cuda_camera_ray_kernels_take_their_octant_walks_without_spilling():
    """The library's 4-wide walk inlined once per ray octant (rt_bvh4.h, RT_BVH4_OCTANT_WALKS) in every
    kernel that walks it: nine walks a kernel, still within the program's cap of 72 and nothing spilled."""
    features = SceneFeatures(stack_size=32, n_lights=0, n_materials=1)
    for defines in ({}, {"RT_BVH4_OCTANT_WALKS": 0}):
        report = nvcc_resources(kernel_source("library_trace", "cuda"),
                                {**build_defines(GPU_RAYS_VARIANT, features), **defines},
                                extra_options=build_options(GPU_RAYS_VARIANT, "cuda", "library_trace"))
        for name in ("trace_ray_grid_ordered", "trace_ray_grid", "trace_rays", "render_primary"):
            assert report[name].registers <= 72 and report[name].spill_bytes == 0, (defines, name, report[name])


@pytest.mark.parametrize("step", kernel_programs())
def test_opencl_step_builds(backend, step):
    if backend.language != "opencl":
        pytest.skip("OpenCL source check")
    backend.compile(kernel_source(step, "opencl"), DEFAULT_DEFINES)


SIZEOF_KERNEL = """
#include "rt_types.h"
RT_KERNEL void struct_sizes(RT_GLOBAL int *out)
{
    out[0] = (int)sizeof(RtFrame);
    out[1] = (int)sizeof(RtLight);
    out[2] = (int)sizeof(RtMaterial);
}
"""


WARP_UNIFORM_KERNEL = """
#include "rt_types.h"
/* 128 threads: warp 0 all the same value, warp 1 one lane different, warp 2 alike on its even lanes
   only (the odd ones leave first), warp 3 alike on its odd lanes and different on its even ones */
RT_KERNEL void warp_uniform(RT_GLOBAL int *out)
{
    int i = rt_global_id(0), w = i / 32, lane = i % 32;
    int v = w == 1 ? (lane == 5) : w == 3 ? (lane % 2 ? 7 : lane) : 3;
    if (w >= 2 && (lane % 2) != (w == 3))
        return;
    out[i] = rt_warp_uniform(v);
}
"""


def test_warp_uniform_asks_the_lanes_still_active(backend, tmp_path):
    """rt_warp_uniform (rt_port.h), the 4-wide walk's question before it walks per octant: 1 where
    every active lane of the warp holds the value, 0 where one differs, lanes that left not counted;
    0 everywhere on a device without warps (PoCL), where the walk takes its one form."""
    _check_warp_uniform(backend, tmp_path)


@pytest.mark.gpu
def test_gpu_warp_uniform_on_cuda_and_nvidia_opencl(tmp_path):
    from rtlab.backends import get_backend
    for be in (get_backend("cuda"), get_backend("opencl", "NVIDIA")):
        _check_warp_uniform(be, tmp_path)


def _check_warp_uniform(backend, tmp_path):
    src = tmp_path / ("uniform" + backend.extension)
    src.write_text(WARP_UNIFORM_KERNEL)
    out = backend.to_device(np.full(128, -1, np.int32))
    backend.compile(src, {}).launch("warp_uniform", (128,), (128,), [out])
    got = backend.to_host(out, np.int32, 128).reshape(4, 32)
    if not backend.has_warp_votes():
        assert np.all((got == 0) | (got == -1)), got
        return
    assert np.all(got[0] == 1) and np.all(got[1] == 0), got[:2]
    assert np.all(got[2, ::2] == 1) and np.all(got[2, 1::2] == -1), got[2]
    assert np.all(got[3, 1::2] == 1) and np.all(got[3, ::2] == -1), got[3]


def test_struct_sizes_match_numpy_mirrors(backend, tmp_path):
    src = tmp_path / ("sizes" + backend.extension)
    src.write_text(SIZEOF_KERNEL)
    program = backend.compile(src, {})
    out = backend.empty(3 * 4)
    program.launch("struct_sizes", (1,), (1,), [out])
    sizes = backend.to_host(out, np.int32, 3)
    assert dict(zip(["RtFrame", "RtLight", "RtMaterial"], sizes.tolist())) == STRUCT_SIZES


def test_build_error_names_file_and_defines(backend, tmp_path):
    from rtlab.errors import KernelBuildError
    src = tmp_path / ("broken" + backend.extension)
    src.write_text('#include "rt_types.h"\nRT_KERNEL void broken(RT_GLOBAL int *out)\n{\n    out[0] = undeclared_name;\n}\n')
    with pytest.raises(KernelBuildError) as e:
        backend.compile(src, {"RT_STACK_SIZE": 7})
    msg = str(e.value)
    assert "broken" in msg and "RT_STACK_SIZE=7" in msg
    assert "undeclared_name" in msg


# ---- the host's constants against what the kernels were compiled with -----------------------------

def _compiled_constants(backend, tmp_path, program: str, defines: dict, expected: dict) -> tuple[list[str], set]:
    """Compile ``program`` with ``defines`` and a probe kernel that writes the compiled value of every
    name in ``expected`` the program defines: ('NAME: host v, kernel w' for each that differs, the
    names the program defines)."""
    names = sorted(expected)
    lines = []
    for k, n in enumerate(names):
        value = f"(int)({n})" if isinstance(expected[n], int) else f"rt_as_int((float)({n}))"
        lines += [f"#ifdef {n}", f"    out[{2 * k}] = 1; out[{2 * k + 1}] = {value};", "#endif"]
    src = tmp_path / (f"probe_{program}" + backend.extension)
    src.write_text(f'#include "{kernel_source(program, backend.language)}"\n'
                   "RT_KERNEL void probe_constants(RT_GLOBAL int *out)\n{\n" + "\n".join(lines) + "\n}\n")
    out = backend.to_device(np.zeros(2 * len(names), np.int32))
    backend.compile(src, defines).launch("probe_constants", (1,), (1,), [out])
    got = backend.to_host(out, np.int32, 2 * len(names)).reshape(-1, 2)
    wrong, defined = [], set()
    for n, (is_defined, value) in zip(names, got.tolist()):
        if not is_defined:
            continue
        defined.add(n)
        host = expected[n]
        want = int(np.int64(host).astype(np.uint32).view(np.int32)) if isinstance(host, int) else \
            int(np.float32(host).view(np.int32))
        if value != want:
            seen = value if isinstance(host, int) else float(np.int32(value).view(np.float32))
            wrong.append(f"{program}: {n}: host {host}, kernel {seen}")
    return wrong, defined


def test_host_constants_are_what_the_kernels_compiled(backend, tmp_path):
    """Every constant the host reads from the headers (rtlab.kernel_constants: layout strides and
    bits, variant codes, the trace block, the ray tree's sentinels) and every -D it passes holds,
    inside the compiled library programs, the value the host uses: a host misreading of a header
    expression, a header that redefines a -D, or a renamed constant fails here. Each constant is
    seen in at least one of the programs compiled (every wide BVH, ropes, the kernel tree)."""
    from rtlab.device.kernels import PACKET_LANES
    from rtlab.device.tracing import TRACE_BLOCK
    from rtlab.device.variants import CPU_DEFAULT_VARIANT, GPU_DEFAULT_VARIANT, resolve_variant
    from rtlab.kernel_constants import HEADERS, kernel_constants, parse_defines
    from rtlab.paths import REFERENCE_KERNEL_DIR
    header = kernel_constants()

    def host_table(defines):
        """The host's reading of the headers as the compiler sees them with these -D (a -D wins over an
        #ifndef default; a name derived from a -D, such as RT_CONSERVATIVE, follows it)."""
        table = dict(defines)
        for name in HEADERS:
            table = parse_defines((REFERENCE_KERNEL_DIR / "shared" / name).read_text(), table)
        return table

    features = SceneFeatures(stack_size=24, n_lights=2, n_materials=3)
    builds = [("library_trace", GPU_DEFAULT_VARIANT), ("library_trace", CPU_DEFAULT_VARIANT),
              ("library_trace", Variant(traversal="bvh8")), ("library_trace", Variant(traversal="bvh4")),
              ("library_trace", Variant(traversal="ropes")), ("library_bounces", GPU_DEFAULT_VARIANT)]
    wrong, seen = [], set()
    for program, variant in builds:
        variant = resolve_variant(variant, backend)
        # the frames' program with its shadow rays through light buffers (rt_light_buffer.h's layout)
        defines = {**build_defines(variant, features), **({"RT_SHADOWS": 1, "RT_LIGHT_BUFFER": 1}
                                                          if program == "library_bounces" else {})}
        assert defines["RT_TRACE_THREADS"] == TRACE_BLOCK
        if variant.spec.lanes:
            assert defines["RT_LANES"] == PACKET_LANES == variant.spec.rays_per_item
        bad, defined = _compiled_constants(backend, tmp_path, program, defines, host_table(defines))
        assert set(defines) <= defined, f"{program}: -D names the program does not see: {set(defines) - defined}"
        wrong += bad
        seen |= defined
        # what the host reads with kernel_constant(...) is what this build compiled (a -D it passes aside)
        used = {n for f in PACKAGE_DIR.rglob("*.py") for n in re.findall(r'kernel_constant\("(\w+)"\)', f.read_text())}
        compiled = host_table(defines)
        wrong += [f"{program}: {n}: the host uses {header[n]}, this build compiles {compiled[n]}"
                  for n in sorted(used - set(defines)) if compiled.get(n) != header[n]]
    assert not wrong, wrong
    assert not set(header) - seen, f"header constants no compiled program defines: {sorted(set(header) - seen)}"
    # and the probe sees a difference where there is one
    defines = build_defines(resolve_variant(GPU_DEFAULT_VARIANT, backend), features)
    off = {**host_table(defines), "RT_TRACE_THREADS": TRACE_BLOCK + 1, "BVH_LEAF_BITS": header["BVH_LEAF_BITS"] + 1}
    assert len(_compiled_constants(backend, tmp_path, "library_trace", defines, off)[0]) == 2
