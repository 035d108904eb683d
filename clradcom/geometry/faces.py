"""Planar faces: coplanar triangles of one object and material are one reflector.

A mesh tessellates a wall or a road into many triangles; a specular
reflection off that plane is one path, whichever triangle the reflection
point falls in. The tracer therefore works with *faces*: every triangle gets
the id of the plane it lies in (per object and material, since objects move
independently and materials reflect differently). Two triangles share a face
when their unit normals agree up to sign within ``angle_tol`` and their plane
offsets within ``offset_tol``; faces are two-sided (which side is lit is
decided per path by the image method).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from clradcom.errors import ArgumentError
from clradcom.geometry.triangles import triangle_normals_and_double_areas


@dataclass(frozen=True)
class Faces:
    """Per-triangle face ids and per-face planes (unit normal n, offset d: n.x = d)."""

    tri_face: np.ndarray  # (T,) int32
    normal: np.ndarray  # (F, 3) float64, unit, sign canonical
    offset: np.ndarray  # (F,) float64
    object_id: np.ndarray  # (F,) int32
    material_id: np.ndarray  # (F,) int32

    @property
    def n_faces(self) -> int:
        return len(self.offset)


def triangle_planes(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normals with a canonical sign, plane offsets and twice the areas, in float64.

    The sign is fixed so the largest-magnitude component is positive: the
    two sides of a plane are one reflector, so normals that differ only in
    sign must compare equal.
    """
    tri = np.asarray(triangles, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        n, area2 = triangle_normals_and_double_areas(tri)
    big = np.argmax(np.abs(n), axis=1)
    sign = np.sign(n[np.arange(len(n)), big])
    sign[sign == 0] = 1.0
    n *= sign[:, None]
    # the offset from the centroid: rounding of any single vertex averages out
    d = np.einsum("ij,ij->i", n, tri.mean(axis=1))
    return n, d, area2


def area_weighted_planes(triangles, normals, area2, face_of, n_faces: int):
    """(normal (F, 3), offset (F,)) of ``n_faces`` faces: each the area-weighted mean of
    its triangles' unit ``normals`` (``area2``: twice their areas) and the offset of that
    normal through their area-weighted centroid. ``face_of`` (T,): each triangle's face,
    0 .. F-1. The same sums in the same order give the same plane bit for bit, which a
    moved object's faces rely on (clradcom.mechanisms.common.GeometryCache)."""
    normal = np.zeros((n_faces, 3))
    np.add.at(normal, face_of, normals * area2[:, None])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    centroid_sum = np.zeros((n_faces, 3))
    np.add.at(centroid_sum, face_of, triangles.mean(axis=1) * area2[:, None])
    wsum = np.bincount(face_of, weights=area2, minlength=n_faces)
    return normal, np.einsum("ij,ij->i", normal, centroid_sum / wsum[:, None])


def merge_coplanar(triangles, tri_object, tri_material, angle_tol=1e-5, offset_tol=1e-5):
    """Group triangles into planar faces per (object, material, plane).

    angle_tol is in radians between normals; offset_tol in metres between
    plane offsets, widened by 1e-7 of the scene's extent (max |coordinate|,
    about twice float32 resolution there) for meshes stored in float32. The
    tolerance is the same for every plane of a scene: it must not grow with
    |d| as such, or the two sides of a thin sheet far from the origin (1 mm at
    100 m, 5 mm at 1 km with a tolerance of 1e-5 |d|) would be merged into one
    plane between them. Grouping sorts on quantised keys and then joins
    neighbours in that order that agree within the tolerances, so a plane
    whose key straddles a quantisation step is still one face.
    """
    tri = np.asarray(triangles, dtype=np.float64)
    obj = np.asarray(tri_object, dtype=np.int64)
    mat = np.asarray(tri_material, dtype=np.int64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise ArgumentError(f"triangles must have shape (T, 3, 3), got {tri.shape}")
    if obj.shape != (len(tri),) or mat.shape != (len(tri),):
        raise ArgumentError("tri_object and tri_material need one entry per triangle")
    if len(tri) == 0:  # a free-space scene: no faces
        return Faces(tri_face=np.zeros(0, np.int32), normal=np.zeros((0, 3)),
                     offset=np.zeros(0), object_id=np.zeros(0, np.int32),
                     material_id=np.zeros(0, np.int32))
    n, d, area2 = triangle_planes(tri)
    if not np.all(area2 > 0):
        bad = int(np.flatnonzero(~(area2 > 0))[0])
        raise ArgumentError(f"triangle {bad} is degenerate (zero area): it has no plane")
    T = len(tri)
    d_tol = offset_tol * (1.0 + 1e-2 * float(np.abs(tri).max()))
    q = np.round(np.column_stack([n / angle_tol * 0.5, d / d_tol]))
    pairs_a, pairs_b = [], []
    for lead in range(4):
        # sort with each key component leading once so near-equal planes end up adjacent
        keys = [q[:, (lead + j) % 4] for j in range(4)][::-1] + [mat, obj]
        order = np.lexsort(keys)
        a, b = order[:-1], order[1:]
        same = (obj[a] == obj[b]) & (mat[a] == mat[b])
        same &= np.einsum("ij,ij->i", n[a], n[b]) > np.cos(angle_tol)
        same &= np.abs(d[a] - d[b]) <= d_tol
        pairs_a.append(a[same])
        pairs_b.append(b[same])
    ia, ib = np.concatenate(pairs_a), np.concatenate(pairs_b)
    graph = coo_matrix((np.ones(len(ia), dtype=np.int8), (ia, ib)), shape=(T, T))
    _, labels = connected_components(graph, directed=False)
    # number faces by their first triangle so ids are stable and ordered
    first = np.full(labels.max() + 1, T, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(T))
    rank = np.argsort(np.argsort(first))
    tri_face = rank[labels]
    uniq = np.sort(first)
    tri_face = tri_face.astype(np.int32)
    F = len(uniq)
    normal, offset = area_weighted_planes(tri, n, area2, tri_face, F)
    return Faces(
        tri_face=tri_face,
        normal=normal,
        offset=offset,
        object_id=obj[uniq].astype(np.int32),
        material_id=mat[uniq].astype(np.int32),
    )
