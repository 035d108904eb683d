"""The ``clradcom`` command: one entry point for everything a user runs.

    clradcom trace scenes/street/street.toml        trace, snapshot, radar images, tables
    clradcom radar out/street/snapshot.npz --scene scenes/street/street.toml
    clradcom interference scenes/street/street.toml two radars: interference, cancellation
    clradcom comms scenes/street/street.toml        the A->D data link: BER, SER, EVM
    clradcom cube scenes/street/street_mimo.toml    MIMO array: radar cube, point cloud
    clradcom map scenes/street/street.toml --kind sinr --rx D
                                                    radio maps: gain, SINR, radar, INR
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
command shares live in :mod:`clradcom.commands.arguments` and are re-exported here;
a command's module is imported only when it is chosen.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys

from clradcom import __version__
from clradcom.commands.arguments import (
    TOOL_ERRORS,
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

__all__ = ["TOOL_ERRORS", "finite_float", "float_in", "int_in", "list_of", "main",
           "noise_figure_db", "non_negative_float", "non_negative_int", "output_folder",
           "positive_float", "positive_int", "run_tool", "seed"]


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


#: name -> (one-line help, its module in clradcom.commands, and that module's
#: add_arguments, check_args (or None) and run functions, by name)
SUBCOMMANDS = {
    "trace": ("trace a scene, write the snapshot, the radar images and detection tables",
              "trace", "add_arguments", None, "run"),
    "radar": ("run the radar stage again on a snapshot (another seed, synthesis, noise)",
              "radar", "add_radar_arguments", None, "run_radar"),
    "interference": ("two radars on one scene: the interference and its cancellation",
                     "interference", "add_arguments", "check_args", "run"),
    "comms": ("the data link: A's frame decoded by D, BER/SER/EVM against SNR and theory",
              "comms", "add_arguments", "check_args", "run"),
    "cube": ("a radar with an array: TDM-MIMO frame, radar cube, point cloud, truth in "
             "range, velocity and azimuth", "cube", "add_arguments", None, "run"),
    "map": ("radio maps: received power, link SINR and BER, radar SNR, INR per cell",
            "map", "add_arguments", "check_args", "run"),
    "tradeoff": ("sweep the tracer's knobs: run time against accuracy, Pareto front",
                 "tradeoff", "add_arguments", None, "run"),
    "sweep": ("trace one scene with many settings on Dask workers: a snapshot per setting",
              "sweep", "add_arguments", None, "run"),
    "rcs": ("the car model's radar cross-section against aspect, GO against PO + SBR",
            "rcs", "add_arguments", "check_args", "run"),
    "drive": ("trace a moving scene at every instant of its [time] table, paths followed",
              "drive", "add_arguments", None, "run"),
    "microdoppler": ("the Doppler spread of wheels over the frames of a moving scene: "
                     "spectrogram against the expected interval", "microdoppler",
                     "add_arguments", None, "run"),
    "compare-waveforms": ("the OFDM and an FMCW radar on the same traced paths: images "
                          "side by side, truth, resolution, CRB, data rate",
                          "compare", "add_arguments", None, "run"),
    "view": ("draw a scene from above, with a snapshot's strongest paths",
             "radar", "add_view_arguments", None, "run_view"),
    "presets": ("list the tracer's named physics (--preset)",
                "presets", "add_arguments", None, "run"),
}


def command_module(name: str):
    """The module of subcommand ``name`` (:data:`SUBCOMMANDS`), imported when the command
    is chosen, not before: ``clradcom --help`` and a light command load neither the
    tracer nor the radar, Dask or matplotlib (tools/bench_cli_import.py measures it).
    Every such module is in clradcom.commands, the layer of this one."""
    return importlib.import_module(f"clradcom.commands.{SUBCOMMANDS[name][1]}")


#: a Sphinx role in a docstring: :mod:`clradcom.x`, :func:`~clradcom.x.f`
_ROLE = re.compile(r":[a-z]+:`(~?)([^`]+)`")


def plain_text(doc: str | None) -> str | None:
    """A docstring as a terminal shows it: a Sphinx role becomes its name in backquotes
    (``:func:`~clradcom.x.f``` the last part, ``f``, as Sphinx shows it), and double
    backquotes single ones."""
    if doc is None:
        return None
    text = _ROLE.sub(lambda m: "`" + (m.group(2).rsplit(".", 1)[-1] if m.group(1)
                                      else m.group(2)) + "`", doc)
    return text.replace("``", "`")


class _CommandParser(argparse.ArgumentParser):
    """A subcommand's parser that takes its options from the command's module when it
    is first used (parsed or asked for help), so that building the whole ``clradcom``
    parser imports none of them."""

    def __init__(self, *args, command: str | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self._command = command

    def _load(self) -> None:
        if self._command is None:
            return
        name, self._command = self._command, None
        _help, _module, add, check, run = SUBCOMMANDS[name]
        module = command_module(name)
        self.description = plain_text(module.__doc__)
        getattr(module, add)(self)
        self.set_defaults(run=getattr(module, run),
                          check=getattr(module, check) if check else None, parser=self)

    def parse_known_args(self, args=None, namespace=None):
        self._load()
        return super().parse_known_args(args, namespace)

    def format_help(self) -> str:
        self._load()
        return super().format_help()

    def format_usage(self) -> str:
        self._load()
        return super().format_usage()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="clradcom", description=plain_text(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"clradcom {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=_CommandParser)
    for name, (help_line, *_where) in SUBCOMMANDS.items():
        sub.add_parser(name, help=help_line, command=name,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
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
