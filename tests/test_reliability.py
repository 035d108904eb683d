"""Bad input is refused where it is read, naming what was given (docs/reliability.md)."""

import os
import stat

import pytest
from tool_helpers import ROOT

import clradcom.trace as trace_module
from clradcom.device.runtime import ENV_DEVICE, OpenCLError, get_runtime
from clradcom.errors import ArgumentError, ArgumentTypeError
from clradcom.paths import Paths
from clradcom.radar.waveform import Waveform
from clradcom.scene import load_scene
from clradcom.snapshot import Link, Snapshot, load_snapshot, save_snapshot
from clradcom.trace import SpecularSettings, TraceSettings, trace_scene

PLATE = ROOT / "scenes" / "canonical" / "plate.toml"


def test_a_bad_device_variable_is_blamed_not_a_flag(monkeypatch):
    monkeypatch.setenv(ENV_DEVICE, "bogus-device")
    with pytest.raises(OpenCLError, match=f"{ENV_DEVICE}='bogus-device'") as info:
        get_runtime()
    assert "--device" not in str(info.value).split("matches")[0]


def test_trace_scene_wants_a_scene_not_a_path():
    with pytest.raises(ArgumentTypeError, match="scene = 'plate.toml': must be a Scene"):
        trace_scene("plate.toml")


@pytest.mark.parametrize("links", [[(0, 5)], [(-1, -1)], [(0,)], [("a", 0)]])
def test_links_outside_the_scene_are_refused_before_tracing(links, runtime, monkeypatch):
    scene = load_scene(PLATE)
    def never(*args, **kwargs):  # pragma: no cover - reached only if the check is missing
        raise AssertionError("traced before the links were checked")

    monkeypatch.setattr(trace_module, "kept_geometry", never)
    with pytest.raises(ArgumentError, match="links"):
        trace_scene(scene, TraceSettings(specular=SpecularSettings(rays=100)),
                    runtime=runtime, links=links)


def test_cyclic_prefix_must_be_shorter_than_the_symbol():
    with pytest.raises(ArgumentError, match="cp_s = 1.2e-05: the cyclic prefix must be "
                                            "shorter"):
        Waveform(cp_s=12e-6)
    assert Waveform(cp_s=5.5e-6).n_cp < Waveform().n_subcarriers


def test_overwriting_a_private_snapshot_keeps_it_private(tmp_path):
    snap = Snapshot(scene_name="s", carrier_hz=24e9, scene_hash="ab",
                    links=(Link("A", "A", 0, 0, Paths.empty(0)),))
    target = tmp_path / "snap.npz"
    save_snapshot(target, snap)
    os.chmod(target, 0o600)
    save_snapshot(target, snap)
    assert stat.S_IMODE(target.stat().st_mode) == 0o600
    assert load_snapshot(target) == snap
    assert sorted(p.name for p in tmp_path.iterdir()) == ["snap.npz"]
