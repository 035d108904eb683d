/* Whether a kernel may use double. CLRADCOM_FP64 is defined where the device has
 * cl_khr_fp64 and the host has not forced the no-fp64 mode (-D CLRADCOM_NO_FP64=1:
 * clradcom/device/runtime.py, Runtime(fp64=False) or CLRADCOM_FP64=0), so a device
 * without fp64 and a forced build compile the same code. Kernels test CLRADCOM_FP64
 * (or precise.h's PRECISE_MODE), never cl_khr_fp64 itself. Included first by
 * fastmath.h and by precise.h.
 *
 * Without it the keyword double and its vector types are macros for a name that does
 * not exist, so a kernel that still names one fails to build on PoCL or Intel in the
 * forced mode exactly as it would on a device without fp64 (where OpenCL C has no
 * double); the runtime also builds with -cl-single-precision-constant there, so a
 * literal such as 0.5 stays a float as such a device makes it. */
#ifndef CLRADCOM_FP64_H
#define CLRADCOM_FP64_H

#if defined(cl_khr_fp64) && !(defined(CLRADCOM_NO_FP64) && CLRADCOM_NO_FP64)
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#define CLRADCOM_FP64 1
#else
#define double clradcom_no_fp64_build_uses_double
#define double2 clradcom_no_fp64_build_uses_double
#define double3 clradcom_no_fp64_build_uses_double
#define double4 clradcom_no_fp64_build_uses_double
#define double8 clradcom_no_fp64_build_uses_double
#define double16 clradcom_no_fp64_build_uses_double
#endif

#endif /* CLRADCOM_FP64_H */
