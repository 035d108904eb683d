/* Ray-box and watertight ray-triangle tests, and BVH traversal.
 *
 * Triangle test: Woop, Benthin & Wald, "Watertight Ray/Triangle
 * Intersection", JCGT 2(1), 2013. The ray is sheared so it runs along +z;
 * the edge functions U, V, W are then 2-D cross products that two triangles
 * sharing an edge evaluate with the same operands, so a ray through the edge
 * can never slip between them. Where an edge function rounds to exactly 0 it
 * is recomputed in double (without fp64 by Kahan's fma algorithm, whose sign is
 * exact as well), as the paper advises.
 * Leaves keep their triangles in groups of four (Tri4 below) tested with
 * float4 operations: every lane does exactly the scalar test's operations in
 * the same order, so each lane's result is the scalar test's, bit for bit.
 *
 * Box test: slabs with the far distance scaled by 1 + 2*gamma(3) (Ize,
 * "Robust BVH Ray Traversal", JCGT 2(2), 2013) so rounding never culls a box
 * that holds a hit the triangle test would find; an axis-parallel ray lying
 * in a slab plane is never culled by that slab. Eight boxes per record
 * (Bvh8Node), tested with float8 operations.
 *
 * Two levels (-D BVH_INSTANCED, for scenes whose objects move): record 0 of
 * `nodes` is then the root of a top-level BVH over instances; a top-level
 * leaf is one instance (Bvh8Instance, types.h): a bottom-level BVH in the
 * same three buffers, placed in the world by a rigid transform. The ray is
 * taken into the instance's frame (a rotation keeps t) and the bottom-level
 * tree walked from its root; identity instances (the static scene, and
 * moving parts whose groups and boxes the host refits in world coordinates
 * every step) use the world ray as is. Without the define the traversal is the single-level one,
 * bit for bit. docs/bvh.md ("Two levels") has the layout.
 *
 * docs/bvh.md ("Performance") records what was measured to get here. */
#ifndef CLRADCOM_INTERSECT_H
#define CLRADCOM_INTERSECT_H

#include "fastmath.h"
#include "types.h"

/* From the host (clradcom/geometry/layout.py), like BVH_WIDTH in types.h. */
#ifndef BVH_STACK_SIZE
#error "BVH_STACK_SIZE must be passed as -D by the host"
#endif
#ifndef TRI4_ROWS
#error "TRI4_ROWS must be passed as -D by the host"
#endif
#if TRI4_ROWS != 9
#error "ray_tri4 reads three vertices of three coordinates: TRI4_ROWS must be 9"
#endif
#ifndef LEAF_GROUP_BITS
#error "LEAF_GROUP_BITS must be passed as -D by the host"
#endif

#ifdef CLRADCOM_FP64   /* fp64.h, through fastmath.h */
#define CLRADCOM_HAS_FP64 1
#endif

/* OpenCL C allows a*b - c*d to be fused into an FMA by default. That breaks
 * the exact antisymmetry of the shared-edge functions the watertight test
 * rests on, so contraction is off for everything that includes this file. */
#pragma OPENCL FP_CONTRACT OFF

#define ROBUST_TMAX_SCALE 1.0000003576f /* 1 + 2*gamma(3), gamma(n) = n*eps/(1-n*eps) */

/* PoCL (3.0, LLVM 14) leaves plain `inline` helpers and even builtins such as
 * vload4/vstore8, fabs, isfinite, any, fmin/fmax as out-of-line calls in the
 * kernel, each passing vectors through memory: in the traversal loop that,
 * not the algorithm, cost ~100 cycles per node (seven vload4 calls per node
 * cost ~25% of the 4-wide traversal). So the hot path is forced inline,
 * loads vectors through typed pointers and uses plain compares and selects
 * instead of those builtins. */
#define CLR_INLINE inline __attribute__((always_inline))
#define MINF(a, b) ((a) < (b) ? (a) : (b))
#define MAXF(a, b) ((a) > (b) ? (a) : (b))
#define ABSF(a) ((a) < 0.0f ? -(a) : (a))

/* CLR_NO_TARGET_BUILTINS (the host sets it for Oclgrind, whose interpreter cannot run
 * llvm.cttz or the AVX mask builtin) keeps to OpenCL C's own builtins. */
#if defined(__has_builtin) && !defined(CLR_NO_TARGET_BUILTINS)
#if __has_builtin(__builtin_ctz)
#define CLR_CTZ(x) __builtin_ctz(x)
#endif
#endif
#ifndef CLR_CTZ   /* lowest set bit by clz (OpenCL 1.1; ctz needs OpenCL C 2.0) */
#define CLR_CTZ(x) (31 - (int)clz((uint)(x) & (0u - (uint)(x))))
#endif

/* The hit mask of eight box tests: one vmovmskps on an AVX CPU (PoCL), ~10%
 * faster traversal than the portable OR-reduction every other device gets. */
#if defined(__AVX__) && defined(__has_builtin) && !defined(CLR_NO_MOVMSK) \
    && !defined(CLR_NO_TARGET_BUILTINS)
#if __has_builtin(__builtin_ia32_movmskps256)
#define CLR_MOVMSK8 1
#endif
#endif

typedef struct {
    float ox, oy, oz;
    float ix, iy, iz;   /* 1 / dir */
    int nx, ny, nz;     /* the Bvh8Node rows holding the near planes (far: 3 rows on) */
    int kx, ky, kz;     /* the shear frame: dir[kz] is the largest component */
    float sx, sy, sz;
#ifdef BVH_INSTANCED
    float dx, dy, dz;   /* the direction itself, to take the ray into an instance */
#endif
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
    /* rows 0-2 of a record hold the minima, rows 3-5 the maxima; a ray running
     * toward -axis enters through the maximum */
    r.nx = (r.ix < 0.0f) ? 3 : 0;
    r.ny = (r.iy < 0.0f) ? 4 : 1;
    r.nz = (r.iz < 0.0f) ? 5 : 2;
    float ax = ABSF(dir.x), ay = ABSF(dir.y), az = ABSF(dir.z);
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
#ifdef BVH_INSTANCED
    r.dx = dir.x; r.dy = dir.y; r.dz = dir.z;
#endif
    return r;
}

/* A Tri4 group is TRI4_ROWS = 9 float4 rows (144 bytes): row 3*j + k holds
 * coordinate k (x, y, z) of vertex j of four triangles, one per lane, so the
 * shear frame picks its rows by index, without shuffles. Leaf slot s is lane
 * s % 4 of group s / 4; lanes past a leaf's last triangle repeat that triangle
 * (an equal t never replaces a hit, and a repeat has the same scene id, so
 * ignore_prim treats it alike). See clradcom/geometry/layout.py: tri4_groups. */

#define ANY4(m) (((m).s0 | (m).s1 | (m).s2 | (m).s3) != 0)

#ifndef CLRADCOM_HAS_FP64
/* a*b - c*d by Kahan's algorithm (the rounding error of c*d recovered by an fma): within
 * 2 ulp of the exact value (Jeannerod, Louvet & Muller, Math. Comp. 82, 2013), so its
 * sign is exact and it is 0 only where the exact value is. The watertight test's
 * re-evaluation of an edge function that rounded to 0 without fp64: the same signs as
 * the double products (exact for float operands), the value within 2 ulp of theirs. */
CLR_INLINE float4 kahan_det4(float4 a, float4 b, float4 c, float4 d)
{
    float4 w = c * d;
    float4 e = fma(-c, d, w);
    float4 f = fma(a, b, -w);
    return f + e;
}
#endif

/* Watertight test of the four triangles of group g: returns the lanes hit in
 * (tmin, tmax) (all bits set) and writes T, det and the edge functions V, W
 * (t = T/det, u = V/det, v = W/det). */
CLR_INLINE int4 ray_tri4(const PreparedRay *r, __global const float4 *g, float tmin, float tmax,
                         float4 *T_out, float4 *det_out, float4 *V_out, float4 *W_out)
{
    float okx = (r->kx == 0) ? r->ox : ((r->kx == 1) ? r->oy : r->oz);
    float oky = (r->ky == 0) ? r->ox : ((r->ky == 1) ? r->oy : r->oz);
    float okz = (r->kz == 0) ? r->ox : ((r->kz == 1) ? r->oy : r->oz);
    float4 sx = (float4)(r->sx), sy = (float4)(r->sy);
    float4 az = g[r->kz] - okz, bz = g[3 + r->kz] - okz, cz = g[6 + r->kz] - okz;
    float4 ax = (g[r->kx] - okx) - sx * az, ay = (g[r->ky] - oky) - sy * az;
    float4 bx = (g[3 + r->kx] - okx) - sx * bz, by = (g[3 + r->ky] - oky) - sy * bz;
    float4 cx = (g[6 + r->kx] - okx) - sx * cz, cy = (g[6 + r->ky] - oky) - sy * cz;
    float4 U = cx * by - cy * bx;
    float4 V = ax * cy - ay * cx;
    float4 W = bx * ay - by * ax;
    int4 zero = (U == 0.0f) | (V == 0.0f) | (W == 0.0f);
    if (ANY4(zero)) {
#ifdef CLRADCOM_HAS_FP64
        double4 dax = convert_double4(ax), day = convert_double4(ay);
        double4 dbx = convert_double4(bx), dby = convert_double4(by);
        double4 dcx = convert_double4(cx), dcy = convert_double4(cy);
        U = zero ? convert_float4(dcx * dby - dcy * dbx) : U;
        V = zero ? convert_float4(dax * dcy - day * dcx) : V;
        W = zero ? convert_float4(dbx * day - dby * dax) : W;
#else
        U = zero ? kahan_det4(cx, by, cy, bx) : U;
        V = zero ? kahan_det4(ax, cy, ay, cx) : V;
        W = zero ? kahan_det4(bx, ay, by, ax) : W;
#endif
    }
    int4 mixed = ((U < 0.0f) | (V < 0.0f) | (W < 0.0f)) & ((U > 0.0f) | (V > 0.0f) | (W > 0.0f));
    float4 det = U + V + W;
    float4 sz = (float4)(r->sz);
    float4 T = U * (sz * az) + V * (sz * bz) + W * (sz * cz);
    /* compare t = T/det against the range without dividing first */
    float4 sdet = (det < 0.0f) ? (float4)(-1.0f) : (float4)(1.0f);
    float4 Ts = T * sdet, adet = det * sdet;
    *T_out = T;
    *det_out = det;
    *V_out = V;
    *W_out = W;
    return ~mixed & (det != 0.0f) & (Ts > tmin * adet) & (Ts < tmax * adet);
}

/* The nearest of a group's four hits t (misses at +inf), the first of equals: its lane,
 * with its t, u and v in *t_out, *u_out, *v_out. */
CLR_INLINE int nearest_lane(float4 t, float4 u, float4 v, float *t_out, float *u_out,
                            float *v_out)
{
    float tb = t.s0, ub = u.s0, vb = v.s0;
    int lane = 0;
    if (t.s1 < tb) { tb = t.s1; ub = u.s1; vb = v.s1; lane = 1; }
    if (t.s2 < tb) { tb = t.s2; ub = u.s2; vb = v.s2; lane = 2; }
    if (t.s3 < tb) { tb = t.s3; ub = u.s3; vb = v.s3; lane = 3; }
    *t_out = tb;
    *u_out = ub;
    *v_out = vb;
    return lane;
}

/* Vertex j (0-2) of leaf slot s. */
CLR_INLINE float3 tri4_vertex(__global const float4 *tri4, int slot, int j)
{
    __global const float *p = (__global const float *)(tri4 + (slot >> 2) * TRI4_ROWS + 3 * j)
                              + (slot & 3);
    return (float3)(p[0], p[4], p[8]);
}

/* Unit geometric normal (v1 - v0) x (v2 - v0) of leaf slot s. */
CLR_INLINE float3 tri4_normal(__global const float4 *tri4, int slot)
{
    float3 v0 = tri4_vertex(tri4, slot, 0);
    return normalize(cross(tri4_vertex(tri4, slot, 1) - v0, tri4_vertex(tri4, slot, 2) - v0));
}

/* A child code (and a traversal stack entry) is one int: an inner child's
 * record index (> 0; record 0 is the root), or a leaf as
 * -(first_group << LEAF_GROUP_BITS | groups) - 1 (at most LEAF_GROUP_MASK Tri4
 * groups); empty slots hold 0 and have +inf/-inf bounds, which no ray can hit. */
#define LEAF_GROUP_MASK ((1 << LEAF_GROUP_BITS) - 1)
#define LEAF_CODE(first, count) (-(((first) << LEAF_GROUP_BITS) + (count)) - 1)

/* BVH_STACK_SIZE: every Bvh8Node on a root-to-leaf path stands for at least
 * one level of the binary tree (depth <= 64, clradcom.geometry.bvh.build_bvh
 * max_depth) and pushes at most 7 entries; clradcom/geometry/layout.py:
 * bvh8_nodes computes the tree's exact need and refuses a tree that needs more
 * than the host's BVH_STACK_SIZE. */

/* Entry distances of the ray into the eight child boxes of a record, and
 * the mask of boxes hit in [tmin, tmax]. Empty slots never hit: their +inf
 * minima and -inf maxima give an entry of +inf and an exit of -inf. */
CLR_INLINE float8 ray_box8(const PreparedRay *r, __global const float8 *q, float tmin,
                           float tmax, int *mask)
{
    float8 ox = (float8)(r->ox), oy = (float8)(r->oy), oz = (float8)(r->oz);
    float8 ix = (float8)(r->ix), iy = (float8)(r->iy), iz = (float8)(r->iz);
    float8 tnx = (q[r->nx] - ox) * ix, tfx = (q[3 - r->nx] - ox) * ix;
    float8 tny = (q[r->ny] - oy) * iy, tfy = (q[5 - r->ny] - oy) * iy;
    float8 tnz = (q[r->nz] - oz) * iz, tfz = (q[7 - r->nz] - oz) * iz;
    /* A ray lying in a slab plane gives 0 * inf = NaN. MAXF(a, b) and MINF(a, b)
     * return b when either is NaN, so in this order a NaN only ever drops
     * distances (never tmin or tmax): the interval widens, and a box the ray
     * touches is never culled (tests/test_raycast.py: the octahedron ridge). */
    float8 t0 = MAXF(MAXF(tnx, tny), MAXF(tnz, (float8)(tmin)));
    float8 t1 = MINF(MINF(tfx, tfy), MINF(tfz, (float8)(tmax))) * ROBUST_TMAX_SCALE;
#ifdef CLR_MOVMSK8
    *mask = __builtin_ia32_movmskps256(as_float8(t0 <= t1));
#else
    int8 bits = (t0 <= t1) & (int8)(1, 2, 4, 8, 16, 32, 64, 128);
    int4 b4 = bits.lo | bits.hi;
    int2 b2 = b4.lo | b4.hi;
    *mask = b2.x | b2.y;
#endif
    return t0;
}

/* Closest hit along the ray in (tmin, tmax). tri4 holds the Tri4 groups in
 * leaf order, slot_prim the scene triangle id of every leaf slot; returns the
 * slot (-1 on a miss) and sets *tmax_io, *u_out, *v_out. ignore_prim (a scene
 * id, or -1) is skipped: the surface a reflected ray leaves.
 *
 * Ordered traversal: a record with one hit child goes straight on to it; with
 * two, the far one is pushed; with more, all are pushed and the run sorted far
 * to near by insertion, and the nearest popped at once. Stack entries keep
 * their entry distance, so subtrees beyond the closest hit so far are skipped
 * when popped. */
CLR_INLINE int blas_closest(__global const Bvh8Node *nodes, __global const float4 *tri4,
                            __global const int *slot_prim, const PreparedRay *r, int root,
                            float tmin, float *tmax_io, float *u_out, float *v_out,
                            int ignore_prim)
{
    int stack_code[BVH_STACK_SIZE + 1];   /* a record may push all 8 before popping one */
    float stack_dist[BVH_STACK_SIZE + 1];
    int sp = 0;
    int code = root;   /* the root record */
    int best = -1;
    float tmax = *tmax_io;
    for (;;) {
        if (code < 0) {
            int packed = -code - 1;
            int first = packed >> LEAF_GROUP_BITS, last = first + (packed & LEAF_GROUP_MASK);
            for (int gi = first; gi < last; ++gi) {
                float4 T, det, V, W;
                int4 ok = ray_tri4(r, tri4 + gi * TRI4_ROWS, tmin, tmax, &T, &det, &V, &W);
                if (ignore_prim >= 0)
                    ok &= (*(__global const int4 *)(slot_prim + 4 * gi) != (int4)(ignore_prim));
                if (!ANY4(ok))
                    continue;
                float4 inv = (float4)(1.0f) / det;
                float4 t = ok ? T * inv : (float4)(INFINITY);
                best = 4 * gi + nearest_lane(t, V * inv, W * inv, &tmax, u_out, v_out);
            }
        } else {
            __global const float8 *q = (__global const float8 *)(nodes + code);
            int mask;
            float8 dv = ray_box8(r, q, tmin, tmax, &mask);
            if (mask != 0) {
                const float *d = (const float *)&dv;
                __global const int *cc = (__global const int *)(q + 6);
                int i0 = CLR_CTZ(mask);
                mask &= mask - 1;
                if (mask == 0) {
                    code = cc[i0];
                    continue;
                }
                int i1 = CLR_CTZ(mask);
                mask &= mask - 1;
                float da = d[i0], db = d[i1];
                int ca = cc[i0], cb = cc[i1];
                if (db < da) {
                    float tf = da; da = db; db = tf;
                    int tc = ca; ca = cb; cb = tc;
                }
                if (mask == 0) {
                    stack_code[sp] = cb; stack_dist[sp] = db; ++sp;
                    code = ca;
                    continue;
                }
                int base = sp;
                stack_code[sp] = cb; stack_dist[sp] = db; ++sp;
                stack_code[sp] = ca; stack_dist[sp] = da; ++sp;
                do {
                    int i = CLR_CTZ(mask);
                    mask &= mask - 1;
                    float di = d[i];
                    int ci = cc[i];
                    int j = sp;
                    while (j > base && stack_dist[j - 1] < di) {
                        stack_dist[j] = stack_dist[j - 1];
                        stack_code[j] = stack_code[j - 1];
                        --j;
                    }
                    stack_dist[j] = di;
                    stack_code[j] = ci;
                    ++sp;
                } while (mask != 0);
                code = stack_code[--sp];
                continue;
            }
        }
        /* pop, skipping subtrees that start beyond the closest hit so far */
        for (;;) {
            if (sp == 0) { *tmax_io = tmax; return best; }
            --sp;
            if (stack_dist[sp] <= tmax) break;
        }
        code = stack_code[sp];
    }
}

/* An any-hit traversal's inner node: every child whose box the ray meets in
 * (tmin, tmax) pushed, in slot order (any hit ends the search, so no sorting);
 * returns the new stack size. */
CLR_INLINE int push_hit_children(const PreparedRay *r, __global const Bvh8Node *nodes,
                                 int code, float tmin, float tmax, int *stack_code, int sp)
{
    __global const float8 *q = (__global const float8 *)(nodes + code);
    int mask;
    ray_box8(r, q, tmin, tmax, &mask);
    __global const int *cc = (__global const int *)(q + 6);
    while (mask != 0) {
        int i = CLR_CTZ(mask);
        mask &= mask - 1;
        stack_code[sp++] = cc[i];
    }
    return sp;
}

/* The children of a record in `mask` (entry distances d, codes cc) pushed sorted far to
 * near, the nearest on top; returns the new stack size. */
CLR_INLINE int push_sorted(int mask, const float *d, __global const int *cc, int *stack_code,
                           float *stack_dist, int sp)
{
    int base = sp;
    while (mask != 0) {
        int i = CLR_CTZ(mask);
        mask &= mask - 1;
        int j = sp;
        while (j > base && stack_dist[j - 1] < d[i]) {
            stack_dist[j] = stack_dist[j - 1];
            stack_code[j] = stack_code[j - 1];
            --j;
        }
        stack_dist[j] = d[i];
        stack_code[j] = cc[i];
        ++sp;
    }
    return sp;
}

/* Any hit in (tmin, tmax): shadow / visibility rays. Slots whose scene id is
 * ignore_a or ignore_b do not count. */
CLR_INLINE bool blas_any(__global const Bvh8Node *nodes, __global const float4 *tri4,
                         __global const int *slot_prim, const PreparedRay *r, int root,
                         float tmin, float tmax, int ignore_a, int ignore_b)
{
    int stack_code[BVH_STACK_SIZE + 1];   /* pushes all hit children, then pops one */
    int sp = 0;
    int code = root;
    for (;;) {
        if (code < 0) {
            int packed = -code - 1;
            int first = packed >> LEAF_GROUP_BITS, last = first + (packed & LEAF_GROUP_MASK);
            for (int gi = first; gi < last; ++gi) {
                float4 T, det, V, W;
                int4 ok = ray_tri4(r, tri4 + gi * TRI4_ROWS, tmin, tmax, &T, &det, &V, &W);
                if (ANY4(ok)) {
                    int4 prim = *(__global const int4 *)(slot_prim + 4 * gi);
                    ok &= (prim != (int4)(ignore_a)) & (prim != (int4)(ignore_b));
                    if (ANY4(ok))
                        return true;
                }
            }
        } else {
            sp = push_hit_children(r, nodes, code, tmin, tmax, stack_code, sp);
        }
        if (sp == 0) return false;
        code = stack_code[--sp];
    }
}

#ifndef BVH_INSTANCED

/* One level: the tree's root is record 0. */
CLR_INLINE int bvh_closest(__global const Bvh8Node *nodes, __global const float4 *tri4,
                           __global const int *slot_prim, const PreparedRay *r,
                           float tmin, float *tmax_io, float *u_out, float *v_out,
                           int ignore_prim)
{
    return blas_closest(nodes, tri4, slot_prim, r, 0, tmin, tmax_io, u_out, v_out,
                        ignore_prim);
}

CLR_INLINE bool bvh_any(__global const Bvh8Node *nodes, __global const float4 *tri4,
                        __global const int *slot_prim, const PreparedRay *r,
                        float tmin, float tmax, int ignore_a, int ignore_b)
{
    return blas_any(nodes, tri4, slot_prim, r, 0, tmin, tmax, ignore_a, ignore_b);
}

/* World-space unit normal of leaf slot s. */
CLR_INLINE float3 slot_normal(__global const Bvh8Node *nodes, __global const float4 *tri4,
                              int slot)
{
    return tri4_normal(tri4, slot);
}

#else

/* Two levels. Record 0 (the top-level root) keeps in pad[0] the record of the
 * first Bvh8Instance and in pad[1] their number; a top-level leaf code holds
 * its instance as LEAF_CODE(instance, 1). */
CLR_INLINE __global const Bvh8Instance *instance_of(__global const Bvh8Node *nodes, int code)
{
    int k = (-code - 1) >> LEAF_GROUP_BITS;
    return (__global const Bvh8Instance *)(nodes + nodes[0].pad[0] + k);
}

/* The ray in the instance's frame: local = R^T (world - p), as the host's
 * clradcom/geometry/instances.py writes R^T and p. */
CLR_INLINE PreparedRay instance_ray(const PreparedRay *r, __global const Bvh8Instance *in)
{
    if (in->identity)
        return *r;
    __global const float *m = in->world_to_local;
    float ox = r->ox - in->origin[0], oy = r->oy - in->origin[1], oz = r->oz - in->origin[2];
    float3 o = (float3)(m[0] * ox + m[1] * oy + m[2] * oz, m[3] * ox + m[4] * oy + m[5] * oz,
                        m[6] * ox + m[7] * oy + m[8] * oz);
    float3 d = (float3)(m[0] * r->dx + m[1] * r->dy + m[2] * r->dz,
                        m[3] * r->dx + m[4] * r->dy + m[5] * r->dz,
                        m[6] * r->dx + m[7] * r->dy + m[8] * r->dz);
    return prepare_ray(o, d);
}

/* Closest hit over all instances: the top-level tree is walked in order (near
 * child first, entries beyond the closest hit so far skipped), each instance's
 * tree with the ray in its frame and the same (tmin, tmax). */
CLR_INLINE int bvh_closest(__global const Bvh8Node *nodes, __global const float4 *tri4,
                           __global const int *slot_prim, const PreparedRay *r,
                           float tmin, float *tmax_io, float *u_out, float *v_out,
                           int ignore_prim)
{
    int stack_code[BVH_STACK_SIZE + 1];
    float stack_dist[BVH_STACK_SIZE + 1];
    int sp = 0;
    int code = 0;
    int best = -1;
    float tmax = *tmax_io;
    for (;;) {
        if (code < 0) {
            __global const Bvh8Instance *in = instance_of(nodes, code);
            PreparedRay lr = instance_ray(r, in);
            int slot = blas_closest(nodes, tri4, slot_prim, &lr, in->root, tmin, &tmax, u_out,
                                    v_out, ignore_prim);
            if (slot >= 0)
                best = slot;
        } else {
            __global const float8 *q = (__global const float8 *)(nodes + code);
            int mask;
            float8 dv = ray_box8(r, q, tmin, tmax, &mask);
            const float *d = (const float *)&dv;
            __global const int *cc = (__global const int *)(q + 6);
            sp = push_sorted(mask, d, cc, stack_code, stack_dist, sp);
        }
        for (;;) {
            if (sp == 0) { *tmax_io = tmax; return best; }
            --sp;
            if (stack_dist[sp] <= tmax) break;
        }
        code = stack_code[sp];
    }
}

CLR_INLINE bool bvh_any(__global const Bvh8Node *nodes, __global const float4 *tri4,
                        __global const int *slot_prim, const PreparedRay *r,
                        float tmin, float tmax, int ignore_a, int ignore_b)
{
    int stack_code[BVH_STACK_SIZE + 1];
    int sp = 0;
    int code = 0;
    for (;;) {
        if (code < 0) {
            __global const Bvh8Instance *in = instance_of(nodes, code);
            PreparedRay lr = instance_ray(r, in);
            if (blas_any(nodes, tri4, slot_prim, &lr, in->root, tmin, tmax, ignore_a,
                         ignore_b))
                return true;
        } else {
            sp = push_hit_children(r, nodes, code, tmin, tmax, stack_code, sp);
        }
        if (sp == 0) return false;
        code = stack_code[--sp];
    }
}

/* World-space unit normal of leaf slot s: its triangle's normal in the frame
 * of the instance whose groups hold the slot, rotated into the world. */
CLR_INLINE float3 slot_normal(__global const Bvh8Node *nodes, __global const float4 *tri4,
                              int slot)
{
    float3 n = tri4_normal(tri4, slot);
    int group = slot >> 2;
    __global const Bvh8Instance *in = (__global const Bvh8Instance *)(nodes + nodes[0].pad[0]);
    for (int k = 0; k < nodes[0].pad[1]; ++k, ++in) {
        if (group >= in->first_group && group < in->end_group) {
            if (in->identity)
                return n;
            __global const float *m = in->local_to_world;
            return (float3)(m[0] * n.x + m[1] * n.y + m[2] * n.z,
                            m[3] * n.x + m[4] * n.y + m[5] * n.z,
                            m[6] * n.x + m[7] * n.y + m[8] * n.z);
        }
    }
    return n;
}

#endif

/* A packet of rays as intervals: origins in [ol, oh] and inverse directions in [il, ih]
 * per axis (all of one sign), the rows n* of their near planes as in PreparedRay. */
typedef struct {
    float olx, ohx, oly, ohy, olz, ohz;
    float ilx, ihx, ily, ihy, ilz, ihz;
    int nx, ny, nz;
} PacketBounds;

/* The bounds of rays pr[member[k]], k < n; false where they cannot be one packet: rays
 * toward both sides of an axis, or along a slab plane (an infinite inverse, whose
 * 0 * inf the intervals cannot bound). */
CLR_INLINE bool packet_bounds(const PreparedRay *pr, const int *member, int n, PacketBounds *b)
{
    const PreparedRay *r0 = &pr[member[0]];
    b->olx = b->ohx = r0->ox; b->oly = b->ohy = r0->oy; b->olz = b->ohz = r0->oz;
    b->ilx = b->ihx = r0->ix; b->ily = b->ihy = r0->iy; b->ilz = b->ihz = r0->iz;
    b->nx = r0->nx; b->ny = r0->ny; b->nz = r0->nz;
    bool together = true;
    for (int k = 1; k < n; ++k) {
        const PreparedRay *r = &pr[member[k]];
        b->olx = MINF(b->olx, r->ox); b->ohx = MAXF(b->ohx, r->ox);
        b->oly = MINF(b->oly, r->oy); b->ohy = MAXF(b->ohy, r->oy);
        b->olz = MINF(b->olz, r->oz); b->ohz = MAXF(b->ohz, r->oz);
        b->ilx = MINF(b->ilx, r->ix); b->ihx = MAXF(b->ihx, r->ix);
        b->ily = MINF(b->ily, r->iy); b->ihy = MAXF(b->ihy, r->iy);
        b->ilz = MINF(b->ilz, r->iz); b->ihz = MAXF(b->ihz, r->iz);
        together &= (r->nx == b->nx) & (r->ny == b->ny) & (r->nz == b->nz);
    }
    return together && isfinite(b->ilx) && isfinite(b->ihx) && isfinite(b->ily)
           && isfinite(b->ihy) && isfinite(b->ilz) && isfinite(b->ihz) && isfinite(b->olx)
           && isfinite(b->ohx) && isfinite(b->oly) && isfinite(b->ohy) && isfinite(b->olz)
           && isfinite(b->ohz);
}

/* ray_box8 for a packet: per axis the nearest entry and farthest exit over the four
 * corners of (plane - origin interval) x (inverse direction interval), so the mask holds
 * every child some ray of the packet enters in [t_lo, t_hi] (and maybe more); returns
 * the nearest entries. */
CLR_INLINE float8 packet_box8(const PacketBounds *b, __global const float8 *q, float t_lo,
                              float t_hi, int *mask)
{
    float8 a1, a2, near, far;
    a1 = q[b->nx] - (float8)(b->ohx); a2 = q[b->nx] - (float8)(b->olx);
    near = MINF(MINF(a1 * b->ilx, a1 * b->ihx), MINF(a2 * b->ilx, a2 * b->ihx));
    a1 = q[3 - b->nx] - (float8)(b->ohx); a2 = q[3 - b->nx] - (float8)(b->olx);
    far = MAXF(MAXF(a1 * b->ilx, a1 * b->ihx), MAXF(a2 * b->ilx, a2 * b->ihx));
    float8 t0 = MAXF(near, (float8)(t_lo)), t1 = MINF(far, (float8)(t_hi));
    a1 = q[b->ny] - (float8)(b->ohy); a2 = q[b->ny] - (float8)(b->oly);
    near = MINF(MINF(a1 * b->ily, a1 * b->ihy), MINF(a2 * b->ily, a2 * b->ihy));
    a1 = q[5 - b->ny] - (float8)(b->ohy); a2 = q[5 - b->ny] - (float8)(b->oly);
    far = MAXF(MAXF(a1 * b->ily, a1 * b->ihy), MAXF(a2 * b->ily, a2 * b->ihy));
    t0 = MAXF(near, t0); t1 = MINF(far, t1);
    a1 = q[b->nz] - (float8)(b->ohz); a2 = q[b->nz] - (float8)(b->olz);
    near = MINF(MINF(a1 * b->ilz, a1 * b->ihz), MINF(a2 * b->ilz, a2 * b->ihz));
    a1 = q[7 - b->nz] - (float8)(b->ohz); a2 = q[7 - b->nz] - (float8)(b->olz);
    far = MAXF(MAXF(a1 * b->ilz, a1 * b->ihz), MAXF(a2 * b->ilz, a2 * b->ihz));
    t0 = MAXF(near, t0);
    t1 = MINF(far, t1) * ROBUST_TMAX_SCALE;
    int8 bits = (t0 <= t1) & (int8)(1, 2, 4, 8, 16, 32, 64, 128);
    int4 b4 = bits.lo | bits.hi;
    int2 b2 = b4.lo | b4.hi;
    *mask = b2.x | b2.y;
    return t0;
}

/* Ray packets: closest hits of up to PACKET_MAX coherent rays (the tubes of one SBR
 * launch block, or those of them that left the same faces) in one walk of the tree.
 *
 * A record is entered once for the whole packet: each child box is tested by interval
 * arithmetic over the packet's origins and inverse directions (packet_box8; Wald,
 * Boulos & Shirley, "Ray Tracing Deformable Scenes using Dynamic Bounding Volume
 * Hierarchies", ACM TOG 26(1), 2007, section 4.2), then every ray of the packet tests
 * the triangles of a leaf it reaches. Rounding is monotone in each operand, so the
 * intervals' nearest entry and farthest exit bound every ray's own float ones: the
 * packet never culls a box that ray_box8 would enter for one of its rays (then scaled by
 * the same ROBUST_TMAX_SCALE), and a subtree is skipped only beyond every ray's closest
 * hit.
 *
 * The result is blas_closest's, ray for ray and bit for bit: the same triangle test,
 * the same strict range and the same choice of lane, so a ray's closest hit is the
 * same wherever it is unique. Where it is not (two hits within rounding of each other,
 * a ray through an edge), blas_closest keeps the first it visits, which depends on its
 * own order of records; a ray that meets such a near tie in the packet's walk is cast
 * again on its own. Packets that packet_bounds refuses are cast ray by ray, as is every
 * ray of a two-level tree. */
#ifndef PACKET_MAX
#error "PACKET_MAX must be passed as -D by the host"
#endif

CLR_INLINE void closest_ray_by_ray(__global const Bvh8Node *nodes, __global const float4 *tri4,
                                   __global const int *slot_prim, const PreparedRay *pr,
                                   const int *member, int n, const float *tmin, float *tmax,
                                   float *u, float *v, int *best)
{
    for (int k = 0; k < n; ++k) {
        int r = member[k];
        best[r] = bvh_closest(nodes, tri4, slot_prim, &pr[r], tmin[r], &tmax[r], &u[r], &v[r],
                              -1);
    }
}

/* Closest hits of rays pr[member[k]], k < n <= PACKET_MAX: per ray r, on entry its
 * range (tmin[r], tmax[r]), on return bvh_closest's slot in best[r] (-1: a miss), and
 * where it hits its t in tmax[r] and u[r], v[r]. No ray ignores a triangle. */
CLR_INLINE void packet_closest(__global const Bvh8Node *nodes, __global const float4 *tri4,
                               __global const int *slot_prim, const PreparedRay *pr,
                               const int *member, int n, const float *tmin, float *tmax,
                               float *u, float *v, int *best)
{
#ifdef BVH_INSTANCED
    closest_ray_by_ray(nodes, tri4, slot_prim, pr, member, n, tmin, tmax, u, v, best);
#else
    PacketBounds box;
    if (n < 2 || !packet_bounds(pr, member, n, &box)) {
        closest_ray_by_ray(nodes, tri4, slot_prim, pr, member, n, tmin, tmax, u, v, best);
        return;
    }
    bool recast[PACKET_MAX];
    float tmax_in[PACKET_MAX];
    float t_lo = tmin[member[0]], far_all = tmax[member[0]];
    for (int k = 0; k < n; ++k) {
        int m = member[k];
        best[m] = -1;
        recast[k] = false;
        tmax_in[k] = tmax[m];
        t_lo = MINF(t_lo, tmin[m]);
        far_all = MAXF(far_all, tmax[m]);
    }
    int stack_code[BVH_STACK_SIZE + 1];
    float stack_dist[BVH_STACK_SIZE + 1];
    int sp = 0;
    int code = 0;
    for (;;) {
        if (code < 0) {
            int packed = -code - 1;
            int first = packed >> LEAF_GROUP_BITS, last = first + (packed & LEAF_GROUP_MASK);
            for (int k = 0; k < n; ++k) {
                int m = member[k];
                for (int gi = first; gi < last; ++gi) {
                    float4 T, det, V, W;
                    /* a little past the ray's closest hit so far: near ties show */
                    int4 ok = ray_tri4(&pr[m], tri4 + gi * TRI4_ROWS, tmin[m],
                                       tmax[m] * ROBUST_TMAX_SCALE, &T, &det, &V, &W);
                    if (!ANY4(ok))
                        continue;
                    float4 inv = (float4)(1.0f) / det;
                    float4 t = ok ? T * inv : (float4)(INFINITY);
                    if (best[m] >= 0) {
                        float4 tm = (float4)(tmax[m]);
                        int4 near = ok & (t <= tm * ROBUST_TMAX_SCALE)
                                    & (t * ROBUST_TMAX_SCALE >= tm);
                        recast[k] |= ANY4(near);
                    }
                    /* ray_tri4's own range test at the ray's tmax */
                    float4 sdet = (det < 0.0f) ? (float4)(-1.0f) : (float4)(1.0f);
                    ok &= (T * sdet < (float4)(tmax[m]) * (det * sdet));
                    if (!ANY4(ok))
                        continue;
                    t = ok ? t : (float4)(INFINITY);
                    best[m] = 4 * gi + nearest_lane(t, V * inv, W * inv, &tmax[m], &u[m], &v[m]);
                }
            }
            far_all = tmax[member[0]];
            for (int k = 1; k < n; ++k)
                far_all = MAXF(far_all, tmax[member[k]]);
        } else {
            __global const float8 *q = (__global const float8 *)(nodes + code);
            int mask;
            float8 t0 = packet_box8(&box, q, t_lo, far_all, &mask);
            const float *d = (const float *)&t0;
            __global const int *cc = (__global const int *)(q + 6);
            sp = push_sorted(mask, d, cc, stack_code, stack_dist, sp);
        }
        /* pop, skipping subtrees that start beyond every ray's closest hit (by the
         * margin of the near-tie test) */
        for (;;) {
            if (sp == 0) {
                for (int k = 0; k < n; ++k) {
                    if (!recast[k])
                        continue;
                    int m = member[k];
                    tmax[m] = tmax_in[k];
                    best[m] = bvh_closest(nodes, tri4, slot_prim, &pr[m], tmin[m], &tmax[m],
                                          &u[m], &v[m], -1);
                }
                return;
            }
            --sp;
            if (stack_dist[sp] <= far_all * ROBUST_TMAX_SCALE) break;
        }
        code = stack_code[sp];
    }
#endif
}

#endif
