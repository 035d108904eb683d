"""Two radars on one street: what radar D does to radar A's image, and how A removes it.

    clradcom interference scenes/street/street.toml --out out/interference
    clradcom interference --snapshot out/street/snapshot.npz --out out/interference

(``python tools/interference.py ...`` runs the same.)

The paper's Fig. 4 (A's radar image with car D's radar as interferer) and Fig. 5 (after
cancellation).  Both radars send the paper's OFDM frame (24 GHz, N = 1024, M = 256, QPSK)
with their own random data.  A receives its own echoes (link A->A) plus D's signal
through the one-way link D->A, shifted by D's symbol timing offset (--timing-offset-us,
beyond the cyclic prefix by default, so it is synthesised exactly in the time domain)
and D's carrier offset (--cfo-hz), plus thermal noise.  Four images of A, same noise:

  without D    A alone
  with D       D's data turns into a white floor; a target stands NM x input SIR over it
  genie        D removed with its true data and channel (the upper bound)
  realistic    D removed by A alone: sync to D from its cyclic prefix, decide D's symbols
               blind, fit D's channel, rebuild D's signal, subtract (docs/interference.md)

Printed: the floor rise measured against the prediction from the D->A paths, the floors
after cancellation, the realistic receiver's channel error (NMSE) and symbol-error rate
and the residual they predict, and which detections of the interference-free image are
found again.  Written into --out:

  interference.png / .svg     the four images side by side, one colour scale
  interference_summary.csv    the numbers above
  snapshot.npz                (only when tracing a scene) every link of the scene

With a scene the links are traced first, with the physics of --preset (default "paper",
as clradcom trace; about as long); with
--snapshot the existing snapshot's links are used and the noise comes from
--tx-power-w / --noise-figure-db.

A radar may carry its own waveform ([radars.waveform], OFDM or FMCW). A pair with an
FMCW radar (FMCW or OFDM into FMCW, FMCW into OFDM; scenes/street/street_fmcw_ofdm.toml)
runs instead the interferer's signal through the traced link into the victim's own
frame, with --timing-offset-us the interferer's frame start after the victim's and
--cfo-hz / --phase-deg its carrier offset and phase: the floor rise against its closed
form through the link, for two FMCW radars the burst length (unequal slopes) or the
ghost's range (equal ones), and one mitigation (FMCW victim: burst repair; OFDM victim:
the crossed symbols bridged along slow time). Written: interference.png / .svg (the
victim without, with the interferer, after mitigation) and interference_summary.csv
(docs/interference.md §6). Two OFDM radars must share one frame.

Everything is checked before anything is traced: the options, the radars' names, their
transmit powers (a radar transmitting nothing, 0 W, has no echoes to image or no
interference to cause: refused) and noise figure (>= 0 dB), the waveform (--subcarriers a
multiple of 8, so that the cyclic prefix is a whole number of samples), D's timing and
carrier offsets, and the memory the rays and the frames need (refused over the budget:
half the machine's memory, or CLRADCOM_MEMORY_BUDGET, e.g. "24G"). The output folder is
built beside the old one and swapped in when the run is done (an interrupted or failed
run leaves the old one as it was; other files in it are kept; a traced scene whose radar
run fails after all, e.g. --cfo-hz with the D->A Doppler beyond ±0.4 Δf, keeps the
traced snapshot.npz and nothing else). Errors are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from clradcom.commands.console import progress_bar, stage_steps
from clradcom.commands.options import (
    add_scene_or_snapshot_arguments,
    add_waveform_arguments,
    check_exact_frame_memory,
    check_two_radars,
    command_parser,
    finite_float,
    noise_figure_db,
    non_negative_float,
    parse_command,
    positive_float,
    preset_settings,
    read_snapshot,
    run_tool,
    run_waveform,
    scene_noise_figure,
    scene_radar_indices,
    seed,
    trace_into,
)
from clradcom.errors import ArgumentError, SceneError, SnapshotError
from clradcom.files import staged_folder
from clradcom.radar.fmcw import FmcwWaveform
from clradcom.radar.interference import (
    INTERFERENCE_STAGES,
    MAX_FREQUENCY_OFFSET,
    two_radar_run,
)
from clradcom.radar.mixed_interference import MIXED_IMAGES, MIXED_STAGES, mixed_pair_run
from clradcom.radar.pipeline import check_frame_memory
from clradcom.radar.plots import save_interference_images, save_side_by_side
from clradcom.radar.report import (
    INTERFERENCE_IMAGES,
    INTERFERENCE_TITLES,
    display_range_db,
    interference_detections,
    interference_summary,
    mixed_summary,
    recovered_detections,
    sorted_detections_line,
    write_table,
)
from clradcom.radar.waveform import Waveform
from clradcom.scene.reader import load_scene
from clradcom.trace import check_launch_memory

#: the relative speeds a mixed pair's images show, m/s (the street's cars: within ±30)
MIXED_VELOCITY_SHOWN = 50.0
#: the names this tool writes into its output folder (clradcom.files.staged_folder); the
#: snapshot only when it traces a scene
OUTPUTS = ("interference.png", "interference.svg", "interference_summary.csv")


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    return command_parser(__doc__, add_arguments, prog)


def parse_args(argv, prog: str | None = None):
    return parse_command(build_parser(prog), argv, check_args)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``clradcom interference`` / tools/interference.py."""
    add_scene_or_snapshot_arguments(ap, "interference")
    ap.add_argument("--victim", default="A", help="the radar whose image is shown (default A)")
    ap.add_argument("--interferer", default="D", help="the interfering radar (default D)")
    ap.add_argument("--timing-offset-us", type=non_negative_float, default=4.2,
                    help="D's symbol boundaries after A's, in µs, in [0, T_sym = 12.375 µs) "
                         "(default 4.2: far beyond the 1.375 µs cyclic prefix)")
    ap.add_argument("--cfo-hz", type=finite_float, default=2400.0,
                    help="D's carrier offset from A's in Hz (default 2400 = 0.1 ppm at "
                         "24 GHz); with the Doppler it must stay within ±0.4 Δf")
    ap.add_argument("--phase-deg", type=finite_float, default=37.0,
                    help="D's oscillator phase relative to A's (default 37)")
    ap.add_argument("--own-synthesis", choices=("fast", "exact"), default="fast",
                    help="A's own echoes: fast (default) = those within 40 dB of the "
                         "strongest exactly, the rest by the frequency-domain model (seconds); "
                         "exact = all in the time domain (many minutes for the street). "
                         "D's signal is always synthesised exactly")
    ap.add_argument("--seed", type=seed, default=0, help="seed of A's data, D's data and "
                    "the noise (an integer >= 0, default 0)")
    ap.add_argument("--tx-power-w", type=positive_float, default=0.01,
                    help="with --snapshot: both radars' transmit power (default 0.01 W)")
    ap.add_argument("--noise-figure-db", type=noise_figure_db, default=10.0,
                    help="with --snapshot: A's noise figure (>= 0 dB, default 10 dB)")
    ap.add_argument("--range-max", type=positive_float, default=60.0,
                    help="range shown in the pictures, m (default 60)")
    ap.add_argument("-q", "--quiet", action="store_true",
                    help="no progress bar (it is shown only when stderr is a terminal)")
    add_waveform_arguments(ap)


def check_args(ap: argparse.ArgumentParser, args) -> None:
    """What argparse alone cannot refuse: the scene or a snapshot, two different radars."""
    check_two_radars(ap, args, "--victim", "--interferer")


def scene_radars(args, scene):
    """(victim's power, interferer's power, victim's noise figure) from the scene, each
    refused by its scene key where the run could not use it."""
    iv, id_ = scene_radar_indices(scene, args, "--victim", "--interferer")
    va, vd = scene.radars[iv], scene.radars[id_]
    if va.tx_power_w == 0:
        raise SceneError("the victim radar transmits nothing, so it has no echoes to image",
                         file=scene.source, key=f"radars[{iv}].tx_power_w", value=0.0)
    if vd.tx_power_w == 0:
        raise SceneError("the interfering radar transmits nothing, so there is no "
                         "interference to show", file=scene.source,
                         key=f"radars[{id_}].tx_power_w", value=0.0)
    return va.tx_power_w, vd.tx_power_w, scene_noise_figure(scene, iv, args.noise_figure_db)


def check_offsets(args, wf) -> None:
    """D's timing offset within a symbol and carrier offset within the cyclic-prefix
    estimate's range, named by their options."""
    t_sym_us = wf.symbol_duration * 1e6
    if not args.timing_offset_us < t_sym_us:
        raise ArgumentError(f"must lie in [0, T_sym = {t_sym_us:.6g} µs): a whole symbol more "
                            "only changes which random symbols fall into A's frame",
                            argument="--timing-offset-us", value=args.timing_offset_us)
    limit = MAX_FREQUENCY_OFFSET * wf.subcarrier_spacing_hz
    if abs(args.cfo_hz) > limit:
        raise ArgumentError(f"must stay within ±{MAX_FREQUENCY_OFFSET}·Δf = ±{limit:.6g} Hz "
                            "(with the D->A Doppler): the cyclic-prefix frequency estimate is "
                            "ambiguous beyond", argument="--cfo-hz", value=args.cfo_hz)


def pair_waveforms(scene, args):
    """(the victim's frame, the interferer's, the lines stating them): each radar's own
    (its ``[radars.waveform]``, else the scene's ``[waveform]``), OFDM or FMCW. Two OFDM
    radars must share one frame (the victim decodes the interferer with its own):
    refused by the interferer's table otherwise."""
    iv, id_ = scene_radar_indices(scene, args, "--victim", "--interferer")
    victim, line_v = run_waveform(scene.carrier_hz, args, scene=scene, fmcw=True, radar=iv)
    interferer, line_i = run_waveform(scene.carrier_hz, args, scene=scene, fmcw=True,
                                      radar=id_)
    if isinstance(victim, Waveform) and isinstance(interferer, Waveform):
        if victim != interferer:
            spec, key = scene.radar_waveform(
                id_ if scene.radars[id_].waveform is not None else iv)
            raise SceneError("two OFDM radars with different frames: the victim decodes "
                             "and cancels the interferer with its own frame; give them one",
                             file=scene.source, key=key, value=spec.hash_params())
        return victim, interferer, [line_v]
    names = (scene.radars[iv].name, scene.radars[id_].name)
    return victim, interferer, [f"victim {names[0]}: {line_v}",
                                f"interferer {names[1]}: {line_i}"]


def run_mixed(args, scene, victim, interferer, lines, powers, t0) -> int:
    """A pair with an FMCW radar (docs/interference.md §6): the victim's own echoes and
    the interferer's signal through the traced link, the closed forms, the mitigation."""
    p_v, p_i, nf = powers
    for line in lines:
        print(line, flush=True)
    print("  the interferer's frame starts --timing-offset-us after the victim's; "
          "--cfo-hz and --phase-deg offset its carrier and phase", flush=True)
    check_frame_memory(victim, args.own_synthesis)
    out = Path(args.out)
    with staged_folder(out, inputs=scene.input_files,
                       owned=(*OUTPUTS, "snapshot.npz")) as stage:
        snap = trace_into(stage, scene, preset_settings(args), args)
        own, dl = link_paths(snap, args, args.scene)
        with progress_bar(len(MIXED_STAGES), "interference", unit="stage",
                          quiet=getattr(args, "quiet", False)) as bar:
            res = mixed_pair_run(own, dl, victim, interferer, tx_power_w=p_v,
                                 interferer_tx_power_w=p_i, noise_figure_db=nf,
                                 start_offset_s=args.timing_offset_us * 1e-6,
                                 cfo_hz=args.cfo_hz, phase_rad=math.radians(args.phase_deg),
                                 seed=args.seed, method=args.own_synthesis,
                                 progress=stage_steps(bar, t0))
        titles = {"clean": f"{args.victim} without {args.interferer}",
                  "interfered": f"{args.victim} with {args.interferer} "
                                f"({res.interferer_kind.upper()}) interfering",
                  "mitigated": f"{args.victim} after mitigation"}
        dets = {k: res.results[k].detections for k in MIXED_IMAGES}
        save_side_by_side({titles[k]: res.results[k].image for k in MIXED_IMAGES},
                          {titles[k]: dets[k] for k in MIXED_IMAGES}, stage / "interference",
                          range_max_m=args.range_max,
                          velocity_max_mps=min(victim.max_velocity, MIXED_VELOCITY_SHOWN),
                          # down to the clean image's floor: the interferer's floor shows
                          dynamic_range_db=display_range_db(res.results["clean"].image),
                          inputs=scene.input_files)
        rows = mixed_summary(res)
        print(f"\n  {res.victim_kind.upper()} victim {args.victim}, "
              f"{res.interferer_kind.upper()} interferer {args.interferer}; mitigation: "
              f"{res.mitigation}")
        _print_rows(rows)
        write_table(stage / "interference_summary.csv", rows, ["quantity", "value"])
    _print_found(dets, {k: res.results[k] for k in MIXED_IMAGES}, titles, victim)
    print(f"\n[{time.perf_counter() - t0:6.1f} s] wrote {out}/interference.png, .svg, "
          "interference_summary.csv")
    return 0


def _print_rows(rows) -> None:
    for name, val in rows:
        if isinstance(val, int):
            print(f"  {name:<68} {val:10d}")
        elif 0 < abs(val) < 1e-2:
            print(f"  {name:<68} {val:10.2e}")
        else:
            print(f"  {name:<68} {val:10.3f}")


def _print_found(dets, results, titles, wf) -> None:
    """Which detections of the interference-free image each other image finds again."""
    keys = list(dets)
    ref = dets[keys[0]]
    print("\n  detections " + "; ".join(f"{k}: {len(dets[k])}" for k in keys))
    for k in keys:
        line = sorted_detections_line(results[k])
        if line:
            print(f"  {titles[k]}: {line}")
    found = {k: recovered_detections(ref, dets[k], wf) for k in keys[1:]}
    print(f"  {'range m':>8} {'v m/s':>7} {'SNR dB':>7}   "
          + "  ".join(f"{k:>10}" for k in keys[1:]))
    for i, d in enumerate(ref):
        marks = "  ".join(f"{'yes' if found[k][i] else 'NO':>10}" for k in keys[1:])
        print(f"  {d['range_m']:8.2f} {d['velocity_mps']:7.2f} {d['snr_db']:7.1f}   {marks}")
    for k in keys[1:]:
        print(f"  {k}: {sum(found[k])} of {len(ref)} interference-free detections found")


def link_paths(snap, args, source):
    """A's own echoes and D's signal at A from the snapshot, a missing link named."""
    try:
        return (snap.link(args.victim, args.victim).paths,
                snap.link(args.interferer, args.victim).paths)
    except KeyError as exc:
        raise SnapshotError(f"{exc.args[0]}; check --victim and --interferer",
                            file=source) from None


def main(argv=None, prog: str = "interference.py") -> int:
    args = parse_args(argv, prog)
    args.prog = prog
    return run_tool(prog, run, args)


def run(args) -> int:
    out = Path(args.out)
    t0 = time.perf_counter()
    # everything the run will refuse, before it traces
    if args.scene is not None:
        check_launch_memory(preset_settings(args), argument="--rays",
                            value=preset_settings(args).specular.rays)
        scene = load_scene(args.scene)
        p_a, p_d, nf = scene_radars(args, scene)
        victim, interferer, lines = pair_waveforms(scene, args)
        if isinstance(victim, FmcwWaveform) or isinstance(interferer, FmcwWaveform):
            return run_mixed(args, scene, victim, interferer, lines, (p_a, p_d, nf), t0)
        wf, frame = victim, lines[0]
        sources, owned = scene.input_files, (*OUTPUTS, "snapshot.npz")
    else:
        snap = read_snapshot(args.snapshot)
        p_a = p_d = args.tx_power_w
        nf = args.noise_figure_db
        wf, frame = run_waveform(snap.carrier_hz, args, snapshot=args.snapshot)
        sources, owned = [args.snapshot], OUTPUTS
        own, dl = link_paths(snap, args, args.snapshot)
    print(frame, flush=True)
    check_offsets(args, wf)
    check_exact_frame_memory(wf)
    with staged_folder(out, inputs=sources, owned=owned) as stage:
        if args.scene is not None:
            snap = trace_into(stage, scene, preset_settings(args), args)
            own, dl = link_paths(snap, args, args.scene)
        try:
            with progress_bar(len(INTERFERENCE_STAGES), "interference", unit="stage",
                              quiet=getattr(args, "quiet", False)) as bar:
                res = two_radar_run(
                    own, dl, wf, tx_power_w=p_a, interferer_tx_power_w=p_d,
                    noise_figure_db=nf, timing_offset_s=args.timing_offset_us * 1e-6,
                    cfo_hz=args.cfo_hz, phase_rad=math.radians(args.phase_deg),
                    seed=args.seed, own_synthesis=args.own_synthesis,
                    progress=stage_steps(bar, t0),
                    detail=lambda text: bar.set_postfix_str(text, refresh=True))
        except ValueError as exc:  # e.g. --cfo-hz with the D->A Doppler beyond the limit
            if args.scene is None:
                if isinstance(exc, ArgumentError):
                    raise
                raise ArgumentError(str(exc)) from None
            # the trace is kept: the folder holds this run's snapshot and nothing else
            failure = exc
        else:
            failure = None
            dets = interference_detections(res)
            save_interference_images(res.images, stage / "interference", dets,
                                     res.floors["clean"], args.range_max)
            rows = interference_summary(res, wf)
            print()
            _print_rows(rows)
            write_table(stage / "interference_summary.csv", rows, ["quantity", "value"])
    if failure is not None:
        print(f"{getattr(args, 'prog', 'interference.py')}: {failure}; the traced links "
              "are kept in "
              f"{out / 'snapshot.npz'} (rerun with --snapshot)", file=sys.stderr)
        return 2
    ref = dets["clean"]
    print(f"\n  detections without D: {len(ref)}; with D: {len(dets['interfered'])}; "
          f"genie: {len(dets['genie'])}; realistic: {len(dets['realistic'])}")
    for k in INTERFERENCE_IMAGES:
        line = sorted_detections_line(res.results[k])
        if line:
            print(f"  {INTERFERENCE_TITLES[k]}: {line}")
    found = {k: recovered_detections(ref, dets[k], wf) for k in INTERFERENCE_IMAGES[1:]}
    print(f"  {'range m':>8} {'v m/s':>7} {'SNR dB':>7}   with D  genie  realistic")
    for i, d in enumerate(ref):
        marks = "  ".join(f"{'yes' if found[k][i] else 'NO':>6}" for k in INTERFERENCE_IMAGES[1:])
        print(f"  {d['range_m']:8.2f} {d['velocity_mps']:7.2f} {d['snr_db']:7.1f}   {marks}")
    for k in INTERFERENCE_IMAGES[1:]:
        print(f"  {k}: {sum(found[k])} of {len(ref)} interference-free detections found")
    print(f"\n[{time.perf_counter() - t0:6.1f} s] wrote {out}/interference.png, .svg, "
          "interference_summary.csv")
    return 0

