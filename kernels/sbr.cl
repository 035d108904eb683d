/* SBR-PO on the device as a wavefront: one small kernel per stage, one work item per
 * tube, footprint or (footprint, receiver), queues compacted between bounces, the
 * footprints' contributions reduced per work group. clradcom/device/sbr.py drives it, a
 * batch of covered launch blocks (clradcom/mechanisms/sbr.py: TubeWindows) at a time:
 *
 *   sbr_launch      one item per cell of the batch's blocks: the tube's direction, its
 *                   ownership against earlier windows, its initial state into the queue;
 *   sbr_bounce      per bounce m, one item per live tube: the closest hit in float32
 *                   over the BVH, the exact hit point on the triangle's plane and the
 *                   unfolded length in `preal` (double, or precise.h's double-float
 *                   without fp64), a footprint where m >= first_bounce on a recorded
 *                   triangle, the mirrored tube into the next queue;
 *   sbr_illuminate  one item per footprint: the tube's cross-section and the fields of
 *                   both tx polarisations at it, replayed from the launch through its
 *                   reflections (the queues carry only what the next hit needs);
 *                   a persistent build (SBR_PERSISTENT, scalar CPU devices) has
 *                   sbr_bounces in place of sbr_launch and sbr_bounce (one item per
 *                   launch block, its tubes cast in packets; the last bounce cast only
 *                   where the ray meets a recorded triangle in their own tree), and
 *                   sbr_radiate, one item per footprint, replays the
 *                   illumination itself where the footprint sees a receiver;
 *   sbr_radiate     per (footprint, receiver): the sight line (float32 any-hit,
 *                   re-decided in float64 where the device has it), the antenna's near
 *                   triangles, the 2x2 polarimetric matrix in the antennas' bases, into
 *                   the slot of its (block, receiver, cell);
 *   sbr_reduce      one work group of SBR_CELLS items per (block, receiver) with any
 *                   contribution at bounce m: the cells with the same face sequence
 *                   summed in cell (tube) order by the first of them, the representative
 *                   the first of the largest |M|_F, one SbrRecord each.
 *
 * The formulas are the host reference's (clradcom/mechanisms/sbr.py: shoot_tubes,
 * _chains, _radiate, _sum_blocks, and clradcom/physics/em.py: polarimetric_matrix),
 * step for step; the records' sums are the host's groups exactly. */
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
#if PRECISE_MODE >= 1
/* sight lines re-decided in float64 (double, or double-float without fp64) where
 * float32 calls them blocked; the float32 control build keeps float32's word */
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

/* component by component, as convert_float3 rounds them: the conversion of the vector
 * reads its padding lane, which Oclgrind's uninitialised-value check reports */
inline float3 to_float3(real3 a) { return (float3)((float)a.x, (float)a.y, (float)a.z); }

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
    return to_float3(a);
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
    long ci = (long)floor(x / s) - wi[0];
    long cj = (long)floor(y / s) - wi[1];
    long bi = (ci >= 0) ? ci / SBR_BLOCK : -((-ci + SBR_BLOCK - 1) / SBR_BLOCK);
    long bj = (cj >= 0) ? cj / SBR_BLOCK : -((-cj + SBR_BLOCK - 1) / SBR_BLOCK);
    if (bi < 0 || bi >= wi[2] || bj < 0 || bj >= wi[3]) return false;
    return masks[wi[4] + bi * wi[3] + bj] != 0;
}


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
    int ordinal;             /* the group's first (cell, bounce, receiver) within the block */
    int count;               /* tubes summed */
    short bounce;
    short receiver;
    int pad;
    int face[SBR_TRI_SLOTS]; /* the planar faces hit, -1 after the bounce */
    int tri[SBR_TRI_SLOTS];  /* the representative's triangles */
} SbrRecord;

/* a tube's triangle history, padded so that the ints after the 8-byte fields pair up */
#define SBR_TUBE_TRIS (SBR_TRI_SLOTS + ((SBR_TRI_SLOTS + 1) & 1))

/* A live tube between two bounces (the queues): what its next closest hit needs. Its
 * cross-section and fields are not carried: sbr_illuminate replays them, where a
 * footprint needs them, from its launch through the triangles it hit. */
typedef struct {
    pout pos[3];             /* its last bounce point (tx at launch) */
    pout org[3];             /* where its next ray starts: pos, spawned off the face */
    pout length;             /* unfolded length tx -> pos */
    real dir[3];             /* unit direction */
    int tube;                /* within the batch: block * SBR_CELLS + cell */
    int tri[SBR_TUBE_TRIS];  /* the triangles hit so far, -1 after */
} SbrTube;

/* A bounce on a recorded triangle at or after first_bounce. */
typedef struct {
    pout point[3];           /* the exact hit on the triangle's plane */
    pout length;             /* unfolded length tx -> point */
    int tube;                /* within the batch */
    int tri[SBR_TUBE_TRIS];  /* the triangles hit, this one last */
} SbrFootprint;

/* What a footprint radiates from, whatever the receiver (sbr_illuminate). */
typedef struct {
    real dir[3];             /* the incident direction k_i */
    real normal[3];          /* the lit side's unit normal n */
    real edge1[3], edge2[3]; /* the tube's cross-section edges projected on the facet */
    real area;               /* the footprint's area */
    real field[24];          /* per tx polarisation the incident field f and, on a
                                penetrable facet only, its reflection D f: f_t, f_p,
                                Df_t, Df_p, x, y, z (re, im) each */
} SbrIllumination;

/* One footprint's radiation toward one receiver (slot (block, receiver, cell) of a
 * bounce; contribution_footprint says which footprint wrote it, -1: none). */
typedef struct {
    pout length;             /* unfolded length tx -> footprint -> rx */
    real M[8];               /* 2x2 complex polarimetric matrix, (re, im) pairs */
    real weight;             /* |M|_F */
    real pad_real;
} SbrContribution;

/* sizeof(SbrRecord) as this build lays it out, for the host's numpy twin's test */
__kernel void sbr_record_size(__global int *out)
{
    out[0] = (int)sizeof(SbrRecord);
}

/* the sizes of the stages' entries, for the host's buffers */
__kernel void sbr_struct_sizes(__global int *out)
{
    out[0] = (int)sizeof(SbrRecord);
    out[1] = (int)sizeof(SbrTube);
    out[2] = (int)sizeof(SbrFootprint);
    out[3] = (int)sizeof(SbrIllumination);
    out[4] = (int)sizeof(SbrContribution);
}

inline void store3(__global real *p, real3 a) { p[0] = a.x; p[1] = a.y; p[2] = a.z; }

inline void pv_store(__global pout *p, pvec a)
{
    p[0] = ps_out(a.x); p[1] = ps_out(a.y); p[2] = ps_out(a.z);
}

inline pscal ps_load(pout a)
{
#if PRECISE_MODE == 2
    return a;
#else
    return pr_from_pair(a);
#endif
}

inline cvec3 cv_load(__global const real *p)
{
    cvec3 r = {(cplx)(p[0], p[1]), (cplx)(p[2], p[3]), (cplx)(p[4], p[5])};
    return r;
}

inline void cv_store(__global real *p, cvec3 a)
{
    p[0] = a.x.x; p[1] = a.x.y; p[2] = a.y.x; p[3] = a.y.y; p[4] = a.z.x; p[5] = a.z.y;
}

inline pscal ps_zero(void)
{
#if PRECISE_MODE == 2
    return 0.0;
#else
    return pr_from_float(0.0f);
#endif
}

inline pscal wavenumber_of(__global const pelem *tx_and_k)
{
#if PRECISE_MODE == 2
    return tx_and_k[3];
#else
    return pr_from_pair(tx_and_k[3]);
#endif
}

/* x / d, and the rest x - (x / d) d in *rest: never x % d beside x / d, which a compiler
 * pairs through an instruction (freeze) that Oclgrind's uninitialised-value check
 * cannot follow */
inline int quotient(int x, int d, int *rest)
{
    int q = x / d;
    *rest = x - q * d;
    return q;
}

/* The tube through cell `cell` of covered block `blk` (sbr.py: window_tubes): its
 * window, unit direction, the cell's solid angle and its first edge. */
typedef struct {
    int window;
    real3 dir;
    real solid_angle;
    real3 edge1;
} CellTube;

inline CellTube cell_tube(__global const real *win_f, __global const int *win_i,
                          __global const int *blocks, long blk, int cell)
{
    CellTube c;
    c.window = blocks[3 * blk];
    __global const real *f = win_f + WIN_F * c.window;
    __global const int *wi = win_i + WIN_I * c.window;
    real3 axis = load3(f), u = load3(f + 3), v = load3(f + 6);
    real D = f[9], s = f[10];
    int cx, cy = quotient(cell, SBR_BLOCK, &cx);
    long i = (long)wi[0] + (long)blocks[3 * blk + 1] * SBR_BLOCK + cx;
    long j = (long)wi[1] + (long)blocks[3 * blk + 2] * SBR_BLOCK + cy;
    /* cell (i, j) centred on ((i + 1/2) s, (j + 1/2) s): sbr.py TubeWindows */
    real3 vec = D * axis + (((real)i + 0.5) * s) * u + (((real)j + 0.5) * s) * v;
    real dist = sqrt(dot(vec, vec));
    c.dir = vec / dist;
    real cos_a = D / dist;
    c.solid_angle = s * s * cos_a * cos_a * cos_a / (D * D);
    real3 e1 = u - dot(c.dir, u) * c.dir;
    c.edge1 = e1 / sqrt(dot(e1, e1));
    return c;
}

/* The per-item kernels below run their items past the count (the rest of the last work
 * group) as copies of the last real one and drop them only before their first write:
 * Intel's CPU compiler rounds the items of a SIMD vector that diverges at the kernel's
 * entry otherwise than the rest (the last footprints of a launch came out a bit apart),
 * which would make a result depend on where a compaction put its item. */

/* One work item per cell of the batch's blocks (n_cells = blocks * SBR_CELLS): the
 * tube through the cell, unless an earlier window owns its direction, into the queue. */
__kernel void sbr_launch(__global const real *win_f,
                         __global const int *win_i,
                         __global const uchar *masks,
                         __global const int *blocks,        /* per covered block: window, i, j */
                         __global const int *overlap_first, /* W+1: window w's earlier overlaps */
                         __global const int *overlap_ids,
                         __global const pelem *tx_and_k,    /* tx position (3), wavenumber */
                         const long first_block,
                         const int n_cells,
                         __global SbrTube *queue,
                         __global volatile int *n_queued)
{
    int gid = get_global_id(0);
    int item = min(gid, n_cells - 1);   /* past the count: a copy of the last */
    int cell, blk = quotient(item, SBR_CELLS, &cell);
    CellTube c = cell_tube(win_f, win_i, blocks, first_block + blk, cell);
    /* owned unless an earlier window whose cone meets this one holds the direction */
    bool owned = true;
    for (int o = overlap_first[c.window]; o < overlap_first[c.window + 1] && owned; ++o)
        owned = !window_covers(win_f, win_i, masks, overlap_ids[o], c.dir);
    if (gid >= n_cells || !owned) return;
    __global SbrTube *t = queue + atomic_inc(n_queued);
    pvec tx = pv_load(tx_and_k);
    pv_store(t->pos, tx);
    pv_store(t->org, tx);
    t->length = ps_out(ps_zero());
    store3(t->dir, c.dir);
    t->tube = gid;
    for (int k = 0; k < SBR_TUBE_TRIS; ++k) t->tri[k] = -1;
}

/* A tube's step past the closest hit `slot` (a leaf slot, -1: none) of its ray from org
 * along d, with the unfolded length L so far at pos: the hit triangle, the exact point on
 * its plane, the length there, the mirrored direction and the next ray's origin. False
 * where the tube ends: it misses, grazes or hits the plane it just left (a corner's
 * edge). */
inline bool tube_follow(int slot, __global const int *slot_prim, __global const pelem *tri_v,
                        __global const pelem *tri_n, real3 d, pvec pos, pscal L, int *tri_hit,
                        pvec *p_hit, pscal *L_hit, real3 *d_out, pvec *org_out)
{
    if (slot < 0) return false;
    int tri = slot_prim[slot];
    pvec n_p = pv_load(tri_n + 3 * tri);
    real3 n = pv_real(n_p);
    real dn = dot(d, n);
    if (!(fabs(dn) > 1e-9)) return false;   /* grazing: no footprint */
    pscal tt = plane_t(pv_load(tri_v + 9 * tri), pos, n_p, n, d, dn);
    if (!(ps_real(tt) > 0.0)) return false;
    pvec p = pv_along(pos, tt, d);
    *tri_hit = tri;
    *p_hit = p;
    *L_hit = ps_add(L, pv_len(pv_sub(p, pos)));
    *d_out = d - 2.0 * dn * n;
    *org_out = spawn(p, n, *d_out);
    return true;
}

/* A tube's next hit (tube_follow) from its own closest-hit cast. */
inline bool tube_next_hit(__global const Bvh8Node *nodes, __global const float4 *tri4,
                          __global const int *slot_prim, __global const pelem *tri_v,
                          __global const pelem *tri_n, real3 d, pvec pos, pvec org,
                          pscal L, int *tri_hit, pvec *p_hit, pscal *L_hit, real3 *d_out,
                          pvec *org_out)
{
    PreparedRay pr = prepare_ray(pv_float3(org), to_float3(d));
    float tmax = INFINITY, hu = 0.0f, hv = 0.0f;
    int slot = bvh_closest(nodes, tri4, slot_prim, &pr, 0.0f, &tmax, &hu, &hv, -1);
    return tube_follow(slot, slot_prim, tri_v, tri_n, d, pos, L, tri_hit, p_hit, L_hit, d_out,
                       org_out);
}

/* Bounce m of every queued tube, one work item each: its next hit; a footprint where m >=
 * first_bounce on a recorded triangle; unless m is the last bounce, the tube mirrored
 * into the next queue. The wavefront's bounce: tubes that end leave the queue, so the
 * work items of a SIMD vector or warp stay busy. */
__kernel void sbr_bounce(__global const Bvh8Node *nodes,
                         __global const float4 *tri4,
                         __global const int *slot_prim,
                         __global const pelem *tri_v,       /* T*9 */
                         __global const pelem *tri_n,       /* T*3, unit */
                         __global const uchar *tri_record,
                         const int bounce,
                         const int first_bounce,
                         const int max_bounces,
                         __global const SbrTube *queue,
                         const int n_tubes,
                         __global SbrTube *next_queue,
                         __global SbrFootprint *footprints,
                         __global volatile int *counts)     /* next tubes, footprints */
{
    int gid = get_global_id(0);
    /* past the count: a copy of the last */
    __global const SbrTube *t = queue + min(gid, n_tubes - 1);
    real3 d = load3(t->dir), d_out;
    pvec p, org;
    pscal L;
    int tri;
    if (!tube_next_hit(nodes, tri4, slot_prim, tri_v, tri_n, d, pv_load(t->pos),
                       pv_load(t->org), ps_load(t->length), &tri, &p, &L, &d_out, &org))
        return;
    if (gid >= n_tubes) return;
    if (bounce >= first_bounce && tri_record[tri]) {
        __global SbrFootprint *fp = footprints + atomic_inc(counts + 1);
        pv_store(fp->point, p);
        fp->length = ps_out(L);
        fp->tube = t->tube;
        for (int k = 0; k < SBR_TUBE_TRIS; ++k)
            fp->tri[k] = (k == bounce - 1) ? tri : t->tri[k];
    }
    if (bounce == max_bounces) return;
    __global SbrTube *o = next_queue + atomic_inc(counts);
    pv_store(o->pos, p);
    pv_store(o->org, org);
    o->length = ps_out(L);
    store3(o->dir, d_out);
    o->tube = t->tube;
    for (int k = 0; k < SBR_TUBE_TRIS; ++k) o->tri[k] = (k == bounce - 1) ? tri : t->tri[k];
}

/* Built only where it runs (SBR_PERSISTENT, clradcom/device/sbr.py): with it in the
 * program, Intel's CPU compiler gave NaN points in sbr_bounce's records without fp64 and
 * crashed the process with fp64 (tests/test_no_fp64.py, tests/test_sbr_engines.py). */
#ifdef SBR_PERSISTENT
/* The tubes of the batch's blocks from their launch through all their bounces, one work
 * item per launch block, its SBR_CELLS tubes in private memory (no queue): per bounce the
 * live tubes cast as packets, those that left the same planar faces (one image source)
 * together, all of them at launch, each packet walking the tree once (intersect.h:
 * packet_closest, whose hits are bvh_closest's, ray for ray); then each tube as
 * sbr_bounce steps it. Bounce m's
 * footprints go into region m - 1 of `footprints` (`region` footprints each), counted in
 * counts[m - 1]; a footprint's tube is block * SBR_CELLS + cell within the batch, as
 * sbr_launch numbers it. For devices that run a work item as scalar code (PoCL's CPU
 * device), where a tube that is not owned or ends early costs nothing and a queue only
 * costs launches and memory traffic. */
__kernel void sbr_bounces(__global const Bvh8Node *nodes,
                          __global const float4 *tri4,
                          __global const int *slot_prim,
                          __global const pelem *tri_v,       /* T*9 */
                          __global const pelem *tri_n,       /* T*3, unit */
                          __global const uchar *tri_record,
                          __global const int *tri_face,      /* the packets' key */
                          __global const real *win_f,        /* sbr_launch's windows */
                          __global const int *win_i,
                          __global const uchar *masks,
                          __global const int *blocks,
                          __global const int *overlap_first,
                          __global const int *overlap_ids,
                          __global const pelem *tx_and_k,
                          const long first_block,
                          const int n_blocks,
                          const int first_bounce,
                          const int max_bounces,
                          __global SbrFootprint *footprints,
                          const int region,
                          __global volatile int *counts,     /* per bounce: footprints */
                          /* the recorded triangles' own tree, in the layout of the
                           * scene's (a single-level tree); last_filter 0: none */
                          __global const Bvh8Node *rec_nodes,
                          __global const float4 *rec_tri4,
                          __global const int *rec_slot_prim,
                          const int last_filter)
{
    int gid = get_global_id(0);
    int item = min(gid, n_blocks - 1);   /* past the count: a copy of the last */
    pvec pos[SBR_CELLS], org[SBR_CELLS];
    pscal len[SBR_CELLS];
    real3 dir[SBR_CELLS];
    int tris[SBR_CELLS][SBR_TUBE_TRIS];
    int live[SBR_CELLS], key[SBR_CELLS], slot[SBR_CELLS];
    uint faces_left[SBR_CELLS];
    PreparedRay pr[SBR_CELLS];
    float tmin[SBR_CELLS], tmax[SBR_CELLS], hu[SBR_CELLS], hv[SBR_CELLS];
    int n_live = 0;
    pvec tx = pv_load(tx_and_k);
    for (int cell = 0; cell < SBR_CELLS; ++cell) {
        CellTube c = cell_tube(win_f, win_i, blocks, first_block + item, cell);
        /* owned unless an earlier window whose cone meets this one holds the direction */
        bool owned = true;
        for (int o = overlap_first[c.window]; o < overlap_first[c.window + 1] && owned; ++o)
            owned = !window_covers(win_f, win_i, masks, overlap_ids[o], c.dir);
        if (!owned) continue;
        /* sbr_launch's tube: from tx along the cell's direction */
        pos[cell] = tx;
        org[cell] = tx;
        len[cell] = ps_zero();
        dir[cell] = c.dir;
        faces_left[cell] = 0u;
        for (int k = 0; k < SBR_TUBE_TRIS; ++k) tris[cell][k] = -1;
        live[n_live++] = cell;
    }
    for (int m = 1; m <= max_bounces && n_live > 0; ++m) {
        /* The last bounce leaves nothing but a footprint on a recorded triangle. Where
         * the ray meets none of them (any hit over their own tree) the scene's closest
         * hit is not one: the same ray and triangle test find every hit in either tree
         * (the boxes never cull one: intersect.h), so the full cast is skipped without
         * changing a footprint. */
        bool filter = m == max_bounces && last_filter && m >= first_bounce;
        int n = 0;
        for (int k = 0; k < n_live; ++k) {
            int c = live[k];
            pr[c] = prepare_ray(pv_float3(org[c]), to_float3(dir[c]));
            if (filter && !blas_any(rec_nodes, rec_tri4, rec_slot_prim, &pr[c], 0, 0.0f,
                                    INFINITY, -1, -1))
                continue;
            tmin[c] = 0.0f;
            tmax[c] = INFINITY;
            live[n] = c;
            key[n] = (int)faces_left[c];
            ++n;
        }
        /* the tubes that left the same faces side by side (insertion sort: at most
         * SBR_CELLS), each run a packet */
        for (int k = 1; k < n; ++k) {
            int c = live[k], kk = key[k], j = k;
            for (; j > 0 && key[j - 1] > kk; --j) {
                live[j] = live[j - 1];
                key[j] = key[j - 1];
            }
            live[j] = c;
            key[j] = kk;
        }
        for (int s = 0; s < n;) {
            int e = s + 1;
            while (e < n && key[e] == key[s]) ++e;
            packet_closest(nodes, tri4, slot_prim, pr, live + s, e - s, tmin, tmax, hu, hv,
                           slot);
            s = e;
        }
        int n_next = 0;
        for (int k = 0; k < n; ++k) {
            int c = live[k], tri;
            pvec p, o;
            pscal L;
            real3 d_out;
            if (!tube_follow(slot[c], slot_prim, tri_v, tri_n, dir[c], pos[c], len[c], &tri,
                             &p, &L, &d_out, &o))
                continue;
            tris[c][m - 1] = tri;
            /* the faces it left so far, hashed: tubes of one image source stay together */
            faces_left[c] = (faces_left[c] ^ (uint)tri_face[tri]) * 0x9E3779B1u;
            if (gid < n_blocks && m >= first_bounce && tri_record[tri]) {
                __global SbrFootprint *fp =
                    footprints + (size_t)(m - 1) * region + atomic_inc(counts + m - 1);
                pv_store(fp->point, p);
                fp->length = ps_out(L);
                fp->tube = item * SBR_CELLS + c;
                for (int j = 0; j < SBR_TUBE_TRIS; ++j) fp->tri[j] = tris[c][j];
            }
            pos[c] = p;
            org[c] = o;
            len[c] = L;
            dir[c] = d_out;
            live[n_next++] = c;
        }
        n_live = n_next;
    }
}
#endif

/* What a footprint radiates from (an SbrIllumination, in private memory). */
typedef struct {
    real3 dir, normal, edge1, edge2;
    real area;
    cvec3 f[2];    /* the incident field per tx polarisation */
    cvec3 Df[2];   /* ... and its reflection D f, on a penetrable facet only */
} Lit;

/* The incident direction at footprint fp of bounce m: the tube's launch direction
 * mirrored in its m - 1 earlier triangles (footprint_lit's steps on d alone). */
inline real3 footprint_direction(__global const SbrFootprint *fp, int bounce,
                                 __global const pelem *tri_n, __global const real *win_f,
                                 __global const int *win_i, __global const int *blocks,
                                 long first_block)
{
    int cell, blk = quotient(fp->tube, SBR_CELLS, &cell);
    real3 d = cell_tube(win_f, win_i, blocks, first_block + blk, cell).dir;
    for (int m = 1; m < bounce; ++m) {
        real3 n = pv_real(pv_load(tri_n + 3 * fp->tri[m - 1]));
        d = d - 2.0 * dot(d, n) * n;
    }
    return d;
}

/* The lit side's unit normal of the footprint's triangle for incident direction d. */
inline real3 lit_normal(__global const SbrFootprint *fp, int bounce,
                        __global const pelem *tri_n, real3 d)
{
    real3 n = pv_real(pv_load(tri_n + 3 * fp->tri[bounce - 1]));
    return (dot(d, n) > 0.0) ? -n : n;   /* -sign(dn) n */
}

/* Footprint fp of bounce m: the tube's cross-section and the fields of both tx
 * polarisations at it, replayed from its launch through its m - 1 reflections (the
 * operations sbr_bounce did on its direction), the cross-section's edges projected on
 * the facet and, on a penetrable facet, the fields it reflects. */
inline Lit footprint_lit(__global const SbrFootprint *fp, int bounce,
                         __global const pelem *tri_n, __global const int *tri_material,
                         __global const real *mat_f, __global const int *mat_i,
                         __global const real *win_f, __global const int *win_i,
                         __global const int *blocks, __global const real *tx_frame,
                         __global const pelem *tx_and_k, long first_block)
{
    int cell, blk = quotient(fp->tube, SBR_CELLS, &cell);
    CellTube c = cell_tube(win_f, win_i, blocks, first_block + blk, cell);
    real k0 = ps_real(wavenumber_of(tx_and_k));
    real3 d = c.dir, e1 = c.edge1, e2 = cross(c.dir, c.edge1);
    /* the field leaving tx per unit tx-basis excitation: (I - k k^T) b_tx */
    real3 bt, bp;
    antenna_basis(d, tx_frame, &bt, &bp);
    cvec3 f_t = cv_real(bt - dot(d, bt) * d), f_p = cv_real(bp - dot(d, bp) * d);
    for (int m = 1; m < bounce; ++m) {
        int tri = fp->tri[m - 1];
        real3 n = pv_real(pv_load(tri_n + 3 * tri));
        int mat = tri_material[tri];
        /* one reflection's coefficients and basis for both polarisations */
        Reflection refl = material_reflection(d, n, mat_f + 4 * mat, mat_i + 2 * mat, k0);
        f_t = reflect(&refl, f_t);
        f_p = reflect(&refl, f_p);
        d = d - 2.0 * dot(d, n) * n;
        e1 = e1 - 2.0 * dot(e1, n) * n;
        e2 = e2 - 2.0 * dot(e2, n) * n;
    }
    int tri = fp->tri[bounce - 1];
    real3 n_lit = lit_normal(fp, bounce, tri_n, d);
    real kn = dot(d, n_lit);
    real w_side = sqrt(c.solid_angle) * ps_real(ps_load(fp->length));
    real3 a1 = w_side * e1, a2 = w_side * e2;
    a1 -= d * (dot(n_lit, a1) / kn);
    a2 -= d * (dot(n_lit, a2) / kn);
    Lit out;
    out.dir = d;
    out.normal = n_lit;
    out.edge1 = a1;
    out.edge2 = a2;
    out.area = w_side * w_side / fabs(kn);
    out.f[0] = f_t;
    out.f[1] = f_p;
    int mat = tri_material[tri];
    if (mat_i[2 * mat]) {   /* PEC: sbr_radiate needs no reflected field */
        out.Df[0] = out.Df[1] = cv_real((real3)(0.0));
        return out;
    }
    Reflection refl = material_reflection(d, n_lit, mat_f + 4 * mat, mat_i + 2 * mat, k0);
    out.Df[0] = reflect(&refl, f_t);
    out.Df[1] = reflect(&refl, f_p);
    return out;
}

/* One work item per footprint of bounce m: footprint_lit into `lit` (the wavefront; a
 * persistent build's sbr_radiate computes it itself, for the footprints that see a
 * receiver). */
__kernel void sbr_illuminate(__global const pelem *tri_n,       /* T*3, unit */
                             __global const int *tri_material,
                             /* per material: eps re, im, sigma_h, specular share; pec,
                              * roughness model */
                             __global const real *mat_f,
                             __global const int *mat_i,
                             __global const real *win_f,
                             __global const int *win_i,
                             __global const int *blocks,
                             __global const real *tx_frame,     /* 9 */
                             __global const pelem *tx_and_k,
                             const long first_block,
                             const int bounce,
                             __global const SbrFootprint *footprints,
                             const int n_footprints,
                             __global SbrIllumination *lit)
{
    int gid = get_global_id(0);
    /* past the count: a copy of the last */
    __global const SbrFootprint *fp = footprints + min(gid, n_footprints - 1);
    Lit x = footprint_lit(fp, bounce, tri_n, tri_material, mat_f, mat_i, win_f, win_i,
                          blocks, tx_frame, tx_and_k, first_block);
    if (gid >= n_footprints) return;
    __global SbrIllumination *out = lit + gid;
    store3(out->dir, x.dir);
    store3(out->normal, x.normal);
    store3(out->edge1, x.edge1);
    store3(out->edge2, x.edge2);
    out->area = x.area;
    cv_store(out->field, x.f[0]);
    cv_store(out->field + 6, x.f[1]);
    if (mat_i[2 * tri_material[fp->tri[bounce - 1]]]) return;   /* PEC */
    cv_store(out->field + 12, x.Df[0]);
    cv_store(out->field + 18, x.Df[1]);
}

/* An SbrIllumination back in private memory; the reflected fields only where `pec` is
 * false (sbr_illuminate writes them only there). */
inline Lit lit_load(__global const SbrIllumination *il, bool pec)
{
    Lit x;
    x.dir = load3(il->dir);
    x.normal = load3(il->normal);
    x.edge1 = load3(il->edge1);
    x.edge2 = load3(il->edge2);
    x.area = il->area;
    x.f[0] = cv_load(il->field);
    x.f[1] = cv_load(il->field + 6);
    if (pec) {
        x.Df[0] = x.Df[1] = cv_real((real3)(0.0));
    } else {
        x.Df[0] = cv_load(il->field + 12);
        x.Df[1] = cv_load(il->field + 18);
    }
    return x;
}

/* The footprints' PO radiation toward each receiver that sees them, as a polarimetric
 * matrix in the antennas' bases, into slot (block, receiver, cell) of this bounce, the
 * (block, receiver) listed for the reduction with its first contribution. The wavefront
 * build: one work item per (footprint, receiver), receiver-major (neighbouring items
 * trace sight lines toward the same antenna). A persistent build: one work item per
 * footprint, its receivers in turn, so that the illumination replayed from the launch
 * (footprint_lit, most of the kernel's arithmetic) is computed once per footprint, at
 * the first receiver that sees it, not once per receiver; each (footprint, receiver)
 * does the same operations either way. */
__kernel void sbr_radiate(__global const Bvh8Node *nodes,
                          __global const float4 *tri4,
                          __global const int *slot_prim,
                          __global const pelem *tri_v,       /* T*9 */
                          __global const pelem *tri_n,       /* T*3, unit */
                          __global const int *tri_material,
                          __global const int *mat_i,
                          __global const pelem *rx_pos,      /* R*3 */
                          __global const real *rx_frame,     /* R*9, row-major */
                          __global const pelem *tx_and_k,    /* tx position (3), wavenumber */
                          __global const int *near_first,    /* R+1: receiver r's near triangles */
                          __global const int *near_tri,
#if PRECISE_MODE >= 1
                          /* scene64.h's face tables (tri_v, tri_n, tri_face are its
                           * vertices, normals and faces), for the float64 sight rounds */
                          __global const int *tri_face,
                          __global const uchar *seam,
                          __global const int *face_first,
                          __global const int *face_tris,
                          __global const pr_elem *face_box,
                          const int n_faces,
                          const int rescue_rounds,
                          const pr_elem look_past,
                          const pr_elem sight_hi,    /* 1 - SIGHT_STOP */
#endif
                          const real on_face_tol_rel,   /* visibility.py: ON_FACE_TOL_REL */
                          const real inside_tol_rel,    /* visibility.py: INSIDE_TOL_REL */
                          const real confirm_tol_m,     /* visibility.py: CONFIRM_TOL_M */
                          const int n_rx,
                          const real wavelength,
                          const float sight_tmax,
                          const int bounce,
                          __global const SbrFootprint *footprints,
#ifdef SBR_PERSISTENT
                          /* sbr_illuminate's inputs: the illumination computed here */
                          __global const real *mat_f,
                          __global const real *win_f,
                          __global const int *win_i,
                          __global const int *blocks,
                          __global const real *tx_frame,
                          const long first_block,
#else
                          __global const SbrIllumination *lit,
#endif
                          const int n_footprints,
                          __global SbrContribution *contributions,
                          __global int *contribution_footprint,
                          __global volatile int *group_tubes,   /* per (block, receiver) */
                          __global int *live_groups,
                          __global volatile int *n_live_groups)
{
    int gid = get_global_id(0);
    /* past the count: a copy of the last, dropped before its first write */
#ifdef SBR_PERSISTENT
    int fi = min(gid, n_footprints - 1), r_first = 0, r_end = n_rx;
    bool past = gid >= n_footprints;
#else
    int fi, r_first = quotient(min(gid, n_footprints * n_rx - 1), n_footprints, &fi);
    int r_end = r_first + 1;
    bool past = gid >= n_footprints * n_rx;
#endif
    __global const SbrFootprint *fp = footprints + fi;
    int tri = fp->tri[bounce - 1];
    pvec p = pv_load(fp->point);
#ifdef SBR_PERSISTENT
    /* the lit side from the direction alone: the fields only for a footprint that sees rx */
    real3 n_lit = lit_normal(fp, bounce, tri_n,
                             footprint_direction(fp, bounce, tri_n, win_f, win_i, blocks,
                                                 first_block));
#else
    real3 n_lit = load3(lit[fi].normal);
#endif
    pscal k_p = wavenumber_of(tx_and_k);
    real k0 = ps_real(k_p);
    /* (lambda / 4 pi) (-j k0 / 2 pi): the real factor; the -j is applied below */
    real amp = wavelength / (4.0 * M_PI) * k0 / (2.0 * M_PI);
    int pec = mat_i[2 * tri_material[tri]];
    pscal L = ps_load(fp->length);
    real L_in = ps_real(L);
    Lit il;
    bool have_lit = false;
    for (int r = r_first; r < r_end; ++r) {
        pvec rx = pv_load(rx_pos + 3 * r);
        pvec dr = pv_sub(rx, p);
        pscal R_rp = pv_len(dr);
        real R_r = ps_real(R_rp);
        if (!(R_r > 0.0)) continue;
        real3 sdir = pv_real(dr) / R_r;
        if (!(dot(sdir, n_lit) > 0.0)) continue;
        /* visibility.py: surface_sees - the sight line from just off the facet, stopping
         * SIGHT_STOP short of the antenna, the facet ignored */
        pvec sorg = spawn(p, n_lit, sdir);
        pvec sseg = pv_sub(rx, sorg);
        PreparedRay sr = prepare_ray(pv_float3(sorg), to_float3(pv_real(sseg)));
        if (bvh_any(nodes, tri4, slot_prim, &sr, 0.0f, sight_tmax, tri, -1)) {
#if PRECISE_MODE >= 1
            /* visibility.py: blocked_in_float64, the facet skipped first */
            Scene64 s64;
            s64.vert = tri_v; s64.normal = tri_n; s64.tri_face = tri_face; s64.seam = seam;
            s64.face_first = face_first; s64.face_tris = face_tris; s64.face_box = face_box;
            s64.n_faces = n_faces; s64.inside_tol = pr_from_float(inside_tol_rel);
            if (blocked_in_float64(nodes, tri4, slot_prim, &s64, &sr, sight_tmax,
                                   sorg.x, sorg.y, sorg.z, sseg.x, sseg.y, sseg.z,
                                   PR_CONST(0.0), pr_of(sight_hi), tri, rescue_rounds,
                                   pr_of(look_past)))
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

        if (!have_lit) {
#ifdef SBR_PERSISTENT
            il = footprint_lit(fp, bounce, tri_n, tri_material, mat_f, mat_i, win_f, win_i,
                               blocks, tx_frame, tx_and_k, first_block);
#else
            il = lit_load(lit + fi, pec);
#endif
            have_lit = true;
        }
        real3 d = il.dir;
        real kn = dot(d, n_lit);
        real3 q = k0 * (sdir - d);
        real i_fp = il.area * sinc_(0.5 * dot(q, il.edge1)) * sinc_(0.5 * dot(q, il.edge2));
        real3 rt, rp;
        antenna_basis(-sdir, rx_frame + 9 * r, &rt, &rp);
        /* g = op f for f = f_t, f_p (PEC: k_i (n.f) - kn f, the projection I - s s^T
         * dropped as b_rx is transverse to s; penetrable: half of po.py:
         * penetrable_po_operator) */
        cvec3 g[2];
        for (int c = 0; c < 2; ++c) {
            cvec3 fc = il.f[c];
            cvec3 gc = cv_axpy(cv_dot_real(fc, n_lit), d, cv_scale_real(fc, -kn));
            if (!pec) {
                cvec3 Dfc = il.Df[c];
                real3 k_r = d - 2.0 * kn * n_lit;
                /* a_r Df = k_r (n.Df) + kn Df */
                cvec3 ar = cv_axpy(cv_dot_real(Dfc, n_lit), k_r, cv_scale_real(Dfc, kn));
                /* [s]x[n]x (f + Df) = n (s.(f+Df)) - (f+Df)(s.n) */
                cvec3 y = cv_add(fc, Dfc);
                cvec3 sn = cv_axpy(cv_dot_real(y, sdir), n_lit, cv_scale_real(y, -dot(sdir, n_lit)));
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
        if (past) continue;
        int cell, group = quotient(fp->tube, SBR_CELLS, &cell) * n_rx + r;
        int slot = group * SBR_CELLS + cell;
        __global SbrContribution *out = contributions + slot;
        for (int k = 0; k < 8; ++k) out->M[k] = M[k];
        out->weight = sqrt(wsum);
        out->length = ps_out(Ltot);
        out->pad_real = 0.0;
        contribution_footprint[slot] = fi;
        /* the first contribution of its (block, receiver) lists the group for sbr_reduce */
        if (atomic_inc(group_tubes + group) == 0)
            live_groups[atomic_inc(n_live_groups)] = group;
    }
}

/* One work group of SBR_CELLS items per (block, receiver) listed by sbr_radiate at this
 * bounce, item = cell: the cells whose footprints hit the same sequence of planar faces
 * form a group; its first cell sums the group's contributions in cell (tube) order, the
 * host reference's order, and writes one SbrRecord, the representative the first of the
 * largest |M|_F. A record past `capacity` is counted, not written: the host then grows
 * the buffer and reduces this bounce again. */
__kernel void sbr_reduce(__global const int *tri_face,
                         __global const SbrFootprint *footprints,
                         __global const SbrContribution *contributions,
                         __global const int *contribution_footprint,
                         __global const int *live_groups,
                         const int bounce,
                         const int n_rx,
                         const long first_block,
                         __global SbrRecord *out,
                         __global volatile int *count,
                         const int capacity)
{
    __local int faces[SBR_CELLS * SBR_TRI_SLOTS];
    __local uint keys[SBR_CELLS];
    __local int leader[SBR_CELLS];
    int group = live_groups[get_group_id(0)];
    int cell = get_local_id(0);
    int fi = contribution_footprint[group * SBR_CELLS + cell];
    /* a hash of the face sequence (0: no footprint) tells most sequences apart in one
     * comparison */
    uint key = 0;
    if (fi >= 0) {
        key = 2166136261u;
        for (int e = 0; e < bounce; ++e) {
            int face = tri_face[footprints[fi].tri[e]];
            faces[cell * SBR_TRI_SLOTS + e] = face;
            key = (key ^ (uint)face) * 16777619u;
        }
        key |= 1u;
    }
    keys[cell] = key;
    barrier(CLK_LOCAL_MEM_FENCE);
    int lead = -1;
    for (int c = 0; c <= cell && key != 0 && lead < 0; ++c) {
        bool same = keys[c] == key;
        for (int e = 0; e < bounce && same; ++e)
            same = faces[c * SBR_TRI_SLOTS + e] == faces[cell * SBR_TRI_SLOTS + e];
        if (same) lead = c;
    }
    leader[cell] = lead;
    barrier(CLK_LOCAL_MEM_FENCE);
    if (lead != cell) return;

    real M[8];
    for (int k = 0; k < 8; ++k) M[k] = 0.0;
    real weight = 0.0, weighted_length = 0.0, rep_weight = 0.0;
    int n = 0, rep = cell;
    for (int c = cell; c < SBR_CELLS; ++c) {
        if (leader[c] != cell) continue;
        __global const SbrContribution *ct = contributions + group * SBR_CELLS + c;
        for (int k = 0; k < 8; ++k) M[k] += ct->M[k];
        real wgt = ct->weight;
        weight += wgt;
        weighted_length += wgt * ps_real(ps_load(ct->length));
        if (n == 0 || wgt > rep_weight) {
            rep_weight = wgt;
            rep = c;
        }
        ++n;
    }
    int k_out = atomic_inc(count);
    if (k_out >= capacity) return;
    __global const SbrFootprint *fp =
        footprints + contribution_footprint[group * SBR_CELLS + rep];
    __global SbrRecord *e = out + k_out;
    e->length = contributions[group * SBR_CELLS + rep].length;
    for (int k = 0; k < 3; ++k) e->point[k] = fp->point[k];
    for (int k = 0; k < 8; ++k) e->M[k] = M[k];
    e->weight = weight;
    e->weighted_length = weighted_length;
    e->rep_weight = rep_weight;
    e->pad_real = 0.0;
    int r, blk = quotient(group, n_rx, &r);
    e->tube = (first_block + blk) * SBR_CELLS + rep;
    /* the host reference numbers a block's groups by first appearance in (tube,
     * bounce, receiver) order: this key sorts them so */
    e->ordinal = (cell * SBR_MAX_BOUNCES + bounce - 1) * n_rx + r;
    e->count = n;
    e->bounce = (short)bounce;
    e->receiver = (short)r;
    e->pad = 0;
    for (int k = 0; k < SBR_TRI_SLOTS; ++k) {
        e->face[k] = (k < bounce) ? faces[cell * SBR_TRI_SLOTS + k] : -1;
        e->tri[k] = (k < bounce) ? fp->tri[k] : -1;
    }
}
