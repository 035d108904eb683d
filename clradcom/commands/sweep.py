"""A parameter sweep of one scene, its traces run on Dask: one snapshot per setting.

    clradcom sweep scenes/street/street.toml --preset fast,paper --vary specular.rays=1e4,1e5
    clradcom sweep SCENE --workers 4                     a local cluster of 4 processes
    clradcom sweep SCENE --scheduler tcp://host:8786     workers started elsewhere
    python tools/sweep.py SCENE ...                      (the same)

Every combination of --preset (comma list, default paper) and each --vary FIELD=v1,v2
(a TraceSettings field, nested ``specular.rays`` or the flat names of docs/tradeoff.md)
is one task: a whole trace of the scene (clradcom.distributed.trace_task). The tasks
run on a local Dask cluster of --workers processes (default 2, one thread each; 0 runs
them here, one after the other, without Dask), or on the workers of --scheduler.
Every worker opens its own OpenCL device once: --devices 0:0,0:1 gives worker i the
i-th (one worker per GPU), else each takes CLRADCOM_DEVICE or the default device.
A task that fails, or whose worker dies under it, runs again up to --retries times
(default 2); past that the sweep stops with an error naming the task.

The snapshots are bit for bit those of a serial run (docs/scale.md). Writes to --out
(default out/<scene>/sweep/): sweep-NNN.npz per task and sweep.csv, one row per task
(file, preset, the varied fields, links, paths, the worker's trace seconds and name);
the folder is built beside the old one and swapped in when the sweep is done.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

from clradcom.commands.console import progress_bar
from clradcom.commands.options import (
    command_parser,
    list_of,
    non_negative_int,
    output_folder,
    positive_int,
    run_tool,
)
from clradcom.commands.tradeoff import _vary
from clradcom.distributed import (
    check_scheduler_address,
    check_workers,
    max_local_workers,
    quiet_dask_logs,
    run_tasks,
    trace_tasks,
)
from clradcom.errors import ArgumentError
from clradcom.evaluation import tradeoff as tr
from clradcom.files import staged_folder, write_csv
from clradcom.mechanisms.common import ENGINES
from clradcom.presets import DEFAULT_PRESET, PRESETS
from clradcom.scene.reader import load_scene
from clradcom.snapshot import save_snapshot
from clradcom.trace import TraceSettings, check_launch_memory

#: the names this tool writes into its output folder (clradcom.files.staged_folder)
OUTPUTS = ("sweep.csv", "sweep-*.npz")


def _preset(text: str) -> str:
    if text not in PRESETS:
        raise argparse.ArgumentTypeError(f"must be one of {', '.join(PRESETS)}, got {text!r}")
    return text


def _option(check):
    """An argparse type from one of clradcom.distributed's checks: its refusal becomes
    argparse's one line about the option."""
    def parse(text: str):
        try:
            return check(text)
        except ArgumentError as exc:
            raise argparse.ArgumentTypeError(f"{exc.reason}, got {text!r}") from None
    parse.__name__ = check.__name__
    return parse


#: --workers: an integer from 0 to the machine's cores
_workers = _option(lambda text: check_workers(non_negative_int(text)))
#: --scheduler: SCHEME://HOST:PORT (reachability is checked when the run connects)
_scheduler = _option(check_scheduler_address)


def _device_list(text: str) -> list[str]:
    items = [t.strip() for t in text.split(",")]
    if not all(items):
        raise argparse.ArgumentTypeError(f"must be device specs separated by commas, "
                                         f"got {text!r}")
    return items


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    return command_parser(__doc__, add_arguments, prog)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``clradcom sweep`` / tools/sweep.py."""
    ap.add_argument("scene", help="scene file (TOML)")
    ap.add_argument("--out", type=output_folder, default=None,
                    help="output folder (default out/<scene>/sweep)")
    ap.add_argument("--preset", type=list_of(_preset, "preset"), default=[DEFAULT_PRESET],
                    help=f"presets to trace with, comma separated (default {DEFAULT_PRESET})")
    ap.add_argument("--vary", type=_vary, action="append", default=[],
                    help="FIELD=v1,v2: every value of a TraceSettings field (nested "
                         "specular.rays or a flat name); repeat for a grid")
    ap.add_argument("--engine", choices=ENGINES, default="device",
                    help="device (default) or host: who resolves the interactions")
    add_cluster_arguments(ap)
    ap.add_argument("--max-tasks", type=positive_int, default=10_000,
                    help="refuse a sweep of more tasks than this (default 10000)")
    ap.add_argument("-q", "--quiet", action="store_true",
                    help="no progress bar (it is shown only when stderr is a terminal)")


def add_cluster_arguments(ap: argparse.ArgumentParser):
    """Where the traces run (``clradcom sweep`` and ``clradcom drive``): ``--workers``,
    ``--scheduler``, ``--devices``, ``--retries`` (clradcom.distributed.run_tasks), in an
    argument group, returned for a command's own options of the kind."""
    g = ap.add_argument_group("where the traces run (Dask, docs/scale.md)")
    g.add_argument("--workers", type=_workers, default=2,
                   help="processes of the local Dask cluster (default 2, at most "
                        f"{max_local_workers()} here: one per core; 0: serially in this "
                        "process, without Dask)")
    g.add_argument("--scheduler", type=_scheduler, default=None, metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://host:8786) whose workers trace; "
                        "--workers is then not used")
    g.add_argument("--devices", type=_device_list, default=None,
                   help="OpenCL device specs shared out over the workers (worker i takes "
                        "the i-th, cyclically), e.g. 0:0,0:1 for one worker per GPU")
    g.add_argument("--retries", type=non_negative_int, default=2,
                   help="further attempts of a task that failed or whose worker died "
                        "(default 2)")
    return g


def cluster_text(args) -> str:
    """Where ``args`` (:func:`add_cluster_arguments`) run the traces, in words."""
    return (f"scheduler {args.scheduler}" if args.scheduler else
            f"a local cluster of {args.workers} workers" if args.workers else
            "this process (serial)")


def sweep_settings(presets, vary, engine: str = "device"):
    """Every (preset, varied values) combination as ``(row, TraceSettings)``, ``row``
    the CSV columns naming it; bad fields and values refused naming ``--vary``."""
    fields = []
    for name, values in vary:
        key = tr.settings_field(name)
        if key is None:
            raise ArgumentError(f"not a TraceSettings field (fields: "
                                f"{', '.join(tr.vary_field_names())})", argument="--vary",
                                value=name)
        fields.append((name, key, values))
    out = []
    for preset in presets:
        for combo in itertools.product(*(values for _, _, values in fields)):
            changes = {key: value for (_, key, _), value in zip(fields, combo, strict=True)}
            try:
                settings = TraceSettings.preset(preset, engine=engine, **changes)
            except (ArgumentError, TypeError) as exc:
                raise ArgumentError(str(exc), argument="--vary", value=", ".join(
                    f"{n}={v!r}" for (n, _, _), v in zip(fields, combo, strict=True))) from None
            row = {"preset": preset, **{n: v for (n, _, _), v in zip(fields, combo,
                                                                       strict=True)}}
            out.append((row, settings))
    return out


def main(argv=None, prog: str = "sweep.py") -> int:
    args = build_parser(prog).parse_args(argv)
    args.prog = prog
    return run_tool(prog, run, args)


def run(args) -> int:
    prog = getattr(args, "prog", "sweep.py")
    scene = load_scene(args.scene)
    points = sweep_settings(args.preset, args.vary, args.engine)
    if len(points) > args.max_tasks:
        raise ArgumentError(f"the sweep has {len(points)} tasks, more than --max-tasks "
                            f"{args.max_tasks}", argument="--vary", value=args.vary)
    for row, settings in points:
        check_launch_memory(settings, argument="--vary/--preset", value=row)
    keys = [f"sweep-{i:03d}" for i in range(len(points))]
    tasks = trace_tasks(scene, [s for _, s in points], keys=keys)
    out = Path(args.out or Path("out") / scene.name / "sweep")
    print(f"{len(tasks)} traces of {scene.name} ({len(scene.triangles)} triangles) on "
          f"{cluster_text(args)}, retries {args.retries}")
    columns = ["preset", *(name for name, _ in args.vary)]
    rows: list = [None] * len(tasks)
    with staged_folder(out, inputs=scene.input_files, owned=OUTPUTS) as stage:
        bar = progress_bar(len(tasks), "sweep", quiet=args.quiet, unit="trace")

        def done(i, result):
            snap = result.value
            save_snapshot(stage / f"{result.key}.npz", snap)
            n_paths = sum(link.paths.n_paths for link in snap)
            rows[i] = [f"{result.key}.npz", *(points[i][0][c] for c in columns),
                       len(snap.links), n_paths, f"{result.seconds:.3f}", result.worker]
            bar.update(1)
            bar.write(f"  {result.key} {points[i][0]}: {n_paths} paths, "
                      f"{result.seconds:.2f} s on worker {result.worker}")

        quiet_dask_logs()
        try:  # a task failing past --retries is a TaskError: one line, exit code 2
            results = run_tasks(tasks, workers=args.workers, scheduler=args.scheduler,
                                devices=args.devices, retries=args.retries, on_result=done,
                                keep=False)
        finally:
            bar.close()
        write_csv(stage / "sweep.csv", rows,
                  header=["file", *columns, "links", "paths", "trace_s", "worker"])
    total = sum(r.seconds for r in results)
    print(f"{prog}: {len(results)} snapshots, {total:.1f} s of tracing; wrote "
          f"{out / 'sweep.csv'}", file=sys.stdout)
    return 0
