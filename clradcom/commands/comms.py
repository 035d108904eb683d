"""The data link of RadCom: radar A's frame received as data by car D.

    clradcom comms scenes/street/street.toml --out out/comms
    clradcom comms --snapshot out/street/snapshot.npz --out out/comms

(``python tools/comms.py ...`` runs the same.)

A sends its OFDM frame (the frame of every command: the options --subcarriers, --symbols,
--subcarrier-spacing, --cyclic-prefix/--cp-samples, over the scene's [waveform], over the
paper's 24 GHz frame) with Gray-mapped random data (--modulation) and known pilots
(--pilots block|comb, --pilot-step); car D receives it through the traced A->D link
(one-way delays, gains and Dopplers with both cars' motion), exact time-domain synthesis
(ICI, ISI), with D's receiver timing (--timing-offset-us) and oscillator offset
(--cfo-hz), plus white noise at each Es/N0 of --snr-db and at the link's own SNR
(P_tx mean|H|² / kTBF of D's noise figure).  D synchronises on the cyclic prefix, estimates
the channel from the pilots, equalises (zero forcing) and decodes.  Written into --out:

  comms.csv          BER, SER, EVM per Es/N0, bit and symbol counts, AWGN and known-channel
                     theory, timing errors, worst frequency-offset error
  comms.png / .svg   BER and SER against Es/N0 beside the AWGN theory, EVM
  snapshot.npz       (only when tracing a scene) every link of the scene

Formulas, the pilot patterns and their overhead, sources: docs/comms.md.  Errors are one
line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from clradcom.commands.options import (
    add_scene_or_snapshot_arguments,
    add_waveform_arguments,
    check_exact_frame_memory,
    check_two_radars,
    command_parser,
    finite_float,
    float_in,
    list_of,
    noise_figure_db,
    non_negative_float,
    non_negative_int,
    parse_command,
    positive_float,
    positive_int,
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
from clradcom.files import save_figure, staged_folder, write_csv
from clradcom.radar.comms import (
    COMMS_MODULATIONS,
    CSV_COLUMNS,
    PilotPattern,
    comms_figure,
    csv_rows,
    link_snr_db,
    monte_carlo,
)
from clradcom.radar.interference import MAX_FREQUENCY_OFFSET
from clradcom.scene.reader import load_scene
from clradcom.trace import check_launch_memory

#: the names this tool writes into its output folder (the snapshot only when tracing)
OUTPUTS = ("comms.csv", "comms.png", "comms.svg")
#: Es/N0 values --snr-db accepts (dB): beyond them the noise power under- or overflows a
#: float64 (1e308 dB) long before it means anything; -100 to 200 dB spans every link
SNR_DB_RANGE = (-100.0, 200.0)


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    return command_parser(__doc__, add_arguments, prog)


def parse_args(argv, prog: str | None = None):
    return parse_command(build_parser(prog), argv, check_args)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``clradcom comms`` / tools/comms.py."""
    add_scene_or_snapshot_arguments(ap, "comms")
    ap.add_argument("--tx", default="A", help="the radar that sends (default A)")
    ap.add_argument("--rx", default="D", help="the radar that receives (default D)")
    ap.add_argument("--pilots", choices=("block", "comb"), default="block",
                    help="block: every --pilot-step-th symbol all pilots; comb: every "
                         "--pilot-step-th subcarrier of every symbol (default block)")
    ap.add_argument("--pilot-step", type=positive_int, default=8,
                    help="pilot spacing in symbols (block) or subcarriers (comb), default 8")
    ap.add_argument("--snr-db", type=list_of(float_in(*SNR_DB_RANGE), "Es/N0"),
                    default=[0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0],
                    help="mean Es/N0 values in dB, comma separated (default 0,2,...,20; "
                         f"each in [{SNR_DB_RANGE[0]:g}, {SNR_DB_RANGE[1]:g}])")
    ap.add_argument("--frames", type=positive_int, default=1,
                    help="frames per Es/N0, each with its own data (default 1)")
    ap.add_argument("--dd-passes", type=non_negative_int, default=0,
                    help="decision-directed re-estimation passes (default 0)")
    ap.add_argument("--timing-offset-us", type=non_negative_float, default=3.0,
                    help="when A's frame leaves, in D's capture, µs (default 3.0)")
    ap.add_argument("--cfo-hz", type=finite_float, default=2400.0,
                    help="D's oscillator offset from A's, Hz (default 2400 = 0.1 ppm at "
                         "24 GHz); with the Doppler within ±0.4 Δf")
    ap.add_argument("--seed", type=seed, default=0, help="seed of data and noise "
                    "(an integer >= 0, default 0)")
    ap.add_argument("--tx-power-w", type=positive_float, default=0.01,
                    help="with --snapshot: the sender's power for the link SNR (default 0.01)")
    ap.add_argument("--noise-figure-db", type=noise_figure_db, default=10.0,
                    help="with --snapshot: the receiver's noise figure (default 10 dB)")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_waveform_arguments(ap, modulations=COMMS_MODULATIONS,
                           modulation_help="data modulation, Gray mapped")


def check_args(ap: argparse.ArgumentParser, args) -> None:
    """What argparse alone cannot refuse: the scene or a snapshot, two different radars."""
    check_two_radars(ap, args, "--tx", "--rx")


def scene_radars(args, scene):
    """(sender's power, receiver's noise figure) from the scene, refused by scene key."""
    it, ir = scene_radar_indices(scene, args, "--tx", "--rx")
    if scene.radars[it].tx_power_w == 0:
        raise SceneError("the sending radar transmits nothing: there is no link to decode",
                         file=scene.source, key=f"radars[{it}].tx_power_w", value=0.0)
    return scene.radars[it].tx_power_w, scene_noise_figure(scene, ir, args.noise_figure_db)


def link_paths(snap, args, source):
    try:
        return snap.link(args.tx, args.rx).paths
    except KeyError as exc:
        raise SnapshotError(f"{exc.args[0]}; check --tx and --rx", file=source) from None


def check_run(args, wf) -> None:
    """The pilot step, the timing and carrier offsets, named by their options."""
    n, m = wf.n_subcarriers, wf.n_symbols
    limit = m if args.pilots == "block" else n
    if args.pilot_step >= limit:
        raise ArgumentError(f"must be below the frame's {limit} "
                            f"{'symbols' if args.pilots == 'block' else 'subcarriers'}",
                            argument="--pilot-step", value=args.pilot_step)
    if not args.timing_offset_us * 1e-6 < wf.symbol_duration:
        raise ArgumentError(f"must lie in [0, T_sym = {wf.symbol_duration * 1e6:.6g} µs)",
                            argument="--timing-offset-us", value=args.timing_offset_us)
    lim = MAX_FREQUENCY_OFFSET * wf.subcarrier_spacing_hz
    if abs(args.cfo_hz) > lim:
        raise ArgumentError(f"must stay within ±{MAX_FREQUENCY_OFFSET}·Δf = ±{lim:.6g} Hz: "
                            "the cyclic-prefix frequency estimate is ambiguous beyond",
                            argument="--cfo-hz", value=args.cfo_hz)


def main(argv=None, prog: str = "comms.py") -> int:
    args = parse_args(argv, prog)
    args.prog = prog
    return run_tool(prog, run, args)


def run(args) -> int:
    out = Path(args.out)
    t0 = time.perf_counter()
    if args.scene is not None:
        check_launch_memory(preset_settings(args), argument="--rays",
                            value=preset_settings(args).specular.rays)
        scene = load_scene(args.scene)
        p_tx, nf = scene_radars(args, scene)
        # the sender's frame; the receiver decodes with its own, so they must agree
        it, ir = scene_radar_indices(scene, args, "--tx", "--rx")
        wf, frame = run_waveform(scene.carrier_hz, args, scene=scene,
                                 modulations=COMMS_MODULATIONS, radar=it)
        if run_waveform(scene.carrier_hz, args, scene=scene, modulations=COMMS_MODULATIONS,
                        radar=ir)[0] != wf:
            spec, key = scene.radar_waveform(ir if scene.radars[ir].waveform is not None
                                             else it)
            raise SceneError("the sender's and the receiver's frames differ: the receiver "
                             "decodes with its own; give them one", file=scene.source,
                             key=key, value=spec.hash_params())
        sources, owned = scene.input_files, (*OUTPUTS, "snapshot.npz")
    else:
        snap = read_snapshot(args.snapshot)
        p_tx, nf = args.tx_power_w, args.noise_figure_db
        wf, frame = run_waveform(snap.carrier_hz, args, snapshot=args.snapshot,
                                 modulations=COMMS_MODULATIONS)
        sources, owned = [args.snapshot], OUTPUTS
        paths = link_paths(snap, args, args.snapshot)
    print(frame, flush=True)
    check_run(args, wf)
    check_exact_frame_memory(wf)
    pattern = PilotPattern.named(args.pilots, args.pilot_step)
    with staged_folder(out, inputs=sources, owned=owned) as stage:
        if args.scene is not None:
            snap = trace_into(stage, scene, preset_settings(args), args)
            paths = link_paths(snap, args, args.scene)
        if len(paths.gain) == 0:
            raise SnapshotError(f"the link {args.tx}->{args.rx} has no paths: D receives "
                                "nothing", file=args.scene or args.snapshot)
        snr_link = link_snr_db(paths.gain, paths.delay_s, paths.doppler_hz, wf, p_tx, nf)
        snrs = sorted(set(args.snr_db) | {round(snr_link, 2)})
        print(f"link {args.tx}->{args.rx}: {len(paths.gain)} paths, mean Es/N0 "
              f"{snr_link:.2f} dB (P_tx {p_tx:g} W, NF {nf:g} dB); pilots "
              f"{pattern.overhead(wf.n_subcarriers, wf.n_symbols):.2%} of the cells",
              flush=True)
        mc = monte_carlo(
            paths.gain, paths.delay_s, paths.doppler_hz, wf, snrs, modulation=wf.modulation,
            pattern=pattern, frames=args.frames, seed=args.seed,
            timing_offset_s=args.timing_offset_us * 1e-6, cfo_hz=args.cfo_hz,
            dd_passes=args.dd_passes,
            progress=lambda msg: print(f"[{time.perf_counter() - t0:6.1f} s] {msg} ...",
                                       flush=True))
        write_csv(stage / "comms.csv", csv_rows(mc), CSV_COLUMNS, inputs=sources)
        fig = comms_figure(mc, f"{args.tx} -> {args.rx} data link", snr_link)
        for ext in ("png", "svg"):
            save_figure(fig, stage / f"comms.{ext}", inputs=sources, dpi=120)
    print(f"\n  {'Es/N0 dB':>8} {'BER':>10} {'AWGN BER':>10} {'SER':>10} {'EVM dB':>7} "
          f"{'timing err':>10}")
    for row in mc.rows:
        mark = "  <- the link's own SNR" if row[0] == round(snr_link, 2) else ""
        print(f"  {row[0]:8.2f} {row[1]:10.3e} {row[8]:10.3e} {row[2]:10.3e} {row[3]:7.2f} "
              f"{row[13]:10d}{mark}")
    print(f"\n[{time.perf_counter() - t0:6.1f} s] wrote {out}/comms.csv, comms.png, comms.svg")
    return 0
