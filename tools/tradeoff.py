#!/usr/bin/env python3
"""Speed against accuracy: sweep the tracer's and the synthesis' knobs on one scene.

    python tools/tradeoff.py scenes/street/street.toml

For one radar's own echoes (the monostatic link) it traces every combination of

  --rays           rays per transmitter             (default 10000,100000,1000000)
  --reflections    most specular reflections        (default 0,1,2,5)
  --diffractions   most UTD edge diffractions       (default 0,1)
  --optics         PEC objects: GO or PO            (default none,pec)
  --scattering     diffuse tiles off/on             (default 0,1)
  --vary F=a,b     any other TraceSettings field, e.g. a tile size where one is offered

and synthesises every trace with each of these back ends (--synthesis):

  fast       frequency-domain model (no ICI/ISI), NUFFT tolerance 1e-10
  fast-lp    the same at NUFFT tolerance 1e-5 (the precision knob the synthesis offers;
             tracer geometry is float32 in kernels and float64 on the host, no knob)
  exact      time-domain superposition with ICI/ISI
  each with "+prune": paths below the radar's noise floor dropped first (unless the weak
             paths of their range-Doppler cell add up above it)

timing each (time.perf_counter: trace + pruning + synthesis + radar processing), and
measures against a converged reference (the largest value of every knob, more rays,
exact synthesis, nothing pruned; its own convergence is checked against half its rays):

  channel_nmse_db     NMSE of the frame's channel F = D_r/D against the reference's, dB
  image_error_db      that error's largest radar-image cell against the thermal noise in
                      it (< 0 dB: invisible to the radar); error_to_noise_db: its bound
  count_share         share of the reference's paths above the noise floor found (paths
                      matched by interaction sequence and faces); power_share: share of
                      their power
  range_error_m, velocity_error_mps, targets_found: CFAR detections of the moving objects
                      against the scene's ground truth (same symbols and noise every run)

Before the sweep the radar's noise floor bounds what is traced (clradcom.budget):
reflection orders whose best case cannot reach it are capped, scattering triangles that
cannot reach it are reported, the tracer's scattering threshold is set from it
(--no-trace-prune: left alone), and "+prune" drops found paths below it. The report says
what was pruned. docs/tradeoff.md has the definitions and the street's front.

Writes to --out (default out/<scene>/tradeoff/): tradeoff.csv (one row per setting, the
Pareto flags included), tradeoff.png (run time against each accuracy measure, the Pareto
front marked), and prints a table and the cheapest setting for each accuracy target
(--target-nmse-db, --target-enr-db, --target-range-m/--target-velocity-mps).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import math
import sys
import time
from pathlib import Path

import numpy as np

from clradcom.device.runtime import OpenCLError, get_runtime
from clradcom.errors import SceneError
from clradcom.evaluation import accuracy as acc
from clradcom.evaluation import budget
from clradcom.radar import (
    Waveform,
    add_thermal_noise,
    random_symbols,
    synthesize_frequency_domain,
    synthesize_time_domain,
)
from clradcom.radar.pipeline import process
from clradcom.radar.truth import detection_truth
from clradcom.radar.waveform import ofdm_demodulate
from clradcom.scene.reader import load_scene
from clradcom.trace import TraceSettings, trace_scene

#: synthesis back end -> (method, NUFFT tolerance)
BACKENDS = {"fast": ("fast", 1e-10), "fast-lp": ("fast", 1e-5), "exact": ("exact", 1e-10)}
DEFAULT_SYNTHESIS = "fast,fast+prune,fast-lp+prune,exact+prune"

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


# ----------------------------------------------------------------------------------------
# argument parsing
# ----------------------------------------------------------------------------------------
def _list(conv):
    def parse(text):
        try:
            return [conv(v.strip()) for v in text.split(",") if v.strip()]
        except ValueError as exc:
            raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None
    return parse


def _bool(v: str) -> bool:
    if v.lower() in ("1", "true", "on", "yes"):
        return True
    if v.lower() in ("0", "false", "off", "no"):
        return False
    raise ValueError(f"not a boolean: {v!r}")


def _value(v: str):
    for conv in (int, float):
        try:
            return conv(v)
        except ValueError:
            pass
    if v.lower() in ("true", "false"):
        return v.lower() == "true"
    return None if v.lower() == "none" else v


def _vary(text: str):
    name, sep, vals = text.partition("=")
    if not sep or not name.strip() or not vals.strip():
        raise argparse.ArgumentTypeError(f"--vary wants FIELD=v1,v2, got {text!r}")
    return name.strip(), [_value(v.strip()) for v in vals.split(",")]


def _synthesis(text: str):
    out = []
    for item in text.split(","):
        name, _, flag = item.strip().partition("+")
        if name not in BACKENDS or flag not in ("", "prune"):
            raise argparse.ArgumentTypeError(
                f"synthesis {item!r}: want one of {sorted(BACKENDS)} with optional '+prune'")
        out.append((name, flag == "prune"))
    return out


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", help="scene file (TOML)")
    ap.add_argument("--radar", default=None, help="radar (default: the first txrx one)")
    ap.add_argument("--out", default=None, help="output folder (default out/<scene>/tradeoff)")
    ap.add_argument("--device", default=None, help="OpenCL device (see tools/trace.py)")
    ap.add_argument("--rays", type=_list(int), default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--reflections", type=_list(int), default=[0, 1, 2, 5])
    ap.add_argument("--diffractions", type=_list(int), default=[0, 1])
    ap.add_argument("--optics", type=_list(str), default=["none", "pec", "sbr"],
                    help="physical_optics values; the last is the reference's")
    ap.add_argument("--scattering", type=_list(_bool), default=[False, True])
    ap.add_argument("--vary", type=_vary, action="append", default=[],
                    help="FIELD=v1,v2: sweep another TraceSettings field too (last value "
                         "is the reference's)")
    ap.add_argument("--synthesis", type=_synthesis, default=_synthesis(DEFAULT_SYNTHESIS),
                    help=f"back ends per trace (default {DEFAULT_SYNTHESIS})")
    ap.add_argument("--reference-synthesis", choices=sorted(BACKENDS), default="exact",
                    help="synthesis of the reference (default exact)")
    ap.add_argument("--reference-margin-db", type=float, default=None,
                    help="drop the reference's paths this far below the noise floor before "
                         "its synthesis (default: keep all; e.g. -20 keeps the exact "
                         "synthesis of a street affordable)")
    ap.add_argument("--reference-rays", type=int, default=None,
                    help="rays of the reference (default 4 x the largest of --rays)")
    ap.add_argument("--no-trace-prune", action="store_true",
                    help="do not set the tracer's scattering threshold from the noise floor")
    ap.add_argument("--margin-db", type=float, default=0.0,
                    help="noise floor margin: paths below floor + margin are pruned")
    ap.add_argument("--subcarriers", type=int, default=None, help="N (default the paper's)")
    ap.add_argument("--symbols", type=int, default=None, help="M (default the paper's)")
    ap.add_argument("--exact-max-paths", type=int, default=None,
                    help="skip the exact back end for traces with more paths than this (its "
                         "cost grows with the paths; the reference always uses it)")
    ap.add_argument("--from-csv", default=None,
                    help="trace nothing: fronts, chart, table and choices from this CSV")
    ap.add_argument("--seed", type=int, default=0, help="seed of the OFDM symbols and noise")
    ap.add_argument("--target-nmse-db", type=_list(float), default=[-10.0, -20.0, -30.0],
                    help="channel error targets (dB) to pick settings for")
    ap.add_argument("--target-enr-db", type=_list(float), default=[0.0],
                    help="radar-image error re noise targets (dB) to pick settings for")
    ap.add_argument("--target-range-m", type=float, default=None,
                    help="detection target: range error (default: range resolution)")
    ap.add_argument("--target-velocity-mps", type=float, default=None,
                    help="detection target: velocity error (default: velocity resolution)")
    args = ap.parse_args(argv)
    for name in ("rays", "reflections", "diffractions", "optics", "scattering"):
        if not getattr(args, name):
            ap.error(f"--{name} needs at least one value")
    return args


# ----------------------------------------------------------------------------------------
# the sweep
# ----------------------------------------------------------------------------------------
def settings_kwargs(rays, refl, diffr, optics, scat, extra=(), scattering_threshold_db=None,
                    scattering_floor=None):
    """TraceSettings keyword arguments of one grid point.

    Fields that only matter for a mechanism that is off are left at their defaults
    (so such points are not traced twice), and ``diffraction_reflections`` is clamped
    to ``max_reflections`` where the tracer offers it.
    """
    kw = {"rays": int(rays), "max_reflections": int(refl), "max_diffractions": int(diffr),
          "physical_optics": optics, "scattering": bool(scat)}
    names = {f.name: f for f in dataclasses.fields(TraceSettings)}
    for name, value in extra:
        if (name.startswith("scattering_") and not kw["scattering"]) or (
                name.startswith("diffraction_") and not kw["max_diffractions"]):
            continue
        kw[name] = value
    if (scattering_threshold_db is not None and kw["scattering"]
            and "scattering_threshold_db" in names and "scattering_threshold_db" not in kw):
        kw["scattering_threshold_db"] = float(scattering_threshold_db)
    if scattering_floor and kw["scattering"] and "scattering_floor" in names:
        kw["scattering_floor"] = float(scattering_floor)
    if "diffraction_reflections" in names:
        kw["diffraction_reflections"] = min(
            kw.get("diffraction_reflections", names["diffraction_reflections"].default),
            kw["max_reflections"])
    return kw


def grid(args, order_cap: int, scattering_threshold_db=None, scattering_floor=None):
    """Unique TraceSettings keyword sets of the sweep, cheapest knobs first."""
    extra_names = [n for n, _ in args.vary]
    extra_vals = [v for _, v in args.vary]
    seen, out = set(), []
    for rays, refl, diffr, optics, scat, *extra in itertools.product(
            sorted(args.rays), sorted(args.reflections), sorted(args.diffractions),
            args.optics, args.scattering, *extra_vals):
        refl = min(refl, order_cap)
        if refl == 0:  # no reflections: the rays find nothing, one ray count is enough
            rays = min(args.rays)
        kw = settings_kwargs(rays, refl, diffr, optics, scat,
                             zip(extra_names, extra, strict=True), scattering_threshold_db,
                             scattering_floor)
        key = tuple(sorted(kw.items()))
        if key not in seen:
            seen.add(key)
            out.append(kw)
    return out


def reference_kwargs(args, order_cap: int):
    extra = [(n, v[-1]) for n, v in args.vary]
    return settings_kwargs(args.reference_rays or 4 * max(args.rays),
                           min(max(args.reflections), max(order_cap, 0)),
                           max(args.diffractions), args.optics[-1], max(args.scattering), extra)


def synthesize(paths, D, wf, backend: str):
    method, eps = BACKENDS[backend]
    if method == "fast":
        return synthesize_frequency_domain(D, paths.gain, paths.delay_s, paths.doppler_hz, wf,
                                           time_origin_s=wf.fft_window_centre, eps=eps)
    rx = synthesize_time_domain(D, paths.gain, paths.delay_s, paths.doppler_hz, wf, tol=eps)
    return ofdm_demodulate(rx, wf)


class Context:
    """What every setting is measured against."""

    def __init__(self, scene, radar_idx, wf, floor, D, noise, truth, tols, ref_paths, F_ref):
        self.scene, self.radar_idx, self.wf, self.floor = scene, radar_idx, wf, floor
        self.D, self.noise, self.truth, self.tols = D, noise, truth, tols
        self.ref_paths, self.F_ref = ref_paths, F_ref


def trace(scene, kw, runtime, radar_idx):
    t0 = time.perf_counter()
    snap = trace_scene(scene, TraceSettings(**kw), runtime=runtime,
                       links=[(radar_idx, radar_idx)])
    return snap.links[0].paths, time.perf_counter() - t0


def measure(ctx: Context, paths, backend: str, prune: bool):
    """Prune (optionally), synthesise, process; accuracy numbers and stage seconds."""
    rec = {"paths_traced": paths.n_paths}
    t0 = time.perf_counter()
    report = None
    if prune:
        paths, report = budget.prune_paths(paths, ctx.floor.power, ctx.wf)
    rec["prune_s"] = time.perf_counter() - t0
    for kind in ("reflection", "diffraction", "scattering"):
        rec[f"pruned_{kind}"] = report.dropped_by_kind[kind] if report else 0
    rec["paths_used"] = paths.n_paths
    t0 = time.perf_counter()
    Dr = synthesize(paths, ctx.D, ctx.wf, backend)
    rec["synth_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    _, dets = process(ctx.D, Dr + ctx.noise, ctx.wf)
    rec["process_s"] = time.perf_counter() - t0
    F = acc.frame_channel(ctx.D, Dr)
    if ctx.F_ref is not None:
        rec["channel_nmse_db"] = acc.channel_nmse_db(F, ctx.F_ref)
        rec["error_to_noise_db"] = acc.error_to_noise_db(F, ctx.F_ref, ctx.floor.noise_variance)
        rec["image_error_db"] = acc.image_error_to_noise_db(F, ctx.F_ref,
                                                            ctx.floor.noise_variance, ctx.wf)
    if ctx.ref_paths is not None:
        c = acc.path_completeness(ctx.ref_paths, paths, ctx.floor.power)
        rec["power_share"], rec["count_share"] = c.power_share, c.count_share
    de = acc.detection_errors(dets, ctx.truth, *ctx.tols)
    rec.update(targets=de.n_targets, targets_found=de.n_found, range_error_m=de.range_error_m,
               velocity_error_mps=de.velocity_error_mps, detections=len(dets))
    return rec, F, report


def detection_score(records):
    """One detection error per record for the chart: the larger of range and velocity
    error in resolution cells; inf when it finds fewer targets than the reference."""
    out = []
    for r in records:
        need = r.get("reference_found", "")
        need = r["targets"] if need == "" else need
        if r["targets_found"] < need:
            out.append(math.inf)
        elif r["targets_found"] == 0:
            out.append(0.0)
        else:
            out.append(max(r["range_error_m"] / r["_dr"], r["velocity_error_mps"] / r["_dv"]))
    return np.array(out)


def mark_pareto(records):
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


def label(r) -> str:
    s = (f"{r['rays']:.0e} r{r['max_reflections']} d{r['max_diffractions']} "
         f"{r['physical_optics']}{' scat' if r['scattering'] else ''} {r['synthesis']}"
         f"{'+prune' if r['prune'] else ''}")
    for k in r.get("_extra", ()):
        v = r.get(k, "")
        if v != "":
            s += f" {k.replace('scattering_', 's_')}={v:.3g}" if isinstance(v, float) else \
                f" {k.replace('scattering_', 's_')}={v}"
    return s


def plot(records, ref_seconds, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
    fig, axes = plt.subplots(2, 2, figsize=(15, 10))
    axes = axes.ravel()
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
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_csv(records, extra, path):
    cols = (["setting"] + SETTING_COLUMNS + list(extra) + ["synthesis", "prune"]
            + MEASURE_COLUMNS + PARETO_COLUMNS)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in records:
            row = []
            for c in cols:
                v = r.get(c, "")
                row.append(f"{v:.6g}" if isinstance(v, float) else v)
            w.writerow(row)


def fmt(v, spec):
    return "   -" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


# ----------------------------------------------------------------------------------------
def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        scene = load_scene(args.scene)
        runtime = get_runtime(args.device)
    except (SceneError, OpenCLError, ValueError) as exc:
        print(f"tradeoff.py: {exc}", file=sys.stderr)
        return 2
    names = [r.name for r in scene.radars]
    if args.radar is None:
        txrx = [i for i, r in enumerate(scene.radars) if r.role == "txrx"]
        if not txrx:
            print(f"tradeoff.py: {args.scene}: no radar with role 'txrx'", file=sys.stderr)
            return 2
        radar_idx = txrx[0]
    elif args.radar in names:
        radar_idx = names.index(args.radar)
    else:
        print(f"tradeoff.py: --radar {args.radar!r} is not in the scene (radars: {names})",
              file=sys.stderr)
        return 2
    radar = scene.radars[radar_idx]
    field_names = {f.name for f in dataclasses.fields(TraceSettings)}
    for name, _ in args.vary:
        if name not in field_names or name in SETTING_COLUMNS:
            print(f"tradeoff.py: --vary {name!r}: not a TraceSettings field other than "
                  f"{SETTING_COLUMNS} (fields: {sorted(field_names)})", file=sys.stderr)
            return 2
    wf_kw = {"carrier_hz": scene.carrier_hz}
    if args.subcarriers:
        wf_kw["n_subcarriers"] = args.subcarriers
    if args.symbols:
        wf_kw["n_symbols"] = args.symbols
    try:
        wf = Waveform(**wf_kw)
        nf_db = radar.noise_figure_db if radar.noise_figure_db is not None else 10.0
        floor = budget.noise_floor(wf, radar.tx_power_w, nf_db, margin_db=args.margin_db)
    except ValueError as exc:
        print(f"tradeoff.py: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out or Path("out") / scene.name / "tradeoff")
    out.mkdir(parents=True, exist_ok=True)
    if args.from_csv:
        return from_csv(args.from_csv, args, wf, out)
    print(f"device: {runtime.info.describe()}")
    print(f"radar {radar.name}: P_tx {radar.tx_power_w} W, NF {nf_db} dB, "
          f"{wf.n_subcarriers} x {wf.n_symbols} frame")
    print(f"noise floor: sigma^2 = {10 * math.log10(floor.noise_variance):.1f} dB per cell, "
          f"processing gain {10 * math.log10(floor.processing_gain):.1f} dB, margin "
          f"{args.margin_db:g} dB -> |a|^2 floor {floor.power_db:.1f} dB "
          f"(GO paths up to {budget.max_path_length(floor.power, scene.wavelength_m):.0f} m "
          "with isotropic antennas and |Gamma| = 1)")

    # --- power bounds before anything is traced -------------------------------------
    max_order = max(args.reflections)
    bounds = budget.order_bounds(scene, radar, radar, floor.power, max_order)
    useful = budget.max_useful_order(bounds)
    order_cap = max(useful, 0)
    print(f"order bound (Gamma_max {bounds[0].gamma_max:.3f}, shortest path "
          f"{bounds[-1].min_length_m:.2f} m):")
    for b in bounds:
        print(f"  order {b.order}: best case {fmt(b.headroom_db, '7.1f')} dB vs the floor"
              f"{'' if b.above_floor or b.order == 0 else '  -> not traced'}")
    skipped_orders = [b.order for b in bounds if b.order > order_cap]
    print(f"  orders skipped: {skipped_orders or 'none'}")
    tri_ids, tri_best, tri_above = budget.scattering_triangle_bounds(scene, radar, radar,
                                                                     floor.power)
    if len(tri_ids):
        print(f"scattering: {int((~tri_above).sum())} of {len(tri_ids)} scattering triangles "
              f"cannot reach the floor (best {10 * math.log10(tri_best.max()):.1f} dB)")
        if not tri_above.any() and True in args.scattering:
            print("  -> no scattering triangle can reach the floor: scattering not traced")
            args.scattering = [False]

    # --- reference ----------------------------------------------------------------------
    D = random_symbols(wf, args.seed)
    noise = add_thermal_noise(np.zeros_like(D), radar.tx_power_w, nf_db, wf.bandwidth,
                              rng=np.random.default_rng(args.seed + 1))
    own = radar.rides_on
    movers = [o.name for i, o in enumerate(scene.objects)
              if i != own and np.any(np.asarray(o.velocity) != 0)]
    truth = detection_truth(scene, radar.name, movers)
    tols = (wf.range_resolution + 0.3, wf.velocity_resolution)
    ctx = Context(scene, radar_idx, wf, floor, D, noise, truth, tols, None, None)
    ref_kw = reference_kwargs(args, order_cap)
    print(f"reference: {ref_kw}, {args.reference_synthesis} synthesis, nothing pruned")
    ref_paths, ref_trace_s = trace(scene, ref_kw, runtime, radar_idx)
    ref_floor = 0.0
    if args.reference_margin_db is not None:
        ref_floor = floor.power * 10.0 ** (args.reference_margin_db / 10.0)
        ref_paths, rep = budget.prune_paths(ref_paths, ref_floor, wf)
        print(f"  reference pruned {-args.reference_margin_db:g} dB below the floor: "
              f"{rep.describe()}; their summed power "
              f"{10 * math.log10(max(rep.dropped_power, 1e-300) / floor.power):.1f} dB "
              "re the floor, "
              f"{10 * math.log10(max(rep.dropped_power, 1e-300) / floor.noise_variance):.1f}"
              " dB re the noise per cell")
    ref_rec, F_ref, _ = measure(ctx, ref_paths, args.reference_synthesis, False)
    ref_seconds = ref_trace_s + ref_rec["synth_s"] + ref_rec["process_s"]
    print(f"  {ref_paths.n_paths} paths, {ref_seconds:.1f} s; targets found "
          f"{ref_rec['targets_found']}/{ref_rec['targets']}")
    # convergence in rays, with the fast synthesis on both sides (the rays' share only)
    half_kw = dict(ref_kw, rays=max(1, ref_kw["rays"] // 2))
    half_paths, _ = trace(scene, half_kw, runtime, radar_idx)
    half_paths, _ = budget.prune_paths(half_paths, ref_floor, wf)  # as the reference was
    _, F_half, _ = measure(ctx, half_paths, "fast", False)
    F_ref_fast = F_ref if args.reference_synthesis == "fast" else measure(
        ctx, ref_paths, "fast", False)[1]
    conv_nmse = acc.channel_nmse_db(F_half, F_ref_fast)
    conv_enr = acc.error_to_noise_db(F_half, F_ref_fast, floor.noise_variance)
    print(f"  convergence: half the rays ({half_paths.n_paths} paths) differ by "
          f"{conv_nmse:.1f} dB NMSE, {conv_enr:.1f} dB error-to-noise")
    ctx.ref_paths, ctx.F_ref = ref_paths, F_ref
    _, ref_prune = budget.prune_paths(ref_paths, floor.power, wf)
    print(f"  power bound on the reference: {ref_prune.describe()}")
    kinds = acc.path_kind(ref_paths.interaction)
    power = np.abs(ref_paths.gain) ** 2
    for k in range(ref_paths.k_max + 1):
        sel = (ref_paths.n_interactions == k) & (kinds == "reflection")
        if sel.any():
            print(f"    order {k} reflections{' (and PO facets)' if k == 1 else ''}: "
                  f"{sel.sum()} paths, strongest "
                  f"{10 * math.log10(power[sel].max() / floor.power):.1f} dB above the floor")

    # --- sweep --------------------------------------------------------------------------
    extra = [n for n, _ in args.vary]
    trace_thr = None
    if (not args.no_trace_prune and len(tri_ids) and tri_above.any()
            and "scattering_threshold_db" in field_names
            and "scattering_threshold_db" not in extra):
        # the strongest tile is at most the largest triangle bound: a threshold this far
        # below it never drops a tile above the floor
        trace_thr = -budget.relative_threshold_db(floor.power, float(tri_best.max()))
        extra.append("scattering_threshold_db")
        print(f"scattering tiles more than {-trace_thr:.1f} dB below the link's strongest "
              "are not emitted (floor against the best tile bound; the tracer's default "
              f"is {TraceSettings().scattering_threshold_db:g} dB)")
    # triangles whose tiles cannot reach the floor are never traced
    points = grid(args, order_cap, trace_thr,
                  None if args.no_trace_prune else floor.power)
    n_runs = len(points) * len(args.synthesis)
    print(f"sweep: {len(points)} traces x {len(args.synthesis)} back ends = {n_runs} settings")
    records, t_start, skipped_exact = [], time.perf_counter(), 0
    for i, kw in enumerate(points):
        try:
            paths, trace_s = trace(scene, kw, runtime, radar_idx)
        except ValueError as exc:
            print(f"  skipped {kw}: {exc}")
            continue
        for backend, prune in args.synthesis:
            if (backend == "exact" and args.exact_max_paths is not None
                    and paths.n_paths > args.exact_max_paths):
                skipped_exact += 1
                continue
            rec, _, _ = measure(ctx, paths, backend, prune)
            rec.update({k: kw.get(k, "") for k in SETTING_COLUMNS + extra})
            rec.update(synthesis=backend, prune=prune, trace_s=trace_s, _extra=extra,
                       _dr=wf.range_resolution, _dv=wf.velocity_resolution,
                       reference_s=ref_seconds, reference_found=ref_rec["targets_found"])
            rec["seconds"] = trace_s + rec["prune_s"] + rec["synth_s"] + rec["process_s"]
            rec["setting"] = len(records)
            records.append(rec)
        write_csv(records, extra, out / "tradeoff.csv")  # partial, in case the run stops
        print(f"  [{time.perf_counter() - t_start:6.1f} s] {i + 1}/{len(points)} "
              f"{label(records[-1]).rsplit(' ', 1)[0]}: {paths.n_paths} paths, "
              f"trace {trace_s:.2f} s", flush=True)
    if skipped_exact:
        print(f"  exact synthesis skipped for {skipped_exact} traces of more than "
              f"{args.exact_max_paths} paths (--exact-max-paths)")
    if not records:
        print("tradeoff.py: every setting failed", file=sys.stderr)
        return 2
    return finish(records, extra, args, wf, out)


def finish(records, extra, args, wf, out) -> int:
    """Pareto flags, CSV, chart, table and the cheapest setting per target."""
    mark_pareto(records)
    write_csv(records, extra, out / "tradeoff.csv")
    ref_seconds = records[0].get("reference_s", "")
    ref_seconds = None if ref_seconds == "" else float(ref_seconds)
    plot(records, ref_seconds, out / "tradeoff.png")
    print(f"\n{'setting':<48} {'s':>6} {'paths':>6} {'pruned':>6} {'NMSE':>7} {'image':>7} "
          f"{'count':>6} {'found':>5} {'dR m':>5} {'dv m/s':>6}  front")
    for r in sorted(records, key=lambda r: r["seconds"]):
        pruned = r["paths_traced"] - r["paths_used"]
        print(f"{label(r):<48} {r['seconds']:6.2f} {r['paths_traced']:6d} {pruned:6d} "
              f"{fmt(r['channel_nmse_db'], '7.1f')} {fmt(r['image_error_db'], '7.1f')} "
              f"{r['count_share']:6.3f} {r['targets_found']:>2}/{r['targets']:<2} "
              f"{fmt(r['range_error_m'], '5.2f')} {fmt(r['velocity_error_mps'], '6.2f')}  "
              f"{'*' if r['pareto_all'] else ''}{'C' if r['pareto_channel'] else ''}"
              f"{'I' if r['pareto_image'] else ''}{'P' if r['pareto_completeness'] else ''}"
              f"{'D' if r['pareto_detection'] else ''}")
    pr = [r for r in records if r["prune"]]
    if pr:
        dropped = {k: sum(r[f"pruned_{k}"] for r in pr)
                   for k in ("reflection", "diffraction", "scattering")}
        print(f"\npruned below the floor over the {len(pr)} '+prune' runs: "
              + ", ".join(f"{v} {k}" for k, v in dropped.items()))
    print("\ncheapest setting per accuracy target (clradcom.budget.choose_settings):")
    targets = [budget.AccuracyTarget(channel_nmse_db=x) for x in args.target_nmse_db]
    targets += [budget.AccuracyTarget(image_error_db=x) for x in args.target_enr_db]
    need = records[0].get("reference_found", "")
    targets.append(budget.AccuracyTarget(
        min_targets_found=None if need == "" else int(need),
        range_error_m=args.target_range_m if args.target_range_m is not None
        else wf.range_resolution,
        velocity_error_mps=args.target_velocity_mps if args.target_velocity_mps is not None
        else wf.velocity_resolution))
    for tg in targets:
        at_least = ("power_share", "count_share", "min_targets_found")
        crit = ", ".join(f"{k} {'>=' if k in at_least else '<='} {v:g}"
                         for k, v in dataclasses.asdict(tg).items() if v is not None)
        ch = budget.choose_settings(records, tg)
        print(f"  {crit}: " + (f"{label(ch.record)} ({ch.record['seconds']:.2f} s; "
                               f"{ch.n_meeting} settings meet it)" if ch.ok else ch.message))
    print(("" if ref_seconds is None else f"\nreference run: {ref_seconds:.1f} s; ")
          + f"wrote {out / 'tradeoff.csv'} and {out / 'tradeoff.png'}")
    return 0


def from_csv(path, args, wf, out) -> int:
    """Fronts, chart, table and choices again from a CSV this tool wrote."""
    try:
        records = budget.read_records(path)
        with open(path, newline="") as fh:
            header = next(csv.reader(fh))
        extra = header[header.index("scattering") + 1:header.index("synthesis")]
        for r in records:
            r.update(_extra=extra, _dr=wf.range_resolution, _dv=wf.velocity_resolution)
            for k in ("range_error_m", "velocity_error_mps"):
                r[k] = math.nan if r[k] == "" else r[k]
        if not records:
            raise ValueError("no rows")
        return finish(records, extra, args, wf, out)
    except (OSError, ValueError, KeyError, StopIteration) as exc:
        print(f"tradeoff.py: --from-csv {path}: not a tradeoff.py CSV ({exc!r})",
              file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
