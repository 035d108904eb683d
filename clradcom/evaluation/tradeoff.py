"""Speed against accuracy: sweep the tracer's and the synthesis' knobs on one radar's own
echoes (its monostatic link), measure every setting against a converged reference, and
mark the Pareto fronts (docs/tradeoff.md).

A sweep *point* is a dict of the CSV's setting columns (:data:`SETTING_COLUMNS` plus any
other settings field it varies, by a flat name such as ``scattering_tile_size_m`` or a
nested one such as ``scattering.tile_size_m``) -> value; :func:`trace_settings` turns it
into a :class:`~clradcom.trace.TraceSettings`. A *record* is a dict with one row of
``tradeoff.csv``: the point, the synthesis back end, and what :func:`measure` found
(:data:`MEASURE_COLUMNS`; keys starting with ``_`` are for labels and scores only and are
not written). tools/tradeoff.py prints what these functions return.
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from clradcom.errors import ArgumentError
from clradcom.evaluation import accuracy as acc
from clradcom.evaluation import budget
from clradcom.figures import new_figure
from clradcom.files import save_figure, write_csv
from clradcom.radar import (
    Waveform,
    add_thermal_noise,
    random_symbols,
    synthesize_frequency_domain,
    synthesize_time_domain,
)
from clradcom.radar.pipeline import frame_result
from clradcom.radar.report import match_tolerances, moving_objects
from clradcom.radar.truth import detection_truth
from clradcom.radar.waveform import ofdm_demodulate
from clradcom.trace import DiffractionSettings, TraceSettings, trace_scene

__all__ = ["BACKENDS", "DEFAULT_SYNTHESIS", "FLAT_FIELDS", "MEASURE_COLUMNS", "PARETO_COLUMNS",
           "PARETO_TOLERANCES", "SETTING_COLUMNS", "SETTING_FIELDS", "Convergence",
           "SweepContext", "SweepStep", "accuracy_targets", "describe_target",
           "detection_score", "estimate_sweep_seconds", "grid_point", "mark_pareto",
           "measure", "plot_tradeoff",
           "pruned_totals", "read_tradeoff_csv", "reference_convergence", "reference_point",
           "reference_seconds", "reflections_by_order", "run_sweep", "setting_label",
           "settings_field", "sweep_context", "sweep_points", "synthesize", "trace_link",
           "trace_settings", "vary_field_names", "write_tradeoff_csv"]

#: synthesis back end -> (method, NUFFT tolerance)
BACKENDS = {"fast": ("fast", 1e-10), "fast-lp": ("fast", 1e-5), "exact": ("exact", 1e-10)}
#: the default sweep's back ends (minutes on a street); FULL_SYNTHESIS: ``--full``'s
DEFAULT_SYNTHESIS = "fast,fast+prune"
FULL_SYNTHESIS = "fast,fast+prune,fast-lp+prune,exact+prune"

SETTING_COLUMNS = ["rays", "max_reflections", "max_diffractions", "physical_optics",
                   "scattering"]
MEASURE_COLUMNS = [
    "trace_s", "prune_s", "synth_s", "process_s", "seconds", "paths_traced", "paths_used",
    "pruned_reflection", "pruned_diffraction", "pruned_scattering", "power_share",
    "count_share", "channel_nmse_db", "error_to_noise_db", "image_error_db", "targets",
    "targets_found",
    "range_error_m", "velocity_error_mps", "detections", "reference_s", "reference_found"]
#: differences within these count as equal on the front: NMSE dB, power share, detection
#: error in resolution cells (timing noise is not a reason to keep a point either)
PARETO_TOLERANCES = (0.5, 0.5, 0.005, 0.05)
PARETO_COLUMNS = ["pareto_channel", "pareto_image", "pareto_completeness", "pareto_detection",
                  "pareto_all"]

#: the sweep's own knobs: CSV column -> ``TraceSettings.replace`` key
SETTING_FIELDS = {"rays": "specular__rays", "max_reflections": "specular__max_reflections",
                  "max_diffractions": "diffraction__max_diffractions",
                  "physical_optics": "optics__mode", "scattering": "scattering__enabled"}
#: the other settings under the flat names they had before the settings were nested
#: (docs/tradeoff.md's ``--vary`` examples and older CSV columns use them)
FLAT_FIELDS = {
    "line_of_sight": "specular__line_of_sight",
    "wedge_angle_deg": "diffraction__wedge_angle_deg",
    "diffraction_reflections": "diffraction__max_reflections",
    "diffraction_hop_m": "diffraction__max_hop_m",
    "sbr_spacing_wavelengths": "optics__sbr_spacing_wavelengths",
    "scattering_max_reflections": "scattering__max_reflections",
    "scattering_threshold_db": "scattering__threshold_db",
    "scattering_tile_size_m": "scattering__tile_size_m",
    "scattering_min_face_area_m2": "scattering__min_face_area_m2",
    "scattering_floor": "scattering__floor",
}
_MECHANISMS = ("specular", "diffraction", "optics", "scattering")
_THRESHOLD = "scattering__threshold_db"
_FLOOR = "scattering__floor"


# ----------------------------------------------------------------------------------------
# sweep points and their settings
# ----------------------------------------------------------------------------------------
def _nested_fields() -> dict[str, str]:
    """"mechanism.field" -> "mechanism__field" for every nested settings field."""
    default = TraceSettings()
    return {f"{m}.{f.name}": f"{m}__{f.name}" for m in _MECHANISMS
            for f in dataclasses.fields(getattr(default, m))}


def settings_field(name: str) -> str | None:
    """The ``TraceSettings.replace`` key a column name stands for: a sweep knob
    (:data:`SETTING_FIELDS`), a flat name (:data:`FLAT_FIELDS`), ``mechanism.field`` or
    ``mechanism__field``; None when it names no settings field."""
    if name in SETTING_FIELDS:
        return SETTING_FIELDS[name]
    if name in FLAT_FIELDS:
        return FLAT_FIELDS[name]
    return _nested_fields().get(name.replace("__", ".", 1))


def vary_field_names() -> list[str]:
    """The names a sweep may vary besides its own knobs (flat and nested)."""
    own = set(SETTING_FIELDS.values())
    nested = [n for n, key in _nested_fields().items() if key not in own]
    return sorted(FLAT_FIELDS) + sorted(nested)


def trace_settings(point: dict) -> TraceSettings:
    """The tracer settings of a sweep point (columns by :func:`settings_field`)."""
    changes = {}
    for name, value in point.items():
        key = settings_field(name)
        if key is None:
            raise ArgumentError(f"column {name!r} is no TraceSettings field", argument="point",
                                value=point)
        changes[key] = value
    return TraceSettings().replace(**changes)


def grid_point(rays, reflections, diffractions, optics, scattering, extra=(),
               scattering_threshold_db=None, scattering_floor=None) -> dict:
    """The sweep point of one combination of knobs (and ``extra`` (column, value) pairs).

    Fields that only matter for a mechanism that is off are left at their defaults (so
    such points are not traced twice), and the reflections beside diffracting edges, when
    varied, are clamped to ``reflections``. ``scattering_threshold_db`` / ``scattering_floor``, when
    given, apply where scattering is on and the point does not set them already.
    """
    point = {"rays": int(rays), "max_reflections": int(reflections),
             "max_diffractions": int(diffractions), "physical_optics": optics,
             "scattering": bool(scattering)}
    for name, value in extra:
        key = settings_field(name)
        if key is None:
            raise ArgumentError(f"{name!r} is no TraceSettings field (fields: "
                                f"{vary_field_names()})", argument="extra", value=name)
        off = (key.startswith("scattering__") and not point["scattering"]) or (
            key.startswith("diffraction__") and not point["max_diffractions"])
        if key == "diffraction__max_reflections":
            # never more than the specular search allows (as the tracer clamps it); at its
            # default where diffraction is off
            if off:
                value = DiffractionSettings().max_reflections
            point[name] = min(value, point["max_reflections"])
        elif not off:
            point[name] = value
    keys = {settings_field(n) for n in point}
    if scattering_threshold_db is not None and point["scattering"] and _THRESHOLD not in keys:
        point["scattering_threshold_db"] = float(scattering_threshold_db)
    if scattering_floor and point["scattering"] and _FLOOR not in keys:
        point["scattering_floor"] = float(scattering_floor)
    return point


def sweep_points(rays, reflections, diffractions, optics, scattering, vary=(),
                 order_cap: int = 16, scattering_threshold_db=None,
                 scattering_floor=None) -> list[dict]:
    """Unique sweep points of every combination, cheapest knobs first.

    ``vary``: (column, values) pairs of other settings fields; reflection orders above
    ``order_cap`` are capped; with no reflections one ray count (the smallest) is enough.
    """
    extra_names = [n for n, _ in vary]
    extra_vals = [v for _, v in vary]
    seen, out = set(), []
    for n_rays, refl, diffr, opt, scat, *extra in itertools.product(
            sorted(rays), sorted(reflections), sorted(diffractions), optics, scattering,
            *extra_vals):
        refl = min(refl, order_cap)
        if refl == 0:  # no reflections: the rays find nothing, one ray count is enough
            n_rays = min(rays)
        point = grid_point(n_rays, refl, diffr, opt, scat,
                           zip(extra_names, extra, strict=True), scattering_threshold_db,
                           scattering_floor)
        key = tuple(sorted(point.items()))
        if key not in seen:
            seen.add(key)
            out.append(point)
    return out


def reference_point(rays, reflections, diffractions, optics, scattering, vary=(),
                    order_cap: int = 16, reference_rays: int | None = None) -> dict:
    """The converged reference: the largest value of every knob (the last of ``optics``
    and of each ``vary`` list), ``reference_rays`` rays (default 4 x the most)."""
    extra = [(n, v[-1]) for n, v in vary]
    return grid_point(reference_rays or 4 * max(rays),
                      min(max(reflections), max(order_cap, 0)),
                      max(diffractions), optics[-1], max(scattering), extra)


# ----------------------------------------------------------------------------------------
# tracing and measuring one setting
# ----------------------------------------------------------------------------------------
@dataclass
class SweepContext:
    """What every setting is measured against: one radar's link, its noise floor, one
    set of OFDM symbols and one thermal-noise realisation, the moving targets' truth and
    (once traced) the reference's paths and frame channel."""

    scene: object
    radar_index: int
    waveform: Waveform
    floor: budget.NoiseFloor
    symbols: np.ndarray
    noise: np.ndarray
    truth: list
    tolerances: tuple[float, float]
    ref_paths: object = None
    F_ref: np.ndarray | None = None


def estimate_sweep_seconds(points, n_backends: int, reference_rays: int,
                           reference_trace_s: float, reference_measure_s: float) -> float:
    """Seconds a sweep is expected to take, from the reference's own run (measured before
    the sweep): each point's trace the reference's trace time scaled by its share of the
    reference's rays (the rays dominate a trace), each back end run the reference's
    synthesis and processing time (no point has more paths than the reference, which
    has the largest value of every knob). An estimate, not a bound: PO facets and
    scattering tiles cost time the rays do not count."""
    if reference_rays <= 0:
        raise ArgumentError("must be positive", argument="reference_rays",
                            value=reference_rays)
    trace = sum(reference_trace_s * min(1.0, p["rays"] / reference_rays) for p in points)
    return float(trace + len(points) * n_backends * reference_measure_s)


def sweep_context(scene, radar_index: int, waveform: Waveform, floor: budget.NoiseFloor,
                  noise_figure_db: float, seed: int = 0) -> SweepContext:
    """The context of a sweep: symbols from ``seed``, noise from ``seed + 1``, the truth
    of the scene's moving objects (other than the radar's own car)."""
    radar = scene.radars[radar_index]
    D = random_symbols(waveform, seed)
    noise = add_thermal_noise(np.zeros_like(D), radar.tx_power_w, noise_figure_db,
                              waveform.bandwidth, rng=np.random.default_rng(seed + 1))
    truth = detection_truth(scene, radar.name, moving_objects(scene, radar))
    return SweepContext(scene, radar_index, waveform, floor, D, noise, truth,
                        match_tolerances(waveform))


def trace_link(scene, point: dict, runtime, radar_index: int):
    """(paths of the radar's monostatic link, seconds) for one sweep point."""
    t0 = time.perf_counter()
    snap = trace_scene(scene, trace_settings(point), runtime=runtime,
                       links=[(radar_index, radar_index)])
    return snap.links[0].paths, time.perf_counter() - t0


def synthesize(paths, D, waveform: Waveform, backend: str) -> np.ndarray:
    """Received symbols D_r of the paths with one of :data:`BACKENDS`."""
    method, eps = BACKENDS[backend]
    if method == "fast":
        return synthesize_frequency_domain(D, paths.gain, paths.delay_s, paths.doppler_hz,
                                           waveform, time_origin_s=waveform.fft_window_centre,
                                           eps=eps)
    rx = synthesize_time_domain(D, paths.gain, paths.delay_s, paths.doppler_hz, waveform,
                                tol=eps)
    return ofdm_demodulate(rx, waveform)


def measure(ctx: SweepContext, paths, backend: str, prune: bool):
    """Prune (optionally), synthesise, process: (record of accuracy numbers and stage
    seconds, frame channel F, prune report or None)."""
    rec = {"paths_traced": paths.n_paths}
    t0 = time.perf_counter()
    report = None
    if prune:
        paths, report = budget.prune_paths(paths, ctx.floor.power, ctx.waveform)
    rec["prune_s"] = time.perf_counter() - t0
    for kind in ("reflection", "diffraction", "scattering"):
        rec[f"pruned_{kind}"] = report.dropped_by_kind[kind] if report else 0
    rec["paths_used"] = paths.n_paths
    t0 = time.perf_counter()
    Dr = synthesize(paths, ctx.symbols, ctx.waveform, backend)
    rec["synth_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    dets = frame_result(ctx.symbols, Dr + ctx.noise, paths, ctx.waveform).detections
    rec["process_s"] = time.perf_counter() - t0
    F = acc.frame_channel(ctx.symbols, Dr)
    if ctx.F_ref is not None:
        sigma2 = ctx.floor.noise_variance
        rec["channel_nmse_db"] = acc.channel_nmse_db(F, ctx.F_ref)
        rec["error_to_noise_db"] = acc.error_to_noise_db(F, ctx.F_ref, sigma2)
        rec["image_error_db"] = acc.image_error_to_noise_db(F, ctx.F_ref, sigma2,
                                                            ctx.waveform)
    if ctx.ref_paths is not None:
        c = acc.path_completeness(ctx.ref_paths, paths, ctx.floor.power)
        rec["power_share"], rec["count_share"] = c.power_share, c.count_share
    de = acc.detection_errors(dets, ctx.truth, *ctx.tolerances)
    rec.update(targets=de.n_targets, targets_found=de.n_found, range_error_m=de.range_error_m,
               velocity_error_mps=de.velocity_error_mps, detections=len(dets))
    return rec, F, report


@dataclass(frozen=True)
class Convergence:
    """The reference against itself at half its rays (fast synthesis on both sides)."""

    n_paths: int
    channel_nmse_db: float
    error_to_noise_db: float


def reference_convergence(ctx: SweepContext, point: dict, runtime, ref_paths, F_ref,
                          reference_synthesis: str, prune_floor: float = 0.0) -> Convergence:
    """Trace the reference point at half its rays, prune below ``prune_floor`` as the
    reference was, and compare the frame channels (the rays' share of the error only).
    ``F_ref`` is the reference's channel by ``reference_synthesis``; the fast one is
    made here when that was another back end."""
    half = dict(point, rays=max(1, point["rays"] // 2))
    half_paths, _ = trace_link(ctx.scene, half, runtime, ctx.radar_index)
    half_paths, _ = budget.prune_paths(half_paths, prune_floor, ctx.waveform)
    _, F_half, _ = measure(ctx, half_paths, "fast", False)
    F_ref_fast = F_ref if reference_synthesis == "fast" else measure(
        ctx, ref_paths, "fast", False)[1]
    return Convergence(half_paths.n_paths, acc.channel_nmse_db(F_half, F_ref_fast),
                       acc.error_to_noise_db(F_half, F_ref_fast, ctx.floor.noise_variance))


def reflections_by_order(paths, floor_power: float) -> list[tuple[int, int, float]]:
    """(order, paths, strongest dB above the floor) of the pure reflection paths of each
    order that has any."""
    kinds = acc.path_kind(paths.interaction)
    power = np.abs(paths.gain) ** 2
    out = []
    for k in range(paths.k_max + 1):
        sel = (paths.n_interactions == k) & (kinds == "reflection")
        if sel.any():
            out.append((k, int(sel.sum()),
                        10 * math.log10(power[sel].max() / floor_power)))
    return out


@dataclass
class SweepStep:
    """One traced point of :func:`run_sweep`: its records (one per back end run), or the
    error that stopped its trace."""

    index: int
    point: dict
    n_paths: int = 0
    trace_s: float = 0.0
    records: list = dataclasses.field(default_factory=list)
    skipped_exact: int = 0
    error: str | None = None


def run_sweep(ctx: SweepContext, points, synthesis, runtime, *, extra=(),
              reference_s: float | None = None, reference_found: int | None = None,
              exact_max_paths: int | None = None) -> Iterator[SweepStep]:
    """Trace every point and measure it with every (back end, prune) of ``synthesis``,
    one :class:`SweepStep` per point.

    Records carry the point's :data:`SETTING_COLUMNS` and ``extra`` columns, the back
    end, the stage seconds and their sum ``seconds``, the reference's seconds and targets
    found, and ``setting``: their index over the whole sweep. The exact back end is
    skipped for traces of more than ``exact_max_paths`` paths.
    """
    extra = list(extra)
    wf = ctx.waveform
    n_records = 0
    for i, point in enumerate(points):
        try:
            paths, trace_s = trace_link(ctx.scene, point, runtime, ctx.radar_index)
        except ValueError as exc:
            yield SweepStep(i, point, error=str(exc))
            continue
        step = SweepStep(i, point, n_paths=paths.n_paths, trace_s=trace_s)
        for backend, prune in synthesis:
            if (backend == "exact" and exact_max_paths is not None
                    and paths.n_paths > exact_max_paths):
                step.skipped_exact += 1
                continue
            rec, _, _ = measure(ctx, paths, backend, prune)
            rec.update({k: point.get(k, "") for k in SETTING_COLUMNS + extra})
            rec.update(synthesis=backend, prune=prune, trace_s=trace_s, _extra=extra,
                       _dr=wf.range_resolution, _dv=wf.velocity_resolution,
                       reference_s=reference_s, reference_found=reference_found)
            rec["seconds"] = trace_s + rec["prune_s"] + rec["synth_s"] + rec["process_s"]
            rec["setting"] = n_records
            n_records += 1
            step.records.append(rec)
        yield step


# ----------------------------------------------------------------------------------------
# fronts, labels, choices
# ----------------------------------------------------------------------------------------
def detection_score(records) -> np.ndarray:
    """One detection error per record for the chart: the larger of range and velocity
    error in resolution cells; inf when it finds fewer targets than the reference."""
    out = []
    for r in records:
        need = r.get("reference_found", "")
        need = r["targets"] if need in ("", None) else need
        if r["targets_found"] < need:
            out.append(math.inf)
        elif r["targets_found"] == 0:
            out.append(0.0)
        else:
            out.append(max(r["range_error_m"] / r["_dr"], r["velocity_error_mps"] / r["_dv"]))
    return np.array(out)


def mark_pareto(records) -> None:
    """Set the :data:`PARETO_COLUMNS` flags of every record: on the front of run time
    against channel NMSE, image error, missed paths, detection error, and all four."""
    cost = [r["seconds"] for r in records]
    nmse = [r["channel_nmse_db"] for r in records]
    image = [r["image_error_db"] for r in records]
    share = [1.0 - r["count_share"] for r in records]
    det = detection_score(records)
    tol = dict(zip(("nmse", "image", "share", "det"), PARETO_TOLERANCES, strict=True))
    fronts = {"pareto_channel": acc.pareto_front(cost, nmse, tolerances=[tol["nmse"]]),
              "pareto_image": acc.pareto_front(cost, image, tolerances=[tol["image"]]),
              "pareto_completeness": acc.pareto_front(cost, share, tolerances=[tol["share"]]),
              "pareto_detection": acc.pareto_front(cost, det, tolerances=[tol["det"]]),
              "pareto_all": acc.pareto_front(cost, nmse, image, share, det,
                                             tolerances=PARETO_TOLERANCES)}
    for name, mask in fronts.items():
        for r, m in zip(records, mask, strict=True):
            r[name] = bool(m)


def setting_label(r: dict) -> str:
    """A record in a few words: "1e+04 r2 d1 pec scat fast+prune s_tile_size_m=0.5"."""

    def short(name):
        return name.replace("scattering_", "s_").replace("scattering.", "s.")

    s = (f"{r['rays']:.0e} r{r['max_reflections']} d{r['max_diffractions']} "
         f"{r['physical_optics']}{' scat' if r['scattering'] else ''} {r['synthesis']}"
         f"{'+prune' if r['prune'] else ''}")
    for k in r.get("_extra", ()):
        v = r.get(k, "")
        if v != "":
            s += f" {short(k)}={v:.3g}" if isinstance(v, float) else f" {short(k)}={v}"
    return s


def reference_seconds(records) -> float | None:
    """The reference run's seconds the records carry (None when they carry none)."""
    v = records[0].get("reference_s", "")
    return None if v in ("", None) else float(v)


def pruned_totals(records) -> dict[str, int]:
    """Paths dropped below the floor per kind, summed over the pruned runs."""
    pr = [r for r in records if r["prune"]]
    return {k: sum(r[f"pruned_{k}"] for r in pr)
            for k in ("reflection", "diffraction", "scattering")}


def accuracy_targets(records, waveform: Waveform, nmse_db=(), image_error_db=(),
                     range_m: float | None = None,
                     velocity_mps: float | None = None) -> list[budget.AccuracyTarget]:
    """The targets to pick settings for: each channel NMSE, each image error, and one
    detection target (within ``range_m`` and ``velocity_mps``; default one resolution
    cell each). Every target asks for as many moving targets detected as the reference
    finds: the channel is dominated by the radar's own mounting and the road under it, so
    a setting that traces nothing else meets an NMSE of -30 dB and finds no car."""
    need = records[0].get("reference_found", "")
    found = None if need in ("", None) else int(need)
    targets = [budget.AccuracyTarget(channel_nmse_db=x, min_targets_found=found)
               for x in nmse_db]
    targets += [budget.AccuracyTarget(image_error_db=x, min_targets_found=found)
                for x in image_error_db]
    targets.append(budget.AccuracyTarget(
        min_targets_found=found,
        range_error_m=range_m if range_m is not None else waveform.range_resolution,
        velocity_error_mps=velocity_mps if velocity_mps is not None
        else waveform.velocity_resolution))
    return targets


def describe_target(target: budget.AccuracyTarget) -> str:
    """"channel_nmse_db <= -20", "..., min_targets_found >= 3": the target's criteria."""
    at_least = ("power_share", "count_share", "min_targets_found")
    return ", ".join(f"{k} {'>=' if k in at_least else '<='} {v:g}"
                     for k, v in dataclasses.asdict(target).items() if v is not None)


# ----------------------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------------------
def write_tradeoff_csv(records, extra, path, *, inputs=()) -> None:
    """tradeoff.csv: ``setting``, the setting columns (and ``extra``), back end and prune,
    the measures and the Pareto flags; floats to 6 significant digits. Written
    atomically, never over a file in ``inputs`` (:func:`clradcom.files.write_csv`)."""
    cols = (["setting"] + SETTING_COLUMNS + list(extra) + ["synthesis", "prune"]
            + MEASURE_COLUMNS + PARETO_COLUMNS)
    rows = []
    for r in records:
        row = []
        for c in cols:
            v = r.get(c, "")
            row.append(f"{v:.6g}" if isinstance(v, float) else v)
        rows.append(row)
    write_csv(path, rows, cols, inputs=inputs)


#: columns a CSV must have to be redrawn, and those of them that must hold numbers
_NEEDED = ["setting", *SETTING_COLUMNS, "synthesis", "prune", *MEASURE_COLUMNS]
_NUMERIC = ["rays", "seconds", "paths_traced", "paths_used", "count_share", "power_share",
            "channel_nmse_db", "image_error_db", "targets", "targets_found",
            "pruned_reflection", "pruned_diffraction", "pruned_scattering"]


def read_tradeoff_csv(path, waveform: Waveform) -> tuple[list[dict], list[str]]:
    """(records, extra columns) of a CSV :func:`write_tradeoff_csv` wrote, ready for
    :func:`mark_pareto` and the chart again (``waveform``: the sweep's, for the
    detection score). A file that cannot be read or is no such CSV (a column missing, a
    measure that is no number, no rows) is refused with
    :class:`~clradcom.errors.ArgumentError` naming ``path`` and what is wrong."""
    def refuse(reason):
        return ArgumentError(reason, argument="path", value=str(path))

    try:
        with open(path, newline="") as fh:
            header = next(csv.reader(fh), [])
        records = budget.read_records(path)
    except OSError as exc:
        raise refuse(f"cannot read it ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise refuse(f"not a tradeoff.py CSV ({exc})") from None
    missing = [c for c in _NEEDED if c not in header]
    if missing:
        raise refuse(f"not a tradeoff.py CSV: no column {missing[0]!r}"
                     + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""))
    if not records:
        raise refuse("not a tradeoff.py CSV: no rows")
    extra = header[header.index("scattering") + 1:header.index("synthesis")]
    for i, r in enumerate(records):
        for k in _NUMERIC:
            if isinstance(r[k], bool) or not isinstance(r[k], int | float):
                raise refuse(f"row {i + 1}: {k} = {r[k]!r} is no number")
        if not isinstance(r["prune"], bool):
            raise refuse(f"row {i + 1}: prune = {r['prune']!r} is neither True nor False")
        for k in ("range_error_m", "velocity_error_mps"):
            r[k] = math.nan if r[k] == "" else r[k]
            if not isinstance(r[k], int | float):
                raise refuse(f"row {i + 1}: {k} = {r[k]!r} is no number")
        r.update(_extra=extra, _dr=waveform.range_resolution, _dv=waveform.velocity_resolution)
    return records, extra


def plot_tradeoff(records, ref_seconds: float | None = None, path=None, *,
                  inputs=()) -> Figure:
    """Run time against each accuracy measure (channel NMSE, image error, share of paths
    found, detection error), the Pareto front of each marked, the reference run's time
    as a line. Written to ``path`` when given, atomically and byte-identically for
    identical records (:func:`clradcom.files.save_figure`)."""
    t = np.array([r["seconds"] for r in records])

    def clip_db(key):
        v = np.array([r[key] for r in records], dtype=float)
        finite = v[np.isfinite(v)]
        lo = (finite.min() - 10.0) if finite.size else -100.0
        return np.where(np.isneginf(v), lo, v)

    share = np.array([r["count_share"] for r in records])
    det = detection_score(records)
    det_plot = np.where(np.isinf(det), np.nan, det)
    panels = [
        ("channel NMSE vs reference (dB; a perfect match drawn 10 dB below the best)",
         clip_db("channel_nmse_db"), "pareto_channel"),
        ("largest radar-image error re thermal noise (dB)", clip_db("image_error_db"),
         "pareto_image"),
        ("share of the reference's paths above the noise floor found", share,
         "pareto_completeness"),
        ("detection error (resolution cells; x: a target the reference finds missed)",
         det_plot,
         "pareto_detection"),
    ]
    fig = new_figure(figsize=(15, 10))
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2).ravel()
    for ax, (title, y, key) in zip(axes, panels, strict=True):
        front = np.array([r[key] for r in records])
        ax.scatter(t[~front], y[~front], s=14, c="0.6", label="setting")
        order = np.argsort(t[front])
        ax.plot(t[front][order], y[front][order], "o-", c="C3", ms=5, label="Pareto front")
        if key == "pareto_detection":
            missed = np.isinf(det)
            if missed.any():
                top = np.nanmax(det_plot) if np.isfinite(det_plot).any() else 1.0
                ax.scatter(t[missed], np.full(missed.sum(), top * 1.1 + 0.1), marker="x",
                           c="k", s=16, label="target missed")
        if ref_seconds is not None:
            ax.axvline(ref_seconds, c="C0", ls="--", lw=1, label="reference run")
        ax.set_xscale("log")
        ax.set_xlabel("run time per setting (s): trace + synthesis + processing")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8, loc="best")
    axes[3].legend(fontsize=8, loc="best")
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path, inputs=inputs, dpi=120)
    return fig
