"""The paper's street with radar A's 3 tx x 4 rx TDM-MIMO array (street_mimo.toml): cars
B, C and D found within one range, velocity and azimuth cell of their truth, buildings
beyond 60 m and the trees in the point cloud, and ``clradcom cube`` end to end.

Fewer rays (1e5) and a coarser SBR tube pitch (2 wavelengths) than the paper preset, one
link: the cars' echoes are the PO/SBR returns of their faces, which these settings keep."""

import csv

import numpy as np
import pytest
from tool_helpers import ROOT

from clradcom.cli import main as cli_main
from clradcom.commands import trace as trace_cmd
from clradcom.radar.array_frame import array_offsets, array_truth, run_array_radar
from clradcom.radar.pointcloud import read_point_cloud_ply
from clradcom.radar.truth import detection_truth
from clradcom.radar.waveform import Waveform
from clradcom.scene.reader import load_scene
from clradcom.trace import trace_scene

SCENE = ROOT / "scenes" / "street" / "street_mimo.toml"
FAST = ["--rays", "100000", "--sbr-spacing", "2"]
CARS = ["carB", "carC", "carD"]


@pytest.fixture(scope="module")
def street(runtime):
    scene = load_scene(SCENE)
    args = trace_cmd.build_parser().parse_args([str(SCENE), *FAST])
    a = scene.radar_index("A")
    snap = trace_scene(scene, trace_cmd.settings_from_args(args), runtime=runtime,
                       links=[(a, a)])
    return scene, scene.radars[a], snap.links[0].paths


def test_the_array_is_a_filled_12_element_virtual_ula_at_half_a_wavelength(street):
    scene, radar, _ = street
    tx, rx, virt = array_offsets(radar)
    assert tx.shape == (3, 3) and rx.shape == (4, 3)
    lam = scene.wavelength_m
    y = np.sort(virt[:, 1])
    np.testing.assert_allclose(np.diff(y), lam / 2, rtol=1e-9)
    assert np.all(virt[:, [0, 2]] == 0)


def test_cars_b_c_d_within_one_cell_in_range_velocity_and_azimuth(street):
    """With thermal noise at the scene's power and noise figure. Truth: range the interval
    from the car's nearest triangle to its centre, radial velocity and azimuth of its
    centre (clradcom.radar.array_frame)."""
    scene, radar, paths = street
    res = run_array_radar(paths, radar, Waveform(carrier_hz=scene.carrier_hz),
                          tx_power_w=radar.tx_power_w, noise_figure_db=radar.noise_figure_db)
    assert res.waveform.n_symbols == 255  # 85 per transmitter
    rows = array_truth(detection_truth(scene, "A", CARS), res)
    for t in rows:
        assert t["detection"] is not None, t["name"]
        assert t["range_error_cells"] <= 1.0
        assert t["velocity_error_cells"] <= 1.0
        assert t["azimuth_error_cells"] <= 1.0, (t["name"], t["azimuth_deg"],
                                                 np.degrees(t["detection"]["azimuth_rad"]))
    # B and D sit in the other lane: clearly off boresight, and found there
    az = {t["name"]: np.degrees(t["detection"]["azimuth_rad"]) for t in rows}
    assert az["carB"] > 6.0 and abs(az["carC"]) < 4.0


def test_buildings_beyond_60_m_and_trees_in_the_point_cloud(street):
    """Noise-free, as the paper's simulation (CFAR floor at the synthesis accuracy): points
    beyond 60 m inside the street at the radar's own speed (the buildings and trees along
    the road, the paper's Fig. 3), and points on the trees."""
    scene, radar, paths = street
    res = run_array_radar(paths, radar, Waveform(carrier_hz=scene.carrier_hz))
    p = res.points
    x_end = scene.triangles[..., 0].max()
    d = np.hypot(p["x"] - radar.position[0], p["y"] - radar.position[1])
    speed = float(np.linalg.norm(radar.velocity))
    far = (d > 60.0) & (p["x"] < x_end) & (np.abs(p["y"]) < 20.0)
    static = far & (np.abs(p["velocity_mps"] - speed) <= res.velocity_cell_mps)
    assert static.sum() >= 3, p[far]
    trees = [o for o in scene.objects if o.name.startswith("tree")]
    centres = np.array([scene.triangles[o.tri_slice].reshape(-1, 3).mean(axis=0)
                        for o in trees])
    gap = np.hypot(p["x"][:, None] - centres[None, :, 0], p["y"][:, None] - centres[None, :, 1])
    # within the crown's radius (1.5 m x scale <= 1.15) of a tree's axis
    assert (gap.min(axis=0) < 1.75).sum() >= 3


def test_cube_command_writes_the_point_cloud_and_prints_the_table(tmp_path, capsys, runtime):
    out = tmp_path / "cube"
    assert cli_main(["cube", str(SCENE), *FAST, "--out", str(out), "-q"]) == 0
    text = capsys.readouterr().out
    for name in CARS:
        assert name in text
    assert "cells: range 1.610 m, velocity 1.979 m/s" in text
    pts = read_point_cloud_ply(out / "A_points.ply")
    with open(out / "A_points.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == pts.size > 10
    np.testing.assert_allclose([float(r["x"]) for r in rows], pts["x"])
    with open(out / "A_cube_truth.csv", newline="") as fh:
        truth = {r["object"]: r for r in csv.DictReader(fh)}
    assert sorted(truth) == CARS
    assert all(float(truth[c]["azimuth_error_cells"]) <= 1.0 for c in CARS)
    assert (out / "A_bird_eye.png").stat().st_size > 10_000


def test_cube_refuses_a_radar_without_an_array(tmp_path):
    scene = ROOT / "scenes" / "street" / "street.toml"
    assert cli_main(["cube", str(scene), "--out", str(tmp_path / "x"), "-q"]) == 2
