"""Ray segments into the cells of a measurement slab on the device (kernels/maps.cl).

:func:`accumulate_segments` is the one device stage of a radio map
(:mod:`clradcom.maps`): each segment's weight per metre times the length it runs inside
each cell's box is added to that cell (the track-length estimator, docs/maps.md), with
float sums by 32-bit compare-and-swap, so a device without 64-bit atomics runs it.
:func:`accumulate_segments_host` is the numpy reference it is tested against.
:func:`segment_cells` walks the same cells and returns each segment's length in each
cell apart, for the coherent sum, whose phases the host weighs in float64.
:func:`po_facet_fields` evaluates PEC facets' physical-optics fields at points (the cell
centres), without the carrier phase, which the host adds in float64. :func:`po_pairs`
finds a map's PO facet-cell pairs and their fields in one launch per round of facets
(kernels/maps_po.cl: lit side, the receiver's sector, the sight cast, the field).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError

__all__ = ["PO_FACET_ROWS", "Slab", "accumulate_rows", "accumulate_segments",
           "accumulate_segments_host", "accumulation_copies", "po_facet_fields", "po_pairs",
           "segment_cells"]

SOURCE = "maps.cl"
PO_SOURCE = "maps_po.cl"
#: Numbers per facet in kernels/maps_po.cl's facet table (-D PO_FACET_ROWS)
PO_FACET_ROWS = 28


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
                        power=None, count=None, square=None, batch: int = 1 << 20):
    """Add ray segments into the slab's cells on ``runtime``'s device.

    ``origins`` (S, 3) and unit ``directions`` (S, 3) world float64, ``lengths`` (S,) m
    (inf: the ray escapes), ``weights`` (S,) >= 0 per metre inside a cell. Returns
    ``(power, count, square)``: (ny, nx) float64 sums of weight x length inside each
    cell, int64 numbers of segments through it and float64 sums of the squares of the
    weight x length terms, added to ``power``/``count``/``square`` when given.
    Weights are scaled to the batch's largest before the float32 sums and back after, so
    no dynamic range is lost to float32's exponent."""
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
    square = np.zeros(shape) if square is None else square
    for start in range(0, len(origins), batch):
        stop = min(start + batch, len(origins))
        w = weights[start:stop]
        if not w.max(initial=0.0) > 0.0:
            continue
        o, d = _relative(slab, origins[start:stop], directions[start:stop],
                         lengths[start:stop])
        accumulate_rows(runtime, slab, runtime.to_device(o), runtime.to_device(d), len(o),
                        w, power, count, square)
    return power, count, square


#: copies of a slab's sums that the accumulation's work groups add into in turn (group id
#: modulo the copies), so that the cores do not share the cells' cache lines near the
#: transmitter, where every ray of a batch passes: at most 16, and at most
#: :data:`COPY_CELLS` cells in all of them
ACCUMULATION_COPIES = 16
COPY_CELLS = 1 << 22


def accumulation_copies(n_cells: int) -> int:
    """The copies of ``n_cells`` cells' sums one accumulation launch adds into."""
    return max(1, min(ACCUMULATION_COPIES, COPY_CELLS // max(int(n_cells), 1)))


def accumulate_rows(runtime, slab: Slab, origins, directions, n: int, weights, power,
                    count, square) -> None:
    """kernels/maps.cl's accumulate_segments over ``n`` segments already on the device:
    ``origins``, ``directions`` float4 buffers as :func:`_relative` lays them out (origin
    relative to the slab's corner; unit direction and length), ``weights`` (n,) float64
    per metre, added into ``power`` (ny, nx) float64, ``count`` (int64) and ``square``
    (float64, the terms' squares). The weights are scaled to their largest before the
    float32 sums and back after, so no dynamic range is lost to float32's exponent (a
    square underflows only for a term 190 dB under the batch's largest); the work groups'
    copies of the sums (:func:`accumulation_copies`) are added up in float64."""
    import pyopencl as cl

    weights = np.asarray(weights, dtype=np.float64)
    scale = float(weights.max(initial=0.0))
    if n == 0 or scale == 0.0:
        return
    shape = (slab.ny, slab.nx)
    copies = accumulation_copies(slab.nx * slab.ny)
    sums = np.zeros((copies, *shape), dtype=np.float32)
    squares = np.zeros((copies, *shape), dtype=np.float32)
    hits = np.zeros((copies, *shape), dtype=np.int32)
    kernel = runtime.kernel(SOURCE, "accumulate_segments")
    mf = cl.mem_flags
    with runtime.kernel_clock(), runtime.guard("radio map accumulation"):
        sums_buf = cl.Buffer(runtime.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=sums)
        squares_buf = cl.Buffer(runtime.context, mf.READ_WRITE | mf.COPY_HOST_PTR,
                                hostbuf=squares)
        hits_buf = cl.Buffer(runtime.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=hits)
        runtime.launch(kernel, n, runtime.local_size(kernel), origins, directions,
                       runtime.to_device((weights / scale).astype(np.float32)),
                       np.float32(0.0), np.float32(slab.z_hi - slab.z_lo),
                       np.float32(slab.cell_x), np.float32(slab.cell_y), np.int32(slab.nx),
                       np.int32(slab.ny), np.int32(n), np.int32(copies), sums_buf,
                       squares_buf, hits_buf, name="accumulate_segments")
        cl.enqueue_copy(runtime.queue, sums, sums_buf)
        cl.enqueue_copy(runtime.queue, squares, squares_buf)
        cl.enqueue_copy(runtime.queue, hits, hits_buf, is_blocking=True)
    power += sums.sum(axis=0, dtype=np.float64) * scale
    square += squares.sum(axis=0, dtype=np.float64) * (scale * scale)
    count += hits.sum(axis=0, dtype=np.int64)


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


def po_pairs(caster, corner, wavenumber: float, source, vertices, centroids, normals, e_tx,
             origins, reach, from_tx, prims, pec, centres, rx_rotation=None,
             rx_bounds=None, sight_tmax: float = 1.0 - 1e-6, capacity: int = 1 << 16,
             pairs_per_launch: int = 1 << 22):
    """A radio map's PO facet-cell pairs on ``caster``'s device, every facet against every
    centre, the pairs made, tested and weighed in one launch each (kernels/maps_po.cl;
    a launch takes up to ``pairs_per_launch`` of them in facet-major order and returns
    at most ``capacity``; the next starts after the last pair whose turn came before
    its list was full): the pairs with the
    centre on the facet's lit side, the arrival inside ``rx_bounds`` (the cosine of the
    largest |azimuth|, the largest |z| and the least x of the arrival direction in the
    receiver's frame ``rx_rotation``, local = world @ R; None: no receiver), and nothing
    between them (the float32 cast from ``origins``, the facets' centroids pushed off
    them, to the centre, up to ``sight_tmax``, the facet's triangle ``prims`` ignored).
    Yields per launch ``(facet, cell, whole, field)``: int64 facet rows and cell indices
    in ascending (facet, cell) order, bool ``whole`` where the device gave the field
    (PEC facets with neither end closer than ``reach`` (F,), ``from_tx`` (F,) the
    transmitter's distance), and the (P, 3) complex field without the carrier phase as
    :func:`po_facet_fields` gives it (zero where not ``whole``: the host weighs those).

    Facets: ``vertices`` (F, 3, 3), ``centroids`` (F, 3), lit-side unit ``normals``
    (F, 3), ``e_tx`` (F, 3) complex, ``origins`` (F, 3), ``pec`` (F,) bool; ``centres``
    (C, 3); all world float64, the field's positions sent about ``corner`` (3,), in
    double where the device has fp64."""
    import pyopencl as cl

    rt = caster.runtime
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    n_facets, n_cells = len(vertices), len(centres)
    if not n_facets or not n_cells:
        return
    if n_cells >= 1 << 31:
        raise ArgumentError("too many cells for one launch's int indices",
                            argument="centres", value=n_cells)
    double = bool(rt.info.has_double)
    real = np.float64 if double else np.float32
    corner = np.asarray(corner, dtype=np.float64)
    centroids = np.asarray(centroids, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    e_tx = np.asarray(e_tx, dtype=np.complex128)
    table = np.zeros((n_facets, PO_FACET_ROWS), dtype=real)
    table[:, :9] = (np.asarray(vertices, np.float64) - centroids[:, None, :]).reshape(-1, 9)
    table[:, 9:12] = centroids - corner
    table[:, 12:15] = normals
    table[:, 15:18] = e_tx.real
    table[:, 18:21] = e_tx.imag
    table[:, 21:24] = origins
    table[:, 24] = np.einsum("ij,ij->i", normals, centroids)
    table[:, 25] = reach
    table[:, 26] = from_tx
    ids = np.zeros((n_facets, 2), dtype=np.int32)
    ids[:, 0] = prims
    ids[:, 1] = np.asarray(pec, dtype=bool)
    points = np.zeros((n_cells, 4), dtype=real)
    points[:, :3] = centres
    corner4 = np.zeros(4, dtype=real)
    corner4[:3] = corner
    corner4[3] = wavenumber
    src = np.zeros(4, dtype=real)
    src[:3] = np.asarray(source, dtype=np.float64) - corner
    rx = np.zeros(12, dtype=real)
    if rx_rotation is not None:
        rx[:9] = np.asarray(rx_rotation, dtype=np.float64).reshape(9)
        rx[9:] = rx_bounds
    capacity = max(1, int(capacity))
    most = max(1, min(int(pairs_per_launch), (1 << 31) - 1))
    per_launch = most
    defines = {"PO_FACET_ROWS": PO_FACET_ROWS, **({"PO_DOUBLE": 1} if double else {})}
    with rt.guard("radio map PO pairs"):
        facet_buf = rt.to_device(table)
        id_buf = rt.to_device(ids)
        centre_buf = rt.to_device(points)
        rx_buf = rt.to_device(rx)
        pair_buf = cl.Buffer(rt.context, cl.mem_flags.WRITE_ONLY, size=4 * capacity)
        field_buf = cl.Buffer(rt.context, cl.mem_flags.WRITE_ONLY,
                              size=6 * np.dtype(real).itemsize * capacity)
        count_buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, size=4)
        resume_buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, size=4)
    start, n_pairs = 0, n_facets * n_cells
    while start < n_pairs:
        n = min(per_launch, n_pairs - start)
        found = np.zeros(1, dtype=np.int32)
        resume = np.array([n], dtype=np.int32)
        with rt.guard("radio map PO pairs"):
            cl.enqueue_copy(rt.queue, count_buf, found)
            cl.enqueue_copy(rt.queue, resume_buf, resume)
            caster.run_kernel(PO_SOURCE, "po_pairs", n, facet_buf, id_buf, centre_buf,
                              corner4, src, rx_buf, np.int32(rx_rotation is not None),
                              np.float32(sight_tmax), np.int64(start), np.int32(n),
                              np.int32(n_cells), pair_buf, field_buf, count_buf,
                              np.int32(capacity), resume_buf, defines=defines)
            cl.enqueue_copy(rt.queue, found, count_buf, is_blocking=False)
            cl.enqueue_copy(rt.queue, resume, resume_buf, is_blocking=True)
            total, done = min(int(found[0]), capacity), int(resume[0])
            pair = np.empty(total, dtype=np.int32)
            field = np.empty((total, 6), dtype=real)
            if total:
                cl.enqueue_copy(rt.queue, pair, pair_buf, is_blocking=False)
                cl.enqueue_copy(rt.queue, field, field_buf, is_blocking=True)
        # the next launch about twice what this one got through (those after a full
        # list did little but their tests); a launch of capacity pairs cannot fill it,
        # so every launch gets somewhere even where work-groups run in any order
        per_launch = max(capacity, min(most, 2 * done))
        if done == 0:
            continue
        whole = pair >= 0
        index = np.where(whole, pair, -1 - pair)
        keep = np.flatnonzero(index < done)
        order = keep[np.argsort(index[keep], kind="stable")]
        index = start + index[order].astype(np.int64)
        yield (index // n_cells, index % n_cells, whole[order],
               field[order, :3] + 1j * field[order, 3:])
        start += done


def accumulate_segments_host(slab: Slab, origins, directions, lengths, weights):
    """The numpy reference of :func:`accumulate_segments` (float64, one segment at a
    time: for tests on a few hundred segments). Each segment is clipped to the slab and
    cut at every cell boundary it crosses, its pieces' lengths added to their cells."""
    shape = (slab.ny, slab.nx)
    power = np.zeros(shape)
    count = np.zeros(shape, dtype=np.int64)
    square = np.zeros(shape)
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
            square[iy, ix] += (w * (b - a)) ** 2
            count[iy, ix] += 1
    return power, count, square
