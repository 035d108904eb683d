"""Trace every tx -> rx link of a scene into a snapshot: the orchestrator.

Each mechanism (:mod:`clradcom.mechanisms`) has its own settings and the same shape,
``prepare`` once per transmitter then ``link_paths`` per link; this module holds the
nested :class:`TraceSettings`, the per-transmitter caches and the link loop:

1. :func:`~clradcom.mechanisms.common.kept_geometry` - planar faces, BVH, ray caster,
   built once per geometry and kept for the next traces of the same triangles in this
   thread; wedges for diffraction (kept with it, per wedge setting).
2. per transmitter: specular candidates (its rays' face sequences, OpenCL) and the
   SBR tubes of physical optics.
3. per link, in this order: line of sight and specular reflections; physical optics
   in place of the GO returns of the objects that ask for it; diffuse scattering;
   UTD diffraction. Their :class:`~clradcom.paths.Paths` are joined in that order, once
   per link (stage "join": a join copies and checks every path of the link).

Geometry is float32 only inside the kernels that propose candidates and confirm
visibility; every point, length, delay and phase of a kept path is computed in float64
on the host.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from clradcom import __version__
from clradcom.device.engines import EngineLog, engine_log
from clradcom.device.runtime import Runtime
from clradcom.errors import ArgumentError, ArgumentTypeError
from clradcom.mechanisms import diffraction, optics, scattering, specular
from clradcom.mechanisms.common import ENGINES, Geometry, kept_geometry
from clradcom.mechanisms.diffraction import DiffractionSettings
from clradcom.mechanisms.optics import OpticsSettings
from clradcom.mechanisms.scattering import ScatteringSettings
from clradcom.mechanisms.specular import SpecularSettings
from clradcom.memory import check_memory
from clradcom.paths import concat_paths, select_paths
from clradcom.presets import DEFAULT_PRESET, PRESETS
from clradcom.scene.records import Scene
from clradcom.snapshot import Link, Snapshot

__all__ = ["DEFAULT_PRESET", "DiffractionSettings", "OpticsSettings", "ScatteringSettings",
           "SpecularSettings", "StageTimes", "TraceSettings", "check_launch_memory",
           "launch_memory_bytes", "trace_scene"]


@dataclass(frozen=True)
class TraceSettings:
    """What the tracer models and how hard it searches, one settings object per mechanism.

    ``TraceSettings(specular=SpecularSettings(max_reflections=3),
    optics=OpticsSettings(mode="sbr"), scattering=ScatteringSettings(enabled=True))``
    """

    specular: SpecularSettings = field(default_factory=SpecularSettings)
    diffraction: DiffractionSettings = field(default_factory=DiffractionSettings)
    optics: OpticsSettings = field(default_factory=OpticsSettings)
    scattering: ScatteringSettings = field(default_factory=ScatteringSettings)
    #: "device": interactions resolved in OpenCL kernels; "host": the numpy reference
    engine: str = "device"

    def __post_init__(self):
        if self.engine not in ENGINES:
            raise ArgumentError(f"must be one of {', '.join(ENGINES)}",
                                argument="TraceSettings.engine", value=self.engine)
        for name, kind in (("specular", SpecularSettings),
                           ("diffraction", DiffractionSettings),
                           ("optics", OpticsSettings), ("scattering", ScatteringSettings)):
            value = getattr(self, name)
            if not isinstance(value, kind):
                raise ArgumentTypeError(f"must be a {kind.__name__}",
                                        argument=f"TraceSettings.{name}", value=value)

    @property
    def diffraction_search(self) -> DiffractionSettings:
        """The diffraction settings as searched: never more reflections beside the edges
        than the specular search allows."""
        cap = min(self.diffraction.max_reflections, self.specular.max_reflections)
        return dataclasses.replace(self.diffraction, max_reflections=cap)

    @property
    def optics_search(self) -> OpticsSettings:
        """The optics settings as searched: SBR bounces follow the specular search's
        max_reflections unless set."""
        if self.optics.max_bounces is not None:
            return self.optics
        return dataclasses.replace(self.optics, max_bounces=self.specular.max_reflections)

    @classmethod
    def preset(cls, name: str = DEFAULT_PRESET, **changes) -> TraceSettings:
        """The named preset of :mod:`clradcom.presets` (``paper``, ``fast``, ``accurate``,
        ``go``), with further ``mechanism__field`` changes:
        ``TraceSettings.preset("paper", specular__rays=10_000)``. The dataclass
        defaults (``TraceSettings()``) are the ``go`` preset; ``trace_scene(scene)``
        without settings traces with ``paper``, as ``clradcom trace`` does."""
        if name not in PRESETS:
            raise ArgumentError(f"is no preset (presets: {', '.join(PRESETS)})",
                                argument="preset", value=name)
        return cls().replace(**{**PRESETS[name].changes, **changes})

    def replace(self, **changes) -> TraceSettings:
        """A copy with fields of the nested settings changed, named ``mechanism__field``
        (and ``engine``): ``settings.replace(specular__rays=10_000, engine="host")``."""
        parts: dict[str, dict] = {}
        top = {}
        for key, value in changes.items():
            if key == "engine":
                top[key] = value
                continue
            mechanism, sep, name = key.partition("__")
            if not sep or mechanism not in ("specular", "diffraction", "optics",
                                            "scattering"):
                raise ArgumentTypeError("TraceSettings.replace takes mechanism__field names "
                                        "(specular, diffraction, optics, scattering)",
                                        argument=key)
            parts.setdefault(mechanism, {})[name] = value
        return dataclasses.replace(self, **top, **{
            m: dataclasses.replace(getattr(self, m), **kw) for m, kw in parts.items()})

    def metadata(self) -> dict:
        """Every setting as ``settings.<mechanism>.<field>`` -> value (None left out), and
        ``settings.engine``."""
        out = {f"settings.{m}.{k}": v for m in ("specular", "diffraction", "optics",
                                                "scattering")
               for k, v in dataclasses.asdict(getattr(self, m)).items() if v is not None}
        out["settings.engine"] = self.engine
        return out


@dataclass
class StageTimes:
    """Wall-clock seconds per stage, for reports and benchmarks."""

    seconds: dict[str, float] = field(default_factory=dict)

    def add(self, stage: str, dt: float) -> None:
        self.seconds[stage] = self.seconds.get(stage, 0.0) + dt


class _Clock:
    """Adds the seconds spent inside a ``with`` block to one stage."""

    def __init__(self, times: StageTimes):
        self.times = times

    def __call__(self, stage: str):
        clock = self

        class _Stage:
            def __enter__(self):
                self.t0 = time.perf_counter()

            def __exit__(self, *exc):
                clock.times.add(stage, time.perf_counter() - self.t0)

        return _Stage()


def launch_memory_bytes(rays: int, max_reflections: int) -> int:
    """Host memory a transmitter's candidate search holds at its peak for ``rays`` rays.

    Per launched ray (:func:`clradcom.mechanisms.specular.prepare`): the Fibonacci lattice
    of launch directions, float64 (n, 3) over the pattern's cap, with its temporaries and
    the pattern's gain evaluated on it (about 160 bytes); later the (n, max_reflections)
    int32 face sequences and their de-duplication (about 40 + 21 bytes per reflection
    order). Measured with tracemalloc on the street (155 bytes per ray up to 5
    reflections, 360 at 16). The device's batches are bounded (2^20 rays); the paths
    found, the BVH and the meshes come on top and are small next to it. No rays are
    launched without reflections (0).
    """
    if max_reflections < 1:
        return 0
    return int(rays) * max(160, 40 + 21 * int(max_reflections))


def check_launch_memory(settings: TraceSettings, *, budget_bytes: float | None = None,
                        argument: str = "settings.specular.rays", value=None,
                        advice: str = "launch fewer rays") -> None:
    """Refuse, before tracing, settings whose ray launch exceeds the memory budget
    (:func:`clradcom.memory.check_memory`: a share of physical memory, or
    ``CLRADCOM_MEMORY_BUDGET``) with :class:`~clradcom.errors.MemoryBudgetError`;
    ``argument``/``value`` name what the caller lets the user change (``--rays``)."""
    spec = settings.specular
    need = launch_memory_bytes(spec.rays, spec.max_reflections)
    check_memory(need, what=f"launching {spec.rays} rays per transmitter "
                            f"(about {need // spec.rays} bytes each)",
                 argument=argument, value=spec.rays if value is None else value,
                 advice=advice, budget_bytes=budget_bytes)


def _check_links(scene: Scene, links) -> list[tuple[int, int]]:
    n = len(scene.radars)
    out = []
    for item in links:
        if not (isinstance(item, tuple | list) and len(item) == 2):
            raise ArgumentError("each link must be a (tx index, rx index) pair",
                                argument="links", value=item)
        pair = []
        for what, idx in zip(("tx", "rx"), item, strict=True):
            if isinstance(idx, bool) or not isinstance(idx, int) or not 0 <= idx < n:
                raise ArgumentError(f"{what} index {idx!r} is not a radar of scene "
                                    f"{scene.name!r} (0..{n - 1})", argument="links",
                                    value=item)
            pair.append(idx)
        out.append((pair[0], pair[1]))
    return out


def trace_scene(scene: Scene, settings: TraceSettings | None = None,
                runtime: Runtime | None = None, links=None,
                progress: Callable[[str], None] | None = None,
                times: StageTimes | None = None,
                steps: Callable[[int, int, str], None] | None = None,
                geometry: Geometry | None = None) -> Snapshot:
    """Trace the links of a scene (default: every transmitter to every receiver).

    ``settings`` None traces with the ``paper`` preset (``TraceSettings.preset()``: PO +
    SBR, scattering, 5 reflections from 3e5 rays and candidate expansion, 1
    diffraction), the same physics as
    ``clradcom trace`` without options; ``TraceSettings()`` is pure GO with diffraction.
    ``progress(message)`` hears each stage as it starts; ``steps(done, total, label)``
    is called before every mechanism of every link (``done`` links of ``total``
    finished), for a progress bar. ``geometry`` (built for this very ``scene`` object,
    e.g. by :meth:`~clradcom.mechanisms.common.GeometryCache.at`) is used instead of
    building one."""
    with engine_log() as engines:
        return _trace_scene(scene, settings, runtime, links, progress, times, steps,
                            geometry, engines)


def _trace_scene(scene, settings, runtime, links, progress, times, steps, geometry,
                 engines: EngineLog) -> Snapshot:
    """:func:`trace_scene` inside its engine log."""
    if not isinstance(scene, Scene):
        raise ArgumentTypeError("must be a Scene: load a scene file with "
                                "clradcom.scene.load_scene(path) first", argument="scene",
                                value=scene)
    settings = TraceSettings.preset(DEFAULT_PRESET) if settings is None else settings
    if not isinstance(settings, TraceSettings):
        raise ArgumentTypeError("must be a TraceSettings", argument="settings", value=settings)
    check_launch_memory(settings)
    txs = [i for i, r in enumerate(scene.radars) if r.role in ("txrx", "tx")]
    rxs = [i for i, r in enumerate(scene.radars) if r.role in ("txrx", "rx")]
    links = [(t, r) for t in txs for r in rxs] if links is None else _check_links(scene, links)
    clock = _Clock(times if times is not None else StageTimes())
    say = progress or (lambda msg: None)
    step = steps or (lambda done, total, label: None)
    spec, opt, scat = settings.specular, settings.optics_search, settings.scattering
    diff = settings.diffraction_search

    if geometry is not None and (geometry.scene is not scene
                                 or geometry.engine != settings.engine):
        raise ArgumentError("must be built for this scene object and the settings' "
                            f"engine ({settings.engine!r})", argument="geometry",
                            value=geometry.engine)
    with clock("geometry"):
        geom = geometry or kept_geometry(scene, runtime, engine=settings.engine)
    use_optics = optics.active(scene, opt)
    with clock("wedges"):
        wedges = diffraction.prepare(geom, diff, optics.po_object_ids(scene, opt)
                                     if use_optics else ())
    candidates: dict[int, specular.Candidates] = {}  # per radar, as tx (or as rx for edges)
    shots: dict[int, optics.SbrShot] = {}  # per transmitter
    stats: dict[str, dict[str, int]] = {"diffraction": {}, "scattering": {}}
    seeing: dict = {}  # the wedges each antenna position may see, shared by its links

    def candidates_of(index: int) -> specular.Candidates:
        if index not in candidates:
            say(f"candidates from {scene.radars[index].name}")
            with clock("specular candidates"):
                candidates[index] = specular.prepare(geom, scene.radars[index], spec)
        return candidates[index]

    out = []
    for done, (t_idx, r_idx) in enumerate(links):
        tx, rx = scene.radars[t_idx], scene.radars[r_idx]
        link_name = f"{tx.name} -> {rx.name}"
        step(done, len(links), f"{link_name}: specular candidates")
        tx_candidates = candidates_of(t_idx)
        say(f"paths {link_name}")
        step(done, len(links), f"{link_name}: specular")
        with clock("specular"):
            link_candidates = tx_candidates
            if spec.from_receiver and r_idx != t_idx:
                link_candidates = specular.both_ways(tx_candidates, candidates_of(r_idx))
            paths = specular.link_paths(geom, link_candidates, tx, rx, spec)
        go_paths = paths  # the GO decisions the UTD terms follow at their boundaries
        if use_optics:
            step(done, len(links), f"{link_name}: physical optics")
            with clock("physical optics"):
                if t_idx not in shots:
                    shots[t_idx] = optics.prepare(geom, tx, opt, receivers=[
                        scene.radars[r] for t, r in links if t == t_idx])
                extra = optics.link_paths(geom, shots[t_idx], tx, rx, opt)
                if extra:
                    kept = select_paths(paths, ~optics.replaced_paths(paths, shots[t_idx]))
                    paths = concat_paths([kept, *extra])
        parts = [paths]  # joined once, after the last mechanism
        if scat.enabled and geom.caster is not None:
            step(done, len(links), f"{link_name}: scattering")
            with clock("scattering"):
                parts.append(scattering.link_paths(
                    geom, scattering.prepare(geom, tx, scat), tx, rx, scat,
                    stats["scattering"]))
        if wedges is not None:
            rx_candidates = candidates_of(r_idx) if diff.max_reflections else {}
            step(done, len(links), f"{link_name}: diffraction")
            with clock("diffraction"):
                parts.append(diffraction.link_paths(
                    geom, wedges, tx, rx, diff, tx_candidates, rx_candidates,
                    stats["diffraction"], go_paths=go_paths, seeing=seeing))
        if len(parts) > 1:
            with clock("join"):
                paths = concat_paths(parts)
        out.append(Link(tx_name=tx.name, rx_name=rx.name, tx_index=t_idx, rx_index=r_idx,
                        paths=paths))
    step(len(links), len(links), "done")

    meta = settings.metadata()
    meta["clradcom_version"] = __version__
    if scat.enabled:
        meta["scattering.tiles_dropped"] = int(stats["scattering"].get("tiles_dropped", 0))
        meta["scattering.triangles_below_floor"] = int(
            stats["scattering"].get("triangles_below_floor", 0))
    for key, value in stats["diffraction"].items():
        meta[f"diffraction.{key}"] = int(value)
    meta["device"] = geom.runtime.info.device_name.strip()
    if settings.engine == "device":
        meta["device.fp64"] = bool(geom.runtime.info.has_double)
    # where each stage ran: "device", "host: reason" or "device+host: reason"
    meta.update(engines.metadata())
    return Snapshot(scene_name=scene.name, carrier_hz=float(scene.carrier_hz),
                    scene_hash=scene.content_hash(), links=tuple(out), metadata=meta,
                    time_s=float(scene.time_s),
                    object_names=tuple(obj.name for obj in scene.objects))
