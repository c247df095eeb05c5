"""Probes for tests and tools: the kernels' own spawn and shadow-ray functions (rt_whitted.h) on
arbitrary hits, through the library's probe kernels (probe_shadow, probe_secondary, probe_refract in
library_shadows and library_bounces). They answer what the shading kernels would do with a hit, without
a render. And the brute force in the kernels' own arithmetic (trace_rays_loop, rt_entry_loop.h), which
every traversal must match exactly.
"""
from __future__ import annotations

import numpy as np

from ..backends import get_backend
from ..errors import RtlabError
from ..kernel_constants import kernel_constant
from ..scene.model import Scene
from .kernels import SceneFeatures, build_defines, kernel_source, load_program
from .layout import float4_rows
from .device_scene import device_scene
from .tracing import TraceResult, unpack_hits
from .variants import Variant, program_for, resolve_variant

SECONDARY_KINDS = {"reflection": int(kernel_constant("RT_RAY_REFLECTION")),
                   "refraction": int(kernel_constant("RT_RAY_REFRACTION"))}
PROBE_BLOCK = (128,)


def hit_records(t, tri, u, v) -> np.ndarray:
    """(N, 4) float32 hit records as the kernels store them: t, u, v, triangle id bits."""
    rec = np.zeros((len(tri), 4), np.float32)
    rec[:, 0], rec[:, 1], rec[:, 2] = t, u, v
    rec[:, 3] = np.asarray(tri, np.int32).view(np.float32)
    return rec


def _probe_program(scene: Scene, backend, purpose: str, variant: Variant | None):
    if not hasattr(backend, "compile"):
        backend = get_backend(backend)
    variant = resolve_variant(variant, backend)
    ds = device_scene(scene, backend)
    program = load_program(backend, program_for(purpose, variant), variant, ds.features(variant))
    ds.set_constants(program, None, variant)
    return backend, program, ds.scene_args(variant)


def probe_shadow_rays(scene: Scene, backend, directions, hits: TraceResult, targets,
                      variant: Variant | None = None) -> np.ndarray:
    """(N,) bool: whether the shadow ray of rtlab's shading (light_visible) from each hit of rays
    with the given directions reaches the target point. Misses count as visible."""
    backend, program, args = _probe_program(scene, backend, "shadows", variant)
    n = len(hits.tri)
    if n == 0:
        return np.zeros(0, bool)
    bufs = [backend.to_device(float4_rows(directions)), backend.to_device(hit_records(hits.t, hits.tri, hits.u, hits.v)),
            backend.to_device(float4_rows(targets))]
    out = backend.empty(4 * n)
    program.launch("probe_shadow", (n,), PROBE_BLOCK, args + bufs + [out, np.int32(n)], constants=("frame",))
    return backend.to_host(out, np.int32, n) != 0


def probe_secondary_rays(scene: Scene, backend, directions, hits: TraceResult, kind: str,
                         variant: Variant | None = None):
    """The reflection ("reflection") or refraction ("refraction") child the kernels spawn from each
    hit (parent weight 1): (origins (N, 3), weights (N,), directions (N, 3), TraceResult of the
    child's closest hit). Weight 0 and tri NO_RAY where none is spawned."""
    if kind not in SECONDARY_KINDS:
        raise RtlabError(f"kind must be 'reflection' or 'refraction', not {kind!r}")
    backend, program, args = _probe_program(scene, backend, "bounces", variant)
    n = len(hits.tri)
    bufs = [backend.to_device(float4_rows(directions)), backend.to_device(hit_records(hits.t, hits.tri, hits.u, hits.v))]
    outs = [backend.empty(16 * n) for _ in range(3)]
    program.launch("probe_secondary", (n,), PROBE_BLOCK, args + bufs + [np.int32(SECONDARY_KINDS[kind]), np.int32(n)] + outs,
                   constants=("frame", "materials"))
    o, d, h = (backend.to_host(b, np.float32, 4 * n).reshape(n, 4) for b in outs)
    t, tri, u, v = unpack_hits(h)
    return o[:, :3], o[:, 3], d[:, :3], TraceResult(t, tri, u, v, 0.0, backend.name, backend.device_name)


def probe_refraction(backend, directions, normals, ior, front) -> tuple[np.ndarray, np.ndarray]:
    """The kernels' refract_dir and fresnel_schlick on unit directions and normals (facing the
    directions' origin side): (refracted directions (N, 3), Schlick reflectance (N,)); zero
    directions and reflectance 1 under total internal reflection."""
    if not hasattr(backend, "compile"):
        backend = get_backend(backend)
    variant = resolve_variant(None, backend)
    program = backend.compile(kernel_source(program_for("bounces", variant), backend.language),
                              build_defines(variant, SceneFeatures()))
    n = len(directions)
    d = float4_rows(directions, np.broadcast_to(np.asarray(front, np.float32), (n,)))
    nrm = float4_rows(normals, np.broadcast_to(np.asarray(ior, np.float32), (n,)))
    out = backend.empty(16 * n)
    program.launch("probe_refract", (n,), PROBE_BLOCK, [backend.to_device(d), backend.to_device(nrm), out, np.int32(n)])
    res = backend.to_host(out, np.float32, 4 * n).reshape(n, 4)
    return res[:, :3], res[:, 3]


def probe_brute_force(scene: Scene, backend, origins, directions, variant: Variant | str | None = None,
                      tmin: float = 0.0, tmax: float = np.inf) -> TraceResult:
    """Closest hits of the rays against every triangle of the scene in a loop, with the variant's
    triangle test and its t as trace() reports it (refined), no acceleration structure: what every
    traversal must return, id for id and t for t, ties at equal t included. Costs rays x triangles
    tests: meant for a few thousand rays."""
    if not hasattr(backend, "compile"):
        backend = get_backend(backend)
    variant = resolve_variant(variant, backend).with_(traversal="stack", node_memory="global")
    ds = device_scene(scene, backend)
    program = load_program(backend, program_for("loop", variant), variant, ds.features(variant))
    ds.set_constants(program, None, variant)
    o = np.asarray(origins, np.float32)
    d = np.asarray(directions, np.float32)
    n = len(o)
    if n == 0:
        empty = np.zeros(0, np.float32)
        return TraceResult(empty, np.zeros(0, np.int32), empty, empty, 0.0, backend.name, backend.device_name)
    lo = np.broadcast_to(np.asarray(tmin, np.float32), (n,))
    hi = np.broadcast_to(np.asarray(tmax, np.float32), (n,))
    out = backend.empty(16 * n)
    ms = program.launch("trace_rays_loop", (n,), PROBE_BLOCK,
                        ds.scene_args(variant) + [backend.to_device(float4_rows(o, lo)), backend.to_device(float4_rows(d, hi)),
                                                  out, np.int32(n), np.int32(scene.n_triangles)])
    t, tri, u, v = unpack_hits(backend.to_host(out, np.float32, 4 * n))
    return TraceResult(t, tri, u, v, float(ms), backend.name, backend.device_name)
