"""The radar chain over a drive: one frame per instant, a detection table with a time
column, the tracks of :mod:`clradcom.radar.tracking` set against the objects' true
trajectories, and the frames as an animated GIF (docs/tracking.md).

Per instant t_k (``radar_step``): the radar's own echoes traced at t_k give its OFDM
frame, range–Doppler image and detections (:func:`clradcom.radar.pipeline.radar_frame`
and :func:`~clradcom.radar.pipeline.process`: CFAR, then range and velocity refined to
the periodogram maximum, at the Cramér–Rao bound); a radar with an array gets its TDM
frame and radar cube instead (:func:`clradcom.radar.array_frame.run_array_radar`), its
detections carry an azimuth and its image is the cube summed over angle. Frame k uses
the OFDM data seed ``seed + 2k`` (the noise ``seed + 2k + 1``), so frames are
independent. The truth of frame k is :func:`clradcom.radar.truth.detection_truth` on the
scene moved to t_k (:func:`clradcom.scene.motion.scene_at`), with each object's echo SNR
(:func:`echo_snr_db`): an object is *visible* when it reaches ``min_snr_db``.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import time
from dataclasses import dataclass, field

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from PIL import Image

from clradcom.errors import ArgumentError
from clradcom.figures import new_figure
from clradcom.files import atomic_write
from clradcom.radar.pipeline import radar_chain
from clradcom.radar.plots import image_title, mounting_return_range_m, plot_radar_image
from clradcom.radar.report import display_range_db, moving_objects
from clradcom.radar.synthesis import thermal_noise_power
from clradcom.radar.tracking import (
    Tracker,
    TrackerSettings,
    moving_detections,
    score_tracks,
    stationary_speed_band,
    track_metrics,
)
from clradcom.radar.truth import detection_truth
from clradcom.radar.waveform import Waveform
from clradcom.scene.motion import scene_at

__all__ = ["DETECTION_TABLE_COLUMNS", "DriveRadar", "FRAME_COLUMNS", "MIN_SNR_DB",
           "beam_directions", "detection_table_rows", "drive_radar", "echo_snr_db",
           "ffmpeg_available", "frame_truth", "radar_step", "save_gif", "save_mp4", "score_rows",
           "track_rows", "tracks_figure"]

#: an object is visible in a frame when its echoes' SNR after the range–Doppler
#: processing gain N·M reaches this (dB): the CA-CFAR threshold at p_fa = 1e-6 (about
#: 12 dB over the noise estimate with the pipeline's 40-odd training cells), plus the
#: Hann windows' SNR loss (1.8 dB per dimension), the straddle loss of a peak between
#: cells (up to about 3 dB in all), and some 6 dB for a high detection probability and
#: an echo spread over more than one cell
MIN_SNR_DB = 25.0

#: header of the detection table (``azimuth_deg`` only for a radar with an array)
DETECTION_TABLE_COLUMNS = ("time_s", "frame", "radar", "range_m", "velocity_m_s",
                           "azimuth_deg", "power_db", "snr_db")
#: header of the per-frame table: its time, paths, detections (all, and those of moving
#: objects that the tracker takes), confirmed tracks against visible objects, the OSPA
#: and GOSPA distances in cells (:func:`clradcom.radar.tracking.track_metrics`) and the
#: seconds spent
FRAME_COLUMNS = ("frame", "time_s", "paths", "detections", "moving_detections",
                 "confirmed_tracks", "visible_objects", "ospa_cells", "gospa_cells",
                 "trace_s", "radar_s")

#: sampling step (deg) of the directions over which the beam's stationary closing speeds
#: are found: 12.9 m/s · (1 − cos 0.5°) = 0.5 mm/s, nothing against a velocity cell
_BEAM_STEP_DEG = 0.5


def radar_step(paths, radar, waveform: Waveform, *, seed: int = 0, method: str = "fast",
               noise_figure_db: float | None = None):
    """(image, detections) of one frame of ``radar``'s own echoes ``paths``: the
    single-antenna chain, or the TDM-MIMO cube for a radar with an array (module
    docstring). Noise when ``noise_figure_db`` is given.

    An array radar's detections keep the windowed cube's parabola estimates, not the
    cube's default ML refinement: a car is many unresolved scatterers in one cell, and the
    one-target ML fit then shows angular glint (on the two-car test drive it put car B at
    3.7°, 12.3° and 2.7° in three frames while the car spans 5.8°–9.7°; the parabola gave
    7.0°, 8.2° and 6.1°), which a tracker cannot follow (docs/tracking.md): the one chain
    of :func:`clradcom.radar.pipeline.radar_chain` with ``refine="parabola"``
    (``clradcom cube --refine parabola`` on the same paths gives the same detections)."""
    tx_power = radar.tx_power_w if noise_figure_db is not None else None
    res = radar_chain(paths, waveform, radar=radar, seed=seed, method=method,
                      tx_power_w=tx_power, noise_figure_db=noise_figure_db, refine="parabola")
    return res.image, res.detections


def echo_snr_db(paths, object_index: int, waveform: Waveform, tx_power_w: float,
                noise_figure_db: float | None) -> float:
    """SNR (dB) of an object's echoes in the range–Doppler image: the summed power of
    the paths that touch the object, Σ|a|², times the processing gain N·M, over the
    thermal noise kTBF / P_tx per cell (:func:`clradcom.radar.synthesis.add_thermal_noise`).
    +inf without noise (``noise_figure_db`` None) when it has any echo, -inf with none."""
    n = np.asarray(paths.n_interactions)
    obj = np.asarray(paths.object_id)
    k = np.arange(obj.shape[1])[None, :] < n[:, None]
    mask = ((obj == object_index) & k).any(axis=1)
    power = float(np.sum(np.abs(np.asarray(paths.gain)[mask]) ** 2))
    if power <= 0:
        return -math.inf
    if noise_figure_db is None:
        return math.inf
    noise = thermal_noise_power(waveform.bandwidth, noise_figure_db) / tx_power_w
    return 10 * math.log10(power * waveform.n_subcarriers * waveform.n_symbols / noise)


def frame_truth(scene, radar, targets, paths, waveform: Waveform, time_s: float, *,
                noise_figure_db: float | None, min_snr_db: float = MIN_SNR_DB) -> list[dict]:
    """The truth rows of ``targets`` (object names) seen from ``radar`` in ``scene``
    (already at ``time_s``), each with ``time_s``, ``echo_snr_db``, ``in_beam`` (its
    centre inside the radar's −3 dB beam) and ``visible``: in the beam, and its echoes at
    ``min_snr_db`` or more. (An object whose centre has left the beam still returns from
    the part of it inside: that part's range and velocity are not the centre's.)"""
    rows = detection_truth(scene, radar.name, targets, waveform.wavelength)
    peak = 10.0 ** (radar.pattern.peak_gain_dbi() / 10.0)
    for t in rows:
        snr = echo_snr_db(paths, scene.object_index(t["name"]), waveform, radar.tx_power_w,
                          noise_figure_db)
        d = radar.orientation.T @ (np.asarray(t["centre_m"]) - np.asarray(radar.position))
        gain = float(np.asarray(radar.pattern.gain(d[None, :] / np.linalg.norm(d)))[0])
        in_beam = gain >= 0.5 * peak
        t.update(time_s=float(time_s), echo_snr_db=snr, in_beam=bool(in_beam),
                 visible=bool(in_beam and snr >= min_snr_db))
    return rows


def beam_directions(radar, step_deg: float = _BEAM_STEP_DEG) -> np.ndarray:
    """Unit directions (n, 3, the radar's frame) inside its −3 dB beam (the criterion of
    :func:`frame_truth`'s ``in_beam``), sampled every ``step_deg`` in azimuth and
    elevation over the front half-space."""
    ang = np.radians(np.arange(-90.0, 90.0 + step_deg / 2, step_deg))
    az, el = np.meshgrid(ang, ang, indexing="ij")
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)],
                 axis=-1).reshape(-1, 3)
    peak = 10.0 ** (radar.pattern.peak_gain_dbi() / 10.0)
    return d[np.asarray(radar.pattern.gain(d)) >= 0.5 * peak]


def _moving(det, radar, beam, scene_box, mount_m, velocity_cell_mps,
            azimuth_std_deg: float | None) -> np.ndarray:
    """Mask of the detections of moving objects: beyond the mounting return, and outside
    the closing speeds the stationary world can have (widened by one velocity cell) in
    the beam's directions where a scatterer at the detection's range lies inside the
    scene's bounding box ``scene_box`` ((2, 3): lowest and highest corner; e.g. nothing
    stationary far above the road), with an array also within three azimuth σ of the
    detection's azimuth (``azimuth_std_deg``; None: the detections carry no azimuth)."""
    rot = np.asarray(radar.orientation, dtype=float)
    world = beam @ rot.T
    points = (np.asarray(radar.position, dtype=float)[None, None, :]
              + np.asarray(det["range_m"], dtype=float)[:, None, None] * world[None, :, :])
    allowed = ((points >= scene_box[0] - 1e-6) & (points <= scene_box[1] + 1e-6)).all(axis=2)
    if azimuth_std_deg is not None:
        az_dir = np.arcsin(np.clip(beam[:, 1] / np.maximum(np.hypot(beam[:, 0], beam[:, 1]),
                                                           1e-300), -1.0, 1.0))
        tol = 3.0 * math.radians(azimuth_std_deg)
        allowed &= np.abs(az_dir[None, :] - np.asarray(det["azimuth_rad"])[:, None]) <= tol
    lo, hi = stationary_speed_band(rot.T @ np.asarray(radar.velocity, dtype=float), beam,
                                   allowed)
    return moving_detections(det, lo, hi, speed_margin_mps=velocity_cell_mps,
                             min_range_m=0.0 if mount_m is None else mount_m)


def detection_table_rows(frame: int, time_s: float, radar_name: str, detections, *,
                         azimuth: bool) -> list[tuple]:
    """Text rows of :data:`DETECTION_TABLE_COLUMNS` (without ``azimuth_deg`` when
    ``azimuth`` is False) for one frame's detections."""
    out = []
    for d in np.asarray(detections):
        row = [f"{time_s:.6f}", str(frame), radar_name, f"{d['range_m']:.3f}",
               f"{d['velocity_mps']:.3f}"]
        if azimuth:
            row.append(f"{math.degrees(d['azimuth_rad']):.3f}")
        row += [f"{d['power_db']:.2f}", f"{d['snr_db']:.2f}"]
        out.append(tuple(row))
    return out


def _rgba(fig) -> np.ndarray:
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def _video_frame(image, detections, truth, tracks, *, title, range_lim_m, velocity_lim_mps,
                 mount_range_m) -> np.ndarray:
    shown = [t for t in truth if t["visible"]]
    fig = plot_radar_image(image, detections, range_lim_m=range_lim_m,
                           velocity_lim_mps=velocity_lim_mps,
                           dynamic_range_db=display_range_db(image), title=title,
                           truth=shown, mount_range_m=mount_range_m)
    ax = fig.axes[0]
    conf = tracks[tracks["confirmed"]]
    if len(conf):
        ax.plot(conf["range_m"], conf["velocity_mps"], "x", color="white", ms=8, mew=2,
                label="confirmed tracks")
        for t in conf:
            if range_lim_m[0] <= t["range_m"] <= range_lim_m[1]:
                ax.annotate(f"T{t['track']}", (t["range_m"], t["velocity_mps"]),
                            textcoords="offset points", xytext=(5, -11), fontsize=7,
                            color="white")
        ax.legend(loc="lower right", fontsize="small")
    return _rgba(fig)


def _check_frames(frames):
    if not len(frames):
        raise ArgumentError("must hold at least one frame", argument="frames", value=0)
    shape = np.asarray(frames[0]).shape
    for f in frames:
        if np.asarray(f).shape != shape or np.asarray(f).dtype != np.uint8 or len(shape) != 3:
            raise ArgumentError(f"must be (H, W, 3) uint8 images of one size {shape}",
                                argument="frames", value=np.asarray(f).shape)


def save_gif(path, frames, fps: float = 5.0, *, inputs=()):
    """Write (H, W, 3) uint8 frames as an animated GIF (Pillow, as matplotlib's
    ``PillowWriter`` does; looping), atomically."""
    _check_frames(frames)
    if not (math.isfinite(fps) and fps > 0):
        raise ArgumentError("must be a positive frame rate", argument="fps", value=fps)
    images = [Image.fromarray(np.asarray(f)) for f in frames]
    duration = int(round(1000.0 / fps))

    def write(fh):
        images[0].save(fh, format="GIF", save_all=True, append_images=images[1:],
                       duration=duration, loop=0)

    return atomic_write(path, write, inputs=inputs)


def ffmpeg_available() -> bool:
    """Whether an ``ffmpeg`` executable is on the PATH (MP4 needs it; GIF does not)."""
    return shutil.which("ffmpeg") is not None


def save_mp4(path, frames, fps: float = 5.0, *, inputs=()):
    """Write frames as an H.264 MP4 through ``ffmpeg`` (refused when it is missing),
    atomically."""
    _check_frames(frames)
    exe = shutil.which("ffmpeg")
    if exe is None:
        raise ArgumentError("needs ffmpeg on the PATH for MP4 (the GIF needs nothing)",
                            argument="--mp4", value=str(path))
    h, w, _ = np.asarray(frames[0]).shape
    raw = b"".join(np.ascontiguousarray(f).tobytes() for f in frames)
    cmd = [exe, "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s",
           f"{w}x{h}", "-r", f"{fps:g}", "-i", "-", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2",
           "-pix_fmt", "yuv420p", "-vcodec", "libx264", "-f", "mp4",
           "-movflags", "frag_keyframe+empty_moov", "-"]

    def write(fh):
        res = subprocess.run(cmd, input=raw, capture_output=True, check=False)
        if res.returncode:
            raise OSError(f"ffmpeg failed: {res.stderr.decode(errors='replace')[-300:]}")
        fh.write(res.stdout)

    return atomic_write(path, write, inputs=inputs)


@dataclass
class DriveRadar:
    """What :func:`drive_radar` returns: per frame its time, detections, truth rows and
    seconds of radar processing; all frames' tracks (:data:`~clradcom.radar.tracking.
    TRACK_DTYPE`) and their scores against truth; the video frames (RGB arrays) and the
    cell sizes of the scores; per frame the mask of detections of moving objects (those
    tracked) and the OSPA/GOSPA row (:data:`~clradcom.radar.tracking.METRIC_DTYPE`)."""

    radar: str
    times_s: np.ndarray
    detections: list
    truth: list
    tracks: np.ndarray
    scores: np.ndarray
    radar_s: list
    range_cell_m: float
    velocity_cell_mps: float
    azimuth: bool
    frames: list = field(default_factory=list)
    moving: list = field(default_factory=list)
    metrics: np.ndarray = field(default_factory=lambda: np.zeros(0))


def drive_radar(scene, radar_index: int, times_s, paths_per_step, waveform: Waveform, *,
                seed: int = 0, method: str = "fast", noise_figure_db: float | None = None,
                tracker: TrackerSettings | None = None, min_snr_db: float = MIN_SNR_DB,
                video: bool = True, range_lim_m=None, velocity_lim_mps=None,
                each=None) -> DriveRadar:
    """The radar chain, the tracker and the truth over a drive (module docstring):
    ``paths_per_step[k]`` are radar ``radar_index``'s own echoes at ``times_s[k]`` (the
    monostatic link of a snapshot traced at that instant). ``each(k, detections)`` hears
    every frame. Range and velocity limits of the video default to the scene's reach
    (at most 100 m) and ± the fastest truth plus 5 m/s. The tracker takes the detections
    of moving objects only (:func:`_moving`: not the radar's mounting, not the
    stationary world at the closing speeds the radar's own motion gives it in its
    beam)."""
    times = np.asarray(times_s, dtype=float).reshape(-1)
    if len(times) != len(paths_per_step):
        raise ArgumentError(f"must be one set of paths per time ({len(times)} times)",
                            argument="paths_per_step", value=len(paths_per_step))
    radar = scene.radars[radar_index]
    targets = moving_objects(scene, radar)
    array = radar.tx_array is not None or radar.rx_array is not None
    trk = None
    settings = tracker if tracker is not None else TrackerSettings()
    beam = beam_directions(radar)
    tri = np.asarray(scene.triangles, dtype=float).reshape(-1, 3)
    scene_box = np.array([tri.min(axis=0), tri.max(axis=0)]) if len(tri) else np.array(
        [[-np.inf] * 3, [np.inf] * 3])
    out = DriveRadar(radar.name, times, [], [], np.zeros(0), np.zeros(0), [], 0.0, 0.0, array)
    track_rows = []
    for k, (t, paths) in enumerate(zip(times, paths_per_step, strict=True)):
        t0 = time.perf_counter()
        scene_t = scene_at(scene, float(t))
        image, det = radar_step(paths, scene_t.radars[radar_index], waveform,
                                seed=seed + 2 * k, method=method,
                                noise_figure_db=noise_figure_db)
        truth = frame_truth(scene_t, scene_t.radars[radar_index], targets, paths, waveform,
                            t, noise_figure_db=noise_figure_db, min_snr_db=min_snr_db)
        if k == 0:
            out.range_cell_m = float(waveform.range_resolution if not array else
                                     image.range_m[1] - image.range_m[0])
            out.velocity_cell_mps = float(waveform.velocity_resolution if not array else
                                          image.velocity_mps[1] - image.velocity_mps[0])
            trk = Tracker(settings, use_azimuth=array, range_cell_m=out.range_cell_m,
                          velocity_cell_mps=out.velocity_cell_mps)
            if range_lim_m is None:
                reach = float(np.abs(scene.triangles[..., :2]).max()) if len(
                    scene.triangles) else 100.0
                range_lim_m = (0.0, min(reach, 100.0))
            if velocity_lim_mps is None:
                v = max([abs(r["v_rel_m_s"]) for r in truth] +
                        [float(np.linalg.norm(radar.velocity))])
                velocity_lim_mps = (-(v + 5.0), v + 5.0)
        mount_m = mounting_return_range_m(paths, waveform.range_resolution)
        moving = _moving(det, scene_t.radars[radar_index], beam, scene_box, mount_m,
                         out.velocity_cell_mps, settings.azimuth_std_deg if array else None)
        rows = trk.step(t, det[moving])
        # the track table names detections by their index in the frame's whole table
        hit = rows["detection"] >= 0
        rows["detection"][hit] = np.flatnonzero(moving)[rows["detection"][hit]]
        track_rows.append(rows)
        out.moving.append(moving)
        if video:
            title = (f"{image_title(radar.name, scene.name)}\n"
                     f"t = {t:.3f} s (frame {k + 1}/{len(times)})")
            out.frames.append(_video_frame(image, det, truth, rows, title=title,
                                           range_lim_m=range_lim_m,
                                           velocity_lim_mps=velocity_lim_mps,
                                           mount_range_m=mount_m))
        out.detections.append(det)
        out.truth.append(truth)
        out.radar_s.append(time.perf_counter() - t0)
        if each is not None:
            each(k, det)
    out.tracks = np.concatenate(track_rows)
    out.scores = score_tracks(out.tracks, out.truth, out.range_cell_m, out.velocity_cell_mps)
    out.metrics = track_metrics(out.tracks, out.truth, out.range_cell_m,
                                out.velocity_cell_mps)
    return out


def track_rows(tracks) -> list[tuple]:
    """Text rows of the track table (the :data:`~clradcom.radar.tracking.TRACK_DTYPE`
    fields in order)."""
    out = []
    for r in np.asarray(tracks):
        out.append((str(r["frame"]), f"{r['time_s']:.6f}", str(r["track"]),
                    str(int(r["confirmed"])), f"{r['range_m']:.3f}", f"{r['velocity_mps']:.3f}",
                    "" if np.isnan(r["azimuth_deg"]) else f"{r['azimuth_deg']:.3f}",
                    f"{r['range_std_m']:.3f}", f"{r['velocity_std_mps']:.3f}",
                    str(r["detection"])))
    return out


def score_rows(scores) -> list[tuple]:
    """Text rows of the track-against-truth table (the
    :data:`~clradcom.radar.tracking.SCORE_DTYPE` fields in order)."""
    def f(x, nd=3):
        return "" if not np.isfinite(x) else f"{x:.{nd}f}"
    return [(str(s["frame"]), f"{s['time_s']:.6f}", s["object"], str(int(s["visible"])),
             str(s["track"]), f(s["range_nearest_m"]), f(s["range_centre_m"]),
             f(s["velocity_true_mps"]), f(s["range_track_m"]), f(s["velocity_track_mps"]),
             f(s["range_error_cells"]), f(s["velocity_error_cells"]), str(int(s["within"])),
             f(s["azimuth_true_deg"]), f(s["azimuth_track_deg"]))
            for s in np.asarray(scores)]


def tracks_figure(result: DriveRadar, title: str | None = None):
    """Range and velocity against time: each object's truth (its range from nearest
    point to centre as a band, its velocity as a line; dotted where it is not visible)
    and the confirmed track paired with it in each frame where it is visible (markers)."""
    fig = new_figure(figsize=(9.0, 6.0))
    FigureCanvasAgg(fig)
    ax_r, ax_v = fig.subplots(2, 1, sharex=True)
    sc = result.scores
    names = list(dict.fromkeys(sc["object"].tolist()))
    colours = [f"C{i % 10}" for i in range(len(names))]
    for name, c in zip(names, colours, strict=True):
        s = sc[sc["object"] == name]
        vis = s["visible"]
        ax_r.fill_between(s["time_s"], s["range_nearest_m"], s["range_centre_m"], color=c,
                          alpha=0.25, label=f"{name} truth (nearest..centre)")
        ax_v.plot(s["time_s"], np.where(vis, s["velocity_true_mps"], np.nan), "-", color=c,
                  label=f"{name} truth")
        ax_v.plot(s["time_s"], s["velocity_true_mps"], ":", color=c)
        tr = s[(s["track"] >= 0) & vis]
        ax_r.plot(tr["time_s"], tr["range_track_m"], "o", color=c, ms=4, mfc="none",
                  label=f"{name} track (visible frames)")
        ax_v.plot(tr["time_s"], tr["velocity_track_mps"], "o", color=c, ms=4, mfc="none")
    ax_r.set_ylabel("range [m]")
    ax_v.set_ylabel("closing velocity [m/s]")
    ax_v.set_xlabel("time [s]")
    ax_r.legend(fontsize="x-small", ncol=2)
    ax_v.legend(fontsize="x-small", ncol=2)
    ax_r.set_title(title or f"Radar {result.radar}: tracks against truth")
    fig.tight_layout()
    return fig
