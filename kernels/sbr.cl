/* SBR-PO on the device: each work item is one ray tube. It leaves the
 * transmitter through a launch window's cell (clradcom/mechanisms/sbr.py:
 * TubeWindows), is dropped when an earlier window owns its direction, follows
 * up to SBR_MAX_BOUNCES specular reflections (closest hits in float32 over the
 * BVH, each hit point the exact float64 intersection with the hit triangle's
 * plane, the transfer chain of the material reflection dyads in float64) and,
 * at every bounce from first_bounce on a recorded triangle, radiates its PO
 * footprint toward every receiver it sees: one SbrRecord each, appended with an
 * atomic counter. The formulas are the host reference's (clradcom/mechanisms/
 * sbr.py: shoot_tubes, _chains, _radiate), step for step. */
#include "intersect.h"
#include "em.h"

#ifndef SPAWN_OFFSET_ROUNDOFFS
#error "SPAWN_OFFSET_ROUNDOFFS must be passed as -D by the host"
#endif
#ifndef SBR_MAX_BOUNCES
#error "SBR_MAX_BOUNCES must be passed as -D by the host"
#endif
#ifndef SBR_TRI_SLOTS
#error "SBR_TRI_SLOTS must be passed as -D by the host"
#endif
#ifndef SBR_BLOCK
#error "SBR_BLOCK must be passed as -D by the host"
#endif
#if SBR_TRI_SLOTS < SBR_MAX_BOUNCES || (SBR_TRI_SLOTS % 2) != 1
#error "SBR_TRI_SLOTS must be odd and at least SBR_MAX_BOUNCES (8-byte record size)"
#endif

#define SBR_CELLS (SBR_BLOCK * SBR_BLOCK)
/* rows of a window: axis, u, v (3 each), distance, spacing, pad */
#define WIN_F 12
/* cell0 (2), shape (2), mask offset, pad */
#define WIN_I 6

/* Mirrored by clradcom/device/sbr.py: RECORD_DTYPE (a test checks the size). */
typedef struct {
    double length;         /* unfolded tx -> footprint -> rx */
    double point[3];       /* footprint centre: the exact hit point */
    double k_arr[3];       /* unit direction footprint -> rx */
    float transfer[18];    /* T, complex 3x3 row-major, (re, im) pairs */
    long tube;
    short bounce;
    short receiver;
    int tri[SBR_TRI_SLOTS];   /* triangles hit up to this bounce, -1 after */
} SbrRecord;

inline double3 load3(__global const double *p) { return (double3)(p[0], p[1], p[2]); }

/* raycast.py: spawn_origins, in float64: off the surface toward the side the ray
 * leaves into, by a float32 error bound growing with |p| */
inline double3 spawn64(double3 p, double3 n, double3 dir)
{
    double3 ap = fabs(p);
    double bound = SPAWN_OFFSET_ROUNDOFFS * (0.5 * (double)FLT_EPSILON)
                   * (fmax(fmax(ap.x, ap.y), ap.z) + 1.0);
    double side = (dot(n, dir) < 0.0) ? -1.0 : 1.0;
    return p + (side * bound / sqrt(dot(n, n))) * n;
}

inline float3 to_float3(double3 a) { return convert_float3(a); }

/* po.py: sinc */
inline double sinc_(double x)
{
    return (fabs(x) < 1e-4) ? 1.0 - x * x / 6.0 : sin(x) / x;
}

/* Whether window k launches a tube whose cell holds direction d (sbr.py: _covers). */
inline bool window_covers(__global const double *win_f, __global const int *win_i,
                          __global const uchar *masks, int k, double3 d)
{
    __global const double *f = win_f + WIN_F * k;
    __global const int *wi = win_i + WIN_I * k;
    double depth = dot(d, load3(f));
    if (!(depth > 0.0)) return false;
    double D = f[9], s = f[10];
    double x = D * dot(d, load3(f + 3)) / depth;
    double y = D * dot(d, load3(f + 6)) / depth;
    if (!(fabs(x) < 1e12 * s && fabs(y) < 1e12 * s)) return false;
    long ci = (long)floor(x / s + 0.5) - wi[0];
    long cj = (long)floor(y / s + 0.5) - wi[1];
    long bi = (ci >= 0) ? ci / SBR_BLOCK : -((-ci + SBR_BLOCK - 1) / SBR_BLOCK);
    long bj = (cj >= 0) ? cj / SBR_BLOCK : -((-cj + SBR_BLOCK - 1) / SBR_BLOCK);
    if (bi < 0 || bi >= wi[2] || bj < 0 || bj >= wi[3]) return false;
    return masks[wi[4] + bi * wi[3] + bj] != 0;
}

__kernel void sbr_shoot(__global const Bvh8Node *nodes,
                        __global const float4 *tri4,
                        __global const int *slot_prim,
                        __global const double *tri_v,      /* T*9 */
                        __global const double *tri_n,      /* T*3, unit */
                        __global const int *tri_material,
                        __global const uchar *tri_record,
                        __global const double *mat_f,      /* per material: eps re, im, sigma_h, spec share */
                        __global const int *mat_i,         /* per material: pec, roughness model */
                        __global const double *win_f,
                        __global const int *win_i,
                        __global const uchar *masks,
                        __global const int *blocks,        /* per covered block: window, i, j */
                        __global const double *rx_pos,     /* R*3 */
                        const int n_rx,
                        const double tx_x, const double tx_y, const double tx_z,
                        const double k0,
                        const float sight_tmax,
                        const int first_bounce,
                        const int max_bounces,
                        const long first_block,
                        const int n_items,
                        __global SbrRecord *out,
                        __global volatile int *count,
                        const int capacity)
{
    int gid = get_global_id(0);
    if (gid >= n_items) return;
    long blk = first_block + gid / SBR_CELLS;
    int cell = gid % SBR_CELLS;
    long tube = blk * SBR_CELLS + cell;
    int w = blocks[3 * blk];
    __global const double *f = win_f + WIN_F * w;
    __global const int *wi = win_i + WIN_I * w;
    long i = (long)wi[0] + (long)blocks[3 * blk + 1] * SBR_BLOCK + cell % SBR_BLOCK;
    long j = (long)wi[1] + (long)blocks[3 * blk + 2] * SBR_BLOCK + cell / SBR_BLOCK;
    double3 axis = load3(f), u = load3(f + 3), v = load3(f + 6);
    double D = f[9], s = f[10];
    double3 vec = D * axis + ((double)i * s) * u + ((double)j * s) * v;
    double dist = sqrt(dot(vec, vec));
    double3 d = vec / dist;
    for (int k = 0; k < w; ++k)
        if (window_covers(win_f, win_i, masks, k, d)) return;   /* an earlier window's tube */
    double cos_a = D / dist;
    double dom = s * s * cos_a * cos_a * cos_a / (D * D);
    double3 e1 = u - dot(d, u) * d;
    e1 /= sqrt(dot(e1, e1));
    double3 e2 = cross(d, e1);
    double3 k_launch = d;

    double3 tx = (double3)(tx_x, tx_y, tx_z);
    double3 pos = tx, org = tx;
    double L = 0.0;
    int tri_hist[SBR_TRI_SLOTS];
    for (int m = 0; m < SBR_TRI_SLOTS; ++m) tri_hist[m] = -1;
    cmat3 chain;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            chain.m[3 * r + c] = (cplx)(((r == c) ? 1.0 : 0.0)
                                        - comp3(k_launch, r) * comp3(k_launch, c), 0.0);

    for (int m = 1; m <= max_bounces; ++m) {
        PreparedRay pr = prepare_ray(to_float3(org), to_float3(d));
        float t = INFINITY, hu = 0.0f, hv = 0.0f;
        int slot = bvh_closest(nodes, tri4, slot_prim, &pr, 0.0f, &t, &hu, &hv, -1);
        if (slot < 0) break;
        int tri = slot_prim[slot];
        double3 n = load3(tri_n + 3 * tri);
        double dn = dot(d, n);
        if (!(fabs(dn) > 1e-9)) break;   /* grazing: no footprint */
        double tt = dot(load3(tri_v + 9 * tri) - pos, n) / dn;
        double3 p = pos + tt * d;
        double3 seg = p - pos;
        L += sqrt(dot(seg, seg));
        tri_hist[m - 1] = tri;
        int mat = tri_material[tri];
        if (m >= first_bounce && tri_record[tri]) {
            double3 n_lit = (dn > 0.0) ? -n : n;   /* -sign(dn) n */
            double kn = dot(d, n_lit);
            double w_side = sqrt(dom) * L;
            double3 a1 = w_side * e1, a2 = w_side * e2;
            a1 -= d * (dot(n_lit, a1) / kn);
            a2 -= d * (dot(n_lit, a2) / kn);
            double area = w_side * w_side / fabs(kn);
            int pec = mat_i[2 * mat];
            cmat3 Dm;
            if (!pec)
                Dm = material_dyad(d, n_lit, (cplx)(mat_f[4 * mat], mat_f[4 * mat + 1]), 0,
                                   mat_f[4 * mat + 2], mat_i[2 * mat + 1], mat_f[4 * mat + 3], k0);
            for (int r = 0; r < n_rx; ++r) {
                double3 rx = load3(rx_pos + 3 * r);
                double3 dr = rx - p;
                double R_r = sqrt(dot(dr, dr));
                if (!(R_r > 0.0)) continue;
                double3 sdir = dr / R_r;
                if (!(dot(sdir, n_lit) > 0.0)) continue;
                /* visibility.py: surface_sees - the sight line from just off the facet,
                 * stopping SIGHT_STOP short of the antenna, the facet itself ignored */
                double3 sorg = spawn64(p, n_lit, sdir);
                PreparedRay sr = prepare_ray(to_float3(sorg), to_float3(rx - sorg));
                if (bvh_any(nodes, tri4, slot_prim, &sr, 0.0f, sight_tmax, tri, -1)) continue;
                double3 q = k0 * (sdir - d);
                double i_fp = area * sinc_(0.5 * dot(q, a1)) * sinc_(0.5 * dot(q, a2));
                /* the current operator: PEC (I - s s^T)(k_i n^T - (k_i.n) I), else
                 * half of po.py: penetrable_po_operator */
                cmat3 op;
                for (int a = 0; a < 3; ++a)
                    for (int b = 0; b < 3; ++b) {
                        double acc = 0.0;
                        for (int c = 0; c < 3; ++c) {
                            double proj = ((a == c) ? 1.0 : 0.0) - comp3(sdir, a) * comp3(sdir, c);
                            double cr = comp3(d, c) * comp3(n_lit, b) - ((c == b) ? kn : 0.0);
                            acc += proj * cr;
                        }
                        op.m[3 * a + b] = (cplx)(acc, 0.0);
                    }
                if (!pec) {
                    double3 k_r = d - 2.0 * kn * n_lit;
                    /* a_r = k_r n^T + kn I;  S N = [s]x [n]x */
                    cmat3 K;
                    for (int a = 0; a < 3; ++a)
                        for (int b = 0; b < 3; ++b) {
                            cplx acc = (cplx)(0.0, 0.0);
                            for (int c = 0; c < 3; ++c) {
                                double proj = ((a == c) ? 1.0 : 0.0) - comp3(sdir, a) * comp3(sdir, c);
                                /* (a_r D)[c][b] */
                                cplx arD = (cplx)(0.0, 0.0);
                                for (int e = 0; e < 3; ++e) {
                                    double ar = comp3(k_r, c) * comp3(n_lit, e) + ((c == e) ? kn : 0.0);
                                    arD += c_scale(Dm.m[3 * e + b], ar);
                                }
                                acc += c_scale(arD, proj);
                            }
                            /* [s]x[n]x (I + D): [s]x[n]x = n s^T - (s.n) I */
                            for (int c = 0; c < 3; ++c) {
                                double sn = comp3(n_lit, a) * comp3(sdir, c)
                                            - ((a == c) ? dot(sdir, n_lit) : 0.0);
                                cplx ipd = Dm.m[3 * c + b] + (cplx)((c == b) ? 1.0 : 0.0, 0.0);
                                acc += c_scale(ipd, sn);
                            }
                            K.m[3 * a + b] = c_scale(op.m[3 * a + b] + acc, 0.5);
                        }
                    op = K;
                }
                double Ltot = L + R_r;
                /* scale = -j k0/(2 pi) L/(L_in R_r) I_fp */
                double sc = -k0 / (2.0 * M_PI) * Ltot / (L * R_r) * i_fp;
                cmat3 T = cmat3_mul(&op, &chain);
                int slot_out = atomic_inc(count);
                if (slot_out >= capacity) continue;   /* the host re-runs with room */
                __global SbrRecord *rec = out + slot_out;
                rec->length = Ltot;
                rec->point[0] = p.x; rec->point[1] = p.y; rec->point[2] = p.z;
                rec->k_arr[0] = sdir.x; rec->k_arr[1] = sdir.y; rec->k_arr[2] = sdir.z;
                for (int e = 0; e < 9; ++e) {
                    /* (0 + j sc) * T: (-sc T.im, sc T.re) */
                    rec->transfer[2 * e] = (float)(-sc * T.m[e].y);
                    rec->transfer[2 * e + 1] = (float)(sc * T.m[e].x);
                }
                rec->tube = tube;
                rec->bounce = (short)m;
                rec->receiver = (short)r;
                for (int e = 0; e < SBR_TRI_SLOTS; ++e) rec->tri[e] = tri_hist[e];
            }
        }
        if (m == max_bounces) break;
        cmat3 Dr = material_dyad(d, n, (cplx)(mat_f[4 * mat], mat_f[4 * mat + 1]),
                                 mat_i[2 * mat], mat_f[4 * mat + 2], mat_i[2 * mat + 1],
                                 mat_f[4 * mat + 3], k0);
        chain = cmat3_mul(&Dr, &chain);
        d = d - 2.0 * dn * n;
        e1 = e1 - 2.0 * dot(e1, n) * n;
        e2 = e2 - 2.0 * dot(e2, n) * n;
        pos = p;
        org = spawn64(p, n, d);
    }
}
