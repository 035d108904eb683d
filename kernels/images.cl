/* Reflection points of candidate face sequences by the image method: the host's
 * clradcom/mechanisms/specular.py: image_points, one work item per candidate, in double
 * with the host's operation order (no contraction, three-term dots in numpy's order:
 * dot3.h), so the points are the host's bit for bit.
 *
 * Forward, tx is mirrored in each face's plane n.x = d in turn (the images); backward,
 * from rx, the line to each image crosses that face's plane at the fraction s of the
 * line, which must lie strictly inside (1e-12, 1 - 1e-12): else the candidate is not a
 * path (flag cleared) and the step goes on from the line's middle, as the host does. */
#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#pragma OPENCL FP_CONTRACT OFF
#define CLR_INLINE inline __attribute__((always_inline))
#include "dot3.h"

#ifndef MAX_ORDER
#error "MAX_ORDER (the most reflections a candidate has) must be passed as -D by the host"
#endif

/* points (C, k + 2, 3): tx, the k reflection points, rx. flags (C): bit 0 the candidate
 * is a path; bit 1 its last reflection failed (the step from rx); bit 2 its first one
 * failed while every later one held (the step toward tx): the host warns where an
 * antenna lies on such a face. */
__kernel void image_points(const double tx0, const double tx1, const double tx2,
                           const double rx0, const double rx1, const double rx2,
                           __global const double *normal,    /* (F, 3) unit */
                           __global const double *offset,    /* (F,) */
                           __global const int *seqs,         /* (C, k) face ids */
                           const int k, const int n,
                           __global double *points,          /* (C, k + 2, 3) */
                           __global uchar *flags)            /* (C,) */
{
    int c = get_global_id(0);
    if (c >= n) return;
    __global const int *seq = seqs + (size_t)c * k;
    __global double *out = points + (size_t)c * (k + 2) * 3;
    double img[3 * MAX_ORDER];
    double p0 = tx0, p1 = tx1, p2 = tx2;
    for (int i = 0; i < k; ++i) {
        __global const double *nf = normal + 3 * seq[i];
        double twice = 2.0 * (dot3(p0, p1, p2, nf[0], nf[1], nf[2]) - offset[seq[i]]);
        p0 = p0 - twice * nf[0];
        p1 = p1 - twice * nf[1];
        p2 = p2 - twice * nf[2];
        img[3 * i] = p0; img[3 * i + 1] = p1; img[3 * i + 2] = p2;
    }
    out[0] = tx0; out[1] = tx1; out[2] = tx2;
    out[3 * (k + 1)] = rx0; out[3 * (k + 1) + 1] = rx1; out[3 * (k + 1) + 2] = rx2;
    double t0 = rx0, t1 = rx1, t2 = rx2;
    bool ok = true;
    uchar warn = 0;
    for (int i = k - 1; i >= 0; --i) {
        __global const double *nf = normal + 3 * seq[i];
        double l0 = img[3 * i] - t0, l1 = img[3 * i + 1] - t1, l2 = img[3 * i + 2] - t2;
        double denom = dot3(l0, l1, l2, nf[0], nf[1], nf[2]);
        double s = (offset[seq[i]] - dot3(t0, t1, t2, nf[0], nf[1], nf[2])) / denom;
        bool good = isfinite(s) && s > 1e-12 && s < 1.0 - 1e-12;
        if (!good && ok) {
            if (i == k - 1) warn |= 2;
            if (i == 0) warn |= 4;
        }
        ok = ok && good;
        if (!good) s = 0.5;
        t0 = t0 + s * l0;
        t1 = t1 + s * l1;
        t2 = t2 + s * l2;
        out[3 * (i + 1)] = t0; out[3 * (i + 1) + 1] = t1; out[3 * (i + 1) + 2] = t2;
    }
    flags[c] = (uchar)(ok ? 1 : 0) | warn;
}
#endif
