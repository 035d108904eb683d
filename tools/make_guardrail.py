#!/usr/bin/env python
"""Write the guard rail scene's meshes: scenes/guardrail/meshes/w_beam.ply and posts.ply.

The geometry comes from clradcom.scene.models.guardrail_meshes (a 60 m W-beam sheet in
0.5 m cells facing -y, box posts every 2 m); the files are little-endian binary PLY
written by clradcom.scene.street.ply_bytes, so running it twice writes the same bytes.
scenes/guardrail/guardrail.toml places them (written by hand, not by this tool).

    python tools/make_guardrail.py                # writes scenes/guardrail/meshes/
    python tools/make_guardrail.py --out /tmp/m

Errors are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from clradcom.cli import output_folder, run_tool
from clradcom.files import atomic_write
from clradcom.scene.models import guardrail_meshes
from clradcom.scene.street import ply_bytes

REPO = Path(__file__).resolve().parent.parent
DEFAULT_OUT = REPO / "scenes" / "guardrail" / "meshes"


def write_meshes(out) -> list[Path]:
    """The guard rail's PLY files in ``out`` (created if needed), atomically."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, (verts, faces) in guardrail_meshes().items():
        data = ply_bytes(verts, faces)
        atomic_write(out / f"{name}.ply", lambda fh, data=data: fh.write(data))
        written.append(out / f"{name}.ply")
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=output_folder, default=str(DEFAULT_OUT),
                    help="folder for the meshes (default: scenes/guardrail/meshes)")
    args = ap.parse_args(argv)

    def run() -> int:
        for path in write_meshes(args.out):
            print(f"wrote {path}")
        return 0

    return run_tool("make_guardrail.py", run)


if __name__ == "__main__":
    raise SystemExit(main())
