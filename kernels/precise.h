/* Precise positions and lengths for kernels whose results become phases.
 *
 * A path length L becomes the phase k*L: at 77 GHz (lambda = 3.9 mm) one
 * degree is 11 um of path, while a float32 coordinate near 1 km is only
 * resolved to 61 um. Geometry in the BVH stays float32 (it only finds which
 * triangle a ray hits); the hit point, the direction after a bounce and the
 * accumulated length are carried in `preal`, one of:
 *
 *   PRECISE_MODE 2  double, where the device has cl_khr_fp64 (the default);
 *   PRECISE_MODE 1  double-float: an unevaluated sum hi + lo of two floats
 *                   (float2 .x = hi, .y = lo, |lo| <= ulp(hi)/2), built from
 *                   error-free transformations (Knuth's TwoSum, Dekker's
 *                   Fast2Sum, TwoProd by an explicit fma); used where the
 *                   device has no fp64, or where the build defines
 *                   CLRADCOM_NO_FP64=1 (so tests exercise it on any device);
 *   PRECISE_MODE 0  plain float, only where the build defines
 *                   CLRADCOM_PRECISE_FLOAT32=1: the negative control of the
 *                   tests, never for results.
 *
 * Double-float algorithms and their relative error bounds, with u = 2^-24 the
 * float32 unit roundoff (u^2 = 3.6e-15), from M. Joldes, J.-M. Muller,
 * V. Popescu, "Tight and rigorous error bounds for basic building blocks of
 * double-word arithmetic", ACM TOMS 44(2), 2017 (algorithm numbers theirs):
 *
 *   pr_add, pr_sub   AccurateDWPlusDW (Alg. 6)   3u^2 + 13u^3
 *   pr_add_f         DWPlusFP (Alg. 4)           2u^2
 *   pr_mul           DWTimesDW3 (Alg. 12)        4u^2
 *   pr_mul_f         DWTimesFP3 (Alg. 9)         2u^2
 *   pr_div           DWDivDW2 (Alg. 17)          15u^2 + 56u^3
 *   pr_sqrt          SQRTDWtoDW of V. Lefevre, N. Louvet, J.-M. Muller,
 *                    J. Picot, L. Rideau, "Accurate calculation of Euclidean
 *                    norms using double-word arithmetic", ACM TOMS 49(1),
 *                    2023: 25/8 u^2
 *   pr_neg, pr_from_float, pr_from_pair, pr_to_pair   exact
 *   pr_to_float      correctly rounded (hi of a normalised pair)
 *
 * Those bounds assume correctly rounded float +, -, *, / and sqrt and a true
 * fma. OpenCL gives +, -, * and fma exactly so; float / and sqrt only with
 * -cl-fp32-correctly-rounded-divide-sqrt (PoCL's CPU device always). Without
 * it (2.5 and 3 ulp) the first quotient or root is a few ulp off and the
 * correction step absorbs it: the bounds of pr_div and pr_sqrt grow by a small
 * factor, still ~1e-14. A build with -cl-fast-relaxed-math (or
 * -cl-unsafe-math-optimizations) may reassociate the error-free
 * transformations away: the double-float mode refuses to compile under
 * __FAST_RELAXED_MATH__; the host never passes the unsafe flag either.
 *
 * The 3-vector operations compose those: pr3_dot is three pr_mul and two
 * pr_add (about 10u^2 of sum |a_i b_i|), pr3_length one more pr_sqrt. The
 * plane hit p = o + t d, t = n.(v0 - o) / (n.d), carries an absolute error of
 * about 20u^2 (|o| + |v0 - o| + |t d|) / |cos| -- 1e-10 m at 1 km for a ray
 * 10 degrees off grazing, against the 11 um of one degree at 77 GHz.
 *
 * Inputs come from the host as float2 pairs (hi, lo) that
 * clradcom.device.precision.split_pairs splits from float64 (hi = f32(x),
 * lo = f32(x - hi): exact to 2^-48 |x|); outputs go back as pairs
 * (pr_to_pair) that join_pairs adds in float64. The same kernel arguments
 * thus serve every mode.
 *
 * API (every function inline):
 *   preal  pr_from_float(float a)          preal  pr_from_pair(float2 hl)
 *   float2 pr_to_pair(preal a)             float  pr_to_float(preal a)
 *   preal  pr_neg(preal a)
 *   preal  pr_add(preal a, preal b)        preal  pr_sub(preal a, preal b)
 *   preal  pr_add_f(preal a, float b)      preal  pr_mul_f(preal a, float b)
 *   preal  pr_mul(preal a, preal b)        preal  pr_div(preal a, preal b)
 *   preal  pr_sqrt(preal a)                (a >= 0)
 *   preal3 pr3_make(preal x, preal y, preal z)
 *   preal3 pr3_from_float3(float3 v)       float3 pr3_to_float3(preal3 v)
 *   preal3 pr3_load_pairs(__global const float2 *p)      (p[0..2] = x, y, z)
 *   void   pr3_store_pairs(__global float2 *p, preal3 v)
 *   preal3 pr3_add(preal3 a, preal3 b)     preal3 pr3_sub(preal3 a, preal3 b)
 *   preal3 pr3_scale(preal3 a, preal s)    preal  pr3_dot(preal3 a, preal3 b)
 *   preal  pr3_length(preal3 a)
 *   preal3 pr3_reflect(preal3 d, preal3 n) d - 2 (d.n) n, n of unit length
 *   preal  pr3_plane_t(preal3 o, preal3 d, preal3 v0, preal3 n)
 *   preal3 pr3_plane_hit(preal3 o, preal3 d, preal3 v0, preal3 n, preal *t)
 *   float  pr_phase_reduced(preal ph)      ph less its whole turns (~[-pi, pi]), a float
 *
 * Float64 buffers whose values a kernel must read exactly where it has fp64 (the
 * float64 scene of the visibility kernels, image points, tile centres: the host's
 * numbers bit for bit) cross as pr_elem instead: double in mode 2, a (hi, lo) float2
 * pair otherwise -- the same 8 bytes (clradcom.device.precision.kernel_float64 and
 * host_float64 choose by the device's mode):
 *   preal  pr_of(pr_elem e)                pr_elem pr_elem_of(preal a)
 *   preal3 pr3_load(__global const pr_elem *p)   void pr3_store(__global pr_elem *p, preal3 v)
 * and the decisions and conversions such kernels take, exact in every mode (mode 1:
 * comparisons of normalised pairs):
 *   bool   pr_lt, pr_le, pr_gt, pr_ge(preal a, preal b)
 *   bool   pr_isfinite(preal a)            bool   pr_isnan(preal a)
 *   preal  pr_fabs(preal a)                preal  pr_fmax, pr_fmin(preal a, preal b)
 *   preal  pr_floor(preal a)               long   pr_to_long(preal a)   (a integral)
 *   preal  pr_from_long(long a)            (exact to 2^48 in mode 1)
 *   PR_CONST(x)                            a literal as preal (float in mode 1)
 * In mode 2 every one of them is the double operation itself, so code written with
 * them compiles to the double code it replaces, bit for bit.
 *
 * docs/precision.md gives the scheme and what tests/test_phase_precision.py
 * measures. */
#ifndef CLRADCOM_PRECISE_H
#define CLRADCOM_PRECISE_H

/* fp64.h, and PoCL's inline fma and sqrt (first: it leaves contraction on) */
#include "fastmath.h"

/* a*b + c must never be contracted behind our back: every fma below is
 * explicit, and TwoSum's rounding errors must be the ones it computes. */
#pragma OPENCL FP_CONTRACT OFF

#ifndef CLRADCOM_NO_FP64
#define CLRADCOM_NO_FP64 0
#endif
#ifndef CLRADCOM_PRECISE_FLOAT32
#define CLRADCOM_PRECISE_FLOAT32 0
#endif

#if CLRADCOM_PRECISE_FLOAT32
#define PRECISE_MODE 0
#elif defined(CLRADCOM_FP64)
#define PRECISE_MODE 2
#else
#define PRECISE_MODE 1
#endif

#define PR_INLINE inline __attribute__((always_inline))

/* ------------------------------------------------------------------------- */
#if PRECISE_MODE == 2

#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double preal;

PR_INLINE preal pr_from_float(float a) { return (double)a; }
PR_INLINE preal pr_from_pair(float2 hl) { return (double)hl.x + (double)hl.y; }
PR_INLINE float2 pr_to_pair(preal a)
{
    float hi = (float)a;
    return (float2)(hi, (float)(a - (double)hi));
}
PR_INLINE float pr_to_float(preal a) { return (float)a; }
PR_INLINE preal pr_neg(preal a) { return -a; }
PR_INLINE preal pr_add(preal a, preal b) { return a + b; }
PR_INLINE preal pr_sub(preal a, preal b) { return a - b; }
PR_INLINE preal pr_add_f(preal a, float b) { return a + (double)b; }
PR_INLINE preal pr_mul(preal a, preal b) { return a * b; }
PR_INLINE preal pr_mul_f(preal a, float b) { return a * (double)b; }
PR_INLINE preal pr_div(preal a, preal b) { return a / b; }
PR_INLINE preal pr_sqrt(preal a) { return sqrt(a); }

typedef double pr_elem;
PR_INLINE preal pr_of(pr_elem e) { return e; }
PR_INLINE pr_elem pr_elem_of(preal a) { return a; }
PR_INLINE bool pr_lt(preal a, preal b) { return a < b; }
PR_INLINE bool pr_le(preal a, preal b) { return a <= b; }
PR_INLINE bool pr_isfinite(preal a) { return isfinite(a); }
PR_INLINE bool pr_isnan(preal a) { return isnan(a); }
PR_INLINE preal pr_fabs(preal a) { return fabs(a); }
PR_INLINE preal pr_fmax(preal a, preal b) { return fmax(a, b); }
PR_INLINE preal pr_fmin(preal a, preal b) { return fmin(a, b); }
PR_INLINE preal pr_floor(preal a) { return floor(a); }
PR_INLINE preal pr_from_long(long a) { return (double)a; }
PR_INLINE long pr_to_long(preal a) { return (long)a; }
#define PR_CONST(x) ((double)(x))

/* ------------------------------------------------------------------------- */
#elif PRECISE_MODE == 1

#ifdef __FAST_RELAXED_MATH__
#error "precise.h: double-float arithmetic needs IEEE float semantics; build without -cl-fast-relaxed-math"
#endif

typedef float2 preal;   /* .x = hi, .y = lo */

/* s + e == a + b exactly (Knuth's TwoSum: no condition on a, b). */
PR_INLINE float2 pr__two_sum(float a, float b)
{
    float s = a + b;
    float ap = s - b;
    float bp = s - ap;
    return (float2)(s, (a - ap) + (b - bp));
}

/* s + e == a + b exactly when |a| >= |b| or a == 0 (Dekker's Fast2Sum). */
PR_INLINE float2 pr__fast_two_sum(float a, float b)
{
    float s = a + b;
    return (float2)(s, b - (s - a));
}

/* p + e == a * b exactly (barring underflow): e by an explicit fma. */
PR_INLINE float2 pr__two_prod(float a, float b)
{
    float p = a * b;
    return (float2)(p, fma(a, b, -p));
}

PR_INLINE preal pr_from_float(float a) { return (float2)(a, 0.0f); }
PR_INLINE preal pr_from_pair(float2 hl) { return pr__fast_two_sum(hl.x, hl.y); }
PR_INLINE float2 pr_to_pair(preal a) { return a; }
PR_INLINE float pr_to_float(preal a) { return a.x; }
PR_INLINE preal pr_neg(preal a) { return -a; }

/* AccurateDWPlusDW (Joldes et al. 2017, Alg. 6): 3u^2 + 13u^3. */
PR_INLINE preal pr_add(preal x, preal y)
{
    float2 s = pr__two_sum(x.x, y.x);
    float2 t = pr__two_sum(x.y, y.y);
    float c = s.y + t.x;
    float2 v = pr__fast_two_sum(s.x, c);
    float w = t.y + v.y;
    return pr__fast_two_sum(v.x, w);
}

PR_INLINE preal pr_sub(preal x, preal y) { return pr_add(x, -y); }

/* DWPlusFP (Alg. 4): 2u^2. */
PR_INLINE preal pr_add_f(preal x, float y)
{
    float2 s = pr__two_sum(x.x, y);
    float v = x.y + s.y;
    return pr__fast_two_sum(s.x, v);
}

/* DWTimesDW3 (Alg. 12): 4u^2. */
PR_INLINE preal pr_mul(preal x, preal y)
{
    float2 c = pr__two_prod(x.x, y.x);
    float tl0 = x.y * y.y;
    float tl1 = fma(x.x, y.y, tl0);
    float cl2 = fma(x.y, y.x, tl1);
    float cl3 = c.y + cl2;
    return pr__fast_two_sum(c.x, cl3);
}

/* DWTimesFP3 (Alg. 9): 2u^2. */
PR_INLINE preal pr_mul_f(preal x, float y)
{
    float2 c = pr__two_prod(x.x, y);
    float cl3 = fma(x.y, y, c.y);
    return pr__fast_two_sum(c.x, cl3);
}

/* DWTimesFP1 (Alg. 7), the product DWDivDW2 is proved with: 1.5u^2 + 4u^3. */
PR_INLINE preal pr__mul_f_accurate(preal x, float y)
{
    float2 c = pr__two_prod(x.x, y);
    float cl2 = x.y * y;
    float2 t = pr__fast_two_sum(c.x, cl2);
    float tl2 = t.y + c.y;
    return pr__fast_two_sum(t.x, tl2);
}

/* DWDivDW2 (Alg. 17): 15u^2 + 56u^3. */
PR_INLINE preal pr_div(preal x, preal y)
{
    float th = x.x / y.x;
    float2 r = pr__mul_f_accurate(y, th);
    float pih = x.x - r.x;
    float dl = x.y - r.y;
    float d = pih + dl;
    float tl = d / y.x;
    return pr__fast_two_sum(th, tl);
}

/* SQRTDWtoDW (Lefevre et al. 2023): 25/8 u^2. The residual x - sh^2 is exact
 * by an fma (sh^2 lies within an ulp of xh). a == 0 gives 0. */
PR_INLINE preal pr_sqrt(preal x)
{
    if (x.x <= 0.0f) return (float2)(sqrt(x.x), 0.0f);
    float sh = sqrt(x.x);
    float r1 = fma(-sh, sh, x.x);
    float r2 = x.y + r1;
    float sl = r2 / (2.0f * sh);
    return pr__fast_two_sum(sh, sl);
}

typedef float2 pr_elem;
PR_INLINE preal pr_of(pr_elem e) { return pr_from_pair(e); }
PR_INLINE pr_elem pr_elem_of(preal a) { return a; }

/* Every operation above returns a normalised pair (hi the sum rounded to float, by a
 * final Fast2Sum), and rounding to nearest is monotonic: so hi orders two pairs, and lo
 * breaks a tie of hi, exactly. A NaN compares false, as in double. */
PR_INLINE bool pr_lt(preal a, preal b) { return a.x < b.x || (a.x == b.x && a.y < b.y); }
PR_INLINE bool pr_le(preal a, preal b) { return a.x < b.x || (a.x == b.x && a.y <= b.y); }
PR_INLINE bool pr_isfinite(preal a) { return isfinite(a.x) && isfinite(a.y); }
PR_INLINE bool pr_isnan(preal a) { return isnan(a.x) || isnan(a.y); }
PR_INLINE preal pr_fabs(preal a) { return (a.x < 0.0f) ? -a : a; }
/* fmax / fmin: a NaN argument gives the other one */
PR_INLINE preal pr_fmax(preal a, preal b)
{
    return pr_isnan(a) ? b : (pr_isnan(b) ? a : (pr_lt(a, b) ? b : a));
}
PR_INLINE preal pr_fmin(preal a, preal b)
{
    return pr_isnan(a) ? b : (pr_isnan(b) ? a : (pr_lt(b, a) ? b : a));
}
/* floor: where hi is not an integer, no lo (|lo| <= ulp(hi)/2) reaches the next one */
PR_INLINE preal pr_floor(preal a)
{
    float fh = floor(a.x);
    if (fh != a.x) return (float2)(fh, 0.0f);
    return pr__fast_two_sum(fh, floor(a.y));
}
/* exact for |a| < 2^48 */
PR_INLINE preal pr_from_long(long a)
{
    float hi = (float)a;
    return pr__fast_two_sum(hi, (float)(a - (long)hi));
}
PR_INLINE long pr_to_long(preal a) { return (long)a.x + (long)a.y; }   /* a integral */
#define PR_CONST(x) pr_from_float((float)(x))

/* ------------------------------------------------------------------------- */
#else   /* PRECISE_MODE 0: plain float, the tests' negative control */

typedef float preal;

PR_INLINE preal pr_from_float(float a) { return a; }
PR_INLINE preal pr_from_pair(float2 hl) { return hl.x; }
PR_INLINE float2 pr_to_pair(preal a) { return (float2)(a, 0.0f); }
PR_INLINE float pr_to_float(preal a) { return a; }
PR_INLINE preal pr_neg(preal a) { return -a; }
PR_INLINE preal pr_add(preal a, preal b) { return a + b; }
PR_INLINE preal pr_sub(preal a, preal b) { return a - b; }
PR_INLINE preal pr_add_f(preal a, float b) { return a + b; }
PR_INLINE preal pr_mul(preal a, preal b) { return a * b; }
PR_INLINE preal pr_mul_f(preal a, float b) { return a * b; }
PR_INLINE preal pr_div(preal a, preal b) { return a / b; }
PR_INLINE preal pr_sqrt(preal a) { return sqrt(a); }

typedef float2 pr_elem;
PR_INLINE preal pr_of(pr_elem e) { return e.x; }
PR_INLINE pr_elem pr_elem_of(preal a) { return (float2)(a, 0.0f); }
PR_INLINE bool pr_lt(preal a, preal b) { return a < b; }
PR_INLINE bool pr_le(preal a, preal b) { return a <= b; }
PR_INLINE bool pr_isfinite(preal a) { return isfinite(a); }
PR_INLINE bool pr_isnan(preal a) { return isnan(a); }
PR_INLINE preal pr_fabs(preal a) { return fabs(a); }
PR_INLINE preal pr_fmax(preal a, preal b) { return fmax(a, b); }
PR_INLINE preal pr_fmin(preal a, preal b) { return fmin(a, b); }
PR_INLINE preal pr_floor(preal a) { return floor(a); }
PR_INLINE preal pr_from_long(long a) { return (float)a; }
PR_INLINE long pr_to_long(preal a) { return (long)a; }
#define PR_CONST(x) ((float)(x))

#endif

/* the rest of the comparisons, from pr_lt and pr_le */
PR_INLINE bool pr_gt(preal a, preal b) { return pr_lt(b, a); }
PR_INLINE bool pr_ge(preal a, preal b) { return pr_le(b, a); }

/* ------------------------------------------------------------------------- */
/* 3-vectors of preal: a struct in every mode (never shared with the host). */
typedef struct {
    preal x, y, z;
} preal3;

PR_INLINE preal3 pr3_make(preal x, preal y, preal z)
{
    preal3 v;
    v.x = x;
    v.y = y;
    v.z = z;
    return v;
}

PR_INLINE preal3 pr3_from_float3(float3 v)
{
    return pr3_make(pr_from_float(v.x), pr_from_float(v.y), pr_from_float(v.z));
}

PR_INLINE float3 pr3_to_float3(preal3 v)
{
    return (float3)(pr_to_float(v.x), pr_to_float(v.y), pr_to_float(v.z));
}

PR_INLINE preal3 pr3_load_pairs(__global const float2 *p)
{
    return pr3_make(pr_from_pair(p[0]), pr_from_pair(p[1]), pr_from_pair(p[2]));
}

PR_INLINE void pr3_store_pairs(__global float2 *p, preal3 v)
{
    p[0] = pr_to_pair(v.x);
    p[1] = pr_to_pair(v.y);
    p[2] = pr_to_pair(v.z);
}

PR_INLINE preal3 pr3_load(__global const pr_elem *p)
{
    return pr3_make(pr_of(p[0]), pr_of(p[1]), pr_of(p[2]));
}

PR_INLINE void pr3_store(__global pr_elem *p, preal3 v)
{
    p[0] = pr_elem_of(v.x);
    p[1] = pr_elem_of(v.y);
    p[2] = pr_elem_of(v.z);
}

PR_INLINE preal3 pr3_add(preal3 a, preal3 b)
{
    return pr3_make(pr_add(a.x, b.x), pr_add(a.y, b.y), pr_add(a.z, b.z));
}

PR_INLINE preal3 pr3_sub(preal3 a, preal3 b)
{
    return pr3_make(pr_sub(a.x, b.x), pr_sub(a.y, b.y), pr_sub(a.z, b.z));
}

PR_INLINE preal3 pr3_scale(preal3 a, preal s)
{
    return pr3_make(pr_mul(a.x, s), pr_mul(a.y, s), pr_mul(a.z, s));
}

PR_INLINE preal pr3_dot(preal3 a, preal3 b)
{
    return pr_add(pr_add(pr_mul(a.x, b.x), pr_mul(a.y, b.y)), pr_mul(a.z, b.z));
}

PR_INLINE preal pr3_length(preal3 a)
{
    return pr_sqrt(pr3_dot(a, a));
}

/* Mirror direction d - 2 (d.n) n off a plane of unit normal n. */
PR_INLINE preal3 pr3_reflect(preal3 d, preal3 n)
{
    preal twice = pr_mul_f(pr3_dot(d, n), 2.0f);   /* times 2: exact */
    return pr3_sub(d, pr3_scale(n, twice));
}

/* A phase (radians, of any size) less its nearest whole number of turns, rounded to
 * float, for the float sine and cosine of a build without fp64: k L of millions of
 * radians keeps its fraction (2 pi as a pair, 2^-48 relative: 3e-8 rad at 1e6 rad). The
 * turns come from a float quotient, so the result may pass +-pi by up to a hundredth
 * of a turn near a half turn; sine and cosine do not mind. */
PR_INLINE float pr_phase_reduced(preal ph)
{
    float turns = rint(pr_to_float(ph) / 6.2831855f);
    preal two_pi = pr_from_pair((float2)(6.2831855f, -1.7484555e-07f));
    return pr_to_float(pr_sub(ph, pr_mul_f(two_pi, turns)));
}

/* Ray parameter t of o + t d on the plane through v0 with normal n (any
 * length): n.(v0 - o) / (n.d). A ray parallel to the plane gives +-inf or
 * NaN, as the float64 formula would; callers test n.d first. */
PR_INLINE preal pr3_plane_t(preal3 o, preal3 d, preal3 v0, preal3 n)
{
    return pr_div(pr3_dot(n, pr3_sub(v0, o)), pr3_dot(n, d));
}

/* The exact hit p = o + t d of a ray with a plane given in float64 (v0, n as
 * pairs); t is written to *t. */
PR_INLINE preal3 pr3_plane_hit(preal3 o, preal3 d, preal3 v0, preal3 n, preal *t)
{
    preal tt = pr3_plane_t(o, d, v0, n);
    *t = tt;
    return pr3_add(o, pr3_scale(d, tt));
}

#endif /* CLRADCOM_PRECISE_H */
