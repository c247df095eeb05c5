/* rt_bvh4.h - 4-wide BVH traversal with float child boxes: the children's planes stored as one float4
 * per plane (lo.x of the four children, hi.x, ...: a structure of arrays, as in Embree's BVH4), the
 * near and far planes picked per ray by row (no per-child select), the children hit entered nearest
 * first and the others pushed with their entry distance, so that a popped child beyond the closest
 * hit so far is dropped (pop culling). A pushed child is its node's row and its sort key; its ref is
 * read from the node when it is popped and not culled, so a visit picks one ref from the refs row
 * (the nearest child's, the row loaded with the planes) and pushes only when a second child is hit.
 * Built by rtlab/accel/bvh4.py: the optimal collapse of Ylitie, Karras & Laine 2017 to 4 children a
 * node, from the binary SAH/SBVH trees. Why 4 and not 8: on the benchmark views
 * (experiments/bench_wide_bvh_quality.py, host mirrors) this traversal tests 0.8-1.0x the boxes the
 * binary BVH tests, in 0.4-0.5x the node visits, where the compressed 8-wide one (rt_bvh8.h: octant
 * order, no distances to cull by) tests 1.0-1.7x the boxes, each box dearer by its decode; ncu found
 * the binary BVH issue-bound on SPONZA, so boxes tested count. It is trace()'s GPU default
 * (rtlab.device.variants.GPU_RAYS_VARIANT).
 *
 * Node layout in node_data, 7 float4 = 112 B per node (sync with rtlab/accel/bvh4.py):
 *   [row + 0] = lo.x of children 0-3    [row + 1] = hi.x
 *   [row + 2] = lo.y                    [row + 3] = hi.y
 *   [row + 4] = lo.z                    [row + 5] = hi.z
 *   [row + 6] = child refs (int bits): >= 0 the row of an inner node; a leaf is
 *               ~((first triangle row << BVH4_LEAF_BITS) | count)
 * An empty slot has the box (+inf, -inf), which no ray enters. Triangles as in rt_bvh8.h: 3 rows each,
 * (v0.xyz, triangle id bits), (v1.xyz, 0), (v2.xyz, 0), a leaf's contiguous. The root is row 0.
 * RT_STACK_SIZE is 3 x depth + 1 (rtlab.device.device_scene): a node pushes at most 3 children.
 *
 * Box test: rt_bvh.h's fused form (one fma a plane, o inv moved outward by its rounding bound, zero
 * direction components as +-2^64 with the ray's length as pad), which keeps every box the exact test
 * keeps at any distance from the origin for coordinates up to 1e18 (the builder checks), in the ray's
 * own units (bvh4_ray: distances scaled by a power of two, exactly, so that the near planes clamp to
 * [0, 1] in the fma); a child is hit where the sign of exit x (1 + RT_T_PAD) - entry is + (one fma,
 * RT_CONSERVATIVE), and entered or pushed where its entry is no later than the cut, t_cull of the closest
 * hit (the scalar BVH's pad), so ties at equal t reach the lower triangle id. */
#ifndef RT_BVH4_H
#define RT_BVH4_H
#include "rt_bvh8.h"

#define BVH4_NODE_ROWS 7             /* float4 rows a node (sync with rtlab/accel/bvh4.py) */
#define BVH4_LEAF_BITS 4             /* at most 15 triangles a leaf */
#define BVH4_NONE (-2147483647 - 1)  /* no child: not a leaf ref (its row would be 2^27 - 1) */
#define BVH4_MISS 0xFFFFFFFFu        /* the sort key of a child not hit (bvh4_key) */

/* A pending child: the row of the node that holds it (where the walk pushes refs, bvh4_visit's
 * push_refs, the child's own ref instead) and its sort key (bvh4_key: the entry distance's bits with
 * the child's slot in the two low bits) */
typedef struct {
    int row;
    int key;
} Bvh4Entry;

typedef struct {
    float3 inv;              /* 1/d, or +-2^64 where |d| <= RT_BVH_MIN_DIR (bvh_inverse) */
    float3 o_near, o_far;    /* o inv moved up (near planes) and down (far planes) by its rounding bound */
    float scale;             /* 2^-k: the walk's distances are t scale, below 1/2 in the scene (bvh4_ray) */
    int near_x, near_y, near_z;   /* row of the near plane's float4 in a node: lo, or hi where inv < 0 */
} Bvh4Ray;

/* The per-ray constants for a ray whose segment in the scene box ends at t_exit (rt_bvh.h's bvh_ray). */
RT_FN Bvh4Ray bvh4_ray(const Ray *ray, float t_exit)
{
    Bvh4Ray r;
    float t_pad = 2.0f * t_exit;
    r.inv = f3(bvh_inverse(ray->d.x), bvh_inverse(ray->d.y), bvh_inverse(ray->d.z));
    float3 oi = hadamard3(ray->o, r.inv);
    float3 pad = f3(bvh_origin_pad(ray->d.x, oi.x, t_pad), bvh_origin_pad(ray->d.y, oi.y, t_pad),
                    bvh_origin_pad(ray->d.z, oi.z, t_pad));
    r.o_near = add3(oi, pad);
    r.o_far = sub3(oi, pad);
    r.near_x = r.inv.x < 0.0f ? 1 : 0;
    r.near_y = r.inv.y < 0.0f ? 3 : 2;
    r.near_z = r.inv.z < 0.0f ? 5 : 4;
    /* The walk's distances in units of 2^k >= t_pad (k >= 0: never scaled up, o inv could overflow), so
     * that an entry distance clamped to [0, 1] (bvh4_near: one saturating fma) keeps every box the ray
     * enters: a power of two scales every fma exactly, and no box in the scene ends beyond t_exit. */
    int e = (rt_as_int(t_pad) >> 23) & 255;            /* t_pad < 2^(e - 126) */
    int k = rt_imin(rt_imax(e - 126, 0), 125);
    r.scale = rt_as_float((127 - k) << 23);
    r.inv = mul3(r.inv, r.scale);
    r.o_near = mul3(r.o_near, r.scale);
    r.o_far = mul3(r.o_far, r.scale);
    return r;
}

/* The closest hit's cut as a key: t_cull(t_hit) in the walk's units, its bits | 3 (a key's slot bits),
 * so that a key is a child entered no later than the cut where key <= cut as unsigned ints (keys of
 * entries >= +0 order as their floats). The scale is exact down to 2^-126: a hit closer than 2^-125
 * t_exit would be cut at a denormal, whose rounding t_cull's pad does not cover. */
RT_FN unsigned int bvh4_cut(const Bvh4Ray *r, float t_hit)
{
    return (unsigned int)(rt_as_int(t_cull(t_hit) * r->scale) | 3);
}

/* A near plane's distance clamped to [0, 1], +0 for -0 and NaN (ptxas: one FFMA.SAT with the fma). The
 * clamp at 0 stands for tmin: a box whose segment ends before tmin may be entered, and its triangles'
 * hits are refused by the test. */
RT_FN float bvh4_near(float t) { return rt_min(t > 0.0f ? t : 0.0f, 1.0f); }

/* Sort key of child `slot` from its near planes (nx, ny, nz) and far planes (fx, fy, fz): its entry
 * distance's bits (>= +0, so ordered as unsigned ints) with the slot in the two low bits; a child not
 * hit gets every bit set (BVH4_MISS: the sign of exit - entry spread over the word), so misses sort
 * last. The closest hit's cut is not in the key: a child hit beyond it sorts between the hits and the
 * misses, and the walk compares keys with the cut where it enters or pushes a child (bvh4_hit_key), as
 * the pop does. */
RT_FN unsigned int bvh4_key(float nx, float ny, float nz, float fx, float fy, float fz, const Bvh4Ray *r,
                            unsigned int slot)
{
    float3 a = r->inv, on = r->o_near, of = r->o_far;
    float t0 = bvh_max3(bvh4_near(rt_fma(nx, a.x, -on.x)), bvh4_near(rt_fma(ny, a.y, -on.y)),
                        bvh4_near(rt_fma(nz, a.z, -on.z)));
    float t1 = bvh_min3(rt_fma(fx, a.x, -of.x), rt_fma(fy, a.y, -of.y), rt_fma(fz, a.z, -of.z));
#if RT_CONSERVATIVE
    float gap = rt_fma(t1, RT_BVH_EXIT_SCALE, -t0);   /* one rounding: its sign is exact */
#else
    float gap = t1 - t0;
#endif
    unsigned int miss = (unsigned int)(rt_as_int(gap) >> 31);
    return ((unsigned int)rt_as_int(t0) & ~3u) | slot | miss;
}

/* Whether a sorted key is a child to enter or push: hit, and entered no later than the cut (a float's
 * bits | 3, the slot's bits) */
RT_FN int bvh4_hit_key(unsigned int key, unsigned int cut) { return key <= cut; }

RT_FN void bvh4_order(unsigned int *a, unsigned int *b)
{
    unsigned int lo = rt_imin(*a, *b), hi = rt_imax(*a, *b);
    *a = lo;
    *b = hi;
}

/* Test the four children of the node at row `row`; push all hit within the cut (bvh4_cut) but the
 * nearest (farthest first) and return the nearest, or BVH4_NONE when none is. *top gets a copy of the
 * stack's top entry where it changes (bvh4_pop_top). With push_refs an entry's .row holds the child's
 * ref instead of its node's row, so that its pop reads no node (bvh4_pop says which walk does). */
RT_FN int bvh4_visit(RT_SCENE_PARAMS, int row, const Bvh4Ray *r, unsigned int cut, Bvh4Entry *stack, int *sp,
                     Bvh4Entry *top, int push_refs)
{
    float4 nx = load_node_data(node_data, row + r->near_x), fx = load_node_data(node_data, row + (r->near_x ^ 1));
    float4 ny = load_node_data(node_data, row + r->near_y), fy = load_node_data(node_data, row + (r->near_y ^ 1));
    float4 nz = load_node_data(node_data, row + r->near_z), fz = load_node_data(node_data, row + (r->near_z ^ 1));
    float4 refs = load_node_data(node_data, row + 6);
    unsigned int k0 = bvh4_key(nx.x, ny.x, nz.x, fx.x, fy.x, fz.x, r, 0u);
    unsigned int k1 = bvh4_key(nx.y, ny.y, nz.y, fx.y, fy.y, fz.y, r, 1u);
    unsigned int k2 = bvh4_key(nx.z, ny.z, nz.z, fx.z, fy.z, fz.z, r, 2u);
    unsigned int k3 = bvh4_key(nx.w, ny.w, nz.w, fx.w, fy.w, fz.w, r, 3u);
    /* Sorting network of four keys: nearest in k0, misses last */
    bvh4_order(&k0, &k1);
    bvh4_order(&k2, &k3);
    bvh4_order(&k0, &k2);
    bvh4_order(&k1, &k3);
    bvh4_order(&k1, &k2);
    /* The nearest child's ref, picked whether or not it is hit: used either way, the refs row's load
     * stays beside the planes' (in a branch, the compiler sinks it there, a second memory latency a
     * visit on the walk's path) */
    int nearest = rt_as_int(get4(refs, (int)(k0 & 3)));
    if (!bvh4_hit_key(k0, cut))
        nearest = BVH4_NONE;
    /* The others farthest first, where a second child is hit before the cut (misses, then children
     * beyond the cut, sort last, so those to push are k1, k2, k3 in order: k3 and k2 are written and
     * counted only if hit before the cut, the stack has 3 spare entries).
     * Without push_refs no ref is picked for them here (the pop reads it from the node). */
    if (bvh4_hit_key(k1, cut)) {
        int n = *sp;
        stack[n].row = push_refs ? rt_as_int(get4(refs, (int)(k3 & 3))) : row;
        stack[n].key = (int)k3;
        n += bvh4_hit_key(k3, cut);
        stack[n].row = push_refs ? rt_as_int(get4(refs, (int)(k2 & 3))) : row;
        stack[n].key = (int)k2;
        n += bvh4_hit_key(k2, cut);
        stack[n].row = push_refs ? rt_as_int(get4(refs, (int)(k1 & 3))) : row;
        stack[n].key = (int)k1;
        *sp = n + 1;
        top->row = row;
        top->key = (int)k1;
    }
    return nearest;
}

/* A pending child's ref, read from its node's refs row */
RT_FN int bvh4_entry_ref(RT_SCENE_PARAMS, Bvh4Entry e)
{
    return load_node_word(node_data, 4 * (e.row + 6) + (e.key & 3));
}

/* The most recent pending child that may still hold a hit as close as the closest hit so far (its
 * key within the cut, bvh4_cut), or BVH4_NONE. push_refs as the visit pushed them (bvh4_visit): the
 * ray fetch's walk pushes refs, since it pops inside its visit loop, where a pop's node read would
 * stand between the stack's read and the next visit's; the closest-hit walk reads the ref from the
 * node (its visit stays shorter; bvh4_pop_top takes the stack read off its path instead). */
RT_FN int bvh4_pop(RT_SCENE_PARAMS, const Bvh4Entry *stack, int *sp, unsigned int cut, int push_refs)
{
    while (*sp > 0) {
        --*sp;
        Bvh4Entry e = stack[*sp];
        if (bvh4_hit_key((unsigned int)e.key, cut))
            return push_refs ? e.row : bvh4_entry_ref(RT_SCENE_ARGS, e);
    }
    return BVH4_NONE;
}

/* bvh4_pop with the stack's top entry held in registers (*top, kept by bvh4_visit): the popped entry
 * needs no local-memory read, and the read of the entry below it is issued here and waited for only
 * at the next pop. The closest-hit walk (camera rays) gains by it; the ray fetch's walk, whose state
 * outlives each refill, lost by it and pops from memory (docs/results.md has both A/Bs). */
RT_FN int bvh4_pop_top(RT_SCENE_PARAMS, const Bvh4Entry *stack, int *sp, unsigned int cut, Bvh4Entry *top)
{
    while (*sp > 0) {
        --*sp;
        Bvh4Entry e = *top;
        if (*sp > 0)
            *top = stack[*sp - 1];
        if (bvh4_hit_key((unsigned int)e.key, cut))
            return bvh4_entry_ref(RT_SCENE_ARGS, e);
    }
    return BVH4_NONE;
}

/* Test the triangles of leaf ref `leaf`; returns 1 when an any-hit query may stop */
RT_FN int bvh4_leaf(RT_SCENE_PARAMS, int leaf, const Ray *ray, Hit *hit, int any_hit)
{
    int bits = ~leaf;
    int row = bits >> BVH4_LEAF_BITS;
    int count = bits & ((1 << BVH4_LEAF_BITS) - 1);
    for (int i = 0; i < count; ++i) {
        if (intersect_bvh8_tri(RT_SCENE_ARGS, row + BVH8_TRI_ROWS * i, ray, hit) && any_hit)
            return 1;
    }
    return 0;
}

/* traverse_bvh4's walk from the root, once the ray is clipped to the scene box and its constants made */
RT_FN void bvh4_walk(RT_SCENE_PARAMS, const Ray *ray, const Bvh4Ray *rp, Hit *hit, int any_hit)
{
    Bvh4Ray r = *rp;
    Bvh4Entry stack[RT_STACK_SIZE + 3], top;
    int sp = 0;
    int ref = 0;
    top.row = 0;
    top.key = 0;
    unsigned int cut = bvh4_cut(&r, hit->t);      /* changes only where a leaf finds a hit */
    for (;;) {
        /* Inner nodes: enter the nearest child hit */
        while (ref >= 0)
            ref = bvh4_visit(RT_SCENE_ARGS, ref, &r, cut, stack, &sp, &top, 0);
        /* A leaf: its triangles' rows */
        if (ref != BVH4_NONE) {
            if (bvh4_leaf(RT_SCENE_ARGS, ref, ray, hit, any_hit))
                return;
            cut = bvh4_cut(&r, hit->t);
        }
        ref = bvh4_pop_top(RT_SCENE_ARGS, stack, &sp, cut, &top);
        if (ref == BVH4_NONE)
            return;
    }
}

/* 4-wide BVH traversal. Closest hit, or with any_hit the first hit found.
 * A warp whose rays share their octant (camera rays in tiles) walks with its near planes' rows as
 * constants: the switch below inlines bvh4_walk once per octant, so a visit's seven loads take their
 * offsets from one address instead of a sum each. The rows are set in each case itself: through a
 * helper taking the octant, NVIDIA's OpenCL kept only part of the gain (docs/results.md, "Camera rays:
 * the 4-wide walk inlined per ray octant").
 * The same walk node for node, so the same hits; a warp whose rays differ walks as before.
 * RT_BVH4_OCTANT_WALKS 1: where the warp shares the octant (library_trace.cu/.cl define it); 2: always
 * (tests: PoCL has no warps to ask); undefined or 0: never (the lab steps, the frames' programs). */
RT_FN void traverse_bvh4(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray, Hit *hit,
                         int any_hit)
{
    float t_enter, t_exit;
    if (!clip_ray_box(ray, scene_min, scene_max, &t_enter, &t_exit))
        return;
    Bvh4Ray r = bvh4_ray(ray, t_exit);
#if defined(RT_BVH4_OCTANT_WALKS) && RT_BVH4_OCTANT_WALKS
    int octant = 4 * r.near_x + 2 * (r.near_y - 2) + (r.near_z - 4);
    if (RT_BVH4_OCTANT_WALKS == 2 || rt_warp_uniform(octant)) {
        switch (octant) {
        case 0: r.near_x = 0; r.near_y = 2; r.near_z = 4; bvh4_walk(RT_SCENE_ARGS, ray, &r, hit, any_hit); return;
        case 1: r.near_x = 0; r.near_y = 2; r.near_z = 5; bvh4_walk(RT_SCENE_ARGS, ray, &r, hit, any_hit); return;
        case 2: r.near_x = 0; r.near_y = 3; r.near_z = 4; bvh4_walk(RT_SCENE_ARGS, ray, &r, hit, any_hit); return;
        case 3: r.near_x = 0; r.near_y = 3; r.near_z = 5; bvh4_walk(RT_SCENE_ARGS, ray, &r, hit, any_hit); return;
        case 4: r.near_x = 1; r.near_y = 2; r.near_z = 4; bvh4_walk(RT_SCENE_ARGS, ray, &r, hit, any_hit); return;
        case 5: r.near_x = 1; r.near_y = 2; r.near_z = 5; bvh4_walk(RT_SCENE_ARGS, ray, &r, hit, any_hit); return;
        case 6: r.near_x = 1; r.near_y = 3; r.near_z = 4; bvh4_walk(RT_SCENE_ARGS, ray, &r, hit, any_hit); return;
        case 7: r.near_x = 1; r.near_y = 3; r.near_z = 5; bvh4_walk(RT_SCENE_ARGS, ray, &r, hit, any_hit); return;
        default: break;
        }
    }
#endif
    bvh4_walk(RT_SCENE_ARGS, ray, &r, hit, any_hit);
}

/* traverse_bvh4's closest hit with its state kept across returns, for rays fetched as lanes free up
 * (trace_rays_fetch, rt_entry_trace.h; rt_bvh.h's bvh_trace_steps is the binary BVH's and says how) */
typedef struct {
    Ray ray;
    Bvh4Ray fused;
    Hit hit;
    int ref;                               /* next node: inner >= 0, leaf < 0, BVH_DONE */
    int sp;
} Bvh4Trace;

RT_FN void bvh4_trace_start(Bvh4Trace *s, float4 scene_min, float4 scene_max)
{
    float t_exit;
    if (bvh_walk_start(&s->ray, &s->hit, &s->ref, &s->sp, scene_min, scene_max, &t_exit))
        s->fused = bvh4_ray(&s->ray, t_exit);
}

/* The ray fetch's warp schedule (a lane's walk stays the same node for node; the hits are the same):
 * - the visit loop is left once fewer than RT_FETCH_VISIT_EXIT lanes are still in it and another lane
 *   of the warp is at its leaf: the lanes at leaves test them and pop, the few still between nodes go
 *   on in the next round (1: left at its last lane, Aila & Laine's while-while, and no switch below);
 * - with RT_FETCH_POP_IN_LOOP, a visit that enters no child pops the next pending one inside the
 *   loop, so the lane stays in it until it reaches a leaf (or its ray is done) instead of spending a
 *   round without one, idle while the others test their leaves.
 * Both raise the lanes busy a warp instruction, where diffuse rays leave most of a warp idle. Chosen
 * on the H100 (docs/results.md, "The ray fetch's visit loop left early, and pops in the loop", with
 * the scenes where they lose); experiments/fetch_lane_model.py models the lanes busy. */
#ifndef RT_FETCH_VISIT_EXIT
#define RT_FETCH_VISIT_EXIT 6
#endif
#ifndef RT_FETCH_POP_IN_LOOP
#define RT_FETCH_POP_IN_LOOP 1
#endif
#ifndef RT_FETCH_PUSH_REFS
#define RT_FETCH_PUSH_REFS 1         /* the ray fetch's stack holds the children's refs (bvh4_pop) */
#endif
#ifndef RT_FETCH_VISIT_EXIT_EACH
#define RT_FETCH_VISIT_EXIT_EACH 0   /* tests: leave it after every visit (PoCL has no warp to count) */
#endif

/* The visit loop of bvh4_trace_steps, as scheduled above: leaves s->ref at a leaf, at BVH4_NONE (no child
 * entered), at BVH_DONE (popped in the loop, none left) or, left early, at an inner node */
RT_FN void bvh4_fetch_visits(RT_SCENE_PARAMS, Bvh4Trace *s, Bvh4Entry *stack, unsigned int cut)
{
    Bvh4Entry unused_top;              /* this walk pops from memory (bvh4_pop_top says why) */
#if RT_FETCH_VISIT_EXIT > 1
    int walking = rt_warp_active(), visited = 0;
    while ((unsigned int)s->ref < (unsigned int)BVH_DONE) {
        int in_loop = rt_warp_active();
        if ((in_loop < RT_FETCH_VISIT_EXIT && in_loop < walking) || (RT_FETCH_VISIT_EXIT_EACH && visited))
            break;
        s->ref = bvh4_visit(RT_SCENE_ARGS, s->ref, &s->fused, cut, stack, &s->sp, &unused_top, RT_FETCH_PUSH_REFS);
#if RT_FETCH_POP_IN_LOOP
        if (s->ref == BVH4_NONE) {            /* no child entered: the next pending one */
            s->ref = bvh4_pop(RT_SCENE_ARGS, stack, &s->sp, cut, RT_FETCH_PUSH_REFS);
            if (s->ref == BVH4_NONE)
                s->ref = BVH_DONE;
        }
#endif
        visited = 1;
    }
#else
    while ((unsigned int)s->ref < (unsigned int)BVH_DONE)
        s->ref = bvh4_visit(RT_SCENE_ARGS, s->ref, &s->fused, cut, stack, &s->sp, &unused_top, RT_FETCH_PUSH_REFS);
#endif
}

RT_FN void bvh4_trace_steps(RT_SCENE_PARAMS, Bvh4Trace *s, Bvh4Entry *stack)
{
    unsigned int cut = bvh4_cut(&s->fused, s->hit.t);
    for (;;) {
        bvh4_fetch_visits(RT_SCENE_ARGS, s, stack, cut);
        if (s->ref < 0) {                     /* at a leaf, or no child entered */
            if (s->ref != BVH4_NONE) {
                bvh4_leaf(RT_SCENE_ARGS, s->ref, &s->ray, &s->hit, 0);
                cut = bvh4_cut(&s->fused, s->hit.t);
            }
            s->ref = bvh4_pop(RT_SCENE_ARGS, stack, &s->sp, cut, RT_FETCH_PUSH_REFS);
            if (s->ref == BVH4_NONE)
                s->ref = BVH_DONE;
        }
        if (s->ref == BVH_DONE || rt_warp_active() < RT_FETCH_THRESHOLD)
            return;
    }
}

#endif /* RT_BVH4_H */
