"""How much cheaper would shadow rays be with a light buffer (Haines & Greenberg 1986)? Host estimate.

A light buffer is a cube of cells around a point light; each cell lists the triangles that overlap
the cone of directions it covers, sorted by their nearest distance to the light. A shadow ray from a
surface point p to the light lies inside the cone of the cell of (p - light), and only triangles
nearer the light than p can occlude it, so its any-hit query tests the cell's list in order until a
hit or a triangle farther than p. This script counts, for the Whitted frame's shadow rays (primary
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
from rtlab.accel.bvh_stats import traversal_bvh, traversal_counts
from rtlab.geometry import moller_trumbore_t, ray_scene_interval, slab_interval
from rtlab.scene.materials import MATERIAL_PRESETS

LEAF_BITS = 4
MAX_LEAF = (1 << LEAF_BITS) - 1


@njit(parallel=True, cache=True)
def any_hit_counts(child_lo, child_hi, child_ref, objects, scene_lo, scene_hi, depth, vertices, faces,
                   origins, directions):
    """Per shadow ray (t in (0, 1)): inner-node visits, triangle tests, occluded."""
    n = origins.shape[0]
    nodes = np.zeros(n, np.int64)
    tris = np.zeros(n, np.int64)
    occluded = np.zeros(n, np.bool_)
    for i in prange(n):
        o, d = origins[i], directions[i]
        inv, t0, t1 = ray_scene_interval(o, d, scene_lo, scene_hi, 0.0)
        if not t0 <= t1:
            continue
        stack = np.empty(depth + 1, np.int64)
        sp = 0
        ref = 0
        n_nodes = n_tris = 0
        done = False
        while not done:
            while ref >= 0:
                n_nodes += 1
                e0, x0 = slab_interval(o, inv, child_lo[ref, 0], child_hi[ref, 0], 0.0, 1.0)
                e1, x1 = slab_interval(o, inv, child_lo[ref, 1], child_hi[ref, 1], 0.0, 1.0)
                hit0 = e0 <= x0
                hit1 = e1 <= x1
                c0, c1 = child_ref[ref, 0], child_ref[ref, 1]
                if hit0 and hit1:
                    near0 = e0 <= e1
                    stack[sp] = c1 if near0 else c0
                    sp += 1
                    ref = c0 if near0 else c1
                elif hit0 or hit1:
                    ref = c0 if hit0 else c1
                else:
                    if sp == 0:
                        done = True
                        break
                    sp -= 1
                    ref = stack[sp]
            if done:
                break
            bits = ~ref
            first, count = bits >> LEAF_BITS, bits & MAX_LEAF
            for j in range(first, first + count):
                f = faces[objects[j]]
                n_tris += 1
                t = moller_trumbore_t(o, d, vertices[f[0]], vertices[f[1]], vertices[f[2]])
                if t > 0.0 and t < 1.0:
                    occluded[i] = True
                    done = True
                    break
            if done or sp == 0:
                break
            sp -= 1
            ref = stack[sp]
        nodes[i], tris[i] = n_nodes, n_tris
    return nodes, tris, occluded


@njit(cache=True)
def _clip(poly, n, a, b, out):
    """Sutherland-Hodgman: keep a*m + b.(u, v) >= 0 of polygon poly[:n] (rows m, u, v)."""
    k = 0
    for i in range(n):
        p, q = poly[i], poly[(i + 1) % n]
        fp = a * p[0] + b[0] * p[1] + b[1] * p[2]
        fq = a * q[0] + b[0] * q[1] + b[1] * q[2]
        if fp >= 0.0:
            out[k] = p
            k += 1
        if (fp >= 0.0) != (fq >= 0.0):
            s = fp / (fp - fq)
            out[k] = p + s * (q - p)
            k += 1
    return k


@njit(cache=True)
def _tri_cells(v, light, res, margin, cells_out):
    """Cells (face * res^2 + row * res + col) whose cones the triangle v (3x3) may overlap."""
    count = 0
    poly = np.empty((12, 3))
    tmp = np.empty((12, 3))
    for face in range(6):
        axis, sign = face // 2, 1.0 - 2.0 * (face % 2)
        ua, va = (axis + 1) % 3, (axis + 2) % 3
        for k in range(3):
            poly[k, 0] = sign * (v[k, axis] - light[axis])
            poly[k, 1] = v[k, ua] - light[ua]
            poly[k, 2] = v[k, va] - light[va]
        n = 3
        scale = 1.0 + margin
        for plane in range(4):
            b = np.zeros(2)
            b[plane // 2] = 1.0 if plane % 2 == 0 else -1.0
            n = _clip(poly, n, scale, b, tmp)
            poly[:n] = tmp[:n]
            if n == 0:
                break
        if n == 0:
            continue
        lo_u = lo_v = np.inf
        hi_u = hi_v = -np.inf
        whole = False
        for k in range(n):
            m = poly[k, 0]
            if m <= 1e-12 * (abs(poly[k, 1]) + abs(poly[k, 2]) + 1e-300):
                whole = True
                break
            uu, vv = poly[k, 1] / m, poly[k, 2] / m
            lo_u, hi_u = min(lo_u, uu), max(hi_u, uu)
            lo_v, hi_v = min(lo_v, vv), max(hi_v, vv)
        if whole:
            c0, c1, r0, r1 = 0, res - 1, 0, res - 1
        else:
            pad = margin * 2.0
            c0 = max(int(np.floor((lo_u - pad + 1.0) * 0.5 * res)), 0)
            c1 = min(int(np.floor((hi_u + pad + 1.0) * 0.5 * res)), res - 1)
            r0 = max(int(np.floor((lo_v - pad + 1.0) * 0.5 * res)), 0)
            r1 = min(int(np.floor((hi_v + pad + 1.0) * 0.5 * res)), res - 1)
        for r in range(r0, r1 + 1):
            for c in range(c0, c1 + 1):
                if cells_out.shape[0] > 0:
                    cells_out[count] = face * res * res + r * res + c
                count += 1
    return count


@njit(cache=True)
def build_light_buffer(vertices, faces, order, light, res, margin):
    """CSR lists of triangle ids per cell, each list in `order` (nearest to the light first)."""
    n_cells = 6 * res * res
    counts = np.zeros(n_cells + 1, np.int64)
    empty = np.empty(0, np.int64)
    v = np.empty((3, 3))
    per_tri = np.zeros(order.shape[0], np.int64)
    for i in range(order.shape[0]):
        f = faces[order[i]]
        for k in range(3):
            v[k] = vertices[f[k]]
        per_tri[i] = _tri_cells(v, light, res, margin, empty)
    buf = np.empty(per_tri.max() + 1, np.int64)
    for i in range(order.shape[0]):
        f = faces[order[i]]
        for k in range(3):
            v[k] = vertices[f[k]]
        m = _tri_cells(v, light, res, margin, buf)
        for j in range(m):
            counts[buf[j] + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    tris = np.empty(start[-1], np.int64)
    for i in range(order.shape[0]):
        f = faces[order[i]]
        for k in range(3):
            v[k] = vertices[f[k]]
        m = _tri_cells(v, light, res, margin, buf)
        for j in range(m):
            tris[fill[buf[j]]] = order[i]
            fill[buf[j]] += 1
    return start, tris


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def point_tri_distance(p, a, b, c):
    """Distance from p to triangle abc (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    if d1 <= 0 and d2 <= 0:
        return np.sqrt(_dot(ap, ap))
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    if d3 >= 0 and d4 <= d3:
        return np.sqrt(_dot(bp, bp))
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        q = a + ab * (d1 / (d1 - d3))
        return np.sqrt(_dot(p - q, p - q))
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    if d6 >= 0 and d5 <= d6:
        return np.sqrt(_dot(cp, cp))
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        q = a + ac * (d2 / (d2 - d6))
        return np.sqrt(_dot(p - q, p - q))
    va = d3 * d6 - d5 * d4
    if va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        q = b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))
        return np.sqrt(_dot(p - q, p - q))
    denom = 1.0 / (va + vb + vc)
    q = a + ab * (vb * denom) + ac * (vc * denom)
    return np.sqrt(_dot(p - q, p - q))


@njit(parallel=True, cache=True)
def tri_distances(vertices, faces, light):
    out = np.empty(faces.shape[0])
    for i in prange(faces.shape[0]):
        f = faces[i]
        out[i] = point_tri_distance(light, vertices[f[0]], vertices[f[1]], vertices[f[2]])
    return out


@njit(parallel=True, cache=True)
def light_buffer_counts(start, tris, dist, vertices, faces, light, res, origins, directions, cap):
    """Per shadow ray: triangles tested through the light buffer (-1: the cell's list is longer
    than cap, the ray would take the BVH), occluded."""
    n = origins.shape[0]
    tests = np.zeros(n, np.int64)
    occluded = np.zeros(n, np.bool_)
    for i in prange(n):
        o, d = origins[i], directions[i]
        w = o - light
        axis = 0
        if abs(w[1]) > abs(w[axis]):
            axis = 1
        if abs(w[2]) > abs(w[axis]):
            axis = 2
        face = 2 * axis + (0 if w[axis] >= 0 else 1)
        m = abs(w[axis])
        ua, va = (axis + 1) % 3, (axis + 2) % 3
        c = min(max(int(np.floor((w[ua] / m + 1.0) * 0.5 * res)), 0), res - 1)
        r = min(max(int(np.floor((w[va] / m + 1.0) * 0.5 * res)), 0), res - 1)
        cell = face * res * res + r * res + c
        s0, s1 = start[cell], start[cell + 1]
        if s1 - s0 > cap:
            tests[i] = -1
            continue
        reach = np.sqrt(_dot(w, w))
        k = 0
        for j in range(s0, s1):
            tri = tris[j]
            if dist[tri] > reach:
                break
            k += 1
            f = faces[tri]
            t = moller_trumbore_t(o, d, vertices[f[0]], vertices[f[1]], vertices[f[2]])
            if t > 0.0 and t < 1.0:
                occluded[i] = True
                break
        tests[i] = k
    return tests, occluded


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
    return np.concatenate(out_o), np.concatenate(out_d), light


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="sponza")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--res", default="64,128,256")
    ap.add_argument("--cap", type=int, default=64)
    args = ap.parse_args()
    scene = rtlab.load_scene(args.scene)
    scene = type(scene)(**{**vars(scene), "materials": MATERIAL_PRESETS["paper"](scene)})
    V = np.asarray(scene.vertices, np.float64)
    F = np.asarray(scene.faces, np.int64)
    bvh = traversal_bvh(scene.vertices, scene.faces)
    so, sd, light = shadow_rays(scene, bvh, args.size)
    print(f"{args.scene}: {len(F):,} triangles, {len(so):,} shadow rays, light {light}")
    b = np.asarray(bvh.bounds, np.float64)
    pad = np.abs(b).max() * 2.0 ** -20 + (b[1] - b[0]).max() * 1e-6 + 1e-30
    nodes, ntris, occ = any_hit_counts(bvh.child_lo.astype(np.float64), bvh.child_hi.astype(np.float64),
                                       bvh.child_ref.astype(np.int64), np.asarray(bvh.objects, np.int64),
                                       b[0] - pad, b[1] + pad, int(bvh.depth), V, F, so, sd)
    bvh_cost = 60 * nodes + 35 * ntris
    print(f"BVH any-hit: occluded {occ.mean():.3f}; nodes mean {nodes.mean():.1f} p99 {np.percentile(nodes, 99):.0f}; "
          f"tris mean {ntris.mean():.1f}; cost mean {bvh_cost.mean():.0f} instr")
    dist = tri_distances(V, F, light)
    order = np.argsort(dist, kind="stable")
    for res in (int(r) for r in args.res.split(",")):
        t0 = time.perf_counter()
        start, tris = build_light_buffer(V, F, order, light, res, 1e-4)
        build = time.perf_counter() - t0
        lens = np.diff(start)
        tests, occ_lb = light_buffer_counts(start, tris, dist, V, F, light, res, so, sd, args.cap)
        fb = tests < 0
        lb_cost = np.where(fb, bvh_cost + 20, 30 + 35 * np.maximum(tests, 0))
        agree = (occ_lb == occ)[~fb].mean()
        print(f"res {res}: build {build:.1f} s, {len(tris):,} refs ({len(tris) * 4 / 2**20:.1f} MiB), "
              f"list mean {lens.mean():.1f} max {lens.max()}; rays to BVH (list > {args.cap}) {fb.mean():.3f}; "
              f"tests mean {tests[~fb].mean():.1f} p99 {np.percentile(tests[~fb], 99):.0f}; occlusion agrees "
              f"{agree:.5f}; cost mean {lb_cost.mean():.0f} instr = {lb_cost.mean() / bvh_cost.mean():.2f} of BVH")


if __name__ == "__main__":
    main()
