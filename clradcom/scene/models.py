"""Procedural meshes for traffic scenes: a rounded car and a street of triangles.

The paper's street needs a PEC car model of about 700 triangles (3.8 m x
1.85 m x 1.7 m) with a rounded body, a cabin and wheels; nothing in the
package registry ships one, so it is generated: superellipsoid body and
cabin (rounded boxes whose roundness is one exponent) and cylinder wheels.
The street builder is the synthetic scene the benchmarks use (road, facades
with recessed windows, cars, trees) and is deterministic for a seed.
"""

from __future__ import annotations

import numpy as np
import trimesh


def superellipsoid(extents, n_theta: int, n_phi: int, exponent: float) -> trimesh.Trimesh:
    """Closed rounded box: |x/a|^(2/e) + |y/b|^(2/e) + |z/c|^(2/e) = 1 on a lat-long grid.

    exponent 1 is an ellipsoid; toward 0 it becomes a box with rounded edges.
    """
    c = 0.5 * float(extents[2])
    body = _superellipsoid_rings(extents, n_theta, n_phi, exponent)
    # poles collapse to single vertices so the mesh is closed and has no slivers
    verts = np.vstack([body, [[0.0, 0.0, -c]], [[0.0, 0.0, c]]])
    faces = _lat_long_faces(n_theta, n_phi)
    mesh = trimesh.Trimesh(verts, faces, process=True)
    mesh.fix_normals()
    return mesh


def car_mesh(length=3.8, width=1.85, height=1.7, wheel_sections=12) -> trimesh.Trimesh:
    """A rounded car about 700 triangles, centred on x, y; wheels touch z = 0; nose at +x."""
    wheel_r = 0.32
    body_h = 0.75
    body = superellipsoid((length, width, body_h), 20, 10, 0.25)
    body.apply_translation([0.0, 0.0, wheel_r * 0.55 + 0.5 * body_h])
    cabin_h = height - (wheel_r * 0.55 + body_h) + 0.08
    cabin = superellipsoid((0.55 * length, 0.9 * width, cabin_h), 14, 8, 0.35)
    cabin.apply_translation([-0.1 * length, 0.0, height - 0.5 * cabin_h])
    parts = [body, cabin]
    for sx in (-0.32 * length, 0.3 * length):
        for sy in (-0.5 * width + 0.12, 0.5 * width - 0.12):
            wheel = trimesh.creation.cylinder(radius=wheel_r, height=0.22,
                                              sections=wheel_sections)
            wheel.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
            wheel.apply_translation([sx, sy, wheel_r])
            parts.append(wheel)
    return trimesh.util.concatenate(parts)


def _grid_plane(x0, x1, y0, y1, z, nx, ny) -> np.ndarray:
    xs = np.linspace(x0, x1, nx + 1)
    ys = np.linspace(y0, y1, ny + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    p = np.stack([gx, gy, np.full_like(gx, z)], axis=-1)
    q = np.stack([p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]], axis=2).reshape(-1, 4, 3)
    return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


def _facade(x0, length, y, depth, height, side, rng) -> list[np.ndarray]:
    """A building block: a box with recessed windows on its street face."""
    tris = []
    box = trimesh.creation.box(extents=[length, depth, height])
    box.apply_translation([x0 + 0.5 * length, y + side * 0.5 * depth, 0.5 * height])
    tris.append(box.vertices[box.faces])
    n_cols = max(int(length / 2.5), 1)
    n_rows = max(int(height / 3.0), 1)
    for i in range(n_cols):
        for j in range(n_rows):
            w = trimesh.creation.box(extents=[1.2, 0.15, 1.4])
            cx = x0 + (i + 0.5) * length / n_cols
            cz = (j + 0.5) * height / n_rows
            w.apply_translation([cx, y - side * 0.05 + side * rng.uniform(0.0, 0.02), cz])
            tris.append(w.vertices[w.faces])
    return tris


def street_triangles(seed: int = 0, street_length: float = 160.0):
    """A synthetic street (road, facades, cars, trees) as (T,3,3) triangles and object ids.

    Lanes run along +x; the road spans y in [-7, 7]; buildings stand beyond.
    """
    rng = np.random.default_rng(seed)
    parts: list[np.ndarray] = []
    ids: list[int] = []

    def add(tris, obj):
        parts.append(np.asarray(tris, dtype=np.float64).reshape(-1, 3, 3))
        ids.append(obj)

    half = 0.5 * street_length
    add(_grid_plane(-half, half, -7.0, 7.0, 0.0, 80, 14), 0)
    obj = 1
    for side, y in ((1, 7.5), (-1, -7.5)):
        x = -half
        while x < half - 4.0:
            length = float(rng.uniform(8.0, 16.0))
            height = float(rng.uniform(8.0, 20.0))
            for t in _facade(x, min(length, half - x), y, 10.0, height, side, rng):
                add(t, obj)
            obj += 1
            x += length + float(rng.uniform(0.5, 3.0))
    car = car_mesh()
    for cx, cy in ((0.0, -1.75), (16.4, -1.75), (26.0, 1.75), (34.6, 1.75),
                   (-20.0, 1.75), (55.0, -1.75)):
        add(car.vertices[car.faces] + [cx, cy, 0.0], obj)
        obj += 1
    tree = trimesh.creation.icosphere(subdivisions=2, radius=1.6)
    trunk = trimesh.creation.cylinder(radius=0.15, height=2.5, sections=8)
    for side in (1, -1):
        for x in np.arange(-half + 6.0, half - 6.0, 12.0):
            crown = tree.vertices[tree.faces] + [x, side * 6.3, 4.0]
            stem = trunk.vertices[trunk.faces] + [x, side * 6.3, 1.25]
            add(np.concatenate([crown, stem]), obj)
            obj += 1
    tris = np.concatenate(parts)
    object_id = np.concatenate(
        [np.full(len(p), i, dtype=np.int32) for p, i in zip(parts, ids, strict=True)]
    )
    return tris, object_id


def superellipsoid_face_centred(extents, n_theta: int, n_phi: int,
                                exponent: float) -> trimesh.Trimesh:
    """`superellipsoid` with its lat-long grid shifted half a cell, so that the +x, -x, +y
    and -y axis points (n_theta a multiple of 4) and the equator (n_phi odd) fall on
    face centres, not on vertices: the flat ends carry facets whose normals are exactly
    +-x (a specular mirror straight back), which the vertex-on-axis grid lacks."""
    if n_theta % 4 or n_phi % 2 == 0:
        raise ValueError("n_theta must be a multiple of 4 and n_phi odd")
    a, b, c = (0.5 * float(e) for e in extents)
    body = _superellipsoid_rings(extents, n_theta, n_phi, exponent, np.pi / n_theta)
    # the axis points are now face centres: stretch so the extents are met exactly
    body[:, 0] *= a / np.abs(body[:, 0]).max()
    body[:, 1] *= b / np.abs(body[:, 1]).max()
    verts = np.vstack([body, [[0.0, 0.0, -c]], [[0.0, 0.0, c]]])
    faces = _lat_long_faces(n_theta, n_phi)
    out = trimesh.Trimesh(verts, faces, process=True)
    out.fix_normals()
    return out


def _superellipsoid_rings(extents, n_theta, n_phi, exponent, phi_shift=0.0) -> np.ndarray:
    """Vertices of the lat-long rings between the poles, ring by ring."""
    a, b, c = (0.5 * float(e) for e in extents)
    theta = np.linspace(-0.5 * np.pi, 0.5 * np.pi, n_phi + 1)  # latitude
    phi = np.linspace(-np.pi, np.pi, n_theta + 1)[:-1] + phi_shift  # longitude, wraps

    def spow(x, p):
        return np.sign(x) * np.abs(x) ** p

    th, ph = np.meshgrid(theta, phi, indexing="ij")
    x = a * spow(np.cos(th), exponent) * spow(np.cos(ph), exponent)
    y = b * spow(np.cos(th), exponent) * spow(np.sin(ph), exponent)
    z = c * spow(np.sin(th), exponent)
    return np.stack([x, y, z], axis=-1)[1:-1].reshape(-1, 3)


def _lat_long_faces(n_theta: int, n_phi: int) -> np.ndarray:
    rings = n_phi - 1
    south, north = rings * n_theta, rings * n_theta + 1
    faces = []
    for i in range(rings - 1):
        for j in range(n_theta):
            p = i * n_theta + j
            q = i * n_theta + (j + 1) % n_theta
            faces.append([p, q, q + n_theta])
            faces.append([p, q + n_theta, p + n_theta])
    top = (rings - 1) * n_theta
    for j in range(n_theta):
        faces.append([south, (j + 1) % n_theta, j])
        faces.append([north, top + j, top + (j + 1) % n_theta])
    return np.array(faces)


def rounded_car(length=3.8, width=1.85, height=1.7, *, body_exponent=0.25,
                cabin_exponent=0.35, body_segments=(20, 10), cabin_segments=(14, 8),
                wheel_sections=12, face_centred: bool = False) -> trimesh.Trimesh:
    """`car_mesh` with its roundness and tessellation as parameters (street-scene variants).

    With the defaults it returns exactly the geometry of ``car_mesh()``: superellipsoid
    body (``body_exponent``: 1 ellipsoid, toward 0 a box) and cabin, four cylinder wheels;
    centred on x, y; wheels touch z = 0; nose at +x. ``*_segments`` are (around, along the
    height) grid counts of the superellipsoids.
    """
    wheel_r = 0.32
    body_h = 0.75
    if face_centred:
        nt = -(-int(body_segments[0]) // 4) * 4
        nph = int(body_segments[1]) | 1
        body = superellipsoid_face_centred((length, width, body_h), nt, nph,
                                           float(body_exponent))
    else:
        body = superellipsoid((length, width, body_h), int(body_segments[0]),
                              int(body_segments[1]), float(body_exponent))
    body.apply_translation([0.0, 0.0, wheel_r * 0.55 + 0.5 * body_h])
    cabin_h = height - (wheel_r * 0.55 + body_h) + 0.08
    cabin = superellipsoid((0.55 * length, 0.9 * width, cabin_h), int(cabin_segments[0]),
                           int(cabin_segments[1]), float(cabin_exponent))
    cabin.apply_translation([-0.1 * length, 0.0, height - 0.5 * cabin_h])
    parts = [body, cabin]
    for sx in (-0.32 * length, 0.3 * length):
        for sy in (-0.5 * width + 0.12, 0.5 * width - 0.12):
            wheel = trimesh.creation.cylinder(radius=wheel_r, height=0.22,
                                              sections=int(wheel_sections))
            wheel.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
            wheel.apply_translation([sx, sy, wheel_r])
            parts.append(wheel)
    return trimesh.util.concatenate(parts)


#: W-beam cross-section (AASHTO M180 class A, simplified): (depth toward the road, height)
#: in m, bottom flange to top flange; 83 mm deep, 312 mm tall
W_BEAM_PROFILE = np.array([
    [0.000, 0.000], [0.000, 0.025], [0.083, 0.075], [0.083, 0.105], [0.020, 0.156],
    [0.083, 0.207], [0.083, 0.237], [0.000, 0.287], [0.000, 0.312]])


def guardrail_meshes(length: float = 60.0, *, cell: float = 0.5, post_spacing: float = 2.0,
                     beam_bottom: float = 0.45, post_size=(0.15, 0.10, 0.80),
                     post_gap: float = 0.15, post_sink: float = 0.05
                     ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """A metal road guard rail along +x from x = 0 to ``length``, its beam facing -y (the
    road) with its back at y = 0: ``{"w_beam": (verts, faces), "posts": (verts, faces)}``.

    The beam is one open sheet of the :data:`W_BEAM_PROFILE` swept along x in cells of
    ``cell`` m (2 triangles per profile strip and cell, normals toward -y), its bottom
    flange ``beam_bottom`` m above z = 0. The posts are closed boxes of ``post_size``
    (x, y, z) m every ``post_spacing`` m from x = 0 to ``length``, sunk ``post_sink`` m
    below z = 0 (so that no post face lies in the road's plane), their front ``post_gap``
    m behind the beam's back (where a blockout would sit).
    """
    n_cells = max(1, int(round(length / cell)))
    xs = np.linspace(0.0, length, n_cells + 1)
    prof = W_BEAM_PROFILE
    # vertex (i, j): x = xs[i], profile point j; the road is at -y
    verts = np.stack(np.broadcast_arrays(
        xs[:, None], -prof[None, :, 0], beam_bottom + prof[None, :, 1]), axis=-1)
    idx = np.arange(verts.shape[0] * verts.shape[1]).reshape(verts.shape[:2])
    p, q = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    r, s = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    # (x step) x (z step) points to -y for a strip whose depth does not change
    beam_faces = np.concatenate([np.stack([p, q, r], 1), np.stack([p, r, s], 1)])
    beam = (verts.reshape(-1, 3), beam_faces)

    box = trimesh.creation.box(extents=post_size)
    bv, bf = np.asarray(box.vertices), np.asarray(box.faces)
    n_posts = int(np.floor(length / post_spacing + 1e-9)) + 1
    centres = [[i * post_spacing, post_gap + 0.5 * post_size[1],
                0.5 * post_size[2] - post_sink]
               for i in range(n_posts)]
    posts = (np.concatenate([bv + c for c in centres]),
             np.concatenate([bf + k * len(bv) for k in range(n_posts)]))
    return {"w_beam": beam, "posts": posts}
