"""Mesh files written by the package: binary PLY bytes, the one writer the street, guard
rail and micro-Doppler generators and :func:`clradcom.scene.edit.save_scene` share (numpy
only, so writing a scene loads no mesh library)."""

from __future__ import annotations

import numpy as np

__all__ = ["ply_bytes"]


def ply_bytes(verts, faces, *, double: bool = False,
              comment: str = "clradcom tools/make_street.py") -> bytes:
    """Binary little-endian PLY, float32 (``double``: float64) vertices, uchar-count int32
    faces, fixed header (written here, not by a library exporter, so the bytes do not
    depend on a trimesh version)."""
    v = np.ascontiguousarray(verts, dtype="<f8" if double else "<f4")
    kind = "double" if double else "float"
    f = np.asarray(faces, dtype=np.int64)
    rec = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"] = 3
    rec["i"] = f
    header = (
        f"ply\nformat binary_little_endian 1.0\ncomment {comment}\n"
        f"element vertex {len(v)}\nproperty {kind} x\nproperty {kind} y\nproperty {kind} z\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    return header.encode("ascii") + v.tobytes() + rec.tobytes()
