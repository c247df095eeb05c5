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
# # Lab 00 — primary rays (Shih et al. 2009, §3.1, Table 4)
#
# The paper's ray tracing kernel (Fig. 2) in four parts: ray generation (`camera_ray`), kd-tree
# traversal (`traverse_kd_stack`, the single ray with a stack of Table 4), the triangle test
# (Möller–Trumbore) and simple shading. This notebook renders with the kernels of this checkout (or
# yours: set `RTLAB_KERNEL_DIR` before starting Jupyter), checks every pixel against the float64
# reference, times block sizes (the paper's Fig. 4), plots error against run time, and shows one
# pixel's ray and the kd-tree leaves it visits.
#
# It runs anywhere: on PoCL (OpenCL on the CPU) at small sizes, or on an NVIDIA GPU with
# `RTLAB_BACKEND=cuda` and a larger `SIZE`.

# %%
import os

import matplotlib.pyplot as plt      # in Jupyter: static PNG figures (inline backend, drawn by Agg)
import numpy as np

import rtlab
from rtlab.backends import get_backend
from rtlab.course.kernel_sources import kernel_sources_summary
from rtlab.reference.check import check_render
from rtlab.paths import find_scene_file

SIZE = int(os.environ.get("RTLAB_NOTEBOOK_SIZE", 96))      # keep <= 128 on PoCL
backend = get_backend(os.environ.get("RTLAB_BACKEND", "opencl"))
print(kernel_sources_summary())   # which kernel sources run ($RTLAB_KERNEL_DIR or the installation's), its stubs
print(backend.describe())

# %% [markdown]
# ## Scenes
# The procedural default scene needs no file; BUNNY (69,451 triangles, Table 2) is used when its
# file is found (`rtlab scenes` says where rtlab looks).

# %%
scenes = [rtlab.load_scene("default", size=SIZE)]
if find_scene_file("bunny.ply"):
    scenes.append(rtlab.load_scene("bunny", size=SIZE))
for s in scenes:
    print(f"{s.name}: {s.n_triangles:,} triangles, camera {s.camera.width}x{s.camera.height}")

# %% [markdown]
# ## Render and check against the float64 reference
# `write_hits=True` makes the kernel also write each pixel's hit record (t, u, v, triangle), which
# `check_render` compares with the float64 reference tracer: triangle ids exactly (apart from ties at
# shared edges), t relatively, and the image against the reference shading.

# %%
results = {}
fig, axes = plt.subplots(len(scenes), 3, figsize=(9, 3 * len(scenes)), squeeze=False)
for row, s in zip(axes, scenes):
    r = rtlab.render(s, backend, rtlab.Variant.paper(), write_hits=True, repeats=3, warmup=1, lab=True)   # the paper's variant
    report = check_render(s, r, s.camera)
    results[s.name] = (r, report)
    print(f"{s.name}: {r.median_ms:.2f} ms, {r.mrays_per_s:.2f} Mrays/s; {report.summary()}")
    diff = np.abs(r.image.astype(int) - report.reference_image.astype(int)).max(axis=2)
    for ax, img, title in zip(row, (r.image, report.reference_image, diff),
                              ("kernel", "float64 reference", "|difference|")):
        ax.imshow(img, cmap="magma" if img.ndim == 2 else None)
        ax.set_title(f"{s.name}: {title}")
        ax.axis("off")
plt.tight_layout()
plt.show()
assert all(rep.hits.n_mismatch == 0 for _, rep in results.values()), "some pixels hit the wrong triangle"

# %% [markdown]
# ## Block size (Fig. 4)
# The launch shape changes the time, never the image: every block size below must give the same
# hits. On a GPU, 32×2 and 32×4 did best in the paper (coherent warps); on PoCL the work-group shape
# mostly sets how work is split over the cores.

# %%
blocks = [(8, 8), (16, 8), (32, 2), (32, 4), (64, 2)]
scene = scenes[-1]
rows = []
for b in blocks:
    v = rtlab.Variant.paper(block=b)
    r = rtlab.render(scene, backend, v, write_hits=True, repeats=5, warmup=1, lab=True)
    rep = check_render(scene, r, scene.camera)
    rows.append((f"{b[0]}x{b[1]}", r.median_ms, rep.hits.n_mismatch, rep.psnr))
    print(f"block {b[0]:>2}x{b[1]}: {r.median_ms:7.2f} ms  mismatches {rep.hits.n_mismatch}  PSNR {rep.psnr:.1f} dB")
assert len({m for _, _, m, _ in rows}) == 1, "the block size changed the hits"

# %% [markdown]
# ## Error against run time
# Every figure in this course pairs a time with an error. Here the error is the share of pixels
# that hit another triangle than the float64 reference (0 for a correct kernel) and the image error
# (1/PSNR, 0 for identical images), against the median time of a frame.

# %%
labels = [r[0] for r in rows]
ms = np.array([r[1] for r in rows])
err = np.array([r[2] / (scene.camera.width * scene.camera.height) for r in rows])
fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.2))
a1.bar(labels, ms, color="#4a78b5")
a1.set_ylabel("ms per frame")
a1.set_title(f"{scene.name} {scene.camera.width}² on {backend.name}")
a2.scatter(ms, err, color="#d62728")
for lbl, x, y in zip(labels, ms, err):
    a2.annotate(lbl, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
a2.set_xlabel("ms per frame")
a2.set_ylabel("mismatching pixels (fraction)")
a2.set_title("error against run time")
plt.tight_layout()
plt.show()

# %% [markdown]
# ## One pixel, in 3-D (pyvista, static)
# The mesh, the kd-tree's cells to depth 6 (one line actor), the camera frustum, the pixel's primary
# ray (yellow) with its hit point, its shadow ray when the scene has a light, and the leaves the ray
# visited before the traversal stopped (orange), computed by walking the tree along the ray in
# float64. `rtlab inspect SCENE --pixel X Y` opens the same view in a window.

# %%
from rtlab.viz import inspect_scene

scene = scenes[-1]
hit_pixels = np.flatnonzero(results[scene.name][0].hits.tri >= 0)
px = int(hit_pixels[len(hit_pixels) // 2])
pixel = (px % scene.camera.width, px // scene.camera.width)
view = inspect_scene(scene, depth=6, pixel=pixel, size=SIZE, screenshot="00_primary_inspect.png",
                     backend=backend, window_size=(900, 650))
print("\n".join(view.summary()))
plt.figure(figsize=(9, 6.5))
plt.imshow(view.image)
plt.axis("off")
plt.show()
assert view.rays[0].tri == results[scene.name][0].hits.tri[px], "the ray tree disagrees with the render"
