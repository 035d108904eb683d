/* SBR launch windows on the device (clradcom/device/silhouette.py), double precision
 * without contraction so that every result is numpy's bit for bit:
 *
 * block_cover: the blocks of the windows' grids that projected triangles cover, the pair
 * test of clradcom/geometry/silhouette.py: cover_blocks_many. Work item = one triangle
 * of any window; it walks the blocks of its box in its window's grid (lo, cnt) and marks
 * those that no edge normal separates from it: (n_x c_x + n_y c_y) - r <= off for all
 * three edges, with the block centre c = origin + (i + 1/2) * block. The host computes
 * the normals, offsets and reaches (silhouette.py: coverage_setup_many). Several
 * triangles may mark one block: each writes the same 1.
 *
 * beside_cull: the mirror windows' clip triangles that lie wholly beyond one side plane
 * of the pyramid from the eye through the rectangle of the window's covered blocks
 * (clradcom/mechanisms/sbr.py: _beside, the same expressions). Work item = one (window,
 * triangle) pair: window w's pairs are pair_start[w] .. pair_start[w+1]-1, its triangles
 * tri_index[tri_start[w] + k]. */
#include "fastmath.h"
#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#pragma OPENCL FP_CONTRACT OFF

__kernel void block_cover(__global const double *nrm,     /* (T, 3, 2) */
                          __global const double *off,     /* (T, 3) */
                          __global const double *radius,  /* (T, 3) */
                          __global const long *lo,        /* (T, 2) first block */
                          __global const long *cnt,       /* (T, 2) blocks of the box */
                          __global const long *window,    /* (T,) grid of the triangle */
                          __global const double *origin,  /* (W, 2) */
                          __global const double *block,   /* (W,) block side */
                          __global const long *ny,        /* (W,) blocks along y */
                          __global const long *mask_off,  /* (W,) first cell */
                          const int n_tri,
                          __global uchar *mask)            /* concatenated (nx, ny) */
{
    int t = get_global_id(0);
    if (t >= n_tri) return;
    long g = window[t];
    double ox = origin[2 * g], oy = origin[2 * g + 1], bs = block[g];
    long row = ny[g];
    __global uchar *m = mask + mask_off[g];
    double n0x = nrm[6 * t], n0y = nrm[6 * t + 1];
    double n1x = nrm[6 * t + 2], n1y = nrm[6 * t + 3];
    double n2x = nrm[6 * t + 4], n2y = nrm[6 * t + 5];
    double o0 = off[3 * t], o1 = off[3 * t + 1], o2 = off[3 * t + 2];
    double r0 = radius[3 * t], r1 = radius[3 * t + 1], r2 = radius[3 * t + 2];
    long i0 = lo[2 * t], j0 = lo[2 * t + 1];
    long ci = cnt[2 * t], cj = cnt[2 * t + 1];
    for (long a = 0; a < ci; ++a) {
        long bi = i0 + a;
        double cx = ox + ((double)bi + 0.5) * bs;
        for (long b = 0; b < cj; ++b) {
            long bj = j0 + b;
            double cy = oy + ((double)bj + 0.5) * bs;
            if ((n0x * cx + n0y * cy) - r0 <= o0 && (n1x * cx + n1y * cy) - r1 <= o1
                && (n2x * cx + n2y * cy) - r2 <= o2)
                m[bi * row + bj] = 1;
        }
    }
}

/* The windows' triangles projected centrally from the eye onto their windows' planes,
 * clradcom/mechanisms/sbr.py: _project's expressions (dot products summed (x + y) + z,
 * x = (D (p - eye).u) / depth): xy (T, 3, 2) and per triangle the extents (T, 5) that
 * the host reduces per window: the least depth, x min, x max, y min, y max. */
__kernel void project_windows(__global const double *tri,    /* (T, 3, 3) */
                              __global const long *window,   /* (T,) */
                              __global const double *frame,  /* (W, 10): axis, u, v, D */
                              const double ex, const double ey, const double ez,
                              const int n_tri,
                              __global double *xy,           /* (T, 3, 2) */
                              __global double *ext)          /* (T, 5) */
{
    int t = get_global_id(0);
    if (t >= n_tri) return;
    __global const double *f = frame + 10 * window[t];
    __global const double *v = tri + 9 * (long)t;
    double D = f[9];
    double dmin = 0.0, x0 = 0.0, x1 = 0.0, y0 = 0.0, y1 = 0.0;
    for (int k = 0; k < 3; ++k) {
        double rx = v[3 * k] - ex, ry = v[3 * k + 1] - ey, rz = v[3 * k + 2] - ez;
        double depth = (rx * f[0] + ry * f[1]) + rz * f[2];
        double x = D * ((rx * f[3] + ry * f[4]) + rz * f[5]) / depth;
        double y = D * ((rx * f[6] + ry * f[7]) + rz * f[8]) / depth;
        xy[6 * (long)t + 2 * k] = x;
        xy[6 * (long)t + 2 * k + 1] = y;
        if (k == 0) {
            dmin = depth; x0 = x; x1 = x; y0 = y; y1 = y;
        } else {
            dmin = fmin(dmin, depth); x0 = fmin(x0, x); x1 = fmax(x1, x);
            y0 = fmin(y0, y); y1 = fmax(y1, y);
        }
    }
    ext[5 * (long)t] = dmin;
    ext[5 * (long)t + 1] = x0; ext[5 * (long)t + 2] = x1;
    ext[5 * (long)t + 3] = y0; ext[5 * (long)t + 4] = y1;
}

/* block_cover with the separating-axis data computed here, per triangle, by
 * clradcom/geometry/silhouette.py: coverage_setup_many's expressions: the projected
 * triangle (xy, 3 x 2) of grid `window`; triangles of (near) zero area or wholly outside
 * the grid mark nothing. */
__kernel void block_cover_xy(__global const double *xy,      /* (T, 3, 2) */
                             __global const long *window,    /* (T,) */
                             __global const double *origin,  /* (W, 2) */
                             __global const double *block,   /* (W,) */
                             __global const long *shape,     /* (W, 2) */
                             __global const long *mask_off,  /* (W,) */
                             const int n_tri,
                             __global uchar *mask)
{
    int t = get_global_id(0);
    if (t >= n_tri) return;
    long g = window[t];
    double ox = origin[2 * g], oy = origin[2 * g + 1], bs = block[g];
    long nx = shape[2 * g], row = shape[2 * g + 1];
    __global const double *q = xy + 6 * t;
    double px[3] = {q[0], q[2], q[4]}, py[3] = {q[1], q[3], q[5]};
    double ex[3], ey[3];
    for (int k = 0; k < 3; ++k) {
        int k1 = (k + 1) % 3;
        ex[k] = px[k1] - px[k];
        ey[k] = py[k1] - py[k];
    }
    double area2 = ex[0] * ey[1] - ey[0] * ex[1];
    double scale = fmax(fmax(fmax(fabs(ex[0]), fabs(ey[0])), fmax(fabs(ex[1]), fabs(ey[1]))),
                        fmax(fabs(ex[2]), fabs(ey[2])));
    if (!(fabs(area2) > 1e-12 * scale * scale)) return;
    double lo_x = fmin(fmin(px[0], px[1]), px[2]), hi_x = fmax(fmax(px[0], px[1]), px[2]);
    double lo_y = fmin(fmin(py[0], py[1]), py[2]), hi_y = fmax(fmax(py[0], py[1]), py[2]);
    long i0 = (long)floor((lo_x - ox) / bs), i1 = (long)floor((hi_x - ox) / bs);
    long j0 = (long)floor((lo_y - oy) / bs), j1 = (long)floor((hi_y - oy) / bs);
    i0 = max(i0, 0L); j0 = max(j0, 0L);
    i1 = min(i1, nx - 1); j1 = min(j1, row - 1);
    if (i1 < i0 || j1 < j0) return;
    double sgn = (area2 > 0.0) ? 1.0 : -1.0;
    double nxk[3], nyk[3], o[3], r[3];
    double half_bs = 0.5 * bs;
    for (int k = 0; k < 3; ++k) {
        nxk[k] = ey[k] * sgn;
        nyk[k] = -ex[k] * sgn;
        o[k] = nxk[k] * px[k] + nyk[k] * py[k];
        r[k] = half_bs * (fabs(nxk[k]) + fabs(nyk[k]));
    }
    __global uchar *m = mask + mask_off[g];
    for (long bi = i0; bi <= i1; ++bi) {
        double cx = ox + ((double)bi + 0.5) * bs;
        for (long bj = j0; bj <= j1; ++bj) {
            double cy = oy + ((double)bj + 0.5) * bs;
            if ((nxk[0] * cx + nyk[0] * cy) - r[0] <= o[0]
                && (nxk[1] * cx + nyk[1] * cy) - r[1] <= o[1]
                && (nxk[2] * cx + nyk[2] * cy) - r[2] <= o[2])
                m[bi * row + bj] = 1;
        }
    }
}

__kernel void beside_cull(__global const double *tri,     /* (N, 3, 3) triangles */
                          __global const int *tri_index,  /* triangles of the windows */
                          __global const long *tri_start, /* (W,) first in tri_index */
                          __global const long *pair_start,/* (W + 1,) first pair */
                          const int n_win,
                          __global const double *frame,   /* (W, 10): axis, u, v, D */
                          __global const double *rect,    /* (W, 4): lo x, lo y, hi x, hi y */
                          const double ex, const double ey, const double ez,
                          __global uchar *beside)         /* (pairs,) 1: culled */
{
    long p = get_global_id(0);
    if (p >= pair_start[n_win]) return;
    int lo_w = 0, hi_w = n_win - 1;   /* the last window whose first pair is <= p */
    while (lo_w < hi_w) {
        int mid = (lo_w + hi_w + 1) / 2;
        if (pair_start[mid] <= p) lo_w = mid; else hi_w = mid - 1;
    }
    int w = lo_w;
    __global const double *f = frame + 10 * w;
    __global const double *r = rect + 4 * w;
    __global const double *v = tri + 9 * (long)tri_index[tri_start[w] + (p - pair_start[w])];
    double D = f[9];
    double lx = r[0], ly = r[1], hx = r[2], hy = r[3];
    double reach = (fmax(fabs(lx), fabs(ly)) + fmax(fabs(hx), fabs(hy))) + D;
    int right = 1, left = 1, top = 1, bottom = 1;
    for (int k = 0; k < 3; ++k) {
        double rx = v[3 * k] - ex, ry = v[3 * k + 1] - ey, rz = v[3 * k + 2] - ez;
        double depth = (rx * f[0] + ry * f[1]) + rz * f[2];
        double x = D * ((rx * f[3] + ry * f[4]) + rz * f[5]);
        double y = D * ((rx * f[6] + ry * f[7]) + rz * f[8]);
        double margin = 1e-9 * ((fabs(x) + fabs(y)) + reach * fabs(depth));
        right &= (x - hx * depth) > margin;
        left &= (lx * depth - x) > margin;
        top &= (y - hy * depth) > margin;
        bottom &= (ly * depth - y) > margin;
    }
    beside[p] = (uchar)(right | left | top | bottom);
}
#endif
