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
 * so the two engines keep the same wedges bit for bit.
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
    __global const double *start;
    __global const double *end;
    __global const double *dir;
    __global const double *length;
    __global const double *normal0;
    __global const double *normal1;
    double clear;   /* EDGE_CLEARANCE_M */
    double lift;    /* EDGE_LIFT_M */
} EdgeSet;

CLR_INLINE double max_abs3(double a, double b, double c)
{
    double m = fabs(a);
    double fb = fabs(b), fc = fabs(c);
    m = (fb > m) ? fb : m;
    return (fc > m) ? fc : m;
}

CLR_INLINE double norm3(double a, double b, double c)
{
    return sqrt((a * a + b * b) + c * c);
}

/* lift_direction: the bisector of the two outward normals, or for a
 * half-plane its normal on the side of `away`. */
CLR_INLINE void lift_direction(const EdgeSet *e, int w, const double *away, double *out)
{
    __global const double *n0 = e->normal0 + 3 * w;
    __global const double *n1 = e->normal1 + 3 * w;
    double b0 = n0[0] + n1[0], b1 = n0[1] + n1[1], b2 = n0[2] + n1[2];
    double size = norm3(b0, b1, b2);
    double side = (dot3(n0[0], n0[1], n0[2], away[0], away[1], away[2]) < 0.0) ? -1.0 : 1.0;
    if (size < 1e-6) {
        out[0] = side * n0[0]; out[1] = side * n0[1]; out[2] = side * n0[2];
    } else {
        out[0] = b0 / size; out[1] = b1 / size; out[2] = b2 / size;
    }
}

/* The point q lifted off wedge w as the sight line q -> p leaves it (o), and
 * |p - q|. */
CLR_INLINE double lifted(const EdgeSet *e, int w, const double *q, const double *p, double *o)
{
    double d[3] = {p[0] - q[0], p[1] - q[1], p[2] - q[2]};
    double l[3];
    lift_direction(e, w, d, l);
    for (int k = 0; k < 3; ++k)
        o[k] = q[k] + e->lift * l[k];
    return norm3(d[0], d[1], d[2]);
}

/* _edge_origins: s metres along wedge w (start + s direction), lifted. */
CLR_INLINE double edge_origin(const EdgeSet *e, int w, double s, const double *p, double *o)
{
    double q[3];
    for (int k = 0; k < 3; ++k)
        q[k] = e->start[3 * w + k] + s * e->dir[3 * w + k];
    return lifted(e, w, q, p, o);
}

/* The float32 sight line o -> p over (clear, 1 - clear) as make_rays packs it. */
CLR_INLINE PreparedRay sight_ray(const double *o, const double *p)
{
    return prepare_ray((float3)((float)o[0], (float)o[1], (float)o[2]),
                       (float3)((float)(p[0] - o[0]), (float)(p[1] - o[1]),
                                (float)(p[2] - o[2])));
}

/* _first_blocker: the scene triangle first met on the sight line from s metres
 * along wedge w to p, -1 where nothing blocks it. */
CLR_INLINE int first_blocker(__global const Bvh8Node *nodes, __global const float4 *tri4,
                             __global const int *slot_prim, const EdgeSet *e, int w, double s,
                             const double *p)
{
    double o[3];
    double len = edge_origin(e, w, s, p, o);
    double clear = e->clear / fmax(len, 1e-12);
    PreparedRay pr = sight_ray(o, p);
    float t = (float)(1.0 - clear), u, v;
    int slot = bvh_closest(nodes, tri4, slot_prim, &pr, (float)clear, &t, &u, &v, -1);
    return (slot >= 0) ? slot_prim[slot] : -1;
}

/* _segment_distances for one pair: the distance between segments a b and c d
 * (closest points by clamping, Ericson 5.1.9), as numpy evaluates it. */
CLR_INLINE double segment_distance(const double *a, const double *b, __global const double *c,
                                   __global const double *d)
{
    double u[3], v[3], w0[3];
    for (int k = 0; k < 3; ++k) {
        u[k] = b[k] - a[k];
        v[k] = d[k] - c[k];
        w0[k] = a[k] - c[k];
    }
    double uu = dot3(u[0], u[1], u[2], u[0], u[1], u[2]);
    double vv = dot3(v[0], v[1], v[2], v[0], v[1], v[2]);
    double uv = dot3(u[0], u[1], u[2], v[0], v[1], v[2]);
    double uw = dot3(u[0], u[1], u[2], w0[0], w0[1], w0[2]);
    double vw = dot3(v[0], v[1], v[2], w0[0], w0[1], w0[2]);
    double den = uu * vv - uv * uv;
    double sc = (den > 0.0) ? (uv * vw - vv * uw) / den : 0.0;
    sc = fmin(fmax(sc, 0.0), 1.0);
    double tc = (vv > 0.0) ? (uv * sc + vw) / vv : 0.0;
    tc = fmin(fmax(tc, 0.0), 1.0);
    sc = (uu > 0.0) ? (uv * tc - uw) / uu : 0.0;
    sc = fmin(fmax(sc, 0.0), 1.0);
    double r0 = (w0[0] + sc * u[0]) - tc * v[0];
    double r1 = (w0[1] + sc * u[1]) - tc * v[1];
    double r2 = (w0[2] + sc * u[2]) - tc * v[2];
    return norm3(r0, r1, r2);
}

/* _face_covers for one piece [s0, s1] of wedge w: the planar face of triangle
 * `blocker` (met first from the piece's start, or its end where at_end) blocks
 * every sight line from the piece to p. */
CLR_INLINE bool face_covers(const Scene64 *sc, const EdgeSet *e, int w, double s0, double s1,
                            int blocker, bool at_end, const double *p)
{
    if (blocker < 0)
        return false;
    double o0[3], o1[3];
    edge_origin(e, w, s0, p, o0);
    edge_origin(e, w, s1, p, o1);
    __global const double *v = sc->vert + 9 * blocker;
    __global const double *n = sc->normal + 3 * blocker;
    double dp = dot3(n[0], n[1], n[2], p[0] - v[0], p[1] - v[1], p[2] - v[2]);
    double d0 = dot3(n[0], n[1], n[2], o0[0] - v[0], o0[1] - v[1], o0[2] - v[2]);
    double d1 = dot3(n[0], n[1], n[2], o1[0] - v[0], o1[1] - v[1], o1[2] - v[2]);
    double margin = 1e-5 + 1e-6 * (1.0 + max_abs3(p[0], p[1], p[2]));
    if (!((d0 * dp < 0.0) && (d1 * dp < 0.0) && (fabs(dp) > margin)
          && (fabs(d0) > 2.0 * e->clear) && (fabs(d1) > 2.0 * e->clear)))
        return false;
    double x0[3], x1[3];
    double r0 = d0 / (d0 - dp), r1 = d1 / (d1 - dp);
    for (int k = 0; k < 3; ++k) {
        x0[k] = o0[k] + r0 * (p[k] - o0[k]);
        x1[k] = o1[k] + r1 * (p[k] - o1[k]);
    }
    double tol = margin + 1e-6 * fmax(max_abs3(x0[0], x0[1], x0[2]),
                                      max_abs3(x1[0], x1[1], x1[2]));
    /* both ends well inside the blocker: the segment is in it */
    bool one = true;
    for (int j = 0; j < 3; ++j)
        one = one && (edge_distance(sc, blocker, j, x0[0], x0[1], x0[2]) > tol)
                  && (edge_distance(sc, blocker, j, x1[0], x1[1], x1[2]) > tol);
    if (one)
        return true;
    /* across seams: the blocker's end in the face, the segment clear of its outline */
    int face = sc->tri_face[blocker];
    const double *anchor = at_end ? x1 : x0;
    if (contains(sc, face, blocker, anchor[0], anchor[1], anchor[2]) < 0)
        return false;
    double gap = INFINITY;
    for (int i = sc->face_first[face]; i < sc->face_first[face + 1]; ++i) {
        int t = sc->face_tris[i];
        for (int j = 0; j < 3; ++j) {
            if (sc->seam[3 * t + j])
                continue;   /* a seam: not the face's outline */
            double g = segment_distance(x0, x1, sc->vert + 9 * t + 3 * j,
                                        sc->vert + 9 * t + 3 * ((j + 1) % 3));
            if (!isnan(gap) && (isnan(g) || g < gap))
                gap = g;   /* np.minimum: a NaN stays */
        }
    }
    return gap > tol;
}

/* seen[pos * n_wedges + w]: bit 0 seen at the samples, bit 1 kept (seen or not
 * proven hidden); see the header. */
__kernel void wedges_seen(__global const Bvh8Node *nodes, __global const float4 *tri4,
                          __global const int *slot_prim, SCENE64_ARGS,
                          __global const double *start, __global const double *end,
                          __global const double *dir, __global const double *length,
                          __global const double *normal0, __global const double *normal1,
                          const double edge_clear, const double edge_lift,
                          __global const double *points, __global const double *samples,
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
    e.clear = edge_clear; e.lift = edge_lift;
    __global const double *pp = points + 3 * (gid / n_wedges);
    double p[3] = {pp[0], pp[1], pp[2]};
    int g = gate[gid];
    /* 1. the sample sight lines */
    for (int k = 0; k < n_samples; ++k) {
        if (!(g & (1 << k)))
            continue;
        double f = samples[k];
        double q[3], o[3];
        for (int c = 0; c < 3; ++c)
            q[c] = start[3 * w + c] + f * (end[3 * w + c] - start[3 * w + c]);
        double len = lifted(&e, w, q, p, o);
        double clear = edge_clear / len;
        PreparedRay pr = sight_ray(o, p);
        if (!bvh_any(nodes, tri4, slot_prim, &pr, (float)clear, (float)(1.0 - clear), -1, -1)) {
            seen[gid] = 3;
            return;
        }
    }
    if (!(g & (1 << n_samples))) {
        seen[gid] = 0;
        return;
    }
    /* 2. five knots along the usable edge, their first blockers */
    double c = edge_clear, L = length[w];
    double knots[5] = {c, 0.25 * L, 0.5 * L, 0.75 * L, L - c};
    for (int k = 0; k < 5; ++k)
        knots[k] = fmin(fmax(knots[k], c), L - c);
    for (int k = 1; k < 5; ++k)   /* np.sort */
        for (int j = k; j > 0 && knots[j] < knots[j - 1]; --j) {
            double tmp = knots[j]; knots[j] = knots[j - 1]; knots[j - 1] = tmp;
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
    double st_s0[EDGE_STACK], st_s1[EDGE_STACK];
    int st_b0[EDGE_STACK], st_b1[EDGE_STACK], st_depth[EDGE_STACK];
    int sp = 0;
    for (int k = 3; k >= 0; --k) {
        st_s0[sp] = knots[k]; st_s1[sp] = knots[k + 1];
        st_b0[sp] = block[k]; st_b1[sp] = block[k + 1]; st_depth[sp] = 0; ++sp;
    }
    while (sp > 0) {
        --sp;
        double s0 = st_s0[sp], s1 = st_s1[sp];
        int b0 = st_b0[sp], b1 = st_b1[sp], depth = st_depth[sp];
        if (!(s1 > s0))
            continue;
        if (face_covers(&sc, &e, w, s0, s1, b0, false, p)
            || face_covers(&sc, &e, w, s0, s1, b1, true, p))
            continue;
        if (depth >= max_depth) {
            seen[gid] = 2;   /* neither seen nor proven hidden: kept */
            return;
        }
        double sm = 0.5 * (s0 + s1);
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
