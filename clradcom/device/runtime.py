"""OpenCL runtime: device choice, program building and caching.

Device choice, in order of precedence:

1. an explicit ``spec`` (the CLI's ``--device`` flag),
2. the environment variable ``CLRADCOM_DEVICE``,
3. the first GPU any platform offers,
4. PoCL's CPU device (installed with ``pip install clradcom[pocl]``),
5. any other CPU device.

A spec is ``"gpu"``, ``"cpu"``, ``"P:D"`` (platform and device index as
``clradcom devices`` lists them), one of the implementation names people type
(:data:`VENDOR_NAMES`: ``pocl``, ``intel``, ``nvidia``, ``amd``, ``oclgrind``), or
a case-insensitive substring of the platform or device name (``"H100"``). The
default order never picks Oclgrind: it is a simulator that calls itself a GPU, and
runs only where a user asks for it by name.

Devices without fp64 are first-class: every kernel builds in a mode without
double (precise.h's double-float for what becomes a phase). ``Runtime(fp64=False)``
or ``CLRADCOM_FP64=0`` forces that mode on any device (``-D CLRADCOM_NO_FP64=1`` on
every build, ``info.has_double`` False), so the tests run it on PoCL and Intel.

Every OpenCL failure (build, kernel creation, launch, out of resources, memory)
becomes an :class:`OpenCLError` of one line naming the device, the kernel and what
to try (:func:`describe_cl_error`, :meth:`Runtime.guard`).

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
#: "0" (or "off", "no", "false") forces the no-fp64 mode on every runtime made without an
#: explicit ``fp64``; anything else (or unset) uses fp64 where the device has it
ENV_FP64 = "CLRADCOM_FP64"

#: The OpenCL implementations known by a short name (``--device NAME``): what each one's
#: platform or vendor string holds, lower case.
VENDOR_NAMES = {
    "pocl": ("portable computing language", "pocl"),
    "intel": ("intel(r) opencl", "intel(r) corporation", "intel"),
    "nvidia": ("nvidia",),
    "amd": ("amd accelerated parallel processing", "advanced micro devices", "amd"),
    "oclgrind": ("oclgrind",),
}

#: Oclgrind's builds (21.10, Debian's): OpenCL C's own builtins only (its interpreter runs
#: neither llvm.cttz nor the AVX mask builtin: kernels/intersect.h), and unoptimised. Its
#: optimised code is what it mishandles: its uninitialised-value check crashes on the
#: shuffles with undefined lanes that LLVM makes of float3 code, and it evaluates a
#: vector "not" of a comparison (xor <4 x i1> with true) as 1 and -2 instead of -1 and 0,
#: which turned the watertight test's hits into misses. Unoptimised, always_inline is
#: read as nothing: clang's always-inliner would leave llvm.experimental.noalias.scope.decl
#: calls, which it cannot run either. docs/devices.md has the reproducers. Its data-race
#: check counts a plain read beside other work items' atomics as a race, so the float sums
#: by compare-and-swap read their first value atomically there (kernels/maps.cl).
SIMULATOR_BUILD_OPTIONS = ("-DCLR_NO_TARGET_BUILTINS=1", "-cl-opt-disable",
                           "-Dalways_inline=", "-DCLR_ATOMIC_FIRST_READ=1")

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
    #: the short name of its implementation (:data:`VENDOR_NAMES`), else the platform's
    #: first word in lower case
    vendor: str = ""
    max_work_group_size: int = 1
    int64_atomics: bool = False
    #: float / and sqrt correctly rounded when built with
    #: -cl-fp32-correctly-rounded-divide-sqrt (the builds then ask for it)
    correctly_rounded_divide_sqrt: bool = False

    @property
    def spec(self) -> str:
        return f"{self.platform_index}:{self.device_index}"

    @property
    def simulator(self) -> bool:
        """Oclgrind: never a default, only by name."""
        return self.vendor == "oclgrind"

    @property
    def label(self) -> str:
        """``name (platform)``: how messages name the device."""
        return f"{self.device_name.strip()} ({self.platform_name.strip()})"

    def describe(self) -> str:
        fp64 = "fp64" if self.has_double else "no fp64"
        return (
            f"[{self.spec}] {self.vendor:<8} {self.device_type:<5} {self.device_name.strip()} "
            f"({self.platform_name.strip()}; {self.compute_units} CUs, "
            f"{self.global_mem_bytes / 2**30:.1f} GiB, {fp64})"
        )


def _cl():
    try:
        import pyopencl as cl
    except ImportError as exc:  # pragma: no cover - pyopencl is a hard dependency
        raise OpenCLError(f"pyopencl is not importable ({exc}). {INSTALL_HINT}") from exc
    _ask_nvidia_only_where_answered()
    return cl


_NV_QUERY_EXTENSION = "cl_nv_device_attribute_query"


def _ask_nvidia_only_where_answered() -> None:
    """Make pyopencl ask a device for NVIDIA's compute capability only where the device
    offers that query (its ``cl_nv_device_attribute_query`` extension).

    pyopencl asks every device for ``CL_DEVICE_COMPUTE_CAPABILITY_MAJOR_NV`` at each
    program build (``Program.build``: does the driver cache builds itself?) and each
    kernel object it makes (``Kernel``: an argument-size check for NVIDIA), and reads a
    refusal as "not NVIDIA". An implementation without the extension must refuse
    (CL_INVALID_VALUE), and Oclgrind's API check reports every refusal as an error. The
    answer is pyopencl's own wherever the query is answered; elsewhere it is the None
    that a refusal gives, without the refused call."""
    import pyopencl.characterize as characterize

    asks = characterize.nv_compute_capability
    if getattr(asks, "clradcom_checks_extension", False):
        return

    def nv_compute_capability(dev):
        try:
            offered = _NV_QUERY_EXTENSION in dev.extensions
        except Exception:  # noqa: BLE001 - as pyopencl's own: any failure is "not NVIDIA"
            return None
        return asks(dev) if offered else None

    nv_compute_capability.clradcom_checks_extension = True
    nv_compute_capability.__doc__ = asks.__doc__
    characterize.nv_compute_capability = nv_compute_capability


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


def vendor_name(platform_name: str, vendor: str = "") -> str:
    """The short name (:data:`VENDOR_NAMES`) of the implementation whose platform is
    ``platform_name`` (``vendor``: the platform's or device's vendor string), else the
    platform name's first word in lower case."""
    text = f"{platform_name} | {vendor}".lower()
    # the platform name decides first: PoCL's CPU device reports the CPU's vendor (Intel)
    for name, marks in VENDOR_NAMES.items():
        if any(m in platform_name.lower() for m in marks):
            return name
    for name, marks in VENDOR_NAMES.items():
        if any(m in text for m in marks):
            return name
    words = platform_name.strip().lower().split()
    return words[0] if words else "opencl"


def _query(device, name: str, default):
    """One clGetDeviceInfo query, ``default`` where the implementation does not answer it
    (OpenCL 1.2 simulators refuse some later queries)."""
    cl = _cl()
    try:
        return getattr(device, name)
    except (cl.Error, AttributeError):
        return default


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
            extensions = str(_query(device, "extensions", ""))
            infos.append(
                DeviceInfo(
                    platform_index=p_index,
                    device_index=d_index,
                    platform_name=platform.name,
                    device_name=device.name,
                    device_type=_type_name(device),
                    compute_units=int(device.max_compute_units),
                    global_mem_bytes=int(device.global_mem_size),
                    has_double="cl_khr_fp64" in extensions
                    or bool(_query(device, "double_fp_config", 0)),
                    vendor=vendor_name(platform.name, f"{_query(platform, 'vendor', '')} "
                                                      f"{_query(device, 'vendor', '')}"),
                    max_work_group_size=int(_query(device, "max_work_group_size", 1)),
                    int64_atomics="cl_khr_int64_base_atomics" in extensions,
                    correctly_rounded_divide_sqrt=bool(
                        int(_query(device, "single_fp_config", 0))
                        & int(cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT)),
                )
            )
    if not infos:
        raise OpenCLError(INSTALL_HINT)
    return infos


def _is_pocl(info: DeviceInfo) -> bool:
    return info.vendor == "pocl"


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
                if rule(info) and not info.simulator:
                    return info
        # nothing but a simulator: it is all there is
        return infos[0]
    text = spec.strip()
    low = text.lower()
    if re.fullmatch(r"\d+:\d+", text):
        p, d = (int(x) for x in text.split(":"))
        for info in infos:
            if (info.platform_index, info.device_index) == (p, d):
                return info
    elif low in ("gpu", "cpu"):
        for info in infos:
            if info.device_type == low.upper() and not info.simulator:
                return info
    elif low in VENDOR_NAMES:
        for info in infos:
            if info.vendor == low:
                return info
    else:
        for info in infos:
            if low in info.device_name.lower() or low in info.platform_name.lower():
                return info
    seen = "\n  ".join(i.describe() for i in infos)
    raise OpenCLError(
        f"{source}={spec!r} matches no OpenCL device. Devices seen:\n  {seen}\n"
        f"Use {', '.join(repr(n) for n in VENDOR_NAMES)}, 'gpu', 'cpu', 'P:D' or part of a "
        "platform or device name."
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


#: what to try after each kind of OpenCL failure, by the error code's name
_HINTS = {
    "OUT_OF_RESOURCES": "ask for less work per launch (fewer --rays, a coarser "
                        "--sbr-spacing) or pick another device (--device pocl)",
    "MEM_OBJECT_ALLOCATION_FAILURE": "ask for less (fewer --rays, a coarser --sbr-spacing) "
                                     "or pick a device with more memory",
    "OUT_OF_HOST_MEMORY": "ask for less (fewer --rays, a coarser --sbr-spacing)",
    "INVALID_WORK_GROUP_SIZE": "this is a clradcom bug (a work-group size the device "
                               "refuses); please report it, and use --device pocl meanwhile",
    "INVALID_KERNEL_NAME": "the installed kernels do not match this clradcom; reinstall it",
}
_DEFAULT_HINT = "try another device (clradcom devices lists them; --device pocl is the CPU)"


def _error_code_name(exc) -> str:
    """The OpenCL status name (``OUT_OF_RESOURCES``) of a pyopencl error, or ''."""
    code = getattr(exc, "code", None)
    if code is None and exc.args:
        code = getattr(exc.args[0], "code", None)
    try:
        from pyopencl import status_code

        for name in dir(status_code):
            if not name.startswith("_") and getattr(status_code, name) == code:
                return name
    except ImportError:  # pragma: no cover
        pass
    # an error made without its code (or by a layer above pyopencl) names it in its text
    text = str(exc)
    return next((name for name in _HINTS if name in text), "")


def describe_cl_error(exc, device: str, what: str) -> str:
    """One line for a pyopencl error ``exc`` raised while doing ``what`` (``"launch of
    kernel sbr_bounce (sbr.cl)"``) on ``device``: the status, the driver's words and what
    to try."""
    code = _error_code_name(exc)
    # str() of a pyopencl error is "routine failed: STATUS - the driver's words"; its
    # .what is a record object, whose repr is no message
    words = " ".join(str(exc).split())
    hint = _HINTS.get(code, _DEFAULT_HINT)
    status = f"{code}: " if code and code not in words else ""
    return f"OpenCL {what} failed on {device}: {status}{words}; {hint}"


def _save_build_log(name: str, device: str, options, log: str) -> str:
    """The whole compiler log in a file of its own (a temporary folder), for the one-line
    message to point at; '' where it cannot be written."""
    import tempfile

    try:
        fd, path = tempfile.mkstemp(prefix=f"clradcom-build-{name.replace('.', '_')}-",
                                    suffix=".log")
        with os.fdopen(fd, "w") as fh:
            fh.write(f"device: {device}\noptions: {' '.join(options)}\n\n{log}\n")
        return path
    except OSError:
        return ""


def _format_build_log(name: str, log: str, device: str = "", options=()) -> str:
    lines = [ln.strip() for ln in log.splitlines() if ln.strip()]
    located = [ln for ln in lines if re.search(r"[\w.]+\.(cl|h):\d+", ln)]
    errors = [ln for ln in located if "error" in ln.lower()] or located
    head = errors[0] if errors else (lines[0] if lines else "(empty log)")
    where = f" on {device}" if device else ""
    path = _save_build_log(name, device, options, log)
    saved = f" (compiler log: {path})" if path else ""
    return (f"OpenCL build of kernels/{name} failed{where} at {head}{saved}; "
            f"{_DEFAULT_HINT}")


#: build options that let a compiler reassociate floating-point arithmetic
UNSAFE_MATH_OPTIONS = ("-cl-fast-relaxed-math", "-cl-unsafe-math-optimizations")

#: how compilers that ignore #line name the program in their messages (NVIDIA:
#: "<kernel>:4:10: error", Oclgrind: "input.cl:4:10: error")
_UNNAMED_SOURCE = re.compile(r"(?:<kernel>|<source>|<stdin>|input\.cl):(\d+)")
_LINE_MARKER = re.compile(r'^#line (\d+) "([^"]+)"$')


def locate_log_lines(log: str, source: str) -> str:
    """``log`` with the lines of the expanded ``source`` that a compiler names by its own
    count (it ignored the #line markers of :func:`kernel_source`) named as ``file:line``
    of the original file, as compilers that honour #line name them."""
    if not _UNNAMED_SOURCE.search(log):
        return log
    where: list[tuple[str, int]] = []   # per line of source, 1-based: (file, line)
    name, line = "source", 0
    for text in source.splitlines():
        m = _LINE_MARKER.match(text.strip())
        where.append((name, line))
        if m:
            name, line = m.group(2), int(m.group(1)) - 1
        line += 1

    def rename(m: re.Match) -> str:
        k = int(m.group(1))
        if not 1 <= k <= len(where):
            return m.group(0)
        file, at = where[k - 1]
        return f"{file}:{at}"

    return _UNNAMED_SOURCE.sub(rename, log)


def _fp64_wanted(fp64: bool | None) -> bool:
    if fp64 is not None:
        return bool(fp64)
    value = os.environ.get(ENV_FP64, "").strip().lower()
    return value not in ("0", "off", "no", "false")


class Runtime:
    """One context and in-order queue on one device, with a program cache.

    :attr:`kernel_seconds` counts the wall time spent inside kernel launches on this
    runtime, from enqueue to finish (the ray caster's :meth:`kernel_clock` blocks):
    what a benchmark compares with a whole trace's time to see the share spent in
    kernels.

    ``fp64=False`` (or ``CLRADCOM_FP64=0`` when ``fp64`` is None) runs the device as one
    without fp64: :attr:`info`'s ``has_double`` is False and every build gets
    ``-D CLRADCOM_NO_FP64=1``; :attr:`device_has_double` keeps what the hardware has.
    """

    def __init__(self, spec: str | None = None, fp64: bool | None = None):
        import dataclasses

        cl = _cl()
        info = choose_device(spec)
        self.device_has_double = info.has_double
        self.force_no_fp64 = info.has_double and not _fp64_wanted(fp64)
        self.info = dataclasses.replace(info, has_double=False) if self.force_no_fp64 \
            else info
        platform = _platforms()[self.info.platform_index]
        self.device = platform.get_devices()[self.info.device_index]
        with self.guard("context creation"):
            self.context = cl.Context([self.device])
            self.queue = cl.CommandQueue(self.context)
        self._programs: dict[tuple[str, tuple[str, ...]], object] = {}
        self._kernels: dict[tuple, object] = {}
        self._local_sizes: dict[tuple, int] = {}
        self._lock = threading.Lock()
        self._kernel_seconds = 0.0
        #: compiler output of builds that succeeded with something to say, per kernel file
        self.build_warnings: dict[str, str] = {}
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

    @contextmanager
    def guard(self, what: str) -> Iterator[None]:
        """Turn any pyopencl error inside the block into an :class:`OpenCLError` of one
        line naming this device, ``what`` was being done and what to try."""
        cl = _cl()
        try:
            yield
        except cl.Error as exc:
            label = getattr(getattr(self, "info", None), "label", "the OpenCL device")
            raise OpenCLError(describe_cl_error(exc, label, what)) from None

    @property
    def has_double(self) -> bool:
        return self.info.has_double

    @property
    def concurrent_calls(self) -> bool:
        """Whether host threads may call this device at once (OpenCL makes every call
        but clSetKernelArg thread-safe, and clradcom never shares a kernel object between
        threads). Not Oclgrind: two threads' calls at once abort it (21.10; a radio map's
        PO stage, its next launch prefetched while the host weighed the last)."""
        return not self.info.simulator

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
            program = self.program(name, options)
            with self.guard(f"creation of kernel {kernel_name} ({name})"):
                k = _cl().Kernel(program, kernel_name)
            with self._lock:
                self._kernels.setdefault(key, k)
        return k

    def local_size(self, kernel, preferred: int = 64) -> int:
        """The work-group size for ``kernel`` on this device: ``preferred`` rounded to the
        kernel's preferred multiple (a warp, a SIMD width) and kept within the kernel's and
        the device's maximum (which private memory and registers lower on a GPU). Where
        even one multiple is over the maximum, the largest power of two under it."""
        key = (id(kernel), int(preferred))
        size = self._local_sizes.get(key)
        if size is not None:
            return size
        cl = _cl()
        wg = cl.kernel_work_group_info
        with self.guard("work-group size query"):
            limit = int(kernel.get_work_group_info(wg.WORK_GROUP_SIZE, self.device))
            try:
                multiple = int(kernel.get_work_group_info(
                    wg.PREFERRED_WORK_GROUP_SIZE_MULTIPLE, self.device))
            except cl.Error:   # an OpenCL 1.0 query some simulators refuse
                multiple = 1
        limit = max(1, min(limit, self.info.max_work_group_size))
        multiple = max(1, multiple)
        size = max(multiple, -(-int(preferred) // multiple) * multiple)
        if size > limit:
            size = (limit // multiple) * multiple if limit >= multiple else 0
            if size < 1:
                size = 1 << (limit.bit_length() - 1)
        self._local_sizes[key] = size
        return size

    def require_local_size(self, kernel, size: int, name: str) -> int:
        """``size``, where a kernel's algorithm needs exactly that many work items per group
        (a reduction over one launch block); one clear error where the device cannot."""
        cl = _cl()
        with self.guard(f"work-group size query of kernel {name}"):
            limit = int(kernel.get_work_group_info(
                cl.kernel_work_group_info.WORK_GROUP_SIZE, self.device))
        limit = min(limit, self.info.max_work_group_size)
        if size > limit:
            raise OpenCLError(
                f"kernel {name} needs work-groups of {size} items and {self.info.label} "
                f"allows {limit} for it; {_DEFAULT_HINT}")
        return int(size)

    def launch(self, kernel, global_size: int, local_size: int | None, *args,
               name: str | None = None, wait: bool = False):
        """Enqueue ``kernel`` over ``global_size`` work items rounded up to whole groups of
        ``local_size`` (the kernels ignore the items past their own count; None: the
        implementation's choice), any failure one :class:`OpenCLError`; ``wait`` finishes
        the queue."""
        label = name or getattr(kernel, "function_name", "kernel")
        gs = int(global_size)
        if local_size:
            gs = -(-gs // int(local_size)) * int(local_size)
            local = (int(local_size),)
        else:
            local = None
        with self.guard(f"launch of kernel {label}"):
            event = kernel(self.queue, (gs,), local, *args)
            if wait:
                self.queue.finish()
        return event

    def build(self, source: str, name: str, options: tuple[str, ...] = (),
              defines: Mapping[str, int] | None = None):
        """Compile ``source``; a failure raises OpenCLError naming the device, file, line
        and the file the whole compiler log went to. On PoCL (:attr:`inline_builtins`) the
        build also gets -D CLR_INLINE_BUILTINS=1; in the forced no-fp64 mode
        -D CLRADCOM_NO_FP64=1, and without fp64 (forced or not)
        -cl-single-precision-constant. Compiler output of a build that succeeds is kept
        in :attr:`build_warnings`, not shown."""
        import warnings

        cl = _cl()
        options = tuple(options) + define_options(defines)
        if self.inline_builtins:
            options += ("-DCLR_INLINE_BUILTINS=1",)
        if self.force_no_fp64 and "-DCLRADCOM_NO_FP64=1" not in options:
            options += ("-DCLRADCOM_NO_FP64=1",)
        if not self.info.has_double and "-cl-single-precision-constant" not in options:
            # a literal such as 0.5 is a float, as a device without fp64 makes it
            # (kernels/fp64.h)
            options += ("-cl-single-precision-constant",)
        if self.info.simulator:
            options += SIMULATOR_BUILD_OPTIONS
        if self.info.correctly_rounded_divide_sqrt:
            # IEEE float / and sqrt (NVIDIA's default is 2.5 and 3 ulp): the kernels then
            # divide alike on every device, and precise.h's double-float keeps its bounds
            options += ("-cl-fp32-correctly-rounded-divide-sqrt",)
        unsafe = [o for o in options if o in UNSAFE_MATH_OPTIONS]
        if unsafe and ("-DCLRADCOM_NO_FP64=1" in options or not self.info.has_double):
            # not every compiler defines __FAST_RELAXED_MATH__ for precise.h to refuse
            raise OpenCLError(
                f"OpenCL build of kernels/{name} refused: the double-float arithmetic of "
                f"the no-fp64 mode needs IEEE rounding, and {' '.join(unsafe)} "
                "(fast-relaxed-math or unsafe math) lets the compiler reassociate it away")
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", cl.CompilerWarning)
                program = cl.Program(self.context, source).build(options=list(options))
            for w in caught:
                if issubclass(w.category, cl.CompilerWarning):
                    self.build_warnings[name] = str(w.message)
                else:
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            return program
        except cl.RuntimeError as exc:
            log = getattr(exc, "build_log", None)
            text = str(exc) if not log else "\n".join(str(x[1]) for x in log)
            text = locate_log_lines(text, source)
            raise OpenCLError(_format_build_log(name, text, self.info.label, options)) \
                from None
        except cl.Error as exc:
            raise OpenCLError(describe_cl_error(exc, self.info.label,
                                                f"build of kernels/{name}")) from None

    def to_device(self, array: np.ndarray):
        """Read-only device buffer holding a contiguous copy of ``array``."""
        cl = _cl()
        array = np.ascontiguousarray(array)
        flags = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
        if array.nbytes == 0:  # zero-sized buffers are invalid in OpenCL
            array = np.zeros(1, dtype=array.dtype)
        with self.guard(f"allocation of {array.nbytes} bytes"):
            return cl.Buffer(self.context, flags, hostbuf=array)

    def empty(self, nbytes: int):
        """A read-write device buffer of ``nbytes`` (at least 1) for kernels to fill.

        On Oclgrind it is written from the host first, all 0xFF bytes (NaN in every float
        and double, -1 in every integer). Its uninitialised-value check (21.10) keeps a
        released buffer's record of which bytes were written for the next buffer that
        gets the same id, with the old buffer's size: a kernel's writes past that size are
        lost to it, and their reads reported as uninitialised. A whole-buffer host write
        gives the buffer a record of its own size; a kernel that reads what it never
        wrote then reads NaN or -1, which the tests' comparison with the host shows."""
        cl = _cl()
        size = max(int(nbytes), 1)
        mf = cl.mem_flags
        with self.guard(f"allocation of {size} bytes"):
            if self.info.simulator:
                return cl.Buffer(self.context, mf.READ_WRITE | mf.COPY_HOST_PTR,
                                 hostbuf=np.full(size, 0xFF, dtype=np.uint8))
            return cl.Buffer(self.context, mf.READ_WRITE, size=size)


    def fill(self, buffer, value, nbytes: int, offset: int = 0):
        """Set ``nbytes`` of ``buffer`` from ``offset`` to copies of the numpy scalar
        ``value`` (clEnqueueFillBuffer), enqueued, not waited for. On Oclgrind by a host
        copy instead: its uninitialised-value check (21.10) does not count what a fill
        writes as written, and would report every later read of it."""
        cl = _cl()
        value = np.asarray(value)
        with self.guard(f"fill of {int(nbytes)} bytes"):
            if self.info.simulator:
                host = np.full(int(nbytes) // value.itemsize, value, dtype=value.dtype)
                return cl.enqueue_copy(self.queue, buffer, host, dst_offset=int(offset),
                                       is_blocking=True)
            return cl.enqueue_fill_buffer(self.queue, buffer, value, int(offset),
                                          int(nbytes))


_default_runtimes: dict[tuple, Runtime] = {}
_default_lock = threading.Lock()


def get_runtime(spec: str | None = None, fp64: bool | None = None) -> Runtime:
    """Shared runtime for a spec (None: environment variable, then default order) and fp64
    mode (None: ``CLRADCOM_FP64``, else fp64 where the device has it)."""
    # the environment variable is part of the key but not passed on as the spec, so that
    # an error blames the variable that was set, not a --device flag never given
    key = (spec, None if spec is not None else os.environ.get(ENV_DEVICE) or None,
           _fp64_wanted(fp64))
    with _default_lock:
        rt = _default_runtimes.get(key)
        if rt is None:
            rt = Runtime(spec, fp64=fp64)
            _default_runtimes[key] = rt
        global _last_label
        _last_label = rt.info.label
        return rt


_last_label = "the OpenCL device"


def last_device_label() -> str:
    """The device of the runtime :func:`get_runtime` returned last (for a message about a
    failure that reached the top of a command without naming its device)."""
    return _last_label
