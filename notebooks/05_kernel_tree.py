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
# # Lab 05 — reflection and refraction as a kernel tree (Shih et al. 2009, §3.2.2, Table 5)
#
# The primary kernel is the root; each level below is one launch of the reflection or refraction
# kernel over the rays of the level above, depth first, so max bounces + 1 ray buffers are alive at
# once. Each ray carries a weight; the frame adds weight × colour. Checked against the float64
# Whitted reference; the time grows with the bounces as in Table 5.

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
print(backend.describe(), "|", scene.name, [m.name for m in scene.materials])

# %%
rows = {}
for bounces in (0, 1, 2, 3):
    r = render_whitted(scene, backend, Variant.paper(), bounces=bounces, write_hits=True, repeats=3, warmup=1,
                       lab=True)
    ref = reference_whitted(scene, bounces=bounces)
    tree = r.tree if r.tree is not None else {"P": r.hits.tri}
    e = whitted_error(r.image, tree, ref)
    rows[bounces] = (r, e)
    print(f"{bounces} bounce(s): {r.median_ms:6.2f} ms, {len(r.launches)} launches; {e.summary()}")
    for launch in r.launches[:8]:
        print(f"    {launch.kernel:<18} node {launch.node:<5} level {launch.level}  {launch.rays:6d} rays  {launch.ms:6.3f} ms")
assert all(e.tree_pixels <= 0.005 * e.pixels for _, e in rows.values()), \
    f"bounces {[b for b, (_, e) in rows.items() if e.tree_pixels > 0.005 * e.pixels]}: over 0.5 % of pixels off the reference"

# %%
fig, axes = plt.subplots(1, 5, figsize=(15, 3.2))
for ax, b in zip(axes, rows):
    ax.imshow(rows[b][0].image)
    ax.set_title(f"{b} bounce(s), {rows[b][0].median_ms:.2f} ms")
    ax.axis("off")
axes[4].plot(list(rows), [rows[b][0].median_ms for b in rows], "o-", label="ms per frame")
ax2 = axes[4].twinx()
ax2.plot(list(rows), [rows[b][1].rmse for b in rows], "s--", color="#d62728", label="RMSE")
axes[4].set_xlabel("bounces")
axes[4].set_ylabel("ms per frame")
ax2.set_ylabel("RMSE vs float64 reference")
axes[4].set_title("time and error against bounces")
plt.tight_layout()
plt.show()

# %% [markdown]
# ## One pixel's ray tree in 3-D
# Yellow primary, red reflection, green refraction, blue shadow rays (dark when blocked), red dots at
# the hits; the rays come from the kernels' own spawn functions (rtlab.device.whitted.probe_*).

# %%
from rtlab.viz import inspect_scene

view = inspect_scene(scene, depth=4, pixel=(SIZE // 2, int(SIZE * 0.47)), size=SIZE, screenshot="05_inspect.png",
                     backend=backend, window_size=(800, 600))
print("\n".join(view.summary()))
plt.figure(figsize=(8, 6))
plt.imshow(view.image)
plt.axis("off")
plt.show()

# %% [markdown]
# ## Your own secondary rays from Python: `rtlab.scene_from_arrays` and `rtlab.spawn_rays`
# The kernel tree spawns its rays on the device. From Python, any mesh given as numpy arrays becomes a
# scene in one call (a default material, a camera framing it, a light), and `rtlab.spawn_rays` turns
# hits into origins for the next rays: the hit point from the barycentrics, moved off its triangle by
# the rounding bound of its coordinates to the side the new ray leaves (pbrt-v4's OffsetRayOrigin, the
# same offset the kernels use). Naive origins `o + t d` with `tmin = 0` hit the triangle they leave;
# here a unit box stands on a mirror floor 1e4 from the origin, where that happens often.

# %%
import numpy as np
import trimesh

import rtlab

box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
box.apply_translation([0.0, 0.5, 0.0])
floor_v = np.array([[-20, 0, -20], [-20, 0, 20], [20, 0, 20], [20, 0, -20]], np.float64)
vertices = np.concatenate([box.vertices, floor_v]) + 1e4          # float64: rounded to float32 once
faces = np.concatenate([box.faces, len(box.vertices) + np.array([[0, 1, 2], [0, 2, 3]])])
mirror = rtlab.scene_from_arrays(vertices, faces, size=SIZE)
print(mirror.name, mirror.n_triangles, "triangles; camera at", np.round(mirror.camera.eye, 2))

o, d = rtlab.camera_rays(mirror.camera)
hits = rtlab.trace(mirror, o, d, backend=backend)
floor_hit = hits.tri >= len(box.faces)
n = np.array([0.0, 1.0, 0.0], np.float32)
r = (d - 2 * (d @ n)[:, None] * n).astype(np.float32)              # mirror reflection off the floor
o2, d2 = rtlab.spawn_rays(mirror, hits, r)
bounce = rtlab.trace(mirror, o2[floor_hit], d2[floor_hit], backend=backend)
naive_o = (o.astype(np.float64) + d * hits.t[:, None].astype(np.float64)).astype(np.float32)
naive = rtlab.trace(mirror, naive_o[floor_hit], r[floor_hit], backend=backend)
own = hits.tri[floor_hit]
print(f"{floor_hit.sum()} reflections off the floor: spawn_rays {np.sum(bounce.tri == own)} back on their own "
      f"triangle, o + t d with tmin 0: {np.sum(naive.tri == own)}")
assert np.sum(bounce.tri == own) == 0, f"{np.sum(bounce.tri == own)} spawned rays hit the triangle they left"

reflected = np.zeros(len(o), np.int32) - 1
reflected[floor_hit] = bounce.tri
fig, axes = plt.subplots(1, 2, figsize=(8, 3.6))
axes[0].imshow((hits.tri.reshape(SIZE, SIZE) >= 0) + (hits.tri.reshape(SIZE, SIZE) < len(box.faces)) * (hits.tri.reshape(SIZE, SIZE) >= 0))
axes[0].set_title("primary: box (yellow), floor")
axes[1].imshow(np.where(reflected.reshape(SIZE, SIZE) >= 0, reflected.reshape(SIZE, SIZE) < len(box.faces), -1))
axes[1].set_title("what the floor reflects: box (yellow)")
for ax in axes:
    ax.axis("off")
plt.tight_layout()
plt.show()
