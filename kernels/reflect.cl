/* Candidate search for specular paths: each work item follows one ray from
 * the transmitter through up to max_order specular bounces and writes the
 * ordered sequence of faces it reflects off. The host turns every prefix of
 * every sequence into a candidate and confirms it with the image method, so
 * nothing here needs to be exact: float32 geometry is enough. */
#include "intersect.h"

/* The host's spawn_origins offset (clradcom/device/raycast.py), so a bounce on
 * the device leaves a surface exactly as far as one on the host. */
#ifndef SPAWN_OFFSET_ROUNDOFFS
#error "SPAWN_OFFSET_ROUNDOFFS must be passed as -D by the host"
#endif

/* Push a point off the surface it lies on, toward the side the ray leaves
 * into, by a float32 error bound that grows with |p| (as spawn_origins does
 * on the host). */
inline float3 spawn_point(float3 p, float3 n, float3 dir)
{
    float3 ap = fabs(p);
    float bound = SPAWN_OFFSET_ROUNDOFFS * 0.5f * FLT_EPSILON
                  * (fmax(fmax(ap.x, ap.y), ap.z) + 1.0f);
    return p + ((dot(n, dir) >= 0.0f) ? bound : -bound) * n;
}

/* One ray's face sequence: up to max_order bounces from org along dir, the faces
 * written to out, -1 after the ray escapes. */
CLR_INLINE void follow_ray(__global const Bvh8Node *nodes, __global const float4 *tri_verts,
                           __global const int *tri_index, __global const int *tri_face,
                           float3 org, float3 dir, const int max_order, __global int *out)
{
    int last_prim = -1;
    int depth = 0;
    for (; depth < max_order; ++depth) {
        PreparedRay pr = prepare_ray(org, dir);
        float t = INFINITY, u, v;
        int slot = bvh_closest(nodes, tri_verts, tri_index, &pr, 0.0f, &t, &u, &v, last_prim);
        if (slot < 0) break;
        last_prim = tri_index[slot];
        out[depth] = tri_face[last_prim];
        float3 n = slot_normal(nodes, tri_verts, slot);
        float3 p = org + t * dir;
        dir = dir - 2.0f * dot(dir, n) * n;
        org = spawn_point(p, n, dir);
    }
    for (; depth < max_order; ++depth) out[depth] = -1;
}

__kernel void trace_reflections(__global const Bvh8Node *nodes,
                                __global const float4 *tri_verts,
                                __global const int *tri_index,
                                __global const int *tri_face,
                                const float ox, const float oy, const float oz,
                                __global const float4 *directions,
                                const int max_order,
                                __global int *face_seq,
                                const int n_rays)
{
    int gid = get_global_id(0);
    if (gid >= n_rays) return;
    follow_ray(nodes, tri_verts, tri_index, tri_face, (float3)(ox, oy, oz),
               directions[gid].xyz, max_order, face_seq + (size_t)gid * max_order);
}

#ifdef CLRADCOM_HAS_FP64
/* trace_reflections of the rays lattice[first + gid] (N, 3) float64 rotated by r (row
 * major 3x3, the antenna's axes as columns): dir_j = (l0 r_j0 + l1 r_j1) + l2 r_j2 in
 * double, as the host's numpy rotation sums it (no contraction: intersect.h), then
 * rounded to float as numpy's cast rounds it, so each ray is the host-rotated one bit
 * for bit. The lattice stays on the device between transmitters and traces. */
__kernel void trace_reflections_rotated(__global const Bvh8Node *nodes,
                                        __global const float4 *tri_verts,
                                        __global const int *tri_index,
                                        __global const int *tri_face,
                                        const float ox, const float oy, const float oz,
                                        __global const double *lattice,
                                        const double r00, const double r01, const double r02,
                                        const double r10, const double r11, const double r12,
                                        const double r20, const double r21, const double r22,
                                        const int first,
                                        const int max_order,
                                        __global int *face_seq,
                                        const int n_rays)
{
    int gid = get_global_id(0);
    if (gid >= n_rays) return;
    size_t k = 3 * ((size_t)first + gid);
    double l0 = lattice[k], l1 = lattice[k + 1], l2 = lattice[k + 2];
    float3 dir = (float3)((float)(l0 * r00 + l1 * r01 + l2 * r02),
                          (float)(l0 * r10 + l1 * r11 + l2 * r12),
                          (float)(l0 * r20 + l1 * r21 + l2 * r22));
    follow_ray(nodes, tri_verts, tri_index, tri_face, (float3)(ox, oy, oz), dir, max_order,
               face_seq + (size_t)gid * max_order);
}
#endif
