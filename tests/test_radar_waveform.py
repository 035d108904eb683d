"""A radar's own waveform (``[radars.waveform]``): read with the scene's rules and refused
by ``radars[i].waveform.<key>``, set and saved through the scene API, and run by every
command that runs a radar (trace, radar, cube, drive) in place of the scene's
``[waveform]``: on one scene the OFDM radar A and the FMCW radar B each find the closing
plate in their own resolution."""

from __future__ import annotations

import contextlib
import csv
import io

import pytest
from tool_helpers import CLOSING_PLATE_SCENE, FMCW_TABLE
from tool_helpers import FMCW_ARRAYS as ARRAYS

from clradcom.cli import main
from clradcom.commands.options import refuse_radar_waveforms, run_waveform
from clradcom.errors import SceneError
from clradcom.radar.fmcw import FmcwWaveform
from clradcom.radar.waveform import Waveform
from clradcom.scene import load_scene
from clradcom.scene.edit import save_scene, set_waveform
from clradcom.scene.records import FmcwSpec, WaveformSpec

OFDM_TABLE = """
[waveform]
subcarriers = 256
symbols = 64
"""

RADAR_B = """
[[radars]]
name = "B"
position = [0.0, 0.6, 1.0]
pattern = "sector"
tx_power_w = 0.01
noise_figure_db = 10.0
"""

FMCW_OWN = FMCW_TABLE.replace("[waveform]", "[radars.waveform]")


class NoOptions:
    """argparse's namespace with no waveform option given."""


def write(tmp_path, own=FMCW_OWN, radar_b=RADAR_B, name="mixed.toml"):
    path = tmp_path / name
    path.write_text(CLOSING_PLATE_SCENE + radar_b + own + OFDM_TABLE)
    return path


def test_a_radars_table_is_read_and_counted_in_the_hash(tmp_path):
    scene = load_scene(write(tmp_path))
    assert scene.radars[0].waveform is None
    assert isinstance(scene.radars[1].waveform, FmcwSpec)
    assert isinstance(scene.waveform, WaveformSpec)
    assert scene.radar_waveform(0) == (scene.waveform, "waveform")
    assert scene.radar_waveform(1) == (scene.radars[1].waveform, "radars[1].waveform")
    a, _ = run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True, radar=0)
    b, _ = run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True, radar=1)
    assert isinstance(a, Waveform) and (a.n_subcarriers, a.n_symbols) == (256, 64)
    assert isinstance(b, FmcwWaveform) and b.slope == pytest.approx(200e6 / 40e-6)
    plain = load_scene(write(tmp_path, own="", name="plain.toml"))
    assert plain.content_hash() != scene.content_hash()
    # an OFDM table of the radar's own is another frame than the scene's
    own_ofdm = load_scene(write(tmp_path, own="[radars.waveform]\nsubcarriers = 128\n",
                                name="ofdm.toml"))
    wf, _ = run_waveform(own_ofdm.carrier_hz, NoOptions(), scene=own_ofdm, radar=1)
    # the table replaces the scene's whole: M from the paper, not the scene's 64
    assert (wf.n_subcarriers, wf.n_symbols) == (128, 256)
    assert own_ofdm.content_hash() not in (plain.content_hash(), scene.content_hash())


@pytest.mark.parametrize("edit, key", [
    (("chirps = 64", "chirps = 0"), "radars[1].waveform.chirps"),
    (("chirps = 64", "subcarriers = 64"), "radars[1].waveform.subcarriers"),  # OFDM key
    (('kind = "fmcw"', 'kind = "fmc"'), "radars[1].waveform.kind"),
    (("adc_sample_rate_hz = 5e6", "adc_sample_rate_hz = -5e6"),
     "radars[1].waveform.adc_sample_rate_hz"),
    (("samples_per_chirp = 128", 'samples_per_chirp = 128\nif_type = "iq"'),
     "radars[1].waveform.if_type"),
])
def test_a_bad_value_in_a_radars_table_is_refused_by_file_and_key(tmp_path, edit, key):
    path = write(tmp_path, FMCW_OWN.replace(*edit))
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert err.value.key == key and str(path) in str(err.value)


def test_a_radars_waveform_that_is_no_table_is_refused(tmp_path):
    path = write(tmp_path, own="", radar_b=RADAR_B + 'waveform = "fmcw"\n')
    with pytest.raises(SceneError, match=r"\[radars.waveform\]") as err:
        load_scene(path)
    assert err.value.key == "radars[1].waveform"


@pytest.mark.parametrize("edit, key", [
    (("start_frequency_hz = 23.9e9", "start_frequency_hz = 24.1e9"),
     "radars[1].waveform.start_frequency_hz"),                 # the sweep misses 24 GHz
    (("samples_per_chirp = 128", "samples_per_chirp = 256"),
     "radars[1].waveform.samples_per_chirp"),                  # window past the chirp
])
def test_contradictions_in_a_radars_table_name_its_key(tmp_path, edit, key):
    scene = load_scene(write(tmp_path, FMCW_OWN.replace(*edit)))
    run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True, radar=0)
    with pytest.raises(SceneError) as err:
        run_waveform(scene.carrier_hz, NoOptions(), scene=scene, fmcw=True, radar=1)
    assert err.value.key == key


def test_an_ofdm_only_command_refuses_an_fmcw_radar_by_its_key(tmp_path):
    scene = load_scene(write(tmp_path))
    with pytest.raises(SceneError) as err:
        run_waveform(scene.carrier_hz, NoOptions(), scene=scene, radar=1)
    assert err.value.key == "radars[1].waveform.kind"


def test_set_waveform_per_radar_and_save_scene_round_trip(tmp_path):
    scene = load_scene(write(tmp_path, own=""))
    keys = dict(kind="fmcw", start_frequency_hz=23.9e9, sweep_bandwidth_hz=200e6,
                chirp_duration_s=40e-6, idle_duration_s=10e-6, chirps=64,
                adc_sample_rate_hz=5e6, samples_per_chirp=128)
    edited = set_waveform(scene, radar="B", **keys)
    assert edited.radars[1].waveform == load_scene(write(tmp_path)).radars[1].waveform
    assert edited.content_hash() == load_scene(write(tmp_path)).content_hash()
    saved = save_scene(edited, tmp_path / "saved" / "mixed.toml")
    assert "[radars.waveform]" in saved.read_text()
    assert load_scene(saved).content_hash() == edited.content_hash()
    # no keys: the radar follows the scene's [waveform] again
    assert set_waveform(edited, radar="B").content_hash() == scene.content_hash()
    with pytest.raises(SceneError) as err:
        set_waveform(scene, radar="B", kind="fmcw", chirps=0)
    assert err.value.key == "radars[1].waveform.chirps"
    with pytest.raises(SceneError, match="only a radar has a waveform"):
        set_waveform(scene, radar="plate", subcarriers=64)


def _truth(path):
    with open(path) as fh:
        return {r["object"]: r for r in csv.DictReader(fh)}


def _plate_found(row, cell_m):
    # the plate's centre at 20 m closing at 8 m/s, within a tenth of the radar's own cell
    assert float(row["range_detected_m"]) == pytest.approx(20.0, abs=0.1 * cell_m)
    assert float(row["velocity_detected_mps"]) == pytest.approx(8.0, abs=0.2)


def test_trace_and_radar_run_each_radar_with_its_own_frame(tmp_path, capsys):
    path, out = write(tmp_path), tmp_path / "out"
    assert main(["trace", str(path), "--out", str(out), "--rays", "2000", "-q"]) == 0
    text = capsys.readouterr().out
    assert "A: waveform: f_c 24 GHz, N 256, M 64" in text
    assert "B: waveform: FMCW" in text
    _plate_found(_truth(out / "A_truth.csv")["plate"], 6.441)   # OFDM Δr
    _plate_found(_truth(out / "B_truth.csv")["plate"], 1.171)   # FMCW Δr
    again = tmp_path / "again"
    assert main(["radar", str(out / "snapshot.npz"), "--scene", str(path), "--out",
                 str(again)]) == 0
    assert "B: waveform: FMCW" in capsys.readouterr().out
    for name in ("A", "B"):
        assert (again / f"{name}_truth.csv").read_text() == \
            (out / f"{name}_truth.csv").read_text()
    # compare-waveforms puts the --fmcw chirp beside each radar's OFDM frame: B's own
    # FMCW table is refused by its key
    table = tmp_path / "fmcw.toml"
    table.write_text(FMCW_OWN.replace("[radars.waveform]", "[waveform]"))
    assert main(["compare-waveforms", str(out / "snapshot.npz"), "--scene", str(path),
                 "--fmcw", str(table), "--out", str(tmp_path / "cmp")]) == 2
    assert "radars[1].waveform.kind" in capsys.readouterr().err


def test_cube_runs_the_chosen_radars_own_frame(tmp_path, capsys):
    radar_b = RADAR_B.replace("noise_figure_db = 10.0\n", "noise_figure_db = 10.0\n" + ARRAYS)
    path = write(tmp_path, radar_b=radar_b)
    assert main(["cube", str(path), "--radar", "B", "--out", str(tmp_path / "out"),
                 "--rays", "2000", "-q"]) == 0
    text = capsys.readouterr().out
    assert "waveform: FMCW" in text
    # FMCW TDM-MIMO: 128 samples per chirp, the 64 chirps shared by 2 transmitters
    assert "N x M = 128 x 64" in text


def test_drive_runs_the_chosen_radars_own_frame(tmp_path):
    path = write(tmp_path)
    out = tmp_path / "out"
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        code = main(["drive", str(path), "--out", str(out), "--radar", "B", "--start", "0",
                     "--step", "0.1", "--count", "2", "--no-video", "--workers", "0",
                     "--rays", "2000", "-q"])
    assert code == 0, text.getvalue()
    assert "waveform: FMCW" in text.getvalue()
    with open(out / "B_detections.csv") as fh:
        rows = list(csv.DictReader(fh))
    # the plate at 20 m, then 19.2 m: found in the FMCW radar's 1.17 m cells
    for step, want in ((0, 20.0), (1, 19.2)):
        ranges = [float(r["range_m"]) for r in rows if int(r["frame"]) == step]
        assert min(abs(r - want) for r in ranges) < 0.2


def test_commands_of_one_frame_refuse_a_radars_own_table_by_its_key(tmp_path, capsys):
    """comms decodes with the receiver's frame: a sender's other frame is refused; map and
    microdoppler build one frame for the scene and refuse a radar's own table rather than
    run the scene's in its place."""
    own_ofdm = "[radars.waveform]\nsubcarriers = 128\nsymbols = 64\n"
    path = write(tmp_path, own=own_ofdm,
                 radar_b=RADAR_B.replace('name = "B"', 'name = "D"'))
    assert main(["comms", str(path), "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "radars[1].waveform" in err and "frames differ" in err
    with pytest.raises(SceneError) as exc:
        refuse_radar_waveforms(load_scene(path), "map")
    assert exc.value.key == "radars[1].waveform"
    refuse_radar_waveforms(load_scene(write(tmp_path, own="", name="plain.toml")), "map")
