"""The SBR launch windows made all at once (clradcom.mechanisms.sbr: _make_windows, with
the block rasters and the mirror clip cull in kernels/silhouette.cl on the device engine)
against the per-window loop they replaced: window by window its frame, grid and mask from
its own triangles, the mirror windows' clip triangles culled, clipped, rastered and
ANDed in turn. Both engines must give the loop's TubeWindows bit for bit; the kernels
must give their numpy twins' results bit for bit."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pyopencl as cl
import pytest
from mode_helpers import assert_points

from clradcom.device import silhouette as device_silhouette
from clradcom.device.precision import host_float64
from clradcom.geometry.silhouette import (
    BLOCK,
    block_coverage,
    cover_blocks_many,
    cover_xy_many,
    coverage_setup_many,
)
from clradcom.mechanisms import sbr
from clradcom.mechanisms.common import build_geometry
from clradcom.physics.vectors import orthonormal_frame
from clradcom.scene import load_scene

STREET = "scenes/street/street.toml"
RAIL = "scenes/guardrail/guardrail.toml"


def project(tri, eye, axis, u, v, D):
    """One window's central projection, dot products summed (x + y) + z."""
    rel = tri - eye
    dot = lambda a, b: (a[..., 0] * b[0] + a[..., 1] * b[1]) + a[..., 2] * b[2]  # noqa: E731
    depth = dot(rel, axis)
    return np.stack([D * dot(rel, u) / depth, D * dot(rel, v) / depth], axis=-1), depth


def window_loop(tx, centre, spacing, triangles, clip=None):
    """One window as the per-window code built it before the batch (commit 57135b8)."""
    rel = centre - tx
    D = float(np.linalg.norm(rel))
    if D == 0.0:
        return None
    axis = rel / D
    u, v = orthonormal_frame(axis)
    xy, depth = project(triangles, tx, axis, u, v, D)
    if len(xy) == 0 or depth.min() < sbr.MIN_DEPTH_FRACTION * D:
        return None
    # cells centred on half-integer multiples of the pitch since (sbr.TubeWindows)
    lo = np.floor(xy.reshape(-1, 2).min(axis=0) / spacing).astype(np.int64) - 1
    hi = np.floor(xy.reshape(-1, 2).max(axis=0) / spacing).astype(np.int64) + 1
    shape = -(-(hi - lo + 1) // BLOCK)
    origin = lo * spacing
    mask = block_coverage(xy, BLOCK * spacing, origin, shape)
    if clip is not None and mask.any():
        ij = np.argwhere(mask)
        rect_lo = origin + ij.min(axis=0) * (BLOCK * spacing)
        rect_hi = origin + (ij.max(axis=0) + 1) * (BLOCK * spacing)
        clip = clip[~sbr._beside(clip, tx, axis, u, v, D, rect_lo, rect_hi)]
        clip = sbr._clip_near(clip, tx, axis, sbr.MIN_DEPTH_FRACTION * D)
        mask &= block_coverage(project(clip, tx, axis, u, v, D)[0], BLOCK * spacing,
                               origin, shape)
    if not mask.any():
        return None
    return axis, u, v, D, lo, shape, mask


def launch_loop(geom, tx, objects, spacing):
    """launch_windows before the batch: the same candidates, one window at a time."""
    scene = geom.scene
    face_ids, face_n, face_d, face_lo, face_hi = sbr._mirror_faces(geom, objects, tx)
    direct, mirrored = [], []
    for o in objects:
        chunks, _ = sbr._chunks(scene.triangles[scene.tri_object == o], tx)
        for tris in chunks:
            c, r = sbr.bounding_sphere(tris)
            win = window_loop(tx, c, spacing, tris)
            if win is not None:
                direct.append((o, -1, win))
            h_c = face_n @ c - face_d
            c_img = c - 2.0 * h_c[:, None] * face_n
            h_tx = face_n @ tx - face_d
            with np.errstate(divide="ignore", invalid="ignore"):
                cross_at = tx + (h_tx / (h_tx + h_c))[:, None] * (c_img - tx)
            near = np.all((cross_at >= face_lo - r) & (cross_at <= face_hi + r), axis=1)
            near &= (h_c > 0) & (np.linalg.norm(c_img - tx, axis=1) > sbr.CHUNK_CLEARANCE * r)
            for f, n, d, ci in zip(face_ids[near], face_n[near], face_d[near], c_img[near],
                                   strict=True):
                h = (tris[..., 0] * n[0] + tris[..., 1] * n[1]) + tris[..., 2] * n[2]
                image = tris - 2.0 * (h - d)[..., None] * n
                win = window_loop(tx, ci, spacing, image,
                                  clip=scene.triangles[geom.faces.tri_face == f])
                if win is not None:
                    mirrored.append((o, int(f), win))
    wins = direct + mirrored
    blocks = [np.argwhere(w[2][6]) for w in wins]
    return dict(
        axis=np.array([w[2][0] for w in wins]), u=np.array([w[2][1] for w in wins]),
        v=np.array([w[2][2] for w in wins]), distance=np.array([w[2][3] for w in wins]),
        cell0=np.array([w[2][4] for w in wins]), shape=np.array([w[2][5] for w in wins]),
        masks=np.concatenate([w[2][6].ravel() for w in wins]).astype(np.uint8),
        mask_offset=np.cumsum([0] + [w[2][6].size for w in wins])[:-1],
        object_id=np.array([w[0] for w in wins]), mirror_face=np.array([w[1] for w in wins]),
        block_window=np.concatenate([np.full(len(b), i) for i, b in enumerate(blocks)]),
        block_i=np.concatenate([b[:, 0] for b in blocks]),
        block_j=np.concatenate([b[:, 1] for b in blocks]))


@pytest.mark.parametrize("path, spacing_wl", [(STREET, 1.0), (RAIL, 2.0)])
def test_windows_at_once_are_the_loops_bit_for_bit(runtime, path, spacing_wl):
    scene = load_scene(path)
    pec = [i for i, o in enumerate(scene.objects) if scene.material_pec[o.material]]
    cars = [i for i, o in enumerate(scene.objects) if o.name.startswith("car")]
    objects = np.array(cars or pec)
    spacing = spacing_wl * scene.wavelength_m
    tx = np.asarray(scene.radars[0].position, np.float64)
    geoms = {e: build_geometry(scene, runtime, engine=e) for e in ("host", "device")}
    want = launch_loop(geoms["host"], tx, objects, spacing)
    n_mirror = (want["mirror_face"] >= 0).sum()
    assert n_mirror > 0 and (want["mirror_face"] < 0).sum() > 0
    for engine, geom in geoms.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # carA holds radar A: triangles dropped
            got = sbr.launch_windows(geom, tx, objects, spacing)
        for key, value in want.items():
            np.testing.assert_array_equal(getattr(got, key), value, err_msg=f"{engine} {key}")
        assert np.all(got.spacing == spacing) and np.array_equal(got.tx, tx)


def test_clip_cull_kernel_is_numpys_bit_for_bit(runtime):
    """Several windows of different frames and rectangles over shared triangles, with
    triangles near the pyramid's planes: the device cull is beside_pairs' bit for bit,
    and beside_pairs is each window's _beside."""
    rng = np.random.default_rng(21)
    tri = rng.normal(size=(900, 3, 3)) * [4.0, 4.0, 6.0] + [0.0, 0.0, 8.0]
    eye = np.array([0.1, -0.2, 0.05])
    axes = rng.normal(size=(5, 3)) * 0.2 + [0.0, 0.0, 1.0]
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    u, v = orthonormal_frame(axes)
    D = rng.uniform(5.0, 12.0, 5)
    rect = np.column_stack([rng.uniform(-2.0, 0.0, (5, 2)), rng.uniform(0.1, 2.5, (5, 2))])
    order = rng.permutation(len(tri)).astype(np.int32)
    tri_start = np.array([0, 100, 100, 450, 200])
    counts = np.array([300, 500, 0, 450, 700])
    pair_start = np.concatenate([[0], np.cumsum(counts)])
    frame = np.column_stack([axes, u, v, D])
    want = sbr.beside_pairs(tri, order, tri_start, pair_start, frame, rect, eye, chunk=333)
    got = device_silhouette.beside_cull(runtime, tri, order, tri_start, pair_start, frame,
                                        rect, eye)
    np.testing.assert_array_equal(got, want)
    assert 0.2 < want.mean() < 0.95
    for w in range(5):
        mine = order[tri_start[w]:tri_start[w] + counts[w]]
        np.testing.assert_array_equal(
            want[pair_start[w]:pair_start[w + 1]],
            sbr._beside(tri[mine], eye, axes[w], u[w], v[w], D[w], rect[w, :2], rect[w, 2:]))


def test_many_grid_raster_is_each_grids_bit_for_bit(runtime):
    """Triangles on three grids of different origins, block sizes and shapes rastered at
    once (numpy and kernel): each grid's part of the concatenated mask is block_coverage
    of its own triangles."""
    rng = np.random.default_rng(5)
    tri = rng.uniform(-3.0, 3.0, size=(120, 1, 2)) + rng.normal(size=(120, 3, 2)) * 0.6
    tri[:4] = tri[:4, :1] + 1e-3 * rng.normal(size=(4, 3, 2))
    tri[4:8] += 20.0
    win = rng.integers(0, 3, len(tri))
    block = np.array([0.4, 0.25, 0.7])
    origin = np.array([[-3.0, -2.6], [-4.05, -3.3], [-2.0, -5.0]])
    shape = np.array([[15, 14], [31, 29], [6, 11]])
    sizes = shape[:, 0] * shape[:, 1]
    offset = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    setup = coverage_setup_many(tri, win, block, origin, shape)
    want = cover_blocks_many(setup, block, origin, shape[:, 1], offset, sizes.sum())
    got = device_silhouette.cover_blocks_many(runtime, setup, block, origin, shape[:, 1],
                                              offset, sizes.sum(), min_pairs=0)
    np.testing.assert_array_equal(got, want)
    # the kernel that computes the separating-axis data itself (the launch's)
    tri[8:10, 2] = tri[8:10, 0] + 0.5 * (tri[8:10, 1] - tri[8:10, 0])  # edge-on: no area
    want = cover_xy_many(tri, win, block, origin, shape, offset, sizes.sum())
    got = device_silhouette.cover_xy_many(runtime, tri, win, block, origin, shape, offset,
                                          sizes.sum())
    np.testing.assert_array_equal(got, want)
    for w in range(3):
        one = block_coverage(tri[win == w], block[w], origin[w], shape[w])
        np.testing.assert_array_equal(want[offset[w]:offset[w] + sizes[w]], one.ravel())
        assert 0 < one.sum() < one.size


def test_windows_keep_their_fields_types(runtime):
    """The batch gives the dataclass the loop gave: the same field dtypes."""
    scene = load_scene(STREET)
    geom = build_geometry(scene, runtime, engine="device")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        w = sbr.launch_windows(geom, scene.radars[1].position, [1, 2], 2 * scene.wavelength_m)
    kinds = {f.name: np.asarray(getattr(w, f.name)).dtype for f in dataclasses.fields(w)}
    empty = sbr.TubeWindows.empty(w.tx)
    for f in dataclasses.fields(w):
        assert kinds[f.name] == np.asarray(getattr(empty, f.name)).dtype, f.name


def test_projection_kernel_is_numpys_bit_for_bit(runtime):
    """project_windows against sbr._project on triangles of several windows: the same
    xy bit for bit, and the extents are the triangles' own minima and maxima (without
    fp64, in double-float: within tests/mode_helpers.py's POINT_TOL_REL)."""
    rng = np.random.default_rng(9)
    tri = rng.normal(size=(700, 3, 3)) * [3.0, 3.0, 2.0] + [0.5, -0.3, 9.0]
    eye = np.array([0.2, 0.1, -0.4])
    axes = rng.normal(size=(4, 3)) * 0.3 + [0.0, 0.0, 1.0]
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    u, v = orthonormal_frame(axes)
    D = rng.uniform(3.0, 15.0, 4)
    win = np.sort(rng.integers(0, 4, len(tri)))
    buf, ext = device_silhouette.project_windows(
        runtime, tri, win, np.column_stack([axes, u, v, D]), eye)
    raw = np.empty((len(tri), 3, 2))
    cl.enqueue_copy(runtime.queue, raw, buf, is_blocking=True)
    xy = host_float64(runtime, raw)   # the buffer's pairs joined without fp64
    want, depth = sbr._project(tri, eye, axes[win], u[win], v[win], D[win])
    assert_points(runtime, xy, want)
    assert_points(runtime, ext, np.column_stack([
        depth.min(axis=1), want[..., 0].min(axis=1), want[..., 0].max(axis=1),
        want[..., 1].min(axis=1), want[..., 1].max(axis=1)]))
    # one window's projection by hand: x = D (p - eye).u / depth
    rel = tri[win == 2] - eye
    x = D[2] * (rel @ u[2]) / (rel @ axes[2])
    np.testing.assert_allclose(xy[win == 2][..., 0], x, rtol=1e-12, atol=1e-12)


def street_car_windows(runtime, pitch_wavelengths: float):
    """Radar A of the street and its SBR windows over the four cars, every block (no
    pattern cut) at this pitch."""
    scene = load_scene(STREET)
    geom = build_geometry(scene, runtime, engine="device")
    tx = scene.radars[scene.radar_index("A")]
    cars = [i for i, o in enumerate(scene.objects) if o.name.startswith("car")]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return tx, sbr.launch_windows(geom, tx.position, cars,
                                      pitch_wavelengths * scene.wavelength_m)


def test_blocks_in_pattern_keep_the_blocks_seen_at_a_corner_or_the_centre(runtime):
    """blocks_in_pattern (each lattice corner once, then the centres) against its
    definition evaluated block by block: a block stays where tx's pattern has gain at one
    of its four corners or its centre."""
    tx, w = street_car_windows(runtime, 2.0)
    got = sbr.blocks_in_pattern(w, tx)
    g = w.block_window.astype(np.int64)
    keep = np.zeros(len(g), dtype=bool)
    for fx, fy in ((0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1.0, 1.0), (0.5, 0.5)):
        x = (w.cell0[g, 0] + w.block_i * BLOCK + fx * BLOCK) * w.spacing[g]
        y = (w.cell0[g, 1] + w.block_j * BLOCK + fy * BLOCK) * w.spacing[g]
        d = w.distance[g, None] * w.axis[g] + x[:, None] * w.u[g] + y[:, None] * w.v[g]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        keep |= np.asarray(tx.pattern.gain(d @ np.asarray(tx.orientation))) > 0
    assert 0 < keep.sum() < len(keep)
    for key in ("block_window", "block_i", "block_j"):
        np.testing.assert_array_equal(getattr(got, key), getattr(w, key)[keep])


def test_launched_holds_the_shot_tubes_and_not_the_blocks_the_pattern_cut(runtime):
    """sbr.launched says which directions SBR shoots a tube in: every owned tube of the
    street's windows (radar A, its 90 degree sector) is launched; a tube of a block that
    blocks_in_pattern cut is not, nor the reverse of a launched direction; a later
    window's tube that an earlier window owns may be launched (by the earlier one)."""
    tx, every = street_car_windows(runtime, 4.0)
    kept = sbr.blocks_in_pattern(every, tx)
    assert 0 < len(kept.block_window) < len(every.block_window)
    grid, owned = sbr.window_tubes(every, np.arange(every.n_tubes))
    in_kept = np.zeros(len(every.block_window), dtype=bool)
    key = (every.block_window.astype(np.int64) << 40) | (every.block_i.astype(np.int64) << 20) \
        | every.block_j.astype(np.int64)
    key_kept = (kept.block_window.astype(np.int64) << 40) \
        | (kept.block_i.astype(np.int64) << 20) | kept.block_j.astype(np.int64)
    in_kept[np.isin(key, key_kept)] = True
    tube_kept = np.repeat(in_kept, BLOCK * BLOCK)
    got = sbr.launched(kept, grid.directions)
    shot = owned & tube_kept
    assert shot.sum() > 1000 and (~tube_kept).sum() > 1000 and (~owned).sum() > 0
    assert got[shot].all()
    # a cut block's own tube, where no earlier window owns the direction: never shot
    assert not got[owned & ~tube_kept].any()
    assert got[~owned].any()
    assert not sbr.launched(kept, -grid.directions[shot]).any()
    assert not sbr.launched(sbr.TubeWindows.empty(tx.position), grid.directions[:5]).any()
