"""How far a cheap setting's result lies from a converged reference (docs/tradeoff.md).

Plain functions, arrays in and numbers out, so that each measure can be tested on its own
and ``tools/tradeoff.py`` only composes them:

``frame_channel``        D, D_r -> the NM-sample channel F = D_r / D of one radar frame
``channel_nmse_db``      F against the reference's F: normalised mean-square error, dB
``error_to_noise_db``    a bound of that error against the radar's thermal noise, dB
``image_error_to_noise_db`` the error's largest radar-image cell against the noise, dB
``path_completeness``    share of the reference's path power (and paths) a setting found
``detection_errors``     CFAR detections against the scene's ground truth (m, m/s)
``pareto_front``         the settings no other setting beats in cost and every error
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.paths import InteractionType
from clradcom.radar.processing import radar_image
from clradcom.radar.truth import match_truth

__all__ = [
    "Completeness",
    "DetectionErrors",
    "channel_nmse_db",
    "detection_errors",
    "error_to_noise_db",
    "frame_channel",
    "image_error_to_noise_db",
    "path_completeness",
    "path_kind",
    "path_signatures",
    "pareto_front",
]


def _finite_complex(name: str, x) -> np.ndarray:
    a = np.asarray(x)
    if not np.issubdtype(a.dtype, np.number):
        raise ArgumentError(f"{name} must be numeric, got dtype {a.dtype}")
    if not np.all(np.isfinite(a)):
        raise ArgumentError(f"{name} contains NaN or infinite values")
    return a.astype(complex, copy=False)


def frame_channel(D, Dr) -> np.ndarray:
    """The channel that one radar frame measures: F(n, μ) = D_r(n, μ) / D(n, μ), (N, M).

    This is the paper's spectral estimate before windowing: for the frequency-domain
    model it is exactly H(n, μ) of eq. (3); for the time-domain synthesis it also holds
    the ICI and ISI the fast model leaves out. Both frames must use the same symbols D.
    """
    d = _finite_complex("D", D)
    dr = _finite_complex("Dr", Dr)
    if d.shape != dr.shape or d.ndim != 2:
        raise ArgumentError(f"D and Dr must be (N, M) arrays of one shape, got {d.shape} "
                         f"and {dr.shape}")
    if np.any(d == 0):
        raise ArgumentError("D has zero symbols; D_r / D is undefined there")
    return dr / d


def _pair(H, H_ref):
    h = _finite_complex("H", H)
    r = _finite_complex("H_ref", H_ref)
    if h.shape != r.shape:
        raise ArgumentError(f"H and H_ref must have one shape, got {h.shape} and {r.shape}")
    return h, r


def channel_nmse_db(H, H_ref) -> float:
    """10 log10( Σ|H − H_ref|² / Σ|H_ref|² ): the channel error of a setting, dB.

    −inf when H equals the reference; 0 dB when the error is as large as the channel
    (e.g. a setting that found nothing). H_ref must not be all zero.
    """
    h, r = _pair(H, H_ref)
    ref = float(np.sum(np.abs(r) ** 2))
    if ref == 0.0:
        raise ArgumentError("H_ref is all zero: the reference has no channel to compare with")
    err = float(np.sum(np.abs(h - r) ** 2))
    return -math.inf if err == 0.0 else 10.0 * math.log10(err / ref)


def error_to_noise_db(H, H_ref, noise_variance: float) -> float:
    """10 log10( Σ|H − H_ref|² / σ² ): a bound of the channel error against the noise, dB.

    σ² is the thermal noise variance per cell of F in the units of the path gains
    (:func:`clradcom.evaluation.budget.noise_floor`). After the range/Doppler transforms the noise
    in one image cell is NM·σ² (window normalised), while an error ΔF can put at most
    NM·Σ|ΔF|² into one cell (Cauchy–Schwarz). So below 0 dB no cell of the radar image
    can move by more than the thermal noise already in it: the error is invisible to
    the radar.
    """
    h, r = _pair(H, H_ref)
    var = float(noise_variance)
    if not (math.isfinite(var) and var > 0):
        raise ArgumentError(f"noise_variance must be positive and finite, got {noise_variance!r}")
    err = float(np.sum(np.abs(h - r) ** 2))
    return -math.inf if err == 0.0 else 10.0 * math.log10(err / var)


def image_error_to_noise_db(H, H_ref, noise_variance: float, waveform, window="hann",
                            zero_pad=(2, 2)) -> float:
    """Largest change of any radar-image cell that H makes against H_ref, re the noise, dB.

    The radar image of ΔF = H − H_ref (``clradcom.radar.radar_image`` with the windows and
    zero padding of ``clradcom.radar.pipeline.process``; the image is normalised so that thermal
    noise has power σ² in every cell) divided by σ². Below 0 dB no cell moves by more
    than the noise already in it. :func:`error_to_noise_db` is the bound this never
    exceeds; for a diffuse error (many weak paths spread over the image) it is far lower.
    """
    h, r = _pair(H, H_ref)
    var = float(noise_variance)
    if not (math.isfinite(var) and var > 0):
        raise ArgumentError(f"noise_variance must be positive and finite, got {noise_variance!r}")
    d = h - r
    if not np.any(d):
        return -math.inf
    img = radar_image(d, waveform, window, window, zero_pad[0], zero_pad[1])
    return 10.0 * math.log10(float(img.power.max()) / var)


# ----------------------------------------------------------------------------------------
# path sets
# ----------------------------------------------------------------------------------------
def path_signatures(n_interactions, interaction, face_id) -> list[tuple]:
    """One hashable signature per path: (n, interaction codes..., face ids...).

    A face sequence has at most one specular path between two points (image method);
    a wedge at most one Keller point; a PO facet term is one per triangle. Scattering
    paths are signed by their source triangle only, so the tiles of one triangle share
    a signature whatever the tile size (their powers are summed when compared).
    """
    n = np.asarray(n_interactions).astype(np.int64).ravel()
    codes = np.asarray(interaction).astype(np.int64)
    faces = np.asarray(face_id).astype(np.int64)
    P = len(n)
    if codes.shape[0] != P or faces.shape[0] != P or codes.ndim != 2 or faces.ndim != 2:
        raise ArgumentError(f"interaction and face_id must be (P, K) with P = {P} paths, got "
                         f"{codes.shape} and {faces.shape}")
    out = []
    for i in range(P):
        k = int(n[i])
        if k > codes.shape[1]:
            raise ArgumentError(f"n_interactions[{i}] = {k} exceeds the {codes.shape[1]} "
                             "interaction slots")
        out.append((k, *codes[i, :k].tolist(), *faces[i, :k].tolist()))
    return out


def _signature_power(paths) -> dict:
    sig = path_signatures(paths.n_interactions, paths.interaction, paths.face_id)
    power = np.abs(np.asarray(paths.gain)) ** 2
    acc: dict = {}
    for s, p in zip(sig, power, strict=True):
        acc[s] = acc.get(s, 0.0) + float(p)
    return acc


@dataclass(frozen=True)
class Completeness:
    """How much of the reference's path set a setting found."""

    power_share: float  #: Σ_s min(P_ref,s, P_s) / Σ_s P_ref,s over the reference's signatures
    count_share: float  #: share of the reference's signatures the setting also has
    n_reference: int  #: reference signatures at or above the power floor
    n_found: int  #: of those, how many the setting has


def path_completeness(reference, paths, power_floor: float = 0.0) -> Completeness:
    """Share of a reference path set that another path set reproduces.

    Paths are matched by signature (:func:`path_signatures`: interaction sequence and
    faces); each signature's power is Σ|a|² of its paths. Only reference signatures with
    power ≥ ``power_floor`` (|a|², e.g. the radar's noise floor) count. ``power_share``
    credits each signature with min(P_ref, P_setting), so a path found at the wrong
    strength counts only for what it carries. An empty reference above the floor gives
    shares of 1 (nothing was there to be missed).
    """
    floor = float(power_floor)
    if not (math.isfinite(floor) and floor >= 0):
        raise ArgumentError(f"power_floor must be finite and >= 0, got {power_floor!r}")
    ref = {s: p for s, p in _signature_power(reference).items() if p >= floor and p > 0}
    got = _signature_power(paths)
    total = sum(ref.values())
    if total == 0.0:
        return Completeness(1.0, 1.0, 0, 0)
    matched = sum(min(p, got.get(s, 0.0)) for s, p in ref.items())
    n_found = sum(1 for s in ref if got.get(s, 0.0) > 0)
    return Completeness(matched / total, n_found / len(ref), len(ref), n_found)


def path_kind(interaction) -> np.ndarray:
    """Per path 'scattering', 'diffraction' or 'reflection' (line of sight counts as
    reflection of order 0): the most exotic interaction a path holds. Physical-optics
    facet and SBR returns count as reflection: they stand in for GO reflections."""
    codes = np.asarray(interaction)
    if codes.ndim != 2:
        raise ArgumentError(f"interaction must be (P, K), got shape {codes.shape}")
    kind = np.full(codes.shape[0], "reflection", dtype=object)
    kind[(codes == int(InteractionType.DIFFRACTION)).any(axis=1)] = "diffraction"
    kind[(codes == int(InteractionType.SCATTERING)).any(axis=1)] = "scattering"
    return kind


# ----------------------------------------------------------------------------------------
# detections
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DetectionErrors:
    """Detections of the moving objects against ground truth."""

    n_targets: int
    n_found: int
    range_error_m: float  #: largest over the found targets (nan when none found)
    velocity_error_mps: float  #: largest over the found targets (nan when none found)
    per_target: tuple  #: (name, range error or None, velocity error or None) per target

    @property
    def all_found(self) -> bool:
        return self.n_found == self.n_targets


def detection_errors(detections, truth, range_tol_m: float,
                     velocity_tol_mps: float) -> DetectionErrors:
    """Range and velocity error of the detections that match each truth row.

    Matching is :func:`clradcom.radar.pipeline.match_truth` (the strongest detection within the
    tolerances). A target's echo comes from its visible surface, which lies between the
    nearest point of its mesh and its centre, so the range error is the distance of the
    detected range from the interval [range_nearest_m, range_centre_m] (0 inside it);
    the velocity error is |v_detected − v_rel_m_s|.
    """
    for name, v in (("range_tol_m", range_tol_m), ("velocity_tol_mps", velocity_tol_mps)):
        if not (isinstance(v, int | float | np.floating) and math.isfinite(v) and v > 0):
            raise ArgumentError(f"{name} must be positive and finite, got {v!r}")
    matches = match_truth(detections, truth, range_tol_m, velocity_tol_mps)
    rows, r_err, v_err = [], [], []
    for t, m in zip(truth, matches, strict=True):
        if m is None:
            rows.append((t.get("name", ""), None, None))
            continue
        lo, hi = sorted((float(t["range_nearest_m"]), float(t["range_centre_m"])))
        r = float(m["range_m"])
        re = max(lo - r, r - hi, 0.0)
        ve = abs(float(m["velocity_mps"]) - float(t["v_rel_m_s"]))
        rows.append((t.get("name", ""), re, ve))
        r_err.append(re)
        v_err.append(ve)
    return DetectionErrors(
        n_targets=len(truth), n_found=len(r_err),
        range_error_m=max(r_err) if r_err else math.nan,
        velocity_error_mps=max(v_err) if v_err else math.nan,
        per_target=tuple(rows))


# ----------------------------------------------------------------------------------------
# Pareto front
# ----------------------------------------------------------------------------------------
def pareto_front(cost, *errors, tolerances=None) -> np.ndarray:
    """Boolean mask of the non-dominated points (all criteria minimised).

    Point i is dominated when some j costs no more, has every error no worse than i's
    plus its tolerance, and is better somewhere: cheaper, or some error lower than i's
    by more than the tolerance. ``tolerances`` (one per error, default 0: the plain
    definition) keep differences within measurement noise from making a point
    "better". NaN counts as worst (+inf); −inf (a perfect match) as best. Identical
    points are all kept.
    """
    cols = [np.asarray(cost, dtype=float).ravel()]
    cols += [np.asarray(e, dtype=float).ravel() for e in errors]
    n = len(cols[0])
    for i, c in enumerate(cols):
        if len(c) != n:
            raise ArgumentError(f"criterion {i} has {len(c)} values, cost has {n}")
    tol = np.zeros(len(errors)) if tolerances is None else np.asarray(tolerances, float)
    if tol.shape != (len(errors),) or np.any(~np.isfinite(tol)) or np.any(tol < 0):
        raise ArgumentError(f"tolerances must be {len(errors)} finite values >= 0, got "
                         f"{tolerances!r}")
    X = np.stack([np.where(np.isnan(c), np.inf, c) for c in cols], axis=1)
    tol = np.concatenate([[0.0], tol])
    keep = np.ones(n, dtype=bool)
    with np.errstate(invalid="ignore"):
        for i in range(n):
            no_worse = np.all((X <= X[i] + tol) | (X <= X[i]), axis=1)
            better = (X[:, 0] < X[i, 0]) | np.any((X[:, 1:] < X[i, 1:] - tol[1:]), axis=1)
            if np.any(no_worse & better):
                keep[i] = False
    return keep
