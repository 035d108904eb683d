"""What a kernel test asserts in the session runtime's precision mode (issue #26).

With fp64 (``runtime.has_double``) a kernel test keeps its own assertion: bit for bit
where the kernel's algorithm fixes every operation (the image method, plane hits, tile
centres in double, as the host writes them). A device without fp64 -- or any device in
the forced mode, ``--fp64=off`` / ``CLRADCOM_FP64=0`` -- runs every kernel in
kernels/precise.h's double-float with float fields, and the tests hold it to that
build's own contract (docs/precision.md, "Without fp64: every kernel") with the
tolerances below: one place for the conformance tests and tests/test_no_fp64.py.

- Points and lengths: double-float carries ~1e-14 of a value (48 bits); a point or a
  length is the host's to POINT_TOL_REL (1 + |p|) m (1e-9 m at 1 km: 3e-7 of a
  wavelength at 77 GHz).
- Decisions (inside a face, blocked, on the lit side): the host's, except where the
  float64 quantity a decision tests lies within DECISION_TOL_REL (1 + |p|) of its
  threshold, where float64 itself decides by its own rounding
  (:func:`segment_margins`, :func:`face_margins`).
- Fields (powers, gains, polarimetric matrices) are float: FIELD_TOL_REL of the
  strongest (float's 6e-8 through a few dozen operations). A gain the host computes
  from the device's points is within -60 dB of its own, or, for a path whose gain is a
  cancellation's residue (a pattern null, a cross-polar projection), within
  CANCELLED_GAIN_DB of the link's strongest (:func:`gain_tolerance`).
- SBR tubes leave in float directions: each footprint lies within SBR_DIRECTION_TOL_REL
  of its unfolded length from the host's, and a block sum within its footprints' norms
  times the phase of that displacement plus float rounding (:func:`sbr_row_tolerance`)
  and within SBR_SUM_TOL_REL of the strongest block.
- Channels: NO_FP64_NMSE_DB, issue #26's bound for the mode.
- Scenes on a knife edge that the no-fp64 build decides by its own rounding are traced
  just off it without fp64 (:data:`NO_FP64_SCENE_EDITS`, :func:`scene_in_mode`).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from clradcom.device.visibility import INSIDE_TOL_REL, edge_distances
from clradcom.geometry.triangles import triangle_normals
from clradcom.scene import load_scene
from clradcom.scene.reader import scene_from_dict

#: a point or length against the host's float64: metres per metre of 1 + |p|
POINT_TOL_REL = 1e-12
#: a decision may differ from the host's where its float64 quantity (a distance from a
#: rim or a seam's tolerance, a crossing's parameter from the segment's ends; times the
#: crossing's |cos| for a segment) lies within this of its threshold, relative to 1 + |p|
DECISION_TOL_REL = 1e-13
#: ... and at most this share of a batch does so (tests/test_visibility_device.py aims a
#: seventh of its segments exactly at rims and vertices: 0.4 to 1.1 % differ there)
DECISIONS_AT_THRESHOLD_MAX = 0.02
#: float fields (tile powers, scattering gains and matrices, SBR footprint sums, their
#: representative's choice among equal norms): relative to the strongest (or to the norm
#: a choice compares)
FIELD_TOL_REL = 1e-5
#: Doppler shifts from float directions (SBR footprints) or float fields (scattering
#: tiles): 0.01 Hz turns a path's phase by 2e-4 rad over the paper's 2.8 ms frame
DOPPLER_TOL_HZ = 1e-2
#: an SBR tube's direction is float without fp64 (kernels/sbr.cl's cell_tube and each
#: mirroring): its footprints land within this of the unfolded length (relative) from
#: the host's float64 tube's (measured: 1.9e-6 on the street, grazing car facets)
SBR_DIRECTION_TOL_REL = 1e-5
#: ... and an SBR path's Doppler, whose last segment starts at that footprint, within
#: this (measured 0.033 Hz on the golden scene's car -> road -> wall bounce, 0.019 Hz on
#: the street, once the tube cells moved by half a pitch; 2 pi x 0.05 Hz x 2.8 ms = 9e-4
#: rad of phase over the paper's frame)
SBR_DOPPLER_TOL_HZ = 5e-2
#: ... so an SBR block sum (a path's: the sum of its blocks) is within this of the
#: strongest one's sum of footprint norms (-80 dB; measured 7e-6 for blocks, 1e-6 for
#: paths), and within :func:`sbr_row_tolerance` of its own
SBR_SUM_TOL_REL = 1e-4
#: a host-computed gain: within -60 dB of its own (docs/devices.md) ...
GAIN_TOL_DB = -60.0
#: ... or, where the path cancels to nothing, of the link's strongest (-120 dB: far below
#: any radar's dynamic range; a path cancelled to -300 dB moves by float64's 1e-14 of its
#: uncancelled terms when its points move by double-float's rounding)
CANCELLED_GAIN_DB = -120.0
#: a link's channel, without fp64 against fp64 or the host: issue #26's bound
NO_FP64_NMSE_DB = -50.0

#: (m) a radar's step off its scene's plane or axis of symmetry without fp64: on it, a
#: column of SBR tubes aims exactly at the crease, and which plate each hits is decided
#: by the rounding of its float launch direction, which the no-fp64 build computes in
#: float and the host in float64 (the dihedral: 1 % of the double bounce's gain on the
#: plane, -45 dB of channel; 1.3 mm off it, -144 dB)
OFF_SYMMETRY_M = (0.0, 0.0013, 0.0007)
#: (deg) moving_car's bumper radar pitched this far nose down without fp64: its ground
#: bounce leaves straight down, the pole of its 90 x 180 deg sector pattern, where the
#: azimuth (which decides inside or outside the sector) and the theta unit vector (the
#: field's sign) are those of the rounding of a horizontal component of 1e-15: the
#: double-float image point 3 float64 ulps west of the host's put the link's strongest
#: path outside the pattern (-0.04 dB channel NMSE). Pitched, the nadir lies 1.7e-4 rad
#: inside the sector.
NADIR_PITCH_DEG = 0.01

#: scene name -> (each radar's position offset m, its orientation change [roll, pitch,
#: yaw] deg): the knife edges above, left without fp64 (with fp64 the scenes stay as
#: they are and the device repeats the host bit for bit on them)
NO_FP64_SCENE_EDITS = {
    "plate": (OFF_SYMMETRY_M, (0.0, 0.0, 0.0)),
    "dihedral": (OFF_SYMMETRY_M, (0.0, 0.0, 0.0)),
    # the trihedral's axis points at the radar: the same tubes aimed at its three creases
    "corner": (OFF_SYMMETRY_M, (0.0, 0.0, 0.0)),
    "corner_mesh": (OFF_SYMMETRY_M, (0.0, 0.0, 0.0)),
    "moving_car": ((0.0, 0.0, 0.0), (0.0, NADIR_PITCH_DEG, 0.0)),
}


def scene_in_mode(path, runtime):
    """The scene of ``path``; without fp64 with :data:`NO_FP64_SCENE_EDITS`' edit of it,
    if any (every radar moved and turned)."""
    path = Path(path)
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    edit = NO_FP64_SCENE_EDITS.get(data["scene"]["name"])
    if runtime.has_double or edit is None:
        return load_scene(path)
    offset, turn = edit
    for radar in data["radars"]:
        radar["position"] = list(np.add(radar["position"], offset))
        radar["orientation_deg"] = list(np.add(radar.get("orientation_deg", (0.0, 0.0, 0.0)),
                                               turn))
    return scene_from_dict(data, file=path, base_dir=path.parent)


def off_symmetry(positions, runtime):
    """Radar positions (N, 3) of a hand-built scene, moved by OFF_SYMMETRY_M without fp64."""
    positions = np.asarray(positions, dtype=np.float64)
    return positions if runtime.has_double else positions + OFF_SYMMETRY_M


# ---------------------------------------------------------------------------
# points, fields, gains

def point_atol(want) -> float:
    """POINT_TOL_REL (1 + |p|) over the points ``want`` (NaN padding ignored)."""
    return POINT_TOL_REL * (1.0 + float(np.nanmax(np.abs(want), initial=0.0)))


def assert_points(runtime, got, want, err_msg=""):
    """Points or lengths from the device: the host's bit for bit with fp64; within
    :func:`point_atol` without (NaN where the host's are)."""
    got, want = np.asarray(got), np.asarray(want)
    if runtime.has_double:
        np.testing.assert_array_equal(got, want, err_msg=err_msg)
        return
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want), err_msg=err_msg)
    np.testing.assert_allclose(got, want, rtol=0, atol=point_atol(want), equal_nan=True,
                               err_msg=err_msg)


def gain_tolerance(gain, strongest=None) -> np.ndarray:
    """(P,) how far a host-computed gain may move where its points carry double-float's
    rounding: -60 dB of its own, at least CANCELLED_GAIN_DB of the link's strongest
    (default: the strongest of ``gain``)."""
    mag = np.abs(np.asarray(gain))
    top = float(mag.max(initial=0.0)) if strongest is None else float(np.abs(strongest))
    return np.maximum(10 ** (GAIN_TOL_DB / 20) * mag, 10 ** (CANCELLED_GAIN_DB / 20) * top)


def nmse_db(h, ref) -> float:
    """-inf where the two are equal bit for bit."""
    with np.errstate(divide="ignore"):
        return float(10 * np.log10(np.sum(np.abs(h - ref) ** 2) / np.sum(np.abs(ref) ** 2)))


# ---------------------------------------------------------------------------
# SBR block sums

def sbr_row_tolerance(weight, length, wavenumber) -> np.ndarray:
    """How far a sum of SBR footprints (its ``weight``: the sum of their norms; its
    representative's unfolded ``length``) may move without fp64: each footprint by the
    phase of its float direction's displacement, k SBR_DIRECTION_TOL_REL L, and float
    rounding, FIELD_TOL_REL, of its norm."""
    return np.asarray(weight) * (FIELD_TOL_REL
                                 + wavenumber * SBR_DIRECTION_TOL_REL * np.asarray(length))


# ---------------------------------------------------------------------------
# decisions at their thresholds (visibility, scene64.h)

def segment_margins(triangles, start, end, tmin, tmax) -> np.ndarray:
    """(S,) how close each segment's float64 decisions come to their thresholds: over
    every triangle whose plane it crosses in [tmin, tmax] (widened), the least of the
    crossing's edge distances from 0 and from the seam tolerance and of the crossing's
    distance along the segment from its ends, times |cos| of the crossing, relative to
    1 + |crossing|."""
    S = len(start)
    n = triangle_normals(triangles)
    g = end - start
    L = np.linalg.norm(g, axis=1)
    tmin, tmax = np.broadcast_to(tmin, (S,)), np.broadcast_to(tmax, (S,))
    out = np.full(S, np.inf)
    for k in range(len(triangles)):
        den = g @ n[k]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((triangles[k, 0] - start) @ n[k]) / den
            cos = np.abs(den) / L
            x = start + t[:, None] * g
            scale = 1.0 + np.abs(x).max(axis=1)
            d = edge_distances(x, np.broadcast_to(triangles[k], (S, 3, 3)))
            seam = -INSIDE_TOL_REL * scale
            m = np.minimum(np.abs(d).min(axis=1), np.abs(d - seam[:, None]).min(axis=1))
            m = np.minimum(m, np.minimum(np.abs(t - tmin), np.abs(t - tmax)) * L / cos)
            m = m * cos / scale
        near = np.isfinite(t) & (t > tmin - 1e-6) & (t < tmax + 1e-6)
        out[near] = np.minimum(out[near], m[near])
    return out


def face_margins(triangles, tri_face, ends, faces) -> np.ndarray:
    """(E,) how close each end's point-in-face decision comes to a threshold: the least
    distance of ``ends[i]`` from an edge of a triangle of face ``faces[i]`` or from the
    seam tolerance off it, relative to 1 + |end|."""
    out = np.empty(len(ends))
    for i, (end, f) in enumerate(zip(ends, faces, strict=True)):
        cand = np.flatnonzero(tri_face == f)
        dist = edge_distances(np.broadcast_to(end, (len(cand), 3)), triangles[cand])
        scale = 1.0 + np.abs(end).max()
        seam = -INSIDE_TOL_REL * scale
        out[i] = np.minimum(np.abs(dist), np.abs(dist - seam)).min() / scale
    return out


def assert_decided_alike(runtime, host, device, margins_of, err_msg=""):
    """Device decisions against the host's: equal with fp64; without, equal but where
    ``margins_of(differing indices)`` puts the float64 quantity within DECISION_TOL_REL of
    its threshold, and for at most DECISIONS_AT_THRESHOLD_MAX of them."""
    host, device = np.asarray(host), np.asarray(device)
    if runtime.has_double:
        assert np.array_equal(host, device), err_msg
        return
    bad = np.flatnonzero(host != device)
    if len(bad):
        margin = np.asarray(margins_of(bad))
        assert (margin <= DECISION_TOL_REL).all(), (err_msg, bad[margin > DECISION_TOL_REL],
                                                    margin.max())
    assert len(bad) <= DECISIONS_AT_THRESHOLD_MAX * len(host), (err_msg, len(bad))
