#!/usr/bin/env python3
"""The same as ``clradcom sweep`` (clradcom.commands.sweep); ``--help`` lists the options."""

import sys

from clradcom.commands.sweep import build_parser, main, run

__all__ = ["build_parser", "main", "run"]

if __name__ == "__main__":
    sys.exit(main(prog="sweep.py"))
