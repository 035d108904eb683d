/* Batched visibility for every mechanism: one work item per segment, the float32
 * BVH cast and, where its answer could be a float32 artefact, the float64
 * re-decision, all in one launch (clradcom/device/visibility.py drives it).
 *
 * The float64 part repeats the host reference of clradcom/device/visibility.py
 * operation for operation, so the two decide every segment alike:
 *
 *   contains()         = containing_triangles for one point: the guessed
 *                        triangle, else every triangle of the face in ascending
 *                        id after the face's box cut; a point may lie up to
 *                        inside_tol x (1 + max |p|) outside an edge only where
 *                        that edge is a seam of the face (seam table), never a rim;
 *   segments_blocked   = segments_clear: any hit in float32, then up to
 *                        max_rounds closest hits, each crossed with its
 *                        triangle's plane in float64 and kept as a blocker only
 *                        where the face holds the crossing (blocked_in_float64);
 *   reach_faces        = reaches_face: the closest float32 hit must be the face
 *                        at the end (or nothing); the end's triangle in float64.
 *
 * Products are rounded one by one (FP_CONTRACT OFF, from intersect.h) and the
 * three-term dot products add in numpy's order (DOT3_ORDER, probed on the host:
 * numpy's einsum adds its lanes in an order that depends on the CPU). Without fp64 the
 * same steps run in precise.h's double-float, the float64 inputs as (hi, lo) pairs
 * (pr_elem): the decisions are the host's except within its rounding of a threshold
 * (scene64.h). */
#include "scene64.h"

/* blocked[i] = 1 where something blocks segment i: rays[i] is its float32 cast
 * (make_rays of start, seg, tmin, tmax), start/seg/tmin/tmax the same in float64.
 * ignore_prim (NULL: none) is skipped by the any-hit and by the first float64 round (the
 * surface a sight line leaves); with max_rounds = 0 a float32 hit stands, otherwise it
 * is re-decided in float64 (scene64.h: blocked_in_float64). */
__kernel void segments_blocked(__global const Bvh8Node *nodes, __global const float4 *tri4,
                               __global const int *slot_prim, SCENE64_ARGS,
                               __global const Ray *rays, __global const pr_elem *start,
                               __global const pr_elem *seg, __global const pr_elem *tmin,
                               __global const pr_elem *tmax, __global const int *ignore_prim,
                               const int max_rounds, const pr_elem look_past,
                               __global uchar *blocked, const int n)
{
    int i = get_global_id(0);
    if (i >= n) return;
    SCENE64_INIT(s);
    Ray ray = rays[i];
    PreparedRay pr = prepare_packed(&ray);
    int skip = ignore_prim ? ignore_prim[i] : -1;
    if (!bvh_any(nodes, tri4, slot_prim, &pr, ray.tmin, ray.tmax, skip, -1)) {
        blocked[i] = 0;
        return;
    }
    blocked[i] = blocked_in_float64(nodes, tri4, slot_prim, &s, &pr, ray.tmax,
                                    pr_of(start[3 * i]), pr_of(start[3 * i + 1]),
                                    pr_of(start[3 * i + 2]), pr_of(seg[3 * i]),
                                    pr_of(seg[3 * i + 1]), pr_of(seg[3 * i + 2]),
                                    pr_of(tmin[i]), pr_of(tmax[i]), skip, max_rounds,
                                    pr_of(look_past)) ? 1 : 0;
}

/* tri[i]: the triangle of face faces[i] holding end[i] where the segment
 * start -> end first meets that face there (|t - 1| <= slack[i]) or meets
 * nothing; else -1. rays[i] is its float32 cast (make_rays of start,
 * end - start, tmin, 1 + 2 slack). */
__kernel void reach_faces(__global const Bvh8Node *nodes, __global const float4 *tri4,
                          __global const int *slot_prim, SCENE64_ARGS,
                          __global const Ray *rays, __global const pr_elem *end,
                          __global const int *faces, __global const pr_elem *slack,
                          __global int *tri, const int n)
{
    int i = get_global_id(0);
    if (i >= n) return;
    SCENE64_INIT(s);
    Ray ray = rays[i];
    PreparedRay pr = prepare_packed(&ray);
    float t = ray.tmax, u, v;
    int slot = bvh_closest(nodes, tri4, slot_prim, &pr, ray.tmin, &t, &u, &v, -1);
    int prim = (slot >= 0) ? slot_prim[slot] : -1;
    int face = faces[i];
    bool reached = prim < 0 || (tri_face[prim] == face
                                && pr_le(pr_from_float(fabs(t - 1.0f)), pr_of(slack[i])));
    tri[i] = reached ? contains(&s, face, prim, pr_of(end[3 * i]), pr_of(end[3 * i + 1]),
                                pr_of(end[3 * i + 2])) : -1;
}
