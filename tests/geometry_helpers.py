"""Hand-built test geometry shared by several test files."""

import numpy as np


def plate_tris(n, size, x, centre=(0.0, 0.0), tilt_deg=0.0):
    """n x n squares (2 n^2 triangles) of a square plate of side ``size`` facing -x,
    centred on (x, centre), rotated by tilt_deg about the z axis (world coordinates).

    Returns (vertices, faces) as lists for a ``shape = "triangles"`` scene object.
    """
    s = np.linspace(-size / 2, size / 2, n + 1)
    verts = np.array([[0.0, y, z] for y in s for z in s])
    th = np.radians(tilt_deg)
    rot = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    verts = verts @ rot.T + [x, centre[0], centre[1]]
    faces = []
    for i in range(n):
        for j in range(n):
            a, b = i * (n + 1) + j, i * (n + 1) + j + 1
            c, d = a + n + 1, b + n + 1
            # (y, z) order (-,-), (-,+), (+,+) -> normal -x
            faces += [[a, b, d], [a, d, c]]
    return verts.tolist(), faces
