/* Structs shared between host and kernels. The host mirrors each one with a
 * numpy dtype in clradcom/device/raycast.py (clradcom/geometry/bvh.py for
 * BVHNode, clradcom/geometry/layout.py for Bvh8Node); a test checks the sizes
 * agree. No float3 in shared structs: its 16-byte alignment differs between
 * host and device, so every member is a scalar or array and padding is
 * explicit. */
#ifndef CLRADCOM_TYPES_H
#define CLRADCOM_TYPES_H

/* Shared numbers come from the host (clradcom/geometry/layout.py) as -D options,
 * never from a copy here that could drift from it. */
#ifndef BVH_WIDTH
#error "BVH_WIDTH must be passed as -D by the host"
#endif
#if BVH_WIDTH != 8
#error "the traversal tests a record's child boxes as one float8: BVH_WIDTH must be 8"
#endif

/* 32 bytes. Inner node: count == 0, children at left_first and left_first+1.
 * Leaf: count > 0 triangles at tri_index[left_first .. left_first+count). */
typedef struct {
    float bmin[3];
    int left_first;
    float bmax[3];
    int count;
} BVHNode;

/* 256 bytes: the 8-wide traversal layout (clradcom/geometry/layout.py: bvh8_nodes),
 * collapsed on the host from the binary BVHNode tree. Bounds are stored per
 * axis for the eight child slots (structure of arrays, 32-byte rows) so one
 * float8 op tests all eight. child[i] > 0: an inner child, its record index;
 * child[i] < 0: a leaf, -(first_group * 32 + groups) - 1 over the Tri4 groups
 * (kernels/intersect.h); child[i] == 0: an empty slot (record 0 is the root,
 * never a child), whose bounds are +inf / -inf so that no ray hits it. */
typedef struct {
    float minx[BVH_WIDTH];
    float miny[BVH_WIDTH];
    float minz[BVH_WIDTH];
    float maxx[BVH_WIDTH];
    float maxy[BVH_WIDTH];
    float maxz[BVH_WIDTH];
    int child[BVH_WIDTH];
    int pad[BVH_WIDTH];
} Bvh8Node;

/* 256 bytes, one Bvh8Node record's room: an instance of the two-level BVH
 * (kernels/intersect.h, -D BVH_INSTANCED; clradcom/geometry/instances.py).
 * world = R local + origin; world_to_local is R^T and local_to_world R, both
 * row-major. root: the record of its bottom-level tree's root; identity: the
 * instance is not moved (the ray is used as is); its Tri4 groups are
 * [first_group, end_group). */
typedef struct {
    float world_to_local[9];
    float origin[3];
    float local_to_world[9];
    int root;
    int identity;
    int first_group;
    int end_group;
    int pad[39];
} Bvh8Instance;

/* 32 bytes. A hit is accepted for tmin < t < tmax. */
typedef struct {
    float org[3];
    float tmin;
    float dir[3];
    float tmax;
} Ray;

/* 32 bytes. prim is the scene's triangle id (-1: miss); the point is
 * (1-u-v)*v0 + u*v1 + v*v2; ng = (v1-v0) x (v2-v0), normalised, so it
 * follows the triangle's winding, not the ray. */
typedef struct {
    float t;
    float u;
    float v;
    int prim;
    float ng[3];
    int pad;
} Hit;

#endif
