#!/usr/bin/env python3
"""The same as ``clradcom comms`` (clradcom.commands.comms); ``--help`` lists the options."""

import sys

from clradcom.commands.comms import build_parser, main, parse_args, run

__all__ = ["build_parser", "main", "parse_args", "run"]

if __name__ == "__main__":
    sys.exit(main(prog="comms.py"))
