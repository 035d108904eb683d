"""Host side of the device SBR-PO engine (``kernels/sbr.cl``): scene tables, launch
windows and receivers to the device; the wavefront driven batch by batch, bounce by
bounce, and the records back.

Tubes are enumerated by index over the covered blocks of the launch windows
(:class:`clradcom.mechanisms.sbr.TubeWindows`) and generated on the device, a batch of
blocks at a time, so device and host memory stay bounded whatever the number of tubes:
only the records of footprints that see a receiver come back.  Per batch: ``sbr_launch``
queues the owned tubes; per bounce ``sbr_bounce`` follows the live ones (a compacted
queue) and lists the footprints, ``sbr_radiate`` radiates each toward each receiver,
``sbr_reduce`` sums them per block, receiver and face sequence in work groups (on a
device that runs work items as scalar code ``sbr_bounces`` launches and bounces the
tubes of a launch block in one work item, no queue, those that left the same faces cast
as a packet, the last bounce cast only where :func:`recorded_tree` has a hit).  Records
are appended with an atomic counter, so their order within a batch is the device's;
they are sorted by block and the group's first (tube, bounce, receiver), so every run
and batch size gives the same records in the same order.
"""

from __future__ import annotations

import hashlib
import math
import weakref

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
    face_boxes,
    scene64_args,
)
from clradcom.errors import ArgumentError
from clradcom.geometry.silhouette import BLOCK

__all__ = ["BATCH_TUBES", "PRECISIONS", "engine_precision", "record_dtype", "record_size",
           "recorded_tree", "shoot_and_radiate"]

#: Tubes per batch at most (whole blocks): about 1 M.
BATCH_TUBES = 1 << 20
#: ... and on a CPU device, whose memory is the host's, the batch's buffers within this
#: many bytes (with two receivers about 88 k tubes; the street's SBR stage on PoCL took
#: the same time, within the noise of a shared machine, from 32 to 256 MB)
CPU_BATCH_BYTES = 1 << 26
#: A batch's buffers take at most this fraction of the device's largest allocation.
MEMORY_SHARE = 8
#: sbr_bounces' work-group size: a work item is a whole block of tubes, so a batch has
#: few of them; small groups keep every thread of a CPU device busy to the end.
BLOCKS_PER_GROUP = 4
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
    if precision != CONTROL_PRECISION:
        # the float64 sight rounds (kernels/scene64.h) add as numpy does
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


def material_tables(scene):
    """Per-material constants of ``kernels/em.h``'s reflection, as the SBR and radio-map
    kernels read them: (eps re, eps im, roughness, sqrt(1 - S^2)) float64 and (pec,
    roughness model) int32."""
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


# per caster: {digest of a record mask: the recorded triangles' own RayCaster, or None}
_RECORDED_TREES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def recorded_tree(caster: RayCaster, record_triangles) -> RayCaster | None:
    """A tree over the triangles ``record_triangles`` (bool per scene triangle) marks,
    for sbr_bounces' last-bounce test: a single-level :class:`RayCaster` on the same
    device, built once per caster and mask. None where the test cannot stand in for the
    scene's tree: a two-level caster (its instances' triangles are tested in their own
    frames, so a hit there and in a world-space tree can round apart), a tree that needs
    a deeper traversal stack than the scene's (the kernel is built with the scene's), or
    no recorded triangle."""
    if caster.EXTRA_DEFINES:
        return None
    record = np.asarray(record_triangles, dtype=bool).reshape(-1)
    key = hashlib.blake2b(np.packbits(record).tobytes(), digest_size=16).digest()
    trees = _RECORDED_TREES.setdefault(caster, {})
    if key not in trees:
        tree = None
        if record.any():
            tree = RayCaster(caster.triangles[record], runtime=caster.runtime)
            if tree.stack_size > caster.stack_size:
                tree = None
        trees[key] = tree
    return trees[key]


def _batch_tubes(rt, per_tube_bytes: int, batch_tubes: int, n_rx: int) -> int:
    """Tubes per batch (whole blocks): ``batch_tubes`` at most, the batch's buffers
    (``per_tube_bytes`` a tube) within 1/MEMORY_SHARE of the device's largest allocation,
    and within CPU_BATCH_BYTES on a CPU device (its memory is the host's); its slots per
    (tube, receiver) within the kernels' int indices."""
    cells = BLOCK * BLOCK
    limit = int(rt.device.max_mem_alloc_size) // MEMORY_SHARE
    if rt.info.device_type == "CPU":
        limit = min(limit, CPU_BATCH_BYTES)
    n = min(int(batch_tubes), limit // max(1, per_tube_bytes),
            (2**31 - 1) // max(1, n_rx) - cells)
    return max(cells, n // cells * cells)


def _struct_sizes(rt, options, defines) -> np.ndarray:
    """sizeof SbrRecord, SbrTube, SbrFootprint, SbrIllumination and SbrContribution in
    this build."""
    import pyopencl as cl

    kernel = rt.kernel("sbr.cl", "sbr_struct_sizes", options, defines)
    sizes = np.zeros(5, np.int32)
    buf = rt.empty(sizes.nbytes)
    with rt.guard("SBR structure sizes"):
        rt.launch(kernel, 1, None, buf, name="sbr_struct_sizes (sbr.cl)")
        cl.enqueue_copy(rt.queue, sizes, buf, is_blocking=True)
    return sizes


class _Wavefront:
    """kernels/sbr.cl's stages for one transmitter: one build's kernels, the scene,
    window and receiver buffers (``*_args``, as each kernel takes them after its BVH
    buffers), and one batch's queues, footprints, contribution slots and records.
    :meth:`shoot` runs a batch of blocks through all of them."""

    def __init__(self, caster: RayCaster, defines: dict, options: tuple, dtype: np.dtype,
                 n_rx: int, n_blocks: int, batch_tubes: int, *, launch_args, bounce_args,
                 illuminate_args, radiate_args, tri_face, recorded=None):
        import pyopencl as cl

        rt = caster.runtime
        self.cl, self.caster, self.rt = cl, caster, rt
        self.defines, self.options, self.dtype, self.n_rx = defines, options, dtype, n_rx
        self.launch_args, self.bounce_args = launch_args, bounce_args
        # sbr_bounces' last-bounce test: the recorded triangles' own tree (recorded_tree),
        # or the scene's buffers and 0 where there is none
        self.last_filter_args = ([*recorded.bvh_buffers(), np.int32(1)] if recorded is not None
                                 else [*caster.bvh_buffers(), np.int32(0)])
        self.illuminate_args, self.radiate_args = illuminate_args, radiate_args
        # what a persistent build's sbr_radiate takes in place of sbr_illuminate's output
        (_, _, mat_f, _, win_f, win_i, blocks, tx_frame, _) = illuminate_args
        self.lit_inputs = [mat_f, win_f, win_i, blocks, tx_frame]
        self.tri_face = tri_face
        # the kernels that do not walk the BVH come from the same program as those that do
        program_defines = {**defines, **caster.kernel_defines()}
        self.launch_kernel = rt.kernel("sbr.cl", "sbr_launch", options, program_defines)
        self.illuminate_kernel = rt.kernel("sbr.cl", "sbr_illuminate", options,
                                           program_defines)
        self.reduce_kernel = rt.kernel("sbr.cl", "sbr_reduce", options, program_defines)
        cells = self.cells = BLOCK * BLOCK
        self.launch_local = rt.local_size(self.launch_kernel, caster.LOCAL_SIZE)
        self.illuminate_local = rt.local_size(self.illuminate_kernel, caster.LOCAL_SIZE)
        self.reduce_local = rt.require_local_size(self.reduce_kernel, cells,
                                                  "sbr_reduce (sbr.cl)")
        # the reduction's local memory: faces (cells x slots), keys and leaders
        need = 4 * cells * (tri_slots(defines["SBR_MAX_BOUNCES"]) + 2)
        have = int(rt.device.local_mem_size)
        if need > have:
            raise OpenCLError(f"kernel sbr_reduce (sbr.cl) needs {need} bytes of local "
                              f"memory and {rt.info.label} has {have}; use fewer bounces "
                              f"or another device")
        _, tube_bytes, footprint_bytes, lit_bytes, contribution_bytes = (
            int(x) for x in _struct_sizes(rt, options, program_defines))
        max_bounces = int(defines["SBR_MAX_BOUNCES"])
        # the build decides: sbr_bounces exists only in a program built for it
        self.persistent = bool(defines.get("SBR_PERSISTENT"))
        # per tube: two queues, a footprint and its illumination (persistent: no queue, a
        # footprint per bounce, its illumination computed where it radiates), per receiver
        # a contribution and its footprint
        per_tube = ((max_bounces * footprint_bytes) if self.persistent
                    else (2 * tube_bytes + footprint_bytes + lit_bytes))
        per_tube += n_rx * (contribution_bytes + 4)
        self.blocks_per_batch = _batch_tubes(rt, per_tube, batch_tubes, n_rx) // cells
        n = min(self.blocks_per_batch, n_blocks) * cells
        empty = rt.empty
        if self.persistent:
            self.bounces_kernel = rt.kernel("sbr.cl", "sbr_bounces", options, program_defines)
            # bounce m's footprints in region m - 1, each region starting on the device's
            # sub-buffer alignment
            align = max(1, int(rt.device.mem_base_addr_align) // 8)
            step = align // math.gcd(align, footprint_bytes)
            self.region = -(-n // step) * step
            region_bytes = self.region * footprint_bytes
            self.footprint_area = empty(max_bounces * region_bytes)
            self.footprint_regions = [
                self.footprint_area.get_sub_region(m * region_bytes, region_bytes)
                for m in range(max_bounces)]
            self.bounce_counts = empty(4 * max_bounces)
        else:
            self.queues = [empty(n * tube_bytes), empty(n * tube_bytes)]
            self.footprints = empty(n * footprint_bytes)
            # a bounce's two counts (next tubes, footprints) in one buffer: one read
            self.bounce_counts = empty(8)
            self.lit = empty(n * lit_bytes)
        self.contributions = empty(n * n_rx * contribution_bytes)
        self.contribution_footprint = empty(n * n_rx * 4)
        # per (block, receiver): its contributions at a bounce; those with any, listed
        self.group_tubes = empty(n // cells * n_rx * 4)
        self.live_groups = empty(n // cells * n_rx * 4)
        # room for a few records per block and receiver: more grow it and reduce again
        self.capacity = int(np.clip(RECORDS_PER_BLOCK_RX * max(1, n_rx) * (n // cells),
                                    1 << 14, MAX_START_RECORDS))
        self.records = empty(self.capacity * dtype.itemsize)
        # the counters: tubes queued, groups, records
        self.n_queued, self.n_groups, self.n_records = (empty(4) for _ in range(3))

    def _zero(self, *bufs):
        # a fill, not a blocking host copy: the queue is not drained for a counter
        for b in bufs:
            self.rt.fill(b, np.int32(0), 4)

    def _read(self, buf) -> int:
        out = np.zeros(1, np.int32)
        self.cl.enqueue_copy(self.rt.queue, out, buf, is_blocking=True)
        return int(out[0])

    def _run(self, kernel, global_size, local_size, *args, name, wait=True):
        """A kernel that does not walk the BVH, timed as the caster's are; ``wait=False``
        leaves it in the in-order queue for the next launch (its time then counts in the
        next waited block)."""
        rt = self.rt
        with rt.kernel_clock():
            rt.launch(kernel, global_size, local_size, *args, name=name, wait=wait)

    def _run_bvh(self, kernel_name, global_size, *args, local_size=None):
        self.caster.run_kernel("sbr.cl", kernel_name, global_size, *args,
                               defines=self.defines, options=self.options,
                               local_size=local_size)

    def shoot(self, first: int, n_blocks: int, max_bounces: int, first_bounce: int):
        """The records of blocks first .. first + n_blocks - 1 (a list of arrays)."""
        out = []
        if self.persistent:
            n_fps = self._bounces(first, n_blocks, first_bounce, max_bounces)
            for m, n_fp in enumerate(n_fps, start=1):
                if n_fp:
                    out += self._radiate_bounce(m, n_fp, first, n_blocks,
                                                self.footprint_regions[m - 1])
            return out
        n_live = self._launch(first, n_blocks)
        for m in range(1, max_bounces + 1):
            if n_live == 0:
                break
            n_next, n_fp = self._bounce(m, n_live, first_bounce, max_bounces)
            if n_fp:
                out += self._radiate_bounce(m, n_fp, first, n_blocks, self.footprints)
            self.queues.reverse()
            n_live = n_next
        return out

    def _radiate_bounce(self, m: int, n_fp: int, first: int, n_blocks: int,
                        footprints) -> list:
        """Bounce m's records from its n_fp ``footprints``: illumination (persistent: in
        sbr_radiate, for the footprints that see a receiver), radiation toward every
        receiver, reduction."""
        if not self.persistent:
            self._illuminate(m, n_fp, first, footprints)
        n_groups = self._radiate(m, n_fp, first, n_blocks, footprints)
        return [self._reduce(m, n_groups, first, footprints)] if n_groups else []

    def _launch(self, first: int, n_blocks: int) -> int:
        with self.rt.guard("SBR tube launch"):
            self._zero(self.n_queued)
            self._run(self.launch_kernel, n_blocks * self.cells, self.launch_local,
                      *self.launch_args, np.int64(first), np.int32(n_blocks * self.cells),
                      self.queues[0], self.n_queued, name="sbr_launch (sbr.cl)")
            return self._read(self.n_queued)

    def _bounce(self, m: int, n_live: int, first_bounce: int, max_bounces: int):
        counts = np.zeros(2, np.int32)
        self.rt.fill(self.bounce_counts, np.int32(0), counts.nbytes)
        self._run_bvh("sbr_bounce", n_live, *self.bounce_args, np.int32(m),
                      np.int32(first_bounce), np.int32(max_bounces), self.queues[0],
                      np.int32(n_live), self.queues[1], self.footprints, self.bounce_counts)
        with self.rt.guard("SBR bounce counts"):
            self.cl.enqueue_copy(self.rt.queue, counts, self.bounce_counts, is_blocking=True)
        return int(counts[0]), int(counts[1])

    def _bounces(self, first: int, n_blocks: int, first_bounce: int,
                 max_bounces: int) -> list[int]:
        """The tubes of blocks first .. first + n_blocks - 1 launched and taken through
        every bounce in one launch (sbr_bounces, no queue, one work item per block whose
        tubes are cast in packets): the footprints per bounce, in
        :attr:`footprint_regions`."""
        counts = np.zeros(max_bounces, np.int32)
        self.rt.fill(self.bounce_counts, np.int32(0), counts.nbytes)
        self._run_bvh("sbr_bounces", n_blocks, *self.bounce_args, self.tri_face,
                      *self.launch_args, np.int64(first), np.int32(n_blocks),
                      np.int32(first_bounce), np.int32(max_bounces), self.footprint_area,
                      np.int32(self.region), self.bounce_counts, *self.last_filter_args,
                      local_size=BLOCKS_PER_GROUP)
        with self.rt.guard("SBR bounce counts"):
            self.cl.enqueue_copy(self.rt.queue, counts, self.bounce_counts, is_blocking=True)
        return [int(c) for c in counts]

    def _illuminate(self, m: int, n_fp: int, first: int, footprints):
        with self.rt.guard("SBR illumination"):
            self._run(self.illuminate_kernel, n_fp, self.illuminate_local,
                      *self.illuminate_args, np.int64(first), np.int32(m), footprints,
                      np.int32(n_fp), self.lit, name="sbr_illuminate (sbr.cl)",
                      wait=False)  # sbr_radiate, next in the queue, waits for it

    def _radiate(self, m: int, n_fp: int, first: int, n_blocks: int, footprints) -> int:
        slots = n_blocks * self.n_rx
        self.rt.fill(self.contribution_footprint, np.int32(-1), slots * self.cells * 4)
        self.rt.fill(self.group_tubes, np.int32(0), slots * 4)
        self._zero(self.n_groups)
        lit = ([*self.lit_inputs, np.int64(first)] if self.persistent else [self.lit])
        # a persistent build radiates a footprint toward every receiver in one work item
        items = n_fp if self.persistent else n_fp * self.n_rx
        self._run_bvh("sbr_radiate", items, *self.radiate_args, np.int32(m),
                      footprints, *lit, np.int32(n_fp), self.contributions,
                      self.contribution_footprint, self.group_tubes, self.live_groups,
                      self.n_groups)
        with self.rt.guard("SBR group count"):
            return self._read(self.n_groups)

    def _reduce(self, m: int, n_groups: int, first: int, footprints) -> np.ndarray:
        rt = self.rt
        while True:
            with rt.guard("SBR reduction"):
                self._zero(self.n_records)
                self._run(self.reduce_kernel, n_groups * self.cells, self.reduce_local,
                          self.tri_face, footprints, self.contributions,
                          self.contribution_footprint, self.live_groups, np.int32(m),
                          np.int32(self.n_rx), np.int64(first), self.records,
                          self.n_records, np.int32(self.capacity), name="sbr_reduce (sbr.cl)")
                n = self._read(self.n_records)
            if n <= self.capacity:
                break
            # more records than the buffer holds: grow it and reduce this bounce again
            self.capacity = max(n, 2 * self.capacity)
            self.records = rt.empty(self.capacity * self.dtype.itemsize)
        rec = np.empty(n, dtype=self.dtype)
        if n:
            with rt.guard("SBR records"):
                self.cl.enqueue_copy(rt.queue, rec, self.records, is_blocking=True)
        return rec


#: Implementations whose CPU device runs a work item as scalar code: there the SBR tubes
#: go through all their bounces in one launch (sbr_bounces), not one launch per bounce
PERSISTENT_BOUNCE_VENDORS = ("pocl",)


def persistent_bounces(rt) -> bool:
    """Whether ``rt``'s SBR tubes bounce in one launch (a scalar CPU device) rather than
    as a wavefront, one launch per bounce with the live tubes compacted between (SIMD
    and SIMT devices, where tubes that end early would idle their lanes)."""
    return rt.info.device_type == "CPU" and rt.info.vendor in PERSISTENT_BOUNCE_VENDORS


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

    The tubes go through the wavefront of kernels/sbr.cl a batch of blocks at a time (at
    most ``batch_tubes`` tubes, fewer where the device's memory asks): launch, then per
    bounce the closest hits of the live tubes, the footprints' radiation per receiver and
    its reduction per (block, receiver) in work groups.
    """
    rt = caster.runtime
    precision = engine_precision(rt, precision)
    fp64 = precision == "fp64"
    receivers = np.ascontiguousarray(np.asarray(receivers, np.float64).reshape(-1, 3))
    n_rx = len(receivers)
    if n_rx >= 2**15:
        raise ArgumentError("at most 32767 receivers per transmitter", argument="receivers",
                            value=n_rx)
    dtype = record_dtype(max_bounces, precision)
    real = np.float64 if fp64 else np.float32
    mat_f, mat_i = material_tables(scene)
    win_f, win_i, blocks = _windows(windows)
    near_first, near_tri = near_triangles(caster, receivers)

    def dev(a, dtype):
        a = np.ascontiguousarray(a, dtype=dtype)
        return rt.to_device(a if a.size else np.zeros(1, dtype))

    def precise(a):
        """float64 positions and lengths as the build reads them: doubles, or pairs"""
        a = np.asarray(a, np.float64).reshape(-1)
        return dev(a, np.float64) if fp64 else dev(split_pairs(a), np.float32)

    if fp64:
        data64 = caster.scene_data64()
        tri_v, tri_n = data64["vertices"], data64["normals"]
    else:
        tri_v, tri_n = precise(caster.triangles), precise(caster.normals64())
    tri_material = dev(scene.tri_material, np.int32)
    materials = [dev(mat_f, real), dev(mat_i, np.int32)]
    tx_and_k = precise(np.append(np.asarray(windows.tx, np.float64), float(wavenumber)))
    radiate_args = [tri_v, tri_n, tri_material, materials[1], precise(receivers),
                    dev(np.asarray(rx_frames, np.float64).reshape(-1, 9), real), tx_and_k,
                    dev(near_first, np.int32), dev(near_tri, np.int32)]
    if precision != CONTROL_PRECISION:
        # the face tables of the float64 sight rounds (kernels/scene64.h): the faces'
        # boxes and the two scalars as this build reads float64 (doubles, or pairs even
        # on a runtime with fp64, when double-float is forced)
        tables = scene64_args(caster, tri_face)
        n_faces = int(tables[7])
        box = face_boxes(caster.triangles, tri_face, n_faces)
        radiate_args += [*tables[2:6], precise(box), np.int32(n_faces),
                         np.int32(RESCUE_ROUNDS), _scalar64(LOOK_PAST, fp64),
                         _scalar64(1.0 - SIGHT_STOP, fp64)]
    radiate_args += [real(ON_FACE_TOL_REL), real(INSIDE_TOL_REL), real(CONFIRM_TOL_M),
                     np.int32(n_rx), real(wavelength), np.float32(1.0 - SIGHT_STOP)]
    window_bufs = [dev(win_f, real), dev(win_i, np.int32), dev(blocks, np.int32)]
    persistent = persistent_bounces(rt)
    wave = _Wavefront(
        caster, {**_defines(max_bounces, precision),
                 **({"SBR_PERSISTENT": 1} if persistent else {})},
        _options(precision), dtype, n_rx,
        len(blocks), batch_tubes,
        launch_args=[*window_bufs[:2], dev(windows.masks, np.uint8), window_bufs[2],
                     *(dev(a, np.int32) for a in _overlap_lists(windows.n_windows, earlier)),
                     tx_and_k],
        bounce_args=[tri_v, tri_n, dev(record_triangles, np.uint8)],
        illuminate_args=[tri_n, tri_material, *materials, *window_bufs,
                         dev(np.asarray(tx_frame, np.float64).reshape(9), real), tx_and_k],
        radiate_args=radiate_args, tri_face=dev(tri_face, np.int32),
        recorded=recorded_tree(caster, record_triangles) if persistent else None)
    parts = []
    for first in range(0, len(blocks), wave.blocks_per_batch):
        parts += wave.shoot(first, min(wave.blocks_per_batch, len(blocks) - first),
                            max_bounces, first_bounce)
    rec = _in_host_order(np.concatenate(parts) if parts else np.zeros(0, dtype=dtype))
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


def _scalar64(x: float, fp64: bool):
    """A ``pr_elem`` kernel argument of a build in fp64 (a double) or double-float (a
    float2 (hi, lo) pair), whatever the runtime's own mode."""
    if fp64:
        return np.float64(x)
    from pyopencl import cltypes

    hi, lo = split_pairs(float(x))
    return cltypes.make_float2(hi, lo)


def _in_host_order(rec: np.ndarray) -> np.ndarray:
    """Records sorted by block, then by their groups' first (cell, bounce, receiver)
    (the kernel's ``ordinal`` key), which becomes the rank within the block."""
    if len(rec) == 0:
        return rec
    cells = BLOCK * BLOCK
    block = rec["tube"] // cells
    rec = rec[np.lexsort((rec["ordinal"], block))]
    block = rec["tube"] // cells
    start = np.flatnonzero(np.diff(block, prepend=-1))
    rec["ordinal"] = np.arange(len(rec)) - np.repeat(start, np.diff(start, append=len(rec)))
    return rec
