"""Micro-Doppler: the Doppler spread of rotating parts (wheels) over consecutive frames.

A point p of an object turning at omega about an axis through c while the object moves at
v has the velocity v + omega x (p - c) (docs/scene-format.md "Motion"), and a monostatic
radar at s moving at v_s sees it at f_D = (2/lambda) u . (v_p - v_s), u = (s - p)/|s - p|.
Over every point of a part within ``r`` of its axis the Doppler lies in

    (2/lambda) [u . (v - v_s) - |omega| r |u_perp|,  u . (v - v_s) + |omega| r |u_perp|]

with u_perp the part of u across the axis (u - (u . w) w, w = omega/|omega|):
omega x (p - c) is perpendicular to omega and at most |omega| r long
(:func:`doppler_interval`). A wheel of radius r rolling without slip has |omega| r = |v|:
seen along its direction of travel, from 0 (the contact point) to 2|v| (the top).

The spectrogram is built per frame (docs/microdoppler.md): each instant of the scene's
``[time]`` table is traced, one OFDM radar frame (M symbols, a few ms) is synthesised from
its paths, and the Doppler spectrum of the range cells the moving objects occupy is one
column (:func:`doppler_spectrum`). A short-time Fourier transform over slow time across
frames would need frames closer than 1/(2 f_D,max) (about 0.15 ms for a wheel top at
20 m/s and 24 GHz): thousands of traces a second. One frame resolves
c/(2 f_c M T_sym) in velocity (1.97 m/s for the paper's frame), enough to show a spread of
2|v|; within the frame every path keeps its Doppler (the wheel turns a few degrees).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg

from clradcom.device.runtime import Runtime
from clradcom.errors import ArgumentError, ArgumentTypeError
from clradcom.figures import new_figure
from clradcom.files import save_figure, write_csv
from clradcom.physics.em import C0
from clradcom.radar.pipeline import radar_frame
from clradcom.radar.processing import radar_image, spectral_estimate
from clradcom.radar.waveform import Waveform
from clradcom.scene.motion import scene_at
from clradcom.scene.records import Scene
from clradcom.trace import TraceSettings, trace_scene

__all__ = ["MicroDoppler", "RotatingPart", "doppler_interval", "doppler_spectrum",
           "microdoppler_run", "path_spread", "range_interval", "rotating_parts",
           "save_microdoppler", "spectrogram_figure", "spread_edges"]


@dataclass(frozen=True)
class RotatingPart:
    """An object that turns: its index and name, rotation centre (m), translation
    velocity (m/s), angular velocity (rad/s, (3,)) and radius about the axis (m: the
    farthest vertex from the axis)."""

    object_id: int
    name: str
    centre: np.ndarray
    velocity: np.ndarray
    omega: np.ndarray
    radius: float


def rotating_parts(scene: Scene) -> list[RotatingPart]:
    """The scene's turning objects (a nonzero ``angular_velocity_deg_s``) at its time."""
    if not isinstance(scene, Scene):
        raise ArgumentTypeError("must be a Scene", argument="scene", value=scene)
    parts = []
    for i, obj in enumerate(scene.objects):
        m = obj.motion
        if m is None or m.angular_velocity_deg_s is None:
            continue
        omega = np.asarray(m.angular_velocity, dtype=np.float64)
        norm = float(np.linalg.norm(omega))
        if norm == 0.0:
            continue
        w = omega / norm
        c = np.asarray(m.rotation_centre, dtype=np.float64)
        q = scene.triangles[obj.tri_slice].reshape(-1, 3) - c
        radius = float(np.max(np.linalg.norm(q - (q @ w)[:, None] * w, axis=1)))
        parts.append(RotatingPart(i, obj.name, c, np.array(scene.object_velocity[i]),
                                  omega, radius))
    return parts


def doppler_interval(part: RotatingPart, radar_position, radar_velocity, carrier_hz: float,
                     points=None) -> tuple[np.ndarray, np.ndarray]:
    """(lowest, highest) monostatic Doppler (Hz) any point of ``part`` can have:
    (2/lambda) (u . (v - v_s) -/+ |omega| r |u_perp|) (module docstring).

    ``points`` None: u along the line of sight from the part's centre to the radar
    (scalars). ``points`` (P, 3): u from each point to the radar (arrays (P,)), so the
    interval holds exactly for a return from that point, whatever its place on the part."""
    lam = C0 / float(carrier_hz)
    s = np.asarray(radar_position, dtype=np.float64)
    vs = np.asarray(radar_velocity, dtype=np.float64)
    p = part.centre if points is None else np.asarray(points, dtype=np.float64)
    u = s - p
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    w_norm = float(np.linalg.norm(part.omega))
    w = part.omega / w_norm
    across = np.linalg.norm(u - (u @ w)[..., None] * w, axis=-1)
    mid = 2.0 / lam * (u @ (part.velocity - vs))
    half = 2.0 / lam * w_norm * part.radius * across
    return mid - half, mid + half


def range_interval(scene: Scene, object_ids, radar_position) -> tuple[float, float]:
    """(nearest, farthest) distance (m) from the radar to the vertices of the objects."""
    ids = [int(i) for i in object_ids]
    if not ids:
        raise ArgumentError("no objects to take the range of", argument="object_ids",
                            value=object_ids)
    pts = np.concatenate([scene.triangles[scene.objects[i].tri_slice].reshape(-1, 3)
                          for i in ids])
    d = np.linalg.norm(pts - np.asarray(radar_position, dtype=np.float64), axis=1)
    return float(d.min()), float(d.max())


def doppler_spectrum(spectral, waveform: Waveform, range_m, *, window="hann",
                     zero_pad_doppler: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The Doppler spectrum of the range cells between ``range_m`` = (lo, hi) m:
    (doppler_hz (M',), power (M',)), the range–Doppler periodogram of the channel estimate
    ``spectral`` (N, M) (:func:`clradcom.radar.processing.radar_image`, ``window`` in range
    and Doppler) summed over the range bins from lo - Δr to hi + Δr (Δr = c/(2NΔf), one
    range cell either side, for the window's main lobe). Doppler bins are fftshifted:
    f = v 2 f_c / c from -1/(2 T_sym) up."""
    lo, hi = (float(x) for x in range_m)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
        raise ArgumentError("must be (lo, hi) m with 0 <= lo <= hi", argument="range_m",
                            value=range_m)
    image = radar_image(spectral, waveform, window, window, 1, zero_pad_doppler)
    cell = C0 / (2.0 * waveform.n_subcarriers * waveform.subcarrier_spacing_hz)
    rows = np.flatnonzero((image.range_m >= lo - cell) & (image.range_m <= hi + cell))
    if rows.size == 0:
        raise ArgumentError(f"no range cell lies within {lo:g} .. {hi:g} m (the frame "
                            f"reaches {image.range_m[-1]:g} m)", argument="range_m",
                            value=range_m)
    power = image.power[rows].sum(axis=0)
    return image.velocity_mps * (2.0 * waveform.carrier_hz / C0), power


def spread_edges(doppler_hz, power, dynamic_range_db: float = 40.0,
                 noise_margin_db: float = 6.0) -> tuple[float, float]:
    """(lowest, highest) Doppler (Hz) of the run of bins around the spectrum's peak whose
    power is within ``dynamic_range_db`` of the peak and ``noise_margin_db`` above the
    spectrum's median (the noise floor where the returns fill few bins): the spread a
    spectrogram column shows. Only bins joined to the peak count, so a noise spike
    elsewhere does not widen it."""
    f = np.asarray(doppler_hz, dtype=np.float64)
    p = np.asarray(power, dtype=np.float64)
    if f.shape != p.shape or f.ndim != 1 or f.size == 0:
        raise ArgumentError("doppler_hz and power must be 1-D arrays of one length",
                            argument="power", value=p.shape)
    for name, value in (("dynamic_range_db", dynamic_range_db),
                        ("noise_margin_db", noise_margin_db)):
        if not (np.isfinite(value) and value > 0):
            raise ArgumentError("must be a positive number of dB", argument=name,
                                value=value)
    top = float(np.max(p))
    if not top > 0:
        return float("nan"), float("nan")
    level = max(top * 10.0 ** (-dynamic_range_db / 10.0),
                float(np.median(p)) * 10.0 ** (noise_margin_db / 10.0))
    on = p >= level
    k = int(np.argmax(p))
    lo = k
    while lo > 0 and on[lo - 1]:
        lo -= 1
    hi = k
    while hi < p.size - 1 and on[hi + 1]:
        hi += 1
    return float(f[lo]), float(f[hi])


def path_spread(paths, object_ids) -> tuple[float, float, int]:
    """(lowest, highest Doppler in Hz, count) of the paths with an interaction on one of
    ``object_ids`` (NaN, NaN, 0 when there is none)."""
    ids = np.asarray(list(object_ids), dtype=np.int64)
    k = np.arange(paths.object_id.shape[1])[None, :]
    valid = k < np.asarray(paths.n_interactions)[:, None]
    hit = np.any(valid & np.isin(paths.object_id, ids), axis=1)
    if not hit.any():
        return float("nan"), float("nan"), 0
    fd = np.asarray(paths.doppler_hz)[hit]
    return float(fd.min()), float(fd.max()), int(hit.sum())


@dataclass(frozen=True, eq=False)
class MicroDoppler:
    """A micro-Doppler run: per frame (instant) the Doppler spectrum of the moving objects'
    range cells, the interval the rotating parts can give and what the paths and the
    spectrum show.

    ``power`` (T, M') linear, ``doppler_hz`` (M',); per frame (T,): ``expected_lo_hz`` /
    ``expected_hi_hz`` (the union of :func:`doppler_interval` over the rotating parts, at
    their centres), ``paths_lo_hz`` / ``paths_hi_hz`` / ``paths_count`` (the paths that
    touch a rotating part), ``measured_lo_hz`` / ``measured_hi_hz`` (:func:`spread_edges`
    of the spectrum), ``body_hz`` (T, B) the Doppler of each moving object that does not
    turn, at its position (``body_names``)."""

    times_s: np.ndarray
    doppler_hz: np.ndarray
    power: np.ndarray
    expected_lo_hz: np.ndarray
    expected_hi_hz: np.ndarray
    paths_lo_hz: np.ndarray
    paths_hi_hz: np.ndarray
    paths_count: np.ndarray
    measured_lo_hz: np.ndarray
    measured_hi_hz: np.ndarray
    body_hz: np.ndarray
    body_names: tuple[str, ...]
    part_names: tuple[str, ...]
    radar_name: str
    carrier_hz: float
    velocity_resolution_mps: float
    dynamic_range_db: float

    def csv_rows(self) -> tuple[list[str], list[list]]:
        """(header, rows) of the per-frame table ``microdoppler.csv``."""
        header = ["time_s", "expected_lo_hz", "expected_hi_hz", "paths_lo_hz",
                  "paths_hi_hz", "wheel_paths", "measured_lo_hz", "measured_hi_hz",
                  *[f"body_hz:{n}" for n in self.body_names]]
        rows = []
        for k, t in enumerate(self.times_s):
            rows.append([f"{t:.9g}", *(f"{x[k]:.6f}" for x in (
                self.expected_lo_hz, self.expected_hi_hz, self.paths_lo_hz,
                self.paths_hi_hz)), int(self.paths_count[k]),
                f"{self.measured_lo_hz[k]:.6f}", f"{self.measured_hi_hz[k]:.6f}",
                *(f"{b:.6f}" for b in self.body_hz[k])])
        return header, rows

    def spectrogram_rows(self) -> tuple[list[str], list[list]]:
        """(header, rows) of ``spectrogram.csv``: one row per frame and Doppler bin, the
        power in dB re the strongest cell of the whole spectrogram."""
        ref = float(np.max(self.power)) if np.max(self.power) > 0 else 1.0
        with np.errstate(divide="ignore"):
            db = 10.0 * np.log10(self.power / ref)
        v = self.doppler_hz * C0 / (2.0 * self.carrier_hz)
        rows = [[f"{t:.9g}", f"{f:.4f}", f"{vv:.6f}", f"{db[k, j]:.3f}"]
                for k, t in enumerate(self.times_s)
                for j, (f, vv) in enumerate(zip(self.doppler_hz, v, strict=True))]
        return ["time_s", "doppler_hz", "velocity_mps", "power_db"], rows


def microdoppler_run(scene: Scene, settings: TraceSettings | None = None, *,
                     waveform: Waveform, times=None, radar: str | None = None,
                     runtime: Runtime | None = None, noise: bool = True, seed: int = 0,
                     dynamic_range_db: float = 40.0,
                     each: Callable[[int, float, int], None] | None = None) -> MicroDoppler:
    """Trace ``scene`` at each instant of ``times`` (default its ``[time]`` table) for the
    monostatic link of ``radar`` (default the first radar that transmits and receives),
    synthesise one frame of ``waveform`` per instant (thermal noise from the radar's power
    and noise figure when ``noise`` and both are set; ``seed`` + frame for the data and
    noise), and take the Doppler spectrum of the range cells of the moving objects.
    ``each(frame, t, paths)`` hears every frame."""
    if not isinstance(scene, Scene):
        raise ArgumentTypeError("must be a Scene", argument="scene", value=scene)
    if not isinstance(waveform, Waveform):
        raise ArgumentTypeError("must be a Waveform", argument="waveform", value=waveform)
    if abs(waveform.carrier_hz - scene.carrier_hz) > 1e-6 * scene.carrier_hz:
        raise ArgumentError(f"the waveform's carrier {waveform.carrier_hz:g} Hz is not the "
                            f"scene's {scene.carrier_hz:g} Hz", argument="waveform",
                            value=waveform.carrier_hz)
    if times is None:
        if scene.time_axis is None:
            raise ArgumentError("the scene has no [time] table: give the times",
                                argument="times", value=None)
        times = scene.time_axis.times
    t_arr = np.asarray(times, dtype=np.float64).reshape(-1)
    if t_arr.size == 0 or not np.all(np.isfinite(t_arr)) or np.any(np.diff(t_arr) <= 0):
        raise ArgumentError("must be one or more finite times, strictly increasing",
                            argument="times", value=times)
    names = [r.name for r in scene.radars]
    if radar is None:
        mono = [i for i, r in enumerate(scene.radars) if r.role == "txrx"]
        if not mono:
            raise ArgumentError("the scene has no radar that transmits and receives",
                                argument="radar", value=None)
        ri = mono[0]
    elif radar in names:
        ri = names.index(radar)
        if scene.radars[ri].role != "txrx":
            raise ArgumentError("must transmit and receive (role txrx)", argument="radar",
                                value=radar)
    else:
        raise ArgumentError(f"is no radar of the scene ({', '.join(names)})",
                            argument="radar", value=radar)
    parts = rotating_parts(scene)
    if not parts:
        raise ArgumentError("has no turning object (no angular_velocity_deg_s)",
                            argument="scene", value=scene.name)
    part_ids = {p.object_id for p in parts}
    riding = scene.radars[ri].rides_on
    bodies = [i for i, o in enumerate(scene.objects) if i not in part_ids and i != riding
              and np.any(scene.object_velocity[i] != 0)]
    moving = sorted(part_ids | set(bodies))
    rows = {k: [] for k in ("lo", "hi", "plo", "phi", "pn", "mlo", "mhi", "body")}
    spectra = []
    doppler = None
    for k, t in enumerate(t_arr):
        at = scene_at(scene, float(t))
        rad = at.radars[ri]
        snap = trace_scene(at, settings, runtime, links=[(ri, ri)])
        paths = snap.links[0].paths
        if each is not None:
            each(k, float(t), paths)
        bounds = [doppler_interval(p, rad.position, rad.velocity, at.carrier_hz)
                  for p in rotating_parts(at)]
        rows["lo"].append(min(b[0] for b in bounds))
        rows["hi"].append(max(b[1] for b in bounds))
        plo, phi, pn = path_spread(paths, part_ids)
        rows["plo"].append(plo)
        rows["phi"].append(phi)
        rows["pn"].append(pn)
        lam = C0 / at.carrier_hz
        body = []
        for b in bodies:
            u = rad.position - at.objects[b].position
            u = u / np.linalg.norm(u)
            body.append(2.0 / lam * u @ (at.object_velocity[b] - rad.velocity))
        rows["body"].append(body)
        noisy = noise and rad.noise_figure_db is not None and rad.tx_power_w > 0
        D, Dr = radar_frame(paths, waveform, seed=seed + k,
                            tx_power_w=rad.tx_power_w if noisy else None,
                            noise_figure_db=rad.noise_figure_db if noisy else None)
        doppler, power = doppler_spectrum(spectral_estimate(Dr, D), waveform,
                                          range_interval(at, moving, rad.position))
        lo, hi = spread_edges(doppler, power, dynamic_range_db)
        rows["mlo"].append(lo)
        rows["mhi"].append(hi)
        spectra.append(power)
    return MicroDoppler(
        times_s=t_arr, doppler_hz=doppler, power=np.array(spectra),
        expected_lo_hz=np.array(rows["lo"]), expected_hi_hz=np.array(rows["hi"]),
        paths_lo_hz=np.array(rows["plo"]), paths_hi_hz=np.array(rows["phi"]),
        paths_count=np.array(rows["pn"], dtype=np.int64),
        measured_lo_hz=np.array(rows["mlo"]), measured_hi_hz=np.array(rows["mhi"]),
        body_hz=np.array(rows["body"], dtype=np.float64).reshape(len(t_arr), len(bodies)),
        body_names=tuple(scene.objects[b].name for b in bodies),
        part_names=tuple(p.name for p in parts), radar_name=names[ri],
        carrier_hz=float(scene.carrier_hz),
        velocity_resolution_mps=C0 / (2.0 * waveform.carrier_hz * waveform.n_symbols
                                      * waveform.symbol_duration),
        dynamic_range_db=float(dynamic_range_db))


def spectrogram_figure(result: MicroDoppler, *, dynamic_range_db: float = 60.0,
                       figsize=(7.0, 4.5)):
    """The spectrogram (frames across, Doppler up, dB re the strongest cell) with the
    rotating parts' expected interval (dashed), the bodies' Doppler (dotted) and the
    spread each column shows within ``result.dynamic_range_db`` (markers)."""
    fig = new_figure(figsize=figsize)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ref = float(np.max(result.power)) if np.max(result.power) > 0 else 1.0
    with np.errstate(divide="ignore"):
        db = 10.0 * np.log10(result.power / ref)
    t = result.times_s
    dt = t[1] - t[0] if t.size > 1 else 1.0
    f = result.doppler_hz
    df = f[1] - f[0]
    span = max(abs(np.nanmin(result.expected_lo_hz)), abs(np.nanmax(result.expected_hi_hz)))
    im = ax.imshow(db.T, origin="lower", aspect="auto", cmap="viridis",
                   vmin=-dynamic_range_db, vmax=0.0, interpolation="nearest",
                   extent=(t[0] - dt / 2, t[-1] + dt / 2, f[0] - df / 2, f[-1] + df / 2))
    fig.colorbar(im, ax=ax, label="power re strongest cell [dB]")
    ax.plot(t, result.expected_lo_hz, "w--", lw=1.2, label="expected wheel interval")
    ax.plot(t, result.expected_hi_hz, "w--", lw=1.2)
    for j, name in enumerate(result.body_names):
        ax.plot(t, result.body_hz[:, j], ":", color="orange", lw=1.2,
                label=f"{name} (2 u·v/λ)")
    ax.plot(t, result.measured_lo_hz, "v", color="red", ms=4,
            label=f"spread within {result.dynamic_range_db:g} dB")
    ax.plot(t, result.measured_hi_hz, "^", color="red", ms=4)
    ax.set_ylim(-0.3 * span - 4 * df, 1.3 * span + 4 * df)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("Doppler [Hz]")
    ax.set_title(f"micro-Doppler seen by {result.radar_name!r}: "
                 f"{len(result.part_names)} rotating parts")
    ax.legend(loc="upper right", fontsize="small")
    fig.tight_layout()
    return fig


def save_microdoppler(result: MicroDoppler, folder, *, inputs=()) -> list:
    """``spectrogram.png``, ``spectrogram.csv`` and ``microdoppler.csv`` in ``folder``."""
    out = Path(folder)
    written = [save_figure(spectrogram_figure(result), out / "spectrogram.png",
                           inputs=inputs, dpi=150)]
    header, rows = result.spectrogram_rows()
    written.append(write_csv(out / "spectrogram.csv", rows, header, inputs=inputs))
    header, rows = result.csv_rows()
    written.append(write_csv(out / "microdoppler.csv", rows, header, inputs=inputs))
    return written
