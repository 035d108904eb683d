/* Electromagnetics of a reflection, in `real`: the device twin of
 * clradcom/physics/em.py (fresnel_coefficients, ament/boithias roughness factors,
 * reflection_dyad and material_reflection_dyad applied to a field vector) and of
 * physics/vectors.py's perpendicular. The formulas, branches and tolerances are the
 * host's, so a kernel's reflection dyad agrees with the host reference to rounding (in double; in
 * float to float rounding, where the device has no fp64); see the host functions for the
 * physics and its sources. */
#ifndef CLRADCOM_EM_H
#define CLRADCOM_EM_H

/* The includer defines `real` (double where the device has fp64, else float) with its
 * vector types real2 and real3 before including this header. */
#ifndef CLRADCOM_REAL_DEFINED
#error "include em.h after defining real, real2 and real3 (kernels/sbr.cl)"
#endif

#define EM_INLINE inline __attribute__((always_inline))

/* em.py: _NORMAL_INCIDENCE_TOL */
#define EM_NORMAL_INCIDENCE_TOL 1e-12
/* em.py: ROUGHNESS_BOITHIAS */
#define EM_ROUGHNESS_BOITHIAS 1

typedef real2 cplx;   /* (re, im) */

EM_INLINE cplx c_mul(cplx a, cplx b) { return (cplx)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x); }
EM_INLINE cplx c_div(cplx a, cplx b)
{
    /* Smith's algorithm: no overflow for large |b| */
    if (fabs(b.x) >= fabs(b.y)) {
        real r = b.y / b.x, den = b.x + b.y * r;
        return (cplx)((a.x + a.y * r) / den, (a.y - a.x * r) / den);
    }
    real r = b.x / b.y, den = b.x * r + b.y;
    return (cplx)((a.x * r + a.y) / den, (a.y * r - a.x) / den);
}
EM_INLINE cplx c_scale(cplx a, real s) { return (cplx)(a.x * s, a.y * s); }

/* principal square root (Re >= 0), as numpy's */
EM_INLINE cplx c_sqrt(cplx z)
{
    real m = hypot(z.x, z.y);
    if (m == 0.0) return (cplx)(0.0, 0.0);
    real re = sqrt(0.5 * (m + fabs(z.x)));
    real im = 0.5 * z.y / re;
    if (z.x >= 0.0) return (cplx)(re, im);
    return (cplx)(fabs(im), (z.y >= 0.0) ? re : -re);
}

/* Fresnel coefficients from air, em.py: fresnel_coefficients (PEC: -1, +1). */
EM_INLINE void fresnel(cplx eps, real cos_theta, int pec, cplx *r_te, cplx *r_tm)
{
    if (pec) { *r_te = (cplx)(-1.0, 0.0); *r_tm = (cplx)(1.0, 0.0); return; }
    real c = fmin(fmax(fabs(cos_theta), (real)0.0), (real)1.0);
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
EM_INLINE real i0e(real x)
{
    x = fabs(x);
    if (x <= 3.75) {
        real t = x / 3.75;
        t *= t;
        real i0 = 1.0 + t * (3.5156229 + t * (3.0899424 + t * (1.2067492 + t * (
                    0.2659732 + t * (0.0360768 + t * 0.0045813)))));
        return i0 * exp(-x);
    }
    real t = 3.75 / x;
    return (0.39894228 + t * (0.01328592 + t * (0.00225319 + t * (-0.00157565 + t * (
            0.00916281 + t * (-0.02057706 + t * (0.02635537 + t * (-0.01647633
            + t * 0.00392377)))))))) / sqrt(x);
}

/* em.py: roughness_factor (Ament, or Boithias for model 1) */
EM_INLINE real roughness_factor(real sigma_h, real cos_theta, real k, int model)
{
    real g = k * sigma_h * fabs(cos_theta);
    g *= g;
    return (model == EM_ROUGHNESS_BOITHIAS) ? i0e(2.0 * g) : exp(-2.0 * g);
}

/* vectors.py: perpendicular (cross with the world axis least aligned with n, the first
 * of equals) */
EM_INLINE real3 perpendicular(real3 n)
{
    real ax = fabs(n.x), ay = fabs(n.y), az = fabs(n.z);
    real3 axis = (ax <= ay && ax <= az) ? (real3)(1.0, 0.0, 0.0)
                 : ((ay <= az) ? (real3)(0.0, 1.0, 0.0) : (real3)(0.0, 0.0, 1.0));
    real3 p = cross(n, axis);
    return p / sqrt(dot(p, p));
}

/* A complex 3-vector: a field. */
typedef struct { cplx x, y, z; } cvec3;

EM_INLINE cvec3 cv_real(real3 a)
{
    cvec3 r = {(cplx)(a.x, 0.0), (cplx)(a.y, 0.0), (cplx)(a.z, 0.0)};
    return r;
}
EM_INLINE cplx cv_dot_real(cvec3 a, real3 b)
{
    return c_scale(a.x, b.x) + c_scale(a.y, b.y) + c_scale(a.z, b.z);
}
EM_INLINE cvec3 cv_axpy(cplx s, real3 a, cvec3 y)   /* s a + y */
{
    cvec3 r = {y.x + c_scale(s, a.x), y.y + c_scale(s, a.y), y.z + c_scale(s, a.z)};
    return r;
}
EM_INLINE cvec3 cv_scale_real(cvec3 a, real s)
{
    cvec3 r = {c_scale(a.x, s), c_scale(a.y, s), c_scale(a.z, s)};
    return r;
}
EM_INLINE cvec3 cv_add(cvec3 a, cvec3 b)
{
    cvec3 r = {a.x + b.x, a.y + b.y, a.z + b.z};
    return r;
}
EM_INLINE cvec3 cv_zero(void)
{
    cvec3 r = {(cplx)(0.0, 0.0), (cplx)(0.0, 0.0), (cplx)(0.0, 0.0)};
    return r;
}

/* em.py: reflection_dyad D = r_te e_perp e_perp^T + r_tm e_par_r e_par_i^T at unit k, n,
 * kept as its pieces: made once per reflection and applied to any number of fields
 * (reflect) without forming the matrix. */
typedef struct {
    real3 e_perp, e_par_i, e_par_r;
    cplx r_te, r_tm;
} Reflection;

EM_INLINE Reflection reflection_at(real3 k, real3 n, cplx r_te, cplx r_tm)
{
    real kn = dot(k, n);
    if (kn > 0.0) n = -n;
    kn = -fabs(kn);
    real3 k_r = k - (real)2.0 * kn * n;
    real3 x = cross(k, n);
    real sx = sqrt(dot(x, x));
    Reflection R;
    R.e_perp = (sx < EM_NORMAL_INCIDENCE_TOL) ? perpendicular(n) : x / sx;
    R.e_par_i = cross(R.e_perp, k);
    R.e_par_r = cross(R.e_perp, k_r);
    R.r_te = r_te;
    R.r_tm = r_tm;
    return R;
}

/* D f */
EM_INLINE cvec3 reflect(const Reflection *R, cvec3 f)
{
    cvec3 r = cv_axpy(c_mul(R->r_te, cv_dot_real(f, R->e_perp)), R->e_perp, cv_zero());
    return cv_axpy(c_mul(R->r_tm, cv_dot_real(f, R->e_par_i)), R->e_par_r, r);
}

/* em.py: material_reflection_dyad: Fresnel x roughness x specular share sqrt(1 - S^2).
 * mf = (eps re, eps im, sigma_h, sqrt(1 - S^2)), mi = (pec, roughness model). */
EM_INLINE Reflection material_reflection(real3 k, real3 n, __global const real *mf,
                                         __global const int *mi, real k0)
{
    real cos_t = fabs(dot(k, n));
    cplx r_te, r_tm;
    fresnel((cplx)(mf[0], mf[1]), cos_t, mi[0], &r_te, &r_tm);
    /* a smooth surface's factor is exactly 1 (exp(-0), i0e(0)): no libm call */
    real rough = (mf[2] == 0.0) ? (real)1.0 : roughness_factor(mf[2], cos_t, k0, mi[1]);
    real rho = rough * mf[3];
    return reflection_at(k, n, c_scale(r_te, rho), c_scale(r_tm, rho));
}

/* em.py: _antenna_basis_world - theta_hat, phi_hat of an antenna frame R (row-major, its
 * columns the local axes in world) at world direction d, in world; and the local
 * direction d R (unnormalised, as the host passes it to the pattern). The cosines and
 * sines of theta = acos(z) and phi = atan2(y, x) come from the components, without the
 * trigonometry (six calls of double libm per call were a tenth of the SBR kernel); on
 * the axis atan2(+-0, x) is 0 or pi: cos phi = +-1 by the sign of x. */
EM_INLINE void antenna_frame_basis(real3 d, __global const real *R, real3 *loc, real3 *th,
                                   real3 *ph)
{
    real3 dl = (real3)((d.x * R[0] + d.y * R[3]) + d.z * R[6],
                       (d.x * R[1] + d.y * R[4]) + d.z * R[7],
                       (d.x * R[2] + d.y * R[5]) + d.z * R[8]);
    *loc = dl;
    dl /= sqrt(dot(dl, dl));
    real ct = fmin(fmax(dl.z, (real)-1.0), (real)1.0);
    real st = sqrt(dl.x * dl.x + dl.y * dl.y);
    real cp = (st > 0.0) ? dl.x / st : (signbit(dl.x) ? (real)-1.0 : (real)1.0);
    real sp = (st > 0.0) ? dl.y / st : (real)0.0;
    real3 t = (real3)(ct * cp, ct * sp, -st), p = (real3)(-sp, cp, (real)0.0);
    *th = (real3)(dot((real3)(R[0], R[1], R[2]), t), dot((real3)(R[3], R[4], R[5]), t),
                  dot((real3)(R[6], R[7], R[8]), t));
    *ph = (real3)(dot((real3)(R[0], R[1], R[2]), p), dot((real3)(R[3], R[4], R[5]), p),
                  dot((real3)(R[6], R[7], R[8]), p));
}

#endif
