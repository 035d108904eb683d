"""Reflection points of candidate face sequences on the device (kernels/images.cl).

:func:`image_points` is the image method of
:func:`clradcom.mechanisms.specular.image_points` with one work item per candidate: the
transmitter mirrored in each face's plane, then the line from the receiver back to each
image crossed with its plane. The kernel evaluates the host's float64 expressions in the
host's order (no contraction, three-term dot products added as numpy's einsum adds them:
:func:`clradcom.device.visibility.dot3_order`): in double where the device has fp64, so
the points are the host's bit for bit (tests/test_image_points.py); in double-float
without (``kernels/precise.h``: the points within ~1e-14 relative of the host's, the
"strictly between" decisions the host's except within that of their 1e-12 margins;
tests/test_no_fp64.py). The host keeps the numpy version as the reference engine.
"""

from __future__ import annotations

import numpy as np

from clradcom.device.precision import host_float64, kernel_float64, kernel_scalar64
from clradcom.device.visibility import DOT3_UNKNOWN, dot3_order, kernel_defines
from clradcom.errors import ArgumentError

__all__ = ["MAX_ORDER", "available", "device_refusal", "image_points"]

SOURCE = "images.cl"
#: the most reflections a candidate may have: SpecularSettings.max_reflections' bound
MAX_ORDER = 16


def device_refusal(runtime) -> str | None:
    """Why ``runtime``'s device cannot place the points, or None where it can: with fp64
    it must repeat the host bit for bit, which needs numpy's order of three-term dot
    products; without, it computes in double-float whatever that order."""
    if runtime.has_double and dot3_order() is None:
        return DOT3_UNKNOWN
    return None


def available(runtime) -> bool:
    """Whether ``runtime``'s device places the points (:func:`device_refusal`)."""
    return device_refusal(runtime) is None


def image_points(runtime, tx, rx, normals, offsets, seqs):
    """(points (C, k + 2, 3) float64, ok (C,) bool, failed_last (C,) bool,
    failed_first (C,) bool) of the candidates ``seqs`` (C, k) face ids between ``tx``
    and ``rx`` (3,), the faces' planes n.x = d given by ``normals`` (F, 3) unit and
    ``offsets`` (F,): tx, the k reflection points, rx, and whether every point lies
    strictly between its neighbours' image line ends. ``failed_last``: the reflection
    next to rx failed; ``failed_first``: the one next to tx failed while every later
    one held (the host warns where an antenna lies on such a face)."""
    import pyopencl as cl

    refusal = device_refusal(runtime)
    if refusal is not None:
        raise ArgumentError(refusal, argument="runtime",
                            value=runtime.info.device_name.strip())
    seqs = np.ascontiguousarray(seqs, dtype=np.int32)
    if seqs.ndim != 2 or not 1 <= seqs.shape[1] <= MAX_ORDER:
        raise ArgumentError(f"seqs must be (C, k) with 1 <= k <= {MAX_ORDER}",
                            argument="seqs", value=seqs.shape)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    offsets = np.ascontiguousarray(offsets, dtype=np.float64)
    if seqs.size and (seqs.min() < 0 or seqs.max() >= len(normals)):
        raise ArgumentError(f"face ids must lie in [0, {len(normals)})", argument="seqs",
                            value=(int(seqs.min()), int(seqs.max())))
    C, k = seqs.shape
    points = np.empty((C, k + 2, 3))
    flags = np.zeros(C, dtype=np.uint8)
    if C:
        tx = np.asarray(tx, dtype=np.float64)
        rx = np.asarray(rx, dtype=np.float64)
        kernel = runtime.kernel(SOURCE, "image_points",
                                defines={**kernel_defines(), "MAX_ORDER": MAX_ORDER})
        out = runtime.empty(points.nbytes)
        flag_buf = runtime.empty(flags.nbytes)
        with runtime.kernel_clock(), runtime.guard("image points"):
            runtime.launch(kernel, C, runtime.local_size(kernel),
                           *(kernel_scalar64(runtime, x) for x in tx),
                           *(kernel_scalar64(runtime, x) for x in rx),
                           runtime.to_device(kernel_float64(runtime, normals)),
                           runtime.to_device(kernel_float64(runtime, offsets)),
                           runtime.to_device(seqs), np.int32(k), np.int32(C), out, flag_buf,
                           name="image_points")
            cl.enqueue_copy(runtime.queue, points, out)
            cl.enqueue_copy(runtime.queue, flags, flag_buf, is_blocking=True)
        points = host_float64(runtime, points)
        # the antennas as given (without fp64 they crossed as pairs, 2^-48 off)
        points[:, 0] = tx
        points[:, -1] = rx
    return points, (flags & 1) != 0, (flags & 2) != 0, (flags & 4) != 0
