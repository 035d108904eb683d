#!/usr/bin/env python3
"""Two radars on one street: what radar D does to radar A's image, and how A removes it.

    python tools/interference.py scenes/street/street.toml --out out/interference
    python tools/interference.py --snapshot out/street/snapshot.npz --out out/interference

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

With a scene the links are traced first (about as long as tools/trace.py); with
--snapshot the existing snapshot's links are used and the noise comes from
--tx-power-w / --noise-figure-db.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from clradcom.device.runtime import get_runtime
from clradcom.radar import Waveform
from clradcom.radar.interference import two_radar_run
from clradcom.radar.plots import save_interference_images
from clradcom.radar.report import (
    INTERFERENCE_IMAGES,
    interference_detections,
    interference_summary,
    recovered_detections,
    write_table,
)
from clradcom.scene.reader import load_scene
from clradcom.snapshot import SnapshotError, load_snapshot, save_snapshot
from clradcom.trace import (
    DiffractionSettings,
    OpticsSettings,
    ScatteringSettings,
    SpecularSettings,
    TraceSettings,
    trace_scene,
)


def parse_args(argv):
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", nargs="?", help="scene file (TOML) to trace, e.g. "
                    "scenes/street/street.toml; leave out when giving --snapshot")
    ap.add_argument("--snapshot", help="an existing snapshot.npz (from tools/trace.py)")
    ap.add_argument("--out", default="out/interference", help="output folder "
                    "(default out/interference)")
    ap.add_argument("--victim", default="A", help="the radar whose image is shown (default A)")
    ap.add_argument("--interferer", default="D", help="the interfering radar (default D)")
    ap.add_argument("--timing-offset-us", type=float, default=4.2,
                    help="D's symbol boundaries after A's, in µs, in [0, T_sym = 12.375 µs) "
                         "(default 4.2: far beyond the 1.375 µs cyclic prefix)")
    ap.add_argument("--cfo-hz", type=float, default=2400.0,
                    help="D's carrier offset from A's in Hz (default 2400 = 0.1 ppm at "
                         "24 GHz); with the Doppler it must stay within ±0.4 Δf")
    ap.add_argument("--phase-deg", type=float, default=37.0,
                    help="D's oscillator phase relative to A's (default 37)")
    ap.add_argument("--own-synthesis", choices=("fast", "exact"), default="fast",
                    help="A's own echoes: fast (default) = those within 40 dB of the "
                         "strongest exactly, the rest by the frequency-domain model (seconds); "
                         "exact = all in the time domain (many minutes for the street). "
                         "D's signal is always synthesised exactly")
    ap.add_argument("--seed", type=int, default=0, help="seed of A's data, D's data and "
                    "the noise (default 0)")
    ap.add_argument("--tx-power-w", type=float, default=0.01,
                    help="with --snapshot: both radars' transmit power (default 0.01 W)")
    ap.add_argument("--noise-figure-db", type=float, default=10.0,
                    help="with --snapshot: A's noise figure (default 10 dB)")
    ap.add_argument("--device", default=None, help="OpenCL device for tracing a scene")
    ap.add_argument("--rays", type=int, default=1_000_000,
                    help="rays per transmitter when tracing a scene (default 1e6)")
    ap.add_argument("--subcarriers", type=int, default=1024,
                    help="N (default 1024, the paper's); fewer for a quick look")
    ap.add_argument("--symbols", type=int, default=256,
                    help="M (default 256, the paper's); fewer for a quick look")
    ap.add_argument("--range-max", type=float, default=60.0,
                    help="range shown in the pictures, m (default 60)")
    args = ap.parse_args(argv)
    if (args.scene is None) == (args.snapshot is None):
        ap.error("give either a scene file or --snapshot (exactly one)")
    return args


def trace(args, out):
    scene = load_scene(args.scene)
    runtime = get_runtime(args.device)
    print(f"tracing {args.scene} on {runtime.info.describe()} ...", flush=True)
    settings = TraceSettings(specular=SpecularSettings(max_reflections=5, rays=args.rays),
                             diffraction=DiffractionSettings(max_diffractions=1),
                             optics=OpticsSettings(mode="pec"),
                             scattering=ScatteringSettings(enabled=True))
    snap = trace_scene(scene, settings, runtime=runtime)
    save_snapshot(out / "snapshot.npz", snap)
    radars = {r.name: r for r in scene.radars}
    for name in (args.victim, args.interferer):
        if name not in radars:
            raise ValueError(f"{args.scene}: no radar named {name!r} (radars: "
                             f"{sorted(radars)})")
    va, vd = radars[args.victim], radars[args.interferer]
    nf = va.noise_figure_db if va.noise_figure_db is not None else args.noise_figure_db
    return snap, scene.carrier_hz, va.tx_power_w, vd.tx_power_w, nf


def main(argv=None) -> int:
    args = parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        if args.scene is not None:
            snap, fc, p_a, p_d, nf = trace(args, out)
        else:
            snap = load_snapshot(args.snapshot)
            fc, p_a, p_d, nf = snap.carrier_hz, args.tx_power_w, args.tx_power_w, \
                args.noise_figure_db
        own = snap.link(args.victim, args.victim).paths
        dl = snap.link(args.interferer, args.victim).paths
        wf = Waveform(carrier_hz=fc, n_subcarriers=args.subcarriers, n_symbols=args.symbols)
        for name, val in (("--tx-power-w", p_a), ("--noise-figure-db", nf)):
            if not math.isfinite(val):
                raise ValueError(f"{name} must be finite, got {val!r}")
        if p_a <= 0 or p_d <= 0:
            raise ValueError(f"transmit powers must be positive, got A {p_a!r} W, D {p_d!r} W")
        res = two_radar_run(
            own, dl, wf, tx_power_w=p_a, interferer_tx_power_w=p_d, noise_figure_db=nf,
            timing_offset_s=args.timing_offset_us * 1e-6, cfo_hz=args.cfo_hz,
            phase_rad=math.radians(args.phase_deg), seed=args.seed,
            own_synthesis=args.own_synthesis,
            progress=lambda msg: print(f"[{time.perf_counter() - t0:6.1f} s] {msg} ...",
                                       flush=True))
    except (SnapshotError, ValueError, KeyError, OSError) as exc:
        print(f"interference.py: {exc}", file=sys.stderr)
        return 2
    dets = interference_detections(res.images)
    save_interference_images(res.images, out / "interference", dets, res.floors["clean"],
                             args.range_max)
    rows = interference_summary(res, wf)
    print()
    for name, val in rows:
        if isinstance(val, int):
            print(f"  {name:<68} {val:10d}")
        elif 0 < abs(val) < 1e-2:
            print(f"  {name:<68} {val:10.2e}")
        else:
            print(f"  {name:<68} {val:10.3f}")
    write_table(out / "interference_summary.csv", rows, ["quantity", "value"])
    ref = dets["clean"]
    print(f"\n  detections without D: {len(ref)}; with D: {len(dets['interfered'])}; "
          f"genie: {len(dets['genie'])}; realistic: {len(dets['realistic'])}")
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


if __name__ == "__main__":
    sys.exit(main())
