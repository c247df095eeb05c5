"""Stiff and extreme cases for every triangle test and traversal: the robustness suite.

Nine families of scenes and rays, each checked against the float64 reference
(:func:`rtlab.reference.brute_force_trace`, or the bit-identical BVH :func:`reference_trace` when
brute force would be slow):

1. ``sphere``: a closed, finely tessellated sphere far from the origin (centre (1.5e5, 1.2e3,
   -2.2e5)), rays from inside, aimed at random directions, at vertices and at points on edges:
   **leaks** (a ray from inside a closed mesh that hits nothing escaped through a crack).
2. ``plane``: a tiled (tilted) plane, rays through interior vertices and points on interior edges:
   exactly (integer directions, dyadic coordinates, at offsets 0 and 1e4), and as a renderer aims
   them (a jittered height field at 1e4, d = p - o rounded in float32): **misses**.
3. ``splits``: axis-aligned rays whose origins lie on the kd-tree's split planes and box faces,
   triangles lying in split planes; a flat scene whose every cell has zero thickness: **mismatches**.
4. ``stairs``: 20 axis-aligned steps, rays straight down on a grid (127² in the benchmark) that puts
   every sixth column exactly in a riser's plane, onto a tread's edge: closest hit and t.
5. ``stairs_scaled``: the same at scales 1e-3, 1, 1e3 and offsets up to 1e4: mismatches.
6. ``slivers``: slivers, needles and zero-area triangles: **no false hits, no NaN t**.
7. ``grazing``: rays 1e-1 to 1e-6 rad off large triangles: mismatches.
8. ``bad_rays``: NaN/Inf in origin or direction, zero directions: **no crash, no hang**, all misses.
9. ``random``: random rays on BUNNY and SPONZA (10^5 in the benchmark): mismatches.

Three on extreme placements and lengths:

10. ``box_planes``: a grid of unit cubes around the origin, axis-aligned rays (and rays with one
    zero component) lying in its planes, zeros of both signs; a 1e-3 sphere in a 1e5 room, rays
    from inside the sphere: **misses** and **leaks** (the BVH's fused box test, RT_BVH_BOX_FMA, on
    near the origin: it must keep what the exact box test keeps).
11. ``spawn_offsets``: the glass scene (:func:`rtlab.scene.materials.glass_scene`) moved to offsets 0
    and 1e0..1e5, and spheres on a 2000-wide mirror floor at the origin, rendered with shadows and 3
    bounces against the float64 Whitted reference: **pixels more than 16/255 off** (spawn offsets
    too small give acne on large triangles, too large ones speckle scenes far from the origin).
12. ``dir_lengths``: the same rays with directions of length 1e-30..1e30: **mismatches** (trace()
    scales directions by powers of two; t comes back in the caller's units).

Three on which hit the closest-hit choice takes (rtlab.robustness.closest):

13. ``slivers_grazing``: slivers (made ones and the scenes' own) seen 10^-3.5..10^-1.5 off their plane,
    with small blockers 2e-5 of t before or after them, and rays spawned along them by spawn_rays:
    **mismatches**, **t off**, **false hits**.
14. ``ties``: on the real scenes, rays exactly through vertices on kd split planes, exactly through
    shared edges, and at coplanar copies and halves of triangles put at random ids: **differs**.
15. ``spawned``: reflections spawned by rtlab.spawn_rays off a box, a sphere and a floor at scales
    1e-4..1e3 and offsets up to 1e4: **false hits** (a ray back on the triangle it left).

Counts per row (one row per case x test x traversal):
  leaks       rays that must hit (closed mesh, interior of the plane) and report no hit
  misses      rays the reference hits and the kernel does not (ties at silhouettes included)
  mismatches  closest hit differs and it is not a tie (:func:`rtlab.reference.compare_hits`)
  ties        differs, but the ray cannot decide (shared edge, graze); reported, not an error
  differs     the id is not the one most traversals report with the same test (-: one traversal run)
  t_off       same triangle as the reference, t further from it than RT_T_ERR (the refined t's bound)
  false_hits  a hit on a zero-area triangle, on a triangle the float64 test misses even with the
              tie slack, or any hit of a NaN/Inf/zero-direction ray
  nan_t       a NaN t written by the kernel
  px_off      (family 11) pixels whose colour is more than 16/255 off the float64 reference
  failure     "crash: ..." or "hang (> N s)" when the case ran in a child process and died or stalled

Goals with the watertight test and the conservative traversal (``GOALS``): 0 leaks and 0 misses in
families 1-2 and 10, 0 mismatches in 3-5, 9, 10 and 12-15, 0 false hits in 6, 8, 13 and 15, and in every
family no NaN t, no failure, the same ids in every traversal (differs) and t within RT_T_ERR (t off).
The other tests' counts are the lesson: they are reported, not hidden.

    rows = run_robustness(get_backend("opencl"), isects=["moller", "watertight"])
    print(rows_table(rows))
"""
from __future__ import annotations

from .cases import FAMILY_NAMES, GOALS, SIZES, STAIR_STEPS, Case, box_mesh, case_scene, merge_meshes
from .families import family_cases
from .runner import (TABLE_COLUMNS, RobustnessRow, aggregate, count_case, robustness_table, row_cells,
                     run_robustness, trace_case)
from .shared_edges import stairs_rays

__all__ = ["FAMILY_NAMES", "GOALS", "SIZES", "STAIR_STEPS", "Case", "RobustnessRow", "TABLE_COLUMNS", "aggregate",
           "box_mesh", "case_scene", "count_case", "family_cases", "merge_meshes", "robustness_table", "row_cells",
           "run_robustness", "stairs_rays", "trace_case"]
