/* Batch ray casting against the 8-wide BVH: one kernel per query type.
 * ignore_prim may be NULL: no ray ignores a triangle. */
#include "intersect.h"

CLR_INLINE PreparedRay prepare_packed_ray(const Ray *ray)
{
    return prepare_ray((float3)(ray->org[0], ray->org[1], ray->org[2]),
                       (float3)(ray->dir[0], ray->dir[1], ray->dir[2]));
}

/* A Hit from a closest-hit traversal's slot (-1: a miss), t, u and v. */
CLR_INLINE Hit hit_record(__global const Bvh8Node *nodes, __global const float4 *tri4,
                          __global const int *slot_prim, int slot, float t, float u, float v)
{
    Hit h;
    h.pad = 0;
    if (slot < 0) {
        h.t = INFINITY; h.u = 0.0f; h.v = 0.0f; h.prim = -1;
        h.ng[0] = 0.0f; h.ng[1] = 0.0f; h.ng[2] = 0.0f;
    } else {
        float3 ng = slot_normal(nodes, tri4, slot);
        h.t = t; h.u = u; h.v = v; h.prim = slot_prim[slot];
        h.ng[0] = ng.x; h.ng[1] = ng.y; h.ng[2] = ng.z;
    }
    return h;
}

__kernel void closest_hit(__global const Bvh8Node *nodes,
                          __global const float4 *tri4,
                          __global const int *slot_prim,
                          __global const Ray *rays,
                          __global const int *ignore_prim,
                          __global Hit *hits,
                          const int n_rays)
{
    int gid = get_global_id(0);
    if (gid >= n_rays) return;
    Ray ray = rays[gid];
    PreparedRay pr = prepare_packed_ray(&ray);
    float tmax = ray.tmax, u = 0.0f, v = 0.0f;
    int slot = bvh_closest(nodes, tri4, slot_prim, &pr, ray.tmin, &tmax, &u, &v,
                           ignore_prim ? ignore_prim[gid] : -1);
    hits[gid] = hit_record(nodes, tri4, slot_prim, slot, tmax, u, v);
}

/* closest_hit's results for rays grouped into packets of at most PACKET_MAX coherent
 * rays (packet p: rays packet_first[p] .. packet_first[p + 1] - 1), one work item per
 * packet walking the tree once for all of them (intersect.h: packet_closest); no ray
 * ignores a triangle. */
__kernel void closest_hit_packets(__global const Bvh8Node *nodes,
                                  __global const float4 *tri4,
                                  __global const int *slot_prim,
                                  __global const Ray *rays,
                                  __global const int *packet_first,
                                  __global Hit *hits,
                                  const int n_packets)
{
    int p = get_global_id(0);
    if (p >= n_packets) return;
    int first = packet_first[p], n = packet_first[p + 1] - first;
    PreparedRay pr[PACKET_MAX];
    int member[PACKET_MAX], best[PACKET_MAX];
    float tmin[PACKET_MAX], tmax[PACKET_MAX], u[PACKET_MAX], v[PACKET_MAX];
    for (int k = 0; k < n; ++k) {
        Ray ray = rays[first + k];
        pr[k] = prepare_packed_ray(&ray);
        member[k] = k;
        tmin[k] = ray.tmin;
        tmax[k] = ray.tmax;
        u[k] = 0.0f;
        v[k] = 0.0f;
    }
    packet_closest(nodes, tri4, slot_prim, pr, member, n, tmin, tmax, u, v, best);
    for (int k = 0; k < n; ++k)
        hits[first + k] = hit_record(nodes, tri4, slot_prim, best[k], tmax[k], u[k], v[k]);
}

__kernel void any_hit(__global const Bvh8Node *nodes,
                      __global const float4 *tri4,
                      __global const int *slot_prim,
                      __global const Ray *rays,
                      __global const int *ignore_prim,
                      __global uchar *occluded,
                      const int n_rays)
{
    int gid = get_global_id(0);
    if (gid >= n_rays) return;
    Ray ray = rays[gid];
    PreparedRay pr = prepare_packed_ray(&ray);
    occluded[gid] = bvh_any(nodes, tri4, slot_prim, &pr, ray.tmin, ray.tmax,
                            ignore_prim ? ignore_prim[gid] : -1, -1) ? 1 : 0;
}
