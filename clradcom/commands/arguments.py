"""The option types and the error boundary that every command shares, apart from what
the commands do (:mod:`clradcom.commands.options`), so that the ``clradcom`` entry point
and the scripts in tools/ load them without the tracer, the radar or Dask:

* option types for argparse (:func:`positive_int`, :func:`seed`, :func:`finite_float`,
  :func:`float_in`, :func:`list_of`, :func:`output_folder`, ...): a value is refused where
  it is parsed, with the option and the value in the message (``argument --rays: must be
  a positive integer, got '-1'``);
* :func:`run_tool`: the project's errors (:data:`TOOL_ERRORS`) become one line
  ``tool.py: <message>`` on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

from clradcom.commands.console import WarningLog
from clradcom.device.runtime import OpenCLError, describe_cl_error, last_device_label
from clradcom.errors import (
    ArgumentError,
    ArgumentTypeError,
    SceneError,
    SnapshotError,
    TaskError,
)
from clradcom.files import OutputError

#: what a tool reports as one line (exit code 2): bad input, a device problem, an output
#: that cannot be written, a computation over the memory budget (an ArgumentError), a
#: distributed task that failed past its retries
TOOL_ERRORS = (SceneError, SnapshotError, ArgumentError, ArgumentTypeError, OpenCLError,
               OutputError, TaskError)


# ----------------------------------------------------------------------------------------
# option types
# ----------------------------------------------------------------------------------------
def _refuse(text, what):
    raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")


def _int(text) -> int:
    try:
        return int(str(text).strip().replace("_", ""))
    except ValueError:
        _refuse(text, "an integer")


def _float(text) -> float:
    try:
        value = float(text)
    except ValueError:
        _refuse(text, "a number")
    if not math.isfinite(value):
        _refuse(text, "a finite number")
    return value


def positive_int(text) -> int:
    """An integer >= 1."""
    value = _int(text)
    if value < 1:
        _refuse(text, "a positive integer")
    return value


def non_negative_int(text) -> int:
    """An integer >= 0."""
    value = _int(text)
    if value < 0:
        _refuse(text, "an integer >= 0")
    return value


def seed(text) -> int:
    """A random seed: an integer in [0, 2^63 - 1] (numpy's generators refuse negative
    seeds; the noise uses seed + 1)."""
    value = _int(text)
    if not 0 <= value < 2**63 - 1:
        _refuse(text, "an integer in [0, 2^63 - 2]")
    return value


def int_in(low: int, high: int):
    """An integer in [low, high]."""
    def parse(text) -> int:
        value = _int(text)
        if not low <= value <= high:
            _refuse(text, f"an integer in [{low}, {high}]")
        return value
    parse.__name__ = f"int_in_{low}_{high}"
    return parse


def float_in(low: float, high: float):
    """A finite number in [low, high]."""
    def parse(text) -> float:
        value = _float(text)
        if not low <= value <= high:
            _refuse(text, f"a number in [{low:g}, {high:g}]")
        return value
    parse.__name__ = f"float_in_{low:g}_{high:g}"
    return parse


def finite_float(text) -> float:
    """A finite number."""
    return _float(text)


def positive_float(text) -> float:
    """A finite number > 0."""
    value = _float(text)
    if not value > 0:
        _refuse(text, "a positive finite number")
    return value


def non_negative_float(text) -> float:
    """A finite number >= 0."""
    value = _float(text)
    if not value >= 0:
        _refuse(text, "a finite number >= 0")
    return value


def noise_figure_db(text) -> float:
    """A receiver noise figure: a finite number of dB >= 0 (F = 10^(NF/10) >= 1)."""
    value = _float(text)
    if value < 0:
        _refuse(text, "a noise figure >= 0 dB (a receiver adds noise, it removes none)")
    return value


def list_of(convert: Callable, name: str = "value"):
    """A comma-separated list of at least one item, each through ``convert`` (one of the
    types above); a refused item is named with its position."""
    def parse(text) -> list:
        items = [v.strip() for v in str(text).split(",") if v.strip()]
        if not items:
            raise argparse.ArgumentTypeError(f"needs at least one {name}, got {text!r}")
        out = []
        for i, item in enumerate(items):
            try:
                out.append(convert(item))
            except argparse.ArgumentTypeError as exc:
                raise argparse.ArgumentTypeError(
                    f"{name} {i + 1} of {text!r}: {exc}") from None
        return out
    parse.__name__ = f"list_of_{getattr(convert, '__name__', 'values')}"
    return parse


def output_folder(text) -> str:
    """An output folder: a path that is no existing file (it may not exist yet)."""
    if not str(text).strip():
        raise argparse.ArgumentTypeError("must name a folder, got an empty string")
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} exists and is not a folder; name a "
                                         "folder for the outputs")
    return str(text)


# ----------------------------------------------------------------------------------------
# the error boundary of a tool
# ----------------------------------------------------------------------------------------
def run_tool(tool: str, body: Callable[..., int], *args, **kwargs) -> int:
    """``body(*args, **kwargs)``'s exit code; the project's errors (:data:`TOOL_ERRORS`)
    print ``tool: <message>`` on stderr and give 2, an interrupt gives 130 (the staged
    output folders are then left as they were), running out of memory gives 2 with a
    line saying so. Anything else is a bug and keeps its traceback.

    The warnings the run raises go through :class:`~clradcom.commands.console.WarningLog`:
    each printed once as ``tool: warning: <message> [Class]``, counted, summed up at
    the end."""
    try:
        with WarningLog(tool):
            return body(*args, **kwargs)
    except TOOL_ERRORS as exc:
        print(f"{tool}: {exc}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"{tool}: ran out of memory; ask for less (fewer rays, subcarriers or "
              f"symbols) or set CLRADCOM_MEMORY_BUDGET lower so that such runs are "
              f"refused before they start", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{tool}: interrupted; the output folder was left as it was",
              file=sys.stderr)
        return 130
    except Exception as exc:
        # an OpenCL failure that no launch site named: still one line, never a traceback
        message = opencl_failure(exc)
        if message is None:
            raise
        print(f"{tool}: {message}", file=sys.stderr)
        return 2


def opencl_failure(exc: BaseException) -> str | None:
    """One line for a pyopencl error that reached the top of a command (None for anything
    else): the status and what to try, the device being the one the run chose."""
    try:
        import pyopencl as cl
    except ImportError:  # pragma: no cover - a hard dependency
        return None
    if not isinstance(exc, cl.Error):
        return None
    return describe_cl_error(exc, last_device_label(), "call")
