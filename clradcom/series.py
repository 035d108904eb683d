"""Coherent path series over time: trace a moving scene step by step and follow each
path from step to step (docs/series.md).

The tracer is deterministic, so a path keeps its identity across steps: its interaction
codes, object ids and triangle ids (:func:`path_keys`). :func:`match_paths` pairs the
paths of two consecutive steps by that key (several paths with one key, e.g. scattering
tiles of one triangle, pair in order of delay); :func:`trace_series` traces the scene at
each instant (:func:`clradcom.scene.motion.scene_at`) and chains the pairs into
*tracks*, each a path followed over a run of consecutive steps. A track's gain, delay and
Doppler per step go into a :class:`Series`, saved as a versioned npz
(:func:`save_series`, :func:`load_series`); :func:`unwrap_phase` unwraps a track's
carrier phase with the help of its own Doppler shift.
"""

from __future__ import annotations

import math
import os
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clradcom.device.runtime import Runtime
from clradcom.errors import ArgumentError, ArgumentTypeError, SnapshotError
from clradcom.files import atomic_write
from clradcom.mechanisms.common import GeometryCache
from clradcom.paths import Paths
from clradcom.scene.motion import scene_at
from clradcom.scene.records import Scene
from clradcom.snapshot import Snapshot, write_npz
from clradcom.trace import TraceSettings, trace_scene

__all__ = ["SERIES_FORMAT_NAME", "SERIES_FORMAT_VERSION", "Series", "check_times",
           "load_series", "match_paths", "path_keys", "save_series", "series_from_snapshots",
           "trace_series", "trace_steps", "unwrap_phase"]

SERIES_FORMAT_NAME = "clradcom-series"
SERIES_FORMAT_VERSION = 1
#: the most bytes :func:`load_series` unpacks (the members' declared sizes)
MAX_SERIES_BYTES = 8 << 30


def path_keys(paths: Paths) -> list[tuple]:
    """The identity of every path: (interaction codes, object ids, triangle ids) of its
    interactions, tuples of ``n_interactions`` entries each."""
    out = []
    for i in range(len(paths.gain)):
        n = int(paths.n_interactions[i])
        out.append((tuple(paths.interaction[i, :n].tolist()),
                    tuple(paths.object_id[i, :n].tolist()),
                    tuple(paths.face_id[i, :n].tolist())))
    return out


def match_paths(previous: Paths, current: Paths) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(i_previous, i_current)`` (two int64 arrays, ordered by ``i_current``) of
    the same path in two consecutive steps: equal :func:`path_keys`; where several paths
    share a key, they pair in order of delay (the extra ones stay unpaired)."""
    groups: dict[tuple, list[int]] = {}
    for i, key in enumerate(path_keys(previous)):
        groups.setdefault(key, []).append(i)
    cur_groups: dict[tuple, list[int]] = {}
    for j, key in enumerate(path_keys(current)):
        cur_groups.setdefault(key, []).append(j)
    pairs = []
    for key, js in cur_groups.items():
        iis = groups.get(key)
        if not iis:
            continue
        iis = sorted(iis, key=lambda i: (previous.delay_s[i], i))
        js = sorted(js, key=lambda j: (current.delay_s[j], j))
        pairs += list(zip(iis, js, strict=False))
    pairs.sort(key=lambda p: p[1])
    a = np.array([p[0] for p in pairs], dtype=np.int64)
    b = np.array([p[1] for p in pairs], dtype=np.int64)
    return a, b


@dataclass(frozen=True, eq=False)
class Series:
    """Paths followed over ``S`` steps: ``N`` tracks, each one path of one link seen at a
    run of consecutive steps (docs/series.md).

    Per step (S,): ``time_s``, ``scene_hash``. Per link (L,): ``tx_name``, ``rx_name``,
    ``tx_index``, ``rx_index``. Per track (N,): ``link`` (index into the links),
    ``n_interactions``, and (N, K) ``interaction``, ``object_id``, ``face_id`` (the path's
    identity, padded with 0 / -1). Per step and track (S, N): ``present`` (bool),
    ``gain`` (complex, 0 where absent), ``delay_s`` and ``doppler_hz`` (NaN where absent).
    """

    scene_name: str
    carrier_hz: float
    time_s: np.ndarray
    scene_hash: tuple[str, ...]
    tx_name: tuple[str, ...]
    rx_name: tuple[str, ...]
    tx_index: np.ndarray
    rx_index: np.ndarray
    link: np.ndarray
    n_interactions: np.ndarray
    interaction: np.ndarray
    object_id: np.ndarray
    face_id: np.ndarray
    present: np.ndarray
    gain: np.ndarray
    delay_s: np.ndarray
    doppler_hz: np.ndarray
    object_names: tuple[str, ...] = ()
    metadata: dict = field(default_factory=dict)

    @property
    def n_steps(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def n_tracks(self) -> int:
        return int(self.link.shape[0])

    def tracks_of(self, tx: int, rx: int) -> np.ndarray:
        """Indices of the tracks of link tx -> rx (radar indices)."""
        links = np.flatnonzero((self.tx_index == tx) & (self.rx_index == rx))
        return np.flatnonzero(np.isin(self.link, links))

    def steps_of(self, track: int) -> np.ndarray:
        """The steps at which ``track`` is present (consecutive)."""
        return np.flatnonzero(self.present[:, track])


def check_times(scene: Scene, times=None) -> np.ndarray:
    """``times`` (s; default the scene's ``[time]`` table) as a float64 array, checked:
    one or more finite instants, strictly increasing."""
    if not isinstance(scene, Scene):
        raise ArgumentTypeError("must be a Scene (clradcom.scene.load_scene)",
                                argument="scene", value=scene)
    if times is None:
        if scene.time_axis is None:
            raise ArgumentError("the scene has no [time] table: give the times",
                                argument="times", value=None)
        times = scene.time_axis.times
    try:
        t_arr = np.asarray(times, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ArgumentError("must be a sequence of times in seconds", argument="times",
                            value=times) from None
    if t_arr.size == 0 or not np.all(np.isfinite(t_arr)) or np.any(np.diff(t_arr) <= 0):
        raise ArgumentError("must be one or more finite times, strictly increasing",
                            argument="times", value=times)
    return t_arr


def trace_steps(scene: Scene, settings: TraceSettings | None = None, times=None, *,
                runtime: Runtime | None = None, links=None,
                each: Callable[[int, float, Snapshot], None] | None = None,
                rebuild: bool = False, placement: str = "refit") -> list[Snapshot]:
    """The snapshots of ``scene`` at every instant of ``times`` (s; default its ``[time]``
    table), moved there by :func:`~clradcom.scene.motion.scene_at` (each with its
    ``time_s`` set). ``settings``, ``runtime`` and ``links`` go to
    :func:`~clradcom.trace.trace_scene`; ``each(step, t, snapshot)`` hears every step.

    The BVH is built once (:class:`~clradcom.mechanisms.common.GeometryCache`: a
    bottom-level tree per moving object, refit to its place at each step, or placed by
    its rigid transform with ``placement="transform"``); ``rebuild=True`` builds the
    whole geometry anew at every step instead (the reference the cache is tested
    against). With "refit" the snapshots do not depend on the instant the cache was
    built at, so any run of consecutive instants (a distributed drive's chunk,
    :func:`clradcom.distributed.drive_tasks`) gives the steps of the whole run bit for
    bit."""
    t_arr = check_times(scene, times)
    settings = TraceSettings.preset() if settings is None else settings
    if not isinstance(settings, TraceSettings):
        raise ArgumentTypeError("must be a TraceSettings", argument="settings", value=settings)
    cache = None if rebuild else GeometryCache(scene, runtime, engine=settings.engine,
                                               placement=placement)
    snaps: list[Snapshot] = []
    for k, t in enumerate(t_arr):
        if cache is None:
            snap = trace_scene(scene_at(scene, float(t)), settings, runtime, links=links)
        else:
            geom = cache.at(float(t))
            snap = trace_scene(geom.scene, settings, runtime, links=links, geometry=geom)
        if each is not None:
            each(k, float(t), snap)
        snaps.append(snap)
    return snaps


def trace_series(scene: Scene, settings: TraceSettings | None = None, times=None, *,
                 runtime: Runtime | None = None, links=None,
                 each: Callable[[int, float, Snapshot], None] | None = None,
                 rebuild: bool = False, placement: str = "refit") -> Series:
    """Trace ``scene`` at every instant of ``times`` (:func:`trace_steps`, whose
    arguments these are) and follow its paths from step to step (:func:`match_paths`,
    :func:`series_from_snapshots`). On Dask: :func:`clradcom.distributed.run_drive`."""
    return series_from_snapshots(trace_steps(
        scene, settings, times, runtime=runtime, links=links, each=each, rebuild=rebuild,
        placement=placement))


def series_from_snapshots(snapshots: list[Snapshot]) -> Series:
    """Tracks through snapshots of one scene at consecutive steps (their links the
    same, in the same order)."""
    first = snapshots[0]
    L = len(first.links)
    for s in snapshots[1:]:
        if [(lk.tx_index, lk.rx_index) for lk in s.links] != [
                (lk.tx_index, lk.rx_index) for lk in first.links]:
            raise ArgumentError("the snapshots hold different links",
                                argument="snapshots")
    S = len(snapshots)
    rows: list[dict] = []  # per track: link, key, step -> path index
    k_max = 0
    for li in range(L):
        open_tracks: dict[int, int] = {}  # path index at the previous step -> track
        prev: Paths | None = None
        for k, snap in enumerate(snapshots):
            paths = snap.links[li].paths
            k_max = max(k_max, paths.interaction.shape[1])
            now: dict[int, int] = {}
            if prev is not None:
                a, b = match_paths(prev, paths)
                for i, j in zip(a.tolist(), b.tolist(), strict=True):
                    track = open_tracks[i]
                    rows[track]["steps"][k] = j
                    now[j] = track
            for j in range(len(paths.gain)):
                if j not in now:
                    n = int(paths.n_interactions[j])
                    rows.append({"link": li, "n": n,
                                 "key": (paths.interaction[j, :n], paths.object_id[j, :n],
                                         paths.face_id[j, :n]), "steps": {k: j}})
                    now[j] = len(rows) - 1
            open_tracks, prev = now, paths
    N = len(rows)
    present = np.zeros((S, N), bool)
    gain = np.zeros((S, N), np.complex128)
    delay = np.full((S, N), np.nan)
    doppler = np.full((S, N), np.nan)
    interaction = np.zeros((N, k_max), np.int8)
    object_id = np.full((N, k_max), -1, np.int32)
    face_id = np.full((N, k_max), -1, np.int32)
    for n, row in enumerate(rows):
        m = row["n"]
        interaction[n, :m], object_id[n, :m], face_id[n, :m] = row["key"]
        li = row["link"]
        for k, j in row["steps"].items():
            p = snapshots[k].links[li].paths
            present[k, n] = True
            gain[k, n] = p.gain[j]
            delay[k, n] = p.delay_s[j]
            doppler[k, n] = p.doppler_hz[j]
    return Series(
        scene_name=first.scene_name, carrier_hz=float(first.carrier_hz),
        time_s=np.array([s.time_s for s in snapshots], dtype=np.float64),
        scene_hash=tuple(s.scene_hash for s in snapshots),
        tx_name=tuple(lk.tx_name for lk in first.links),
        rx_name=tuple(lk.rx_name for lk in first.links),
        tx_index=np.array([lk.tx_index for lk in first.links], np.int64),
        rx_index=np.array([lk.rx_index for lk in first.links], np.int64),
        link=np.array([r["link"] for r in rows], np.int64),
        n_interactions=np.array([r["n"] for r in rows], np.int16),
        interaction=interaction, object_id=object_id, face_id=face_id, present=present,
        gain=gain, delay_s=delay, doppler_hz=doppler,
        object_names=tuple(first.object_names), metadata=dict(first.metadata))


def unwrap_phase(series: Series, track: int) -> np.ndarray:
    """(S,) carrier phase arg(gain) of ``track`` (rad), unwrapped along its steps with
    its own Doppler shift: the phase of a path turns at 2 pi f_D (f_D = -(1/lambda)
    dL/dt), so from one step to the next it moves by about pi (f_D,k + f_D,k+1) dt; the
    measured step is taken as that prediction plus the wrapped difference. This holds
    while the prediction errs by less than pi per step (a Doppler rate far below
    1 / dt^2), so coarse steps unwrap where :func:`numpy.unwrap` would alias. NaN where
    the track is absent."""
    steps = series.steps_of(int(track))
    out = np.full(series.n_steps, np.nan)
    if steps.size == 0:
        return out
    phase = np.angle(series.gain[steps, track])
    f = series.doppler_hz[steps, track]
    t = series.time_s[steps]
    unwrapped = np.empty_like(phase)
    unwrapped[0] = phase[0]
    for i in range(1, len(steps)):
        predicted = math.pi * (f[i - 1] + f[i]) * (t[i] - t[i - 1])
        step = phase[i] - phase[i - 1] - predicted
        unwrapped[i] = unwrapped[i - 1] + predicted + (step + math.pi) % (2 * math.pi) \
            - math.pi
    out[steps] = unwrapped
    return out


# ---------------------------------------------------------------------------
# the file


def _strings(values) -> np.ndarray:
    values = list(values)
    return np.array(values, dtype=np.str_) if values else np.zeros(0, dtype="<U1")


def _entries(series: Series) -> list[tuple[str, np.ndarray]]:
    out = [
        ("meta/format", np.array(SERIES_FORMAT_NAME)),
        ("meta/version", np.array(SERIES_FORMAT_VERSION, dtype=np.int64)),
        ("meta/scene_name", np.array(series.scene_name, dtype=np.str_)),
        ("meta/carrier_hz", np.array(series.carrier_hz, dtype=np.float64)),
        ("meta/object_names", _strings(series.object_names)),
        ("steps/time_s", np.asarray(series.time_s, np.float64)),
        ("steps/scene_hash", _strings(series.scene_hash)),
        ("links/tx_name", _strings(series.tx_name)),
        ("links/rx_name", _strings(series.rx_name)),
        ("links/tx_index", np.asarray(series.tx_index, np.int64)),
        ("links/rx_index", np.asarray(series.rx_index, np.int64)),
        ("tracks/link", np.asarray(series.link, np.int64)),
        ("tracks/n_interactions", np.asarray(series.n_interactions, np.int16)),
        ("tracks/interaction", np.asarray(series.interaction, np.int8)),
        ("tracks/object_id", np.asarray(series.object_id, np.int32)),
        ("tracks/face_id", np.asarray(series.face_id, np.int32)),
        ("values/present", np.asarray(series.present, bool)),
        ("values/gain", np.asarray(series.gain, np.complex128)),
        ("values/delay_s", np.asarray(series.delay_s, np.float64)),
        ("values/doppler_hz", np.asarray(series.doppler_hz, np.float64)),
    ]
    for key in sorted(series.metadata):
        value = series.metadata[key]
        out.append((f"metadata/{key}", np.array(value, dtype=np.str_ if isinstance(
            value, str) else None)))
    return out


def save_series(path: str | os.PathLike, series: Series, *, compress: bool = False) -> Path:
    """Write ``series`` as an npz (format :data:`SERIES_FORMAT_NAME` version
    :data:`SERIES_FORMAT_VERSION`, docs/series.md), atomically, identical bytes for
    identical series; ``compress`` deflates the members."""
    if not isinstance(series, Series):
        raise ArgumentTypeError("must be a Series (clradcom.series.trace_series)",
                                argument="series", value=series)
    entries = _entries(series)
    return atomic_write(path, lambda fh: write_npz(fh, entries, bool(compress)))


def load_series(path: str | os.PathLike, *, max_bytes: int = MAX_SERIES_BYTES) -> Series:
    """Read a series file, checked: its format and version, every array's dtype and
    shape; refusals are :class:`~clradcom.errors.SnapshotError` naming file and key."""
    path = Path(path)

    def err(key, reason):
        return SnapshotError(reason, file=path, key=key)

    try:
        with zipfile.ZipFile(path) as zf:
            total = sum(i.file_size for i in zf.infolist())
    except (OSError, zipfile.BadZipFile) as exc:
        raise err(None, f"cannot read it as a series file ({exc})") from None
    if total > max_bytes:
        raise err(None, f"declares {total} bytes unpacked, over the limit {max_bytes}")
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}

    def get(key, kind, ndim):
        if key not in data:
            raise err(key, "missing")
        a = data[key]
        if a.dtype.kind not in kind or a.ndim != ndim:
            raise err(key, f"has dtype {a.dtype} and {a.ndim} dimensions, expected "
                      f"kind {kind!r} with {ndim}")
        return a

    if str(get("meta/format", "U", 0)) != SERIES_FORMAT_NAME:
        raise err("meta/format", f"is {str(data['meta/format'])!r}, not a clradcom series")
    version = int(get("meta/version", "i", 0))
    if version != SERIES_FORMAT_VERSION:
        raise err("meta/version", f"is {version}; this clradcom reads version "
                  f"{SERIES_FORMAT_VERSION}")
    time_s = get("steps/time_s", "f", 1)
    S = time_s.shape[0]
    link = get("tracks/link", "i", 1)
    N = link.shape[0]
    tx_index = get("links/tx_index", "i", 1)
    L = tx_index.shape[0]
    checks = {"steps/scene_hash": ("U", (S,)), "links/tx_name": ("U", (L,)),
              "links/rx_name": ("U", (L,)), "links/rx_index": ("i", (L,)),
              "tracks/n_interactions": ("i", (N,)), "values/present": ("b", (S, N)),
              "values/gain": ("c", (S, N)), "values/delay_s": ("f", (S, N)),
              "values/doppler_hz": ("f", (S, N))}
    for key, (kind, shape) in checks.items():
        if get(key, kind, len(shape)).shape != shape:
            raise err(key, f"has shape {data[key].shape}, expected {shape}")
    K = get("tracks/interaction", "i", 2).shape[1]
    for key in ("tracks/interaction", "tracks/object_id", "tracks/face_id"):
        if get(key, "i", 2).shape != (N, K):
            raise err(key, f"has shape {data[key].shape}, expected {(N, K)}")
    if N and (link.min() < 0 or link.max() >= L):
        raise err("tracks/link", "holds an index beyond the links")
    metadata = {k.removeprefix("metadata/"): data[k].item() for k in data
                if k.startswith("metadata/")}
    return Series(
        scene_name=str(get("meta/scene_name", "U", 0)),
        carrier_hz=float(get("meta/carrier_hz", "f", 0)), time_s=time_s,
        scene_hash=tuple(str(x) for x in data["steps/scene_hash"]),
        tx_name=tuple(str(x) for x in data["links/tx_name"]),
        rx_name=tuple(str(x) for x in data["links/rx_name"]), tx_index=tx_index,
        rx_index=data["links/rx_index"], link=link,
        n_interactions=data["tracks/n_interactions"],
        interaction=data["tracks/interaction"], object_id=data["tracks/object_id"],
        face_id=data["tracks/face_id"], present=data["values/present"],
        gain=data["values/gain"], delay_s=data["values/delay_s"],
        doppler_hz=data["values/doppler_hz"],
        object_names=tuple(str(x) for x in get("meta/object_names", "U", 1)),
        metadata=metadata)
