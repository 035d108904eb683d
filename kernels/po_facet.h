/* Physical-optics field of a PEC facet at a point (clradcom/maps.py's PO facets;
 * kernels/maps.cl po_facet_fields, kernels/maps_po.cl po_pairs): physics/po.py's
 * po_transfer applied to the transmitter's field, without the carrier phase, which the
 * host adds in float64:
 *
 *     F = -(j k / 2 pi) / (R_t R_r) (I - s s^T) [k_i (n . e) - e (n . k_i)] I_c(k (s - k_i))
 *
 * so that the field at the point is (lambda / 4 pi) e^{-jkL} F (= T e e^{-jkL}/L), with
 * I_c the closed-form triangle integral about the centroid (Gordon's edge sum, or its
 * Taylor series where the phase spread over the facet is under 2 rad). Positions are
 * relative to the grid's corner. In a facet's far sidelobes the edge sum is a small
 * difference of terms as large as the phase spread times the result (500 rad for a
 * 0.5 m facet): float32 loses 1e-3 of such a lobe, so devices with fp64 build it in
 * double (-D PO_DOUBLE), float32 elsewhere. */
#ifndef CLRADCOM_PO_FACET_H
#define CLRADCOM_PO_FACET_H

#ifdef PO_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double po_real;
typedef double2 po_real2;
typedef double3 po_real3;
typedef double4 po_real4;
#define PO_PI M_PI
#else
typedef float po_real;
typedef float2 po_real2;
typedef float3 po_real3;
typedef float4 po_real4;
#define PO_PI M_PI_F
#endif

#define PO_SERIES_SPREAD 2.0
#define PO_SERIES_TERMS 24

inline po_real2 c_mul(const po_real2 a, const po_real2 b)
{
    return (po_real2)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

inline po_real po_sinc(const po_real x)
{
    return fabs(x) < 1e-4 ? 1.0 - x * x / 6.0 : sin(x) / x;
}

/* int_triangle e^{j q . r} dA for vertices relative to their centroid (po.py:
 * triangle_po_integral); h_n of the series by h2_n = d1 h2_{n-1} + d0^n,
 * h3_n = d2 h3_{n-1} + h2_n. */
inline po_real2 triangle_integral(const po_real3 v0, const po_real3 v1, const po_real3 v2,
                                  const po_real3 q)
{
    po_real3 area_vector = cross(v1 - v0, v2 - v0);
    po_real two_area = length(area_vector);
    po_real3 n = area_vector / two_area;
    po_real d0 = dot(q, v0), d1 = dot(q, v1), d2 = dot(q, v2);
    if (fmax(fabs(d0), fmax(fabs(d1), fabs(d2))) < PO_SERIES_SPREAD) {
        po_real h2 = 0.0, h3 = 0.0, d0n = 1.0, factorial = 2.0;
        po_real2 jn = (po_real2)(1.0, 0.0), sum = (po_real2)(0.0, 0.0);
        for (int k = 0; k <= PO_SERIES_TERMS; ++k) {
            h2 = d1 * h2 + d0n;
            h3 = d2 * h3 + h2;
            sum += jn * (h3 / factorial);
            d0n *= d0;
            jn = (po_real2)(-jn.y, jn.x);
            factorial *= (po_real)(k + 3);
        }
        return two_area * sum;
    }
    po_real qn = dot(q, n);
    po_real qt2 = dot(q, q) - qn * qn;
    po_real3 v[3] = {v0, v1, v2};
    po_real2 acc = (po_real2)(0.0, 0.0);
    for (int e = 0; e < 3; ++e) {
        po_real3 a = v[e], b = v[(e + 1) % 3];
        po_real3 ell = b - a, mid = (po_real)0.5 * (a + b);
        po_real w = dot(q, cross(ell, n)) * po_sinc(0.5 * dot(q, ell));
        po_real p = dot(q, mid);
        acc += w * (po_real2)(cos(p), sin(p));
    }
    return (po_real2)(acc.y, -acc.x) / qt2;
}

/* F (re, im) of the facet with vertices v0..v2 about its centroid c, lit-side unit
 * normal nrm and the transmitter's field e (re, im) at it, from the transmitter at
 * source to point (all relative to the grid's corner), wavenumber k. */
inline void po_facet_field(const po_real3 v0, const po_real3 v1, const po_real3 v2,
                           const po_real3 c, const po_real3 nrm, const po_real3 e_re,
                           const po_real3 e_im, const po_real3 source, const po_real3 point,
                           const po_real k, po_real3 *o_re, po_real3 *o_im)
{
    po_real3 dt = c - source, dr = point - c;
    po_real r_t = length(dt), r_r = length(dr);
    po_real3 ki = dt / r_t, s = dr / r_r;
    po_real2 integral = triangle_integral(v0, v1, v2, k * (s - ki));
    po_real n_ki = dot(nrm, ki);
    /* the current's direction k_i (n . e) - e (n . k_i), then its part across s */
    po_real3 j_re = ki * dot(nrm, e_re) - e_re * n_ki;
    po_real3 j_im = ki * dot(nrm, e_im) - e_im * n_ki;
    j_re -= s * dot(s, j_re);
    j_im -= s * dot(s, j_im);
    /* -(j k / 2 pi) I_c / (R_t R_r) */
    po_real2 scale = c_mul((po_real2)(0.0, -k / (2.0 * PO_PI * r_t * r_r)), integral);
    *o_re = scale.x * j_re - scale.y * j_im;
    *o_im = scale.x * j_im + scale.y * j_re;
}

#endif /* CLRADCOM_PO_FACET_H */
