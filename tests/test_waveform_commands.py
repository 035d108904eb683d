"""Every command reads the radar frame the same way (issue #17, item 8): the scene's
``[waveform]`` reaches ``clradcom comms``, ``interference`` and ``tradeoff`` (as it does
trace, radar and cube), the options override it, and contradictory values are refused
naming the option or the scene's key and the value, before anything is traced."""

from __future__ import annotations

import pytest
from tool_helpers import CLOSING_PLATE_SCENE

from clradcom.commands import comms, interference, tradeoff

TWO_RADARS = CLOSING_PLATE_SCENE + """
[[radars]]
name = "D"
position = [30.0, 5.0, 1.0]
orientation_deg = [0.0, 0.0, 180.0]
pattern = "sector"
tx_power_w = 0.01
noise_figure_db = 10.0
"""

FRAME = """
[waveform]
subcarriers = 96
symbols = 24
subcarrier_spacing_hz = 120e3
cyclic_prefix_samples = 12
modulation = "16qam"
"""


class Reached(Exception):
    """Raised by the stand-in for the first stage that receives the frame."""


def scene_file(tmp_path, table=FRAME):
    path = tmp_path / "two.toml"
    path.write_text(TWO_RADARS + table)
    return path


# (command module, its parser's extra arguments, the name of the first function the
# waveform is handed to, which the test replaces to catch it)
COMMANDS = [
    (comms, [], "check_run"),
    (interference, [], "check_offsets"),
    (tradeoff, ["--rays", "1000"], "check_frame_memory"),
]


def run_command(module, argv, catch, monkeypatch):
    """Run the command up to the stage ``catch`` and return the waveform it got."""
    got = {}

    def stand_in(*args, **kwargs):
        got["wf"] = next(a for a in (*args, *kwargs.values()) if hasattr(a, "n_cp"))
        raise Reached

    monkeypatch.setattr(module, catch, stand_in)
    args = module.parse_args(argv, "x")
    with pytest.raises(Reached):
        module.run(args)
    return got["wf"]


@pytest.mark.parametrize("module, extra, catch", COMMANDS,
                         ids=[m.__name__.rsplit(".", 1)[1] for m, _, _ in COMMANDS])
def test_the_scenes_waveform_reaches_every_command(tmp_path, monkeypatch, capsys, module,
                                                   extra, catch):
    path = scene_file(tmp_path)
    out = str(tmp_path / "out")
    wf = run_command(module, [str(path), "--out", out, *extra], catch, monkeypatch)
    assert (wf.n_subcarriers, wf.n_symbols, wf.subcarrier_spacing_hz, wf.n_cp,
            wf.modulation) == (96, 24, 120e3, 12, "16qam")
    assert "N 96, M 24, Δf 120 kHz, 16qam" in capsys.readouterr().out
    # an option overrides the scene's value, the rest still comes from the scene
    wf = run_command(module, [str(path), "--out", out, *extra, "--symbols", "32",
                              "--modulation", "qpsk"], catch, monkeypatch)
    assert (wf.n_subcarriers, wf.n_symbols, wf.n_cp, wf.modulation) == (96, 32, 12, "qpsk")
    # no [waveform], no option: the paper's frame
    wf = run_command(module, [str(scene_file(tmp_path, "")), "--out", out, *extra], catch,
                     monkeypatch)
    assert (wf.n_subcarriers, wf.n_symbols, wf.n_cp) == (1024, 256, 128)


@pytest.mark.parametrize("module, extra, catch", COMMANDS,
                         ids=[m.__name__.rsplit(".", 1)[1] for m, _, _ in COMMANDS])
def test_contradictions_are_refused_naming_the_value(tmp_path, monkeypatch, module, extra,
                                                     catch):
    monkeypatch.setattr(module, catch, lambda *a, **k: pytest.fail("not refused"))
    out = str(tmp_path / "out")
    # the scene's prefix in seconds and in samples disagree (1.375 µs = 15.84 samples)
    bad = scene_file(tmp_path, FRAME + "cyclic_prefix_s = 1.375e-6\n")
    args = module.parse_args([str(bad), "--out", out, *extra], "x")
    with pytest.raises(Exception) as exc:
        module.run(args)
    msg = str(exc.value)
    assert "two.toml" in msg and "waveform.cyclic_prefix_s and " \
        "waveform.cyclic_prefix_samples" in msg and "rounds to 16, not 12" in msg
    # a prefix not shorter than the symbol, from the command line
    args = module.parse_args([str(scene_file(tmp_path)), "--out", out, *extra,
                              "--cp-samples", "96"], "x")
    with pytest.raises(Exception) as exc:
        module.run(args)
    assert "--cp-samples = 96" in str(exc.value) and "N = 96" in str(exc.value)
    assert not (tmp_path / "out").exists()


def test_comms_refuses_a_scene_modulation_it_cannot_decode(tmp_path, monkeypatch):
    monkeypatch.setattr(comms, "check_run", lambda *a, **k: pytest.fail("not refused"))
    path = scene_file(tmp_path, FRAME.replace("16qam", "8psk"))
    args = comms.parse_args([str(path), "--out", str(tmp_path / "o")], "x")
    with pytest.raises(Exception) as exc:
        comms.run(args)
    msg = str(exc.value)
    assert "waveform.modulation" in msg and "8psk" in msg and "16qam" in msg
