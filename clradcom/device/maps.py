"""Ray segments into the cells of a measurement slab on the device (kernels/maps.cl).

:func:`accumulate_segments` is the one device stage of a radio map
(:mod:`clradcom.maps`): each segment's weight per metre times the length it runs inside
each cell's box is added to that cell (the track-length estimator, docs/maps.md), with
float sums by 32-bit compare-and-swap, so a device without 64-bit atomics runs it.
:func:`accumulate_segments_host` is the numpy reference it is tested against.
:func:`segment_cells` walks the same cells and returns each segment's length in each
cell apart, for the coherent sum, whose phases the host weighs in float64.
:func:`po_facet_fields` evaluates PEC facets' physical-optics fields at points (the cell
centres), without the carrier phase, which the host adds in float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError

__all__ = ["Slab", "accumulate_segments", "accumulate_segments_host", "po_facet_fields",
           "segment_cells"]

SOURCE = "maps.cl"


@dataclass(frozen=True)
class Slab:
    """The measurement volume: nx x ny cells of cell_x x cell_y m from the corner
    (x0, y0), between heights z_lo and z_hi (m, world)."""

    x0: float
    y0: float
    cell_x: float
    cell_y: float
    nx: int
    ny: int
    z_lo: float
    z_hi: float

    def __post_init__(self):
        for name in ("x0", "y0", "cell_x", "cell_y", "z_lo", "z_hi"):
            value = getattr(self, name)
            if not np.isfinite(value):
                raise ArgumentError("must be finite", argument=f"Slab.{name}", value=value)
        if not (self.cell_x > 0 and self.cell_y > 0):
            raise ArgumentError("cells must be larger than 0 m", argument="Slab.cell",
                                value=(self.cell_x, self.cell_y))
        if not (self.nx >= 1 and self.ny >= 1):
            raise ArgumentError("needs at least one cell each way", argument="Slab.cells",
                                value=(self.nx, self.ny))
        if not self.z_hi > self.z_lo:
            raise ArgumentError("z_hi must lie above z_lo", argument="Slab.z",
                                value=(self.z_lo, self.z_hi))

    @property
    def cell_volume(self) -> float:
        return self.cell_x * self.cell_y * (self.z_hi - self.z_lo)


def _relative(slab: Slab, origins, directions, lengths):
    """Float32 rows relative to the slab's corner (x0, y0, z_lo): the kernel's inputs."""
    o = np.zeros((len(origins), 4), dtype=np.float32)
    o[:, 0] = np.asarray(origins[:, 0], np.float64) - slab.x0
    o[:, 1] = np.asarray(origins[:, 1], np.float64) - slab.y0
    o[:, 2] = np.asarray(origins[:, 2], np.float64) - slab.z_lo
    d = np.zeros((len(origins), 4), dtype=np.float32)
    d[:, :3] = directions
    # a miss runs to the end of the scene: 1e30 m stays finite in float32
    d[:, 3] = np.minimum(np.asarray(lengths, np.float64), 1e30)
    return o, d


def accumulate_segments(runtime, slab: Slab, origins, directions, lengths, weights,
                        power=None, count=None, batch: int = 1 << 20):
    """Add ray segments into the slab's cells on ``runtime``'s device.

    ``origins`` (S, 3) and unit ``directions`` (S, 3) world float64, ``lengths`` (S,) m
    (inf: the ray escapes), ``weights`` (S,) >= 0 per metre inside a cell. Returns
    ``(power, count)``: (ny, nx) float64 sums of weight x length inside each cell and
    int64 numbers of segments through it, added to ``power``/``count`` when given.
    Weights are scaled to the batch's largest before the float32 sums and back after, so
    no dynamic range is lost to float32's exponent."""
    import pyopencl as cl

    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    lengths = np.asarray(lengths, dtype=np.float64).reshape(-1)
    weights = np.asarray(weights, dtype=np.float64).reshape(-1)
    if not (len(directions) == len(lengths) == len(weights) == len(origins)):
        raise ArgumentError("origins, directions, lengths and weights must have one row "
                            "per segment", argument="segments",
                            value=(len(origins), len(directions), len(lengths), len(weights)))
    if np.any(~np.isfinite(weights)) or np.any(weights < 0):
        raise ArgumentError("weights must be finite and >= 0", argument="weights",
                            value=weights[~(np.isfinite(weights) & (weights >= 0))][:1])
    shape = (slab.ny, slab.nx)
    power = np.zeros(shape) if power is None else power
    count = np.zeros(shape, dtype=np.int64) if count is None else count
    kernel = runtime.kernel(SOURCE, "accumulate_segments")
    local = runtime.local_size(kernel)
    for start in range(0, len(origins), batch):
        stop = min(start + batch, len(origins))
        w = weights[start:stop]
        scale = float(w.max(initial=0.0))
        if scale == 0.0:
            continue
        o, d = _relative(slab, origins[start:stop], directions[start:stop],
                         lengths[start:stop])
        sums = np.zeros(shape, dtype=np.float32)
        hits = np.zeros(shape, dtype=np.int32)
        mf = cl.mem_flags
        with runtime.kernel_clock(), runtime.guard("radio map accumulation"):
            sums_buf = cl.Buffer(runtime.context, mf.READ_WRITE | mf.COPY_HOST_PTR,
                                 hostbuf=sums)
            hits_buf = cl.Buffer(runtime.context, mf.READ_WRITE | mf.COPY_HOST_PTR,
                                 hostbuf=hits)
            runtime.launch(kernel, len(o), local, runtime.to_device(o),
                           runtime.to_device(d),
                           runtime.to_device((w / scale).astype(np.float32)),
                           np.float32(0.0), np.float32(slab.z_hi - slab.z_lo),
                           np.float32(slab.cell_x), np.float32(slab.cell_y),
                           np.int32(slab.nx), np.int32(slab.ny), np.int32(len(o)),
                           sums_buf, hits_buf, name="accumulate_segments")
            cl.enqueue_copy(runtime.queue, sums, sums_buf)
            cl.enqueue_copy(runtime.queue, hits, hits_buf, is_blocking=True)
        power += sums.astype(np.float64) * scale
        count += hits
    return power, count


def segment_cells(runtime, slab: Slab, origins, directions, lengths,
                  capacity: int | None = None):
    """The cells each segment crosses, walked as :func:`accumulate_segments` walks them:
    ``(segment, cell, length)`` int64 segment rows, int64 flat cell indices
    (iy * nx + ix) and float64 lengths (m) inside the cell's box, one record per segment
    and cell, in the device's order. ``capacity`` (records) is a first guess; a batch that
    needs more is run again with room for all."""
    import pyopencl as cl

    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    lengths = np.asarray(lengths, dtype=np.float64).reshape(-1)
    if not (len(directions) == len(lengths) == len(origins)):
        raise ArgumentError("origins, directions and lengths must have one row per "
                            "segment", argument="segments",
                            value=(len(origins), len(directions), len(lengths)))
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if not len(origins):
        return empty
    kernel = runtime.kernel(SOURCE, "segment_cells")
    local = runtime.local_size(kernel)
    o, d = _relative(slab, origins, directions, lengths)
    capacity = int(capacity or 4 * len(o))
    mf = cl.mem_flags
    while True:
        n_records = np.zeros(1, dtype=np.int32)
        with runtime.kernel_clock(), runtime.guard("radio map cells of segments"):
            bufs = [cl.Buffer(runtime.context, mf.WRITE_ONLY, size=4 * capacity)
                    for _ in range(3)]
            n_buf = cl.Buffer(runtime.context, mf.READ_WRITE | mf.COPY_HOST_PTR,
                              hostbuf=n_records)
            runtime.launch(kernel, len(o), local, runtime.to_device(o), runtime.to_device(d),
                           np.float32(0.0), np.float32(slab.z_hi - slab.z_lo),
                           np.float32(slab.cell_x), np.float32(slab.cell_y),
                           np.int32(slab.nx), np.int32(slab.ny), np.int32(len(o)), *bufs,
                           n_buf, np.int32(capacity), name="segment_cells")
            cl.enqueue_copy(runtime.queue, n_records, n_buf, is_blocking=True)
            total = int(n_records[0])
            if total > capacity:
                capacity = total
                continue
            seg = np.empty(total, np.int32)
            cell = np.empty(total, np.int32)
            length = np.empty(total, np.float32)
            if total:
                for host, buf in zip((seg, cell, length), bufs, strict=True):
                    cl.enqueue_copy(runtime.queue, host, buf, is_blocking=False)
                runtime.queue.finish()
        return seg.astype(np.int64), cell.astype(np.int64), length.astype(np.float64)


def po_facet_fields(runtime, corner, vertices, normals, e_tx, source, points,
                    wavenumber: float, batch: int = 1 << 18, centroids=None) -> np.ndarray:
    """(S, 3) complex: the PO field of PEC facet-point pairs on the device, F with the
    field at the point (lambda / 4 pi) e^{-jkL} F (kernels/maps.cl po_facet_fields;
    :func:`clradcom.physics.po.po_transfer` times ``e_tx`` over L without e^{-jkL}).
    ``vertices`` (S, 3, 3), lit-side unit ``normals`` (S, 3), the transmitter's field
    ``e_tx`` (S, 3) complex at the facet, ``source`` (3,) the transmitter, ``points``
    (S, 3), all world float64 (``centroids`` (S, 3) the vertices' means, when known),
    sent relative to ``corner`` (3,): in double where the
    device has fp64 (a far sidelobe is a small difference of large edge terms), else in
    float32 (1e-3 of such a lobe)."""
    import pyopencl as cl

    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3, 3)
    count = len(vertices)
    out = np.zeros((count, 3), dtype=np.complex128)
    if not count:
        return out
    corner = np.asarray(corner, dtype=np.float64)
    double = bool(runtime.info.has_double)
    real = np.float64 if double else np.float32
    kernel = runtime.kernel(SOURCE, "po_facet_fields",
                            defines={"PO_DOUBLE": 1} if double else None)
    local = runtime.local_size(kernel)
    src = np.zeros(4, dtype=real)
    src[:3] = np.asarray(source, dtype=np.float64) - corner
    src[3] = wavenumber
    e_tx = np.asarray(e_tx, dtype=np.complex128)
    for start in range(0, count, batch):
        stop = min(start + batch, count)
        v = vertices[start:stop]
        centroid = v.mean(axis=1) if centroids is None else centroids[start:stop]
        rows = np.empty((stop - start, 21), dtype=real)
        rows[:, :9] = (v - centroid[:, None, :]).reshape(-1, 9)
        rows[:, 9:12] = centroid - corner
        rows[:, 12:15] = normals[start:stop]
        rows[:, 15:18] = e_tx[start:stop].real
        rows[:, 18:21] = e_tx[start:stop].imag
        pts = np.zeros((stop - start, 4), dtype=real)
        pts[:, :3] = np.asarray(points[start:stop], dtype=np.float64) - corner
        field = np.empty((stop - start, 6), dtype=real)
        with runtime.kernel_clock(), runtime.guard("radio map PO facets"):
            buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, size=field.nbytes)
            runtime.launch(kernel, stop - start, local, runtime.to_device(rows),
                           runtime.to_device(pts), src, np.int32(stop - start), buf,
                           name="po_facet_fields")
            cl.enqueue_copy(runtime.queue, field, buf, is_blocking=True)
        out[start:stop] = field[:, :3] + 1j * field[:, 3:]
    return out


def accumulate_segments_host(slab: Slab, origins, directions, lengths, weights):
    """The numpy reference of :func:`accumulate_segments` (float64, one segment at a
    time: for tests on a few hundred segments). Each segment is clipped to the slab and
    cut at every cell boundary it crosses, its pieces' lengths added to their cells."""
    shape = (slab.ny, slab.nx)
    power = np.zeros(shape)
    count = np.zeros(shape, dtype=np.int64)
    lo = np.array([slab.x0, slab.y0, slab.z_lo])
    hi = np.array([slab.x0 + slab.nx * slab.cell_x, slab.y0 + slab.ny * slab.cell_y,
                   slab.z_hi])
    for o, d, length, w in zip(np.asarray(origins, float), np.asarray(directions, float),
                               np.asarray(lengths, float), np.asarray(weights, float),
                               strict=True):
        if w <= 0:
            continue
        t0, t1 = 0.0, min(length, 1e30)
        empty = False
        for axis in range(3):
            if d[axis] == 0.0:
                empty |= not lo[axis] <= o[axis] <= hi[axis]
                continue
            a, b = (lo[axis] - o[axis]) / d[axis], (hi[axis] - o[axis]) / d[axis]
            t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
        if empty or not t0 < t1:
            continue
        cuts = [t0, t1]
        for axis, size, n, base in ((0, slab.cell_x, slab.nx, slab.x0),
                                    (1, slab.cell_y, slab.ny, slab.y0)):
            if d[axis] == 0.0:
                continue
            planes = base + size * np.arange(1, n)
            t = (planes - o[axis]) / d[axis]
            cuts.extend(t[(t > t0) & (t < t1)].tolist())
        cuts = np.unique(cuts)
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            mid = o + 0.5 * (a + b) * d
            ix = min(max(int(np.floor((mid[0] - slab.x0) / slab.cell_x)), 0), slab.nx - 1)
            iy = min(max(int(np.floor((mid[1] - slab.y0) / slab.cell_y)), 0), slab.ny - 1)
            power[iy, ix] += w * (b - a)
            count[iy, ix] += 1
    return power, count
