import pytest

from clradcom.device.runtime import get_runtime


@pytest.fixture(scope="session")
def runtime():
    """The default OpenCL runtime (PoCL's CPU device in CI)."""
    return get_runtime()
