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
import csv
import math
import sys
import time
from pathlib import Path

import numpy as np

from clradcom.radar import Waveform, detect, random_symbols
from clradcom.radar import interference as itf
from clradcom.radar.synthesis import thermal_noise_power
from clradcom.snapshot import SnapshotError, load_snapshot, save_snapshot

KEYS = ("clean", "interfered", "genie", "realistic")
TITLES = {"clean": "A without D", "interfered": "A with D interfering",
          "genie": "after cancelling D (genie)", "realistic": "after cancelling D (realistic)"}


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
    from clradcom.device.runtime import get_runtime
    from clradcom.scene.reader import load_scene
    from clradcom.trace import TraceSettings, trace_scene

    scene = load_scene(args.scene)
    runtime = get_runtime(args.device)
    print(f"tracing {args.scene} on {runtime.info.describe()} ...", flush=True)
    snap = trace_scene(scene, TraceSettings(max_reflections=5, rays=args.rays,
                                            max_diffractions=1, physical_optics="pec",
                                            scattering=True), runtime=runtime)
    save_snapshot(out / "snapshot.npz", snap)
    radars = {r.name: r for r in scene.radars}
    for name in (args.victim, args.interferer):
        if name not in radars:
            raise ValueError(f"{args.scene}: no radar named {name!r} (radars: "
                             f"{sorted(radars)})")
    va, vd = radars[args.victim], radars[args.interferer]
    nf = va.noise_figure_db if va.noise_figure_db is not None else args.noise_figure_db
    return snap, scene.carrier_hz, va.tx_power_w, vd.tx_power_w, nf


def plot(images, path_stem, range_max, detections, floor_clean):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ref = images["clean"]
    r, v = ref.range_m, ref.velocity_mps
    ri = np.flatnonzero(r <= range_max)
    vi = np.flatnonzero(np.abs(v) <= 40.0)
    top = float(ref.power_db[np.ix_(ri, vi)].max())  # one colour scale: A's strongest echo
    # down to 3 dB under the interference-free floor, so the rise of the floor shows
    dyn_db = max(30.0, top - 10 * math.log10(floor_clean) + 3.0)
    fig = Figure(figsize=(17.0, 4.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(KEYS), sharey=True)
    ext = (r[ri[0]], r[ri[-1]], v[vi[0]], v[vi[-1]])
    for ax, key in zip(axes, KEYS, strict=True):
        crop = images[key].power_db[np.ix_(ri, vi)] - top
        im = ax.imshow(crop.T, origin="lower", aspect="auto", cmap="jet", vmin=-dyn_db,
                       vmax=0.0, extent=ext, interpolation="nearest")
        det = detections[key]
        if len(det):
            ax.plot(det["range_m"], det["velocity_mps"], "o", mfc="none", mec="white",
                    ms=8, mew=1.2)
        ax.set_xlim(ext[0], ext[1])
        ax.set_ylim(ext[2], ext[3])
        ax.set_title(TITLES[key])
        ax.set_xlabel("range [m]")
    axes[0].set_ylabel("relative velocity [m/s]")
    fig.colorbar(im, ax=list(axes), label="power re A's strongest echo [dB]")
    fig.savefig(path_stem.with_suffix(".png"), dpi=120)
    fig.savefig(path_stem.with_suffix(".svg"))


def recovered(reference, found, waveform):
    """For each reference detection, whether one lies within one range and one velocity
    resolution cell in ``found``."""
    out = []
    for d in reference:
        ok = (np.abs(found["range_m"] - d["range_m"]) <= waveform.range_resolution) & \
             (np.abs(found["velocity_mps"] - d["velocity_mps"]) <= waveform.velocity_resolution)
        out.append(bool(ok.any()))
    return out


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
        noise_var = thermal_noise_power(wf.bandwidth, nf) / p_a
        rng = np.random.default_rng(args.seed)
        d_a = random_symbols(wf, rng)
        wf_stream = Waveform(carrier_hz=fc, n_subcarriers=args.subcarriers,
                             n_symbols=itf.stream_symbols(wf))
        d_d = random_symbols(wf_stream, rng)
        print(f"[{time.perf_counter() - t0:6.1f} s] synthesising {len(own.gain)} own paths "
              f"({args.own_synthesis}) ...", flush=True)
        y_own = itf.own_echo_signal(d_a, own.gain, own.delay_s, own.doppler_hz, wf,
                                    method=args.own_synthesis)
        print(f"[{time.perf_counter() - t0:6.1f} s] {len(dl.gain)} interferer paths (time "
              "domain), estimation, cancellation ...", flush=True)
        res = itf.run_interference(
            y_own, d_a, d_d, dl.gain, dl.delay_s, dl.doppler_hz, wf,
            timing_offset_s=args.timing_offset_us * 1e-6, cfo_hz=args.cfo_hz,
            phase_rad=math.radians(args.phase_deg), power_ratio=p_d / p_a,
            noise_variance=noise_var, rng=rng)
    except (SnapshotError, ValueError, KeyError, OSError) as exc:
        print(f"interference.py: {exc}", file=sys.stderr)
        return 2
    dets = {k: detect(res.images[k], guard=(3, 2), train=(8, 4)) for k in KEYS}
    plot(res.images, out / "interference", args.range_max, dets, res.floors["clean"])

    def db(x):
        return 10 * math.log10(x) if x > 0 else -math.inf

    nv = res.noise_variance
    e = res.estimate
    rows = [
        ("noise per cell re P_tx,A [dB]", db(nv)),
        ("interference power per sample, measured [dB]", db(res.interference_power)),
        ("interference power predicted from D->A paths [dB]",
         db(res.predicted_interference_power)),
        ("floor rise predicted (1 + INR) [dB]", res.predicted_floor_rise_db),
        ("floor rise measured [dB]", res.measured_floor_rise_db),
        ("floor after genie cancellation re without D [dB]",
         db(res.floors["genie"] / res.floors["clean"])),
        ("floor after realistic cancellation re without D [dB]",
         db(res.floors["realistic"] / res.floors["clean"])),
        ("residual interference re interference [dB]",
         db(res.residual_power / res.interference_power)),
        ("channel NMSE (true data, estimated channel) [dB]", db(res.channel_nmse)),
        ("symbol-error rate of D's decisions", res.symbol_error_rate),
        ("D symbols decided (inside A's frame)", int(res.symbols_decided)),
        ("predicted residual P_I(NMSE + SER E|d-d^|^2) re interference [dB]",
         db(res.predicted_residual_power / res.interference_power)),
        ("predicted residual, errors weighted by |H^|^2 where they fall [dB]",
         db(res.predicted_residual_weighted / res.interference_power)),
        ("D's decision SINR as the receiver judges it [dB]", e.sinr_db),
        ("cancelled (1) or judged unreliable and left alone (0)", int(e.cancel)),
        ("D timing found (CP start mod L) [samples]", e.theta),
        ("D frequency offset found (CFO + Doppler) [Hz]",
         e.eps * wf.subcarrier_spacing_hz),
        ("D channel components fitted", int(e.components.amplitude.size)),
        ("own echoes removed before decoding D", int(e.own.amplitude.size)),
    ]
    print()
    for name, val in rows:
        if isinstance(val, int):
            print(f"  {name:<68} {val:10d}")
        elif 0 < abs(val) < 1e-2:
            print(f"  {name:<68} {val:10.2e}")
        else:
            print(f"  {name:<68} {val:10.3f}")
    with open(out / "interference_summary.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["quantity", "value"])
        w.writerows(rows)
    ref = dets["clean"]
    print(f"\n  detections without D: {len(ref)}; with D: {len(dets['interfered'])}; "
          f"genie: {len(dets['genie'])}; realistic: {len(dets['realistic'])}")
    found = {k: recovered(ref, dets[k], wf) for k in KEYS[1:]}
    print(f"  {'range m':>8} {'v m/s':>7} {'SNR dB':>7}   with D  genie  realistic")
    for i, d in enumerate(ref):
        marks = "  ".join(f"{'yes' if found[k][i] else 'NO':>6}" for k in KEYS[1:])
        print(f"  {d['range_m']:8.2f} {d['velocity_mps']:7.2f} {d['snr_db']:7.1f}   {marks}")
    for k in KEYS[1:]:
        print(f"  {k}: {sum(found[k])} of {len(ref)} interference-free detections found")
    print(f"\n[{time.perf_counter() - t0:6.1f} s] wrote {out}/interference.png, .svg, "
          "interference_summary.csv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
