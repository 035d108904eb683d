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
"""

from __future__ import annotations

import argparse
from pathlib import Path

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


def options_from_args(args) -> StreetOptions:
    return StreetOptions(length=args.length, trees=args.trees, car_roundness=args.car_roundness,
                         car_segments=args.car_segments, car_flat_ends=args.car_flat_ends,
                         lane_width=args.lane_width, range_from=args.range_from)


def build(args) -> Path:
    """Write street.toml, meshes/*.ply and README.md into args.out."""
    options = options_from_args(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mdir = out / "meshes"
    if mdir.is_dir():  # remove stale meshes of an earlier layout (only our .ply files)
        for f in sorted(mdir.glob("*.ply")):
            f.unlink()
    plan = plan_street(options)
    mdir.mkdir(parents=True, exist_ok=True)
    for name, data in street_meshes(plan).items():
        (mdir / name).write_bytes(data)
    (out / "street.toml").write_text(street_toml(options, plan), encoding="utf-8")
    scene = load_scene(out / "street.toml")
    truth = detection_truth(scene, "A", ["carB", "carC", "carD"])
    (out / "README.md").write_text(street_readme(options, plan, scene, truth),
                                   encoding="utf-8")
    return out


def parse_args(argv=None):
    ap = argparse.ArgumentParser(
        description="Write the seed paper's street scene (TOML + binary PLY meshes + README) "
                    "deterministically.")
    ap.add_argument("--out", default=str(DEFAULT_OUT),
                    help="output folder (default: scenes/street in the repository)")
    ap.add_argument("--length", type=float, default=160.0,
                    help="street length in m, starting 40 m behind car A (default 160)")
    ap.add_argument("--no-trees", dest="trees", action="store_false",
                    help="leave the trees out")
    ap.add_argument("--car-roundness", type=float, default=0.25,
                    help="superellipsoid exponent of the car body: 1 ellipsoid, toward 0 a "
                         "box (default 0.25 = car_mesh())")
    ap.add_argument("--car-segments", type=int, default=20,
                    help="car body segments around (height segments = half; default 20 = "
                         "car_mesh(), ~750 triangles)")
    ap.add_argument("--car-flat-ends", action="store_true",
                    help="car body grid shifted half a cell so nose and tail carry flat "
                         "facets facing exactly +-x (a specular echo straight back; the "
                         "default car_mesh() grid has a vertex on the axis instead)")
    ap.add_argument("--lane-width", type=float, default=3.5, help="lane width in m")
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
    out = build(parse_args(argv))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
