/* Diffuse-scattering tiles on the device (clradcom/device/scatter.py drives these;
 * docs/scattering.md "On the device").
 *
 *   tile_centres   the tiles of the scattering triangles: centroid (double) and triangle
 *   tile_sight     front side and float32 sight line of every tile centre to tx and rx
 *   tile_lambert   Lambertian power of the tiles both ends see (rows listed by the host)
 *   tile_fields    the direct paths tx -> tile -> rx of those rows: length, Doppler,
 *                  antenna directions, polarimetric matrix for Gamma = 1, the pieces of
 *                  Gamma (Fresnel coefficients and the tx basis' TE/TM projections), and
 *                  whether a float64 antenna end is left for the host to decide
 *
 * Every position is precise.h's preal, computed with the host's operations in the
 * host's order (FP_CONTRACT is off, intersect.h): in double where the device has fp64,
 * so a tile centre, a spawned origin and the float32 ray cast from it are the host's
 * (clradcom/mechanisms/scattering.py: make_tiles, clradcom/device/visibility.py:
 * surface_sees) bit for bit; in double-float without (float64 values as (hi, lo) pairs,
 * pr_elem), within ~1e-14 relative of the host's. The sight casts are float32 with the
 * float64 re-decision of a "blocked", as on the host; the float64 antenna-end check
 * stays on the host. The fields are `real`: double with fp64, float without, their
 * phase k L taken in preal and reduced to one turn before its float sine and cosine. */
#include "intersect.h"
#include "precise.h"

#if PRECISE_MODE == 2
typedef double real;
typedef double2 real2;
typedef double3 real3;
#else
typedef float real;
typedef float2 real2;
typedef float3 real3;
#endif
#define CLRADCOM_REAL_DEFINED 1
#include "em.h"

/* sight lines re-decided in float64 where float32 calls them blocked */
#include "scene64.h"
#ifndef SPAWN_OFFSET_ROUNDOFFS
#error "SPAWN_OFFSET_ROUNDOFFS must be passed as -D by the host"
#endif

/* A float64 value as a field quantity, and back */
#if PRECISE_MODE == 2
PR_INLINE real pr_real(preal a) { return a; }
#else
PR_INLINE real pr_real(preal a) { return pr_to_float(a); }
#endif
PR_INLINE real real_of(pr_elem e) { return pr_real(pr_of(e)); }
PR_INLINE pr_elem elem_of_real(real x) { return pr_elem_of(PR_CONST(x)); }

/* Positions and their differences as the host's float64 vectors: double3 with fp64 (its
 * dot products the builtin's, as before), a preal3 without. */
#if PRECISE_MODE == 2
typedef double3 pvec;
PR_INLINE pvec pv_load(__global const pr_elem *p) { return (double3)(p[0], p[1], p[2]); }
PR_INLINE pvec pv_sub(pvec a, pvec b) { return a - b; }
PR_INLINE preal pv_dot(pvec a, pvec b) { return dot(a, b); }
PR_INLINE real3 pv_real(pvec a) { return a; }
PR_INLINE preal pv_x(pvec a) { return a.x; }
PR_INLINE preal pv_y(pvec a) { return a.y; }
PR_INLINE preal pv_z(pvec a) { return a.z; }
PR_INLINE pvec pv_make(preal x, preal y, preal z) { return (double3)(x, y, z); }
#else
typedef preal3 pvec;
PR_INLINE pvec pv_load(__global const pr_elem *p) { return pr3_load(p); }
PR_INLINE pvec pv_sub(pvec a, pvec b) { return pr3_sub(a, b); }
PR_INLINE preal pv_dot(pvec a, pvec b) { return pr3_dot(a, b); }
PR_INLINE real3 pv_real(pvec a) { return pr3_to_float3(a); }
PR_INLINE preal pv_x(pvec a) { return a.x; }
PR_INLINE preal pv_y(pvec a) { return a.y; }
PR_INLINE preal pv_z(pvec a) { return a.z; }
PR_INLINE pvec pv_make(preal x, preal y, preal z) { return pr3_make(x, y, z); }
#endif

/* The traced triangle k holding tile g: tile_first[k] <= g < tile_first[k + 1]. */
CLR_INLINE int tile_triangle(__global const int *tile_first, int n_tri, int g)
{
    int lo = 0, hi = n_tri;   /* invariant: tile_first[lo] <= g < tile_first[hi] */
    while (hi - lo > 1) {
        int mid = (lo + hi) >> 1;
        if (tile_first[mid] <= g) lo = mid; else hi = mid;
    }
    return lo;
}

/* Tile centroids by regular barycentric subdivision (n x n similar sub-triangles): the
 * "up" tiles (i, j), j < n - i, at barycentric ((3i+1)/3n, (3j+1)/3n), then the "down"
 * tiles, j < n - 1 - i, at ((3i+2)/3n, (3j+2)/3n); per triangle in that order, as the
 * host's make_tiles lists them. centre = v0 + u (v1 - v0) + v (v2 - v0). */
__kernel void tile_centres(__global const Bvh8Node *nodes, __global const float4 *tri4,
                           __global const int *slot_prim,
                           __global const pr_elem *vertices, /* (K, 3, 3) */
                           __global const int *tile_first,   /* (K + 1,) */
                           __global const int *tile_n,       /* (K,) subdivisions */
                           const int n_tri, const int n_tiles,
                           __global pr_elem *centres,        /* (N, 3) out */
                           __global int *tile_tri)           /* (N,) out: k */
{
    int g = get_global_id(0);
    if (g >= n_tiles) return;
    int k = tile_triangle(tile_first, n_tri, g);
    int n = tile_n[k];
    int li = g - tile_first[k];   /* the tile within its triangle */
    int up = n * (n + 1) / 2;
    int off = 1, rows = n;           /* up tiles: row i holds n - i of them */
    if (li >= up) {               /* down tiles: row i holds n - 1 - i */
        li -= up;
        off = 2;
        rows = n - 1;
    }
    int i = 0;
    while (li >= rows - i) {
        li -= rows - i;
        ++i;
    }
    preal u = pr_div(pr_from_long(3 * i + off), pr_from_long(3 * n));
    preal v = pr_div(pr_from_long(3 * li + off), pr_from_long(3 * n));
    __global const pr_elem *t = vertices + 9 * (size_t)k;
    for (int c = 0; c < 3; ++c) {
        preal t0 = pr_of(t[c]);
        centres[3 * (size_t)g + c] = pr_elem_of(pr_add(
            pr_add(t0, pr_mul(u, pr_sub(pr_of(t[3 + c]), t0))),
            pr_mul(v, pr_sub(pr_of(t[6 + c]), t0))));
    }
    tile_tri[g] = k;
}

/* raycast.py: spawn_origins for a point q of a surface of normal nrm toward a: q moved
 * off the surface, to the side of a, by a float32 error bound that grows with |q|. */
CLR_INLINE void spawn_toward(const preal *q, const preal *nrm, const preal *a, preal *org)
{
    const preal zero = PR_CONST(0.0);
    preal dir[3] = {pr_sub(a[0], q[0]), pr_sub(a[1], q[1]), pr_sub(a[2], q[2])};
    preal m = pr_fabs(q[0]);
    m = pr_fmax(m, pr_fabs(q[1]));
    m = pr_fmax(m, pr_fabs(q[2]));
    preal bound = pr_mul(PR_CONST(SPAWN_OFFSET_ROUNDOFFS * 0x1p-24), pr_add(m, PR_CONST(1.0)));
    preal s = pr_add(pr_add(pr_mul(nrm[0], dir[0]), pr_mul(nrm[1], dir[1])),
                     pr_mul(nrm[2], dir[2]));
    preal side = pr_lt(s, zero) ? PR_CONST(-1.0) : PR_CONST(1.0);
    preal n_len = pr_sqrt(pr_add(pr_add(pr_mul(nrm[0], nrm[0]), pr_mul(nrm[1], nrm[1])),
                                 pr_mul(nrm[2], nrm[2])));
    if (pr_le(n_len, zero)) n_len = PR_CONST(1.0);
    preal step = pr_div(pr_mul(side, bound), n_len);
    for (int c = 0; c < 3; ++c) org[c] = pr_add(q[c], pr_mul(step, nrm[c]));
}

/* Does the tile centre q (normal nrm, triangle prim) see the antenna at a? The host's
 * surface_sees: origin spawned off the surface toward a (spawn_toward), float32 ray
 * origin -> a, stopping at tmax (1 - SIGHT_STOP) of it, prim itself ignored; a float32
 * "blocked" re-decided in float64 (scene64.h: blocked_in_float64, the segment
 * origin -> a up to hi = 1 - SIGHT_STOP). */
CLR_INLINE bool tile_sees(__global const Bvh8Node *nodes, __global const float4 *tri4,
                          __global const int *slot_prim, const Scene64 *s64,
                          const int rounds, const preal look_past, const preal hi,
                          const preal *q, const preal *nrm, int prim, const preal *a,
                          float tmax)
{
    preal org[3];
    spawn_toward(q, nrm, a, org);
    preal g[3] = {pr_sub(a[0], org[0]), pr_sub(a[1], org[1]), pr_sub(a[2], org[2])};
    float3 o32 = (float3)(pr_to_float(org[0]), pr_to_float(org[1]), pr_to_float(org[2]));
    float3 d32 = (float3)(pr_to_float(g[0]), pr_to_float(g[1]), pr_to_float(g[2]));
    PreparedRay pr = prepare_ray(o32, d32);
    if (!bvh_any(nodes, tri4, slot_prim, &pr, 0.0f, tmax, prim, -1))
        return true;
    return !blocked_in_float64(nodes, tri4, slot_prim, s64, &pr, tmax, org[0], org[1],
                               org[2], g[0], g[1], g[2], PR_CONST(0.0), hi, prim, rounds,
                               look_past);
}

/* n . (end - q) > 0: the tile's front faces that end */
CLR_INLINE bool front_faces(const preal *nrm, const preal *end, const preal *q)
{
    return pr_gt(pr_add(pr_add(pr_mul(nrm[0], pr_sub(end[0], q[0])),
                               pr_mul(nrm[1], pr_sub(end[1], q[1]))),
                        pr_mul(nrm[2], pr_sub(end[2], q[2]))), PR_CONST(0.0));
}

/* flags[g]: bit 0 the tile's front faces tx and tx sees it, bit 1 the same for rx
 * (front: n . (end - q) > 0). all_ends == 0 (direct paths only): a tile counts only when
 * both fronts face their ends, and rx is cast only where tx sees it (bit 1 then means
 * both). all_ends == 1: each end on its own; monostatic (tx == rx) copies bit 0. */
#define TILE_SEES(end) \
    tile_sees(nodes, tri4, slot_prim, &s64, rounds, look, top, q, nrm, p, end, tmax)
__kernel void tile_sight(__global const Bvh8Node *nodes, __global const float4 *tri4,
                         __global const int *slot_prim, SCENE64_ARGS,
                         const int rounds, const pr_elem look_past, const pr_elem hi,
                         __global const pr_elem *centres, __global const int *tile_tri,
                         __global const pr_elem *normals,  /* (K, 3) unit */
                         __global const int *prim,         /* (K,) scene triangle */
                         const pr_elem tx_x, const pr_elem tx_y, const pr_elem tx_z,
                         const pr_elem rx_x, const pr_elem rx_y, const pr_elem rx_z,
                         const float tmax, const int all_ends, const int monostatic,
                         const int n_tiles, __global uchar *flags)
{
    int g = get_global_id(0);
    if (g >= n_tiles) return;
    int k = tile_tri[g];
    preal q[3] = {pr_of(centres[3 * (size_t)g]), pr_of(centres[3 * (size_t)g + 1]),
                  pr_of(centres[3 * (size_t)g + 2])};
    preal nrm[3] = {pr_of(normals[3 * k]), pr_of(normals[3 * k + 1]),
                    pr_of(normals[3 * k + 2])};
    preal tx[3] = {pr_of(tx_x), pr_of(tx_y), pr_of(tx_z)};
    preal rx[3] = {pr_of(rx_x), pr_of(rx_y), pr_of(rx_z)};
    preal look = pr_of(look_past), top = pr_of(hi);
    bool front_t = front_faces(nrm, tx, q);
    bool front_r = front_faces(nrm, rx, q);
    int p = prim[k];
    uchar out = 0;
    SCENE64_INIT(s64);
    if (all_ends == 0) {
        if (front_t && front_r && TILE_SEES(tx)) {
            out = 1;
            if (monostatic || TILE_SEES(rx))
                out |= 2;
        }
    } else {
        if (front_t && TILE_SEES(tx))
            out = 1;
        if (monostatic)
            out |= (uchar)(out << 1);
        else if (front_r && TILE_SEES(rx))
            out |= 2;
    }
    flags[g] = out;
}
#undef TILE_SEES

/* Lambertian power of the tiles both ends see, rows[r] listing them in tile order (the
 * host's flatnonzero of flags == 3), for isotropic antennas and Gamma = 1:
 *   power = scale S^2 A cos(theta_i) cos(theta_s) / (r_i^2 r_s^2),
 * scale = lambda^2 / (16 pi^3) (docs/scattering.md); the centre comes along. */
__kernel void tile_lambert(__global const Bvh8Node *nodes, __global const float4 *tri4,
                           __global const int *slot_prim,
                           __global const pr_elem *centres, __global const int *tile_tri,
                           __global const pr_elem *normals,     /* (K, 3) unit */
                           __global const pr_elem *tile_area,   /* (K,) one tile's area */
                           __global const pr_elem *scattering,  /* (K,) S */
                           __global const int *rows, const int n_rows,
                           const pr_elem tx_x, const pr_elem tx_y, const pr_elem tx_z,
                           const pr_elem rx_x, const pr_elem rx_y, const pr_elem rx_z,
                           const pr_elem scale,
                           __global pr_elem *out_centre, __global pr_elem *out_power)
{
    int r = get_global_id(0);
    if (r >= n_rows) return;
    int g = rows[r];
    int k = tile_tri[g];
    pvec q = pv_load(centres + 3 * (size_t)g);
    real3 n = pv_real(pv_load(normals + 3 * k));
    pvec dt = pv_sub(q, pv_make(pr_of(tx_x), pr_of(tx_y), pr_of(tx_z)));
    pvec dr = pv_sub(pv_make(pr_of(rx_x), pr_of(rx_y), pr_of(rx_z)), q);
    real ri2 = pr_real(pv_dot(dt, dt)), rs2 = pr_real(pv_dot(dr, dr));
    real ri = sqrt(ri2), rs = sqrt(rs2);
    real cos_i = clamp(-dot(pv_real(dt), n) / ri, (real)0.0, (real)1.0);
    real cos_s = clamp(dot(pv_real(dr), n) / rs, (real)0.0, (real)1.0);
    real S = real_of(scattering[k]);
    out_power[r] = elem_of_real(real_of(scale) * S * S * real_of(tile_area[k]) * cos_i * cos_s
                                / (ri2 * rs2));
    for (int c = 0; c < 3; ++c) out_centre[3 * (size_t)r + c] = centres[3 * (size_t)g + c];
}

/* em.h's fresnel (em.py: fresnel_coefficients) with |z| as sqrt(x^2 + y^2) instead of
 * hypot, which PoCL calls out of line (40 ns a row of tile_fields, a fifth of it); a
 * permittivity is far from overflowing the squares. */
CLR_INLINE void tile_fresnel(cplx eps, real cos_theta, int pec, cplx *r_te, cplx *r_tm)
{
    if (pec) { *r_te = (cplx)(-1.0, 0.0); *r_tm = (cplx)(1.0, 0.0); return; }
    real c = fmin(fmax(fabs(cos_theta), (real)0.0), (real)1.0);
    cplx z = (cplx)((eps.x - 1.0) + c * c, eps.y);
    real m = sqrt(z.x * z.x + z.y * z.y);
    cplx a = (cplx)(0.0, 0.0);
    if (m != 0.0) {   /* principal square root (Re >= 0), as numpy's */
        real re = sqrt(0.5 * (m + fabs(z.x)));
        real im = 0.5 * z.y / re;
        a = (z.x >= 0.0) ? (cplx)(re, im) : (cplx)(fabs(im), (z.y >= 0.0) ? re : -re);
    }
    a.y = -fabs(a.y);
    cplx cc = (cplx)(c, 0.0);
    cplx den_te = cc + a;
    cplx epsc = c_scale(eps, c);
    cplx den_tm = epsc + a;
    *r_te = (den_te.x == 0.0 && den_te.y == 0.0) ? (cplx)(0.0, 0.0) : c_div(cc - a, den_te);
    *r_tm = (den_tm.x == 0.0 && den_tm.y == 0.0) ? (cplx)(0.0, 0.0) : c_div(epsc - a, den_tm);
}

/* scattering.py: _te_basis - TE = k x n / |k x n| (along the normal: n x a, a the x axis
 * unless |n_x| >= 0.9, then the y axis), TM = TE x k */
CLR_INLINE void te_tm(real3 k, real3 n, real3 *te, real3 *tm)
{
    real3 t = cross(k, n);
    real len = sqrt(dot(t, t));
    if (len < 1e-9) {
        real3 a = (fabs(n.x) < 0.9) ? (real3)(1.0, 0.0, 0.0) : (real3)(0.0, 1.0, 0.0);
        t = cross(n, a);
        len = sqrt(dot(t, t));
    }
    *te = t / len;
    *tm = cross(*te, k);
}

/* Might visibility.py: antenna_blocked call the segment ant -> other blocked? Only a
 * triangle of the antenna's near list (within the radius of it, the antenna off its
 * plane: chosen on the host) whose plane the segment crosses strictly between its ends
 * within `radius` of the antenna can; whether the crossing lies inside the triangle is
 * left to the host (true here means "the host decides", false "not blocked"). The
 * radius is widened by 1e-9 of itself, so rounding never makes this a subset. */
CLR_INLINE bool antenna_end_open(pvec ant, pvec other, preal radius,
                                 __global const int *near, int n_near,
                                 __global const pr_elem *tri_v, __global const pr_elem *tri_n)
{
    pvec seg = pv_sub(other, ant);
    preal seg_len = pr_sqrt(pv_dot(seg, seg));
    preal reach = pr_mul(radius, pr_add(PR_CONST(1.0), PR_CONST(1e-9)));
    for (int i = 0; i < n_near; ++i) {
        int t = near[i];
        pvec n = pv_load(tri_n + 3 * t);
        pvec v0 = pv_load(tri_v + 9 * t);
        preal d_ant = pv_dot(n, pv_sub(ant, v0));
        preal d_other = pv_dot(n, pv_sub(other, v0));
        if (!pr_lt(pr_mul(d_ant, d_other), PR_CONST(0.0))) continue;
        preal x = pr_div(d_ant, pr_sub(d_ant, d_other));
        if (pr_le(pr_mul(x, seg_len), reach)) return true;
    }
    return false;
}

/* The spawned origin of a ray from tile centre q (normal nrm) toward a, as tile_sees. */
CLR_INLINE pvec spawned(pvec q, pvec nrm, pvec a)
{
    preal qq[3] = {pv_x(q), pv_y(q), pv_z(q)}, nn[3] = {pv_x(nrm), pv_y(nrm), pv_z(nrm)};
    preal aa[3] = {pv_x(a), pv_y(a), pv_z(a)}, org[3];
    spawn_toward(qq, nn, aa, org);
    return pv_make(org[0], org[1], org[2]);
}

/* Columns of tile_fields' rows, from the host (clradcom/device/scatter.py: FIELD_COLUMNS,
 * which reads them by the same names): TF_POWER Lambertian power (isotropic antennas,
 * Gamma = 1); TF_CENTRE (3) the tile centre q; TF_LENGTH L = r_i + r_s; TF_DOPPLER
 * -(1/lambda) dL/dt; TF_TX_DIR (3) k_dep in tx's frame (k_dep R_tx); TF_RX_DIR (3) -k_arr
 * in rx's frame; TF_MATRIX (2x2 complex, re im) M for Gamma = 1, [[VV, VH], [HV, HH]];
 * TF_PROJ (2x2) [theta_t, phi_t] . te_i, then . tm_i; TF_FRESNEL r_te, r_tm (re im) at the
 * tile; TF_UNDECIDED 1 where an antenna end is left to the host's float64 test;
 * TILE_FIELDS pr_elem (float64 values) a row. */
#ifndef TILE_FIELDS
#error "the TF_* columns and TILE_FIELDS must be passed as -D by the host"
#endif

/* The direct path tx -> tile -> rx through each tile rows[r] both ends see, one row of
 * TILE_FIELDS values each (clradcom/mechanisms/scattering.py: _path_rows, tile_transfer
 * and em.path_gains with no mirror on either side; the formulas and their sources are
 * there and in docs/scattering.md):
 *   M = (lambda/4 pi) e^{-jkL} / (r_i r_s) S sqrt(A cos_i cos_s / pi) b_rx^T X b_tx,
 *   X = e^{j chi1} sqrt(1 - K) R0 + e^{j chi2} sqrt(K) [s]x R0,
 *   R0 = -te_s te_i^T + tm_s tm_i^T,
 * for Gamma = 1: Gamma depends on tx's pattern (the polarisation arriving at the tile),
 * which the host applies, as it applies both patterns to the SBR kernel's matrices.
 * `link` holds tx (3), rx (3), v_tx (3), v_rx (3), then 2 pi / lambda, lambda / 4 pi,
 * lambda, lambda^2 / 16 pi^3 (12-15), and the antenna-end radii of tx and rx (16, 17);
 * `frames` R_tx (9), R_rx (9) in `real`; `tri_par` per traced triangle S, K_x, eps',
 * -eps'', pec, v (3), omega (3), rotation centre (3); `phases` (n_rows, 2) each row's
 * chi1, chi2 (drawn on the host for every tile, gathered for the rows). Lengths, centres
 * and the phase k L are preal; the rest is real. */
__kernel void tile_fields(__global const Bvh8Node *nodes, __global const float4 *tri4,
                          __global const int *slot_prim,
                          __global const pr_elem *centres, __global const int *tile_tri,
                          __global const pr_elem *normals,   /* (K, 3) unit */
                          __global const pr_elem *tile_area, /* (K,) */
                          __global const pr_elem *tri_par,   /* (K, 14) */
                          __global const pr_elem *phases,    /* (n_rows, 2) */
                          __global const pr_elem *link,      /* (18,) */
                          __global const real *frames,       /* (18,) */
                          __global const int *near_first,    /* (3,): tx's, rx's near lists */
                          __global const int *near_tri,
                          __global const pr_elem *tri_v,     /* scene triangles, float64 */
                          __global const pr_elem *tri_n,
                          __global const int *rows, const int n_rows,
                          const int monostatic,              /* rx is tx (same frame too) */
                          __global pr_elem *out)             /* (n_rows, TILE_FIELDS) */
{
    int r = get_global_id(0);
    if (r >= n_rows) return;
    int g = rows[r];
    int k = tile_tri[g];
    __global const pr_elem *lk = link;
    pvec tx = pv_load(lk), rx = pv_load(lk + 3);
    real3 v_tx = (real3)(real_of(lk[6]), real_of(lk[7]), real_of(lk[8]));
    real3 v_rx = (real3)(real_of(lk[9]), real_of(lk[10]), real_of(lk[11]));
    preal two_pi_lambda = pr_of(lk[12]);
    real lambda_4pi = real_of(lk[13]), lambda = real_of(lk[14]);
    pvec q = pv_load(centres + 3 * (size_t)g);
    real3 n = pv_real(pv_load(normals + 3 * k));
    __global const pr_elem *tp = tri_par + 14 * (size_t)k;
    real S = real_of(tp[0]), Kx = real_of(tp[1]);
    cplx eps = (cplx)(real_of(tp[2]), real_of(tp[3]));
    int pec = real_of(tp[4]) != 0.0;
    real3 v_obj = (real3)(real_of(tp[5]), real_of(tp[6]), real_of(tp[7]));
    real3 omega = (real3)(real_of(tp[8]), real_of(tp[9]), real_of(tp[10]));
    real A = real_of(tile_area[k]);

    pvec dt_p = pv_sub(q, tx), dr_p = pv_sub(rx, q);
    preal ri2_p = pv_dot(dt_p, dt_p), rs2_p = pv_dot(dr_p, dr_p);
    preal ri_p = pr_sqrt(ri2_p), rs_p = pr_sqrt(rs2_p);
    real3 dt = pv_real(dt_p), dr = pv_real(dr_p);
    real ri2 = pr_real(ri2_p), rs2 = pr_real(rs2_p), ri = pr_real(ri_p), rs = pr_real(rs_p);
    real3 ki = dt / ri, s = dr / rs;
    real cos_i = clamp(-dot(ki, n), (real)0.0, (real)1.0);
    real cos_s = clamp(dot(s, n), (real)0.0, (real)1.0);
    preal L = pr_add(ri_p, rs_p);
    __global pr_elem *o = out + (size_t)r * TILE_FIELDS;
    o[TF_POWER] = elem_of_real(real_of(lk[15]) * S * S * A
                               * clamp(-dot(dt, n) / ri, (real)0.0, (real)1.0)
                               * clamp(dot(dr, n) / rs, (real)0.0, (real)1.0) / (ri2 * rs2));
    o[TF_CENTRE] = pr_elem_of(pv_x(q));
    o[TF_CENTRE + 1] = pr_elem_of(pv_y(q));
    o[TF_CENTRE + 2] = pr_elem_of(pv_z(q));
    o[TF_LENGTH] = pr_elem_of(L);

    /* Doppler: the tile is a material point of its object (v + omega x (q - c)) */
    real3 lever = pv_real(pv_sub(q, pv_load(tp + 11)));
    real3 v_q = v_obj + cross(omega, lever);
    o[TF_DOPPLER] = elem_of_real(-(dot(v_q - v_tx, ki) + dot(v_rx - v_q, s)) / lambda);

    /* Fresnel at the tile for the host's Gamma */
    cplx r_te, r_tm;
    tile_fresnel(eps, fabs(dot(ki, n)), pec, &r_te, &r_tm);
    o[TF_FRESNEL] = elem_of_real(r_te.x);
    o[TF_FRESNEL + 1] = elem_of_real(r_te.y);
    o[TF_FRESNEL + 2] = elem_of_real(r_tm.x);
    o[TF_FRESNEL + 3] = elem_of_real(r_tm.y);

    real3 d_tx, th_t, ph_t, d_rx, th_r, ph_r;
    antenna_frame_basis(ki, frames, &d_tx, &th_t, &ph_t);
    if (monostatic) {   /* rx is tx: -s = ki bit for bit (rx - q = -(q - tx), r_s = r_i) */
        d_rx = d_tx;
        th_r = th_t;
        ph_r = ph_t;
    } else {
        antenna_frame_basis(-s, frames + 9, &d_rx, &th_r, &ph_r);
    }
    o[TF_TX_DIR] = elem_of_real(d_tx.x);
    o[TF_TX_DIR + 1] = elem_of_real(d_tx.y);
    o[TF_TX_DIR + 2] = elem_of_real(d_tx.z);
    o[TF_RX_DIR] = elem_of_real(d_rx.x);
    o[TF_RX_DIR + 1] = elem_of_real(d_rx.y);
    o[TF_RX_DIR + 2] = elem_of_real(d_rx.z);

    real3 te_i, tm_i, te_s, tm_s;
    te_tm(ki, n, &te_i, &tm_i);
    te_tm(s, n, &te_s, &tm_s);
    real Tt[2] = {dot(th_t, te_i), dot(ph_t, te_i)}, Tm[2] = {dot(th_t, tm_i), dot(ph_t, tm_i)};
    o[TF_PROJ] = elem_of_real(Tt[0]);
    o[TF_PROJ + 1] = elem_of_real(Tt[1]);
    o[TF_PROJ + 2] = elem_of_real(Tm[0]);
    o[TF_PROJ + 3] = elem_of_real(Tm[1]);

    /* M for Gamma = 1 */
    real c1, c2, cp;
    real s1 = sincos(real_of(phases[2 * (size_t)r]), &c1);
    real s2 = sincos(real_of(phases[2 * (size_t)r + 1]), &c2);
    real co = sqrt(1.0 - Kx), cx = sqrt(Kx);
    cplx e1 = (cplx)(c1, s1) * co, e2 = (cplx)(c2, s2) * cx;
    real amp = lambda_4pi / (ri * rs) * S * sqrt(A * cos_i * cos_s / M_PI);
#if PRECISE_MODE == 2
    real sp = sincos(two_pi_lambda * L, &cp);
#else
    /* k L (up to millions of radians) reduced to one turn in double-float first */
    real sp = sincos(pr_phase_reduced(pr_mul(two_pi_lambda, L)), &cp);
#endif
    cplx rot = (cplx)(cp, -sp) * amp;
    /* b_rx_i^T R0 b_tx_j = -Rt_i Tt_j + Rm_i Tm_j and b_rx_i . (s x R0 b_tx_j) =
     * Rm_i Tt_j + Rt_i Tm_j, with Rt_i, Rm_i = b_rx_i . te_s, tm_s and Tt_j, Tm_j =
     * te_i, tm_i . b_tx_j (s x te_s = -tm_s as tm_s = te_s x s; s x tm_s = te_s up to
     * (b_rx . s)(s . te_s), zero to rounding as b_rx is transverse to s) */
    real Rt[2] = {dot(th_r, te_s), dot(ph_r, te_s)}, Rm[2] = {dot(th_r, tm_s), dot(ph_r, tm_s)};
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) {
            cplx x = e1 * (Rm[i] * Tm[j] - Rt[i] * Tt[j]) + e2 * (Rm[i] * Tt[j] + Rt[i] * Tm[j]);
            cplx m = c_mul(rot, x);
            o[TF_MATRIX + 4 * i + 2 * j] = elem_of_real(m.x);
            o[TF_MATRIX + 4 * i + 2 * j + 1] = elem_of_real(m.y);
        }

    /* the float64 antenna ends of the sight lines (visibility.py: antenna_blocked) */
    bool undecided = false;
    int nt = near_first[1] - near_first[0];
    if (nt > 0)
        undecided = antenna_end_open(tx, spawned(q, pv_load(normals + 3 * k), tx),
                                     pr_of(lk[16]), near_tri + near_first[0], nt, tri_v, tri_n);
    int nr = near_first[2] - near_first[1];
    if (!undecided && nr > 0)
        undecided = antenna_end_open(rx, spawned(q, pv_load(normals + 3 * k), rx),
                                     pr_of(lk[17]), near_tri + near_first[1], nr, tri_v,
                                     tri_n);
    o[TF_UNDECIDED] = elem_of_real(undecided ? 1.0 : 0.0);
}
