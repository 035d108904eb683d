"""The multi-target tracker on Stone Soup (clradcom.radar.tracking) on simulated
constant-velocity targets: noise, missed detections and clutter (also at the CFAR's design
false-alarm rate); confirmation and deletion; the filter's reported spread against its
actual errors; OSPA and GOSPA against hand cases and Stone Soup's own; the stationary
world's closing speeds; the scores against truth; refusals."""

from __future__ import annotations

from datetime import datetime

import numpy as np
import pytest
from stonesoup.metricgenerator.ospametric import GOSPAMetric, OSPAMetric
from stonesoup.types.state import State

from clradcom.errors import ArgumentError
from clradcom.radar.tracking import (
    Tracker,
    TrackerSettings,
    clutter_density,
    gospa,
    moving_detections,
    ospa,
    score_summary,
    score_tracks,
    stationary_speed_band,
    track_detections,
    track_metrics,
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
                                                           acceleration_psd_m2_s3=2.0),
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
    tracks = track_detections(times, dets, TrackerSettings(acceleration_psd_m2_s3=0.2,
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
    trk = Tracker(TrackerSettings(confirm_hits=3, tentative_misses=2, delete_misses=2))
    seen = [trk.step(0.00, _one(20.0, 10.0)), trk.step(0.05, _one(19.5, 10.0)),
            trk.step(0.10, EMPTY), trk.step(0.15, _one(18.5, 10.0))]
    # tentative after 1 and 2 hits and through one miss, confirmed with the 3rd hit
    assert [len(s) for s in seen] == [1, 1, 1, 1]
    assert [bool(s["confirmed"].any()) for s in seen] == [False, False, False, True]
    assert seen[2]["detection"][0] == -1 and seen[3]["detection"][0] == 0
    # two misses in a row delete a confirmed track
    assert len(trk.step(0.20, EMPTY)) == 1
    assert len(trk.step(0.25, EMPTY)) == 0
    # a lone false alarm starts a tentative track that is dropped after two misses in a
    # row (tentative_misses)
    trk = Tracker(TrackerSettings(confirm_hits=3, tentative_misses=2))
    assert len(trk.step(0.0, _one(30.0, -5.0))) == 1
    assert len(trk.step(0.05, EMPTY)) == 1
    assert len(trk.step(0.10, EMPTY)) == 0
    # a detection outside the gate starts a new track instead of updating the old one
    trk = Tracker()
    a = trk.step(0.0, _one(30.0, -5.0))
    b = trk.step(0.05, _one(40.0, 20.0))
    assert set(b["track"].tolist()) == {a["track"][0], a["track"][0] + 1}
    assert b[b["track"] == a["track"][0]]["detection"][0] == -1
    # a second echo inside a confirmed track's gate (an extended object) starts nothing
    trk = Tracker(TrackerSettings(confirm_hits=2))
    trk.step(0.0, _one(30.0, -5.0))
    assert trk.step(0.05, _one(30.25, -5.0))["confirmed"].all()
    two = np.concatenate([_one(30.5, -5.0), _one(31.0, -5.0)])
    assert len(trk.step(0.10, two)) == 1


def test_synthetic_drive_at_the_design_false_alarm_rate():
    # the paper frame, 1024 x 256 cells; CFAR false alarms at p_fa = 1e-4 per cell (26 a
    # frame, uniform over the cells) and the tracker told that rate: exactly one
    # confirmed track per target, and once all are confirmed (3 hits each; with 5 % of
    # detections missed, by frame 5) no target missed and no false track in any frame:
    # GOSPA then stays below sqrt(c^2/2), the cost of one missed or false track alone
    n_cells, p_fa, frames = (1024, 256), 1e-4, 40
    rng = np.random.default_rng(7)
    times, dets, truth = simulate(TARGETS, frames, clutter=0.0, p_detect=0.95, seed=3)
    for k in range(frames):
        n = rng.poisson(p_fa * n_cells[0] * n_cells[1])
        extra = np.zeros(n, DET)
        extra["range_m"] = rng.integers(0, n_cells[0], n) * R_CELL
        extra["velocity_mps"] = (rng.integers(0, n_cells[1], n) - n_cells[1] // 2) * V_CELL
        dets[k] = np.concatenate([dets[k], extra])
    assert np.mean([len(d) for d in dets]) > 20
    tracks = track_detections(times, dets, TrackerSettings(range_std_m=0.2,
                                                           velocity_std_mps=0.2, p_fa=p_fa),
                              use_azimuth=False, range_cell_m=R_CELL, velocity_cell_mps=V_CELL)
    confirmed = set(tracks["track"][tracks["confirmed"]].tolist())
    assert len(confirmed) == len(TARGETS)
    assert len(set(tracks["track"].tolist())) > 10 * len(confirmed)  # clutter starts many
    metrics = track_metrics(tracks, truth, R_CELL, V_CELL, cutoff_cells=3.0)
    settled = metrics[5:]
    assert (settled["confirmed_tracks"] == len(TARGETS)).all()
    assert (settled["gospa_missed"] == 0).all() and (settled["gospa_false"] == 0).all()
    assert settled["gospa_cells"].max() < np.sqrt(3.0 ** 2 / 2)
    # the same errors, smaller than the measurement noise in cells (0.2 m / 1.61 m)
    assert np.sqrt(np.mean(settled["gospa_localisation"] / len(TARGETS))) < 0.2 / R_CELL * 2
    # before any track is confirmed, GOSPA is the missed targets' cost alone
    np.testing.assert_allclose(metrics["gospa_cells"][0], np.sqrt(3 * 3.0 ** 2 / 2))
    np.testing.assert_allclose(metrics["ospa_cells"][0], 3.0)


def test_ospa_and_gospa_hand_cases():
    # one estimate 1 away from one truth, one truth missed: c = 2, p = 2
    d = np.array([[1.0, 5.0]])
    assert ospa(d, 2.0) == pytest.approx(np.sqrt((1.0 + 4.0) / 2))
    g = gospa(d, 2.0)
    assert g["distance"] == pytest.approx(np.sqrt(1.0 + 4.0 / 2))
    assert (g["localisation"], g["missed"], g["false"]) == (1.0, 2.0, 0.0)
    # a pair beyond the cut-off is one missed and one false, not a pair
    g = gospa(np.array([[3.0]]), 2.0)
    assert (g["localisation"], g["missed"], g["false"]) == (0.0, 2.0, 2.0)
    assert ospa(np.array([[3.0]]), 2.0) == pytest.approx(2.0)
    # the optimal assignment, not the greedy one
    d = np.array([[1.0, 1.5], [1.5, 10.0]])
    assert ospa(d, 20.0, p=1) == pytest.approx((1.5 + 1.5) / 2)
    assert ospa(np.zeros((0, 0)), 1.0) == 0.0 and gospa(np.zeros((0, 3)), 1.0)["missed"] == 1.5
    with pytest.raises(ArgumentError, match="distances"):
        ospa(np.array([[-1.0]]), 1.0)
    with pytest.raises(ArgumentError, match="'c'|c"):
        gospa(np.ones((1, 1)), 0.0)


def test_ospa_and_gospa_agree_with_stone_soup():
    rng = np.random.default_rng(2)
    c, p = 4.0, 2.0
    stamp = datetime(2000, 1, 1)
    for trial in range(20):
        x = rng.uniform(0, 10, (rng.integers(0, 6), 2))
        y = rng.uniform(0, 10, (rng.integers(1, 6), 2))
        d = np.linalg.norm(x[:, None, :] - y[None, :, :], axis=2)
        sx = [State(v.reshape(2, 1), timestamp=stamp) for v in x]
        sy = [State(v.reshape(2, 1), timestamp=stamp) for v in y]
        theirs = OSPAMetric(c=c, p=p).compute_OSPA_distance(sx, sy).value
        assert ospa(d, c, p) == pytest.approx(theirs, abs=1e-9), trial
        g, _ = GOSPAMetric(c=c, p=p).compute_gospa_metric(sx, sy)
        mine = gospa(d, c, p)
        for key in ("distance", "localisation", "missed", "false"):
            assert mine[key] == pytest.approx(g.value[key], abs=1e-9), (trial, key)


def test_stationary_world_band_and_moving_detections():
    # a radar moving at 12.9 m/s along its boresight, beam +-45 deg in azimuth in the
    # horizontal plane: a stationary scatterer closes at 12.9 cos(az), 9.12 .. 12.9 m/s
    az = np.radians(np.linspace(-45, 45, 91))
    beam = np.stack([np.cos(az), np.sin(az), np.zeros_like(az)], axis=1)
    lo, hi = stationary_speed_band([12.9, 0.0, 0.0], beam)
    assert lo[0] == pytest.approx(12.9 * np.cos(np.radians(45))) and hi[0] == pytest.approx(12.9)
    det = np.zeros(5, DET)
    det["range_m"] = [0.5, 8.0, 24.0, 20.0, 30.0]
    det["velocity_mps"] = [0.0, 11.0, 0.0, 26.0, 8.5]
    keep = moving_detections(det, lo, hi, speed_margin_mps=0.5, min_range_m=1.0)
    # the mounting return (0.5 m), the stationary return closing at 11 m/s out; the car at
    # the radar's speed (0 m/s), the oncoming car and the one just outside the band in
    assert keep.tolist() == [False, False, True, True, True]
    # per detection: where only directions near 40 deg are allowed, 11 m/s is not
    # stationary there (12.9 cos 40 = 9.9)
    allowed = np.abs(np.degrees(az) - 40.0)[None, :] <= 1.0
    lo2, hi2 = stationary_speed_band([12.9, 0.0, 0.0], beam, np.repeat(allowed, 5, axis=0))
    assert hi2[0] == pytest.approx(12.9 * np.cos(np.radians(39)))
    assert moving_detections(det, lo2, hi2, speed_margin_mps=0.5)[1]
    # a detection allowed no direction is moving
    lo3, hi3 = stationary_speed_band([12.9, 0, 0], beam, np.zeros((5, len(az)), bool))
    assert moving_detections(det, lo3, hi3, speed_margin_mps=0.5).all()
    # the clutter density of the CFAR: p_fa per cell
    assert clutter_density(1e-6, 1.61, 1.97) == pytest.approx(1e-6 / (1.61 * 1.97))
    assert clutter_density(1e-6, 2.0, 1.0, np.pi) == pytest.approx(0.5e-6 / np.pi)


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
    ({"confirm_hits": 0}, "TrackerSettings.confirm_hits"),
    ({"tentative_misses": 1.5}, "TrackerSettings.tentative_misses"),
    ({"prob_detect": 1.0}, "TrackerSettings.prob_detect"),
    ({"p_fa": 0.0}, "TrackerSettings.p_fa"),
    ({"range_std_m": -1.0}, "TrackerSettings.range_std_m"),
    ({"velocity_std_mps": float("nan")}, "TrackerSettings.velocity_std_mps"),
    ({"gate_probability": 1.0}, "TrackerSettings.gate_probability"),
    ({"delete_misses": 0}, "TrackerSettings.delete_misses"),
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
