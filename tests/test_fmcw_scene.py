"""An FMCW radar from the scene file (``[waveform] kind = "fmcw"``) through the commands:
the table read and refused by file, key and value, the OFDM options refused beside it,
and ``clradcom trace`` / ``cube`` finding the closing plate where it is."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from tool_helpers import CLOSING_PLATE_SCENE, FMCW_TABLE
from tool_helpers import FMCW_ARRAYS as ARRAYS

from clradcom.cli import main
from clradcom.commands.options import run_waveform
from clradcom.errors import ArgumentError, SceneError
from clradcom.radar.fmcw import FmcwWaveform
from clradcom.scene import load_scene
from clradcom.scene.records import FmcwSpec

RADAR_D = """
[[radars]]
name = "D"
position = [30.0, 5.0, 1.0]
orientation_deg = [0.0, 0.0, 180.0]
pattern = "sector"
tx_power_w = 0.01
noise_figure_db = 10.0
"""


class NoOptions:
    """argparse's namespace with no waveform option given."""


def write(tmp_path, table=FMCW_TABLE, scene=CLOSING_PLATE_SCENE, name="plate.toml"):
    path = tmp_path / name
    path.write_text(scene + table)
    return path


def test_scene_table_becomes_the_chirp_sequence(tmp_path):
    scene = load_scene(write(tmp_path))
    assert isinstance(scene.waveform, FmcwSpec)
    wf, line = run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True)
    assert isinstance(wf, FmcwWaveform)
    assert wf.traced_carrier_hz == scene.carrier_hz == 24e9
    assert wf.slope == pytest.approx(200e6 / 40e-6)
    assert (wf.n_chirps, wf.samples_per_chirp, wf.adc_rate_hz) == (64, 128, 5e6)
    assert "FMCW" in line and "Δr 1.171 m" in line
    # the table counts in the scene's hash: another sweep is another scene
    other = load_scene(write(tmp_path, FMCW_TABLE.replace("chirps = 64", "chirps = 32"),
                             name="other.toml"))
    assert other.content_hash() != scene.content_hash()


@pytest.mark.parametrize("edit, key", [
    (("chirps = 64", "chirps = 0"), "waveform.chirps"),
    (("chirps = 64", "subcarriers = 64"), "waveform.subcarriers"),      # an OFDM key
    (('kind = "fmcw"', 'kind = "fmc"'), "waveform.kind"),
    (("samples_per_chirp = 128", 'samples_per_chirp = 128\nif_type = "iq"'),
     "waveform.if_type"),
    (("adc_sample_rate_hz = 5e6", "adc_sample_rate_hz = -5e6"),
     "waveform.adc_sample_rate_hz"),
])
def test_reader_refuses_a_bad_value_by_file_and_key(tmp_path, edit, key):
    path = write(tmp_path, FMCW_TABLE.replace(*edit))
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert err.value.key == key and str(path) in str(err.value)


@pytest.mark.parametrize("edit, key", [
    (("start_frequency_hz = 23.9e9", "start_frequency_hz = 24.1e9"),
     "waveform.start_frequency_hz"),                         # the sweep misses 24 GHz
    (("samples_per_chirp = 128", "samples_per_chirp = 256"),
     "waveform.samples_per_chirp"),                          # 51.2 µs window > 40 µs chirp
    (("samples_per_chirp = 128", "samples_per_chirp = 128\nif_bandwidth_hz = 6e6"),
     "waveform.if_bandwidth_hz"),                            # beyond the ADC's 5 MHz
])
def test_contradictions_are_refused_naming_the_key(tmp_path, edit, key):
    scene = load_scene(write(tmp_path, FMCW_TABLE.replace(*edit)))
    with pytest.raises(SceneError) as err:
        run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True)
    assert err.value.key == key


def test_a_default_that_contradicts_the_table_names_the_key_to_set(tmp_path):
    table = FMCW_TABLE.replace("samples_per_chirp = 128\n", "")  # default 256: too long
    scene = load_scene(write(tmp_path, table))
    with pytest.raises(SceneError, match="left out: the default 256") as err:
        run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True)
    assert err.value.key == "waveform.samples_per_chirp"


def test_an_ofdm_option_beside_an_fmcw_scene_is_refused(tmp_path):
    scene = load_scene(write(tmp_path))
    args = NoOptions()
    args.subcarriers = 64
    with pytest.raises(ArgumentError) as err:
        run_waveform(scene.carrier_hz, args, scene=scene, fmcw=True)
    assert err.value.argument == "--subcarriers"


# (interference runs FMCW radars too: tests/test_mixed_interference.py)
@pytest.mark.parametrize("command", ["comms", "tradeoff"])
def test_commands_that_run_ofdm_only_refuse_the_fmcw_scene_by_its_key(tmp_path, capsys,
                                                                      command):
    assert main([command, str(write(tmp_path, scene=CLOSING_PLATE_SCENE + RADAR_D))]) == 2
    err = capsys.readouterr().err
    assert "waveform.kind" in err and "OFDM radar only" in err
    scene = load_scene(write(tmp_path))
    with pytest.raises(SceneError) as exc:
        run_waveform(scene.carrier_hz, NoOptions(), scene=scene)
    assert exc.value.key == "waveform.kind"


def test_trace_runs_the_fmcw_radar_and_finds_the_plate(tmp_path):
    out = tmp_path / "out"
    assert main(["trace", str(write(tmp_path)), "--out", str(out), "--rays", "2000",
                 "-q"]) == 0
    with open(out / "A_truth.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["object"] for r in rows] == ["plate"]
    # the plate's centre at 20 m closing at 8 m/s; Δr 1.17 m, Δv 1.95 m/s
    assert float(rows[0]["range_detected_m"]) == pytest.approx(20.0, abs=0.1)
    assert float(rows[0]["velocity_detected_mps"]) == pytest.approx(8.0, abs=0.2)


def test_cube_runs_the_fmcw_tdm_mimo_radar_and_finds_the_plates_azimuth(tmp_path, capsys):
    scene = CLOSING_PLATE_SCENE.replace("noise_figure_db = 10.0\n",
                                        "noise_figure_db = 10.0\n" + ARRAYS, 1)
    scene = scene.replace("position = [20.0, 0.0, 1.0]", "position = [20.0, 5.0, 1.0]")
    out = tmp_path / "out"
    assert main(["cube", str(write(tmp_path, scene=scene)), "--out", str(out), "--rays",
                 "2000", "-q"]) == 0
    text = capsys.readouterr().out
    row = next(line for line in text.splitlines() if line.strip().startswith("plate"))
    fields = row.split()
    r_det, v_true, v_det, az_true, az_det = map(float, fields[2:7])
    assert 20.3 < r_det < 20.8
    assert v_det == pytest.approx(v_true, abs=0.2)
    assert az_det == pytest.approx(az_true, abs=0.5)
    assert az_true == pytest.approx(np.degrees(np.arctan2(5.0, 20.0)), abs=0.5)


def test_compare_waveforms_runs_both_radars_on_the_same_paths(tmp_path, capsys):
    ofdm_scene = write(tmp_path, "\n[waveform]\nsubcarriers = 256\nsymbols = 64\n",
                       name="ofdm.toml")
    fmcw = tmp_path / "fmcw.toml"
    fmcw.write_text(FMCW_TABLE)
    out = tmp_path / "out"
    assert main(["trace", str(ofdm_scene), "--out", str(out), "--rays", "2000", "-q"]) == 0
    capsys.readouterr()
    assert main(["compare-waveforms", str(out / "snapshot.npz"), "--scene", str(ofdm_scene),
                 "--fmcw", str(fmcw)]) == 0
    text = capsys.readouterr().out
    assert "range resolution [m]               6.441           1.171" in text
    assert "none" in text.splitlines()[[i for i, ln in enumerate(text.splitlines())
                                       if "data carried" in ln][0]]
    with open(out / "A_compare.csv") as fh:
        rows = {r["waveform"]: r for r in csv.DictReader(fh)}
    # the plate at 20 m closing at 8 m/s: each within a tenth of its own range cell
    assert abs(float(rows["OFDM"]["range_error_m"])) < 0.1 * 6.441
    assert abs(float(rows["FMCW"]["range_error_m"])) < 0.1 * 1.171
    for r in rows.values():
        assert abs(float(r["v_error_mps"])) < 0.1
    assert (out / "A_compare.png").stat().st_size > 0
    # an FMCW table where the OFDM one belongs, and the OFDM one for --fmcw, are refused
    table = tmp_path / "ofdm_table.toml"
    table.write_text("[waveform]\nsubcarriers = 256\n")
    assert main(["compare-waveforms", str(out / "snapshot.npz"), "--scene", str(ofdm_scene),
                 "--fmcw", str(table)]) == 2
    assert "waveform.kind" in capsys.readouterr().err


def test_phase_noise_mask_from_the_scene(tmp_path):
    mask = ("samples_per_chirp = 128\nphase_noise_offsets_hz = [1e3, 1e5, 1e6]\n"
            "phase_noise_dbc_per_hz = [-60, -80, -100]\n")
    scene = load_scene(write(tmp_path, FMCW_TABLE.replace("samples_per_chirp = 128\n", mask)))
    wf, _ = run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True)
    assert wf.phase_noise_offsets_hz == (1e3, 1e5, 1e6)
    assert wf.phase_noise_dbc_per_hz == (-60.0, -80.0, -100.0)
    for bad, key in [("[-60, -80]", "waveform.phase_noise_dbc_per_hz"),
                     (None, "waveform.phase_noise_dbc_per_hz")]:
        text = mask if bad is None else mask.replace("[-60, -80, -100]", bad)
        if bad is None:
            text = text.replace("phase_noise_dbc_per_hz = [-60, -80, -100]\n", "")
        scene = load_scene(write(tmp_path, FMCW_TABLE.replace("samples_per_chirp = 128\n",
                                                              text), name="bad.toml"))
        with pytest.raises(SceneError) as err:
            run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True)
        assert err.value.key == key
    with pytest.raises(SceneError) as err:
        load_scene(write(tmp_path, FMCW_TABLE.replace(
            "samples_per_chirp = 128\n", "phase_noise_offsets_hz = 'a'\n"), name="c.toml"))
    assert err.value.key == "waveform.phase_noise_offsets_hz"
