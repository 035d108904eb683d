/* Which diffracting edges an antenna may see: one work item per (antenna
 * position, wedge), the whole of clradcom.mechanisms.diffraction._seeing for
 * that wedge (clradcom/device/edges.py drives it):
 *
 *   1. sight lines from the sample points of the edge (lifted off the wedge)
 *      to the antenna, float32 any-hit casts: one clear -> seen ("sampled");
 *   2. otherwise the first blocker (float32 closest hit) of the sight lines
 *      from five knots along the usable edge; one clear -> seen;
 *   3. the four pieces between knots: a piece is hidden when the planar face
 *      of the first blocker at one of its ends covers the whole triangle
 *      antenna - piece (face_covers, float64); a piece not proven hidden is
 *      halved (a sight line from its midpoint: clear -> seen) down to
 *      max_depth halvings; a piece still open then -> seen (over-accept).
 *
 * The host walks the pieces breadth first over all wedges at once; here one
 * wedge's pieces are walked depth first: every piece's decision depends on
 * its own ends only, so the wedge's answer is the same. Rays are built from
 * float64 origins and lengths rounded to float32 as make_rays rounds them, and
 * cast with the same traversal as kernels/raycast.cl; the float64 arithmetic
 * repeats the numpy reference operation for operation (FP_CONTRACT OFF, dot
 * products in numpy's order DOT3_ORDER), the point-in-face test and the seam
 * table are kernels/scene64.h's (contains, Scene64, as visibility.cl uses them),
 * so the two engines keep the same wedges bit for bit. The float64 arithmetic is
 * precise.h's preal: double with fp64; without, double-float on (hi, lo) pairs
 * (pr_elem), whose decisions differ from the host's only within ~1e-13 (1 + |p|) m of
 * a threshold (tests/test_no_fp64.py).
 *
 * Whether the antenna lies outside the wedge (an arctangent on the host) is
 * decided by the host and passed in: gate[(P * (n_samples + 1)) ...] holds,
 * per position and wedge, bit k for "sample k is outside and far enough" and
 * bit n_samples for "the antenna is outside the wedge seen from its midpoint
 * and the edge is long enough for pieces". */
#include "scene64.h"

#define EDGE_MAX_DEPTH 10
#define EDGE_STACK (4 + 2 * (EDGE_MAX_DEPTH + 1))

typedef struct {
    __global const pr_elem *start;
    __global const pr_elem *end;
    __global const pr_elem *dir;
    __global const pr_elem *length;
    __global const pr_elem *normal0;
    __global const pr_elem *normal1;
    preal clear;   /* EDGE_CLEARANCE_M */
    preal lift;    /* EDGE_LIFT_M */
} EdgeSet;

CLR_INLINE preal max_abs3(preal a, preal b, preal c)
{
    preal m = pr_fabs(a);
    preal fb = pr_fabs(b), fc = pr_fabs(c);
    m = pr_gt(fb, m) ? fb : m;
    return pr_gt(fc, m) ? fc : m;
}

CLR_INLINE preal norm3(preal a, preal b, preal c)
{
    return pr_sqrt(pr_add(pr_add(pr_mul(a, a), pr_mul(b, b)), pr_mul(c, c)));
}

/* lift_direction: the bisector of the two outward normals, or for a
 * half-plane its normal on the side of `away`. */
CLR_INLINE void lift_direction(const EdgeSet *e, int w, const preal *away, preal *out)
{
    __global const pr_elem *g0 = e->normal0 + 3 * w;
    __global const pr_elem *g1 = e->normal1 + 3 * w;
    preal n0[3] = {pr_of(g0[0]), pr_of(g0[1]), pr_of(g0[2])};
    preal b0 = pr_add(n0[0], pr_of(g1[0])), b1 = pr_add(n0[1], pr_of(g1[1]));
    preal b2 = pr_add(n0[2], pr_of(g1[2]));
    preal size = norm3(b0, b1, b2);
    preal side = pr_lt(dot3(n0[0], n0[1], n0[2], away[0], away[1], away[2]), PR_CONST(0.0))
                 ? PR_CONST(-1.0) : PR_CONST(1.0);
    if (pr_lt(size, PR_CONST(1e-6))) {
        out[0] = pr_mul(side, n0[0]); out[1] = pr_mul(side, n0[1]);
        out[2] = pr_mul(side, n0[2]);
    } else {
        out[0] = pr_div(b0, size); out[1] = pr_div(b1, size); out[2] = pr_div(b2, size);
    }
}

/* The point q lifted off wedge w as the sight line q -> p leaves it (o), and
 * |p - q|. */
CLR_INLINE preal lifted(const EdgeSet *e, int w, const preal *q, const preal *p, preal *o)
{
    preal d[3] = {pr_sub(p[0], q[0]), pr_sub(p[1], q[1]), pr_sub(p[2], q[2])};
    preal l[3];
    lift_direction(e, w, d, l);
    for (int k = 0; k < 3; ++k)
        o[k] = pr_add(q[k], pr_mul(e->lift, l[k]));
    return norm3(d[0], d[1], d[2]);
}

/* _edge_origins: s metres along wedge w (start + s direction), lifted. */
CLR_INLINE preal edge_origin(const EdgeSet *e, int w, preal s, const preal *p, preal *o)
{
    preal q[3];
    for (int k = 0; k < 3; ++k)
        q[k] = pr_add(pr_of(e->start[3 * w + k]), pr_mul(s, pr_of(e->dir[3 * w + k])));
    return lifted(e, w, q, p, o);
}

/* The float32 sight line o -> p over (clear, 1 - clear) as make_rays packs it. */
CLR_INLINE PreparedRay sight_ray(const preal *o, const preal *p)
{
    return prepare_ray((float3)(pr_to_float(o[0]), pr_to_float(o[1]), pr_to_float(o[2])),
                       (float3)(pr_to_float(pr_sub(p[0], o[0])),
                                pr_to_float(pr_sub(p[1], o[1])),
                                pr_to_float(pr_sub(p[2], o[2]))));
}

/* _first_blocker: the scene triangle first met on the sight line from s metres
 * along wedge w to p, -1 where nothing blocks it. */
CLR_INLINE int first_blocker(__global const Bvh8Node *nodes, __global const float4 *tri4,
                             __global const int *slot_prim, const EdgeSet *e, int w, preal s,
                             const preal *p)
{
    preal o[3];
    preal len = edge_origin(e, w, s, p, o);
    preal clear = pr_div(e->clear, pr_fmax(len, PR_CONST(1e-12)));
    PreparedRay pr = sight_ray(o, p);
    float t = pr_to_float(pr_sub(PR_CONST(1.0), clear)), u, v;
    int slot = bvh_closest(nodes, tri4, slot_prim, &pr, pr_to_float(clear), &t, &u, &v, -1);
    return (slot >= 0) ? slot_prim[slot] : -1;
}

CLR_INLINE preal clamp01(preal x)
{
    return pr_fmin(pr_fmax(x, PR_CONST(0.0)), PR_CONST(1.0));
}

/* _segment_distances for one pair: the distance between segments a b and c d
 * (closest points by clamping, Ericson 5.1.9), as numpy evaluates it. */
CLR_INLINE preal segment_distance(const preal *a, const preal *b, __global const pr_elem *c,
                                  __global const pr_elem *d)
{
    const preal zero = PR_CONST(0.0);
    preal u[3], v[3], w0[3];
    for (int k = 0; k < 3; ++k) {
        preal ck = pr_of(c[k]);
        u[k] = pr_sub(b[k], a[k]);
        v[k] = pr_sub(pr_of(d[k]), ck);
        w0[k] = pr_sub(a[k], ck);
    }
    preal uu = dot3(u[0], u[1], u[2], u[0], u[1], u[2]);
    preal vv = dot3(v[0], v[1], v[2], v[0], v[1], v[2]);
    preal uv = dot3(u[0], u[1], u[2], v[0], v[1], v[2]);
    preal uw = dot3(u[0], u[1], u[2], w0[0], w0[1], w0[2]);
    preal vw = dot3(v[0], v[1], v[2], w0[0], w0[1], w0[2]);
    preal den = pr_sub(pr_mul(uu, vv), pr_mul(uv, uv));
    preal sc = pr_gt(den, zero) ? pr_div(pr_sub(pr_mul(uv, vw), pr_mul(vv, uw)), den) : zero;
    sc = clamp01(sc);
    preal tc = pr_gt(vv, zero) ? pr_div(pr_add(pr_mul(uv, sc), vw), vv) : zero;
    tc = clamp01(tc);
    sc = pr_gt(uu, zero) ? pr_div(pr_sub(pr_mul(uv, tc), uw), uu) : zero;
    sc = clamp01(sc);
    preal r0 = pr_sub(pr_add(w0[0], pr_mul(sc, u[0])), pr_mul(tc, v[0]));
    preal r1 = pr_sub(pr_add(w0[1], pr_mul(sc, u[1])), pr_mul(tc, v[1]));
    preal r2 = pr_sub(pr_add(w0[2], pr_mul(sc, u[2])), pr_mul(tc, v[2]));
    return norm3(r0, r1, r2);
}

/* _face_covers for one piece [s0, s1] of wedge w: the planar face of triangle
 * `blocker` (met first from the piece's start, or its end where at_end) blocks
 * every sight line from the piece to p. */
CLR_INLINE bool face_covers(const Scene64 *sc, const EdgeSet *e, int w, preal s0, preal s1,
                            int blocker, bool at_end, const preal *p)
{
    if (blocker < 0)
        return false;
    const preal zero = PR_CONST(0.0);
    preal o0[3], o1[3];
    edge_origin(e, w, s0, p, o0);
    edge_origin(e, w, s1, p, o1);
    __global const pr_elem *v = sc->vert + 9 * blocker;
    __global const pr_elem *n = sc->normal + 3 * blocker;
    preal v0 = pr_of(v[0]), v1 = pr_of(v[1]), v2 = pr_of(v[2]);
    preal n0 = pr_of(n[0]), n1 = pr_of(n[1]), n2 = pr_of(n[2]);
    preal dp = dot3(n0, n1, n2, pr_sub(p[0], v0), pr_sub(p[1], v1), pr_sub(p[2], v2));
    preal d0 = dot3(n0, n1, n2, pr_sub(o0[0], v0), pr_sub(o0[1], v1), pr_sub(o0[2], v2));
    preal d1 = dot3(n0, n1, n2, pr_sub(o1[0], v0), pr_sub(o1[1], v1), pr_sub(o1[2], v2));
    preal margin = pr_add(PR_CONST(1e-5), pr_mul(PR_CONST(1e-6), pr_add(
        PR_CONST(1.0), max_abs3(p[0], p[1], p[2]))));
    preal two_clear = pr_mul(PR_CONST(2.0), e->clear);
    if (!(pr_lt(pr_mul(d0, dp), zero) && pr_lt(pr_mul(d1, dp), zero)
          && pr_gt(pr_fabs(dp), margin) && pr_gt(pr_fabs(d0), two_clear)
          && pr_gt(pr_fabs(d1), two_clear)))
        return false;
    preal x0[3], x1[3];
    preal r0 = pr_div(d0, pr_sub(d0, dp)), r1 = pr_div(d1, pr_sub(d1, dp));
    for (int k = 0; k < 3; ++k) {
        x0[k] = pr_add(o0[k], pr_mul(r0, pr_sub(p[k], o0[k])));
        x1[k] = pr_add(o1[k], pr_mul(r1, pr_sub(p[k], o1[k])));
    }
    preal tol = pr_add(margin, pr_mul(PR_CONST(1e-6), pr_fmax(max_abs3(x0[0], x0[1], x0[2]),
                                                              max_abs3(x1[0], x1[1], x1[2]))));
    /* both ends well inside the blocker: the segment is in it */
    bool one = true;
    for (int j = 0; j < 3; ++j)
        one = one && pr_gt(edge_distance(sc, blocker, j, x0[0], x0[1], x0[2]), tol)
                  && pr_gt(edge_distance(sc, blocker, j, x1[0], x1[1], x1[2]), tol);
    if (one)
        return true;
    /* across seams: the blocker's end in the face, the segment clear of its outline */
    int face = sc->tri_face[blocker];
    const preal *anchor = at_end ? x1 : x0;
    if (contains(sc, face, blocker, anchor[0], anchor[1], anchor[2]) < 0)
        return false;
    preal gap = PR_CONST(INFINITY);
    for (int i = sc->face_first[face]; i < sc->face_first[face + 1]; ++i) {
        int t = sc->face_tris[i];
        for (int j = 0; j < 3; ++j) {
            if (sc->seam[3 * t + j])
                continue;   /* a seam: not the face's outline */
            preal g = segment_distance(x0, x1, sc->vert + 9 * t + 3 * j,
                                       sc->vert + 9 * t + 3 * ((j + 1) % 3));
            if (!pr_isnan(gap) && (pr_isnan(g) || pr_lt(g, gap)))
                gap = g;   /* np.minimum: a NaN stays */
        }
    }
    return pr_gt(gap, tol);
}

/* seen[pos * n_wedges + w]: bit 0 seen at the samples, bit 1 kept (seen or not
 * proven hidden); see the header. */
__kernel void wedges_seen(__global const Bvh8Node *nodes, __global const float4 *tri4,
                          __global const int *slot_prim, SCENE64_ARGS,
                          __global const pr_elem *start, __global const pr_elem *end,
                          __global const pr_elem *dir, __global const pr_elem *length,
                          __global const pr_elem *normal0, __global const pr_elem *normal1,
                          const pr_elem edge_clear, const pr_elem edge_lift,
                          __global const pr_elem *points, __global const pr_elem *samples,
                          const int n_samples, __global const uchar *gate,
                          const int max_depth, __global uchar *seen, const int n_wedges,
                          const int n)
{
    int gid = get_global_id(0);
    if (gid >= n) return;
    int w = gid % n_wedges;
    SCENE64_INIT(sc);
    EdgeSet e;
    e.start = start; e.end = end; e.dir = dir; e.length = length;
    e.normal0 = normal0; e.normal1 = normal1;
    e.clear = pr_of(edge_clear); e.lift = pr_of(edge_lift);
    const preal one = PR_CONST(1.0);
    __global const pr_elem *pp = points + 3 * (gid / n_wedges);
    preal p[3] = {pr_of(pp[0]), pr_of(pp[1]), pr_of(pp[2])};
    int g = gate[gid];
    /* 1. the sample sight lines */
    for (int k = 0; k < n_samples; ++k) {
        if (!(g & (1 << k)))
            continue;
        preal f = pr_of(samples[k]);
        preal q[3], o[3];
        for (int c = 0; c < 3; ++c) {
            preal s0 = pr_of(start[3 * w + c]);
            q[c] = pr_add(s0, pr_mul(f, pr_sub(pr_of(end[3 * w + c]), s0)));
        }
        preal len = lifted(&e, w, q, p, o);
        preal clear = pr_div(e.clear, len);
        PreparedRay pr = sight_ray(o, p);
        if (!bvh_any(nodes, tri4, slot_prim, &pr, pr_to_float(clear),
                     pr_to_float(pr_sub(one, clear)), -1, -1)) {
            seen[gid] = 3;
            return;
        }
    }
    if (!(g & (1 << n_samples))) {
        seen[gid] = 0;
        return;
    }
    /* 2. five knots along the usable edge, their first blockers */
    preal c = e.clear, L = pr_of(length[w]);
    preal knots[5] = {c, pr_mul(PR_CONST(0.25), L), pr_mul(PR_CONST(0.5), L),
                      pr_mul(PR_CONST(0.75), L), pr_sub(L, c)};
    for (int k = 0; k < 5; ++k)
        knots[k] = pr_fmin(pr_fmax(knots[k], c), pr_sub(L, c));
    for (int k = 1; k < 5; ++k)   /* np.sort */
        for (int j = k; j > 0 && pr_lt(knots[j], knots[j - 1]); --j) {
            preal tmp = knots[j]; knots[j] = knots[j - 1]; knots[j - 1] = tmp;
        }
    int block[5];
    for (int k = 0; k < 5; ++k) {
        block[k] = first_blocker(nodes, tri4, slot_prim, &e, w, knots[k], p);
        if (block[k] < 0) {
            seen[gid] = 2;
            return;
        }
    }
    /* 3. the pieces, depth first */
    preal st_s0[EDGE_STACK], st_s1[EDGE_STACK];
    int st_b0[EDGE_STACK], st_b1[EDGE_STACK], st_depth[EDGE_STACK];
    int sp = 0;
    for (int k = 3; k >= 0; --k) {
        st_s0[sp] = knots[k]; st_s1[sp] = knots[k + 1];
        st_b0[sp] = block[k]; st_b1[sp] = block[k + 1]; st_depth[sp] = 0; ++sp;
    }
    while (sp > 0) {
        --sp;
        preal s0 = st_s0[sp], s1 = st_s1[sp];
        int b0 = st_b0[sp], b1 = st_b1[sp], depth = st_depth[sp];
        if (!pr_gt(s1, s0))
            continue;
        if (face_covers(&sc, &e, w, s0, s1, b0, false, p)
            || face_covers(&sc, &e, w, s0, s1, b1, true, p))
            continue;
        if (depth >= max_depth) {
            seen[gid] = 2;   /* neither seen nor proven hidden: kept */
            return;
        }
        preal sm = pr_mul(PR_CONST(0.5), pr_add(s0, s1));
        int bm = first_blocker(nodes, tri4, slot_prim, &e, w, sm, p);
        if (bm < 0) {
            seen[gid] = 2;
            return;
        }
        st_s0[sp] = sm; st_s1[sp] = s1; st_b0[sp] = bm; st_b1[sp] = b1;
        st_depth[sp] = depth + 1; ++sp;
        st_s0[sp] = s0; st_s1[sp] = sm; st_b0[sp] = b0; st_b1[sp] = bm;
        st_depth[sp] = depth + 1; ++sp;
    }
    seen[gid] = 0;
}
