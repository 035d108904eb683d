"""Benchmark the start of the ``clradcom`` command: how long a fresh interpreter takes to
import the package, print ``clradcom --help``, list ``clradcom presets``, and to import
every command's module (what ``import clradcom.cli`` loaded before the commands were
imported on demand), each against a plain ``python -c pass`` measured in the same run.

The runs are interleaved (pass, then each case, ``--repeat`` rounds) so that a load on
the machine weighs on all of them alike; the median of each is printed with its ratio to
the median of ``pass``. ``python -X importtime -m clradcom --help`` shows where the time
of one goes.

    python tools/bench_cli_import.py [--repeat 7]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

from clradcom.cli import SUBCOMMANDS, positive_int, run_tool

#: every command module, imported at once: the old `import clradcom.cli`
ALL_COMMANDS = "; ".join(sorted({f"import clradcom.commands.{module}"
                                 for _help, module, *_rest in SUBCOMMANDS.values()}))

CASES = {
    "python -c pass": ["-c", "pass"],
    "import clradcom": ["-c", "import clradcom"],
    "import clradcom.cli": ["-c", "import clradcom.cli"],
    "clradcom --help": ["-m", "clradcom", "--help"],
    "clradcom presets": ["-m", "clradcom", "presets"],
    "every command module": ["-c", ALL_COMMANDS],
}


def wall_time(argv: list[str]) -> float:
    """Seconds a fresh interpreter takes to run ``argv`` (its output discarded)."""
    start = time.perf_counter()
    subprocess.run([sys.executable, *argv], check=True, stdout=subprocess.DEVNULL,
                   env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
    return time.perf_counter() - start


def measure(repeat: int) -> dict[str, list[float]]:
    """Seconds per case, ``repeat`` interleaved rounds (one warm-up round first, so the
    byte code and the file cache are warm for all)."""
    for argv in CASES.values():
        wall_time(argv)
    times: dict[str, list[float]] = {name: [] for name in CASES}
    for _ in range(repeat):
        for name, argv in CASES.items():
            times[name].append(wall_time(argv))
    return times


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=positive_int, default=7,
                    help="interleaved rounds (default 7)")
    args = ap.parse_args(argv)
    return run_tool("bench_cli_import.py", body, args)


def body(args) -> int:
    times = measure(args.repeat)
    reference = statistics.median(times["python -c pass"])
    print(f"{'case':24s} {'median s':>9s} {'min s':>7s} {'x pass':>7s}   "
          f"({args.repeat} interleaved rounds; load {os.getloadavg()[0]:.1f})")
    for name, values in times.items():
        median = statistics.median(values)
        print(f"{name:24s} {median:9.3f} {min(values):7.3f} {median / reference:7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
