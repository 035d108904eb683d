"""Which diffracting edges antennas may see, on the device (``kernels/edges.cl``).

One launch answers every (antenna position, wedge) pair of a batch: the sample sight
lines, the knots' first blockers, and the pieces between them proven hidden by one planar
face or halved, all in one work item (:func:`wedges_seen`).  It is the device twin of
:func:`clradcom.mechanisms.diffraction.wedges_seeing` (the numpy reference over float32
casts), which decides what the kernel cannot take cheaply and exactly: whether the antenna
lies outside each wedge (an arctangent), passed in as ``gate`` bits.  The float32 rays are
built as :func:`clradcom.device.raycast.make_rays` builds them and the float64 tests
repeat the reference operation for operation, with the point-in-face test and the seam
table of ``kernels/visibility.cl`` (:mod:`clradcom.device.visibility`'s tables, uploaded
once per caster), so both engines keep the same wedges: bit for bit in double where the
device has fp64, in double-float without (``kernels/precise.h``; the same wedges except
for a decision within ~1e-13 (1 + |p|) m of its threshold, tests/test_no_fp64.py).
"""

from __future__ import annotations

import numpy as np

from clradcom.device import visibility
from clradcom.device.precision import kernel_float64, kernel_scalar64
from clradcom.device.raycast import RayCaster
from clradcom.errors import ArgumentError

__all__ = ["MAX_DEPTH", "SAMPLED", "SEEN", "device_refusal", "usable", "wedges_seen"]

SOURCE = "edges.cl"
#: the most halvings of a piece the kernel takes (EDGE_MAX_DEPTH in kernels/edges.cl)
MAX_DEPTH = 10
#: result bits of :func:`wedges_seen`: seen at the sample points; kept (seen, or not
#: proven hidden)
SAMPLED, SEEN = 1, 2


def device_refusal(caster: RayCaster, n_samples: int, max_depth: int) -> str | None:
    """Why the kernel cannot take the edge test, or None where it can: a device whose
    float64 tests cannot repeat numpy's (:func:`clradcom.device.visibility.device_refusal`),
    more than 7 samples (a gate byte holds them and the pieces' bit) or more than
    :data:`MAX_DEPTH` halvings (the kernel's stack)."""
    refusal = visibility.device_refusal(caster)
    if refusal is not None:
        return refusal
    if not 0 <= n_samples <= 7:
        return f"{n_samples} sample points per edge: the kernel takes at most 7"
    if not 0 <= max_depth <= MAX_DEPTH:
        return f"{max_depth} halvings of an edge: the kernel takes at most {MAX_DEPTH}"
    return None


def usable(caster: RayCaster, engine: str, n_samples: int, max_depth: int) -> bool:
    """True where ``engine`` is "device" and the kernel can take the edge test
    (:func:`device_refusal`)."""
    return engine == "device" and device_refusal(caster, n_samples, max_depth) is None


def wedges_seen(caster: RayCaster, tri_face, start, end, direction, length, normal0,
                normal1, points, samples, gate, max_depth: int, edge_clearance_m: float,
                edge_lift_m: float) -> np.ndarray:
    """(P, W) uint8 bits (:data:`SAMPLED`, :data:`SEEN`) for wedges given by their
    ``start``, ``end``, unit ``direction`` (W, 3), ``length`` (W,) and outward normals
    (W, 3), seen from ``points`` (P, 3), in one launch of ``wedges_seen``.

    ``gate`` (P, W) uint8: bit k (k < len(samples)) where the sight line from the
    sample point ``samples[k]`` (a fraction of the edge) is to be cast (the point lies
    outside the wedge and farther than twice the clearance), bit len(samples) where the
    pieces are to be tried (outside seen from the midpoint, an edge longer than twice the
    clearance).  ``tri_face``: the planar face of every triangle (the covering faces)."""
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    samples = np.ascontiguousarray(samples, dtype=np.float64).reshape(-1)
    P, W = len(points), len(length)
    gate = np.ascontiguousarray(gate, dtype=np.uint8)
    if gate.shape != (P, W):
        raise ArgumentError(f"must have shape ({P}, {W})", argument="gate", value=gate.shape)
    if not 0 <= max_depth <= MAX_DEPTH:
        raise ArgumentError(f"must lie in [0, {MAX_DEPTH}]", argument="max_depth",
                            value=max_depth)
    if len(samples) > 7:
        raise ArgumentError("at most 7 samples", argument="samples", value=len(samples))
    n = P * W
    if n == 0:
        return np.zeros((P, W), dtype=np.uint8)
    rt = caster.runtime

    def vec(a):
        return rt.to_device(kernel_float64(rt, a))

    out = rt.empty(n)
    caster.run_kernel(SOURCE, "wedges_seen", n, *visibility.scene64_args(caster, tri_face),
                      vec(start), vec(end), vec(direction), vec(length), vec(normal0),
                      vec(normal1), kernel_scalar64(rt, edge_clearance_m),
                      kernel_scalar64(rt, edge_lift_m),
                      vec(points), vec(samples if len(samples) else np.zeros(1)),
                      np.int32(len(samples)), rt.to_device(gate), np.int32(max_depth), out,
                      np.int32(W), np.int32(n), defines=visibility.kernel_defines())
    return visibility.download(caster, out, n, np.uint8).reshape(P, W)
