"""The ``clradcom`` command: one entry point for everything a user runs.

    clradcom trace scenes/street/street.toml        trace, snapshot, radar images, tables
    clradcom radar out/street/snapshot.npz --scene scenes/street/street.toml
    clradcom interference scenes/street/street.toml two radars: interference, cancellation
    clradcom comms scenes/street/street.toml        the A->D data link: BER, SER, EVM
    clradcom cube scenes/street/street_mimo.toml    MIMO array: radar cube, point cloud
    clradcom tradeoff scenes/street/street.toml     speed against accuracy sweep
    clradcom sweep scenes/street/street.toml --preset fast,paper --workers 2
                                                    traces of many settings on Dask
    clradcom rcs --out out/rcs                      the car's RCS against aspect
    clradcom drive scene.toml                       a moving scene over time: path series
    clradcom microdoppler scene.toml                the wheels' Doppler spread: spectrogram
    clradcom compare-waveforms SNAPSHOT --scene SCENE --fmcw FMCW.toml
                                                    OFDM against FMCW on the same paths
    clradcom view scenes/street/street.toml         the scene from above
    clradcom presets                                the tracer's named physics
    clradcom devices                                the OpenCL devices

Each subcommand is the code of :mod:`clradcom.commands` (the scripts in tools/ are thin
wrappers around the same functions). The option types and the error boundary every
command shares live in :mod:`clradcom.commands.options` and are re-exported here.
"""

from __future__ import annotations

import argparse
import sys

from clradcom import __version__
from clradcom.commands import comms as comms_cmd
from clradcom.commands import compare as compare_cmd
from clradcom.commands import cube as cube_cmd
from clradcom.commands import drive as drive_cmd
from clradcom.commands import interference as interference_cmd
from clradcom.commands import microdoppler as microdoppler_cmd
from clradcom.commands import radar as radar_cmd
from clradcom.commands import rcs as rcs_cmd
from clradcom.commands import sweep as sweep_cmd
from clradcom.commands import trace as trace_cmd
from clradcom.commands import tradeoff as tradeoff_cmd
from clradcom.commands.options import (
    TOOL_ERRORS,
    check_snapshot_scene,
    finite_float,
    float_in,
    int_in,
    list_of,
    noise_figure_db,
    non_negative_float,
    non_negative_int,
    output_folder,
    positive_float,
    positive_int,
    run_tool,
    seed,
)
from clradcom.device.runtime import (
    ENV_DEVICE,
    ENV_FP64,
    VENDOR_NAMES,
    choose_device,
    list_devices,
)
from clradcom.presets import DEFAULT_PRESET, PRESETS
from clradcom.trace import TraceSettings

__all__ = ["TOOL_ERRORS", "check_snapshot_scene", "finite_float", "float_in", "int_in",
           "list_of", "main", "noise_figure_db", "non_negative_float", "non_negative_int",
           "output_folder", "positive_float", "positive_int", "run_tool", "seed"]


def _cmd_devices(args) -> int:
    infos = list_devices()
    chosen = choose_device(args.device)
    names = ", ".join(VENDOR_NAMES)
    print(f"OpenCL devices (select with --device NAME ({names}), P:D, 'gpu', 'cpu', a")
    print(f"name fragment, or the environment variable {ENV_DEVICE}; {ENV_FP64}=0 runs any")
    print("device as one without fp64):")
    for info in infos:
        mark = "*" if info == chosen else " "
        print(f" {mark} {info.describe()}")
    what = "chosen" if args.device else "default"
    print(f"{what}: [{chosen.spec}] {chosen.vendor} {chosen.device_name.strip()}")
    if any(i.simulator for i in infos) and not chosen.simulator:
        print("(Oclgrind, a simulator, runs only when asked for: --device oclgrind)")
    return 0


def _cmd_presets(args) -> int:
    names = [args.name] if args.name else list(PRESETS)
    for name in names:
        preset = PRESETS[name]
        mark = " (default)" if name == DEFAULT_PRESET else ""
        print(f"{name}{mark}: {preset.summary}")
        if args.name or args.verbose:
            for key, value in TraceSettings.preset(name).metadata().items():
                print(f"    {key.removeprefix('settings.')} = {value}")
    if not args.name:
        print(f"\n`clradcom trace SCENE --preset NAME` traces with one; in Python "
              f"TraceSettings.preset(NAME), and trace_scene(scene) uses {DEFAULT_PRESET}.")
    return 0


#: name -> (one-line help, module docstring, add_arguments, check_args or None, run)
SUBCOMMANDS = {
    "trace": ("trace a scene, write the snapshot, the radar images and detection tables",
              trace_cmd.__doc__, trace_cmd.add_arguments, None, trace_cmd.run),
    "radar": ("run the radar stage again on a snapshot (another seed, synthesis, noise)",
              radar_cmd.__doc__, radar_cmd.add_radar_arguments, None, radar_cmd.run_radar),
    "interference": ("two radars on one scene: the interference and its cancellation",
                     interference_cmd.__doc__, interference_cmd.add_arguments,
                     interference_cmd.check_args, interference_cmd.run),
    "comms": ("the data link: A's frame decoded by D, BER/SER/EVM against SNR and theory",
              comms_cmd.__doc__, comms_cmd.add_arguments, comms_cmd.check_args, comms_cmd.run),
    "cube": ("a radar with an array: TDM-MIMO frame, radar cube, point cloud, truth in "
             "range, velocity and azimuth", cube_cmd.__doc__, cube_cmd.add_arguments, None,
             cube_cmd.run),
    "tradeoff": ("sweep the tracer's knobs: run time against accuracy, Pareto front",
                 tradeoff_cmd.__doc__, tradeoff_cmd.add_arguments, None, tradeoff_cmd.run),
    "sweep": ("trace one scene with many settings on Dask workers: a snapshot per setting",
              sweep_cmd.__doc__, sweep_cmd.add_arguments, None, sweep_cmd.run),
    "rcs": ("the car model's radar cross-section against aspect, GO against PO + SBR",
            rcs_cmd.__doc__, rcs_cmd.add_arguments, rcs_cmd.check_args, rcs_cmd.run),
    "drive": ("trace a moving scene at every instant of its [time] table, paths followed",
              drive_cmd.__doc__, drive_cmd.add_arguments, None, drive_cmd.run),
    "microdoppler": ("the Doppler spread of wheels over the frames of a moving scene: "
                     "spectrogram against the expected interval", microdoppler_cmd.__doc__,
                     microdoppler_cmd.add_arguments, None, microdoppler_cmd.run),
    "compare-waveforms": ("the OFDM and an FMCW radar on the same traced paths: images "
                          "side by side, truth, resolution, CRB, data rate",
                          compare_cmd.__doc__, compare_cmd.add_arguments, None,
                          compare_cmd.run),
    "view": ("draw a scene from above, with a snapshot's strongest paths",
             radar_cmd.__doc__, radar_cmd.add_view_arguments, None, radar_cmd.run_view),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="clradcom", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"clradcom {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (help_line, doc, add, check, run) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_line, description=doc,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        add(p)
        p.set_defaults(run=run, check=check, parser=p)
    p_pre = sub.add_parser("presets", help="list the tracer's named physics (--preset)",
                           description="The named tracer presets (clradcom.presets).")
    p_pre.add_argument("name", nargs="?", choices=tuple(PRESETS),
                       help="show every setting of this preset")
    p_pre.add_argument("-v", "--verbose", action="store_true",
                       help="every setting of every preset")
    p_pre.set_defaults(run=_cmd_presets, check=None, parser=p_pre)
    p_dev = sub.add_parser(
        "devices", help="list the OpenCL devices and the one chosen",
        description="The OpenCL devices clradcom sees, and the one a run uses: --device "
                    f"of a command, else the environment variable {ENV_DEVICE}, else the "
                    "first GPU, else PoCL's CPU device (pip install 'clradcom[pocl]'). "
                    "Every command that traces takes --device ('gpu', 'cpu', 'P:D' or "
                    "part of the device's name).")
    p_dev.add_argument("--device", default=None, help="device spec to test the choice of")
    p_dev.set_defaults(run=_cmd_devices, check=None, parser=p_dev)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.check is not None:
        args.check(args.parser, args)
    args.prog = f"clradcom {args.command}"
    return run_tool(args.prog, args.run, args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
