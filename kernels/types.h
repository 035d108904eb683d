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

/* 128 bytes: the 4-wide traversal layout (clradcom/raycast.py: bvh4_nodes),
 * collapsed on the host from the binary BVHNode tree. Bounds are stored per
 * axis for the four child slots (structure of arrays) so one float4 op tests
 * all four. child[i] > 0: an inner child, its record index; child[i] < 0: a
 * leaf, -(first_slot * 32 + count) - 1; child[i] == 0: an empty slot (record 0
 * is the root, never a child), whose bounds are +inf / -inf and which the
 * kernel masks out by its code anyway. */
typedef struct {
    float minx[4];
    float miny[4];
    float minz[4];
    float maxx[4];
    float maxy[4];
    float maxz[4];
    int child[4];
    int pad[4];
} Bvh4Node;

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
