"""Micro-Doppler of rotating parts: a spectrogram over the frames of a moving scene.

    clradcom microdoppler scenes/microdoppler/car_wheels.toml
    clradcom microdoppler scene.toml --count 10 --step 0.1 --preset fast --out out/md

The scene needs turning objects (angular_velocity_deg_s: wheels) and a [time] table, or
--start, --step and --count (which replace it). At every instant the radar's own link is
traced (the preset's physics: --preset, default "paper"), one OFDM radar frame is
synthesised from its paths (the scene's [waveform] and the waveform options; thermal
noise from the radar's power and noise figure unless --no-noise), and the Doppler
spectrum of the range cells of the moving objects is one column of the spectrogram. The
spread each column shows (within --dynamic-range dB of its peak and above its noise) and
the spread of the wheel paths are set against the interval the rotating parts can give,
(2/λ)(u·v ± ω r |u⊥|) (docs/microdoppler.md). Written into the output folder (default
out/<scene name>/):

  spectrogram.png     frames across, Doppler up, with the expected interval
  spectrogram.csv     time, Doppler, velocity and power (dB) of every cell
  microdoppler.csv    per frame: expected, path and measured extremes, bodies' Doppler

Errors are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clradcom.commands.options import (
    add_sequence_arguments,
    add_tracer_arguments,
    add_waveform_arguments,
    output_folder,
    positive_float,
    refuse_radar_waveforms,
    run_waveform,
    seed,
    sequence_times,
)
from clradcom.commands.trace import settings_from_args
from clradcom.device.runtime import get_runtime
from clradcom.errors import ArgumentError
from clradcom.files import staged_folder
from clradcom.radar.microdoppler import microdoppler_run, rotating_parts, save_microdoppler
from clradcom.radar.pipeline import check_frame_memory
from clradcom.scene.reader import load_scene
from clradcom.trace import check_launch_memory

__all__ = ["OUTPUTS", "add_arguments", "run"]

#: the names this command writes into its output folder
OUTPUTS = ("spectrogram.png", "spectrogram.csv", "microdoppler.csv")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("scene", help="scene file (TOML) with turning objects and a [time] table "
                    "or --step/--count")
    ap.add_argument("--out", type=output_folder, default=None,
                    help="output folder (default: out/<scene name>/)")
    ap.add_argument("--radar", default=None,
                    help="the radar (default: the first that transmits and receives)")
    add_sequence_arguments(ap, count_help="number of instants (frames)")
    add_tracer_arguments(ap)
    ap.add_argument("--no-noise", action="store_true", help="no thermal noise")
    ap.add_argument("--seed", type=seed, default=0,
                    help="seed of the data symbols and noise (frame k uses seed + k)")
    ap.add_argument("--dynamic-range", type=positive_float, default=40.0, metavar="DB",
                    help="the measured spread: cells within this many dB of a column's "
                    "peak (default 40)")
    add_waveform_arguments(ap)


def run(args) -> int:
    scene = load_scene(args.scene)
    if not rotating_parts(scene):
        raise ArgumentError("has no turning object (no angular_velocity_deg_s): nothing "
                            "gives a micro-Doppler spread", argument="scene",
                            value=args.scene)
    times = sequence_times(scene, args)
    settings = settings_from_args(args)
    check_launch_memory(settings, argument="--rays", value=settings.specular.rays)
    refuse_radar_waveforms(scene, "microdoppler")
    waveform, line = run_waveform(scene.carrier_hz, args, scene=scene)
    check_frame_memory(waveform)
    print(line)
    runtime = get_runtime(args.device)
    out = Path(args.out) if args.out else Path("out") / scene.name

    def each(k, t, paths):
        print(f"  frame {k + 1}/{len(times)}: t = {t:.6g} s, {len(paths.gain)} paths",
              flush=True)

    result = microdoppler_run(scene, settings, waveform=waveform, times=times,
                              radar=args.radar, runtime=runtime, noise=not args.no_noise,
                              seed=args.seed, dynamic_range_db=args.dynamic_range, each=each)
    with staged_folder(out, inputs=scene.input_files, owned=OUTPUTS) as stage:
        save_microdoppler(result, stage, inputs=scene.input_files)
    bin_hz = float(result.doppler_hz[1] - result.doppler_hz[0])
    lo_err = np.nanmax(np.abs(result.measured_lo_hz - result.expected_lo_hz))
    hi_err = np.nanmax(np.abs(result.measured_hi_hz - result.expected_hi_hz))
    print(f"rotating parts: {', '.join(result.part_names)}; Doppler bin {bin_hz:.1f} Hz "
          f"({result.velocity_resolution_mps:.3g} m/s)")
    print(f"expected interval {result.expected_lo_hz[0]:.0f} .. "
          f"{result.expected_hi_hz[0]:.0f} Hz at t = {result.times_s[0]:.6g} s; "
          f"paths {result.paths_lo_hz[0]:.0f} .. {result.paths_hi_hz[0]:.0f} Hz; "
          f"spectrogram {result.measured_lo_hz[0]:.0f} .. {result.measured_hi_hz[0]:.0f} Hz")
    print(f"spectrogram edges against the expected interval over all frames: low within "
          f"{lo_err:.0f} Hz, high within {hi_err:.0f} Hz ({max(lo_err, hi_err) / bin_hz:.2f} "
          f"bins); outputs in {out}/")
    return 0
