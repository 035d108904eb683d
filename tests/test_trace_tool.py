"""tools/trace.py end to end on a small scene: outputs written, the target found."""

import csv

import numpy as np
import pytest
from tool_helpers import CLOSING_PLATE_SCENE, load_tool

from clradcom.trace import SpecularSettings


def load_trace_tool():
    return load_tool("trace")


SCENE = CLOSING_PLATE_SCENE


def test_trace_tool_finds_a_closing_plate(tmp_path):
    scene = tmp_path / "closing_plate.toml"
    scene.write_text(SCENE)
    out = tmp_path / "out"
    tool = load_trace_tool()
    assert tool.main([str(scene), "--out", str(out), "--rays", "20000",
                      "--reflections", "2"]) == 0
    for name in ("snapshot.npz", "A_image.png", "A_image.svg", "A_detections.csv",
                 "A_truth.csv", "scene_top.png"):
        assert (out / name).stat().st_size > 0, name
    with open(out / "A_truth.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["object"] for r in rows] == ["plate"]
    # set range of the plate's centre 20 m, closing at 8 m/s
    assert float(rows[0]["range_detected_m"]) == pytest.approx(20.0, abs=0.2)
    assert float(rows[0]["velocity_detected_mps"]) == pytest.approx(8.0, abs=0.3)
    with open(out / "A_detections.csv") as fh:
        dets = list(csv.DictReader(fh))
    strongest = max(dets, key=lambda d: float(d["power_db"]))
    assert np.isclose(float(strongest["range_m"]), 20.0, atol=0.2)


def test_trace_tool_refuses_a_bad_scene_with_a_message(tmp_path, capsys):
    scene = tmp_path / "bad.toml"
    scene.write_text(SCENE.replace('material = "metal"', 'material = "unobtainium"'))
    assert load_trace_tool().main([str(scene), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "unobtainium" in err
    assert not (tmp_path / "o" / "snapshot.npz").exists()


def test_settings_from_args_maps_every_flag_to_its_mechanism(capsys):
    tool = load_trace_tool()
    default = tool.settings_from_args(tool.build_parser().parse_args(["s.toml"]))
    assert (default.specular.max_reflections, default.specular.rays,
            default.specular.expand_rounds) == (5, 300_000, 4)
    assert default.diffraction.max_diffractions == 1
    assert default.diffraction.max_reflections == 0
    assert default.optics.mode == "sbr"
    assert default.scattering.enabled and default.scattering.max_reflections == 0
    s = tool.settings_from_args(tool.build_parser().parse_args([
        "s.toml", "--rays", "1000", "--expand-rounds", "0", "--reflections", "2",
        "--diffractions", "3", "--diffraction-reflections", "1", "--physical-optics", "none",
        "--no-scattering", "--scattering-reflections", "2"]))
    assert s.specular == SpecularSettings(max_reflections=2, rays=1000, expand_rounds=0)
    assert (s.diffraction.max_diffractions, s.diffraction.max_reflections) == (3, 1)
    assert s.optics.mode == "none"
    assert not s.scattering.enabled and s.scattering.max_reflections == 2
    # refused where it is parsed, naming the option and the value
    with pytest.raises(SystemExit):
        tool.build_parser().parse_args(["s.toml", "--rays", "0"])
    assert "argument --rays: must be a positive integer, got '0'" in capsys.readouterr().err


def test_the_main_job_prints_the_papers_table_iii_beside_the_detections(tmp_path, capsys):
    """The street run prints, for radar A, each car's set values and detections beside
    the paper's Table III (set and simulated), and nothing of the paper for radar D."""
    from pathlib import Path

    street = Path(__file__).resolve().parent.parent / "scenes" / "street" / "street.toml"
    assert load_trace_tool().main([str(street), "--preset", "go", "--rays", "5000",
                                   "--reflections", "1", "--diffractions", "0", "--quiet",
                                   "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    a = out[out.index("  A: "):out.index("  D: ")]
    d = out[out.index("  D: "):]
    assert "paper (Sit et al.), Table III" in a and "Table III" not in d
    rows = {line.split()[0]: line for line in a.splitlines() if line.startswith("    car")}
    # object, our set R and v, our detection, then the paper's set R, v and simulated R, v
    for car, paper in {"carB": "16.40   26.20   16.10   25.70",
                       "carC": "26.00    0.00   25.20    0.00",
                       "carD": "34.60   27.40   34.40   27.40"}.items():
        ours, theirs = rows[car].split("|")
        assert theirs.split() == paper.split()
        assert float(ours.split()[1]) == pytest.approx(float(paper.split()[0]), abs=0.01)
