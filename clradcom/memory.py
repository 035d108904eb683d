"""The memory budget: estimates of large allocations are checked against it before any of
them is made, and refused with the estimate and what to change (docs/reliability.md)."""

from __future__ import annotations

import os

from clradcom.errors import ArgumentError, MemoryBudgetError

__all__ = ["ENV_MEMORY_BUDGET", "MEMORY_SHARE", "check_memory", "format_bytes",
           "memory_budget_bytes", "parse_bytes"]


#: environment variable that sets the memory budget: bytes, or a number with a binary
#: suffix K, M, G or T ("24G")
ENV_MEMORY_BUDGET = "CLRADCOM_MEMORY_BUDGET"
#: share of the machine's physical memory one computation may plan to hold by default
MEMORY_SHARE = 0.5
_SUFFIXES = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def format_bytes(n: float) -> str:
    """``80000000000`` -> ``"74.5 GiB"``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError  # pragma: no cover


def _physical_memory() -> int | None:
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):  # pragma: no cover - not POSIX
        return None


def parse_bytes(text: str, argument: str) -> int:
    """A number of bytes written as ``24G``, ``512M``, ``1.5GiB`` or plain bytes; anything
    else is refused naming ``argument``."""
    text = str(text).strip()
    number, suffix = text.upper().rstrip("IB"), ""
    if number[-1:] in _SUFFIXES:
        number, suffix = number[:-1], number[-1]
    try:
        value = float(number) * _SUFFIXES[suffix]
    except ValueError:
        value = -1.0
    if not 0 < value < float("inf"):
        raise ArgumentError("must be a positive number of bytes, optionally with K, M, "
                            "G or T (e.g. 24G)", argument=argument, value=text)
    return int(value)


def memory_budget_bytes(budget_bytes: float | None = None) -> tuple[int | None, str]:
    """(bytes one computation may plan to hold, where that number comes from).

    ``budget_bytes`` when given; else the environment variable
    :data:`ENV_MEMORY_BUDGET`; else :data:`MEMORY_SHARE` of the machine's physical memory;
    ``(None, ...)`` where none of these is known (nothing is refused then).
    """
    if budget_bytes is not None:
        if (isinstance(budget_bytes, bool) or not isinstance(budget_bytes, int | float)
                or not budget_bytes > 0 or budget_bytes == float("inf")):
            raise ArgumentError("must be a positive number of bytes", argument="budget_bytes",
                                value=budget_bytes)
        return int(budget_bytes), "the budget given"
    text = os.environ.get(ENV_MEMORY_BUDGET, "").strip()
    if text:
        return parse_bytes(text, ENV_MEMORY_BUDGET), f"{ENV_MEMORY_BUDGET}={text}"
    physical = _physical_memory()
    if physical is None:  # pragma: no cover - not POSIX
        return None, "unknown"
    return int(MEMORY_SHARE * physical), (f"{MEMORY_SHARE:.0%} of this machine's "
                                          f"{format_bytes(physical)}; set "
                                          f"{ENV_MEMORY_BUDGET} to change it")


def check_memory(nbytes: float, *, what: str, argument: str, value: object,
                 advice: str, budget_bytes: float | None = None) -> None:
    """Refuse, before any of it is allocated, a computation estimated to hold ``nbytes``
    over the memory budget (:func:`memory_budget_bytes`): :class:`MemoryBudgetError`
    naming ``argument = value``, the estimate of ``what`` and ``advice`` (what to
    change)."""
    budget, source = memory_budget_bytes(budget_bytes)
    if budget is not None and nbytes > budget:
        raise MemoryBudgetError(f"{what} would need about {format_bytes(nbytes)} of memory, "
                                f"over the budget of {format_bytes(budget)} ({source}); "
                                f"{advice}", argument=argument, value=value)
