/* Inline builtins for PoCL. PoCL (3.0, the suite's CPU device) turns dot, cross, fabs,
 * sqrt, fmax and fmin into out-of-line calls into its kernel library, each passing
 * vectors through memory: a call for every dot product, absolute value or square root in
 * the kernels' hot loops. Where the host passes -D CLR_INLINE_BUILTINS=1 (the runtime
 * does on PoCL: clradcom/device/runtime.py, Runtime.build) they become inline functions
 * here, evaluated as written without contraction, as PoCL's own are, so every kernel's
 * results stay bit for bit the same (golden snapshot, engine tests); measured on the
 * street: 6-12 % less SBR kernel time, ~8 % less in trace_reflections
 * (docs/performance.md). fma too (llvm.fma, fused as OpenCL's): 7 % less time in a chain
 * of precise.h's double-float products and sums. Included first by intersect.h and
 * precise.h, so it comes before any use. */
#ifndef CLRADCOM_FASTMATH_H
#define CLRADCOM_FASTMATH_H

#include "fp64.h"

#ifdef CLR_INLINE_BUILTINS
#define CLR_INL static inline __attribute__((overloadable, always_inline))
#pragma OPENCL FP_CONTRACT OFF
/* The set for one floating type T (vector T3), its scalar builtins' suffix SFX (f for
 * float, none for double). */
#define CLR_BUILTINS(T, T3, SFX)                                                        \
    CLR_INL T clr_dot(T3 a, T3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }         \
    CLR_INL T3 clr_cross(T3 a, T3 b)                                                    \
    {                                                                                   \
        return (T3)(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x); \
    }                                                                                   \
    CLR_INL T clr_fabs(T a) { return __builtin_fabs##SFX(a); }                          \
    CLR_INL T3 clr_fabs(T3 a)                                                           \
    {                                                                                   \
        return (T3)(__builtin_fabs##SFX(a.x), __builtin_fabs##SFX(a.y),                 \
                    __builtin_fabs##SFX(a.z));                                          \
    }                                                                                   \
    CLR_INL T clr_sqrt(T a) { return __builtin_sqrt##SFX(a); }                          \
    CLR_INL T clr_fmax(T a, T b) { return __builtin_fmax##SFX(a, b); }                  \
    CLR_INL T clr_fmin(T a, T b) { return __builtin_fmin##SFX(a, b); }                  \
    CLR_INL T clr_fma(T a, T b, T c) { return __builtin_fma##SFX(a, b, c); }
CLR_BUILTINS(float, float3, f)
#ifdef CLRADCOM_FP64
CLR_BUILTINS(double, double3, )
#endif
#undef CLR_BUILTINS
/* fused, one rounding (llvm.fma), as OpenCL's fma: the double-float of precise.h and
 * the watertight test's Kahan determinant need it exact */
CLR_INL float4 clr_fma(float4 a, float4 b, float4 c)
{
    return (float4)(__builtin_fmaf(a.x, b.x, c.x), __builtin_fmaf(a.y, b.y, c.y),
                    __builtin_fmaf(a.z, b.z, c.z), __builtin_fmaf(a.w, b.w, c.w));
}
#pragma OPENCL FP_CONTRACT ON
#undef dot
#undef cross
#undef fabs
#undef sqrt
#undef fmax
#undef fmin
#undef fma
#define dot clr_dot
#define cross clr_cross
#define fabs clr_fabs
#define sqrt clr_sqrt
#define fmax clr_fmax
#define fmin clr_fmin
#define fma clr_fma
#endif

#endif /* CLRADCOM_FASTMATH_H */
