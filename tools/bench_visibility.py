#!/usr/bin/env python3
"""Specular and diffraction stage times with the visibility decisions on the device
(kernels/visibility.cl) against the host reference (numpy float64 rounds), same run.

    python tools/bench_visibility.py scenes/street/street.toml [--rays 1000000] [--repeat 3]

Traces every link of the scene with physical optics and scattering off (their own
visibility goes through surface_sees, unchanged here), once per engine to warm up
(kernel builds) and then ``--repeat`` times alternating the engines; prints the best
seconds per stage and engine and their ratio, and checks that both engines traced the
same paths bit for bit (they must: the device repeats the host's float64 rules).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from clradcom.device.runtime import get_runtime
from clradcom.scene import load_scene
from clradcom.trace import (
    DiffractionSettings,
    OpticsSettings,
    ScatteringSettings,
    SpecularSettings,
    StageTimes,
    TraceSettings,
    trace_scene,
)

STAGES = ("specular candidates", "specular", "diffraction")
FIELDS = ("gain", "delay_s", "doppler_hz", "points", "face_id", "n_interactions")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--reflections", type=int, default=5)
    ap.add_argument("--diffractions", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    runtime = get_runtime(args.device)
    scene = load_scene(args.scene)
    base = TraceSettings(
        specular=SpecularSettings(max_reflections=args.reflections, rays=args.rays),
        diffraction=DiffractionSettings(max_diffractions=args.diffractions),
        optics=OpticsSettings(mode="none"),
        scattering=ScatteringSettings(enabled=False))
    print(f"{scene.name}: {len(scene.triangles)} triangles, {args.rays} rays, "
          f"{args.reflections} reflections, {args.diffractions} diffraction(s); "
          f"{runtime.info.describe()}")
    best: dict[str, dict[str, float]] = {"host": {}, "device": {}}
    snaps = {}
    for rep in range(args.repeat + 1):
        for engine in ("host", "device"):
            times = StageTimes()
            snaps[engine] = trace_scene(scene, base.replace(engine=engine), runtime=runtime,
                                        times=times)
            if rep == 0:
                continue  # warm-up: kernel builds
            for stage in STAGES:
                t = times.seconds.get(stage, 0.0)
                best[engine][stage] = min(best[engine].get(stage, np.inf), t)
    same = True
    for a, b in zip(snaps["host"].links, snaps["device"].links, strict=True):
        for f in FIELDS:
            x, y = np.asarray(getattr(a.paths, f)), np.asarray(getattr(b.paths, f))
            same &= x.shape == y.shape and np.array_equal(x, y, equal_nan=True)
    n_paths = sum(link.paths.n_paths for link in snaps["device"].links)
    print(f"{'stage':<22}{'host s':>10}{'device s':>10}{'host/device':>13}")
    for stage in STAGES:
        h, d = best["host"][stage], best["device"][stage]
        print(f"{stage:<22}{h:>10.3f}{d:>10.3f}{h / d if d else np.nan:>13.2f}")
    h = best["host"]["specular"] + best["host"]["diffraction"]
    d = best["device"]["specular"] + best["device"]["diffraction"]
    print(f"{'specular+diffraction':<22}{h:>10.3f}{d:>10.3f}{h / d:>13.2f}")
    print(f"{n_paths} paths; engines agree bit for bit: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
