#!/usr/bin/env python
"""Benchmark of the OFDM RadCom DSP chain on the paper's frame (N = 1024, M = 256), and
the FMCW beat synthesis on a 256-sample x 128-chirp frame.

Stages, each against a plain numpy reference written the obvious way and timed in the same
run: fast (frequency-domain) synthesis, exact time-domain synthesis, processing
(divide, windows, 2-D FFT, dB, CA-CFAR, peak picking), and range/velocity estimation
(the joint Newton fit of every detection against scipy's Nelder–Mead on each detection's
periodogram, 16 targets at 0 dB SNR per cell), and the radar cube with CFAR and the point
cloud (TDM MIMO, 2 x 6 = 12 virtual elements, range x Doppler x 16 azimuth bins, against
the same steps in plain numpy).  Prints times, speed-ups, the
issue's targets, accuracy against the reference and the traced memory peak per stage
(tracemalloc sees numpy's buffers, not finufft's internal C allocations; the process
max-RSS is printed too).

    python tools/bench_dsp.py [--paths 1000] [--repeat 3] [--ref-paths 1000]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import time
import tracemalloc

import numpy as np
from scipy.optimize import minimize

from clradcom.cli import positive_int, run_tool, seed
from clradcom.memory import check_memory
from clradcom.radar import (
    Waveform,
    add_noise,
    detect,
    estimate_detections,
    ofdm_demodulate,
    radar_image,
    random_symbols,
    spectral_estimate,
    synthesize_frequency_domain,
    synthesize_time_domain,
)
from clradcom.radar.cube import (
    detect_cube,
    point_cloud,
    radar_cube,
    refine_detections,
    tdm_channels,
)
from clradcom.radar.fmcw import FmcwWaveform, beat_frequencies, if_response, synthesize_beat
from clradcom.radar.mimo import tdm_range_doppler, virtual_positions


# --- references: the obvious numpy ------------------------------------------------------
def ref_fast(d, a, tau, fd, wf):
    """One outer product per path."""
    n = np.arange(wf.n_subcarriers)
    mu = np.arange(wf.n_symbols)
    h = np.zeros(d.shape, complex)
    for k in range(a.size):
        h += a[k] * np.outer(np.exp(-2j * np.pi * n * wf.subcarrier_spacing_hz * tau[k]),
                             np.exp(2j * np.pi * fd[k] * mu * wf.symbol_duration))
    return d * h


def ref_exact(d, a, tau, fd, wf):
    """Per path: delay δ = τ f_s = whole + frac samples.  Received sample i belongs to source
    symbol ν when νL ≤ i − δ < (ν+1)L, so with c = [frac > 0] the delayed frame is the CP-OFDM
    frame of the symbols D·e^{−j2πn(frac − c)/N} shifted by whole + c samples; then the
    Doppler ramp e^{j2π f_D t} over the whole frame; accumulate (np.fft, one path at a time)."""
    n, ncp = wf.n_subcarriers, wf.n_cp
    total = wf.n_samples
    t = np.arange(total) / wf.sample_rate
    sub = np.arange(n)[:, None]
    y = np.zeros(total, complex)
    for k in range(a.size):
        delta = tau[k] * wf.sample_rate
        whole = int(np.floor(delta))
        frac = delta - whole
        c = 1 if frac > 0 else 0
        body = np.fft.ifft(d * np.exp(-2j * np.pi * sub * (frac - c) / n), axis=0) * np.sqrt(n)
        x = np.concatenate([body[n - ncp:], body], axis=0).T.ravel()
        shift = whole + c
        delayed = np.zeros(total, complex)
        if shift < total:
            delayed[shift:] = x[: total - shift]
        y += a[k] * np.exp(2j * np.pi * fd[k] * t) * delayed
    return y


def ref_fmcw(a, tau, fd, wf):
    """The obvious numpy sum of the FMCW beat frame: every path's exact phase at every
    sample (docs/fmcw.md §2), one (N, M) exponential per path."""
    t_fast = wf.adc_start_s + np.arange(wf.samples_per_chirp)[:, None] / wf.adc_rate_hz
    t = np.arange(wf.n_chirps)[None, :] * wf.chirp_interval + t_fast
    f_fast, _ = beat_frequencies(tau, fd, wf)
    w = a * if_response(wf, f_fast)
    out = np.zeros((wf.samples_per_chirp, wf.n_chirps), complex)
    fc, f0, s = wf.traced_carrier_hz, wf.start_hz, wf.slope
    for k in range(a.size):
        d = tau[k] - fd[k] / fc * t
        out += w[k] * np.exp(-2j * np.pi * ((f0 - fc) * d + s * t_fast * d - 0.5 * s * d * d)
                             + 2j * np.pi * fd[k] * t)
    return out


def ref_processing(dr, d, wf, p_fa, guard, train):
    """Divide, Hann outer-product window, np.fft, dB, CA-CFAR by summing shifted copies,
    local maxima by comparing with shifted copies."""
    f = dr / d
    w = np.outer(np.hanning(wf.n_subcarriers + 1)[:-1], np.hanning(wf.n_symbols + 1)[:-1])
    img = np.fft.fftshift(np.fft.fft(np.fft.ifft(f * w, axis=0), axis=1), axes=1)
    power = np.abs(img) ** 2
    power_db = 10 * np.log10(power)
    gr, gd = guard
    hr, hd = guard[0] + train[0], guard[1] + train[1]
    acc = np.zeros_like(power)
    count = 0
    for i in range(-hr, hr + 1):
        for j in range(-hd, hd + 1):
            if abs(i) <= gr and abs(j) <= gd:
                continue
            acc += np.roll(power, (i, j), axis=(0, 1))
            count += 1
    alpha = count * (p_fa ** (-1.0 / count) - 1.0)
    hit = power > alpha * acc / count
    for i in (-1, 0, 1):
        for j in (-1, 0, 1):
            if i or j:
                hit &= power >= np.roll(power, (i, j), axis=(0, 1))
    return power_db, np.argwhere(hit)


def ref_cube(dr, d, wf, n_tx, vp_y, spacing, p_fa, guard, train, n_az):
    """TDM radar cube the obvious way: per virtual channel F = D_r/D on its symbols, Hann
    windows, np.fft over range and Doppler, a loop over Doppler bins for the motion
    compensation, np.fft over the zero-padded virtual array, CA-CFAR by summing rolled
    copies of each angle slice, local maxima by comparing with rolled copies in 3-D, and
    the point (x, y, z) of each detection."""
    er, n, m = dr.shape
    mv = m // n_tx
    wn = np.hanning(n + 1)[:-1]
    wm = np.hanning(mv + 1)[:-1]
    chans = []
    for i in range(n_tx):
        for j in range(er):
            f = dr[j][:, i::n_tx] / d[:, i::n_tx]
            h = np.fft.fft(np.fft.ifft(f * np.outer(wn, wm), axis=0), axis=1)
            fd = np.fft.fftfreq(mv, n_tx * wf.symbol_duration)
            for q in range(mv):
                h[:, q] *= np.exp(-2j * np.pi * fd[q] * i * wf.symbol_duration)
            chans.append(np.fft.fftshift(h, axes=1))
    x = np.stack(chans, axis=2)
    g = np.round(vp_y / spacing).astype(int)
    wa = np.hanning(g.max() + 3)[1:-1] if g.max() > 0 else np.ones(1)
    grid = np.zeros(x.shape[:2] + (g.max() + 1,), complex)
    for v in range(x.shape[2]):
        grid[:, :, g[v]] += wa[g[v]] * x[:, :, v]
    power = np.abs(np.fft.fftshift(np.fft.fft(grid, n_az, axis=2), axes=2)) ** 2
    gr, gd = guard
    hr, hd = guard[0] + train[0], guard[1] + train[1]
    acc = np.zeros_like(power)
    count = 0
    for a in range(-hr, hr + 1):
        for b in range(-hd, hd + 1):
            if abs(a) <= gr and abs(b) <= gd:
                continue
            acc += np.roll(power, (a, b), axis=(0, 1))
            count += 1
    alpha = count * (p_fa ** (-1.0 / count) - 1.0)
    hit = power > alpha * acc / count
    for a in (-1, 0, 1):
        for b in (-1, 0, 1):
            for c in (-1, 0, 1):
                if a or b or c:
                    hit &= power >= np.roll(power, (a, b, c), axis=(0, 1, 2))
    cells = np.argwhere(hit)
    r = cells[:, 0] * 3e8 / (2 * n * wf.subcarrier_spacing_hz)
    u = (cells[:, 2] - n_az // 2) * wf.wavelength / (n_az * spacing)
    az = np.arcsin(np.clip(u, -1, 1))
    return cells, np.stack([r * np.cos(az), r * np.sin(az), 0 * r], axis=1)


def ref_estimation(f, x0, y0):
    """Each detection alone: Nelder–Mead on −|u(x)ᵀ F v(y)|², the un-windowed periodogram
    as a vector–matrix–vector product, from the same starts."""
    n, m = f.shape
    i, j = np.arange(n), np.arange(m)

    def neg(p):
        return -abs(np.exp(2j * np.pi * i * p[0] / n) @ f @ np.exp(-2j * np.pi * j * p[1] / m))

    out = [minimize(neg, (x, y), method="Nelder-Mead",
                    options={"xatol": 1e-7, "fatol": 1e-12}).x
           for x, y in zip(x0, y0, strict=True)]
    return np.array(out).reshape(-1, 2)


# --- harness -----------------------------------------------------------------------------
def timed(fn, repeat):
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), min(times), out


def traced_peak(fn):
    tracemalloc.start()
    tracemalloc.reset_peak()
    fn()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=positive_int, default=1000)
    ap.add_argument("--repeat", type=positive_int, default=3)
    ap.add_argument("--ref-paths", type=positive_int, default=None,
                    help="paths for the slow references (default: all); times are scaled "
                         "linearly to --paths and marked '*'")
    ap.add_argument("--seed", type=seed, default=1)
    ap.add_argument("--fmcw-only", action="store_true",
                    help="time only the FMCW synthesis against its obvious numpy sum")
    args = ap.parse_args(argv)
    return run_tool("bench_dsp.py", run, args)


def run(args) -> int:
    wf = Waveform()
    # the matmul synthesis' (N, K) and (K, M) complex factors and their product's operands
    check_memory(3 * 16 * args.paths * (wf.n_subcarriers + wf.n_symbols),
                 what=f"{args.paths} paths", argument="--paths", value=args.paths,
                 advice="use fewer --paths")
    rng = np.random.default_rng(args.seed)
    k = args.paths
    r = rng.uniform(1.0, 200.0, k)  # street scale, inside the ISI-free 206 m
    v = rng.uniform(-30.0, 30.0, k)
    a = 1e-3 * (rng.standard_normal(k) + 1j * rng.standard_normal(k)) / np.sqrt(2)
    tau, fd = wf.range_to_delay(r), wf.velocity_to_doppler(v)
    d = random_symbols(wf, args.seed)
    kr = min(args.ref_paths or k, k)
    scale = k / kr

    guard, train, p_fa = (2, 2), (4, 4), 1e-6
    rows = []

    def add(stage, fn, ref_fn, target_s, err_fn=None, ref_scale=1.0):
        med, best, out = timed(fn, args.repeat)
        ref_med, _, ref_out = timed(ref_fn, 1)
        ref_med *= ref_scale
        err = err_fn(out, ref_out) if err_fn else float("nan")
        mem = traced_peak(fn)
        rows.append((stage, med, best, ref_med, target_s, err, mem, ref_scale != 1.0))

    def rel_db(x, ref):
        return 10 * np.log10(np.sum(np.abs(x - ref) ** 2) / np.sum(np.abs(ref) ** 2))

    # FMCW: the issue's 256-sample x 128-chirp frame (77 GHz, 1 GHz sweep), the same
    # number of paths inside its 60 m and ±19 m/s
    fw = FmcwWaveform()
    rf = rng.uniform(1.0, 0.9 * fw.max_range, k)
    vf = rng.uniform(-0.95, 0.95, k) * fw.max_velocity
    tau_f, fd_f = fw.range_to_delay(rf), fw.velocity_to_doppler(vf)
    synthesize_beat(a[:4], tau_f[:4], fd_f[:4], fw)
    add(f"FMCW synthesis {fw.samples_per_chirp}x{fw.n_chirps}",
        lambda: synthesize_beat(a, tau_f, fd_f, fw),
        # the reference on every path whatever --ref-paths: the ratio is measured, not scaled
        lambda: ref_fmcw(a, tau_f, fd_f, fw), float("nan"), rel_db)
    if args.fmcw_only:
        return _report(rows, args, wf, k, kr)
    synthesize_frequency_domain(d, a[:4], tau[:4], fd[:4], wf)  # load finufft once
    add("fast synthesis, finufft", lambda: synthesize_frequency_domain(d, a, tau, fd, wf),
        lambda: ref_fast(d, a, tau, fd, wf), 0.05, rel_db)
    add("fast synthesis, matmul",
        lambda: synthesize_frequency_domain(d, a, tau, fd, wf, method="matmul"),
        lambda: ref_fast(d, a, tau, fd, wf), 0.05, rel_db)
    add("exact time-domain synthesis",
        lambda: synthesize_time_domain(d, a, tau, fd, wf),
        lambda: ref_exact(d, a[:kr], tau[:kr], fd[:kr], wf), 1.0,
        (lambda o, ref: rel_db(synthesize_time_domain(d, a[:kr], tau[:kr], fd[:kr], wf),
                               ref)) if kr < k else rel_db,
        ref_scale=scale)
    y = synthesize_time_domain(d, a, tau, fd, wf)
    dr = ofdm_demodulate(y, wf)

    def proc():
        img = radar_image(spectral_estimate(dr, d), wf)
        return img, detect(img, guard, train, p_fa)

    def proc_err(out, ref):
        img, det = out
        ref_db, _ = ref
        return float(np.max(np.abs(img.power_db - ref_db - (img.power_db - ref_db).mean())))

    add("processing + CA-CFAR", proc, lambda: ref_processing(dr, d, wf, p_fa, guard, train),
        0.05, proc_err)

    def proc_os():
        img = radar_image(spectral_estimate(dr, d), wf)
        return img, detect(img, guard, train, p_fa, method="os")

    add("processing + OS-CFAR", proc_os,
        lambda: ref_processing(dr, d, wf, p_fa, guard, train), float("nan"), proc_err)

    # estimation: 16 targets well apart at 0 dB SNR per cell, fast model, detections of
    # the critically sampled Hann image as the start of both
    kt = 16
    tr = (20 + 62 * np.arange(kt) + rng.uniform(0, 1, kt)) * wf.range_resolution
    tv = (-120 + 15 * np.arange(kt) + rng.uniform(0, 1, kt)) * wf.velocity_resolution
    ta = np.exp(2j * np.pi * rng.uniform(size=kt))
    # F = D_r/D of the fast model (PSK: the divided noise stays white), built directly:
    # most of these ranges lie beyond the cyclic prefix, which only the exact model minds
    h = (np.exp(-2j * np.pi * np.outer(np.arange(wf.n_subcarriers), tr)
                / (wf.n_subcarriers * wf.range_resolution)) * ta) @ \
        np.exp(2j * np.pi * np.outer(tv, np.arange(wf.n_symbols))
               / (wf.n_symbols * wf.velocity_resolution))
    fe = add_noise(h, 1.0, rng)
    start = detect(radar_image(fe, wf), (2, 1), (4, 2), p_fa)
    m2 = wf.n_symbols // 2

    def est_err(out, ref):
        # the 16 targets (strongest first); a noise peak among the detections is fitted
        # with its neighbours by the joint fit and alone by the reference
        got = np.stack([out["range_bin"], out["doppler_bin"] - m2], axis=1)
        return float(np.max(np.abs(got - ref)[:kt]))

    add(f"estimation, {start.size} detections", lambda: estimate_detections(start, fe, wf),
        lambda: ref_estimation(fe, start["range_bin"], start["doppler_bin"] - m2),
        float("nan"), est_err)

    # the radar cube and point cloud: paper frame, TDM with 2 tx x 6 rx = a filled 12-element
    # virtual ULA (128 symbols per transmitter), 16 targets at 10 dB SNR per cell
    n_tx, n_rx = 2, 6
    lam = wf.wavelength
    tx_pos = np.zeros((n_tx, 3))
    tx_pos[:, 1] = np.arange(n_tx) * n_rx * lam / 2
    rx_pos = np.zeros((n_rx, 3))
    rx_pos[:, 1] = np.arange(n_rx) * lam / 2
    vp = virtual_positions(tx_pos, rx_pos)
    taz = np.radians(rng.uniform(-50, 50, kt))
    u = np.stack([np.cos(taz), np.sin(taz), 0 * taz], axis=1)
    kk = 2 * np.pi / lam
    mu = np.arange(wf.n_symbols)
    owner = mu % n_tx
    dr_mimo = np.empty((n_rx, wf.n_subcarriers, wf.n_symbols), complex)
    ph_r = np.exp(-2j * np.pi * np.outer(np.arange(wf.n_subcarriers), tr)
                  / (wf.n_subcarriers * wf.range_resolution))
    # half the estimation stage's velocities: TDM with 2 tx halves the unambiguous span
    ph_d = np.exp(2j * np.pi * np.outer(tv / 2, mu) / (wf.n_symbols * wf.velocity_resolution))
    for j in range(n_rx):
        steer = np.exp(1j * kk * (tx_pos @ u.T)[owner] + 1j * kk * (rx_pos[j] @ u.T))  # (M, K)
        dr_mimo[j] = d * ((ph_r * ta) @ (ph_d * steer.T))
    dr_mimo = d * add_noise(dr_mimo / d, 0.1, rng)
    n_az = 16

    def cube_stage():
        rd = tdm_range_doppler(dr_mimo, d, wf, n_tx)
        cube = radar_cube(rd, vp, lam, n_azimuth=n_az)
        det = detect_cube(cube, guard, train, p_fa, sidelobe_db=None)
        # range, velocity and angle of every detection: the joint ML fit on the channels
        f, slow = tdm_channels(dr_mimo, d, wf, n_tx)
        det = refine_detections(det, cube, f, slow, vp, wf)
        return det, point_cloud(det, np.zeros(3), np.eye(3))

    def cube_err(out, ref):
        # detections in different cells (the package's refined bins rounded against the
        # reference's cells; the points then differ only by the sub-bin refinement)
        det, _ = out
        cells, _ = ref
        got = {(round(a) % wf.n_subcarriers, round(b) % (wf.n_symbols // n_tx), round(c) % n_az)
               for a, b, c in zip(det["range_bin"], det["doppler_bin"], det["azimuth_bin"],
                                  strict=True)}
        return float(len(got.symmetric_difference(map(tuple, cells.tolist()))))

    add(f"cube+CFAR+ML+cloud, {n_tx}x{n_rx}", cube_stage,
        lambda: ref_cube(dr_mimo, d, wf, n_tx, vp[:, 1], lam / 2, p_fa, guard, train, n_az),
        0.3, cube_err)

    def cube_parabola():  # the same without the ML step (the parabola's points)
        rd = tdm_range_doppler(dr_mimo, d, wf, n_tx)
        det = detect_cube(radar_cube(rd, vp, lam, n_azimuth=n_az), guard, train, p_fa,
                          sidelobe_db=None)
        return det, point_cloud(det, np.zeros(3), np.eye(3))

    add(f"  same, parabola only, {n_tx}x{n_rx}", cube_parabola,
        lambda: ref_cube(dr_mimo, d, wf, n_tx, vp[:, 1], lam / 2, p_fa, guard, train, n_az),
        float("nan"), cube_err)

    return _report(rows, args, wf, k, kr)


def _report(rows, args, wf, k, kr) -> int:
    print(f"OFDM RadCom DSP benchmark: N={wf.n_subcarriers}, M={wf.n_symbols}, {k} paths, "
          f"median of {args.repeat}")
    head = (f"{'stage':30s} {'median ms':>10s} {'best ms':>9s} {'ref ms':>10s} {'speed-up':>9s}"
            f" {'target ms':>9s} {'ok':>4s} {'err vs ref':>12s} {'peak MiB':>9s}")
    print(head)
    print("-" * len(head))
    for stage, med, best, ref, target, err, mem, scaled in rows:
        ok = "" if np.isnan(target) else ("yes" if med < target else "NO")
        tgt = "-" if np.isnan(target) else f"{target * 1e3:.0f}"
        errs = "-" if np.isnan(err) else (
            f"{err:.2g} bin" if stage.startswith("estimation") else
            f"{err:.0f} cells" if stage.startswith(("cube", "  same")) else
            f"{err:.1f} dB" if err < 0 else f"{err:.2g} dB")
        star = "*" if scaled else " "
        print(f"{stage:30s} {med * 1e3:10.1f} {best * 1e3:9.1f} {ref * 1e3:9.0f}{star}"
              f" {ref / med:8.1f}x {tgt:>9s} {ok:>4s} {errs:>12s} {mem:9.0f}")
    print("err vs ref: synthesis = relative error power of output vs reference; processing ="
          " max |ΔdB| of the image (after removing the constant normalisation offset);"
          " estimation = max |Δ| of range or Doppler bin (joint fit vs each alone);"
          " cube = detections in cells the other does not have (0: the same detections).")
    fm = next(r for r in rows if r[0].startswith("FMCW"))
    print(f"FMCW synthesis against the obvious numpy sum, same run: {fm[3] / fm[1]:.1f}x "
          f"(issue #29 target >= 20x: {'yes' if fm[3] / fm[1] >= 20 else 'NO'})")
    if kr < k:
        print(f"* reference timed on {kr} paths and scaled linearly to {k}.")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"process max RSS: {rss:.0f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
