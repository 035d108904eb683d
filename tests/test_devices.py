"""Any OpenCL device: the names people type, never a simulator by default, the forced
no-fp64 mode, work-group sizes the device allows, one-line errors for every OpenCL
failure, and where each stage of a trace ran."""

import dataclasses
import warnings

import numpy as np
import pyopencl as cl
import pytest

from clradcom.commands.options import run_tool
from clradcom.device import engines
from clradcom.device import runtime as opencl
from clradcom.device.raycast import RayCaster, make_rays
from clradcom.device.runtime import (
    DeviceInfo,
    OpenCLError,
    Runtime,
    choose_device,
    describe_cl_error,
    vendor_name,
)
from clradcom.errors import DeviceFallbackWarning


def info(p, d, platform, name, kind, vendor):
    return DeviceInfo(platform_index=p, device_index=d, platform_name=platform,
                      device_name=name, device_type=kind, compute_units=1,
                      global_mem_bytes=1 << 30, has_double=True, vendor=vendor,
                      max_work_group_size=256)


#: the platforms of a machine with every implementation the project knows
MACHINE = [
    info(0, 0, "Oclgrind", "Oclgrind Simulator", "GPU", "oclgrind"),
    info(1, 0, "Intel(R) OpenCL", "Intel(R) Xeon(R)", "CPU", "intel"),
    info(2, 0, "Portable Computing Language", "pthread-Intel(R) Xeon(R)", "CPU", "pocl"),
    info(3, 0, "NVIDIA CUDA", "NVIDIA H200", "GPU", "nvidia"),
    info(4, 0, "AMD Accelerated Parallel Processing", "gfx90a", "GPU", "amd"),
]


@pytest.mark.parametrize("platform, vendor, expected", [
    ("Portable Computing Language", "Intel(R) Corporation", "pocl"),   # PoCL on an Intel CPU
    ("Intel(R) OpenCL", "Intel(R) Corporation", "intel"),
    ("Intel(R) OpenCL Graphics", "Intel(R) Corporation", "intel"),
    ("NVIDIA CUDA", "NVIDIA Corporation", "nvidia"),
    ("AMD Accelerated Parallel Processing", "Advanced Micro Devices, Inc.", "amd"),
    ("Oclgrind", "University of Bristol", "oclgrind"),
    ("rusticl", "Mesa/X.org", "rusticl"),
])
def test_implementations_get_the_names_people_type(platform, vendor, expected):
    assert vendor_name(platform, vendor) == expected


def test_names_select_their_implementation_and_the_default_is_never_the_simulator(
        monkeypatch):
    monkeypatch.setattr(opencl, "list_devices", lambda: list(MACHINE))
    monkeypatch.delenv(opencl.ENV_DEVICE, raising=False)
    for name in opencl.VENDOR_NAMES:
        assert choose_device(name).vendor == name
    assert choose_device().vendor == "nvidia"          # the first real GPU
    assert choose_device("gpu").vendor == "nvidia"     # Oclgrind calls itself a GPU
    assert choose_device("0:0").vendor == "oclgrind"   # but can be asked for
    cpus = [i for i in MACHINE if i.device_type == "CPU" or i.simulator]
    monkeypatch.setattr(opencl, "list_devices", lambda: cpus)
    assert choose_device().vendor == "pocl"
    monkeypatch.setattr(opencl, "list_devices", lambda: [MACHINE[0]])
    assert choose_device().vendor == "oclgrind"        # all there is
    with pytest.raises(OpenCLError, match="'pocl', 'intel', 'nvidia', 'amd', 'oclgrind'"):
        choose_device("pocl")


def test_the_suite_device_is_found_by_its_name(runtime):
    assert choose_device(runtime.info.vendor).vendor == runtime.info.vendor
    assert runtime.info.max_work_group_size >= 1


# ---------------------------------------------------------------------------
# the forced no-fp64 mode

MODE_PROBE = """
#include "fastmath.h"
__kernel void fp64_mode(__global int *out)
{
#ifdef CLRADCOM_FP64
    out[0] = 1;
#else
    out[0] = 0;
#endif
}
"""


def fp64_mode(rt) -> int:
    src = opencl.kernel_source("fastmath.h").replace("#line 1 \"fastmath.h\"", "")
    prog = rt.build(MODE_PROBE.replace('#include "fastmath.h"', src), "fp64_probe.cl")
    buf = rt.empty(4)
    out = np.zeros(1, np.int32)
    prog.fp64_mode(rt.queue, (1,), None, buf)
    cl.enqueue_copy(rt.queue, out, buf)
    return int(out[0])


def test_a_runtime_can_be_run_as_a_device_without_fp64(runtime, monkeypatch):
    forced = Runtime(runtime.info.spec, fp64=False)
    assert not forced.info.has_double and not forced.has_double
    assert forced.device_has_double == runtime.info.has_double
    assert fp64_mode(forced) == 0
    assert fp64_mode(runtime) == int(runtime.info.has_double)
    monkeypatch.setenv(opencl.ENV_FP64, "0")
    assert not Runtime(runtime.info.spec).info.has_double
    assert opencl.get_runtime(runtime.info.spec) is not opencl.get_runtime(
        runtime.info.spec, fp64=True)


# ---------------------------------------------------------------------------
# work-group sizes


def test_work_group_sizes_come_from_the_kernel_and_the_device(runtime):
    caster = RayCaster(np.array([[[0.0, -1, -1], [0, 2, -1], [0, -1, 2]]]), runtime=runtime)
    kernel = runtime.kernel("raycast.cl", "closest_hit", defines=caster.kernel_defines())
    wg = cl.kernel_work_group_info
    limit = kernel.get_work_group_info(wg.WORK_GROUP_SIZE, runtime.device)
    multiple = kernel.get_work_group_info(wg.PREFERRED_WORK_GROUP_SIZE_MULTIPLE,
                                          runtime.device)
    for preferred in (1, 16, 64, 100, 10**6):
        size = runtime.local_size(kernel, preferred)
        assert 1 <= size <= min(limit, runtime.info.max_work_group_size)
        assert size % multiple == 0 or size < multiple
        assert size >= min(preferred, multiple, limit)
    assert runtime.require_local_size(kernel, 1, "closest_hit") == 1
    with pytest.raises(OpenCLError, match="closest_hit needs work-groups of"):
        runtime.require_local_size(kernel, limit + 1, "closest_hit")


def test_a_device_that_allows_small_groups_gets_small_groups(runtime):
    """A device whose limit is below the preferred size (a GPU with heavy kernels) is
    given its limit, rounded down to its multiple."""
    small = Runtime(runtime.info.spec)
    small.info = dataclasses.replace(small.info, max_work_group_size=24)
    caster = RayCaster(np.array([[[0.0, -1, -1], [0, 2, -1], [0, -1, 2]]]), runtime=small)
    kernel = small.kernel("raycast.cl", "closest_hit", defines=caster.kernel_defines())
    size = small.local_size(kernel, 64)
    assert 1 <= size <= 24
    hits = caster.closest_hit(make_rays([[5.0, 0.1, 0.1]] * 100, [[-1.0, 0, 0]] * 100))
    assert (hits["prim"] == 0).all() and np.allclose(hits["t"], 5.0)


# ---------------------------------------------------------------------------
# one line for every OpenCL failure


def test_a_failed_build_is_one_line_naming_device_line_and_the_log_file(runtime):
    broken = '#line 1 "broken.cl"\n__kernel void k(__global int *a)\n{\n  a[0] = nothing;\n}\n'
    with pytest.raises(OpenCLError) as exc:
        runtime.build(broken, "broken.cl")
    text = str(exc.value)
    assert "\n" not in text
    assert runtime.info.label in text and "broken.cl:3" in text
    log = text.split("compiler log: ")[1].split(")")[0]
    with open(log) as fh:
        assert "nothing" in fh.read()
    assert "--device pocl" in text


def test_a_failed_launch_is_one_line_naming_the_kernel(runtime):
    caster = RayCaster(np.array([[[0.0, -1, -1], [0, 2, -1], [0, -1, 2]]]), runtime=runtime)
    kernel = runtime.kernel("raycast.cl", "closest_hit", defines=caster.kernel_defines())
    limit = kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE,
                                       runtime.device)
    # a work-group over the device's limit: the driver refuses the launch
    with pytest.raises(OpenCLError) as exc:
        runtime.launch(kernel, 4 * limit, 2 * limit, *caster.bvh_buffers(), None, None, None,
                       np.int32(0), name="closest_hit")
    text = str(exc.value)
    assert "\n" not in text
    assert "launch of kernel closest_hit" in text and runtime.info.label in text
    assert "INVALID_WORK_GROUP_SIZE" in text or "try another device" in text


def test_an_unnamed_opencl_error_reaching_a_command_is_one_line(capsys):
    def body():
        raise cl.MemoryError("clEnqueueNDRangeKernel failed: OUT_OF_RESOURCES")

    assert run_tool("tool", body) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("tool: OpenCL call failed on ")
    assert "fewer --rays" in err


def test_status_names_and_hints():
    exc = cl.MemoryError("clCreateBuffer failed: MEM_OBJECT_ALLOCATION_FAILURE")
    text = describe_cl_error(exc, "GPU X (P)", "allocation of 8 bytes")
    assert text.startswith("OpenCL allocation of 8 bytes failed on GPU X (P): ")
    assert "device with more memory" in text


# ---------------------------------------------------------------------------
# where each stage ran


def test_a_stage_that_leaves_the_device_says_so_once_and_the_log_records_it():
    with engines.engine_log() as log, warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("default")
        for _ in range(3):
            engines.record("specular.image_points", "host", "no fp64")
        engines.record("visibility.segments", "device")
        engines.record("visibility.segments", "host", "batch of 3 segments")
        engines.record("scattering.tiles", "host", "the host engine", fallback=False)
    fallbacks = [w for w in seen if issubclass(w.category, DeviceFallbackWarning)]
    assert len(fallbacks) == 2   # one per stage and reason; the host engine's own: none
    assert "specular.image_points" in str(fallbacks[0].message)
    assert "no fp64" in str(fallbacks[0].message)
    meta = log.metadata()
    assert meta["engine.specular.image_points"] == "host: no fp64"
    assert meta["engine.visibility.segments"] == "device+host: batch of 3 segments"
    assert meta["engine.scattering.tiles"] == "host: the host engine"
    with pytest.raises(ValueError, match="must be one of"):
        engines.record("no.such.stage", "device")


def test_a_compiler_that_ignores_line_markers_is_mapped_back_to_our_files():
    """NVIDIA names the program's lines by its own count ("<kernel>:N"), Oclgrind
    "input.cl:N": the message must still name the kernel file and line a reader opens."""
    source = opencl.kernel_source("reflect.cl")
    lines = source.splitlines()
    raw = next(k for k, text in enumerate(lines, start=1)
               if "BVH_STACK_SIZE must be passed" in text)
    own = next(k for k, text in enumerate(
        opencl.importlib.resources.files("clradcom.kernels").joinpath(
            "intersect.h").read_text().splitlines(), start=1)
        if "BVH_STACK_SIZE must be passed" in text)
    for style in ("<kernel>", "input.cl"):
        log = f"{style}:{raw}:2: error: \"BVH_STACK_SIZE must be passed as -D by the host\""
        assert opencl.locate_log_lines(log, source).startswith(f"intersect.h:{own}:2: error")
    assert opencl.locate_log_lines("broken.cl:3:1: error", source) == "broken.cl:3:1: error"
