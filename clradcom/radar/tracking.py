"""Multi-target tracking of radar detections over frames, and tracks set against truth
(docs/tracking.md).

A textbook tracker (Blackman & Popoli, *Design and Analysis of Modern Tracking Systems*,
1999, ch. 3, 4 and 6; Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to
Tracking and Navigation*, 2001, §6.3 and §11.3):

* **state** per track: range and range rate, ``x = [r, ṙ]``, and where the detections
  carry an azimuth (an array radar) also ``[az, aż]``; a constant-velocity model with
  discrete white-noise acceleration (Bar-Shalom §6.3.3: ``Q = σ_a² [[Δt⁴/4, Δt³/2],
  [Δt³/2, Δt²]]`` per coordinate).
* **measurement**: range, range rate from the Doppler (``ṙ = −v``, v the detection's
  closing velocity) and azimuth, each with its own standard deviation (a Kalman filter
  with ``H`` picking r, ṙ and az).
* **gating and assignment**: the normalised innovation ``d² = yᵀ S⁻¹ y`` must lie inside
  the χ² gate of ``gate_probability``; detections and tracks are paired by
  ``scipy.optimize.linear_sum_assignment`` on Blackman's generalised distance
  ``d² + ln |S|`` (global nearest neighbour).
* **track management**: every detection left over that lies in no confirmed track's gate
  (Blackman & Popoli §3.4: such a detection is the confirmed track's, a second echo of
  the same object or clutter, not a new object) starts a tentative track (its state the
  measurement, range rate included: the Doppler gives it at once); a tentative track
  is confirmed once it has ``confirm_hits`` hits within its last ``confirm_window``
  frames (M-of-N), and dropped when it can no longer reach them in its first
  ``confirm_window`` frames; a confirmed track is deleted after ``delete_misses``
  consecutive frames without a detection.

:func:`score_tracks` sets confirmed tracks against the true objects frame by frame:
errors in range cells (distance to the interval from the object's nearest point to its
centre, where its echoes lie; :mod:`clradcom.radar.array_frame`) and velocity cells.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

from clradcom.errors import ArgumentError

__all__ = ["SCORE_DTYPE", "TRACK_DTYPE", "Tracker", "TrackerSettings", "score_summary",
           "score_tracks", "track_detections"]

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

_BIG = 1e12


@dataclass(frozen=True)
class TrackerSettings:
    """The tracker's numbers (module docstring). Measurement standard deviations are the
    spread of an extended target's detections about its track, not the Cramér–Rao bound
    of one point scatterer: a car's echoes come from its whole front."""

    range_std_m: float = 0.5
    velocity_std_mps: float = 0.5
    azimuth_std_deg: float = 2.0
    #: σ_a of the white-noise acceleration in range (m/s²)
    acceleration_std_mps2: float = 10.0
    #: σ of the white-noise angular acceleration in azimuth (deg/s²)
    azimuth_acceleration_std_deg_s2: float = 200.0
    #: initial σ of a new track's azimuth rate (deg/s)
    azimuth_rate_std_deg_s: float = 30.0
    gate_probability: float = 0.999
    confirm_hits: int = 3
    confirm_window: int = 4
    delete_misses: int = 3

    def __post_init__(self):
        for f in ("range_std_m", "velocity_std_mps", "azimuth_std_deg",
                  "acceleration_std_mps2", "azimuth_acceleration_std_deg_s2",
                  "azimuth_rate_std_deg_s"):
            v = getattr(self, f)
            if not (isinstance(v, int | float | np.floating) and not isinstance(v, bool)
                    and math.isfinite(v) and v > 0):
                raise ArgumentError("must be a positive finite number",
                                    argument=f"TrackerSettings.{f}", value=v)
        p = self.gate_probability
        if not (isinstance(p, int | float | np.floating) and 0 < p < 1):
            raise ArgumentError("must lie strictly between 0 and 1",
                                argument="TrackerSettings.gate_probability", value=p)
        for f in ("confirm_hits", "confirm_window", "delete_misses"):
            v = getattr(self, f)
            if not (isinstance(v, int | np.integer) and not isinstance(v, bool) and v >= 1):
                raise ArgumentError("must be an integer >= 1",
                                    argument=f"TrackerSettings.{f}", value=v)
        if self.confirm_hits > self.confirm_window:
            raise ArgumentError(f"must not exceed confirm_window = {self.confirm_window}",
                                argument="TrackerSettings.confirm_hits",
                                value=self.confirm_hits)

    def replace(self, **changes) -> TrackerSettings:
        return dataclasses.replace(self, **changes)


def _cv_blocks(dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    f = np.array([[1.0, dt], [0.0, 1.0]])
    qq = q * q * np.array([[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]])
    return f, qq


def _detections(det, use_azimuth: bool) -> np.ndarray:
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


class _Track:
    __slots__ = ("id", "x", "P", "history", "misses", "confirmed")

    def __init__(self, tid, x, P):
        self.id, self.x, self.P = tid, x, P
        self.history: list[bool] = [True]
        self.misses = 0
        self.confirmed = False


class Tracker:
    """The online tracker: :meth:`step` takes one frame's detections (structured, fields
    ``range_m``, ``velocity_mps`` and, with ``use_azimuth``, ``azimuth_rad``) at its time
    and returns the live tracks' :data:`TRACK_DTYPE` rows."""

    def __init__(self, settings: TrackerSettings | None = None, *, use_azimuth: bool = False):
        if settings is None:
            settings = TrackerSettings()
        if not isinstance(settings, TrackerSettings):
            raise ArgumentError("must be a TrackerSettings", argument="settings",
                                value=settings)
        self.settings = settings
        self.use_azimuth = bool(use_azimuth)
        s = settings
        meas = [s.range_std_m, s.velocity_std_mps]
        if self.use_azimuth:
            meas.append(math.radians(s.azimuth_std_deg))
        self.R = np.diag(np.square(meas))
        dim = 4 if self.use_azimuth else 2
        self.H = np.zeros((len(meas), dim))
        self.H[0, 0] = self.H[1, 1] = 1.0
        if self.use_azimuth:
            self.H[2, 2] = 1.0
        self.gate = float(chi2.ppf(s.gate_probability, len(meas)))
        self.tracks: list[_Track] = []
        self.frame = -1
        self.time_s: float | None = None
        self._next_id = 0

    # -- the filter -------------------------------------------------------------------
    def _predict(self, dt: float) -> None:
        s = self.settings
        f, q = _cv_blocks(dt, s.acceleration_std_mps2)
        F, Q = f, q
        if self.use_azimuth:
            fa, qa = _cv_blocks(dt, math.radians(s.azimuth_acceleration_std_deg_s2))
            F = np.block([[f, np.zeros((2, 2))], [np.zeros((2, 2)), fa]])
            Q = np.block([[q, np.zeros((2, 2))], [np.zeros((2, 2)), qa]])
        for t in self.tracks:
            t.x = F @ t.x
            t.P = F @ t.P @ F.T + Q

    def _new_track(self, z) -> _Track:
        s = self.settings
        if self.use_azimuth:
            x = np.array([z[0], z[1], z[2], 0.0])
            P = np.diag([s.range_std_m ** 2, s.velocity_std_mps ** 2,
                         math.radians(s.azimuth_std_deg) ** 2,
                         math.radians(s.azimuth_rate_std_deg_s) ** 2])
        else:
            x = np.array([z[0], z[1]])
            P = np.diag([s.range_std_m ** 2, s.velocity_std_mps ** 2])
        t = _Track(self._next_id, x, P)
        self._next_id += 1
        return t

    def step(self, time_s: float, detections) -> np.ndarray:
        """Predict every track to ``time_s``, gate and assign the detections, update,
        confirm, delete and start tracks; the live tracks' rows."""
        t_now = float(time_s)
        if not math.isfinite(t_now) or (self.time_s is not None and t_now <= self.time_s):
            raise ArgumentError("must be finite and later than the previous frame's "
                                f"({self.time_s})", argument="time_s", value=time_s)
        z = _detections(detections, self.use_azimuth)
        if self.time_s is not None:
            self._predict(t_now - self.time_s)
        self.time_s, self.frame = t_now, self.frame + 1
        n_t, n_z = len(self.tracks), len(z)
        assigned: dict[int, int] = {}
        in_confirmed_gate = np.zeros(n_z, bool)
        if n_t and n_z:
            cost = np.full((n_t, n_z), _BIG)
            for i, t in enumerate(self.tracks):
                S = self.H @ t.P @ self.H.T + self.R
                Si = np.linalg.inv(S)
                y = z - (self.H @ t.x)[None, :]
                d2 = np.einsum("ij,jk,ik->i", y, Si, y)
                ok = d2 <= self.gate
                cost[i, ok] = d2[ok] + math.log(np.linalg.det(S))
                if t.confirmed:
                    in_confirmed_gate |= ok
            rows, cols = linear_sum_assignment(cost)
            for i, j in zip(rows.tolist(), cols.tolist(), strict=True):
                if cost[i, j] < _BIG:
                    assigned[i] = j
        s = self.settings
        keep, det_of = [], {}
        for i, t in enumerate(self.tracks):
            j = assigned.get(i)
            if j is not None:
                S = self.H @ t.P @ self.H.T + self.R
                K = t.P @ self.H.T @ np.linalg.inv(S)
                t.x = t.x + K @ (z[j] - self.H @ t.x)
                ikh = np.eye(len(t.x)) - K @ self.H
                t.P = ikh @ t.P @ ikh.T + K @ self.R @ K.T  # Joseph form
                t.misses = 0
            else:
                t.misses += 1
            t.history.append(j is not None)
            if not t.confirmed:
                recent = t.history[-s.confirm_window:]
                if sum(recent) >= s.confirm_hits:
                    t.confirmed = True
                elif len(t.history) >= s.confirm_window or \
                        len(t.history) - sum(t.history) > s.confirm_window - s.confirm_hits:
                    continue  # can no longer be confirmed in its first window: dropped
            elif t.misses >= s.delete_misses:
                continue
            keep.append(t)
            det_of[t.id] = -1 if j is None else j
        used = set(assigned.values())
        for j in range(n_z):
            if j not in used and not in_confirmed_gate[j]:
                t = self._new_track(z[j])
                if s.confirm_hits == 1:
                    t.confirmed = True
                keep.append(t)
                det_of[t.id] = j
        self.tracks = keep
        out = np.zeros(len(keep), TRACK_DTYPE)
        for k, t in enumerate(keep):
            out[k] = (self.frame, t_now, t.id, t.confirmed, t.x[0], -t.x[1],
                      math.degrees(t.x[2]) if self.use_azimuth else np.nan,
                      math.sqrt(t.P[0, 0]), math.sqrt(t.P[1, 1]), det_of[t.id])
        return out


def track_detections(times_s, detections, settings: TrackerSettings | None = None, *,
                     use_azimuth: bool | None = None) -> np.ndarray:
    """Run a :class:`Tracker` over frames: ``detections[k]`` at ``times_s[k]``; all
    frames' :data:`TRACK_DTYPE` rows. ``use_azimuth`` defaults to whether the first
    frame's detections have an ``azimuth_rad`` field."""
    times = np.asarray(times_s, dtype=float).reshape(-1)
    if len(times) != len(detections):
        raise ArgumentError(f"must be one array of detections per time ({len(times)})",
                            argument="detections", value=len(detections))
    if use_azimuth is None:
        names = np.asarray(detections[0]).dtype.names if len(detections) else None
        use_azimuth = bool(names and "azimuth_rad" in names)
    tracker = Tracker(settings, use_azimuth=use_azimuth)
    rows = [tracker.step(t, d) for t, d in zip(times, detections, strict=True)]
    return np.concatenate(rows) if rows else np.zeros(0, TRACK_DTYPE)


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
        er = np.zeros((n_o, n_t))
        ev = np.zeros((n_o, n_t))
        for i, t in enumerate(truth):
            r = live["range_m"]
            er[i] = np.maximum(np.maximum(t["range_nearest_m"] - r,
                                          r - t["range_centre_m"]), 0.0) / dr_cell
            ev[i] = np.abs(live["velocity_mps"] - t["v_rel_m_s"]) / dv_cell
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
