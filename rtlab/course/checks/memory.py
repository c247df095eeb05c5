"""Kinds of lab step 01, memory placement (§3.1.1): the scene's buffers read back through a placement,
and a placement's render against the global variant's (the CUDA kernel compiled offline by nvcc:
rtlab.course.checks.nvcc)."""
from __future__ import annotations

import numpy as np

from .base import (Kind, Outcome, Prepared, Produced, device_scene_of, hit_text, pixel_namer, primary_step_of,
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
    from ...device.device_scene import SCENE_ELEMENTS
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
        return Prepared({"arrays": _fetch_test_arrays(int(spec.params["count"]), int(spec.params["seed"]))})

    def variants(self, spec, inputs):
        return []

    def setup(self, spec, inputs, backend, count_work=False):
        from ...device.device_scene import SCENE_ELEMENTS
        from ...device.kernels import MEMORY_STEP, SceneFeatures, build_defines, kernel_source
        variant = spec_variant(spec)
        program = backend.compile(kernel_source(MEMORY_STEP, backend.language),
                                  build_defines(variant, SceneFeatures()))
        arrays = inputs["arrays"]
        buffers = [backend.to_device(a) for a in arrays]
        if variant.node_memory == "texture":
            args = [backend.texture(b, dt, ch, len(a)).arg for b, a, (dt, ch) in zip(buffers, arrays, SCENE_ELEMENTS)]
        else:
            args = buffers
        return backend, program, args, arrays, buffers

    def produce(self, state, request):
        backend, program, args, arrays, _ = state
        out = {}
        for which, a in enumerate(arrays):
            n = len(a)
            buf = backend.empty(n * 16)
            program.launch("fetch_scene", (n,), (64,), list(args) + [np.int32(which), np.int32(n), buf])
            out[SCENE_BUFFERS[which]] = backend.to_host(buf, np.int32, 4 * n).reshape(n, 4)
        return Produced(out)

    def outputs(self, spec, inputs):
        return {SCENE_BUFFERS[k]: (np.int32, (len(a), 4)) for k, a in enumerate(inputs["arrays"])}

    def check(self, spec, inputs, expected, out):
        from ...device.device_scene import SCENE_ELEMENTS
        language = out.info.get("language", "opencl")
        arrays = inputs["arrays"]
        problems, total = [], 0
        for which, a in enumerate(arrays):
            n = len(a)
            got = out.arrays[SCENE_BUFFERS[which]]
            want = a.view(np.int32).reshape(n, -1)
            got = got[:, :want.shape[1]]
            bad = np.flatnonzero(np.any(got != want, axis=1))
            total += n
            if bad.size:
                i = int(bad[0])
                dtype, ch = SCENE_ELEMENTS[which]
                fmt = (lambda r: vec_text(r.view(np.float32))) if np.dtype(dtype) == np.float32 else \
                      (lambda r: "(" + ", ".join(str(int(x)) for x in r) + ")")
                problems.append(f"{SCENE_BUFFERS[which]} ({_fetch_function(dtype, ch, language)}): "
                                f"{bad.size} of {n} elements differ; first, element {i}: expected {fmt(want[i])}, "
                                f"got {fmt(got[i])}")
        path = "texture path" if language == "cuda" else "image path"
        if problems:
            return Outcome(0.0, f"reading the scene buffers through the {path}:\n" + "\n".join(problems))
        return Outcome(1.0, f"all {total} elements of the 7 scene buffers read back bit for bit through the "
                            f"{path} (NaN, infinities, -0 and denormals included; {len(arrays[0])} "
                            f"nodes, an odd count)")


def _hit_diff_text(base_image, base_t, base_tri, image, t, tri, width: int, what: str) -> tuple[bool, str]:
    """(same, message): a placement's render against the global variant's, bit for bit."""
    differ = (base_tri != tri) | (base_t.view(np.int32) != t.view(np.int32))
    px = np.any(base_image != image, axis=-1).reshape(-1)
    if not differ.any() and not px.any():
        return True, f"0 of {differ.size} pixels differ from the global variant (hits bit for bit, image)"
    where = pixel_namer(width)
    if differ.any():
        i = int(np.flatnonzero(differ)[0])
        return False, (f"{int(differ.sum())} of {differ.size} pixels differ from the global variant; first at "
                       f"{where(i)}: global variant: {hit_text(base_tri[i], base_t[i])}, {what}: "
                       f"{hit_text(tri[i], t[i])}")
    i = int(np.flatnonzero(px)[0])
    return False, (f"the hits match the global variant but {int(px.sum())} pixels' colours differ; first at "
                   f"{where(i)} (normals or materials read wrongly?)")


class PlacementKind(RenderKind):
    """A memory placement (lab step 01) rendering the scene's camera view: every pixel's hit and
    colour identical, bit for bit, to the global-memory variant's (a placement moves data, never a
    result), and the hits right against the float64 reference."""
    name = "placement"
    params = {**RenderKind.params, "node_memory": "texture", "constants": "", "ray_memory": ""}
    tolerance = {k: v for k, v in RenderKind.tolerance.items() if k != "work_budget"}

    def counts_work(self, spec):
        return False

    def variants(self, spec, inputs):
        return [spec_variant(spec), self.global_variant(spec_variant(spec))]

    def setup(self, spec, inputs, backend, count_work=False):
        from ...device.kernels import load_program
        spec_, inputs_, backend, variant = super().setup(spec, inputs, backend)
        base = self.global_variant(variant)
        load_program(backend, primary_step_of(base), base, device_scene_of(inputs["scene"], backend).features(base),
                     RT_WRITE_HITS=1)
        return spec_, inputs_, backend, variant

    @staticmethod
    def global_variant(variant):
        return variant.with_(node_memory="global", constants="constant", ray_memory="registers")

    def produce(self, state, request):
        from ...device.rendering import render
        spec, inputs, backend, variant = state
        got = super().produce(state, request)
        base = render(inputs["scene"], backend, self.global_variant(variant), write_hits=True, lab=True)
        got.arrays.update({"global_image": base.image, "global_t": base.hits.t, "global_tri": base.hits.tri})
        return got

    def outputs(self, spec, inputs, camera=None):
        out = super().outputs(spec, inputs, camera)
        return {**out, "global_image": out["image"], "global_t": out["t"], "global_tri": out["tri"]}

    def check(self, spec, inputs, expected, out):
        a = out.arrays
        variant = spec_variant(spec)
        what = ("texture path" if out.info.get("language") == "cuda" else "image path") \
            if variant.node_memory == "texture" else variant.label()
        same, diff_msg = _hit_diff_text(a["global_image"], a["global_t"], a["global_tri"], a["image"], a["t"], a["tri"],
                                        inputs["scene"].camera.width, what)
        checked = super().check(spec, inputs, expected, out)
        data = {**checked.data, "differ_from_global": int(not same)}
        fraction = 1.0 if same and checked.fraction >= 1.0 else 0.0
        return Outcome(fraction, f"{variant.label()}: {diff_msg}\nagainst the float64 reference: {checked.output}",
                       data)
