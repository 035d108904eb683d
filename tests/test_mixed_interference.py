"""An FMCW radar and an OFDM radar on the paper's street (scenes/street/street_fmcw_ofdm.toml:
radar D an FMCW chirp sequence of its own, radar A the paper's OFDM frame), interfering
through the traced link between them (clradcom.radar.mixed_interference, clradcom
interference): each direction's floor rise within 0.5 dB of its closed form through the
link, the FMCW pair's burst length and ghost range against theirs, and the victim's
detections of the cars after mitigation. The street is traced once, small (preset fast,
2e4 rays)."""

from __future__ import annotations

import argparse
import csv
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from clradcom.cli import main
from clradcom.commands.interference import pair_waveforms
from clradcom.commands.options import run_waveform
from clradcom.errors import SceneError
from clradcom.radar.fmcw import FmcwWaveform, if_response
from clradcom.radar.fmcw_interference import (
    burst_floor_power,
    ofdm_burst_energy,
)
from clradcom.radar.mixed_interference import (
    chirp_band_energy,
    fmcw_burst_floor,
    link_response,
    mixed_pair_run,
    ofdm_band_floor,
)
from clradcom.radar.report import match_tolerances, moving_objects
from clradcom.radar.truth import detection_truth, match_truth
from clradcom.radar.waveform import Waveform
from clradcom.scene import load_scene
from clradcom.scene.edit import set_waveform
from clradcom.trace import TraceSettings, trace_scene

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "street" / "street_fmcw_ofdm.toml"
C = 299_792_458.0


class NoOptions:
    """argparse's namespace with no waveform option given."""


@pytest.fixture(scope="module")
def street():
    scene = load_scene(SCENE)
    snap = trace_scene(scene, TraceSettings.preset("fast").replace(specular__rays=20_000))
    ofdm, _ = run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True, radar=0)
    fmcw, _ = run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True, radar=1)
    assert isinstance(ofdm, Waveform) and isinstance(fmcw, FmcwWaveform)
    return scene, snap, ofdm, fmcw


def _run(street, victim_name, interferer_name, victim, interferer, offset_s=4.2e-6):
    scene, snap, _, _ = street
    rv = scene.radars[scene.radar_index(victim_name)]
    ri = scene.radars[scene.radar_index(interferer_name)]
    return mixed_pair_run(snap.link(victim_name, victim_name).paths,
                          snap.link(interferer_name, victim_name).paths, victim, interferer,
                          tx_power_w=rv.tx_power_w, interferer_tx_power_w=ri.tx_power_w,
                          noise_figure_db=rv.noise_figure_db, start_offset_s=offset_s,
                          cfo_hz=2400.0, phase_rad=0.6)


def _cars(street, radar, result, key, wf):
    """The moving cars ``radar`` detects in ``result``'s image ``key``."""
    scene = street[0]
    truth = detection_truth(scene, radar, moving_objects(scene, scene.radars[
        scene.radar_index(radar)]))
    matches = match_truth(result.results[key].detections, truth, *match_tolerances(wf))
    return {t["name"] for t, m in zip(truth, matches, strict=True) if m is not None}


def _found_again(result, key, wf) -> bool:
    ref, got = result.results["clean"].detections, result.results[key].detections
    return all(np.any((np.abs(got["range_m"] - d["range_m"]) <= wf.range_resolution)
                      & (np.abs(got["velocity_mps"] - d["velocity_mps"])
                         <= wf.velocity_resolution)) for d in ref)


def test_fmcw_chirps_into_the_ofdm_radar_through_the_link(street):
    """D's chirps cross A's 93 MHz band for B/S = 15 µs of every 50 µs: A's floor rises by
    (B/S)∫|H|²dν per crossing over L·M·σ² (13.4 dB on this link), measured within
    0.5 dB; bridging the crossed symbols along slow time gives the floor and every
    detection back, car B's among them, which the interference had buried."""
    _, _, ofdm, fmcw = street
    res = _run(street, "A", "D", ofdm, fmcw)
    assert (res.victim_kind, res.interferer_kind) == ("ofdm", "fmcw")
    assert res.predicted_floor_rise_db > 10.0
    assert res.measured_floor_rise_db == pytest.approx(res.predicted_floor_rise_db, abs=0.5)
    clean_cars = _cars(street, "A", res, "clean", ofdm)
    assert "carB" in clean_cars
    assert "carB" not in _cars(street, "A", res, "interfered", ofdm)
    assert _cars(street, "A", res, "mitigated", ofdm) == clean_cars
    assert _found_again(res, "mitigated", ofdm)
    assert 10 * np.log10(res.floors["mitigated"] / res.floors["clean"]) == \
        pytest.approx(0.0, abs=0.5)
    assert 0.2 < res.mitigated_share < 0.5  # 15 µs of every 50 µs, and a symbol around


def test_ofdm_into_the_fmcw_radar_through_the_link(street):
    """A's OFDM band in D's beat signal while D's chirp sweeps it: |H_IF(f)|²f_s²/(N S)
    times the band's mean |H|² per range bin (14.8 dB on this link), measured within
    0.5 dB. The band fills 60 % of the ADC window's sweep, no burst: the repair finds
    nothing to replace, and the floor stays (docs/interference.md §6)."""
    _, _, ofdm, fmcw = street
    res = _run(street, "D", "A", fmcw, ofdm)
    assert (res.victim_kind, res.interferer_kind) == ("fmcw", "ofdm")
    assert res.predicted_floor_rise_db > 10.0
    assert res.measured_floor_rise_db == pytest.approx(res.predicted_floor_rise_db, abs=0.5)
    assert res.mitigated_share == 0.0
    assert res.floors["mitigated"] == res.floors["interfered"]


def test_two_fmcw_radars_with_different_slopes_burst_and_are_repaired(street):
    """A as an FMCW radar 20 % slower than D (5 against 6.25 MHz/µs, chirps every
    59.99 µs against 50): a burst of 2B_IF/|S_I − S_V| = 4 µs where their difference
    frequency crosses A's 2.5 MHz IF band, measured within the issue's 1 % (the burst's
    edges found from its frequency, between samples); A's floor rises as the
    bursts through the link say (within 0.5 dB); the repair brings the floor most of the
    way back, the cars A saw without D still seen."""
    _, _, _, fmcw = street
    victim = replace(fmcw, chirp_s=50e-6, idle_s=9.99e-6)
    res = _run(street, "A", "D", victim, fmcw)
    assert res.predicted_burst_duration_s == pytest.approx(4e-6)
    assert res.burst_duration_s == pytest.approx(res.predicted_burst_duration_s, rel=0.01)
    assert res.predicted_floor_rise_db > 10.0
    assert res.measured_floor_rise_db == pytest.approx(res.predicted_floor_rise_db, abs=0.5)
    rise = 10 * np.log10(res.floors["interfered"] / res.floors["clean"])
    left = 10 * np.log10(res.floors["mitigated"] / res.floors["clean"])
    assert rise > 2.0 and left < 0.5 * rise
    clean_cars = _cars(street, "A", res, "clean", victim)
    assert {"carB", "carC"} <= clean_cars
    assert _cars(street, "A", res, "mitigated", victim) == clean_cars


def test_two_fmcw_radars_with_equal_slopes_make_a_ghost_where_the_closed_form_says(street):
    """The same chirp sequence on both, D's chirps 0.2 µs after A's: a ghost at
    c(τ + t_d)/2 = 46.3 m (τ the one-way LoS delay), found within 1 %; a coherent tone is
    no burst, so the repair leaves it."""
    _, snap, _, fmcw = street
    res = _run(street, "A", "D", fmcw, fmcw, offset_s=0.2e-6)
    tau = snap.link("D", "A").paths.delay_s[np.argmax(np.abs(snap.link("D", "A").paths.gain))]
    assert res.predicted_ghost_range_m == pytest.approx(C * (tau + 0.2e-6) / 2, rel=1e-9)
    assert res.ghost_range_m == pytest.approx(res.predicted_ghost_range_m, rel=0.01)
    assert math.isnan(res.measured_floor_rise_db) and res.mitigated_share == 0.0
    # chirps that repeat at another interval move the ghost from chirp to chirp: no figure
    other = _run(street, "A", "D", replace(fmcw, idle_s=12e-6), fmcw, offset_s=0.2e-6)
    assert math.isnan(other.predicted_ghost_range_m) and math.isnan(other.ghost_range_m)


def test_the_link_closed_forms_reduce_to_one_paths():
    """One path: H(ν) = a, so the link forms are the single-path closed forms of
    clradcom.radar.fmcw_interference (tested against simulation there)."""
    a, tau = 1e-3 * np.exp(0.3j), 30.0 / C
    assert link_response([24.01e9, 24.05e9], [a], [tau], 24e9) == pytest.approx(
        a * np.exp(-2j * np.pi * np.array([1e7, 5e7]) * tau))
    fmcw = FmcwWaveform(traced_carrier_hz=24e9, start_hz=23.95e9, sweep_bandwidth_hz=250e6,
                        chirp_s=40e-6, idle_s=10e-6, n_chirps=16, adc_rate_hz=10e6,
                        samples_per_chirp=256, adc_start_s=2e-6, if_bandwidth_hz=2.5e6)
    ofdm = Waveform(carrier_hz=24e9, n_subcarriers=256, subcarrier_spacing_hz=90.909e3,
                    cp_s=64 / (256 * 90.909e3), n_symbols=64)
    beat = np.linspace(-2e6, 2e6, 9)
    # the band crossed whole inside the ADC window: |a|²|H_IF|²f_s²/(N S) per bin
    want = abs(a) ** 2 * np.abs(if_response(fmcw, beat)) ** 2 * 1e14 / (256 * fmcw.slope)
    assert ofdm_band_floor(fmcw, ofdm, [a], [tau], beat) == pytest.approx(want, rel=1e-3)
    # chirps 50 µs apart in a 21.1 ms frame, each crossing whole: |a|²B²/S each
    e = chirp_band_energy(ofdm, fmcw, [a], [tau], [0.0], 1e-6)
    n = e / ofdm_burst_energy(ofdm, fmcw, a)
    assert n == pytest.approx(round(n), abs=0.02) and abs(n - ofdm.frame_duration / 50e-6) < 2
    # bursts: one per victim chirp whose crossing lies inside the window
    slow = replace(fmcw, chirp_s=50e-6, idle_s=9.99e-6)
    per_bin = fmcw_burst_floor(slow, fmcw, [a], [tau], [0.0], 4.2e-6, beat)
    ratio = per_bin / burst_floor_power(slow, fmcw, a, beat)
    assert np.all((ratio >= 0) & (ratio <= 1))
    assert np.ptp(ratio[2:-2]) < 0.15  # the same chirps hold bins in the band's middle


def test_two_ofdm_radars_must_share_their_frame():
    scene = set_waveform(load_scene(SCENE), radar="D", subcarriers=512)
    args = argparse.Namespace(victim="A", interferer="D", subcarriers=None, symbols=None,
                              subcarrier_spacing=None, cyclic_prefix=None, cp_samples=None,
                              modulation=None)
    with pytest.raises(SceneError, match="two OFDM radars with different frames") as err:
        pair_waveforms(scene, args)
    assert err.value.key == "radars[1].waveform"


def test_clradcom_interference_runs_the_fmcw_ofdm_pair(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["interference", str(SCENE), "--out", str(out), "--preset", "fast",
                 "--rays", "20000", "-q"]) == 0
    text = capsys.readouterr().out
    assert "victim A: waveform: f_c 24 GHz, N 1024" in text
    assert "interferer D: waveform: FMCW" in text
    with open(out / "interference_summary.csv") as fh:
        rows = {r["quantity"]: float(r["value"]) for r in csv.DictReader(fh)}
    assert rows["floor rise measured [dB]"] == pytest.approx(
        rows["floor rise predicted through the link [dB]"], abs=0.5)
    assert abs(rows["image floor after mitigation, re without [dB]"]) < 0.5
    assert (out / "interference.png").stat().st_size > 0
    assert (out / "snapshot.npz").is_file()
