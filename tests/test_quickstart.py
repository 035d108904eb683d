"""docs/quickstart.md's Python example runs as written, on a small scene with few rays.

The code block is executed with two substitutions only: the street becomes
tests/data/all_mechanisms.toml (every mechanism, radar A monostatic) and the ``paper``
preset gets 20 000 rays instead of 1e6 (same physics, fewer rays), so the test takes
seconds. Its results are then checked, not just that it ran."""

import re
from pathlib import Path

import numpy as np
import pytest

from clradcom.radar import SPEED_OF_LIGHT, Waveform
from clradcom.radar.truth import detection_truth

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "quickstart.md"
SMALL = ROOT / "tests" / "data" / "all_mechanisms.toml"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_the_quickstart_example_runs_and_detects(tmp_path, monkeypatch, capsys):
    blocks = python_blocks(DOC.read_text())
    assert len(blocks) == 1
    code = blocks[0]
    for old, new in (('"scenes/street/street.toml"', repr(str(SMALL))),
                     ('TraceSettings.preset("paper")',
                      'TraceSettings.preset("paper", specular__rays=20_000)')):
        assert code.count(old) == 1, old
        code = code.replace(old, new)
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(code, str(DOC), "exec"), ns)
    # the paper preset's physics: SBR physical optics and scattering on
    assert ns["settings"].optics.mode == "sbr" and ns["settings"].scattering.enabled
    assert ns["snapshot"].metadata["settings.optics.mode"] == "sbr"
    # radar A's echoes: line of sight absent (monostatic), reflections present
    assert ns["link"].paths.n_paths > 0
    dets = ns["detections"]
    assert len(dets) >= 1
    # the strongest detection is an echo of something in the scene: within its reach
    scene = ns["scene"]
    reach = float(np.max(np.linalg.norm(
        scene.triangles.reshape(-1, 3) - scene.radars[0].position, axis=1)))
    assert 0 < max(dets, key=lambda d: d["snr_db"])["range_m"] < reach + 1.0
    # the car (the scene's one moving object) is detected where its echo is. Its
    # strongest echo path (here the car-hedge double bounce, 35 dB above the rotated
    # box's own return) lies between the car's nearest point and its centre, give or take
    # a range cell, and closes within two velocity cells of the car's 17.8 m/s, faster
    # than anything static (at most the radar's 10 m/s). A detection lies within half a
    # cell of it in range and in velocity.
    wf = Waveform(carrier_hz=scene.carrier_hz)
    cell_m, cell_mps = wf.range_resolution, wf.velocity_resolution
    (car,) = detection_truth(scene, "A", ["car"], wf.wavelength)
    paths = ns["link"].paths
    on_car = np.flatnonzero(np.any(paths.object_id == scene.object_index("car"), axis=1))
    assert on_car.size
    echo = on_car[np.argmax(np.abs(paths.gain[on_car]))]
    echo_m = paths.delay_s[echo] * SPEED_OF_LIGHT / 2
    echo_mps = paths.doppler_hz[echo] * wf.wavelength / 2
    assert car["range_nearest_m"] - cell_m <= echo_m <= car["range_centre_m"] + cell_m
    assert abs(echo_mps - car["v_rel_m_s"]) < 2 * cell_mps and echo_mps > 10.0 + cell_mps
    at_car = [d for d in dets if abs(d["range_m"] - echo_m) <= 0.5 * cell_m
              and abs(d["velocity_mps"] - echo_mps) <= 0.5 * cell_mps]
    assert at_car, (echo_m, echo_mps, [(d["range_m"], d["velocity_mps"]) for d in dets])
    assert (tmp_path / "A_image.png").stat().st_size > 0
    out = capsys.readouterr().out
    assert re.search(r"-?\d+\.\d\d m +-?\d+\.\d\d m/s", out)


@pytest.mark.parametrize("name", ["paper", "fast", "accurate", "go"])
def test_the_quickstart_names_every_preset(name):
    assert f"`{name}`" in DOC.read_text()
