#!/usr/bin/env python3
"""Ray-casting throughput of clradcom's OpenCL kernels beside Intel Embree.

Both casters get exactly the same rays in the same run, on a synthetic street
of ~22 k triangles (clradcom.models.street_triangles):

  primary  rays from a radar on a car's front bumper over the paper's
           90 deg azimuth x 180 deg elevation sector (Fibonacci lattice)
  bounce   the specular reflections of the primary hits, leaving the
           surfaces they hit: incoherent secondary rays

Embree (the ``embreex`` package, ``pip install clradcom[bench]``) traces on
one thread per process, so it runs in as many processes as the machine has
cores, each on its share of the rays; its time is the slowest process's.
The ratio printed is clradcom's throughput over Embree's on the same cores.
BVH build times are set beside each other too.

    python tools/bench_raycast.py [--rays 1000000] [--device SPEC] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from clradcom.bvh import build_bvh
from clradcom.models import street_triangles
from clradcom.opencl import get_runtime
from clradcom.raycast import RayCaster, make_rays, spawn_origins


def sector_directions(n: int, az_half_deg=45.0) -> np.ndarray:
    """Fibonacci lattice on the sphere, kept within +-az_half_deg of +x (all elevations)."""
    k = np.arange(int(n * 360.0 / (2 * az_half_deg) * 1.05))
    z = 1.0 - 2.0 * (k + 0.5) / len(k)
    r = np.sqrt(1.0 - z * z)
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    return d[np.abs(az) <= az_half_deg][:n]


_EMBREE_SCENE = None


def _embree_worker_init(tris32):
    global _EMBREE_SCENE
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    _EMBREE_SCENE = rtcs.EmbreeScene()
    TriangleMesh(_EMBREE_SCENE, tris32)
    _EMBREE_SCENE.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))


def _embree_worker_run(args):
    origins, dirs = args
    t0 = time.perf_counter()
    out = _EMBREE_SCENE.run(origins, dirs, output=1)
    return time.perf_counter() - t0, out["primID"], out["tfar"]


def embree_build_time(tris32) -> float:
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        scene = rtcs.EmbreeScene()
        TriangleMesh(scene, tris32)
        scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))  # commit = build
        best = min(best, time.perf_counter() - t0)
    return best


def run_embree(pool, origins, dirs, n_proc, repeat):
    chunks = np.array_split(np.arange(len(origins)), n_proc)
    best = np.inf
    prim = tfar = None
    for _ in range(repeat):
        jobs = [(origins[c], dirs[c]) for c in chunks]
        results = list(pool.map(_embree_worker_run, jobs))
        best = min(best, max(r[0] for r in results))
        prim = np.concatenate([r[1] for r in results])
        tfar = np.concatenate([r[2] for r in results])
    return best, prim, tfar


def run_clradcom(caster, rays, repeat):
    caster.closest_hit(rays[:1024])  # compile and warm up
    best = np.inf
    hits = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        hits = caster.closest_hit(rays)
        best = min(best, time.perf_counter() - t0)
    return best, hits


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--rays", type=int, default=1_000_000, help="primary rays (default 1e6)")
    ap.add_argument("--device", default=None, help="OpenCL device spec (see: clradcom devices)")
    ap.add_argument("--repeat", type=int, default=3, help="timed repetitions, best kept")
    ap.add_argument("--no-embree", action="store_true", help="skip the Embree reference")
    args = ap.parse_args(argv)

    tris, _ = street_triangles(seed=0)
    tris32 = np.ascontiguousarray(tris, dtype=np.float32)
    runtime = get_runtime(args.device)
    print(f"device : {runtime.info.describe()}")
    print(f"scene  : synthetic street, {len(tris)} triangles")

    t0 = time.perf_counter()
    bvh = build_bvh(tris)
    t_build = time.perf_counter() - t0
    caster = RayCaster(tris, bvh=bvh, runtime=runtime)

    bumper = np.array([1.95, -1.75, 0.55])
    dirs = sector_directions(args.rays)
    primary = make_rays(np.broadcast_to(bumper, dirs.shape), dirs, tmin=1e-4)
    t_primary, hits = run_clradcom(caster, primary, args.repeat)

    ok = hits["prim"] >= 0
    p = bumper + hits["t"][ok, None] * dirs[ok]
    n = hits["ng"][ok].astype(np.float64)
    d_in = dirs[ok]
    d_out = d_in - 2.0 * np.einsum("ij,ij->i", d_in, n)[:, None] * n
    bounce = make_rays(spawn_origins(p, n, d_out), d_out, tmin=1e-4)
    t_bounce, bhits = run_clradcom(caster, bounce, args.repeat)

    rows = [("primary", len(primary), t_primary, hits), ("bounce", len(bounce), t_bounce, bhits)]
    n_proc = os.cpu_count() or 1
    embree = {}
    t_embree_build = None
    if not args.no_embree:
        try:
            import embreex  # noqa: F401
        except ImportError:
            print("embreex not installed (pip install 'clradcom[bench]'): no reference")
        else:
            t_embree_build = embree_build_time(tris32)
            with ProcessPoolExecutor(n_proc, initializer=_embree_worker_init,
                                     initargs=(tris32,)) as pool:
                for name, rays in (("primary", primary), ("bounce", bounce)):
                    o = np.ascontiguousarray(rays["org"])
                    d = np.ascontiguousarray(rays["dir"])
                    embree[name] = run_embree(pool, o, d, n_proc, args.repeat)

    print(f"\nBVH build: clradcom {t_build * 1e3:.1f} ms", end="")
    if t_embree_build is not None:
        print(f", Embree {t_embree_build * 1e3:.1f} ms  (ratio Embree/clradcom "
              f"{t_embree_build / t_build:.2f})")
    else:
        print()
    print(f"\n{'rays':<8} {'count':>9} {'clradcom':>14} {'Embree x' + str(n_proc):>14} "
          f"{'ratio':>7} {'same hit':>9}")
    for name, count, t, h in rows:
        mrays = count / t / 1e6
        line = f"{name:<8} {count:>9} {mrays:>9.2f} Mr/s"
        if name in embree:
            te, prim, _ = embree[name]
            prim = np.where(prim == np.iinfo(np.uint32).max, -1, prim.astype(np.int64))
            prim = np.where(prim >= len(tris), -1, prim)
            same = np.mean(prim == h["prim"])
            line += f" {count / te / 1e6:>9.2f} Mr/s {te / t:>7.2f} {same * 100:>8.2f}%"
        print(line)
    print("\nratio = clradcom throughput / Embree throughput on the same cores "
          "(end-to-end for clradcom: upload, kernel, download)")


if __name__ == "__main__":
    main()
