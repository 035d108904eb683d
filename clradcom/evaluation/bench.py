"""The trace benchmark behind tools/bench_trace.py: whole traces timed stage by stage
with the share of their time inside kernels, the device engine against the host reference
in the same process, other scenes each in a fresh process with its peak memory, and the
broadside RCS of a flat plate against 4 pi A^2 / lambda^2.

* :func:`time_trace` - one :func:`~clradcom.trace.trace_scene` call: wall seconds, the
  :class:`~clradcom.trace.StageTimes`, the seconds inside kernels
  (:attr:`~clradcom.device.runtime.Runtime.kernel_seconds` before and after), paths.
* :func:`compare_engines` - one warm-up trace per engine (kernel builds, caches), then
  the engines in turn ``repeats`` times; :func:`median_timing` takes the medians.
* :func:`compare_devices` - the device engine on several OpenCL devices in one process
  (one warm-up trace each, whose time with the kernel builds is kept, then the devices
  in turn ``repeats`` times); :func:`link_channels` and :func:`table_iii_detections`
  hold each device's snapshot to the reference device's (the channel of every link at
  the radar's subcarriers, NMSE; radar A's detections of the moving cars).
* :func:`run_in_subprocess` - one device trace of a scene file in a fresh Python
  process (:func:`child_main`), returning its timing, its peak resident memory
  (:func:`peak_rss_bytes` of that process: the interpreter, numpy and pyopencl included, and on a
  CPU OpenCL device the device's buffers too) and the coherent path sums of its
  monostatic links and the warnings it raised; a failure comes back as the error's
  text, never as an exception.
* :func:`plate_rcs` - for a scene of one flat PEC object and a monostatic radar: the
  object's RCS from the path sums by the radar range equation
  (sigma = |a|^2 (4 pi)^3 R^4 / lambda^2, :func:`clradcom.evaluation.rcs.dbsm`) beside the
  far-field physical-optics value 4 pi A^2 / lambda^2 (docs/po.md).

Times are wall clock (time.perf_counter); nothing here asserts a speed.
"""

from __future__ import annotations

import dataclasses
import json
import os
import resource
import statistics
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from clradcom.device.runtime import OpenCLError, Runtime, get_runtime
from clradcom.errors import ArgumentError
from clradcom.evaluation.accuracy import channel_nmse_db
from clradcom.evaluation.rcs import dbsm
from clradcom.geometry.triangles import triangle_double_areas, triangle_normals
from clradcom.mechanisms.common import ENGINES
from clradcom.paths import InteractionType
from clradcom.radar.pipeline import radar_chain
from clradcom.radar.report import match_tolerances, moving_objects
from clradcom.radar.truth import detection_truth, match_truth
from clradcom.scene.reader import load_scene
from clradcom.scene.records import Scene
from clradcom.snapshot import Snapshot
from clradcom.trace import (
    DiffractionSettings,
    OpticsSettings,
    ScatteringSettings,
    SpecularSettings,
    StageTimes,
    TraceSettings,
    trace_scene,
)

__all__ = ["CSV_HEADER", "DeviceRuns", "PlateRcs", "SceneRun", "TraceTiming",
           "channel_agreement_db", "child_main", "compare_devices", "compare_engines",
           "link_channels", "link_sums", "median_timing", "peak_rss_bytes", "plate_rcs",
           "run_in_subprocess", "settings_from_dict", "settings_to_dict", "time_trace",
           "table_iii_detections", "timing_rows"]

#: columns of the benchmark's CSV (one measured quantity per row)
CSV_HEADER = ("scene", "engine", "quantity", "value", "unit")


@dataclass
class TraceTiming:
    """One whole trace: wall seconds, seconds inside kernels, per-stage seconds, paths."""

    engine: str
    seconds: float
    kernel_seconds: float
    stages: dict[str, float] = field(default_factory=dict)
    n_paths: int = 0

    @property
    def kernel_share(self) -> float:
        """Share of the trace's wall time spent inside kernel launches (0 for no time)."""
        return self.kernel_seconds / self.seconds if self.seconds > 0 else 0.0


def time_trace(scene: Scene, settings: TraceSettings, runtime: Runtime | None = None,
               links=None) -> tuple[TraceTiming, Snapshot]:
    """Trace ``scene`` once with ``settings`` (its ``engine`` included) and time it."""
    runtime = runtime or get_runtime()
    times = StageTimes()
    k0, t0 = runtime.kernel_seconds, time.perf_counter()
    snap = trace_scene(scene, settings, runtime=runtime, links=links, times=times)
    seconds = time.perf_counter() - t0
    return TraceTiming(engine=settings.engine, seconds=seconds,
                       kernel_seconds=runtime.kernel_seconds - k0,
                       stages=dict(times.seconds), n_paths=snap.total_paths), snap


def median_timing(timings: list[TraceTiming]) -> TraceTiming:
    """The median of every number over runs of one engine (a stage missing from a run
    counts as 0 s there)."""
    if not timings:
        raise ArgumentError("needs at least one timing", argument="timings", value=timings)
    engines = {t.engine for t in timings}
    if len(engines) != 1:
        raise ArgumentError("mixes engines", argument="timings", value=sorted(engines))
    stages = dict.fromkeys(s for t in timings for s in t.stages)
    return TraceTiming(
        engine=timings[0].engine,
        seconds=statistics.median(t.seconds for t in timings),
        kernel_seconds=statistics.median(t.kernel_seconds for t in timings),
        stages={s: statistics.median(t.stages.get(s, 0.0) for t in timings) for s in stages},
        n_paths=int(statistics.median(t.n_paths for t in timings)))


def compare_engines(scene: Scene, settings: TraceSettings, runtime: Runtime | None = None, *,
                    repeats: int = 3, engines=ENGINES, links=None,
                    progress: Callable[[str], None] | None = None
                    ) -> dict[str, list[TraceTiming]]:
    """``repeats`` timed traces per engine, the engines taking turns (so a machine that
    gets busier or quieter during the run weighs on each alike), after one untimed
    warm-up trace per engine."""
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise ArgumentError("must be an integer >= 1", argument="repeats", value=repeats)
    runtime = runtime or get_runtime()
    say = progress or (lambda msg: None)
    out: dict[str, list[TraceTiming]] = {e: [] for e in engines}
    for engine in engines:
        say(f"warm-up trace, {engine} engine")
        time_trace(scene, settings.replace(engine=engine), runtime, links)
    for i in range(repeats):
        for engine in engines:
            timing, _ = time_trace(scene, settings.replace(engine=engine), runtime, links)
            say(f"run {i + 1}/{repeats}, {engine} engine: {timing.seconds:.2f} s, "
                f"{timing.kernel_share:.0%} in kernels")
            out[engine].append(timing)
    return out


@dataclass
class DeviceRuns:
    """One device's traces in :func:`compare_devices`: the warm-up (kernel builds
    included), the timed runs and the last run's snapshot."""

    label: str
    first: TraceTiming | None
    runs: list[TraceTiming]
    snapshot: Snapshot | None
    #: the one-line error of a device that could not trace (its runs are then empty)
    error: str = ""


def compare_devices(scene: Scene, settings: TraceSettings, runtimes: dict[str, Runtime], *,
                    repeats: int = 3, progress: Callable[[str], None] | None = None
                    ) -> dict[str, DeviceRuns]:
    """The device engine on each of ``runtimes`` (name -> Runtime): one warm-up trace per
    device (its time kept: the first run's cost, builds and caches included), then the
    devices take turns ``repeats`` times, so a machine that gets busier or quieter weighs
    on each alike. A device whose warm-up fails with an OpenCL error is reported with it
    (``DeviceRuns.error``) and left out of the turns; the others go on."""
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise ArgumentError("must be an integer >= 1", argument="repeats", value=repeats)
    if not runtimes:
        raise ArgumentError("needs at least one device", argument="runtimes", value=runtimes)
    say = progress or (lambda msg: None)
    settings = settings.replace(engine="device")
    out: dict[str, DeviceRuns] = {}
    for name, rt in runtimes.items():
        say(f"warm-up trace on {name} ({rt.info.label})")
        try:
            first, snap = time_trace(scene, settings, rt)
        except OpenCLError as exc:
            say(f"{name} failed: {exc}")
            out[name] = DeviceRuns(label=rt.info.label, first=None, runs=[], snapshot=None,
                                   error=str(exc))
            continue
        out[name] = DeviceRuns(label=rt.info.label, first=first, runs=[], snapshot=snap)
    for i in range(repeats):
        for name, rt in runtimes.items():
            if out[name].error:
                continue
            timing, snap = time_trace(scene, settings, rt)
            say(f"run {i + 1}/{repeats} on {name}: {timing.seconds:.2f} s, "
                f"{timing.kernel_share:.0%} in kernels")
            out[name].runs.append(timing)
            out[name].snapshot = snap
    return out


def link_channels(snapshot: Snapshot, waveform) -> dict[str, np.ndarray]:
    """Each link's channel at the waveform's subcarriers for one symbol,
    H(n) = sum_k a_k exp(-j 2 pi n df tau_k), keyed "tx->rx"."""
    n = np.arange(waveform.n_subcarriers)[:, None]
    out = {}
    for link in snapshot.links:
        p = link.paths
        out[f"{link.tx_name}->{link.rx_name}"] = (
            np.exp(-2j * np.pi * n * waveform.subcarrier_spacing_hz * p.delay_s[None, :])
            @ p.gain)
    return out


def channel_agreement_db(snapshot: Snapshot, reference: Snapshot, waveform
                         ) -> dict[str, float]:
    """Per link, the NMSE (dB) of ``snapshot``'s channel against ``reference``'s
    (:func:`clradcom.evaluation.accuracy.channel_nmse_db`)."""
    ref = link_channels(reference, waveform)
    got = link_channels(snapshot, waveform)
    return {k: channel_nmse_db(got[k], ref[k]) for k in ref if k in got}


def table_iii_detections(scene: Scene, snapshot: Snapshot, waveform, noise_figure_db: float,
                         radar_name: str = "A", seed: int = 0
                         ) -> dict[str, tuple[float, float] | None]:
    """The main job's detections of the moving objects by radar ``radar_name`` on its own
    link of ``snapshot``, as tools/trace.py finds them (thermal noise at the radar's power
    and ``noise_figure_db``, seed ``seed``): object -> (range m, velocity m/s), None if
    missed."""
    r = scene.radar_index(radar_name)
    radar = scene.radars[r]
    link = next(lk for lk in snapshot.links if lk.tx_index == r and lk.rx_index == r)
    dets = radar_chain(link.paths, waveform, seed=seed, tx_power_w=radar.tx_power_w,
                       noise_figure_db=noise_figure_db).detections
    truth = detection_truth(scene, radar.name, moving_objects(scene, radar))
    matches = match_truth(dets, truth, *match_tolerances(waveform))
    return {t["name"]: None if m is None else (float(m["range_m"]), float(m["velocity_mps"]))
            for t, m in zip(truth, matches, strict=True)}


# ----------------------------------------------------------------------------------------
# settings across a process boundary
# ----------------------------------------------------------------------------------------
def settings_to_dict(settings: TraceSettings) -> dict:
    """Plain JSON-able form of a TraceSettings (:func:`settings_from_dict` reverses it)."""
    return dataclasses.asdict(settings)


def settings_from_dict(data: dict) -> TraceSettings:
    """The TraceSettings of :func:`settings_to_dict`'s dict, checked as when built."""
    return TraceSettings(specular=SpecularSettings(**data["specular"]),
                         diffraction=DiffractionSettings(**data["diffraction"]),
                         optics=OpticsSettings(**data["optics"]),
                         scattering=ScatteringSettings(**data["scattering"]),
                         engine=data["engine"])


# ----------------------------------------------------------------------------------------
# one scene in a fresh process
# ----------------------------------------------------------------------------------------
_PO_CODES = (int(InteractionType.PHYSICAL_OPTICS), int(InteractionType.SBR))


def peak_rss_bytes() -> int:
    """Peak resident memory of this process so far, bytes: ``VmHWM`` of
    /proc/self/status where there is one (Linux), else ``ru_maxrss`` (KiB on Linux,
    bytes on macOS). Linux keeps ``ru_maxrss`` across exec, so a child started from a
    large parent would report the parent's size; ``VmHWM`` belongs to the new image."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak) * (1 if sys.platform == "darwin" else 1024)


def link_sums(snapshot: Snapshot) -> list[dict]:
    """Per monostatic link (tx = rx): the radar's index and the coherent sum of the gains
    of all its paths and of its physical-optics ones (PO facets and SBR tubes), as
    [re, im], with the path counts."""
    out = []
    for link in snapshot:
        if link.tx_index != link.rx_index:
            continue
        p = link.paths
        po = np.isin(p.interaction, _PO_CODES).any(axis=1) if p.n_paths else np.zeros(0, bool)
        total, po_sum = complex(p.gain.sum()), complex(p.gain[po].sum())
        out.append({"radar": int(link.tx_index), "paths": int(p.n_paths),
                    "po_paths": int(po.sum()), "sum_all": [total.real, total.imag],
                    "sum_po": [po_sum.real, po_sum.imag]})
    return out


@dataclass
class SceneRun:
    """One scene traced in its own process: what came back, or why nothing did."""

    scene: str  #: the scene file
    ok: bool
    error: str = ""
    timing: TraceTiming | None = None
    peak_rss_bytes: int = 0  #: the child's peak resident memory (0 when unknown)
    rss_before_trace_bytes: int = 0  #: its peak before the trace (imports, device, scene)
    links: list[dict] = field(default_factory=list)  #: :func:`link_sums`
    wall_seconds: float = 0.0  #: the child process from start to exit
    #: the distinct warnings the trace raised ("Category: message"), in order
    warnings: list[str] = field(default_factory=list)


def child_main(stdin=None, stdout=None) -> int:
    """The child process of :func:`run_in_subprocess`: reads ``{"scene", "settings",
    "device"}`` as JSON from stdin, traces, writes one JSON object to stdout."""
    stdin, stdout = stdin or sys.stdin, stdout or sys.stdout
    job = json.loads(stdin.read())
    result: dict = {"ok": False}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            runtime = get_runtime(job.get("device"))
            scene = load_scene(job["scene"])
            settings = settings_from_dict(job["settings"])
            result["rss_before_trace_bytes"] = peak_rss_bytes()
            timing, snap = time_trace(scene, settings, runtime)
            result.update(ok=True, timing=dataclasses.asdict(timing), links=link_sums(snap))
        except Exception as exc:  # reported to the parent as text, never a traceback
            result["error"] = f"{type(exc).__name__}: {exc}"
    result["warnings"] = list(dict.fromkeys(f"{w.category.__name__}: {w.message}"
                                            for w in caught))
    result["peak_rss_bytes"] = peak_rss_bytes()
    stdout.write(json.dumps(result) + "\n")
    stdout.flush()
    return 0


_CHILD = "import sys; from clradcom.evaluation.bench import child_main; sys.exit(child_main())"


def run_in_subprocess(scene_path, settings: TraceSettings, device: str | None = None, *,
                      timeout_s: float | None = None) -> SceneRun:
    """Trace the scene file in a fresh Python process (so its peak memory is its own) and
    return what it measured; a failure, a crash or a timeout comes back as ``ok=False``
    with the reason."""
    if not isinstance(settings, TraceSettings):
        raise ArgumentError("must be a TraceSettings", argument="settings", value=settings)
    job = json.dumps({"scene": str(scene_path), "settings": settings_to_dict(settings),
                      "device": device})
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-c", _CHILD], input=job, text=True,
                              capture_output=True, timeout=timeout_s, env=dict(os.environ))
    except subprocess.TimeoutExpired:
        return SceneRun(scene=str(scene_path), ok=False,
                        error=f"no result within {timeout_s:g} s (the process was killed)",
                        wall_seconds=time.perf_counter() - t0)
    wall = time.perf_counter() - t0
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        tail = " | ".join(proc.stderr.strip().splitlines()[-3:])
        return SceneRun(scene=str(scene_path), ok=False, wall_seconds=wall,
                        error=f"the process ended with exit code {proc.returncode}"
                              + (f": {tail}" if tail else ""))
    data = json.loads(lines[-1])
    timing = TraceTiming(**data["timing"]) if data.get("timing") else None
    return SceneRun(scene=str(scene_path), ok=bool(data["ok"]), error=data.get("error", ""),
                    timing=timing, peak_rss_bytes=int(data.get("peak_rss_bytes", 0)),
                    rss_before_trace_bytes=int(data.get("rss_before_trace_bytes", 0)),
                    links=data.get("links", []), wall_seconds=wall,
                    warnings=data.get("warnings", []))


# ----------------------------------------------------------------------------------------
# the plate's RCS
# ----------------------------------------------------------------------------------------
@dataclass
class PlateRcs:
    """A flat plate's monostatic RCS from the traced paths against physical optics."""

    area_m2: float
    range_m: float
    expected_dbsm: float  #: 4 pi A^2 / lambda^2, the far-field PO value at broadside
    all_dbsm: float  #: from the coherent sum of every path of the monostatic link
    po_dbsm: float  #: from the PO facet and SBR paths alone
    incidence_deg: float  #: angle between the plate's normal and the radar


def plate_rcs(scene: Scene, links: list[dict]) -> PlateRcs | None:
    """The broadside check of a scene holding one flat PEC object (every triangle in one
    plane) and a monostatic radar, from :func:`link_sums` of its trace; None for any
    other scene or when the radar has no monostatic link."""
    if len(scene.objects) != 1 or not scene.material_pec[scene.objects[0].material]:
        return None
    tri = scene.triangles
    normals = triangle_normals(tri)
    if len(tri) == 0 or not np.allclose(np.abs(normals @ normals[0]), 1.0, atol=1e-9):
        return None
    centroids = tri.mean(axis=1)
    if not np.allclose((centroids - centroids[0]) @ normals[0], 0.0,
                       atol=1e-9 * (1.0 + float(np.abs(centroids).max()))):
        return None
    mono = [lk for lk in links if scene.radars[lk["radar"]].role == "txrx"]
    if not mono:
        return None
    link = mono[0]
    areas = 0.5 * triangle_double_areas(tri)
    area = float(areas.sum())
    centre = (areas[:, None] * centroids).sum(axis=0) / area
    offset = centre - scene.radars[link["radar"]].position
    rng = float(np.linalg.norm(offset))
    lam = scene.wavelength_m
    cos_inc = abs(float(offset @ normals[0])) / rng
    return PlateRcs(
        area_m2=area, range_m=rng,
        expected_dbsm=float(10 * np.log10(4 * np.pi * area**2 / lam**2)),
        all_dbsm=float(dbsm(complex(*link["sum_all"]), rng, lam)),
        po_dbsm=float(dbsm(complex(*link["sum_po"]), rng, lam)),
        incidence_deg=float(np.degrees(np.arccos(min(cos_inc, 1.0)))))



def timing_rows(scene: str, timing: TraceTiming) -> list[tuple]:
    """CSV rows (:data:`CSV_HEADER`) of one timing: trace and kernel seconds, the kernel
    share, paths, and every stage's seconds."""
    e = timing.engine
    rows = [(scene, e, "trace_s", f"{timing.seconds:.6f}", "s"),
            (scene, e, "kernel_s", f"{timing.kernel_seconds:.6f}", "s"),
            (scene, e, "kernel_share", f"{timing.kernel_share:.6f}", "1"),
            (scene, e, "paths", str(timing.n_paths), "1")]
    rows += [(scene, e, f"stage:{k}", f"{v:.6f}", "s") for k, v in timing.stages.items()]
    return rows
