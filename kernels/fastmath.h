/* Inline builtins for PoCL. PoCL (3.0, the suite's CPU device) turns dot, cross, fabs,
 * sqrt, fmax and fmin into out-of-line calls into its kernel library, each passing
 * vectors through memory: a call for every dot product, absolute value or square root in
 * the kernels' hot loops. Where the host passes -D CLR_INLINE_BUILTINS=1 (the runtime
 * does on PoCL: clradcom/device/runtime.py, Runtime.build) they become inline functions
 * here, evaluated as written without contraction, as PoCL's own are, so every kernel's
 * results stay bit for bit the same (golden snapshot, engine tests); measured on the
 * street: 6-12 % less SBR kernel time, ~8 % less in trace_reflections
 * (docs/performance.md). Included first by intersect.h, so it comes before any use. */
#ifndef CLRADCOM_FASTMATH_H
#define CLRADCOM_FASTMATH_H

#ifdef CLR_INLINE_BUILTINS
#define CLR_INL static inline __attribute__((overloadable, always_inline))
#pragma OPENCL FP_CONTRACT OFF
CLR_INL float clr_dot(float3 a, float3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
CLR_INL float3 clr_cross(float3 a, float3 b)
{
    return (float3)(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
CLR_INL float clr_fabs(float a) { return __builtin_fabsf(a); }
CLR_INL float3 clr_fabs(float3 a)
{
    return (float3)(__builtin_fabsf(a.x), __builtin_fabsf(a.y), __builtin_fabsf(a.z));
}
CLR_INL float clr_sqrt(float a) { return __builtin_sqrtf(a); }
CLR_INL float clr_fmax(float a, float b) { return __builtin_fmaxf(a, b); }
CLR_INL float clr_fmin(float a, float b) { return __builtin_fminf(a, b); }
#ifdef cl_khr_fp64
CLR_INL double clr_dot(double3 a, double3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
CLR_INL double3 clr_cross(double3 a, double3 b)
{
    return (double3)(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
CLR_INL double clr_fabs(double a) { return __builtin_fabs(a); }
CLR_INL double3 clr_fabs(double3 a)
{
    return (double3)(__builtin_fabs(a.x), __builtin_fabs(a.y), __builtin_fabs(a.z));
}
CLR_INL double clr_sqrt(double a) { return __builtin_sqrt(a); }
CLR_INL double clr_fmax(double a, double b) { return __builtin_fmax(a, b); }
CLR_INL double clr_fmin(double a, double b) { return __builtin_fmin(a, b); }
#endif
#pragma OPENCL FP_CONTRACT ON
#undef dot
#undef cross
#undef fabs
#undef sqrt
#undef fmax
#undef fmin
#define dot clr_dot
#define cross clr_cross
#define fabs clr_fabs
#define sqrt clr_sqrt
#define fmax clr_fmax
#define fmin clr_fmin
#endif

#endif /* CLRADCOM_FASTMATH_H */
