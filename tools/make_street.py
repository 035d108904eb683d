#!/usr/bin/env python
"""Generate the paper's street scene: scenes/street/street.toml, its meshes and README.md.

The scene reproduces Section IV of the seed paper (Sit et al., "Verification of an OFDM-based
range and Doppler estimation algorithm with ray-tracing"): a two-lane street along +x with a
concrete road, concrete buildings and trees on both sides, and four PEC cars A-D; radar A on
car A's front bumper (90 deg x 180 deg sector) and a second radar on car D for the
multi-user case. Everything is deterministic: running it twice writes the same bytes.
The scene's numbers, text and mesh bytes come from clradcom.scene.street; this tool
writes them.

    python tools/make_street.py                 # writes scenes/street/
    python tools/make_street.py --out /tmp/s --no-trees --length 250

Meshes are little-endian binary PLY (float32 vertices, int32 faces) built by the package, not
by a library exporter, so the bytes do not depend on a trimesh version. The car mesh is written
once (meshes/car.ply) and referenced by all four cars; one tree mesh serves every tree.

The output folder is built beside the old one and swapped in when it is complete:
street.toml, README.md and meshes/ are this tool's and are replaced together (an
interrupted run leaves the old ones as they were); anything else in the folder is kept.
Errors are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from clradcom.cli import finite_float, output_folder, positive_float, positive_int, run_tool
from clradcom.files import atomic_write, staged_folder, write_text
from clradcom.radar.truth import detection_truth
from clradcom.scene.reader import load_scene
from clradcom.scene.street import (
    StreetOptions,
    plan_street,
    street_meshes,
    street_readme,
    street_toml,
)

REPO = Path(__file__).resolve().parent.parent
DEFAULT_OUT = REPO / "scenes" / "street"
#: the names this tool writes into its output folder (clradcom.files.staged_folder)
OUTPUTS = ("street.toml", "street_mimo.toml", "street_drive.toml", "street_fmcw_ofdm.toml",
           "README.md", "meshes")


def options_from_args(args) -> StreetOptions:
    return StreetOptions(length=args.length, trees=args.trees, car_roundness=args.car_roundness,
                         car_segments=args.car_segments, car_flat_ends=args.car_flat_ends,
                         lane_width=args.lane_width, range_from=args.range_from)


def build(args) -> Path:
    """Write street.toml, meshes/*.ply and README.md into args.out, swapped in whole
    (meshes of an earlier layout go with the old folder)."""
    options = options_from_args(args)
    out = Path(args.out)
    plan = plan_street(options)
    with staged_folder(out, owned=OUTPUTS) as stage:
        mdir = stage / "meshes"
        mdir.mkdir()
        for name, data in street_meshes(plan).items():
            atomic_write(mdir / name, lambda fh, data=data: fh.write(data))
        write_text(stage / "street.toml", street_toml(options, plan))
        # the MIMO variant: the same street, radar A with a 3 tx x 4 rx array
        write_text(stage / "street_mimo.toml", street_toml(replace(options, mimo=True), plan))
        # the drive variant: the same street with a [time] table (one second, 20 frames)
        write_text(stage / "street_drive.toml", street_toml(replace(options, drive=True), plan))
        # the FMCW + OFDM variant: radar D with an FMCW waveform of its own
        write_text(stage / "street_fmcw_ofdm.toml",
                   street_toml(replace(options, mixed=True), plan))
        scene = load_scene(stage / "street.toml")
        truth = detection_truth(scene, "A", ["carB", "carC", "carD"])
        write_text(stage / "README.md", street_readme(options, plan, scene, truth))
    return out


def parse_args(argv=None):
    ap = argparse.ArgumentParser(
        description="Write the seed paper's street scene (TOML + binary PLY meshes + README) "
                    "deterministically.")
    ap.add_argument("--out", type=output_folder, default=str(DEFAULT_OUT),
                    help="output folder (default: scenes/street in the repository)")
    ap.add_argument("--length", type=finite_float, default=160.0,
                    help="street length in m, starting 40 m behind car A (default 160)")
    ap.add_argument("--no-trees", dest="trees", action="store_false",
                    help="leave the trees out")
    ap.add_argument("--car-roundness", type=finite_float, default=0.25,
                    help="superellipsoid exponent of the car body: 1 ellipsoid, toward 0 a "
                         "box (default 0.25 = car_mesh())")
    ap.add_argument("--car-segments", type=positive_int, default=20,
                    help="car body segments around (height segments = half; default 20 = "
                         "car_mesh(), ~750 triangles)")
    ap.add_argument("--car-flat-ends", action="store_true",
                    help="car body grid shifted half a cell so nose and tail carry flat "
                         "facets facing exactly +-x (a specular echo straight back; the "
                         "default car_mesh() grid has a vertex on the axis instead)")
    ap.add_argument("--lane-width", type=positive_float, default=3.5, help="lane width in m")
    ap.add_argument("--range-from", choices=("radar", "car-centre"), default="radar",
                    help="reference of the paper's distances R: radar A's antenna (default) "
                         "or car A's centre")
    args = ap.parse_args(argv)
    if args.length < 60.0:
        ap.error("--length must be >= 60 m (car D is ~37 m ahead of car A)")
    if args.car_segments < 8:
        ap.error("--car-segments must be >= 8")
    if not 0.05 <= args.car_roundness <= 1.0:
        ap.error("--car-roundness must be in [0.05, 1]")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)

    def run() -> int:
        print(f"wrote {build(args)}")
        return 0

    return run_tool("make_street.py", run)


if __name__ == "__main__":
    raise SystemExit(main())
