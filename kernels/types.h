/* Structs shared between host and kernels. The host mirrors each one with a
 * numpy dtype in clradcom/raycast.py (and clradcom/bvh.py for BVHNode); a test
 * checks the sizes agree. No float3 in shared structs: its 16-byte alignment
 * differs between host and device, so every member is a scalar or array and
 * padding is explicit. */
#ifndef CLRADCOM_TYPES_H
#define CLRADCOM_TYPES_H

/* 32 bytes. Inner node: count == 0, children at left_first and left_first+1.
 * Leaf: count > 0 triangles at tri_index[left_first .. left_first+count). */
typedef struct {
    float bmin[3];
    int left_first;
    float bmax[3];
    int count;
} BVHNode;

/* 256 bytes: the 8-wide traversal layout (clradcom/raycast.py: bvh8_nodes),
 * collapsed on the host from the binary BVHNode tree. Bounds are stored per
 * axis for the eight child slots (structure of arrays, 32-byte rows) so one
 * float8 op tests all eight. child[i] > 0: an inner child, its record index;
 * child[i] < 0: a leaf, -(first_group * 32 + groups) - 1 over the Tri4 groups
 * (kernels/intersect.h); child[i] == 0: an empty slot (record 0 is the root,
 * never a child), whose bounds are +inf / -inf so that no ray hits it. */
typedef struct {
    float minx[8];
    float miny[8];
    float minz[8];
    float maxx[8];
    float maxy[8];
    float maxz[8];
    int child[8];
    int pad[8];
} Bvh8Node;

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
