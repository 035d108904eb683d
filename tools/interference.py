#!/usr/bin/env python3
"""The same as ``clradcom interference`` (clradcom.commands.interference); ``--help``
lists the options."""

import sys

from clradcom.commands.interference import build_parser, main, parse_args, run

__all__ = ["build_parser", "main", "parse_args", "run"]

if __name__ == "__main__":
    sys.exit(main(prog="interference.py"))
