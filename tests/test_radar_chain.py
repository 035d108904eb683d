"""One radar chain for every tool (issue 27 item 5).

``clradcom trace`` and ``clradcom radar`` (their radar stage), ``clradcom drive`` (a
single-antenna radar's frame) and ``clradcom interference`` (A's image without D) run
:func:`clradcom.radar.pipeline.radar_chain` on a radar's own echoes: the same paths, seed
and noise give the same detections and SNRs in each, to the last bit. The interference
tool used to run its own CFAR on the 2 x 2 zero-padded image (guard 3 x 2, training 8 x 4
padded cells, no numerical floor, no refinement): there the training band of a strong echo
reaches into its own window main lobe (the 0.5 m ground return's SNR came out 20 dB low),
and the oversampled noise raised the false-alarm rate about tenfold (detections at 669 m
on a street whose longest path is 114 m). Detections farther than the longest path are
noise and are left out; a path beyond the unambiguous range shows folded and is marked.
"""

from __future__ import annotations

import csv
import types
import warnings

import numpy as np
import pytest

from clradcom.commands.trace import Stopwatch, radar_stage
from clradcom.errors import PhysicsWarning
from clradcom.radar import DETECTION_DTYPE, Waveform
from clradcom.radar.interference import INTERFERENCE_STAGES, two_radar_run
from clradcom.radar.pipeline import (
    ECHO_MARGIN_CELLS,
    radar_chain,
    sort_detections,
)
from clradcom.radar.report import detection_rows, interference_detections
from clradcom.radar.video import radar_step
from clradcom.radar.waveform import SPEED_OF_LIGHT
from clradcom.scene.reader import scene_from_dict
from clradcom.snapshot import Link
from tests.dsp_helpers import los_paths

N, M = 256, 64
WF = Waveform(n_subcarriers=N, n_symbols=M)
P_TX, NF = 0.01, 10.0
SEED = 5
# A's own echoes: the road under the bumper (0.5 m), two cars (outside the road return's
# CFAR training band: 6.4 m range and 7.9 m/s velocity cells), a wall at 150 m
RANGES = np.array([0.5, 62.0, 95.0, 150.0])
SPEEDS = np.array([0.0, -30.0, 25.0, 10.0])
OWN = los_paths(np.array([10 ** (-60 / 20), 10 ** (-95 / 20) * 1j, 10 ** (-100 / 20),
                          10 ** (-103 / 20) * np.exp(2j)]),
                2 * RANGES / SPEED_OF_LIGHT, WF.velocity_to_doppler(SPEEDS))
# D -> A: line of sight and a reflection
D_TO_A = los_paths(np.array([10 ** (-90 / 20), 10 ** (-98 / 20) * np.exp(2.1j)]),
                   np.array([108.9e-9, 190.0e-9]), np.array([2180.0, 1620.0]))


def _scene():
    return scene_from_dict({
        "scene": {"name": "chain", "carrier_hz": WF.carrier_hz},
        "objects": [{"name": "ground", "material": "metal", "shape": "plane",
                     "size": [10.0, 10.0], "position": [0.0, 0.0, 0.0]}],
        "radars": [{"name": "A", "role": "txrx", "position": [0.0, 0.0, 0.5],
                    "tx_power_w": P_TX, "noise_figure_db": NF}]}, base_dir=".")


def _same(a, b):
    for name in ("range_m", "velocity_mps", "power_db", "snr_db"):
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_trace_radar_drive_and_interference_give_the_same_detections(tmp_path, capsys):
    chain = radar_chain(OWN, WF, seed=SEED, tx_power_w=P_TX, noise_figure_db=NF)
    dets = chain.detections
    # the chain finds the echoes, and nothing beyond the wall
    for r, v in zip(RANGES, SPEEDS, strict=True):
        near = (np.abs(dets["range_m"] - r) < WF.range_resolution) & \
               (np.abs(dets["velocity_mps"] - v) < WF.velocity_resolution)
        assert near.any(), (r, v)
    assert np.all(dets["range_m"] <= RANGES.max() + ECHO_MARGIN_CELLS * WF.range_resolution)
    assert not chain.aliased.any()

    # clradcom trace / clradcom radar: their radar stage's table
    scene = _scene()
    radar = scene.radars[0]
    args = types.SimpleNamespace(seed=SEED, synthesis="fast")
    radar_stage(Stopwatch(), args, scene, WF, Link("A", "A", 0, 0, OWN), radar, NF, tmp_path)
    with open(tmp_path / "A_detections.csv") as fh:
        rows = [tuple(r.values()) for r in csv.DictReader(fh)]
    assert rows == detection_rows(dets, chain.aliased)
    assert f"A: {len(dets)} detections" in capsys.readouterr().out

    # clradcom drive: one frame of a single-antenna radar (its frame k has seed + 2k)
    _, drive = radar_step(OWN, radar, WF, seed=SEED, noise_figure_db=NF)
    _same(drive, dets)

    # clradcom interference: A's image without D; every stage announced, in order
    heard: list[str] = []
    details: list[str] = []
    res = two_radar_run(OWN, D_TO_A, WF, tx_power_w=P_TX, interferer_tx_power_w=P_TX,
                        noise_figure_db=NF, timing_offset_s=5e-6, cfo_hz=3000.0, seed=SEED,
                        progress=heard.append, detail=details.append)
    assert len(heard) == len(INTERFERENCE_STAGES)
    assert all(m.startswith(s) for m, s in zip(heard, INTERFERENCE_STAGES, strict=True))
    # inside D's estimation (the longest stage) the steps and each fitted component
    steps = [d for d in details if "components" not in d]
    assert steps[0] == "fitting A's strong own echoes"
    assert steps[-2:] == ["synchronising to D's cyclic prefixes",
                          "D's channel from its symbols alone (power law)"]
    assert "A's own echoes: 1 of at most 32 components" in details
    assert details[-1].startswith("D's channel, round 2 of 2: ")
    found = interference_detections(res)
    _same(found["clean"], dets)
    _same(found["genie"], dets)
    # the mounting return's SNR is one number in every tool
    ground = np.argmin(np.abs(dets["range_m"] - 0.5))
    assert found["clean"]["snr_db"][ground] == dets["snr_db"][ground]
    # D's interference is there in the image with D: its floor rises by the INR (~10 dB)
    assert res.floors["interfered"] > 3 * res.floors["clean"]


def test_detections_beyond_the_longest_path_are_left_out_and_folded_ones_marked():
    wf = WF
    det = np.zeros(4, DETECTION_DTYPE)
    det["range_m"] = [30.0, 40.0 + 2 * wf.range_resolution, 300.0, 120.0]
    det["velocity_mps"] = [-20.0, 0.0, 5.0, 60.0]
    # paths: a car at 30 m, a wall at 40 m, and one beyond r_max that folds to 120 m
    far = wf.max_range + 120.0
    paths = los_paths(np.ones(3), 2 * np.array([30.0, 40.0, far]) / SPEED_OF_LIGHT,
                      wf.velocity_to_doppler(np.array([-20.0, 0.0, 60.0])))
    kept, aliased, beyond = sort_detections(det, paths, wf)
    # nothing explains 300 m, yet it is not beyond the longest path (r_max + 120 m): kept
    assert list(kept["range_m"]) == list(det["range_m"])
    assert list(aliased) == [False, False, False, True]
    assert len(beyond) == 0
    # without the folding path the longest is 40 m: 300 m and 120 m are noise, left out
    near = los_paths(np.ones(2), 2 * np.array([30.0, 40.0]) / SPEED_OF_LIGHT,
                     wf.velocity_to_doppler(np.array([-20.0, 0.0])))
    kept, aliased, beyond = sort_detections(det, near, wf)
    assert list(beyond["range_m"]) == [300.0, 120.0]
    assert list(kept["range_m"]) == [30.0, 40.0 + 2 * wf.range_resolution]
    assert not aliased.any()
    # within ECHO_MARGIN_CELLS of the longest path a detection stays (window, refinement)
    edge = det[:1].copy()
    edge["range_m"] = 40.0 + (ECHO_MARGIN_CELLS - 0.1) * wf.range_resolution
    assert len(sort_detections(edge, near, wf)[0]) == 1


def test_a_path_beyond_the_unambiguous_range_is_detected_folded_and_marked():
    far = WF.max_range + 80.0
    paths = los_paths(np.array([10 ** (-60 / 20), 10 ** (-70 / 20)]),
                      2 * np.array([12.0, far]) / SPEED_OF_LIGHT,
                      WF.velocity_to_doppler(np.array([0.0, 40.0])))
    with warnings.catch_warnings():  # beyond r_max and the cyclic prefix, as intended
        warnings.simplefilter("ignore", PhysicsWarning)
        chain = radar_chain(paths, WF, seed=1)
    d = chain.detections
    at = np.flatnonzero((np.abs(d["range_m"] - 80.0) < WF.range_resolution)
                        & (np.abs(d["velocity_mps"] - 40.0) < WF.velocity_resolution))
    assert len(at) == 1 and chain.aliased[at[0]]
    assert chain.aliased.sum() == 1
    assert chain.longest_range_m == pytest.approx(far)


def _echo_paths(ranges, speeds, gains, azimuth_deg, origin):
    """Monostatic echoes off points at the given ranges and azimuths (one interaction
    each), for the array radar's plane-wave channels."""
    p = len(ranges)
    az = np.radians(np.asarray(azimuth_deg, float))
    pts = np.repeat(np.asarray(origin, float)[None, None, :], 3, axis=1).repeat(p, axis=0)
    pts[:, 1] = origin + np.asarray(ranges)[:, None] * np.stack(
        [np.cos(az), np.sin(az), np.zeros(p)], axis=1)
    paths = los_paths(gains, 2 * np.asarray(ranges) / SPEED_OF_LIGHT,
                      WF.velocity_to_doppler(np.asarray(speeds)))
    return type(paths)(gain=paths.gain, matrix=np.broadcast_to(np.eye(2), (p, 2, 2)) + 0j,
                       delay_s=paths.delay_s, doppler_hz=paths.doppler_hz,
                       n_interactions=np.ones(p, np.int16),
                       interaction=np.ones((p, 1), np.int8), points=pts,
                       object_id=np.zeros((p, 1), np.int32), face_id=np.zeros((p, 1), np.int32))


def test_an_array_radar_gets_the_same_cube_in_trace_cube_and_drive(tmp_path):
    scene = scene_from_dict({
        "scene": {"name": "chain", "carrier_hz": WF.carrier_hz},
        "objects": [{"name": "ground", "material": "metal", "shape": "plane",
                     "size": [10.0, 10.0], "position": [0.0, 0.0, 0.0]}],
        "radars": [{"name": "A", "role": "txrx", "position": [0.0, 0.0, 0.5],
                    "tx_power_w": P_TX, "noise_figure_db": NF,
                    "tx_array": {"kind": "ula", "count": 2, "spacing_wavelengths": 2.0},
                    "rx_array": {"kind": "ula", "count": 2, "spacing_wavelengths": 0.5}}]},
        base_dir=".")
    radar = scene.radars[0]
    paths = _echo_paths([30.0, 62.0], [-20.0, 15.0], [10 ** (-95 / 20), 10 ** (-100 / 20)],
                        [10.0, -20.0], radar.position)
    ml = radar_chain(paths, WF, radar=radar, seed=SEED, tx_power_w=P_TX, noise_figure_db=NF)
    assert ml.array is not None and len(ml.detections) >= 2
    # clradcom cube's detections and point cloud are the chain's
    assert len(ml.array.points) == len(ml.detections)
    # clradcom trace / radar on the same radar: the cube, not a single antenna
    radar_stage(Stopwatch(), types.SimpleNamespace(seed=SEED, synthesis="fast"), scene, WF,
                Link("A", "A", 0, 0, paths), radar, NF, tmp_path)
    with open(tmp_path / "A_detections.csv") as fh:
        rows = [tuple(r.values()) for r in csv.DictReader(fh)]
    assert rows == detection_rows(ml.detections, ml.aliased)
    # clradcom drive: the same cube with the parabola estimates (cube --refine parabola)
    parabola = radar_chain(paths, WF, radar=radar, seed=SEED, tx_power_w=P_TX,
                           noise_figure_db=NF, refine="parabola")
    _, drive = radar_step(paths, radar, WF, seed=SEED, noise_figure_db=NF)
    _same(drive, parabola.detections)
