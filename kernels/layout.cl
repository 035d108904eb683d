/* Reports the device's sizes and member offsets of the shared structs, and the
 * numbers the host passed as -D options as the kernels' headers see them, so
 * the host can prove both match its own (tests/test_opencl.py). OpenCL C has
 * no offsetof, so offsets are pointer differences within a local instance. */
#include "intersect.h"

#define MEMBER_OFFSET(s, m) ((int)((const char *)&(s).m - (const char *)&(s)))

__kernel void struct_layout(__global int *out)
{
    if (get_global_id(0) != 0) return;
    BVHNode n;
    Ray r;
    Hit h;
    Bvh8Node b8;
    out[0] = sizeof(BVHNode);
    out[1] = MEMBER_OFFSET(n, left_first);
    out[2] = MEMBER_OFFSET(n, bmax);
    out[3] = MEMBER_OFFSET(n, count);
    out[4] = sizeof(Ray);
    out[5] = MEMBER_OFFSET(r, tmin);
    out[6] = MEMBER_OFFSET(r, dir);
    out[7] = MEMBER_OFFSET(r, tmax);
    out[8] = sizeof(Hit);
    out[9] = MEMBER_OFFSET(h, prim);
    out[10] = MEMBER_OFFSET(h, ng);
    out[11] = MEMBER_OFFSET(h, pad);
    out[12] = sizeof(Bvh8Node);
    out[13] = MEMBER_OFFSET(b8, miny);
    out[14] = MEMBER_OFFSET(b8, maxx);
    out[15] = MEMBER_OFFSET(b8, child);
    out[16] = MEMBER_OFFSET(b8, pad);
}

/* In the order of clradcom.device.raycast.KERNEL_DEFINES. */
__kernel void build_constants(__global int *out)
{
    if (get_global_id(0) != 0) return;
    out[0] = BVH_WIDTH;
    out[1] = BVH_STACK_SIZE;
    out[2] = TRI4_ROWS;
    out[3] = LEAF_GROUP_BITS;
    out[4] = SPAWN_OFFSET_ROUNDOFFS;
    out[5] = PACKET_MAX;
}

/* The two-level BVH's instance record (clradcom/geometry/instances.py). */
__kernel void instance_layout(__global int *out)
{
    if (get_global_id(0) != 0) return;
    Bvh8Instance in;
    out[0] = sizeof(Bvh8Instance);
    out[1] = MEMBER_OFFSET(in, origin);
    out[2] = MEMBER_OFFSET(in, local_to_world);
    out[3] = MEMBER_OFFSET(in, root);
    out[4] = MEMBER_OFFSET(in, identity);
    out[5] = MEMBER_OFFSET(in, first_group);
    out[6] = MEMBER_OFFSET(in, end_group);
}
