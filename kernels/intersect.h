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

/* A traversal stack entry packs a child into one int: an inner child's record
 * index (>= 0), or a leaf as -(first_slot * 32 + count) - 1 (leaves hold at
 * most 31 triangles; the builder caps them at 16). Fewer private arrays make
 * PoCL's work-item loops markedly faster. */
#define LEAF_CODE(first, count) (-((first) * 32 + (count)) - 1)

/* The 4-wide stack: a Bvh4Node pushes at most 3 children, and every record
 * on a root-to-leaf path stands for at least one level of the binary tree
 * (depth <= 64, clradcom.bvh.build_bvh max_depth), so 3 * 64 entries always
 * suffice; bvh4_nodes on the host also computes the tree's exact need and
 * refuses a tree that would exceed this. */
#define BVH4_STACK_SIZE 192

/* Entry distances of the ray into the four child boxes of a Bvh4Node record
 * (INFINITY for a miss or an empty slot). Per axis the near plane is picked
 * by the sign of 1/dir, so no min/max orders the slab ends; empty slots have
 * +inf/-inf bounds and are masked by their code as well. */
CLR_INLINE float4 ray_box4(const PreparedRay *r, __global const float *rec, int4 code,
                           float tmin, float tmax)
{
    float4 lx = vload4(0, rec), ly = vload4(1, rec), lz = vload4(2, rec);
    float4 hx = vload4(3, rec), hy = vload4(4, rec), hz = vload4(5, rec);
    float4 nx = (r->ix < 0.0f) ? hx : lx, fx = (r->ix < 0.0f) ? lx : hx;
    float4 ny = (r->iy < 0.0f) ? hy : ly, fy = (r->iy < 0.0f) ? ly : hy;
    float4 nz = (r->iz < 0.0f) ? hz : lz, fz = (r->iz < 0.0f) ? lz : hz;
    float4 ox = (float4)(r->ox), oy = (float4)(r->oy), oz = (float4)(r->oz);
    float4 ix = (float4)(r->ix), iy = (float4)(r->iy), iz = (float4)(r->iz);
    float4 tnx = (nx - ox) * ix, tfx = (fx - ox) * ix;
    float4 tny = (ny - oy) * iy, tfy = (fy - oy) * iy;
    float4 tnz = (nz - oz) * iz, tfz = (fz - oz) * iz;
    if (r->axis_parallel) {
        /* 0 * inf = NaN only for a ray lying in a slab plane: inside that slab */
        float4 ninf = (float4)(-INFINITY), pinf = (float4)(INFINITY);
        tnx = (tnx != tnx) ? ninf : tnx; tfx = (tfx != tfx) ? pinf : tfx;
        tny = (tny != tny) ? ninf : tny; tfy = (tfy != tfy) ? pinf : tfy;
        tnz = (tnz != tnz) ? ninf : tnz; tfz = (tfz != tfz) ? pinf : tfz;
    }
    float4 t0 = MAXF(MAXF(tnx, tny), MAXF(tnz, (float4)(tmin)));
    float4 t1 = MINF(MINF(tfx, tfy), MINF(tfz, (float4)(tmax))) * ROBUST_TMAX_SCALE;
    int4 hit = (t0 <= t1) & (code != (int4)(0));
    return hit ? t0 : (float4)(INFINITY);
}

#define CSWAP(da, ca, db, cb)                                               \
    do {                                                                   \
        bool s_ = (db) < (da);                                             \
        float td_ = s_ ? (db) : (da); (db) = s_ ? (da) : (db); (da) = td_; \
        int tc_ = s_ ? (cb) : (ca); (cb) = s_ ? (ca) : (cb); (ca) = tc_;   \
    } while (0)

/* Closest hit along the ray in (tmin, tmax). tri_verts holds three float4
 * per leaf slot (slot i is scene triangle tri_index[i]); returns the slot,
 * -1 on a miss. ignore_prim (a scene id, or -1) is skipped: the surface a
 * reflected ray leaves. A record with one hit child goes straight on to it;
 * with more, the hit children are sorted near to far (a 5-exchange network,
 * misses sort last as INFINITY), the nearest is visited next and the rest
 * pushed far first. */
CLR_INLINE int bvh_closest(__global const Bvh4Node *nodes, __global const float4 *tri_verts,
                       __global const int *tri_index, const PreparedRay *r,
                       float tmin, float *tmax_io, float *u_out, float *v_out,
                       int ignore_prim)
{
    int stack_code[BVH4_STACK_SIZE];
    float stack_dist[BVH4_STACK_SIZE];
    int sp = 0;
    int code = 0;   /* the root record */
    bool inner = true;
    int best = -1;
    float tmax = *tmax_io;
    for (;;) {
        if (!inner) {
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
            __global const float *rec = (__global const float *)(nodes + code);
            int4 c = vload4(6, (__global const int *)rec);
            float4 d = ray_box4(r, rec, c, tmin, tmax);
            float d0 = d.s0, d1 = d.s1, d2 = d.s2, d3 = d.s3;
            int c0 = c.s0, c1 = c.s1, c2 = c.s2, c3 = c.s3;
            int nh = (d0 != INFINITY) + (d1 != INFINITY) + (d2 != INFINITY) + (d3 != INFINITY);
            if (nh == 0) goto pop;
            if (nh == 1) {
                code = (d0 != INFINITY) ? c0 : ((d1 != INFINITY) ? c1 : ((d2 != INFINITY) ? c2 : c3));
                inner = code > 0;
                continue;
            }
            CSWAP(d0, c0, d1, c1);
            CSWAP(d2, c2, d3, c3);
            CSWAP(d0, c0, d2, c2);
            CSWAP(d1, c1, d3, c3);
            CSWAP(d1, c1, d2, c2);
            if (d0 != INFINITY) {
                if (d3 != INFINITY) { stack_code[sp] = c3; stack_dist[sp] = d3; ++sp; }
                if (d2 != INFINITY) { stack_code[sp] = c2; stack_dist[sp] = d2; ++sp; }
                if (d1 != INFINITY) { stack_code[sp] = c1; stack_dist[sp] = d1; ++sp; }
                code = c0;
                inner = code > 0;
                continue;
            }
        }
        /* pop, skipping subtrees that start beyond the current closest hit */
    pop:
        for (;;) {
            if (sp == 0) { *tmax_io = tmax; return best; }
            --sp;
            if (stack_dist[sp] <= tmax) break;
        }
        code = stack_code[sp];
        inner = code > 0;
    }
}

/* Any hit in (tmin, tmax): shadow / visibility rays. */
CLR_INLINE bool bvh_any(__global const Bvh4Node *nodes, __global const float4 *tri_verts,
                    __global const int *tri_index, const PreparedRay *r,
                    float tmin, float tmax, int ignore_a, int ignore_b)
{
    int stack_code[BVH4_STACK_SIZE + 1];   /* pushes all hit children, then pops one */
    int sp = 0;
    int code = 0;
    bool inner = true;
    for (;;) {
        if (!inner) {
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
            __global const float *rec = (__global const float *)(nodes + code);
            int4 c = vload4(6, (__global const int *)rec);
            float4 d = ray_box4(r, rec, c, tmin, tmax);
            if (d.s3 != INFINITY) stack_code[sp++] = c.s3;
            if (d.s2 != INFINITY) stack_code[sp++] = c.s2;
            if (d.s1 != INFINITY) stack_code[sp++] = c.s1;
            if (d.s0 != INFINITY) stack_code[sp++] = c.s0;
        }
        if (sp == 0) return false;
        code = stack_code[--sp];
        inner = code > 0;
    }
}

#endif
