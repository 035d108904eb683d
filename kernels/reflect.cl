/* Candidate search for specular paths: each work item follows one ray from
 * the transmitter through up to max_order specular bounces and writes the
 * ordered sequence of faces it reflects off. The host turns every prefix of
 * every sequence into a candidate and confirms it with the image method, so
 * nothing here needs to be exact: float32 geometry is enough. */
#include "intersect.h"
#include "precise.h"

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

/* A ray between bounces: where it leaves from, where it goes, the triangle it left. */
typedef struct { float3 org; float3 dir; int last_prim; } BouncingRay;

/* The ray's next specular bounce: the face it reflects off (the ray moved on past it),
 * or -1 when it escapes. */
CLR_INLINE int next_bounce(__global const Bvh8Node *nodes, __global const float4 *tri_verts,
                           __global const int *tri_index, __global const int *tri_face,
                           BouncingRay *ray)
{
    PreparedRay pr = prepare_ray(ray->org, ray->dir);
    float t = INFINITY, u, v;
    int slot = bvh_closest(nodes, tri_verts, tri_index, &pr, 0.0f, &t, &u, &v,
                           ray->last_prim);
    if (slot < 0) return -1;
    ray->last_prim = tri_index[slot];
    float3 n = slot_normal(nodes, tri_verts, slot);
    float3 p = ray->org + t * ray->dir;
    ray->dir = ray->dir - 2.0f * dot(ray->dir, n) * n;
    ray->org = spawn_point(p, n, ray->dir);
    return tri_face[ray->last_prim];
}

/* One ray's face sequence: up to max_order bounces from org along dir, the faces
 * written to out, -1 after the ray escapes. */
CLR_INLINE void follow_ray(__global const Bvh8Node *nodes, __global const float4 *tri_verts,
                           __global const int *tri_index, __global const int *tri_face,
                           float3 org, float3 dir, const int max_order, __global int *out)
{
    BouncingRay ray = {org, dir, -1};
    int depth = 0;
    for (; depth < max_order; ++depth) {
        int face = next_bounce(nodes, tri_verts, tri_index, tri_face, &ray);
        if (face < 0) break;
        out[depth] = face;
    }
    for (; depth < max_order; ++depth) out[depth] = -1;
}

/* One ray's face sequence as the exact key of clradcom/mechanisms/specular.py:
 * sequence_keys: digits face + 1 in base ``base``, first face most significant, 0 from
 * the first escape or the first face repeated straight after itself on (a plane cannot
 * reflect a ray twice in a row: the rest is a float32 re-hit of a neighbouring triangle
 * of the face just left). The host checks that base^max_order fits a long. */
CLR_INLINE long follow_ray_key(__global const Bvh8Node *nodes,
                               __global const float4 *tri_verts,
                               __global const int *tri_index, __global const int *tri_face,
                               float3 org, float3 dir, const int max_order, const long base)
{
    BouncingRay ray = {org, dir, -1};
    long key = 0;
    int depth = 0, prev = -1;
    for (; depth < max_order; ++depth) {
        int face = next_bounce(nodes, tri_verts, tri_index, tri_face, &ray);
        if (face < 0 || face == prev) break;
        key = key * base + (long)(face + 1);
        prev = face;
    }
    for (; depth < max_order; ++depth) key *= base;
    return key;
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

/* (l0 r0 + l1 r1) + l2 r2 rounded to float */
CLR_INLINE float rotated(preal l0, preal l1, preal l2, pr_elem r0, pr_elem r1, pr_elem r2)
{
    return pr_to_float(pr_add(pr_add(pr_mul(l0, pr_of(r0)), pr_mul(l1, pr_of(r1))),
                              pr_mul(l2, pr_of(r2))));
}

/* Lattice ray first + gid (N, 3) float64 rotated by r (row major 3x3, the antenna's axes
 * as columns): dir_j = (l0 r_j0 + l1 r_j1) + l2 r_j2, as the host's numpy rotation sums
 * it (no contraction: intersect.h), then rounded to float as numpy's cast rounds it. In
 * precise.h's preal: double with fp64, so each ray is the host-rotated one bit for bit;
 * double-float without (lattice and rotation as (hi, lo) pairs), whose sum is the
 * float64 one to ~1e-14 relative: a component rounds to another float only where it
 * lies that close to a rounding boundary (1 ulp, about one component in 10^6). */
CLR_INLINE float3 lattice_direction(__global const pr_elem *lattice, const size_t ray,
                                    const pr_elem r00, const pr_elem r01, const pr_elem r02,
                                    const pr_elem r10, const pr_elem r11, const pr_elem r12,
                                    const pr_elem r20, const pr_elem r21, const pr_elem r22)
{
    size_t k = 3 * ray;
    preal l0 = pr_of(lattice[k]), l1 = pr_of(lattice[k + 1]), l2 = pr_of(lattice[k + 2]);
    return (float3)(rotated(l0, l1, l2, r00, r01, r02), rotated(l0, l1, l2, r10, r11, r12),
                    rotated(l0, l1, l2, r20, r21, r22));
}

/* The arguments every kernel over a rotated launch lattice starts with: the BVH, the
 * faces, the origin, the lattice (N, 3) and its rotation r (row major), the first ray
 * of the batch and the most reflections; LATTICE_DIRECTION is work item gid's ray. */
#define ROTATED_LATTICE_ARGS                                                            \
    __global const Bvh8Node *nodes, __global const float4 *tri_verts,                   \
    __global const int *tri_index, __global const int *tri_face,                        \
    const float ox, const float oy, const float oz, __global const pr_elem *lattice,    \
    const pr_elem r00, const pr_elem r01, const pr_elem r02, const pr_elem r10,         \
    const pr_elem r11, const pr_elem r12, const pr_elem r20, const pr_elem r21,         \
    const pr_elem r22, const int first, const int max_order
#define LATTICE_DIRECTION(gid)                                                          \
    lattice_direction(lattice, (size_t)first + (gid), r00, r01, r02, r10, r11, r12, r20, \
                      r21, r22)

/* trace_reflections of the rays of a launch lattice rotated on the device
 * (lattice_direction). The lattice stays on the device between transmitters and
 * traces. */
__kernel void trace_reflections_rotated(ROTATED_LATTICE_ARGS, __global int *face_seq,
                                        const int n_rays)
{
    int gid = get_global_id(0);
    if (gid >= n_rays) return;
    follow_ray(nodes, tri_verts, tri_index, tri_face, (float3)(ox, oy, oz),
               LATTICE_DIRECTION(gid), max_order, face_seq + (size_t)gid * max_order);
}

/* trace_reflections_rotated writing each ray's exact sequence key (follow_ray_key)
 * instead of its faces: one long per ray for the host's de-duplication. */
__kernel void trace_reflection_keys_rotated(ROTATED_LATTICE_ARGS, const long base,
                                            __global long *keys, const int n_rays)
{
    int gid = get_global_id(0);
    if (gid >= n_rays) return;
    keys[gid] = follow_ray_key(nodes, tri_verts, tri_index, tri_face, (float3)(ox, oy, oz),
                               LATTICE_DIRECTION(gid), max_order, base);
}

#ifdef cl_khr_int64_base_atomics
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable

/* trace_reflection_keys_rotated with the keys gathered into a set on the device instead
 * of written per ray: an open-addressed table of 2^table_bits longs (-1: empty), linear
 * probing from a multiplicative hash. Every probe is one compare-and-swap, which returns
 * the slot's key where it holds one: a plain read of a slot that another work item may
 * be swapping is a data race (Oclgrind reports it; a 64-bit read may tear on some
 * devices, and a torn key would be stored twice). A key that finds no slot within
 * MAX_PROBES sets *overflow: the host then reads every ray's key instead (the set is not
 * complete). Key 0 (no face) is left out: it proposes no candidate. */
#define KEY_SET_MAX_PROBES 64
__kernel void collect_reflection_keys_rotated(ROTATED_LATTICE_ARGS, const long base,
                                              const int table_bits,
                                              __global volatile long *table,
                                              __global volatile int *overflow,
                                              const int n_rays)
{
    int gid = get_global_id(0);
    if (gid >= n_rays) return;
    long key = follow_ray_key(nodes, tri_verts, tri_index, tri_face, (float3)(ox, oy, oz),
                              LATTICE_DIRECTION(gid), max_order, base);
    if (key == 0) return;
    ulong mask = ((ulong)1 << table_bits) - 1;
    ulong slot = ((ulong)key * 0x9E3779B97F4A7C15UL) >> (64 - table_bits);
    for (int probe = 0; probe < KEY_SET_MAX_PROBES; ++probe) {
        long held = atom_cmpxchg(&table[slot], -1L, key);
        if (held == -1 || held == key) return;
        slot = (slot + 1) & mask;
    }
    atomic_or(overflow, 1);
}
#endif
