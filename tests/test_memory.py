"""Memory placement (lab step 01, §3.1.1), launch shape and ray order (§4.1): every placement, block
shape and ray order must give the very same hits and image as the plain global-memory variant, the
texture path must read every buffer back bit for bit, and the register cap must reach the compiler."""
from __future__ import annotations

import ctypes
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import rtlab
from rtlab.backends.nvcc import nvcc_available, nvcc_resources
from rtlab.device.kernels import (MEMORY_STEP, SceneFeatures, TRACE_THREADS, Variant, build_defines, build_options,
                           kernel_source, load_program, primary_step)
from rtlab.device.rendering import render
from rtlab.device.device_scene import device_scene
from rtlab.errors import VariantError
from rtlab.reference.check import check_render

from .conftest import require_scene_file

SIZE = 64


@pytest.fixture(scope="module")
def default_scene():
    return rtlab.load_scene("default", size=SIZE)


@pytest.fixture(scope="module")
def bunny():
    require_scene_file("bunny.ply")
    return rtlab.load_scene("bunny", size=SIZE)


def placements(backend) -> list[Variant]:
    """Every placement this backend runs, alone and all together."""
    out = [Variant.paper(node_memory="texture"), Variant.paper(constants="global"), Variant.paper(ray_memory="indexed"),
           Variant.paper(node_memory="texture", constants="global", ray_memory="indexed")]
    if backend.language == "cuda":
        out += [Variant.paper(ray_memory="shared"), Variant.paper(node_memory="texture", constants="global", ray_memory="shared")]
    return out


def assert_same_render(result, base, what: str):
    assert np.array_equal(result.hits.tri, base.hits.tri), f"{what}: triangle ids differ"
    assert np.array_equal(result.hits.t.view(np.int32), base.hits.t.view(np.int32)), f"{what}: t differs"
    assert np.array_equal(result.image, base.image), f"{what}: image differs"


@pytest.mark.parametrize("scene_fixture", ["default_scene", "bunny"])
def test_placements_give_the_global_variants_hits(backend, scene_fixture, request):
    scene = request.getfixturevalue(scene_fixture)
    base = render(scene, backend, Variant.paper(), write_hits=True, lab=True)
    # The global variant itself against the float64 reference, so "same as global" means "right"
    report = check_render(scene, base, scene.camera)
    assert report.hits.n_mismatch == 0, report.summary()
    assert report.hits.n_hits_ref > 0.05 * report.hits.n_rays
    for v in placements(backend):
        assert_same_render(render(scene, backend, v, write_hits=True, lab=True), base, f"{scene.name} {v.label()}")


def test_trace_rays_through_placements(backend, default_scene):
    """trace_rays (arbitrary rays, 1-D blocks) in lab step 01's kernels: the same hits as step 00."""
    rng = np.random.default_rng(7)
    lo, hi = default_scene.vertices.min(0), default_scene.vertices.max(0)
    o = rng.uniform(lo, hi, (3000, 3)).astype(np.float32)
    d = rng.normal(size=(3000, 3)).astype(np.float32)
    base = rtlab.trace(default_scene, o, d, backend, Variant.paper(), lab=True)
    assert base.hit.sum() > 300
    for v in placements(backend):
        r = rtlab.trace(default_scene, o, d, backend, v, lab=True)
        assert np.array_equal(r.tri, base.tri), v.label()
        assert np.array_equal(r.t.view(np.int32), base.t.view(np.int32)), v.label()


def _extremes_f4(rng, n):
    a = rng.normal(size=(n, 4)).astype(np.float32) * np.float32(1e3)
    a.flat[:6] = [np.inf, -np.inf, np.nan, -0.0, np.float32(1e-42), np.finfo(np.float32).max]
    return a


def test_texture_round_trip_reads_back_exactly(backend):
    """Every buffer of RT_SCENE_PARAMS through the texture path (fetch_scene of lab step 01) equals
    the host array bit for bit: NaN, infinities, -0 and denormals included, an odd node count (the
    OpenCL node image packs two nodes a texel) and one-element buffers."""
    rng = np.random.default_rng(3)
    info = np.iinfo(np.int32)
    arrays = [
        rng.integers(info.min, info.max, (1001, 2), dtype=np.int32),          # nodes (odd count)
        _extremes_f4(rng, 37),                                                # node_data
        np.array([info.min, info.max, -1, 0, 5], np.int32),                  # objects
        _extremes_f4(rng, 3 * 11),                                            # tris
        _extremes_f4(rng, 1),                                                 # tri_data (dummy)
        _extremes_f4(rng, 3 * 11),                                            # normals
        rng.integers(0, 64, 11, dtype=np.int32),                              # tri_materials
    ]
    from rtlab.device.device_scene import SCENE_ELEMENTS
    buffers = [backend.to_device(a) for a in arrays]
    textures = [backend.texture(b, dt, ch, len(a)) for b, a, (dt, ch) in zip(buffers, arrays, SCENE_ELEMENTS)]
    program = backend.compile(kernel_source(MEMORY_STEP, backend.language),
                              build_defines(Variant.paper(node_memory="texture"), SceneFeatures()))
    for which, a in enumerate(arrays):
        n = len(a)
        out = backend.empty(n * 16)
        program.launch("fetch_scene", (n,), (64,), [t.arg for t in textures] + [np.int32(which), np.int32(n), out])
        got = backend.to_host(out, np.int32, 4 * n).reshape(n, 4)
        want = a.view(np.int32).reshape(n, -1)
        assert np.array_equal(got[:, :want.shape[1]], want), f"buffer {which} differs through the texture path"


def _render_into_sentinel(scene, backend, variant):
    """Pixels of a render into a buffer filled with 0 first: a pixel no thread wrote keeps alpha 0."""
    ds = device_scene(scene, backend)
    program = load_program(backend, primary_step(variant), variant, ds.features(variant))
    ds.set_constants(program, scene.camera, variant)
    n = scene.camera.width * scene.camera.height
    pixels = backend.empty(4 * n)
    backend.fill(pixels, np.zeros(n, np.uint32))
    program.launch("render_primary", (scene.camera.width, scene.camera.height), variant.block,
                   ds.scene_args(variant) + [pixels, backend.empty(4)], constants=("frame", "lights", "materials"))
    return backend.to_host(pixels, np.uint32, n)


@pytest.fixture(scope="module")
def odd_scene():
    """61 x 61 pixels: no block shape below divides it."""
    return rtlab.load_scene("default", size=61)


BLOCKS = [(1, 32), (2, 32), (4, 32), (8, 8), (16, 16), (32, 4), (14, 32), (22, 20), (7, 3)]


def test_block_shapes_give_the_same_image(backend, odd_scene):
    base = _render_into_sentinel(odd_scene, backend, Variant.paper(block=(32, 4)))
    assert (base >> 24 == 255).all(), "a pixel was never written"
    for block in BLOCKS:
        pixels = _render_into_sentinel(odd_scene, backend, Variant.paper(block=block))
        assert np.array_equal(pixels, base), f"block {block[0]}x{block[1]}"


@pytest.mark.parametrize("block", [(32, 4), (8, 8), (16, 16), (32, 32), (4, 32), (1, 32)])
def test_morton_order_writes_every_pixel_once(backend, odd_scene, block):
    rows = _render_into_sentinel(odd_scene, backend, Variant.paper(block=block))
    morton = _render_into_sentinel(odd_scene, backend, Variant.paper(block=block, ray_order="morton"))
    assert (morton >> 24 == 255).all(), "Morton order left pixels unwritten"
    assert np.array_equal(morton, rows)


def test_variant_checks():
    with pytest.raises(VariantError, match="power-of-two"):
        Variant.paper(block=(22, 20), ray_order="morton")
    with pytest.raises(VariantError, match="max_registers"):
        Variant.paper(max_registers=8)
    with pytest.raises(VariantError, match="ray placement"):
        Variant.paper(ray_memory="texture")
    with pytest.raises(VariantError, match="takes rays in packets"):
        primary_step(Variant.paper(traversal="packet", constants="global"))
    assert primary_step(Variant.paper(ray_memory="shared")) == MEMORY_STEP
    assert primary_step(Variant.paper(ray_memory="indexed")) == "00_primary"
    assert Variant.paper().label() == "stack/moller/global/32x4"
    assert Variant().label() == "default/default/global/default"
    assert Variant.paper(node_memory="texture", max_registers=32).label() == "stack/moller/texture/32x4/maxrreg32"


def test_shared_ray_is_cuda_only(backend, default_scene):
    if backend.language == "cuda":
        pytest.skip("CUDA runs it (test_placements_give_the_global_variants_hits)")
    with pytest.raises(VariantError, match="CUDA only"):
        render(default_scene, backend, Variant.paper(ray_memory="shared"), lab=True)
    with pytest.raises(VariantError, match="placement study"):
        render(default_scene, backend, Variant.paper(constants="global"))       # the library's kernels


class _FakeNvidia:
    language = "opencl"

    def is_nvidia(self):
        return True


def test_register_cap_options():
    v = Variant.paper(max_registers=48)
    own = "-DRT_FETCH_MAX_REGISTERS=0"          # the variant's cap also binds the kernel with a cap of its own
    assert build_options(v, "cuda") == ("-maxrregcount=48", own)
    assert build_options(v, _FakeNvidia()) == ("-cl-nv-maxrregcount=48",)
    assert build_options(Variant.paper(), "cuda") == ()
    # the Whitted program's own cap where the variant names none; the variant's cap first; labs none
    assert build_options(Variant.paper(), "cuda", "library_bounces") == ("-maxrregcount=64",)
    assert build_options(Variant.paper(), _FakeNvidia(), "library_bounces") == ("-cl-nv-maxrregcount=64",)
    assert build_options(v, "cuda", "library_bounces") == ("-maxrregcount=48", own)
    assert build_options(Variant.paper(), "cuda", "05_kernel_tree") == ()
    assert build_options(Variant.paper(), "opencl", "library_bounces") == ()      # PoCL: no register file


@pytest.mark.skipif(not nvcc_available(), reason="nvcc not on PATH")
def test_whitted_program_cap_reaches_nvcc():
    """The library's Whitted wavefront kernels with the watertight test, for a SPONZA-like scene (near
    the origin: the fused box test), need more than 64 registers uncapped; built with the options
    the loader gives library_bounces they take at most 64."""
    variant = Variant(traversal="bvh", intersection="watertight", block=(8, 16))
    defines = {**build_defines(variant, SceneFeatures(stack_size=48, n_lights=1, n_materials=16, near_origin=True)),
               "RT_WAVEFRONT": 1, "RT_REFLECTION": 1, "RT_REFRACTION": 1, "RT_MAX_DEPTH": 3}
    src = kernel_source("library_bounces", "cuda")
    free = nvcc_resources(src, defines)["trace_wavefront"].registers
    assert free > 64, f"trace_wavefront needs only {free} registers: the cap no longer binds"
    capped = nvcc_resources(src, defines, extra_options=build_options(variant, "cuda", "library_bounces"))
    assert capped["trace_wavefront"].registers <= 64
    assert capped["trace_wavefront_primary"].registers <= 64


@pytest.mark.skipif(not nvcc_available(), reason="nvcc not on PATH")
def test_trace_program_cap_reaches_nvcc():
    """The options the loader gives library_trace with the 4-wide BVH: a cap of 72 on CUDA, under which
    every trace kernel stays within 72 registers, and on NVIDIA's OpenCL. The binary BVH's trace
    kernels get no cap (ptxas would take it as leave to use more). A variant's own cap comes first, and
    as the loader words it, it reaches ptxas: the ray fetch, above 48 registers free, is built within
    48 (the default cap may not bind: the kernels can fit under it uncapped), the fetch's own cap of 64
    (rt_entry_trace.h) giving way to it."""
    features = SceneFeatures(stack_size=48, near_origin=True)
    src = kernel_source("library_trace", "cuda")
    wide = build_defines(Variant(traversal="bvh4", intersection="watertight", block=(8, 16)), features)
    options = build_options(Variant(traversal="bvh4"), "cuda", "library_trace")
    assert options == ("-maxrregcount=72",)
    capped = nvcc_resources(src, wide, extra_options=options)
    kernels = ("trace_ray_grid", "trace_ray_grid_ordered", "trace_rays", "trace_rays_fetch")
    assert max(capped[k].registers for k in kernels) <= 72
    assert build_options(Variant(traversal="bvh4"), _FakeNvidia(), "library_trace") == ("-cl-nv-maxrregcount=72",)
    assert build_options(Variant(traversal="bvh4"), "opencl", "library_trace") == ()     # PoCL: no register file
    assert build_options(Variant(traversal="bvh"), "cuda", "library_trace") == ()
    named = build_options(Variant(traversal="bvh4", max_registers=48), "cuda", "library_trace")
    assert named == ("-maxrregcount=48", "-DRT_FETCH_MAX_REGISTERS=0")
    free, tight = nvcc_resources(src, wide), nvcc_resources(src, wide, extra_options=named)
    assert free["trace_rays_fetch"].registers > 48 >= tight["trace_rays_fetch"].registers, \
        "the variant's cap did not reach ptxas"


@pytest.mark.skipif(not nvcc_available(), reason="nvcc not on PATH")
def test_register_cap_reaches_nvcc():
    defines = build_defines(Variant.paper(), SceneFeatures(stack_size=32))
    src = kernel_source("00_primary", "cuda")
    free = nvcc_resources(src, defines)["render_primary"].registers
    cap = 24       # below what render_primary takes uncapped (32 to 40 with the stack traversal)
    assert free > cap, f"render_primary needs only {free} registers: pick a lower cap for this test"
    capped = nvcc_resources(src, defines, extra_options=build_options(Variant.paper(max_registers=cap), "cuda"))
    assert capped["render_primary"].registers <= cap


@pytest.mark.skipif(not nvcc_available(), reason="nvcc not on PATH")
def test_cuda_memory_step_keeps_the_ray_in_shared_memory():
    """The shared-ray variant's kernels hold one Ray (44 bytes in CUDA) a thread in shared memory;
    the other placements none."""
    features = SceneFeatures(stack_size=32)
    src = kernel_source(MEMORY_STEP, "cuda")
    shared = nvcc_resources(src, build_defines(Variant.paper(ray_memory="shared", block=(16, 8)), features))
    assert shared["render_primary"].shared_bytes >= 16 * 8 * 44
    assert shared["trace_rays"].shared_bytes >= TRACE_THREADS * 44
    plain = nvcc_resources(src, build_defines(Variant.paper(node_memory="texture", constants="global"), features))
    assert plain["render_primary"].shared_bytes == 0


CUDA_H = Path("/usr/local/cuda/include/cuda.h")


def _cuda_header() -> Path | None:
    nvcc = shutil.which("nvcc")
    candidates = [CUDA_H] + ([Path(nvcc).resolve().parent.parent / "include" / "cuda.h"] if nvcc else [])
    candidates += sorted(Path("/usr/local").glob("cuda-*/include/cuda.h"))
    return next((c for c in candidates if c.is_file()), None)


def test_cuda_texture_descriptors_match_cuda_h(tmp_path):
    """The ctypes mirrors of CUDA_RESOURCE_DESC / CUDA_TEXTURE_DESC have the header's layout."""
    from rtlab.backends import cuda_texture as ct
    header = _cuda_header()
    if header is None or shutil.which("gcc") is None:
        pytest.skip("no cuda.h or gcc here")
    src = tmp_path / "layout.c"
    src.write_text("""#include <cuda.h>
#include <stdio.h>
#include <stddef.h>
int main(void) {
    printf("%zu %zu %zu %zu %zu %zu %zu\\n", sizeof(CUDA_RESOURCE_DESC), offsetof(CUDA_RESOURCE_DESC, res),
           offsetof(CUDA_RESOURCE_DESC, flags), offsetof(CUDA_RESOURCE_DESC, res.linear.format),
           offsetof(CUDA_RESOURCE_DESC, res.linear.numChannels), offsetof(CUDA_RESOURCE_DESC, res.linear.sizeInBytes),
           sizeof(CUDA_TEXTURE_DESC));
    printf("%zu %zu %zu\\n", offsetof(CUDA_TEXTURE_DESC, filterMode), offsetof(CUDA_TEXTURE_DESC, flags),
           offsetof(CUDA_TEXTURE_DESC, borderColor));
    printf("%d %d %d %d %d\\n", CU_RESOURCE_TYPE_LINEAR, CU_AD_FORMAT_SIGNED_INT32, CU_AD_FORMAT_FLOAT,
           CU_TRSF_READ_AS_INTEGER, CU_TR_FILTER_MODE_POINT);
    return 0;
}
""")
    exe = tmp_path / "layout"
    subprocess.run(["gcc", f"-I{header.parent}", str(src), "-o", str(exe)], check=True, capture_output=True)
    lines = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout.split("\n")
    res = ct.CudaResourceDesc
    lin = ct._Linear
    ours = [ctypes.sizeof(res), res.res.offset, res.flags.offset, res.res.offset + lin.format.offset,
            res.res.offset + lin.numChannels.offset, res.res.offset + lin.sizeInBytes.offset,
            ctypes.sizeof(ct.CudaTextureDesc)]
    assert [int(x) for x in lines[0].split()] == ours
    tex = ct.CudaTextureDesc
    assert [int(x) for x in lines[1].split()] == [tex.filterMode.offset, tex.flags.offset, tex.borderColor.offset]
    assert [int(x) for x in lines[2].split()] == [ct.CU_RESOURCE_TYPE_LINEAR, ct.CU_AD_FORMAT_SIGNED_INT32,
                                                  ct.CU_AD_FORMAT_FLOAT, ct.CU_TRSF_READ_AS_INTEGER,
                                                  ct.CU_TR_FILTER_MODE_POINT]


def test_trace_threads_matches_tracing():
    from rtlab.device.tracing import TRACE_BLOCK
    assert TRACE_THREADS == TRACE_BLOCK


STUDENT_FUNCTIONS = {
    "shared/rt_memory.h": ["fetch_int2_texture", "fetch_float4_texture", "fetch_int_texture",
                           "fetch_int2_image", "fetch_float4_image", "fetch_int_image"],
    "cuda/01_memory.cu": ["place_ray_shared"],
}


def absolute_includes(tree):
    """Make the top-level kernels of ``tree`` include its shared headers by absolute path, so they
    compile from anywhere (the backends also search the shared folder of a kernel's own tree)."""
    shared = tree / "shared"
    for f in list((tree / "opencl").glob("*.cl")) + list((tree / "cuda").glob("*.cu")):
        f.write_text(re.sub(r'^(\s*#\s*include\s*)"([^"/]+)"',
                            lambda m: f'{m.group(1)}"{shared / m.group(2)}"' if (shared / m.group(2)).is_file()
                            else m.group(0), f.read_text(), flags=re.M))


def test_lab01_template_compiles_and_every_ray_misses(backend, default_scene, tmp_path):
    """Lab step 01 with every student region replaced by its stub (rtlab.course.regions): both languages
    still compile, and the stubs read as 'no geometry' (a root leaf with no triangles): every pixel misses."""
    from rtlab.course.regions import strip_regions
    from rtlab.paths import KERNEL_DIR
    tree = tmp_path / "kernels"
    shutil.copytree(KERNEL_DIR, tree, ignore=shutil.ignore_patterns("__pycache__"))
    for rel, functions in STUDENT_FUNCTIONS.items():
        f = tree / rel
        f.write_text(strip_regions(f.read_text(), functions, "01_memory", rel))
    absolute_includes(tree)
    features = SceneFeatures(stack_size=32)
    if nvcc_available():
        for v in (Variant.paper(node_memory="texture"), Variant.paper(node_memory="texture", ray_memory="shared")):
            assert "render_primary" in nvcc_resources(tree / "cuda" / "01_memory.cu", build_defines(v, features))
    if backend.language == "cuda":
        return
    v = Variant.paper(node_memory="texture")
    ds = device_scene(default_scene, backend)
    program = backend.compile(tree / "opencl" / "01_memory.cl", build_defines(v, ds.features(v), RT_WRITE_HITS=1))
    ds.set_constants(program, default_scene.camera, v)
    n = SIZE * SIZE
    hits = backend.empty(16 * n)
    program.launch("render_primary", (SIZE, SIZE), v.block, ds.scene_args(v) + [backend.empty(4 * n), hits],
                   constants=("frame", "lights", "materials"))
    tri = backend.to_host(hits, np.float32, 4 * n).view(np.int32)[3::4]
    assert (tri == -1).all()


def test_bench_paper_writes_tables_and_resumes(backend, tmp_path, monkeypatch):
    """`rtlab bench paper` on a small scene: markdown, CSV and the error plot; every placement row
    identical to the global variant; a second run keeps finished sections; a missing bench module is
    reported, not fatal."""
    import csv

    from rtlab.benches import paper
    if backend.language == "cuda":
        pytest.skip("PoCL/NVIDIA OpenCL run is enough for the orchestration")
    d = paper.run_paper(backend, tmp_path, scenes=["default"], size=32, repeats=1, sections=("table2", "memory"))
    rows = list(csv.DictReader(open(d / "paper.csv")))
    memory = [r for r in rows if r["section"] == "memory"]
    assert len(memory) >= 4 and all(r["differs"] == "0" for r in memory)
    assert all(r["mismatches"] == "0" for r in memory)
    assert (d / "error_vs_time.png").stat().st_size > 0
    text = (d / "paper.md").read_text()
    assert "Memory placement" in text and "kd-tree statistics" in text

    def missing(ctx):
        raise ImportError("No module named 'rtlab.benches.not_yet'")
    monkeypatch.setitem(paper.SECTION_FUNCS, "table3", missing)
    paper.run_paper(backend, tmp_path, scenes=["default"], size=32, repeats=1, sections=("memory", "table3"))
    text = (d / "paper.md").read_text()
    assert "done (from an earlier run)" in text and "missing: its bench module is not there yet" in text
