"""A radar with an antenna array on a scene: TDM-MIMO frame, radar cube, point cloud.

    clradcom cube scenes/street/street_mimo.toml
    clradcom cube scenes/street/street_mimo.toml --snapshot out/street_mimo/snapshot.npz
    clradcom cube scenes/street/street_mimo.toml --array-channel exact

(``python tools/cube.py ...`` runs the same.) The radar (--radar, default the first radar
with a ``tx_array``/``rx_array``) has its own echoes traced (the monostatic link alone,
with clradcom trace's physics options) or read from a snapshot of this scene; with
--array-channel exact every transmit element -> receive element pair is traced instead
(written to <radar>_elements.npz, which --snapshot then takes); then:

  1. frame      every element pair's channel (--array-channel): synthetic (default) =
                plane-wave phases on the reference paths along each path's departure
                and arrival directions, corrected = their first and last legs
                recomputed from the elements, exact = the traced pairs; each element
                with its own pattern and polarisation where the array gives them,
                TDM: transmitter i sends symbols i, i + E_tx, ... (the paper's
                waveform with M cut to a multiple of E_tx), thermal noise per receiver
  2. cube       range-Doppler per virtual channel with TDM's motion-induced phase
                compensated, FFT over the virtual array, CA-CFAR over the cube, each
                detection's range, velocity and angle refined to the joint maximum-
                likelihood fit on the raw channels (--refine parabola: the cube's
                3-point dB parabola)
                -> <radar>_points.csv / .ply   the point cloud (world x, y, z, radial
                                               velocity, power, SNR)
                -> <radar>_bird_eye.png        the points over the scene, true objects
                -> <radar>_cube_truth.csv      each moving object's truth against the
                                               detection matching it, errors in cells
                -> <radar>_elements.npz        (--array-channel exact) the element pairs'
                                               snapshot (docs/snapshot-format.md)
  and prints the truth table (range, velocity, azimuth; the cell sizes).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clradcom.commands import trace as trace_cmd
from clradcom.commands.options import (
    check_snapshot_scene,
    read_snapshot,
    run_tool,
    run_waveform,
)
from clradcom.device.runtime import get_runtime
from clradcom.errors import ArgumentError, SnapshotError
from clradcom.files import staged_folder
from clradcom.radar.array_frame import (
    ARRAY_CHANNELS,
    REFINEMENTS,
    array_truth,
    truth_table,
)
from clradcom.radar.element_trace import element_pair_paths, element_scene, trace_elements
from clradcom.radar.pipeline import radar_chain
from clradcom.radar.pointcloud import (
    save_bird_eye,
    write_point_cloud_csv,
    write_point_cloud_ply,
)
from clradcom.radar.report import moving_objects, sorted_detections_line, write_table
from clradcom.radar.truth import detection_truth
from clradcom.scene.reader import load_scene
from clradcom.snapshot import save_snapshot
from clradcom.trace import trace_scene

__all__ = ["CUBE_OUTPUTS", "CUBE_TRUTH_COLUMNS", "add_arguments", "array_radar", "run"]

#: the names ``clradcom cube`` writes into its output folder
CUBE_OUTPUTS = ("*_points.csv", "*_points.ply", "*_bird_eye.png", "*_cube_truth.csv",
                "*_elements.npz")
#: header of <radar>_cube_truth.csv
CUBE_TRUTH_COLUMNS = ("object", "range_nearest_m", "range_centre_m", "v_rel_mps",
                      "azimuth_deg", "range_detected_m", "velocity_detected_mps",
                      "azimuth_detected_deg", "range_error_cells", "velocity_error_cells",
                      "azimuth_error_cells")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    trace_cmd.add_arguments(ap)
    ap.add_argument("--snapshot", default=None,
                    help="a snapshot.npz of this scene to use instead of tracing")
    ap.add_argument("--radar", default=None,
                    help="the radar (name) with an array (default: the first one)")
    ap.add_argument("--array-channel", choices=ARRAY_CHANNELS, default="synthetic",
                    help="each element pair's channel: synthetic = plane-wave phases on the "
                         "reference point's paths (default, far field), corrected = their "
                         "first and last legs recomputed from the elements, exact = the "
                         "scene traced for every tx element -> rx element pair (near-field "
                         "targets, large arrays; writes <radar>_elements.npz, and "
                         "--snapshot then takes such a file)")
    ap.add_argument("--refine", choices=REFINEMENTS, default="ml",
                    help="each detection's range, velocity and direction: ml = the joint "
                         "maximum-likelihood fit on the raw channels (default), parabola = "
                         "the cube's 3-point dB parabola")


def array_radar(scene, name):
    """Index of the radar ``name``, or of the first radar with an array (None)."""
    if name is not None:
        i = scene.radar_index(name)
        r = scene.radars[i]
        if r.tx_array is None and r.rx_array is None:
            raise ArgumentError("has no array in the scene (tx_array/rx_array/array)",
                                argument="--radar", value=name)
        return i
    for i, r in enumerate(scene.radars):
        if r.role == "txrx" and (r.tx_array is not None or r.rx_array is not None):
            return i
    raise ArgumentError("has no transmit-receive radar with an array (give one tx_array/"
                        "rx_array, e.g. scenes/street/street_mimo.toml)", argument="scene",
                        value=str(scene.source))


def _paths(args, scene, index, settings):
    if args.snapshot is None:
        snap = trace_scene(scene, settings, runtime=get_runtime(args.device),
                           links=[(index, index)])
        return snap.links[0].paths
    snap = read_snapshot(args.snapshot)
    check_snapshot_scene(snap, scene, args.snapshot, args.scene)
    for link in snap:
        if link.tx_index == index and link.rx_index == index:
            return link.paths
    raise SnapshotError(f"holds no link of radar {scene.radars[index].name!r} to itself",
                        file=args.snapshot, key="links")


def _pair_paths(args, scene, index, settings, stage):
    """The element pairs' paths for --array-channel exact: traced (and written to
    <radar>_elements.npz) or read from --snapshot, which must be such a file of this
    scene."""
    radar = scene.radars[index]
    if args.snapshot is None:
        snap = trace_elements(scene, index, settings, runtime=get_runtime(args.device))
        save_snapshot(stage / f"{radar.name}_elements.npz", snap)
        return element_pair_paths(snap, radar)
    snap = read_snapshot(args.snapshot)
    escene, _, _ = element_scene(scene, index)
    if snap.scene_hash and snap.scene_hash != escene.content_hash():
        raise SnapshotError(f"is not an element-pair snapshot of radar {radar.name!r} of "
                            f"{args.scene} (clradcom cube --array-channel exact writes one: "
                            f"{radar.name}_elements.npz)", file=args.snapshot,
                            key="scene_hash")
    try:
        return element_pair_paths(snap, radar)
    except SnapshotError as exc:
        raise SnapshotError(exc.reason, file=args.snapshot, key="links") from None


def _csv_rows(rows):
    out = []
    for t in rows:
        d = t["detection"]
        det = ("", "", "") if d is None else (
            f"{d['range_m']:.3f}", f"{d['velocity_mps']:.3f}",
            f"{np.degrees(d['azimuth_rad']):.3f}")
        out.append((t["name"], f"{t['range_nearest_m']:.3f}", f"{t['range_centre_m']:.3f}",
                    f"{t['v_rel_m_s']:.3f}", f"{t['azimuth_deg']:.3f}", *det,
                    *(f"{t[k]:.3f}" for k in ("range_error_cells", "velocity_error_cells",
                                              "azimuth_error_cells"))))
    return out


def run(args) -> int:
    sw = trace_cmd.Stopwatch()
    settings = trace_cmd.settings_from_args(args)
    with sw.stage("load scene"):
        scene = load_scene(args.scene)
    index = array_radar(scene, args.radar)
    radar = scene.radars[index]
    wf, frame = run_waveform(scene.carrier_hz, args, scene=scene, fmcw=True, radar=index)
    print(f"  {frame}")
    nf = trace_cmd.radar_noise(scene, args)[index]
    out = Path(args.out or Path("out") / scene.name)
    inputs = [*scene.input_files] + ([args.snapshot] if args.snapshot else [])
    with staged_folder(out, inputs=inputs, owned=CUBE_OUTPUTS) as stage:
        exact = args.array_channel == "exact"
        what = "snapshot" if args.snapshot else (
            "trace every element pair" if exact else "trace the monostatic link")
        with sw.stage(f"radar {radar.name}: paths ({what})"):
            pairs = _pair_paths(args, scene, index, settings, stage) if exact else None
            paths = None if exact else _paths(args, scene, index, settings)
        with sw.stage(f"radar {radar.name}: TDM frame ({args.array_channel} element "
                      "channels), cube, CFAR"):
            chain = radar_chain(paths, wf, radar=radar, seed=args.seed,
                                tx_power_w=radar.tx_power_w if nf is not None else None,
                                noise_figure_db=nf, refine=args.refine,
                                channel=args.array_channel, pair_paths=pairs)
            res = chain.array
        truth = detection_truth(scene, radar.name, moving_objects(scene, radar))
        rows = array_truth(truth, res)
        et = 1 if radar.tx_array is None else radar.tx_array.n_elements
        er = 1 if radar.rx_array is None else radar.rx_array.n_elements
        print(f"  {radar.name}: {et} tx x {er} rx TDM-MIMO, N x M = "
              f"{res.waveform.n_subcarriers} x {res.waveform.n_symbols}, cube "
              f"{' x '.join(str(k) for k in res.cube.power.shape[:3])}; "
              f"{res.detections.size} detections")
        sorted_line = sorted_detections_line(chain)
        if sorted_line:
            print(f"  {radar.name}: {sorted_line}")
        for line in truth_table(rows, res):
            print(f"    {line}")
        with sw.stage(f"radar {radar.name}: point cloud and picture"):
            write_point_cloud_csv(stage / f"{radar.name}_points.csv", res.points)
            write_point_cloud_ply(stage / f"{radar.name}_points.ply", res.points)
            reach = np.abs(scene.triangles[..., :2]).max()
            save_bird_eye(stage / f"{radar.name}_bird_eye.png", res.points, scene.triangles,
                          truth, radar.position[:2],
                          xlim=(scene.triangles[..., 0].min(), scene.triangles[..., 0].max()),
                          ylim=(-min(reach, 40.0), min(reach, 40.0)),
                          title=f"Radar {radar.name} ({et} tx x {er} rx TDM-MIMO) point "
                                f"cloud, scene {scene.name}")
            write_table(stage / f"{radar.name}_cube_truth.csv", _csv_rows(rows),
                        CUBE_TRUTH_COLUMNS)
    print("\nstage timings:")
    for name, dt in sw.rows:
        print(f"  {dt:8.2f} s  {name}")
    print(f"outputs in {out}/")
    return 0


def main(argv=None, prog: str = "cube.py") -> int:
    ap = argparse.ArgumentParser(prog=prog, description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(ap)
    return run_tool(prog, run, ap.parse_args(argv))
