"""Specular paths: candidate search on the device, exact geometry on the host.

Stages (each plain arrays in and out):

1. :func:`launch_directions` - a Fibonacci lattice over the transmit
   pattern's support (directions where its gain is non-zero).
2. :func:`reflection_sequences` - the device
   (:meth:`clradcom.device.raycast.RayCaster.specular_sequences`) follows every
   ray through up to ``max_order`` specular bounces and returns the faces it
   reflects off, in order.
3. :func:`unique_candidates` - every prefix of every sequence is a
   candidate for a path to any receiver (the approach of Sionna RT's
   shooting-and-bouncing candidate stage); duplicates go.
4. :func:`image_points` - the image method in float64 gives the exact
   reflection points of a candidate for one tx/rx pair and rejects those
   whose line to an image misses the plane between its ends (wrong side).
5. :func:`clradcom.device.visibility.confirm_paths` - one closest-hit query
   per segment: the segment toward a reflection point must first meet exactly
   that face there (so the point lies inside the face and nothing blocks it),
   and the last segment must reach the receiver unobstructed.

The ray density only decides which candidates are proposed; every kept path
is exact, and the set stops growing once the lattice is dense enough.
"""

from __future__ import annotations

import warnings

import numpy as np

from clradcom.device.raycast import RayCaster
from clradcom.errors import SurfaceContactWarning

#: An antenna this close to a face's plane, relative to 1 + its largest coordinate
#: (float64 rounding, as visibility.INSIDE_TOL_REL), is on it.
CONTACT_TOL_REL = 1e-9


def fibonacci_cap(n: int, half_angle: float = np.pi) -> np.ndarray:
    """n nearly uniform unit vectors (golden-angle spiral) within half_angle of +x.

    half_angle = pi covers the whole sphere. Uniform steps in x = cos(angle
    from +x) give equal areas, so the lattice density is the same everywhere.
    """
    if n < 1:
        raise ValueError(f"need at least one direction, got n={n}")
    k = np.arange(n, dtype=np.float64)
    x = 1.0 - (1.0 - np.cos(half_angle)) * (k + 0.5) / n
    r = np.sqrt(np.maximum(1.0 - x * x, 0.0))
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([x, r * np.cos(phi), r * np.sin(phi)], axis=1)


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors over the whole sphere, float64 (n, 3)."""
    return fibonacci_cap(n, np.pi)


def launch_directions(n_rays: int, gain_fn=None, orientation=None) -> np.ndarray:
    """About n_rays world directions covering where the pattern radiates.

    gain_fn maps local unit directions (K,3) to gain; orientation (3,3) has
    the antenna's local axes as columns. The lattice is laid over the
    smallest cap around boresight (+x) that holds the pattern's support, at
    the density that puts about n_rays inside the support, so a narrow beam
    costs no more than a wide one.
    """
    if gain_fn is None:
        return fibonacci_sphere(n_rays)
    probe = fibonacci_sphere(1 << 16)
    inside = np.asarray(gain_fn(probe)) > 0
    if not inside.any():
        raise ValueError("the antenna pattern has zero gain everywhere (or in a region "
                         "narrower than 0.01 sr)")
    spacing = np.sqrt(4.0 * np.pi / len(probe))
    half_angle = min(np.pi, float(np.arccos(probe[inside, 0].min())) + 2.0 * spacing)
    in_cap = probe[:, 0] >= np.cos(half_angle)
    share = float(inside[in_cap].mean())
    local = fibonacci_cap(int(np.ceil(n_rays / share)), half_angle)
    local = local[np.asarray(gain_fn(local)) > 0]
    if orientation is None:
        return local
    return local @ np.asarray(orientation, dtype=np.float64).T


def reflection_sequences(caster: RayCaster, tri_face, origin, directions, max_order: int,
                         batch: int = 1 << 20) -> np.ndarray:
    """(R, max_order) int32 face ids of each ray's specular bounces, -1 after it escapes."""
    return caster.specular_sequences(origin, directions, tri_face, max_order, batch)


def unique_candidates(face_seq: np.ndarray) -> dict[int, np.ndarray]:
    """Unique face sequences of each length 1..max_order from all prefixes.

    Sequences that reflect off one plane twice in a row are cut there: a
    planar face cannot do that, so the rest of such a ray is a float32
    artefact of re-hitting a neighbouring triangle of the face it left.
    Rays repeat each other massively, so whole rows are de-duplicated first
    (one sort) and prefixes are taken from the few unique rows.
    """
    seq = np.ascontiguousarray(face_seq, dtype=np.int32)
    k_max = seq.shape[1]
    if k_max > 1:
        repeat = np.zeros(seq.shape, dtype=bool)
        repeat[:, 1:] = (seq[:, 1:] == seq[:, :-1]) & (seq[:, 1:] >= 0)
        cut = np.cumsum(repeat, axis=1) > 0
        seq = np.where(cut, -1, seq)
    if len(seq):
        rows = seq.view(np.dtype((np.void, seq.dtype.itemsize * k_max))).ravel()
        seq = seq[np.unique(rows, return_index=True)[1]]
    out: dict[int, np.ndarray] = {}
    for k in range(1, k_max + 1):
        pref = seq[seq[:, k - 1] >= 0, :k]
        out[k] = np.unique(pref, axis=0) if len(pref) else np.zeros((0, k), np.int32)
    return out


def mirror(points, normal, offset):
    """Reflect points (C,3) across planes n.x = d (n unit), all float64."""
    dist = np.einsum("ij,ij->i", points, normal) - offset
    return points - 2.0 * dist[:, None] * normal


def image_points(tx, rx, normals, offsets, seqs: np.ndarray):
    """Exact reflection points for candidate face sequences, by the image method.

    tx, rx: (3,) positions; normals (F,3) unit and offsets (F,) of the
    faces' planes; seqs (C,k) face ids. Returns points (C, k+2, 3) - tx, the
    k reflection points, rx - and a mask of candidates whose every point lies
    strictly between its neighbours' image line ends (so each reflection
    happens on the side both segments are on).
    """
    seqs = np.asarray(seqs)
    C, k = seqs.shape
    tx = np.asarray(tx, dtype=np.float64)
    rx = np.asarray(rx, dtype=np.float64)
    points = np.empty((C, k + 2, 3))
    points[:, 0] = tx
    points[:, -1] = rx
    ok = np.ones(C, dtype=bool)
    if C == 0:
        return points, ok
    images = np.empty((C, k, 3))
    current = np.broadcast_to(tx, (C, 3))
    for i in range(k):
        n = normals[seqs[:, i]]
        d = offsets[seqs[:, i]]
        current = mirror(current, n, d)
        images[:, i] = current
    target = np.broadcast_to(rx, (C, 3)).copy()
    for i in range(k - 1, -1, -1):
        n = normals[seqs[:, i]]
        d = offsets[seqs[:, i]]
        line = images[:, i] - target
        denom = np.einsum("ij,ij->i", line, n)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (d - np.einsum("ij,ij->i", target, n)) / denom
        good = np.isfinite(s) & (s > 1e-12) & (s < 1.0 - 1e-12)
        ends = ([("receiver", rx)] if i == k - 1 else []) + (
            [("transmitter", tx)] if i == 0 else [])
        for what, point in ends if not good.all() else ():
            _warn_surface_contact(point, what, n, d, seqs[:, i], ok & ~good)
        ok &= good
        s = np.where(good, s, 0.5)
        target = target + s[:, None] * line
        points[:, i + 1] = target
    return points, ok


def _warn_surface_contact(point, what, normals, offsets, faces, dropped):
    """Warn when candidates were dropped because an antenna lies on their face's plane:
    the reflection point then coincides with the antenna, and the path with the line
    of sight (geometrical optics has no wave guided along the surface)."""
    dist = np.abs(normals @ point - offsets)
    on = dropped & (dist <= CONTACT_TOL_REL * (1.0 + np.abs(point).max()))
    if on.any():
        warnings.warn(f"the {what} at {point.tolist()} lies on the plane of face(s) "
                      f"{np.unique(faces[on]).tolist()}: the reflection off it coincides with "
                      "the line of sight and the image method cannot place it; the tracer "
                      "adds it as the limit of the merging rays where the line of sight "
                      "exists (tracer.surface_contact_paths)", SurfaceContactWarning,
                      stacklevel=5)
