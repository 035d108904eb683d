"""Plain numpy geometry of triangle soups: triangles, planar faces, wedges, the BVH and
the node layouts the kernels read. No OpenCL, no physics."""
