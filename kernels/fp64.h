/* Whether a kernel may use double. CLRADCOM_FP64 is defined where the device has
 * cl_khr_fp64 and the host has not forced the no-fp64 mode (-D CLRADCOM_NO_FP64=1:
 * clradcom/device/runtime.py, Runtime(fp64=False) or CLRADCOM_FP64=0), so a device
 * without fp64 and a forced build compile the same code. Kernels test CLRADCOM_FP64,
 * never cl_khr_fp64 itself. Included first by fastmath.h. */
#ifndef CLRADCOM_FP64_H
#define CLRADCOM_FP64_H

#if defined(cl_khr_fp64) && !(defined(CLRADCOM_NO_FP64) && CLRADCOM_NO_FP64)
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#define CLRADCOM_FP64 1
#endif

#endif /* CLRADCOM_FP64_H */
