"""The device engine of clradcom.device.visibility (kernels/visibility.cl) against the host
reference (engine="host": float32 casts re-decided in numpy float64): the same decisions
on segment batches aimed at edges, seams and rims (at the origin and 1 km from it, where
float32 cannot tell), on the golden scene's paths and on the street's specular
confirmation; without fp64 the same but where float64 decides at its threshold, and
points and gains within double-float's rounding (tests/mode_helpers.py)."""

import dataclasses
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from geometry_helpers import plate_tris
from mode_helpers import (
    assert_decided_alike,
    assert_points,
    face_margins,
    gain_tolerance,
    point_atol,
    segment_margins,
)

from clradcom.device import visibility
from clradcom.device.raycast import RayCaster, make_rays, spawn_origins
from clradcom.device.visibility import (
    SIGHT_STOP,
    _seam_edges,
    confirm_paths,
    confirm_slack,
    dot3_order,
    face_tables,
    reaches_face,
    segments_clear,
    surface_sees,
    uses_device,
)
from clradcom.errors import ArgumentError, DeviceFallbackWarning
from clradcom.geometry.faces import merge_coplanar
from clradcom.mechanisms import diffraction, specular
from clradcom.mechanisms.common import build_geometry
from clradcom.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "data" / "all_mechanisms.toml"
STREET = ROOT / "scenes" / "street" / "street.toml"


def wall_and_floor():
    """A 4 x 4 m wall at x = 2 tessellated 3 x 3 (18 triangles: seams inside, rims
    around; face 1) over a floor z = 0 of two triangles (face 0), a 1 m plate at x = 3
    behind a gap (face 2)."""
    verts, tris = plate_tris(3, 4.0, 2.0, centre=(0.0, 2.2))
    wall = np.asarray(verts)[np.asarray(tris)]
    floor = np.array([[[-3, -3, 0], [5, -3, 0], [5, 3, 0]], [[-3, -3, 0], [5, 3, 0], [-3, 3, 0]]],
                     dtype=np.float64)
    verts, tris = plate_tris(1, 1.0, 3.0, centre=(0.0, 2.2))
    plate = np.asarray(verts)[np.asarray(tris)]
    triangles = np.concatenate([floor, wall, plate])
    tri_face = np.concatenate([[0, 0], np.ones(len(wall), int), [2, 2]])
    return triangles, tri_face


@pytest.fixture(scope="module")
def device_ok(runtime):
    """The runtime; without fp64 the device decides in double-float, and the comparisons
    allow a difference only where float64 decides at its threshold (tests/mode_helpers.py)."""
    assert dot3_order() is not None
    return runtime


def edge_points(triangles, rng, n, offsets):
    """n points on random edges of ``triangles`` moved in the triangle's plane across the
    edge by a random one of ``offsets`` (m, either side)."""
    t = rng.integers(0, len(triangles), n)
    j = rng.integers(0, 3, n)
    a, b, c = triangles[t, j], triangles[t, (j + 1) % 3], triangles[t, (j + 2) % 3]
    s = rng.uniform(0.0, 1.0, n)
    s[::7] = 0.0  # vertices too
    p = a + s[:, None] * (b - a)
    inward = (c - a) - np.einsum("ij,ij->i", c - a, b - a)[:, None] * (b - a) / np.einsum(
        "ij,ij->i", b - a, b - a)[:, None]
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    d = rng.choice(offsets, n) * rng.choice([-1.0, 1.0], n)
    return p + d[:, None] * inward, t


def test_face_tables_are_the_host_seams_faces_and_boxes():
    triangles, tri_face = wall_and_floor()
    T = len(triangles)
    tab = face_tables(triangles, tri_face)
    ref = _seam_edges(np.repeat(np.arange(T), 3), np.tile(np.arange(3), T), triangles,
                      tri_face).reshape(T, 3)
    assert np.array_equal(tab["seam"], ref)
    assert 0 < ref.sum() < ref.size  # seams and rims both
    for f in range(3):
        tris = tab["face_tris"][tab["face_first"][f]:tab["face_first"][f + 1]]
        assert tris.tolist() == np.flatnonzero(tri_face == f).tolist()
        assert np.array_equal(tab["face_box"][f, :3], triangles[tris].min(axis=(0, 1)))
        assert np.array_equal(tab["face_box"][f, 3:], triangles[tris].max(axis=(0, 1)))
    # -0.0 and 0.0 are one coordinate to the host's == test: still a seam
    neg = triangles.copy()
    neg[neg == 0.0] = -0.0
    neg[0, 0] = [-3.0, -3.0, 0.0]
    assert np.array_equal(face_tables(neg, tri_face)["seam"], ref)


@pytest.mark.parametrize("offset", [0.0, 1000.0])
def test_segments_near_edges_seams_and_rims_decide_alike(device_ok, offset):
    triangles, tri_face = wall_and_floor()
    triangles = triangles + offset
    caster = RayCaster(triangles, runtime=device_ok)
    assert uses_device(caster)
    rng = np.random.default_rng(7)
    scale = 1.0 + offset
    offsets = np.array([0.0, 1e-13, 1e-11, 1e-9, 3e-8, 1e-6, 3e-5]) * scale
    p, _ = edge_points(triangles, rng, 6000, offsets)
    d = rng.normal(size=p.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    start, end = p - 3.0 * d, p + 3.0 * d
    for tmin, tmax in ((0.0, 1.0), (0.3, 0.7), (rng.uniform(0, 0.5, len(p)), 1.0)):
        host = segments_clear(caster, tri_face, start, end, tmin, tmax, engine="host")
        dev = segments_clear(caster, tri_face, start, end, tmin, tmax, engine="device")
        # without fp64: alike but where float64 decides at its threshold (points exactly
        # on a rim or at a seam's tolerance, as the generator makes many)
        assert_decided_alike(device_ok, host, dev, lambda bad, lo=tmin, hi=tmax: segment_margins(
            triangles, start[bad], end[bad], np.broadcast_to(lo, len(p))[bad], hi))
    # the batch holds float32 "blocked" that float64 clears, and ones it keeps
    f32 = caster.occluded(make_rays(start, end - start, 0.0, 1.0))
    host = segments_clear(caster, tri_face, start, end, 0.0, 1.0, engine="host")
    assert (f32 & host).sum() > 20 and (f32 & ~host).sum() > 20


@pytest.mark.parametrize("offset", [0.0, 1000.0])
def test_reaching_a_face_at_its_rims_and_seams_decides_alike(device_ok, offset):
    triangles, tri_face = wall_and_floor()
    triangles = triangles + offset
    caster = RayCaster(triangles, runtime=device_ok)
    rng = np.random.default_rng(11)
    scale = 1.0 + offset
    end, t = edge_points(triangles, rng, 6000, np.array([0.0, 1e-12, 1e-9, 1e-7, 1e-5]) * scale)
    n = np.cross(triangles[t, 1] - triangles[t, 0], triangles[t, 2] - triangles[t, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    away = rng.normal(size=end.shape)
    away += 2.0 * n * np.where(rng.uniform(size=len(end)) < 0.8, 1.0, -1.0)[:, None]
    start = end + 2.5 * away
    slack = confirm_slack(end, np.linalg.norm(end - start, axis=1))
    host = reaches_face(caster, tri_face, start, end, tri_face[t], slack, engine="host")
    dev = reaches_face(caster, tri_face, start, end, tri_face[t], slack, engine="device")
    # without fp64: alike but for an end within DECISION_TOL_REL of a rim or a seam's
    # tolerance of its face
    assert_decided_alike(device_ok, host, dev, lambda bad: face_margins(
        triangles, tri_face, end[bad], tri_face[t[bad]]))
    assert (host >= 0).sum() > 100 and (host < 0).sum() > 100
    # the end's triangle is often not the one the point was put on (a seam's neighbour)
    assert np.any((host >= 0) & (host != t))


def test_surface_sight_lines_decide_alike(device_ok):
    triangles, tri_face = wall_and_floor()
    caster = RayCaster(triangles, runtime=device_ok)
    rng = np.random.default_rng(3)
    p = np.column_stack([rng.uniform(-3, 5, 500), rng.uniform(-3, 3, 500), np.zeros(500)])
    ignore = np.where(p[:, 0] - p[:, 1] < 2.0, 0, 1)
    normals = np.tile([0.0, 0.0, 1.0], (500, 1))
    for target in ([4.0, 0.3, 1.5], [-1.0, 0.0, 3.0], [2.0, 0.1, 2.0]):
        host = surface_sees(caster, p, normals, target, ignore, tri_face=tri_face,
                            engine="host")
        dev = surface_sees(caster, p, normals, target, ignore, tri_face=tri_face)
        assert np.array_equal(host, dev)
        if target[0] == 4.0:
            assert 0 < host.sum() < len(host)


def test_engine_is_checked_and_only_an_unknown_dot_order_means_the_host(monkeypatch):
    """Without fp64 the device decides in double-float (tests/test_no_fp64.py); with fp64
    it needs numpy's dot-product order to repeat the host bit for bit, and says so."""
    def caster(fp64):
        return SimpleNamespace(runtime=SimpleNamespace(info=SimpleNamespace(has_double=fp64)))

    assert uses_device(caster(False), "device") and uses_device(caster(True), "device")
    assert not uses_device(caster(True), "host")
    monkeypatch.setattr(visibility, "dot3_order", lambda: None)
    assert uses_device(caster(False), "device")
    assert not uses_device(caster(True), "device")
    assert "dot products" in visibility.device_refusal(caster(True))
    with pytest.raises(ArgumentError, match="engine"):
        uses_device(caster(False), "gpu")


def test_a_decision_left_to_the_host_is_recorded_and_said(runtime, monkeypatch):
    """With fp64 and numpy's dot order unknown the host decides: the same answer, the
    stage recorded as host with the reason, one DeviceFallbackWarning; the host engine
    records itself without a warning."""
    triangles, tri_face = wall_and_floor()
    caster = RayCaster(triangles, runtime=runtime)
    start = np.array([[-1.0, 0.5, 1.0], [-1.0, 0.5, 6.0]])   # through the wall, above it
    end = np.array([[4.0, 0.5, 1.0], [4.0, 0.5, 6.0]])
    want = segments_clear(caster, tri_face, start, end, 0.0, 1.0)
    assert want.tolist() == [False, True]
    with visibility.engines.engine_log() as log:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert np.array_equal(segments_clear(caster, tri_face, start, end, 0.0, 1.0,
                                                 engine="host"), want)
        if runtime.has_double:
            monkeypatch.setattr(visibility, "dot3_order", lambda: None)
            with pytest.warns(DeviceFallbackWarning, match="visibility.segments.*dot"):
                got = segments_clear(caster, tri_face, start, end, 0.0, 1.0)
            assert np.array_equal(got, want)
    text = log.metadata()["engine.visibility.segments"]
    assert text.startswith("host") if runtime.has_double else text == "host"


def _same_paths(a, b, runtime):
    """The device's paths are the host's: bit for bit with fp64; without, the same paths,
    their points and delays within double-float's rounding and their gains (computed by
    the host from those points) within tests/mode_helpers.py's gain_tolerance."""
    assert a.n_paths == b.n_paths
    if runtime.has_double:
        for field in ("gain", "delay_s", "points", "face_id", "n_interactions"):
            assert np.array_equal(np.asarray(getattr(a, field)), np.asarray(getattr(b, field)),
                                  equal_nan=True), field
        return
    for field in ("face_id", "n_interactions"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert_points(runtime, a.points, b.points, "points")
    # a delay is a length: POINT_TOL_REL of the path's scale, over c
    np.testing.assert_allclose(a.delay_s, b.delay_s, rtol=0,
                               atol=point_atol(b.points) / 299_792_458.0, err_msg="delay")
    assert (np.abs(a.gain - b.gain) <= gain_tolerance(b.gain)).all(), "gain"


@pytest.mark.parametrize("edges, reflections", [(2, 0), (1, 1)])
def test_golden_scene_specular_and_diffraction_paths_alike(device_ok, edges, reflections):
    scene = load_scene(GOLDEN)
    geom = build_geometry(scene, device_ok)
    host = dataclasses.replace(geom, engine="host")
    spec = specular.SpecularSettings(max_reflections=3, rays=20_000)
    diff = diffraction.DiffractionSettings(max_diffractions=edges, max_reflections=reflections)
    wedges = diffraction.prepare(geom, diff)
    tx = scene.radars[0]
    cands = specular.prepare(geom, tx, spec)
    n_paths = 0
    for rx in scene.radars:
        a = specular.link_paths(geom, cands, tx, rx, spec)
        b = specular.link_paths(host, cands, tx, rx, spec)
        _same_paths(a, b, device_ok)
        a = diffraction.link_paths(geom, wedges, tx, rx, diff, cands, cands)
        b = diffraction.link_paths(host, wedges, tx, rx, diff, cands, cands)
        _same_paths(a, b, device_ok)
        n_paths += a.n_paths
    assert n_paths > 20


def test_street_specular_confirmation_alike(device_ok):
    scene = load_scene(STREET)
    faces = merge_coplanar(scene.triangles, scene.tri_object, scene.tri_material)
    geom = build_geometry(scene, device_ok)
    host = dataclasses.replace(geom, engine="host")
    tx = scene.radars[0]
    cands = specular.prepare(geom, tx, specular.SpecularSettings(max_reflections=3,
                                                                 rays=30_000))
    kept = 0
    for rx in scene.radars:
        a = specular.specular_paths(geom, tx.position, rx.position, cands)
        b = specular.specular_paths(host, tx.position, rx.position, cands)
        assert np.array_equal(a.triangles, b.triangles)
        if device_ok.has_double:
            assert np.array_equal(a.points, b.points, equal_nan=True)
        else:
            assert_points(device_ok, a.points, b.points)
        kept += a.n_paths
    assert kept > 5
    # every order of a link confirmed in one batch is each order confirmed on its own
    rx = scene.radars[1]
    per_order, rows = [], []
    for k, seqs in cands.items():
        pts, ok = specular.image_points(tx.position, rx.position, geom.faces.normal,
                                        geom.faces.offset, seqs)
        per_order.append(confirm_paths(geom.caster, geom.faces.tri_face, geom.faces.normal,
                                       pts, seqs, ok))
        pad = np.full((len(seqs), 5, 3), np.nan)
        pad[:, :k + 2] = pts
        rows.append((pad, np.pad(seqs, ((0, 0), (0, 3 - k)), constant_values=-1), ok,
                     np.full(len(seqs), k)))
    pts, seqs, ok, n = (np.concatenate(x) for x in zip(*rows, strict=True))
    keep, tris = confirm_paths(geom.caster, geom.faces.tri_face, geom.faces.normal, pts,
                               seqs, ok, n_interactions=n)
    np.testing.assert_array_equal(keep, np.concatenate([a for a, _ in per_order]))
    assert keep.sum() >= 3 and len(set(n[keep].tolist())) >= 2   # paths of several orders
    bounds = np.cumsum([0] + [len(a) for a, _ in per_order])
    for (_, t), k, lo, hi in zip(per_order, cands, bounds[:-1], bounds[1:], strict=True):
        np.testing.assert_array_equal(tris[lo:hi, :k], t)
    # the seam table on a sample of the street's triangles is the host's
    T = len(scene.triangles)
    t = np.random.default_rng(0).choice(T, 200, replace=False)
    ref = _seam_edges(np.repeat(t, 3), np.tile(np.arange(3), len(t)), scene.triangles,
                      faces.tri_face).reshape(-1, 3)
    assert np.array_equal(face_tables(scene.triangles, faces.tri_face)["seam"][t], ref)


def test_triangles_near_an_antenna_are_the_full_scans(runtime):
    """antenna_blocked's per-antenna shortlist (_boxes_near) gives exactly the triangles a
    scan of the whole scene gives, for radii below and above its cached reach."""
    from clradcom.device import visibility

    rng = np.random.default_rng(7)
    tris = rng.uniform(-2.0, 2.0, (3000, 1, 3)) + rng.uniform(-0.05, 0.05, (3000, 3, 3))
    caster = RayCaster(tris + 700.0, runtime=runtime)   # far out: rounding at 1e-13
    lo, hi = caster.triangle_bounds()
    for ant in (np.array([700.0, 700.0, 700.0]), lo[5].copy(), hi[17] + 1e-3):
        for r in (0.0, 2e-3, 0.1, visibility.NEAR_ANTENNA_M, 0.6):
            want = np.flatnonzero(np.all((ant >= lo - r) & (ant <= hi + r), axis=1))
            np.testing.assert_array_equal(visibility._boxes_near(caster, ant, r), want)
    assert len(visibility._boxes_near(caster, lo[5].copy(), 2e-3)) >= 1


def test_surface_sight_lines_past_a_rim_are_decided_in_float64(runtime):
    """A sight line from a facet that passes a wall's rim closer than float32 resolution
    (1 km from the origin): a float32 "blocked" is re-decided as the float64 geometry
    has it (clear above the rim, blocked below it), on both engines alike; a float32
    "clear" stands (here there is none below the rim)."""
    base = np.array([1000.0, 1000.0, 1000.0])
    top = base[2] + 1.0
    wall = np.array([[[0, -1, 0], [0, 1, 0], [0, 1, 1]], [[0, -1, 0], [0, 1, 1], [0, -1, 1]]],
                    dtype=np.float64) + base
    facet = np.array([[[-5, -1, 0], [-5, 1, 0], [-5, 0, 2]]], dtype=np.float64) + base
    tris = np.concatenate([wall, facet])
    caster = RayCaster(tris, runtime=runtime)
    tri_face = np.array([0, 0, 1])
    deltas = np.array([-3e-5, -1e-5, -3e-6, -1e-7, 1e-7, 3e-6, 1e-5, 3e-5])
    points = np.stack([np.full(len(deltas), base[0] - 5.0), np.full(len(deltas), base[1]),
                       top + deltas], axis=1)
    targets = points + [10.0, 0.0, 0.0]
    normals = np.broadcast_to([1.0, 0.0, 0.0], points.shape)
    ignore = np.full(len(deltas), 2)
    exact = deltas > 0   # a horizontal sight line above the wall's top rim is clear
    for engine in ("host", "device"):
        got = np.array([surface_sees(caster, points[i:i + 1], normals[i:i + 1], targets[i],
                                     ignore[i:i + 1], tri_face=tri_face, engine=engine)[0]
                        for i in range(len(deltas))])
        np.testing.assert_array_equal(got, exact, err_msg=engine)
    # some float32 "blocked" lines pass above the rim: the rescue is what sees them
    org = spawn_origins(points, normals, targets - points)
    rays = make_rays(org, targets - org, 0.0, 1.0 - SIGHT_STOP)
    assert np.any(caster.occluded(rays, ignore_prim=ignore) & exact)
