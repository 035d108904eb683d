"""Per-element patterns and polarisation of an array (issue #17, item 1: "element pattern
and polarisation shared or per element"): read from the array table, applied through the
paths' polarimetric matrices in the synthetic and corrected channels and by the tracer
itself in the exact one: an element with a null toward the target gets nothing from it,
a cross-polarised element loses the co-polarised return of a plate."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from clradcom.device.runtime import get_runtime
from clradcom.errors import SceneError
from clradcom.radar import Waveform
from clradcom.radar.array import element_gains
from clradcom.radar.array_frame import element_channels
from clradcom.radar.element_trace import element_pair_paths, trace_elements
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import TraceSettings, trace_scene

SETTINGS = TraceSettings.preset("go").replace(specular__rays=60_000,
                                              specular__max_reflections=1,
                                              diffraction__max_diffractions=0)
WF = Waveform()


def scene(rx_array, azimuth_deg=0.0, radar_extra=None, h=10.0):
    """A 2 m PEC plate h metres away at ``azimuth_deg``, facing the radar at the origin."""
    a = np.radians(azimuth_deg)
    radar = {"name": "A", "position": [0.0, 0.0, 0.0],
             "tx_array": {"kind": "ula", "count": 2, "spacing_wavelengths": 2.0},
             "rx_array": rx_array}
    radar.update(radar_extra or {})
    return scene_from_dict({
        "scene": {"carrier_hz": 24e9, "name": "plate"},
        "objects": [{"name": "plate", "material": "metal", "shape": "plane",
                     "size": [2.0, 2.0], "position": [h * np.cos(a), h * np.sin(a), 0.0],
                     "rotation_deg": [0.0, -90.0, azimuth_deg]}],
        "radars": [radar]}, file="p.toml")


def ula4(**extra):
    return {"kind": "ula", "count": 4, "spacing_wavelengths": 0.5, **extra}


@pytest.fixture(scope="module")
def runtime():
    return get_runtime(None)


def traced(sc, runtime):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = trace_scene(sc, SETTINGS, runtime=runtime, links=[(0, 0)]).links[0].paths
        pairs = element_pair_paths(trace_elements(sc, 0, SETTINGS, runtime=runtime),
                                   sc.radars[0])
    return ref, pairs


def pair_power(pairs):
    return np.array([[np.sum(np.abs(p.gain) ** 2) for p in row] for row in pairs])


# -- the scene file ---------------------------------------------------------------------


def test_patterns_fall_back_element_array_radar():
    sc = scene(ula4(polarization="H", elements=[
        {}, {"pattern": {"type": "sector", "azimuth_width_deg": 20}},
        {"polarization": "V"}, {"pattern": "isotropic"}]),
        radar_extra={"pattern": "sector", "polarization": "V"})
    r = sc.radars[0]
    assert r.tx_array.patterns is None  # the transmitters share the radar's
    kinds = [p.kind for p in r.rx_array.patterns]
    pols = [np.round(np.abs(p.polarization), 6).tolist() for p in r.rx_array.patterns]
    assert kinds == ["sector", "sector", "sector", "isotropic"]
    assert r.rx_array.patterns[1].azimuth_width_deg == 20.0
    assert pols == [[0, 1], [0, 1], [1, 0], [0, 1]]  # H, H, V, H (Jones (C_θ, C_φ))
    # the hash counts them
    plain = scene(ula4(), radar_extra={"pattern": "sector", "polarization": "V"})
    assert plain.radars[0].rx_array.patterns is None
    assert sc.content_hash() != plain.content_hash()


@pytest.mark.parametrize("rx, key, fragment", [
    (ula4(elements=[{}, {}]), "radars[0].rx_array.elements", "list of 4 tables"),
    (ula4(elements=[{}, {}, {}, {"pol": "H"}]), "radars[0].rx_array.elements[3].pol",
     "unknown key"),
    (ula4(elements=[{}, {"polarization": "Q"}, {}, {}]),
     "radars[0].rx_array.elements[1].polarization", "unknown polarization"),
    (ula4(pattern="dipole"), "radars[0].rx_array.pattern", "unknown pattern"),
])
def test_bad_element_patterns_are_refused_naming_file_key_and_value(rx, key, fragment):
    with pytest.raises(SceneError) as ei:
        scene(rx)
    assert ei.value.key == key and "p.toml" in str(ei.value) and fragment in str(ei.value)


# -- applied ----------------------------------------------------------------------------


def test_element_gains_are_the_tracers_own_product(runtime):
    """Elements given the radar's own pattern and polarisation explicitly: c_rxᵀ M c_tx of
    every element pair is the traced path's gain."""
    sc = scene(ula4(pattern="sector", polarization="V"), radar_extra={"pattern": "sector"})
    ref, _ = traced(sc, runtime)
    g = element_gains(ref, sc.radars[0])
    np.testing.assert_allclose(g, np.broadcast_to(ref.gain, g.shape), rtol=1e-12)


def test_an_element_with_a_null_toward_the_target_gets_nothing(runtime):
    # the plate 30° off boresight; receive element 1 sees only ±10° of azimuth
    sc = scene(ula4(elements=[{}, {"pattern": {"type": "sector", "azimuth_width_deg": 20}},
                              {}, {}]), azimuth_deg=30.0)
    ref, pairs = traced(sc, runtime)
    assert len(ref.gain) == 1
    for channel in ("synthetic", "corrected"):
        g, _, _ = element_channels(ref, sc.radars[0], WF, channel)
        power = np.abs(g[:, :, 0]) ** 2
        assert np.all(power[:, 1] == 0) and np.all(power[:, [0, 2, 3]] > 0)
        # the others keep the isotropic element's gain, the reference path's
        np.testing.assert_allclose(power[:, [0, 2, 3]], abs(ref.gain[0]) ** 2, rtol=1e-12)
    traced_power = pair_power(pairs)
    assert np.all(traced_power[:, 1] == 0) and np.all(traced_power[:, [0, 2, 3]] > 0)
    # (each pair its own spreading: 1/L² differs by ~0.1 % across the array at 10 m)
    np.testing.assert_allclose(traced_power[:, [0, 2, 3]], abs(ref.gain[0]) ** 2, rtol=5e-3)
    # the same plate on boresight: element 1 sees it as well as the others (sector 20°
    # has the higher directivity)
    sc0 = scene(ula4(elements=[{}, {"pattern": {"type": "sector", "azimuth_width_deg": 20}},
                               {}, {}]), azimuth_deg=0.0)
    ref0, _ = traced(sc0, runtime)
    g0, _, _ = element_channels(ref0, sc0.radars[0], WF, "synthetic")
    assert np.all(np.abs(g0[:, 1, 0]) > np.abs(g0[:, 0, 0]))


def test_a_cross_polarised_element_loses_the_co_polarised_return(runtime):
    # vertical radar, receive element 2 horizontal: a PEC plate at normal incidence keeps
    # the polarisation (M = −I in the backscatter basis), so element 2 gets nothing
    sc = scene(ula4(elements=[{}, {}, {"polarization": "H"}, {}]),
               radar_extra={"polarization": "V"})
    ref, pairs = traced(sc, runtime)
    np.testing.assert_allclose(ref.matrix[0] / ref.matrix[0][0, 0], np.eye(2), atol=1e-9)
    for channel in ("synthetic", "corrected"):
        g, _, _ = element_channels(ref, sc.radars[0], WF, channel)
        p = np.abs(g[:, :, 0]) ** 2
        assert np.all(p[:, 2] < 1e-18 * p[:, 0])
        np.testing.assert_allclose(p[:, [0, 1, 3]], abs(ref.gain[0]) ** 2, rtol=1e-12)
    tp = pair_power(pairs)
    assert np.all(tp[:, 2] < 1e-12 * tp[:, 0])
    # a 45° slant element gets half the power (−3 dB) of the co-polarised ones
    sc45 = scene(ula4(elements=[{}, {}, {"polarization": [0.7071067811865476,
                                                          0.7071067811865476]}, {}]))
    ref45, _ = traced(sc45, runtime)
    g45, _, _ = element_channels(ref45, sc45.radars[0], WF, "synthetic")
    p45 = np.abs(g45[:, :, 0]) ** 2
    np.testing.assert_allclose(p45[:, 2] / p45[:, 0], 0.5, rtol=1e-9)
