/* Ray-box and watertight ray-triangle tests, and BVH traversal.
 *
 * Triangle test: Woop, Benthin & Wald, "Watertight Ray/Triangle
 * Intersection", JCGT 2(1), 2013. The ray is sheared so it runs along +z;
 * the edge functions U, V, W are then 2-D cross products that two triangles
 * sharing an edge evaluate with the same operands, so a ray through the edge
 * can never slip between them. Where an edge function rounds to exactly 0 it
 * is recomputed in double (when the device has it), as the paper advises.
 *
 * Box test: slabs with the far distance scaled by 1 + 2*gamma(3) (Ize,
 * "Robust BVH Ray Traversal", JCGT 2(2), 2013) so rounding never culls a box
 * that holds a hit the triangle test would find; an axis-parallel ray lying
 * in a slab plane counts as inside that slab. */
#ifndef CLRADCOM_INTERSECT_H
#define CLRADCOM_INTERSECT_H

#include "types.h"

#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#define CLRADCOM_HAS_FP64 1
#endif

/* OpenCL C allows a*b - c*d to be fused into an FMA by default. That breaks
 * the exact antisymmetry of the shared-edge functions the watertight test
 * rests on, so contraction is off for everything that includes this file. */
#pragma OPENCL FP_CONTRACT OFF

/* The stack never holds more entries than the tree is deep; the builder
 * caps depth at this (clradcom.bvh.build_bvh max_depth) and RayCaster checks. */
#define BVH_STACK_SIZE 64
#define ROBUST_TMAX_SCALE 1.0000003576f /* 1 + 2*gamma(3), gamma(n) = n*eps/(1-n*eps) */

typedef struct {
    float3 org;
    float3 inv_dir;
    uint4 perm;         /* (kx, ky, kz, 3): the shear frame as a shuffle mask */
    float sx, sy, sz;
    int axis_parallel;  /* some direction component is exactly 0 */
} PreparedRay;

inline PreparedRay prepare_ray(float3 org, float3 dir)
{
    PreparedRay r;
    r.org = org;
    r.inv_dir = (float3)(1.0f / dir.x, 1.0f / dir.y, 1.0f / dir.z);
    r.axis_parallel = (dir.x == 0.0f) || (dir.y == 0.0f) || (dir.z == 0.0f);
    float ax = fabs(dir.x), ay = fabs(dir.y), az = fabs(dir.z);
    uint kz = (ax > ay) ? ((ax > az) ? 0u : 2u) : ((ay > az) ? 1u : 2u);
    uint kx = (kz == 2u) ? 0u : kz + 1u;
    uint ky = (kx == 2u) ? 0u : kx + 1u;
    float4 d = shuffle((float4)(dir, 0.0f), (uint4)(kx, ky, kz, 3u));
    /* keep the sheared frame right-handed so the winding (and sign of det) is kept */
    if (d.z < 0.0f) { uint tmp = kx; kx = ky; ky = tmp; float td = d.x; d.x = d.y; d.y = td; }
    r.perm = (uint4)(kx, ky, kz, 3u);
    r.sx = d.x / d.z;
    r.sy = d.y / d.z;
    r.sz = 1.0f / d.z;
    return r;
}

/* Entry distance of the ray into the box, or INFINITY when it misses
 * (tmin, tmax). */
inline float ray_box(const PreparedRay *r, float3 bmin, float3 bmax, float tmin, float tmax)
{
    float3 lo = (bmin - r->org) * r->inv_dir;
    float3 hi = (bmax - r->org) * r->inv_dir;
    float3 tn = fmin(lo, hi);
    float3 tf = fmax(lo, hi);
    if (r->axis_parallel) {
        /* 0*inf = NaN only for an axis-parallel ray lying in a slab plane: the
         * ray is inside that slab for all t, so that axis must not cull it.
         * Only such rays pay for the test (vector isnan is slow on PoCL). */
        int3 in_plane = isnan(lo) | isnan(hi);
        tn = select(tn, (float3)(-INFINITY), in_plane);
        tf = select(tf, (float3)(INFINITY), in_plane);
    }
    float t0 = fmax(fmax(tn.x, tn.y), fmax(tn.z, tmin));
    float t1 = fmin(fmin(tf.x, tf.y), fmin(tf.z, tmax)) * ROBUST_TMAX_SCALE;
    return (t0 <= t1) ? t0 : INFINITY;
}

/* Watertight test of one triangle; on a hit in (tmin, tmax) writes t, u, v. */
inline bool ray_triangle(const PreparedRay *r, float4 v0, float4 v1, float4 v2,
                         float tmin, float tmax, float *t_out, float *u_out, float *v_out)
{
    float4 org = (float4)(r->org, 0.0f);
    float4 a = shuffle(v0 - org, r->perm);
    float4 b = shuffle(v1 - org, r->perm);
    float4 c = shuffle(v2 - org, r->perm);
    float ax = a.x - r->sx * a.z, ay = a.y - r->sy * a.z;
    float bx = b.x - r->sx * b.z, by = b.y - r->sy * b.z;
    float cx = c.x - r->sx * c.z, cy = c.y - r->sy * c.z;
    float U = cx * by - cy * bx;
    float V = ax * cy - ay * cx;
    float W = bx * ay - by * ax;
#ifdef CLRADCOM_HAS_FP64
    if (U == 0.0f || V == 0.0f || W == 0.0f) {
        U = (float)((double)cx * (double)by - (double)cy * (double)bx);
        V = (float)((double)ax * (double)cy - (double)ay * (double)cx);
        W = (float)((double)bx * (double)ay - (double)by * (double)ax);
    }
#endif
    if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f))
        return false;
    float det = U + V + W;
    if (det == 0.0f)
        return false;
    float T = U * (r->sz * a.z) + V * (r->sz * b.z) + W * (r->sz * c.z);
    /* compare t = T/det against the range without dividing first */
    float sdet = (det < 0.0f) ? -1.0f : 1.0f;
    float Ts = T * sdet, adet = det * sdet;
    if (Ts <= tmin * adet || Ts >= tmax * adet)
        return false;
    float inv = 1.0f / det;
    *t_out = T * inv;
    *u_out = V * inv;
    *v_out = W * inv;
    return true;
}

inline float3 box_min(__global const float *p) { return (float3)(p[0], p[1], p[2]); }

/* Closest hit along the ray in (tmin, tmax). tri_verts holds three float4
 * per leaf slot (slot i is scene triangle tri_index[i]); returns the slot,
 * -1 on a miss. ignore_prim (a scene id, or -1) is skipped: the surface a
 * reflected ray leaves. */
/* A traversal stack entry packs a child into one int: an inner child's record
 * index (>= 0), or a leaf as -(first_slot * 32 + count) - 1 (leaves hold at
 * most 31 triangles; the builder caps them at 16). Fewer private arrays make
 * PoCL's work-item loops markedly faster. */
#define LEAF_CODE(first, count) (-((first) * 32 + (count)) - 1)

inline int child_code(int ref, int count)
{
    return (count > 0) ? LEAF_CODE(ref, count) : ref;
}

/* Closest hit along the ray in (tmin, tmax). tri_verts holds three float4
 * per leaf slot (slot i is scene triangle tri_index[i]); returns the slot,
 * -1 on a miss. ignore_prim (a scene id, or -1) is skipped: the surface a
 * reflected ray leaves. */
inline int bvh_closest(__global const PairNode *nodes, __global const float4 *tri_verts,
                       __global const int *tri_index, const PreparedRay *r,
                       float tmin, float *tmax_io, float *u_out, float *v_out,
                       int ignore_prim)
{
    int stack_code[BVH_STACK_SIZE];
    float stack_dist[BVH_STACK_SIZE];
    int sp = 0;
    int code = 0;   /* the root record */
    int best = -1;
    float tmax = *tmax_io;
    for (;;) {
        if (code < 0) {
            int packed = -code - 1;
            int first = packed >> 5, last = first + (packed & 31);
            for (int i = first; i < last; ++i) {
                float t, u, v;
                if (ray_triangle(r, tri_verts[3 * i], tri_verts[3 * i + 1], tri_verts[3 * i + 2],
                                 tmin, tmax, &t, &u, &v)
                    && tri_index[i] != ignore_prim) {
                    tmax = t; best = i; *u_out = u; *v_out = v;
                }
            }
        } else {
            __global const PairNode *n = nodes + code;
            float dl = (n->lcount >= 0)
                ? ray_box(r, box_min(n->lmin), box_min(n->lmax), tmin, tmax) : INFINITY;
            float dr = (n->rcount >= 0)
                ? ray_box(r, box_min(n->rmin), box_min(n->rmax), tmin, tmax) : INFINITY;
            int lc = child_code(n->lref, n->lcount), rc = child_code(n->rref, n->rcount);
            if (dl > dr) {
                float td = dl; dl = dr; dr = td;
                int tc = lc; lc = rc; rc = tc;
            }
            if (dl != INFINITY) {
                if (dr != INFINITY) {
                    stack_code[sp] = rc; stack_dist[sp] = dr; ++sp;
                }
                code = lc;
                continue;
            }
        }
        /* pop, skipping subtrees that start beyond the current closest hit */
        for (;;) {
            if (sp == 0) { *tmax_io = tmax; return best; }
            --sp;
            if (stack_dist[sp] <= tmax) break;
        }
        code = stack_code[sp];
    }
}

/* Any hit in (tmin, tmax): shadow / visibility rays. */
inline bool bvh_any(__global const PairNode *nodes, __global const float4 *tri_verts,
                    __global const int *tri_index, const PreparedRay *r,
                    float tmin, float tmax, int ignore_a, int ignore_b)
{
    int stack_code[BVH_STACK_SIZE];
    int sp = 0;
    int code = 0;
    for (;;) {
        if (code < 0) {
            int packed = -code - 1;
            int first = packed >> 5, last = first + (packed & 31);
            for (int i = first; i < last; ++i) {
                float t, u, v;
                int prim = tri_index[i];
                if (prim != ignore_a && prim != ignore_b
                    && ray_triangle(r, tri_verts[3 * i], tri_verts[3 * i + 1],
                                    tri_verts[3 * i + 2], tmin, tmax, &t, &u, &v))
                    return true;
            }
        } else {
            __global const PairNode *n = nodes + code;
            bool hl = (n->lcount >= 0)
                && ray_box(r, box_min(n->lmin), box_min(n->lmax), tmin, tmax) != INFINITY;
            bool hr = (n->rcount >= 0)
                && ray_box(r, box_min(n->rmin), box_min(n->rmax), tmin, tmax) != INFINITY;
            if (hl || hr) {
                if (hl && hr) {
                    stack_code[sp++] = child_code(n->rref, n->rcount);
                }
                code = hl ? child_code(n->lref, n->lcount) : child_code(n->rref, n->rcount);
                continue;
            }
        }
        if (sp == 0) return false;
        code = stack_code[--sp];
    }
}

#endif
