/* The float64 scene the visibility kernels decide in (kernels/visibility.cl,
 * kernels/edges.cl): Scene64 and the point-in-face test contains(), the host's
 * clradcom/device/visibility.py: containing_triangles operation for operation
 * (contraction off, three-term dot products in numpy's order: dot3.h). */
#ifndef CLRADCOM_SCENE64_H
#define CLRADCOM_SCENE64_H

#include "intersect.h"

#ifndef CLRADCOM_HAS_FP64
#error "kernels/scene64.h needs fp64 (cl_khr_fp64); the host keeps its own float64 rescue without it"
#endif
#include "dot3.h"

/* The float64 scene: vertices (T*9, v0 v1 v2), unit normals (T*3,
 * triangle_normals), the planar face of every triangle, the seam flag of every
 * edge j -> j+1 (T*3), the triangles of face f at face_tris[face_first[f] ..
 * face_first[f+1]) in ascending id, and each face's box (F*6: min xyz, max xyz). */
typedef struct {
    __global const double *vert;
    __global const double *normal;
    __global const int *tri_face;
    __global const uchar *seam;
    __global const int *face_first;
    __global const int *face_tris;
    __global const double *face_box;
    int n_faces;
    double inside_tol;
} Scene64;

/* Signed in-plane distance of p inside edge j of triangle t (edge_distances):
 * ((b - a) x (p - a)) . n / |b - a|. */
CLR_INLINE double edge_distance(const Scene64 *s, int t, int j, double px, double py, double pz)
{
    __global const double *a = s->vert + 9 * t + 3 * j;
    __global const double *b = s->vert + 9 * t + 3 * ((j + 1) % 3);
    __global const double *n = s->normal + 3 * t;
    double e0 = b[0] - a[0], e1 = b[1] - a[1], e2 = b[2] - a[2];
    double d0 = px - a[0], d1 = py - a[1], d2 = pz - a[2];
    double c0 = e1 * d2 - e2 * d1;
    double c1 = e2 * d0 - e0 * d2;
    double c2 = e0 * d1 - e1 * d0;
    double len = sqrt((e0 * e0 + e1 * e1) + e2 * e2);
    return dot3(c0, c1, c2, n[0], n[1], n[2]) / len;
}

/* _inside for one point and triangle: no edge distance negative, or the
 * negative ones no less than min_dist and all across seams. */
CLR_INLINE bool inside_triangle(const Scene64 *s, int t, double px, double py, double pz,
                                double min_dist)
{
    double d[3];
    bool exact = true;
    for (int j = 0; j < 3; ++j) {
        d[j] = edge_distance(s, t, j, px, py, pz);
        exact = exact && (d[j] >= 0.0);
    }
    if (exact)
        return true;
    for (int j = 0; j < 3; ++j)
        if (!(d[j] >= min_dist))
            return false;
    for (int j = 0; j < 3; ++j)
        if (d[j] < 0.0 && !s->seam[3 * t + j])
            return false;
    return true;
}

/* containing_triangles for one point: the triangle of face `face` holding p,
 * `guess` first (the float32 hit, -1 for none), or -1. */
CLR_INLINE int contains(const Scene64 *s, int face, int guess, double px, double py, double pz)
{
    double m = fmax(fmax(fabs(px), fabs(py)), fabs(pz));
    double min_dist = -s->inside_tol * (1.0 + m);
    if (guess >= 0 && s->tri_face[guess] == face && inside_triangle(s, guess, px, py, pz, min_dist))
        return guess;
    if (face < 0 || face >= s->n_faces)
        return -1;
    __global const double *box = s->face_box + 6 * face;
    if (!(px >= box[0] + min_dist && px <= box[3] - min_dist &&
          py >= box[1] + min_dist && py <= box[4] - min_dist &&
          pz >= box[2] + min_dist && pz <= box[5] - min_dist))
        return -1;
    for (int i = s->face_first[face]; i < s->face_first[face + 1]; ++i) {
        int c = s->face_tris[i];
        if (inside_triangle(s, c, px, py, pz, min_dist))
            return c;
    }
    return -1;
}

#define SCENE64_ARGS                                                                  \
    __global const double *vert, __global const double *normal,                       \
    __global const int *tri_face, __global const uchar *seam,                         \
    __global const int *face_first, __global const int *face_tris,                    \
    __global const double *face_box, const int n_faces, const double inside_tol

#define SCENE64_INIT(s)                                                               \
    Scene64 s;                                                                        \
    s.vert = vert; s.normal = normal; s.tri_face = tri_face; s.seam = seam;           \
    s.face_first = face_first; s.face_tris = face_tris; s.face_box = face_box;        \
    s.n_faces = n_faces; s.inside_tol = inside_tol

/* visibility.py: blocked_in_float64 for one segment start + t seg (float64, t in
 * [lo, hi]) whose float32 cast pr (up to tmax32) an any-hit called blocked: up to
 * max_rounds closest float32 hits past lo, each crossed with its triangle's plane in
 * float64. Blocked once a face holds a crossing; clear when no hit is left; blocked
 * still when undecided after max_rounds. The first round ignores the triangle skip
 * (the surface a sight line leaves; -1: none), each later one the last blocker looked
 * past. */
CLR_INLINE bool blocked_in_float64(__global const Bvh8Node *nodes,
                                   __global const float4 *tri4,
                                   __global const int *slot_prim, const Scene64 *s,
                                   const PreparedRay *pr, float tmax32, double s0,
                                   double s1, double s2, double g0, double g1, double g2,
                                   double lo, double hi, int skip, int max_rounds,
                                   double look_past)
{
    for (int round = 0; round < max_rounds; ++round) {
        float t = tmax32, u, v;
        int slot = bvh_closest(nodes, tri4, slot_prim, pr, (float)lo, &t, &u, &v, skip);
        if (slot < 0)
            return false;
        int prim = slot_prim[slot];
        __global const double *w = s->vert + 9 * prim;
        double a0 = w[3] - w[0], a1 = w[4] - w[1], a2 = w[5] - w[2];
        double b0 = w[6] - w[0], b1 = w[7] - w[1], b2 = w[8] - w[2];
        double n0 = a1 * b2 - a2 * b1, n1 = a2 * b0 - a0 * b2, n2 = a0 * b1 - a1 * b0;
        double denom = dot3(n0, n1, n2, g0, g1, g2);
        double tc = dot3(n0, n1, n2, w[0] - s0, w[1] - s1, w[2] - s2) / denom;
        if (isfinite(tc) && tc >= lo && tc <= hi &&
            contains(s, s->tri_face[prim], prim, s0 + tc * g0, s1 + tc * g1, s2 + tc * g2) >= 0)
            return true;   /* the face holds the crossing */
        lo = fmax(lo, (double)t * look_past);
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
