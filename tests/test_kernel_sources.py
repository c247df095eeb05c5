"""Every program (lab step or the library's) exists in both languages, compiles in both, and the shared
structs agree in size."""
from __future__ import annotations

import numpy as np
import pytest

from rtlab.backends.nvcc import nvcc_available, nvcc_resources
from rtlab.device.kernels import (SceneFeatures, Variant, build_defines, kernel_programs, kernel_source, lab_steps,
                                  unpaired_steps)
from rtlab.device.layout import STRUCT_SIZES

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
