"""clradcom sweep: presets x --vary values, a snapshot per task equal to trace_scene's,
the CSV index, refusals as one line."""

from __future__ import annotations

import csv
from pathlib import Path

from clradcom.cli import main
from clradcom.scene.reader import load_scene
from clradcom.snapshot import assert_snapshot_equal, load_snapshot
from clradcom.trace import TraceSettings, trace_scene

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "canonical" / "corner.toml"


def test_sweep_writes_one_snapshot_per_setting(tmp_path, capsys):
    out = tmp_path / "sweep"
    code = main(["sweep", str(SCENE), "--preset", "fast,paper", "--vary",
                 "specular.rays=5000,10000", "--workers", "0", "--out", str(out), "-q"])
    assert code == 0, capsys.readouterr().err
    with open(out / "sweep.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["preset"], int(r["specular.rays"])) for r in rows] == [
        ("fast", 5000), ("fast", 10000), ("paper", 5000), ("paper", 10000)]
    scene = load_scene(SCENE)
    for row in rows:
        snap = load_snapshot(out / row["file"])
        want = trace_scene(scene, TraceSettings.preset(
            row["preset"], specular__rays=int(row["specular.rays"])))
        assert_snapshot_equal(snap, want)
        assert int(row["paths"]) == sum(lk.paths.n_paths for lk in snap) > 0
        assert row["worker"] == "serial"


def test_sweep_refuses_bad_fields_in_one_line(tmp_path, capsys):
    code = main(["sweep", str(SCENE), "--vary", "specular.nope=1", "--workers", "0",
                 "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2
    assert "--vary" in err and "specular.nope" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()
