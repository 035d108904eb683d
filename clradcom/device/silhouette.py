"""SBR launch windows on the device (kernels/silhouette.cl).

:func:`cover_blocks_many` is :func:`clradcom.geometry.silhouette.cover_blocks_many` (the
block raster of every window of a transmitter at once) with its (triangle, block) pair
tests in a kernel, one work item per triangle; :func:`beside_cull` is
:func:`clradcom.mechanisms.sbr.beside_pairs` (the mirror windows' clip triangles culled by
the pyramid through their covered blocks' rectangle), one work item per (window,
triangle) pair. The host's :func:`~clradcom.geometry.silhouette.coverage_setup_many`
gives the edge normals, offsets and reaches; the kernels evaluate the same expressions in
double without contraction, so masks and culls are the host's bit for bit
(tests/test_sbr_launch.py). Devices without fp64 use the host's functions.
"""

from __future__ import annotations

import numpy as np

from clradcom.device.runtime import Runtime
from clradcom.geometry import silhouette as host

__all__ = ["DEVICE_MIN_PAIRS", "beside_cull", "block_coverage", "cover_blocks_many",
           "cover_xy_many", "project_windows"]

SOURCE = "silhouette.cl"
#: below this many (triangle, block) pairs the host's numpy test is the faster
DEVICE_MIN_PAIRS = 4096
LOCAL = 16


def _in(runtime, a, dtype):
    import pyopencl as cl

    mf = cl.mem_flags
    return cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                     hostbuf=np.ascontiguousarray(a, dtype=dtype))


def cover_blocks_many(runtime: Runtime, setup: dict | None, block_size, origin, ny, offset,
                      size: int, min_pairs: int = DEVICE_MIN_PAIRS) -> np.ndarray:
    """(size,) bool: :func:`clradcom.geometry.silhouette.cover_blocks_many` of the same
    arguments, its pair tests on ``runtime``'s device in one launch when they number
    ``min_pairs`` or more and the device has fp64."""

    if setup is None:
        return np.zeros(int(size), dtype=bool)
    if not runtime.has_double or int(setup["n_pairs"].sum()) < min_pairs:
        return host.cover_blocks_many(setup, block_size, origin, ny, offset, size)
    n = len(setup["nrm"])
    mask = np.zeros(int(size), dtype=np.uint8)
    args = [_in(runtime, setup[k], dt) for k, dt in (
        ("nrm", np.float64), ("off", np.float64), ("radius", np.float64),
        ("lo", np.int64), ("cnt", np.int64), ("window", np.int64))]
    args += [_in(runtime, origin, np.float64), _in(runtime, block_size, np.float64),
             _in(runtime, ny, np.int64), _in(runtime, offset, np.int64)]
    return _raster(runtime, "block_cover", args, n, mask)


def _raster(runtime: Runtime, kernel_name: str, args, n: int, mask: np.ndarray) -> np.ndarray:
    """Launch a raster kernel of silhouette.cl over n work items, its arguments ``args``
    then the count and the uint8 ``mask`` it marks (uploaded with its contents), and
    return the mask as bool."""
    import pyopencl as cl

    kernel = runtime.kernel(SOURCE, kernel_name)
    out = cl.Buffer(runtime.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                    hostbuf=mask)
    with runtime.kernel_clock():
        kernel(runtime.queue, (-(-n // LOCAL) * LOCAL,), (LOCAL,), *args, np.int32(n), out)
        cl.enqueue_copy(runtime.queue, mask, out, is_blocking=True)
    return mask.view(bool)


def block_coverage(runtime: Runtime, tri_xy, block_size: float, origin, shape,
                   min_pairs: int = DEVICE_MIN_PAIRS) -> np.ndarray:
    """(shape) bool: :func:`clradcom.geometry.silhouette.block_coverage` of the same
    arguments, its pair tests on ``runtime``'s device when they number ``min_pairs`` or
    more and the device has fp64."""
    nx, ny = (int(n) for n in shape)
    setup = host.coverage_setup(tri_xy, block_size, shape, origin)
    return cover_blocks_many(runtime, setup, np.array([float(block_size)]),
                             np.array([[float(o) for o in origin]]),
                             np.array([ny], np.int64), np.zeros(1, np.int64), nx * ny,
                             min_pairs).reshape(nx, ny)


def beside_cull(runtime: Runtime, triangles, tri_index, tri_start, pair_start, frame, rect,
                eye) -> np.ndarray:
    """(pairs,) bool: :func:`clradcom.mechanisms.sbr.beside_pairs` on the device, one
    launch. Window w's pairs are ``pair_start[w]`` .. ``pair_start[w+1] - 1``, with the
    triangles ``triangles[tri_index[tri_start[w] + k]]``; ``frame`` (W, 10) holds each
    window's axis, u, v and distance, ``rect`` (W, 4) its rectangle (lo, hi). Needs
    fp64."""
    import pyopencl as cl

    pair_start = np.ascontiguousarray(pair_start, dtype=np.int64)
    n_pairs = int(pair_start[-1])
    out = np.zeros(n_pairs, dtype=np.uint8)
    if n_pairs == 0:
        return out.view(bool)
    kernel = runtime.kernel(SOURCE, "beside_cull")
    buf = runtime.empty(out.nbytes)
    args = [_in(runtime, triangles, np.float64), _in(runtime, tri_index, np.int32),
            _in(runtime, tri_start, np.int64), _in(runtime, pair_start, np.int64),
            np.int32(len(pair_start) - 1), _in(runtime, frame, np.float64),
            _in(runtime, rect, np.float64)]
    e = np.asarray(eye, dtype=np.float64)
    local = 64
    with runtime.kernel_clock():
        kernel(runtime.queue, (-(-n_pairs // local) * local,), (local,), *args,
               np.float64(e[0]), np.float64(e[1]), np.float64(e[2]), buf)
        cl.enqueue_copy(runtime.queue, out, buf, is_blocking=True)
    return out.view(bool)


def cover_xy_many(runtime: Runtime, tri_xy, window, block_size, origin, shape, offset,
                  size: int) -> np.ndarray:
    """(size,) bool: :func:`clradcom.geometry.silhouette.cover_xy_many` of the same
    arguments in one launch, each triangle's separating-axis data computed in the kernel
    (block_cover_xy) as coverage_setup_many computes them; the host's where the device
    has no fp64. ``tri_xy`` may be :func:`project_windows`' device buffer, which holds
    every candidate window's triangles: a window of shape (0, 0) gets no mark."""
    import pyopencl as cl

    if isinstance(tri_xy, cl.Buffer):   # projected on the device (project_windows)
        n = len(window)
        xy_buf = tri_xy
    else:
        if not runtime.has_double:
            return host.cover_xy_many(tri_xy, window, block_size, origin, shape, offset,
                                      size)
        n = len(tri_xy)
        xy_buf = _in(runtime, tri_xy, np.float64) if n else None
    mask = np.zeros(int(size), dtype=np.uint8)
    if n == 0 or size == 0:
        return mask.view(bool)
    args = [xy_buf, _in(runtime, window, np.int64),
            _in(runtime, origin, np.float64), _in(runtime, block_size, np.float64),
            _in(runtime, shape, np.int64), _in(runtime, offset, np.int64)]
    return _raster(runtime, "block_cover_xy", args, n, mask)


def project_windows(runtime: Runtime, triangles, window, frame, eye):
    """The triangles (T,3,3) of windows ``window`` (T,) projected onto their planes
    (``frame`` (W, 10): axis, u, v, distance) from ``eye`` in one launch, as
    :func:`clradcom.mechanisms.sbr._project` does: (device buffer of xy (T,3,2), extents
    (T,5) on the host: least depth, x min, x max, y min, y max). Needs fp64."""
    import pyopencl as cl

    n = len(triangles)
    ext = np.empty((n, 5), dtype=np.float64)
    xy = runtime.empty(max(1, n) * 48)
    if n == 0:
        return xy, ext
    kernel = runtime.kernel(SOURCE, "project_windows")
    ext_buf = runtime.empty(ext.nbytes)
    e = np.asarray(eye, dtype=np.float64)
    with runtime.kernel_clock():
        kernel(runtime.queue, (-(-n // LOCAL) * LOCAL,), (LOCAL,),
               _in(runtime, triangles, np.float64), _in(runtime, window, np.int64),
               _in(runtime, frame, np.float64), np.float64(e[0]), np.float64(e[1]),
               np.float64(e[2]), np.int32(n), xy, ext_buf)
        cl.enqueue_copy(runtime.queue, ext, ext_buf, is_blocking=True)
    return xy, ext
