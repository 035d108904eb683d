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
 * Every position is double, computed with the host's operations in the host's order
 * (FP_CONTRACT is off, intersect.h), so a tile centre, a spawned origin and the float32
 * ray cast from it are the host's (clradcom/mechanisms/scattering.py: make_tiles,
 * clradcom/device/visibility.py: surface_sees) bit for bit. The sight casts are float32
 * with the float64 re-decision of a "blocked", as on the host; the float64 antenna-end
 * check stays on the host. */
#include "intersect.h"

/* em.h's Fresnel coefficients, in double (scatter.cl needs fp64) */
typedef double real;
typedef double2 real2;
typedef double3 real3;
#define CLRADCOM_REAL_DEFINED 1
#include "em.h"

#ifndef CLRADCOM_HAS_FP64
#error "scatter.cl needs cl_khr_fp64 (the host falls back to its numpy path without it)"
#endif
/* sight lines re-decided in float64 where float32 calls them blocked */
#include "scene64.h"
#ifndef SPAWN_OFFSET_ROUNDOFFS
#error "SPAWN_OFFSET_ROUNDOFFS must be passed as -D by the host"
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
                           __global const double *vertices,  /* (K, 3, 3) */
                           __global const int *tile_first,   /* (K + 1,) */
                           __global const int *tile_n,       /* (K,) subdivisions */
                           const int n_tri, const int n_tiles,
                           __global double *centres,         /* (N, 3) out */
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
    double u = (double)(3 * i + off) / (double)(3 * n);
    double v = (double)(3 * li + off) / (double)(3 * n);
    __global const double *t = vertices + 9 * (size_t)k;
    for (int c = 0; c < 3; ++c)
        centres[3 * (size_t)g + c] = (t[c] + u * (t[3 + c] - t[c])) + v * (t[6 + c] - t[c]);
    tile_tri[g] = k;
}

/* Does the tile centre q (normal nrm, triangle prim) see the antenna at a? The host's
 * surface_sees: origin spawned off the surface toward a (raycast.spawn_origins), float32
 * ray origin -> a, stopping at tmax (1 - SIGHT_STOP) of it, prim itself ignored; a
 * float32 "blocked" re-decided in float64 (scene64.h: blocked_in_float64, the segment
 * origin -> a up to hi = 1 - SIGHT_STOP). */
CLR_INLINE bool tile_sees(__global const Bvh8Node *nodes, __global const float4 *tri4,
                          __global const int *slot_prim, const Scene64 *s64,
                          const int rounds, const double look_past, const double hi,
                          const double *q, const double *nrm, int prim, const double *a,
                          float tmax)
{
    double dir[3] = {a[0] - q[0], a[1] - q[1], a[2] - q[2]};
    double m = fabs(q[0]);
    m = fmax(m, fabs(q[1]));
    m = fmax(m, fabs(q[2]));
    double bound = ((double)SPAWN_OFFSET_ROUNDOFFS * 0x1p-24) * (m + 1.0);
    double s = (nrm[0] * dir[0] + nrm[1] * dir[1]) + nrm[2] * dir[2];
    double side = (s < 0.0) ? -1.0 : 1.0;
    double n_len = sqrt((nrm[0] * nrm[0] + nrm[1] * nrm[1]) + nrm[2] * nrm[2]);
    if (n_len == 0.0) n_len = 1.0;
    double step = side * bound / n_len;
    double org[3];
    for (int c = 0; c < 3; ++c) org[c] = q[c] + step * nrm[c];
    float3 o32 = (float3)((float)org[0], (float)org[1], (float)org[2]);
    float3 d32 = (float3)((float)(a[0] - org[0]), (float)(a[1] - org[1]),
                          (float)(a[2] - org[2]));
    PreparedRay pr = prepare_ray(o32, d32);
    if (!bvh_any(nodes, tri4, slot_prim, &pr, 0.0f, tmax, prim, -1))
        return true;
    return !blocked_in_float64(nodes, tri4, slot_prim, s64, &pr, tmax, org[0], org[1],
                               org[2], a[0] - org[0], a[1] - org[1], a[2] - org[2], 0.0,
                               hi, prim, rounds, look_past);
}

/* flags[g]: bit 0 the tile's front faces tx and tx sees it, bit 1 the same for rx
 * (front: n . (end - q) > 0). all_ends == 0 (direct paths only): a tile counts only when
 * both fronts face their ends, and rx is cast only where tx sees it (bit 1 then means
 * both). all_ends == 1: each end on its own; monostatic (tx == rx) copies bit 0. */
#define TILE_SEES(end) \
    tile_sees(nodes, tri4, slot_prim, &s64, rounds, look_past, hi, q, nrm, p, end, tmax)
__kernel void tile_sight(__global const Bvh8Node *nodes, __global const float4 *tri4,
                         __global const int *slot_prim, SCENE64_ARGS,
                         const int rounds, const double look_past, const double hi,
                         __global const double *centres, __global const int *tile_tri,
                         __global const double *normals,   /* (K, 3) unit */
                         __global const int *prim,         /* (K,) scene triangle */
                         const double tx_x, const double tx_y, const double tx_z,
                         const double rx_x, const double rx_y, const double rx_z,
                         const float tmax, const int all_ends, const int monostatic,
                         const int n_tiles, __global uchar *flags)
{
    int g = get_global_id(0);
    if (g >= n_tiles) return;
    int k = tile_tri[g];
    double q[3] = {centres[3 * (size_t)g], centres[3 * (size_t)g + 1],
                   centres[3 * (size_t)g + 2]};
    double nrm[3] = {normals[3 * k], normals[3 * k + 1], normals[3 * k + 2]};
    double tx[3] = {tx_x, tx_y, tx_z}, rx[3] = {rx_x, rx_y, rx_z};
    bool front_t = ((nrm[0] * (tx[0] - q[0]) + nrm[1] * (tx[1] - q[1]))
                    + nrm[2] * (tx[2] - q[2])) > 0.0;
    bool front_r = ((nrm[0] * (rx[0] - q[0]) + nrm[1] * (rx[1] - q[1]))
                    + nrm[2] * (rx[2] - q[2])) > 0.0;
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
                           __global const double *centres, __global const int *tile_tri,
                           __global const double *normals,      /* (K, 3) unit */
                           __global const double *tile_area,    /* (K,) one tile's area */
                           __global const double *scattering,   /* (K,) S */
                           __global const int *rows, const int n_rows,
                           const double tx_x, const double tx_y, const double tx_z,
                           const double rx_x, const double rx_y, const double rx_z,
                           const double scale,
                           __global double *out_centre, __global double *out_power)
{
    int r = get_global_id(0);
    if (r >= n_rows) return;
    int g = rows[r];
    int k = tile_tri[g];
    double3 q = (double3)(centres[3 * (size_t)g], centres[3 * (size_t)g + 1],
                          centres[3 * (size_t)g + 2]);
    double3 n = (double3)(normals[3 * k], normals[3 * k + 1], normals[3 * k + 2]);
    double3 dt = q - (double3)(tx_x, tx_y, tx_z);
    double3 dr = (double3)(rx_x, rx_y, rx_z) - q;
    double ri2 = dot(dt, dt), rs2 = dot(dr, dr);
    double ri = sqrt(ri2), rs = sqrt(rs2);
    double cos_i = clamp(-dot(dt, n) / ri, 0.0, 1.0);
    double cos_s = clamp(dot(dr, n) / rs, 0.0, 1.0);
    double S = scattering[k];
    out_power[r] = scale * S * S * tile_area[k] * cos_i * cos_s / (ri2 * rs2);
    for (int c = 0; c < 3; ++c) out_centre[3 * (size_t)r + c] = centres[3 * (size_t)g + c];
}

/* em.h's fresnel (em.py: fresnel_coefficients) with |z| as sqrt(x^2 + y^2) instead of
 * hypot, which PoCL calls out of line (40 ns a row of tile_fields, a fifth of it); a
 * permittivity is far from overflowing the squares. */
CLR_INLINE void tile_fresnel(cplx eps, double cos_theta, int pec, cplx *r_te, cplx *r_tm)
{
    if (pec) { *r_te = (cplx)(-1.0, 0.0); *r_tm = (cplx)(1.0, 0.0); return; }
    double c = fmin(fmax(fabs(cos_theta), 0.0), 1.0);
    cplx z = (cplx)((eps.x - 1.0) + c * c, eps.y);
    double m = sqrt(z.x * z.x + z.y * z.y);
    cplx a = (cplx)(0.0, 0.0);
    if (m != 0.0) {   /* principal square root (Re >= 0), as numpy's */
        double re = sqrt(0.5 * (m + fabs(z.x)));
        double im = 0.5 * z.y / re;
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
CLR_INLINE void te_tm(double3 k, double3 n, double3 *te, double3 *tm)
{
    double3 t = cross(k, n);
    double len = sqrt(dot(t, t));
    if (len < 1e-9) {
        double3 a = (fabs(n.x) < 0.9) ? (double3)(1.0, 0.0, 0.0) : (double3)(0.0, 1.0, 0.0);
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
 * left to the host (true here means "the host decides", false "not blocked"). */
CLR_INLINE bool antenna_end_open(double3 ant, double3 other, double radius,
                                 __global const int *near, int n_near,
                                 __global const double *tri_v, __global const double *tri_n)
{
    double3 seg = other - ant;
    double seg_len = sqrt(dot(seg, seg));
    for (int i = 0; i < n_near; ++i) {
        int t = near[i];
        double3 n = (double3)(tri_n[3 * t], tri_n[3 * t + 1], tri_n[3 * t + 2]);
        double3 v0 = (double3)(tri_v[9 * t], tri_v[9 * t + 1], tri_v[9 * t + 2]);
        double d_ant = dot(n, ant - v0);
        double d_other = dot(n, other - v0);
        if (!(d_ant * d_other < 0.0)) continue;
        double x = d_ant / (d_ant - d_other);
        if (x * seg_len <= radius * (1.0 + 1e-9)) return true;
    }
    return false;
}

/* The spawned origin of a ray from tile centre q (normal nrm) toward a, as tile_sees. */
CLR_INLINE double3 spawned(double3 q, double3 nrm, double3 a)
{
    double3 dir = a - q;
    double m = fmax(fmax(fabs(q.x), fabs(q.y)), fabs(q.z));
    double bound = ((double)SPAWN_OFFSET_ROUNDOFFS * 0x1p-24) * (m + 1.0);
    double s = (nrm.x * dir.x + nrm.y * dir.y) + nrm.z * dir.z;
    double side = (s < 0.0) ? -1.0 : 1.0;
    double n_len = sqrt((nrm.x * nrm.x + nrm.y * nrm.y) + nrm.z * nrm.z);
    if (n_len == 0.0) n_len = 1.0;
    return q + (side * bound / n_len) * nrm;
}

/* Columns of tile_fields' rows, from the host (clradcom/device/scatter.py: FIELD_COLUMNS,
 * which reads them by the same names): TF_POWER Lambertian power (isotropic antennas,
 * Gamma = 1); TF_CENTRE (3) the tile centre q; TF_LENGTH L = r_i + r_s; TF_DOPPLER
 * -(1/lambda) dL/dt; TF_TX_DIR (3) k_dep in tx's frame (k_dep R_tx); TF_RX_DIR (3) -k_arr
 * in rx's frame; TF_MATRIX (2x2 complex, re im) M for Gamma = 1, [[VV, VH], [HV, HH]];
 * TF_PROJ (2x2) [theta_t, phi_t] . te_i, then . tm_i; TF_FRESNEL r_te, r_tm (re im) at the
 * tile; TF_UNDECIDED 1 where an antenna end is left to the host's float64 test;
 * TILE_FIELDS doubles a row. */
#ifndef TILE_FIELDS
#error "the TF_* columns and TILE_FIELDS must be passed as -D by the host"
#endif

/* The direct path tx -> tile -> rx through each tile rows[r] both ends see, one row of
 * TILE_FIELDS doubles each (clradcom/mechanisms/scattering.py: _path_rows, tile_transfer
 * and em.path_gains with no mirror on either side; the formulas and their sources are
 * there and in docs/scattering.md):
 *   M = (lambda/4 pi) e^{-jkL} / (r_i r_s) S sqrt(A cos_i cos_s / pi) b_rx^T X b_tx,
 *   X = e^{j chi1} sqrt(1 - K) R0 + e^{j chi2} sqrt(K) [s]x R0,
 *   R0 = -te_s te_i^T + tm_s tm_i^T,
 * for Gamma = 1: Gamma depends on tx's pattern (the polarisation arriving at the tile),
 * which the host applies, as it applies both patterns to the SBR kernel's matrices.
 * `link` holds tx (3), rx (3), v_tx (3), v_rx (3), R_tx (9), R_rx (9), then
 * 2 pi / lambda, lambda / 4 pi, lambda, lambda^2 / 16 pi^3 (30-33), and the antenna-end
 * radii of tx and rx (34, 35); `tri_par` per traced triangle S, K_x, eps', -eps'', pec,
 * v (3), omega (3), rotation centre (3); `phases` (n_rows, 2) each row's chi1, chi2 (drawn on
 * the host for every tile, gathered for the rows). */
__kernel void tile_fields(__global const Bvh8Node *nodes, __global const float4 *tri4,
                          __global const int *slot_prim,
                          __global const double *centres, __global const int *tile_tri,
                          __global const double *normals,   /* (K, 3) unit */
                          __global const double *tile_area, /* (K,) */
                          __global const double *tri_par,   /* (K, 14) */
                          __global const double *phases,    /* (n_rows, 2) */
                          __global const double *link,      /* (36,) */
                          __global const int *near_first,   /* (3,): tx's, rx's near lists */
                          __global const int *near_tri,
                          __global const double *tri_v,     /* scene triangles, float64 */
                          __global const double *tri_n,
                          __global const int *rows, const int n_rows,
                          const int monostatic,             /* rx is tx (same frame too) */
                          __global double *out)             /* (n_rows, TILE_FIELDS) */
{
    int r = get_global_id(0);
    if (r >= n_rows) return;
    int g = rows[r];
    int k = tile_tri[g];
    __global const double *lk = link;
    double3 tx = (double3)(lk[0], lk[1], lk[2]), rx = (double3)(lk[3], lk[4], lk[5]);
    double3 v_tx = (double3)(lk[6], lk[7], lk[8]), v_rx = (double3)(lk[9], lk[10], lk[11]);
    double two_pi_lambda = lk[30], lambda_4pi = lk[31], lambda = lk[32];
    double3 q = (double3)(centres[3 * (size_t)g], centres[3 * (size_t)g + 1],
                          centres[3 * (size_t)g + 2]);
    double3 n = (double3)(normals[3 * k], normals[3 * k + 1], normals[3 * k + 2]);
    __global const double *tp = tri_par + 14 * (size_t)k;
    double S = tp[0], Kx = tp[1];
    cplx eps = (cplx)(tp[2], tp[3]);
    int pec = tp[4] != 0.0;
    double3 v_obj = (double3)(tp[5], tp[6], tp[7]), omega = (double3)(tp[8], tp[9], tp[10]);
    double3 rot_c = (double3)(tp[11], tp[12], tp[13]);
    double A = tile_area[k];

    double3 dt = q - tx, dr = rx - q;
    double ri2 = dot(dt, dt), rs2 = dot(dr, dr);
    double ri = sqrt(ri2), rs = sqrt(rs2);
    double3 ki = dt / ri, s = dr / rs;
    double cos_i = clamp(-dot(ki, n), 0.0, 1.0);
    double cos_s = clamp(dot(s, n), 0.0, 1.0);
    double L = ri + rs;
    __global double *o = out + (size_t)r * TILE_FIELDS;
    o[TF_POWER] = lk[33] * S * S * A * clamp(-dot(dt, n) / ri, 0.0, 1.0)
                  * clamp(dot(dr, n) / rs, 0.0, 1.0) / (ri2 * rs2);
    o[TF_CENTRE] = q.x;
    o[TF_CENTRE + 1] = q.y;
    o[TF_CENTRE + 2] = q.z;
    o[TF_LENGTH] = L;

    /* Doppler: the tile is a material point of its object (v + omega x (q - c)) */
    double3 v_q = v_obj + cross(omega, q - rot_c);
    o[TF_DOPPLER] = -(dot(v_q - v_tx, ki) + dot(v_rx - v_q, s)) / lambda;

    /* Fresnel at the tile for the host's Gamma */
    cplx r_te, r_tm;
    tile_fresnel(eps, fabs(dot(ki, n)), pec, &r_te, &r_tm);
    o[TF_FRESNEL] = r_te.x;
    o[TF_FRESNEL + 1] = r_te.y;
    o[TF_FRESNEL + 2] = r_tm.x;
    o[TF_FRESNEL + 3] = r_tm.y;

    double3 d_tx, th_t, ph_t, d_rx, th_r, ph_r;
    antenna_frame_basis(ki, lk + 12, &d_tx, &th_t, &ph_t);
    if (monostatic) {   /* rx is tx: -s = ki bit for bit (rx - q = -(q - tx), r_s = r_i) */
        d_rx = d_tx;
        th_r = th_t;
        ph_r = ph_t;
    } else {
        antenna_frame_basis(-s, lk + 21, &d_rx, &th_r, &ph_r);
    }
    o[TF_TX_DIR] = d_tx.x;
    o[TF_TX_DIR + 1] = d_tx.y;
    o[TF_TX_DIR + 2] = d_tx.z;
    o[TF_RX_DIR] = d_rx.x;
    o[TF_RX_DIR + 1] = d_rx.y;
    o[TF_RX_DIR + 2] = d_rx.z;

    double3 te_i, tm_i, te_s, tm_s;
    te_tm(ki, n, &te_i, &tm_i);
    te_tm(s, n, &te_s, &tm_s);
    double Tt[2] = {dot(th_t, te_i), dot(ph_t, te_i)}, Tm[2] = {dot(th_t, tm_i), dot(ph_t, tm_i)};
    o[TF_PROJ] = Tt[0];
    o[TF_PROJ + 1] = Tt[1];
    o[TF_PROJ + 2] = Tm[0];
    o[TF_PROJ + 3] = Tm[1];

    /* M for Gamma = 1 */
    double c1, c2, cp;
    double s1 = sincos(phases[2 * (size_t)r], &c1), s2 = sincos(phases[2 * (size_t)r + 1], &c2);
    double co = sqrt(1.0 - Kx), cx = sqrt(Kx);
    cplx e1 = (cplx)(c1, s1) * co, e2 = (cplx)(c2, s2) * cx;
    double amp = lambda_4pi / (ri * rs) * S * sqrt(A * cos_i * cos_s / M_PI);
    double sp = sincos(two_pi_lambda * L, &cp);
    cplx rot = (cplx)(cp, -sp) * amp;
    /* b_rx_i^T R0 b_tx_j = -Rt_i Tt_j + Rm_i Tm_j and b_rx_i . (s x R0 b_tx_j) =
     * Rm_i Tt_j + Rt_i Tm_j, with Rt_i, Rm_i = b_rx_i . te_s, tm_s and Tt_j, Tm_j =
     * te_i, tm_i . b_tx_j (s x te_s = -tm_s as tm_s = te_s x s; s x tm_s = te_s up to
     * (b_rx . s)(s . te_s), zero to rounding as b_rx is transverse to s) */
    double Rt[2] = {dot(th_r, te_s), dot(ph_r, te_s)}, Rm[2] = {dot(th_r, tm_s), dot(ph_r, tm_s)};
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) {
            cplx x = e1 * (Rm[i] * Tm[j] - Rt[i] * Tt[j]) + e2 * (Rm[i] * Tt[j] + Rt[i] * Tm[j]);
            cplx m = c_mul(rot, x);
            o[TF_MATRIX + 4 * i + 2 * j] = m.x;
            o[TF_MATRIX + 4 * i + 2 * j + 1] = m.y;
        }

    /* the float64 antenna ends of the sight lines (visibility.py: antenna_blocked) */
    bool undecided = false;
    int nt = near_first[1] - near_first[0];
    if (nt > 0)
        undecided = antenna_end_open(tx, spawned(q, n, tx), link[34], near_tri + near_first[0],
                                     nt, tri_v, tri_n);
    int nr = near_first[2] - near_first[1];
    if (!undecided && nr > 0)
        undecided = antenna_end_open(rx, spawned(q, n, rx), link[35],
                                     near_tri + near_first[1], nr, tri_v, tri_n);
    o[TF_UNDECIDED] = undecided ? 1.0 : 0.0;
}
