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
from rtlab.labs.trees import kernel_tree_summary
from rtlab.reference.whitted import reference_whitted, whitted_error
from rtlab.scene.materials import glass_scene
from rtlab.device.whitted import render_whitted

SIZE = int(os.environ.get("RTLAB_NOTEBOOK_SIZE", 96))
backend = get_backend(os.environ.get("RTLAB_BACKEND", "opencl"))
print(kernel_tree_summary())   # which kernel tree runs ($RTLAB_KERNEL_DIR or the installation's), its stubs
scene = glass_scene(SIZE)
print(backend.describe(), "|", scene.name, [m.name for m in scene.materials])

# %%
rows = {}
for bounces in (0, 1, 2, 3):
    r = render_whitted(scene, backend, Variant(), bounces=bounces, write_hits=True, repeats=3, warmup=1)
    ref = reference_whitted(scene, bounces=bounces)
    tree = r.tree if r.tree is not None else {"P": r.hits.tri}
    e = whitted_error(r.image, tree, ref)
    rows[bounces] = (r, e)
    print(f"{bounces} bounce(s): {r.median_ms:6.2f} ms, {len(r.launches)} launches; {e.summary()}")
    for launch in r.launches[:8]:
        print(f"    {launch.kernel:<18} node {launch.node:<5} level {launch.level}  {launch.rays:6d} rays  {launch.ms:6.3f} ms")
assert all(e.tree_pixels <= 0.005 * e.pixels for _, e in rows.values())

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
