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


def _worker_processes(pid: int) -> list:
    """The Dask worker processes under process ``pid`` (multiprocessing's spawned
    children of its nannies)."""
    import psutil

    try:
        children = psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []
    out = []
    for child in children:
        try:
            if any("spawn_main" in part for part in child.cmdline()):
                out.append(child)
        except psutil.Error:
            continue
    return out


def test_ctrl_c_during_a_distributed_sweep_is_one_line_and_exit_130(tmp_path):
    """Ctrl-C at a terminal signals the whole process group: the command stops the
    cluster and says so in one line (exit 130); the workers print nothing, the output
    folder is not created, no staging folder stays behind."""
    import os
    import signal
    import subprocess
    import sys

    street = Path(__file__).resolve().parents[1] / "scenes" / "street" / "street.toml"
    out = tmp_path / "sweep"
    # ten paper traces: after the first is in, seconds of work per worker remain, however
    # fast a repeated trace of the street has become
    proc = subprocess.Popen(
        [sys.executable, "-m", "clradcom", "sweep", str(street), "--preset",
         ",".join(["paper"] * 10), "--workers", "2", "--out", str(out), "-q"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        first = proc.stdout.readline().decode()
        assert "traces of" in first, first
        # Ctrl-C while the cluster starts is ignored (distributed._interrupts_ignored: the
        # workers must inherit SIGINT ignored); this test wants it while the workers
        # trace: the first trace's line says the cluster is up, however loaded the machine
        second = proc.stdout.readline().decode()
        assert "sweep-" in second and "paths" in second, second
        assert len(_worker_processes(proc.pid)) == 2
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    lines = [ln for ln in err.decode().splitlines() if ln.strip()]
    assert proc.returncode == 130, err.decode()
    assert lines[-1] == "clradcom sweep: interrupted; the output folder was left as it was"
    # the whole stderr in the message: pytest shortens a list's repr, and a rare traceback
    # at shutdown is only worth its full text
    assert not any("Traceback" in ln or "KeyboardInterrupt" in ln for ln in lines), (
        "\n".join(lines))
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".sweep.")]
