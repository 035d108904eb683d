/* The blocks of a launch window's grid that projected triangles cover: the pair test of
 * clradcom/geometry/silhouette.py: block_coverage on the device. Work item = one
 * triangle; it walks the blocks of its box in the grid (lo, cnt) and marks those that no
 * edge normal separates from it: (n_x c_x + n_y c_y) - r <= off for all three edges, with
 * the block centre c = origin + (i + 1/2) * block. The host computes the normals, offsets
 * and reaches (silhouette.py: coverage_setup) and the kernel evaluates the test's
 * expressions in double without contraction, as numpy does, so the mask is the host's
 * bit for bit. Several triangles may mark one block: each writes the same 1. */
#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#pragma OPENCL FP_CONTRACT OFF

__kernel void block_cover(__global const double *nrm,     /* (T, 3, 2) */
                          __global const double *off,     /* (T, 3) */
                          __global const double *radius,  /* (T, 3) */
                          __global const long *lo,        /* (T, 2) first block */
                          __global const long *cnt,       /* (T, 2) blocks of the box */
                          const double ox, const double oy, const double block,
                          const long ny, const int n_tri,
                          __global uchar *mask)            /* (nx, ny) */
{
    int t = get_global_id(0);
    if (t >= n_tri) return;
    double n0x = nrm[6 * t], n0y = nrm[6 * t + 1];
    double n1x = nrm[6 * t + 2], n1y = nrm[6 * t + 3];
    double n2x = nrm[6 * t + 4], n2y = nrm[6 * t + 5];
    double o0 = off[3 * t], o1 = off[3 * t + 1], o2 = off[3 * t + 2];
    double r0 = radius[3 * t], r1 = radius[3 * t + 1], r2 = radius[3 * t + 2];
    long i0 = lo[2 * t], j0 = lo[2 * t + 1];
    long ci = cnt[2 * t], cj = cnt[2 * t + 1];
    for (long a = 0; a < ci; ++a) {
        long bi = i0 + a;
        double cx = ox + ((double)bi + 0.5) * block;
        for (long b = 0; b < cj; ++b) {
            long bj = j0 + b;
            double cy = oy + ((double)bj + 0.5) * block;
            if ((n0x * cx + n0y * cy) - r0 <= o0 && (n1x * cx + n1y * cy) - r1 <= o1
                && (n2x * cx + n2y * cy) - r2 <= o2)
                mask[bi * ny + bj] = 1;
        }
    }
}
#endif
