"""OpenCL runtime: device choice, program building and caching.

Device choice, in order of precedence:

1. an explicit ``spec`` (the CLI's ``--device`` flag),
2. the environment variable ``CLRADCOM_DEVICE``,
3. the first GPU any platform offers,
4. PoCL's CPU device (installed with ``pip install clradcom[pocl]``),
5. any other CPU device.

A spec is ``"gpu"``, ``"cpu"``, ``"P:D"`` (platform and device index as
``clradcom devices`` lists them), or a case-insensitive substring of the
platform or device name (``"pocl"``, ``"nvidia"``, ``"H100"``).

Kernel sources live in ``kernels/`` (installed as ``clradcom.kernels``) and
are read through :mod:`importlib.resources`, so an installed copy finds them.
``#include "x.h"`` lines are expanded on the host with ``#line`` markers:
compiler messages still name the original file and line, and no vendor
binary cache can serve a program built against a stale header. Numbers the
host and the kernels share reach a build as ``defines`` (``-D NAME=value``),
so the host is their only source.
"""

from __future__ import annotations

import importlib.resources
import os
import re
import threading
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError

ENV_DEVICE = "CLRADCOM_DEVICE"

INSTALL_HINT = (
    "No OpenCL platform was found. clradcom needs one OpenCL device; the simplest is "
    "PoCL's CPU device from the package registry:\n"
    "    pip install 'clradcom[pocl]'    (or: pip install pocl-binary-distribution)\n"
    "A GPU vendor's OpenCL driver (NVIDIA, AMD, Intel) works as well."
)


class OpenCLError(RuntimeError):
    """An OpenCL set-up or build problem, with a message that says what to do."""


@dataclass(frozen=True)
class DeviceInfo:
    platform_index: int
    device_index: int
    platform_name: str
    device_name: str
    device_type: str
    compute_units: int
    global_mem_bytes: int
    has_double: bool

    @property
    def spec(self) -> str:
        return f"{self.platform_index}:{self.device_index}"

    def describe(self) -> str:
        fp64 = "fp64" if self.has_double else "no fp64"
        return (
            f"[{self.spec}] {self.device_type:<5} {self.device_name.strip()} "
            f"({self.platform_name.strip()}; {self.compute_units} CUs, "
            f"{self.global_mem_bytes / 2**30:.1f} GiB, {fp64})"
        )


def _cl():
    try:
        import pyopencl as cl
    except ImportError as exc:  # pragma: no cover - pyopencl is a hard dependency
        raise OpenCLError(f"pyopencl is not importable ({exc}). {INSTALL_HINT}") from exc
    return cl


def _type_name(device) -> str:
    cl = _cl()
    if device.type & cl.device_type.GPU:
        return "GPU"
    if device.type & cl.device_type.CPU:
        return "CPU"
    if device.type & cl.device_type.ACCELERATOR:
        return "ACCEL"
    return "OTHER"


def _platforms():
    cl = _cl()
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:  # PLATFORM_NOT_FOUND_KHR when the ICD loader finds nothing
        raise OpenCLError(INSTALL_HINT) from exc
    if not platforms:
        raise OpenCLError(INSTALL_HINT)
    return platforms


def list_devices() -> list[DeviceInfo]:
    """Every OpenCL device on every platform, in the order specs index them."""
    cl = _cl()
    infos = []
    for p_index, platform in enumerate(_platforms()):
        try:
            devices = platform.get_devices()
        except cl.Error:
            devices = []
        for d_index, device in enumerate(devices):
            infos.append(
                DeviceInfo(
                    platform_index=p_index,
                    device_index=d_index,
                    platform_name=platform.name,
                    device_name=device.name,
                    device_type=_type_name(device),
                    compute_units=int(device.max_compute_units),
                    global_mem_bytes=int(device.global_mem_size),
                    has_double=bool(device.double_fp_config),
                )
            )
    if not infos:
        raise OpenCLError(INSTALL_HINT)
    return infos


def _is_pocl(info: DeviceInfo) -> bool:
    return "portable computing language" in info.platform_name.lower() or (
        "pocl" in info.platform_name.lower()
    )


def choose_device(spec: str | None = None) -> DeviceInfo:
    """Pick a device by spec, environment variable, or the default order."""
    infos = list_devices()
    source = "--device"
    if spec is None:
        spec = os.environ.get(ENV_DEVICE) or None
        source = ENV_DEVICE
    if spec is None:
        for rule in (
            lambda i: i.device_type == "GPU",
            lambda i: i.device_type == "CPU" and _is_pocl(i),
            lambda i: i.device_type == "CPU",
            lambda i: True,
        ):
            for info in infos:
                if rule(info):
                    return info
    text = spec.strip()
    low = text.lower()
    if re.fullmatch(r"\d+:\d+", text):
        p, d = (int(x) for x in text.split(":"))
        for info in infos:
            if (info.platform_index, info.device_index) == (p, d):
                return info
    elif low in ("gpu", "cpu"):
        for info in infos:
            if info.device_type == low.upper():
                return info
    else:
        for info in infos:
            if low in info.device_name.lower() or low in info.platform_name.lower():
                return info
    seen = "\n  ".join(i.describe() for i in infos)
    raise OpenCLError(
        f"{source}={spec!r} matches no OpenCL device. Devices seen:\n  {seen}\n"
        "Use 'gpu', 'cpu', 'P:D' or part of a platform or device name."
    )


# ---------------------------------------------------------------------------
# kernel sources

_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*$')


def kernel_source(name: str) -> str:
    """Source of ``kernels/<name>`` with local includes expanded (with #line markers)."""
    root = importlib.resources.files("clradcom.kernels")

    def expand(fname: str, stack: tuple[str, ...]) -> str:
        if fname in stack:
            raise OpenCLError(f"kernels/{fname}: include cycle {' -> '.join(stack + (fname,))}")
        res = root.joinpath(fname)
        if not res.is_file():
            raise OpenCLError(
                f"kernels/{fname} not found in the installed package "
                f"(from {stack[-1] if stack else 'the host'}); reinstall clradcom"
            )
        out = [f'#line 1 "{fname}"']
        for lineno, line in enumerate(res.read_text().splitlines(), start=1):
            m = _INCLUDE.match(line)
            if m:
                out.append(expand(m.group(1), stack + (fname,)))
                out.append(f'#line {lineno + 1} "{fname}"')
            else:
                out.append(line)
        return "\n".join(out)

    return expand(name, ())


_MACRO_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def define_options(defines: Mapping[str, int] | None) -> tuple[str, ...]:
    """``-D NAME=value`` build options for integer macros, sorted so that equal
    mappings give one program cache key."""
    options = []
    for name, value in sorted((defines or {}).items()):
        if not _MACRO_NAME.fullmatch(name):
            raise ArgumentError(f"{name!r} is not a C macro name")
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ArgumentError(f"macro {name} must be an integer, got {value!r}")
        options.append(f"-D{name}={int(value)}")
    return tuple(options)


def _format_build_log(name: str, log: str) -> str:
    lines = [ln for ln in log.splitlines() if ln.strip()]
    located = [ln for ln in lines if re.search(r"[\w.]+\.(cl|h):\d+", ln)]
    head = located[0] if located else (lines[0] if lines else "(empty log)")
    return f"OpenCL build of kernels/{name} failed at {head}\n--- compiler log ---\n{log}"


class Runtime:
    """One context and in-order queue on one device, with a program cache.

    :attr:`kernel_seconds` counts the wall time spent inside kernel launches on this
    runtime, from enqueue to finish (the ray caster's :meth:`kernel_clock` blocks):
    what a benchmark compares with a whole trace's time to see the share spent in
    kernels.
    """

    def __init__(self, spec: str | None = None):
        cl = _cl()
        self.info = choose_device(spec)
        platform = _platforms()[self.info.platform_index]
        self.device = platform.get_devices()[self.info.device_index]
        self.context = cl.Context([self.device])
        self.queue = cl.CommandQueue(self.context)
        self._programs: dict[tuple[str, tuple[str, ...]], object] = {}
        self._kernels: dict[tuple, object] = {}
        self._lock = threading.Lock()
        self._kernel_seconds = 0.0
        #: -D CLR_INLINE_BUILTINS=1 on every build (kernels/fastmath.h): PoCL calls its
        #: builtins (dot, fabs, sqrt, ...) out of line, and inline ones with the same
        #: arithmetic give the same bits in less time. A plain attribute, so a benchmark
        #: can build both variants in one process (the program cache keys on it).
        self.inline_builtins = _is_pocl(self.info)

    @property
    def kernel_seconds(self) -> float:
        """Wall seconds spent inside :meth:`kernel_clock` blocks since this runtime was
        made: read it before and after a piece of work for that work's share."""
        return self._kernel_seconds

    @contextmanager
    def kernel_clock(self) -> Iterator[None]:
        """Add the wall time of the block (enqueue to finish of a kernel launch, with its
        transfers) to :attr:`kernel_seconds`. Blocks may run in several threads at once;
        their times then add up (so the sum can exceed the wall time of the whole)."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            dt = time.perf_counter() - t0
            with self._lock:
                self._kernel_seconds += dt

    @property
    def has_double(self) -> bool:
        return self.info.has_double

    def program(self, name: str, options: tuple[str, ...] = (),
                defines: Mapping[str, int] | None = None):
        """Built program for ``kernels/<name>``, compiled once per runtime, options and
        defines."""
        options = tuple(options) + define_options(defines)
        key = (name, options, self.inline_builtins)
        with self._lock:
            prog = self._programs.get(key)
            if prog is None:
                prog = self.build(kernel_source(name), name, options)
                self._programs[key] = prog
            return prog

    def kernel(self, name: str, kernel_name: str, options: tuple[str, ...] = (),
               defines: Mapping[str, int] | None = None):
        """One cached Kernel object per (program, kernel): pyopencl makes a new one per lookup."""
        options = tuple(options) + define_options(defines)
        key = (name, options, kernel_name, self.inline_builtins)
        with self._lock:
            k = self._kernels.get(key)
        if k is None:
            k = _cl().Kernel(self.program(name, options), kernel_name)
            with self._lock:
                self._kernels.setdefault(key, k)
        return k

    def build(self, source: str, name: str, options: tuple[str, ...] = (),
              defines: Mapping[str, int] | None = None):
        """Compile ``source``; a failure raises OpenCLError naming file, line and log.
        On PoCL (:attr:`inline_builtins`) the build also gets -D CLR_INLINE_BUILTINS=1."""
        cl = _cl()
        options = tuple(options) + define_options(defines)
        if self.inline_builtins:
            options += ("-DCLR_INLINE_BUILTINS=1",)
        try:
            return cl.Program(self.context, source).build(options=list(options))
        except cl.RuntimeError as exc:
            log = getattr(exc, "build_log", None)
            text = str(exc) if not log else "\n".join(str(x[1]) for x in log)
            raise OpenCLError(_format_build_log(name, text)) from None

    def to_device(self, array: np.ndarray):
        """Read-only device buffer holding a contiguous copy of ``array``."""
        cl = _cl()
        array = np.ascontiguousarray(array)
        flags = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
        if array.nbytes == 0:  # zero-sized buffers are invalid in OpenCL
            array = np.zeros(1, dtype=array.dtype)
        return cl.Buffer(self.context, flags, hostbuf=array)

    def empty(self, nbytes: int):
        cl = _cl()
        return cl.Buffer(self.context, cl.mem_flags.READ_WRITE, size=max(int(nbytes), 1))


_default_runtimes: dict[tuple[str | None, str | None], Runtime] = {}
_default_lock = threading.Lock()


def get_runtime(spec: str | None = None) -> Runtime:
    """Shared runtime for a spec (None: environment variable, then default order)."""
    # the environment variable is part of the key but not passed on as the spec, so that
    # an error blames the variable that was set, not a --device flag never given
    key = (spec, None if spec is not None else os.environ.get(ENV_DEVICE) or None)
    with _default_lock:
        rt = _default_runtimes.get(key)
        if rt is None:
            rt = Runtime(spec)
            _default_runtimes[key] = rt
        return rt
