"""Outputs are written whole or not at all, keep their permissions, never replace an
input, and a run's folder is swapped in as a whole (clradcom.files)."""

import os
import stat

import matplotlib

matplotlib.use("Agg")
import pytest
from matplotlib.figure import Figure

from clradcom.errors import ArgumentError
from clradcom.files import OutputError, atomic_write, save_figure, staged_folder


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_replaces_whole_and_keeps_permissions(tmp_path):
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    os.chmod(target, 0o600)
    atomic_write(target, lambda fh: fh.write(b"new contents"))
    assert target.read_bytes() == b"new contents"
    assert stat.S_IMODE(target.stat().st_mode) == 0o600
    assert leftovers(tmp_path) == []


def test_new_file_gets_the_umask_mode(tmp_path):
    umask = os.umask(0o022)
    try:
        atomic_write(tmp_path / "fresh", lambda fh: fh.write(b"x"))
    finally:
        os.umask(umask)
    assert stat.S_IMODE((tmp_path / "fresh").stat().st_mode) == 0o644


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_failure_midway_leaves_old_file_and_nothing_else(tmp_path, exc):
    target = tmp_path / "out.svg"
    target.write_bytes(b"old svg")

    def half(fh):
        fh.write(b"<svg> cut off")
        raise exc

    with pytest.raises(type(exc)):
        atomic_write(target, half)
    assert target.read_bytes() == b"old svg"
    assert leftovers(tmp_path) == []


def test_missing_folder_and_folder_target_are_output_errors(tmp_path):
    with pytest.raises(OutputError, match="does not exist"):
        atomic_write(tmp_path / "nope" / "f", lambda fh: fh.write(b"x"))
    with pytest.raises(OutputError, match="is a folder"):
        atomic_write(tmp_path, lambda fh: fh.write(b"x"))


def test_full_disk_is_an_output_error_naming_the_file(tmp_path):
    target = tmp_path / "sweep.csv"
    target.write_bytes(b"the only copy")

    def full(fh):
        raise OSError(28, "No space left on device")

    with pytest.raises(OutputError, match="sweep.csv.*No space left"):
        atomic_write(target, full)
    assert target.read_bytes() == b"the only copy"


def test_an_input_is_never_overwritten(tmp_path):
    source = tmp_path / "tradeoff.csv"
    source.write_text("a,b\n1,2\n")
    with pytest.raises(ArgumentError, match="input file"):
        atomic_write(source, lambda fh: fh.write(b"x"), inputs=[source])
    assert source.read_text() == "a,b\n1,2\n"


def test_staged_folder_swaps_whole_or_keeps_old(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "old.png").write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with staged_folder(out) as stage:
            (stage / "new.png").write_bytes(b"new")
            raise RuntimeError("interrupted")
    assert sorted(p.name for p in out.iterdir()) == ["old.png"]
    assert leftovers(tmp_path) == []
    with staged_folder(out) as stage:
        (stage / "new.png").write_bytes(b"new")
    assert sorted(p.name for p in out.iterdir()) == ["new.png"]
    assert leftovers(tmp_path) == []


def test_staged_folder_refuses_a_file_and_a_folder_holding_an_input(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="not a folder"):
        with staged_folder(tmp_path / "file"):
            pass
    folder = tmp_path / "sweep"
    folder.mkdir()
    (folder / "in.csv").write_text("x")
    with pytest.raises(ArgumentError, match="holds an input"):
        with staged_folder(folder, inputs=[folder / "in.csv"]):
            pass
    assert (folder / "in.csv").read_text() == "x"


@pytest.mark.parametrize("suffix", ["svg", "png", "pdf"])
def test_identical_figures_give_identical_bytes(tmp_path, suffix):
    def draw(path):
        fig = Figure(figsize=(3, 2))
        ax = fig.add_subplot()
        ax.plot([0, 1, 2], [1, 0, 1])
        ax.imshow([[0, 1], [1, 0]])  # an image: SVG clip paths get random ids otherwise
        save_figure(fig, path)
        return path.read_bytes()

    assert draw(tmp_path / f"a.{suffix}") == draw(tmp_path / f"b.{suffix}")


def _dead_pid() -> int:
    import subprocess
    import sys
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_a_killed_runs_staging_folder_is_removed_by_the_next_run(tmp_path):
    """SIGKILL leaves the staging folder; the next run into the same place names and
    removes it where its process is gone, and leaves alone what may still be written."""
    import warnings as _w

    from clradcom import files
    tag = files._host_tag()
    dead = tmp_path / f".out.{tag}p{_dead_pid()}-{'a' * 12}.new"
    live = tmp_path / f".out.{tag}p{os.getpid()}-{'b' * 12}.new"
    elsewhere = tmp_path / f".out.{'0' * 8}p1-{'c' * 12}.new"
    older = tmp_path / f".out.{'d' * 12}.new"
    for d in (dead, live, elsewhere, older):
        d.mkdir()
        (d / "snapshot.npz").write_bytes(b"partial")
    with _w.catch_warnings(record=True) as caught:
        _w.simplefilter("always")
        with files.staged_folder(tmp_path / "out") as stage:
            (stage / "a.txt").write_text("new")
    assert not dead.exists()
    assert live.exists() and elsewhere.exists() and older.exists()
    texts = [str(w.message) for w in caught if issubclass(w.category, files.LeftoverWarning)]
    assert any(t.startswith(f"removed {dead}") for t in texts)
    assert any(str(elsewhere) in t and "remove it" in t for t in texts)
    assert any(str(older) in t for t in texts)
    assert not any(str(live) in t for t in texts)
    assert (tmp_path / "out" / "a.txt").read_text() == "new"
