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
# # Lab 01 — memory placement (Shih et al. 2009, §3.1.1)
#
# The paper binds the kd-tree, object list, vertices and normals to **textures**, keeps camera,
# lights and materials in **constant memory**, and moves the ray to **shared memory**, because a ray
# indexed by the split axis (`o[axis]`) landed in slow local memory on 2008's compiler. Here every
# placement renders the same view; each is timed, its registers are read from nvcc's offline sm_90
# report (when nvcc is installed), and its hits are compared with the global-memory variant's, bit
# for bit: a placement moves data, it must never change a result.
#
# On PoCL (OpenCL on the CPU) the images exercise your `fetch_*_image` functions and the timings say
# little about a GPU; the shared-memory ray is CUDA only. On an NVIDIA GPU set `RTLAB_BACKEND=cuda`
# and a larger `RTLAB_NOTEBOOK_SIZE`.

# %%
import os

import matplotlib.pyplot as plt      # in Jupyter: static PNG figures (inline backend, drawn by Agg)
import numpy as np

import rtlab
from rtlab.backends import get_backend
from rtlab.course.kernel_sources import kernel_sources_summary
from rtlab.benches.memory import PLACEMENTS, bench_memory, compiler_report
from rtlab.backends.nvcc import nvcc_available
from rtlab.paths import find_scene_file

SIZE = min(int(os.environ.get("RTLAB_NOTEBOOK_SIZE", 96)), 96)    # PoCL: keep <= 96
backend = get_backend(os.environ.get("RTLAB_BACKEND", "opencl"))
print(kernel_sources_summary())   # which kernel sources run ($RTLAB_KERNEL_DIR or the installation's), its stubs
print(backend.describe(), "| nvcc:", "yes" if nvcc_available() else "not installed (no register report)")
scenes = [rtlab.load_scene("default", size=SIZE)]
if find_scene_file("bunny.ply"):
    scenes.append(rtlab.load_scene("bunny", size=SIZE))

# %% [markdown]
# ## Every placement, timed and checked
# `bench_memory` renders each placement (`rtlab.benches.memory.PLACEMENTS`; the CUDA-only ones are
# left out on OpenCL), counts the pixels whose hit (triangle id and `t` bits) or colour differ from
# the global variant, and checks the global variant itself against the float64 reference.

# %%
rows = {s.name: bench_memory(s, backend, repeats=3) for s in scenes}
for name, rs in rows.items():
    print(f"\n{name}, {SIZE}x{SIZE} on {backend.name}")
    print(f"{'placement':>13} {'ms':>8} {'Mrays/s':>8} {'nvcc regs':>9} {'stack B':>8} {'shared B':>8}  differs")
    for r in rs:
        nv = r.nvcc or {}
        print(f"{r.placement:>13} {r.bench.median_ms:8.2f} {r.bench.mrays:8.2f} {nv.get('registers', '-'):>9} "
              f"{nv.get('local_bytes', '-'):>8} {nv.get('shared_bytes', '-'):>8}  "
              f"{r.diff['tri']} hits, {r.diff['t_bits']} t, {r.diff['pixels']} pixels")
    print("global variant against the float64 reference:", rs[0].bench.error_text())
assert all(r.diff == {"tri": 0, "t_bits": 0, "pixels": 0} for rs in rows.values() for r in rs), \
    "a placement changed a result"
assert all(rs[0].bench.error["mismatches"] == 0 for rs in rows.values()), \
    "the global variant's hits differ from the float64 reference (see its line above)"

# %% [markdown]
# ## Time and registers per placement
# Left: time relative to the global variant on each scene (1.0 = global). Right: what nvcc gives
# the render kernel on sm_90 for each placement (registers and stack bytes), whatever the device
# here. The H100 measured (docs/results.md, "Memory placement"): textures 6 % slower than `__ldg`,
# the indexed ray 28 % slower, the shared-memory ray 2–6 % slower.

# %%
names = [p for p in PLACEMENTS if any(r.placement == p for rs in rows.values() for r in rs)]
fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
width = 0.8 / len(rows)
for k, (scene_name, rs) in enumerate(rows.items()):
    by = {r.placement: r for r in rs}
    base = by["global"].bench.median_ms
    a1.bar(np.arange(len(names)) + k * width, [by[n].bench.median_ms / base for n in names], width, label=scene_name)
a1.axhline(1.0, color="k", lw=0.8)
a1.set_xticks(np.arange(len(names)) + width * (len(rows) - 1) / 2, names, rotation=20)
a1.set_ylabel("time / global variant")
a1.set_title(f"{backend.name}, {SIZE}², 0 hits differ from global")
a1.legend(fontsize=8)
first = next(iter(rows.values()))
report = {r.placement: r.nvcc for r in first if r.nvcc}
if report:
    xs = np.arange(len(report))
    a2.bar(xs - 0.2, [v["registers"] for v in report.values()], 0.4, label="registers")
    a2b = a2.twinx()
    a2b.bar(xs + 0.2, [v["local_bytes"] for v in report.values()], 0.4, color="#d08040", label="stack bytes")
    a2b.set_ylabel("stack (local) bytes")
    a2.set_xticks(xs, list(report), rotation=20)
    a2.set_ylabel("registers (nvcc, sm_90)")
    a2.set_title(f"render_primary on sm_90 ({next(iter(rows))})")
    a2.legend(loc="upper left", fontsize=8)
    a2b.legend(loc="upper right", fontsize=8)
else:
    a2.text(0.5, 0.5, "nvcc not installed:\nno register report", ha="center", va="center")
    a2.axis("off")
plt.tight_layout()
plt.show()

# %% [markdown]
# ## Why the paper moved the ray (nvcc only)
# The same render kernel for each ray placement: a ray indexed by the split axis needs local memory
# (more local loads and stores in the PTX), a ray in shared memory reads it with shared loads. On a
# G80 with 8,192 registers per multiprocessor and no cache in front of local memory that decided
# the speed; today the select-based `get3()` keeps the ray in registers anyway.

# %%
if nvcc_available():
    for r in compiler_report(caps=(0,)):
        print(f"ray in {r['ray']:>9}: {r['registers']} registers, {r['local_bytes']} B stack, "
              f"{r['shared_bytes']} B shared, PTX local ld/st {r.get('ld_local', '-')}/{r.get('st_local', '-')}, "
              f"shared ld/st {r.get('ld_shared', '-')}/{r.get('st_shared', '-')}")
else:
    print("nvcc is not installed: `rtlab bench memory` on a machine with the CUDA toolkit prints this report")
