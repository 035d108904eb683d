/* Probes of kernels/precise.h for clradcom/device/precision.py and its tests:
 * the build's mode, the scalar operations, unfolded lengths of given polylines
 * and of rays bounced off given planes, all in `preal`. Every float64 value
 * crosses as a (hi, lo) float2 pair. */
#include "precise.h"

/* The mode this build runs in (2 double, 1 double-float, 0 plain float). */
__kernel void precise_mode(__global int *out)
{
    if (get_global_id(0) == 0) out[0] = PRECISE_MODE;
}

/* out[i*7 + 0..6] = a+b, a-b, a*b, a/b, sqrt|a|, a + hi(b), a * hi(b). */
__kernel void precise_ops(__global const float2 *a, __global const float2 *b,
                          __global float2 *out, const int n)
{
    int i = get_global_id(0);
    if (i >= n) return;
    preal x = pr_from_pair(a[i]);
    preal y = pr_from_pair(b[i]);
    float yf = pr_to_float(y);
    __global float2 *o = out + (size_t)i * 7;
    o[0] = pr_to_pair(pr_add(x, y));
    o[1] = pr_to_pair(pr_sub(x, y));
    o[2] = pr_to_pair(pr_mul(x, y));
    o[3] = pr_to_pair(pr_div(x, y));
    o[4] = pr_to_pair(pr_sqrt(pr_to_float(x) < 0.0f ? pr_neg(x) : x));
    o[5] = pr_to_pair(pr_add_f(x, yf));
    o[6] = pr_to_pair(pr_mul_f(x, yf));
}

/* Unfolded length sum_i |x_{i+1} - x_i| of n_paths polylines of n_vertices
 * points each (points[(p * n_vertices + i) * 3 + axis]). */
__kernel void polyline_lengths(__global const float2 *points, const int n_vertices,
                               __global float2 *lengths, const int n_paths)
{
    int p = get_global_id(0);
    if (p >= n_paths) return;
    __global const float2 *pts = points + (size_t)p * n_vertices * 3;
    preal3 prev = pr3_load_pairs(pts);
    preal total = pr_from_float(0.0f);
    for (int i = 1; i < n_vertices; ++i) {
        preal3 cur = pr3_load_pairs(pts + 3 * i);
        total = pr_add(total, pr3_length(pr3_sub(cur, prev)));
        prev = cur;
    }
    lengths[p] = pr_to_pair(total);
}

/* A ray from origins[p] along directions[p] (any length) mirrored off the
 * planes plane_seq[p * max_bounces + k] (index into plane_points/plane_normals,
 * -1 ends the sequence) in order, as a ray tube of kernels/sbr.cl is: the hit
 * is the exact plane hit pr3_plane_hit, the new direction pr3_reflect, and the
 * length grows by t |d| per leg. Writes every hit point (zeros after the
 * last) and the length from the origin to the last hit. */
__kernel void bounce_lengths(__global const float2 *origins,
                             __global const float2 *directions,
                             __global const float2 *plane_points,
                             __global const float2 *plane_normals,
                             __global const int *plane_seq,
                             const int max_bounces,
                             __global float2 *hits,
                             __global float2 *lengths,
                             const int n_paths)
{
    int p = get_global_id(0);
    if (p >= n_paths) return;
    preal3 o = pr3_load_pairs(origins + (size_t)p * 3);
    preal3 d = pr3_load_pairs(directions + (size_t)p * 3);
    preal total = pr_from_float(0.0f);
    __global float2 *out = hits + (size_t)p * max_bounces * 3;
    int k = 0;
    for (; k < max_bounces; ++k) {
        int f = plane_seq[(size_t)p * max_bounces + k];
        if (f < 0) break;
        preal3 v0 = pr3_load_pairs(plane_points + (size_t)f * 3);
        preal3 n = pr3_load_pairs(plane_normals + (size_t)f * 3);
        preal t;
        preal3 hit = pr3_plane_hit(o, d, v0, n, &t);
        total = pr_add(total, pr_mul(t, pr3_length(d)));
        pr3_store_pairs(out + 3 * k, hit);
        d = pr3_reflect(d, n);
        o = hit;
    }
    for (; k < max_bounces; ++k) pr3_store_pairs(out + 3 * k, pr3_from_float3((float3)(0.0f)));
    lengths[p] = pr_to_pair(total);
}

/* The decisions and conversions kernels take on preal, element by element:
 * out[i*6 + 0..5] = (a < b, a <= b, fmax(a, b), fmin(a, b), floor(a),
 * pr_phase_reduced(a)); the two comparisons as 1 or 0 in hi. */
__kernel void precise_decisions(__global const float2 *a, __global const float2 *b,
                                __global float2 *out, const int n)
{
    int i = get_global_id(0);
    if (i >= n) return;
    preal x = pr_from_pair(a[i]);
    preal y = pr_from_pair(b[i]);
    __global float2 *o = out + (size_t)i * 6;
    o[0] = (float2)(pr_lt(x, y) ? 1.0f : 0.0f, 0.0f);
    o[1] = (float2)(pr_le(x, y) ? 1.0f : 0.0f, 0.0f);
    o[2] = pr_to_pair(pr_fmax(x, y));
    o[3] = pr_to_pair(pr_fmin(x, y));
    o[4] = pr_to_pair(pr_floor(x));
    o[5] = (float2)(pr_phase_reduced(x), 0.0f);
}
