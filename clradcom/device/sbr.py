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

from clradcom.device.raycast import RayCaster
from clradcom.device.visibility import SIGHT_STOP
from clradcom.errors import ArgumentError
from clradcom.geometry.silhouette import BLOCK

__all__ = ["BATCH_TUBES", "record_dtype", "shoot_and_radiate"]

#: Tubes per kernel launch (whole blocks): about 1 M, some 10 ms to a second of work.
BATCH_TUBES = 1 << 20


def tri_slots(max_bounces: int) -> int:
    """Triangle slots per record: max_bounces rounded up to odd (8-byte record size)."""
    return int(max_bounces) | 1


def record_dtype(max_bounces: int) -> np.dtype:
    """numpy twin of ``SbrRecord`` in kernels/sbr.cl."""
    return np.dtype([("length", "<f8"), ("point", "<f8", (3,)), ("k_arr", "<f8", (3,)),
                     ("transfer", "<f4", (18,)), ("tube", "<i8"), ("bounce", "<i2"),
                     ("receiver", "<i2"), ("tri", "<i4", (tri_slots(max_bounces),))])


def _tables(scene):
    """Per-triangle material and per-material constants for the kernel."""
    mats = np.arange(len(scene.material_pec))
    eps = np.asarray(scene.material_eps_r, dtype=np.complex128)
    pec = np.asarray(scene.material_pec, dtype=bool) | ~np.isfinite(eps)
    mat_f = np.zeros((len(mats), 4))
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
                            argument="spacing", value=windows.spacing.min())
    blocks = np.stack([windows.block_window, windows.block_i, windows.block_j], axis=1)
    return win_f, win_i.astype(np.int32), np.ascontiguousarray(blocks, dtype=np.int32)


def shoot_and_radiate(caster: RayCaster, scene, windows, receivers, *, wavenumber: float,
                      max_bounces: int, first_bounce: int, record_triangles,
                      batch_tubes: int = BATCH_TUBES) -> dict:
    """Every tube of ``windows`` that radiates toward a receiver (positions (R,3)) from a
    bounce >= ``first_bounce`` on a triangle of ``record_triangles`` (bool per scene
    triangle) at ``wavenumber`` (rad/m), as kernels/sbr.cl computes it: a dict of arrays, one row per record,
    ``receiver``, ``tube``, ``bounce``, ``length``, ``point``, ``k_arr``, ``transfer``
    (complex128 (C,3,3)) and ``tri_history`` (C, max_bounces), sorted by tube, bounce and
    receiver.
    """
    import pyopencl as cl

    rt = caster.runtime
    if not rt.info.has_double:
        raise ArgumentError("the device SBR engine needs an OpenCL device with fp64; "
                            "use engine \"host\"", argument="device",
                            value=rt.info.device_name.strip())
    receivers = np.ascontiguousarray(np.asarray(receivers, np.float64).reshape(-1, 3))
    if len(receivers) >= 2**15:
        raise ArgumentError("at most 32767 receivers per transmitter", argument="receivers",
                            value=len(receivers))
    dtype = record_dtype(max_bounces)
    defines = {"SBR_MAX_BOUNCES": int(max_bounces), "SBR_TRI_SLOTS": tri_slots(max_bounces),
               "SBR_BLOCK": BLOCK}
    data64 = caster.scene_data64()
    mat_f, mat_i = _tables(scene)
    win_f, win_i, blocks = _windows(windows)
    to_dev = rt.to_device
    bufs = [data64["vertices"], data64["normals"],
            to_dev(np.ascontiguousarray(scene.tri_material, dtype=np.int32)),
            to_dev(np.ascontiguousarray(record_triangles, dtype=np.uint8)),
            to_dev(np.ascontiguousarray(mat_f)), to_dev(np.ascontiguousarray(mat_i)),
            to_dev(np.ascontiguousarray(win_f)), to_dev(np.ascontiguousarray(win_i)),
            to_dev(np.ascontiguousarray(windows.masks, dtype=np.uint8)
                   if len(windows.masks) else np.zeros(1, np.uint8)),
            to_dev(blocks if len(blocks) else np.zeros((1, 3), np.int32)),
            to_dev(receivers)]
    tx = np.asarray(windows.tx, dtype=np.float64)
    k0 = float(wavenumber)
    sight_tmax = np.float32(1.0 - SIGHT_STOP)
    cells = BLOCK * BLOCK
    blocks_per_batch = max(1, int(batch_tubes) // cells)
    n_blocks = len(blocks)
    count = np.zeros(1, dtype=np.int32)
    count_buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, size=4)
    capacity = 1 << 16
    out_buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, size=capacity * dtype.itemsize)
    parts = []
    for first in range(0, n_blocks, blocks_per_batch):
        nb = min(blocks_per_batch, n_blocks - first)
        while True:
            cl.enqueue_copy(rt.queue, count_buf, np.zeros(1, np.int32))
            caster.run_kernel("sbr.cl", "sbr_shoot", nb * cells, *bufs, np.int32(len(receivers)),
                              np.float64(tx[0]), np.float64(tx[1]), np.float64(tx[2]),
                              np.float64(k0), sight_tmax, np.int32(first_bounce),
                              np.int32(max_bounces), np.int64(first), np.int32(nb * cells),
                              out_buf, count_buf, np.int32(capacity), defines=defines)
            cl.enqueue_copy(rt.queue, count, count_buf)
            n = int(count[0])
            if n <= capacity:
                break
            # too many records for the buffer: grow it and shoot this batch again
            capacity = max(n, 2 * capacity)
            out_buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE,
                                size=capacity * dtype.itemsize)
        if n:
            rec = np.empty(n, dtype=dtype)
            cl.enqueue_copy(rt.queue, rec, out_buf)
            parts.append(rec)
    rec = np.concatenate(parts) if parts else np.zeros(0, dtype=dtype)
    rec = rec[np.lexsort((rec["receiver"], rec["bounce"], rec["tube"]))]
    transfer = rec["transfer"].astype(np.float64).reshape(-1, 9, 2)
    return {"receiver": rec["receiver"], "tube": rec["tube"], "bounce": rec["bounce"],
            "length": rec["length"], "point": rec["point"], "k_arr": rec["k_arr"],
            "transfer": (transfer[..., 0] + 1j * transfer[..., 1]).reshape(-1, 3, 3),
            "tri_history": rec["tri"][:, :max_bounces]}
