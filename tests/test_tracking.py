"""The multi-target tracker (clradcom.radar.tracking) on simulated constant-velocity
targets: noise, missed detections and clutter; confirmation and deletion; the filter's
reported spread against its actual errors; the scores against truth; refusals."""

from __future__ import annotations

import numpy as np
import pytest

from clradcom.errors import ArgumentError
from clradcom.radar.tracking import (
    Tracker,
    TrackerSettings,
    score_summary,
    score_tracks,
    track_detections,
)

DET = np.dtype([("range_m", float), ("velocity_mps", float), ("azimuth_rad", float),
                ("power_db", float)])
DT = 0.05
R_CELL, V_CELL = 1.61, 1.97  # the paper frame's cells


def truth_at(targets, t):
    """(range, closing velocity, azimuth) of constant-velocity targets at t."""
    return [(r0 - v * t, v, az0 + w * t) for r0, v, az0, w in targets]


def simulate(targets, frames, *, p_detect=0.9, clutter=5.0, sigma=(0.2, 0.2, 0.005),
             seed=1):
    rng = np.random.default_rng(seed)
    times = np.arange(frames) * DT
    dets, truth = [], []
    for t in times:
        rows, tr = [], []
        for i, (r, v, az) in enumerate(truth_at(targets, t)):
            tr.append({"name": f"T{i}", "range_nearest_m": r, "range_centre_m": r,
                       "v_rel_m_s": v, "azimuth_deg": np.degrees(az), "time_s": t})
            if rng.random() < p_detect:
                rows.append((r + sigma[0] * rng.standard_normal(),
                             v + sigma[1] * rng.standard_normal(),
                             az + sigma[2] * rng.standard_normal(), 0.0))
        for _ in range(rng.poisson(clutter)):
            rows.append((rng.uniform(0, 60), rng.uniform(-30, 30), rng.uniform(-0.8, 0.8),
                         0.0))
        order = rng.permutation(len(rows))
        dets.append(np.array(rows, DET)[order])
        truth.append(tr)
    return times, dets, truth


# two targets cross in range (at 20 m, t = 1 s) with different range rates, a third
# closes in; over 40 frames (2 s) all stay ahead (range > 10 m)
TARGETS = [(30.0, 10.0, 0.1, 0.0), (10.0, -10.0, -0.2, 0.0), (40.0, 12.0, 0.3, -0.2)]


def test_tracks_follow_crossing_targets_through_clutter_without_swaps():
    times, dets, truth = simulate(TARGETS, 40)
    tracks = track_detections(times, dets, TrackerSettings(range_std_m=0.2,
                                                           velocity_std_mps=0.2,
                                                           acceleration_std_mps2=2.0),
                              use_azimuth=False)
    scores = score_tracks(tracks, truth, R_CELL, V_CELL)
    summary = score_summary(scores)
    for s in summary:
        assert s["visible"] == 40
        assert len(s["tracks"]) == 1, s  # one track from start to end: no swap, no break
        assert s["all_within"], s
    # the errors, computed here from the closed-form trajectories, are a fraction of the
    # measurement noise (the filter averages); score_tracks reports the same numbers
    for s in summary:
        tid = s["tracks"][0]
        mine = tracks[tracks["track"] == tid]
        k = mine["frame"]
        r_true = np.array([truth_at(TARGETS, times[f])[int(s["object"][1])][0] for f in k])
        v_true = TARGETS[int(s["object"][1])][1]
        err_r = mine["range_m"] - r_true
        assert np.sqrt(np.mean(err_r[5:] ** 2)) < 0.2
        assert np.sqrt(np.mean((mine["velocity_mps"][5:] - v_true) ** 2)) < 0.2
        sc = scores[scores["object"] == s["object"]]
        np.testing.assert_allclose(sc["range_error_cells"], np.abs(err_r) / R_CELL,
                                   atol=1e-12)
    # clutter starts tracks too, but they are rarely confirmed: far fewer confirmed tracks
    # than clutter detections
    confirmed = set(tracks["track"][tracks["confirmed"]].tolist())
    assert len(confirmed) < 10
    assert len(set(tracks["track"].tolist())) > 3 * len(confirmed)


def test_azimuth_is_tracked_for_an_array_radar():
    times, dets, truth = simulate(TARGETS, 30, clutter=2.0)
    tracks = track_detections(times, dets)  # azimuth_rad present: tracked
    for i, (_, _, az0, w) in enumerate(TARGETS):
        s = score_tracks(tracks, truth, R_CELL, V_CELL)
        tid = s[(s["object"] == f"T{i}") & (s["track"] >= 0)]["track"]
        assert len(set(tid.tolist())) == 1
        mine = tracks[tracks["track"] == tid[0]]
        az_true = np.degrees(az0 + w * mine["time_s"])
        # below the measurement noise (0.005 rad = 0.29 deg) once settled
        assert np.sqrt(np.mean((mine["azimuth_deg"][5:] - az_true[5:]) ** 2)) < 0.29


def test_reported_spread_matches_the_actual_errors():
    # one target, no clutter, 400 frames: the filter's own range sigma is its RMS error
    # (a consistent filter), and both lie below the measurement noise
    target = [(50.0, 5.0, 0.0, 0.0)]
    times, dets, truth = simulate(target, 400, p_detect=1.0, clutter=0.0,
                                  sigma=(0.5, 0.5, 0.0), seed=4)
    tracks = track_detections(times, dets, TrackerSettings(acceleration_std_mps2=0.5,
                                                           gate_probability=1 - 1e-9),
                              use_azimuth=False)
    assert len(set(tracks["track"].tolist())) == 1
    err = tracks["range_m"] - (50.0 - 5.0 * tracks["time_s"])
    rms, sd = np.sqrt(np.mean(err[50:] ** 2)), np.mean(tracks["range_std_m"][50:])
    assert 0.7 < rms / sd < 1.4
    assert rms < 0.5 / 2


def _one(r, v):
    return np.array([(r, v, 0.0, 0.0)], DET)


EMPTY = np.zeros(0, DET)


def test_confirmation_m_of_n_and_deletion():
    trk = Tracker(TrackerSettings(confirm_hits=3, confirm_window=4, delete_misses=2))
    seen = [trk.step(0.00, _one(20.0, 10.0)), trk.step(0.05, _one(19.5, 10.0)),
            trk.step(0.10, EMPTY), trk.step(0.15, _one(18.5, 10.0))]
    # tentative after 1 and 2 hits, confirmed with the 3rd hit in 4 frames
    assert [bool(s["confirmed"].any()) for s in seen] == [False, False, False, True]
    assert seen[2]["detection"][0] == -1 and seen[3]["detection"][0] == 0
    # two misses in a row delete a confirmed track
    assert len(trk.step(0.20, EMPTY)) == 1
    assert len(trk.step(0.25, EMPTY)) == 0
    # a lone false alarm starts a tentative track that is dropped once it can no longer
    # reach 3 hits in its first 4 frames (after its second miss)
    trk = Tracker(TrackerSettings(confirm_hits=3, confirm_window=4))
    assert len(trk.step(0.0, _one(30.0, -5.0))) == 1
    assert len(trk.step(0.05, EMPTY)) == 1
    assert len(trk.step(0.10, EMPTY)) == 0
    # a detection outside the gate starts a new track instead of updating the old one
    trk = Tracker()
    a = trk.step(0.0, _one(30.0, -5.0))
    b = trk.step(0.05, _one(40.0, 20.0))
    assert set(b["track"].tolist()) == {a["track"][0], a["track"][0] + 1}
    assert b[b["track"] == a["track"][0]]["detection"][0] == -1


def test_scores_count_only_confirmed_tracks_and_visible_frames():
    times, dets, truth = simulate(TARGETS[:1], 6, p_detect=1.0, clutter=0.0)
    tracks = track_detections(times, dets, use_azimuth=False)
    for k in range(6):
        truth[k][0]["visible"] = k < 4
    online = score_tracks(tracks, truth, R_CELL, V_CELL, retroactive=False)
    batch = score_tracks(tracks, truth, R_CELL, V_CELL)
    # confirmed at its 3rd frame: online from frame 2, in a batch evaluation from frame 0
    assert online["track"].tolist() == [-1, -1, 0, 0, 0, 0]
    assert batch["track"].tolist() == [0] * 6
    s_online, s_batch = score_summary(online)[0], score_summary(batch)[0]
    assert (s_online["visible"], s_online["within"], s_online["all_within"]) == (4, 2, False)
    assert (s_batch["visible"], s_batch["within"], s_batch["all_within"]) == (4, 4, True)
    # a track more than gate_cells away is no track of the object
    far = [[dict(t[0], range_nearest_m=t[0]["range_nearest_m"] + 10 * R_CELL,
                 range_centre_m=t[0]["range_centre_m"] + 10 * R_CELL)] for t in truth]
    assert (score_tracks(tracks, far, R_CELL, V_CELL)["track"] == -1).all()


@pytest.mark.parametrize("change, field", [
    ({"confirm_hits": 5, "confirm_window": 4}, "TrackerSettings.confirm_hits"),
    ({"range_std_m": -1.0}, "TrackerSettings.range_std_m"),
    ({"velocity_std_mps": float("nan")}, "TrackerSettings.velocity_std_mps"),
    ({"gate_probability": 1.0}, "TrackerSettings.gate_probability"),
    ({"delete_misses": 0}, "TrackerSettings.delete_misses"),
    ({"confirm_window": 2.5}, "TrackerSettings.confirm_window"),
])
def test_bad_settings_are_refused_by_name(change, field):
    with pytest.raises(ArgumentError, match=field.replace(".", r"\.")):
        TrackerSettings(**change)


def test_bad_frames_are_refused():
    trk = Tracker()
    trk.step(1.0, _one(20.0, 1.0))
    with pytest.raises(ArgumentError, match="time_s"):
        trk.step(1.0, _one(20.0, 1.0))
    with pytest.raises(ArgumentError, match="range_m"):
        trk.step(2.0, np.zeros(1, [("velocity_mps", float)]))
    with pytest.raises(ArgumentError, match="azimuth_rad"):
        Tracker(use_azimuth=True).step(0.0, np.zeros(1, [("range_m", float),
                                                         ("velocity_mps", float)]))
    with pytest.raises(ArgumentError, match="non-finite"):
        trk.step(2.0, _one(float("nan"), 1.0))
    with pytest.raises(ArgumentError, match="one array of detections per time"):
        track_detections([0.0, 0.1], [EMPTY])
    with pytest.raises(ArgumentError, match="range_cell_m"):
        score_tracks(np.zeros(0), [], 0.0, 1.0)
    with pytest.raises(ArgumentError, match="settings"):
        Tracker(settings={"range_std_m": 1.0})
