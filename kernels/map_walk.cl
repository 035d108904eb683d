/* Radio maps: the rays stage in one launch per batch (clradcom/device/map_walk.py,
 * docs/maps.md "The rays on the device").
 *
 * One work item per launched ray of the transmitter's launch lattice. It rotates its
 * lattice direction into the world, forms the transmit field from the pattern's
 * (C_theta, C_phi) (the host evaluates the pattern once per lattice), and walks the ray
 * through all its bounces: the closest hit over the BVH in float32 (intersect.h, the
 * host's closest_hit on the same float32 rows), the hit point, mirror direction, spawn
 * offset and field in `real` (double where the device has fp64, else float), each
 * reflection the material's Fresnel dyad with its roughness and specular share
 * (em.h: material_reflection, the device twin of em.py's reflected_fields). It emits two
 * compact lists, slots taken from an atomic counter (records past capacity are counted,
 * not written, so the host can size the buffers and run the batch again):
 *
 *   segments  every segment that may pass through the slab's box (the host's _reaches,
 *             with its 1 mm margin), line of sight as the host's flag says, a first
 *             reflection off an object with PO facets left out (optics.replaced_paths):
 *             its float32 rows for kernels/maps.cl's accumulation, which reads them
 *             where they are, and its arrival direction and field components in the
 *             receiver's frame, the host's receive projection without the pattern,
 *             which the host evaluates (a Python object) and turns into the weights;
 *   hits      every hit on a face whose material scatters (S > 0), after at most
 *             scatter_orders reflections: the host's diffuse rays start there.
 *
 * The host sorts the hits by (order, ray), the order the numpy walk makes them in, so the
 * diffuse rays draw the same random numbers as there. */
#include "intersect.h"

#ifdef CLRADCOM_FP64
typedef double real;
typedef double2 real2;
typedef double3 real3;
#define REAL_INF ((double)INFINITY)
#else
typedef float real;
typedef float2 real2;
typedef float3 real3;
#define REAL_INF INFINITY
#endif
#define CLRADCOM_REAL_DEFINED 1
#include "em.h"

#ifndef SPAWN_OFFSET_ROUNDOFFS
#error "SPAWN_OFFSET_ROUNDOFFS must be passed as -D by the host"
#endif

/* reals of a scatter record: origin 3, direction 3, length, field re 3, im 3; its ints:
 * ray, order, triangle */
#define HIT_REALS 13
#define HIT_INTS 3
/* reals of a segment's receive record: the arrival direction in the receiver's frame
 * (3), the field's theta and phi components there (re, im each); without a receiver
 * |E|^2 first; then, for a segment leaving an SBR object's triangle after its second or
 * later bounce, the ray's index as two 16-bit halves (exact in float), else -1, -1: the
 * host drops it where SBR-PO's tubes radiate that bounce (maps.py) */
#define RX_REALS 9

/* params: tx xyz, slab box lo xyz and hi xyz (grown by the margin), wavenumber, the
 * slab's corner (x0, y0, z_lo) that the segments' float32 rows are relative to */
#define P_TX 0
#define P_LO 3
#define P_HI 6
#define P_K 9
#define P_CORNER 10

/* PO objects' triangles (tri_flags): their first reflections are the PO stage's */
#define FLAG_PO 1
/* SBR objects' triangles: a later bounce's exit segment may be SBR-PO's footprints' */
#define FLAG_SBR 2

inline real3 load_real3(__global const real *p) { return (real3)(p[0], p[1], p[2]); }

/* component by component: converting the vector reads its padding lane, which
 * Oclgrind's uninitialised-value check reports */
inline float3 to_float3(const real3 a)
{
    return (float3)((float)a.x, (float)a.y, (float)a.z);
}

/* The host's spawn_origins: pushed off the surface along the normal, toward the side the
 * ray leaves into, by SPAWN_OFFSET_ROUNDOFFS float32 roundoffs times 1 + max |p|. */
inline real3 spawn_origin(const real3 p, const real3 n, const real3 dir)
{
    real bound = (real)(SPAWN_OFFSET_ROUNDOFFS * 0.5f * FLT_EPSILON)
                 * (fmax(fmax(fabs(p.x), fabs(p.y)), fabs(p.z)) + (real)1.0);
    real side = (dot(n, dir) < (real)0.0) ? (real)-1.0 : (real)1.0;
    return p + (side * bound / sqrt(dot(n, n))) * n;
}

/* The host's _reaches: whether o + t d, 0 <= t <= length, may pass through the box. */
inline bool reaches_box(const real3 o, const real3 d, const real len,
                        __global const real *params)
{
    real t0 = 0.0, t1 = fmin(len, (real)1e30);
    real oo[3] = {o.x, o.y, o.z}, dd[3] = {d.x, d.y, d.z};
    for (int axis = 0; axis < 3; ++axis) {
        real lo = params[P_LO + axis], hi = params[P_HI + axis];
        if (dd[axis] == 0.0) {
            if (!(oo[axis] >= lo && oo[axis] <= hi)) return false;
            continue;
        }
        real a = (lo - oo[axis]) / dd[axis], b = (hi - oo[axis]) / dd[axis];
        t0 = fmax(t0, fmin(a, b));
        t1 = fmin(t1, fmax(a, b));
    }
    return t0 <= t1;
}

/* A scattering hit into the next slot of the list (counted past capacity, not written). */
inline void emit_hit(volatile __global int *counter, const int capacity,
                     __global real *rows, __global int *ints, const real3 o, const real3 d,
                     const real len, const cvec3 e, const int ray, const int order,
                     const int prim)
{
    int slot = atomic_inc(counter);
    if (slot >= capacity) return;
    __global real *r = rows + (size_t)HIT_REALS * slot;
    r[0] = o.x; r[1] = o.y; r[2] = o.z;
    r[3] = d.x; r[4] = d.y; r[5] = d.z;
    r[6] = len;
    r[7] = e.x.x; r[8] = e.y.x; r[9] = e.z.x;
    r[10] = e.x.y; r[11] = e.y.y; r[12] = e.z.y;
    __global int *i = ints + (size_t)HIT_INTS * slot;
    i[0] = ray; i[1] = order; i[2] = prim;
}

/* A segment that may reach the slab: its float32 rows for the accumulation
 * (kernels/maps.cl: accumulate_segments, origin relative to the slab's corner, length
 * at most 1e30 m) and what the host's receive projection needs (maps.py: _projection,
 * written out: the arrival direction -d and the field in the receiver's frame rx, row
 * major; without a receiver |E|^2). */
inline void emit_segment(volatile __global int *counter, const int capacity,
                         __global float4 *seg_org, __global float4 *seg_dir,
                         __global real *seg_rx, const real3 o, const real3 d,
                         const real len, const cvec3 e, __global const real *params,
                         __global const real *rx, const int exit_ray)
{
    int slot = atomic_inc(counter);
    if (slot >= capacity) return;
    real3 rel = o - (real3)(params[P_CORNER], params[P_CORNER + 1], params[P_CORNER + 2]);
    seg_org[slot] = (float4)((float)rel.x, (float)rel.y, (float)rel.z, 0.0f);
    seg_dir[slot] = (float4)((float)d.x, (float)d.y, (float)d.z,
                             (float)fmin(len, (real)1e30));
    __global real *r = seg_rx + (size_t)RX_REALS * slot;
    r[7] = exit_ray < 0 ? (real)-1.0 : (real)(exit_ray & 0xffff);
    r[8] = exit_ray < 0 ? (real)-1.0 : (real)(exit_ray >> 16);
    if (!rx) {
        real power = e.x.x * e.x.x + e.x.y * e.x.y + e.y.x * e.y.x + e.y.y * e.y.y
                     + e.z.x * e.z.x + e.z.y * e.z.y;
        r[0] = power;
        r[1] = 0.0; r[2] = 0.0; r[3] = 0.0; r[4] = 0.0; r[5] = 0.0; r[6] = 0.0;
        return;
    }
    /* v R for the arrival direction v = -d and for the field (the host's _rotate) */
    real3 c0 = (real3)(rx[0], rx[3], rx[6]), c1 = (real3)(rx[1], rx[4], rx[7]);
    real3 c2 = (real3)(rx[2], rx[5], rx[8]);
    real3 a = (real3)(-dot(d, c0), -dot(d, c1), -dot(d, c2));
    cplx ex = c_scale(e.x, c0.x) + c_scale(e.y, c0.y) + c_scale(e.z, c0.z);
    cplx ey = c_scale(e.x, c1.x) + c_scale(e.y, c1.y) + c_scale(e.z, c1.z);
    cplx ez = c_scale(e.x, c2.x) + c_scale(e.y, c2.y) + c_scale(e.z, c2.z);
    real rho = sqrt(a.x * a.x + a.y * a.y);
    real cos_p = rho > 0.0 ? a.x / rho : (real)1.0;
    real sin_p = rho > 0.0 ? a.y / rho : (real)0.0;
    cplx along_x = c_scale(ex, cos_p) + c_scale(ey, sin_p);
    cplx e_theta = c_scale(along_x, a.z) - c_scale(ez, rho);
    cplx e_phi = c_scale(ey, cos_p) - c_scale(ex, sin_p);
    r[0] = a.x; r[1] = a.y; r[2] = a.z;
    r[3] = e_theta.x; r[4] = e_theta.y; r[5] = e_phi.x; r[6] = e_phi.y;
}

__kernel void map_walk(__global const Bvh8Node *nodes, __global const float4 *tri4,
                       __global const int *slot_prim,
                       __global const real *lattice,   /* (N, 3) local directions */
                       __global const real *launch,    /* (N, 4) C_theta, C_phi re/im */
                       __global const real *frame,     /* tx orientation, row major */
                       __global const real *params,
                       __global const real *normals,   /* (T, 3) unit, float64's */
                       __global const int *tri_material,
                       __global const int *tri_flags,
                       __global const real *mat_f,     /* (M, 4) em.h material rows */
                       __global const int *mat_i,      /* (M, 3): em.h's 2, S > 0 */
                       const int first, const int n, const int max_reflections,
                       const int line_of_sight, const int scatter_orders,
                       __global const real *rx,        /* rx orientation or 0 */
                       __global float4 *seg_org, __global float4 *seg_dir,
                       __global real *seg_rx, const int seg_capacity,
                       __global real *hit_rows, __global int *hit_ints,
                       const int hit_capacity,
                       volatile __global int *counters) /* segments, hits */
{
    int gid = get_global_id(0);
    if (gid >= n) return;
    int ray = first + gid;
    real3 loc = load_real3(lattice + 3 * (size_t)ray);
    /* d = R loc (the host's loc @ R^T) */
    real3 dir = (real3)(dot((real3)(frame[0], frame[1], frame[2]), loc),
                        dot((real3)(frame[3], frame[4], frame[5]), loc),
                        dot((real3)(frame[6], frame[7], frame[8]), loc));
    real3 unused, th, ph;
    antenna_frame_basis(dir, frame, &unused, &th, &ph);
    __global const real *c = launch + 4 * (size_t)ray;
    cvec3 field = cv_axpy((cplx)(c[2], c[3]), ph,
                          cv_axpy((cplx)(c[0], c[1]), th, cv_zero()));
    real3 org = load_real3(params + P_TX);
    real k0 = params[P_K];
    int last = -1;
    for (int order = 0; order <= max_reflections; ++order) {
        PreparedRay pr = prepare_ray(to_float3(org), to_float3(dir));
        float t32 = INFINITY, u, v;
        int slot = bvh_closest(nodes, tri4, slot_prim, &pr, 0.0f, &t32, &u, &v, -1);
        int prim = slot >= 0 ? slot_prim[slot] : -1;
        real t = slot >= 0 ? (real)t32 : REAL_INF;
        if ((order > 0 || line_of_sight)
                && !(order == 1 && (tri_flags[last] & FLAG_PO))
                && reaches_box(org, dir, t, params))
            emit_segment(counters, seg_capacity, seg_org, seg_dir, seg_rx, org, dir, t, field,
                         params, rx,
                         (order >= 2 && (tri_flags[last] & FLAG_SBR)) ? ray : -1);
        if (prim < 0) break;
        int mat = tri_material[prim];
        if (order <= scatter_orders && mat_i[3 * mat + 2])
            emit_hit(counters + 1, hit_capacity, hit_rows, hit_ints, org, dir, t, field, ray,
                     order, prim);
        if (order == max_reflections) break;
        real3 nrm = load_real3(normals + 3 * (size_t)prim);
        real3 point = org + t * dir;
        Reflection refl = material_reflection(dir, nrm, mat_f + 4 * mat, mat_i + 3 * mat,
                                              k0);
        field = reflect(&refl, field);
        dir = dir - (real)2.0 * dot(dir, nrm) * nrm;
        dir /= sqrt(dot(dir, dir));
        org = spawn_origin(point, nrm, dir);
        last = prim;
    }
}
