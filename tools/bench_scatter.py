#!/usr/bin/env python3
"""Scattering-stage time on the street: tiles on the device against the host reference.

For each link and number of reflections around a tile, times
``clradcom.mechanisms.scattering.link_paths`` (default settings: tile size by the rule,
-60 dB threshold) with ``engine="device"`` (kernels/scatter.cl: tiles, sight of tx and
rx, Lambertian power) and ``engine="host"`` (numpy tiles, casts through the caster),
both warm, best of ``--repeat``; the two must emit the same number of paths.

    python tools/bench_scatter.py [--scene PATH] [--device SPEC] [--links A:A,A:D]
                                  [--reflections 0,1] [--repeat 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from clradcom.cli import int_in, list_of, positive_int, run_tool
from clradcom.device.runtime import get_runtime
from clradcom.mechanisms import scattering
from clradcom.mechanisms.common import build_geometry
from clradcom.scene.reader import load_scene

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_paths import parse_links  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="scenes/street/street.toml")
    ap.add_argument("--links", default="A:A,A:D")
    ap.add_argument("--device", default=None)
    ap.add_argument("--reflections", type=list_of(int_in(0, 2), "reflections"), default=[0, 1])
    ap.add_argument("--repeat", type=positive_int, default=3)
    args = ap.parse_args(argv)
    return run_tool("bench_scatter.py", run, args)


def _best(geom, tx, rx, settings, repeat):
    """Best warm time of one link's scattering stage, and its paths."""
    scattering.link_paths(geom, None, tx, rx, settings)  # warm: kernels built
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = scattering.link_paths(geom, None, tx, rx, settings)
        best = min(best, time.perf_counter() - t0)
    return best, out


def run(args) -> int:
    scene = load_scene(args.scene)
    links = parse_links(scene, args.links)
    rt = get_runtime(args.device)
    device = build_geometry(scene, rt)
    host = build_geometry(scene, rt, engine="host")
    host.caster = device.caster
    print(f"device : {rt.info.describe()}")
    print(f"scene  : {scene.name}, {len(scene.triangles)} triangles")
    print(f"\n{'link':>6} {'refl.':>5} {'paths':>7} {'host s':>8} {'device s':>9} {'ratio':>6}")
    for mr in args.reflections:
        settings = scattering.ScatteringSettings(enabled=True, max_reflections=mr)
        for t, r in links:
            tx, rx = scene.radars[t], scene.radars[r]
            th, ph = _best(host, tx, rx, settings, args.repeat)
            td, pd = _best(device, tx, rx, settings, args.repeat)
            if pd.n_paths != ph.n_paths:
                print(f"{tx.name}:{rx.name}: device {pd.n_paths} paths, host {ph.n_paths}",
                      file=sys.stderr)
                return 1
            print(f"{tx.name + ':' + rx.name:>6} {mr:>5} {ph.n_paths:>7} {th:>8.3f} {td:>9.3f} "
                  f"{th / td:>6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
