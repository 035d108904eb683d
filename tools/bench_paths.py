#!/usr/bin/env python3
"""Path-tracer throughput: time per snapshot and paths per second on the street.

For reflection orders 1..5 and several ray densities, traces radar A's
monostatic link and its bistatic link to radar D in scenes/street/street.toml
(>= 15 k triangles; candidates from A's rays serve both links) and prints
the time of each stage (candidate search on the OpenCL device, specular paths:
exact image method + confirmation casts + fields) and the number of paths found.
The number of paths at the densest setting of each order shows convergence.

A second table gives the cost of each diffraction order (0-3 edges per path, with 0 or 1
reflection beside the edges): paths found per interaction pattern and the time of the
diffraction stage (candidate search, exact points, confirmation casts, UTD fields).

A third table gives the cost of one edge with up to R reflections on one side of it
(the rays' face sequences as prefixes and suffixes, order R specular search): the
diffraction stage of the links with the image-method pre-test of its candidates, against
the same stage with every candidate through the exact tests (the reference, measured in
the same run), and whether both give the same paths bit for bit.

Context (not measured here): Sionna RT 2.2 on this machine's CPU, reflections
<= 5 + first-order diffraction on a 16 k-triangle street: 1e6 rays in 1.6 s,
~1,100 paths (docs/performance.md, "Peer figures").

    python tools/bench_paths.py [--scene PATH] [--device SPEC] [--orders 1,2,3,4,5]
                                [--rays 100000,300000,1000000]
                                [--diffraction-orders 0,1,2,3] [--diffraction-rays 300000]
                                [--edge-reflections 4] [--edge-reflection-rays 100000]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from clradcom.cli import int_in, list_of, positive_int, run_tool
from clradcom.device.runtime import get_runtime
from clradcom.errors import ArgumentError
from clradcom.mechanisms import diffraction, specular
from clradcom.mechanisms.common import build_geometry, seen_by_antennas
from clradcom.paths import concat_paths, pattern_counts
from clradcom.scene.reader import load_scene
from clradcom.trace import (
    DiffractionSettings,
    SpecularSettings,
    StageTimes,
    TraceSettings,
    trace_scene,
)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="scenes/street/street.toml")
    ap.add_argument("--links", default="A:A,A:D",
                    help="tx:rx links to trace together (default A:A,A:D - monostatic and "
                         "the bistatic link to the radar on car D)")
    ap.add_argument("--device", default=None)
    ap.add_argument("--orders", type=_optional(list_of(int_in(1, 16), "order")),
                    default=[1, 2, 3, 4, 5], help="reflection orders of the first table "
                                                  "('' skips it)")
    ap.add_argument("--rays", type=list_of(positive_int, "ray count"),
                    default=[100_000, 300_000, 1_000_000])
    ap.add_argument("--diffractions", type=int, choices=(0, 1, 2, 3), default=1,
                    help="UTD edge diffractions per path in the first table (default 1)")
    ap.add_argument("--diffraction-orders", type=_optional(list_of(int_in(0, 3), "order")),
                    default=[0, 1, 2, 3],
                    help="diffraction orders of the second table ('' skips it)")
    ap.add_argument("--diffraction-rays", type=positive_int, default=300_000)
    ap.add_argument("--diffraction-reflections", type=list_of(int_in(0, 16), "order"),
                    default=[0, 1], help="reflections beside the edges in the second table")
    ap.add_argument("--edge-reflections", type=_optional(list_of(int_in(1, 16), "order")),
                    default=[4], help="reflections beside one edge in the third table "
                                      "('' skips it; default 4)")
    ap.add_argument("--edge-reflection-rays", type=positive_int, default=100_000,
                    help="rays per transmitter in the third table (default 100000)")
    args = ap.parse_args(argv)
    return run_tool("bench_paths.py", run, args)


def _optional(parse):
    """'' for none, else ``parse``."""
    def inner(text):
        return [] if not str(text).strip() else parse(text)
    inner.__name__ = parse.__name__
    return inner


def parse_links(scene, text) -> list[tuple[int, int]]:
    """tx:rx pairs of radar names, each name checked against the scene."""
    links = []
    for pair in text.split(","):
        names = pair.strip().split(":")
        if len(names) != 2 or not all(names):
            raise ArgumentError("wants tx:rx pairs of radar names, comma separated (A:A,A:D)",
                                argument="--links", value=text)
        for name in names:
            if name not in [r.name for r in scene.radars]:
                raise ArgumentError(f"radar {name!r} is not in {scene.name!r} (radars: "
                                    f"{[r.name for r in scene.radars]})", argument="--links",
                                    value=text)
        links.append(tuple(scene.radar_index(n) for n in names))
    return links


def run(args) -> int:
    scene = load_scene(args.scene)
    links = parse_links(scene, args.links)
    rt = get_runtime(args.device)
    print(f"device : {rt.info.describe()}")
    print(f"scene  : {scene.name}, {len(scene.triangles)} triangles, links {args.links}")
    # warm up: geometry, kernels compiled
    trace_scene(scene, TraceSettings(specular=SpecularSettings(max_reflections=1, rays=1000)),
                runtime=rt, links=links)
    if args.orders:
        paths_table(scene, rt, links, args)
    if args.diffraction_orders:
        diffraction_table(scene, rt, links, args)
    if args.edge_reflections:
        edge_reflections_table(scene, rt, links, args)
    return 0


def paths_table(scene, rt, links, args):
    print(f"diffractions per path: {args.diffractions}")
    print(f"\n{'order':>5} {'rays':>9} {'refl.':>6} {'diffr.':>6} {'geometry':>9} "
          f"{'candid.':>9} {'specular':>9} {'wedges':>8} {'UTD':>7} {'total s':>8} "
          f"{'paths/s':>9}")
    for order in args.orders:
        for rays in args.rays:
            times = StageTimes()
            t0 = time.perf_counter()
            settings = TraceSettings(
                specular=SpecularSettings(max_reflections=order, rays=rays),
                diffraction=DiffractionSettings(max_diffractions=args.diffractions))
            snap = trace_scene(scene, settings, runtime=rt, links=links, times=times)
            total = time.perf_counter() - t0
            s = times.seconds
            n = snap.total_paths
            n_diff = sum(pattern_counts([lk.paths for lk in snap], containing="D").values())
            print(f"{order:>5} {rays:>9} {n - n_diff:>6} {n_diff:>6} "
                  f"{s.get('geometry', 0):>9.3f} {s.get('specular candidates', 0):>9.3f} "
                  f"{s.get('specular', 0):>9.3f} "
                  f"{s.get('wedges', 0):>8.3f} {s.get('diffraction', 0):>7.3f} "
                  f"{total:>8.2f} {n / total:>9.1f}")


def edge_reflections_table(scene, rt, links, args):
    rays = args.edge_reflection_rays
    print(f"\none edge with reflections ({rays} rays, specular order = reflections): the "
          "diffraction stage with the candidates' pre-test against every candidate through "
          "the exact tests (reference)")
    print(f"{'refl.':>5} {'wedges':>7} {'candidates':>11} {'passed':>11} {'paths':>6} "
          f"{'pre-test s':>10} {'reference s':>11} {'speed-up':>8}  same paths")
    geom = build_geometry(scene, rt)
    for refl in args.edge_reflections:
        spec = SpecularSettings(max_reflections=refl, rays=rays)
        budget = DiffractionSettings(max_diffractions=1, max_reflections=refl)
        wedges = diffraction.prepare(geom, budget)
        sequences = {i: specular.prepare(geom, scene.radars[i], spec)
                     for i in dict.fromkeys(i for link in links for i in link)}
        results = {}
        for pretest in (True, False):
            seeing, parts, stats = {}, [], {"candidates": 0, "pretested": 0}
            t0 = time.perf_counter()
            for t, r in links:
                tx, rx = scene.radars[t], scene.radars[r]
                found, counts = diffraction.diffraction_link_paths(
                    scene, geom.faces, geom.caster, wedges, tx, rx, sequences[t],
                    sequences[r], budget, seeing=seeing, engine=geom.engine,
                    keep_fn=lambda d, a, tx=tx, rx=rx: seen_by_antennas(tx, rx, d, a),
                    pretest=pretest)
                parts.extend(found)
                for key in stats:
                    stats[key] += counts.get(key, 0)
            results[pretest] = (time.perf_counter() - t0, stats,
                                concat_paths(parts) if parts else None)
        (fast, st, got), (slow, st_ref, ref) = results[True], results[False]
        same = (got is None and ref is None) or (
            got is not None and ref is not None and got.n_paths == ref.n_paths and all(
                np.array_equal(getattr(got, k), getattr(ref, k), equal_nan=True)
                for k in ("gain", "matrix", "delay_s", "doppler_hz", "points", "interaction",
                          "object_id", "face_id")))
        n = 0 if got is None else got.n_paths
        print(f"{refl:>5} {len(wedges):>7} {st_ref['candidates']:>11} {st['candidates']:>11} "
              f"{n:>6} {fast:>10.2f} {slow:>11.2f} {slow / fast:>7.1f}x  "
              f"{'yes' if same else 'NO'}")


def diffraction_table(scene, rt, links, args):
    print(f"\ncost of each diffraction order (reflection order 2, {args.diffraction_rays} rays)")
    print(f"{'edges':>5} {'refl.':>5} {'candidates':>11} {'over cap':>10} {'paths':>6} "
          f"{'UTD s':>7} {'total s':>8}  paths per pattern")
    for order in args.diffraction_orders:
        for refl in args.diffraction_reflections:
            if order == 0 and refl:
                continue
            times = StageTimes()
            t0 = time.perf_counter()
            settings = TraceSettings(
                specular=SpecularSettings(max_reflections=2, rays=args.diffraction_rays),
                diffraction=DiffractionSettings(max_diffractions=order, max_reflections=refl))
            snap = trace_scene(scene, settings, runtime=rt, links=links, times=times)
            total = time.perf_counter() - t0
            meta = snap.metadata
            counts = pattern_counts([lk.paths for lk in snap], containing="D")
            print(f"{order:>5} {refl:>5} {meta.get('diffraction.candidates', 0):>11} "
                  f"{meta.get('diffraction.chains_over_cap', 0):>10} {sum(counts.values()):>6} "
                  f"{times.seconds.get('diffraction', 0.0):>7.2f} {total:>8.2f}  "
                  + " ".join(f"{k}:{v}" for k, v in sorted(counts.items())))


if __name__ == "__main__":
    sys.exit(main())
