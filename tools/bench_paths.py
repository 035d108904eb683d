#!/usr/bin/env python3
"""Path-tracer throughput: time per snapshot and paths per second on the street.

For reflection orders 1..5 and several ray densities, traces radar A's
monostatic link and its bistatic link to radar D in scenes/street/street.toml
(>= 15 k triangles; candidates from A's rays serve both links) and prints
the time of each stage (candidate search on the OpenCL device, exact image
method + confirmation casts, fields) and the number of paths found. The
number of paths at the densest setting of each order shows convergence.

Context (not measured here): Sionna RT 2.2 on this machine's CPU, reflections
<= 5 + first-order diffraction on a 16 k-triangle street: 1e6 rays in 1.6 s,
~1,100 paths (shared/DESIGN.md).

    python tools/bench_paths.py [--scene PATH] [--device SPEC] [--orders 1,2,3,4,5]
                                [--rays 100000,300000,1000000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from clradcom.opencl import get_runtime
from clradcom.scene import load_scene
from clradcom.snapshot import InteractionType
from clradcom.tracer import StageTimes, TraceSettings, trace_scene


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="scenes/street/street.toml")
    ap.add_argument("--links", default="A:A,A:D",
                    help="tx:rx links to trace together (default A:A,A:D - monostatic and "
                         "the bistatic link to the radar on car D)")
    ap.add_argument("--device", default=None)
    ap.add_argument("--orders", default="1,2,3,4,5")
    ap.add_argument("--rays", default="100000,300000,1000000")
    ap.add_argument("--diffractions", type=int, choices=(0, 1), default=1,
                    help="single UTD diffraction on (1, default) or off (0)")
    args = ap.parse_args(argv)
    scene = load_scene(args.scene)
    rt = get_runtime(args.device)
    links = [tuple(scene.radar_index(n) for n in pair.split(":"))
             for pair in args.links.split(",")]
    print(f"device : {rt.info.describe()}")
    print(f"scene  : {scene.name}, {len(scene.triangles)} triangles, links {args.links}")
    # warm up: geometry, kernels compiled
    trace_scene(scene, TraceSettings(max_reflections=1, rays=1000), runtime=rt, links=links)
    print(f"single diffraction: {'on' if args.diffractions else 'off'}")
    print(f"\n{'order':>5} {'rays':>9} {'refl.':>6} {'diffr.':>6} {'geometry':>9} "
          f"{'candid.':>9} {'exact':>9} {'fields':>8} {'wedges':>8} {'UTD':>7} {'total s':>8} "
          f"{'paths/s':>9}")
    for order in (int(x) for x in args.orders.split(",")):
        for rays in (int(x) for x in args.rays.split(",")):
            times = StageTimes()
            t0 = time.perf_counter()
            settings = TraceSettings(max_reflections=order, rays=rays,
                                     max_diffractions=args.diffractions)
            snap = trace_scene(scene, settings, runtime=rt, links=links, times=times)
            total = time.perf_counter() - t0
            s = times.seconds
            n = snap.total_paths
            n_diff = sum(int(np.sum(lk.paths.interaction == InteractionType.DIFFRACTION))
                         for lk in snap)
            print(f"{order:>5} {rays:>9} {n - n_diff:>6} {n_diff:>6} "
                  f"{s.get('geometry', 0):>9.3f} {s.get('candidates', 0):>9.3f} "
                  f"{s.get('exact paths', 0):>9.3f} {s.get('fields', 0):>8.3f} "
                  f"{s.get('wedges', 0):>8.3f} {s.get('diffraction', 0):>7.3f} "
                  f"{total:>8.2f} {n / total:>9.1f}")


if __name__ == "__main__":
    main()
