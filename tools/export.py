#!/usr/bin/env python
"""Export a snapshot: MATLAB .mat, Sionna-style arrays with the channel frequency
response, a compressed copy, and (with --scene) the top view and the 3-D views.

    python tools/export.py out/street/snapshot.npz --mat --sionna
    python tools/export.py snap.npz --out exports --compressed
    python tools/export.py snap.npz --scene scenes/street/street.toml --glb --html --top-view

Files are named after the snapshot (``snap.mat``, ``snap.sionna.npz``,
``snap.compressed.npz``, ``snap.glb``, ``snap.html``, ``snap_top.png``) in ``--out``
(default: the snapshot's folder), each written atomically; docs/snapshot-format.md
("Exports") describes their contents. The Sionna arrays hold the CFR at the subcarrier
offsets k * spacing, k = -N/2 .. N/2-1 (Sionna's ``subcarrier_frequencies``), or at
``--frequencies-hz``. Errors are one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clradcom.cli import (
    finite_float,
    list_of,
    output_folder,
    positive_float,
    positive_int,
    run_tool,
)
from clradcom.commands.options import check_snapshot_scene
from clradcom.errors import ArgumentError
from clradcom.export import save_mat, save_sionna
from clradcom.plots import plot_top_view
from clradcom.scene import load_scene
from clradcom.snapshot import load_snapshot, save_snapshot
from clradcom.views import save_glb, save_html


def subcarrier_offsets(n: int, spacing_hz: float) -> np.ndarray:
    """Sionna's subcarrier_frequencies: k * spacing for k = -N/2 .. N/2-1 (N even), or
    -(N-1)/2 .. (N-1)/2 (N odd)."""
    start = -(n // 2) if n % 2 == 0 else -((n - 1) // 2)
    return (start + np.arange(n)) * spacing_hz


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("snapshot", help="snapshot file (.npz) written by tools/trace.py")
    ap.add_argument("--out", type=output_folder, default=None,
                    help="folder for the exports (default: the snapshot's folder)")
    ap.add_argument("--mat", action="store_true", help="write <name>.mat for MATLAB")
    ap.add_argument("--sionna", action="store_true",
                    help="write <name>.sionna.npz: a, tau, angles, h_freq")
    ap.add_argument("--compressed", action="store_true",
                    help="write <name>.compressed.npz, the snapshot deflated")
    ap.add_argument("--subcarriers", type=positive_int, default=1024,
                    help="CFR points for --sionna (default 1024, the paper's N)")
    ap.add_argument("--spacing-hz", type=positive_float, default=90.909e3,
                    help="CFR spacing for --sionna (default 90.909e3, the paper's)")
    ap.add_argument("--frequencies-hz", type=list_of(finite_float, "frequency"),
                    default=None, help="comma-separated CFR offsets from the carrier "
                    "(Hz), instead of --subcarriers/--spacing-hz")
    ap.add_argument("--no-carrier-phase", action="store_true",
                    help="export Sionna RT's passband a (carrier phase taken out) instead "
                         "of clradcom's gain; h_freq stays the channel")
    ap.add_argument("--normalize-delays", action="store_true",
                    help="h_freq as Sionna RT's cfr() with its default normalize_delays="
                         "True (each link's delays less its first path's); without it "
                         "h_freq is cfr(normalize_delays=False)")
    ap.add_argument("--scene", default=None, help="the scene file, for the views")
    ap.add_argument("--top-view", action="store_true", help="write <name>_top.png")
    ap.add_argument("--glb", action="store_true", help="write <name>.glb (3-D view)")
    ap.add_argument("--html", action="store_true",
                    help="write <name>.html (interactive 3-D view, works offline)")
    ap.add_argument("--link", default=None, help="link whose paths the views draw, "
                    "'TX->RX' (default: the first)")
    ap.add_argument("--paths", type=positive_int, default=50,
                    help="strongest paths the views draw (default 50)")
    args = ap.parse_args(argv)

    def run() -> int:
        src = Path(args.snapshot)
        if not src.is_file():
            raise ArgumentError("no such snapshot file", argument="snapshot",
                                value=str(src))
        views = args.top_view or args.glb or args.html
        if views and args.scene is None:
            raise ArgumentError("--top-view, --glb and --html need --scene",
                                argument="--scene", value=None)
        if not (args.mat or args.sionna or args.compressed or views):
            raise ArgumentError("nothing to write: give --mat, --sionna, --compressed, "
                                "--top-view, --glb or --html", argument="options",
                                value=None)
        snap = load_snapshot(src)
        scene = load_scene(args.scene) if views else None
        if scene is not None:
            check_snapshot_scene(snap, scene, src, args.scene)
        link = None   # checked before anything is written
        if args.link is not None:
            tx, _, rx = args.link.partition("->")
            try:
                link = snap.link(tx, rx)
            except KeyError as exc:
                raise ArgumentError(str(exc.args[0]), argument="--link",
                                    value=args.link) from None
        out = Path(args.out) if args.out is not None else src.parent
        out.mkdir(parents=True, exist_ok=True)
        stem = src.name.removesuffix(".npz")
        inputs = [src] + (list(scene.input_files) if views else [])
        written = []
        if args.mat:
            written.append(save_mat(out / f"{stem}.mat", snap, inputs=inputs))
        if args.sionna:
            freqs = (np.array(args.frequencies_hz) if args.frequencies_hz is not None
                     else subcarrier_offsets(args.subcarriers, args.spacing_hz))
            written.append(save_sionna(out / f"{stem}.sionna.npz", snap, freqs,
                                       carrier_phase=not args.no_carrier_phase,
                                       normalize_delays=args.normalize_delays,
                                       inputs=inputs))
        if args.compressed:
            target = out / f"{stem}.compressed.npz"
            if target.exists() and target.samefile(src):
                raise ArgumentError("refusing to overwrite the input snapshot",
                                    argument="--compressed", value=str(target))
            written.append(save_snapshot(target, snap, compress=True))
        if args.top_view:
            plot_top_view(scene, snap, link, n_paths=args.paths,
                          path=out / f"{stem}_top.png", inputs=inputs)
            written.append(out / f"{stem}_top.png")
        if args.glb:
            written.append(save_glb(out / f"{stem}.glb", scene, snap, args.link, args.paths,
                                    inputs=inputs))
        if args.html:
            written.append(save_html(out / f"{stem}.html", scene, snap, args.link,
                                     args.paths, inputs=inputs))
        for path in written:
            print(f"wrote {path} ({path.stat().st_size} bytes)")
        return 0

    return run_tool("export.py", run)


if __name__ == "__main__":
    raise SystemExit(main())
