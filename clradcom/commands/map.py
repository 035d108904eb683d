"""Radio maps of a scene: where the link works, the radar sees, the other radar interferes.

    clradcom map scenes/street/street.toml --kind gain --tx A --out out/map
    clradcom map scenes/street/street.toml --kind sinr --tx A --rx D [--interferer C]
    clradcom map scenes/street/street.toml --kind radar --tx A --rcs 10
    clradcom map scenes/street/street.toml --kind inr --tx A --interferer D

Rays are shot from one radar and their segments accumulated into the cells of a
horizontal layer (--height, --thickness) over a rectangle (--area, default the scene's
footprint) on the OpenCL device (docs/maps.md); line of sight, up to --reflections
specular reflections and, with --scattering and --diffraction, diffuse scattering and
first-order edge diffraction; --optics sbr gives the cars (the targets) their physical
optics as the tracer's paper preset does; --coherent adds the wavefronts as fields at the carrier
(cells small against the interference fringes). The kinds:

  gain    received power of --tx's frame (dBW) with --rx's antenna in each cell (without
          --rx: gain 1, both polarisations)
  sinr    --tx's frame received with --rx's antenna and noise figure in each cell, another
          radar --interferer transmitting too: SINR (dB) and the comms model's BER
  radar   SNR after processing (dB) of a point target of --rcs m² in each cell, seen by
          the monostatic radar --tx (processing gain NM / ENBW of --window)
  inr     the INR (dB) in --tx's receiver when --interferer stands in each cell, with its
          own antenna, orientation and power (one map by reciprocity)

Written into --out: map.png (the map over the scene's top view, dB colour bar, cells under
the convergence rule faded), map.html (the scene in 3-D with the map as a coloured plane
at its height; opens offline), map.npz (every layer with the grid's georeference),
map.csv (one row per cell). The memory a run holds is estimated first and refused over
the budget (--memory-budget, else CLRADCOM_MEMORY_BUDGET, else half the machine's).
Errors are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from clradcom.commands.console import progress_bar
from clradcom.commands.options import (
    add_waveform_arguments,
    command_parser,
    finite_float,
    int_in,
    list_of,
    output_folder,
    parse_command,
    positive_float,
    refuse_radar_waveforms,
    run_tool,
    run_waveform,
)
from clradcom.device.runtime import get_runtime
from clradcom.errors import ArgumentError
from clradcom.export import save_map_csv, save_map_npz
from clradcom.files import staged_folder
from clradcom.maps import (
    MIN_EFFECTIVE_SEGMENTS,
    MIN_SEGMENTS,
    SBR_MODES,
    MapGrid,
    MapSettings,
    map_memory_bytes,
)
from clradcom.mechanisms.common import build_geometry
from clradcom.memory import check_memory, parse_bytes
from clradcom.plots import plot_radio_map
from clradcom.radar.comms import COMMS_MODULATIONS
from clradcom.radar.maps import (
    MAP_KINDS,
    inr_map,
    radar_snr_map,
    received_power_map,
    sinr_map,
)
from clradcom.scene.reader import load_scene
from clradcom.views import save_html

#: the names this command writes into its output folder
OUTPUTS = ("map.png", "map.html", "map.npz", "map.csv")


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    return command_parser(__doc__, add_arguments, prog)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``clradcom map``."""
    ap.add_argument("scene", help="scene file (TOML), e.g. scenes/street/street.toml")
    ap.add_argument("--kind", choices=MAP_KINDS, default="gain",
                    help="which map (default gain; see above)")
    ap.add_argument("--tx", default="A", help="the radar that transmits (default A)")
    ap.add_argument("--rx", default=None,
                    help="the radar whose antenna receives in each cell (gain: optional; "
                         "sinr: required)")
    ap.add_argument("--interferer", default=None,
                    help="the other radar (sinr: optional; inr: required)")
    ap.add_argument("--area", type=list_of(finite_float, "coordinate"), default=None,
                    metavar="X0,X1,Y0,Y1",
                    help="the rectangle in m (default: the scene's footprint)")
    ap.add_argument("--height", type=finite_float, default=None,
                    help="the layer's centre height in m (default: the --rx radar's, else "
                         "the --tx radar's)")
    ap.add_argument("--cell", type=positive_float, default=0.5, help="cell size in m "
                    "(default 0.5)")
    ap.add_argument("--thickness", type=positive_float, default=None,
                    help="the layer's thickness in m (default: --cell)")
    ap.add_argument("--rays", type=int_in(1, 10**10), default=2_000_000,
                    help="rays launched over the transmit pattern (default 2e6)")
    ap.add_argument("--reflections", type=int_in(0, 16), default=2,
                    help="most specular reflections per ray (default 2)")
    ap.add_argument("--scattering", action="store_true",
                    help="add diffuse scattering off materials with a scattering "
                         "coefficient (the trees), --diffuse-rays per hit")
    ap.add_argument("--diffuse-rays", type=int_in(1, 1024), default=4,
                    help="with --scattering: diffuse rays per hit (default 4)")
    ap.add_argument("--diffraction", action="store_true",
                    help="add first-order UTD edge diffraction from the transmitter "
                         "(edges cut every --edge-step m, a ray every --cone-step degrees)")
    ap.add_argument("--edge-step", type=positive_float, default=0.05,
                    help="with --diffraction: edge piece length in m (default 0.05)")
    ap.add_argument("--cone-step", type=positive_float, default=1.0,
                    help="with --diffraction: Keller-cone ray spacing in degrees "
                         "(default 1)")
    ap.add_argument("--optics", choices=("none", "pec", "sbr"), default="none",
                    help="physical optics as the tracer's --physical-optics chooses it per "
                         "object (sbr: the paper preset's; the cars' first bounce becomes "
                         "their PO facets' field at the cell centres; default none: GO)")
    ap.add_argument("--sbr", choices=SBR_MODES, default="exit-rays",
                    help="with --optics sbr, the cars' later bounces: exit-rays (default: "
                         "the rays' GO exit segments, the tubes' GO limit) or footprints "
                         "(the tracer's SBR-PO tubes radiated to the cell centres; slower)")
    ap.add_argument("--coherent", action="store_true",
                    help="the coherent sum at the carrier: each wavefront's power per cell "
                         "with its phase at the cell's centre, added as fields (for cells "
                         "small against the fringes; docs/maps.md)")
    ap.add_argument("--rcs", type=positive_float, default=1.0,
                    help="radar: the point target's RCS in m² (default 1)")
    ap.add_argument("--window", default="rect", choices=("rect", "hann", "hamming",
                                                         "blackman", "blackmanharris"),
                    help="radar: range and Doppler window of the processing gain "
                         "(default rect)")
    ap.add_argument("--cmap", choices=("viridis", "cividis"), default="viridis",
                    help="colour map of the picture (default viridis)")
    ap.add_argument("--memory-budget", default=None, metavar="BYTES",
                    help="refuse runs estimated above this (24G, 512M, ...; default "
                         "CLRADCOM_MEMORY_BUDGET, else half the machine's memory)")
    ap.add_argument("--out", type=output_folder, default="out/map",
                    help="output folder (default out/map)")
    ap.add_argument("--device", default=None, help="OpenCL device")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_waveform_arguments(ap, modulations=COMMS_MODULATIONS,
                           modulation_help="sinr: the data modulation of the BER")


def check_args(ap: argparse.ArgumentParser, args) -> None:
    """What argparse alone cannot refuse: the radars each kind needs, the area."""
    if args.kind == "sinr" and args.rx is None:
        ap.error("--kind sinr needs --rx (the radar that decodes the frame)")
    if args.kind == "inr" and args.interferer is None:
        ap.error("--kind inr needs --interferer (the radar that interferes)")
    if args.interferer is not None and args.interferer == args.tx:
        ap.error(f"argument --interferer: must be another radar than --tx {args.tx!r}")
    if args.area is not None and len(args.area) != 4:
        ap.error(f"argument --area: needs X0,X1,Y0,Y1 (4 numbers), got {len(args.area)}")


def parse_args(argv, prog: str | None = None):
    return parse_command(build_parser(prog), argv, check_args)


def main(argv=None, prog: str = "clradcom map") -> int:
    args = parse_args(argv, prog)
    return run_tool(prog, run, args)


def scene_grid(scene, args) -> MapGrid:
    """The map's grid from --area (default: the scene's triangles' and radars' x-y box),
    --height (default the --rx radar's, else --tx's), --cell and --thickness."""
    names = [r.name for r in scene.radars]
    for option in ("tx", "rx", "interferer"):
        name = getattr(args, option)
        if name is not None and name not in names:
            raise ArgumentError(f"{args.scene} has no radar of that name (radars: "
                                f"{sorted(names)})", argument=f"--{option}", value=name)
    if args.area is None:
        pts = np.concatenate([np.asarray(scene.triangles).reshape(-1, 3),
                              *(r.position[None] for r in scene.radars)])
        x0, y0 = pts[:, :2].min(axis=0)
        x1, y1 = pts[:, :2].max(axis=0)
    else:
        x0, x1, y0, y1 = args.area
        if not (x1 > x0 and y1 > y0):
            raise ArgumentError("needs X1 > X0 and Y1 > Y0", argument="--area",
                                value=",".join(f"{v:g}" for v in args.area))
    height = args.height
    if height is None:
        height = float(scene.radars[names.index(args.rx or args.tx)].position[2])
    return MapGrid(float(x0), float(x1), float(y0), float(y1), float(height),
                   cell_m=args.cell, thickness_m=args.thickness)


def run(args) -> int:
    t0 = time.perf_counter()
    scene = load_scene(args.scene)
    grid = scene_grid(scene, args)
    settings = MapSettings(rays=args.rays, max_reflections=args.reflections,
                           scattering=args.scattering, diffuse_rays=args.diffuse_rays,
                           diffraction=args.diffraction, edge_step_m=args.edge_step,
                           cone_step_deg=args.cone_step, coherent=args.coherent,
                           optics=args.optics, sbr=args.sbr)
    budget = None if args.memory_budget is None else parse_bytes(args.memory_budget,
                                                                 "--memory-budget")
    need = map_memory_bytes(settings, grid)
    check_memory(need, what=f"a map of {grid.nx} x {grid.ny} cells with {args.rays} rays",
                 argument="--rays", value=args.rays, budget_bytes=budget,
                 advice="launch fewer --rays, or use a larger --cell or a smaller --area")
    refuse_radar_waveforms(scene, "map")
    wf, frame = run_waveform(scene.carrier_hz, args, scene=scene,
                             modulations=COMMS_MODULATIONS)
    runtime = get_runtime(args.device)
    geometry = build_geometry(scene, runtime)
    print(f"{args.kind} map of {scene.name}: {grid.nx} x {grid.ny} cells of {grid.cell_m:g} m "
          f"at z = {grid.height_m:g} m ({grid.thickness:g} m thick), {args.rays} rays, "
          f"{args.reflections} reflections{', scattering' if args.scattering else ''}"
          f"{', diffraction' if args.diffraction else ''}"
          f"{', coherent' if args.coherent else ''}"
          f"{'' if args.optics == 'none' else ', optics ' + args.optics}; "
          f"{frame}", flush=True)
    n_maps = 2 if args.kind == "sinr" and args.interferer is not None else 1
    with progress_bar(n_maps, f"{args.kind} map", quiet=args.quiet, unit="batch") as bar:
        def steps(done: int, total: int) -> None:
            if bar.total != total * n_maps:
                bar.reset(total=total * n_maps)
            bar.update(1 if done else 0)

        common = dict(settings=settings, geometry=geometry, steps=steps,
                      budget_bytes=budget)
        if args.kind == "gain":
            out = received_power_map(scene, args.tx, grid, rx=args.rx, **common)
        elif args.kind == "sinr":
            out = sinr_map(scene, args.tx, args.rx, args.interferer, grid, wf,
                           modulation=wf.modulation, **common)
        elif args.kind == "radar":
            out = radar_snr_map(scene, args.tx, grid, wf, rcs_m2=args.rcs,
                                window_range=args.window, window_doppler=args.window,
                                **common)
        else:
            out = inr_map(scene, args.tx, args.interferer, grid, wf, **common)
    layers = {"value_db": out.value_db, "converged": out.converged.astype(np.uint8),
              "segments": np.minimum.reduce([m.count for m in out.maps]),
              "effective_segments": np.minimum.reduce([m.effective_count for m in out.maps])}
    if "ber" in out.extra:
        layers["ber"] = out.extra["ber"]
    meta = {"kind": out.kind, "quantity": out.quantity, "scene": scene.name,
            "tx": args.tx, "rx": args.rx, "interferer": args.interferer,
            "rays": args.rays, "reflections": args.reflections,
            "scattering": args.scattering, "diffraction": args.diffraction,
            "coherent": args.coherent, "optics": args.optics, "sbr": args.sbr,
            "min_segments": MIN_SEGMENTS, "min_effective_segments": MIN_EFFECTIVE_SEGMENTS}
    sources = scene.input_files
    target = Path(args.out)
    with staged_folder(target, inputs=sources, owned=OUTPUTS) as stage:
        save_map_npz(stage / "map.npz", grid, layers, metadata=meta, inputs=sources)
        save_map_csv(stage / "map.csv", grid, layers, inputs=sources)
        plot_radio_map(scene, grid, out.value_db, label=out.quantity,
                       converged=out.converged, cmap=args.cmap,
                       title=f"{scene.name}: {out.quantity}, from {args.tx}",
                       path=stage / "map.png", inputs=sources)
        save_html(stage / "map.html", scene, n_paths=0, inputs=sources,
                  radio_map=(grid, out.value_db, out.quantity))
    finite = np.isfinite(out.value_db)
    share = float(out.converged.mean())
    print(f"{out.quantity}: {np.nanmin(out.value_db[finite]) if finite.any() else np.nan:.1f} "
          f"to {np.nanmax(out.value_db[finite]) if finite.any() else np.nan:.1f}; "
          f"{share:.0%} of the cells hold >= {MIN_SEGMENTS} ray segments, >= "
          f"{MIN_EFFECTIVE_SEGMENTS} of them effective (the convergence rule; more --rays "
          f"converge more)")
    print(f"[{time.perf_counter() - t0:6.1f} s] wrote {target}/map.png, map.html, map.npz, map.csv")
    return 0
