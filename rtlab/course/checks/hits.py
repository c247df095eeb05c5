"""Kinds that check a kernel's hits: it compiles, arbitrary rays through trace_rays, the render of a
view, and the paper's Table 3 loop (lab steps 00, 02, 03). The camera's own rays: checks/camera.py."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...settings import HIT_T_REL_TOL
from .base import (DEFAULT_WORK_BUDGET, PROBE_IMAGE, PROBE_RAYS, Kind, Outcome, Prepared, Produced, camera_scene,
                   describe_hit_errors, describe_image_error, device_scene_of, fresh_outputs, hits_agree, pixel_namer,
                   primary_step_of, ray_namer, require_hits, spec_variant, work_budget_applies, counted_produce)
from .edges import describe_leaks, edge_ray_namer, edge_rays, leaks


class CompileKind(Kind):
    """The step's kernel (``kernel`` = another step's, if set) compiles with the submission."""
    name = "compile"
    params = {"kernel": "", "traversal": "", "intersection": "", "node_memory": "", "block": None,
              "defines": {}}

    def prepare(self, spec, scene):
        return Prepared({"scene": scene})

    def setup(self, spec, inputs, backend, count_work=False):
        from ...device.kernels import load_program
        variant = spec_variant(spec)
        ds = device_scene_of(inputs["scene"], backend)
        step = spec.params["kernel"] or inputs["step"]
        load_program(backend, step, variant, ds.features(variant), **spec.params["defines"])
        return step

    def produce(self, state, request):
        return Produced(info={"step": state})

    def check(self, spec, inputs, expected, out):
        step = spec.params["kernel"] or expected["step"]
        return Outcome(1.0, f"{step} compiles on {out.info.get('device', 'the grading device')}")


class TraceRaysKind(Kind):
    """Closest hits of rays that are not camera rays (the trace_rays kernel: traversal and triangle
    test on their own), against the float64 reference, within a work budget (the reads of the tree
    and of triangles against the reference kernel's on the same rays).
    rays = "random": origins inside and around the scene box, directions uniform on the sphere;
    rays = "axis": axis-aligned directions, and rays lying in the kd-tree's split planes;
    rays = "edges": aimed at shared edges and vertices of the scene's closed meshes from afar, half
    of them grazing (edge_rays); each must hit one of the triangles that meet there, and a miss or a
    triangle behind is a leak however near the edge (where compare_hits' rule (b) sees a tie)."""
    name = "trace_rays"
    params = {"rays": "random", "count": 4000, "seed": 7, "tmin": 0.0, "tmax": float("inf"),
              "traversal": "", "intersection": "", "node_memory": "", "block": None}
    tolerance = {"mismatch_fraction": 0.0, "t_rel": HIT_T_REL_TOL, "work_budget": DEFAULT_WORK_BUDGET}

    def prepare(self, spec, scene):
        from ...reference import reference_trace
        p = spec.params
        expected = {}
        if p["rays"] == "edges":     # the triangles around each ray's target are answers: the grader's
            o, d, expected["fans"], ref = edge_rays(scene, int(p["count"]), int(p["seed"]), p["tmin"], p["tmax"],
                                                    spec.name)
        else:
            o, d = make_rays(scene, p["rays"], int(p["count"]), int(p["seed"]))
            ref = reference_trace(scene.vertices, scene.faces, o, d, tmin=p["tmin"], tmax=p["tmax"])
        require_hits(ref, spec)
        return Prepared({"scene": scene, "origins": o, "directions": d}, {"ref": ref, **expected})

    def counts_work(self, spec):
        return work_budget_applies(spec)

    def setup(self, spec, inputs, backend, count_work=False):
        from ...device.kernels import load_program
        variant = spec_variant(spec).with_(count_work=count_work)
        ds = device_scene_of(inputs["scene"], backend)
        load_program(backend, primary_step_of(variant), variant, ds.features(variant))
        return spec, inputs, backend, variant

    def produce(self, state, request):
        from ...device.tracing import trace
        spec, inputs, backend, variant = state
        p = spec.params
        o, d = inputs["origins"], inputs["directions"]
        ds = device_scene_of(inputs["scene"], backend)

        def traced(count: int):
            return trace(inputs["scene"], o[:count], d[:count], backend=backend, variant=variant, tmin=p["tmin"],
                         tmax=p["tmax"], lab=True)

        def run():
            got = traced(len(o))
            return Produced({"t": got.t, "tri": got.tri}, {"kernel_ms": got.kernel_ms})
        return counted_produce(variant, ds, request, lambda: traced(PROBE_RAYS), PROBE_RAYS, run, len(o))

    def outputs(self, spec, inputs):
        n = len(inputs["origins"])
        return {"t": (np.float32, (n,)), "tri": (np.int32, (n,))}

    def check(self, spec, inputs, expected, out):
        from ...reference import compare_hits
        scene, o, d, ref = inputs["scene"], inputs["origins"], inputs["directions"], expected["ref"]
        p = spec.params
        t, tri = out.arrays["t"], out.arrays["tri"]
        fans = expected.get("fans")
        where = ray_namer(o, d) if fans is None else edge_ray_namer(o, d)
        cmp_ = compare_hits(ref, tri, t, scene.vertices, scene.faces, o, d, tmin=p["tmin"], tmax=p["tmax"])
        ok, msg = describe_hit_errors(cmp_, ref, tri, t, spec.tolerance, where, origins=o)
        data = {"mismatches": cmp_.n_mismatch, "rays": cmp_.n_rays, "kernel_ms": out.info.get("kernel_ms")}
        if fans is not None:        # a leak is a failure even where compare_hits sees a tie
            leaked = leaks(fans, tri)
            data.update(leaks=int(leaked.sum()), misses=int((leaked & (tri < 0)).sum()))
            if leaked.any():
                ok, msg = False, describe_leaks(leaked, fans, ref, tri, t, where) + ("" if ok else "\n" + msg)
        return Outcome(1.0 if ok else 0.0, msg, data)


def make_rays(scene, kind: str, count: int, seed: int):
    """Test rays as float32 (origins, directions)."""
    from ...errors import RtlabError
    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds().astype(np.float64)
    ext = hi - lo
    if kind == "random":
        o = rng.uniform(lo - 0.5 * ext, hi + 0.5 * ext, size=(count, 3))
        d = rng.normal(size=(count, 3))
    elif kind == "axis":
        # half: axis-aligned directions (two zero components: inv_d = +-inf) from random origins
        half = count // 2
        o1 = rng.uniform(lo - 0.25 * ext, hi + 0.25 * ext, size=(half, 3))
        axis = rng.integers(0, 3, half)
        d1 = np.zeros((half, 3))
        d1[np.arange(half), axis] = rng.choice([-1.0, 1.0], half)
        # half: rays lying in a split plane of the kd-tree (origin on the plane, no component across it)
        from ...device.device_scene import scene_kdtree
        tree = scene_kdtree(scene)
        interior = np.flatnonzero(~tree.is_leaf())
        pick = interior[rng.integers(0, interior.size, count - half)]
        ax = tree.split_axis()[pick]
        pos = tree.split_pos()[pick].astype(np.float64)
        o2 = rng.uniform(lo, hi, size=(count - half, 3))
        o2[np.arange(count - half), ax] = pos
        d2 = rng.normal(size=(count - half, 3))
        d2[np.arange(count - half), ax] = 0.0
        o, d = np.concatenate([o1, o2]), np.concatenate([d1, d2])
    else:
        raise RtlabError(f"unknown ray set '{kind}'; use random, axis or edges")
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o.astype(np.float32), d.astype(np.float32)


class RenderKind(Kind):
    """The step's render of the scene's camera view (primary rays, simple shading): every pixel's
    hit (the render's hit buffer) against the float64 reference, the image against the reference
    shading (PSNR), and the render's reads within the work budget."""
    name = "render"
    params = {"traversal": "", "intersection": "", "node_memory": "", "block": None}
    tolerance = {"mismatch_fraction": 0.0, "t_rel": HIT_T_REL_TOL, "min_psnr": 40.0, "work_budget": DEFAULT_WORK_BUDGET}

    def prepare(self, spec, scene):
        from ...reference.shading import reference_shade, to_rgb8
        from ...reference.check import reference_camera_hits
        o, d, ref = reference_camera_hits(scene, scene.camera)
        require_hits(ref, spec)
        img = to_rgb8(reference_shade(scene, o, d, ref.tri, ref.t, ref.u, ref.v))
        return Prepared({"scene": scene},
                        {"origins": o, "directions": d, "ref": ref,
                         "ref_image": img.reshape(scene.camera.height, scene.camera.width, 3)})

    def counts_work(self, spec):
        return work_budget_applies(spec)

    def setup(self, spec, inputs, backend, count_work=False):
        from ...device.kernels import load_program
        variant = spec_variant(spec).with_(count_work=count_work)
        ds = device_scene_of(inputs["scene"], backend)
        load_program(backend, primary_step_of(variant), variant, ds.features(variant), RT_WRITE_HITS=1)
        return spec, inputs, backend, variant

    def produce(self, state, request):
        """The render of the scene's view (``request["camera"]``: another camera, for speed tests)."""
        from ...device.rendering import render
        spec, inputs, backend, variant = state
        scene = camera_scene(inputs["scene"], request)
        small = replace(scene, camera=scene.camera.with_size(*PROBE_IMAGE))

        def run():
            r = render(scene, fresh_outputs(backend, request), variant, write_hits=True, lab=True)
            arrays = {"image": r.image, "t": r.hits.t, "tri": r.hits.tri, "u": r.hits.u, "v": r.hits.v}
            return Produced(arrays, {"kernel_ms": float(r.kernel_ms[0])})
        # launches round their grids up to whole blocks: room for a margin of 64 a side
        return counted_produce(variant, device_scene_of(scene, backend), request,
                               lambda: render(small, backend, variant, write_hits=True, lab=True),
                               (PROBE_IMAGE[0] + 64) * (PROBE_IMAGE[1] + 64), run,
                               (scene.camera.width + 64) * (scene.camera.height + 64))

    def outputs(self, spec, inputs, camera=None):
        cam = camera or inputs["scene"].camera
        n = cam.width * cam.height
        return {"image": (np.uint8, (cam.height, cam.width, 3)), "t": (np.float32, (n,)), "tri": (np.int32, (n,)),
                "u": (np.float32, (n,)), "v": (np.float32, (n,))}

    def time_of(self, out) -> float:
        return float(out.info["kernel_ms"])

    def check(self, spec, inputs, expected, out):
        from ...reference import compare_hits
        scene, ref = inputs["scene"], expected["ref"]
        tri, t = out.arrays["tri"], out.arrays["t"]
        cmp_ = compare_hits(ref, tri, t, scene.vertices, scene.faces, expected["origins"], expected["directions"])
        ok, msg = describe_hit_errors(cmp_, ref, tri, t, spec.tolerance, pixel_namer(scene.camera.width))
        img_ok, img_msg, psnr = describe_image_error(out.arrays["image"], expected["ref_image"],
                                                     spec.tolerance["min_psnr"], "the reference shading")
        return Outcome(1.0 if ok and img_ok else 0.0, msg + img_msg,
                       {"mismatches": cmp_.n_mismatch, "pixels": cmp_.n_rays, "psnr": psnr})

    def agree(self, spec, inputs, camera, got, want) -> tuple[bool, str]:
        """Whether a render matches the reference kernel's render of the same view (speed tests)."""
        scene = inputs["scene"]
        g, w = got.arrays, want.arrays
        ok, why = hits_agree(g["tri"], g["t"], w["tri"], w["t"], w["u"], w["v"], scene, scene.faces, camera,
                             spec.tolerance, pixel_namer(camera.width))
        if not ok:
            return ok, why
        img_ok, img_msg, _ = describe_image_error(g["image"], w["image"], spec.tolerance["min_psnr"],
                                                  "the reference kernel's image")
        return img_ok, img_msg.strip()


class IntersectLoopKind(Kind):
    """The paper's Table 3 kernel (lab step 02): every pixel's camera ray against the first
    ``n_tris`` triangles in a loop, no acceleration structure (rtlab.benches.intersect), against the
    float64 reference over the same triangles. ``triangles = "visible"`` (the default) grades on a
    scene of the first ``n_tris`` triangles the camera sees, in file order: the first 1000 of a
    file (the paper's timing setup, ``"first"``) may cover no pixel of a small image."""
    name = "intersect_loop"
    params = {"intersection": "moller", "n_tris": 1000, "triangles": "visible", "block": None}
    tolerance = {"mismatch_fraction": 0.0, "t_rel": HIT_T_REL_TOL}

    def prepare(self, spec, scene):
        from ...errors import RtlabError
        from ...reference import reference_trace
        from ...scene.model import camera_rays
        o, d = camera_rays(scene.camera)
        n = int(spec.params["n_tris"])
        if spec.params["triangles"] == "visible":
            seen = np.unique(reference_trace(scene.vertices, scene.faces, o, d).tri)
            keep = seen[seen >= 0][:n]
            scene = replace(scene, name=f"{scene.name}-visible{len(keep)}", faces=scene.faces[keep],
                            material_ids=scene.material_ids[keep])
        elif spec.params["triangles"] != "first":
            raise RtlabError(f"triangles must be 'visible' or 'first', not {spec.params['triangles']!r}")
        n = min(n, scene.n_triangles)
        ref = reference_trace(scene.vertices, scene.faces[:n], o, d)
        require_hits(ref, spec)
        return Prepared({"scene": scene, "n_tris": n}, {"origins": o, "directions": d, "ref": ref})

    def setup(self, spec, inputs, backend, count_work=False):
        from ...benches.intersect import INTERSECT_STEP
        from ...device.kernels import load_program
        variant = spec_variant(spec)
        ds = device_scene_of(inputs["scene"], backend)
        load_program(backend, INTERSECT_STEP, variant, ds.features(variant))
        return spec, inputs, backend, variant

    def produce(self, state, request):
        from ...benches.intersect import intersect_loop
        spec, inputs, backend, variant = state
        scene = camera_scene(inputs["scene"], request)
        r = intersect_loop(scene, fresh_outputs(backend, request), variant.intersection, int(inputs["n_tris"]),
                           camera=scene.camera)
        return Produced({"t": r.t, "tri": r.tri}, {"kernel_ms": float(r.kernel_ms[0])})

    def outputs(self, spec, inputs, camera=None):
        cam = camera or inputs["scene"].camera
        n = cam.width * cam.height
        return {"t": (np.float32, (n,)), "tri": (np.int32, (n,))}

    def time_of(self, out) -> float:
        return float(out.info["kernel_ms"])

    def check(self, spec, inputs, expected, out):
        from ...reference import compare_hits
        scene, ref, n = inputs["scene"], expected["ref"], int(inputs["n_tris"])
        faces = scene.faces[:n]
        t, tri = out.arrays["t"], out.arrays["tri"]
        cmp_ = compare_hits(ref, tri, t, scene.vertices, faces, expected["origins"], expected["directions"])
        ok, msg = describe_hit_errors(cmp_, ref, tri, t, spec.tolerance, pixel_namer(scene.camera.width))
        return Outcome(1.0 if ok else 0.0, f"{spec.params['intersection']}, {n} triangles in a loop: {msg}",
                       {"mismatches": cmp_.n_mismatch, "pixels": cmp_.n_rays})

    def agree(self, spec, inputs, camera, got, want) -> tuple[bool, str]:
        scene = inputs["scene"]
        nan = np.full(len(want.arrays["tri"]), np.nan)     # the loop keeps no barycentrics: ties by equal t only
        return hits_agree(got.arrays["tri"], got.arrays["t"], want.arrays["tri"], want.arrays["t"], nan, nan, scene,
                          scene.faces[:int(inputs["n_tris"])], camera, spec.tolerance, pixel_namer(camera.width))
