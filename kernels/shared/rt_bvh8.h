/* rt_bvh8.h - compressed 8-wide BVH traversal after Ylitie, Karras & Laine, "Efficient Incoherent Ray
 * Traversal on GPUs Through Compressed Wide BVHs" (HPG 2017): 80-byte nodes whose eight child boxes
 * are quantised to 8 bits a plane against a node origin and a power-of-two step per axis, child slots
 * ordered by ray octant so that visiting them in a fixed bit order is roughly front to back, leaf
 * triangles in contiguous rows, and the traversal state as node and triangle hit masks ("groups") on
 * a small stack. Built by rtlab/accel/bvh8.py from the binary SAH/SBVH trees (optimal collapse).
 *
 * Node layout in node_data, 5 float4 = 80 B per node (sync with rtlab/accel/bvh8.py):
 *   [row + 0] = (p.x, p.y, p.z, bytes e.x + 127, e.y + 127, e.z + 127, imask)
 *   [row + 1] = (row of the first inner child, row of the first triangle, meta of slots 0-3, 4-7)
 *   [row + 2..4] = q_lo.x[8], q_lo.y[8], q_lo.z[8], q_hi.x[8], q_hi.y[8], q_hi.z[8] (bytes)
 * meta of an inner child in slot s: 0b001 << 5 | (24 + s), its node at row x + 5 popc(imask below s);
 * of a leaf: unary triangle count << 5 | triangle offset, its triangles at rows y + 3 offset ...;
 * empty: 0. Triangles: 3 rows each, (v0.xyz, triangle id bits), (v1.xyz, 0), (v2.xyz, 0). The root is
 * node 0; RT_STACK_SIZE is the tree depth + 1 (rtlab.device.device_scene), so the stack cannot overflow.
 *
 * Box test. A plane of slot j along an axis is p + q 2^e; its distance (p + q 2^e - o) / d is one fma,
 * (2^15 + q) s + off with s = 2^e / d and off = (p - o) / d - 2^15 s computed once a node: 2^15 + q is
 * a float built from q's byte by one byte permute (rt_byte_at_bits8), no int-to-float conversion
 * (a quarter-rate instruction on sm_90). Hazards:
 *  1. off is rounded near 2^15 s: it errs by up to ~2^-9 of one step's distance, the product's
 *     own rounding by a few ulps of the result. The builder rounds every quantised plane 2^-6 of a step
 *     outward (rtlab.accel.bvh8.SLACK_STEPS), eight times that error, so the computed box holds
 *     the exact child box up to the relative rounding that RT_CONSERVATIVE's exit scale (1 + RT_T_PAD)
 *     covers, as in rt_bvh.h: no box the exact test keeps is culled (Ize 2013).
 *  2. A zero direction component gets the inverse +-2^64 (rt_bvh.h's bvh_inverse, -0 as negative):
 *     a ray lying in a slab is inside the quantised slab by the slack, so its interval there spans
 *     +-2^64 x slack, which a ray starting far enough away outruns (2^43 extents of a scene of small
 *     triangles: missed hits). So along such an axis the near planes' distances are padded down and
 *     the far planes' up by the ray's length in the scene box, 2 t_exit, as rt_bvh.h's bvh_origin_pad
 *     does (Bvh8Ray.pad: 0 along every other axis): the slab then holds the whole segment. A box
 *     outside the slab within 2 t_exit / 2^64 of it is kept too (visited, never a wrong hit).
 *     Coordinates up to 2^50 keep products finite.
 *  3. Near and far planes by the direction's sign: the lo and hi bytes swap roles where inv < 0, so
 *     the entry and exit are a max and a min of three distances each (rt_bvh.h's int-bit span test).
 * Boxes are culled beyond t_cull of the closest hit (rt_intersect.h), the scalar BVH's pad, so ties at
 * equal t reach the lower triangle id.
 */
#ifndef RT_BVH8_H
#define RT_BVH8_H
#include "rt_bvh.h"

#define BVH8_NODE_ROWS 5             /* float4 rows a node (sync with rtlab/accel/bvh8.py) */
#define BVH8_TRI_ROWS 3              /* float4 rows a triangle */
#define BVH8_MAGIC 0x47000000u       /* float bits of 2^15: a byte at bits 8-15 makes 2^15 + byte */
#define BVH8_MAGIC_VALUE 32768.0f
#define BVH8_NODE_BITS 0xFF000000u   /* a group's mask: node hits in bits 24-31 (slot ^ octinv), */
#define BVH8_TRI_BITS 0x00FFFFFFu    /* triangle hits in bits 0-23; a node group keeps imask in 0-7 */

/* A node group: the row of a node's first inner child and its pending hits (Ylitie et al.'s node groups) */
typedef struct {
    int base;
    unsigned int mask;
} Bvh8Group;

typedef struct {
    float3 inv;              /* 1/d, or +-2^64 where |d| <= RT_BVH_MIN_DIR (bvh_inverse) */
    float3 pad;              /* 2 t_exit where |d| <= RT_BVH_MIN_DIR, else 0 (hazard 2) */
    float tmin;              /* the ray's tmin, +0 for -0 (bvh_span_enter compares bit patterns) */
    unsigned int octinv;     /* 7 - octant, octant bits 4, 2, 1: x, y, z negative */
    unsigned int octinv4;    /* octinv in each byte */
    int neg_x, neg_y, neg_z; /* inv < 0: the hi plane is the near one */
    unsigned int magic;      /* BVH8_MAGIC */
} Bvh8Ray;

RT_FN Bvh8Ray bvh8_ray(const Ray *ray, float t_exit)
{
    Bvh8Ray r;
    r.inv = f3(bvh_inverse(ray->d.x), bvh_inverse(ray->d.y), bvh_inverse(ray->d.z));
    float t_pad = 2.0f * t_exit;
    r.pad = f3(bvh_origin_pad(ray->d.x, 0.0f, t_pad), bvh_origin_pad(ray->d.y, 0.0f, t_pad),
               bvh_origin_pad(ray->d.z, 0.0f, t_pad));
    r.neg_x = r.inv.x < 0.0f;
    r.neg_y = r.inv.y < 0.0f;
    r.neg_z = r.inv.z < 0.0f;
    r.octinv = 7u - (unsigned int)(4 * r.neg_x + 2 * r.neg_y + r.neg_z);
    r.octinv4 = r.octinv * 0x01010101u;
    r.tmin = ray->tmin > 0.0f ? ray->tmin : 0.0f;
    /* BVH8_MAGIC as a run-time value (tmin's sign bit is 0 here): a literal would take the byte
     * permute's one immediate operand, leaving its four selectors to be rebuilt in registers */
    r.magic = BVH8_MAGIC | ((unsigned int)rt_as_int(r.tmin) & 0x80000000u);
    return r;
}

/* Hits of four child slots (one word of each plane array): for each slot whose quantised box the
 * segment [tmin, t_cut] meets, its meta's bits at its meta's position: one bit at 24 + (slot ^ octinv)
 * for an inner child, the triangle bits for a leaf (Ylitie et al.'s hit mask). */
RT_FN unsigned int bvh8_quad_hits(const Bvh8Ray *r, float3 s, float3 off_near, float3 off_far, float t_cut,
                                  unsigned int meta4,
                                  unsigned int lox, unsigned int loy, unsigned int loz, unsigned int hix,
                                  unsigned int hiy, unsigned int hiz)
{
    unsigned int nx = r->neg_x ? hix : lox, fx = r->neg_x ? lox : hix;
    unsigned int ny = r->neg_y ? hiy : loy, fy = r->neg_y ? loy : hiy;
    unsigned int nz = r->neg_z ? hiz : loz, fz = r->neg_z ? loz : hiz;
    /* Inner children's positions follow the octant: 24 + slot becomes 24 + (slot ^ octinv) */
    unsigned int is_inner4 = (meta4 & (meta4 << 1)) & 0x10101010u;
    unsigned int bit_index4 = (meta4 ^ (r->octinv4 & ((is_inner4 >> 4) * 0xFFu))) & 0x1F1F1F1Fu;
    unsigned int child_bits4 = (meta4 >> 5) & 0x07070707u;
    unsigned int hits = 0u;
#pragma unroll
    for (int j = 0; j < 4; ++j) {
        float tx0 = rt_fma(rt_as_float((int)rt_byte_at_bits8(nx, j, r->magic)), s.x, off_near.x);
        float ty0 = rt_fma(rt_as_float((int)rt_byte_at_bits8(ny, j, r->magic)), s.y, off_near.y);
        float tz0 = rt_fma(rt_as_float((int)rt_byte_at_bits8(nz, j, r->magic)), s.z, off_near.z);
        float tx1 = rt_fma(rt_as_float((int)rt_byte_at_bits8(fx, j, r->magic)), s.x, off_far.x);
        float ty1 = rt_fma(rt_as_float((int)rt_byte_at_bits8(fy, j, r->magic)), s.y, off_far.y);
        float tz1 = rt_fma(rt_as_float((int)rt_byte_at_bits8(fz, j, r->magic)), s.z, off_far.z);
        float t0 = bvh_span_enter(tx0, ty0, tz0, r->tmin);
        float t1 = bvh_span_exit(tx1, ty1, tz1, t_cut);
#if RT_CONSERVATIVE
        t1 *= RT_BVH_EXIT_SCALE;
#endif
        if (t0 <= t1)
            hits |= rt_byte(child_bits4, j) << rt_byte(bit_index4, j);
    }
    return hits;
}

/* The hit mask of a node's eight children (rows n0..n4) for the segment [tmin, t_cut]. */
RT_FN unsigned int bvh8_child_hits(const Ray *ray, const Bvh8Ray *r, float4 n0, float4 n1, float4 n2, float4 n3,
                                   float4 n4, float t_cut)
{
    unsigned int e = (unsigned int)rt_as_int(n0.w);
    /* s = 2^e / d: 2^e from its biased exponent byte, exact */
    float3 s = f3(r->inv.x * rt_as_float((int)((e & 0xFFu) << 23)), r->inv.y * rt_as_float((int)((e & 0xFF00u) << 15)),
                  r->inv.z * rt_as_float((int)((e & 0xFF0000u) << 7)));
    float3 off = f3(rt_fma(n0.x - ray->o.x, r->inv.x, -BVH8_MAGIC_VALUE * s.x),
                    rt_fma(n0.y - ray->o.y, r->inv.y, -BVH8_MAGIC_VALUE * s.y),
                    rt_fma(n0.z - ray->o.z, r->inv.z, -BVH8_MAGIC_VALUE * s.z));
    float3 off_near = sub3(off, r->pad), off_far = add3(off, r->pad);
    unsigned int lo = bvh8_quad_hits(r, s, off_near, off_far, t_cut, (unsigned int)rt_as_int(n1.z), (unsigned int)rt_as_int(n2.x),
                                     (unsigned int)rt_as_int(n2.z), (unsigned int)rt_as_int(n3.x),
                                     (unsigned int)rt_as_int(n3.z), (unsigned int)rt_as_int(n4.x),
                                     (unsigned int)rt_as_int(n4.z));
    unsigned int hi = bvh8_quad_hits(r, s, off_near, off_far, t_cut, (unsigned int)rt_as_int(n1.w), (unsigned int)rt_as_int(n2.y),
                                     (unsigned int)rt_as_int(n2.w), (unsigned int)rt_as_int(n3.y),
                                     (unsigned int)rt_as_int(n3.w), (unsigned int)rt_as_int(n4.y),
                                     (unsigned int)rt_as_int(n4.w));
    return lo | hi;
}

/* The triangle at `row` (three rows, id in the first one's w); whether it became the hit. The
 * vertices are the scene's own floats, so the tests give the binary BVH's bits; Wald's and Plucker's
 * read their precomputed rows by id. */
RT_FN int intersect_bvh8_tri(RT_SCENE_PARAMS, int row, const Ray *ray, Hit *hit)
{
    float4 a = load_node_data(node_data, row);
    int tri = rt_as_int(a.w);
#if RT_ISECT == RT_ISECT_WATERTIGHT || RT_ISECT == RT_ISECT_MOLLER
    float4 b = load_node_data(node_data, row + 1);
    float4 c = load_node_data(node_data, row + 2);
#if RT_ISECT == RT_ISECT_WATERTIGHT
    return intersect_ray_tri_watertight(ray, xyz(a), xyz(b), xyz(c), tri, hit);
#else
    return intersect_ray_tri_moller(ray, xyz(a), xyz(b), xyz(c), tri, hit);
#endif
#else
    return intersect_tri(RT_SCENE_ARGS, ray, tri, hit);
#endif
}

/* Compressed wide BVH traversal (Ylitie et al. 2017, Algorithm 1 without triangle postponing).
 * Closest hit, or with any_hit the first hit found. The current node group holds the pending inner
 * children of a node; the next is its highest bit, whose slot is (bit - 24) ^ octinv; the rest of the
 * group goes on the stack. A node's leaf triangles are tested before its children are entered. */
RT_FN void traverse_bvh8(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray, Hit *hit,
                         int any_hit)
{
    float t_enter, t_exit;
    if (!clip_ray_box(ray, scene_min, scene_max, &t_enter, &t_exit))
        return;
    Bvh8Ray r = bvh8_ray(ray, t_exit);
    Bvh8Group stack[RT_STACK_SIZE];
    int sp = 0;
    Bvh8Group group;
    group.base = 0;
    group.mask = 0x80000000u;          /* the root: one pending child, at rel 0 (no imask bits) */
    float t_cut = t_cull(hit->t);      /* changes only where a triangle test finds a hit */
    for (;;) {
        /* Enter the group's next child; keep the rest for later */
        int bit = 31 - rt_clz(group.mask);
        unsigned int slot = ((unsigned int)bit - 24u) ^ r.octinv;
        int row = group.base + BVH8_NODE_ROWS * rt_popc(group.mask & ~(0xFFFFFFFFu << slot));
        group.mask &= ~(1u << bit);
        if (group.mask & BVH8_NODE_BITS)
            stack[sp++] = group;
        float4 n0 = load_node_data(node_data, row);
        float4 n1 = load_node_data(node_data, row + 1);
        float4 n2 = load_node_data(node_data, row + 2);
        float4 n3 = load_node_data(node_data, row + 3);
        float4 n4 = load_node_data(node_data, row + 4);
        unsigned int hits = bvh8_child_hits(ray, &r, n0, n1, n2, n3, n4, t_cut);
        group.base = rt_as_int(n1.x);
        group.mask = (hits & BVH8_NODE_BITS) | ((unsigned int)rt_as_int(n0.w) >> 24);
        /* The node's leaf triangles, now */
        int tri_base = rt_as_int(n1.y);
        unsigned int tri_hits = hits & BVH8_TRI_BITS;
        if (tri_hits) {
            do {
                int b = 31 - rt_clz(tri_hits);
                tri_hits &= ~(1u << b);
                if (intersect_bvh8_tri(RT_SCENE_ARGS, tri_base + BVH8_TRI_ROWS * b, ray, hit) && any_hit)
                    return;
            } while (tri_hits);
            t_cut = t_cull(hit->t);
        }
        /* No inner child hit: the most recent pending group */
        if (!(group.mask & BVH8_NODE_BITS)) {
            if (sp == 0)
                return;
            group = stack[--sp];
        }
    }
}

#endif /* RT_BVH8_H */
