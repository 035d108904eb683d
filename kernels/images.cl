/* Reflection points of candidate face sequences by the image method: the host's
 * clradcom/mechanisms/specular.py: image_points, one work item per candidate, with the
 * host's operation order (no contraction, three-term dots in numpy's order: dot3.h). In
 * precise.h's preal: double where the device has fp64, so the points are the host's bit
 * for bit; double-float without (points within ~1e-14 relative of the host's, float64
 * values crossing as (hi, lo) pairs: pr_elem).
 *
 * Forward, tx is mirrored in each face's plane n.x = d in turn (the images); backward,
 * from rx, the line to each image crosses that face's plane at the fraction s of the
 * line, which must lie strictly inside (1e-12, 1 - 1e-12): else the candidate is not a
 * path (flag cleared) and the step goes on from the line's middle, as the host does. */
#include "dot3.h"
#pragma OPENCL FP_CONTRACT OFF

#ifndef MAX_ORDER
#error "MAX_ORDER (the most reflections a candidate has) must be passed as -D by the host"
#endif

/* points (C, k + 2, 3): tx, the k reflection points, rx. flags (C): bit 0 the candidate
 * is a path; bit 1 its last reflection failed (the step from rx); bit 2 its first one
 * failed while every later one held (the step toward tx): the host warns where an
 * antenna lies on such a face. */
__kernel void image_points(const pr_elem tx0, const pr_elem tx1, const pr_elem tx2,
                           const pr_elem rx0, const pr_elem rx1, const pr_elem rx2,
                           __global const pr_elem *normal,   /* (F, 3) unit */
                           __global const pr_elem *offset,   /* (F,) */
                           __global const int *seqs,         /* (C, k) face ids */
                           const int k, const int n,
                           __global pr_elem *points,         /* (C, k + 2, 3) */
                           __global uchar *flags)            /* (C,) */
{
    int c = get_global_id(0);
    if (c >= n) return;
    __global const int *seq = seqs + (size_t)c * k;
    __global pr_elem *out = points + (size_t)c * (k + 2) * 3;
    preal img[3 * MAX_ORDER];
    preal p0 = pr_of(tx0), p1 = pr_of(tx1), p2 = pr_of(tx2);
    for (int i = 0; i < k; ++i) {
        __global const pr_elem *nf = normal + 3 * seq[i];
        preal n0 = pr_of(nf[0]), n1 = pr_of(nf[1]), n2 = pr_of(nf[2]);
        preal twice = pr_mul(PR_CONST(2.0), pr_sub(dot3(p0, p1, p2, n0, n1, n2),
                                                   pr_of(offset[seq[i]])));
        p0 = pr_sub(p0, pr_mul(twice, n0));
        p1 = pr_sub(p1, pr_mul(twice, n1));
        p2 = pr_sub(p2, pr_mul(twice, n2));
        img[3 * i] = p0; img[3 * i + 1] = p1; img[3 * i + 2] = p2;
    }
    out[0] = tx0; out[1] = tx1; out[2] = tx2;
    out[3 * (k + 1)] = rx0; out[3 * (k + 1) + 1] = rx1; out[3 * (k + 1) + 2] = rx2;
    preal t0 = pr_of(rx0), t1 = pr_of(rx1), t2 = pr_of(rx2);
    const preal s_lo = PR_CONST(1e-12), s_hi = pr_sub(PR_CONST(1.0), PR_CONST(1e-12));
    bool ok = true;
    uchar warn = 0;
    for (int i = k - 1; i >= 0; --i) {
        __global const pr_elem *nf = normal + 3 * seq[i];
        preal n0 = pr_of(nf[0]), n1 = pr_of(nf[1]), n2 = pr_of(nf[2]);
        preal l0 = pr_sub(img[3 * i], t0), l1 = pr_sub(img[3 * i + 1], t1);
        preal l2 = pr_sub(img[3 * i + 2], t2);
        preal denom = dot3(l0, l1, l2, n0, n1, n2);
        preal s = pr_div(pr_sub(pr_of(offset[seq[i]]), dot3(t0, t1, t2, n0, n1, n2)), denom);
        bool good = pr_isfinite(s) && pr_gt(s, s_lo) && pr_lt(s, s_hi);
        if (!good && ok) {
            if (i == k - 1) warn |= 2;
            if (i == 0) warn |= 4;
        }
        ok = ok && good;
        if (!good) s = PR_CONST(0.5);
        t0 = pr_add(t0, pr_mul(s, l0));
        t1 = pr_add(t1, pr_mul(s, l1));
        t2 = pr_add(t2, pr_mul(s, l2));
        out[3 * (i + 1)] = pr_elem_of(t0);
        out[3 * (i + 1) + 1] = pr_elem_of(t1);
        out[3 * (i + 1) + 2] = pr_elem_of(t2);
    }
    flags[c] = (uchar)(ok ? 1 : 0) | warn;
}
