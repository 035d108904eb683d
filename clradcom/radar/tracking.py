"""Multi-target tracking of radar detections over frames on Stone Soup, the moving
objects picked from the stationary world, and tracks set against truth (OSPA, GOSPA and
per-object scores; docs/tracking.md).

The tracker is assembled from Stone Soup's components (Barr et al., "Stone Soup: an
open-source framework for tracking and state estimation", Proc. SPIE 12122, 2022;
https://stonesoup.readthedocs.io):

* **state** per track: range and range rate ``[r, ṙ]``, and where the detections carry
  an azimuth (an array radar) also ``[az, aż]``: the radar's own measurement coordinates,
  so that a radar with one antenna, which measures no angle, is tracked without inventing
  one. Motion: ``CombinedLinearGaussianTransitionModel`` of ``ConstantVelocity`` per
  coordinate (continuous white-noise acceleration of spectral density q:
  ``Q = q [[Δt³/3, Δt²/2], [Δt²/2, Δt]]``; Bar-Shalom, Li & Kirubarajan 2001, §6.2.2).
* **measurement**: ``LinearGaussian`` picking r, ṙ (from the Doppler: ṙ = −v, v the
  detection's closing velocity) and az, each with its standard deviation; Kalman
  predictor and updater.
* **association**: ``PDAHypothesiser`` (likelihood of each detection against the
  clutter density, the track's detection probability, the χ² gate of
  ``gate_probability``) and ``GNNWith2DAssignment``: the globally most likely one-to-one
  pairing of tracks and detections. The clutter density is that of the CFAR's false
  alarms: ``p_fa`` per range–Doppler cell, so ``p_fa / (Δr Δv)`` per unit of range and
  velocity (and per radian of the azimuth span with an array).
* **initiation**: detections left over that lie in no confirmed track's gate (an extended
  object's second echo is its track's, not a new object; Blackman & Popoli 1999 §3.4)
  feed a ``MultiMeasurementInitiator``: a tentative track, its state the measurement (the
  Doppler gives ṙ at once), is confirmed at its ``confirm_hits``-th detection and dropped
  after ``tentative_misses`` frames in a row without one.
* **deletion**: ``UpdateTimeStepsDeleter``: a confirmed track goes after
  ``delete_misses`` frames in a row without a detection.

Which detections are tracked (:func:`moving_detections`): a vehicle radar sees the
stationary world (road, buildings, trees) at the closing speeds its own motion gives
them, v_radar · u over the directions u of its beam; the tracker follows moving objects,
so detections whose closing speed lies in that band (widened by ``speed_margin_mps``)
and those at the radar's own mounting are left out before tracking.

:func:`ospa` and :func:`gospa` are the OSPA distance (Schuhmacher, Vo & Vo, IEEE TSP 56(8)
2008) and the generalised OSPA (Rahmathullah, García-Fernández & Svensson, FUSION 2017)
from a matrix of base distances; :func:`track_metrics` applies them frame by frame to
confirmed tracks against the visible objects, in range and velocity cells.
:func:`score_tracks` sets confirmed tracks against the true objects frame by frame:
errors in range cells (distance to the interval from the object's nearest point to its
centre, where its echoes lie; :mod:`clradcom.radar.array_frame`) and velocity cells.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from datetime import datetime, timedelta

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2
from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
from stonesoup.deleter.time import UpdateTimeStepsDeleter
from stonesoup.hypothesiser.probability import PDAHypothesiser
from stonesoup.initiator.simple import MultiMeasurementInitiator
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.models.transition.linear import (
    CombinedLinearGaussianTransitionModel,
    ConstantVelocity,
)
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.types.detection import Detection
from stonesoup.types.state import GaussianState
from stonesoup.types.update import Update
from stonesoup.updater.kalman import KalmanUpdater

from clradcom.errors import ArgumentError

__all__ = ["METRIC_DTYPE", "SCORE_DTYPE", "TRACK_DTYPE", "Tracker", "TrackerSettings",
           "clutter_density", "gospa", "moving_detections", "ospa", "score_summary",
           "score_tracks", "stationary_speed_band", "track_detections", "track_metrics"]

#: one row per live track and frame (after the frame's update)
TRACK_DTYPE = np.dtype([
    ("frame", np.int64), ("time_s", float), ("track", np.int64), ("confirmed", bool),
    ("range_m", float), ("velocity_mps", float), ("azimuth_deg", float),
    ("range_std_m", float), ("velocity_std_mps", float), ("detection", np.int64),
])

#: one row per object and frame (:func:`score_tracks`)
SCORE_DTYPE = np.dtype([
    ("frame", np.int64), ("time_s", float), ("object", "U64"), ("visible", bool),
    ("track", np.int64), ("range_nearest_m", float), ("range_centre_m", float),
    ("velocity_true_mps", float), ("range_track_m", float), ("velocity_track_mps", float),
    ("range_error_cells", float), ("velocity_error_cells", float), ("within", bool),
    ("azimuth_true_deg", float), ("azimuth_track_deg", float),
])

#: one row per frame (:func:`track_metrics`): confirmed tracks, visible objects, the OSPA
#: distance and GOSPA with its parts (localisation, missed, false), in cells
METRIC_DTYPE = np.dtype([
    ("frame", np.int64), ("time_s", float), ("confirmed_tracks", np.int64),
    ("visible_objects", np.int64), ("ospa_cells", float), ("gospa_cells", float),
    ("gospa_localisation", float), ("gospa_missed", float), ("gospa_false", float),
])

_BIG = 1e12
#: Stone Soup works in datetimes: frame times are seconds after this instant
_EPOCH = datetime(2000, 1, 1)


def _positive(name, v, *, integer=False):
    if integer:
        ok = isinstance(v, int | np.integer) and not isinstance(v, bool) and v >= 1
        if not ok:
            raise ArgumentError("must be an integer >= 1", argument=name, value=v)
        return
    if not (isinstance(v, int | float | np.floating) and not isinstance(v, bool)
            and math.isfinite(v) and v > 0):
        raise ArgumentError("must be a positive finite number", argument=name, value=v)


def _probability(name, v):
    if not (isinstance(v, int | float | np.floating) and not isinstance(v, bool)
            and 0 < v < 1):
        raise ArgumentError("must lie strictly between 0 and 1", argument=name, value=v)


@dataclass(frozen=True)
class TrackerSettings:
    """The tracker's numbers (module docstring). Measurement standard deviations are the
    spread of an extended target's detections about its track, not the Cramér–Rao bound
    of one point scatterer: a car's echoes come from its whole front."""

    range_std_m: float = 0.5
    velocity_std_mps: float = 0.5
    azimuth_std_deg: float = 2.0
    #: spectral density q of the white-noise acceleration in range (m²/s³)
    acceleration_psd_m2_s3: float = 5.0
    #: the same in azimuth (deg²/s³)
    azimuth_acceleration_psd_deg2_s3: float = 2000.0
    #: initial σ of a new track's azimuth rate (deg/s)
    azimuth_rate_std_deg_s: float = 30.0
    #: probability that a tracked object is detected in a frame
    prob_detect: float = 0.9
    gate_probability: float = 0.999
    #: the CFAR's false-alarm probability per range–Doppler cell (the clutter density)
    p_fa: float = 1e-6
    confirm_hits: int = 3
    tentative_misses: int = 2
    delete_misses: int = 3

    def __post_init__(self):
        for f in ("range_std_m", "velocity_std_mps", "azimuth_std_deg",
                  "acceleration_psd_m2_s3", "azimuth_acceleration_psd_deg2_s3",
                  "azimuth_rate_std_deg_s"):
            _positive(f"TrackerSettings.{f}", getattr(self, f))
        for f in ("prob_detect", "gate_probability", "p_fa"):
            _probability(f"TrackerSettings.{f}", getattr(self, f))
        for f in ("confirm_hits", "tentative_misses", "delete_misses"):
            _positive(f"TrackerSettings.{f}", getattr(self, f), integer=True)

    def replace(self, **changes) -> TrackerSettings:
        return dataclasses.replace(self, **changes)


def clutter_density(p_fa: float, range_cell_m: float, velocity_cell_mps: float,
                    azimuth_span_rad: float | None = None) -> float:
    """False alarms per unit of measurement space: ``p_fa`` per range–Doppler cell of
    Δr × Δv, spread over ``azimuth_span_rad`` where the detections carry an azimuth."""
    _probability("p_fa", p_fa)
    _positive("range_cell_m", range_cell_m)
    _positive("velocity_cell_mps", velocity_cell_mps)
    density = p_fa / (range_cell_m * velocity_cell_mps)
    if azimuth_span_rad is not None:
        _positive("azimuth_span_rad", azimuth_span_rad)
        density /= azimuth_span_rad
    return float(density)


def stationary_speed_band(velocity_local, directions_local,
                          allowed=None) -> tuple[np.ndarray, np.ndarray]:
    """Closing speeds (lowest, highest) that a stationary scatterer can have, seen from a
    radar moving at ``velocity_local`` (m/s, in the radar's frame) in any of
    ``directions_local`` (n, 3 unit vectors in that frame, e.g. those of its beam): v · u.
    One band, or with ``allowed`` (detections × directions, bool: where a detection's
    scatterer can lie) one per detection; a detection allowed no direction gets the
    empty band (+inf, -inf)."""
    v = np.asarray(velocity_local, dtype=float).reshape(3)
    u = np.asarray(directions_local, dtype=float).reshape(-1, 3)
    if not len(u):
        raise ArgumentError("must hold at least one direction", argument="directions_local",
                            value=u.shape)
    speed = u @ v
    if allowed is None:
        return np.array([speed.min()]), np.array([speed.max()])
    ok = np.asarray(allowed, dtype=bool)
    if ok.ndim != 2 or ok.shape[1] != len(u):
        raise ArgumentError(f"must be a (detections, {len(u)}) mask", argument="allowed",
                            value=ok.shape)
    return (np.where(ok, speed[None, :], np.inf).min(axis=1),
            np.where(ok, speed[None, :], -np.inf).max(axis=1))


def moving_detections(detections, band_low_mps, band_high_mps, *, speed_margin_mps: float,
                      min_range_m: float = 0.0) -> np.ndarray:
    """Mask of the detections to track: farther than ``min_range_m`` (the radar's own
    mounting return lies nearer) and with a closing speed outside the stationary world's
    band [low − margin, high + margin] (:func:`stationary_speed_band`; one band for all,
    or one per detection; a detection whose band is empty is moving)."""
    det = np.asarray(detections)
    r = np.asarray(det["range_m"], dtype=float)
    v = np.asarray(det["velocity_mps"], dtype=float)
    lo = np.broadcast_to(np.asarray(band_low_mps, dtype=float), v.shape)
    hi = np.broadcast_to(np.asarray(band_high_mps, dtype=float), v.shape)
    stationary = (v >= lo - speed_margin_mps) & (v <= hi + speed_margin_mps)
    return (r > min_range_m) & ~stationary


def _measurements(det, use_azimuth: bool) -> np.ndarray:
    """Measurements (n, 2 or 3): range, range rate, [azimuth rad]."""
    det = np.asarray(det)
    names = det.dtype.names or ()
    for k in ("range_m", "velocity_mps") + (("azimuth_rad",) if use_azimuth else ()):
        if k not in names:
            raise ArgumentError(f"must be structured detections with a {k!r} field",
                                argument="detections", value=det.dtype)
    cols = [det["range_m"].astype(float), -det["velocity_mps"].astype(float)]
    if use_azimuth:
        cols.append(det["azimuth_rad"].astype(float))
    z = np.stack(cols, axis=1) if det.size else np.zeros((0, len(cols)))
    if not np.all(np.isfinite(z)):
        raise ArgumentError("hold non-finite range, velocity or azimuth",
                            argument="detections", value=z[~np.isfinite(z).all(axis=1)][:1])
    return z


class Tracker:
    """The online tracker on Stone Soup (module docstring): :meth:`step` takes one
    frame's detections (structured, fields ``range_m``, ``velocity_mps`` and, with
    ``use_azimuth``, ``azimuth_rad``) at its time and returns the live tracks'
    :data:`TRACK_DTYPE` rows, tentative ones included. ``range_cell_m`` and
    ``velocity_cell_mps`` (the radar's cells; by default the paper frame's) and
    ``azimuth_span_rad`` set the clutter density of the CFAR's ``p_fa``."""

    def __init__(self, settings: TrackerSettings | None = None, *, use_azimuth: bool = False,
                 range_cell_m: float = 1.61, velocity_cell_mps: float = 1.97,
                 azimuth_span_rad: float = math.pi):
        if settings is None:
            settings = TrackerSettings()
        if not isinstance(settings, TrackerSettings):
            raise ArgumentError("must be a TrackerSettings", argument="settings",
                                value=settings)
        self.settings = s = settings
        self.use_azimuth = bool(use_azimuth)
        self.clutter_density = clutter_density(
            s.p_fa, range_cell_m, velocity_cell_mps,
            azimuth_span_rad if self.use_azimuth else None)
        meas_std = [s.range_std_m, s.velocity_std_mps]
        axes = [ConstantVelocity(s.acceleration_psd_m2_s3)]
        prior_std = [s.range_std_m, s.velocity_std_mps]
        if self.use_azimuth:
            meas_std.append(math.radians(s.azimuth_std_deg))
            axes.append(ConstantVelocity(math.radians(1.0) ** 2
                                         * s.azimuth_acceleration_psd_deg2_s3))
            prior_std += [math.radians(s.azimuth_std_deg), math.radians(s.azimuth_rate_std_deg_s)]
        self.n_meas = len(meas_std)
        self.measurement_model = LinearGaussian(
            ndim_state=2 * len(axes), mapping=tuple(range(self.n_meas)),
            noise_covar=np.diag(np.square(meas_std)))
        self.transition_model = CombinedLinearGaussianTransitionModel(axes)
        predictor = KalmanPredictor(self.transition_model)
        self.updater = KalmanUpdater(self.measurement_model)
        hypothesiser = PDAHypothesiser(predictor, self.updater,
                                       clutter_spatial_density=self.clutter_density,
                                       prob_detect=s.prob_detect,
                                       prob_gate=s.gate_probability)
        self.associator = GNNWith2DAssignment(hypothesiser)
        self.deleter = UpdateTimeStepsDeleter(s.delete_misses)
        self.initiator = MultiMeasurementInitiator(
            prior_state=GaussianState(np.zeros(2 * len(axes)), np.diag(np.square(prior_std))),
            measurement_model=self.measurement_model,
            deleter=UpdateTimeStepsDeleter(s.tentative_misses),
            data_associator=self.associator, updater=self.updater,
            min_points=s.confirm_hits)
        self.gate = float(chi2.ppf(s.gate_probability, self.n_meas))
        self.tracks: set = set()
        self.frame = -1
        self.time_s: float | None = None
        self._ids: dict = {}

    def _id(self, track) -> int:
        return self._ids.setdefault(track.id, len(self._ids))

    def _in_gates(self, predictions, z) -> np.ndarray:
        """Mask of the measurements inside any of these predictions' χ² gates."""
        inside = np.zeros(len(z), bool)
        for pred in predictions:
            mp = self.updater.predict_measurement(pred)
            y = z - np.asarray(mp.state_vector, dtype=float).reshape(1, -1)
            d2 = np.einsum("ij,jk,ik->i", y, np.linalg.inv(np.asarray(mp.covar, float)), y)
            inside |= d2 <= self.gate
        return inside

    def step(self, time_s: float, detections) -> np.ndarray:
        """Associate this frame's detections with the confirmed tracks, update them,
        delete the stale ones, and pass the detections outside every confirmed track's
        gate to the initiator; the live tracks' rows (confirmed and tentative)."""
        t_now = float(time_s)
        if not math.isfinite(t_now) or (self.time_s is not None and t_now <= self.time_s):
            raise ArgumentError("must be finite and later than the previous frame's "
                                f"({self.time_s})", argument="time_s", value=time_s)
        z = _measurements(detections, self.use_azimuth)
        stamp = _EPOCH + timedelta(seconds=t_now)
        self.time_s, self.frame = t_now, self.frame + 1
        dets = [Detection(z[j].reshape(-1, 1), timestamp=stamp,
                          measurement_model=self.measurement_model, metadata={"index": j})
                for j in range(len(z))]
        used, predicted = set(), {}
        if self.tracks:
            for track, hyp in self.associator.associate(self.tracks, set(dets),
                                                        stamp).items():
                predicted[track] = hyp.prediction
                if hyp:
                    track.append(self.updater.update(hyp))
                    used.add(hyp.measurement.metadata["index"])
                else:
                    track.append(hyp.prediction)
            self.tracks -= self.deleter.delete_tracks(self.tracks)
        gated = self._in_gates([predicted[t] for t in self.tracks], z)
        fresh = {d for d in dets if d.metadata["index"] not in used
                 and not gated[d.metadata["index"]]}
        self.tracks |= self.initiator.initiate(fresh, stamp)
        rows = [(t, True) for t in self.tracks] + [(t, False)
                                                   for t in self.initiator.holding_tracks]
        # new tracks numbered in the order of the detections that started them (the sets
        # Stone Soup keeps have no order that would repeat from run to run)
        for t, _ in sorted((tc for tc in rows if tc[0].id not in self._ids),
                           key=lambda tc: _first_detection(tc[0])):
            self._id(t)
        out = np.zeros(len(rows), TRACK_DTYPE)
        for k, (t, confirmed) in enumerate(sorted(rows, key=lambda tc: self._id(tc[0]))):
            st = t.state
            x, P = np.asarray(st.state_vector, float).ravel(), np.asarray(st.covar, float)
            hit = (isinstance(st, Update) and st.timestamp == stamp and st.hypothesis
                   and st.hypothesis.measurement.metadata.get("index") is not None)
            out[k] = (self.frame, t_now, self._id(t), confirmed, x[0], -x[1],
                      math.degrees(x[2]) if self.use_azimuth else np.nan,
                      math.sqrt(P[0, 0]), math.sqrt(P[1, 1]),
                      st.hypothesis.measurement.metadata["index"] if hit else -1)
        return out


def _first_detection(track) -> tuple[float, int]:
    """(time, index in its frame) of the detection that started a track."""
    first = track.states[0]
    hyp = getattr(first, "hypothesis", None)
    index = hyp.measurement.metadata.get("index", -1) if hyp else -1
    return first.timestamp.timestamp(), int(index)


def track_detections(times_s, detections, settings: TrackerSettings | None = None, *,
                     use_azimuth: bool | None = None, **cells) -> np.ndarray:
    """Run a :class:`Tracker` over frames: ``detections[k]`` at ``times_s[k]``; all
    frames' :data:`TRACK_DTYPE` rows. ``use_azimuth`` defaults to whether the first
    frame's detections have an ``azimuth_rad`` field; ``cells``: the
    :class:`Tracker`'s ``range_cell_m``, ``velocity_cell_mps``, ``azimuth_span_rad``."""
    times = np.asarray(times_s, dtype=float).reshape(-1)
    if len(times) != len(detections):
        raise ArgumentError(f"must be one array of detections per time ({len(times)})",
                            argument="detections", value=len(detections))
    if use_azimuth is None:
        names = np.asarray(detections[0]).dtype.names if len(detections) else None
        use_azimuth = bool(names and "azimuth_rad" in names)
    tracker = Tracker(settings, use_azimuth=use_azimuth, **cells)
    rows = [tracker.step(t, d) for t, d in zip(times, detections, strict=True)]
    return np.concatenate(rows) if rows else np.zeros(0, TRACK_DTYPE)


def ospa(distances, c: float, p: float = 2.0) -> float:
    """OSPA distance of order ``p`` and cut-off ``c`` between two finite sets, from the
    matrix of base distances between their elements (m × n; either side may be empty):
    (1/max(m,n) · (min over assignments Σ min(d, c)^p + c^p |m − n|))^(1/p)
    (Schuhmacher, Vo & Vo 2008, eq. 3). 0 for two empty sets."""
    d, c, p = _metric_args(distances, c, p)
    m, n = d.shape
    if max(m, n) == 0:
        return 0.0
    dc = np.minimum(d, c) ** p
    cost = 0.0
    if m and n:
        rows, cols = linear_sum_assignment(dc)
        cost = float(dc[rows, cols].sum())
    return float(((cost + c ** p * abs(m - n)) / max(m, n)) ** (1.0 / p))


def gospa(distances, c: float, p: float = 2.0) -> dict:
    """GOSPA (α = 2) between estimates (rows) and truth (columns) from their base
    distances: (min over assignments Σ_assigned d^p + c^p/2 (missed + false))^(1/p), pairs
    farther than c left unassigned (Rahmathullah, García-Fernández & Svensson 2017,
    Proposition 1). Returns ``distance`` and its p-th-power parts ``localisation``,
    ``missed`` (truths unassigned · c^p/2) and ``false`` (estimates unassigned · c^p/2)."""
    d, c, p = _metric_args(distances, c, p)
    m, n = d.shape
    half = c ** p / 2.0
    loc, n_pairs = 0.0, 0
    if m and n:
        # assigning a pair costs d^p, leaving both unassigned c^p: min(d^p, c^p) then
        # pairs at the cut-off dropped
        dc = np.minimum(d ** p, c ** p)
        rows, cols = linear_sum_assignment(dc)
        keep = d[rows, cols] < c
        loc, n_pairs = float((d[rows, cols][keep] ** p).sum()), int(keep.sum())
    missed, false = half * (n - n_pairs), half * (m - n_pairs)
    return {"distance": float((loc + missed + false) ** (1.0 / p)), "localisation": loc,
            "missed": missed, "false": false}


def _metric_args(distances, c, p):
    d = np.asarray(distances, dtype=float)
    if d.ndim != 2 or not np.all(np.isfinite(d)) or (d < 0).any():
        raise ArgumentError("must be a 2-D matrix of finite distances >= 0",
                            argument="distances", value=d.shape)
    _positive("c", c)
    if not (isinstance(p, int | float | np.floating) and math.isfinite(p) and p >= 1):
        raise ArgumentError("must be a finite number >= 1", argument="p", value=p)
    return d, float(c), float(p)


def _errors_in_cells(truth, live, dr_cell, dv_cell):
    """(range, velocity) errors in cells, objects × tracks: range to the object's
    [nearest, centre] interval, velocity to its closing speed."""
    n_o, n_t = len(truth), len(live)
    er = np.zeros((n_o, n_t))
    ev = np.zeros((n_o, n_t))
    for i, t in enumerate(truth):
        r = live["range_m"]
        er[i] = np.maximum(np.maximum(t["range_nearest_m"] - r,
                                      r - t["range_centre_m"]), 0.0) / dr_cell
        ev[i] = np.abs(live["velocity_mps"] - t["v_rel_m_s"]) / dv_cell
    return er, ev


def track_metrics(tracks, truth_frames, range_cell_m: float, velocity_cell_mps: float, *,
                  cutoff_cells: float = 3.0, p: float = 2.0) -> np.ndarray:
    """Per frame (:data:`METRIC_DTYPE`): the tracks confirmed at that frame (as the online
    tracker shows them) against the objects visible in it; base distance
    √(e_r² + e_v²), the errors in range and velocity cells of :func:`score_tracks`;
    OSPA and GOSPA with cut-off ``cutoff_cells`` and order ``p``."""
    dr_cell = _cells("range_cell_m", range_cell_m)
    dv_cell = _cells("velocity_cell_mps", velocity_cell_mps)
    tr = np.asarray(tracks, dtype=TRACK_DTYPE)
    out = np.zeros(len(truth_frames), METRIC_DTYPE)
    for k, truth in enumerate(truth_frames):
        shown = [t for t in truth if bool(t.get("visible", True))]
        live = tr[(tr["frame"] == k) & tr["confirmed"]]
        er, ev = _errors_in_cells(shown, live, dr_cell, dv_cell)
        d = np.hypot(er, ev).T  # tracks × objects
        g = gospa(d, cutoff_cells, p)
        time_s = truth[0].get("time_s", np.nan) if truth else (
            live["time_s"][0] if len(live) else np.nan)
        out[k] = (k, time_s, len(live), len(shown), ospa(d, cutoff_cells, p), g["distance"],
                  g["localisation"], g["missed"], g["false"])
    return out


def _cells(name, value) -> float:
    if not (isinstance(value, int | float | np.floating) and math.isfinite(value)
            and value > 0):
        raise ArgumentError("must be a positive finite cell size", argument=name, value=value)
    return float(value)


def score_tracks(tracks, truth_frames, range_cell_m: float, velocity_cell_mps: float, *,
                 gate_cells: float = 3.0, retroactive: bool = True) -> np.ndarray:
    """Confirmed tracks set against the true objects, frame by frame.

    ``tracks``: :data:`TRACK_DTYPE` rows; ``truth_frames[k]``: frame k's truth rows
    (:func:`clradcom.radar.truth.detection_truth`, with a ``visible`` flag and
    ``time_s``). A track's range error is its distance to the object's interval
    [``range_nearest_m``, ``range_centre_m``] in range cells, its velocity error
    |v_track − v_rel| in velocity cells; each frame, objects and confirmed tracks are
    paired by ``linear_sum_assignment`` on the larger of the two errors, a pair kept
    when it is at most ``gate_cells``. One :data:`SCORE_DTYPE` row per object and frame;
    ``within``: both errors at most one cell (azimuth, where tracked, is reported
    beside the centre's, not scored). ``retroactive``: a track confirmed at some
    frame counts from its first frame on (a batch evaluation: the online tracker shows it
    only from its confirmation, ``confirm_hits - 1`` frames after it began at the
    earliest); False: only the frames where it already was confirmed."""
    dr_cell = _cells("range_cell_m", range_cell_m)
    dv_cell = _cells("velocity_cell_mps", velocity_cell_mps)
    tr = np.asarray(tracks, dtype=TRACK_DTYPE)
    ok = np.isin(tr["track"], tr["track"][tr["confirmed"]]) if retroactive else tr["confirmed"]
    out = []
    for k, truth in enumerate(truth_frames):
        live = tr[(tr["frame"] == k) & ok]
        n_o, n_t = len(truth), len(live)
        er, ev = _errors_in_cells(truth, live, dr_cell, dv_cell)
        pair = {}
        if n_o and n_t:
            cost = np.maximum(er, ev)
            rows, cols = linear_sum_assignment(np.where(cost <= gate_cells, cost, _BIG))
            pair = {i: j for i, j in zip(rows.tolist(), cols.tolist(), strict=True)
                    if cost[i, j] <= gate_cells}
        for i, t in enumerate(truth):
            j = pair.get(i)
            row = np.zeros((), SCORE_DTYPE)
            row["frame"], row["time_s"] = k, t.get("time_s", np.nan)
            row["object"], row["visible"] = t["name"], bool(t.get("visible", True))
            row["range_nearest_m"], row["range_centre_m"] = (t["range_nearest_m"],
                                                             t["range_centre_m"])
            row["velocity_true_mps"] = t["v_rel_m_s"]
            row["azimuth_true_deg"] = t.get("azimuth_deg", np.nan)
            if j is None:
                row["track"] = -1
                for f in ("range_track_m", "velocity_track_mps", "azimuth_track_deg"):
                    row[f] = np.nan
                row["range_error_cells"] = row["velocity_error_cells"] = np.inf
            else:
                row["track"] = live["track"][j]
                row["range_track_m"] = live["range_m"][j]
                row["velocity_track_mps"] = live["velocity_mps"][j]
                row["azimuth_track_deg"] = live["azimuth_deg"][j]
                row["range_error_cells"], row["velocity_error_cells"] = er[i, j], ev[i, j]
            row["within"] = bool(row["range_error_cells"] <= 1.0
                                 and row["velocity_error_cells"] <= 1.0)
            out.append(row)
    return np.array(out, dtype=SCORE_DTYPE) if out else np.zeros(0, SCORE_DTYPE)


def score_summary(scores) -> list[dict]:
    """Per object (in order of first appearance): frames, frames visible, visible frames
    with a track within one cell, the largest errors over the visible frames with a track,
    the distinct tracks that followed it, and ``all_within`` (every visible frame within
    one range and one velocity cell; False for an object never visible)."""
    sc = np.asarray(scores, dtype=SCORE_DTYPE)
    out = []
    for name in dict.fromkeys(sc["object"].tolist()):
        s = sc[sc["object"] == name]
        vis = s[s["visible"]]
        tracked = vis[vis["track"] >= 0]
        out.append({
            "object": name, "frames": int(len(s)), "visible": int(len(vis)),
            "within": int(vis["within"].sum()),
            "max_range_error_cells": float(tracked["range_error_cells"].max())
            if len(tracked) else np.nan,
            "max_velocity_error_cells": float(tracked["velocity_error_cells"].max())
            if len(tracked) else np.nan,
            "tracks": sorted(set(tracked["track"].tolist())),
            "all_within": bool(len(vis) and vis["within"].all()),
        })
    return out
