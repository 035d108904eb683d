"""Benchmark the numpy BVH builder (clradcom.geometry.bvh) against Embree's builder.

Prints, for random and street-like triangle soups of 16 k, 100 k and 1 M triangles: build time
(best of ``--repeat`` runs and the first, cold run), SAH cost, depth and mean leaf size, the SAH
cost of an object-median build for comparison, and, when ``embreex`` imports, Embree's build time
on the same float32 triangles (scene set-up and the commit forced by a first ``run``).

    python tools/bench_bvh.py [--sizes 16000 100000 1000000] [--repeat 3] [--no-median]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from clradcom.cli import positive_int, run_tool
from clradcom.geometry.bvh import build_bvh


def random_soup(n: int, seed: int = 0) -> np.ndarray:
    """n small random triangles in a 1 km cube (edge ~ 1/density^(1/3))."""
    rng = np.random.default_rng(seed)
    size = 1000.0 / n ** (1.0 / 3.0)
    centers = rng.uniform(0.0, 1000.0, (n, 1, 3))
    return (centers + rng.normal(0.0, size, (n, 3, 3))).astype(np.float32)


def street_scene(n: int, seed: int = 0) -> np.ndarray:
    """A city-like scene: a ground grid and box buildings on a street grid, 1e3-1e4 m offsets.

    Roughly half of the triangles are the (flat, z = 0) ground tessellation, the rest are building
    facades (12 triangles per box), which gives the clustered, axis-aligned, flat-heavy structure
    of a street canyon model.
    """
    rng = np.random.default_rng(seed)
    offset = np.array([4.0e3, 7.0e3, 0.0])
    n_ground_cells = max(1, n // 4)  # 2 triangles per cell -> ~n/2 triangles
    g = int(np.ceil(np.sqrt(n_ground_cells)))
    extent = 2000.0
    cell = extent / g
    ix, iy = np.meshgrid(np.arange(g), np.arange(g), indexing="ij")
    x0 = (ix.ravel() * cell)[:n_ground_cells]
    y0 = (iy.ravel() * cell)[:n_ground_cells]
    z = np.zeros_like(x0)
    p00 = np.stack([x0, y0, z], -1)
    p10 = np.stack([x0 + cell, y0, z], -1)
    p01 = np.stack([x0, y0 + cell, z], -1)
    p11 = np.stack([x0 + cell, y0 + cell, z], -1)
    ground = np.concatenate([np.stack([p00, p10, p11], 1), np.stack([p00, p11, p01], 1)])

    n_build = max(1, (n - ground.shape[0]) // 12)
    block = 100.0  # street grid pitch
    bx = rng.integers(0, int(extent // block), n_build) * block + rng.uniform(5, 60, n_build)
    by = rng.integers(0, int(extent // block), n_build) * block + rng.uniform(5, 60, n_build)
    sx = rng.uniform(5, 35, n_build)
    sy = rng.uniform(5, 35, n_build)
    sz = rng.uniform(6, 60, n_build)
    corners = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
        dtype=np.float64,
    )
    faces = np.array(
        [
            [0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
            [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7],
        ]
    )  # fmt: skip
    verts = (
        corners[None] * np.stack([sx, sy, sz], -1)[:, None]
        + np.stack([bx, by, np.zeros(n_build)], -1)[:, None]
    )
    boxes = verts[:, faces].reshape(-1, 3, 3)
    tris = np.concatenate([ground, boxes])[:n] + offset
    return tris.astype(np.float32)


def time_build(tris: np.ndarray, repeat: int, **kw) -> tuple[float, float, object]:
    times = []
    bvh = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        bvh = build_bvh(tris, **kw)
        times.append(time.perf_counter() - t0)
    return times[0], min(times), bvh


def embree_build(tris: np.ndarray, repeat: int) -> tuple[float, float] | None:
    """(best set-up + commit time, best commit-only time) in seconds, or None."""
    try:
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh
    except ImportError:
        return None
    org = np.zeros((1, 3), dtype=np.float32)
    dirs = np.ones((1, 3), dtype=np.float32)
    best_total = best_commit = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        scene = rtcs.EmbreeScene()
        TriangleMesh(scene, tris)
        t1 = time.perf_counter()
        scene.run(org, dirs)  # the first query commits the scene, i.e. builds the BVH
        t2 = time.perf_counter()
        best_total = min(best_total, t2 - t0)
        best_commit = min(best_commit, t2 - t1)
    return best_total, best_commit


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--sizes", type=positive_int, nargs="+", default=[16_000, 100_000, 1_000_000])
    ap.add_argument("--repeat", type=positive_int, default=3)
    ap.add_argument("--no-median", action="store_true", help="skip the median-split reference")
    ap.add_argument("--no-embree", action="store_true")
    args = ap.parse_args(argv)
    return run_tool("bench_bvh.py", run, args)


def run(args) -> int:
    print(
        f"{'scene':8s} {'tris':>9s} {'first_s':>8s} {'best_s':>8s} {'SAH':>9s} "
        f"{'SAH_med':>9s} {'depth':>5s} {'leaf':>5s} {'embree_s':>9s} {'commit_s':>9s} "
        f"{'ratio':>6s}"
    )
    for name, gen in (("random", random_soup), ("street", street_scene)):
        for n in args.sizes:
            tris = gen(n)
            first, best, bvh = time_build(tris, args.repeat)
            sah = bvh.sah_cost()
            med = np.nan
            if not args.no_median:
                med = build_bvh(tris, method="median").sah_cost()
            emb = None if args.no_embree else embree_build(tris, args.repeat)
            e_total, e_commit = emb if emb else (np.nan, np.nan)
            ratio = best / e_total if emb else np.nan
            print(
                f"{name:8s} {n:9d} {first:8.3f} {best:8.3f} {sah:9.2f} {med:9.2f} "
                f"{bvh.depth():5d} {bvh.leaf_sizes().mean():5.2f} {e_total:9.3f} "
                f"{e_commit:9.3f} {ratio:6.2f}",
                flush=True,
            )
    print(
        "ratio = numpy best build / Embree (set-up + commit); SAH relative to root area, "
        "C_t = C_i = 1"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
