"""The device matrix (issue #26, docs/devices.md): every OpenCL implementation present
besides the one this suite runs on runs the kernel tests in a subprocess of its own
(``pytest -m conformance --device NAME``), Oclgrind its ``oclgrind`` subset with all its
checks on (memory, data races, uninitialised values, API use: any report fails the
test that caused it, tests/conftest.py), and PoCL runs them once more as a device
without fp64 (``--fp64=off``: entry ``pocl-fp64-off``); and the street's main job gives
the same Table III detections and every link's channel within -60 dB NMSE of PoCL's on
each of them.

``CLRADCOM_REQUIRE_DEVICES=pocl,intel,oclgrind`` (CI sets it) makes a named
implementation that is missing a failure; without it the matrix is what is present.
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from device_helpers import (
    NO_FP64_DEVICES,
    NO_FP64_SUFFIX,
    SUBPROCESS_TIMEOUT_S,
    entry_device,
    oclgrind_reports,
    subset_run,
)

from clradcom.commands.options import run_waveform
from clradcom.commands.trace import build_parser, radar_noise, settings_from_args
from clradcom.device.runtime import (
    VENDOR_NAMES,
    choose_device,
    get_runtime,
    list_devices,
)
from clradcom.radar.pipeline import process, radar_frame
from clradcom.radar.report import match_tolerances, moving_objects, truth_rows
from clradcom.radar.truth import detection_truth, match_truth
from clradcom.scene import load_scene
from clradcom.trace import trace_scene

ROOT = Path(__file__).resolve().parent.parent
STREET = ROOT / "scenes" / "street" / "street.toml"
ENV_REQUIRE = "CLRADCOM_REQUIRE_DEVICES"
CHANNEL_NMSE_DB = -60.0


def _required() -> list[str]:
    names = [n.strip().lower() for n in os.environ.get(ENV_REQUIRE, "").split(",")]
    unknown = [n for n in names if n and n not in VENDOR_NAMES]
    if unknown:
        raise pytest.UsageError(f"{ENV_REQUIRE}: {', '.join(unknown)} is not one of "
                                f"{', '.join(VENDOR_NAMES)}")
    return [n for n in names if n]


PRESENT = sorted({info.vendor for info in list_devices() if info.vendor in VENDOR_NAMES})
OWN = choose_device().vendor
#: this suite's own entry: its implementation, without fp64 where it runs so
OWN_ENTRY = OWN if get_runtime().has_double else OWN + NO_FP64_SUFFIX
REQUIRED = _required()
#: the implementations this suite's device is not, and any required one (absent: fails);
#: then those run without fp64 (PoCL), unless this suite is that run
OTHERS = sorted((set(PRESENT) | set(REQUIRED)) - {OWN}) + [
    name + NO_FP64_SUFFIX for name in NO_FP64_DEVICES
    if name + NO_FP64_SUFFIX != OWN_ENTRY and (name in PRESENT or name in REQUIRED)]
#: where the street's main job runs besides PoCL: Oclgrind would take days
STREET_DEVICES = sorted((set(PRESENT) | set(REQUIRED)) - {"pocl", "oclgrind"})


def _present(name: str) -> None:
    if name not in PRESENT:
        seen = "\n  ".join(i.describe() for i in list_devices())
        pytest.fail(f"{ENV_REQUIRE} names {name}, but no OpenCL device of it is present. "
                    f"Devices seen:\n  {seen}\n(docs/devices.md: how CI installs each one)")


def _failures(output: str) -> str:
    """The child's failed tests and errors, from its short summary."""
    lines = [ln for ln in output.splitlines()
             if re.match(r"^(FAILED|ERROR) ", ln) or re.match(r"^=+ .*(failed|error)", ln)]
    return "\n".join(lines)


@pytest.mark.parametrize("name", OTHERS)
def test_kernel_tests_pass_on(name):
    """The conformance subset on entry ``name`` (on Oclgrind: the oclgrind subset, with
    every check on; ``pocl-fp64-off``: PoCL as a device without fp64), in a subprocess
    (started at collection: tests/conftest.py); fails with the subprocess's failures."""
    _present(entry_device(name)[0])
    run = subset_run(name)
    cmd = " ".join(run.cmd)
    if run.returncode is None:
        pytest.fail(f"{cmd} ran past {SUBPROCESS_TIMEOUT_S} s:\n{run.output[-3000:]}")
    if run.returncode != 0:
        pytest.fail(f"the tests on {name} failed ({cmd}, exit {run.returncode}):\n"
                    f"{_failures(run.output) or run.output[-6000:]}", pytrace=False)
    assert re.search(r"\d+ passed", run.output), run.output[-3000:]
    # a report outside any test's capture (at exit, in a session fixture) counts too
    assert not oclgrind_reports(run.output), oclgrind_reports(run.output)[:20]


def _main_job(runtime):
    """The street's main job (``clradcom trace scenes/street/street.toml``: its settings,
    every link) on ``runtime``: the snapshot and radar A's Table III rows (each car's set
    range and speed beside the detection matching it, as the job prints them)."""
    scene = load_scene(STREET)
    args = build_parser().parse_args([str(STREET)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the street's expected physics warnings
        snap = trace_scene(scene, settings_from_args(args), runtime=runtime)
    a = scene.radar_index("A")
    link = next(lk for lk in snap if lk.tx_index == a and lk.rx_index == a)
    radar = scene.radars[a]
    wf, _ = run_waveform(scene.carrier_hz, args, scene=scene)
    nf = radar_noise(scene, args)[a]
    D, Dr = radar_frame(link.paths, wf, seed=args.seed, method=args.synthesis,
                        tx_power_w=radar.tx_power_w if nf is not None else None,
                        noise_figure_db=nf)
    _, dets = process(D, Dr, wf)
    truth = detection_truth(scene, radar.name, moving_objects(scene, radar))
    rows = truth_rows(truth, match_truth(dets, truth, *match_tolerances(wf)))
    return snap, {row[0]: row for row in rows}


def _channel(paths, n=1024, df=90.909e3):
    k = np.arange(n)[:, None]
    return np.exp(-2j * np.pi * k * df * paths.delay_s[None, :]) @ paths.gain


@pytest.fixture(scope="module")
def street_on_pocl():
    _present("pocl")
    return _main_job(get_runtime("pocl"))


@pytest.mark.parametrize("name", STREET_DEVICES)
def test_street_main_job_agrees_with_pocl(name, street_on_pocl):
    """Radar A's detections of cars B, C and D are PoCL's, as the main job prints them,
    and every link's channel at the radar's 1024 subcarriers is within -60 dB NMSE of
    PoCL's."""
    _present(name)
    ref_snap, ref_rows = street_on_pocl
    snap, rows = _main_job(get_runtime(name))
    for car in ("carB", "carC", "carD"):
        assert ref_rows[car][4], f"PoCL's main job misses {car}: {ref_rows[car]}"
        assert rows[car] == ref_rows[car], (car, rows[car], ref_rows[car])
    assert [lk.label for lk in snap] == [lk.label for lk in ref_snap]
    for lk, ref in zip(snap, ref_snap, strict=True):
        h, h_ref = _channel(lk.paths), _channel(ref.paths)
        nmse = float(np.sum(np.abs(h - h_ref) ** 2) / np.sum(np.abs(h_ref) ** 2))
        assert nmse <= 10 ** (CHANNEL_NMSE_DB / 10), (lk.label, 10 * np.log10(nmse))
