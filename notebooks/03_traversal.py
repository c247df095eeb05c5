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
# # Lab 03 — traversal variants (Shih et al. 2009, §3.1.2, Table 4)
#
# Single ray with a stack (lab 00), the packet with one shared stack, and the stackless kd-restart,
# short stack and ropes; plus a BVH (the paper's future work). Every variant must give the same hits;
# they differ in time, registers and occupancy. Small sizes on PoCL; `RTLAB_BACKEND=cuda` on a GPU.

# %%
import os

import matplotlib.pyplot as plt      # in Jupyter: static PNG figures (inline backend, drawn by Agg)
import numpy as np

import rtlab
from rtlab.backends import get_backend
from rtlab.course.kernel_sources import kernel_sources_summary
from rtlab.reference.check import check_render
from rtlab.device.kernels import TRAVERSALS
from rtlab.paths import find_scene_file

SIZE = int(os.environ.get("RTLAB_NOTEBOOK_SIZE", 96))
backend = get_backend(os.environ.get("RTLAB_BACKEND", "opencl"))
print(kernel_sources_summary())   # which kernel sources run ($RTLAB_KERNEL_DIR or the installation's), its stubs
scene = rtlab.load_scene("bunny" if find_scene_file("bunny.ply") else "default", size=SIZE)
print(backend.describe(), "|", scene.name, "| traversals:", ", ".join(TRAVERSALS))

# %% [markdown]
# ## Every variant, checked and timed

# %%
rows = {}
for name in TRAVERSALS:
    v = rtlab.Variant.paper(traversal=name)
    r = rtlab.render(scene, backend, v, write_hits=True, repeats=3, warmup=1, lab=True)
    rep = check_render(scene, r, scene.camera)
    rows[name] = (r, rep)
    res = r.resources
    print(f"{name:>10}: {r.median_ms:7.2f} ms  {r.mrays_per_s:6.2f} Mrays/s  private {res.get('local_bytes')} B  "
          f"{rep.summary()}")
assert all(rep.hits.n_mismatch == 0 for _, rep in rows.values()), "a traversal lost or invented hits"

# %%
names = list(rows)
ms = [rows[n][0].median_ms for n in names]
fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.4))
a1.bar(names, ms, color="#4a78b5")
a1.set_ylabel("ms per frame")
a1.set_title(f"{scene.name} {SIZE}² on {backend.name} (cf. Table 4)")
a1.tick_params(axis="x", rotation=30)
for n, x in zip(names, ms):
    rep = rows[n][1]
    a2.scatter(x, rep.hits.n_mismatch + rep.hits.n_ties, s=40, label=n)
a2.set_xlabel("ms per frame")
a2.set_ylabel("pixels differing from the reference")
a2.set_title("error against run time")
a2.legend(fontsize=8)
plt.tight_layout()
plt.show()

# %% [markdown]
# ## What the stack traversal visits
# The leaves along one pixel's ray, front to back, until the hit: the kd-restart visits the same
# leaves but walks down from the root before each one; ropes jump from leaf to leaf.

# %%
from rtlab.viz import inspect_scene

hits = rows["stack"][0].hits.tri
seen = np.flatnonzero(hits >= 0)
px = int(seen[len(seen) // 2])
view = inspect_scene(scene, depth=6, pixel=(px % SIZE, px // SIZE), size=SIZE, screenshot="03_inspect.png",
                     backend=backend, window_size=(800, 600))
print("\n".join(view.summary()[:3]))
plt.figure(figsize=(8, 6))
plt.imshow(view.image)
plt.axis("off")
plt.show()
