/* Diffuse-scattering tiles on the device (clradcom/device/scatter.py drives these;
 * docs/scattering.md "On the device").
 *
 *   tile_centres   the tiles of the scattering triangles: centroid (double) and triangle
 *   tile_sight     front side and float32 sight line of every tile centre to tx and rx
 *   tile_lambert   Lambertian power of the tiles both ends see, compacted (atomic counter)
 *
 * Every position is double, computed with the host's operations in the host's order
 * (FP_CONTRACT is off, intersect.h), so a tile centre, a spawned origin and the float32
 * ray cast from it are the host's (clradcom/mechanisms/scattering.py: make_tiles,
 * clradcom/device/visibility.py: surface_sees) bit for bit. Only the sight casts are
 * float32, as on the host; the float64 antenna-end check stays on the host. */
#include "intersect.h"

#ifndef CLRADCOM_HAS_FP64
#error "scatter.cl needs cl_khr_fp64 (the host falls back to its numpy path without it)"
#endif
#ifndef SPAWN_OFFSET_ROUNDOFFS
#error "SPAWN_OFFSET_ROUNDOFFS must be passed as -D by the host"
#endif

/* The traced triangle k holding tile g: tile_first[k] <= g < tile_first[k + 1]. */
CLR_INLINE int tile_triangle(__global const int *tile_first, int n_tri, int g)
{
    int lo = 0, hi = n_tri;   /* invariant: tile_first[lo] <= g < tile_first[hi] */
    while (hi - lo > 1) {
        int mid = (lo + hi) >> 1;
        if (tile_first[mid] <= g) lo = mid; else hi = mid;
    }
    return lo;
}

/* Tile centroids by regular barycentric subdivision (n x n similar sub-triangles): the
 * "up" tiles (i, j), j < n - i, at barycentric ((3i+1)/3n, (3j+1)/3n), then the "down"
 * tiles, j < n - 1 - i, at ((3i+2)/3n, (3j+2)/3n); per triangle in that order, as the
 * host's make_tiles lists them. centre = v0 + u (v1 - v0) + v (v2 - v0). */
__kernel void tile_centres(__global const Bvh8Node *nodes, __global const float4 *tri4,
                           __global const int *slot_prim,
                           __global const double *vertices,  /* (K, 3, 3) */
                           __global const int *tile_first,   /* (K + 1,) */
                           __global const int *tile_n,       /* (K,) subdivisions */
                           const int n_tri, const int n_tiles,
                           __global double *centres,         /* (N, 3) out */
                           __global int *tile_tri)           /* (N,) out: k */
{
    int g = get_global_id(0);
    if (g >= n_tiles) return;
    int k = tile_triangle(tile_first, n_tri, g);
    int n = tile_n[k];
    int li = g - tile_first[k];   /* the tile within its triangle */
    int up = n * (n + 1) / 2;
    int off = 1, rows = n;           /* up tiles: row i holds n - i of them */
    if (li >= up) {               /* down tiles: row i holds n - 1 - i */
        li -= up;
        off = 2;
        rows = n - 1;
    }
    int i = 0;
    while (li >= rows - i) {
        li -= rows - i;
        ++i;
    }
    double u = (double)(3 * i + off) / (double)(3 * n);
    double v = (double)(3 * li + off) / (double)(3 * n);
    __global const double *t = vertices + 9 * (size_t)k;
    for (int c = 0; c < 3; ++c)
        centres[3 * (size_t)g + c] = (t[c] + u * (t[3 + c] - t[c])) + v * (t[6 + c] - t[c]);
    tile_tri[g] = k;
}

/* Does the tile centre q (normal nrm, triangle prim) see the antenna at a? The host's
 * surface_sees: origin spawned off the surface toward a (raycast.spawn_origins), float32
 * ray origin -> a, stopping at tmax (1 - SIGHT_STOP) of it, prim itself ignored. */
CLR_INLINE bool tile_sees(__global const Bvh8Node *nodes, __global const float4 *tri4,
                          __global const int *slot_prim, const double *q,
                          const double *nrm, int prim, const double *a, float tmax)
{
    double dir[3] = {a[0] - q[0], a[1] - q[1], a[2] - q[2]};
    double m = fabs(q[0]);
    m = fmax(m, fabs(q[1]));
    m = fmax(m, fabs(q[2]));
    double bound = ((double)SPAWN_OFFSET_ROUNDOFFS * 0x1p-24) * (m + 1.0);
    double s = (nrm[0] * dir[0] + nrm[1] * dir[1]) + nrm[2] * dir[2];
    double side = (s < 0.0) ? -1.0 : 1.0;
    double n_len = sqrt((nrm[0] * nrm[0] + nrm[1] * nrm[1]) + nrm[2] * nrm[2]);
    if (n_len == 0.0) n_len = 1.0;
    double step = side * bound / n_len;
    double org[3];
    for (int c = 0; c < 3; ++c) org[c] = q[c] + step * nrm[c];
    float3 o32 = (float3)((float)org[0], (float)org[1], (float)org[2]);
    float3 d32 = (float3)((float)(a[0] - org[0]), (float)(a[1] - org[1]),
                          (float)(a[2] - org[2]));
    PreparedRay pr = prepare_ray(o32, d32);
    return !bvh_any(nodes, tri4, slot_prim, &pr, 0.0f, tmax, prim, -1);
}

/* flags[g]: bit 0 the tile's front faces tx and tx sees it, bit 1 the same for rx
 * (front: n . (end - q) > 0). all_ends == 0 (direct paths only): a tile counts only when
 * both fronts face their ends, and rx is cast only where tx sees it (bit 1 then means
 * both). all_ends == 1: each end on its own; monostatic (tx == rx) copies bit 0. */
__kernel void tile_sight(__global const Bvh8Node *nodes, __global const float4 *tri4,
                         __global const int *slot_prim,
                         __global const double *centres, __global const int *tile_tri,
                         __global const double *normals,   /* (K, 3) unit */
                         __global const int *prim,         /* (K,) scene triangle */
                         const double tx_x, const double tx_y, const double tx_z,
                         const double rx_x, const double rx_y, const double rx_z,
                         const float tmax, const int all_ends, const int monostatic,
                         const int n_tiles, __global uchar *flags)
{
    int g = get_global_id(0);
    if (g >= n_tiles) return;
    int k = tile_tri[g];
    double q[3] = {centres[3 * (size_t)g], centres[3 * (size_t)g + 1],
                   centres[3 * (size_t)g + 2]};
    double nrm[3] = {normals[3 * k], normals[3 * k + 1], normals[3 * k + 2]};
    double tx[3] = {tx_x, tx_y, tx_z}, rx[3] = {rx_x, rx_y, rx_z};
    bool front_t = ((nrm[0] * (tx[0] - q[0]) + nrm[1] * (tx[1] - q[1]))
                    + nrm[2] * (tx[2] - q[2])) > 0.0;
    bool front_r = ((nrm[0] * (rx[0] - q[0]) + nrm[1] * (rx[1] - q[1]))
                    + nrm[2] * (rx[2] - q[2])) > 0.0;
    int p = prim[k];
    uchar out = 0;
    if (all_ends == 0) {
        if (front_t && front_r && tile_sees(nodes, tri4, slot_prim, q, nrm, p, tx, tmax)) {
            out = 1;
            if (monostatic || tile_sees(nodes, tri4, slot_prim, q, nrm, p, rx, tmax))
                out |= 2;
        }
    } else {
        if (front_t && tile_sees(nodes, tri4, slot_prim, q, nrm, p, tx, tmax))
            out = 1;
        if (monostatic)
            out |= (uchar)(out << 1);
        else if (front_r && tile_sees(nodes, tri4, slot_prim, q, nrm, p, rx, tmax))
            out |= 2;
    }
    flags[g] = out;
}

/* The tiles both ends see (flags == 3), packed in any order by an atomic counter with
 * their centre and Lambertian power for isotropic antennas and Gamma = 1:
 *   power = scale S^2 A cos(theta_i) cos(theta_s) / (r_i^2 r_s^2),
 * scale = lambda^2 / (16 pi^3) (docs/scattering.md), the bound the host's threshold
 * pre-cut uses. counter[0] ends as the number of such tiles. */
__kernel void tile_lambert(__global const Bvh8Node *nodes, __global const float4 *tri4,
                           __global const int *slot_prim,
                           __global const double *centres, __global const int *tile_tri,
                           __global const double *normals,      /* (K, 3) unit */
                           __global const double *tile_area,    /* (K,) one tile's area */
                           __global const double *scattering,   /* (K,) S */
                           __global const uchar *flags,
                           const double tx_x, const double tx_y, const double tx_z,
                           const double rx_x, const double rx_y, const double rx_z,
                           const double scale, const int n_tiles,
                           __global int *counter, __global int *out_tile,
                           __global double *out_centre, __global double *out_power)
{
    int g = get_global_id(0);
    if (g >= n_tiles || flags[g] != 3) return;
    int k = tile_tri[g];
    double3 q = (double3)(centres[3 * (size_t)g], centres[3 * (size_t)g + 1],
                          centres[3 * (size_t)g + 2]);
    double3 n = (double3)(normals[3 * k], normals[3 * k + 1], normals[3 * k + 2]);
    double3 dt = q - (double3)(tx_x, tx_y, tx_z);
    double3 dr = (double3)(rx_x, rx_y, rx_z) - q;
    double ri2 = dot(dt, dt), rs2 = dot(dr, dr);
    double ri = sqrt(ri2), rs = sqrt(rs2);
    double cos_i = clamp(-dot(dt, n) / ri, 0.0, 1.0);
    double cos_s = clamp(dot(dr, n) / rs, 0.0, 1.0);
    double S = scattering[k];
    double power = scale * S * S * tile_area[k] * cos_i * cos_s / (ri2 * rs2);
    int row = atomic_inc(counter);
    out_tile[row] = g;
    for (int c = 0; c < 3; ++c) out_centre[3 * (size_t)row + c] = centres[3 * (size_t)g + c];
    out_power[row] = power;
}
