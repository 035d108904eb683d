"""Speed against accuracy: sweep the tracer's and the synthesis' knobs on one scene.

    clradcom tradeoff scenes/street/street.toml
    python tools/tradeoff.py scenes/street/street.toml      (the same)

For one radar's own echoes (the monostatic link) it traces every combination of

  --rays           rays per transmitter             (default 10000,100000)
  --reflections    most specular reflections        (default 1,3)
  --diffractions   most UTD edge diffractions       (default 0,1)
  --optics         metal objects: GO, PO or SBR-PO  (default pec,sbr)
  --scattering     diffuse tiles off/on             (default 0,1)
  --vary F=a,b     any other TraceSettings field, e.g. scattering.tile_size_m (nested
                   names, or the flat ones of docs/tradeoff.md: scattering_tile_size_m)

and synthesises every trace with each of these back ends (--synthesis, default
fast,fast+prune):

  fast       frequency-domain model (no ICI/ISI), NUFFT tolerance 1e-10
  fast-lp    the same at NUFFT tolerance 1e-5 (the precision knob the synthesis offers;
             tracer geometry is float32 in kernels and float64 on the host, no knob)
  exact      time-domain superposition with ICI/ISI
  each with "+prune": paths below the radar's noise floor dropped first (unless the weak
             paths of their range-Doppler cell add up above it)

The defaults are a small grid that takes minutes on a street; --full sweeps the large one
(rays 10000,100000,1000000; reflections 0,1,2,5; diffractions 0,1; optics none,pec,sbr;
scattering 0,1; synthesis fast,fast+prune,fast-lp+prune,exact+prune; exact reference
synthesis: hours on a street), each knob still set by its option when given. Once the
reference is measured the sweep's time is estimated and printed; a sweep whose estimate
exceeds --budget-s (default 300 s) is refused before it starts, and one that runs over
it on the way stops there loudly, with the settings measured so far.

It times each (time.perf_counter: trace + pruning + synthesis + radar processing), and
measures against a converged reference (the largest value of every knob, more rays,
--reference-synthesis (default fast; exact with --full), nothing pruned; its own
convergence is checked against half its rays):

  channel_nmse_db     NMSE of the frame's channel F = D_r/D against the reference's, dB
  image_error_db      that error's largest radar-image cell against the thermal noise in
                      it (< 0 dB: invisible to the radar); error_to_noise_db: its bound
  count_share         share of the reference's paths above the noise floor found (paths
                      matched by interaction sequence and faces); power_share: share of
                      their power
  range_error_m, velocity_error_mps, targets_found: CFAR detections of the moving objects
                      against the scene's ground truth (same symbols and noise every run)

Before the sweep the radar's noise floor bounds what is traced (clradcom.evaluation.budget):
reflection orders whose best case cannot reach it are capped, scattering triangles that
cannot reach it are reported, the tracer's scattering threshold is set from it
(--no-trace-prune: left alone), and "+prune" drops found paths below it. The report says
what was pruned. docs/tradeoff.md has the definitions and the street's front.

Writes to --out (default out/<scene>/tradeoff/): tradeoff.csv (one row per setting, the
Pareto flags included), tradeoff.png (run time against each accuracy measure, the Pareto
front marked), and prints a table and the cheapest setting for each accuracy target
(--target-nmse-db, --target-enr-db, --target-range-m/--target-velocity-mps). Every
target also asks for the moving objects the reference detects: the channel of a vehicle
radar is its own mounting and the road under it, which any setting traces, so an NMSE
target alone picks a setting that finds no car.
The sweep, the measures, the fronts, the CSV and the chart are clradcom.evaluation.tradeoff.

The output folder is built beside the old one and swapped in when the run is done (an
interrupted or failed run leaves the old one as it was; other files in it are kept).
While the sweep runs, the rows measured so far are kept in <out>.partial.csv beside the
folder (removed when the run finishes), so an interrupted sweep loses nothing.
--from-csv redraws from an earlier sweep's CSV into out/<scene>/tradeoff-from-csv/ by
default, never into the folder holding that CSV (an --out that would replace the CSV
is refused). Every option is checked before anything is traced, including the memory
the rays and the frame need (refused over the budget: half the machine's memory, or
CLRADCOM_MEMORY_BUDGET, e.g. "24G"). Errors are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from clradcom.commands.console import progress_bar
from clradcom.commands.options import (
    add_waveform_arguments,
    command_parser,
    finite_float,
    int_in,
    list_of,
    non_negative_float,
    non_negative_int,
    output_folder,
    positive_float,
    positive_int,
    run_tool,
    run_waveform,
    seed,
)
from clradcom.device.runtime import get_runtime
from clradcom.errors import ArgumentError, SceneError
from clradcom.evaluation import budget
from clradcom.evaluation import tradeoff as tr
from clradcom.evaluation.tradeoff import (
    BACKENDS,
    DEFAULT_SYNTHESIS,
    FULL_SYNTHESIS,
    SETTING_COLUMNS,
)
from clradcom.files import staged_folder
from clradcom.mechanisms.scattering import scattering_triangle_bounds
from clradcom.radar.pipeline import check_frame_memory
from clradcom.radar.synthesis import check_noise_figure
from clradcom.scene.reader import load_scene
from clradcom.trace import TraceSettings, check_launch_memory

#: the names this tool writes into its output folder (clradcom.files.staged_folder)
OUTPUTS = ("tradeoff.csv", "tradeoff.png")
OPTICS = ("none", "pec", "sbr")
#: the knobs of the default sweep and of --full (an option given on the command line wins)
DEFAULT_GRID = {"rays": [10_000, 100_000], "reflections": [1, 3], "diffractions": [0, 1],
                "optics": ["pec", "sbr"], "scattering": [False, True],
                "synthesis": DEFAULT_SYNTHESIS, "reference_synthesis": "fast"}
FULL_GRID = {"rays": [10_000, 100_000, 1_000_000], "reflections": [0, 1, 2, 5],
             "diffractions": [0, 1], "optics": ["none", "pec", "sbr"],
             "scattering": [False, True], "synthesis": FULL_SYNTHESIS,
             "reference_synthesis": "exact"}
#: default --budget-s: the longest sweep (estimated) run without asking
DEFAULT_BUDGET_S = 300.0


# ----------------------------------------------------------------------------------------
# argument parsing
# ----------------------------------------------------------------------------------------
def _bool(v: str) -> bool:
    if v.lower() in ("1", "true", "on", "yes"):
        return True
    if v.lower() in ("0", "false", "off", "no"):
        return False
    raise argparse.ArgumentTypeError(f"must be 0/1, true/false, on/off or yes/no, got {v!r}")


def _optics(v: str) -> str:
    if v not in OPTICS:
        raise argparse.ArgumentTypeError(f"must be one of {OPTICS}, got {v!r}")
    return v


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


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    return command_parser(__doc__, add_arguments, prog)


def parse_args(argv, prog: str | None = None):
    return build_parser(prog).parse_args(argv)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``clradcom tradeoff`` / tools/tradeoff.py."""
    ap.add_argument("scene", help="scene file (TOML)")
    ap.add_argument("--radar", default=None, help="radar (default: the first txrx one)")
    ap.add_argument("--out", type=output_folder, default=None,
                    help="output folder (default out/<scene>/tradeoff; with --from-csv "
                         "out/<scene>/tradeoff-from-csv)")
    ap.add_argument("--device", default=None, help="OpenCL device (see tools/trace.py)")
    ap.add_argument("--full", action="store_true",
                    help="the large grid (hours on a street; module docstring) for every "
                         "knob not given")
    ap.add_argument("--budget-s", type=positive_float, default=DEFAULT_BUDGET_S,
                    help="refuse a sweep estimated longer than this (seconds), and stop one "
                         "that runs over it (default %(default)s)")
    ap.add_argument("--rays", type=list_of(positive_int, "ray count"), default=None,
                    help="default 10000,100000 (--full: 10000,100000,1000000)")
    ap.add_argument("--reflections", type=list_of(int_in(0, 16), "reflection order"),
                    default=None, help="default 1,3 (--full: 0,1,2,5)")
    ap.add_argument("--diffractions", type=list_of(int_in(0, 3), "diffraction order"),
                    default=None, help="default 0,1")
    ap.add_argument("--optics", type=list_of(_optics, "optics mode"), default=None,
                    help="physical_optics values; the last is the reference's (default "
                         "pec,sbr; --full: none,pec,sbr)")
    ap.add_argument("--scattering", type=list_of(_bool, "scattering flag"), default=None,
                    help="default 0,1")
    ap.add_argument("--vary", type=_vary, action="append", default=[],
                    help="FIELD=v1,v2: sweep another TraceSettings field too (last value "
                         "is the reference's)")
    ap.add_argument("--synthesis", type=_synthesis, default=None,
                    help=f"back ends per trace (default {DEFAULT_SYNTHESIS}; --full: "
                         f"{FULL_SYNTHESIS})")
    ap.add_argument("--reference-synthesis", choices=sorted(BACKENDS), default=None,
                    help="synthesis of the reference (default fast; --full: exact)")
    ap.add_argument("--reference-margin-db", type=finite_float, default=None,
                    help="drop the reference's paths this far below the noise floor before "
                         "its synthesis (default: keep all; e.g. -20 keeps the exact "
                         "synthesis of a street affordable)")
    ap.add_argument("--reference-rays", type=positive_int, default=None,
                    help="rays of the reference (default 4 x the largest of --rays)")
    ap.add_argument("--no-trace-prune", action="store_true",
                    help="do not set the tracer's scattering threshold from the noise floor")
    ap.add_argument("--margin-db", type=finite_float, default=0.0,
                    help="noise floor margin: paths below floor + margin are pruned")
    ap.add_argument("--exact-max-paths", type=non_negative_int, default=None,
                    help="skip the exact back end for traces with more paths than this (its "
                         "cost grows with the paths; the reference always uses it)")
    ap.add_argument("--from-csv", default=None,
                    help="trace nothing: fronts, chart, table and choices from this CSV "
                         "(written to out/<scene>/tradeoff-from-csv unless --out is given; "
                         "an --out whose tradeoff.csv is this CSV is refused)")
    ap.add_argument("--seed", type=seed, default=0,
                    help="seed of the OFDM symbols (an integer >= 0; the noise uses seed + 1)")
    ap.add_argument("--target-nmse-db", type=list_of(finite_float, "target"),
                    default=[-10.0, -20.0, -30.0],
                    help="channel error targets (dB) to pick settings for")
    ap.add_argument("--target-enr-db", type=list_of(finite_float, "target"), default=[0.0],
                    help="radar-image error re noise targets (dB) to pick settings for")
    ap.add_argument("--target-range-m", type=non_negative_float, default=None,
                    help="detection target: range error (default: range resolution)")
    ap.add_argument("--target-velocity-mps", type=non_negative_float, default=None,
                    help="detection target: velocity error (default: velocity resolution)")
    ap.add_argument("-q", "--quiet", action="store_true",
                    help="no progress bar (it is shown only when stderr is a terminal)")
    add_waveform_arguments(ap)


# ----------------------------------------------------------------------------------------
# printing
# ----------------------------------------------------------------------------------------
def fmt(v, spec):
    return "   -" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


# ----------------------------------------------------------------------------------------
def main(argv=None, prog: str = "tradeoff.py") -> int:
    args = parse_args(argv, prog)
    args.prog = prog
    return run_tool(prog, run, args)


def frame_option(args, wf) -> tuple[str, object]:
    """The option(s) that set the frame's size, as the user typed them."""
    if args.subcarriers is not None and args.symbols is not None:
        return "--subcarriers x --symbols", f"{args.subcarriers} x {args.symbols}"
    if args.symbols is not None:
        return "--symbols", args.symbols
    if args.subcarriers is not None:
        return "--subcarriers", args.subcarriers
    return "frame", f"{wf.n_subcarriers} x {wf.n_symbols}"


def apply_grid(args) -> None:
    """Fill the knobs not given from the default grid, or --full's."""
    grid = FULL_GRID if args.full else DEFAULT_GRID
    for key, value in grid.items():
        if getattr(args, key) is None:
            setattr(args, key, _synthesis(value) if key == "synthesis" else
                    (list(value) if isinstance(value, list) else value))


def run(args) -> int:
    apply_grid(args)
    scene = load_scene(args.scene)
    names = [r.name for r in scene.radars]
    if args.radar is None:
        txrx = [i for i, r in enumerate(scene.radars) if r.role == "txrx"]
        if not txrx:
            raise SceneError("no radar with role 'txrx'", file=args.scene)
        radar_idx = txrx[0]
    elif args.radar in names:
        radar_idx = names.index(args.radar)
    else:
        raise ArgumentError(f"is not in the scene (radars: {names})", argument="--radar",
                            value=args.radar)
    radar = scene.radars[radar_idx]
    if radar.role != "txrx":
        raise ArgumentError(f"has role {radar.role!r}: the sweep needs a radar's own echoes, "
                            "so one that transmits and receives ('txrx')", argument="--radar",
                            value=radar.name)
    if radar.tx_power_w == 0:
        raise SceneError("the radar transmits nothing, so it has no echo to sweep; choose a "
                         "radar that transmits (--radar)", file=scene.source,
                         key=f"radars[{radar_idx}].tx_power_w", value=radar.tx_power_w)
    for name, values in args.vary:
        field = tr.settings_field(name)
        if field is None or field in tr.SETTING_FIELDS.values():
            raise ArgumentError(f"not a TraceSettings field other than {SETTING_COLUMNS} "
                                f"(fields: {tr.vary_field_names()})", argument="--vary",
                                value=name)
        for value in values:  # each value must make valid settings before anything runs
            try:
                TraceSettings().replace(**{field: value})
            except ArgumentError as exc:
                raise ArgumentError(str(exc), argument="--vary",
                                    value=f"{name}={value!r}") from None
    wf, frame = run_waveform(scene.carrier_hz, args, scene=scene, radar=radar_idx)
    print(frame, flush=True)
    nf_db = radar.noise_figure_db if radar.noise_figure_db is not None else 10.0
    try:
        check_noise_figure(nf_db)
    except ArgumentError as exc:
        raise SceneError(exc.reason, file=scene.source,
                         key=f"radars[{radar_idx}].noise_figure_db", value=nf_db) from None
    frame_arg, frame_value = frame_option(args, wf)
    exact = args.reference_synthesis == "exact" or any(b == "exact" for b, _ in args.synthesis)
    check_frame_memory(wf, "exact" if exact else "fast", argument=frame_arg,
                       value=frame_value, advice="choose fewer --subcarriers or --symbols")
    floor = budget.noise_floor(wf, radar.tx_power_w, nf_db, margin_db=args.margin_db)
    if args.from_csv:
        out = Path(args.out or Path("out") / scene.name / "tradeoff-from-csv")
        return from_csv(args.from_csv, args, wf, out)
    ref_rays = args.reference_rays or 4 * max(args.rays)
    check_launch_memory(TraceSettings().replace(specular__rays=ref_rays,
                                                specular__max_reflections=max(args.reflections)),
                        argument="--reference-rays" if args.reference_rays else "--rays",
                        value=args.reference_rays or args.rays,
                        advice="launch fewer rays (the reference launches --reference-rays, "
                               "by default 4 x the most of --rays)")
    out = Path(args.out or Path("out") / scene.name / "tradeoff")
    partial = out.parent / f"{out.name}.partial.csv"
    try:
        with staged_folder(out, inputs=scene.input_files, owned=OUTPUTS) as stage:
            runtime = get_runtime(args.device)
            code = sweep(args, scene, radar_idx, radar, wf, nf_db, floor, runtime, stage, out,
                         partial)
    except BaseException:
        if partial.exists():
            print(f"{getattr(args, 'prog', 'tradeoff.py')}: the rows measured so far are "
                  f"in {partial}", file=sys.stderr)
        raise
    if partial.exists():
        partial.unlink()
    return code


def sweep(args, scene, radar_idx, radar, wf, nf_db, floor, runtime, stage, out,
          partial) -> int:
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
    tri_ids, tri_best, tri_above = scattering_triangle_bounds(scene, radar, radar, floor.power)
    if len(tri_ids):
        print(f"scattering: {int((~tri_above).sum())} of {len(tri_ids)} scattering triangles "
              f"cannot reach the floor (best {10 * math.log10(tri_best.max()):.1f} dB)")
        if not tri_above.any() and True in args.scattering:
            print("  -> no scattering triangle can reach the floor: scattering not traced")
            args.scattering = [False]

    # --- reference ----------------------------------------------------------------------
    ctx = tr.sweep_context(scene, radar_idx, wf, floor, nf_db, args.seed)
    knobs = (args.rays, args.reflections, args.diffractions, args.optics, args.scattering,
             args.vary)
    ref_point = tr.reference_point(*knobs, order_cap, args.reference_rays)
    print(f"reference: {ref_point}, {args.reference_synthesis} synthesis, nothing pruned")
    ref_paths, ref_trace_s = tr.trace_link(scene, ref_point, runtime, radar_idx)
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
    ref_rec, F_ref, _ = tr.measure(ctx, ref_paths, args.reference_synthesis, False)
    ref_seconds = ref_trace_s + ref_rec["synth_s"] + ref_rec["process_s"]
    print(f"  {ref_paths.n_paths} paths, {ref_seconds:.1f} s; targets found "
          f"{ref_rec['targets_found']}/{ref_rec['targets']}")
    # convergence in rays, with the fast synthesis on both sides (the rays' share only)
    conv = tr.reference_convergence(ctx, ref_point, runtime, ref_paths, F_ref,
                                    args.reference_synthesis, ref_floor)
    print(f"  convergence: half the rays ({conv.n_paths} paths) differ by "
          f"{conv.channel_nmse_db:.1f} dB NMSE, {conv.error_to_noise_db:.1f} dB "
          "error-to-noise")
    ctx.ref_paths, ctx.F_ref = ref_paths, F_ref
    _, ref_prune = budget.prune_paths(ref_paths, floor.power, wf)
    print(f"  power bound on the reference: {ref_prune.describe()}")
    for k, n, above in tr.reflections_by_order(ref_paths, floor.power):
        print(f"    order {k} reflections{' (and PO facets)' if k == 1 else ''}: "
              f"{n} paths, strongest {above:.1f} dB above the floor")

    # --- sweep --------------------------------------------------------------------------
    extra = [n for n, _ in args.vary]
    trace_thr = None
    if (not args.no_trace_prune and len(tri_ids) and tri_above.any()
            and all(tr.settings_field(n) != "scattering__threshold_db" for n in extra)):
        # the strongest tile is at most the largest triangle bound: a threshold this far
        # below it never drops a tile above the floor
        trace_thr = -budget.relative_threshold_db(floor.power, float(tri_best.max()))
        extra.append("scattering_threshold_db")
        print(f"scattering tiles more than {-trace_thr:.1f} dB below the link's strongest "
              "are not emitted (floor against the best tile bound; the tracer's default "
              f"is {TraceSettings().scattering.threshold_db:g} dB)")
    # triangles whose tiles cannot reach the floor are never traced
    points = tr.sweep_points(*knobs, order_cap, trace_thr,
                             None if args.no_trace_prune else floor.power)
    n_runs = len(points) * len(args.synthesis)
    estimate = tr.estimate_sweep_seconds(points, len(args.synthesis), ref_point["rays"],
                                         ref_trace_s,
                                         ref_rec["synth_s"] + ref_rec["process_s"])
    print(f"sweep: {len(points)} traces x {len(args.synthesis)} back ends = {n_runs} settings; "
          f"estimated {estimate:.0f} s (from the reference's {ref_seconds:.1f} s), budget "
          f"{args.budget_s:g} s (--budget-s)", flush=True)
    if estimate > args.budget_s:
        raise ArgumentError(f"is below the sweep's estimated {estimate:.0f} s ({len(points)} "
                            "traces): raise it, or sweep fewer values (the defaults without "
                            "--full take minutes)", argument="--budget-s", value=args.budget_s)
    records, t_start, skipped_exact = [], time.perf_counter(), 0
    bar = progress_bar(len(points), "sweep", quiet=getattr(args, "quiet", False),
                       unit="trace")
    for step in tr.run_sweep(ctx, points, args.synthesis, runtime, extra=extra,
                             reference_s=ref_seconds,
                             reference_found=ref_rec["targets_found"],
                             exact_max_paths=args.exact_max_paths):
        bar.update(1)
        if step.error is not None:
            bar.write(f"  skipped {step.point}: {step.error}")
            continue
        records.extend(step.records)
        skipped_exact += step.skipped_exact
        # the rows so far, beside the folder: an interrupted sweep loses nothing
        tr.write_tradeoff_csv(records, extra, partial)
        latest = tr.setting_label(records[-1]).rsplit(" ", 1)[0] if records else str(step.point)
        elapsed = time.perf_counter() - t_start
        bar.write(f"  [{elapsed:6.1f} s] {step.index + 1}/{len(points)} "
                  f"{latest}: {step.n_paths} paths, trace {step.trace_s:.2f} s")
        projected = elapsed / (step.index + 1) * len(points)
        if projected > args.budget_s and step.index + 1 < len(points):
            bar.write(f"  STOPPED after {step.index + 1} of {len(points)} traces: at this pace "
                      f"the sweep takes {projected:.0f} s, over --budget-s {args.budget_s:g}; "
                      "the choices below are among the settings measured so far")
            break
    bar.close()
    if skipped_exact:
        print(f"  exact synthesis skipped for {skipped_exact} traces of more than "
              f"{args.exact_max_paths} paths (--exact-max-paths)")
    if not records:
        raise ArgumentError("every setting of the sweep failed (see the lines above)",
                            argument="scene", value=args.scene)
    return finish(records, extra, args, wf, stage, out)


def finish(records, extra, args, wf, stage, out, inputs=()) -> int:
    """Pareto flags, CSV, chart (into the staging folder), table and the cheapest setting
    per target."""
    tr.mark_pareto(records)
    tr.write_tradeoff_csv(records, extra, stage / "tradeoff.csv", inputs=inputs)
    ref_seconds = tr.reference_seconds(records)
    tr.plot_tradeoff(records, ref_seconds, stage / "tradeoff.png", inputs=inputs)
    print(f"\n{'setting':<48} {'s':>6} {'paths':>6} {'pruned':>6} {'NMSE':>7} {'image':>7} "
          f"{'count':>6} {'found':>5} {'dR m':>5} {'dv m/s':>6}  front")
    for r in sorted(records, key=lambda r: r["seconds"]):
        pruned = r["paths_traced"] - r["paths_used"]
        print(f"{tr.setting_label(r):<48} {r['seconds']:6.2f} {r['paths_traced']:6d} {pruned:6d} "
              f"{fmt(r['channel_nmse_db'], '7.1f')} {fmt(r['image_error_db'], '7.1f')} "
              f"{r['count_share']:6.3f} {r['targets_found']:>2}/{r['targets']:<2} "
              f"{fmt(r['range_error_m'], '5.2f')} {fmt(r['velocity_error_mps'], '6.2f')}  "
              f"{'*' if r['pareto_all'] else ''}{'C' if r['pareto_channel'] else ''}"
              f"{'I' if r['pareto_image'] else ''}{'P' if r['pareto_completeness'] else ''}"
              f"{'D' if r['pareto_detection'] else ''}")
    n_pruned = sum(1 for r in records if r["prune"])
    if n_pruned:
        print(f"\npruned below the floor over the {n_pruned} '+prune' runs: "
              + ", ".join(f"{v} {k}" for k, v in tr.pruned_totals(records).items()))
    print("\ncheapest setting per accuracy target (clradcom.evaluation.budget.choose_settings):")
    targets = tr.accuracy_targets(records, wf, args.target_nmse_db, args.target_enr_db,
                                  args.target_range_m, args.target_velocity_mps)
    for tg in targets:
        ch = budget.choose_settings(records, tg)
        print(f"  {tr.describe_target(tg)}: "
              + (f"{tr.setting_label(ch.record)} ({ch.record['seconds']:.2f} s; "
                 f"{ch.n_meeting} settings meet it)" if ch.ok else ch.message))
    print(("" if ref_seconds is None else f"\nreference run: {ref_seconds:.1f} s; ")
          + f"wrote {out / 'tradeoff.csv'} and {out / 'tradeoff.png'}")
    return 0


def from_csv(path, args, wf, out) -> int:
    """Fronts, chart, table and choices again from a CSV this tool wrote, into ``out``
    (never over the CSV itself)."""
    try:
        records, extra = tr.read_tradeoff_csv(path, wf)
    except ArgumentError as exc:
        raise ArgumentError(exc.reason, argument="--from-csv", value=path) from None
    try:
        with staged_folder(out, inputs=[path], owned=OUTPUTS) as stage:
            return finish(records, extra, args, wf, stage, out, inputs=[path])
    except ArgumentError as exc:
        if exc.argument != "output":
            raise
        raise ArgumentError(f"holds the --from-csv file {path}, which this run would "
                            "replace; choose another --out", argument="--out",
                            value=str(out)) from None

