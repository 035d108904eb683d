/* Electromagnetics of a reflection in double precision: the device twin of
 * clradcom/physics/em.py (fresnel_coefficients, ament/boithias roughness factors,
 * reflection_dyad, material_reflection_dyad) and of physics/vectors.py's
 * perpendicular. The formulas, branches and tolerances are the host's, so a
 * kernel's reflection dyad agrees with the host reference to rounding; see the
 * host functions for the physics and its sources. Needs cl_khr_fp64. */
#ifndef CLRADCOM_EM_H
#define CLRADCOM_EM_H

#pragma OPENCL EXTENSION cl_khr_fp64 : enable

#define EM_INLINE inline __attribute__((always_inline))

/* em.py: _NORMAL_INCIDENCE_TOL */
#define EM_NORMAL_INCIDENCE_TOL 1e-12
/* em.py: ROUGHNESS_BOITHIAS */
#define EM_ROUGHNESS_BOITHIAS 1

typedef double2 cplx;   /* (re, im) */

EM_INLINE cplx c_mul(cplx a, cplx b) { return (cplx)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x); }
EM_INLINE cplx c_div(cplx a, cplx b)
{
    /* Smith's algorithm: no overflow for large |b| */
    if (fabs(b.x) >= fabs(b.y)) {
        double r = b.y / b.x, den = b.x + b.y * r;
        return (cplx)((a.x + a.y * r) / den, (a.y - a.x * r) / den);
    }
    double r = b.x / b.y, den = b.x * r + b.y;
    return (cplx)((a.x * r + a.y) / den, (a.y * r - a.x) / den);
}
EM_INLINE cplx c_scale(cplx a, double s) { return (cplx)(a.x * s, a.y * s); }

/* principal square root (Re >= 0), as numpy's */
EM_INLINE cplx c_sqrt(cplx z)
{
    double m = hypot(z.x, z.y);
    if (m == 0.0) return (cplx)(0.0, 0.0);
    double re = sqrt(0.5 * (m + fabs(z.x)));
    double im = 0.5 * z.y / re;
    if (z.x >= 0.0) return (cplx)(re, im);
    return (cplx)(fabs(im), (z.y >= 0.0) ? re : -re);
}

/* Fresnel coefficients from air, em.py: fresnel_coefficients (PEC: -1, +1). */
EM_INLINE void fresnel(cplx eps, double cos_theta, int pec, cplx *r_te, cplx *r_tm)
{
    if (pec) { *r_te = (cplx)(-1.0, 0.0); *r_tm = (cplx)(1.0, 0.0); return; }
    double c = fmin(fmax(fabs(cos_theta), 0.0), 1.0);
    cplx a = c_sqrt((cplx)((eps.x - 1.0) + c * c, eps.y));
    a.y = -fabs(a.y);
    cplx cc = (cplx)(c, 0.0);
    cplx den_te = cc + a;
    cplx epsc = c_scale(eps, c);
    cplx den_tm = epsc + a;
    *r_te = (den_te.x == 0.0 && den_te.y == 0.0) ? (cplx)(0.0, 0.0) : c_div(cc - a, den_te);
    *r_tm = (den_tm.x == 0.0 && den_tm.y == 0.0) ? (cplx)(0.0, 0.0) : c_div(epsc - a, den_tm);
}

/* exp(-x) I0(x) for x >= 0: Abramowitz & Stegun 9.8.1 (x <= 3.75, |error| < 1.6e-7
 * relative to I0) and 9.8.2 (x > 3.75, < 1.9e-7 relative), as scipy's i0e to that
 * accuracy. */
EM_INLINE double i0e(double x)
{
    x = fabs(x);
    if (x <= 3.75) {
        double t = x / 3.75;
        t *= t;
        double i0 = 1.0 + t * (3.5156229 + t * (3.0899424 + t * (1.2067492 + t * (
                    0.2659732 + t * (0.0360768 + t * 0.0045813)))));
        return i0 * exp(-x);
    }
    double t = 3.75 / x;
    return (0.39894228 + t * (0.01328592 + t * (0.00225319 + t * (-0.00157565 + t * (
            0.00916281 + t * (-0.02057706 + t * (0.02635537 + t * (-0.01647633
            + t * 0.00392377)))))))) / sqrt(x);
}

/* em.py: roughness_factor (Ament, or Boithias for model 1) */
EM_INLINE double roughness_factor(double sigma_h, double cos_theta, double k, int model)
{
    double g = k * sigma_h * fabs(cos_theta);
    g *= g;
    return (model == EM_ROUGHNESS_BOITHIAS) ? i0e(2.0 * g) : exp(-2.0 * g);
}

/* vectors.py: perpendicular (cross with the world axis least aligned with n, the first
 * of equals) */
EM_INLINE double3 perpendicular(double3 n)
{
    double ax = fabs(n.x), ay = fabs(n.y), az = fabs(n.z);
    double3 axis = (ax <= ay && ax <= az) ? (double3)(1.0, 0.0, 0.0)
                 : ((ay <= az) ? (double3)(0.0, 1.0, 0.0) : (double3)(0.0, 0.0, 1.0));
    double3 p = cross(n, axis);
    return p / sqrt(dot(p, p));
}

/* A complex 3x3 matrix, row-major. */
typedef struct { cplx m[9]; } cmat3;

EM_INLINE cmat3 cmat3_mul(const cmat3 *a, const cmat3 *b)
{
    cmat3 r;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            cplx s = (cplx)(0.0, 0.0);
            for (int k = 0; k < 3; ++k) s += c_mul(a->m[3 * i + k], b->m[3 * k + j]);
            r.m[3 * i + j] = s;
        }
    return r;
}

EM_INLINE double comp3(double3 a, int i) { return (i == 0) ? a.x : ((i == 1) ? a.y : a.z); }

/* em.py: reflection_dyad for unit k, n: r_te e_perp e_perp^T + r_tm e_par_r e_par_i^T */
EM_INLINE cmat3 reflection_dyad(double3 k, double3 n, cplx r_te, cplx r_tm)
{
    double kn = dot(k, n);
    if (kn > 0.0) n = -n;
    kn = -fabs(kn);
    double3 k_r = k - 2.0 * kn * n;
    double3 x = cross(k, n);
    double sx = sqrt(dot(x, x));
    double3 e_perp = (sx < EM_NORMAL_INCIDENCE_TOL) ? perpendicular(n) : x / sx;
    double3 e_par_i = cross(e_perp, k);
    double3 e_par_r = cross(e_perp, k_r);
    cmat3 D;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            D.m[3 * i + j] = c_scale(r_te, comp3(e_perp, i) * comp3(e_perp, j))
                           + c_scale(r_tm, comp3(e_par_r, i) * comp3(e_par_i, j));
    return D;
}

/* em.py: material_reflection_dyad of one material for a unit k and unit n:
 * Fresnel x roughness x specular share sqrt(1 - S^2) (given as spec_share). */
EM_INLINE cmat3 material_dyad(double3 k, double3 n, cplx eps, int pec, double sigma_h,
                              int rough_model, double spec_share, double k0)
{
    double cos_t = fabs(dot(k, n));
    cplx r_te, r_tm;
    fresnel(eps, cos_t, pec, &r_te, &r_tm);
    double rho = roughness_factor(sigma_h, cos_t, k0, rough_model) * spec_share;
    return reflection_dyad(k, n, c_scale(r_te, rho), c_scale(r_tm, rho));
}

#endif
