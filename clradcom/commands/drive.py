"""Drive a moving scene through time: trace it at every instant and follow its paths.

    clradcom drive scenes/street/street_drive.toml
    clradcom drive scene.toml --start 0 --step 0.01 --count 100 --preset fast
    clradcom drive SCENE --workers 0                     serially in this process
    clradcom drive SCENE --scheduler tcp://host:8786     on workers started elsewhere

The instants are the scene's [time] table (start_s, step_s, count), or --start, --step and
--count (which replace it); objects and radars move by their velocity, trajectory and
angular velocity (docs/scene-format.md, "Motion"). Every step is traced with the preset's
physics (--preset, default "paper"; --rays and --reflections change one knob) and the
paths of consecutive steps are matched by their interactions, objects and triangles
into tracks.

The steps are traced on Dask like `clradcom sweep` (docs/scale.md): a local cluster of
--workers processes (default 2, as the sweep's: the steps are independent traces, so two
workers trace nearly twice as fast where two cores or devices are free; 0 traces them
here, one after the other, without Dask), or the workers of --scheduler. Each task is a
run of consecutive steps (--chunk; default the steps shared out, one run per worker)
traced with the task's own two-level BVH, refit step by step; every worker opens its own
OpenCL device (--device for all, or --devices shared out); a task that fails or loses
its worker runs again up to --retries times. The results are those of the serial run bit
for bit, gathered in step order. Written into the output folder (default out/<scene
name>/):

  series.npz              every track's gain, delay and Doppler per step (docs/series.md)
  snapshot_NNNN.npz       with --snapshots: each step's whole snapshot (its time_s set)

With --radar NAME only that radar's own echoes are traced, and each step is also a radar
frame (docs/tracking.md): range-Doppler image and CFAR detections (with an array: the
TDM-MIMO cube and azimuth), a Stone Soup tracker (constant-velocity Kalman filter, GNN
association, M-of-N initiation) over the detections of moving objects (the stationary
world, at the closing speeds the radar's own motion gives it, and the radar's mounting
left out), and the moving objects' truth at every instant:

  <radar>_detections.csv  time_s, frame, radar, range, velocity, [azimuth], power, SNR
  <radar>_tracks.csv      every live track per frame (range, velocity, confirmed)
  <radar>_track_truth.csv each moving object per frame: visible, its track, errors in cells
  <radar>_tracks.png      tracks against the true ranges and velocities over time
  <radar>_video.gif       the range-Doppler image per frame, detections, truth, tracks
                          (--no-video: none; --mp4: also <radar>_video.mp4, needs ffmpeg)
  <radar>_frames.csv      per frame: paths, detections (all, moving), confirmed tracks,
                          visible objects, OSPA and GOSPA (cells), seconds tracing and
                          processing

and prints per object whether its track stayed within one range and one velocity cell of
its truth in every frame where it is visible, the OSPA and GOSPA distances per frame, and
the time per frame.

Errors are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clradcom.commands.console import progress_bar, write_line
from clradcom.commands.options import (
    add_frame_arguments,
    add_sequence_arguments,
    add_tracer_arguments,
    add_waveform_arguments,
    finite_float,
    int_in,
    output_folder,
    positive_float,
    run_waveform,
    sequence_times,
)
from clradcom.commands.sweep import add_cluster_arguments, cluster_text
from clradcom.commands.trace import radar_noise, settings_from_args
from clradcom.distributed import quiet_dask_logs, run_drive
from clradcom.errors import ArgumentError
from clradcom.files import save_figure, staged_folder
from clradcom.radar.pipeline import check_frame_memory
from clradcom.radar.report import write_table
from clradcom.radar.tracking import SCORE_DTYPE, TRACK_DTYPE, score_summary
from clradcom.radar.video import (
    DETECTION_TABLE_COLUMNS,
    FRAME_COLUMNS,
    MIN_SNR_DB,
    detection_table_rows,
    drive_radar,
    ffmpeg_available,
    save_gif,
    save_mp4,
    score_rows,
    track_rows,
    tracks_figure,
)
from clradcom.scene.motion import MAX_TIME_STEPS
from clradcom.scene.reader import load_scene
from clradcom.series import save_series, series_from_snapshots
from clradcom.snapshot import save_snapshot
from clradcom.trace import check_launch_memory

__all__ = ["OUTPUTS", "add_arguments", "run"]

#: the names this command writes into its output folder
OUTPUTS = ("series.npz", "snapshot_*.npz", "*_detections.csv", "*_tracks.csv",
           "*_track_truth.csv", "*_tracks.png", "*_video.gif", "*_video.mp4", "*_frames.csv")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("scene", help="scene file (TOML), with a [time] table or --step/--count")
    ap.add_argument("--out", type=output_folder, default=None,
                    help="output folder (default: out/<scene name>/)")
    add_sequence_arguments(ap)
    add_tracer_arguments(ap, device_help="OpenCL device of every worker: 'gpu', 'cpu', 'P:D' "
                                         "or part of its name (--devices: one per worker)")
    ap.add_argument("--snapshots", action="store_true",
                    help="also write every step's snapshot")
    g = ap.add_argument_group("radar video and tracks (docs/tracking.md)")
    g.add_argument("--radar", default=None,
                   help="trace only this radar's own echoes and run its radar chain, "
                        "tracker and truth at every step")
    g.add_argument("--no-video", action="store_true", help="no <radar>_video.gif")
    g.add_argument("--mp4", action="store_true",
                   help="also write <radar>_video.mp4 (needs ffmpeg on the PATH)")
    g.add_argument("--fps", type=positive_float, default=5.0,
                   help="frames per second of the video (default %(default)s)")
    g.add_argument("--min-snr-db", type=finite_float, default=MIN_SNR_DB,
                   help="an object in the beam is visible when its echoes reach this SNR "
                        "(dB, default %(default)s)")
    add_frame_arguments(g, seed_help="seed of frame 0's OFDM data (frame k: seed + 2k; "
                                     "noise + 1)")
    add_cluster_arguments(ap).add_argument(
        "--chunk", type=int_in(1, MAX_TIME_STEPS), default=None,
        help="consecutive steps per task (default: the steps shared out evenly, one task "
             "per worker)")
    add_waveform_arguments(ap)
    ap.add_argument("-q", "--quiet", action="store_true",
                    help="no progress bars (they show only on a terminal)")


def _radar_of(scene, args):
    """(index, waveform, noise figure) of --radar, checked before any tracing."""
    if args.radar is None:
        if args.mp4 or args.no_video:
            raise ArgumentError("needs --radar (the video is a radar's)",
                                argument="--mp4" if args.mp4 else "--no-video", value=None)
        return None, None, None
    try:
        index = scene.radar_index(args.radar)
    except (KeyError, ValueError, IndexError):
        raise ArgumentError("is no radar of the scene (" + ", ".join(
            r.name for r in scene.radars) + ")", argument="--radar", value=args.radar) from None
    radar = scene.radars[index]
    if radar.role != "txrx":
        raise ArgumentError(f"has role {radar.role!r}: only a transmit-receive radar has "
                            "echoes to image", argument="--radar", value=args.radar)
    if radar.tx_power_w == 0:
        raise ArgumentError("has tx_power_w = 0: it transmits nothing, so it has no echo",
                            argument="--radar", value=args.radar)
    if args.mp4 and not ffmpeg_available():
        raise ArgumentError("needs ffmpeg on the PATH (the GIF needs nothing; leave --mp4 "
                            "out)", argument="--mp4", value=None)
    wf, frame = run_waveform(scene.carrier_hz, args, scene=scene, fmcw=True, radar=index)
    print(f"  {frame}")
    check_frame_memory(wf, args.synthesis)
    return index, wf, radar_noise(scene, args)[index]


def _radar_outputs(stage: Path, scene, res, times, n_paths, trace_s, args) -> None:
    name = res.radar
    rows = []
    for k, det in enumerate(res.detections):
        rows += detection_table_rows(k, times[k], name, det, azimuth=res.azimuth)
    cols = DETECTION_TABLE_COLUMNS if res.azimuth else tuple(
        c for c in DETECTION_TABLE_COLUMNS if c != "azimuth_deg")
    write_table(stage / f"{name}_detections.csv", rows, cols, inputs=scene.input_files)
    write_table(stage / f"{name}_tracks.csv", track_rows(res.tracks), TRACK_DTYPE.names)
    write_table(stage / f"{name}_track_truth.csv", score_rows(res.scores), SCORE_DTYPE.names)
    save_figure(tracks_figure(res, f"Radar {name}, scene {scene.name}: tracks against "
                                   "truth"), stage / f"{name}_tracks.png", dpi=120)
    m = res.metrics
    write_table(stage / f"{name}_frames.csv",
                [(str(k), f"{times[k]:.6f}", str(n_paths[k]), str(len(res.detections[k])),
                  str(int(res.moving[k].sum())), str(m["confirmed_tracks"][k]),
                  str(m["visible_objects"][k]), f"{m['ospa_cells'][k]:.4f}",
                  f"{m['gospa_cells'][k]:.4f}", f"{trace_s[k]:.3f}", f"{res.radar_s[k]:.3f}")
                 for k in range(len(times))], FRAME_COLUMNS)
    if res.frames:
        save_gif(stage / f"{name}_video.gif", res.frames, args.fps)
        if args.mp4:
            save_mp4(stage / f"{name}_video.mp4", res.frames, args.fps)


def _print_summary(res, trace_s) -> None:
    confirmed = set(res.tracks["track"][res.tracks["confirmed"]].tolist())
    print(f"  radar {res.radar}: cells {res.range_cell_m:.3f} m, "
          f"{res.velocity_cell_mps:.3f} m/s; {sum(len(d) for d in res.detections)} "
          f"detections, {sum(int(m.sum()) for m in res.moving)} of moving objects tracked; "
          f"{len(set(res.tracks['track'].tolist()))} tracks started, {len(confirmed)} "
          "confirmed")
    m = res.metrics
    print("  per frame: confirmed tracks / visible objects, OSPA and GOSPA (cells, cut-off "
          "3, p = 2): " + ", ".join(f"{c}/{v} {o:.2f} {g:.2f}" for c, v, o, g in zip(
              m["confirmed_tracks"], m["visible_objects"], m["ospa_cells"], m["gospa_cells"],
              strict=True)))
    print(f"  mean OSPA {np.mean(m['ospa_cells']):.2f} cells, mean GOSPA "
          f"{np.mean(m['gospa_cells']):.2f} cells over {len(m)} frames")
    print(f"    {'object':<10} {'visible':>8} {'within':>7} {'max cells (R, v)':>17}  tracks")
    for s in score_summary(res.scores):
        cells = ("" if not s["tracks"] else
                 f"{s['max_range_error_cells']:.2f}, {s['max_velocity_error_cells']:.2f}")
        print(f"    {s['object']:<10} {s['visible']:>3}/{s['frames']:<4} {s['within']:>7} "
              f"{cells:>17}  {' '.join(f'T{t}' for t in s['tracks']) or '-'}"
              + ("  all visible frames within one cell" if s["all_within"] else ""))
    n = len(trace_s)
    print(f"  time per frame: trace {np.mean(trace_s):.2f} s, radar chain, tracker and "
          f"video {np.mean(res.radar_s):.2f} s, total "
          f"{(np.sum(trace_s) + np.sum(res.radar_s)) / n:.2f} s ({n} frames)")


def run(args) -> int:
    scene = load_scene(args.scene)
    times = sequence_times(scene, args)
    settings = settings_from_args(args)
    check_launch_memory(settings, argument="--rays", value=settings.specular.rays)
    index, wf, nf = _radar_of(scene, args)
    if args.device is not None and args.devices is not None:
        raise ArgumentError("give --device (every worker) or --devices (one each), not both",
                            argument="--device", value=args.device)
    devices = args.devices or ([args.device] if args.device is not None else None)
    out = Path(args.out) if args.out else Path("out") / scene.name
    links = None if index is None else [(index, index)]
    paths_of, n_paths, trace_s = [], [], []
    print(f"  {len(times)} steps on {cluster_text(args)}, retries {args.retries}")
    quiet = getattr(args, "quiet", False)
    with staged_folder(out, inputs=scene.input_files, owned=OUTPUTS) as stage:
        steps_bar = progress_bar(len(times), "trace", unit="step", quiet=quiet)

        def each(k, t, snap, seconds):
            trace_s.append(seconds)
            paths = sum(len(lk.paths.gain) for lk in snap.links)
            n_paths.append(paths)
            write_line(f"  step {k + 1}/{len(times)}: t = {t:.6g} s, {paths} paths "
                       f"({seconds:.2f} s)")
            if args.snapshots:
                save_snapshot(Path(stage) / f"snapshot_{k:04d}.npz", snap)
            if index is not None:
                paths_of.append(snap.links[0].paths)

        quiet_dask_logs()
        with steps_bar:
            snaps, _ = run_drive(scene, settings, times, workers=args.workers,
                                 scheduler=args.scheduler, devices=devices,
                                 retries=args.retries, links=links, chunk=args.chunk,
                                 each=each, traced=lambda: steps_bar.update(1))
        write_line(f"  following {sum(n_paths)} paths from step to step into tracks ...")
        series = series_from_snapshots(snaps)
        del snaps
        save_series(Path(stage) / "series.npz", series)
        if index is not None:
            with progress_bar(len(times), f"radar {args.radar}", unit="frame",
                              quiet=quiet) as frames_bar:
                def frame_done(k, det):
                    frames_bar.update(1)
                    write_line(f"  frame {k + 1}/{len(times)}: {len(det)} detections")

                res = drive_radar(scene, index, times, paths_of, wf, seed=args.seed,
                                  method=args.synthesis, noise_figure_db=nf,
                                  min_snr_db=args.min_snr_db, video=not args.no_video,
                                  each=frame_done)
            write_line("  writing the tables, the tracks figure"
                       + ("" if args.no_video else " and the video") + " ...")
            _radar_outputs(Path(stage), scene, res, times, n_paths, trace_s, args)
    print(f"{series.n_tracks} tracks over {series.n_steps} steps; outputs in {out}/")
    if index is not None:
        _print_summary(res, trace_s)
    return 0
