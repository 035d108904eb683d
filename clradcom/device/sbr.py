"""Host side of the device SBR-PO engine (``kernels/sbr.cl``): scene tables, launch
windows and receivers to the device; the wavefront driven batch by batch, bounce by
bounce, and the records back.

Tubes are enumerated by index over the covered blocks of the launch windows
(:class:`clradcom.mechanisms.sbr.TubeWindows`) and generated on the device, a batch of
blocks at a time, so device and host memory stay bounded whatever the number of tubes:
only the records of footprints that see a receiver come back.  Per batch: ``sbr_launch``
queues the owned tubes; per bounce ``sbr_bounce`` follows the live ones (a compacted
queue) and lists the footprints, ``sbr_radiate`` radiates each toward each receiver,
``sbr_reduce`` sums them per block, receiver and face sequence in work groups.  Records
are appended with an atomic counter, so their order within a batch is the device's;
they are sorted by block and the group's first (tube, bounce, receiver), so every run
and batch size gives the same records in the same order.
"""

from __future__ import annotations

import numpy as np

from clradcom.device.precision import join_pairs, split_pairs
from clradcom.device.raycast import KERNEL_DEFINES, RayCaster
from clradcom.device.runtime import OpenCLError
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

#: Tubes per batch at most (whole blocks): about 1 M.
BATCH_TUBES = 1 << 20
#: ... and on a CPU device, whose memory is the host's: the batch's queues and slots
#: stay within some 100 MB
CPU_BATCH_TUBES = 1 << 17
#: A batch's buffers take at most this fraction of the device's largest allocation.
MEMORY_SHARE = 8
#: Records the output buffer has room for at first, per block and receiver of a batch,
#: and at most (about 60 MB); more records grow it and reduce the bounce again.
RECORDS_PER_BLOCK_RX = 4
MAX_START_RECORDS = 1 << 18


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

    # the BVH layout constants a build needs without a caster
    kernel = runtime.kernel("sbr.cl", "sbr_record_size", _options(precision),
                            defines={**KERNEL_DEFINES, **_defines(max_bounces, precision)})
    out = np.zeros(1, dtype=np.int32)
    buf = runtime.empty(4)
    with runtime.guard("SBR record size"):
        runtime.launch(kernel, 1, None, buf, name="sbr_record_size (sbr.cl)")
        cl.enqueue_copy(runtime.queue, out, buf, is_blocking=True)
    return int(out[0])


def _options(precision: str) -> tuple:
    """Build options: without fp64 a literal such as 0.5 is a float, as a device without
    fp64 makes it (and PoCL, which has fp64, must be told)."""
    return ("-cl-single-precision-constant",) if precision != "fp64" else ()


def _defines(max_bounces: int, precision: str) -> dict:
    out = {"SBR_MAX_BOUNCES": int(max_bounces),
           "SBR_TRI_SLOTS": tri_slots(max_bounces), "SBR_BLOCK": BLOCK}
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


def _batch_tubes(rt, per_tube_bytes: int, batch_tubes: int) -> int:
    """Tubes per batch (whole blocks): ``batch_tubes`` at most, the batch's buffers within
    MEMORY_SHARE of the device's largest allocation, and CPU_BATCH_TUBES on a CPU device
    (its memory is the host's)."""
    cells = BLOCK * BLOCK
    limit = int(rt.device.max_mem_alloc_size) // MEMORY_SHARE
    n = min(int(batch_tubes), max(cells, limit // max(1, per_tube_bytes)))
    if rt.info.device_type == "CPU":
        n = min(n, CPU_BATCH_TUBES)
    return max(cells, n // cells * cells)


class _Wavefront:
    """The kernels of kernels/sbr.cl for one build, with the batch's device buffers."""

    def __init__(self, caster: RayCaster, defines: dict, options: tuple):
        rt = caster.runtime
        self.caster, self.rt, self.defines, self.options = caster, rt, defines, options
        # the kernels that do not walk the BVH come from the same program as those that do
        program_defines = {**defines, **caster.kernel_defines()}
        self.launch_kernel = rt.kernel("sbr.cl", "sbr_launch", options, program_defines)
        self.reduce_kernel = rt.kernel("sbr.cl", "sbr_reduce", options, program_defines)
        sizes = np.zeros(4, np.int32)
        sizes_buf = rt.empty(sizes.nbytes)
        size_kernel = rt.kernel("sbr.cl", "sbr_struct_sizes", options, program_defines)
        with rt.guard("SBR structure sizes"):
            rt.launch(size_kernel, 1, None, sizes_buf, name="sbr_struct_sizes (sbr.cl)")
            _cl().enqueue_copy(rt.queue, sizes, sizes_buf, is_blocking=True)
        self.record_bytes, self.tube_bytes, self.footprint_bytes, self.contribution_bytes = (
            int(x) for x in sizes)
        cells = BLOCK * BLOCK
        self.reduce_local = rt.require_local_size(self.reduce_kernel, cells,
                                                  "sbr_reduce (sbr.cl)")
        # faces (cells x slots), live and leader flags (cells each), all int
        need = 4 * cells * (tri_slots(defines["SBR_MAX_BOUNCES"]) + 2)
        have = int(rt.device.local_mem_size)
        if need > have:
            raise OpenCLError(f"kernel sbr_reduce (sbr.cl) needs {need} bytes of local "
                              f"memory and {rt.info.label} has {have}; use fewer "
                              f"bounces or another device")

    def per_tube_bytes(self, n_rx: int) -> int:
        """Device memory a batch holds per tube: two queues, a footprint, and per
        receiver a contribution and its footprint index."""
        return (2 * self.tube_bytes + self.footprint_bytes
                + n_rx * (self.contribution_bytes + 4))

    def timed(self, kernel, global_size, local_size, *args, name):
        rt = self.rt
        with rt.kernel_clock():
            rt.launch(kernel, global_size, local_size, *args, name=name, wait=True)

    def local(self, kernel) -> int:
        return self.rt.local_size(kernel, self.caster.LOCAL_SIZE)


def _cl():
    import pyopencl as cl

    return cl


def shoot_and_radiate(caster: RayCaster, scene, tri_face, windows, tx_frame, receivers,
                      rx_frames, *, wavenumber: float, wavelength: float, max_bounces: int,
                      first_bounce: int, record_triangles, batch_tubes: int = BATCH_TUBES,
                      precision: str = "auto", earlier=None) -> np.ndarray:
    """Block sums (:func:`record_dtype`) of the tubes of ``windows`` as kernels/sbr.cl
    computes them: per covered block, bounce >= ``first_bounce`` on a triangle of
    ``record_triangles`` (bool per scene triangle), receiver (positions (R,3), antenna
    frames (R,3,3); tx's frame ``tx_frame``) and sequence of planar faces ``tri_face``,
    the sum of the tubes' 2x2 polarimetric matrices at ``wavenumber`` (rad/m) and
    ``wavelength`` (m), with the representative tube.  Sorted by block and, within a
    block, by the group's first (tube, bounce, receiver) - the order the host reference
    numbers its groups in - so every run and batch size returns the same records in the
    same order (``ordinal``: that rank within the block).  ``precision``
    (:data:`PRECISIONS`): fp64 where the device has it; "double-float" carries positions
    and lengths in kernels/precise.h's compensated float pairs and the fields in float
    (devices without fp64; tests force it on any device).  Records come back in the
    fp64 layout either way.  ``earlier`` (W, W) bool marks the earlier windows k < w whose
    directions can meet window w's (:func:`clradcom.mechanisms.sbr.earlier_overlaps`): a
    tube tests its ownership against those only (default: every earlier window).

    The tubes go through the wavefront of kernels/sbr.cl a batch of blocks at a time
    (at most ``batch_tubes`` tubes, fewer where the device's memory asks): launch, then
    per bounce the closest hits of the live tubes, the footprints' radiation per
    receiver and its reduction per (block, receiver) in work groups.
    """
    cl = _cl()
    rt = caster.runtime
    precision = engine_precision(rt, precision)
    fp64 = precision == "fp64"
    receivers = np.ascontiguousarray(np.asarray(receivers, np.float64).reshape(-1, 3))
    n_rx = len(receivers)
    if n_rx >= 2**15:
        raise ArgumentError("at most 32767 receivers per transmitter", argument="receivers",
                            value=n_rx)
    dtype = record_dtype(max_bounces, precision)
    defines = _defines(max_bounces, precision)
    options = _options(precision)
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

    wave = _Wavefront(caster, defines, options)
    if fp64:
        data64 = caster.scene_data64()
        tri_v, tri_n = data64["vertices"], data64["normals"]
    else:
        tri_v, tri_n = precise(caster.triangles), precise(caster.normals64())
    tri_material = dev(scene.tri_material, np.int32)
    tri_face_buf = dev(tri_face, np.int32)
    materials = [dev(mat_f, real), dev(mat_i, np.int32)]
    tx_and_k = precise(np.append(np.asarray(windows.tx, np.float64), float(wavenumber)))
    tx_frame_buf = dev(np.asarray(tx_frame, np.float64).reshape(9), real)
    launch_args = [dev(win_f, real), dev(win_i, np.int32), dev(windows.masks, np.uint8),
                   dev(blocks, np.int32),
                   *(dev(a, np.int32) for a in _overlap_lists(windows.n_windows, earlier)),
                   tx_frame_buf, tx_and_k]
    bounce_args = [tri_v, tri_n, tri_material, dev(record_triangles, np.uint8), *materials,
                   tx_and_k]
    radiate_args = [tri_v, tri_n, tri_material, *materials, precise(receivers),
                    dev(np.asarray(rx_frames, np.float64).reshape(-1, 9), real), tx_and_k,
                    dev(near_first, np.int32), dev(near_tri, np.int32)]
    if fp64:
        # the face tables of the float64 sight rounds (kernels/scene64.h)
        tri_face64, seam, face_first, face_tris, face_box, n_faces = \
            scene64_args(caster, tri_face)[2:8]
        radiate_args += [tri_face64, seam, face_first, face_tris, face_box, n_faces,
                         np.int32(RESCUE_ROUNDS), np.float64(LOOK_PAST),
                         np.float64(1.0 - SIGHT_STOP)]
    radiate_args += [real(ON_FACE_TOL_REL), real(INSIDE_TOL_REL), real(CONFIRM_TOL_M),
                     np.int32(n_rx), real(wavelength), np.float32(1.0 - SIGHT_STOP)]

    cells = BLOCK * BLOCK
    n_blocks = len(blocks)
    per_batch = _batch_tubes(rt, wave.per_tube_bytes(n_rx), batch_tubes)
    blocks_per_batch = per_batch // cells
    batch_cells = min(blocks_per_batch, n_blocks) * cells
    slots = batch_cells * n_rx
    empty = rt.empty
    queues = [empty(batch_cells * wave.tube_bytes), empty(batch_cells * wave.tube_bytes)]
    footprints = empty(batch_cells * wave.footprint_bytes)
    contributions = empty(slots * wave.contribution_bytes)
    contribution_footprint = empty(slots * 4)
    # room for a few records per block and receiver: more grow it and reduce again
    capacity = int(np.clip(RECORDS_PER_BLOCK_RX * max(1, n_rx) * (batch_cells // cells),
                           1 << 14, MAX_START_RECORDS))
    out_buf = empty(capacity * dtype.itemsize)
    # the counters: tubes queued, next bounce's tubes, footprints, records
    n_live_buf, n_next_buf, n_fp_buf, n_rec_buf = (empty(4) for _ in range(4))

    def zero(*bufs):
        for b in bufs:
            cl.enqueue_copy(rt.queue, b, np.zeros(1, np.int32))

    def read(buf) -> int:
        out = np.zeros(1, np.int32)
        cl.enqueue_copy(rt.queue, out, buf, is_blocking=True)
        return int(out[0])

    parts = []
    for first in range(0, n_blocks, blocks_per_batch):
        nb = min(blocks_per_batch, n_blocks - first)
        with rt.guard("SBR tube launch"):
            zero(n_live_buf)
            wave.timed(wave.launch_kernel, nb * cells, wave.local(wave.launch_kernel),
                       *launch_args, np.int64(first), np.int32(nb * cells), queues[0],
                       n_live_buf, name="sbr_launch (sbr.cl)")
            n_live = read(n_live_buf)
        for m in range(1, max_bounces + 1):
            if n_live == 0:
                break
            with rt.guard("SBR bounce"):
                zero(n_next_buf, n_fp_buf)
            caster.run_kernel("sbr.cl", "sbr_bounce", n_live, *bounce_args, np.int32(m),
                              np.int32(first_bounce), np.int32(max_bounces), queues[0],
                              np.int32(n_live), queues[1], n_next_buf, footprints, n_fp_buf,
                              defines=defines, options=options)
            with rt.guard("SBR bounce counts"):
                n_next, n_fp = read(n_next_buf), read(n_fp_buf)
            if n_fp:
                with rt.guard("SBR contribution slots"):
                    cl.enqueue_fill_buffer(rt.queue, contribution_footprint,
                                           np.int32(-1), 0, nb * cells * n_rx * 4)
                caster.run_kernel("sbr.cl", "sbr_radiate", n_fp * n_rx, *radiate_args,
                                  queues[0], footprints, np.int32(n_fp), contributions,
                                  contribution_footprint, defines=defines, options=options)
                while True:
                    with rt.guard("SBR reduction"):
                        zero(n_rec_buf)
                        wave.timed(wave.reduce_kernel, nb * n_rx * cells, wave.reduce_local,
                                   tri_face_buf, queues[0], footprints, contributions,
                                   contribution_footprint, np.int32(m), np.int32(n_rx),
                                   np.int64(first), out_buf, n_rec_buf, np.int32(capacity),
                                   name="sbr_reduce (sbr.cl)")
                        n = read(n_rec_buf)
                    if n <= capacity:
                        break
                    # more records than the buffer holds: grow it, reduce this bounce again
                    capacity = max(n, 2 * capacity)
                    out_buf = empty(capacity * dtype.itemsize)
                if n:
                    rec = np.empty(n, dtype=dtype)
                    with rt.guard("SBR records"):
                        cl.enqueue_copy(rt.queue, rec, out_buf, is_blocking=True)
                    parts.append(rec)
            queues.reverse()
            n_live = n_next
    rec = np.concatenate(parts) if parts else np.zeros(0, dtype=dtype)
    if len(rec):
        # by block, then the group's first (cell, bounce, receiver): one int64 key
        block = rec["tube"] // cells
        key = block * (int(rec["ordinal"].max()) + 1) + rec["ordinal"]
        rec = rec[np.argsort(key, kind="stable")]
        # ordinal: the rank within the block
        head = np.ones(len(rec), bool)
        block = rec["tube"] // cells
        head[1:] = block[1:] != block[:-1]
        start = np.flatnonzero(head)
        rec["ordinal"] = np.arange(len(rec)) - np.repeat(start, np.diff(np.append(start,
                                                                              len(rec))))
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
