"""Small vector helpers over the last axis, shared by the field physics and mechanisms:
dot and cross products, unit vectors, a perpendicular and an orthonormal frame."""

from __future__ import annotations

import numpy as np

from clradcom.errors import ArgumentError

__all__ = ["checked_unit", "cross", "dot", "orthonormal_frame", "perpendicular", "unit"]


def dot(a, b):
    return np.sum(a * b, axis=-1)


def cross(a, b):
    return np.cross(a, b, axis=-1)


def unit(v):
    """v / |v| along the last axis (NaN for zero vectors)."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def checked_unit(v, what: str):
    """v / |v| of 3-vectors, refusing zero-length or non-finite ones (``what`` names
    them)."""
    v = np.asarray(v, dtype=np.float64)
    if v.shape[-1:] != (3,):
        raise ArgumentError(f"{what}: last axis must have length 3, got shape {v.shape}")
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if not np.all(np.isfinite(n)) or np.any(n == 0):
        raise ArgumentError(f"{what}: zero-length or non-finite vector")
    return v / n


def perpendicular(n):
    """A unit vector perpendicular to each unit n (cross with the world axis least aligned
    with n): deterministic, well conditioned."""
    axis = np.zeros_like(n)
    idx = np.argmin(np.abs(n), axis=-1)
    np.put_along_axis(axis, idx[..., None], 1.0, axis=-1)
    p = cross(n, axis)
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


def orthonormal_frame(w):
    """Two unit vectors (e1, e2) completing unit w to a right-handed frame (e1, e2, w)."""
    e1 = perpendicular(w)
    return e1, cross(w, e1)
