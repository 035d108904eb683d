"""Accuracy measures (clradcom.evaluation.accuracy), the sweep's points
(clradcom.evaluation.tradeoff) and tools/tradeoff.py end to end on a small scene.

Independent checks: the frame channel against the closed-form H(n, μ), NMSE against a
known relative error, the error-to-noise bound against the project's radar image, path
completeness against hand-counted power, the Pareto front against a hand example, and the
tool's CSV against its own definitions (fronts recomputed, shares and counts consistent).
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from tool_helpers import CLOSING_PLATE_SCENE
from tool_helpers import load_tool as load_named_tool

from clradcom.commands import tradeoff as tradeoff_command
from clradcom.evaluation import accuracy as acc
from clradcom.evaluation import tradeoff as tr
from clradcom.paths import InteractionType
from clradcom.radar import (
    DETECTION_DTYPE,
    Waveform,
    channel_transfer_function,
    radar_image,
    random_symbols,
    synthesize_frequency_domain,
)

SMALL = Waveform(carrier_hz=24e9, n_subcarriers=64, n_symbols=32)
R, D, S = (int(InteractionType.REFLECTION), int(InteractionType.DIFFRACTION),
           int(InteractionType.SCATTERING))


# ---------------------------------------------------------------------------
# channel error
def test_frame_channel_of_the_fast_model_is_the_closed_form_transfer_function():
    D = random_symbols(SMALL, 3)
    gains, delays, dopplers = [1e-5, 2e-6j], [1.3e-7, 2.9e-7], [1.1e3, -2.3e3]
    Dr = synthesize_frequency_domain(D, gains, delays, dopplers, SMALL)
    H = channel_transfer_function(gains, delays, dopplers, SMALL, method="direct")
    assert np.allclose(acc.frame_channel(D, Dr), H, rtol=0, atol=1e-9 * np.abs(H).max())


def test_frame_channel_refuses_zero_symbols_and_shape_mismatch():
    D = np.ones((4, 3), complex)
    with pytest.raises(ValueError, match="shape"):
        acc.frame_channel(D, np.ones((4, 2)))
    D[1, 1] = 0
    with pytest.raises(ValueError, match="zero symbols"):
        acc.frame_channel(D, np.ones((4, 3)))
    with pytest.raises(ValueError, match="Dr contains NaN"):
        acc.frame_channel(np.ones((2, 2)), np.full((2, 2), np.nan))


def test_channel_nmse_db_of_known_errors():
    rng = np.random.default_rng(0)
    H = rng.normal(size=(8, 5)) + 1j * rng.normal(size=(8, 5))
    assert acc.channel_nmse_db(1.1 * H, H) == pytest.approx(-20.0)
    assert acc.channel_nmse_db(H * np.exp(1j * 0.01), H) == pytest.approx(
        20 * math.log10(2 * math.sin(0.005)))
    assert acc.channel_nmse_db(np.zeros_like(H), H) == pytest.approx(0.0)
    assert acc.channel_nmse_db(H, H) == -math.inf
    with pytest.raises(ValueError, match="H_ref is all zero"):
        acc.channel_nmse_db(H, np.zeros_like(H))
    with pytest.raises(ValueError, match="one shape"):
        acc.channel_nmse_db(H[:2], H)


def test_error_to_noise_bounds_the_error_in_any_radar_image_cell():
    """Σ|ΔF|² bounds the error power of every image cell (noise normalised to σ² per cell
    by radar_image), with equality for one on-grid path and rectangular windows."""
    rng = np.random.default_rng(1)
    dF = 1e-7 * (rng.normal(size=(64, 32)) + 1j * rng.normal(size=(64, 32)))
    total = float(np.sum(np.abs(dF) ** 2))
    for win in ("hann", "rect"):
        assert radar_image(dF, SMALL, win, win).power.max() <= total * (1 + 1e-12)
    one = synthesize_frequency_domain(np.ones((64, 32)), [3e-7], [4 / SMALL.bandwidth], [0.0],
                                      SMALL)
    assert radar_image(one, SMALL, "rect", "rect").power.max() == pytest.approx(
        float(np.sum(np.abs(one) ** 2)), rel=1e-9)
    sigma2 = 1e-13
    H = np.ones((64, 32), complex)
    assert acc.error_to_noise_db(H + dF, H, sigma2) == pytest.approx(
        10 * math.log10(total / sigma2))
    with pytest.raises(ValueError, match="noise_variance"):
        acc.error_to_noise_db(H, H, 0.0)


def test_image_error_of_one_path_is_its_snr_after_processing():
    """An on-grid error path of gain a peaks at |a|² G_p / σ² in the (Hann, zero-padded)
    image: the processing gain of clradcom.evaluation.budget, an independent closed form."""
    from clradcom.evaluation.budget import processing_gain

    a, sigma2 = 2e-7, 1e-12
    dF = synthesize_frequency_domain(np.ones((64, 32)), [a], [6 / SMALL.bandwidth], [0.0],
                                     SMALL)
    H = np.full((64, 32), 1e-5 + 0j)
    got = acc.image_error_to_noise_db(H + dF, H, sigma2, SMALL)
    assert got == pytest.approx(10 * math.log10(a**2 * processing_gain(64, 32) / sigma2),
                                abs=0.01)
    assert got <= acc.error_to_noise_db(H + dF, H, sigma2)
    # a diffuse error (many weak random paths) sits far below the Cauchy-Schwarz bound
    rng = np.random.default_rng(2)
    diffuse = 1e-8 * (rng.normal(size=(64, 32)) + 1j * rng.normal(size=(64, 32)))
    assert (acc.image_error_to_noise_db(H + diffuse, H, sigma2, SMALL)
            < acc.error_to_noise_db(H + diffuse, H, sigma2) - 20.0)
    assert acc.image_error_to_noise_db(H, H, sigma2, SMALL) == -math.inf
    with pytest.raises(ValueError, match="noise_variance"):
        acc.image_error_to_noise_db(H, H, -1.0, SMALL)


# ---------------------------------------------------------------------------
# path sets
def paths(rows):
    """rows: (|a|^2, [codes], [faces]) -> path arrays (K = the longest)."""
    P, K = len(rows), max(len(r[1]) for r in rows)
    inter = np.zeros((P, K), np.int8)
    face = np.full((P, K), -1, np.int32)
    n = np.zeros(P, np.int16)
    for i, (_, codes, faces) in enumerate(rows):
        n[i] = len(codes)
        inter[i, :len(codes)] = codes
        face[i, :len(faces)] = faces
    gain = np.sqrt([r[0] for r in rows]).astype(complex)
    # only what path_completeness reads (a full Paths insists on valid geometry)
    return SimpleNamespace(gain=gain, n_interactions=n, interaction=inter, face_id=face)


def test_path_completeness_by_signature_and_power():
    ref = paths([(4.0, [R], [1]), (1.0, [R, R], [2, 5]), (0.5, [S], [7]), (0.5, [S], [7]),
                 (1e-6, [D], [3])])
    got = paths([(4.0, [R], [1]), (0.2, [S], [7]), (0.2, [S], [7]), (0.2, [S], [7]),
                 (1.0, [D], [2]), (1.0, [R, R], [5, 2])])  # other faces / order: no match
    c = acc.path_completeness(ref, got)
    assert c.power_share == pytest.approx((4.0 + 0.6) / (4.0 + 1.0 + 1.0 + 1e-6))
    assert (c.n_reference, c.n_found) == (4, 2)
    above = acc.path_completeness(ref, got, power_floor=1e-3)  # the diffraction is below
    assert (above.n_reference, above.n_found) == (3, 2)
    assert above.count_share == pytest.approx(2 / 3)
    same = acc.path_completeness(ref, ref)
    assert same.power_share == pytest.approx(1.0) and same.count_share == 1.0
    # a setting stronger than the reference is credited with the reference's power only
    loud = acc.path_completeness(paths([(1.0, [R], [1])]), paths([(9.0, [R], [1])]))
    assert loud.power_share == pytest.approx(1.0)
    with pytest.raises(ValueError, match="power_floor"):
        acc.path_completeness(ref, got, power_floor=-1.0)


def test_path_signatures_and_kinds():
    p = paths([(1.0, [R, D], [4, 9]), (1.0, [S], [2]), (1.0, [R], [4])])
    sig = acc.path_signatures(p.n_interactions, p.interaction, p.face_id)
    assert sig == [(2, R, D, 4, 9), (1, S, 2), (1, R, 4)]
    assert list(acc.path_kind(p.interaction)) == ["diffraction", "scattering", "reflection"]
    with pytest.raises(ValueError, match="interaction and face_id"):
        acc.path_signatures(p.n_interactions, p.interaction[:2], p.face_id)


# ---------------------------------------------------------------------------
# detections
def test_detection_errors_against_truth_interval_and_velocity():
    dets = np.zeros(3, DETECTION_DTYPE)
    dets["range_m"] = [16.0, 25.3, 40.0]
    dets["velocity_mps"] = [26.0, 0.4, -3.0]
    dets["power_db"] = [30.0, 20.0, 10.0]
    truth = [{"name": "B", "range_nearest_m": 15.0, "range_centre_m": 16.5, "v_rel_m_s": 26.2},
             {"name": "C", "range_nearest_m": 24.0, "range_centre_m": 25.0, "v_rel_m_s": 0.0},
             {"name": "X", "range_nearest_m": 60.0, "range_centre_m": 61.0, "v_rel_m_s": 5.0}]
    e = acc.detection_errors(dets, truth, 2.0, 1.0)
    assert (e.n_targets, e.n_found, e.all_found) == (3, 2, False)
    assert e.per_target[0][1] == 0.0 and e.per_target[0][2] == pytest.approx(0.2)
    assert e.per_target[1][1] == pytest.approx(0.3) and e.per_target[1][2] == pytest.approx(0.4)
    assert e.per_target[2] == ("X", None, None)
    assert e.range_error_m == pytest.approx(0.3) and e.velocity_error_mps == pytest.approx(0.4)
    none = acc.detection_errors(dets[:0], truth[:1], 2.0, 1.0)
    assert none.n_found == 0 and math.isnan(none.range_error_m)
    with pytest.raises(ValueError, match="range_tol_m"):
        acc.detection_errors(dets, truth, 0.0, 1.0)


# ---------------------------------------------------------------------------
# Pareto front
def test_pareto_front_by_hand():
    cost = [1.0, 2.0, 3.0, 2.5, 4.0]
    err = [-5.0, -20.0, -30.0, -19.0, np.nan]
    assert list(acc.pareto_front(cost, err)) == [True, True, True, False, False]
    # with 2 dB of tolerance -20 and -19 count as equal: the cheaper still wins, and
    # point 2 (-30 at 3.0) beats point 3 by more than the tolerance
    assert list(acc.pareto_front(cost, err, tolerances=[2.0])) == [True, True, True, False,
                                                                   False]
    # a perfect match (-inf) at the highest cost stays on the front
    assert list(acc.pareto_front([1.0, 9.0], [0.0, -np.inf])) == [True, True]
    # within tolerance a costlier point with a hair better error is dominated
    assert list(acc.pareto_front([1.0, 2.0], [-20.0, -20.1], tolerances=[0.5])) == [True,
                                                                                  False]
    assert list(acc.pareto_front([1.0, 2.0], [-20.0, -20.1])) == [True, True]
    # two criteria: each point best in one
    assert list(acc.pareto_front([1, 1, 1], [1, 2, 3], [3, 2, 1])) == [True, True, True]
    with pytest.raises(ValueError, match="criterion 1"):
        acc.pareto_front([1, 2], [1])
    with pytest.raises(ValueError, match="tolerances"):
        acc.pareto_front([1, 2], [1, 2], tolerances=[-1.0])


# ---------------------------------------------------------------------------
# sweep points (clradcom.evaluation.tradeoff)
def test_settings_fields_by_flat_and_nested_names():
    assert tr.settings_field("rays") == "specular__rays"
    assert tr.settings_field("physical_optics") == "optics__mode"
    assert tr.settings_field("scattering_tile_size_m") == "scattering__tile_size_m"
    assert tr.settings_field("diffraction_reflections") == "diffraction__max_reflections"
    assert tr.settings_field("scattering.tile_size_m") == "scattering__tile_size_m"
    assert tr.settings_field("diffraction__max_hop_m") == "diffraction__max_hop_m"
    assert tr.settings_field("warp") is None and tr.settings_field("specular.warp") is None
    names = tr.vary_field_names()
    assert "scattering_tile_size_m" in names and "scattering.tile_size_m" in names
    assert "specular.rays" not in names  # a knob of its own
    s = tr.trace_settings({"rays": 1000, "max_reflections": 2, "max_diffractions": 0,
                           "physical_optics": "pec", "scattering": True,
                           "scattering.tile_size_m": 0.5, "diffraction_reflections": 1})
    assert (s.specular.rays, s.specular.max_reflections, s.optics.mode) == (1000, 2, "pec")
    assert s.scattering.enabled and s.scattering.tile_size_m == 0.5
    assert (s.diffraction.max_diffractions, s.diffraction.max_reflections) == (0, 1)
    with pytest.raises(ValueError, match="warp"):
        tr.trace_settings({"warp": 1})


def test_sweep_points_skip_what_cannot_differ():
    vary = [("scattering_tile_size_m", [0.25, 0.5]), ("diffraction_reflections", [0, 3])]
    points = tr.sweep_points([10_000, 1000], [0, 2], [0, 1], ["none"], [False, True], vary,
                             order_cap=5, scattering_threshold_db=-40.0,
                             scattering_floor=1e-15)
    keys = [tuple(sorted(p.items())) for p in points]
    assert len(keys) == len(set(keys))
    # no reflections: one ray count, the smallest
    assert {p["rays"] for p in points if p["max_reflections"] == 0} == {1000}
    assert {p["rays"] for p in points if p["max_reflections"] == 2} == {1000, 10_000}
    for p in points:
        # scattering's fields only where it is on; the tracer's threshold and floor there
        assert ("scattering_tile_size_m" in p) == p["scattering"]
        assert ("scattering_threshold_db" in p) == p["scattering"]
        if p["scattering"]:
            assert (p["scattering_threshold_db"], p["scattering_floor"]) == (-40.0, 1e-15)
        # reflections beside the edges: never more than the specular search, 0 without edges
        assert p["diffraction_reflections"] <= p["max_reflections"]
        if not p["max_diffractions"]:
            assert p["diffraction_reflections"] == 0
    # 3 scattering configurations (off, two tile sizes) each: r0 one ray count, d0 and d1
    # (reflections beside the edges clamped to 0); r2 two ray counts, d0 and d1 with
    # 0 or 2 reflections beside the edges
    assert len(points) == 2 * 3 + 2 * (3 + 2 * 3)
    ref = tr.reference_point([10_000, 1000], [0, 2, 5], [0, 1], ["none", "sbr"], [False, True],
                             vary, order_cap=3)
    assert ref == {"rays": 40_000, "max_reflections": 3, "max_diffractions": 1,
                   "physical_optics": "sbr", "scattering": True,
                   "scattering_tile_size_m": 0.5, "diffraction_reflections": 3}


# ---------------------------------------------------------------------------
# the tool
SCENE = CLOSING_PLATE_SCENE


def load_tool():
    return load_named_tool("tradeoff")


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tradeoff")
    scene = tmp / "plate.toml"
    scene.write_text(SCENE)
    out = tmp / "out"
    tool = load_tool()
    # a 50 dB margin puts the plate's edge diffractions (~34 dB over the floor; four in one
    # range-Doppler cell, summed in phase 6 dB more) below it
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        rc = tool.main([str(scene), "--out", str(out), "--rays", "2000", "--reflections", "1",
                        "--diffractions", "0,1", "--optics", "none,pec", "--scattering", "0",
                        "--synthesis", "fast,fast+prune,fast-lp", "--subcarriers", "256",
                        "--reference-synthesis", "fast",
                        "--symbols", "64", "--margin-db", "50", "--target-nmse-db=-20,-200",
                        "--target-range-m", "0", "--target-velocity-mps", "0"])
    return tool, rc, out, text.getvalue()


def test_tradeoff_tool_writes_a_consistent_sweep(sweep):
    tool, rc, out, text = sweep
    assert rc == 0
    assert (out / "tradeoff.png").stat().st_size > 10_000
    with open(out / "tradeoff.csv") as fh:
        rows = list(csv.DictReader(fh))
    # diffractions 0 and 1 x GO/PO, each with 3 back ends
    assert len(rows) == 2 * 2 * 3
    f = {k: np.array([float(r[k]) for r in rows]) for k in (
        "seconds", "channel_nmse_db", "power_share", "paths_traced", "paths_used",
        "pruned_diffraction", "trace_s", "synth_s", "process_s", "prune_s",
        "max_diffractions", "targets_found")}
    assert np.allclose(f["seconds"], f["trace_s"] + f["prune_s"] + f["synth_s"]
                       + f["process_s"], rtol=1e-4)
    prune = np.array([r["prune"] == "True" for r in rows])
    # pruning drops exactly the diffractions (below the raised floor), nothing else
    assert np.all(f["paths_traced"] - f["paths_used"] == f["pruned_diffraction"])
    assert np.all(f["pruned_diffraction"][~prune] == 0)
    go = np.array([r["physical_optics"] == "none" for r in rows])
    with_d = prune & (f["max_diffractions"] == 1)
    assert (with_d & go).any() and np.all(f["pruned_diffraction"][with_d & go] > 0)
    # with PO on the plate its edges diffract no UTD (the facet integral carries them)
    assert np.all(f["pruned_diffraction"][~go] == 0)
    # the setting equal to the reference (r1 d1 pec, fast, nothing pruned)
    ref = [i for i, r in enumerate(rows) if r["max_reflections"] == "1"
           and r["max_diffractions"] == "1" and r["physical_optics"] == "pec"
           and r["synthesis"] == "fast" and r["prune"] == "False"]
    assert len(ref) == 1
    # the same paths synthesised again: equal up to the NUFFT's threaded summation order
    assert f["channel_nmse_db"][ref[0]] < -200.0 and f["power_share"][ref[0]] == 1.0
    assert float(rows[ref[0]]["image_error_db"]) < -100.0
    # the image error never exceeds its bound
    assert all(float(r["image_error_db"]) <= float(r["error_to_noise_db"]) + 1e-9
               for r in rows)
    # the same paths at NUFFT tolerance 1e-5: a small error, not zero
    lp = [i for i, r in enumerate(rows) if r["max_reflections"] == "1"
          and r["max_diffractions"] == "1" and r["physical_optics"] == "pec"
          and r["synthesis"] == "fast-lp"]
    assert -160.0 < f["channel_nmse_db"][lp[0]] < -60.0
    # GO with no diffraction misses the PO returns' power
    go = [i for i, r in enumerate(rows) if r["physical_optics"] == "none"
          and r["max_diffractions"] == "0"]
    assert np.all(f["power_share"][go] < 0.999)
    assert np.all(f["targets_found"] == 1)
    # the Pareto flags are the fronts of the CSV's own numbers
    tol = tr.PARETO_TOLERANCES
    front = acc.pareto_front(f["seconds"], f["channel_nmse_db"], tolerances=tol[:1])
    assert list(front) == [r["pareto_channel"] == "True" for r in rows]
    # the reference's accuracy is on the front: itself, or a faster setting as exact (with
    # PO on the plate, diffraction adds nothing there, so d0 pec equals d1 pec)
    assert front[ref[0]] or np.any(
        front & (f["channel_nmse_db"] <= f["channel_nmse_db"][ref[0]] + tol[0])
        & (f["seconds"] <= f["seconds"][ref[0]]))
    image = acc.pareto_front(f["seconds"], [float(r["image_error_db"]) for r in rows],
                             tolerances=tol[1:2])
    assert list(image) == [r["pareto_image"] == "True" for r in rows]
    share = acc.pareto_front(f["seconds"], [1 - float(r["count_share"]) for r in rows],
                             tolerances=tol[2:3])
    assert list(share) == [r["pareto_completeness"] == "True" for r in rows]
    assert "channel_nmse_db <= -20, min_targets_found >= 1:" in text
    # only the reference's paths meet -200 dB: its own setting, or the same without the
    # diffraction (or its pruning) that the PO plate no longer gets; the fastest of those
    # equals is named
    assert re.search(r"channel_nmse_db <= -200, min_targets_found >= 1: 2e\+03 r1 d[01] pec "
                     r"fast(\+prune)? \(", text)
    # the sweep's time was estimated from the reference before it began
    assert re.search(r"= 12 settings; estimated \d+ s \(from the reference's", text)
    assert "range_error_m <= 0, velocity_error_mps <= 0, min_targets_found >= 1: no setting" \
        in text
    assert "pruned below the floor" in text


def test_tradeoff_tool_redraws_from_its_csv(sweep, tmp_path, capsys):
    tool, _, out, _ = sweep
    again = tmp_path / "again"
    assert tool.main([str(out.parent / "plate.toml"), "--out", str(again), "--from-csv",
                      str(out / "tradeoff.csv"), "--subcarriers", "256", "--symbols", "64",
                      "--target-nmse-db=-20"]) == 0
    with open(out / "tradeoff.csv") as fh:
        first = list(csv.DictReader(fh))
    with open(again / "tradeoff.csv") as fh:
        second = list(csv.DictReader(fh))
    assert [r["pareto_all"] for r in first] == [r["pareto_all"] for r in second]
    assert [r["channel_nmse_db"] for r in first] == [r["channel_nmse_db"] for r in second]
    assert (again / "tradeoff.png").stat().st_size > 10_000
    assert "channel_nmse_db <= -20, min_targets_found >= 1:" in capsys.readouterr().out
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    assert tool.main([str(out.parent / "plate.toml"), "--out", str(again), "--from-csv",
                      str(bad)]) == 2
    assert "bad.csv" in capsys.readouterr().err


def test_tradeoff_tool_refuses_bad_arguments_by_name(tmp_path, capsys):
    scene = tmp_path / "plate.toml"
    scene.write_text(SCENE)
    tool = load_tool()
    assert tool.main([str(scene), "--out", str(tmp_path / "o"), "--radar", "Z"]) == 2
    assert "'Z'" in capsys.readouterr().err
    assert tool.main([str(scene), "--out", str(tmp_path / "o"), "--vary", "warp=1,2"]) == 2
    assert "'warp'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        tool.main([str(scene), "--synthesis", "slow"])
    assert "slow" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENE.replace('material = "metal"', 'material = "unobtainium"'))
    assert tool.main([str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "unobtainium" in capsys.readouterr().err
    assert not (tmp_path / "o" / "tradeoff.csv").exists()


def test_default_grid_is_small_and_full_is_behind_an_option():
    tool = tradeoff_command
    args = tool.parse_args(["s.toml"])
    tool.apply_grid(args)
    points = tr.sweep_points(args.rays, args.reflections, args.diffractions, args.optics,
                             args.scattering)
    # a grid of minutes: 32 traces, two fast back ends, a fast reference
    assert len(points) == 32 and len(args.synthesis) == 2
    assert args.reference_synthesis == "fast"
    full = tool.parse_args(["s.toml", "--full", "--rays", "1000"])
    tool.apply_grid(full)
    assert full.rays == [1000]  # a knob given wins over --full's
    assert full.reflections == [0, 1, 2, 5] and full.reference_synthesis == "exact"
    assert len(full.synthesis) == 4


def test_sweep_time_estimate_scales_the_reference_by_rays():
    points = [{"rays": 1000}, {"rays": 4000}, {"rays": 8000}]
    # traces: 10 s x (1/8 + 1/2 + 1); each of 2 back ends 0.5 s per trace
    assert tr.estimate_sweep_seconds(points, 2, 8000, 10.0, 0.5) == pytest.approx(
        10.0 * (1 / 8 + 1 / 2 + 1) + 3 * 2 * 0.5)


def test_a_sweep_over_its_budget_is_refused_before_it_starts(tmp_path, capsys):
    scene = tmp_path / "plate.toml"
    scene.write_text(SCENE)
    tool = load_tool()
    rc = tool.main([str(scene), "--out", str(tmp_path / "o"), "--rays", "2000",
                    "--reflections", "1", "--diffractions", "0", "--optics", "pec",
                    "--scattering", "0", "--subcarriers", "64", "--symbols", "16",
                    "--budget-s", "1e-6"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "--budget-s" in err and "estimated" in err
    assert not (tmp_path / "o" / "tradeoff.csv").exists()


TWO_CARS = """
[scene]
name = "two_cars"
carrier_hz = 24e9

[[objects]]
name = "road"
material = "concrete_road"
shape = "plane"
size = [120.0, 16.0]
position = [20.0, 0.0, 0.0]

[[objects]]
name = "carB"
material = "metal"
mesh = "{car}"
position = [30.0, 1.75, 0.0]
rotation_deg = [0.0, 0.0, 180.0]
velocity = [-13.3, 0.0, 0.0]

[[objects]]
name = "carC"
material = "metal"
mesh = "{car}"
position = [20.0, -1.75, 0.0]
velocity = [27.0, 0.0, 0.0]

[[radars]]
name = "radarA"
position = [1.95, -1.75, 0.5]
velocity = [12.9, 0.0, 0.0]
pattern = {{ type = "sector", azimuth_width_deg = 90.0, elevation_width_deg = 180.0 }}
tx_power_w = 0.01
noise_figure_db = 10.0
"""


def test_nmse_target_picks_a_setting_that_detects_the_cars(tmp_path):
    # a radar 0.5 m over the road: the road right under it is the channel. GO with one
    # reflection traces that return alone (NMSE -45 dB against the reference) and finds no
    # car; the choice for NMSE <= -30 dB must find the cars the reference finds: both
    car = (Path(__file__).resolve().parent.parent / "scenes" / "street" / "meshes"
           / "car.ply").as_posix()
    scene = tmp_path / "two_cars.toml"
    scene.write_text(TWO_CARS.format(car=car))
    out = tmp_path / "o"
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        rc = load_tool().main([str(scene), "--out", str(out), "--rays", "2000",
                               "--reflections", "1", "--diffractions", "0", "--optics",
                               "none,pec", "--scattering", "0", "--synthesis", "fast",
                               "--subcarriers", "1024", "--symbols", "128",
                               "--target-nmse-db=-30"])
    assert rc == 0, text.getvalue()
    with open(out / "tradeoff.csv") as fh:
        rows = {r["physical_optics"]: r for r in csv.DictReader(fh)}
    need = int(rows["pec"]["reference_found"])
    assert need == int(rows["pec"]["targets"]) == 2  # the reference finds both cars
    # the GO setting meets the NMSE alone, and is the cheaper one, but finds nothing
    go, po = rows["none"], rows["pec"]
    assert float(go["channel_nmse_db"]) <= -30 and int(go["targets_found"]) == 0
    chosen = re.search(r"channel_nmse_db <= -30, min_targets_found >= (\d+): (\S+ r\d d\d "
                       r"(\w+))", text.getvalue())
    assert chosen and int(chosen.group(1)) == need and chosen.group(3) == "pec"
    assert int(po["targets_found"]) == 2  # the chosen setting finds every car
