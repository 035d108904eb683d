#!/usr/bin/env python
"""``clradcom cube`` as a script: a radar with an antenna array, its TDM-MIMO frame, the
radar cube, the point cloud and the truth table (clradcom/commands/cube.py)."""

import sys

from clradcom.commands.cube import main

if __name__ == "__main__":
    sys.exit(main(prog="cube.py"))
