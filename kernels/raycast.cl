/* Batch ray casting against the 8-wide BVH: one kernel per query type.
 * ignore_prim may be NULL: no ray ignores a triangle. */
#include "intersect.h"

CLR_INLINE PreparedRay prepare_packed_ray(const Ray *ray)
{
    return prepare_ray((float3)(ray->org[0], ray->org[1], ray->org[2]),
                       (float3)(ray->dir[0], ray->dir[1], ray->dir[2]));
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
    Hit h;
    h.pad = 0;
    if (slot < 0) {
        h.t = INFINITY; h.u = 0.0f; h.v = 0.0f; h.prim = -1;
        h.ng[0] = 0.0f; h.ng[1] = 0.0f; h.ng[2] = 0.0f;
    } else {
        float3 ng = slot_normal(nodes, tri4, slot);
        h.t = tmax; h.u = u; h.v = v; h.prim = slot_prim[slot];
        h.ng[0] = ng.x; h.ng[1] = ng.y; h.ng[2] = ng.z;
    }
    hits[gid] = h;
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
