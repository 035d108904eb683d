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


def detection_truth(scene, radar: str, targets, wavelength_m: float | None = None) -> list[dict]:
    """Expected radar detections of moving objects, from a loaded scene (at t = 0).

    For each target object (by name), with p the radar's world position, v_r its velocity,
    c the centre of the target's axis-aligned world bounding box, v_t its velocity and
    u = (c - p) / |c - p|:

    * ``range_centre_m`` = |c - p|  (the paper's set R, Table III)
    * ``range_nearest_m`` = distance from p to the closest point of the target's triangles
      (where the first echo starts; the paper's "reflective centre" lies in between)
    * ``v_rel_m_s`` = -(v_t - v_r) . u  : radial closing speed, positive when approaching
      (the paper's sign: car B 26.2 m/s); ``range_rate_m_s`` = -v_rel
    * ``v_rel_along_m_s`` = -(v_t - v_r) . b with b the radar boresight: the paper's set
      v_rel (12.9 + 13.3 = 26.2 m/s for car B), no cosine of the lateral offset
    * ``doppler_hz`` = 2 v_rel / lambda  (monostatic; same sign as snapshot ``doppler_hz``)
    * ``azimuth_deg`` of c in the radar frame (phi from boresight towards local +y)
    """
    r = scene.radars[scene.radar_index(radar)]
    p = np.asarray(r.position, dtype=np.float64)
    v_r = np.asarray(r.velocity, dtype=np.float64)
    lam = float(scene.wavelength_m if wavelength_m is None else wavelength_m)
    out = []
    for name in targets:
        obj = scene.objects[scene.object_index(name)]
        tri = scene.triangles[obj.tri_start:obj.tri_stop]
        pts = tri.reshape(-1, 3)
        c = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
        d = c - p
        rng_c = float(np.linalg.norm(d))
        u = d / rng_c
        dv = np.asarray(obj.velocity, dtype=np.float64) - v_r
        dist = point_triangle_distance(p, tri).min()
        local = r.orientation.T @ d
        v_rel = float(-dv @ u)
        out.append({
            "name": name,
            "centre_m": c.tolist(),
            "range_centre_m": rng_c,
            "range_nearest_m": float(dist),
            "v_rel_m_s": v_rel,
            "range_rate_m_s": -v_rel,
            "v_rel_along_m_s": float(-dv @ r.orientation[:, 0]),
            "doppler_hz": 2.0 * v_rel / lam,
            "azimuth_deg": float(np.degrees(np.arctan2(local[1], local[0]))),
        })
    return out


def point_triangle_distance(point, triangles) -> np.ndarray:
    """Euclidean distance from one point (3,) to each triangle (T, 3, 3); numpy, exact.

    Closest point by Voronoi regions of the triangle (Ericson, Real-Time Collision
    Detection, 5.1.5), vectorised over triangles.
    """
    p = np.asarray(point, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        q = a + ab * (vb * denom)[:, None] + ac * (vc * denom)[:, None]  # interior
        # edges
        v_ab = d1 / (d1 - d3)
        q = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[:, None], a + ab * v_ab[:, None], q)
        w_ac = d2 / (d2 - d6)
        q = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[:, None], a + ac * w_ac[:, None], q)
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        q = np.where(((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0))[:, None],
                     b + (c - b) * w_bc[:, None], q)
    # vertices
    q = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, q)
    q = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, q)
    q = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, q)
    return np.linalg.norm(p - q, axis=1)


def ray_hit_distances(origin, direction, triangles) -> np.ndarray:
    """Distances t > 0 along one ray to every triangle it crosses (float64, Moller-Trumbore).

    A plain numpy check for scene generation and tests, where trimesh's own ray
    queries would need optional packages (rtree or embreex).
    """
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.float64)
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = o - tri[:, 0]
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ d) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return np.sort(t[hit])


def inside_closed_mesh(point, triangles) -> bool:
    """Parity test: a point is inside a closed mesh when a ray from it crosses it oddly often.

    The ray direction is irrational-looking so it does not graze edges of
    axis-aligned or symmetric meshes.
    """
    d = np.array([0.5773502691896258, 0.5772502691896258, 0.5774502691896258])
    return len(ray_hit_distances(point, d, triangles)) % 2 == 1
