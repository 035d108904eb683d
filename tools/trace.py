#!/usr/bin/env python3
"""The scene runner: the same as ``clradcom trace`` (clradcom.commands.trace).

    python tools/trace.py scenes/street/street.toml

``python tools/trace.py --help`` lists the options; ``clradcom presets`` the physics.
"""

import sys

from clradcom.commands.trace import (
    OUTPUTS,
    add_arguments,
    build_parser,
    main,
    radar_noise,
    radar_stage,
    run,
    settings_from_args,
)

__all__ = ["OUTPUTS", "add_arguments", "build_parser", "main", "radar_noise", "radar_stage",
           "run", "settings_from_args"]

if __name__ == "__main__":
    sys.exit(main(prog="trace.py"))
