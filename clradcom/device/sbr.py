"""Host side of the device SBR-PO engine (``kernels/sbr.cl``): scene tables, launch
windows and receivers to the device; tube batches launched and their records back.

Tubes are enumerated by index over the covered blocks of the launch windows
(:class:`clradcom.mechanisms.sbr.TubeWindows`) and generated in the kernel, a batch of
blocks at a time, so device and host memory stay bounded whatever the number of tubes:
only the records of footprints that see a receiver come back.  Records are appended with
an atomic counter, so their order within a batch is the device's; they are sorted by
(tube, bounce, receiver) so every run gives the same contributions in the same order.
"""

from __future__ import annotations

import numpy as np

from clradcom.device.precision import join_pairs, split_pairs
from clradcom.device.raycast import KERNEL_DEFINES, RayCaster
from clradcom.device.visibility import (
    CONFIRM_TOL_M,
    INSIDE_TOL_REL,
    LOOK_PAST,
    ON_FACE_TOL_REL,
    RESCUE_ROUNDS,
    SIGHT_STOP,
    confirm_margin_m,
    dot3_order,
    scene64_args,
)
from clradcom.errors import ArgumentError
from clradcom.geometry.silhouette import BLOCK

__all__ = ["BATCH_TUBES", "PRECISIONS", "engine_precision", "record_dtype", "record_size",
           "shoot_and_radiate"]

#: Tubes per kernel launch (whole blocks): about 1 M, some 10 ms to a second of work.
BATCH_TUBES = 1 << 20
#: Records the output buffer has room for at first, per block and receiver of a batch,
#: and at most (about 60 MB); more records grow it and shoot the batch again.
RECORDS_PER_BLOCK_RX = 4
MAX_START_RECORDS = 1 << 18
#: Face sequences a work item sums at once per block (the oldest is written out when a
#: new one finds the table full: the sums stay exact, the block just yields more records).
GROUPS = 16


def tri_slots(max_bounces: int) -> int:
    """Face and triangle slots per record."""
    return max(1, int(max_bounces))


#: the precisions the engine runs in: "fp64" (double throughout) and "double-float"
#: (kernels/precise.h for positions and lengths, float for the fields), and "auto", fp64
#: where the device has it
PRECISIONS = ("auto", "fp64", "double-float")
#: plain float32 positions and lengths: the tests' negative control, never for results
CONTROL_PRECISION = "float32"


def record_dtype(max_bounces: int, precision: str = "fp64") -> np.dtype:
    """numpy twin of ``SbrRecord`` in kernels/sbr.cl, as a build of ``precision`` lays it
    out (fp64: doubles; double-float: lengths and points as (hi, lo) float pairs, the
    rest float)."""
    k = tri_slots(max_bounces)
    real = "<f8" if precision == "fp64" else "<f4"
    out = ("<f8", ()) if precision == "fp64" else ("<f4", (2,))
    return np.dtype([("length", out[0], out[1]), ("point", out[0], (3, *out[1])),
                     ("M", real, (8,)), ("weight", real), ("weighted_length", real),
                     ("rep_weight", real), ("pad_real", real),
                     ("tube", "<i8"), ("ordinal", "<i4"), ("count", "<i4"),
                     ("bounce", "<i2"), ("receiver", "<i2"), ("pad", "<i4"),
                     ("face", "<i4", (k,)), ("tri", "<i4", (k,))])


def engine_precision(runtime, precision: str = "auto") -> str:
    """The precision a build for ``precision`` runs in on ``runtime``'s device:
    "fp64" or "double-float"."""
    if precision == CONTROL_PRECISION:
        return precision
    if precision not in PRECISIONS:
        raise ArgumentError(f"must be one of {', '.join(PRECISIONS)}", argument="precision",
                            value=precision)
    if precision == "fp64" and not runtime.info.has_double:
        raise ArgumentError("this OpenCL device has no fp64 (use 'auto' or 'double-float')",
                            argument="precision", value=precision)
    if precision == "auto":
        return "fp64" if runtime.info.has_double else "double-float"
    return precision


def record_size(runtime, max_bounces: int, precision: str = "fp64") -> int:
    """sizeof(SbrRecord) as the device lays it out in ``precision`` (for a test)."""
    import pyopencl as cl

    kernel = runtime.kernel("sbr.cl", "sbr_record_size", _options(precision),
                            defines=_defines(max_bounces, precision))
    out = np.zeros(1, dtype=np.int32)
    buf = runtime.empty(4)
    kernel(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, out, buf, is_blocking=True)
    return int(out[0])


def _options(precision: str) -> tuple:
    """Build options: without fp64 a literal such as 0.5 is a float, as a device without
    fp64 makes it (and PoCL, which has fp64, must be told)."""
    return ("-cl-single-precision-constant",) if precision != "fp64" else ()


def _defines(max_bounces: int, precision: str) -> dict:
    out = {**KERNEL_DEFINES, "SBR_MAX_BOUNCES": int(max_bounces),
           "SBR_TRI_SLOTS": tri_slots(max_bounces), "SBR_BLOCK": BLOCK, "SBR_GROUPS": GROUPS}
    if precision == "double-float":
        out["CLRADCOM_NO_FP64"] = 1
    elif precision == CONTROL_PRECISION:
        out["CLRADCOM_PRECISE_FLOAT32"] = 1
    else:
        out["DOT3_ORDER"] = int(dot3_order() or 0)
    return out


def _overlap_lists(n_windows: int, earlier) -> tuple[np.ndarray, np.ndarray]:
    """``earlier`` (W, W) bool as CSR lists (first (W+1,), window ids), each window's
    earlier windows in increasing order; None: all of them."""
    if earlier is None:
        earlier = np.tri(n_windows, k=-1, dtype=bool)
    earlier = np.asarray(earlier, dtype=bool).reshape(n_windows, n_windows)
    rows, cols = np.nonzero(earlier & np.tri(n_windows, k=-1, dtype=bool))
    first = np.searchsorted(rows, np.arange(n_windows + 1)).astype(np.int32)
    return first, cols.astype(np.int32)


def _tables(scene):
    """Per-material constants for the kernel: (eps re, eps im, roughness, sqrt(1 - S^2))
    and (pec, roughness model)."""
    eps = np.asarray(scene.material_eps_r, dtype=np.complex128)
    pec = np.asarray(scene.material_pec, dtype=bool) | ~np.isfinite(eps)
    mat_f = np.zeros((len(eps), 4))
    mat_f[:, 0] = np.where(pec, 0.0, eps.real)
    mat_f[:, 1] = np.where(pec, 0.0, eps.imag)
    mat_f[:, 2] = scene.material_roughness_m
    mat_f[:, 3] = np.sqrt(1.0 - np.asarray(scene.material_scattering, dtype=np.float64) ** 2)
    mat_i = np.stack([pec.astype(np.int32),
                      np.asarray(scene.material_roughness_model, dtype=np.int32)], axis=1)
    return mat_f, mat_i.astype(np.int32)


def _windows(windows):
    W = windows.n_windows
    win_f = np.zeros((W, 12))
    win_f[:, 0:3], win_f[:, 3:6], win_f[:, 6:9] = windows.axis, windows.u, windows.v
    win_f[:, 9], win_f[:, 10] = windows.distance, windows.spacing
    win_i = np.zeros((W, 6), dtype=np.int64)
    win_i[:, 0:2], win_i[:, 2:4], win_i[:, 4] = windows.cell0, windows.shape, windows.mask_offset
    if np.abs(win_i).max(initial=0) >= 2**31:
        raise ArgumentError("a launch window is too large for 32-bit cell indices",
                            argument="spacing", value=float(windows.spacing.min()))
    blocks = np.stack([windows.block_window, windows.block_i, windows.block_j], axis=1)
    return win_f, win_i.astype(np.int32), np.ascontiguousarray(blocks, dtype=np.int32)


def near_triangles(caster: RayCaster, antennas) -> tuple[np.ndarray, np.ndarray]:
    """Per antenna (R,3), the triangles that :func:`clradcom.device.visibility.
    antenna_blocked` would test for its segments: boxes within twice the confirmation
    margin of it, the antenna off their plane. (first (R+1,), triangles) as a CSR list."""
    triangles = caster.triangles
    lo, hi = caster.triangle_bounds()
    normals = caster.normals64()
    first, tris = [0], []
    for ant in np.asarray(antennas, dtype=np.float64).reshape(-1, 3):
        r = 2.0 * float(confirm_margin_m(ant[None])[0])
        # the box test axis by axis on the triangles left (the same comparisons)
        near = np.flatnonzero((ant[0] >= lo[:, 0] - r) & (ant[0] <= hi[:, 0] + r))
        for k in (1, 2):
            near = near[(ant[k] >= lo[near, k] - r) & (ant[k] <= hi[near, k] + r)]
        d_ant = np.einsum("ij,ij->i", normals[near], ant - triangles[near, 0])
        near = near[np.abs(d_ant) > ON_FACE_TOL_REL * (1.0 + np.abs(ant).max())]
        tris.append(near)
        first.append(first[-1] + len(near))
    return (np.array(first, dtype=np.int32),
            np.concatenate(tris).astype(np.int32) if tris else np.zeros(0, np.int32))


def shoot_and_radiate(caster: RayCaster, scene, tri_face, windows, tx_frame, receivers,
                      rx_frames, *, wavenumber: float, wavelength: float, max_bounces: int,
                      first_bounce: int, record_triangles, batch_tubes: int = BATCH_TUBES,
                      precision: str = "auto", earlier=None) -> np.ndarray:
    """Block sums (:func:`record_dtype`) of the tubes of ``windows`` as kernels/sbr.cl
    computes them: per covered block, bounce >= ``first_bounce`` on a triangle of
    ``record_triangles`` (bool per scene triangle), receiver (positions (R,3), antenna
    frames (R,3,3); tx's frame ``tx_frame``) and sequence of planar faces ``tri_face``,
    the sum of the tubes' 2x2 polarimetric matrices at ``wavenumber`` (rad/m) and
    ``wavelength`` (m), with the representative tube.  Sorted by block and emission
    order, so every run returns the same records in the same order.  ``precision``
    (:data:`PRECISIONS`): fp64 where the device has it; "double-float" carries positions
    and lengths in kernels/precise.h's compensated float pairs and the fields in float
    (devices without fp64; tests force it on any device).  Records come back in the
    fp64 layout either way.  ``earlier`` (W, W) bool marks the earlier windows k < w whose
    directions can meet window w's (:func:`clradcom.mechanisms.sbr.earlier_overlaps`): a
    tube tests its ownership against those only (default: every earlier window).
    """
    import pyopencl as cl

    rt = caster.runtime
    precision = engine_precision(rt, precision)
    fp64 = precision == "fp64"
    receivers = np.ascontiguousarray(np.asarray(receivers, np.float64).reshape(-1, 3))
    if len(receivers) >= 2**15:
        raise ArgumentError("at most 32767 receivers per transmitter", argument="receivers",
                            value=len(receivers))
    dtype = record_dtype(max_bounces, precision)
    defines = _defines(max_bounces, precision)
    real = np.float64 if fp64 else np.float32
    mat_f, mat_i = _tables(scene)
    win_f, win_i, blocks = _windows(windows)
    near_first, near_tri = near_triangles(caster, receivers)
    to_dev = rt.to_device

    def dev(a, dtype):
        a = np.ascontiguousarray(a, dtype=dtype)
        return to_dev(a if a.size else np.zeros(1, dtype))

    def precise(a):
        """float64 positions and lengths as the build reads them: doubles, or pairs"""
        a = np.asarray(a, np.float64).reshape(-1)
        return dev(a, np.float64) if fp64 else dev(split_pairs(a), np.float32)

    if fp64:
        data64 = caster.scene_data64()
        tri_v, tri_n = data64["vertices"], data64["normals"]
    else:
        tri_v, tri_n = precise(caster.triangles), precise(caster.normals64())
    tx_and_k = np.append(np.asarray(windows.tx, np.float64), float(wavenumber))
    bufs = [tri_v, tri_n, dev(scene.tri_material, np.int32),
            dev(tri_face, np.int32), dev(record_triangles, np.uint8), dev(mat_f, real),
            dev(mat_i, np.int32), dev(win_f, real), dev(win_i, np.int32),
            dev(windows.masks, np.uint8), dev(blocks, np.int32),
            *(dev(a, np.int32) for a in _overlap_lists(windows.n_windows, earlier)),
            precise(receivers),
            dev(np.asarray(rx_frames, np.float64).reshape(-1, 9), real),
            dev(np.asarray(tx_frame, np.float64).reshape(9), real), precise(tx_and_k),
            dev(near_first, np.int32), dev(near_tri, np.int32)]
    if fp64:
        # the face tables of the float64 sight rounds (kernels/scene64.h)
        seam, face_first, face_tris, face_box, n_faces = scene64_args(caster, tri_face)[3:8]
        bufs += [seam, face_first, face_tris, face_box, n_faces, np.int32(RESCUE_ROUNDS),
                 np.float64(LOOK_PAST), np.float64(1.0 - SIGHT_STOP)]
    sight_tmax = np.float32(1.0 - SIGHT_STOP)
    cells = BLOCK * BLOCK
    blocks_per_batch = max(1, int(batch_tubes) // cells)
    n_blocks = len(blocks)
    count = np.zeros(1, dtype=np.int32)
    count_buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, size=4)
    # room for a few records per block and receiver: a batch whose records overflow the
    # buffer is shot again (the street's first transmitter, 19k records, overflowed the
    # 16k it once had, and the kernel ran twice)
    capacity = int(np.clip(RECORDS_PER_BLOCK_RX * max(1, len(receivers))
                           * min(blocks_per_batch, n_blocks), 1 << 14, MAX_START_RECORDS))
    out_buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, size=capacity * dtype.itemsize)
    parts = []
    for first in range(0, n_blocks, blocks_per_batch):
        nb = min(blocks_per_batch, n_blocks - first)
        while True:
            cl.enqueue_copy(rt.queue, count_buf, np.zeros(1, np.int32))
            caster.run_kernel("sbr.cl", "sbr_blocks", nb, *bufs, real(ON_FACE_TOL_REL),
                              real(INSIDE_TOL_REL), real(CONFIRM_TOL_M),
                              np.int32(len(receivers)), real(wavelength), sight_tmax,
                              np.int32(first_bounce), np.int32(max_bounces), np.int64(first),
                              np.int32(nb), out_buf, count_buf, np.int32(capacity),
                              defines=defines, options=_options(precision))
            cl.enqueue_copy(rt.queue, count, count_buf)
            n = int(count[0])
            if n <= capacity:
                break
            # more records than the buffer holds: grow it and shoot this batch again
            capacity = max(n, 2 * capacity)
            out_buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE,
                                size=capacity * dtype.itemsize)
        if n:
            rec = np.empty(n, dtype=dtype)
            cl.enqueue_copy(rt.queue, rec, out_buf)
            parts.append(rec)
    rec = np.concatenate(parts) if parts else np.zeros(0, dtype=dtype)
    if len(rec):
        # by block, then emission order: lexsort's order, from one int64 key whose
        # records come nearly sorted (a stable sort runs through them)
        key = (rec["tube"] // cells) * (int(rec["ordinal"].max()) + 1) + rec["ordinal"]
        order = np.argsort(key, kind="stable")
        if np.any(order != np.arange(len(order))):
            rec = rec[order]
    if fp64:
        return rec
    # double-float: lengths and points back to float64, the rest widened
    out = np.zeros(len(rec), dtype=record_dtype(max_bounces, "fp64"))
    for name in out.dtype.names:
        if name in ("length", "point"):
            out[name] = join_pairs(rec[name])
        else:
            out[name] = rec[name]
    return out
