#!/usr/bin/env python3
"""A radio map of the street against tracing its cells one link at a time, same run.

    python tools/bench_maps.py scenes/street/street.toml [--rays 2000000] [--samples 48]
        [--refine 6] [--out FOLDER]

The map: radar A's frame received with D's antenna over x in [-40, 160] m,
y in [-20, 20] m at D's height, 0.5 m cells (32,000 cells; --area, --cell), line of sight,
--reflections specular reflections, diffuse scattering, first-order diffraction and the
cars' physical optics as the paper preset chooses it (--optics sbr: PO facets at the cell
centres, SBR exit rays; --go-only: none of these; docs/maps.md), timed warm (a first
map of 1000 rays with the same mechanisms builds the kernels), with the seconds of its
stages. The reference:
trace_scene from A to a receiver with D's antenna at --samples cell centres picked among
the converged cells, once with the map's physics (specular, one diffraction and
scattering without reflections beside them, the same optics) and once with the paper
preset (every mechanism, PO/SBR on the cars); the time per
link is the median of the links after the first (which carries A's candidate search and
SBR shot), and tracing every cell is extrapolated as first link + cells x median.
Prints the map's time, both extrapolations and their ratios to the map, and the map's
agreement with the traces of its own physics (median and 95th percentile of |dB|) at the
cell centres and as the mean of 8 points inside each cell (what the map estimates), and
with the paper preset's at the centres (which adds PO/SBR and the reflections beside
edges and tiles that the map lacks). The agreement of a few cells says little: 8 sample
cells gave a 95th percentile of 1.30 dB against the cell means where 200 gave 2.41 dB
(docs/maps.md), so the default is 48. Eight points do not hold the mean of a cell that a
shadow or a small facet's reflected beam cuts (one street cell's mean over 8 points was
4.9 dB, over 64 points 3.1 dB, from its mean over 512): where a cell's 8 points span
more than 3 dB, its mean is taken again over --refine^3 points (6: 216), and the
agreement printed against that as well. Every sample cell goes to
<out>/bench_maps.csv (its centre, segments, effective segments, the map's dB and the
traces' at the centre, over 8 points and refined; --out defaults to a new temporary
folder, never the repository).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from clradcom.cli import output_folder
from clradcom.device.runtime import get_runtime
from clradcom.errors import FresnelZoneWarning
from clradcom.files import write_csv
from clradcom.maps import MapGrid, MapSettings, radio_map
from clradcom.mechanisms.common import build_geometry
from clradcom.scene import load_scene
from clradcom.trace import (
    DiffractionSettings,
    OpticsSettings,
    ScatteringSettings,
    SpecularSettings,
    TraceSettings,
    trace_scene,
)


def per_link_seconds(scene, tx, receivers, settings, runtime):
    """(seconds of the first link, median seconds of the others, incoherent power per
    receiver) of trace_scene from ``tx`` to each of ``receivers`` (Radar records)."""
    sample = dataclasses.replace(scene, radars=[tx, *receivers])
    marks: dict[int, float] = {}

    def steps(done, total, label):
        marks.setdefault(done, time.perf_counter())

    t0 = time.perf_counter()
    snap = trace_scene(sample, settings, runtime=runtime, steps=steps,
                       links=[(0, i + 1) for i in range(len(receivers))])
    ends = [marks[i] for i in sorted(marks)]
    per_link = np.diff([t0, *ends[1:]])
    power = np.array([np.sum(np.abs(link.paths.gain) ** 2) for link in snap.links])
    return float(per_link[0]), float(np.median(per_link[1:])), power


def cell_offsets(grid: MapGrid, n: int) -> np.ndarray:
    """(n^3, 3) offsets from a cell's centre: the centres of its n x n x n sub-cells."""
    f = (np.arange(n) + 0.5) / n - 0.5
    return np.stack(np.meshgrid(f * grid.cell_m, f * grid.cell_m, f * grid.thickness,
                                indexing="ij"), -1).reshape(-1, 3)


def points_power(scene, tx, receivers, offsets, settings, runtime,
                 links: int = 512) -> np.ndarray:
    """(len(receivers), len(offsets)) incoherent power traced to each receiver's
    position plus each offset, about ``links`` links a trace (a trace's memory grows with
    its receivers)."""
    per_trace = max(1, links // len(offsets))
    rows = []
    for start in range(0, len(receivers), per_trace):
        inside = [dataclasses.replace(r, name=f"{r.name}_{j}", position=r.position + o)
                  for r in receivers[start:start + per_trace]
                  for j, o in enumerate(offsets)]
        _, _, power = per_link_seconds(scene, tx, inside, settings, runtime)
        rows.append(power.reshape(-1, len(offsets)))
    return np.concatenate(rows)


def decibels(power) -> np.ndarray:
    """10 log10 of ``power``, -inf where it is 0."""
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(np.asarray(power, dtype=np.float64))


def agreement(mapped, traced) -> str:
    """Median and 95th percentile of |dB| where the trace has power, and how many cells
    it has none at (a centre inside a building, in a tree: the map's cell is partly out)."""
    none = traced <= 0
    err = np.abs(10 * np.log10(mapped[~none] / traced[~none]))
    text = (f"median {np.median(err):.2f} dB, 95th percentile {np.percentile(err, 95):.2f} dB"
            if len(err) else "no cell to compare")
    return text + (f" ({int(none.sum())} cells without traced power left out)"
                   if none.any() else "")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--tx", default="A")
    ap.add_argument("--rx", default="D")
    ap.add_argument("--rays", type=int, default=2_000_000)
    ap.add_argument("--reflections", type=int, default=5)
    ap.add_argument("--area", default="-40,160,-20,20", help="X0,X1,Y0,Y1 (m)")
    ap.add_argument("--cell", type=float, default=0.5)
    ap.add_argument("--samples", type=int, default=48)
    ap.add_argument("--refine", type=int, default=6,
                    help="points per side of the dense cell mean where a cell's 8 traced "
                         "points span more than 3 dB (<= 2: none)")
    ap.add_argument("--go-only", action="store_true",
                    help="line of sight and reflections only (no scattering, diffraction)")
    ap.add_argument("--edge-step", type=float, default=0.2)
    ap.add_argument("--cone-step", type=float, default=2.0)
    ap.add_argument("--optics", default="sbr", choices=("none", "pec", "sbr"),
                    help="physical optics of the map and its own-physics trace (default "
                         "sbr, the paper preset's; --go-only: none)")
    ap.add_argument("--device", default=None)
    ap.add_argument("--out", type=output_folder, default=None,
                    help="folder for bench_maps.csv (default: a new temporary folder)")
    args = ap.parse_args(argv)
    # the per-link PO of the cars warns of facets in a radar's Fresnel zone once a link
    warnings.simplefilter("ignore", FresnelZoneWarning)
    runtime = get_runtime(args.device)
    scene = load_scene(args.scene)
    tx = scene.radars[scene.radar_index(args.tx)]
    rx = scene.radars[scene.radar_index(args.rx)]
    x0, x1, y0, y1 = (float(v) for v in args.area.split(","))
    grid = MapGrid(x0, x1, y0, y1, float(rx.position[2]), cell_m=args.cell)
    full = not args.go_only
    optics = args.optics if full else "none"
    settings = MapSettings(rays=args.rays, max_reflections=args.reflections,
                           scattering=full, diffraction=full, edge_step_m=args.edge_step,
                           cone_step_deg=args.cone_step, optics=optics)
    print(f"{scene.name}: {len(scene.triangles)} triangles; {grid.nx} x {grid.ny} = "
          f"{grid.n_cells} cells of {grid.cell_m} m; {args.rays} rays, {args.reflections} "
          f"reflections{'' if args.go_only else ', scattering, diffraction'}"
          f"{'' if optics == 'none' else ', optics ' + optics}; "
          f"{runtime.info.describe()}; load {os.getloadavg()[0]:.1f}")
    geometry = build_geometry(scene, runtime)
    # the warm-up runs every stage of the timed map (its PO, diffraction and scattering
    # kernels too: a plain 1000-ray map left their builds, 0.55 s, inside the timing)
    radio_map(scene, tx, grid, rx=rx, settings=dataclasses.replace(settings, rays=1000),
              geometry=geometry)
    k0 = runtime.kernel_seconds
    t0 = time.perf_counter()
    m = radio_map(scene, tx, grid, rx=rx, settings=settings, geometry=geometry)
    map_s = time.perf_counter() - t0
    print(f"map: {map_s:.2f} s ({runtime.kernel_seconds - k0:.2f} s in kernels; "
          + ", ".join(f"{k} {v:.2f} s" for k, v in m.stage_seconds.items())
          + f"), {m.converged.mean():.0%} of the cells converged, "
          f"{(m.count > 0).mean():.0%} reached; load {os.getloadavg()[0]:.1f}")

    rng = np.random.default_rng(0)
    cells = np.argwhere(m.converged & (m.gain > 0))
    pick = cells[rng.choice(len(cells), min(args.samples, len(cells)), replace=False)]
    centres = grid.centres()
    receivers = [dataclasses.replace(rx, name=f"cell{i}", position=centres[iy, ix].copy(),
                                     rides_on=-1, role="rx", velocity=np.zeros(3),
                                     motion=None)
                 for i, (iy, ix) in enumerate(pick)]
    mapped = m.gain[pick[:, 0], pick[:, 1]]
    go = TraceSettings(specular=SpecularSettings(max_reflections=args.reflections,
                                                 rays=1_000_000),
                       diffraction=DiffractionSettings(max_diffractions=int(full)),
                       optics=OpticsSettings(mode=optics),
                       scattering=ScatteringSettings(enabled=full))
    # the map estimates the mean over each cell's volume: a GO field has lit/unlit edges
    # (small facets' reflected beams, shadows) that a point at the centre may fall beside,
    # so the reference is also the mean over 2 x 2 x 2 points inside the cell, and over
    # --refine^3 points in the cells where those 8 span more than 3 dB (an edge inside)
    offsets = cell_offsets(grid, 2)
    columns = {"x_m": centres[pick[:, 0], pick[:, 1], 0],
               "y_m": centres[pick[:, 0], pick[:, 1], 1],
               "segments": m.count[pick[:, 0], pick[:, 1]],
               "effective_segments": m.effective_count[pick[:, 0], pick[:, 1]],
               "map_db": decibels(mapped)}
    for label, trace_settings in (("the map's physics", go),
                                  ("paper preset (every mechanism)", TraceSettings.preset())):
        first, median, power = per_link_seconds(scene, tx, receivers, trace_settings,
                                                runtime)
        every = first + grid.n_cells * median
        print(f"per-link, {label}: first link {first:.2f} s, then {median:.3f} s a link; "
              f"all {grid.n_cells} cells {every:.0f} s = {every / map_s:.0f}x the map")
        print(f"  map vs trace at {len(pick)} cell centres: {agreement(mapped, power)}")
        columns["own_centre_db" if trace_settings is go else "paper_centre_db"] = (
            decibels(power))
        if trace_settings is go:
            inner = points_power(scene, tx, receivers, offsets, go, runtime)
            mean = inner.mean(axis=1)
            print(f"  map vs the mean of {len(offsets)} traced points in each cell: "
                  f"{agreement(mapped, mean)}")
            columns["own_mean8_db"] = decibels(mean)
            if args.refine > 2:
                edge = ~(inner.min(axis=1) * 10 ** 0.3 >= inner.max(axis=1))
                dense = cell_offsets(grid, args.refine)
                refined = mean.copy()
                if edge.any():
                    refined[edge] = points_power(
                        scene, tx, [r for r, e in zip(receivers, edge, strict=True) if e],
                        dense, go, runtime).mean(axis=1)
                print(f"  map vs the mean of {len(offsets)} traced points, of {len(dense)} "
                      f"in the {int(edge.sum())} cells where those span more than 3 dB: "
                      f"{agreement(mapped, refined)}")
                columns["own_refined_db"] = decibels(refined)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_maps-"))
    out.mkdir(parents=True, exist_ok=True)
    csv_path = write_csv(out / "bench_maps.csv", zip(*columns.values(), strict=True),
                         list(columns))
    print(f"cells in {csv_path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
