"""Noise-floor power bounds, pruning and the cheapest-setting choice (clradcom.evaluation.budget).

Independent checks: the floor against the real radar chain (a path |a|² = floor · 10^x
stands x dB above the image noise), the GO bounds against traced paths and the Friis
free-space gain, the scattering bound against the tiles scattering_paths emits.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from geometry_helpers import plate_tris

from clradcom.evaluation import budget
from clradcom.evaluation.accuracy import pareto_front
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.scattering import scattering_paths, scattering_triangle_bounds
from clradcom.paths import InteractionType, Paths
from clradcom.physics.em import C0
from clradcom.radar import Waveform, radar_image, synthesize_frequency_domain
from clradcom.radar.synthesis import BOLTZMANN
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import DiffractionSettings, SpecularSettings, TraceSettings, trace_scene

F_C = 24e9
LAM = C0 / F_C
SMALL = Waveform(carrier_hz=F_C, n_subcarriers=64, n_symbols=32)


def go_settings(max_reflections: int, rays: int) -> TraceSettings:
    """Line of sight and specular reflections only."""
    return TraceSettings(
        specular=SpecularSettings(max_reflections=max_reflections, rays=rays),
        diffraction=DiffractionSettings(max_diffractions=0))


def plate_scene(x=10.0, size=1.0, material="metal", materials=None, radars=None, n=1):
    verts, faces = plate_tris(n, size, x)
    return scene_from_dict({
        "scene": {"name": "plate", "carrier_hz": F_C},
        "materials": materials or [],
        "objects": [{"name": "plate", "material": material, "shape": "triangles",
                     "vertices": verts, "faces": faces}],
        "radars": radars or [{"name": "A", "position": [0.0, 0.0, 0.0],
                              "pattern": "isotropic", "tx_power_w": 0.01,
                              "noise_figure_db": 10.0}]})


# ---------------------------------------------------------------------------
# noise floor
def test_processing_gain_rect_is_nm_and_hann_loses_two_thirds_per_axis():
    assert budget.processing_gain(64, 32, "rect", "rect") == pytest.approx(64 * 32)
    # DFT-even Hann: (sum w)^2 / sum w^2 = (N/2)^2 / (3N/8) = 2N/3
    assert budget.processing_gain(64, 32) == pytest.approx((2 * 64 / 3) * (2 * 32 / 3))


def test_noise_floor_is_ktbf_over_ptx_and_processing_gain():
    nf = budget.noise_floor(SMALL, 0.01, 10.0, window_range="rect", window_doppler="rect")
    var = BOLTZMANN * 290.0 * SMALL.bandwidth * 10.0 / 0.01
    assert nf.noise_variance == pytest.approx(var, rel=1e-12)
    assert nf.power == pytest.approx(var / (64 * 32), rel=1e-12)
    shifted = budget.noise_floor(SMALL, 0.01, 10.0, margin_db=10.0, window_range="rect",
                                 window_doppler="rect")
    assert shifted.power == pytest.approx(10 * nf.power)
    assert nf.amplitude == pytest.approx(math.sqrt(nf.power))


@pytest.mark.parametrize("snr_db", [0.0, 20.0])
def test_a_path_at_floor_plus_x_stands_x_db_over_the_image_noise(snr_db):
    """The floor's convention against the project's radar chain: radar_image normalises
    its noise to σ² per cell, so an on-grid path of |a|² = floor·10^(x/10) peaks at
    σ²·10^(x/10)."""
    nf = budget.noise_floor(SMALL, 0.01, 10.0)  # Hann windows, as pipeline.process
    a = math.sqrt(nf.power * 10.0 ** (snr_db / 10.0))
    tau = 5.0 / SMALL.bandwidth  # range bin 5, no Doppler: on the grid, no scalloping
    D = np.ones((64, 32), complex)
    Dr = synthesize_frequency_domain(D, [a], [tau], [0.0], SMALL)
    img = radar_image(Dr / D, SMALL, "hann", "hann")
    assert 10 * np.log10(img.power.max() / nf.noise_variance) == pytest.approx(snr_db, abs=0.01)


def test_noise_floor_refuses_bad_numbers_by_name():
    with pytest.raises(ValueError, match="tx_power_w"):
        budget.noise_floor(SMALL, 0.0, 10.0)
    with pytest.raises(ValueError, match="noise_figure_db"):
        budget.noise_floor(SMALL, 0.01, float("nan"))
    with pytest.raises(ValueError, match="margin_db"):
        budget.noise_floor(SMALL, 0.01, 10.0, margin_db="3")
    with pytest.raises(ValueError, match="waveform"):
        budget.noise_floor({"n": 1}, 0.01, 10.0)


# ---------------------------------------------------------------------------
# GO bounds
def test_max_length_and_min_gamma_invert_each_other_and_friis():
    floor = 1e-14
    L = budget.max_path_length(floor, LAM, gamma_product=0.5, g_tx=4.0, g_rx=4.0)
    # Friis: |a|^2 = (lambda / 4 pi L)^2 G_t G_r |Gamma|^2 equals the floor at L
    assert (LAM / (4 * math.pi * L)) ** 2 * 16 * 0.25 == pytest.approx(floor, rel=1e-12)
    assert budget.min_gamma_product(floor, LAM, L, 4.0, 4.0) == pytest.approx(0.5, rel=1e-12)
    assert budget.max_path_length(floor, LAM, 0.0) == 0.0
    with pytest.raises(ValueError, match="gamma_product"):
        budget.max_path_length(floor, LAM, 1.5)
    with pytest.raises(ValueError, match="floor_power"):
        budget.max_path_length(-1.0, LAM)


def test_free_space_bound_matches_a_traced_line_of_sight(runtime):
    """At the bound's longest length the traced LOS gain equals the floor."""
    floor = 1e-12
    L = budget.max_path_length(floor, LAM)
    scene = scene_from_dict({"scene": {"name": "fs", "carrier_hz": F_C}, "objects": [],
                             "radars": [{"name": "t", "position": [0, 0, 0],
                                         "pattern": "isotropic", "role": "tx"},
                                        {"name": "r", "position": [L, 0, 0],
                                         "pattern": "isotropic", "role": "rx"}]})
    snap = trace_scene(scene, go_settings(max_reflections=0, rays=100),
                       runtime=runtime)
    g = snap.links[0].paths.gain
    assert len(g) == 1 and abs(g[0]) ** 2 == pytest.approx(floor, rel=1e-9)


def test_gamma_max_is_one_with_pec_or_dielectric_and_below_one_when_all_scatter():
    assert budget.scene_gamma_max(plate_scene()) == pytest.approx(1.0)
    # a dielectric reaches |Gamma| -> 1 at grazing
    diel = plate_scene(materials=[{"name": "glass", "eps_r": [5.0, -0.1]}], material="glass")
    assert budget.scene_gamma_max(diel) == pytest.approx(1.0, abs=1e-9)
    rough = plate_scene(materials=[{"name": "rough", "pec": True,
                                    "scattering_coefficient": 0.6}], material="rough")
    assert budget.scene_gamma_max(rough) == pytest.approx(0.8)


def test_shortest_path_is_distance_to_the_plate_and_back():
    scene = plate_scene(x=7.0)
    r = scene.radars[0]
    assert budget.shortest_path_length(scene, r.position, r.position, 0) == 0.0
    assert budget.shortest_path_length(scene, r.position, r.position, 3) == pytest.approx(14.0)
    with pytest.raises(ValueError, match="order"):
        budget.shortest_path_length(scene, r.position, r.position, -1)


def test_order_bounds_hold_for_a_traced_path_and_cap_orders(runtime):
    # S = 0.9 leaves |Gamma| <= sqrt(1 - 0.81) = 0.436 per bounce on this plate
    scene = plate_scene(x=10.0, size=2.0, material="rough", materials=[
        {"name": "rough", "pec": True, "scattering_coefficient": 0.9}])
    r = scene.radars[0]
    bounds = budget.order_bounds(scene, r, r, 1e-30, 4)
    assert [b.order for b in bounds] == [0, 1, 2, 3, 4]
    assert bounds[0].best_power == 0.0  # monostatic: no line of sight
    g = 0.19 ** 0.5
    assert bounds[1].best_power == pytest.approx((LAM / (4 * math.pi * 20.0)) ** 2 * g**2)
    snap = trace_scene(scene, go_settings(max_reflections=1, rays=20_000),
                       runtime=runtime)
    p = snap.links[0].paths
    assert p.n_paths == 1 and abs(p.gain[0]) ** 2 <= bounds[1].best_power * (1 + 1e-9)
    # a floor between the order-2 and order-3 best cases: orders 3, 4 need not be traced
    floor = math.sqrt(bounds[2].best_power * bounds[3].best_power)
    capped = budget.order_bounds(scene, r, r, floor, 4)
    assert budget.max_useful_order(capped) == 2
    assert [b.above_floor for b in capped] == [False, True, True, False, False]
    assert capped[3].headroom_db < 0 < capped[2].headroom_db


def test_scattering_triangle_bound_exceeds_the_emitted_tiles(runtime):
    scene = plate_scene(x=5.0, size=1.0, n=2, material="rough", materials=[
        {"name": "rough", "eps_r": [5.0, 0.0], "scattering_coefficient": 0.5}])
    r = scene.radars[0]
    ids, best, above = scattering_triangle_bounds(scene, r, r, 1e-30)
    assert list(ids) == list(range(8)) and above.all()
    paths, _ = scattering_paths(build_geometry(scene, runtime), r, r, tile_size_m=0.1,
                                threshold_db=300.0)
    per_tri = np.bincount(paths.face_id[:, 0], weights=np.abs(paths.gain) ** 2, minlength=8)
    assert np.all(per_tri <= best) and np.all(per_tri > 0.05 * best)
    # a floor above every bound marks every triangle as below it
    _, _, above = scattering_triangle_bounds(scene, r, r, 2 * best.max())
    assert not above.any()


def test_relative_threshold_converts_the_floor():
    assert budget.relative_threshold_db(1e-14, 1e-10) == pytest.approx(40.0)
    assert budget.relative_threshold_db(1e-10, 1e-14) == 0.0
    with pytest.raises(ValueError, match="strongest_power"):
        budget.relative_threshold_db(1e-14, 0.0)


# ---------------------------------------------------------------------------
# pruning
def fake_paths(gains, codes, delays=None):
    P = len(gains)
    inter = np.array(codes, dtype=np.int8).reshape(P, 1)
    return Paths(gain=np.asarray(gains, complex), matrix=np.zeros((P, 2, 2), complex),
                 delay_s=np.linspace(1e-7, 2e-7, P) if delays is None else np.asarray(delays),
                 doppler_hz=np.zeros(P), n_interactions=np.ones(P, np.int16), interaction=inter,
                 points=np.zeros((P, 3, 3)), object_id=np.zeros((P, 1), np.int32),
                 face_id=np.arange(P, dtype=np.int32)[:, None])


def test_prune_paths_drops_below_the_floor_and_reports_by_kind():
    R, D, S = (int(InteractionType.REFLECTION), int(InteractionType.DIFFRACTION),
               int(InteractionType.SCATTERING))
    gains = [1e-5, 1e-9, 3e-8j, 1e-8, 2e-9, 1e-6]
    kept, rep = budget.prune_paths(fake_paths(gains, [R, R, D, S, S, S]), 1e-16)  # |a|=1e-8
    assert np.allclose(np.abs(kept.gain), [1e-5, 3e-8, 1e-8, 1e-6])
    assert rep.n_in == 6 and rep.n_kept == 4 and rep.n_dropped == 2
    assert rep.dropped_by_kind == {"reflection": 1, "diffraction": 0, "scattering": 1}
    assert rep.dropped_power == pytest.approx(1e-18 + 4e-18)
    assert rep.strongest_dropped == pytest.approx(4e-18)
    assert "2 of 6 paths" in rep.describe()
    with pytest.raises(ValueError, match="floor_power"):
        budget.prune_paths(kept, float("nan"))
    with pytest.raises(ValueError, match="waveform"):
        budget.prune_paths(kept, 1e-16, waveform="paper")


def test_prune_paths_keeps_weak_paths_whose_cell_adds_up():
    """Four paths of |a| = 0.6 floor amplitudes in one range-Doppler cell add up to 2.4 of it
    in phase: kept; the same path alone in its cell is dropped."""
    S_ = int(InteractionType.SCATTERING)
    floor = 1e-16
    a = 0.6 * math.sqrt(floor)
    bin_s = 1.0 / SMALL.bandwidth
    p = fake_paths([a] * 5, [S_] * 5, [10 * bin_s, 10.2 * bin_s, 9.8 * bin_s, 10.1 * bin_s,
                                       30 * bin_s])
    assert len(np.unique(budget.radar_cells(p.delay_s, p.doppler_hz, SMALL))) == 2
    kept, rep = budget.prune_paths(p, floor, SMALL)
    assert rep.n_kept == 4 and rep.kept_below_floor == 4
    assert np.allclose(kept.delay_s, p.delay_s[:4])
    assert "4 weak paths kept" in rep.describe()
    # without the waveform every weak path goes
    assert budget.prune_paths(p, floor)[1].n_kept == 0
    # (4 x 0.6)^2 = 5.76 < 6: at a floor 6x higher the cell stays below it too
    assert budget.prune_paths(p, 6 * floor, SMALL)[1].n_kept == 0


# ---------------------------------------------------------------------------
# choosing settings
RECORDS = [
    {"setting": 0, "seconds": 1.0, "channel_nmse_db": -5.0, "error_to_noise_db": 30.0,
     "image_error_db": 20.0, "count_share": 0.4, "power_share": 0.5,
     "targets": 3, "targets_found": 2, "range_error_m": 0.1,
     "velocity_error_mps": 0.1},
    {"setting": 1, "seconds": 2.0, "channel_nmse_db": -22.0, "error_to_noise_db": 12.0,
     "image_error_db": 5.0, "count_share": 0.8, "power_share": 0.9,
     "targets": 3, "targets_found": 3, "range_error_m": 0.9,
     "velocity_error_mps": 0.2},
    {"setting": 2, "seconds": 3.0, "channel_nmse_db": -21.0, "error_to_noise_db": 11.0,
     "image_error_db": 4.0, "count_share": 0.85, "power_share": 0.95,
     "targets": 3, "targets_found": 3, "range_error_m": 0.2,
     "velocity_error_mps": 0.2},
    {"setting": 3, "seconds": 9.0, "channel_nmse_db": -45.0, "error_to_noise_db": -3.0,
     "image_error_db": -20.0, "count_share": 1.0, "power_share": 1.0,
     "targets": 3, "targets_found": 3, "range_error_m": 0.2,
     "velocity_error_mps": 0.1},
]


@pytest.mark.parametrize("target, setting", [
    (budget.AccuracyTarget(channel_nmse_db=-20.0), 1),
    (budget.AccuracyTarget(channel_nmse_db=-30.0), 3),
    (budget.AccuracyTarget(error_to_noise_db=0.0), 3),
    (budget.AccuracyTarget(range_error_m=0.5, velocity_error_mps=0.5), 2),
    (budget.AccuracyTarget(range_error_m=1.0), 1),  # setting 0 misses a target
    (budget.AccuracyTarget(power_share=0.92), 2),
    (budget.AccuracyTarget(count_share=0.7), 1),
    (budget.AccuracyTarget(image_error_db=-1.0), 3),
    # two of three targets suffice: the cheapest, within 0.5 m
    (budget.AccuracyTarget(range_error_m=0.5, min_targets_found=2), 0),
    (budget.AccuracyTarget(min_targets_found=3), 1),
])
def test_choose_settings_takes_the_cheapest_meeting_the_target(target, setting):
    choice = budget.choose_settings(RECORDS, target)
    assert choice.ok and choice.record["setting"] == setting
    # the cheapest setting meeting bounds lies on the front of cost and those criteria
    front = pareto_front([r["seconds"] for r in RECORDS],
                         [r["channel_nmse_db"] for r in RECORDS],
                         [r["error_to_noise_db"] for r in RECORDS],
                         [r["image_error_db"] for r in RECORDS],
                         [-r["power_share"] for r in RECORDS],
                         [-r["count_share"] for r in RECORDS],
                         [-r["targets_found"] for r in RECORDS],
                         [r["range_error_m"] if r["targets_found"] == 3 else np.inf
                          for r in RECORDS])
    assert front[setting]


def test_choose_settings_says_when_nothing_meets_the_target():
    choice = budget.choose_settings(RECORDS, budget.AccuracyTarget(channel_nmse_db=-60.0))
    assert not choice.ok and choice.record is None and choice.n_meeting == 0
    assert "no setting" in choice.message and "channel_nmse_db -45.0 > -60" in choice.message
    assert not budget.choose_settings([], budget.AccuracyTarget(power_share=0.5)).ok


def test_choose_settings_refuses_bad_targets_and_records_by_name():
    with pytest.raises(ValueError, match="at least one criterion"):
        budget.AccuracyTarget()
    with pytest.raises(ValueError, match="power_share"):
        budget.AccuracyTarget(power_share=1.5)
    with pytest.raises(ValueError, match="range_error_m"):
        budget.AccuracyTarget(range_error_m=-1.0)
    with pytest.raises(ValueError, match="min_targets_found"):
        budget.AccuracyTarget(min_targets_found=1.5)
    with pytest.raises(ValueError, match="count_share"):
        budget.AccuracyTarget(count_share=-0.1)
    with pytest.raises(ValueError, match="'channel_nmse_db'"):
        budget.choose_settings([{"seconds": 1.0}], budget.AccuracyTarget(channel_nmse_db=0))
    with pytest.raises(ValueError, match="seconds"):
        budget.choose_settings([{"channel_nmse_db": 1.0}],
                               budget.AccuracyTarget(channel_nmse_db=0))


def test_read_records_round_trips_a_sweep_csv(tmp_path):
    path = tmp_path / "sweep.csv"
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["setting", "seconds", "channel_nmse_db", "prune",
                                           "synthesis"])
        w.writeheader()
        w.writerow({"setting": 0, "seconds": "1.5", "channel_nmse_db": "-inf", "prune": True,
                    "synthesis": "fast"})
    rec = budget.read_records(path)
    assert rec == [{"setting": 0, "seconds": 1.5, "channel_nmse_db": -math.inf, "prune": True,
                    "synthesis": "fast"}]
    assert budget.choose_settings(rec, budget.AccuracyTarget(channel_nmse_db=-100)).ok
