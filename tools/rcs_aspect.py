#!/usr/bin/env python3
"""The same as ``clradcom rcs`` (clradcom.commands.rcs); ``--help`` lists the options."""

import sys

from clradcom.commands.rcs import build_parser, main, measure, parse_args, run

__all__ = ["build_parser", "main", "measure", "parse_args", "run"]

if __name__ == "__main__":
    sys.exit(main(prog="rcs_aspect.py"))
