"""The ``clradcom`` command and what it shares with the API: presets (one physics),
subcommands calling the same code as tools/, progress bars, warnings shown once each."""

from __future__ import annotations

import ast
import io
import re
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from tool_helpers import CLOSING_PLATE_SCENE, load_tool

import clradcom.trace as trace_module
from clradcom import cli
from clradcom.commands.console import WarningLog, progress_bar, stage_steps, trace_steps
from clradcom.errors import ArgumentError, NearFieldWarning, SceneWarning
from clradcom.presets import DEFAULT_PRESET, PRESETS
from clradcom.scene import scene_from_dict
from clradcom.trace import SpecularSettings, TraceSettings, trace_scene

SUBCOMMANDS = ("trace", "radar", "cube", "interference", "tradeoff", "sweep", "rcs", "view",
               "drive", "comms", "microdoppler", "presets", "devices")


# ----------------------------------------------------------------------------------------
# presets: one physics for the command, the tools and the API
# ----------------------------------------------------------------------------------------
def test_paper_preset_is_the_trace_commands_default():
    tool = load_tool("trace")
    from_tool = tool.settings_from_args(tool.build_parser().parse_args(["s.toml"]))
    from_cli = cli.build_parser().parse_args(["trace", "s.toml"])
    assert DEFAULT_PRESET == "paper"
    assert from_tool == TraceSettings.preset("paper") == TraceSettings.preset()
    assert tool.settings_from_args(from_cli) == from_tool
    # what tools/trace.py traced before presets existed, but for the specular search:
    # 3e5 rays and candidate expansion in place of 1e6 rays, a superset of their paths
    # (tests/test_specular_expand.py)
    p = TraceSettings.preset("paper")
    assert (p.specular.rays, p.specular.expand_rounds, p.specular.max_reflections) == (
        300_000, 4, 5)
    assert (p.diffraction.max_diffractions, p.diffraction.max_reflections) == (1, 0)
    assert p.optics.mode == "sbr" and p.scattering.enabled
    assert p.scattering.max_reflections == 0


def test_trace_scene_without_settings_traces_the_paper_preset(monkeypatch):
    seen = []

    class Stop(Exception):
        pass

    def capture(settings, **kwargs):
        seen.append(settings)
        raise Stop

    monkeypatch.setattr(trace_module, "check_launch_memory", capture)
    scene = scene_from_dict({"scene": {"name": "s", "carrier_hz": 24e9},
                             "radars": [{"name": "A", "position": [0, 0, 1]}]}, base_dir=".")
    with pytest.raises(Stop):
        trace_scene(scene)
    assert seen == [TraceSettings.preset("paper")]
    with pytest.raises(Stop):
        trace_scene(scene, TraceSettings())
    assert seen[-1] == TraceSettings.preset("go") != TraceSettings.preset("paper")


def test_presets_differ_and_take_changes():
    settings = {name: TraceSettings.preset(name) for name in PRESETS}
    assert len(set(settings.values())) == len(PRESETS)
    assert settings["fast"].specular.rays < settings["paper"].specular.rays \
        < settings["accurate"].specular.rays
    assert not settings["fast"].scattering.enabled and settings["fast"].optics.mode == "pec"
    s = TraceSettings.preset("fast", specular__rays=123, engine="host")
    assert s.specular.rays == 123 and s.engine == "host" and s.optics.mode == "pec"
    with pytest.raises(ArgumentError, match="preset = 'papr'.*paper, fast, accurate, go"):
        TraceSettings.preset("papr")


def test_a_preset_option_with_a_knob_on_top():
    tool = load_tool("trace")
    args = tool.build_parser().parse_args(["s.toml", "--preset", "fast", "--rays", "5000",
                                           "--no-sbr-mirrors"])
    s = tool.settings_from_args(args)
    assert s == TraceSettings.preset("fast", specular__rays=5000, optics__sbr_mirrors=False)
    args = tool.build_parser().parse_args(["s.toml", "--rays", "1000000", "--expand-rounds",
                                           "0"])
    assert tool.settings_from_args(args) == TraceSettings.preset(
        "paper", specular__rays=1_000_000, specular__expand_rounds=0)


def test_interference_traces_the_same_preset():
    tool = load_tool("interference")
    args = tool.parse_args(["s.toml"])
    from clradcom.commands.options import preset_settings
    assert preset_settings(args) == TraceSettings.preset("paper")
    assert preset_settings(tool.parse_args(["s.toml", "--rays", "99"])).specular.rays == 99


# ----------------------------------------------------------------------------------------
# the command
# ----------------------------------------------------------------------------------------
def test_help_lists_every_subcommand_and_each_explains_itself(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0
    top = capsys.readouterr().out
    for name in SUBCOMMANDS:
        assert f"    {name}" in top
        with pytest.raises(SystemExit) as exc:
            cli.main([name, "--help"])
        assert exc.value.code == 0
        text = capsys.readouterr().out
        assert f"usage: clradcom {name}" in text
        assert len(text.splitlines()) > 5, name


def test_help_texts_show_no_sphinx_roles(capsys):
    """Docstrings become help texts: :mod:`x` and :func:`~a.b` read as `x` and `b`."""
    for argv in (["--help"], ["trace", "--help"], ["radar", "--help"], ["sweep", "--help"]):
        with pytest.raises(SystemExit):
            cli.main(argv)
        text = capsys.readouterr().out
        assert not re.search(r":[a-z]+:`", text), (argv, text)
        assert "``" not in text
    assert (cli.plain_text("see :mod:`clradcom.commands` and :func:`~clradcom.x.run_tool`"
                           " with ``--out``")
            == "see `clradcom.commands` and `run_tool` with `--out`")


def test_the_command_imports_a_subcommand_only_when_chosen():
    """`import clradcom.cli` (and so `clradcom --help`) loads none of the heavy modules;
    choosing a command loads its own (tools/bench_cli_import.py times it)."""
    heavy = ("trimesh", "scipy", "matplotlib", "dask", "distributed", "pyopencl",
             "finufft", "clradcom.trace", "clradcom.scene", "clradcom.radar")
    probe = ("import sys, clradcom.cli as c; p = c.build_parser(); {}; "
             "print(sorted(m for m in {!r} if m in sys.modules))")
    for parse, expected in (("None", []),
                            ("p.parse_args(['devices'])", []),
                            ("p.parse_args(['rcs', '--out', 'o'])",
                             ["clradcom.radar", "clradcom.scene", "clradcom.trace",
                              "matplotlib", "scipy", "trimesh"])):
        out = subprocess.run([sys.executable, "-c", probe.format(parse, heavy)],
                             capture_output=True, text=True, check=True).stdout
        loaded = ast.literal_eval(out.strip())
        assert (set(expected) <= set(loaded)) if expected else loaded == [], (parse, loaded)


def test_every_scene_a_help_text_names_exists(capsys):
    """`clradcom drive --help` named scenes/canonical/drive_by.toml, which never existed."""
    root = Path(__file__).resolve().parents[1]
    named = set()
    for argv in [["--help"]] + [[name, "--help"] for name in cli.SUBCOMMANDS]:
        with pytest.raises(SystemExit):
            cli.main(argv)
        named |= set(re.findall(r"scenes/[\w/.-]+\.toml", capsys.readouterr().out))
    assert "scenes/street/street_drive.toml" in named
    assert [p for p in sorted(named) if not (root / p).is_file()] == []


def test_stage_steps_move_the_bar_one_stage_per_message():
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    err, out = Terminal(), io.StringIO()
    with progress_bar(3, "run", stream=err, unit="stage") as bar:
        say = stage_steps(bar, time.perf_counter(), stream=out)
        positions = []
        for message in ("first", "second", "third"):
            say(message)
            positions.append((bar.n, bar.desc))
    assert positions == [(0, "first"), (1, "second"), (2, "third")]
    lines = out.getvalue().splitlines()
    assert [line.split("] ", 1)[1] for line in lines] == ["first ...", "second ...",
                                                         "third ..."]
    assert "third" in err.getvalue()


def test_bad_option_names_the_subcommand_option_and_value(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["trace", "s.toml", "--rays", "-1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "clradcom trace: error: argument --rays: must be a positive integer, got '-1'" in err
    with pytest.raises(SystemExit):
        cli.main(["rcs", "--out", "o", "--start-deg", "10", "--stop-deg", "5"])
    assert "--stop-deg (5.0) is below --start-deg (10.0)" in capsys.readouterr().err


def test_errors_are_one_line_with_the_subcommand(tmp_path, capsys):
    assert cli.main(["trace", str(tmp_path / "missing.toml"), "--out",
                     str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("clradcom trace: ") and err.count("\n") == 1
    assert "missing.toml" in err


def test_presets_command_lists_them(capsys):
    assert cli.main(["presets"]) == 0
    out = capsys.readouterr().out
    for name, preset in PRESETS.items():
        assert f"{name}{' (default)' if name == DEFAULT_PRESET else ''}: {preset.summary}" \
            in out
    assert cli.main(["presets", "fast"]) == 0
    assert "specular.rays = 100000" in capsys.readouterr().out


def test_trace_then_radar_then_view(tmp_path, capsys):
    """``clradcom trace`` on a closing plate, then ``clradcom radar`` on its snapshot
    gives the same detections byte for byte (same seed), another seed other noise; and
    ``clradcom view`` draws it."""
    scene = tmp_path / "closing_plate.toml"
    scene.write_text(CLOSING_PLATE_SCENE)
    out = tmp_path / "trace"
    assert cli.main(["trace", str(scene), "--out", str(out), "--preset", "go", "--rays",
                     "20000", "--reflections", "2", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "preset go, specular.max_reflections=2, specular.rays=20000" in text
    first = (out / "A_detections.csv").read_bytes()
    again = tmp_path / "radar"
    assert cli.main(["radar", str(out / "snapshot.npz"), "--scene", str(scene), "--out",
                     str(again)]) == 0
    assert (again / "A_detections.csv").read_bytes() == first
    assert (again / "A_truth.csv").read_bytes() == (out / "A_truth.csv").read_bytes()
    other = tmp_path / "radar7"
    assert cli.main(["radar", str(out / "snapshot.npz"), "--scene", str(scene), "--out",
                     str(other), "--seed", "7"]) == 0
    assert (other / "A_detections.csv").read_bytes() != first
    picture = tmp_path / "top.png"
    assert cli.main(["view", str(scene), "--snapshot", str(out / "snapshot.npz"), "--out",
                     str(picture)]) == 0
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    # a snapshot of another scene is refused by name
    moved = tmp_path / "moved.toml"
    moved.write_text(CLOSING_PLATE_SCENE.replace("[20.0, 0.0, 1.0]", "[25.0, 0.0, 1.0]"))
    assert cli.main(["radar", str(out / "snapshot.npz"), "--scene", str(moved), "--out",
                     str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "snapshot.npz" in err and "another scene" in err


# ----------------------------------------------------------------------------------------
# progress bars
# ----------------------------------------------------------------------------------------
class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_progress_bar_only_on_a_terminal_and_not_when_quiet():
    for stream, quiet, shown in ((Terminal(), False, True), (Terminal(), True, False),
                                 (io.StringIO(), False, False)):
        with progress_bar(3, "links", quiet=quiet, stream=stream) as bar:
            assert bar.disable == (not shown)
            for _ in range(3):
                bar.update(1)
        assert ("links" in stream.getvalue()) == shown


def test_trace_steps_follow_the_links(runtime):
    scene = scene_from_dict({
        "scene": {"name": "ground", "carrier_hz": 24e9},
        "objects": [{"name": "ground", "material": "concrete_road", "shape": "plane",
                     "size": [40.0, 40.0]}],
        "radars": [{"name": "A", "position": [0, 0, 1]},
                   {"name": "B", "position": [10, 0, 1.5], "role": "rx"}]}, base_dir=".")
    calls = []
    trace_scene(scene, TraceSettings(specular=SpecularSettings(max_reflections=1,
                                                               rays=2000)),
                runtime=runtime, steps=lambda d, t, label: calls.append((d, t, label)))
    links = [(0, 0), (0, 1)]
    assert {t for _, t, _ in calls} == {len(links)}
    done = [d for d, _, _ in calls]
    assert done == sorted(done) and done[0] == 0 and calls[-1] == (2, 2, "done")
    assert any(label == "A -> B: specular" for _, _, label in calls)
    assert any(label == "A -> B: diffraction" for _, _, label in calls)
    stream = Terminal()
    bar = progress_bar(None, "trace", stream=stream)
    for d, t, label in calls:
        trace_steps(bar)(d, t, label)
    assert bar.n == 2 and bar.total == 2
    bar.close()


# ----------------------------------------------------------------------------------------
# warnings: once each, one clean line, counted, a summary
# ----------------------------------------------------------------------------------------
def warn_short(i):
    warnings.warn(f"{i} path(s) shorter than a wavelength", NearFieldWarning, stacklevel=1)


def test_warnings_once_each_as_one_clean_line_with_counts():
    stream = io.StringIO()
    with WarningLog("clradcom trace", stream=stream) as log:
        for i in range(5):
            warn_short(i)
        warnings.warn("scene.toml: carrier_hz = 1e7 is outside\n   1e9-3e11 Hz", SceneWarning,
                      stacklevel=1)
    lines = stream.getvalue().splitlines()
    assert lines == [
        "clradcom trace: warning: 0 path(s) shorter than a wavelength [NearFieldWarning]",
        "clradcom trace: warning: scene.toml: carrier_hz = 1e7 is outside 1e9-3e11 Hz "
        "[SceneWarning]",
        "clradcom trace: 6 warnings (2 kinds, each shown once above): NearFieldWarning x5, "
        "SceneWarning x1"]
    assert log.counts == {"NearFieldWarning": 5, "SceneWarning": 1}
    assert not any(".py:" in ln for ln in lines)


def test_no_warnings_no_summary_and_others_keep_their_form():
    stream = io.StringIO()
    with pytest.warns(DeprecationWarning, match="old"):
        with WarningLog("t", stream=stream):
            warnings.warn("old", DeprecationWarning, stacklevel=1)
    assert stream.getvalue() == ""
    # the filters are restored on leaving
    with pytest.warns(NearFieldWarning):
        warn_short(1)


def test_a_command_shows_the_scene_warning_once(tmp_path, capsys):
    """A speed above 1e-3 c is accepted with a warning: the tool shows it as one line and
    sums it up, instead of Python's ``file.py:NN: UserWarning`` form."""
    scene = tmp_path / "fast.toml"
    scene.write_text(CLOSING_PLATE_SCENE.replace("[-8.0, 0.0, 0.0]", "[-4e5, 0.0, 0.0]"))
    assert cli.main(["view", str(scene), "--out", str(tmp_path / "top.png")]) == 0
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 2, err
    assert lines[0].startswith("clradcom view: warning: ") and "[ValidityRangeWarning]" in lines[0]
    assert lines[1] == ("clradcom view: 1 warning (1 kind, each shown once above): "
                        "ValidityRangeWarning x1")
