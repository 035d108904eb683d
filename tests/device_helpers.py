"""The device matrix's helpers: reading Oclgrind's reports (tests/conftest.py fails a
test by them on Oclgrind; tests/test_device_matrix.py reads a whole run's), and running
an entry's test subset in a subprocess, in the background while the rest of the suite
runs. An entry is an implementation (``pocl``, ``intel``, ``oclgrind``), or one run as a
device without fp64 (``pocl-fp64-off``: ``--fp64=off``)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path

from clradcom.device.runtime import ENV_DEVICE, ENV_FP64

#: The first line of every report Oclgrind prints: an OpenCL API error, a fatal error, or
#: a kernel's error or warning (memory, data race, uninitialised value), whose second line
#: names the kernel.
OCLGRIND_REPORT = re.compile(
    r"^(Oclgrind - OpenCL runtime error detected|OCLGRIND FATAL ERROR.*|\tKernel: .*)$",
    re.MULTILINE)


def oclgrind_reports(text: str) -> list[str]:
    """The reports in Oclgrind's output ``text``, each as the line that starts it (for a
    kernel's report, the message line before its ``Kernel:`` line joined to it)."""
    lines = text.splitlines()
    out = []
    for i, line in enumerate(lines):
        if OCLGRIND_REPORT.match(line):
            if line.startswith("\tKernel:"):
                head = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
                out.append(f"{head.strip()} ({line.strip()})")
            else:
                out.append(line.strip())
    return out


# ---------------------------------------------------------------------------
# the device matrix's subprocesses (tests/test_device_matrix.py)

ROOT = Path(__file__).resolve().parent.parent
#: what Oclgrind checks when the matrix runs it (docs/devices.md): all of it
OCLGRIND_CHECKS = {"OCLGRIND_CHECK_API": "1", "OCLGRIND_DATA_RACES": "1",
                   "OCLGRIND_UNINITIALIZED": "1"}
#: one subprocess's wall-clock limit: several times what it takes on CI's two busy cores
SUBPROCESS_TIMEOUT_S = 1800
#: an entry's name for its implementation run as a device without fp64
NO_FP64_SUFFIX = "-fp64-off"
#: the implementations the matrix also runs without fp64 (--fp64=off): PoCL, as some
#: mobile and integrated GPUs would run the kernels (tests/mode_helpers.py: the no-fp64
#: build's contract the conformance tests hold it to)
NO_FP64_DEVICES = ("pocl",)


def entry_device(name: str) -> tuple[str, bool]:
    """(implementation, without fp64) of the matrix entry ``name``."""
    if name.endswith(NO_FP64_SUFFIX):
        return name[:-len(NO_FP64_SUFFIX)], True
    return name, False


@dataclass
class SubsetRun:
    """One implementation's run of its subset: the command, and once it is done its exit
    status (None: it ran past the limit) and output."""

    name: str
    cmd: list[str]
    returncode: int | None = None
    output: str = ""
    done: threading.Event = field(default_factory=threading.Event)


def subset_command(name: str) -> tuple[list[str], dict[str, str]]:
    """The command and environment that run entry ``name``'s subset: ``-m conformance``,
    on Oclgrind ``-m oclgrind`` with all its checks on; ``--fp64=off`` for an entry
    without fp64."""
    device, no_fp64 = entry_device(name)
    marker = "oclgrind" if device == "oclgrind" else "conformance"
    env = dict(os.environ, **{ENV_DEVICE: device})
    if device == "oclgrind":
        env.update(OCLGRIND_CHECKS)
    mode = []
    if no_fp64:
        env[ENV_FP64] = "0"
        mode = ["--fp64=off"]
    cmd = [sys.executable, "-m", "pytest", "-m", marker, "--device", device, *mode,
           "-p", "no:cacheprovider", "-q", "-rfE", str(ROOT / "tests")]
    return cmd, env


_RUNS: dict[str, SubsetRun] = {}
_RUNS_LOCK = threading.Lock()


def _run(runs: list[SubsetRun]) -> None:
    for run in runs:
        cmd, env = subset_command(run.name)
        try:
            done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True,
                                  timeout=SUBPROCESS_TIMEOUT_S)
            run.returncode, run.output = done.returncode, done.stdout + done.stderr
        except subprocess.TimeoutExpired as exc:
            out = exc.stdout or b""
            run.output = out.decode(errors="replace") if isinstance(out, bytes) else out
        finally:
            run.done.set()


def start_subset_runs(names) -> None:
    """Start the subsets of ``names`` one after another in a background thread (the
    suite's collection does, so they run while the rest of the suite does: a pytest
    process keeps about one of two cores busy); each name once."""
    with _RUNS_LOCK:
        runs = []
        for name in names:
            if name not in _RUNS:
                _RUNS[name] = SubsetRun(name, subset_command(name)[0])
                runs.append(_RUNS[name])
    if runs:
        threading.Thread(target=_run, args=(runs,), name="device-matrix",
                         daemon=True).start()


def subset_run(name: str) -> SubsetRun:
    """``name``'s finished run (started now where it was not yet)."""
    start_subset_runs([name])
    run = _RUNS[name]
    run.done.wait()
    return run
