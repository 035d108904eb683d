"""The radar frame from the scene's [waveform] and the command line (issue #17, item 8):
precedence, the cyclic prefix's rounding stated, contradictions refused naming values,
and a 77 GHz frame of another size run end to end through ``clradcom trace``."""

import csv
import math

import pytest
from tool_helpers import CLOSING_PLATE_SCENE, load_tool

from clradcom.commands.options import run_waveform
from clradcom.errors import ArgumentError, SceneError
from clradcom.radar.waveform import SPEED_OF_LIGHT, round_cyclic_prefix
from clradcom.scene.reader import load_scene, scene_from_dict

FRAME_77 = """
[waveform]
subcarriers = 512
symbols = 128
subcarrier_spacing_hz = 250e3
"""


def scene_77(tmp_path, waveform=FRAME_77, name="plate77.toml"):
    path = tmp_path / name
    path.write_text(CLOSING_PLATE_SCENE.replace("carrier_hz = 24e9", "carrier_hz = 77e9")
                    + waveform)
    return path


def parse(argv):
    return load_tool("trace").build_parser().parse_args(["s.toml", *argv])


def test_a_77_ghz_frame_from_the_scene_runs_end_to_end(tmp_path, capsys):
    path = scene_77(tmp_path)
    out = tmp_path / "out"
    assert load_tool("trace").main([str(path), "--out", str(out), "--rays", "20000",
                                    "--reflections", "1", "--diffractions", "0",
                                    "--physical-optics", "none", "--no-scattering",
                                    "--quiet"]) == 0
    printed = capsys.readouterr().out
    fs = 512 * 250e3
    # the paper's 1.375 µs prefix is 176 whole samples at 128 MHz, and the line says so
    assert "N 512, M 128, Δf 250 kHz" in printed
    assert "cyclic prefix 1.375 µs → 176 samples = 1.3750 µs at 128 MHz" in printed
    with open(out / "A_truth.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["object"] for r in rows] == ["plate"]
    dr = SPEED_OF_LIGHT / (2 * fs)                              # 1.17 m
    t_sym = (512 + 176) / fs
    dv = SPEED_OF_LIGHT / (2 * 77e9 * 128 * t_sym)              # 2.83 m/s
    # the plate's centre is set at 20 m, closing at 8 m/s: detected within half a cell
    # of this frame's resolution (the paper's frame would resolve 1.6 m and 0.6 m/s)
    assert float(rows[0]["range_detected_m"]) == pytest.approx(20.0, abs=dr / 2)
    assert float(rows[0]["velocity_detected_mps"]) == pytest.approx(8.0, abs=dv / 2)


def test_the_command_line_overrides_the_scene_over_the_paper(tmp_path):
    scene = load_scene(scene_77(tmp_path, FRAME_77 + 'modulation = "16qam"\n'))
    wf, _ = run_waveform(77e9, parse([]), scene=scene)
    assert (wf.n_subcarriers, wf.n_symbols, wf.subcarrier_spacing_hz, wf.modulation) == (
        512, 128, 250e3, "16qam")
    wf, _ = run_waveform(77e9, parse(["--subcarriers", "256", "--modulation", "bpsk",
                                      "--cp-samples", "40"]), scene=scene)
    assert (wf.n_subcarriers, wf.n_symbols, wf.subcarrier_spacing_hz, wf.modulation) == (
        256, 128, 250e3, "bpsk")
    assert wf.n_cp == 40 and math.isclose(wf.cp_duration, 40 / (256 * 250e3))
    # no scene table, no option: the paper's Table I
    plain = scene_from_dict({"scene": {"carrier_hz": 24e9}})
    wf, _ = run_waveform(24e9, parse([]), scene=plain)
    assert (wf.n_subcarriers, wf.n_symbols, wf.n_cp, wf.modulation) == (1024, 256, 128,
                                                                         "qpsk")


def test_the_cyclic_prefix_is_rounded_to_whole_samples_and_said_so():
    # 1.375 µs at 1000 × 90.909 kHz = 125.0 samples exactly... at N = 1000 it is
    # 124.9998..., rounded to 125; at N = 100: 12.4999 → 12
    wf, line = run_waveform(24e9, parse(["--subcarriers", "1000"]))
    assert wf.n_cp == 125
    assert "cyclic prefix 1.375 µs → 125 samples = 1.3750 µs at 90.909 MHz" in line
    assert "rounded to the nearest whole sample" in line
    wf, line = run_waveform(24e9, parse(["--subcarriers", "1024", "--cyclic-prefix",
                                         "1.38e-6"]))
    exact = 1.38e-6 * 1024 * 90.909e3                           # 128.46 samples
    assert wf.n_cp == math.floor(exact + 0.5) == 128
    assert "cyclic prefix 1.38 µs → 128 samples = 1.3750 µs at 93.0908 MHz" in line
    assert round_cyclic_prefix(2.5, 1.0) == 3 and round_cyclic_prefix(3.5, 1.0) == 4
    with pytest.raises(ArgumentError, match="sample_rate_hz"):
        round_cyclic_prefix(1e-6, 0.0)


@pytest.mark.parametrize("table, key, value", [
    ("cyclic_prefix_s = 1.375e-6\ncyclic_prefix_samples = 100\n",
     "waveform.cyclic_prefix_s and waveform.cyclic_prefix_samples", "100"),
    ("cyclic_prefix_samples = 600\n", "waveform.cyclic_prefix_samples", "600"),
    ("useful_duration_s = 5e-6\n", "waveform.useful_duration_s", "5e-06"),
])
def test_contradictions_in_the_scene_are_refused_naming_key_and_value(tmp_path, table, key,
                                                                      value):
    scene = load_scene(scene_77(tmp_path, FRAME_77 + table))
    with pytest.raises(SceneError) as exc:
        run_waveform(77e9, parse([]), scene=scene)
    msg = str(exc.value)
    assert "plate77.toml" in msg and key in msg and value in msg


@pytest.mark.parametrize("table, key, value", [
    ("subcarriers = 0\n", "waveform.subcarriers", "0"),
    ("symbols = 2.5\n", "waveform.symbols", "2.5"),
    ("subcarrier_spacing_hz = -1.0\n", "waveform.subcarrier_spacing_hz", "-1.0"),
    ('modulation = "qam17"\n', "waveform.modulation", "qam17"),
    ("cyclic_prefix_s = -1e-6\n", "waveform.cyclic_prefix_s", "-1e-06"),
    ("cp = 3\n", "waveform.cp", "3"),
])
def test_bad_values_in_the_table_are_refused_by_the_reader(tmp_path, table, key, value):
    with pytest.raises(SceneError) as exc:
        load_scene(scene_77(tmp_path, "[waveform]\n" + table))
    msg = str(exc.value)
    assert "plate77.toml" in msg and key in msg and value in msg


def test_contradictions_on_the_command_line_name_the_options(tmp_path):
    with pytest.raises(ArgumentError) as exc:
        run_waveform(24e9, parse(["--cyclic-prefix", "1.375e-6", "--cp-samples", "127"]))
    msg = str(exc.value)
    assert "--cyclic-prefix and --cp-samples" in msg and "127" in msg and "128" in msg
    with pytest.raises(ArgumentError) as exc:
        run_waveform(24e9, parse(["--subcarriers", "64", "--cp-samples", "64"]))
    assert "--cp-samples = 64" in str(exc.value) and "N = 64" in str(exc.value)
    # the paper's prefix is longer than the symbol at Δf = 1 MHz: the default is named
    with pytest.raises(ArgumentError) as exc:
        run_waveform(24e9, parse(["--subcarrier-spacing", "1e6"]))
    assert "cyclic_prefix" in str(exc.value) and "paper's default" in str(exc.value)
    # a carrier below half the bandwidth names the scene's carrier
    scene = load_scene(scene_77(tmp_path))
    with pytest.raises(SceneError, match="scene.carrier_hz"):
        run_waveform(60e6, parse(["--subcarrier-spacing", "250e3"]), scene=scene)
    with pytest.raises(SystemExit):
        parse(["--modulation", "qam17"])
    with pytest.raises(SystemExit):
        parse(["--symbols", "0"])


def test_the_scene_hash_counts_the_table_only_when_given(tmp_path):
    base = load_scene(scene_77(tmp_path, "", name="a.toml"))
    same = load_scene(scene_77(tmp_path, "\n", name="b.toml"))
    framed = load_scene(scene_77(tmp_path, FRAME_77, name="c.toml"))
    other = load_scene(scene_77(tmp_path, FRAME_77.replace("128", "64"), name="d.toml"))
    assert base.waveform is None and framed.waveform.subcarriers == 512
    assert base.content_hash() == same.content_hash() != framed.content_hash()
    assert framed.content_hash() != other.content_hash()
