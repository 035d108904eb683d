"""What a command shows while it runs, beside its results: progress bars and warnings.

* :func:`progress_bar`: a tqdm bar on stderr, off when stderr is not a terminal (a log
  file, a pipe, the test suite) or with ``--quiet``;
* :class:`WarningLog`: the physics and scene warnings a run raises
  (:class:`~clradcom.errors.PhysicsWarning`, :class:`~clradcom.errors.SceneWarning` and
  every other ``UserWarning``), each printed once, as the first time it is raised, as
  one line ``tool: warning: <message> [Class]`` instead of Python's
  ``file.py:459: Class`` form; repeats of the same warning (the same place in the code)
  are counted, and the end of the run has one summary line with the counts. Other
  warnings (numpy's, deprecations) keep Python's own form.
"""

from __future__ import annotations

import sys
import time
import warnings
from collections import Counter

from tqdm import tqdm

__all__ = ["WarningLog", "progress_bar", "stage_steps", "trace_steps", "write_line"]


def progress_bar(total: int | None, desc: str, *, quiet: bool = False, unit: str = "it",
                 stream=None) -> tqdm:
    """A tqdm bar on ``stream`` (stderr); disabled with ``quiet`` or when the stream is no
    terminal (tqdm's ``disable=None``). Close it (or use it in ``with``)."""
    stream = stream or sys.stderr
    terminal = bool(getattr(stream, "isatty", lambda: False)())
    return tqdm(total=total, desc=desc, unit=unit, file=stream, leave=False,
                disable=quiet or not terminal, dynamic_ncols=True)


def trace_steps(bar: tqdm):
    """A ``steps(done, total, label)`` callback for :func:`clradcom.trace.trace_scene` that
    moves ``bar``: links done of the total, the running mechanism as its label."""
    def steps(done: int, total: int, label: str) -> None:
        if bar.disable:
            return
        bar.total = total
        bar.n = done
        bar.set_description_str(label, refresh=False)
        bar.refresh()
    return steps


def write_line(text: str, stream=None) -> None:
    """``text`` as one line on ``stream`` (stdout) above the progress bars, at once."""
    out = stream or sys.stdout
    tqdm.write(text, file=out)
    out.flush()


def stage_steps(bar: tqdm, started: float, stream=None):
    """A ``progress(message)`` callback for a run of stages whose count is ``bar.total``:
    each message ends the stage before it (the bar moves on by one), becomes the bar's
    label, and is printed above the bar as ``[  12.3 s] message ...`` (seconds since
    ``started``, a ``time.perf_counter()``) on ``stream`` (stdout), so a log without a
    terminal still shows the stages in order."""
    calls = 0

    def progress(message: str) -> None:
        nonlocal calls
        if calls:
            bar.update(1)
        calls += 1
        bar.set_description_str(message, refresh=True)
        write_line(f"[{time.perf_counter() - started:6.1f} s] {message} ...", stream)
    return progress


def _one_line(message) -> str:
    return " ".join(str(message).split())


class WarningLog:
    """Collects the warnings raised inside ``with WarningLog("tool")``: the first of each
    (its category and the place in the code that raises it) printed at once as one clean
    line, later ones counted; on leaving, one summary line with the counts per class.

    ``lines`` holds what was printed (first lines and the summary), ``counts`` the number
    of each warning class."""

    def __init__(self, tool: str, stream=None):
        self.tool = tool
        self.stream = stream
        self.counts: Counter[str] = Counter()
        self.seen: Counter[tuple] = Counter()
        self.lines: list[str] = []
        self._catch = None

    def _write(self, line: str) -> None:
        self.lines.append(line)
        tqdm.write(line, file=self.stream or sys.stderr)

    def _show(self, message, category, filename, lineno, file=None, line=None):
        if not issubclass(category, UserWarning):
            self._previous(message, category, filename, lineno, file, line)
            return
        key = (category, filename, lineno)
        self.seen[key] += 1
        self.counts[category.__name__] += 1
        if self.seen[key] == 1:
            self._write(f"{self.tool}: warning: {_one_line(message)} [{category.__name__}]")

    def __enter__(self) -> WarningLog:
        self._catch = warnings.catch_warnings()
        self._catch.__enter__()
        # every occurrence reaches _show, which counts them and prints the first
        warnings.simplefilter("always", UserWarning)
        self._previous = warnings.showwarning
        warnings.showwarning = self._show
        return self

    def summary(self) -> str | None:
        """``tool: 14 warnings (3 kinds, each shown once above): NearFieldWarning x12,
        ...``, or None when there were none."""
        total = sum(self.counts.values())
        if not total:
            return None
        parts = ", ".join(f"{name} x{n}" for name, n in self.counts.most_common())
        kinds = len(self.seen)
        return (f"{self.tool}: {total} warning{'s' if total != 1 else ''} ({kinds} "
                f"kind{'s' if kinds != 1 else ''}, each shown once above): {parts}")

    def __exit__(self, *exc) -> None:
        self._catch.__exit__(*exc)
        line = self.summary()
        if line is not None:
            self._write(line)
