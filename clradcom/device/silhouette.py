"""The silhouette block raster of SBR launch windows on the device (kernels/silhouette.cl).

:func:`block_coverage` is :func:`clradcom.geometry.silhouette.block_coverage` with its
(triangle, block) pair tests in a kernel, one work item per triangle: the host's
:func:`~clradcom.geometry.silhouette.coverage_setup` gives the edge normals, offsets and
reaches, the kernel evaluates the same expressions in double without contraction, so the
mask is the host's bit for bit (tests/test_sbr_launch.py). Grids with few pairs stay on
the host, where a launch would cost more than the test; devices without fp64 too.
"""

from __future__ import annotations

import numpy as np

from clradcom.device.runtime import Runtime
from clradcom.geometry import silhouette as host

__all__ = ["DEVICE_MIN_PAIRS", "block_coverage"]

SOURCE = "silhouette.cl"
#: below this many (triangle, block) pairs the host's numpy test is the faster
DEVICE_MIN_PAIRS = 4096


def block_coverage(runtime: Runtime, tri_xy, block_size: float, origin, shape,
                   min_pairs: int = DEVICE_MIN_PAIRS) -> np.ndarray:
    """(shape) bool: :func:`clradcom.geometry.silhouette.block_coverage` of the same
    arguments, its pair tests on ``runtime``'s device when they number ``min_pairs`` or
    more and the device has fp64."""
    import pyopencl as cl

    nx, ny = (int(n) for n in shape)
    setup = host.coverage_setup(tri_xy, block_size, shape, origin)
    if setup is None:
        return np.zeros((nx, ny), dtype=bool)
    if not runtime.has_double or int(setup["n_pairs"].sum()) < min_pairs:
        return host.cover_blocks(setup, block_size, origin, shape)
    n = len(setup["nrm"])
    mask = np.zeros((nx, ny), dtype=np.uint8)
    kernel = runtime.kernel(SOURCE, "block_cover")
    mf = cl.mem_flags
    args = [cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                      hostbuf=np.ascontiguousarray(setup[k], dtype=dt))
            for k, dt in (("nrm", np.float64), ("off", np.float64), ("radius", np.float64),
                          ("lo", np.int64), ("cnt", np.int64))]
    out = cl.Buffer(runtime.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=mask)
    ox, oy = (float(o) for o in origin)
    local = 16
    with runtime.kernel_clock():
        kernel(runtime.queue, (-(-n // local) * local,), (local,), *args, np.float64(ox),
               np.float64(oy), np.float64(block_size), np.int64(ny), np.int32(n), out)
        cl.enqueue_copy(runtime.queue, mask, out, is_blocking=True)
    return mask.astype(bool)
