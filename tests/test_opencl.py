import numpy as np
import pyopencl as cl
import pytest

from clradcom.cli import main as cli_main
from clradcom.device import runtime as opencl
from clradcom.device.raycast import (
    HIT_DTYPE,
    KERNEL_DEFINES,
    PACKET_MAX,
    RAY_DTYPE,
    SPAWN_OFFSET_ROUNDOFFS,
)
from clradcom.device.runtime import (
    OpenCLError,
    Runtime,
    choose_device,
    define_options,
    kernel_source,
    list_devices,
)
from clradcom.geometry import layout
from clradcom.geometry.bvh import BVH_NODE_DTYPE
from clradcom.geometry.layout import BVH8_NODE_DTYPE


def test_device_list_and_default_is_gpu_or_pocl(monkeypatch):
    """The default order (no --device, no CLRADCOM_DEVICE: the suite's --device sets it):
    the first GPU, else PoCL's CPU device; never Oclgrind, a simulator that calls itself a
    GPU."""
    monkeypatch.delenv(opencl.ENV_DEVICE, raising=False)
    infos = list_devices()
    assert infos
    chosen = choose_device()
    assert not chosen.simulator
    gpus = [i for i in infos if i.device_type == "GPU" and not i.simulator]
    if gpus:
        assert chosen == gpus[0]
    else:
        assert chosen.device_type == "CPU"
        assert chosen.vendor == "pocl"
        assert "portable computing language" in chosen.platform_name.lower()


def test_device_spec_by_index_name_and_env(monkeypatch):
    first = list_devices()[0]
    assert choose_device(first.spec) == first
    assert choose_device(first.device_name[:6]) == first
    monkeypatch.setenv(opencl.ENV_DEVICE, first.spec)
    assert choose_device() == first


def test_unknown_device_spec_names_source_and_value(monkeypatch):
    with pytest.raises(OpenCLError, match=r"--device='no-such-device-xyz'.*Devices seen"):
        choose_device("no-such-device-xyz")
    monkeypatch.setenv(opencl.ENV_DEVICE, "9:9")
    with pytest.raises(OpenCLError, match=r"CLRADCOM_DEVICE='9:9'"):
        choose_device()


def test_no_platform_is_one_clear_error(monkeypatch):
    def no_platforms():
        raise cl.LogicError("clGetPlatformIDs failed: PLATFORM_NOT_FOUND_KHR")

    monkeypatch.setattr(cl, "get_platforms", no_platforms)
    with pytest.raises(OpenCLError, match=r"pip install 'clradcom\[pocl\]'"):
        list_devices()
    monkeypatch.setattr(cl, "get_platforms", lambda: [])
    with pytest.raises(OpenCLError, match="pocl-binary-distribution"):
        choose_device()


def test_cli_lists_devices(capsys):
    assert cli_main(["devices"]) == 0
    out = capsys.readouterr().out
    assert choose_device().device_name.strip() in out
    assert cli_main(["devices", "--device", "nothing-like-this"]) == 2


def test_kernel_sources_come_from_the_package_with_line_markers():
    src = kernel_source("raycast.cl")
    assert '#line 1 "raycast.cl"' in src
    assert '#line 1 "types.h"' in src  # expanded through intersect.h
    assert "typedef struct" in src
    with pytest.raises(OpenCLError, match="kernels/missing.cl not found"):
        kernel_source("missing.cl")


def test_build_error_names_file_line_and_log(runtime):
    broken = (
        '#line 1 "broken.cl"\n__kernel void k(__global int *a)\n{\n'
        "  a[0] = undefined_thing;\n}\n"
    )
    with pytest.raises(OpenCLError) as info:
        runtime.build(broken, "broken.cl")
    text = str(info.value)
    assert "broken.cl:3" in text  # #line 1 numbers the line after it
    assert "undefined_thing" in text


def test_a_failed_kernel_creation_is_one_line_naming_status_kernel_and_device(runtime):
    with pytest.raises(OpenCLError) as info:
        runtime.kernel("raycast.cl", "no_such_kernel", defines=KERNEL_DEFINES)
    text = str(info.value)
    assert "\n" not in text and "object at 0x" not in text
    assert "INVALID_KERNEL_NAME" in text and "no_such_kernel" in text
    assert runtime.info.label in text


def test_programs_are_cached_per_runtime(runtime):
    prog = runtime.program("raycast.cl", defines=KERNEL_DEFINES)
    assert runtime.program("raycast.cl", defines=dict(reversed(KERNEL_DEFINES.items()))) is prog
    other = Runtime(runtime.info.spec)
    assert other.program("raycast.cl", defines=KERNEL_DEFINES) is not prog


def test_empty_buffers_and_oclgrinds_host_written_ones(runtime):
    """Runtime.empty gives at least the bytes asked (one for none); on Oclgrind every one
    of them is 0xFF, written from the host so that its uninitialised-value check keeps a
    record of the buffer's own size (docs/devices.md)."""
    buf = runtime.empty(10)
    assert buf.size >= 10 and runtime.empty(0).size >= 1
    if runtime.info.simulator:
        out = np.zeros(10, dtype=np.uint8)
        cl.enqueue_copy(runtime.queue, out, buf)
        assert np.all(out == 0xFF)


def test_define_options_are_integer_macros():
    assert define_options({"B": 2, "A": np.int32(1)}) == ("-DA=1", "-DB=2")
    assert define_options(None) == ()
    with pytest.raises(ValueError, match="not a C macro name"):
        define_options({"A B": 1})
    with pytest.raises(ValueError, match="must be an integer"):
        define_options({"A": 1.5})


@pytest.mark.parametrize("missing", list(KERNEL_DEFINES))
def test_a_build_without_a_host_number_fails_naming_it(runtime, missing):
    defines = {k: v for k, v in KERNEL_DEFINES.items() if k != missing}
    with pytest.raises(OpenCLError, match=f"{missing} must be passed as -D by the host"):
        runtime.build(kernel_source("reflect.cl"), "reflect.cl", defines=defines)


def test_kernels_see_the_hosts_numbers(runtime):
    prog = runtime.program("layout.cl", defines=KERNEL_DEFINES)
    out = np.zeros(len(KERNEL_DEFINES), dtype=np.int32)
    buf = runtime.empty(out.nbytes)
    prog.build_constants(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, out, buf)
    expected = {"BVH_WIDTH": layout.BVH_WIDTH, "BVH_STACK_SIZE": layout.BVH_STACK_SIZE,
                "TRI4_ROWS": layout.TRI4_ROWS, "LEAF_GROUP_BITS": layout.LEAF_GROUP_BITS,
                "SPAWN_OFFSET_ROUNDOFFS": SPAWN_OFFSET_ROUNDOFFS, "PACKET_MAX": PACKET_MAX}
    assert KERNEL_DEFINES == expected
    assert dict(zip(KERNEL_DEFINES, out.tolist(), strict=True)) == expected


def test_host_dtypes_match_kernel_structs(runtime):
    prog = runtime.program("layout.cl", defines=KERNEL_DEFINES)
    out = np.zeros(17, dtype=np.int32)
    buf = runtime.empty(out.nbytes)
    prog.struct_layout(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, out, buf)
    expected = [
        BVH_NODE_DTYPE.itemsize, BVH_NODE_DTYPE.fields["left_first"][1],
        BVH_NODE_DTYPE.fields["bmax"][1], BVH_NODE_DTYPE.fields["count"][1],
        RAY_DTYPE.itemsize, RAY_DTYPE.fields["tmin"][1],
        RAY_DTYPE.fields["dir"][1], RAY_DTYPE.fields["tmax"][1],
        HIT_DTYPE.itemsize, HIT_DTYPE.fields["prim"][1],
        HIT_DTYPE.fields["ng"][1], HIT_DTYPE.fields["pad"][1],
        BVH8_NODE_DTYPE.itemsize, BVH8_NODE_DTYPE.fields["miny"][1],
        BVH8_NODE_DTYPE.fields["maxx"][1], BVH8_NODE_DTYPE.fields["child"][1],
        BVH8_NODE_DTYPE.fields["pad"][1],
    ]
    assert out.tolist() == expected


class _Device:
    """A device for pyopencl's NVIDIA check: which queries it was asked."""

    def __init__(self, extensions: str):
        self.asked: list[str] = []
        self._extensions = extensions

    @property
    def extensions(self):
        self.asked.append("extensions")
        return self._extensions

    @property
    def compute_capability_major_nv(self):
        self.asked.append("major_nv")
        if "cl_nv_device_attribute_query" not in self._extensions:
            raise cl.LogicError("clGetDeviceInfo failed: INVALID_VALUE")
        return 9

    @property
    def compute_capability_minor_nv(self):
        self.asked.append("minor_nv")
        return 0


def test_pyopencl_asks_for_nvidias_compute_capability_only_where_answered():
    """pyopencl asks every device at every build and kernel for NVIDIA's compute
    capability; where the device lacks the query's extension that is a refused call,
    which Oclgrind's API check reports. After the runtime is loaded the answer is the
    same (None: not NVIDIA) without the call; an NVIDIA device is still asked."""
    from pyopencl.characterize import has_src_build_cache

    opencl.list_devices()   # pyopencl through the runtime
    import pyopencl.characterize as characterize

    other = _Device("cl_khr_fp64 cl_khr_int64_base_atomics")
    assert characterize.nv_compute_capability(other) is None
    assert other.asked == ["extensions"]
    nvidia = _Device("cl_khr_fp64 cl_nv_device_attribute_query")
    assert characterize.nv_compute_capability(nvidia) == (9, 0)
    assert "major_nv" in nvidia.asked
    assert has_src_build_cache.__globals__["nv_compute_capability"] is \
        characterize.nv_compute_capability
