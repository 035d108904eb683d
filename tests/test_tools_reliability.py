"""The tools in tools/ lose nothing and are never silently wrong: outputs go through
clradcom.files (whole or not at all, never over an input, a folder swapped in whole,
identical bytes for identical runs), options are refused where they are parsed with the
option and the value, radar-stage inputs and memory are checked before any tracing, and
errors are one line with exit code 2. Every test writes only into tmp_path."""

from __future__ import annotations

import errno
import os
import re
from pathlib import Path

import pytest
from dsp_helpers import los_paths
from tool_helpers import ROOT, load_tool

import clradcom.commands.trace as trace_command
import clradcom.commands.tradeoff as tradeoff_command
import clradcom.trace as trace_module
from clradcom.errors import ArgumentError, MemoryBudgetError
from clradcom.evaluation import tradeoff as tr
from clradcom.files import OutputError, staged_folder, write_csv
from clradcom.memory import ENV_MEMORY_BUDGET, check_memory, memory_budget_bytes
from clradcom.radar import Waveform
from clradcom.radar.pipeline import check_frame_memory, frame_memory_bytes, process, radar_frame
from clradcom.radar.plots import plot_radar_image, save_radar_image
from clradcom.radar.synthesis import thermal_noise_power
from clradcom.scene import load_scene
from clradcom.snapshot import Link, Snapshot, save_snapshot
from clradcom.trace import SpecularSettings, TraceSettings, launch_memory_bytes, trace_scene

PLATE = ROOT / "scenes" / "canonical" / "plate.toml"
TRACE_OUTPUTS = ["radar_detections.csv", "radar_image.png", "radar_image.svg",
                 "radar_truth.csv", "scene_top.png", "snapshot.npz"]


@pytest.fixture(scope="module")
def trace_tool():
    return load_tool("trace")


@pytest.fixture(scope="module")
def tradeoff_tool():
    return load_tool("tradeoff")


@pytest.fixture(scope="module")
def interference_tool():
    return load_tool("interference")


def error_lines(err: str) -> list[str]:
    """stderr's lines less the physics warnings a run prints on its way (each once, then
    their count), which are not the error: the error must be one line of its own."""
    return [ln for ln in err.splitlines()
            if ": warning: " not in ln and not re.search(r": \d+ warnings? \(", ln)]


def run_trace(tool, out, *extra, scene=PLATE):
    return tool.main([str(scene), "--out", str(out), "--rays", "2000", "--reflections", "1",
                      *extra])


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def plate_with(tmp_path, line: str, name: str = "plate.toml") -> Path:
    """plate.toml with one more line in its radar's table (or its carrier replaced)."""
    text = PLATE.read_text()
    if line.startswith("carrier_hz"):
        text = text.replace("carrier_hz = 24e9", line)
    else:
        text = text.replace('role = "txrx"', f'role = "txrx"\n{line}')
    path = tmp_path / name
    path.write_text(text)
    return path


def never(*args, **kwargs):  # pragma: no cover - reached only if a check is missing
    raise AssertionError("work started before the input was checked")


def tradeoff_records(n=3):
    """Records as a sweep writes them (every column tradeoff.csv has)."""
    records = []
    for i in range(n):
        r = {c: 0 for c in tr.MEASURE_COLUMNS}
        r.update(setting=i, rays=1000 * (i + 1), max_reflections=1, max_diffractions=0,
                 physical_optics="pec", scattering=False, synthesis="fast", prune=False,
                 seconds=0.1 * (i + 1), channel_nmse_db=-10.0 * (i + 1),
                 image_error_db=-5.0 * i, error_to_noise_db=0.0, count_share=0.5 + 0.2 * i,
                 power_share=0.9, targets=1, targets_found=1, range_error_m=0.1,
                 velocity_error_mps=0.1, paths_traced=5 + i, paths_used=5 + i,
                 reference_s=1.0, reference_found=1, _extra=[], _dr=0.5, _dv=0.5)
        records.append(r)
    tr.mark_pareto(records)
    return records


# ----------------------------------------------------------------------------------------
# 1. nothing damaged: whole files, whole folders, never over an input
# ----------------------------------------------------------------------------------------
def test_trace_rerun_swaps_its_outputs_in_whole_and_keeps_what_is_not_its(trace_tool,
                                                                             tmp_path):
    out = tmp_path / "run"
    assert run_trace(trace_tool, out) == 0
    assert sorted(p.name for p in out.iterdir()) == TRACE_OUTPUTS
    (out / "notes.txt").write_text("mine")
    (out / "tradeoff").mkdir()
    (out / "tradeoff" / "tradeoff.csv").write_text("another tool's")
    (out / "B_image.png").write_bytes(b"an earlier run's radar B")
    assert run_trace(trace_tool, out, "--seed", "3") == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(TRACE_OUTPUTS
                                                           + ["notes.txt", "tradeoff"])
    assert (out / "notes.txt").read_text() == "mine"
    assert (out / "tradeoff" / "tradeoff.csv").read_text() == "another tool's"
    assert hidden(tmp_path) == []


def test_an_interrupted_or_failed_trace_leaves_the_old_folder_as_it_was(trace_tool, tmp_path,
                                                                       monkeypatch, capsys):
    out = tmp_path / "run"
    assert run_trace(trace_tool, out) == 0
    before = folder_bytes(out)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(trace_command, "save_radar_image", interrupted)
    assert run_trace(trace_tool, out, "--seed", "5") == 130
    assert "interrupted" in capsys.readouterr().err
    assert folder_bytes(out) == before
    assert hidden(tmp_path) == []

    # the disk fills up while the image is written: one line naming the file, old folder kept
    monkeypatch.undo()

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    assert run_trace(trace_tool, out, "--seed", "5") == 2
    err = capsys.readouterr().err
    assert len(error_lines(err)) == 1 and "Traceback" not in err
    assert err.startswith("trace.py: ") and "No space left on device" in err
    assert "snapshot.npz" in err  # the first file written
    assert folder_bytes(out) == before
    assert hidden(tmp_path) == []


def test_a_read_only_output_place_is_one_line_before_any_work(trace_tool, tmp_path,
                                                             monkeypatch, capsys):
    def read_only(self, *args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(Path, "mkdir", read_only)
    monkeypatch.setattr(trace_command, "trace_scene", never)
    assert run_trace(trace_tool, tmp_path / "ro" / "run") == 2
    err = capsys.readouterr().err
    assert len(error_lines(err)) == 1
    assert "ro/run" in err and "Read-only file system" in err


def test_tradeoff_from_csv_never_rewrites_its_input(tradeoff_tool, tmp_path, monkeypatch,
                                                    capsys):
    sweep = tmp_path / "out" / "plate" / "tradeoff"
    sweep.mkdir(parents=True)
    tr.write_tradeoff_csv(tradeoff_records(), [], sweep / "tradeoff.csv")
    source = (sweep / "tradeoff.csv").read_bytes()
    monkeypatch.chdir(tmp_path)
    # an --out that would replace the CSV is refused before anything is written
    assert tradeoff_tool.main([str(PLATE), "--from-csv", str(sweep / "tradeoff.csv"),
                               "--out", str(sweep)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tradeoff.py: --out = ") and "tradeoff.csv" in err
    assert folder_bytes(sweep) == {"tradeoff.csv": source}
    # the default output is a folder of its own beside the sweep's
    assert tradeoff_tool.main([str(PLATE), "--from-csv", str(sweep / "tradeoff.csv")]) == 0
    capsys.readouterr()
    assert folder_bytes(sweep) == {"tradeoff.csv": source}
    redrawn = tmp_path / "out" / "plate" / "tradeoff-from-csv"
    assert sorted(p.name for p in redrawn.iterdir()) == ["tradeoff.csv", "tradeoff.png"]
    # the disk is full: the input is untouched, one line names the output file
    before = folder_bytes(redrawn)

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    assert tradeoff_tool.main([str(PLATE), "--from-csv", str(sweep / "tradeoff.csv")]) == 2
    err = capsys.readouterr().err
    assert len(error_lines(err)) == 1 and "tradeoff.csv: cannot write (No space left" in err
    assert folder_bytes(sweep) == {"tradeoff.csv": source}
    assert folder_bytes(redrawn) == before


def test_a_bad_tradeoff_csv_is_blamed_by_option_and_reason(tradeoff_tool, tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    assert tradeoff_tool.main([str(PLATE), "--out", str(tmp_path / "o"), "--from-csv",
                               str(bad)]) == 2
    err = capsys.readouterr().err
    assert "--from-csv = " in err and "bad.csv" in err and "no column 'setting'" in err
    with pytest.raises(ArgumentError, match="path = .*missing.csv.*cannot read it"):
        tr.read_tradeoff_csv(tmp_path / "missing.csv", Waveform())
    rows = tradeoff_records()
    rows[1]["seconds"] = "soon"
    tr.write_tradeoff_csv(rows, [], tmp_path / "t.csv")
    with pytest.raises(ArgumentError, match="row 2: seconds = 'soon' is no number"):
        tr.read_tradeoff_csv(tmp_path / "t.csv", Waveform())


def test_staged_folder_carries_what_the_run_does_not_own(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "a.png").write_bytes(b"old a")
    (out / "b.png").write_bytes(b"old b, not written again")
    (out / "notes.txt").write_text("keep")
    with staged_folder(out, owned=["*.png"]) as stage:
        (stage / "a.png").write_bytes(b"new a")
    assert folder_bytes(out) == {"a.png": b"new a", "notes.txt": b"keep"}
    # an input of an owned name is refused; one it does not own is kept
    with pytest.raises(ArgumentError, match="holds an input"):
        with staged_folder(out, inputs=[out / "a.png"], owned=["*.png"]):
            pass
    with staged_folder(out, inputs=[out / "notes.txt"], owned=["*.png"]) as stage:
        write_csv(stage / "t.png", [[1, 2]], ["x", "y"])
    assert folder_bytes(out) == {"notes.txt": b"keep", "t.png": b"x,y\r\n1,2\r\n"}
    assert hidden(tmp_path) == []


def test_staged_folder_refuses_the_current_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "precious.txt").write_text("x")
    for path in (".", str(tmp_path), str(tmp_path.parent)):
        with pytest.raises(OutputError, match="current folder"):
            with staged_folder(path):
                pass
    assert (tmp_path / "precious.txt").read_text() == "x"


def test_a_failed_swap_puts_everything_back(tmp_path, monkeypatch):
    out = tmp_path / "run"
    out.mkdir()
    (out / "old.png").write_bytes(b"old")
    (out / "notes.txt").write_text("keep")
    real_replace = os.replace

    def refuse_second_replace(src, dst):
        if str(src).endswith(".new"):
            raise OSError(errno.EXDEV, "Invalid cross-device link")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", refuse_second_replace)
    with pytest.raises(OutputError, match="cannot swap the new outputs in"):
        with staged_folder(out, owned=["*.png"]) as stage:
            (stage / "old.png").write_bytes(b"new")
    assert folder_bytes(out) == {"notes.txt": b"keep", "old.png": b"old"}
    assert hidden(tmp_path) == []


# ----------------------------------------------------------------------------------------
# 2. plain mistakes: refused before any work, naming what the user typed
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("tool,argv,message", [
    ("tradeoff", ["--subcarriers", "0"], "argument --subcarriers: must be a positive integer"),
    ("tradeoff", ["--symbols", "0"], "argument --symbols: must be a positive integer"),
    ("tradeoff", ["--seed", "-1"], "argument --seed: must be an integer in [0"),
    ("tradeoff", ["--rays", "-1"], "argument --rays: ray count 1 of '-1': must be a positive"),
    ("tradeoff", ["--rays", "1000,x"], "ray count 2 of '1000,x': must be an integer"),
    ("tradeoff", ["--reflections", "17"], "reflection order 1 of '17': must be an integer in"),
    ("tradeoff", ["--optics", "pec,po"], "must be one of ('none', 'pec', 'sbr'), got 'po'"),
    ("tradeoff", ["--margin-db", "nan"], "argument --margin-db: must be a finite number"),
    ("tradeoff", ["--target-range-m", "-1"], "argument --target-range-m: must be a finite "
                                             "number >= 0"),
    ("trace", ["--seed", "-1"], "argument --seed: must be an integer in [0"),
    ("trace", ["--rays", "0"], "argument --rays: must be a positive integer, got '0'"),
    ("trace", ["--reflections", "-1"], "argument --reflections: must be an integer in [0, 16]"),
    ("interference", ["--seed", "-2"], "argument --seed: must be an integer in [0"),
    ("interference", ["--noise-figure-db", "-3"], "argument --noise-figure-db: must be a "
                                                  "noise figure >= 0 dB"),
    ("interference", ["--tx-power-w", "0"], "argument --tx-power-w: must be a positive"),
    ("interference", ["--cfo-hz", "inf"], "argument --cfo-hz: must be a finite number"),
    ("rcs_aspect", ["--height-m", "nan"], "argument --height-m: must be a finite number"),
    ("make_street", ["--lane-width", "0"], "argument --lane-width: must be a positive"),
    ("bench_dsp", ["--seed", "-1"], "argument --seed: must be an integer in [0"),
    ("bench_paths", ["--orders", "1,0"], "order 2 of '1,0': must be an integer in [1, 16]"),
    ("bench_raycast", ["--rays", "0"], "argument --rays: must be a positive integer"),
    ("bench_bvh", ["--repeat", "0"], "argument --repeat: must be a positive integer"),
])
def test_options_are_refused_where_they_are_parsed(tool, argv, message, tmp_path, capsys):
    first = {"tradeoff": [str(PLATE)], "trace": [str(PLATE)],
             "interference": ["--snapshot", str(tmp_path / "s.npz")],
             "rcs_aspect": ["--out", str(tmp_path / "o")]}.get(tool, [])
    with pytest.raises(SystemExit) as info:
        load_tool(tool).main([*first, *argv])
    assert info.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("tool", ["trace", "tradeoff", "interference", "rcs_aspect",
                                  "make_street"])
def test_an_out_that_is_a_file_is_refused_by_name(tool, tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    first = {"trace": [str(PLATE)], "tradeoff": [str(PLATE)],
             "interference": ["--snapshot", str(tmp_path / "s.npz")]}.get(tool, [])
    with pytest.raises(SystemExit):
        load_tool(tool).main([*first, "--out", str(afile)])
    assert f"argument --out: '{afile}' exists and is not a folder" in capsys.readouterr().err
    assert afile.read_text() == "not a folder"


def test_too_many_rays_are_refused_before_tracing_with_the_estimate(trace_tool, tradeoff_tool,
                                                                   tmp_path, monkeypatch,
                                                                   capsys):
    monkeypatch.setattr(trace_module, "kept_geometry", never)
    assert trace_tool.main([str(PLATE), "--out", str(tmp_path / "a"),
                            "--rays", "10000000000"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("trace.py: --rays = 10000000000: launching 10000000000 rays")
    assert "TiB of memory, over the budget" in err and len(error_lines(err)) == 1
    # tradeoff's reference launches 4 x the most rays: the user's value is named
    assert tradeoff_tool.main([str(PLATE), "--out", str(tmp_path / "b"),
                               "--rays", "10000000000"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tradeoff.py: --rays = [10000000000]: launching 40000000000 rays")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    # the library refuses it too, before any geometry is built
    with pytest.raises(MemoryBudgetError, match="settings.specular.rays = 10000000000"):
        trace_scene(load_scene(PLATE), TraceSettings(
            specular=SpecularSettings(rays=10_000_000_000)))


def test_a_frame_too_large_is_refused_before_tracing(tradeoff_tool, tmp_path, monkeypatch,
                                                     capsys):
    monkeypatch.setattr(tradeoff_command, "get_runtime", never)
    assert tradeoff_tool.main([str(PLATE), "--out", str(tmp_path / "o"),
                               "--symbols", "100000000"]) == 2
    err = capsys.readouterr().err
    # the default sweep synthesises fast only; --full's exact synthesis needs more
    assert err.startswith("tradeoff.py: --symbols = 100000000: the 1024 x 100000000 radar "
                          "frame (fast synthesis) would need about")
    assert "choose fewer --subcarriers or --symbols" in err
    assert tradeoff_tool.main([str(PLATE), "--out", str(tmp_path / "o"), "--full",
                               "--symbols", "100000000"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tradeoff.py: --symbols = 100000000: the 1024 x 100000000 radar "
                          "frame (exact synthesis) would need about")
    wf = Waveform(n_symbols=100_000_000)
    with pytest.raises(MemoryBudgetError, match="N x M = 1024 x 100000000"):
        radar_frame(los_paths([1e-3], [1e-7], [0.0]), wf)


def test_memory_estimates_and_the_budget(monkeypatch):
    assert launch_memory_bytes(1000, 0) == 0  # no reflections: no rays launched
    assert launch_memory_bytes(1000, 5) == 160_000
    assert launch_memory_bytes(1000, 16) == (40 + 21 * 16) * 1000
    wf = Waveform(n_subcarriers=256, n_symbols=64)
    assert frame_memory_bytes(wf, "exact") > frame_memory_bytes(wf, "fast") > 16 * 256 * 64
    with pytest.raises(MemoryBudgetError, match="waveform = 'N x M = 256 x 64'"):
        check_frame_memory(wf, budget_bytes=1e6)
    check_frame_memory(wf, budget_bytes=1e9)
    monkeypatch.setenv(ENV_MEMORY_BUDGET, "2K")
    assert memory_budget_bytes() == (2048, f"{ENV_MEMORY_BUDGET}=2K")
    with pytest.raises(MemoryBudgetError,
                       match=f"over the budget of 2.0 KiB \\({ENV_MEMORY_BUDGET}"):
        check_memory(4096, what="x", argument="--n", value=4, advice="less")
    monkeypatch.setenv(ENV_MEMORY_BUDGET, "lots")
    with pytest.raises(ArgumentError, match=f"{ENV_MEMORY_BUDGET} = 'lots'"):
        memory_budget_bytes()


def test_subcarriers_that_break_the_cyclic_prefix_name_the_option(interference_tool, tmp_path,
                                                                  capsys):
    snap = tmp_path / "s.npz"
    save_snapshot(snap, Snapshot("two", 24e9, "", links=(
        Link("A", "A", 0, 0, los_paths([1e-4], [1e-7], [0.0])),
        Link("D", "A", 1, 0, los_paths([1e-5], [2e-7], [100.0])))))
    # N = 100 (not a multiple of 8) no longer breaks the paper's prefix: it is rounded to
    # whole samples as every command does; a prefix given in seconds and in samples that
    # disagree is refused naming both options and values (2 µs is 18.18 samples)
    assert interference_tool.main(["--snapshot", str(snap), "--out", str(tmp_path / "o"),
                                   "--subcarriers", "100", "--symbols", "16",
                                   "--cyclic-prefix", "2e-6", "--cp-samples", "17"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("interference.py: --cyclic-prefix and --cp-samples = "
                          "'--cyclic-prefix 2e-06, --cp-samples 17': disagree")
    assert "rounds to 18, not 17" in err and "cp_s" not in err
    # an interferer that is not in the snapshot is named with the options to change
    assert interference_tool.main(["--snapshot", str(snap), "--out", str(tmp_path / "o"),
                                   "--interferer", "B", "--subcarriers", "64",
                                   "--symbols", "16"]) == 2
    assert "no link 'B' -> 'A'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_carrier_the_radar_cannot_use_is_refused_before_tracing(trace_tool, tmp_path,
                                                                  monkeypatch, capsys):
    scene = plate_with(tmp_path, "carrier_hz = 1.0")
    monkeypatch.setattr(trace_command, "trace_scene", never)
    assert run_trace(trace_tool, tmp_path / "o", scene=scene) == 2
    err = capsys.readouterr().err
    # the scene loader already refuses a carrier no radio ray tracer can mean
    assert err.startswith(f"trace.py: {scene}: scene.carrier_hz = 1.0: must be")
    assert not (tmp_path / "o").exists()


def test_a_carrier_below_half_the_bandwidth_is_refused_before_tracing(
        trace_tool, tmp_path, monkeypatch, capsys):
    """10 MHz is a radio carrier the scene accepts (with a warning), but the paper's frame
    spans 93 MHz: the radar stage refuses it before anything is traced."""
    scene = plate_with(tmp_path, "carrier_hz = 1e7")
    monkeypatch.setattr(trace_command, "trace_scene", never)
    assert run_trace(trace_tool, tmp_path / "o", scene=scene) == 2
    err = capsys.readouterr().err
    assert "carrier_hz = 10000000.0: the radar's carrier must exceed half the bandwidth" in err
    # the scene's warning is one clean line (no Python source prefix), counted at the end
    warning = [ln for ln in err.splitlines() if ln.startswith("trace.py: warning:")]
    assert len(warning) == 1 and "carrier" in warning[0]
    assert warning[0].endswith("[ValidityRangeWarning]")
    assert "trace.py: 1 warning (1 kind, each shown once above): ValidityRangeWarning x1" in err
    assert not (tmp_path / "o").exists()


def test_a_noise_figure_below_0_db_is_refused_before_tracing(trace_tool, tmp_path,
                                                             monkeypatch, capsys):
    scene = plate_with(tmp_path, "noise_figure_db = -1.0")
    monkeypatch.setattr(trace_command, "trace_scene", never)
    assert run_trace(trace_tool, tmp_path / "o", scene=scene) == 2
    err = capsys.readouterr().err
    assert "radars[0].noise_figure_db = -1.0: must be >= 0 dB" in err
    assert not (tmp_path / "o").exists()
    with pytest.raises(ArgumentError, match="noise_figure_db = -1"):
        thermal_noise_power(1e6, -1.0)
    with pytest.raises(ArgumentError, match="noise_figure_db = -0.5"):
        radar_frame(los_paths([1e-3], [1e-7], [0.0]), Waveform(n_subcarriers=64, n_symbols=8),
                    tx_power_w=1.0, noise_figure_db=-0.5)
    assert thermal_noise_power(1e6, 0.0) > 0


def test_a_radar_that_transmits_nothing_has_no_image(trace_tool, tradeoff_tool, tmp_path,
                                                     capsys):
    scene = plate_with(tmp_path, "tx_power_w = 0.0")
    out = tmp_path / "o"
    assert run_trace(trace_tool, out, scene=scene) == 0
    text = capsys.readouterr().out
    assert "radar: tx_power_w = 0 W: it transmits nothing, so it has no echo; no radar " \
           "image or tables for it" in text
    assert sorted(p.name for p in out.iterdir()) == ["scene_top.png", "snapshot.npz"]
    assert tradeoff_tool.main([str(scene), "--out", str(tmp_path / "t")]) == 2
    assert "radars[0].tx_power_w = 0.0: the radar transmits nothing" in capsys.readouterr().err


# ----------------------------------------------------------------------------------------
# 4. identical runs, identical bytes; 5. library refusals name the argument
# ----------------------------------------------------------------------------------------
def test_identical_trace_runs_write_identical_files(trace_tool, tmp_path):
    assert run_trace(trace_tool, tmp_path / "a") == 0
    assert run_trace(trace_tool, tmp_path / "b") == 0
    a, b = folder_bytes(tmp_path / "a"), folder_bytes(tmp_path / "b")
    assert sorted(a) == TRACE_OUTPUTS
    assert a == b


def test_radar_images_are_byte_identical_and_refuse_bad_limits(tmp_path):
    wf = Waveform(n_subcarriers=128, n_symbols=32)
    D, Dr = radar_frame(los_paths([1e-3], [2e-7], [300.0]), wf, tx_power_w=0.01,
                        noise_figure_db=10.0)
    image, dets = process(D, Dr, wf)
    for stem in ("a", "b"):
        save_radar_image(image, tmp_path / stem, dets)
    for suffix in (".png", ".svg"):
        assert (tmp_path / f"a{suffix}").read_bytes() == (tmp_path / f"b{suffix}").read_bytes()
    with pytest.raises(ArgumentError, match="range_lim_m = \\(5, 1\\): must be an increasing"):
        plot_radar_image(image, range_lim_m=(5, 1))
    with pytest.raises(ArgumentError, match="dynamic_range_db = 0"):
        plot_radar_image(image, dynamic_range_db=0)
    with pytest.raises(ArgumentError, match="carrier_hz = 1.0: must exceed half the bandwidth"):
        Waveform(carrier_hz=1.0)
    with pytest.raises(ArgumentError, match="method = 'slow'"):
        radar_frame(los_paths([1e-3], [2e-7], [0.0]), wf, method="slow")


TWO_RADARS = """
[scene]
name = "two_radars"
carrier_hz = 24e9

[[objects]]
name = "plate"
material = "metal"
shape = "plane"
size = [1.0, 1.0]
position = [10.0, 3.0, 0.0]
rotation_deg = [0.0, -90.0, 0.0]

[[radars]]
name = "A"
position = [0.0, 0.0, 0.0]
pattern = "isotropic"

[[radars]]
name = "D"
position = [20.0, 0.0, 0.0]
orientation_deg = [0.0, 0.0, 180.0]
pattern = "isotropic"
velocity = [-10.0, 0.0, 0.0]
"""


def test_a_radar_run_that_fails_after_tracing_keeps_the_trace(interference_tool, tmp_path,
                                                              capsys):
    scene = tmp_path / "two.toml"
    scene.write_text(TWO_RADARS)
    out = tmp_path / "o"
    # 36 kHz is within 0.4 Δf = 36.4 kHz, but D closing at 10 m/s adds 800 Hz of Doppler,
    # which only the traced D->A paths show
    assert interference_tool.main([str(scene), "--out", str(out), "--rays", "1000",
                                   "--subcarriers", "64", "--symbols", "16",
                                   "--timing-offset-us", "0.5", "--cfo-hz", "36000"]) == 2
    err = capsys.readouterr().err
    assert len(error_lines(err)) == 1 and "cfo_hz=36000" in err
    assert f"the traced links are kept in {out / 'snapshot.npz'}" in err
    assert sorted(p.name for p in out.iterdir()) == ["snapshot.npz"]
    # refused before tracing: an offset the estimate cannot hold even without Doppler
    assert interference_tool.main([str(scene), "--out", str(tmp_path / "p"), "--cfo-hz",
                                   "40000", "--subcarriers", "64", "--symbols", "16"]) == 2
    assert "--cfo-hz = 40000.0: must stay within ±0.4·Δf" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()
