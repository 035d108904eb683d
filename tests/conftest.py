import pytest

from clradcom.device.runtime import OpenCLError, get_runtime, list_devices


@pytest.fixture(scope="session")
def runtime():
    """The default OpenCL runtime (PoCL's CPU device in CI)."""
    return get_runtime()


def no_fp64_devices() -> list[str]:
    """The implementations the no-fp64 mode is forced on: PoCL, and Intel's CPU runtime
    where list_devices() shows it (CI installs it)."""
    names = ["pocl"]
    try:
        if any(d.vendor == "intel" for d in list_devices()):
            names.append("intel")
    except OpenCLError:
        pass
    return names


@pytest.fixture(scope="session", params=no_fp64_devices())
def no_fp64(request):
    """A runtime in the forced no-fp64 mode (Runtime(name, fp64=False): -D
    CLRADCOM_NO_FP64=1, precise.h's double-float), on PoCL and on Intel's runtime."""
    return get_runtime(request.param, fp64=False)
