"""clradcom compare-waveforms SNAPSHOT --scene SCENE --fmcw FMCW.toml: the OFDM RadCom radar
and an FMCW chirp-sequence radar on the same car and the same traced paths.

The OFDM frame is the scene's (its ``[waveform]``, the options, the paper's Table I), the
FMCW one the ``[waveform] kind = "fmcw"`` table of ``--fmcw`` (docs/scene-format.md),
both at the scene's carrier. Every radar's own echoes in the snapshot go through both
radar chains (pipeline.radar_chain: same paths, same power and noise figure), and the
command prints, per radar and waveform, the resolutions and unambiguous limits, the
Cramér-Rao bound of range and velocity at 10 dB SNR per cell, the detections against
the moving objects' truth, and the data rate that only the OFDM frame carries; it writes
both images side by side (``<radar>_compare.png``/``.svg``) and a table
(``<radar>_compare.csv``). docs/fmcw.md §6.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from clradcom.commands.options import (
    add_frame_arguments,
    add_waveform_arguments,
    check_snapshot_scene,
    fmcw_run_waveform,
    output_folder,
    radar_waveforms,
    read_snapshot,
)
from clradcom.commands.radar import monostatic_links
from clradcom.commands.trace import Stopwatch, radar_noise
from clradcom.errors import SceneError
from clradcom.files import staged_folder
from clradcom.radar.estimation import cramer_rao_bound
from clradcom.radar.fmcw import FmcwWaveform, fmcw_cramer_rao_bound
from clradcom.radar.pipeline import check_frame_memory, radar_chain
from clradcom.radar.plots import save_side_by_side
from clradcom.radar.report import match_tolerances, moving_objects, write_table
from clradcom.radar.truth import detection_truth, match_truth
from clradcom.scene.read_waveform import load_waveform_table
from clradcom.scene.reader import load_scene
from clradcom.scene.records import FmcwSpec

COMPARE_OUTPUTS = ("*_compare.png", "*_compare.svg", "*_compare.csv")
COMPARE_COLUMNS = ("waveform", "object", "range_set_m", "v_set_mps", "range_det_m",
                   "v_det_mps", "range_error_m", "v_error_mps")
#: the SNR per cell the bounds are quoted at
CRB_SNR_DB = 10.0


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("snapshot", help="a snapshot.npz written by clradcom trace")
    ap.add_argument("--scene", required=True, help="the scene file (TOML) it was traced from")
    ap.add_argument("--fmcw", required=True, metavar="TOML",
                    help='a file holding the FMCW radar\'s [waveform] table (kind = "fmcw")')
    ap.add_argument("--out", type=output_folder, default=None,
                    help="output folder (default: the snapshot's folder)")
    add_frame_arguments(ap)
    add_waveform_arguments(ap)


def waveform_rows(ofdm, fmcw) -> list[tuple[str, str, str]]:
    """(figure, OFDM, FMCW) text rows: resolutions, limits, bounds, data rate."""
    crb_o = cramer_rao_bound(ofdm, 10 ** (CRB_SNR_DB / 10))
    crb_f = fmcw_cramer_rao_bound(fmcw, 10 ** (CRB_SNR_DB / 10))
    bits = math.log2(len_constellation(ofdm.modulation))
    rate = ofdm.n_subcarriers * ofdm.n_symbols * bits / ofdm.frame_duration
    return [
        ("range resolution [m]", f"{ofdm.range_resolution:.4g}", f"{fmcw.range_resolution:.4g}"),
        ("unambiguous range [m]", f"{ofdm.max_range:.4g}", f"{fmcw.max_range:.4g}"),
        ("velocity resolution [m/s]", f"{ofdm.velocity_resolution:.4g}",
         f"{fmcw.velocity_resolution:.4g}"),
        ("unambiguous velocity [m/s]", f"±{ofdm.max_velocity:.4g}",
         f"±{fmcw.max_velocity:.4g}"),
        ("frame [ms]", f"{ofdm.frame_duration * 1e3:.4g}", f"{fmcw.frame_duration * 1e3:.4g}"),
        (f"CRB range at {CRB_SNR_DB:g} dB/cell [mm]", f"{float(crb_o.range_m) * 1e3:.3g}",
         f"{float(crb_f.range_m) * 1e3:.3g}"),
        (f"CRB velocity at {CRB_SNR_DB:g} dB/cell [mm/s]",
         f"{float(crb_o.velocity_mps) * 1e3:.3g}", f"{float(crb_f.velocity_mps) * 1e3:.3g}"),
        ("data carried [Mbit/s]", f"{rate / 1e6:.4g} ({ofdm.modulation})", "none"),
    ]


def len_constellation(modulation: str) -> int:
    """Points of a modulation's constellation (qpsk 4, 16qam 16, ...)."""
    digits = "".join(ch for ch in modulation if ch.isdigit())
    return {"bpsk": 2, "qpsk": 4}.get(modulation, int(digits) if digits else 0)


def run(args) -> int:
    sw = Stopwatch()
    scene = load_scene(args.scene)
    if isinstance(scene.waveform, FmcwSpec):
        raise SceneError("compare-waveforms takes the OFDM frame from the scene and the "
                         "FMCW one from --fmcw; give the scene an OFDM [waveform] or none",
                         file=scene.source, key="waveform.kind", value="fmcw")
    snap = read_snapshot(args.snapshot)
    check_snapshot_scene(snap, scene, args.snapshot, args.scene)
    mono = monostatic_links(snap, scene, args.snapshot)
    # each radar's OFDM frame: its own [radars.waveform] where it has one (an FMCW one
    # refused by its key: compare-waveforms puts the --fmcw chirp beside the OFDM frame)
    frames, lines = radar_waveforms(scene, args, [lk.tx_index for lk in mono], fmcw=False)
    spec = load_waveform_table(args.fmcw)
    if not isinstance(spec, FmcwSpec):
        raise SceneError('must hold kind = "fmcw"', file=args.fmcw, key="waveform.kind",
                         value="ofdm")
    fmcw, fline = fmcw_run_waveform(scene.carrier_hz, None, scene, spec=spec,
                                    source=Path(args.fmcw))
    print("\n".join(f"  {line}" for line in lines) + f"\n  {fline}")
    for wf in (*frames.values(), fmcw):
        check_frame_memory(wf, args.synthesis)
    noise = radar_noise(scene, args)
    shown = []
    for ofdm in frames.values():
        if ofdm in shown:
            continue
        shown.append(ofdm)
        own = [scene.radars[j].name for j, w in frames.items() if w == ofdm]
        head = "" if len(frames) == len(own) else f"  ({', '.join(own)})"
        print("  figure                              OFDM            FMCW" + head)
        for name, a, b in waveform_rows(ofdm, fmcw):
            print(f"  {name:<34} {a:<15} {b}")
    out = Path(args.out) if args.out else Path(args.snapshot).parent
    with staged_folder(out, inputs=[*scene.input_files, args.snapshot, args.fmcw],
                       owned=COMPARE_OUTPUTS) as stage:
        for link in mono:
            radar = scene.radars[link.tx_index]
            if radar.tx_power_w == 0:
                continue
            compare_radar(sw, args, scene, link, radar, noise[link.tx_index],
                          frames[link.tx_index], fmcw, stage)
    print(f"outputs in {out}/")
    return 0


def compare_radar(sw, args, scene, link, radar, nf, ofdm, fmcw: FmcwWaveform, stage):
    """Both chains on one radar's own echoes; truth table, images, CSV."""
    truth = detection_truth(scene, radar.name, moving_objects(scene, radar))
    results, rows = {}, []
    for name, wf in (("OFDM", ofdm), ("FMCW", fmcw)):
        with sw.stage(f"radar {radar.name}: {name} chain"):
            res = radar_chain(link.paths, wf, radar=radar, seed=args.seed,
                              method=args.synthesis,
                              tx_power_w=radar.tx_power_w if nf is not None else None,
                              noise_figure_db=nf)
        results[name] = res
        for t, m in zip(truth, match_truth(res.detections, truth, *match_tolerances(wf)),
                        strict=True):
            found = m is not None
            rows.append((name, t["name"], f"{t['range_centre_m']:.3f}",
                         f"{t['v_rel_m_s']:.3f}",
                         f"{m['range_m']:.3f}" if found else "",
                         f"{m['velocity_mps']:.3f}" if found else "",
                         f"{m['range_m'] - t['range_centre_m']:.3f}" if found else "",
                         f"{m['velocity_mps'] - t['v_rel_m_s']:.3f}" if found else ""))
    print(f"  {radar.name}: {len(results['OFDM'].detections)} OFDM and "
          f"{len(results['FMCW'].detections)} FMCW detections; moving objects:")
    print(f"    {'waveform':<8} {'object':<10} {'R set':>7} {'v set':>7} {'R det':>7} "
          f"{'v det':>7}")
    for r in rows:
        print(f"    {r[0]:<8} {r[1]:<10} {r[2]:>7} {r[3]:>7} {r[4] or 'missed':>7} {r[5]:>7}")
    write_table(stage / f"{radar.name}_compare.csv", rows, COMPARE_COLUMNS)
    reach = min(max(results["OFDM"].longest_range_m, 10.0) * 1.3,
                ofdm.max_range, fmcw.max_range)
    fastest = max([abs(t["v_rel_m_s"]) for t in truth] + [5.0]) + 10.0
    save_side_by_side({f"{radar.name}: {k}": results[k].image for k in ("OFDM", "FMCW")},
                      {f"{radar.name}: {k}": results[k].detections for k in ("OFDM", "FMCW")},
                      stage / f"{radar.name}_compare", range_max_m=reach,
                      velocity_max_mps=min(fastest, ofdm.max_velocity, fmcw.max_velocity))
