/* Radio maps: a batch of ray segments accumulated into the cells of a measurement slab
 * (clradcom/device/maps.py, docs/maps.md).
 *
 * One work item per segment. The segment (origin, unit direction, length) is clipped to
 * the slab z_lo <= z <= z_hi over the rectangle [0, nx cx] x [0, ny cy] (coordinates
 * relative to the grid's corner, so float32 keeps them to ~1e-5 m over a street), then
 * walked cell by cell (Amanatides-Woo in x and y); each cell it passes through gets
 * weight x (length of the segment inside that cell's box): the track-length estimator of
 * the mean power density over the cell's volume. Its thin-slab limit is the crossing
 * estimator Sionna RT's radio maps use (weight / |cos theta| per crossing), and unlike it
 * a ray that runs along the slab counts. Each cell also sums the squares of its terms,
 * whose ratio to the squared sum tells how many segments carry the cell's value (the
 * convergence rule's effective count, docs/maps.md).
 *
 * Only 32-bit atomics (core since OpenCL 1.1): float sums by compare-and-swap on their
 * bits, so devices without 64-bit atomics run it. The order of the additions within a
 * cell is the device's: sums agree between runs to float32 rounding (~1e-7 relative).
 *
 * Each work group adds into its own copy of the sums (group id modulo the copies; the
 * host adds the copies up in float64): the rays of a batch leave the transmitter
 * together, so without copies the cores fight over the same cells' cache lines near it,
 * and on the street's map the accumulation took 2.6x as long (docs/maps.md). */

#ifndef MAX_STEPS_PAD
#define MAX_STEPS_PAD 2
#endif

/* The first read of the sum is a plain one, the compare-and-swap deciding: a stale or
 * torn value only fails the swap, which hands back the value it met for the next try
 * (CUDA's documented double atomicAdd starts the same way). An atomic first read
 * (atomic_or with 0) cost as much as the swap itself. Oclgrind's data-race check counts
 * the plain read beside other work items' swaps as a race, so its builds read atomically
 * (CLR_ATOMIC_FIRST_READ, clradcom/device/runtime.py: SIMULATOR_BUILD_OPTIONS). */
inline void add_float(volatile __global float *where, const float value)
{
    volatile __global unsigned int *bits = (volatile __global unsigned int *)where;
    union { unsigned int u; float f; } before, after;
#ifdef CLR_ATOMIC_FIRST_READ
    before.u = atomic_or(bits, 0u);
#else
    before.u = *bits;
#endif
    for (;;) {
        after.f = before.f + value;
        const unsigned int met = atomic_cmpxchg(bits, before.u, after.u);
        if (met == before.u)
            return;
        before.u = met;
    }
}

/* The parameter range [*t0, *t1] of o + t d inside lo <= x <= hi; false when empty. */
inline bool clip_axis(const float o, const float d, const float lo, const float hi,
                      float *t0, float *t1)
{
    if (d == 0.0f)
        return o >= lo && o <= hi;
    float a = (lo - o) / d, b = (hi - o) / d;
    *t0 = fmax(*t0, fmin(a, b));
    *t1 = fmin(*t1, fmax(a, b));
    return *t0 < *t1;
}

/* Walks one segment through the slab's cells. With power != 0 each cell it crosses gets
 * w x (length inside), its square and a count; else the (segment, cell, length) records
 * are appended to rec_* at slots taken from *n_records (those past capacity are counted,
 * not written, so the host can size the buffer and run again). */
inline void walk_segment(const int gid, const float w, const float4 o, const float4 d,
                         const float z_lo, const float z_hi,
                         const float cell_x, const float cell_y, const int nx, const int ny,
                         __global float *power, __global float *square,
                         __global int *count, __global int *rec_segment,
                         __global int *rec_cell, __global float *rec_length,
                         volatile __global int *n_records,
                         const int capacity)
{
    float t0 = 0.0f, t1 = d.w;
    if (!clip_axis(o.z, d.z, z_lo, z_hi, &t0, &t1)) return;
    if (!clip_axis(o.x, d.x, 0.0f, cell_x * nx, &t0, &t1)) return;
    if (!clip_axis(o.y, d.y, 0.0f, cell_y * ny, &t0, &t1)) return;
    if (!(t0 < t1)) return;

    /* the cell at the segment's middle point of its first step decides where it starts:
     * the entry point itself may lie on a boundary */
    float tm = t0 + 0.5f * fmin(t1 - t0, 1e-3f * fmin(cell_x, cell_y));
    int ix = clamp((int)floor((o.x + tm * d.x) / cell_x), 0, nx - 1);
    int iy = clamp((int)floor((o.y + tm * d.y) / cell_y), 0, ny - 1);
    int step_x = d.x > 0.0f ? 1 : -1, step_y = d.y > 0.0f ? 1 : -1;
    float next_x = d.x != 0.0f
        ? ((ix + (step_x > 0 ? 1 : 0)) * cell_x - o.x) / d.x : INFINITY;
    float next_y = d.y != 0.0f
        ? ((iy + (step_y > 0 ? 1 : 0)) * cell_y - o.y) / d.y : INFINITY;
    float delta_x = d.x != 0.0f ? cell_x / fabs(d.x) : INFINITY;
    float delta_y = d.y != 0.0f ? cell_y / fabs(d.y) : INFINITY;
    float t = t0;
    for (int s = 0; s < nx + ny + MAX_STEPS_PAD; ++s) {
        float t_exit = fmin(fmin(next_x, next_y), t1);
        float inside = t_exit - t;
        if (inside > 0.0f) {
            int cell = iy * nx + ix;
            if (power) {
                const float term = w * inside;
                add_float(power + cell, term);
                add_float(square + cell, term * term);
                atomic_inc(count + cell);
            } else {
                int slot = atomic_inc(n_records);
                if (slot < capacity) {
                    rec_segment[slot] = gid;
                    rec_cell[slot] = cell;
                    rec_length[slot] = inside;
                }
            }
        }
        if (t_exit >= t1) break;
        t = t_exit;
        if (next_x <= next_y) {
            ix += step_x;
            next_x += delta_x;
        } else {
            iy += step_y;
            next_y += delta_y;
        }
        if (ix < 0 || ix >= nx || iy < 0 || iy >= ny) break;
    }
}

__kernel void accumulate_segments(__global const float4 *origin,    /* xyz, w unused */
                                  __global const float4 *direction, /* unit xyz, w length */
                                  __global const float *weight,     /* per metre in a cell */
                                  const float z_lo, const float z_hi,
                                  const float cell_x, const float cell_y,
                                  const int nx, const int ny, const int n,
                                  const int copies,
                                  __global float *power,            /* (copies, ny, nx) */
                                  __global float *square,           /* (copies, ny, nx) */
                                  __global int *count)              /* (copies, ny, nx) */
{
    int gid = get_global_id(0);
    if (gid >= n) return;
    float w = weight[gid];
    if (!(w > 0.0f)) return;
    const size_t copy = (size_t)(get_group_id(0) % (size_t)copies) * (size_t)(nx * ny);
    power += copy;
    square += copy;
    count += copy;
    walk_segment(gid, w, origin[gid], direction[gid], z_lo, z_hi, cell_x, cell_y, nx, ny,
                 power, square, count, 0, 0, 0, 0, 0);
}

/* The cells each segment crosses, as records: the coherent sum (docs/maps.md) needs each
 * segment's length in each cell apart, to weigh the phase of its wavefront at the cell's
 * centre on the host in float64. */
__kernel void segment_cells(__global const float4 *origin,
                            __global const float4 *direction,
                            const float z_lo, const float z_hi,
                            const float cell_x, const float cell_y,
                            const int nx, const int ny, const int n,
                            __global int *rec_segment, __global int *rec_cell,
                            __global float *rec_length,
                            volatile __global int *n_records, const int capacity)
{
    int gid = get_global_id(0);
    if (gid >= n) return;
    walk_segment(gid, 1.0f, origin[gid], direction[gid], z_lo, z_hi, cell_x, cell_y, nx,
                 ny, 0, 0, 0, rec_segment, rec_cell, rec_length, n_records, capacity);
}

/* ---- physical-optics facet fields at cell centres (clradcom/maps.py: _po_facets) ----
 *
 * One work item per (facet, point) pair of PEC facets: po_facet.h's field without the
 * carrier phase, which the host adds in float64 (kernels/maps_po.cl's po_pairs does the
 * same for the pairs it finds, in the launch that finds them). */
#include "po_facet.h"

__kernel void po_facet_fields(__global const po_real *facet,  /* 9 vertices - centroid,
                                                                 3 centroid, 3 lit normal,
                                                                 6 e_tx re/im xyz */
                              __global const po_real4 *point, /* xyz per pair */
                              const po_real4 source,          /* tx xyz, w = k */
                              const int n,
                              __global po_real *field)        /* 6 per pair: re/im xyz */
{
    int gid = get_global_id(0);
    if (gid >= n) return;
    __global const po_real *f = facet + 21 * gid;
    po_real3 v0 = (po_real3)(f[0], f[1], f[2]), v1 = (po_real3)(f[3], f[4], f[5]);
    po_real3 v2 = (po_real3)(f[6], f[7], f[8]);
    po_real3 c = (po_real3)(f[9], f[10], f[11]), nrm = (po_real3)(f[12], f[13], f[14]);
    po_real3 e_re = (po_real3)(f[15], f[16], f[17]), e_im = (po_real3)(f[18], f[19], f[20]);
    po_real3 o_re, o_im;
    po_facet_field(v0, v1, v2, c, nrm, e_re, e_im, source.xyz, point[gid].xyz, source.w,
                   &o_re, &o_im);
    __global po_real *out = field + 6 * gid;
    out[0] = o_re.x; out[1] = o_re.y; out[2] = o_re.z;
    out[3] = o_im.x; out[4] = o_im.y; out[5] = o_im.z;
}
