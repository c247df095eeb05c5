"""Kinds of lab step 01, memory placement (§3.1.1): the scene's buffers read back through a placement,
a placement's render against the global variant's, and the CUDA kernel compiled offline by nvcc."""
from __future__ import annotations

import re

import numpy as np

from .base import (Kind, Outcome, device_scene_of, hit_text, pixel_namer, primary_step_of, setup_tick,
                   spec_variant, vec_text)
from .hits import RenderKind

SCENE_BUFFERS = ("nodes", "node_data", "objects", "tris", "tri_data", "normals", "tri_materials")


def _fetch_function(dtype, channels, language: str) -> str:
    """The rt_memory.h fetch function that reads a buffer of this element type through the placement."""
    base = {(np.dtype(np.int32), 2): "fetch_int2", (np.dtype(np.float32), 4): "fetch_float4",
            (np.dtype(np.int32), 1): "fetch_int"}[(np.dtype(dtype), channels)]
    return base + ("_texture" if language == "cuda" else "_image")


def _path_name(backend) -> str:
    return "texture path" if backend.language == "cuda" else "image path"


def _fetch_test_arrays(count: int, seed: int) -> list[np.ndarray]:
    """One host array a scene buffer (RT_SCENE_PARAMS order): random bits with the float specials
    (NaN, infinities, -0, a denormal, the largest float) up front, an odd node count (the OpenCL node
    image packs two nodes a texel) and a one-element buffer."""
    from ...device.scene import SCENE_ELEMENTS
    rng = np.random.default_rng(seed)
    info = np.iinfo(np.int32)
    out = []
    for k, (dtype, ch) in enumerate(SCENE_ELEMENTS):
        n = 1 if SCENE_BUFFERS[k] == "tri_data" else count | 1
        if np.dtype(dtype) == np.float32:
            a = (rng.normal(size=(n, ch)) * 1e3).astype(np.float32)
            a.flat[:6] = [np.inf, -np.inf, np.nan, -0.0, np.float32(1e-42), np.finfo(np.float32).max][:a.size]
        else:
            a = rng.integers(info.min, info.max, (n, ch), dtype=np.int32)
            a.flat[:2] = [info.min, info.max][:a.size]
        out.append(a.reshape(n) if ch == 1 else a)
    return out


class FetchSceneKind(Kind):
    """Every scene buffer read back through a placement's fetch functions (lab step 01's
    ``fetch_scene`` kernel, any element of any buffer by index) against the host array, bit for bit:
    a placement moves data, it never changes a bit of it."""
    name = "fetch_scene"
    params = {"node_memory": "texture", "count": 1001, "seed": 3}

    def prepare(self, spec, scene):
        return {"arrays": _fetch_test_arrays(int(spec.params["count"]), int(spec.params["seed"]))}

    def setup(self, spec, fixture, backend):
        from ...device.scene import SCENE_ELEMENTS
        from ...device.kernels import MEMORY_STEP, SceneFeatures, build_defines, kernel_source
        variant = spec_variant(spec)
        program = backend.compile(kernel_source(MEMORY_STEP, backend.language),
                                  build_defines(variant, SceneFeatures()))
        arrays = fixture["arrays"]
        buffers = [backend.to_device(a) for a in arrays]
        if variant.node_memory == "texture":
            args = [backend.texture(b, dt, ch, len(a)).arg for b, a, (dt, ch) in zip(buffers, arrays, SCENE_ELEMENTS)]
        else:
            args = buffers
        return backend, program, args, arrays, buffers

    def run(self, state):
        from ...device.scene import SCENE_ELEMENTS
        backend, program, args, arrays, _ = state
        problems, total = [], 0
        for which, a in enumerate(arrays):
            n = len(a)
            out = backend.empty(n * 16)
            program.launch("fetch_scene", (n,), (64,), list(args) + [np.int32(which), np.int32(n), out])
            got = backend.to_host(out, np.int32, 4 * n).reshape(n, 4)
            want = a.view(np.int32).reshape(n, -1)
            got = got[:, :want.shape[1]]
            bad = np.flatnonzero(np.any(got != want, axis=1))
            total += n
            if bad.size:
                i = int(bad[0])
                dtype, ch = SCENE_ELEMENTS[which]
                fmt = (lambda r: vec_text(r.view(np.float32))) if np.dtype(dtype) == np.float32 else \
                      (lambda r: "(" + ", ".join(str(int(x)) for x in r) + ")")
                problems.append(f"{SCENE_BUFFERS[which]} ({_fetch_function(dtype, ch, backend.language)}): "
                                f"{bad.size} of {n} elements differ; first, element {i}: expected {fmt(want[i])}, "
                                f"got {fmt(got[i])}")
        if problems:
            return Outcome(0.0, f"reading the scene buffers through the {_path_name(backend)}:\n" + "\n".join(problems))
        return Outcome(1.0, f"all {total} elements of the 7 scene buffers read back bit for bit through the "
                            f"{_path_name(backend)} (NaN, infinities, -0 and denormals included; {len(arrays[0])} "
                            f"nodes, an odd count)")


def _hit_diff_text(base, got, width: int, what: str) -> tuple[bool, str]:
    """(same, message): a placement's render against the global variant's, bit for bit."""
    tri_b, tri_g = base.hits.tri, got.hits.tri
    t_b, t_g = base.hits.t.view(np.int32), got.hits.t.view(np.int32)
    differ = (tri_b != tri_g) | (t_b != t_g)
    px = np.any(base.image != got.image, axis=-1).reshape(-1)
    if not differ.any() and not px.any():
        return True, f"0 of {differ.size} pixels differ from the global variant (hits bit for bit, image)"
    where = pixel_namer(width)
    if differ.any():
        i = int(np.flatnonzero(differ)[0])
        return False, (f"{int(differ.sum())} of {differ.size} pixels differ from the global variant; first at "
                       f"{where(i)}: global variant: {hit_text(tri_b[i], base.hits.t[i])}, {what}: "
                       f"{hit_text(tri_g[i], got.hits.t[i])}")
    i = int(np.flatnonzero(px)[0])
    return False, (f"the hits match the global variant but {int(px.sum())} pixels' colours differ; first at "
                   f"{where(i)} (normals or materials read wrongly?)")


class PlacementKind(RenderKind):
    """A memory placement (lab step 01) rendering the scene's camera view: every pixel's hit and
    colour identical, bit for bit, to the global-memory variant's (a placement moves data, never a
    result), and the hits right against the float64 reference."""
    name = "placement"
    params = {**RenderKind.params, "node_memory": "texture", "constants": "", "ray_memory": ""}

    def setup(self, spec, fixture, backend):
        from ...device.kernels import load_program
        spec_, fx, backend, variant = super().setup(spec, fixture, backend)
        base = self.global_variant(variant)
        load_program(backend, primary_step_of(base), base, device_scene_of(fx["scene"], backend).features(base),
                     RT_WRITE_HITS=1)
        return spec_, fx, backend, variant

    @staticmethod
    def global_variant(variant):
        return variant.with_(node_memory="global", constants="constant", ray_memory="registers")

    def run(self, state):
        from ...device.rendering import render
        spec, fx, backend, variant = state
        got = self.render(state)
        base = render(fx["scene"], backend, self.global_variant(variant), write_hits=True)
        what = _path_name(backend) if variant.node_memory == "texture" else variant.label()
        same, diff_msg = _hit_diff_text(base, got, fx["scene"].camera.width, what)
        checked = self.check(state, got)
        data = {**checked.data, "differ_from_global": int(not same)}
        fraction = 1.0 if same and checked.fraction >= 1.0 else 0.0
        return Outcome(fraction, f"{variant.label()}: {diff_msg}\nagainst the float64 reference: {checked.output}",
                       data)


class NvccKind(Kind):
    """The step's CUDA kernel compiled offline by nvcc (graders have no NVIDIA GPU; the lab asks for
    the API in both languages): it must compile, the listed student ``functions`` must be written (not
    the template's stub), and the PTX must show the placement: texture fetches of int and float data
    for node_memory = "texture", the ray stored in shared memory for ray_memory = "shared".
    Reports registers, stack, spills and shared memory per kernel (ptxas -v). Without nvcc on the
    grading machine the test is skipped (0 points) and says so."""
    name = "nvcc"
    params = {"kernel": "", "traversal": "", "intersection": "", "node_memory": "", "constants": "",
              "ray_memory": "", "block": None, "functions": [], "arch": "sm_90"}

    def setup(self, spec, fixture, backend):
        from ...device.scene import scene_features, scene_kdtree
        from ...device.kernels import build_defines, build_options, kernel_source
        from ...backends.nvcc import nvcc_available, nvcc_ptx, nvcc_resources
        if not nvcc_available():
            return None
        variant = spec_variant(spec)
        scene = fixture["scene"]
        defines = build_defines(variant, scene_features(scene, scene_kdtree(scene).depth + 1))
        path = kernel_source(spec.params["kernel"] or fixture["step"], "cuda")
        options = build_options(variant, "cuda")
        arch = spec.params["arch"]
        setup_tick()
        resources = nvcc_resources(path, defines, arch=arch, block_threads=variant.block[0] * variant.block[1],
                                   extra_options=options)
        setup_tick()
        return spec, variant, path, resources, nvcc_ptx(path, defines, arch=arch, extra_options=options)

    def run(self, state):
        if state is None:
            return Outcome(0.0, "skipped: nvcc (the CUDA toolkit) is not on PATH on this grading machine, so the "
                                "CUDA kernel was not compiled; the course's grader has it", skipped=True)
        from ...paths import kernel_dir
        from ..regions import stubbed_functions
        spec, variant, path, resources, ptx = state
        problems = []
        wanted = set(spec.params["functions"])
        stubs = sorted({f for src in [*sorted((kernel_dir() / "shared").glob("*.h")), path]
                        for f in stubbed_functions(src.read_text()) if f in wanted})
        if stubs:
            problems.append(f"{', '.join(stubs)} still hold{'s' if len(stubs) == 1 else ''} the template's stub")
        if variant.node_memory == "texture":
            body = _ptx_entry(ptx, "fetch_scene")
            for kind, pattern in (("int", r"\btex\.1d\.v4\.s32\.s32\b"), ("float", r"\btex\.1d\.v4\.f32\.s32\b")):
                if not re.search(pattern, body):
                    problems.append(f"fetch_scene reads no {kind} data through a texture fetch (no tex.1d ... in its "
                                    f"PTX): the fetch_*_texture functions must read with tex1Dfetch")
        if variant.ray_memory == "shared":
            for kernel in ("render_primary", "trace_rays"):
                r = resources.get(kernel)
                # the ray must be stored into the block's slots (nvcc may then forward the stored values
                # to registers instead of loading them back: no ld.shared is required)
                if r is None or not re.search(r"\bst\.shared\b", _ptx_entry(ptx, kernel)) or not r.shared_bytes:
                    problems.append(f"{kernel} does not store its ray in shared memory (no st.shared in its PTX, "
                                    f"or no shared memory): place_ray_shared must copy the ray into its slot "
                                    f"and return the slot's address")
        report = "; ".join(f"{k}: {r.registers} registers, {r.local_bytes} B stack, {r.spill_bytes} B spills, "
                           f"{r.shared_bytes} B shared" for k, r in sorted(resources.items())
                           if k in ("render_primary", "trace_rays"))
        head = f"{path.name} ({variant.label()}) compiles with nvcc for {spec.params['arch']}: {report}"
        data = {k: {"registers": r.registers, "local_bytes": r.local_bytes, "spill_bytes": r.spill_bytes,
                    "shared_bytes": r.shared_bytes} for k, r in resources.items()}
        if problems:
            return Outcome(0.0, head + "\n" + "\n".join(problems), data)
        return Outcome(1.0, head, data)


def _ptx_entry(ptx: str, kernel: str) -> str:
    m = re.search(rf"\.entry {re.escape(kernel)}\b.*?\n}}", ptx, re.S)
    return m.group(0) if m else ""
