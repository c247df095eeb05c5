/* rt_lanes.h - RT_LANES values side by side in one work-item: the SIMD registers of a CPU. Part of
 * the port layer (rt_port.h): it defines the lane types and their helpers once per language.
 *
 * A GPU runs one ray a thread and forms its SIMD groups (warps) from threads. PoCL on a CPU runs a
 * work-group's work-items one after another and vectorises across them only where the code between
 * barriers is straight-line: a traversal loop is not, so each ray runs in scalar registers. The
 * CPU traversals therefore put their lanes into one work-item: a packet of RT_LANES rays
 * (rt_bvh_packet.h), or one ray's RT_LANES child boxes or triangles (rt_bvh_wide.h), and write
 * their arithmetic on lane vectors: OpenCL's float8/int8 (one AVX register each on
 * x86-64), which PoCL's compiler keeps as vector instructions. CUDA has no vector operators, so
 * there a lane vector is an array and each helper a loop over it: the same code compiles and runs
 * (one thread a packet), it is only not what a GPU is for.
 *
 *   lanef / lanei   RT_LANES floats / ints; masks are lanei with every bit set where true
 *   lf_* li_*       element-wise helpers (names say what they do; no operator syntax in CUDA)
 *   lane_any        whether any lane of a mask is set
 *   lf_get / lf_set one lane (the gather/scatter at a packet's ends); in OpenCL through the vector's
 *                   memory, so read lanes in unrolled loops, where the index is a constant and the
 *                   read an extract: in a rolled loop LLVM stores every live vector each iteration
 *   lanes_load_rows the lanes of float4 rows (rays), whole packets by vector loads and shuffles
 *   lf_load_rows    one lane vector stored as RT_LANES / 4 consecutive float4 rows (a wide BVH node's
 *                   boxes, a block of triangles), read through a loader of rt_memory.h
 *   lane_bits       a mask as an int, bit k for lane k (which children of a wide node a ray enters)
 *   lane_load_row_float, lane_prefetch_rows  one lane's float of such a vector; a cache prefetch
 * The helpers that mirror a scalar expression (lf_sub_mul, lf_diff_of_products_rn, lf_dot3_scaled,
 * lf_plane_t_fp64)
 * are written as that one expression, so each lane rounds (and contracts into fused multiply-adds)
 * exactly as the scalar code does: the lane triangle tests return the scalar tests' ids and t.
 */
#ifndef RT_LANES_H
#define RT_LANES_H
#include "rt_memory.h"
#include "rt_port.h"

#ifndef RT_LANES                   /* rays in a packet; the loader sets it (rtlab.device.kernels.PACKET_LANES) */
#define RT_LANES 8
#endif
#if RT_LANES != 4 && RT_LANES != 8 && RT_LANES != 16
#error "RT_LANES must be 4, 8 or 16"
#endif

#if defined(__CUDACC__)
typedef struct { float v[RT_LANES]; } lanef;
typedef struct { int v[RT_LANES]; } lanei;
#define RT_LANE_LOOP _Pragma("unroll") for (int k_ = 0; k_ < RT_LANES; ++k_)
#define RT_LF_OP(name, expr) RT_FN lanef name(lanef a, lanef b) { lanef r; RT_LANE_LOOP r.v[k_] = (expr); return r; }
#define RT_LF_CMP(name, op) RT_FN lanei name(lanef a, lanef b) { lanei r; RT_LANE_LOOP r.v[k_] = a.v[k_] op b.v[k_] ? -1 : 0; return r; }
RT_LF_OP(lf_add, a.v[k_] + b.v[k_])
RT_LF_OP(lf_sub, a.v[k_] - b.v[k_])
RT_LF_OP(lf_mul, a.v[k_] * b.v[k_])
RT_LF_OP(lf_min, a.v[k_] < b.v[k_] ? a.v[k_] : b.v[k_])
RT_LF_OP(lf_max, a.v[k_] > b.v[k_] ? a.v[k_] : b.v[k_])
RT_LF_CMP(lf_lt, <)
RT_LF_CMP(lf_le, <=)
RT_LF_CMP(lf_eq, ==)
RT_FN lanef lf_splat(float s) { lanef r; RT_LANE_LOOP r.v[k_] = s; return r; }
RT_FN lanef lf_div(float s, lanef b) { lanef r; RT_LANE_LOOP r.v[k_] = s / b.v[k_]; return r; }
RT_FN lanef lf_select(lanef a, lanef b, lanei m) { lanef r; RT_LANE_LOOP r.v[k_] = m.v[k_] ? b.v[k_] : a.v[k_]; return r; }
RT_FN lanei li_select(lanei a, lanei b, lanei m) { lanei r; RT_LANE_LOOP r.v[k_] = m.v[k_] ? b.v[k_] : a.v[k_]; return r; }
RT_FN lanei li_splat(int s) { lanei r; RT_LANE_LOOP r.v[k_] = s; return r; }
RT_FN lanei li_and(lanei a, lanei b) { lanei r; RT_LANE_LOOP r.v[k_] = a.v[k_] & b.v[k_]; return r; }
RT_FN lanei li_andnot(lanei a, lanei b) { lanei r; RT_LANE_LOOP r.v[k_] = a.v[k_] & ~b.v[k_]; return r; }
RT_FN lanei li_or(lanei a, lanei b) { lanei r; RT_LANE_LOOP r.v[k_] = a.v[k_] | b.v[k_]; return r; }
RT_FN lanei li_lt(lanei a, lanei b) { lanei r; RT_LANE_LOOP r.v[k_] = a.v[k_] < b.v[k_] ? -1 : 0; return r; }
RT_FN int lane_any(lanei m) { int r = 0; RT_LANE_LOOP r |= m.v[k_]; return r != 0; }
RT_FN float lf_hmin(lanef a) { float r = a.v[0]; RT_LANE_LOOP r = a.v[k_] < r ? a.v[k_] : r; return r; }
RT_FN float lf_get(lanef a, int k) { return a.v[k]; }
RT_FN int li_get(lanei a, int k) { return a.v[k]; }
RT_FN void lf_set(lanef *a, int k, float s) { a->v[k] = s; }
RT_FN void li_set(lanei *a, int k, int s) { a->v[k] = s; }
/* Sums of products as one expression each, so the compiler contracts them into fused multiply-adds
 * as it does the scalar code's dot3 and cross3 */
RT_FN lanef lf_dot3(lanef ax, lanef ay, lanef az, lanef bx, lanef by, lanef bz)
{
    lanef r;
    RT_LANE_LOOP r.v[k_] = ax.v[k_] * bx.v[k_] + ay.v[k_] * by.v[k_] + az.v[k_] * bz.v[k_];
    return r;
}
RT_FN lanef lf_dot3s(lanef ax, lanef ay, lanef az, float bx, float by, float bz)
{
    lanef r;
    RT_LANE_LOOP r.v[k_] = ax.v[k_] * bx + ay.v[k_] * by + az.v[k_] * bz;
    return r;
}
RT_FN lanef lf_cross1(lanef a, float b, lanef c, float d)    /* a b - c d: a cross product's component */
{
    lanef r;
    RT_LANE_LOOP r.v[k_] = a.v[k_] * b - c.v[k_] * d;
    return r;
}
RT_FN lanef lf_nan_to(lanef a, float s) { lanef r; RT_LANE_LOOP r.v[k_] = a.v[k_] != a.v[k_] ? s : a.v[k_]; return r; }
RT_FN lanef lf_fms(float a, lanef b, lanef c) { lanef r; RT_LANE_LOOP r.v[k_] = rt_fma(a, b.v[k_], -c.v[k_]); return r; }
RT_FN lanei lf_finite(lanef a) { lanei r; RT_LANE_LOOP r.v[k_] = isfinite(a.v[k_]) ? -1 : 0; return r; }
/* d with components of magnitude <= tiny replaced by tiny of their sign (-0 counts as negative) */
/* Lanes whose |a| <= tiny */
RT_FN lanei lf_tiny(lanef a, float tiny) { lanei r; RT_LANE_LOOP r.v[k_] = fabsf(a.v[k_]) <= tiny ? -1 : 0; return r; }
RT_FN lanef lf_abs(lanef a) { lanef r; RT_LANE_LOOP r.v[k_] = fabsf(a.v[k_]); return r; }
RT_FN lanef lf_away_from_zero(lanef d, float tiny)
{
    lanef r;
    RT_LANE_LOOP r.v[k_] = fabsf(d.v[k_]) > tiny ? d.v[k_] : copysignf(tiny, d.v[k_]);
    return r;
}
RT_FN lanei li_eq(lanei a, lanei b) { lanei r; RT_LANE_LOOP r.v[k_] = a.v[k_] == b.v[k_] ? -1 : 0; return r; }
RT_FN lanei li_add1(lanei a) { lanei r; RT_LANE_LOOP r.v[k_] = a.v[k_] + 1; return r; }
RT_FN lanef lf_sqrt(lanef a) { lanef r; RT_LANE_LOOP r.v[k_] = sqrtf(a.v[k_]); return r; }
RT_FN lanef lf_div_lanes(lanef a, lanef b) { lanef r; RT_LANE_LOOP r.v[k_] = a.v[k_] / b.v[k_]; return r; }
RT_FN void lf_store(float *p, lanef a) { RT_LANE_LOOP p[k_] = a.v[k_]; }
RT_FN void li_store(int *p, lanei a) { RT_LANE_LOOP p[k_] = a.v[k_]; }
RT_FN lanef lf_sub_mul(lanef a, lanef s, lanef c) { lanef r; RT_LANE_LOOP r.v[k_] = a.v[k_] - s.v[k_] * c.v[k_]; return r; }
RT_FN lanef lf_diff_mul(lanef a, lanef b, lanef c, lanef d)    /* a b - c d: cross3's component */
{
    lanef r;
    RT_LANE_LOOP r.v[k_] = a.v[k_] * b.v[k_] - c.v[k_] * d.v[k_];
    return r;
}
RT_FN lanef lf_diff_of_products_rn(lanef a, lanef b, lanef c, lanef d)
{
    lanef r;
    RT_LANE_LOOP r.v[k_] = diff_of_products_rn(a.v[k_], b.v[k_], c.v[k_], d.v[k_]);
    return r;
}
RT_FN lanef lf_dot3_scaled(lanef a, lanef b, lanef c, lanef s, lanef x, lanef y, lanef z)
{
    lanef r;
    RT_LANE_LOOP r.v[k_] = a.v[k_] * (s.v[k_] * x.v[k_]) + b.v[k_] * (s.v[k_] * y.v[k_]) + c.v[k_] * (s.v[k_] * z.v[k_]);
    return r;
}
#if RT_HAS_FP64
/* rt_intersect.h's plane_t_fp64_n on each lane's ray o + t d, the triangle's v0 = (px, py, pz) and
 * normal n in double */
RT_FN lanef lf_plane_t_fp64(lanef ox, lanef oy, lanef oz, lanef dx, lanef dy, lanef dz, double px, double py,
                            double pz, double nx, double ny, double nz)
{
    lanef r;
    RT_LANE_LOOP {
        double num = nx * (px - (double)ox.v[k_]) + ny * (py - (double)oy.v[k_]) + nz * (pz - (double)oz.v[k_]);
        double den = nx * (double)dx.v[k_] + ny * (double)dy.v[k_] + nz * (double)dz.v[k_];
        r.v[k_] = (float)(num / den);
    }
    return r;
}
#endif
RT_FN int lane_bits(lanei m) { int r = 0; RT_LANE_LOOP r |= m.v[k_] ? 1 << k_ : 0; return r; }
RT_FN lanei li_of_bits(lanef a) { lanei r; RT_LANE_LOOP r.v[k_] = __float_as_int(a.v[k_]); return r; }
RT_FN lanef lf_join4(float4 a, float4 b, float4 c, float4 d)
{
    float4 q[4] = {a, b, c, d};
    lanef r;
    RT_LANE_LOOP {
        float4 e = q[k_ >> 2];
        r.v[k_] = (k_ & 3) == 0 ? e.x : (k_ & 3) == 1 ? e.y : (k_ & 3) == 2 ? e.z : e.w;
    }
    return r;
}
#define lf_join1(a) lf_join4((a), (a), (a), (a))
#define lf_join2(a, b) lf_join4((a), (b), (a), (b))
/* Lanes 0 .. count - 1 of x, y, z, w from p[first ..] (float4 rows); the others 0 */
RT_FN void lanes_load_rows(RT_GLOBAL const float4 *p, int first, int count, lanef *x, lanef *y, lanef *z, lanef *w)
{
    RT_LANE_LOOP {
        float4 a = k_ < count ? p[first + k_] : make_float4(0.0f, 0.0f, 0.0f, 0.0f);
        x->v[k_] = a.x;
        y->v[k_] = a.y;
        z->v[k_] = a.z;
        w->v[k_] = a.w;
    }
}
#else /* OpenCL C: vector types and operators; min/max/select/any map to single instructions */
#if RT_LANES == 4
typedef float4 lanef;
typedef int4 lanei;
#elif RT_LANES == 8
typedef float8 lanef;
typedef int8 lanei;
#else
typedef float16 lanef;
typedef int16 lanei;
#endif
RT_FN lanef lf_add(lanef a, lanef b) { return a + b; }
RT_FN lanef lf_sub(lanef a, lanef b) { return a - b; }
RT_FN lanef lf_mul(lanef a, lanef b) { return a * b; }
/* min/max of OpenCL (not fmin/fmax): one instruction, no NaN rule; the packet code keeps NaN out */
RT_FN lanef lf_min(lanef a, lanef b) { return min(a, b); }
RT_FN lanef lf_max(lanef a, lanef b) { return max(a, b); }
RT_FN lanei lf_lt(lanef a, lanef b) { return a < b; }
RT_FN lanei lf_le(lanef a, lanef b) { return a <= b; }
RT_FN lanei lf_eq(lanef a, lanef b) { return a == b; }
RT_FN lanef lf_splat(float s) { return (lanef)(s); }
RT_FN lanef lf_div(float s, lanef b) { return (lanef)(s) / b; }
RT_FN lanef lf_select(lanef a, lanef b, lanei m) { return select(a, b, m); }
RT_FN lanei li_select(lanei a, lanei b, lanei m) { return select(a, b, m); }
RT_FN lanei li_splat(int s) { return (lanei)(s); }
RT_FN lanei li_and(lanei a, lanei b) { return a & b; }
RT_FN lanei li_andnot(lanei a, lanei b) { return a & ~b; }
RT_FN lanei li_or(lanei a, lanei b) { return a | b; }
RT_FN lanei li_lt(lanei a, lanei b) { return a < b; }
/* OR of the lanes, sign bit tested: branch-free (PoCL's any() tests lane after lane) */
RT_FN int lane_any(lanei m)
{
#if RT_LANES == 16
    int8 h = m.lo | m.hi;
    int4 q = h.lo | h.hi;
#elif RT_LANES == 8
    int4 q = m.lo | m.hi;
#else
    int4 q = m;
#endif
    int2 p = q.lo | q.hi;
    return (p.x | p.y) < 0;
}
RT_FN float lf_hmin(lanef a)
{
#if RT_LANES == 16
    float8 h = min(a.lo, a.hi);
    float4 q = min(h.lo, h.hi);
#elif RT_LANES == 8
    float4 q = min(a.lo, a.hi);
#else
    float4 q = a;
#endif
    float2 p = min(q.lo, q.hi);
    return min(p.x, p.y);
}
/* Sums of products as one expression each, so the compiler contracts them into fused multiply-adds
 * as it does the scalar code's dot3 and cross3 */
RT_FN lanef lf_dot3(lanef ax, lanef ay, lanef az, lanef bx, lanef by, lanef bz) { return ax * bx + ay * by + az * bz; }
RT_FN lanef lf_dot3s(lanef ax, lanef ay, lanef az, float bx, float by, float bz) { return ax * bx + ay * by + az * bz; }
RT_FN lanef lf_cross1(lanef a, float b, lanef c, float d) { return a * b - c * d; }
RT_FN float lf_get(lanef a, int k) { return ((float *)&a)[k]; }
RT_FN int li_get(lanei a, int k) { return ((int *)&a)[k]; }
RT_FN void lf_set(lanef *a, int k, float s) { ((float *)a)[k] = s; }
RT_FN void li_set(lanei *a, int k, int s) { ((int *)a)[k] = s; }
RT_FN lanef lf_nan_to(lanef a, float s) { return select(a, (lanef)(s), isnan(a)); }
RT_FN lanef lf_fms(float a, lanef b, lanef c) { return fma((lanef)(a), b, -c); }
RT_FN lanei lf_finite(lanef a) { return isfinite(a); }
/* d with components of magnitude <= tiny replaced by tiny of their sign (-0 counts as negative) */
RT_FN lanef lf_away_from_zero(lanef d, float tiny) { return select(copysign((lanef)(tiny), d), d, fabs(d) > tiny); }
RT_FN lanei lf_tiny(lanef a, float tiny) { return fabs(a) <= (lanef)(tiny); }
RT_FN lanef lf_abs(lanef a) { return fabs(a); }
RT_FN lanei li_eq(lanei a, lanei b) { return a == b; }
RT_FN lanei li_add1(lanei a) { return a + 1; }
RT_FN lanef lf_sqrt(lanef a) { return sqrt(a); }
RT_FN lanef lf_div_lanes(lanef a, lanef b) { return a / b; }
/* The lanes into a private array (a traversal's few dynamically indexed reads) */
#if RT_LANES == 4
RT_FN void lf_store(float *p, lanef a) { vstore4(a, 0, p); }
RT_FN void li_store(int *p, lanei a) { vstore4(a, 0, p); }
#elif RT_LANES == 8
RT_FN void lf_store(float *p, lanef a) { vstore8(a, 0, p); }
RT_FN void li_store(int *p, lanei a) { vstore8(a, 0, p); }
#else
RT_FN void lf_store(float *p, lanef a) { vstore16(a, 0, p); }
RT_FN void li_store(int *p, lanei a) { vstore16(a, 0, p); }
#endif
RT_FN lanef lf_sub_mul(lanef a, lanef s, lanef c) { return a - s * c; }
RT_FN lanef lf_diff_mul(lanef a, lanef b, lanef c, lanef d) { return a * b - c * d; }
RT_FN lanef lf_diff_of_products_rn(lanef a, lanef b, lanef c, lanef d)
{
#pragma OPENCL FP_CONTRACT OFF
    return a * b - c * d;
}
#if RT_HAS_FP64
#if RT_LANES == 4
#define RT_LANED double4
#define RT_LANE_DOUBLE(a) convert_double4(a)
#define RT_LANE_FLOAT(a) convert_float4(a)
#elif RT_LANES == 8
#define RT_LANED double8
#define RT_LANE_DOUBLE(a) convert_double8(a)
#define RT_LANE_FLOAT(a) convert_float8(a)
#else
#define RT_LANED double16
#define RT_LANE_DOUBLE(a) convert_double16(a)
#define RT_LANE_FLOAT(a) convert_float16(a)
#endif
#endif
RT_FN lanef lf_dot3_scaled(lanef a, lanef b, lanef c, lanef s, lanef x, lanef y, lanef z)
{
    return a * (s * x) + b * (s * y) + c * (s * z);
}
#if RT_HAS_FP64
/* rt_intersect.h's plane_t_fp64_n on each lane's ray o + t d, the triangle's v0 = (px, py, pz) and
 * normal n in double: the same expression on double lanes (two AVX registers, or one AVX-512) */
RT_FN lanef lf_plane_t_fp64(lanef ox, lanef oy, lanef oz, lanef dx, lanef dy, lanef dz, double px, double py,
                            double pz, double nx, double ny, double nz)
{
    RT_LANED num = nx * (px - RT_LANE_DOUBLE(ox)) + ny * (py - RT_LANE_DOUBLE(oy)) + nz * (pz - RT_LANE_DOUBLE(oz));
    RT_LANED den = nx * RT_LANE_DOUBLE(dx) + ny * RT_LANE_DOUBLE(dy) + nz * RT_LANE_DOUBLE(dz);
    return RT_LANE_FLOAT(num / den);
}
#endif
/* Bit k of the result is lane k's sign bit: one vmovmskps where the compiler targets AVX (PoCL on
 * x86-64 does; LLVM does not see the generic form below as one), else an AND with the lane's bit
 * and an OR across the lanes */
RT_FN int lane_bits(lanei m)
{
#if RT_LANES == 8 && defined(__AVX__)
    return __builtin_ia32_movmskps256(as_float8(m));
#elif RT_LANES == 4 && defined(__SSE__)
    return __builtin_ia32_movmskps(as_float4(m));
#else
#if RT_LANES == 16
    int16 w = m & (int16)(1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096, 8192, 16384, 32768);
    int8 h = w.lo | w.hi;
    int4 q = h.lo | h.hi;
#elif RT_LANES == 8
    int8 w = m & (int8)(1, 2, 4, 8, 16, 32, 64, 128);
    int4 q = w.lo | w.hi;
#else
    int4 q = m & (int4)(1, 2, 4, 8);
#endif
    int2 p = q.lo | q.hi;
    return p.x | p.y;
#endif
}
#if RT_LANES == 4
RT_FN lanei li_of_bits(lanef a) { return as_int4(a); }
#define lf_join1(a) (a)
#elif RT_LANES == 8
RT_FN lanei li_of_bits(lanef a) { return as_int8(a); }
#define lf_join2(a, b) ((float8)((a), (b)))
#else
RT_FN lanei li_of_bits(lanef a) { return as_int16(a); }
#define lf_join4(a, b, c, d) ((float16)((a), (b), (c), (d)))
#endif
/* Lanes 0 .. count - 1 of x, y, z, w from p[first ..] (float4 rows); the others 0. A whole packet
 * (8 lanes) is four 8-float loads and shuffles, not a store per lane followed by a vector load. */
RT_FN void lanes_load_rows(__global const float4 *p, int first, int count, lanef *x, lanef *y, lanef *z, lanef *w)
{
#if RT_LANES == 8
    if (count == RT_LANES) {
        __global const float *f = (__global const float *)(p + first);
        float8 a = vload8(0, f), b = vload8(1, f), c = vload8(2, f), d = vload8(3, f);   /* 2 rows each */
        *x = (float8)(a.s04, b.s04, c.s04, d.s04);
        *y = (float8)(a.s15, b.s15, c.s15, d.s15);
        *z = (float8)(a.s26, b.s26, c.s26, d.s26);
        *w = (float8)(a.s37, b.s37, c.s37, d.s37);
        return;
    }
#endif
    *x = (lanef)(0.0f);
    *y = *x;
    *z = *x;
    *w = *x;
    for (int k = 0; k < count; ++k) {
        float4 a = p[first + k];
        lf_set(x, k, a.x);
        lf_set(y, k, a.y);
        lf_set(z, k, a.z);
        lf_set(w, k, a.w);
    }
}
#endif

/* The lane vector stored in float4 rows row .. row + RT_LANES / 4 - 1 of buf, read by load, a
 * loader of rt_memory.h (load_node_data): the loaders stay the only reads of scene buffers. In
 * OpenCL's global placement, where such a loader is buf[i], one vector load of the same floats
 * (two float4 loads joined come out as two loads and a shuffle). */
#if !defined(__CUDACC__) && RT_NODE_MEM == RT_MEM_GLOBAL && !RT_COUNT_WORK
#define lf_load_rows(load, buf, row) RT_LANE_VLOAD(0, (__global const float *)((buf) + (row)))
#define lane_load_row_float(load, buf, row, k) (((__global const float *)((buf) + (row)))[(k)])
/* Start loading the 64-byte line of float4 rows row .. row + 3 into the cache: a traversal asks
 * for a node it pushed long before it pops it. Clang's builtin, prefetcht0 on x86-64 (OpenCL's own
 * prefetch() compiles to nothing on PoCL 3.1). */
#if defined(__AVX__)
#define lane_prefetch_rows(buf, row) __builtin_prefetch((buf) + (row))
#endif
#if RT_LANES == 4
#define RT_LANE_VLOAD vload4
#elif RT_LANES == 8
#define RT_LANE_VLOAD vload8
#else
#define RT_LANE_VLOAD vload16
#endif
#elif RT_LANES == 4
#define lf_load_rows(load, buf, row) lf_join1(load(buf, row))
#elif RT_LANES == 8
#define lf_load_rows(load, buf, row) lf_join2(load(buf, row), load(buf, (row) + 1))
#else
#define lf_load_rows(load, buf, row) lf_join4(load(buf, row), load(buf, (row) + 1), load(buf, (row) + 2), load(buf, (row) + 3))
#endif
#define li_load_rows(load, buf, row) li_of_bits(lf_load_rows(load, buf, row))
/* Lane k of the lane vector at float4 row `row` (k need not be a constant): one scalar load in
 * OpenCL's global placement, else its float4 through the loader and a select */
#ifndef lane_prefetch_rows
#define lane_prefetch_rows(buf, row) ((void)0)
#endif
#ifndef lane_load_row_float
#define lane_load_row_float(load, buf, row, k) get4(load(buf, (row) + ((k) >> 2)), (k) & 3)
#endif

#endif /* RT_LANES_H */
