"""The radar stage again on a traced snapshot, and a look at a scene from above.

    clradcom radar out/street/snapshot.npz --scene scenes/street/street.toml
    clradcom view scenes/street/street.toml --snapshot out/street/snapshot.npz

``clradcom radar`` runs what ``clradcom trace`` does after tracing (its stage 2) on
a snapshot it wrote: every radar that transmits and receives gets its range-Doppler
image, detections and ground truth from its own echoes, the same files and lines as
``clradcom trace`` (another --seed, --synthesis or --no-noise without tracing again).
The scene is needed for the radars' powers, noise figures and the moving objects'
truth; a snapshot traced from another scene (its scene hash differs) is refused.

``clradcom view`` draws the scene from above (scene_top.png), with the strongest paths
of a snapshot's first monostatic link when --snapshot is given.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from clradcom.commands.options import (
    add_frame_arguments,
    add_waveform_arguments,
    check_snapshot_scene,
    output_folder,
    radar_waveforms,
    read_snapshot,
)
from clradcom.commands.trace import Stopwatch, radar_noise, radar_stage
from clradcom.errors import ArgumentError
from clradcom.files import staged_folder
from clradcom.plots import plot_top_view
from clradcom.radar.pipeline import check_frame_memory
from clradcom.scene.reader import load_scene
from clradcom.snapshot import Snapshot

__all__ = ["RADAR_OUTPUTS", "add_radar_arguments", "add_view_arguments", "run_radar",
           "run_view"]

#: the names ``clradcom radar`` writes into its output folder (those of clradcom trace's
#: radar stage)
RADAR_OUTPUTS = ("*_image.png", "*_image.svg", "*_detections.csv", "*_truth.csv")


def monostatic_links(snap, scene, snapshot) -> list:
    """The links of ``snap`` from a transmitting and receiving radar to itself (its
    echoes), refused when there is none (``snapshot``: the file named)."""
    mono = [lk for lk in snap if lk.tx_index == lk.rx_index
            and scene.radars[lk.tx_index].role == "txrx"]
    if not mono:
        raise ArgumentError("holds no link of a radar to itself, so there is no echo to "
                            "image", argument="snapshot", value=snapshot)
    return mono


def add_radar_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("snapshot", help="a snapshot.npz written by clradcom trace")
    ap.add_argument("--scene", required=True,
                    help="the scene file (TOML) the snapshot was traced from")
    ap.add_argument("--out", type=output_folder, default=None,
                    help="output folder (default: the snapshot's folder)")
    add_frame_arguments(ap)
    add_waveform_arguments(ap)


def run_radar(args) -> int:
    sw = Stopwatch()
    scene = load_scene(args.scene)
    snap = read_snapshot(args.snapshot)
    check_snapshot_scene(snap, scene, args.snapshot, args.scene)
    mono = monostatic_links(snap, scene, args.snapshot)
    frames, lines = radar_waveforms(scene, args, [lk.tx_index for lk in mono])
    for line in lines:
        print(f"  {line}")
    for wf in frames.values():
        check_frame_memory(wf, args.synthesis)
    noise = radar_noise(scene, args)
    out = Path(args.out) if args.out else Path(args.snapshot).parent
    with staged_folder(out, inputs=[*scene.input_files, args.snapshot],
                      owned=RADAR_OUTPUTS) as stage:
        for link in mono:
            radar = scene.radars[link.tx_index]
            if radar.tx_power_w == 0:
                print(f"  {radar.name}: tx_power_w = 0 W: it transmits nothing, so it has no "
                      "echo; no radar image or tables for it")
                continue
            radar_stage(sw, args, scene, frames[link.tx_index], link, radar,
                        noise[link.tx_index], stage)
    print(f"outputs in {out}/")
    return 0


def add_view_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("scene", help="scene file (TOML)")
    ap.add_argument("--snapshot", default=None,
                    help="a snapshot.npz of this scene: its strongest paths are drawn")
    ap.add_argument("--paths", type=int, default=20,
                    help="how many of the strongest paths to draw (default 20)")
    ap.add_argument("--out", default="scene_top.png",
                    help="the picture to write (default scene_top.png)")


def run_view(args) -> int:
    scene = load_scene(args.scene)
    if args.snapshot is not None:
        snap = read_snapshot(args.snapshot)
        check_snapshot_scene(snap, scene, args.snapshot, args.scene)
    else:
        snap = Snapshot(scene_name=scene.name, carrier_hz=float(scene.carrier_hz),
                        scene_hash=scene.content_hash(), links=(), metadata={})
    mono = [lk for lk in snap if lk.tx_index == lk.rx_index]
    plot_top_view(scene, snap, mono[0] if mono else None, n_paths=args.paths,
                  path=Path(args.out), inputs=[*scene.input_files] + (
                      [args.snapshot] if args.snapshot else []))
    print(f"wrote {args.out}")
    return 0

