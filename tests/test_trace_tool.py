"""tools/trace.py end to end on a small scene: outputs written, the target found."""

import csv

import numpy as np
import pytest
from tool_helpers import CLOSING_PLATE_SCENE, load_tool


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
