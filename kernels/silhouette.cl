/* SBR launch windows on the device (clradcom/device/silhouette.py), without contraction,
 * in precise.h's preal: double where the device has fp64, so that every result is
 * numpy's bit for bit; double-float without (float64 inputs and outputs as (hi, lo)
 * pairs, pr_elem), every result then within ~1e-14 relative of numpy's and every test
 * the same except within that of its threshold:
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
#include "precise.h"
#pragma OPENCL FP_CONTRACT OFF

/* A block centre's coordinate: origin + (i + 1/2) * block */
PR_INLINE preal block_centre(preal origin, long i, preal block)
{
    return pr_add(origin, pr_mul(pr_add(pr_from_long(i), PR_CONST(0.5)), block));
}

/* (nx c_x + ny c_y) - r <= off: no edge normal separates the block at (cx, cy) */
PR_INLINE bool edge_reaches(preal nx, preal ny, preal r, preal off, preal cx, preal cy)
{
    return pr_le(pr_sub(pr_add(pr_mul(nx, cx), pr_mul(ny, cy)), r), off);
}

__kernel void block_cover(__global const pr_elem *nrm,    /* (T, 3, 2) */
                          __global const pr_elem *off,    /* (T, 3) */
                          __global const pr_elem *radius, /* (T, 3) */
                          __global const long *lo,        /* (T, 2) first block */
                          __global const long *cnt,       /* (T, 2) blocks of the box */
                          __global const long *window,    /* (T,) grid of the triangle */
                          __global const pr_elem *origin, /* (W, 2) */
                          __global const pr_elem *block,  /* (W,) block side */
                          __global const long *ny,        /* (W,) blocks along y */
                          __global const long *mask_off,  /* (W,) first cell */
                          const int n_tri,
                          __global uchar *mask)            /* concatenated (nx, ny) */
{
    int t = get_global_id(0);
    if (t >= n_tri) return;
    long g = window[t];
    preal ox = pr_of(origin[2 * g]), oy = pr_of(origin[2 * g + 1]), bs = pr_of(block[g]);
    long row = ny[g];
    __global uchar *m = mask + mask_off[g];
    preal nx[3], nyk[3], o[3], r[3];
    for (int k = 0; k < 3; ++k) {
        nx[k] = pr_of(nrm[6 * t + 2 * k]);
        nyk[k] = pr_of(nrm[6 * t + 2 * k + 1]);
        o[k] = pr_of(off[3 * t + k]);
        r[k] = pr_of(radius[3 * t + k]);
    }
    long i0 = lo[2 * t], j0 = lo[2 * t + 1];
    long ci = cnt[2 * t], cj = cnt[2 * t + 1];
    for (long a = 0; a < ci; ++a) {
        long bi = i0 + a;
        preal cx = block_centre(ox, bi, bs);
        for (long b = 0; b < cj; ++b) {
            long bj = j0 + b;
            preal cy = block_centre(oy, bj, bs);
            if (edge_reaches(nx[0], nyk[0], r[0], o[0], cx, cy)
                && edge_reaches(nx[1], nyk[1], r[1], o[1], cx, cy)
                && edge_reaches(nx[2], nyk[2], r[2], o[2], cx, cy))
                m[bi * row + bj] = 1;
        }
    }
}

/* (x + y) + z of three products */
PR_INLINE preal dot_xyz(preal ax, preal ay, preal az, preal bx, preal by, preal bz)
{
    return pr_add(pr_add(pr_mul(ax, bx), pr_mul(ay, by)), pr_mul(az, bz));
}

/* The windows' triangles projected centrally from the eye onto their windows' planes,
 * clradcom/mechanisms/sbr.py: _project's expressions (dot products summed (x + y) + z,
 * x = (D (p - eye).u) / depth): xy (T, 3, 2) and per triangle the extents (T, 5) that
 * the host reduces per window: the least depth, x min, x max, y min, y max. */
__kernel void project_windows(__global const pr_elem *tri,   /* (T, 3, 3) */
                              __global const long *window,   /* (T,) */
                              __global const pr_elem *frame, /* (W, 10): axis, u, v, D */
                              const pr_elem ex, const pr_elem ey, const pr_elem ez,
                              const int n_tri,
                              __global pr_elem *xy,          /* (T, 3, 2) */
                              __global pr_elem *ext)         /* (T, 5) */
{
    int t = get_global_id(0);
    if (t >= n_tri) return;
    __global const pr_elem *fr = frame + 10 * window[t];
    __global const pr_elem *v = tri + 9 * (long)t;
    preal f[10];
    for (int k = 0; k < 10; ++k) f[k] = pr_of(fr[k]);
    preal e0 = pr_of(ex), e1 = pr_of(ey), e2 = pr_of(ez);
    preal D = f[9];
    preal dmin = PR_CONST(0.0), x0 = dmin, x1 = dmin, y0 = dmin, y1 = dmin;
    for (int k = 0; k < 3; ++k) {
        preal rx = pr_sub(pr_of(v[3 * k]), e0), ry = pr_sub(pr_of(v[3 * k + 1]), e1);
        preal rz = pr_sub(pr_of(v[3 * k + 2]), e2);
        preal depth = dot_xyz(rx, ry, rz, f[0], f[1], f[2]);
        preal x = pr_div(pr_mul(D, dot_xyz(rx, ry, rz, f[3], f[4], f[5])), depth);
        preal y = pr_div(pr_mul(D, dot_xyz(rx, ry, rz, f[6], f[7], f[8])), depth);
        xy[6 * (long)t + 2 * k] = pr_elem_of(x);
        xy[6 * (long)t + 2 * k + 1] = pr_elem_of(y);
        if (k == 0) {
            dmin = depth; x0 = x; x1 = x; y0 = y; y1 = y;
        } else {
            dmin = pr_fmin(dmin, depth); x0 = pr_fmin(x0, x); x1 = pr_fmax(x1, x);
            y0 = pr_fmin(y0, y); y1 = pr_fmax(y1, y);
        }
    }
    ext[5 * (long)t] = pr_elem_of(dmin);
    ext[5 * (long)t + 1] = pr_elem_of(x0); ext[5 * (long)t + 2] = pr_elem_of(x1);
    ext[5 * (long)t + 3] = pr_elem_of(y0); ext[5 * (long)t + 4] = pr_elem_of(y1);
}

/* block_cover with the separating-axis data computed here, per triangle, by
 * clradcom/geometry/silhouette.py: coverage_setup_many's expressions: the projected
 * triangle (xy, 3 x 2) of grid `window`; triangles of (near) zero area or wholly outside
 * the grid mark nothing. */
__kernel void block_cover_xy(__global const pr_elem *xy,     /* (T, 3, 2) */
                             __global const long *window,    /* (T,) */
                             __global const pr_elem *origin, /* (W, 2) */
                             __global const pr_elem *block,  /* (W,) */
                             __global const long *shape,     /* (W, 2) */
                             __global const long *mask_off,  /* (W,) */
                             const int n_tri,
                             __global uchar *mask)
{
    int t = get_global_id(0);
    if (t >= n_tri) return;
    long g = window[t];
    preal ox = pr_of(origin[2 * g]), oy = pr_of(origin[2 * g + 1]), bs = pr_of(block[g]);
    long nx = shape[2 * g], row = shape[2 * g + 1];
    __global const pr_elem *q = xy + 6 * t;
    preal px[3] = {pr_of(q[0]), pr_of(q[2]), pr_of(q[4])};
    preal py[3] = {pr_of(q[1]), pr_of(q[3]), pr_of(q[5])};
    preal ex[3], ey[3];
    for (int k = 0; k < 3; ++k) {
        int k1 = (k + 1) % 3;
        ex[k] = pr_sub(px[k1], px[k]);
        ey[k] = pr_sub(py[k1], py[k]);
    }
    preal area2 = pr_sub(pr_mul(ex[0], ey[1]), pr_mul(ey[0], ex[1]));
    preal scale = pr_fmax(pr_fmax(pr_fmax(pr_fabs(ex[0]), pr_fabs(ey[0])),
                                  pr_fmax(pr_fabs(ex[1]), pr_fabs(ey[1]))),
                          pr_fmax(pr_fabs(ex[2]), pr_fabs(ey[2])));
    if (!pr_gt(pr_fabs(area2), pr_mul(pr_mul(PR_CONST(1e-12), scale), scale))) return;
    preal lo_x = pr_fmin(pr_fmin(px[0], px[1]), px[2]), hi_x = pr_fmax(pr_fmax(px[0], px[1]), px[2]);
    preal lo_y = pr_fmin(pr_fmin(py[0], py[1]), py[2]), hi_y = pr_fmax(pr_fmax(py[0], py[1]), py[2]);
    long i0 = pr_to_long(pr_floor(pr_div(pr_sub(lo_x, ox), bs)));
    long i1 = pr_to_long(pr_floor(pr_div(pr_sub(hi_x, ox), bs)));
    long j0 = pr_to_long(pr_floor(pr_div(pr_sub(lo_y, oy), bs)));
    long j1 = pr_to_long(pr_floor(pr_div(pr_sub(hi_y, oy), bs)));
    i0 = max(i0, 0L); j0 = max(j0, 0L);
    i1 = min(i1, nx - 1); j1 = min(j1, row - 1);
    if (i1 < i0 || j1 < j0) return;
    preal sgn = pr_gt(area2, PR_CONST(0.0)) ? PR_CONST(1.0) : PR_CONST(-1.0);
    preal nxk[3], nyk[3], o[3], r[3];
    preal half_bs = pr_mul(PR_CONST(0.5), bs);
    for (int k = 0; k < 3; ++k) {
        nxk[k] = pr_mul(ey[k], sgn);
        nyk[k] = pr_mul(pr_neg(ex[k]), sgn);
        o[k] = pr_add(pr_mul(nxk[k], px[k]), pr_mul(nyk[k], py[k]));
        r[k] = pr_mul(half_bs, pr_add(pr_fabs(nxk[k]), pr_fabs(nyk[k])));
    }
    __global uchar *m = mask + mask_off[g];
    for (long bi = i0; bi <= i1; ++bi) {
        preal cx = block_centre(ox, bi, bs);
        for (long bj = j0; bj <= j1; ++bj) {
            preal cy = block_centre(oy, bj, bs);
            if (edge_reaches(nxk[0], nyk[0], r[0], o[0], cx, cy)
                && edge_reaches(nxk[1], nyk[1], r[1], o[1], cx, cy)
                && edge_reaches(nxk[2], nyk[2], r[2], o[2], cx, cy))
                m[bi * row + bj] = 1;
        }
    }
}

__kernel void beside_cull(__global const pr_elem *tri,    /* (N, 3, 3) triangles */
                          __global const int *tri_index,  /* triangles of the windows */
                          __global const long *tri_start, /* (W,) first in tri_index */
                          __global const long *pair_start,/* (W + 1,) first pair */
                          const int n_win,
                          __global const pr_elem *frame,  /* (W, 10): axis, u, v, D */
                          __global const pr_elem *rect,   /* (W, 4): lo x, lo y, hi x, hi y */
                          const pr_elem ex, const pr_elem ey, const pr_elem ez,
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
    __global const pr_elem *fr = frame + 10 * w;
    __global const pr_elem *r = rect + 4 * w;
    __global const pr_elem *v = tri + 9 * (long)tri_index[tri_start[w] + (p - pair_start[w])];
    preal f[10];
    for (int k = 0; k < 10; ++k) f[k] = pr_of(fr[k]);
    preal e0 = pr_of(ex), e1 = pr_of(ey), e2 = pr_of(ez);
    preal D = f[9];
    preal lx = pr_of(r[0]), ly = pr_of(r[1]), hx = pr_of(r[2]), hy = pr_of(r[3]);
    preal reach = pr_add(pr_add(pr_fmax(pr_fabs(lx), pr_fabs(ly)), pr_fmax(pr_fabs(hx), pr_fabs(hy))),
                         D);
    int right = 1, left = 1, top = 1, bottom = 1;
    for (int k = 0; k < 3; ++k) {
        preal rx = pr_sub(pr_of(v[3 * k]), e0), ry = pr_sub(pr_of(v[3 * k + 1]), e1);
        preal rz = pr_sub(pr_of(v[3 * k + 2]), e2);
        preal depth = dot_xyz(rx, ry, rz, f[0], f[1], f[2]);
        preal x = pr_mul(D, dot_xyz(rx, ry, rz, f[3], f[4], f[5]));
        preal y = pr_mul(D, dot_xyz(rx, ry, rz, f[6], f[7], f[8]));
        preal margin = pr_mul(PR_CONST(1e-9), pr_add(pr_add(pr_fabs(x), pr_fabs(y)),
                                                     pr_mul(reach, pr_fabs(depth))));
        right &= pr_gt(pr_sub(x, pr_mul(hx, depth)), margin);
        left &= pr_gt(pr_sub(pr_mul(lx, depth), x), margin);
        top &= pr_gt(pr_sub(y, pr_mul(hy, depth)), margin);
        bottom &= pr_gt(pr_sub(pr_mul(ly, depth), y), margin);
    }
    beside[p] = (uchar)(right | left | top | bottom);
}
