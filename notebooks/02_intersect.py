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
# # Lab 02 — triangle intersection tests (Shih et al. 2009, §3.1.2, Table 3)
#
# Table 3 times "pure triangle intersection test on 1000 triangles": every pixel's camera ray
# against the first 1000 triangles of the scene in a for-loop, no kd-tree. Here: Möller–Trumbore,
# Wald's projection test, Plücker and the watertight test, each timed and checked against the
# float64 reference over the same triangles, then each inside the renderer. Small sizes on PoCL;
# set `RTLAB_BACKEND=cuda` and a larger `RTLAB_NOTEBOOK_SIZE` on a GPU.

# %%
import os

import matplotlib.pyplot as plt      # in Jupyter: static PNG figures (inline backend, drawn by Agg)
import numpy as np

import rtlab
from rtlab.backends import get_backend
from rtlab.course.kernel_sources import kernel_sources_summary
from rtlab.benches.intersect import check_loop, intersect_loop
from rtlab.reference.check import check_render
from rtlab.paths import find_scene_file

SIZE = int(os.environ.get("RTLAB_NOTEBOOK_SIZE", 96))
backend = get_backend(os.environ.get("RTLAB_BACKEND", "opencl"))
print(kernel_sources_summary())   # which kernel sources run ($RTLAB_KERNEL_DIR or the installation's), its stubs
TESTS = ["moller", "wald", "plucker", "watertight"]
scene = rtlab.load_scene("bunny" if find_scene_file("bunny.ply") else "default", size=SIZE)
print(backend.describe(), "|", scene.name, scene.n_triangles, "triangles")

# %% [markdown]
# ## Table 3: the tests on their own
# The first 1000 triangles of the file (the paper's setup), every pixel's ray, best of 3 launches.
# The error column compares each pixel's closest hit among those triangles with the float64 reference.

# %%
loops = {}
for isect in TESTS:
    r = intersect_loop(scene, backend, isect, 1000, repeats=3, warmup=1)
    cmp_ = check_loop(scene, r)
    loops[isect] = (r, cmp_)
    print(f"{isect:>10}: {r.median_ms:8.2f} ms  {r.mtests_per_s:8.1f} Mtests/s  "
          f"{cmp_.n_mismatch} mismatches, {cmp_.n_ties} ties, {cmp_.n_hits_ref} pixels hit")
assert all(c.n_mismatch == 0 for _, c in loops.values()), \
    f"wrong closest hits with {[k for k, (_, c) in loops.items() if c.n_mismatch]} (mismatches above)"

# %% [markdown]
# ## Inside the renderer
# The same tests behind the kd-tree: Mrays/s and the error of every pixel.

# %%
renders = {}
for isect in TESTS:
    r = rtlab.render(scene, backend, rtlab.Variant.paper(intersection=isect), write_hits=True, repeats=3, warmup=1,
                     lab=True)
    renders[isect] = (r, check_render(scene, r, scene.camera))
    print(f"{isect:>10}: {r.median_ms:7.2f} ms  {r.mrays_per_s:6.2f} Mrays/s  {renders[isect][1].summary()}")

# %%
fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.4))
a1.bar(TESTS, [loops[i][0].median_ms for i in TESTS], color="#4a78b5")
a1.set_ylabel("ms per launch")
a1.set_title(f"Table 3 loop, 1000 triangles, {SIZE}² rays")
for i in TESTS:
    r, rep = renders[i]
    a2.scatter(r.median_ms, rep.hits.n_ties + rep.hits.n_mismatch, label=i, s=40)
a2.set_xlabel("render ms")
a2.set_ylabel("pixels differing from the reference\n(mismatches + ties)")
a2.set_title("error against run time, in the renderer")
a2.legend(fontsize=8)
plt.tight_layout()
plt.show()

# %% [markdown]
# ## One pixel in 3-D
# The pixel's ray with the projection test, its hit and the kd-tree leaves the stack traversal visited.

# %%
from rtlab.viz import inspect_scene

hits = renders["wald"][0].hits.tri
px = int(np.flatnonzero(hits >= 0)[len(np.flatnonzero(hits >= 0)) // 3])
view = inspect_scene(scene, depth=5, pixel=(px % SIZE, px // SIZE), size=SIZE, screenshot="02_inspect.png",
                     backend=backend, window_size=(800, 600))
print("\n".join(view.summary()[:3]))
plt.figure(figsize=(8, 6))
plt.imshow(view.image)
plt.axis("off")
plt.show()
