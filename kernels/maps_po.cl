/* A radio map's PO facet-cell pairs in one launch (clradcom/device/maps.py: po_pairs,
 * clradcom/maps.py: _po_facets; docs/maps.md "The PO stage in one launch").
 *
 * One work item per (facet, cell) pair of the lit facets and every cell centre, the
 * pair start + index in facet-major order made from the work item's index (no host
 * array per pair). In the order of their cost, and as the host's pair-wise reference
 * (clradcom/maps.py: _po_pairs) takes them:
 *
 *   front     the centre on the facet's lit side: n . centre > n . centroid (world);
 *   sector    the arrival -(centre - centroid) inside a box in the receiver's frame
 *             that holds its pattern's support (bounds on |azimuth|, |z| and x grown by
 *             a margin: conservative, the host keeps the exact pattern test);
 *   sight     nothing between the facet and the centre: the float32 any-hit cast of
 *             raycast.cl's any_hit from the facet's centroid pushed off it (the host's
 *             spawn_origins, given per facet) to the centre, tmax just under 1, the
 *             facet's own triangle ignored: the host's rays rounded as pack_rays rounds
 *             them, so the two decide alike;
 *   field     where the facet is PEC and neither the transmitter nor the centre is in
 *             its near zone (closer than NEAR_SIZE_FACTOR times its longest edge),
 *             po_facet.h's field without the carrier phase (double with -D PO_DOUBLE).
 *
 * Every pair that passes the first three is appended at a slot of a compact list: its
 * index in the launch (the work item's), negated minus one where the host weighs its
 * field (near-zone pieces, penetrable materials), and its
 * field. A launch keeps at most capacity pairs: a pair that finds the list full (or
 * comes to its cast once it is) lowers *resume to its index instead, and the host
 * keeps the pairs under *resume and starts the next launch there. The list's order is
 * the device's; the host sorts it by index. */
#include "intersect.h"
#include "po_facet.h"

/* PO_FACET_ROWS numbers per facet (-D from clradcom/device/maps.py): 0-8 vertices -
 * centroid, 9-11 centroid, 12-14 lit unit normal, 15-20 the transmitter's field re/im
 * xyz (these about the grid's corner, as po_facet_fields takes them), 21-23 the sight
 * rays' origin (world), 24 n . centroid (world), 25 the near zone's reach, 26 the
 * distance from the transmitter, the rest unused */

__kernel void po_pairs(__global const Bvh8Node *nodes,
                       __global const float4 *tri4,
                       __global const int *slot_prim,
                       __global const po_real *facet,       /* PO_FACET_ROWS per facet */
                       __global const int2 *facet_id,       /* scene triangle, 1 if PEC */
                       __global const po_real4 *centre,     /* cell centres, world xyz */
                       const po_real4 corner,               /* grid corner xyz, w = k */
                       const po_real4 source,               /* tx about the corner */
                       __global const po_real *receiver,    /* 9 rotation, 3 bounds */
                       const int has_receiver,
                       const float sight_tmax,
                       const long start, const int n, const int n_cells,
                       __global int *out_pair,
                       __global po_real *out_field,         /* 6 per slot: re/im xyz */
                       volatile __global int *n_out, const int capacity,
                       volatile __global int *resume)
{
    const int gid = get_global_id(0);
    if (gid >= n) return;
    const long pair = start + gid;
    const int f = (int)(pair / n_cells), cell = (int)(pair % n_cells);
    __global const po_real *row = facet + PO_FACET_ROWS * f;
    const po_real3 nrm = (po_real3)(row[12], row[13], row[14]);
    const po_real3 at = centre[cell].xyz;
    if (!(dot(nrm, at) > row[24])) return;

    const po_real3 c = (po_real3)(row[9], row[10], row[11]);
    const po_real3 point = at - corner.xyz;
    const po_real3 toward = point - c;
    const po_real to_centre = length(toward);
    if (has_receiver) {
        /* the arrival -toward in the receiver's frame: d = -toward R (the host's
         * _rotate(-arrival, R)), against the bounds of its pattern's support */
        const po_real3 a = -toward / to_centre;
        const po_real dx = a.x * receiver[0] + a.y * receiver[3] + a.z * receiver[6];
        const po_real dy = a.x * receiver[1] + a.y * receiver[4] + a.z * receiver[7];
        const po_real dz = a.x * receiver[2] + a.y * receiver[5] + a.z * receiver[8];
        /* |azimuth| <= h as dx >= cos(h) |(dx, dy)|: no atan2 (a third of the launch) */
        if (dx < receiver[9] * sqrt(dx * dx + dy * dy) || fabs(dz) > receiver[10]
            || dx < receiver[11])
            return;
    }

    /* the list is full: the next launch starts at or before this pair. The count only
     * grows, so a plain read's stale value only lets a pair on to the atomic_inc below,
     * which decides; an atomic read of the counter every work item shares cost a fifth
     * of the launch (its cache line passed between the cores). Oclgrind's race check
     * counts the plain read, so its builds read atomically (kernels/maps.cl). */
#ifdef CLR_ATOMIC_FIRST_READ
    const int listed = atomic_or(n_out, 0);
#else
    const int listed = *n_out;
#endif
    if (listed >= capacity) {
        atomic_min(resume, gid);
        return;
    }
    const int2 id = facet_id[f];
    const po_real3 origin = (po_real3)(row[21], row[22], row[23]);
    const po_real3 span = at - origin;
    PreparedRay pr = prepare_ray((float3)((float)origin.x, (float)origin.y, (float)origin.z),
                                 (float3)((float)span.x, (float)span.y, (float)span.z));
    if (bvh_any(nodes, tri4, slot_prim, &pr, 0.0f, sight_tmax, id.x, -1)) return;

    const bool whole = id.y && fmin(to_centre, row[26]) >= row[25];
    const int slot = atomic_inc(n_out);
    if (slot >= capacity) {
        atomic_min(resume, gid);
        return;
    }
    out_pair[slot] = whole ? gid : -1 - gid;
    __global po_real *out = out_field + 6 * slot;
    po_real3 o_re = (po_real3)(0.0, 0.0, 0.0), o_im = (po_real3)(0.0, 0.0, 0.0);
    if (whole) {
        const po_real3 v0 = (po_real3)(row[0], row[1], row[2]);
        const po_real3 v1 = (po_real3)(row[3], row[4], row[5]);
        const po_real3 v2 = (po_real3)(row[6], row[7], row[8]);
        const po_real3 e_re = (po_real3)(row[15], row[16], row[17]);
        const po_real3 e_im = (po_real3)(row[18], row[19], row[20]);
        po_facet_field(v0, v1, v2, c, nrm, e_re, e_im, source.xyz, point, corner.w, &o_re,
                       &o_im);
    }
    out[0] = o_re.x; out[1] = o_re.y; out[2] = o_re.z;
    out[3] = o_im.x; out[4] = o_im.y; out[5] = o_im.z;
}
