"""The tracker on the paper's street driven for half a second (`clradcom drive
scenes/street/street_drive.toml --radar A`, the paper preset and frame): one confirmed
track per car in view and none else, OSPA per frame small once the tracks are confirmed
(docs/tracking.md)."""

from __future__ import annotations

import contextlib
import csv
import io
from pathlib import Path

import numpy as np

from clradcom import cli

ROOT = Path(__file__).resolve().parent.parent
FRAMES = 10  # car B is visible in the first 10 frames (0.45 s), C and D in all


def _csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return rows


def test_street_drive_has_one_confirmed_track_per_car_and_none_else(tmp_path, runtime):
    out = tmp_path / "out"
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        code = cli.main(["drive", str(ROOT / "scenes" / "street" / "street_drive.toml"),
                         "--radar", "A", "--count", str(FRAMES), "--workers", "0",
                         "--no-video", "--out", str(out)])
    assert code == 0, text.getvalue()
    truth = _csv(out / "A_track_truth.csv")
    tracks = _csv(out / "A_tracks.csv")
    frames = _csv(out / "A_frames.csv")
    cars = sorted({r["object"] for r in truth if r["visible"] == "1"})
    assert cars == ["carB", "carC", "carD"]
    per_car = {c: {r["track"] for r in truth if r["object"] == c and r["visible"] == "1"
                   and r["track"] != "-1"} for c in cars}
    # each car in view followed by one track, not shared
    assert all(len(t) == 1 for t in per_car.values()), per_car
    assert len(set().union(*per_car.values())) == len(cars)
    # and no other track was ever confirmed: not the mounting, the road, the buildings
    # or a multiple bounce
    confirmed = {r["track"] for r in tracks if r["confirmed"] == "1"}
    assert confirmed == set().union(*per_car.values())
    # once the three tracks are confirmed, every frame has as many confirmed tracks as
    # visible cars and an OSPA distance under half its cut-off of 3 cells (car B's
    # closing speed changes fastest as it nears the edge of the beam: its track, coasting
    # through a missed frame, lags by up to 1.5 velocity cells)
    late = [f for f in frames if int(f["frame"]) >= 6]
    assert all(f["confirmed_tracks"] == f["visible_objects"] == "3" for f in late), late
    assert max(float(f["ospa_cells"]) for f in late) < 1.5
    ospa = np.array([float(f["ospa_cells"]) for f in frames])
    assert ospa[0] == 3.0  # nothing confirmed in the first frame: every car missed
    assert "OSPA" in text.getvalue()
