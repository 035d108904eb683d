"""Antenna arrays: the scene file's array tables, and the per-element channel of the
synthetic array against the exact path-length correction (and against plain geometry)."""

from __future__ import annotations

import numpy as np
import pytest

from clradcom.errors import SceneError
from clradcom.paths import InteractionType, Paths
from clradcom.radar.array import (
    element_positions,
    exact_channels,
    path_angles,
    synthetic_channels,
)
from clradcom.radar.waveform import SPEED_OF_LIGHT
from clradcom.scene.materials import C0
from clradcom.scene.reader import scene_from_dict

LAM = C0 / 24e9


def scene_with(**radar_keys):
    radar = {"name": "r", "position": [1.0, 2.0, 0.5], "orientation_deg": [0, 0, 90]}
    radar.update(radar_keys)
    return scene_from_dict({"scene": {"carrier_hz": 24e9}, "radars": [radar]},
                           file="s.toml")


# -- scene file -------------------------------------------------------------------------------


def test_ula_upa_positions_parse_in_the_radar_frame():
    s = scene_with(tx_array={"kind": "ula", "count": 3, "spacing_m": 0.01},
                   rx_array={"kind": "upa", "counts": [2, 3], "spacing_wavelengths": [0.5, 1]})
    r = s.radars[0]
    np.testing.assert_allclose(r.tx_array.positions_local,
                               [[0, -0.01, 0], [0, 0, 0], [0, 0.01, 0]], atol=1e-15)
    rx = r.rx_array.positions_local
    assert rx.shape == (6, 3)
    np.testing.assert_allclose(np.unique(rx[:, 1]), [-LAM / 4, LAM / 4])
    np.testing.assert_allclose(np.unique(rx[:, 2]), [-LAM, 0, LAM])
    # yaw 90°: local +y is world -x; the elements lie along world x about the radar
    world = element_positions(r.position, r.orientation, r.tx_array.positions_local)
    np.testing.assert_allclose(world, [[1.01, 2, 0.5], [1, 2, 0.5], [0.99, 2, 0.5]],
                               atol=1e-12)


def test_shared_array_and_explicit_positions():
    s = scene_with(array={"kind": "positions", "positions_wavelengths": [[0, 0, 0], [0, 2, 1]]})
    r = s.radars[0]
    assert r.tx_array is r.rx_array
    np.testing.assert_allclose(r.rx_array.positions_local, [[0, 0, 0], [0, 2 * LAM, LAM]])


def test_hash_counts_the_array_only_when_given():
    plain = scene_with().content_hash()
    assert scene_with().content_hash() == plain
    a = scene_with(rx_array={"kind": "ula", "count": 4, "spacing_wavelengths": 0.5})
    b = scene_with(rx_array={"kind": "ula", "count": 4, "spacing_wavelengths": 0.6})
    assert len({plain, a.content_hash(), b.content_hash()}) == 3


@pytest.mark.parametrize("keys, key, fragment", [
    ({"array": {"kind": "ula", "count": 2, "spacing_m": 0.01},
      "rx_array": {"kind": "ula", "count": 2, "spacing_m": 0.01}},
     "radars[0].rx_array", "not both"),
    ({"tx_array": {"kind": "circle"}}, "radars[0].tx_array.kind", "must be one of"),
    ({"tx_array": {"kind": "ula", "count": 0, "spacing_m": 0.01}},
     "radars[0].tx_array.count", "whole number"),
    ({"tx_array": {"kind": "ula", "count": 2, "spacing_m": 0.01, "spacing_wavelengths": 1}},
     "radars[0].tx_array.spacing_wavelengths", "exactly one"),
    ({"tx_array": {"kind": "ula", "count": 2, "spacing_m": -0.01}},
     "radars[0].tx_array.spacing_m", "> 0"),
    ({"tx_array": {"kind": "ula", "count": 2, "spacing_m": 0.01, "axis": [0, 0, 0]}},
     "radars[0].tx_array.axis", "zero vector"),
    ({"tx_array": {"kind": "ula", "count": 2, "spacing_m": 0.01, "counts": [2, 2]}},
     "radars[0].tx_array.counts", "not a key of kind"),
    ({"tx_array": {"kind": "upa", "counts": [2, 2], "spacing_m": 0.01,
                   "axes": [[0, 1, 0], [0, 1, 1]]}},
     "radars[0].tx_array.axes", "perpendicular"),
    ({"rx_array": {"kind": "positions", "positions_m": [[0, 0, 0], [0, 0, 0]]}},
     "radars[0].rx_array.positions_m", "repeats"),
    ({"rx_array": {"kind": "positions", "positions_m": [[0, 0, 0], [0, float("nan"), 0]]}},
     "radars[0].rx_array.positions_m", "NaN"),
    ({"rx_array": {"kind": "ula", "count": 4, "spacing_m": 100.0}},
     "radars[0].rx_array", "at most"),
    ({"rx_array": [1, 2]}, "radars[0].rx_array", "expected a table"),
    ({"rx_array": {"kind": "ula", "count": 3, "spacing_m": 0.1, "axes": 1}},
     "radars[0].rx_array.axes", "not a key of kind"),
    ({"rx_array": {"kind": "ula", "count": 3, "spacing_m": 0.1, "axs": 1}},
     "radars[0].rx_array.axs", "did you mean 'axis'"),
])
def test_bad_arrays_are_refused_naming_file_key_and_value(keys, key, fragment):
    with pytest.raises(SceneError) as ei:
        scene_with(**keys)
    msg = str(ei.value)
    assert ei.value.key == key and "s.toml" in msg and fragment in msg


# -- synthetic against exact ------------------------------------------------------------------


def point_paths(target, radar=(0.0, 0.0, 0.0), gain=1.0):
    """A monostatic return from one point (a scattering tile's centre)."""
    t, r = np.asarray(target, float), np.asarray(radar, float)
    length = 2 * np.linalg.norm(t - r)
    return Paths(gain=[gain], matrix=np.eye(2)[None] * 1.0, delay_s=[length / SPEED_OF_LIGHT],
                 doppler_hz=[0.0], n_interactions=[1],
                 interaction=[[InteractionType.SCATTERING]], points=[[r, t, r]],
                 object_id=[[0]], face_id=[[0]])


def ula(n, spacing, axis=(0.0, 1.0, 0.0)):
    return np.outer((np.arange(n) - (n - 1) / 2) * spacing, axis)


@pytest.mark.parametrize("distance, agree", [(1000.0, True), (0.5, False)])
def test_synthetic_array_matches_the_exact_one_in_the_far_field_only(distance, agree):
    az, el = np.radians(30.0), np.radians(10.0)
    target = distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    paths = point_paths(target)
    tx, rx = ula(2, 4 * LAM), ula(8, LAM / 2)
    syn = synthetic_channels(paths, tx, rx, LAM)
    ex, ex_delay = exact_channels(paths, tx, rx, LAM)
    # the exact form against plain geometry: |T - p_i| + |T - q_j|
    geo = (np.linalg.norm(target - tx, axis=1)[:, None]
           + np.linalg.norm(target - rx, axis=1)[None, :])
    np.testing.assert_allclose(ex_delay[:, :, 0] * SPEED_OF_LIGHT, geo, rtol=0, atol=1e-9)
    # phase -k·(length) up to the reference path's own phase
    rel = ex[:, :, 0] * np.exp(2j * np.pi * geo / LAM)
    np.testing.assert_allclose(np.angle(rel / rel[0, 0]), 0, atol=1e-6)
    err = np.max(np.abs(np.angle(syn / ex)))
    if agree:
        assert err < 1e-3  # far field: D²/(λR) ~ 1e-4
    else:
        assert err > 0.1  # near field: the plane wave is wrong by more than 6°


def test_line_of_sight_between_two_arrays_is_exact():
    a, b = np.array([0.0, 0, 0]), np.array([3.0, 0.4, 0.2])
    length = np.linalg.norm(b - a)
    paths = Paths(gain=[1.0], matrix=np.eye(2)[None] * 1.0, delay_s=[length / C0],
                  doppler_hz=[0.0], n_interactions=[0], interaction=np.zeros((1, 0)),
                  points=[[a, b]], object_id=np.zeros((1, 0)), face_id=np.zeros((1, 0)))
    tx, rx = ula(3, LAM, (0, 0, 1.0)), ula(4, LAM / 2)
    _, delay = exact_channels(paths, tx, rx, LAM)
    geo = np.linalg.norm((b + rx)[None, :, :] - (a + tx)[:, None, :], axis=2)
    np.testing.assert_allclose(delay[:, :, 0] * C0, geo, atol=1e-9)
    ang = path_angles(paths, np.eye(3), np.eye(3))
    assert ang["departure_azimuth"][0] == pytest.approx(np.arctan2(0.4, 3.0))
    assert ang["arrival_azimuth"][0] == pytest.approx(np.arctan2(-0.4, -3.0))
