#!/usr/bin/env python3
"""Benchmark: the cost of one time step of a moving scene, the two-level BVH
(clradcom.mechanisms.common.GeometryCache) against a full rebuild (build_geometry on
scene_at(scene, t)), on the paper's street with its static objects subdivided.

    python tools/bench_steps.py [--levels 3] [--steps 5] [--rays 200000]

The street (scenes/street/street.toml, 4 moving cars) has every triangle of its static
objects (road, buildings, trees) split into four by its edge midpoints ``--levels``
times (3: 21 k -> ~1.2 M triangles); the cars keep their meshes. Printed:

* set-up: a full build (faces + BVH + upload) against the cache's one-time build
  (faces + one bottom-level tree per part);
* per step (median of ``--steps`` steps 0.05 s apart): the full rebuild (scene_at +
  faces + BVH build + upload) against the cache's step (scene_at + top-level tree +
  head upload + moved parts' normals and faces), with the parts of each, and the ratio,
  for both placements of the moving objects: "transform" (instances) and "refit" (their
  Tri4 groups rewritten and boxes refit);
* ray casting at the last step: closest hits of ``--rays`` rays from car A's radar
  through the single-level BVH of the rebuild and the two-level BVHs (rays per second,
  the same hits).

Numbers vary by +-20 % on the shared 2-core machine; docs/bvh.md records a run.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from clradcom.cli import positive_int, run_tool
from clradcom.device.raycast import RayCaster, make_rays
from clradcom.device.runtime import get_runtime
from clradcom.geometry.faces import merge_coplanar
from clradcom.mechanisms.common import GeometryCache, moving_objects
from clradcom.scene.motion import scene_at
from clradcom.scene.reader import load_scene

STREET = Path(__file__).resolve().parent.parent / "scenes" / "street" / "street.toml"


def split4(tri: np.ndarray) -> np.ndarray:
    """Every triangle (T, 3, 3) into four by its edge midpoints, in place order."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    return np.stack([np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c),
                                                (ab, bc, ca))], 1).reshape(-1, 3, 3)


def subdivided(scene, levels: int):
    """``scene`` with the triangles of its non-moving objects split ``levels`` times."""
    moving = set(moving_objects(scene))
    tris, objs, mats, objects = [], [], [], []
    start = 0
    for i, o in enumerate(scene.objects):
        t = scene.triangles[o.tri_slice]
        if i not in moving:
            for _ in range(levels):
                t = split4(t)
        tris.append(t)
        objs.append(np.full(len(t), i, np.int32))
        mats.append(np.full(len(t), o.material, np.int32))
        objects.append(dataclasses.replace(o, tri_start=start, tri_stop=start + len(t)))
        start += len(t)
    return dataclasses.replace(scene, triangles=np.concatenate(tris),
                               tri_object=np.concatenate(objs),
                               tri_material=np.concatenate(mats), objects=objects)


def full_step(scene, t, runtime):
    """A full rebuild: (seconds per part, the caster)."""
    t0 = time.perf_counter()
    s = scene_at(scene, t)
    t1 = time.perf_counter()
    merge_coplanar(s.triangles, s.tri_object, s.tri_material)
    t2 = time.perf_counter()
    caster = RayCaster(s.triangles, runtime=runtime)
    t3 = time.perf_counter()
    return {"scene_at": t1 - t0, "faces": t2 - t1, "bvh+upload": t3 - t2,
            "total": t3 - t0}, caster


def run(args) -> int:
    rt = get_runtime()
    scene = subdivided(load_scene(STREET), args.levels)
    n_mov = sum(scene.objects[i].n_triangles for i in moving_objects(scene))
    print(f"street, static objects split {args.levels}x: {len(scene.triangles):,} triangles "
          f"({len(moving_objects(scene))} moving objects, {n_mov:,} triangles); "
          f"device {rt.info.device_name.strip()}")
    t0 = time.perf_counter()
    full_step(scene, 0.0, rt)
    t_full0 = time.perf_counter() - t0
    caches = {}
    for placement in GeometryCache.PLACEMENTS:
        t0 = time.perf_counter()
        caches[placement] = GeometryCache(scene, rt, placement=placement)
        print(f"set-up: full build {t_full0:.3f} s, cache build ({placement}) "
              f"{time.perf_counter() - t0:.3f} s")
    times = [0.05 * (k + 1) for k in range(args.steps)]
    full = []
    cached = {p: [] for p in caches}
    placed = {p: [] for p in caches}
    flat = None
    geoms = {}
    for t in times:   # alternate, so all see the same load
        f, flat = full_step(scene, t, rt)
        full.append(f)
        for p, cache in caches.items():
            t0 = time.perf_counter()
            geoms[p] = cache.at(t)
            cached[p].append(dict(cache.last_times, total=time.perf_counter() - t0))
            placed[p].append(cache.caster.last_times)

    def med(rows, key):
        return float(np.median([r[key] for r in rows]))

    print(f"per step (median of {args.steps}):")
    print("  full rebuild       " + ", ".join(f"{k} {med(full, k) * 1e3:.1f} ms"
                                              for k in full[0]))
    for p in caches:
        print(f"  two-level {p:10s}" + ", ".join(f"{k} {med(cached[p], k) * 1e3:.1f} ms"
                                                for k in cached[p][0]))
        print("    place          " + ", ".join(f"{k} {med(placed[p], k) * 1e3:.2f} ms"
                                                for k in placed[p][0]))
        print(f"    ratio full / two-level ({p}): whole step "
              f"{med(full, 'total') / med(cached[p], 'total'):.1f}x")
    # ray casting through all at the last step
    radar = geoms["transform"].scene.radars[0]
    rng = np.random.default_rng(0)
    d = rng.normal(size=(args.rays, 3))
    d[:, 0] = np.abs(d[:, 0])   # the forward half-space of car A's radar
    rays = make_rays(np.tile(radar.position, (args.rays, 1)) + 0.05 * np.array([1, 0, 0]), d)
    best = {}
    hits = {}
    casters = {"single-level": flat, **{f"two-level {p}": g.caster for p, g in geoms.items()}}
    for _ in range(3):
        for name, caster in casters.items():
            t0 = time.perf_counter()
            hits[name] = caster.closest_hit(rays)
            best[name] = min(best.get(name, np.inf), time.perf_counter() - t0)
    print(f"closest hit, {args.rays:,} rays from {radar.name}: " + ", ".join(
        f"{k} {args.rays / v / 1e6:.2f} Mrays/s" for k, v in best.items()))
    for name in list(casters)[1:]:
        same = (hits["single-level"]["prim"] == hits[name]["prim"]).mean()
        print(f"  {name}: time / single-level {best[name] / best['single-level']:.2f}, "
              f"same hit {same * 100:.3f} %, bit-identical hits "
              f"{(hits['single-level'] == hits[name]).mean() * 100:.3f} %")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--levels", type=int, default=3, choices=range(0, 5),
                    help="times the static triangles are split into four (default 3)")
    ap.add_argument("--steps", type=positive_int, default=5)
    ap.add_argument("--rays", type=positive_int, default=200_000)
    return run_tool("bench_steps.py", run, ap.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
