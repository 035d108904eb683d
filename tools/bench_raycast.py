#!/usr/bin/env python3
"""Ray-casting throughput of clradcom's OpenCL kernels beside Intel Embree.

Both casters get exactly the same rays in the same run, on a synthetic street
of ~22 k triangles (clradcom.scene.models.street_triangles):

  primary  rays from a radar on a car's front bumper over the paper's
           90 deg azimuth x 180 deg elevation sector (Fibonacci lattice)
  bounce   the specular reflections of the primary hits, leaving the
           surfaces they hit: incoherent secondary rays
  primary* / bounce*  the same rays in coherent order (clradcom.geometry.ray_order:
           along a Morton curve over the directions' octahedral map, as the tracer
           launches its lattice): neighbouring rays run one after the other
  tubes    an SBR launch: rays through a square grid of the 10 x 5 deg ahead, in
           8 x 8 blocks one after the other, as SBR-PO launches its tubes
  tubes 2  their reflections, those of a block that left one plane side by side
  tubes[p] / tubes 2[p]  the same rays cast in packets (RayCaster.closest_hit_packets:
           a block, or the part of it that left one plane, walks the tree once), as
           the SBR kernels cast them; their hits must be the single rays' bit for bit

Embree (the ``embreex`` package, ``pip install clradcom[bench]``) traces on
one thread per process, so it runs in as many processes as the machine has
cores, each on its share of the rays; its time is the slowest process's.
The ratio printed is clradcom's throughput over Embree's on the same cores.
A third column times the closest-hit kernel alone on the device (OpenCL profiling
events, the rays already in device memory): on a GPU the end-to-end figure is bound by
the copies over the bus, the kernel's own rate is what the traversal reaches.
The timed repetitions alternate between the two casters (best of each kept),
so a machine that other jobs load unevenly slows both alike. Build times are
set beside each other too: clradcom's is the whole RayCaster set-up (binary
SAH build, 8-wide collapse, Tri4 groups, upload).

    python tools/bench_raycast.py [--rays 1000000] [--device SPEC] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from clradcom.cli import positive_int, run_tool
from clradcom.device.raycast import RayCaster, make_rays, spawn_origins
from clradcom.device.runtime import get_runtime
from clradcom.geometry.ray_order import coherent_order
from clradcom.memory import check_memory
from clradcom.scene.models import street_triangles


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


def embree_once(pool, origins, dirs, n_proc):
    chunks = np.array_split(np.arange(len(origins)), n_proc)
    jobs = [(origins[c], dirs[c]) for c in chunks]
    results = list(pool.map(_embree_worker_run, jobs))
    return (max(r[0] for r in results), np.concatenate([r[1] for r in results]),
            np.concatenate([r[2] for r in results]))


def clradcom_once(caster, rays, packet_first=None):
    t0 = time.perf_counter()
    if packet_first is None:
        hits = caster.closest_hit(rays)
    else:
        hits = caster.closest_hit_packets(rays, packet_first)
    return time.perf_counter() - t0, hits


def tube_grid(n: int, block: int = 8) -> np.ndarray:
    """About n unit directions through a square grid on the plane x = 1 over +-5 deg of
    azimuth and +-2.5 of elevation (at 10^6 rays a pitch of 0.006 deg, as the street's
    SBR tubes have about 0.025 deg), in block x block blocks one after the other (an SBR
    launch window's order)."""
    ny = max(block, int(round(np.sqrt(n / 2.0) / block)) * block)
    nx = 2 * ny
    y = np.tan(np.radians(5.0)) * ((np.arange(nx) + 0.5) / nx * 2.0 - 1.0)
    z = np.tan(np.radians(2.5)) * ((np.arange(ny) + 0.5) / ny * 2.0 - 1.0)
    gy, gz = np.meshgrid(y, z, indexing="ij")
    gy = gy.reshape(nx // block, block, ny // block, block).transpose(0, 2, 1, 3).ravel()
    gz = gz.reshape(nx // block, block, ny // block, block).transpose(0, 2, 1, 3).ravel()
    d = np.stack([np.ones_like(gy), gy, gz], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def runs_of(keys, most: int = 64) -> np.ndarray:
    """packet_first for rays sorted by key: runs of equal keys, split at ``most``."""
    starts = np.flatnonzero(np.diff(keys, prepend=keys[:1] - 1))
    ends = np.append(starts[1:], len(keys))
    first = np.concatenate([np.arange(a, b, most) for a, b in zip(starts, ends, strict=True)])
    return np.append(first, len(keys)).astype(np.int64)


def reflect_hits(origin, dirs, hits):
    """The specular reflections of the rays from ``origin`` that hit (rays leaving the
    surfaces) and which rays they come from."""
    ok = np.flatnonzero(hits["prim"] >= 0)
    p = origin + hits["t"][ok, None] * dirs[ok]
    n = hits["ng"][ok].astype(np.float64)
    d_out = dirs[ok] - 2.0 * np.einsum("ij,ij->i", dirs[ok], n)[:, None] * n
    return make_rays(spawn_origins(p, n, d_out), d_out, tmin=1e-4), ok


def kernel_only_seconds(caster, rays) -> float:
    """Seconds the closest-hit kernel alone takes on ``rays`` already on the device (an
    OpenCL profiling event on a queue of its own)."""
    import pyopencl as cl

    from clradcom.device.raycast import HIT_DTYPE

    rt = caster.runtime
    with rt.guard("profiling of closest_hit"):
        queue = cl.CommandQueue(rt.context,
                                properties=cl.command_queue_properties.PROFILING_ENABLE)
        kernel = rt.kernel("raycast.cl", "closest_hit", defines=caster.kernel_defines())
        mf = cl.mem_flags
        ray_buf = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=rays)
        out_buf = cl.Buffer(rt.context, mf.WRITE_ONLY, size=len(rays) * HIT_DTYPE.itemsize)
        local = caster.local_size(kernel)
        size = -(-len(rays) // local) * local
        event = kernel(queue, (size,), (local,), *caster.bvh_buffers(), ray_buf, None,
                       out_buf, np.int32(len(rays)))
        event.wait()
        return (event.profile.end - event.profile.start) * 1e-9


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--rays", type=positive_int, default=1_000_000,
                    help="primary rays (default 1e6)")
    ap.add_argument("--device", default=None, help="OpenCL device spec (see: clradcom devices)")
    ap.add_argument("--repeat", type=positive_int, default=5,
                    help="timed repetitions, best kept")
    ap.add_argument("--no-embree", action="store_true", help="skip the Embree reference")
    args = ap.parse_args(argv)
    return run_tool("bench_raycast.py", run, args)


def run(args) -> int:
    # the direction lattice, four ray sets (two orders) and their hits (32 bytes each),
    # the bounce computation's float64 temporaries and the order's two int64 indices
    check_memory(args.rays * (24 + 4 * (32 + 32) + 6 * 24 + 16), what=f"{args.rays} rays",
                 argument="--rays", value=args.rays, advice="use fewer --rays")

    tris, _ = street_triangles(seed=0)
    tris32 = np.ascontiguousarray(tris, dtype=np.float32)
    runtime = get_runtime(args.device)
    print(f"device : {runtime.info.describe()}")
    print(f"scene  : synthetic street, {len(tris)} triangles")

    t0 = time.perf_counter()
    caster = RayCaster(tris, runtime=runtime)
    t_build = time.perf_counter() - t0

    bumper = np.array([1.95, -1.75, 0.55])
    dirs = sector_directions(args.rays)
    primary = make_rays(np.broadcast_to(bumper, dirs.shape), dirs, tmin=1e-4)
    caster.closest_hit(primary[:1024])  # compile and warm up
    _, hits = clradcom_once(caster, primary)

    bounce, came_from = reflect_hits(bumper, dirs, hits)
    # the same rays in coherent order; a bounce ray keeps its primary ray's place
    order = coherent_order(dirs)
    place = np.empty(len(dirs), dtype=np.int64)
    place[order] = np.arange(len(dirs))
    # an SBR launch: blocks of 8 x 8, then the reflections of a block off one plane
    tube_dirs = tube_grid(args.rays)
    tubes = make_rays(np.broadcast_to(bumper, tube_dirs.shape), tube_dirs, tmin=1e-4)
    tube_first = np.arange(0, len(tubes) + 1, 64)
    tube_hits = caster.closest_hit(tubes)
    tube_bounce, came = reflect_hits(bumper, tube_dirs, tube_hits)
    normals = np.round(tube_hits["ng"][came].astype(np.float64), 5)
    plane = np.unique(np.column_stack([normals, np.round(
        np.einsum("ij,ij->i", normals, tube_bounce["org"].astype(np.float64)), 3)]),
        axis=0, return_inverse=True)[1].ravel()
    sort = np.lexsort((plane, came // 64))
    tube_bounce = tube_bounce[sort]
    key = (came // 64)[sort] * (int(plane.max(initial=0)) + 1) + plane[sort]
    sets = {"primary": primary, "bounce": bounce, "primary*": primary[order],
            "bounce*": bounce[np.argsort(place[came_from])],
            "tubes": tubes, "tubes 2": tube_bounce, "tubes[p]": tubes,
            "tubes 2[p]": tube_bounce}
    packets = {"tubes[p]": tube_first, "tubes 2[p]": runs_of(key)}
    single = {"tubes[p]": "tubes", "tubes 2[p]": "tubes 2"}  # the same rays one by one

    n_proc = os.cpu_count() or 1
    pool = None
    t_embree_build = None
    if not args.no_embree:
        try:
            import embreex  # noqa: F401
        except ImportError:
            print("embreex not installed (pip install 'clradcom[bench]'): no reference")
        else:
            t_embree_build = embree_build_time(tris32)
            pool = ProcessPoolExecutor(n_proc, initializer=_embree_worker_init,
                                       initargs=(tris32,))
    best = {name: np.inf for name in sets}
    best_kernel = {name: np.inf for name in sets}
    out = {}
    embree = {}
    try:
        for _ in range(args.repeat):
            for name, rays in sets.items():
                t, out[name] = clradcom_once(caster, rays, packets.get(name))
                best[name] = min(best[name], t)
                if name not in packets:
                    best_kernel[name] = min(best_kernel[name],
                                            kernel_only_seconds(caster, rays))
                if pool is not None and name not in packets:
                    o = np.ascontiguousarray(rays["org"])
                    d = np.ascontiguousarray(rays["dir"])
                    te, prim, tfar = embree_once(pool, o, d, n_proc)
                    if name not in embree or te < embree[name][0]:
                        embree[name] = (te, prim, tfar)
    finally:
        if pool is not None:
            pool.shutdown()
    rows = [(name, len(sets[name]), best[name], out[name]) for name in sets]
    # the order changes which rays run together, never what a ray hits
    reordered_alike = (np.array_equal(out["primary*"], out["primary"][order])
                       and np.array_equal(out["bounce*"], out["bounce"][
                           np.argsort(place[came_from])]))
    packed_alike = all(out[p].tobytes() == out[s].tobytes() for p, s in single.items())
    for p, s in single.items():   # Embree's figures for the packets are the same rays'
        if s in embree:
            embree[p] = embree[s]

    print(f"\nBVH build: clradcom {t_build * 1e3:.1f} ms", end="")
    if t_embree_build is not None:
        print(f", Embree {t_embree_build * 1e3:.1f} ms  (ratio Embree/clradcom "
              f"{t_embree_build / t_build:.2f})")
    else:
        print()
    print(f"\n{'rays':<10} {'count':>9} {'clradcom':>14} {'kernel only':>14} "
          f"{'Embree x' + str(n_proc):>14} {'ratio':>7} {'same hit':>9}")
    for name, count, t, h in rows:
        mrays = count / t / 1e6
        kernel = (f"{count / best_kernel[name] / 1e6:>9.2f} Mr/s"
                  if np.isfinite(best_kernel[name]) else f"{'-':>14}")
        line = f"{name:<10} {count:>9} {mrays:>9.2f} Mr/s {kernel}"
        if name in embree:
            te, prim, _ = embree[name]
            prim = np.where(prim == np.iinfo(np.uint32).max, -1, prim.astype(np.int64))
            prim = np.where(prim >= len(tris), -1, prim)
            same = np.mean(prim == h["prim"])
            line += f" {count / te / 1e6:>9.2f} Mr/s {te / t:>7.2f} {same * 100:>8.2f}%"
        print(line)
    print("\nratio = clradcom throughput / Embree throughput on the same cores "
          "(end-to-end for clradcom: upload, kernel, download; kernel only: the device's "
          "profiling clock); *: the same rays in coherent order, hits "
          f"{'identical ray for ray' if reordered_alike else 'DIFFERENT'}; [p]: the rays "
          f"above cast in packets, hits {'identical' if packed_alike else 'DIFFERENT'} "
          "(kernel only: not timed)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
