/* SBR-PO on the device. Work item = one covered block of a launch window
 * (clradcom/mechanisms/sbr.py: TubeWindows); it shoots the block's
 * SBR_BLOCK x SBR_BLOCK tubes one after the other. A tube leaves the transmitter
 * through its window cell, is dropped when an earlier window owns its direction,
 * follows up to SBR_MAX_BOUNCES specular reflections (closest hits in float32 over
 * the BVH; each hit point the exact intersection with the hit triangle's plane and the
 * unfolded length in double, or in precise.h's double-float without fp64; the field of
 * each tx polarisation carried through the material reflections in `real`) and, at every bounce from first_bounce on a recorded
 * triangle, radiates its PO footprint toward every receiver it sees: a 2x2
 * polarimetric matrix in the antennas' bases, summed per (bounce, receiver, face
 * sequence) over the block and written as one SbrRecord. The formulas are the host
 * reference's (clradcom/mechanisms/sbr.py: shoot_tubes, _chains, _radiate, and
 * clradcom/physics/em.py: polarimetric_matrix), step for step. */
#include "intersect.h"
#include "precise.h"

/* Field and geometry arithmetic in `real`: double where the device has fp64, float where
 * it has not. Positions and lengths that become phases are `pvec`/`pscal`: double, or
 * precise.h's double-float (PRECISE_MODE 1, also forced with -D CLRADCOM_NO_FP64=1). */
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
#if PRECISE_MODE == 2
/* sight lines re-decided in float64 where float32 calls them blocked */
#include "scene64.h"
#endif

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
#if SBR_TRI_SLOTS < SBR_MAX_BOUNCES
#error "SBR_TRI_SLOTS must be at least SBR_MAX_BOUNCES"
#endif

#define SBR_CELLS (SBR_BLOCK * SBR_BLOCK)
/* rows of a window: axis, u, v (3 each), distance, spacing, pad */
#define WIN_F 12
/* cell0 (2), shape (2), mask offset, pad */
#define WIN_I 6

inline real3 load3(__global const real *p) { return (real3)(p[0], p[1], p[2]); }

inline float3 to_float3(real3 a) { return convert_float3(a); }

#if PRECISE_MODE == 2
typedef double3 pvec;   /* a position */
typedef double pscal;   /* a length */
typedef double pelem;   /* a buffer element of either */
typedef double pout;    /* a record field of either */
inline pvec pv_load(__global const pelem *p) { return (double3)(p[0], p[1], p[2]); }
inline pvec pv_sub(pvec a, pvec b) { return a - b; }
inline pvec pv_along(pvec a, pscal t, real3 d) { return a + t * d; }
inline pscal pv_len(pvec a) { return sqrt(dot(a, a)); }
inline real3 pv_real(pvec a) { return a; }
inline pscal ps_add(pscal a, pscal b) { return a + b; }
inline real ps_real(pscal a) { return a; }
inline pout ps_out(pscal a) { return a; }
/* n.(v0 - o) / (d.n) of the host's float64 plane hit */
inline pscal plane_t(pvec v0, pvec o, pvec n_p, real3 n, real3 d, real dn)
{
    return dot(v0 - o, n) / dn;
}
/* the phase k L, whose sine and cosine double takes as it is */
inline real phase_of(pscal k, pscal L) { return k * L; }
#else
typedef preal3 pvec;
typedef preal pscal;
typedef float2 pelem;
typedef float2 pout;
inline pvec pv_load(__global const pelem *p) { return pr3_load_pairs(p); }
inline pvec pv_sub(pvec a, pvec b) { return pr3_sub(a, b); }
inline pvec pv_along(pvec a, pscal t, real3 d) { return pr3_add(a, pr3_scale(pr3_from_float3(d), t)); }
inline pscal pv_len(pvec a) { return pr3_length(a); }
inline real3 pv_real(pvec a) { return pr3_to_float3(a); }
inline pscal ps_add(pscal a, pscal b) { return pr_add(a, b); }
inline real ps_real(pscal a) { return pr_to_float(a); }
inline pout ps_out(pscal a) { return pr_to_pair(a); }
inline pscal plane_t(pvec v0, pvec o, pvec n_p, real3 n, real3 d, real dn)
{
    return pr_div(pr3_dot(n_p, pr3_sub(v0, o)), pr3_dot(n_p, pr3_from_float3(d)));
}
/* k L reduced to [-pi, pi] in double-float (2 pi as a pair), then rounded to float: a
 * phase of millions of radians keeps its fraction */
inline real phase_of(pscal k, pscal L)
{
    preal ph = pr_mul(k, L);
    float turns = rint(pr_to_float(ph) / 6.2831855f);
    preal two_pi = pr_from_pair((float2)(6.2831855f, -1.7484555e-07f));
    return pr_to_float(pr_sub(ph, pr_mul_f(two_pi, turns)));
}
#endif

/* raycast.py: spawn_origins: off the surface toward the side the ray leaves into, by a
 * float32 error bound growing with |p| */
inline pvec spawn(pvec p, real3 n, real3 dir)
{
    real3 ap = fabs(pv_real(p));
    real bound = SPAWN_OFFSET_ROUNDOFFS * (0.5 * (real)FLT_EPSILON)
                 * (fmax(fmax(ap.x, ap.y), ap.z) + 1.0);
    real side = (dot(n, dir) < 0.0) ? -1.0 : 1.0;
#if PRECISE_MODE == 2
    return p + (side * bound / sqrt(dot(n, n))) * n;
#else
    return pr3_add(p, pr3_from_float3((side * bound / sqrt(dot(n, n))) * n));
#endif
}

inline float3 pv_float3(pvec a)
{
#if PRECISE_MODE == 2
    return convert_float3(a);
#else
    return pr3_to_float3(a);
#endif
}

/* po.py: sinc */
inline real sinc_(real x)
{
    return (fabs(x) < 1e-4) ? 1.0 - x * x / 6.0 : sin(x) / x;
}

/* Whether window k launches a tube whose cell holds direction d (sbr.py: _covers). */
inline bool window_covers(__global const real *win_f, __global const int *win_i,
                          __global const uchar *masks, int k, real3 d)
{
    __global const real *f = win_f + WIN_F * k;
    __global const int *wi = win_i + WIN_I * k;
    real depth = dot(d, load3(f));
    if (!(depth > 0.0)) return false;
    real D = f[9], s = f[10];
    real x = D * dot(d, load3(f + 3)) / depth;
    real y = D * dot(d, load3(f + 6)) / depth;
    if (!(fabs(x) < 1e12 * s && fabs(y) < 1e12 * s)) return false;
    long ci = (long)floor(x / s + 0.5) - wi[0];
    long cj = (long)floor(y / s + 0.5) - wi[1];
    long bi = (ci >= 0) ? ci / SBR_BLOCK : -((-ci + SBR_BLOCK - 1) / SBR_BLOCK);
    long bj = (cj >= 0) ? cj / SBR_BLOCK : -((-cj + SBR_BLOCK - 1) / SBR_BLOCK);
    if (bi < 0 || bi >= wi[2] || bj < 0 || bj >= wi[3]) return false;
    return masks[wi[4] + bi * wi[3] + bj] != 0;
}


#ifndef SBR_GROUPS
#error "SBR_GROUPS must be passed as -D by the host"
#endif

/* One face sequence of one block toward one receiver at one bounce: the sum of its
 * tubes' polarimetric matrices. Mirrored by clradcom/device/sbr.py: record_dtype
 * (a test checks the size). */
typedef struct {
    pout length;             /* the representative's unfolded length tx -> rx */
    pout point[3];           /* the representative's footprint centre */
    real M[8];               /* sum of 2x2 complex M (VV VH HV HH), (re, im) pairs */
    real weight;             /* sum of |M|_F */
    real weighted_length;    /* sum of |M|_F L */
    real rep_weight;         /* the representative's |M|_F */
    real pad_real;           /* keeps `tube` on 8 bytes in both precisions */
    long tube;               /* the representative: largest |M|_F, the first of equals */
    int ordinal;             /* emission order within the block */
    int count;               /* tubes summed */
    short bounce;
    short receiver;
    int pad;
    int face[SBR_TRI_SLOTS]; /* the planar faces hit, -1 after the bounce */
    int tri[SBR_TRI_SLOTS];  /* the representative's triangles */
} SbrRecord;

/* em.h: antenna_frame_basis without the local direction */
inline void antenna_basis(real3 d, __global const real *R, real3 *th, real3 *ph)
{
    real3 loc;
    antenna_frame_basis(d, R, &loc, th, ph);
}

/* visibility.py: antenna_blocked for one segment antenna -> other: a triangle of the
 * antenna's near list (those within reach of it and off its plane, chosen on the host)
 * crossed strictly between the ends within `radius` of the antenna, in float64. The
 * crossing counts as inside a triangle within on_tol of its edges. */
inline bool antenna_end_blocked(pvec ant, pvec other, real radius,
                                __global const int *near, int n_near,
                                __global const pelem *tri_v, __global const pelem *tri_n,
                                real on_tol_rel, real inside_tol_rel)
{
#if PRECISE_MODE == 2
    double3 seg = other - ant;
    double seg_len = sqrt(dot(seg, seg));
    double3 ao = fabs(other);
    double on_other = on_tol_rel * (1.0 + fmax(fmax(ao.x, ao.y), ao.z));
    for (int k = 0; k < n_near; ++k) {
        int tri = near[k];
        double3 n = pv_load(tri_n + 3 * tri);
        double3 v0 = pv_load(tri_v + 9 * tri);
        double d_ant = dot(n, ant - v0);
        double d_other = dot(other, n) - dot(n, v0);
        if (fabs(d_other) <= on_other || !(d_ant * d_other < 0.0)) continue;
        double t = d_ant / (d_ant - d_other);
        if (t * seg_len > radius) continue;
        double3 x = ant + t * seg;
        double3 v1 = pv_load(tri_v + 9 * tri + 3), v2 = pv_load(tri_v + 9 * tri + 6);
        double3 ax = fabs(x);
        double tol = inside_tol_rel * (1.0 + fmax(fmax(ax.x, ax.y), ax.z));
#else
    /* without fp64: the same test in float relative to the antenna, its tolerances
     * those of float rounding there */
    float3 seg = pv_real(pv_sub(other, ant));
    float seg_len = length(seg);
    for (int k = 0; k < n_near; ++k) {
        int tri = near[k];
        float3 n = pv_real(pv_load(tri_n + 3 * tri));
        float3 v0 = pv_real(pv_sub(pv_load(tri_v + 9 * tri), ant));
        float3 v1 = pv_real(pv_sub(pv_load(tri_v + 9 * tri + 3), ant));
        float3 v2 = pv_real(pv_sub(pv_load(tri_v + 9 * tri + 6), ant));
        float d_ant = -dot(n, v0);
        float d_other = dot(n, seg - v0);
        float on_other = 4.0f * FLT_EPSILON * (1.0f + length(seg) + length(v0));
        if (fabs(d_other) <= on_other || !(d_ant * d_other < 0.0f)) continue;
        float t = d_ant / (d_ant - d_other);
        if (t * seg_len > radius) continue;
        float3 x = t * seg;
        float tol = 4.0f * FLT_EPSILON * (1.0f + length(v0));
#endif
        /* signed distances inside each edge, in the triangle's plane */
        real3 c0 = cross(n, v1 - v0), c1 = cross(n, v2 - v1), c2 = cross(n, v0 - v2);
        bool inside = dot(x - v0, c0) >= -tol * sqrt(dot(c0, c0))
                      && dot(x - v1, c1) >= -tol * sqrt(dot(c1, c1))
                      && dot(x - v2, c2) >= -tol * sqrt(dot(c2, c2));
        if (inside) return true;
    }
    return false;
}

/* sizeof(SbrRecord) as this build lays it out, for the host's numpy twin's test */
__kernel void sbr_record_size(__global int *out)
{
    out[0] = (int)sizeof(SbrRecord);
}

inline void emit(__global SbrRecord *out, __global volatile int *count, int capacity,
                 SbrRecord *rec, int *ordinal)
{
    rec->ordinal = (*ordinal)++;
    int slot = atomic_inc(count);
    if (slot < capacity) out[slot] = *rec;   /* else the host re-runs the batch with room */
}

/* One work item per covered block: its BLOCK x BLOCK tubes in order, their
 * contributions summed per (bounce, receiver, face sequence) in a small table
 * (the oldest entry is written out when it is full), so a block's records come
 * out in an order fixed by the block alone. */
__kernel void sbr_blocks(__global const Bvh8Node *nodes,
                         __global const float4 *tri4,
                         __global const int *slot_prim,
                         __global const pelem *tri_v,       /* T*9 */
                         __global const pelem *tri_n,       /* T*3, unit */
                         __global const int *tri_material,
                         __global const int *tri_face,
                         __global const uchar *tri_record,
                         __global const real *mat_f,        /* per material: eps re, im, sigma_h, spec share */
                         __global const int *mat_i,         /* per material: pec, roughness model */
                         __global const real *win_f,
                         __global const int *win_i,
                         __global const uchar *masks,
                         __global const int *blocks,        /* per covered block: window, i, j */
                         __global const int *overlap_first, /* W+1: window w's earlier overlaps */
                         __global const int *overlap_ids,
                         __global const pelem *rx_pos,      /* R*3 */
                         __global const real *rx_frame,     /* R*9, row-major */
                         __global const real *tx_frame,     /* 9 */
                         __global const pelem *tx_and_k,    /* tx position (3), wavenumber */
                         __global const int *near_first,    /* R+1: receiver r's near triangles */
                         __global const int *near_tri,
#if PRECISE_MODE == 2
                         /* scene64.h's face tables (tri_v, tri_n, tri_face are its
                          * vertices, normals and faces), for the float64 sight rounds */
                         __global const uchar *seam,
                         __global const int *face_first,
                         __global const int *face_tris,
                         __global const double *face_box,
                         const int n_faces,
                         const int rescue_rounds,
                         const double look_past,
                         const double sight_hi,     /* 1 - SIGHT_STOP */
#endif
                         const real on_face_tol_rel,   /* visibility.py: ON_FACE_TOL_REL */
                         const real inside_tol_rel,    /* visibility.py: INSIDE_TOL_REL */
                         const real confirm_tol_m,     /* visibility.py: CONFIRM_TOL_M */
                         const int n_rx,
                         const real wavelength,
                         const float sight_tmax,
                         const int first_bounce,
                         const int max_bounces,
                         const long first_block,
                         const int n_blocks,
                         __global SbrRecord *out,
                         __global volatile int *count,
                         const int capacity)
{
    int gid = get_global_id(0);
    if (gid >= n_blocks) return;
    long blk = first_block + gid;
    int w = blocks[3 * blk];
    __global const real *f = win_f + WIN_F * w;
    __global const int *wi = win_i + WIN_I * w;
    real3 axis = load3(f), u = load3(f + 3), v = load3(f + 6);
    real D = f[9], s = f[10];
    pvec tx = pv_load(tx_and_k);
#if PRECISE_MODE == 2
    pscal k_p = tx_and_k[3];
#else
    pscal k_p = pr_from_pair(tx_and_k[3]);
#endif
    real k0 = ps_real(k_p);
    /* (lambda / 4 pi) (-j k0 / 2 pi): the real factor; the -j is applied below */
    real amp = wavelength / (4.0 * M_PI) * k0 / (2.0 * M_PI);

    SbrRecord table[SBR_GROUPS];
    int n_groups = 0, ordinal = 0;
#if PRECISE_MODE == 2
    Scene64 s64;
    s64.vert = tri_v; s64.normal = tri_n; s64.tri_face = tri_face; s64.seam = seam;
    s64.face_first = face_first; s64.face_tris = face_tris; s64.face_box = face_box;
    s64.n_faces = n_faces; s64.inside_tol = inside_tol_rel;
#endif

    for (int cell = 0; cell < SBR_CELLS; ++cell) {
        long tube = blk * SBR_CELLS + cell;
        long i = (long)wi[0] + (long)blocks[3 * blk + 1] * SBR_BLOCK + cell % SBR_BLOCK;
        long j = (long)wi[1] + (long)blocks[3 * blk + 2] * SBR_BLOCK + cell / SBR_BLOCK;
        real3 vec = D * axis + ((real)i * s) * u + ((real)j * s) * v;
        real dist = sqrt(dot(vec, vec));
        real3 d = vec / dist;
        bool owned = true;   /* unless an earlier window whose cone meets this one holds d */
        for (int o = overlap_first[w]; o < overlap_first[w + 1] && owned; ++o)
            owned = !window_covers(win_f, win_i, masks, overlap_ids[o], d);
        if (!owned) continue;
        real cos_a = D / dist;
        real dom = s * s * cos_a * cos_a * cos_a / (D * D);
        real3 e1 = u - dot(d, u) * d;
        e1 /= sqrt(dot(e1, e1));
        real3 e2 = cross(d, e1);
        /* the field leaving tx per unit tx-basis excitation: (I - k k^T) b_tx */
        real3 bt, bp;
        antenna_basis(d, tx_frame, &bt, &bp);
        cvec3 f_t = cv_real(bt - dot(d, bt) * d), f_p = cv_real(bp - dot(d, bp) * d);

        pvec pos = tx, org = tx;
#if PRECISE_MODE == 2
        pscal L = 0.0;
#else
        pscal L = pr_from_float(0.0f);
#endif
        int tri_hist[SBR_TRI_SLOTS];
        for (int m = 0; m < SBR_TRI_SLOTS; ++m) tri_hist[m] = -1;

        for (int m = 1; m <= max_bounces; ++m) {
            PreparedRay pr = prepare_ray(pv_float3(org), to_float3(d));
            float t = INFINITY, hu = 0.0f, hv = 0.0f;
            int slot = bvh_closest(nodes, tri4, slot_prim, &pr, 0.0f, &t, &hu, &hv, -1);
            if (slot < 0) break;
            int tri = slot_prim[slot];
            pvec n_p = pv_load(tri_n + 3 * tri);
            real3 n = pv_real(n_p);
            real dn = dot(d, n);
            if (!(fabs(dn) > 1e-9)) break;   /* grazing: no footprint */
            pscal tt = plane_t(pv_load(tri_v + 9 * tri), pos, n_p, n, d, dn);
            if (!(ps_real(tt) > 0.0)) break;   /* on the plane it just left (a corner's edge) */
            pvec p = pv_along(pos, tt, d);
            L = ps_add(L, pv_len(pv_sub(p, pos)));
            tri_hist[m - 1] = tri;
            int mat = tri_material[tri];
            __global const real *mf = mat_f + 4 * mat;
            __global const int *mi = mat_i + 2 * mat;
            if (m >= first_bounce && tri_record[tri]) {
                real3 n_lit = (dn > 0.0) ? -n : n;   /* -sign(dn) n */
                real kn = dot(d, n_lit);
                real L_in = ps_real(L);
                real w_side = sqrt(dom) * L_in;
                real3 a1 = w_side * e1, a2 = w_side * e2;
                a1 -= d * (dot(n_lit, a1) / kn);
                a2 -= d * (dot(n_lit, a2) / kn);
                real area = w_side * w_side / fabs(kn);
                int pec = mi[0];
                cvec3 Df_t = f_t, Df_p = f_p;
                if (!pec) {
                    Reflection refl = material_reflection(d, n_lit, mf, mi, k0);
                    Df_t = reflect(&refl, f_t);
                    Df_p = reflect(&refl, f_p);
                }
                for (int r = 0; r < n_rx; ++r) {
                    pvec rx = pv_load(rx_pos + 3 * r);
                    pvec dr = pv_sub(rx, p);
                    pscal R_rp = pv_len(dr);
                    real R_r = ps_real(R_rp);
                    if (!(R_r > 0.0)) continue;
                    real3 sdir = pv_real(dr) / R_r;
                    if (!(dot(sdir, n_lit) > 0.0)) continue;
                    /* visibility.py: surface_sees - the sight line from just off the
                     * facet, stopping SIGHT_STOP short of the antenna, the facet ignored */
                    pvec sorg = spawn(p, n_lit, sdir);
                    pvec sseg = pv_sub(rx, sorg);
                    PreparedRay sr = prepare_ray(pv_float3(sorg), to_float3(pv_real(sseg)));
                    if (bvh_any(nodes, tri4, slot_prim, &sr, 0.0f, sight_tmax, tri, -1)) {
#if PRECISE_MODE == 2
                        /* visibility.py: blocked_in_float64, the facet skipped first */
                        if (blocked_in_float64(nodes, tri4, slot_prim, &s64, &sr, sight_tmax,
                                               sorg.x, sorg.y, sorg.z, sseg.x, sseg.y,
                                               sseg.z, 0.0, sight_hi, tri, rescue_rounds,
                                               look_past))
                            continue;
#else
                        continue;
#endif
                    }
                    int n_near = near_first[r + 1] - near_first[r];
                    if (n_near > 0) {
                        real3 ar = fabs(pv_real(rx));
                        real radius = 2.0 * (confirm_tol_m + 1e-6 * fmax(fmax(ar.x, ar.y), ar.z));
                        if (antenna_end_blocked(rx, sorg, radius, near_tri + near_first[r], n_near,
                                                tri_v, tri_n, on_face_tol_rel, inside_tol_rel))
                            continue;
                    }
                    real3 q = k0 * (sdir - d);
                    real i_fp = area * sinc_(0.5 * dot(q, a1)) * sinc_(0.5 * dot(q, a2));
                    real3 rt, rp;
                    antenna_basis(-sdir, rx_frame + 9 * r, &rt, &rp);
                    /* g = op f for f = f_t, f_p (PEC: k_i (n.f) - kn f, the projection
                     * I - s s^T dropped as b_rx is transverse to s; penetrable: half of
                     * po.py: penetrable_po_operator) */
                    cvec3 g[2];
                    for (int c = 0; c < 2; ++c) {
                        cvec3 fc = (c == 0) ? f_t : f_p;
                        cvec3 gc = cv_axpy(cv_dot_real(fc, n_lit), d, cv_scale_real(fc, -kn));
                        if (!pec) {
                            cvec3 Dfc = (c == 0) ? Df_t : Df_p;
                            real3 k_r = d - 2.0 * kn * n_lit;
                            /* a_r Df = k_r (n.Df) + kn Df */
                            cvec3 ar = cv_axpy(cv_dot_real(Dfc, n_lit), k_r, cv_scale_real(Dfc, kn));
                            /* [s]x[n]x (f + Df) = n (s.(f+Df)) - (f+Df)(s.n) */
                            cvec3 y = cv_add(fc, Dfc);
                            cvec3 sn = cv_axpy(cv_dot_real(y, sdir), n_lit,
                                               cv_scale_real(y, -dot(sdir, n_lit)));
                            /* P (a_i f + a_r Df): P drops against b_rx as well */
                            gc = cv_scale_real(cv_add(cv_add(gc, ar), sn), 0.5);
                        }
                        g[c] = gc;
                    }
                    pscal Ltot = ps_add(L, R_rp);
                    real ph = phase_of(k_p, Ltot);
                    /* -j e^{-j k L} = (-sin kL, -cos kL) */
                    cplx rot = (cplx)(-sin(ph), -cos(ph));
                    real mag = amp * i_fp / (L_in * R_r);
                    real M[8];
                    real wsum = 0.0;
                    for (int a = 0; a < 2; ++a)
                        for (int c = 0; c < 2; ++c) {
                            cplx val = c_scale(c_mul(rot, cv_dot_real(g[c], (a == 0) ? rt : rp)), mag);
                            M[4 * a + 2 * c] = val.x;
                            M[4 * a + 2 * c + 1] = val.y;
                            wsum += val.x * val.x + val.y * val.y;
                        }
                    real wgt = sqrt(wsum);
                    /* the group of (bounce, receiver, face sequence) */
                    int g_idx = -1;
                    for (int k = 0; k < n_groups && g_idx < 0; ++k) {
                        bool same = table[k].bounce == m && table[k].receiver == r;
                        for (int e = 0; e < m && same; ++e)
                            same = table[k].face[e] == tri_face[tri_hist[e]];
                        if (same) g_idx = k;
                    }
                    if (g_idx < 0) {
                        if (n_groups == SBR_GROUPS) {
                            emit(out, count, capacity, &table[0], &ordinal);
                            for (int k = 1; k < n_groups; ++k) table[k - 1] = table[k];
                            --n_groups;
                        }
                        g_idx = n_groups++;
                        SbrRecord *e = &table[g_idx];
                        for (int k = 0; k < 8; ++k) e->M[k] = 0.0;
                        e->weight = 0.0; e->weighted_length = 0.0; e->rep_weight = 0.0;
                        e->pad_real = 0.0; e->count = 0;
                        e->bounce = (short)m; e->receiver = (short)r; e->pad = 0;
                        e->tube = -1;
                        for (int k = 0; k < SBR_TRI_SLOTS; ++k)
                            e->face[k] = (k < m) ? tri_face[tri_hist[k]] : -1;
                    }
                    SbrRecord *e = &table[g_idx];
                    for (int k = 0; k < 8; ++k) e->M[k] += M[k];
                    e->weight += wgt;
                    e->weighted_length += wgt * ps_real(Ltot);
                    e->count += 1;
                    if (e->tube < 0 || wgt > e->rep_weight) {
                        e->rep_weight = wgt;
                        e->tube = tube;
                        e->length = ps_out(Ltot);
                        e->point[0] = ps_out(p.x); e->point[1] = ps_out(p.y);
                        e->point[2] = ps_out(p.z);
                        for (int k = 0; k < SBR_TRI_SLOTS; ++k) e->tri[k] = tri_hist[k];
                    }
                }
            }
            if (m == max_bounces) break;
            /* one reflection's coefficients and basis for both polarisations */
            Reflection refl = material_reflection(d, n, mf, mi, k0);
            f_t = reflect(&refl, f_t);
            f_p = reflect(&refl, f_p);
            d = d - 2.0 * dn * n;
            e1 = e1 - 2.0 * dot(e1, n) * n;
            e2 = e2 - 2.0 * dot(e2, n) * n;
            pos = p;
            org = spawn(p, n, d);
        }
    }
    for (int k = 0; k < n_groups; ++k) emit(out, count, capacity, &table[k], &ordinal);
}
