"""Reading Oclgrind's reports (tests/conftest.py fails a test by them on Oclgrind;
tests/test_device_matrix.py reads a whole run's)."""

from __future__ import annotations

import re

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
