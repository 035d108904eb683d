"""``clradcom presets``: the tracer's named physics (:mod:`clradcom.presets`), one line
each, or every setting of one (``clradcom presets NAME``) or of all (``-v``)."""

from __future__ import annotations

import argparse

from clradcom.presets import DEFAULT_PRESET, PRESETS
from clradcom.trace import TraceSettings

__all__ = ["add_arguments", "run"]


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("name", nargs="?", choices=tuple(PRESETS),
                    help="show every setting of this preset")
    ap.add_argument("-v", "--verbose", action="store_true",
                    help="every setting of every preset")


def run(args) -> int:
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
