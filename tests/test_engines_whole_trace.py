"""The whole trace, device engine against the host reference (issue #16): on every
canonical scene, the extra scenes and the paper's street, every link's channel at the
radar's 1024 subcarriers agrees within -60 dB NMSE, with the same number of paths; without
fp64 too, the scenes on a knife edge moved just off it (tests/mode_helpers.py)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from mode_helpers import scene_in_mode

from clradcom.scene import load_scene
from clradcom.trace import TraceSettings, trace_scene

ROOT = Path(__file__).resolve().parent.parent
SCENES = sorted((ROOT / "scenes" / "canonical").glob("*.toml")) + [
    ROOT / "scenes" / name / f"{name}.toml" for name in ("plate", "truck77", "guardrail")
] + [ROOT / "tests" / "data" / "all_mechanisms.toml"]
#: the paper's physics at fewer rays and a coarser SBR grid: every mechanism, CI's budget
SETTINGS = TraceSettings.preset("paper").replace(specular__rays=100_000,
                                                 optics__sbr_spacing_wavelengths=2.0)


def channel(paths, n=1024, df=90.909e3):
    k = np.arange(n)[:, None]
    return np.exp(-2j * np.pi * k * df * paths.delay_s[None, :]) @ paths.gain


def nmse_db(h, ref):
    """-inf where the two are equal bit for bit."""
    with np.errstate(divide="ignore"):
        return 10 * np.log10(np.sum(np.abs(h - ref) ** 2) / np.sum(np.abs(ref) ** 2))


def both(scene, runtime, settings):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the scenes' expected physics warnings
        return [trace_scene(scene, settings.replace(engine=e), runtime=runtime)
                for e in ("device", "host")]


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_device_and_host_agree_on_every_link(runtime, path):
    # without fp64 the scenes on a knife edge (a radar on a corner's axis of symmetry, a
    # ground bounce at the pole of a sector pattern) are traced just off it: that the
    # double-float build decides those by its own rounding is no disagreement
    scene = scene_in_mode(path, runtime)
    dev, host = both(scene, runtime, SETTINGS)
    for a, b in zip(dev.links, host.links, strict=True):
        assert a.paths.n_paths == b.paths.n_paths, a.label
        if b.paths.n_paths:
            assert nmse_db(channel(a.paths), channel(b.paths)) < -60.0, a.label


def test_street_device_and_host_agree(runtime):
    scene = load_scene(ROOT / "scenes" / "street" / "street.toml")
    a = scene.radar_index("A")
    settings = SETTINGS.replace(specular__rays=300_000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dev, host = (trace_scene(scene, settings.replace(engine=e), runtime=runtime,
                                 links=[(a, a)]) for e in ("device", "host"))
    p, q = dev.links[0].paths, host.links[0].paths
    assert p.n_paths == q.n_paths > 1000
    assert nmse_db(channel(p), channel(q)) < -60.0
