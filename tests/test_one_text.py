"""A grading test's programs as one text (rtlab.course.one_text): the runtime (PoCL) builds the very
text the grader's rules read, every directive but #pragma resolved once by the rules' clang.

The independent references: the runtime's own answers (a kernel that stores what its compiler saw,
the device's OpenCL queries) and the rules' reading of the same program (its LLVM IR)."""
from __future__ import annotations

import re

import numpy as np
import pytest

from rtlab.course.deps import find_clang, opencl_ir, preprocessed_opencl
from rtlab.course.kernel_sources import reference_kernels
from rtlab.course.one_text import OneText, runtime_macro_values, runtime_tested_macros
from rtlab.errors import KernelBuildError

from .test_sandbox import needs_pocl

pytestmark = [needs_pocl, pytest.mark.skipif(find_clang() is None, reason="no clang on PATH")]

# Macros PoCL's compile defines and the rules' clang does not, or gives another value
DIFFERING = """
#define STR_(x) #x
#define STR(x) STR_(x)
kernel void facts(global long *out) {
#ifdef POCL_DEVICE_ADDRESS_BITS
    out[0] = 1;
#else
    out[0] = 2;
#endif
    out[1] = __OPENCL_C_VERSION__;
    out[2] = sizeof(STR(LLVM_15_0));
}
"""


@pytest.fixture(scope="module")
def pocl():
    from rtlab.backends import get_backend
    return get_backend("opencl", "cpu")


def _tree(tmp_path, text: str, name: str = "probe.cl"):
    (tmp_path / "kernels" / "shared").mkdir(parents=True)
    (tmp_path / "kernels" / "opencl").mkdir()
    path = tmp_path / "kernels" / "opencl" / name
    path.write_text(text)
    return path


def _run_facts(pocl, path) -> list[int]:
    import pyopencl as cl
    program = pocl.compile(path, {})
    out = np.zeros(3, np.int64)
    buf = cl.Buffer(pocl.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=out)
    program.kernel("facts")(pocl.queue, (1,), None, buf)
    cl.enqueue_copy(pocl.queue, out, buf).wait()
    return out.tolist()


def _stores_in_ir(ir: str) -> list[int]:
    """The constants the kernel stores, in order, as the rules' clang reads it (before optimisation)."""
    return [int(v) for v in re.findall(r"store i64 (-?\d+), ", ir)]


def test_the_runtime_runs_the_text_the_rules_read(tmp_path, pocl):
    path = _tree(tmp_path, DIFFERING)
    plain = _run_facts(pocl, path)
    ir = opencl_ir(path, [], {})
    read = _stores_in_ir(ir)
    # the two compilers differ here: the same file reads one way to the rules and runs another way
    assert plain != read, (plain, read)
    pocl.one_text = OneText(pocl, runtime_tested_macros(reference_kernels()))
    try:
        text = pocl.one_text(path, {})
        path_one = path.with_name("probe_one.cl")      # a new program key: the backend caches by path
        path_one.write_text(DIFFERING)
        ran = _run_facts(pocl, path_one)
    finally:
        pocl.one_text = None
    assert not re.search(r"^\s*#\s*(if|ifdef|define|include)", text, re.M)
    assert ran == _stores_in_ir(opencl_ir(path, [], {}, text)) == read


def test_the_runtime_answers_for_its_own_macros(pocl):
    names = ["cl_khr_fp64", "cl_khr_int64_base_atomics", "POCL_DEVICE_ADDRESS_BITS", "__CUDACC__",
             "__ENDIAN_LITTLE__", "RTLAB_NEVER_DEFINED"]
    got = runtime_macro_values(pocl, names)
    extensions = pocl.device.extensions.split()
    assert got["cl_khr_fp64"] == ("1" if "cl_khr_fp64" in extensions else None)
    assert got["cl_khr_int64_base_atomics"] == ("1" if "cl_khr_int64_base_atomics" in extensions else None)
    assert got["POCL_DEVICE_ADDRESS_BITS"] == str(pocl.device.address_bits)
    assert got["__ENDIAN_LITTLE__"] == ("1" if pocl.device.endian_little else None)
    assert got["__CUDACC__"] is None and got["RTLAB_NEVER_DEFINED"] is None


def test_the_kernels_take_the_runtimes_branches(tmp_path, pocl):
    """The names the kernels test are asked of the runtime, and the text follows its answers."""
    names = runtime_tested_macros(reference_kernels())
    assert {"cl_khr_fp64", "__AVX__", "__CUDACC__"} <= set(names)
    assert not any(n.startswith("RT_") for n in names)
    path = _tree(tmp_path, "#include \"rt_port.h\"\nkernel void k(global float *o) { o[0] = 1.0f; }\n")
    (tmp_path / "kernels" / "shared" / "rt_port.h").write_text(
        "#if defined(cl_khr_fp64)\n#define HAS_FP64 11\n#else\n#define HAS_FP64 22\n#endif\n"
        "constant int has_fp64 = HAS_FP64;\n")
    with_fp64 = preprocessed_opencl(path, [path.parent.parent / "shared"], {}, {"cl_khr_fp64": "1"})
    without = preprocessed_opencl(path, [path.parent.parent / "shared"], {}, {"cl_khr_fp64": None})
    assert "has_fp64 = 11" in with_fp64 and "has_fp64 = 22" in without
    assert '# 1 "' + str((tmp_path / "kernels" / "shared" / "rt_port.h").resolve()) + '"' in with_fp64


def test_a_build_error_in_the_one_text_names_the_file_and_line(tmp_path, pocl):
    path = _tree(tmp_path, "kernel void k(global float *o) {\n    o[0] = 1.0f;\n    o[1] = undeclared_name;\n}\n",
                 "broken.cl")
    pocl.one_text = OneText(pocl, ())
    try:
        with pytest.raises(KernelBuildError) as e:
            pocl.compile(path, {})
    finally:
        pocl.one_text = None
    assert re.search(r"broken\.cl:3:\d+\b", str(e.value)), str(e.value)


def test_a_grading_test_compiles_its_opencl_programs_as_one_text():
    from types import SimpleNamespace
    from rtlab.course.run_test import Recorder
    for language, pocl, allowed, wired in (("opencl", True, [], True), ("opencl", True, None, False),
                                           ("opencl", False, [], False), ("cuda", False, [], False)):
        fake = SimpleNamespace(language=language, compile=lambda *a: None, one_text=None, is_pocl=lambda: pocl)
        recorder = Recorder(allowed, runtime_macros=("cl_khr_fp64",))
        recorder.wrap(fake)
        assert (fake.one_text is not None) == wired and fake.one_text is recorder.one_text
        if wired:
            assert fake.one_text.names == ("cl_khr_fp64",)
