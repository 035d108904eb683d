/* The float64 scene the visibility kernels decide in (kernels/visibility.cl,
 * kernels/edges.cl, kernels/scatter.cl, kernels/sbr.cl): Scene64 and the point-in-face
 * test contains(), the host's clradcom/device/visibility.py: containing_triangles
 * operation for operation (contraction off, three-term dot products in numpy's order:
 * dot3.h), and blocked_in_float64, the float64 re-decision of a float32 "blocked".
 *
 * The arithmetic is precise.h's preal. With fp64 that is double, and the decisions are
 * the host's bit for bit. Without, it is double-float (~1e-14 relative; the scene's
 * float64 numbers cross as (hi, lo) pairs, 2^-48 relative): a decision can then differ
 * from the host's only where its float64 quantity lies within that rounding of the
 * threshold -- a point within ~1e-13 (1 + |p|) m of a rim or of a face's box, a crossing
 * that close to a segment's end -- where float64 itself decides by its own rounding
 * (tests/test_no_fp64.py holds both). */
#ifndef CLRADCOM_SCENE64_H
#define CLRADCOM_SCENE64_H

#include "intersect.h"
#include "dot3.h"

/* The float64 scene: vertices (T*9, v0 v1 v2), unit normals (T*3,
 * triangle_normals), the planar face of every triangle, the seam flag of every
 * edge j -> j+1 (T*3), the triangles of face f at face_tris[face_first[f] ..
 * face_first[f+1]) in ascending id, and each face's box (F*6: min xyz, max xyz).
 * Float64 values are pr_elem (double, or (hi, lo) pairs without fp64). */
typedef struct {
    __global const pr_elem *vert;
    __global const pr_elem *normal;
    __global const int *tri_face;
    __global const uchar *seam;
    __global const int *face_first;
    __global const int *face_tris;
    __global const pr_elem *face_box;
    int n_faces;
    preal inside_tol;
} Scene64;

/* Signed in-plane distance of p inside edge j of triangle t (edge_distances):
 * ((b - a) x (p - a)) . n / |b - a|. */
CLR_INLINE preal edge_distance(const Scene64 *s, int t, int j, preal px, preal py, preal pz)
{
    __global const pr_elem *a = s->vert + 9 * t + 3 * j;
    __global const pr_elem *b = s->vert + 9 * t + 3 * ((j + 1) % 3);
    __global const pr_elem *n = s->normal + 3 * t;
    preal a0 = pr_of(a[0]), a1 = pr_of(a[1]), a2 = pr_of(a[2]);
    preal e0 = pr_sub(pr_of(b[0]), a0), e1 = pr_sub(pr_of(b[1]), a1);
    preal e2 = pr_sub(pr_of(b[2]), a2);
    preal d0 = pr_sub(px, a0), d1 = pr_sub(py, a1), d2 = pr_sub(pz, a2);
    preal c0 = pr_sub(pr_mul(e1, d2), pr_mul(e2, d1));
    preal c1 = pr_sub(pr_mul(e2, d0), pr_mul(e0, d2));
    preal c2 = pr_sub(pr_mul(e0, d1), pr_mul(e1, d0));
    preal len = pr_sqrt(pr_add(pr_add(pr_mul(e0, e0), pr_mul(e1, e1)), pr_mul(e2, e2)));
    return pr_div(dot3(c0, c1, c2, pr_of(n[0]), pr_of(n[1]), pr_of(n[2])), len);
}

/* _inside for one point and triangle: no edge distance negative, or the
 * negative ones no less than min_dist and all across seams. */
CLR_INLINE bool inside_triangle(const Scene64 *s, int t, preal px, preal py, preal pz,
                                preal min_dist)
{
    const preal zero = PR_CONST(0.0);
    preal d[3];
    bool exact = true;
    for (int j = 0; j < 3; ++j) {
        d[j] = edge_distance(s, t, j, px, py, pz);
        exact = exact && pr_ge(d[j], zero);
    }
    if (exact)
        return true;
    for (int j = 0; j < 3; ++j)
        if (!pr_ge(d[j], min_dist))
            return false;
    for (int j = 0; j < 3; ++j)
        if (pr_lt(d[j], zero) && !s->seam[3 * t + j])
            return false;
    return true;
}

/* containing_triangles for one point: the triangle of face `face` holding p,
 * `guess` first (the float32 hit, -1 for none), or -1. */
CLR_INLINE int contains(const Scene64 *s, int face, int guess, preal px, preal py, preal pz)
{
    preal m = pr_fmax(pr_fmax(pr_fabs(px), pr_fabs(py)), pr_fabs(pz));
    preal min_dist = pr_mul(pr_neg(s->inside_tol), pr_add(PR_CONST(1.0), m));
    if (guess >= 0 && s->tri_face[guess] == face && inside_triangle(s, guess, px, py, pz, min_dist))
        return guess;
    if (face < 0 || face >= s->n_faces)
        return -1;
    __global const pr_elem *box = s->face_box + 6 * face;
    if (!(pr_ge(px, pr_add(pr_of(box[0]), min_dist)) && pr_le(px, pr_sub(pr_of(box[3]), min_dist))
          && pr_ge(py, pr_add(pr_of(box[1]), min_dist)) && pr_le(py, pr_sub(pr_of(box[4]), min_dist))
          && pr_ge(pz, pr_add(pr_of(box[2]), min_dist)) && pr_le(pz, pr_sub(pr_of(box[5]), min_dist))))
        return -1;
    for (int i = s->face_first[face]; i < s->face_first[face + 1]; ++i) {
        int c = s->face_tris[i];
        if (inside_triangle(s, c, px, py, pz, min_dist))
            return c;
    }
    return -1;
}

#define SCENE64_ARGS                                                                  \
    __global const pr_elem *vert, __global const pr_elem *normal,                     \
    __global const int *tri_face, __global const uchar *seam,                         \
    __global const int *face_first, __global const int *face_tris,                    \
    __global const pr_elem *face_box, const int n_faces, const pr_elem inside_tol

#define SCENE64_INIT(s)                                                               \
    Scene64 s;                                                                        \
    s.vert = vert; s.normal = normal; s.tri_face = tri_face; s.seam = seam;           \
    s.face_first = face_first; s.face_tris = face_tris; s.face_box = face_box;        \
    s.n_faces = n_faces; s.inside_tol = pr_of(inside_tol)

/* visibility.py: blocked_in_float64 for one segment start + t seg (float64, t in
 * [lo, hi]) whose float32 cast pr (up to tmax32) an any-hit called blocked: up to
 * max_rounds closest float32 hits past lo, each crossed with its triangle's plane in
 * float64. Blocked once a face holds a crossing; clear when no hit is left; blocked
 * still when undecided after max_rounds. The first round ignores the triangle skip
 * (the surface a sight line leaves; -1: none), each later one the last blocker looked
 * past. Every float64 argument is a preal: double with fp64 (as kernels/sbr.cl passes
 * its double positions), the pairs' double-float without (a caller converts its
 * pr_elem arguments with pr_of, a float with pr_from_float). */
CLR_INLINE bool blocked_in_float64(__global const Bvh8Node *nodes,
                                   __global const float4 *tri4,
                                   __global const int *slot_prim, const Scene64 *s,
                                   const PreparedRay *pr, float tmax32, preal s0,
                                   preal s1, preal s2, preal g0, preal g1, preal g2,
                                   preal lo, preal hi, int skip, int max_rounds,
                                   preal look_past)
{
    for (int round = 0; round < max_rounds; ++round) {
        float t = tmax32, u, v;
        int slot = bvh_closest(nodes, tri4, slot_prim, pr, pr_to_float(lo), &t, &u, &v, skip);
        if (slot < 0)
            return false;
        int prim = slot_prim[slot];
        __global const pr_elem *w = s->vert + 9 * prim;
        preal w0 = pr_of(w[0]), w1 = pr_of(w[1]), w2 = pr_of(w[2]);
        preal a0 = pr_sub(pr_of(w[3]), w0), a1 = pr_sub(pr_of(w[4]), w1);
        preal a2 = pr_sub(pr_of(w[5]), w2);
        preal b0 = pr_sub(pr_of(w[6]), w0), b1 = pr_sub(pr_of(w[7]), w1);
        preal b2 = pr_sub(pr_of(w[8]), w2);
        preal n0 = pr_sub(pr_mul(a1, b2), pr_mul(a2, b1));
        preal n1 = pr_sub(pr_mul(a2, b0), pr_mul(a0, b2));
        preal n2 = pr_sub(pr_mul(a0, b1), pr_mul(a1, b0));
        preal denom = dot3(n0, n1, n2, g0, g1, g2);
        preal tc = pr_div(dot3(n0, n1, n2, pr_sub(w0, s0), pr_sub(w1, s1), pr_sub(w2, s2)),
                          denom);
        if (pr_isfinite(tc) && pr_ge(tc, lo) && pr_le(tc, hi) &&
            contains(s, s->tri_face[prim], prim, pr_add(s0, pr_mul(tc, g0)),
                     pr_add(s1, pr_mul(tc, g1)), pr_add(s2, pr_mul(tc, g2))) >= 0)
            return true;   /* the face holds the crossing */
        lo = pr_fmax(lo, pr_mul(pr_from_float(t), look_past));
        skip = prim;
    }
    return true;
}

CLR_INLINE PreparedRay prepare_packed(const Ray *ray)
{
    return prepare_ray((float3)(ray->org[0], ray->org[1], ray->org[2]),
                       (float3)(ray->dir[0], ray->dir[1], ray->dir[2]));
}

#endif
