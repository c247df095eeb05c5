"""How much cheaper would shadow rays be with a light buffer (Haines & Greenberg 1986)? Host estimate.

The light buffer is rtlab.accel.light_buffer's (the library's frames use it: kernels/shared/
rt_light_buffer.h). This script counts, for the Whitted frame's shadow rays (primary
hits and one mirror bounce), the BVH's any-hit work (node visits, triangle tests) and the light
buffer's (triangle tests), with the cost model of the host mirrors (a binary node visit ~60
instructions, a triangle test ~35 with Moller).

    python experiments/light_buffer_estimate.py --scene sponza --size 512 --res 64,128,256
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit, prange

import rtlab
from rtlab.accel import light_buffer
from rtlab.accel.bvh_stats import traversal_bvh, traversal_counts
from rtlab.accel.light_buffer import build_light_buffer, light_buffer_stats
from rtlab.geometry import moller_trumbore_t
from rtlab.scene.materials import MATERIAL_PRESETS

@njit(parallel=True, cache=True)
def _buffer_counts(res, records, blocked_at, ref_id, ref_dist, vertices, faces, light, origins, directions):
    """Per shadow ray, what rt_light_buffer.h does: triangles tested (-1: the cell sends the ray to
    the traversal; 0 also where the cell's blocking distance answers), occluded."""
    n = origins.shape[0]
    tests = np.zeros(n, np.int64)
    occluded = np.zeros(n, np.bool_)
    for i in prange(n):
        w = origins[i] - light
        axis = 0
        if abs(w[1]) > abs(w[axis]):
            axis = 1
        if abs(w[2]) > abs(w[axis]):
            axis = 2
        m = abs(w[axis])
        col = min(int((w[(axis + 1) % 3] / m + 1.0) * 0.5 * res), res - 1)
        row = min(int((w[(axis + 2) % 3] / m + 1.0) * 0.5 * res), res - 1)
        cell = ((2 * axis + (1 if w[axis] < 0 else 0)) * res + row) * res + col
        first, count, blocked = records[cell, 0], records[cell, 1], blocked_at[cell]
        if count < 0:
            tests[i] = -1
            continue
        reach = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        if reach > blocked:
            occluded[i] = True
            continue
        k = 0
        for j in range(count):
            if ref_dist[first + j] > reach:
                break
            k += 1
            f = faces[ref_id[first + j]]
            t = moller_trumbore_t(origins[i], directions[i], vertices[f[0]], vertices[f[1]], vertices[f[2]])
            if t > 0.0 and t < 1.0:
                occluded[i] = True
                break
        tests[i] = k
    return tests, occluded


def buffer_counts(words, vertices, faces, light, origins, directions):
    """_buffer_counts on a block of rtlab.accel.light_buffer's layout."""
    records = light_buffer.cell_records(words)
    ref_id, ref_dist = light_buffer.decode_refs(words, 0, len(words))     # every word read as a ref
    blocked = records[:, 2].astype(np.int32).view(np.float32)
    return _buffer_counts(int(words[0]), records, blocked, ref_id, ref_dist, vertices, faces, light, origins,
                          directions)


def shadow_rays(scene, bvh, size):
    """Shadow rays of the primary hits and of one mirror bounce off them (reflective materials)."""
    cam = scene.camera.with_size(size)
    o, d = rtlab.camera_rays(cam)
    o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
    V = np.asarray(scene.vertices, np.float64)
    F = np.asarray(scene.faces, np.int64)
    refl = np.array([m.reflectivity + m.transparency for m in scene.materials])
    mat = np.asarray(scene.material_ids)
    light = np.asarray(scene.lights[0].position, np.float64)
    out_o, out_d = [], []
    for level in range(2):
        _, _, tri, t = traversal_counts(bvh, V, F, o, d)
        hit = tri >= 0
        tri, t, o, d = tri[hit], t[hit], o[hit], d[hit]
        p = o + t[:, None] * d
        f = F[tri]
        ng = np.cross(V[f[:, 1]] - V[f[:, 0]], V[f[:, 2]] - V[f[:, 0]])
        ng /= np.linalg.norm(ng, axis=1)[:, None]
        ng *= np.where((ng * d).sum(1) > 0, -1.0, 1.0)[:, None]
        eps = 1e-4 * (1.0 + np.abs(p).max(1))
        lit_side = ((light - p) * ng).sum(1) > 0
        so = p + ng * eps[:, None]
        out_o.append(so[lit_side])
        out_d.append((light - so)[lit_side])
        mirror = refl[mat[tri]] > 0
        o = so[mirror]
        dd = d[mirror]
        d = dd - 2.0 * (dd * ng[mirror]).sum(1)[:, None] * ng[mirror]
    as_float32 = lambda a: np.concatenate(a).astype(np.float32).astype(np.float64)   # the rays the kernels get
    return as_float32(out_o), as_float32(out_d), light


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="sponza")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--res", default="64,128,256")
    args = ap.parse_args()
    scene = rtlab.load_scene(args.scene)
    scene = type(scene)(**{**vars(scene), "materials": MATERIAL_PRESETS["paper"](scene)})
    V = np.asarray(scene.vertices, np.float64)
    F = np.asarray(scene.faces, np.int64)
    bvh = traversal_bvh(scene.vertices, scene.faces)
    so, sd, light = shadow_rays(scene, bvh, args.size)
    print(f"{args.scene}: {len(F):,} triangles, {len(so):,} shadow rays, light {light}")
    nodes, ntris, tri, _ = traversal_counts(bvh, V, F, so, sd, tmax=1.0, any_hit=True)
    occ = tri >= 0
    bvh_cost = 60 * nodes + 35 * ntris
    print(f"BVH any-hit: occluded {occ.mean():.3f}; nodes mean {nodes.mean():.1f} p99 {np.percentile(nodes, 99):.0f}; "
          f"tris mean {ntris.mean():.1f}; cost mean {bvh_cost.mean():.0f} instr")
    for res in (int(r) for r in args.res.split(",")):
        light_buffer.RESOLUTIONS = (res,)
        t0 = time.perf_counter()
        words = build_light_buffer(V, F, light, max_words=1 << 30)
        build = time.perf_counter() - t0
        stats = light_buffer_stats(words)
        tests, occ_lb = buffer_counts(words, V, F, light, so, sd)
        fb = tests < 0
        lb_cost = np.where(fb, bvh_cost + 20, 30 + 35 * np.maximum(tests, 0))
        agree = (occ_lb == occ)[~fb].mean()
        print(f"res {res}: build {build:.1f} s, {stats['mib']:.1f} MiB, list mean {stats['mean_list']:.1f}; rays to "
              f"the traversal {fb.mean():.3f}; tests mean {tests[~fb].mean():.1f} p99 {np.percentile(tests[~fb], 99):.0f}; "
              f"occlusion agrees {agree:.5f}; cost mean {lb_cost.mean():.0f} instr = {lb_cost.mean() / bvh_cost.mean():.2f} of BVH")

if __name__ == "__main__":
    main()
