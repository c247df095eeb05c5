# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Lab 04 — shadow rays, one pass or two (Shih et al. 2009, §3.2.1, Table 5)
#
# One-pass: the primary kernel also traces the shadow rays and shades. Two-pass: the primary kernel
# writes hit records to a global buffer; a second kernel traces the shadow rays and shades. Same
# image, different registers and occupancy. Checked against the float64 Whitted reference.

# %%
import os

import matplotlib.pyplot as plt      # in Jupyter: static PNG figures (inline backend, drawn by Agg)

from rtlab.backends import get_backend
from rtlab.device.kernels import Variant
from rtlab.course.kernel_sources import kernel_sources_summary
from rtlab.reference.whitted import reference_whitted, whitted_error
from rtlab.scene.materials import glass_scene
from rtlab.device.whitted import render_whitted

SIZE = int(os.environ.get("RTLAB_NOTEBOOK_SIZE", 96))
backend = get_backend(os.environ.get("RTLAB_BACKEND", "opencl"))
print(kernel_sources_summary())   # which kernel sources run ($RTLAB_KERNEL_DIR or the installation's), its stubs
scene = glass_scene(SIZE)
print(backend.describe(), "|", scene.name, scene.n_triangles, "triangles,", len(scene.lights), "light(s)")

# %%
modes = ["none", "one-pass", "two-pass"]
results, errors = {}, {}
refs = {True: reference_whitted(scene, bounces=0, shadows=True), False: reference_whitted(scene, bounces=0, shadows=False)}
for mode in modes:
    r = render_whitted(scene, backend, Variant.paper(), shadows=mode, write_hits=True, repeats=5, warmup=1, lab=True)
    e = whitted_error(r.image, {"P": r.hits.tri}, refs[mode != "none"])
    results[mode], errors[mode] = r, e
    regs = {k: v.get("local_bytes") for k, v in r.resources.items()}
    print(f"{mode:>9}: {r.median_ms:6.2f} ms, {len(r.launches)} launch(es), private bytes {regs}; {e.summary()}")
assert all(e.tree_pixels <= 0.005 * e.pixels for e in errors.values()), \
    f"shadows {[m for m, e in errors.items() if e.tree_pixels > 0.005 * e.pixels]}: over 0.5 % of pixels off the reference"

# %%
fig, axes = plt.subplots(1, 4, figsize=(13, 3.4))
for ax, mode in zip(axes, modes):
    ax.imshow(results[mode].image)
    ax.set_title(f"{mode}: {results[mode].median_ms:.2f} ms")
    ax.axis("off")
axes[3].scatter([results[m].median_ms for m in modes], [errors[m].rmse for m in modes], color="#d62728")
for m in modes:
    axes[3].annotate(m, (results[m].median_ms, errors[m].rmse), textcoords="offset points", xytext=(4, 4), fontsize=8)
axes[3].set_xlabel("ms per frame")
axes[3].set_ylabel("RMSE vs float64 reference")
axes[3].set_title("error against run time")
plt.tight_layout()
plt.show()

# %% [markdown]
# ## A pixel's shadow ray in 3-D
# Blue: the light is visible; dark: the shadow ray is blocked.

# %%
from rtlab.viz import inspect_scene

view = inspect_scene(scene, depth=4, pixel=(SIZE // 2, int(SIZE * 0.6)), size=SIZE, screenshot="04_inspect.png",
                     backend=backend, window_size=(800, 600))
view.rays = [s for s in view.rays if s.kind in ("primary", "shadow")]
print("\n".join(view.summary()))
p = view.plotter(off_screen=True, window_size=(800, 600))
img = p.screenshot(return_img=True)
p.close()
plt.figure(figsize=(8, 6))
plt.imshow(img)
plt.axis("off")
plt.show()
