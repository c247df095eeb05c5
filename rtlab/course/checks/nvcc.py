"""Lab step 01's CUDA kernel compiled offline by nvcc (graders have no NVIDIA GPU): :class:`NvccKind`,
and what its check reads of the PTX against the reference's (rtlab.course.ptx_facts)."""
from __future__ import annotations

import functools
import re
import threading
from pathlib import Path

import numpy as np

from .base import Kind, Outcome, Prepared, Produced, setup_tick, spec_variant
from .memory import SCENE_BUFFERS, _fetch_function


class NvccKind(Kind):
    """The step's CUDA kernel compiled offline by nvcc (graders have no NVIDIA GPU; the lab asks for
    the API in both languages): it must compile, the listed student ``functions`` must be written (not
    the template's stub, compared token by token: rtlab.course.regions), and the PTX must show the
    placement, compared with the reference's PTX (the grader compiles it with the same nvcc and
    defines; rtlab.course.ptx_facts):

    * node_memory = "texture": ``fetch_scene`` followed for every buffer and a few threads must store
      what the reference's stores: component by component, the texture fetch of element i (a fetch
      of element 0, of i + 1, or a constant stores something else);
    * ray_memory = "shared": render_primary and trace_rays must store into shared memory, from the
      kernel's inputs (the ray's origin and direction, loaded or computed from the camera), every
      byte of the slot the reference stores from them, with as many distinct values (the stub's
      constant ray, or the thread's index, stores none).

    Where the installation has no reference (a student release) or the reference's PTX cannot be
    followed, only the presence of the texture fetches and shared stores is checked, as before.
    Reports registers, stack, spills and shared memory per kernel (ptxas -v). Without nvcc on the
    grading machine the test is skipped (0 points) and says so."""
    name = "nvcc"
    params = {"kernel": "", "traversal": "", "intersection": "", "node_memory": "", "constants": "",
              "ray_memory": "", "block": None, "functions": [], "arch": "sm_90"}

    def prepare(self, spec, scene):
        return Prepared({"scene": scene})

    @staticmethod
    def build(spec, scene):
        """(defines, compiler options) of the test's CUDA compile: the variant's, on the test's scene."""
        from ...device.device_scene import scene_features, scene_kdtree
        from ...device.kernels import build_defines, build_options
        variant = spec_variant(spec)
        return (build_defines(variant, scene_features(scene, scene_kdtree(scene).depth + 1)),
                build_options(variant, "cuda"))

    def setup(self, spec, inputs, backend, count_work=False):
        from ...device.kernels import kernel_source
        from ...backends.nvcc import nvcc_available, nvcc_ptx, nvcc_resources
        if not nvcc_available():
            return None
        variant = spec_variant(spec)
        defines, options = self.build(spec, inputs["scene"])
        path = kernel_source(spec.params["kernel"] or inputs["step"], "cuda")
        arch = spec.params["arch"]
        setup_tick()
        resources = nvcc_resources(path, defines, arch=arch, block_threads=variant.block[0] * variant.block[1],
                                   extra_options=options)
        setup_tick()
        ptx = nvcc_ptx(path, defines, arch=arch, extra_options=options)
        # what the check reads of the PTX, found here: the process runs no submitted code
        return {"nvcc": True, "source": path.name,
                "resources": {k: {"registers": r.registers, "local_bytes": r.local_bytes, "spill_bytes": r.spill_bytes,
                                  "shared_bytes": r.shared_bytes} for k, r in resources.items()},
                **ptx_facts(ptx, variant.node_memory, variant.ray_memory)}

    def produce(self, state, request):
        return Produced(info=state or {"nvcc": False})

    def check(self, spec, inputs, expected, out):
        info = out.info
        if not info.get("nvcc"):
            return Outcome(0.0, "skipped: nvcc (the CUDA toolkit) is not on PATH on this grading machine, so the "
                                "CUDA kernel was not compiled; the course's grader has it", skipped=True)
        variant = spec_variant(spec)
        resources = info.get("resources") if isinstance(info.get("resources"), dict) else {}
        problems = []
        stubs = sorted(set(spec.params["functions"]) & set(expected.get("stubs", ())))
        if stubs:
            problems.append(f"{', '.join(stubs)} still hold{'s' if len(stubs) == 1 else ''} the template's stub")
        reference = self.reference_facts(spec, inputs, expected)
        if variant.node_memory == "texture":
            for kind in ("int", "float"):
                if not info.get(f"tex_{kind}"):
                    problems.append(f"fetch_scene reads no {kind} data through a texture fetch (no tex.1d ... in its "
                                    f"PTX): the fetch_*_texture functions must read with tex1Dfetch")
            if not problems:
                problems += fetch_problems(info.get("fetch_followed"), reference.get("fetch_followed"))
        if variant.ray_memory == "shared":
            for kernel in ("render_primary", "trace_rays"):
                r = resources.get(kernel)
                # the ray must be stored into the block's slots (nvcc may then forward the stored values
                # to registers instead of loading them back: no ld.shared is required)
                if not isinstance(r, dict) or not info.get("st_shared", {}).get(kernel) or not r.get("shared_bytes"):
                    problems.append(f"{kernel} does not store its ray in shared memory (no st.shared in its PTX, "
                                    f"or no shared memory): place_ray_shared must copy the ray into its slot "
                                    f"and return the slot's address")
                else:
                    problems += shared_problems(kernel, (info.get("shared_stores") or {}).get(kernel),
                                                (reference.get("shared_stores") or {}).get(kernel))
        report = "; ".join(f"{k}: {r.get('registers')} registers, {r.get('local_bytes')} B stack, "
                           f"{r.get('spill_bytes')} B spills, {r.get('shared_bytes')} B shared"
                           for k, r in sorted(resources.items()) if k in ("render_primary", "trace_rays"))
        head = f"{info.get('source')} ({variant.label()}) compiles with nvcc for {spec.params['arch']}: {report}"
        if problems:
            return Outcome(0.0, head + "\n" + "\n".join(problems), resources)
        return Outcome(1.0, head, resources)

    def reference_facts(self, spec, inputs, expected) -> dict:
        """What the reference's PTX shows, compiled by the grader with the test's defines (the same
        nvcc as the test's); {} where the installation has no reference or nvcc fails on it."""
        from ...backends.nvcc import nvcc_available
        from ..kernel_sources import has_reference, reference_kernels
        step = spec.params["kernel"] or expected.get("step")
        if not step or not nvcc_available() or not has_reference(step):
            return {}
        defines, options = self.build(spec, inputs["scene"])
        path = reference_kernels() / "cuda" / f"{step}.cu"
        variant = spec_variant(spec)
        return _reference_facts(str(path), tuple(sorted(defines.items())), spec.params["arch"], tuple(options),
                                variant.node_memory, variant.ray_memory)


def _ptx_entry(ptx: str, kernel: str) -> str:
    m = re.search(rf"\.entry {re.escape(kernel)}\b.*?\n}}", ptx, re.S)
    return m.group(0) if m else ""


SHARED_RAY_KERNELS = ("render_primary", "trace_rays")


def ptx_facts(ptx: str, node_memory: str, ray_memory: str) -> dict:
    """What NvccKind's check reads of a program's PTX (rtlab.course.ptx_facts): the texture fetches in
    fetch_scene and, followed, what it stores; the shared-memory stores of the kernels that place
    their ray in shared memory."""
    from ..ptx_facts import follow_fetch_scene, shared_stores
    fetch = _ptx_entry(ptx, "fetch_scene")
    facts = {"tex_int": bool(re.search(r"\btex\.1d\.v4\.[su]32\.s32\b", fetch)),
             "tex_float": bool(re.search(r"\btex\.1d\.v4\.f32\.s32\b", fetch)),
             "st_shared": {k: bool(re.search(r"\bst\.shared\b", _ptx_entry(ptx, k))) for k in SHARED_RAY_KERNELS}}
    if node_memory == "texture":
        facts["fetch_followed"] = follow_fetch_scene(ptx, len(SCENE_BUFFERS))
    if ray_memory == "shared":
        facts["shared_stores"] = {k: shared_stores(ptx, k) for k in SHARED_RAY_KERNELS}
    return facts


_reference_lock = threading.Lock()


@functools.lru_cache(maxsize=16)
def _reference_facts_cached(path: str, defines: tuple, arch: str, options: tuple, node_memory: str,
                            ray_memory: str) -> dict:
    from ...backends.nvcc import nvcc_ptx
    from ...errors import KernelBuildError
    try:
        ptx = nvcc_ptx(Path(path), dict(defines), arch=arch, extra_options=options)
    except KernelBuildError:
        return {}
    return ptx_facts(ptx, node_memory, ray_memory)


def _reference_facts(*key) -> dict:
    with _reference_lock:          # the grader checks tests in threads: one nvcc of the reference each
        return _reference_facts_cached(*key)


def _buffer_text(text: str) -> str:
    """``i32 #0[71].x`` -> ``nodes[71].x``: a followed fetch named by its scene buffer."""
    def name(m):
        k = int(m.group(2))
        buf = SCENE_BUFFERS[k] if 0 <= k < len(SCENE_BUFFERS) else f"texture {k}"
        as_float = np.dtype(_scene_elements()[k][0]) == np.float32 if k < len(SCENE_BUFFERS) else None
        read = "float" if m.group(1) == "f32" else "int"
        kind = "" if as_float is None or as_float == (read == "float") else f" (read as {read})"
        return f"{buf}{kind}["
    return re.sub(r"\b([if]32) #(\d+)\[", name, text)


def _scene_elements():
    from ...device.device_scene import SCENE_ELEMENTS
    return SCENE_ELEMENTS


def fetch_problems(got, want) -> list[str]:
    """Why fetch_scene, followed, does not store what the reference's does (first difference)."""
    if not isinstance(want, dict) or "stores" not in want:
        return []                    # no reference to compare with (a student release): presence only
    if not isinstance(got, dict) or "stores" not in got:
        why = got.get("error") if isinstance(got, dict) else None
        return [f"fetch_scene's PTX could not be followed ({why or 'missing'}), where the reference's can: "
                f"each fetch_*_texture function reads element i of its texture with one tex1Dfetch"]
    from ..ptx_facts import FETCH_THREADS, fetch_element

    def values(r):
        vals = r[0][1] if r and isinstance(r[0], list) and len(r[0]) == 2 else []
        return "(" + ", ".join(_buffer_text(str(v)) for v in vals) + ")" if r else "nothing"

    problems, seen = [], set()
    for which, rows in sorted(want["stores"].items(), key=lambda kv: int(kv[0])):
        theirs = got["stores"].get(which) if isinstance(got["stores"], dict) else None
        k = int(which)
        dtype, ch = _scene_elements()[k]
        function = _fetch_function(dtype, ch, "cuda")
        if function in seen:
            continue
        pairs = list(zip(FETCH_THREADS, rows, theirs or [[]] * len(rows)))
        # the first difference at an element past 1 shows the index best (element 0 hides it)
        pairs.sort(key=lambda p: fetch_element(*p[0]) < 2)
        for (block, thread), ref_row, row in pairs:
            if row == ref_row:
                continue
            seen.add(function)
            problems.append(f"fetch_scene, followed through its PTX for {SCENE_BUFFERS[k]} ({function}), element "
                            f"{fetch_element(block, thread)}: stores {values(row)} where the reference stores "
                            f"{values(ref_row)}: {function} must return element i of its texture (tex1Dfetch at i), "
                            f"every component")
            break
    return problems


def shared_problems(kernel: str, got, want) -> list[str]:
    """Why a kernel's stores into shared memory do not hold its ray as the reference's do."""
    if not isinstance(want, dict) or not want.get("inputs"):
        return []                    # no reference to compare with: presence only
    got = got if isinstance(got, dict) else {}
    have = set(got.get("inputs") or [])
    missing = [b for b in want["inputs"] if b not in have]
    distinct = int(got.get("distinct") or 0)
    if not missing and distinct >= int(want.get("distinct") or 0):
        return []
    lack = (f"bytes {', '.join(map(str, missing))} of the slot get no value from the ray (a constant, or the "
            f"thread's index, is not the ray)" if missing else
            f"only {distinct} distinct values of the ray reach the slot, the reference's {want.get('distinct')} (one "
            f"of its values stored in several fields?)")
    return [f"{kernel}: place_ray_shared stores {len(have)} of the slot's fields from the kernel's ray (its origin "
            f"and direction) where the reference stores {len(want['inputs'])}: {lack}: place_ray_shared must copy "
            f"the ray it is given into its slot"]
