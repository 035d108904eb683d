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

/* PoCL (3.0, LLVM 14) leaves plain `inline` helpers and even the fmin/fmax/
 * fabs/shuffle builtins as out-of-line calls in the kernel, each passing float3
 * through memory: that, not the algorithm, cost ~100 cycles per node. So the
 * hot path is forced inline and written with scalar compares and selects. */
#define CLR_INLINE inline __attribute__((always_inline))
#define MINF(a, b) ((a) < (b) ? (a) : (b))
#define MAXF(a, b) ((a) > (b) ? (a) : (b))

typedef struct {
    float ox, oy, oz;
    float ix, iy, iz;   /* 1 / dir */
    int kx, ky, kz;     /* the shear frame: dir[kz] is the largest component */
    float sx, sy, sz;
    int axis_parallel;  /* some 1/dir component is infinite (dir component 0 or denormal) */
} PreparedRay;

CLR_INLINE float component(float3 a, int k)
{
    return (k == 0) ? a.x : ((k == 1) ? a.y : a.z);
}

CLR_INLINE PreparedRay prepare_ray(float3 org, float3 dir)
{
    PreparedRay r;
    r.ox = org.x; r.oy = org.y; r.oz = org.z;
    r.ix = 1.0f / dir.x; r.iy = 1.0f / dir.y; r.iz = 1.0f / dir.z;
    r.axis_parallel = !(isfinite(r.ix) && isfinite(r.iy) && isfinite(r.iz));
    float ax = fabs(dir.x), ay = fabs(dir.y), az = fabs(dir.z);
    int kz = (ax > ay) ? ((ax > az) ? 0 : 2) : ((ay > az) ? 1 : 2);
    int kx = (kz == 2) ? 0 : kz + 1;
    int ky = (kx == 2) ? 0 : kx + 1;
    float dz = component(dir, kz);
    /* keep the sheared frame right-handed so the winding (and sign of det) is kept */
    if (dz < 0.0f) { int tmp = kx; kx = ky; ky = tmp; }
    r.kx = kx; r.ky = ky; r.kz = kz;
    r.sx = component(dir, kx) / dz;
    r.sy = component(dir, ky) / dz;
    r.sz = 1.0f / dz;
    return r;
}

/* One slab: entry and exit distance along one axis, ordered. */
#define SLAB(lo_, hi_, b0, b1, o, inv)                                      \
    do {                                                                   \
        float a_ = ((b0) - (o)) * (inv), b_ = ((b1) - (o)) * (inv);        \
        lo_ = MINF(a_, b_); hi_ = MAXF(a_, b_);                            \
    } while (0)

/* As SLAB, for a ray with an infinite 1/dir: 0*inf = NaN only for a ray
 * lying in a slab plane, which is inside that slab for all t, so that axis
 * must not cull it. */
#define SLAB_NAN(lo_, hi_, b0, b1, o, inv)                                  \
    do {                                                                   \
        float a_ = ((b0) - (o)) * (inv), b_ = ((b1) - (o)) * (inv);        \
        bool nan_ = (a_ != a_) || (b_ != b_);                              \
        lo_ = nan_ ? -INFINITY : MINF(a_, b_);                             \
        hi_ = nan_ ? INFINITY : MAXF(a_, b_);                              \
    } while (0)

/* Entry distance of the ray into the box b = (xmin, ymin, zmin, xmax, ymax,
 * zmax), or INFINITY when it misses (tmin, tmax). */
CLR_INLINE float ray_box(const PreparedRay *r, __global const float *bmin,
                         __global const float *bmax, float tmin, float tmax)
{
    float nx, fx, ny, fy, nz, fz;
    if (r->axis_parallel) {
        SLAB_NAN(nx, fx, bmin[0], bmax[0], r->ox, r->ix);
        SLAB_NAN(ny, fy, bmin[1], bmax[1], r->oy, r->iy);
        SLAB_NAN(nz, fz, bmin[2], bmax[2], r->oz, r->iz);
    } else {
        SLAB(nx, fx, bmin[0], bmax[0], r->ox, r->ix);
        SLAB(ny, fy, bmin[1], bmax[1], r->oy, r->iy);
        SLAB(nz, fz, bmin[2], bmax[2], r->oz, r->iz);
    }
    float t0 = MAXF(MAXF(nx, ny), MAXF(nz, tmin));
    float t1 = MINF(MINF(fx, fy), MINF(fz, tmax)) * ROBUST_TMAX_SCALE;
    return (t0 <= t1) ? t0 : INFINITY;
}

/* Both boxes of a PairNode record at once with float8 ops (x, y, z of the
 * left box in lanes 0-2, of the right in 4-6). */
CLR_INLINE void ray_box2(const PreparedRay *r, __global const float *rec, float tmin, float tmax,
                         float *dl, float *dr)
{
    if (r->axis_parallel) {
        *dl = ray_box(r, rec, rec + 4, tmin, tmax);
        *dr = ray_box(r, rec + 8, rec + 12, tmin, tmax);
        return;
    }
    float16 q = vload16(0, rec);
    float8 lo = (float8)(q.s012, 0.0f, q.s89a, 0.0f);
    float8 hi = (float8)(q.s456, 0.0f, q.scde, 0.0f);
    float8 o = (float8)(r->ox, r->oy, r->oz, 0.0f, r->ox, r->oy, r->oz, 0.0f);
    float8 inv = (float8)(r->ix, r->iy, r->iz, 0.0f, r->ix, r->iy, r->iz, 0.0f);
    float8 a = (lo - o) * inv, b = (hi - o) * inv;
    float8 tn = (a < b) ? a : b, tf = (a > b) ? a : b;
    float l0 = MAXF(MAXF(tn.s0, tn.s1), MAXF(tn.s2, tmin));
    float l1 = MINF(MINF(tf.s0, tf.s1), MINF(tf.s2, tmax)) * ROBUST_TMAX_SCALE;
    float r0 = MAXF(MAXF(tn.s4, tn.s5), MAXF(tn.s6, tmin));
    float r1 = MINF(MINF(tf.s4, tf.s5), MINF(tf.s6, tmax)) * ROBUST_TMAX_SCALE;
    *dl = (l0 <= l1) ? l0 : INFINITY;
    *dr = (r0 <= r1) ? r0 : INFINITY;
}

/* Watertight test of one triangle (vertices at p[0..2], p[4..6], p[8..10]);
 * on a hit in (tmin, tmax) writes t, u, v. The shear frame's components are
 * fetched by index (scalar loads) rather than shuffled. */
CLR_INLINE bool ray_triangle(const PreparedRay *r, __global const float *p,
                             float tmin, float tmax, float *t_out, float *u_out, float *v_out)
{
    float okx = (r->kx == 0) ? r->ox : ((r->kx == 1) ? r->oy : r->oz);
    float oky = (r->ky == 0) ? r->ox : ((r->ky == 1) ? r->oy : r->oz);
    float okz = (r->kz == 0) ? r->ox : ((r->kz == 1) ? r->oy : r->oz);
    float az = p[r->kz] - okz, bz = p[4 + r->kz] - okz, cz = p[8 + r->kz] - okz;
    float ax = (p[r->kx] - okx) - r->sx * az, ay = (p[r->ky] - oky) - r->sy * az;
    float bx = (p[4 + r->kx] - okx) - r->sx * bz, by = (p[4 + r->ky] - oky) - r->sy * bz;
    float cx = (p[8 + r->kx] - okx) - r->sx * cz, cy = (p[8 + r->ky] - oky) - r->sy * cz;
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
    float T = U * (r->sz * az) + V * (r->sz * bz) + W * (r->sz * cz);
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

/* Closest hit along the ray in (tmin, tmax). tri_verts holds three float4
 * per leaf slot (slot i is scene triangle tri_index[i]); returns the slot,
 * -1 on a miss. ignore_prim (a scene id, or -1) is skipped: the surface a
 * reflected ray leaves. */
/* A traversal stack entry packs a child into one int: an inner child's record
 * index (>= 0), or a leaf as -(first_slot * 32 + count) - 1 (leaves hold at
 * most 31 triangles; the builder caps them at 16). Fewer private arrays make
 * PoCL's work-item loops markedly faster. */
#define LEAF_CODE(first, count) (-((first) * 32 + (count)) - 1)

CLR_INLINE int child_code(int ref, int count)
{
    return (count > 0) ? LEAF_CODE(ref, count) : ref;
}

/* Closest hit along the ray in (tmin, tmax). tri_verts holds three float4
 * per leaf slot (slot i is scene triangle tri_index[i]); returns the slot,
 * -1 on a miss. ignore_prim (a scene id, or -1) is skipped: the surface a
 * reflected ray leaves. */
CLR_INLINE int bvh_closest(__global const PairNode *nodes, __global const float4 *tri_verts,
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
                if (ray_triangle(r, (__global const float *)(tri_verts + 3 * i),
                                 tmin, tmax, &t, &u, &v)
                    && tri_index[i] != ignore_prim) {
                    tmax = t; best = i; *u_out = u; *v_out = v;
                }
            }
        } else {
            __global const PairNode *n = nodes + code;
            float dl, dr;
            ray_box2(r, (__global const float *)n, tmin, tmax, &dl, &dr);
            if (n->rcount < 0) dr = INFINITY;
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
CLR_INLINE bool bvh_any(__global const PairNode *nodes, __global const float4 *tri_verts,
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
                    && ray_triangle(r, (__global const float *)(tri_verts + 3 * i), tmin, tmax, &t, &u, &v))
                    return true;
            }
        } else {
            __global const PairNode *n = nodes + code;
            float dl, dr;
            ray_box2(r, (__global const float *)n, tmin, tmax, &dl, &dr);
            bool hl = dl != INFINITY;
            bool hr = n->rcount >= 0 && dr != INFINITY;
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
