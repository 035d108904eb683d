#!/usr/bin/env python
"""Write the micro-Doppler scene: scenes/microdoppler/car_wheels.toml and its meshes
(meshes/car_body.ply, meshes/wheel.ply).

The geometry comes from clradcom.scene.wheeled_car (a rounded car body without wheels,
one closed wheel mesh placed four times as rotating objects, rolling without slip); the
PLY files are little-endian binary written by clradcom.scene.street.ply_bytes, so
running it twice writes the same bytes (docs/microdoppler.md).

    python tools/make_microdoppler.py                # writes scenes/microdoppler/
    python tools/make_microdoppler.py --out /tmp/md --speed 15

Errors are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from clradcom.cli import output_folder, positive_float, positive_int, run_tool
from clradcom.files import atomic_write
from clradcom.scene.street import ply_bytes
from clradcom.scene.wheeled_car import WheeledCar, body_mesh, microdoppler_toml, wheel_mesh

REPO = Path(__file__).resolve().parent.parent
DEFAULT_OUT = REPO / "scenes" / "microdoppler"


def write_scene(out, *, speed: float = 10.0, count: int = 20, step_s: float = 0.05
                ) -> list[Path]:
    """The scene file and its meshes in ``out`` (created if needed), atomically."""
    out = Path(out)
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    car = WheeledCar()
    files = {"meshes/car_body.ply": ply_bytes(*body_mesh(car)),
             "meshes/wheel.ply": ply_bytes(*wheel_mesh(car)),
             "car_wheels.toml": microdoppler_toml(car, speed=speed, count=count,
                                                  step_s=step_s).encode()}
    written = []
    for name, data in files.items():
        atomic_write(out / name, lambda fh, data=data: fh.write(data))
        written.append(out / name)
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=output_folder, default=str(DEFAULT_OUT),
                    help="folder for the scene (default: scenes/microdoppler)")
    ap.add_argument("--speed", type=positive_float, default=10.0,
                    help="the car's speed in m/s (default 10)")
    ap.add_argument("--count", type=positive_int, default=20,
                    help="instants of the [time] table (default 20)")
    ap.add_argument("--step", type=positive_float, default=0.05, metavar="SECONDS",
                    help="time between instants (default 0.05 s)")
    args = ap.parse_args(argv)

    def run() -> int:
        for path in write_scene(args.out, speed=args.speed, count=args.count,
                                step_s=args.step):
            print(f"wrote {path}")
        return 0

    return run_tool("make_microdoppler.py", run)


if __name__ == "__main__":
    raise SystemExit(main())
