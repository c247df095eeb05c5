"""The kind that checks Whitted ray tracing (lab steps 04, 05): shadows and the reflection/refraction
kernel tree against the float64 Whitted reference, ray tree by ray tree."""
from __future__ import annotations

from .base import Kind, Outcome, describe_image_error, device_scene_of, percent_text, spec_variant


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
        return {"ref": reference_whitted(scene, bounces=int(p["bounces"]), shadows=p["shadows"] != "none",
                                         fresnel=p["fresnel"])}

    def setup(self, spec, fixture, backend):
        from ...errors import KernelBuildError
        from ...device.kernels import load_program
        variant = spec_variant(spec)
        p = spec.params
        try:   # compile here, as render_whitted will, so the test's time limit covers only the run
            from ...device.whitted import SHADOWS_STEP, TREE_STEP, shading_defines
            ds = device_scene_of(fixture["scene"], backend)
            features = ds.features(variant)
            tree = int(p["bounces"]) > 0
            extra = shading_defines(features, p["shadows"], int(p["bounces"]), p["fresnel"], bool(p["compact"]),
                                    True, tree)
            load_program(backend, TREE_STEP if tree else SHADOWS_STEP, variant, features, **extra)
        except KernelBuildError:
            raise
        except Exception:   # the run compiles what it needs anyway
            pass
        return spec, fixture, backend, variant

    def render(self, state):
        from ...device.whitted import render_whitted
        spec, fx, backend, variant = state
        p = spec.params
        return render_whitted(fx["scene"], backend, variant, shadows=p["shadows"], bounces=int(p["bounces"]),
                              compact=bool(p["compact"]), fresnel=p["fresnel"], write_hits=True)

    def time_of(self, result) -> float:
        return float(result.frame_ms[0])

    def check(self, state, result) -> Outcome:
        from ...reference.whitted import NO_RAY, first_tree_difference, whitted_error
        spec, fx, _, _ = state
        ref, tol = fx["ref"], spec.tolerance
        tree = result.tree if result.tree is not None else {"P": result.hits.tri}
        err = whitted_error(result.image, tree, ref)
        w = fx["scene"].camera.width
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
        img_ok, img_msg, psnr = describe_image_error(result.image, ref.image, tol["min_psnr"], "the float64 reference")
        if not img_ok:
            problems.append(img_msg.strip())
        data = {"tree_pixels": err.tree_pixels, "pixels": err.pixels, "color_max": err.color_max_same_tree, "psnr": psnr}
        if problems:
            return Outcome(0.0, "\n".join(problems), data)
        return Outcome(1.0, f"{err.summary()}", data)

    def agree(self, state, got, want) -> tuple[bool, str]:
        from types import SimpleNamespace
        from ...reference.whitted import whitted_error
        tol = state[0].tolerance

        def tree_of(result):
            return result.tree if result.tree is not None else {"P": result.hits.tri}

        err = whitted_error(got.image, tree_of(got), SimpleNamespace(image=want.image, tree=tree_of(want)))
        problems = []
        if err.tree_pixels > tol["tree_fraction"] * err.pixels:
            problems.append(f"{err.tree_pixels} of {err.pixels} pixels trace another ray tree than the reference kernel")
        if err.color_max_same_tree > tol["color_max"]:
            problems.append(f"where the ray trees agree, colours differ by up to {err.color_max_same_tree}/255 "
                            f"(allowed {tol['color_max']}/255)")
        if not err.psnr >= tol["min_psnr"]:
            problems.append(f"image PSNR {err.psnr:.1f} dB against the reference kernel's, needs {tol['min_psnr']:.0f} dB")
        return not problems, "\n".join(problems)

    def run(self, state):
        return self.check(state, self.render(state))


def describe_node(node: str) -> str:
    names = {"R": "reflection", "T": "refraction"}
    return "primary" if node == "P" else " of the ".join(names[c] for c in reversed(node[1:])) + " of the primary"
