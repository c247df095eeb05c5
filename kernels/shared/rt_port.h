/* rt_port.h - the portability layer: one source of device code for two languages.
 *
 * Compiled as CUDA C++ by nvcc (sm_90; pycuda) and as OpenCL C by NVIDIA's OpenCL 3.0 and PoCL.
 * The port layer is three headers, the only ones that test __CUDACC__ (tests/test_architecture.py
 * checks): this one (qualifiers, math, atomics, barriers, double precision), rt_memory.h (where the
 * scene's buffers live and how they are read) and rt_lanes.h (SIMD lane vectors of the CPU packet
 * traversal). Algorithm headers include them and are written in the C both languages accept: no
 * references, templates, overloads or default arguments; results come back through a pointer
 * (Hit *hit). Entry kernels are written once too (rt_entry_*.h), through the kernel-side macros
 * below: RT_KERNEL, RT_IN/RT_OUT buffers, RT_SHARED block-wide variables, the thread indices
 * (rt_global_id...) and the constant-memory items (RT_WITH_FRAME in a signature, rt_frame in a body:
 * CUDA reads module symbols c_frame, c_lights, c_materials, which each .cu declares; OpenCL takes
 * __constant pointers, last). A program's .cu and .cl files only declare storage and pick the entry
 * headers it holds.
 *
 * Pitfall: float3 is 12 bytes in CUDA and 16 in OpenCL. It is used only in registers, never in a
 * buffer shared with the host (those are float4, mirrored by numpy dtypes in rtlab/device/layout.py).
 */
#ifndef RT_PORT_H
#define RT_PORT_H

/* ---- Variants: compile-time switches. rtlab/device/kernels.py passes -D for each; these are the
 * defaults. The host reads the codes from this file (rtlab/kernel_constants.py): one source. */
#define RT_ISECT_MOLLER 0          /* Moller & Trumbore 1997 (Table 3, MT) */
#define RT_ISECT_WALD 1            /* Wald 2004 projection test, precomputed data (Table 3) */
#define RT_ISECT_PLUCKER 2         /* Plucker coordinates, precomputed (Table 3) */
#define RT_ISECT_WATERTIGHT 3      /* Woop, Benthin & Wald 2013, with conservative traversal */
#define RT_TRAVERSAL_STACK 0       /* single ray, per-thread stack (Table 4, first column) */
#define RT_TRAVERSAL_PACKET 1      /* block-wide packet with a shared stack (Table 4) */
#define RT_TRAVERSAL_RESTART 2     /* kd-restart, Foley & Sugerman 2005 */
#define RT_TRAVERSAL_SHORTSTACK 3  /* short stack, Horn et al. 2007 */
#define RT_TRAVERSAL_ROPES 4       /* ropes, Popov et al. 2007 */
#define RT_TRAVERSAL_BVH 5         /* binned-SAH BVH, Aila & Laine 2009 style (the paper's future work) */
#define RT_TRAVERSAL_BVH_PACKET 6  /* the same BVH, RT_LANES rays a work-item in SIMD lanes: for CPUs */
#define RT_TRAVERSAL_BVH8 7        /* compressed 8-wide BVH, Ylitie, Karras & Laine 2017 (rt_bvh8.h) */
#define RT_TRAVERSAL_BVH4 8        /* 4-wide BVH, float boxes, nearest child first (rt_bvh4.h) */
#define RT_TRAVERSAL_BVH_WIDE 9    /* a BVH of RT_LANES children a node in SIMD lanes, one ray: for CPUs */
#define RT_MEM_GLOBAL 0            /* tree and triangles through read-only global loads */
#define RT_MEM_TEXTURE 1           /* ... through CUDA texture objects / OpenCL images (§3.1.1) */
#define RT_MEM_CONSTANT 2          /* camera, lights, materials in constant memory (§3.1.1) */
#define RT_MEM_REGISTERS 3         /* ray origin/direction in registers, components picked by selects */
#define RT_MEM_SHARED 4            /* ... in shared memory: the paper's cure for local-memory rays (§3.1.1) */
#define RT_MEM_INDEXED 5           /* ... as arrays indexed by the split axis: what spilled in 2008 */
#define RT_ORDER_ROWS 0            /* a block's threads take its pixels row by row */
#define RT_ORDER_MORTON 1          /* ... in Morton (Z) order: each warp an 8x4 tile (§4.1, coherence) */

#ifndef RT_ISECT
#define RT_ISECT RT_ISECT_MOLLER
#endif
#ifndef RT_CONSERVATIVE            /* 1: box and kd split tests padded by their rounding bound (Ize 2013) */
#define RT_CONSERVATIVE (RT_ISECT == RT_ISECT_WATERTIGHT)
#endif
#ifndef RT_TRAVERSAL
#define RT_TRAVERSAL RT_TRAVERSAL_STACK
#endif
#ifndef RT_NODE_MEM
#define RT_NODE_MEM RT_MEM_GLOBAL
#endif
#ifndef RT_CONST_MEM               /* camera, lights, materials: RT_MEM_CONSTANT or RT_MEM_GLOBAL */
#define RT_CONST_MEM RT_MEM_CONSTANT
#endif
#ifndef RT_RAY_MEM                 /* RT_MEM_REGISTERS, RT_MEM_SHARED (01_memory kernels) or RT_MEM_INDEXED */
#define RT_RAY_MEM RT_MEM_REGISTERS
#endif
#ifndef RT_RAY_ORDER
#define RT_RAY_ORDER RT_ORDER_ROWS
#endif
#ifndef RT_STACK_SIZE              /* the loader sets tree depth + 1, so the stack cannot overflow */
#define RT_STACK_SIZE 64
#endif
#ifndef RT_SMOOTH_NORMALS          /* 1: interpolate per-vertex normals; 0: flat (no normal buffer reads) */
#define RT_SMOOTH_NORMALS 0
#endif
#ifndef RT_MAX_LIGHTS
#define RT_MAX_LIGHTS 4
#endif
#ifndef RT_MAX_MATERIALS
#define RT_MAX_MATERIALS 64
#endif
#ifndef RT_WRITE_HITS              /* 1: the render kernel also writes each pixel's hit record */
#define RT_WRITE_HITS 0
#endif
#ifndef RT_TRACE_THREADS           /* threads a block of trace_rays: the host launches this many (read from */
#define RT_TRACE_THREADS 128       /* here); a ray in shared memory takes one slot of a block's array each */
#endif

/* ---- Language split ---- */
#if defined(__CUDACC__)
#define RT_FN static __device__ __forceinline__
#define RT_FN_NOINLINE static __device__ __noinline__  /* a call: its registers are not the caller's */
#ifndef RT_REFINE_CALL             /* the watertight test's double plane distance as a call (rt_intersect.h): */
#define RT_REFINE_CALL 1           /* its doubles off the walk's registers (docs/results.md) */
#endif
#define RT_KERNEL extern "C" __global__
#if __CUDACC_VER_MAJOR__ > 12 || (__CUDACC_VER_MAJOR__ == 12 && __CUDACC_VER_MINOR__ >= 4)
#define RT_KERNEL_MAX_REGISTERS(n) __maxnreg__(n)  /* one kernel's cap, under the program's -maxrregcount */
#else
#define RT_KERNEL_MAX_REGISTERS(n)  /* nvcc before 12.4 has no __maxnreg__: the program's cap */
#endif
#define RT_GLOBAL                   /* address-space qualifiers: empty in CUDA (generic addressing) */
#define RT_CONST
#define RT_SHARED_PTR               /* a pointer to block-wide (__shared__) memory: generic address space */
#define RT_INF __int_as_float(0x7f800000)
#define rt_as_float(i) __int_as_float(i)
#define rt_as_int(f) __float_as_int(f)
#define rt_min fminf
#define rt_fma fmaf
#define rt_max fmaxf
#define rt_imin min                                           /* int32 */
#define rt_imax max
#define rt_load_once(p) __ldcs(p)                              /* streamed: a ray read once, a hit written */
#define rt_store_once(p, v) __stcs((p), (v))                   /* once (evict first, keeps L1/L2 for the scene) */
#define rt_abs fabsf
#define rt_sqrt sqrtf
#define rt_pow powf
#define rt_isfinite isfinite
#define rt_barrier() __syncthreads()                          /* a block's threads meet */
#define rt_shared_atomic_add(p, v) atomicAdd((p), (v))        /* int in block-wide memory */
#define rt_atomic_inc(p) atomicAdd((p), 1)                    /* int in global memory; the old value */
#define rt_clz(x) __clz((int)(x))                              /* leading zero bits of a 32-bit word */
#define rt_popc(x) __popc((unsigned int)(x))                   /* set bits of a 32-bit word */
#define rt_ctz(x) (__ffs(x) - 1)                               /* lowest set bit of x != 0 */
typedef unsigned long long rt_u64;
/* Byte k (0-3) of w, zero-extended: one byte permute (PRMT) where shift and mask would take two */
RT_FN unsigned int rt_byte(unsigned int w, int k) { return __byte_perm(w, 0u, 0x4440u | (unsigned int)k); }
/* Byte k (0-3) of w at bits 8-15 of hi, whose bits 0-15 are zero: one byte permute (PRMT) */
RT_FN unsigned int rt_byte_at_bits8(unsigned int w, int k, unsigned int hi)
{
    return __byte_perm(w, hi, 0x7604u | ((unsigned int)k << 4));
}
/* Thread indices of a launch of up to two dimensions (d = 0: x, 1: y), as ints: the thread in its
 * block, the block, threads a block, blocks in the launch, the thread in the launch (unsigned
 * arithmetic, as CUDA's own) */
#define rt_local_id(d) ((int)((d) == 0 ? threadIdx.x : threadIdx.y))
#define rt_group_id(d) ((int)((d) == 0 ? blockIdx.x : blockIdx.y))
#define rt_local_size(d) ((int)((d) == 0 ? blockDim.x : blockDim.y))
#define rt_num_groups(d) ((int)((d) == 0 ? gridDim.x : gridDim.y))
#define rt_global_id(d) ((int)((d) == 0 ? blockIdx.x * blockDim.x + threadIdx.x : blockIdx.y * blockDim.y + threadIdx.y))
/* this thread's index in the whole launch (x fastest, then y) */
RT_FN unsigned int rt_item_index(void)
{
    return (blockIdx.x * blockDim.x + threadIdx.x) + gridDim.x * blockDim.x * (blockIdx.y * blockDim.y + threadIdx.y);
}
/* Entry kernels' buffers, block-wide variables and constant-memory items (see the top) */
#define RT_IN(type) const type *__restrict__
#define RT_OUT(type) type *__restrict__
#define RT_SHARED __shared__
#define RT_WITH_FRAME
#define RT_WITH_FRAME_MATERIALS
#define RT_WITH_SHADING
#define rt_frame (&c_frame)
#define rt_lights c_lights
#define rt_materials c_materials
RT_FN float3 f3(float x, float y, float z) { return make_float3(x, y, z); }
RT_FN float4 f4(float x, float y, float z, float w) { return make_float4(x, y, z, w); }
RT_FN int4 i4(int x, int y, int z, int w) { return make_int4(x, y, z, w); }
RT_FN void rt_atomic_add_float(RT_GLOBAL float *p, float v) { atomicAdd(p, v); }
#else /* OpenCL C */
#define RT_FN static inline
#define RT_FN_NOINLINE static __attribute__((noinline))
#ifndef RT_REFINE_CALL             /* the watertight test's double plane distance (rt_intersect.h): */
#if defined(RT_NV_PTX) && RT_NV_PTX
#define RT_REFINE_CALL 1           /* NVIDIA's OpenCL: a call, as on CUDA (inlined, NVVM keeps the ray's */
#else                              /* doubles live through the walk, registers the walk needs) */
#define RT_REFINE_CALL 0           /* inlined: PoCL vectorises work-items through it */
#endif
#endif
#define RT_KERNEL __kernel
#define RT_KERNEL_MAX_REGISTERS(n)  /* OpenCL has no per-kernel cap: the program's (-cl-nv-maxrregcount) */
#define RT_GLOBAL __global
#if RT_CONST_MEM == RT_MEM_GLOBAL  /* frame, lights, materials passed as global buffers (§3.1.1 study) */
#define RT_CONST __global
#else
#define RT_CONST __constant
#endif
#define RT_SHARED_PTR __local
#define RT_INF INFINITY
#define rt_as_float(i) as_float(i)
#define rt_as_int(f) as_int(f)
#define rt_min fmin
#define rt_fma fma
#define rt_max fmax
#define rt_imin min
#define rt_imax max
#if defined(RT_NV_PTX) && RT_NV_PTX
/* NVIDIA's OpenCL: a ray read once and a hit written once streamed (ld/st .cs: evict first), as
 * CUDA's __ldcs/__stcs, through inline PTX; a plain read of the const rays goes through L1 like the
 * tree's nodes and evicts them (what it costs: docs/results.md, "NVIDIA OpenCL") */
RT_FN float4 rt_load_once_cs(const __global float4 *p)
{
    float x, y, z, w;
    asm("ld.global.cs.v4.f32 {%0, %1, %2, %3}, [%4];" : "=f"(x), "=f"(y), "=f"(z), "=f"(w) : "l"(p));
    return (float4)(x, y, z, w);
}
RT_FN void rt_store_once_cs(__global float4 *p, float4 v)
{
    asm volatile("st.global.cs.v4.f32 [%0], {%1, %2, %3, %4};" : : "l"(p), "f"(v.x), "f"(v.y), "f"(v.z), "f"(v.w)
                 : "memory");
}
#define rt_load_once(p) rt_load_once_cs(p)
#define rt_store_once(p, v) rt_store_once_cs((p), (v))
#else
#define rt_load_once(p) (*(p))
#define rt_store_once(p, v) (*(p) = (v))
#endif
#define rt_abs fabs
#define rt_sqrt sqrt
#define rt_pow pow
#define rt_isfinite isfinite
#define rt_barrier() barrier(CLK_LOCAL_MEM_FENCE)
#define rt_shared_atomic_add(p, v) atomic_add((p), (v))
#define rt_atomic_inc(p) atomic_inc(p)
#define rt_clz(x) ((int)clz((unsigned int)(x)))
#define rt_popc(x) ((int)popcount((unsigned int)(x)))
#define rt_ctz(x) (31 - clz((x) & -(x)))                       /* lowest set bit of x != 0 (ctz is OpenCL C 2.0) */
typedef ulong rt_u64;
RT_FN unsigned int rt_byte(unsigned int w, int k) { return (w >> (8 * k)) & 0xFFu; }
RT_FN unsigned int rt_byte_at_bits8(unsigned int w, int k, unsigned int hi)
{
    return (((w >> (8 * k)) & 0xFFu) << 8) | hi;
}
#define rt_local_id(d) ((int)get_local_id(d))
#define rt_group_id(d) ((int)get_group_id(d))
#define rt_local_size(d) ((int)get_local_size(d))
#define rt_num_groups(d) ((int)get_num_groups(d))
#define rt_global_id(d) ((int)get_global_id(d))
RT_FN unsigned int rt_item_index(void)           /* this work-item's index in the whole launch */
{
    return (unsigned int)(get_global_id(0) + get_global_size(0) * get_global_id(1));
}
#define RT_IN(type) __global const type *restrict
#define RT_OUT(type) __global type *restrict
#define RT_SHARED __local                  /* OpenCL C: only at a kernel's outermost scope */
#define RT_WITH_FRAME , RT_CONST const RtFrame *frame
#define RT_WITH_FRAME_MATERIALS , RT_CONST const RtFrame *frame, RT_CONST const RtMaterial *materials
#define RT_WITH_SHADING , RT_CONST const RtFrame *frame, RT_CONST const RtLight *lights, \
    RT_CONST const RtMaterial *materials
#define rt_frame frame
#define rt_lights lights
#define rt_materials materials
RT_FN float3 f3(float x, float y, float z) { return (float3)(x, y, z); }
RT_FN float4 f4(float x, float y, float z, float w) { return (float4)(x, y, z, w); }
RT_FN int4 i4(int x, int y, int z, int w) { return (int4)(x, y, z, w); }
/* OpenCL 1.2 has no float atomics: compare-and-swap on the bits. */
RT_FN void rt_atomic_add_float(volatile RT_GLOBAL float *p, float v)
{
    volatile RT_GLOBAL unsigned int *bits = (volatile RT_GLOBAL unsigned int *)p;
    unsigned int seen = *bits, expected;
    do {
        expected = seen;
        seen = atomic_cmpxchg(bits, expected, as_uint(as_float(expected) + v));
    } while (seen != expected);
}
#endif

/* ---- Warp occupancy (the BVH's ray fetch, rt_bvh.h): how many threads of the warp run this
 * instruction together now. CUDA: the active mask's population. NVIDIA's OpenCL: the same PTX,
 * inline (RT_NV_PTX: the host sets it on NVIDIA's platform). Elsewhere (PoCL: no warps) 1; the host
 * launches what relies on the count only where the device has warps (Backend.has_warp_votes). */
#if defined(__CUDACC__)
#define rt_warp_active() __popc(__activemask())
#elif defined(RT_NV_PTX) && RT_NV_PTX
RT_FN int rt_warp_active(void)
{
    int n;
    asm volatile("{\n\t.reg .b32 m;\n\tactivemask.b32 m;\n\tpopc.b32 %0, m;\n\t}" : "=r"(n));
    return n;
}
#else
#define rt_warp_active() 1
#endif

/* Whether every active lane of the warp holds the same value v (a speed hint only: code that takes a
 * path per value where it is 1 must give the same results where it is 0). match.any from sm_70, the
 * highest active lane's value by shuffle before; NVIDIA's OpenCL the same as inline PTX (RT_NV_PTX: the
 * host passes the compute capability, major x 10 + minor). Elsewhere 0. */
#if defined(__CUDACC__)
RT_FN int rt_warp_uniform(int v)
{
    unsigned int m = __activemask();
#if __CUDA_ARCH__ >= 700
    return __match_any_sync(m, v) == m;
#else
    return __all_sync(m, __shfl_sync(m, v, 31 - __clz(m)) == v);
#endif
}
#elif defined(RT_NV_PTX) && RT_NV_PTX >= 70
RT_FN int rt_warp_uniform(int v)
{
    int same;
    asm volatile("{\n\t.reg .b32 m, r;\n\t.reg .pred p;\n\tactivemask.b32 m;\n\tmatch.any.sync.b32 r, %1, m;\n\t"
                 "setp.eq.b32 p, r, m;\n\tselp.s32 %0, 1, 0, p;\n\t}" : "=r"(same) : "r"(v));
    return same;
}
#elif defined(RT_NV_PTX) && RT_NV_PTX
RT_FN int rt_warp_uniform(int v)
{
    int same;
    asm volatile("{\n\t.reg .b32 m, lane, first;\n\t.reg .pred p, q;\n\tactivemask.b32 m;\n\t"
                 "bfind.u32 lane, m;\n\tshfl.sync.idx.b32 first, %1, lane, 31, m;\n\t"
                 "setp.eq.s32 p, first, %1;\n\tvote.sync.all.pred q, p, m;\n\tselp.s32 %0, 1, 0, q;\n\t}"
                 : "=r"(same) : "r"(v));
    return same;
}
#else
#define rt_warp_uniform(v) 0
#endif

/* ---- Double precision (the watertight test's fallback, rt_intersect.h): always in CUDA, in OpenCL
 * where the device has cl_khr_fp64; -DRT_HAS_FP64=0 forces the float-only path. */
#ifndef RT_HAS_FP64
#if defined(__CUDACC__)
#define RT_HAS_FP64 1
#elif defined(cl_khr_fp64)
#define RT_HAS_FP64 1
#else
#define RT_HAS_FP64 0
#endif
#endif
#if RT_HAS_FP64 && !defined(__CUDACC__)
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif

/* a*b - c*d with each product rounded on its own. A fused multiply-add would round the two
 * products differently, and the edge function of a shared edge would no longer be exactly the
 * negation of its neighbour's (Woop et al. 2013 assume no contraction). */
RT_FN float diff_of_products_rn(float a, float b, float c, float d)
{
#if defined(__CUDACC__)
    return __fsub_rn(__fmul_rn(a, b), __fmul_rn(c, d));
#else
#pragma OPENCL FP_CONTRACT OFF
    return a * b - c * d;
#endif
}

/* ---- Vector helpers (OpenCL has operators on float3, CUDA does not: use these everywhere) ---- */
RT_FN float3 xyz(float4 a) { return f3(a.x, a.y, a.z); }
RT_FN float3 add3(float3 a, float3 b) { return f3(a.x + b.x, a.y + b.y, a.z + b.z); }
RT_FN float3 sub3(float3 a, float3 b) { return f3(a.x - b.x, a.y - b.y, a.z - b.z); }
RT_FN float3 mul3(float3 a, float s) { return f3(a.x * s, a.y * s, a.z * s); }
RT_FN float3 hadamard3(float3 a, float3 b) { return f3(a.x * b.x, a.y * b.y, a.z * b.z); }
RT_FN float3 madd3(float3 a, float3 b, float s) { return f3(a.x + b.x * s, a.y + b.y * s, a.z + b.z * s); }
RT_FN float dot3(float3 a, float3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
RT_FN float3 cross3(float3 a, float3 b)
{
    return f3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
RT_FN float3 normalize3(float3 a) { return mul3(a, 1.0f / rt_sqrt(dot3(a, a))); }
/* Component by run-time index with selects, not a[axis]: indexing a register vector is what pushed
 * the paper's rays into local memory (§3.1.1). */
#if RT_RAY_MEM == RT_MEM_INDEXED
/* The 2008 way, kept to show its cost: a per-thread array indexed at run time lives in local memory
 * unless the compiler turns the index into selects (rtlab bench memory prints nvcc's stack bytes). */
RT_FN float get3(float3 a, int axis)
{
    float c[3];
    c[0] = a.x;
    c[1] = a.y;
    c[2] = a.z;
    return c[axis];
}
#else
RT_FN float get3(float3 a, int axis) { return axis == 0 ? a.x : (axis == 1 ? a.y : a.z); }
#endif
/* Component k (0-3) by selects on k's two bits (nested ?: over four became branches on the GPU) */
RT_FN float get4(float4 a, int k)
{
    float lo = (k & 1) ? a.y : a.x, hi = (k & 1) ? a.w : a.z;
    return (k & 2) ? hi : lo;
}
RT_FN int finite3(float3 a) { return rt_isfinite(a.x) && rt_isfinite(a.y) && rt_isfinite(a.z); }

#endif /* RT_PORT_H */
