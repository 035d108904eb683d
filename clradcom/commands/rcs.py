"""Monostatic RCS of the car model against aspect angle: pure GO versus PO + SBR.

A radar circles the PEC car (``clradcom.scene.models.car_mesh`` or ``rounded_car``) at
range --range-m and height --height-m; aspect 0° looks at the nose (+x), 90° at the
left side, 180° at the rear.  No ground: the car's own returns only.

* GO: image-method paths up to --bounces reflections (candidates from a dense ray grid
  over the car, exact paths and fields as in ``clradcom.mechanisms.specular``); a flat facet seen at
  its specular angle returns like an infinite mirror (pi R^2 at range R), any other
  facet nothing.
* PO + SBR: physical-optics facet integrals for the first bounce
  (``clradcom.mechanisms.physical_optics.po_paths``), shooting-and-bouncing ray tubes
  with PO radiation for bounces 2..--bounces (``clradcom.mechanisms.sbr.sbr_paths``).

RCS here is the apparent one at the stated range, sigma = |a|^2 (4 pi)^3 R^4 / lambda^2
with the coherent sum a of all paths, isotropic antennas, VV and HH from the
polarimetric matrix. Writes rcs_aspect.csv and rcs_aspect.png into --out and prints
the run time of each method. The computation is clradcom.evaluation.rcs.

Every option is checked before anything is traced (the radar outside the car's bounding
sphere, at most 4e6 ray tubes per grid, the aspects within the memory budget). The
output folder is built beside the old one and swapped in when the run is done (an
interrupted or failed run leaves the old one as it was; other files in it are kept).
Errors are one line on stderr, exit code 2.

    clradcom rcs --out out/rcs [--range-m 20] [--step-deg 5] [--device SPEC]
    python tools/rcs_aspect.py --out out/rcs ...      (the same)
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from clradcom.commands.console import progress_bar
from clradcom.commands.options import (
    command_parser,
    finite_float,
    output_folder,
    parse_command,
    positive_float,
    run_tool,
)
from clradcom.device.runtime import get_runtime
from clradcom.evaluation.rcs import (
    MODELS,
    aspect_rcs,
    aspect_scene,
    check_aspect_grids,
    model_mesh,
    plot_rcs,
    write_rcs_csv,
)
from clradcom.files import staged_folder
from clradcom.memory import check_memory

#: the names this tool writes into its output folder (clradcom.files.staged_folder)
OUTPUTS = ("rcs_aspect.csv", "rcs_aspect.png")
#: memory an aspect holds before it is traced: its radar in the aspect scene (record,
#: pattern, the scene dict it is built from) and its CSV row
ASPECT_BYTES = 4096


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    return command_parser(__doc__, add_arguments, prog)


def parse_args(argv, prog: str | None = None):
    return parse_command(build_parser(prog), argv, check_args)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``clradcom rcs`` / tools/rcs_aspect.py."""
    ap.add_argument("--out", type=output_folder, required=True,
                    help="folder for rcs_aspect.csv / .png")
    ap.add_argument("--model", choices=MODELS, default="car",
                    help="car: car_mesh() (default); rounded: rounded_car(face_centred=True)")
    ap.add_argument("--range-m", type=positive_float, default=20.0)
    ap.add_argument("--height-m", type=finite_float, default=0.5,
                    help="radar height (default 0.5 m; the car stands on z = 0)")
    ap.add_argument("--start-deg", type=finite_float, default=0.0)
    ap.add_argument("--stop-deg", type=finite_float, default=180.0)
    ap.add_argument("--step-deg", type=positive_float, default=5.0)
    ap.add_argument("--bounces", type=int, choices=(1, 2, 3, 4, 5), default=3)
    ap.add_argument("--spacing-wavelengths", type=positive_float, default=0.5,
                    help="SBR ray-tube pitch at the car (default 0.5 wavelength)")
    ap.add_argument("--go-spacing-m", type=positive_float, default=0.01,
                    help="pitch of the GO candidate rays at the car (default 1 cm)")
    ap.add_argument("--device", default=None,
                    help="OpenCL device: 'gpu', 'cpu', 'P:D' or part of its name")
    ap.add_argument("-q", "--quiet", action="store_true",
                    help="no progress bar (it is shown only when stderr is a terminal)")


def check_args(ap: argparse.ArgumentParser, args) -> None:
    """What argparse alone cannot refuse: an empty aspect range."""
    if args.stop_deg < args.start_deg:
        ap.error(f"--stop-deg ({args.stop_deg}) is below --start-deg ({args.start_deg})")


def main(argv=None, prog: str = "rcs_aspect.py"):
    args = parse_args(argv, prog)
    return run_tool(prog, run, args)


def run(args) -> int:
    n_aspects = math.floor((args.stop_deg - args.start_deg + 1e-9) / args.step_deg) + 1
    check_memory(n_aspects * ASPECT_BYTES, what=f"{n_aspects} aspects",
                 argument="--step-deg", value=args.step_deg,
                 advice="use a coarser --step-deg or a narrower --start-deg/--stop-deg")
    aspects = np.arange(args.start_deg, args.stop_deg + 1e-9, args.step_deg)
    R, h = args.range_m, args.height_m
    scene = aspect_scene(model_mesh(args.model), aspects, R, h)
    check_aspect_grids(scene, R, spacing_wavelengths=args.spacing_wavelengths,
                       go_spacing_m=args.go_spacing_m,
                       names={"range_m": "--range-m", "go_spacing_m": "--go-spacing-m",
                              "spacing_wavelengths": "--spacing-wavelengths"})
    out = Path(args.out)
    with staged_folder(out, owned=OUTPUTS) as stage:
        measure(args, scene, aspects, stage)
    print(f"wrote {out / 'rcs_aspect.csv'} and {out / 'rcs_aspect.png'}")
    return 0


def measure(args, scene, aspects, stage) -> None:
    """Trace every aspect, print it, write the CSV and the chart into ``stage``."""
    R, h = args.range_m, args.height_m
    rt = get_runtime(args.device)
    print(f"device : {rt.info.describe()}")
    print(f"car    : {args.model}, {len(scene.triangles)} triangles; radar at {R} m, "
          f"{h} m high; {len(aspects)} aspects; up to {args.bounces} bounces")

    rows = []
    t_go = t_po = t_sbr = 0.0
    n_tubes = 0
    bar = progress_bar(len(aspects), "aspects", quiet=getattr(args, "quiet", False),
                       unit="aspect")
    for res in aspect_rcs(scene, aspects, R, rt, bounces=args.bounces,
                          spacing_wavelengths=args.spacing_wavelengths,
                          go_spacing_m=args.go_spacing_m):
        bar.update(1)
        row = res.row
        t_go, t_po, t_sbr = t_go + res.go_s, t_po + res.po_s, t_sbr + res.sbr_s
        n_tubes += res.tubes
        rows.append(row)
        bar.write(f"  {row['aspect_deg']:6.1f} deg  GO {row['go_vv_dbsm']:7.1f} dBsm "
                  f"({row['go_paths']} paths)   PO+SBR {row['po_sbr_vv_dbsm']:6.1f} dBsm "
                  f"({row['po_facets']} facets, {row['sbr_paths']} SBR paths)")
    bar.close()

    write_rcs_csv(stage / "rcs_aspect.csv", rows)
    n = len(aspects)
    print(f"time GO      : {t_go:7.2f} s  ({t_go / n * 1e3:.0f} ms per aspect)")
    print(f"time PO      : {t_po:7.2f} s  ({t_po / n * 1e3:.0f} ms per aspect)")
    print(f"time SBR     : {t_sbr:7.2f} s  ({t_sbr / n * 1e3:.0f} ms per aspect, "
          f"~{n_tubes / n / 1e3:.0f} k tubes)")
    print(f"time PO+SBR  : {t_po + t_sbr:7.2f} s")
    plot_rcs(rows, model=args.model, range_m=args.range_m, height_m=args.height_m,
             bounces=args.bounces, go_s=t_go, po_sbr_s=t_po + t_sbr,
             path=stage / "rcs_aspect.png")

