#!/usr/bin/env python3
"""Scaling of a sweep or a drive on Dask: the same traces serially, then on local
clusters of 1 and 2 (``--workers``) processes, with the speed-up against 1 worker and the
check that every snapshot equals the serial run's bit for bit.

    python tools/bench_scale.py                       8 traces of the street, preset fast
    python tools/bench_scale.py --traces 16 --rays 200000 --workers 1,2,4
    python tools/bench_scale.py --drive 8             the street's drive, its first 8 steps
    python tools/bench_scale.py --drive 8 --chunk 1   one task per step (default: the steps
                                                      shared out, one chunk per worker)

Each cluster is started and warmed first (every worker opens its device and builds the
kernels on one small trace, through ``client.run``), so the timed part is the sweep
itself: submit to the last result in. The start and warm-up times are printed too. On
PoCL's CPU device each worker gets cores // workers threads (clradcom.distributed).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import distributed

from clradcom import distributed as cd
from clradcom.commands.options import list_of, positive_int
from clradcom.presets import PRESETS
from clradcom.scene.reader import load_scene
from clradcom.snapshot import assert_snapshot_equal
from clradcom.trace import TraceSettings

ROOT = Path(__file__).resolve().parents[1]


def _warm(scene, settings):
    """Open this worker's device and build every kernel the sweep uses."""
    cd.trace_task(scene, settings)
    return cd.worker_runtime().info.describe()


def _cpu_seconds() -> float:
    """CPU seconds of this process so far, every thread (PoCL's too)."""
    return time.process_time()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "street" / "street.toml"))
    ap.add_argument("--preset", choices=tuple(PRESETS), default="fast")
    ap.add_argument("--rays", type=positive_int, default=100_000)
    ap.add_argument("--traces", type=positive_int, default=8)
    ap.add_argument("--workers", type=list_of(positive_int, "worker count"), default=[1, 2])
    ap.add_argument("--no-serial", action="store_true", help="skip the serial run")
    ap.add_argument("--drive", type=positive_int, default=None, metavar="STEPS",
                    help="time a drive of this many steps of --drive-scene instead")
    ap.add_argument("--drive-scene",
                    default=str(ROOT / "scenes" / "street" / "street_drive.toml"))
    ap.add_argument("--chunk", type=positive_int, default=None,
                    help="steps per task of the drive (default: one chunk per worker)")
    args = ap.parse_args(argv)

    scene = load_scene(args.drive_scene if args.drive else args.scene)
    small = TraceSettings.preset(args.preset, specular__rays=1000)
    if args.drive:  # one settings, the scene's instants
        settings = TraceSettings.preset(args.preset, specular__rays=args.rays)
        times = scene.time_axis.times[:args.drive]
        n_traces = len(times)

        def run(n, **where):  # the chunks' results, one per step (cd.run_drive's tasks)
            chunk = args.chunk or cd.steps_per_task(len(times), n)
            done = cd.run_tasks(cd.drive_tasks(scene, settings, times, chunk=chunk), **where)
            return [cd.TaskResult(r.key, snap, s, r.worker) for r in done
                    for snap, s in zip(*r.value, strict=True)]
        what = (f"a drive of {n_traces} steps ({times[0]:g} to {times[-1]:g} s, chunk "
                f"{args.chunk or 'one per worker'})")
    else:
        # distinct traces: the rays differ by one per task (same work, different snapshots)
        tasks = cd.trace_tasks(scene, [TraceSettings.preset(args.preset,
                                                            specular__rays=args.rays + i)
                                       for i in range(args.traces)])
        n_traces = args.traces

        def run(n, **where):
            return cd.run_tasks(tasks, **where)
        what = f"{n_traces} traces"
    print(f"{what} of {scene.name} ({len(scene.triangles)} triangles), preset "
          f"{args.preset}, {args.rays} rays; {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f} (other processes share the machine: the CPU seconds "
          "per wall second below say how many cores the run really had)")

    serial = None
    if not args.no_serial:
        _warm(scene, small)
        t0, c0 = time.perf_counter(), _cpu_seconds()
        serial = run(1, workers=0)
        t_serial, c_serial = time.perf_counter() - t0, _cpu_seconds() - c0
        print(f"serial (this process, {cd.worker_runtime().info.describe()}): "
              f"{t_serial:7.2f} s, {t_serial / n_traces:.2f} s per trace, "
              f"{c_serial / t_serial:.2f} CPU s per s")

    base = None
    for n in args.workers:
        t0 = time.perf_counter()
        with cd.local_cluster(n) as cluster, distributed.Client(cluster) as client:
            t_start = time.perf_counter() - t0
            t1 = time.perf_counter()
            devices = client.run(_warm, scene, small)
            t_warm = time.perf_counter() - t1
            c0 = sum(client.run(_cpu_seconds).values())
            t1 = time.perf_counter()
            results = run(n, client=client)
            t_run = time.perf_counter() - t1
            cpu = sum(client.run(_cpu_seconds).values()) - c0
        base = base or t_run
        same = "-"
        if serial is not None:
            for got, want in zip(results, serial, strict=True):
                assert_snapshot_equal(got.value, want.value)
            same = "yes"
        per_worker = {}
        for r in results:
            per_worker[r.worker] = per_worker.get(r.worker, 0) + 1
        kind = "drive" if args.drive else "sweep"
        print(f"{n} worker(s): {kind} {t_run:7.2f} s (start {t_start:.1f} s, warm-up "
              f"{t_warm:.1f} s), speed-up against {args.workers[0]} worker(s) {base / t_run:.2f}x; "
              f"traces per worker {dict(sorted(per_worker.items()))}; identical to serial: "
              f"{same}; {cpu / t_run:.2f} CPU s per s; device "
              f"{sorted(set(devices.values()))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
