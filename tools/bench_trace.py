#!/usr/bin/env python3
"""Trace benchmark: the whole street trace, device engine against the host reference,
and the scenes that the old SBR-PO could not trace.

    python tools/bench_trace.py                       # street x 3 per engine, then extras
    python tools/bench_trace.py --repeats 5 --extra none
    python tools/bench_trace.py --street none --extra plate,truck77 --out /tmp/bench
    python tools/bench_trace.py --device all          # every OpenCL implementation here
    python tools/bench_trace.py --device pocl,intel --repeats 5 --extra none

1. The street (scenes/street/street.toml) at the main job's settings: the very
   TraceSettings tools/trace.py builds from its defaults (the paper preset: 5
   reflections from 3e5 rays and candidate expansion, one diffraction, SBR-PO,
   scattering), with --rays and --sbr-spacing passed on to it. One
   untimed warm-up trace per engine (kernel builds), then the device and host engines
   take turns --repeats times in this process; printed are the medians per stage
   (clradcom.trace.StageTimes), the whole trace, the ratio host/device and the share of
   the device trace's wall time spent inside kernels (Runtime.kernel_seconds: enqueue to
   finish of every kernel launch).
2. Extra scenes (default scenes/plate, scenes/truck77, scenes/guardrail), device engine,
   each traced once in a fresh process: trace time (kernel builds included, as in a
   user's first run), share in kernels, paths, and the process's peak resident memory
   (VmHWM; on a CPU OpenCL device the device buffers are in it too). For a scene of
   one flat PEC plate and a monostatic radar (scenes/plate) also its RCS from the path sum
   by the radar range equation against 4 pi A^2 / lambda^2. A scene that fails is
   reported with its error and the run goes on.

With --device all (every OpenCL implementation present but the Oclgrind simulator) or a
list of device names (pocl,intel,nvidia,...), the street's main job instead runs with the
device engine on each device in one process: one warm-up trace each (kept: the first
run's time, kernel builds included), then the devices take turns --repeats times; printed
are the medians per stage and whole, the share inside kernels and each device's time
over PoCL's; then every link's channel at the radar's 1024 subcarriers against PoCL's
(NMSE, dB) and radar A's detections of the cars beside the paper's Table III. The extra
scenes run once per device, each in its own process.

Every number goes to <out>/bench_trace.csv (scene, engine, quantity, value, unit); --out
defaults to a new temporary folder, never the repository. The logic lives in
clradcom.evaluation.bench. Errors in the options are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
from pathlib import Path

from clradcom.cli import float_in, output_folder, positive_float, positive_int, run_tool
from clradcom.commands.trace import radar_noise
from clradcom.device.runtime import VENDOR_NAMES, Runtime, get_runtime, list_devices
from clradcom.evaluation.bench import (
    CSV_HEADER,
    channel_agreement_db,
    compare_devices,
    compare_engines,
    median_timing,
    plate_rcs,
    run_in_subprocess,
    table_iii_detections,
    timing_rows,
)
from clradcom.files import write_csv
from clradcom.radar.waveform import Waveform
from clradcom.scene.reader import load_scene
from clradcom.scene.records import SBR_SPACING_WAVELENGTHS
from clradcom.scene.street import TABLE_III
from clradcom.trace import check_launch_memory

REPO = Path(__file__).resolve().parent.parent
STREET = REPO / "scenes" / "street" / "street.toml"
EXTRA = {name: REPO / "scenes" / name / f"{name}.toml"
         for name in ("plate", "truck77", "guardrail")}
#: targets printed beside the numbers (issue #16)
TARGET_RATIO, TARGET_KERNEL_SHARE, TARGET_PEAK_GIB, TARGET_PLATE_DB = 5.0, 0.70, 4.0, 0.1


def trace_tool():
    """tools/trace.py as a module: its parser and settings are the main job's."""
    spec = importlib.util.spec_from_file_location("trace_tool", Path(__file__).with_name(
        "trace.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main_job_settings(scene, rays=None, sbr_spacing=None):
    """The TraceSettings tools/trace.py builds for ``scene`` from its defaults, with
    ``--rays`` / ``--sbr-spacing`` when given."""
    tool = trace_tool()
    argv = [str(scene)]
    if rays is not None:
        argv += ["--rays", str(rays)]
    if sbr_spacing is not None:
        argv += ["--sbr-spacing", repr(sbr_spacing)]
    return tool.settings_from_args(tool.build_parser().parse_args(argv))


def scene_list(text):
    """--extra: 'none', or comma-separated names of the extra scenes or scene files."""
    if text.strip() == "none":
        return []
    out = []
    for item in (t.strip() for t in text.split(",") if t.strip()):
        path = EXTRA.get(item, Path(item))
        if not path.is_file():
            raise argparse.ArgumentTypeError(
                f"{item!r} is neither one of {', '.join(EXTRA)} nor a scene file")
        out.append(path)
    if not out:
        raise argparse.ArgumentTypeError(f"names no scene: {text!r}")
    return out


def street_file(text):
    """--street: 'none', or a scene file."""
    if text.strip() == "none":
        return None
    if not Path(text).is_file():
        raise argparse.ArgumentTypeError(f"{text!r} is not a scene file")
    return Path(text)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--street", type=street_file, default=STREET,
                    help="scene timed with both engines (default scenes/street/street.toml; "
                         "'none' skips it)")
    ap.add_argument("--extra", type=scene_list, default=list(EXTRA.values()),
                    help=f"extra scenes, device engine, one process each: names "
                         f"({', '.join(EXTRA)}) or scene files, comma-separated (default "
                         "all three; 'none' skips them)")
    ap.add_argument("--repeats", type=positive_int, default=3,
                    help="timed street traces per engine; medians are printed (default 3)")
    ap.add_argument("--rays", type=positive_int, default=None,
                    help="rays per transmitter (default: tools/trace.py's, 3e5)")
    ap.add_argument("--sbr-spacing", type=float_in(*SBR_SPACING_WAVELENGTHS), default=None,
                    metavar="WAVELENGTHS",
                    help="SBR ray-tube pitch in wavelengths (default: tools/trace.py's)")
    ap.add_argument("--timeout", type=positive_float, default=1800.0,
                    help="seconds an extra scene may take before it is reported as failed "
                         "(default 1800)")
    ap.add_argument("--device", default=None,
                    help="OpenCL device: a name (pocl, intel, nvidia, amd, oclgrind), 'gpu', "
                         "'cpu', 'P:D' or part of its name; 'all' or a comma-separated list "
                         "compares devices (every implementation present but Oclgrind)")
    ap.add_argument("--out", type=output_folder, default=None,
                    help="folder for bench_trace.csv (default: a new temporary folder)")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return run_tool("bench_trace.py", run, args)


def settings_for(args, scene):
    return main_job_settings(scene, args.rays, args.sbr_spacing)


def device_runtimes(spec: str | None) -> dict[str, Runtime] | None:
    """The runtimes of a multi-device run: 'all' (every implementation present, Oclgrind
    only when named), or a comma-separated list of device specs; None for one device."""
    if spec is None or (spec.strip().lower() != "all" and "," not in spec):
        return None
    if spec.strip().lower() == "all":
        names = list(dict.fromkeys(i.vendor for i in list_devices() if not i.simulator))
    else:
        names = [t.strip() for t in spec.split(",") if t.strip()]
    out = {}
    for name in names:
        rt = get_runtime(name)
        out.setdefault(name if name in VENDOR_NAMES else rt.info.vendor, rt)
    return out


def run(args) -> int:
    rows: list[tuple] = []
    runtimes = device_runtimes(args.device)
    if runtimes is None:
        runtime = get_runtime(args.device)
        print(f"device: {runtime.info.describe()}")
        if args.street is not None:
            rows += bench_street(args, runtime)
        for path in args.extra:
            rows += bench_extra(args, path)
    else:
        for rt in runtimes.values():
            print(f"device: {rt.info.describe()}")
        if args.street is not None:
            rows += bench_devices(args, runtimes)
        for name, rt in runtimes.items():
            for path in args.extra:
                rows += bench_extra(args, path, device=rt.info.spec, label=name)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_trace-"))
    out.mkdir(parents=True, exist_ok=True)
    csv_path = write_csv(out / "bench_trace.csv", rows, CSV_HEADER)
    print(f"\nnumbers in {csv_path}")
    return 0


def bench_street(args, runtime) -> list[tuple]:
    scene = load_scene(args.street)
    settings = settings_for(args, args.street)
    check_launch_memory(settings, argument="--rays", value=settings.specular.rays)
    print(f"\n{scene.name}: {len(scene.triangles)} triangles, {len(scene.radars)} radars, "
          f"{settings.specular.rays} rays, {args.repeats} timed traces per engine")
    runs = compare_engines(scene, settings, runtime, repeats=args.repeats,
                           progress=lambda m: print(f"  {m}", flush=True))
    med = {e: median_timing(t) for e, t in runs.items()}
    dev, host = med["device"], med["host"]
    print(f"\n  {'median seconds':<22} {'device':>9} {'host':>9} {'host/device':>12}")
    for stage in dict.fromkeys([*dev.stages, *host.stages]):
        d, h = dev.stages.get(stage, 0.0), host.stages.get(stage, 0.0)
        print(f"  {stage:<22} {d:9.3f} {h:9.3f} {_ratio(h, d):>12}")
    ratio = host.seconds / dev.seconds if dev.seconds > 0 else float("inf")
    print(f"  {'whole trace':<22} {dev.seconds:9.3f} {host.seconds:9.3f} "
          f"{_ratio(host.seconds, dev.seconds):>12}   (target >= {TARGET_RATIO:g})")
    print(f"  {'inside kernels':<22} {dev.kernel_seconds:9.3f} {host.kernel_seconds:9.3f}")
    print(f"  share in kernels: device {dev.kernel_share:.1%}, host {host.kernel_share:.1%}"
          f"   (target >= {TARGET_KERNEL_SHARE:.0%} for the device)")
    print(f"  paths: device {dev.n_paths}, host {host.n_paths}")
    rows = []
    for engine in runs:
        for i, t in enumerate(runs[engine]):
            rows += [(scene.name, engine, f"run{i + 1}:{q}", v, u)
                     for _, _, q, v, u in timing_rows(scene.name, t)[:3]]
        rows += [(s, e, f"median:{q}", v, u) for s, e, q, v, u in
                 timing_rows(scene.name, med[engine])]
    rows.append((scene.name, "", "host_over_device", f"{ratio:.6g}", "1"))
    return rows


def bench_devices(args, runtimes) -> list[tuple]:
    """The street's main job with the device engine on every device of ``runtimes``."""
    scene = load_scene(args.street)
    settings = settings_for(args, args.street)
    check_launch_memory(settings, argument="--rays", value=settings.specular.rays)
    print(f"\n{scene.name}: {len(scene.triangles)} triangles, {len(scene.radars)} radars, "
          f"{settings.specular.rays} rays, device engine on {', '.join(runtimes)}, "
          f"{args.repeats} timed traces each")
    runs = compare_devices(scene, settings, runtimes, repeats=args.repeats,
                           progress=lambda m: print(f"  {m}", flush=True))
    rows = []
    for name, r in list(runs.items()):
        if r.error:
            print(f"  {name}: FAILED: {r.error}")
            rows.append((scene.name, name, "error", r.error, ""))
            del runs[name]
    if not runs:
        return rows
    med = {name: median_timing(r.runs) for name, r in runs.items()}
    ref = "pocl" if "pocl" in runs else next(iter(runs))
    names = list(runs)
    width = max(10, *(len(n) + 1 for n in names))
    print(f"\n  {'median seconds':<22}" + "".join(f"{n:>{width}}" for n in names))
    for stage in dict.fromkeys(s for t in med.values() for s in t.stages):
        print(f"  {stage:<22}" + "".join(f"{med[n].stages.get(stage, 0.0):>{width}.3f}"
                                         for n in names))
    print(f"  {'whole trace':<22}" + "".join(f"{med[n].seconds:>{width}.3f}" for n in names))
    print(f"  {'inside kernels':<22}" + "".join(f"{med[n].kernel_share:>{width}.1%}"
                                                for n in names))
    print(f"  {'first trace (builds)':<22}" + "".join(f"{runs[n].first.seconds:>{width}.2f}"
                                                      for n in names))
    print(f"  {'time / ' + ref:<22}" + "".join(
        f"{_ratio(med[n].seconds, med[ref].seconds):>{width}}" for n in names))
    print(f"  {'paths':<22}" + "".join(f"{med[n].n_paths:>{width}d}" for n in names))
    wf = Waveform(carrier_hz=scene.carrier_hz)
    nf = radar_noise(scene, argparse.Namespace(no_noise=False))
    a = scene.radar_index("A") if any(r.name == "A" for r in scene.radars) else None
    for name in names:
        agree = channel_agreement_db(runs[name].snapshot, runs[ref].snapshot, wf)
        if name != ref:
            print(f"  {name} channel against {ref} (NMSE): " + ", ".join(
                f"{k} {v:.1f} dB" for k, v in agree.items()))
        rows += [(scene.name, name, f"nmse_vs_{ref}:{k}", f"{v:.4f}", "dB")
                 for k, v in agree.items() if name != ref]
        if a is not None and nf.get(a) is not None:
            found = table_iii_detections(scene, runs[name].snapshot, wf, nf[a], "A")
            print(f"  {name} radar A detections (R m, v m/s): " + ", ".join(
                f"{obj} " + ("missed" if d is None else f"{d[0]:.2f} / {d[1]:.2f}")
                for obj, d in found.items()))
            rows += [(scene.name, name, f"detection_range:{obj}",
                      "" if d is None else f"{d[0]:.4f}", "m") for obj, d in found.items()]
        rows += [(s, name, q, v, u) for s, _, q, v, u in timing_rows(scene.name, med[name])]
        rows += [(scene.name, name, "first_trace_s", f"{runs[name].first.seconds:.6f}", "s"),
                 (scene.name, name, "device", runs[name].label, ""),
                 (scene.name, name, f"time_over_{ref}",
                  f"{med[name].seconds / med[ref].seconds:.6g}", "1")]
    print("  (the paper's Table III, its own simulation: " + ", ".join(
        f"car{car} {row['range_sim_m']:.2f} / {row['v_rel_sim_mps']:.2f}"
        for car, row in TABLE_III.items()) + ")")
    return rows


def bench_extra(args, path, device: str | None = None, label: str = "device"
                ) -> list[tuple]:
    scene = load_scene(path)
    settings = settings_for(args, path)
    device = args.device if device is None else device
    where = "" if label == "device" else f" on {label}"
    print(f"\n{scene.name}: {len(scene.triangles)} triangles, device engine{where}, own "
          f"process ...", flush=True)
    res = run_in_subprocess(path, settings, device, timeout_s=args.timeout)
    gib = res.peak_rss_bytes / 2**30
    rows = [(scene.name, label, "ok", str(int(res.ok)), "1"),
            (scene.name, label, "peak_rss", f"{gib:.4f}", "GiB"),
            (scene.name, label, "process_s", f"{res.wall_seconds:.4f}", "s")]
    for text in res.warnings:
        print(f"  warning: {text}")
    rows.append((scene.name, label, "warnings", str(len(res.warnings)), "1"))
    if not res.ok:
        print(f"  FAILED after {res.wall_seconds:.1f} s: {res.error}")
        print(f"  peak memory {gib:.2f} GiB")
        return rows
    t = res.timing
    print(f"  trace {t.seconds:.2f} s ({t.kernel_share:.0%} in kernels), {t.n_paths} paths, "
          f"peak memory {gib:.2f} GiB (target < {TARGET_PEAK_GIB:g}; "
          f"{res.rss_before_trace_bytes / 2**30:.2f} GiB before the trace)")
    print("  " + ", ".join(f"{k} {v:.2f} s" for k, v in t.stages.items()))
    rows += [(s, label, q, v, u) for s, _, q, v, u in timing_rows(scene.name, t)]
    check = plate_rcs(scene, res.links)
    if check is not None:
        d_all, d_po = check.all_dbsm - check.expected_dbsm, check.po_dbsm - check.expected_dbsm
        print(f"  plate {check.area_m2:g} m^2 at {check.range_m:g} m, "
              f"{check.incidence_deg:.2f} deg off broadside: 4 pi A^2/lambda^2 = "
              f"{check.expected_dbsm:.3f} dBsm; all paths {check.all_dbsm:.3f} dBsm "
              f"({d_all:+.3f} dB), PO/SBR paths {check.po_dbsm:.3f} dBsm ({d_po:+.3f} dB)"
              f"   (target within {TARGET_PLATE_DB:g} dB)")
        rows += [(scene.name, label, "rcs_expected", f"{check.expected_dbsm:.4f}", "dBsm"),
                 (scene.name, label, "rcs_all_paths", f"{check.all_dbsm:.4f}", "dBsm"),
                 (scene.name, label, "rcs_po_paths", f"{check.po_dbsm:.4f}", "dBsm")]
    return rows


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}" if b > 0 else "-"


if __name__ == "__main__":
    sys.exit(main())
