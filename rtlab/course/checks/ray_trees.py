"""The kind that checks Whitted ray tracing (lab steps 04, 05): shadows and the reflection/refraction
kernel tree against the float64 Whitted reference, ray tree by ray tree."""
from __future__ import annotations

import re

import numpy as np

from .base import Kind, Outcome, Prepared, Produced, describe_image_error, device_scene_of, percent_text, spec_variant


class WhittedKind(Kind):
    """Whitted ray tracing (labs 04, 05; rtlab.device.whitted.render_whitted): shadows one-pass, two-pass
    or none, ``bounces`` levels of the reflection/refraction kernel tree, against the float64
    Whitted reference (rtlab.reference.whitted): the ray tree of every pixel (triangle hit by each
    node) and the colour where the trees agree."""
    name = "whitted"
    params = {"shadows": "one-pass", "bounces": 0, "fresnel": "schlick", "compact": False,
              "traversal": "", "intersection": "", "node_memory": "", "block": None}
    tolerance = {"tree_fraction": 0.005, "color_max": 2, "min_psnr": 30.0}

    def prepare(self, spec, scene):
        from ...reference.whitted import reference_whitted
        p = spec.params
        ref = reference_whitted(scene, bounces=int(p["bounces"]), shadows=p["shadows"] != "none", fresnel=p["fresnel"])
        return Prepared({"scene": scene}, {"ref": ref})

    def setup(self, spec, inputs, backend, count_work=False):
        from ...device.kernels import load_program
        from ...device.whitted import SHADOWS_STEP, TREE_STEP, shading_defines
        variant = spec_variant(spec)
        p = spec.params
        # compile here what render_whitted will launch: the run phase builds nothing
        ds = device_scene_of(inputs["scene"], backend)
        features = ds.features(variant)
        tree = int(p["bounces"]) > 0
        extra = shading_defines(features, p["shadows"], int(p["bounces"]), p["fresnel"], bool(p["compact"]),
                                True, tree)
        load_program(backend, TREE_STEP if tree else SHADOWS_STEP, variant, features, **extra)
        return spec, inputs, backend, variant

    def produce(self, state, request):
        from ...device.whitted import render_whitted
        from .base import camera_scene, fresh_outputs
        spec, inputs, backend, variant = state
        p = spec.params
        r = render_whitted(camera_scene(inputs["scene"], request), fresh_outputs(backend, request), variant,
                           shadows=p["shadows"], bounces=int(p["bounces"]), compact=bool(p["compact"]),
                           fresnel=p["fresnel"], write_hits=True, lab=True)
        tree = r.tree if r.tree is not None else {"P": r.hits.tri}
        return Produced({"image": r.image, **{f"tree_{node}": np.asarray(ids, np.int32) for node, ids in tree.items()}},
                        {"kernel_ms": float(r.frame_ms[0])})

    def outputs(self, spec, inputs, camera=None):
        cam = camera or inputs["scene"].camera
        n = cam.width * cam.height
        return {"image": (np.uint8, (cam.height, cam.width, 3)), "tree_P": (np.int32, (n,))}

    def tree_of(self, spec, out: Produced, n: int) -> dict:
        """The ray tree a test process returned: node name -> (n,) int32; nodes other than the
        primary only as deep as the test's bounces ("R", "T", "RT"...)."""
        tree = {}
        depth = int(spec.params["bounces"])
        for name, ids in out.arrays.items():
            m = re.fullmatch(r"tree_(P[RT]*)", name)
            if m and len(m.group(1)) <= depth + 1 and ids.dtype == np.int32 and ids.shape == (n,):
                tree[m.group(1)] = ids
        return tree

    def time_of(self, out) -> float:
        return float(out.info["kernel_ms"])

    def check(self, spec, inputs, expected, out):
        from ...reference.whitted import NO_RAY, first_tree_difference, whitted_error
        ref, tol = expected["ref"], spec.tolerance
        w = inputs["scene"].camera.width
        image = out.arrays["image"]
        tree = self.tree_of(spec, out, image.shape[0] * image.shape[1])
        err = whitted_error(image, tree, ref)
        problems = []
        if err.tree_pixels > tol["tree_fraction"] * err.pixels:
            what = lambda tri: "no ray" if tri == NO_RAY else "a miss" if tri < 0 else f"triangle {tri}"
            node, i, exp, got = first_tree_difference(tree, ref.tree, err.pixels)
            problems.append(f"{percent_text(err.tree_pixels, err.pixels)} of pixels trace another ray tree than the "
                            f"reference ({err.tree_pixels} of {err.pixels}); first at ({i % w}, {i // w}), ray {node} "
                            f"({describe_node(node)}): expected {what(exp)}, got {what(got)}")
        if err.color_max_same_tree > tol["color_max"]:
            problems.append(f"where the ray trees agree, colours are off by up to {err.color_max_same_tree}/255 "
                            f"(allowed {tol['color_max']}/255; 99th percentile {err.color_p99_same_tree:.0f}/255)")
        img_ok, img_msg, psnr = describe_image_error(image, ref.image, tol["min_psnr"], "the float64 reference")
        if not img_ok:
            problems.append(img_msg.strip())
        data = {"tree_pixels": err.tree_pixels, "pixels": err.pixels, "color_max": err.color_max_same_tree, "psnr": psnr}
        if problems:
            return Outcome(0.0, "\n".join(problems), data)
        return Outcome(1.0, f"{err.summary()}", data)

    def agree(self, spec, inputs, camera, got, want) -> tuple[bool, str]:
        from types import SimpleNamespace
        from ...reference.whitted import whitted_error
        tol = spec.tolerance
        n = camera.width * camera.height
        err = whitted_error(got.arrays["image"], self.tree_of(spec, got, n),
                            SimpleNamespace(image=want.arrays["image"], tree=self.tree_of(spec, want, n)))
        problems = []
        if err.tree_pixels > tol["tree_fraction"] * err.pixels:
            problems.append(f"{err.tree_pixels} of {err.pixels} pixels trace another ray tree than the reference kernel")
        if err.color_max_same_tree > tol["color_max"]:
            problems.append(f"where the ray trees agree, colours differ by up to {err.color_max_same_tree}/255 "
                            f"(allowed {tol['color_max']}/255)")
        if not err.psnr >= tol["min_psnr"]:
            problems.append(f"image PSNR {err.psnr:.1f} dB against the reference kernel's, needs {tol['min_psnr']:.0f} dB")
        return not problems, "\n".join(problems)


def describe_node(node: str) -> str:
    names = {"R": "reflection", "T": "refraction"}
    return "primary" if node == "P" else " of the ".join(names[c] for c in reversed(node[1:])) + " of the primary"
