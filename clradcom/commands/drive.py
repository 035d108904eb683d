"""Drive a moving scene through time: trace it at every instant and follow its paths.

    clradcom drive scenes/canonical/drive_by.toml
    clradcom drive scene.toml --start 0 --step 0.01 --count 100 --preset fast

The instants are the scene's [time] table (start_s, step_s, count), or --start, --step and
--count (which replace it); objects and radars move by their velocity, trajectory and
angular velocity (docs/scene-format.md, "Motion"). Every step is traced with the preset's
physics (--preset, default "paper"; --rays and --reflections change one knob) and the
paths of consecutive steps are matched by their interactions, objects and triangles
into tracks. Written into the output folder (default out/<scene name>/):

  series.npz              every track's gain, delay and Doppler per step (docs/series.md)
  snapshot_NNNN.npz       with --snapshots: each step's whole snapshot (its time_s set)

Errors are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clradcom.commands.options import finite_float, int_in, output_folder, positive_float
from clradcom.commands.trace import settings_from_args
from clradcom.device.runtime import get_runtime
from clradcom.errors import ArgumentError
from clradcom.files import staged_folder
from clradcom.mechanisms.common import ENGINES
from clradcom.presets import DEFAULT_PRESET, PRESETS
from clradcom.scene.motion import MAX_TIME_STEPS
from clradcom.scene.reader import load_scene
from clradcom.series import save_series, trace_series
from clradcom.snapshot import save_snapshot
from clradcom.trace import check_launch_memory

__all__ = ["OUTPUTS", "add_arguments", "run"]

#: the names this command writes into its output folder
OUTPUTS = ("series.npz", "snapshot_*.npz")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("scene", help="scene file (TOML), with a [time] table or --step/--count")
    ap.add_argument("--out", type=output_folder, default=None,
                    help="output folder (default: out/<scene name>/)")
    ap.add_argument("--start", type=finite_float, default=None,
                    help="first instant (s; default the [time] table's start_s, else 0)")
    ap.add_argument("--step", type=positive_float, default=None, help="time step (s)")
    ap.add_argument("--count", type=int_in(1, MAX_TIME_STEPS), default=None,
                    help="number of instants")
    ap.add_argument("--preset", choices=tuple(PRESETS), default=DEFAULT_PRESET,
                    help="the tracer's physics (default %(default)s)")
    ap.add_argument("--rays", type=int_in(1, 10**9), default=None,
                    help="rays launched per transmitter")
    ap.add_argument("--reflections", type=int_in(0, 16), default=None,
                    help="most specular reflections per path")
    ap.add_argument("--no-scattering", action="store_true", help="no diffuse scattering")
    ap.add_argument("--engine", choices=ENGINES, default="device",
                    help="device (default) or host (the numpy reference)")
    ap.add_argument("--device", default=None,
                    help="OpenCL device: 'gpu', 'cpu', 'P:D' or part of its name")
    ap.add_argument("--snapshots", action="store_true",
                    help="also write every step's snapshot")
    ap.set_defaults(no_sbr_mirrors=False)


def _times(scene, args) -> np.ndarray:
    axis = scene.time_axis
    start = args.start if args.start is not None else (axis.start_s if axis else 0.0)
    step = args.step if args.step is not None else (axis.step_s if axis else None)
    count = args.count if args.count is not None else (axis.count if axis else None)
    if step is None or count is None:
        raise ArgumentError(f"{args.scene} has no [time] table: give --step and --count",
                            argument="--step", value=None)
    return start + step * np.arange(count, dtype=np.float64)


def run(args) -> int:
    scene = load_scene(args.scene)
    times = _times(scene, args)
    settings = settings_from_args(args)
    check_launch_memory(settings, argument="--rays", value=settings.specular.rays)
    runtime = get_runtime(args.device)
    out = Path(args.out) if args.out else Path("out") / scene.name
    with staged_folder(out, inputs=[args.scene], owned=OUTPUTS) as stage:
        def each(k, t, snap):
            paths = sum(len(lk.paths.gain) for lk in snap.links)
            print(f"  step {k + 1}/{len(times)}: t = {t:.6g} s, {paths} paths", flush=True)
            if args.snapshots:
                save_snapshot(Path(stage) / f"snapshot_{k:04d}.npz", snap)

        series = trace_series(scene, settings, times, runtime=runtime, each=each)
        save_series(Path(stage) / "series.npz", series)
    print(f"{series.n_tracks} tracks over {series.n_steps} steps; outputs in {out}/")
    return 0
