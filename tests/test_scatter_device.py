"""Scattering tiles on the device (kernels/scatter.cl, clradcom/device/scatter.py) against
the host's numpy reference (engine "host"): the same tiles, the same sight decisions, the
same paths, the same channel."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from mode_helpers import DOPPLER_TOL_HZ, FIELD_TOL_REL, assert_points, point_atol

from clradcom.device import scatter as device_scatter
from clradcom.device.raycast import make_rays, spawn_origins
from clradcom.device.visibility import SIGHT_STOP
from clradcom.errors import ArgumentError
from clradcom.evaluation.accuracy import channel_nmse_db
from clradcom.geometry.triangles import triangle_normals_and_double_areas
from clradcom.mechanisms import scattering
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.scattering import make_tiles, scattering_paths
from clradcom.scene import load_scene
from clradcom.scene.reader import scene_from_dict

ROOT = Path(__file__).resolve().parent.parent
N_SUB, DF = 1024, 90.909e3  # the paper's OFDM grid around 24 GHz


def wall_scene():
    """A leafy wall with a hedge box in front of it (shadows part of the wall from both
    radars) over a concrete road (mirror for reflected legs), a monostatic radar and a
    bistatic receiver."""
    return scene_from_dict({
        "scene": {"name": "wall", "carrier_hz": 24e9},
        "materials": [{"name": "leaves", "eps_r": [10.0, -6.0], "scattering_coefficient": 0.5,
                       "cross_pol_share": 0.3}],
        "objects": [
            {"name": "road", "material": "concrete_road", "shape": "plane",
             "size": [30.0, 20.0], "position": [8.0, 0.0, 0.0]},
            {"name": "wall", "material": "leaves", "shape": "box",
             "extents": [12.0, 0.4, 3.0], "position": [8.0, 6.0, 1.5]},
            {"name": "hedge", "material": "trees", "shape": "box",
             "extents": [1.5, 1.0, 1.2], "position": [6.0, 3.0, 0.6],
             "velocity": [0.0, 0.5, 0.0]}],
        "radars": [{"name": "A", "position": [1.0, 0.0, 0.6], "velocity": [8.0, 0.0, 0.0],
                    "polarization": "V"},
                   {"name": "B", "role": "rx", "position": [15.0, 1.0, 0.8],
                    "pattern": "isotropic", "polarization": "H"}]})


def engines(scene, runtime):
    device = build_geometry(scene, runtime)
    host = build_geometry(scene, runtime, engine="host")
    host.caster = device.caster  # one BVH: the comparison is about the tile stages only
    return device, host


#: Relative field error allowed between tile_fields and the host: the phase k L of a path
#: is ~5e4 rad at 24 GHz, one float64 ulp of it 7e-12 rad, and implementations differ by a
#: few ulp in sin/cos and in how they order the double arithmetic (PoCL agrees with numpy
#: to 3e-14; NVIDIA's OpenCL to 3e-11). 1e-9 rad of phase is 2e-12 m of path, and a gain
#: error of 1e-9 is -180 dB: rounding, not physics, on any device.
FIELD_RTOL = 1e-9


def channel(paths):
    f = np.arange(N_SUB) * DF
    return np.exp(-2j * np.pi * f[:, None] * paths.delay_s[None, :]) @ paths.gain


def assert_same_paths(dev, host, label, runtime):
    """The device engine's scattering paths against the host's: with fp64 the tile
    stages' rounding only; without, the no-fp64 contract (tests/mode_helpers.py): points
    and lengths in double-float, fields in float."""
    (pd, nd), (ph, nh) = dev, host
    assert ph.n_paths > 0, label
    assert pd.n_paths == ph.n_paths and nd == nh, label
    # the same tiles, reached the same way
    for name in ("n_interactions", "interaction", "object_id", "face_id"):
        np.testing.assert_array_equal(getattr(pd, name), getattr(ph, name), err_msg=label)
    if not runtime.has_double:
        np.testing.assert_allclose(pd.points, ph.points, rtol=0, atol=point_atol(ph.points),
                                   err_msg=label)
        # delays from double-float lengths: 1e-18 s is 0.3 nm
        np.testing.assert_allclose(pd.delay_s, ph.delay_s, rtol=0, atol=1e-18, err_msg=label)
        np.testing.assert_allclose(pd.gain, ph.gain, rtol=0,
                                   atol=FIELD_TOL_REL * np.abs(ph.gain).max(), err_msg=label)
        np.testing.assert_allclose(pd.matrix, ph.matrix, rtol=0,
                                   atol=FIELD_TOL_REL * np.abs(ph.matrix).max(), err_msg=label)
        np.testing.assert_allclose(pd.doppler_hz, ph.doppler_hz, rtol=0, atol=DOPPLER_TOL_HZ,
                                   err_msg=label)
        # float fields within 1e-5 of the strongest: the channel within -100 dB
        assert channel_nmse_db(channel(pd), channel(ph)) < 20 * np.log10(FIELD_TOL_REL), label
        return
    np.testing.assert_allclose(pd.points, ph.points, rtol=0, atol=1e-12, err_msg=label)
    # the direct paths' fields come from tile_fields (double, its own order of operations)
    np.testing.assert_allclose(pd.gain, ph.gain, rtol=FIELD_RTOL, atol=0, err_msg=label)
    np.testing.assert_allclose(pd.matrix, ph.matrix, rtol=0,
                               atol=FIELD_RTOL * np.abs(ph.matrix).max(), err_msg=label)
    np.testing.assert_allclose(pd.delay_s, ph.delay_s, rtol=0, atol=1e-18, err_msg=label)
    # Doppler summed in another order: float64 rounding of a few kHz (a 1e-9 Hz error
    # turns the phase by 2e-11 rad over a 3 ms frame)
    np.testing.assert_allclose(pd.doppler_hz, ph.doppler_hz, rtol=0, atol=1e-9, err_msg=label)
    assert channel_nmse_db(channel(pd), channel(ph)) < -200.0, label


def triangle_inputs(scene, size):
    sel = np.flatnonzero(scene.material_scattering[scene.tri_material] > 0)
    tris = scene.triangles[sel]
    nrm, two_a = triangle_normals_and_double_areas(tris)
    n = scattering._subdivisions(tris, size)
    S = scene.material_scattering[scene.tri_material[sel]]
    return sel, tris, nrm, 0.5 * two_a / (n * n), S, n


# ---------------------------------------------------------------------------
# the kernels on their own

def test_device_tiles_are_the_hosts_bit_for_bit(runtime):
    rng = np.random.default_rng(3)
    tris = rng.uniform(-40.0, 40.0, size=(40, 3, 3))
    caster = build_geometry(wall_scene(), runtime).caster
    for size in (50.0, 7.0, 1.3):  # n = 1 up to tens of subdivisions per triangle
        q, area, _, local = make_tiles(tris, size)
        nrm, two_a = triangle_normals_and_double_areas(tris)
        n = scattering._subdivisions(tris, size)
        far = [500.0, 500.0, 500.0]
        got = device_scatter.tile_sight(caster, tris, nrm, 0.5 * two_a / (n * n),
                                        np.ones(len(tris)), np.zeros(len(tris)), n, far, far,
                                        0.0125, all_ends=True, monostatic=True)
        assert len(got.centres) == len(q) == int(np.sum(n * n))
        # same rule, order and rounding (in double-float without fp64)
        assert_points(runtime, got.centres, q)
        assert np.array_equal(np.repeat(np.arange(len(tris)), n * n), local)


@pytest.mark.parametrize("all_ends", [False, True])
def test_sight_flags_and_lambertian_power_against_host_casts(runtime, all_ends):
    sc = wall_scene()
    geom = build_geometry(sc, runtime)
    sel, tris, nrm_t, tile_area, S, n = triangle_inputs(sc, 0.4)
    A, B = sc.radars
    got = device_scatter.tile_sight(geom.caster, tris, nrm_t, tile_area, S, sel, n,
                                    A.position, B.position, sc.wavelength_m, all_ends=all_ends,
                                    monostatic=False, want_tiles=True)
    q, area, nrm, local = make_tiles(tris, 0.4)
    prim = sel[local].astype(np.int32)

    def sees(end, idx):  # the float32 casts of visibility.surface_sees, done by the host
        org = spawn_origins(q[idx], nrm[idx], end - q[idx])
        rays = make_rays(org, end - org, 0.0, 1.0 - SIGHT_STOP)
        return ~geom.caster.occluded(rays, ignore_prim=prim[idx])

    front_t = np.einsum("pi,pi->p", nrm, A.position - q) > 0
    front_r = np.einsum("pi,pi->p", nrm, B.position - q) > 0
    vis_t, vis_r = np.zeros(len(q), bool), np.zeros(len(q), bool)
    idx = np.flatnonzero(front_t if all_ends else front_t & front_r)
    vis_t[idx] = sees(A.position, idx)
    idx = np.flatnonzero(front_r) if all_ends else idx[vis_t[idx]]
    vis_r[idx] = sees(B.position, idx)
    want = vis_t.astype(np.uint8) | (vis_r.astype(np.uint8) << 1)
    np.testing.assert_array_equal(got.flags, want)
    both = np.flatnonzero(vis_t & vis_r)
    assert 0 < len(both) < np.count_nonzero(front_t & front_r)  # the hedge shadows some
    np.testing.assert_array_equal(got.tile, both)  # compacted, in tile order
    assert_points(runtime, got.centre, q[both])
    # closed form: lambda^2 S^2 A cos(theta_i) cos(theta_s) / (16 pi^3 r_i^2 r_s^2)
    dt, dr = q[both] - A.position, B.position - q[both]
    ri, rs = np.linalg.norm(dt, axis=1), np.linalg.norm(dr, axis=1)
    cos_i = -np.einsum("pi,pi->p", dt, nrm[both]) / ri
    cos_s = np.einsum("pi,pi->p", dr, nrm[both]) / rs
    Sq = S[local[both]]
    power = (sc.wavelength_m ** 2 * Sq ** 2 * area[both] * cos_i * cos_s
             / (16 * math.pi ** 3 * ri ** 2 * rs ** 2))
    # the power in double, or in float without fp64
    np.testing.assert_allclose(got.power, power,
                               rtol=1e-12 if runtime.has_double else FIELD_TOL_REL)


def test_bad_subdivisions_are_refused_by_name(runtime):
    sc = wall_scene()
    caster = build_geometry(sc, runtime).caster
    sel, tris, nrm, area, S, n = triangle_inputs(sc, 1.0)
    with pytest.raises(ArgumentError, match="subdivisions"):
        device_scatter.tile_sight(caster, tris, nrm, area, S, sel, n * 0, [0, 0, 1], [0, 0, 1],
                                  0.0125, all_ends=False, monostatic=True)
    with pytest.raises(ArgumentError, match="tx_pos"):
        device_scatter.tile_sight(caster, tris, nrm, area, S, sel, n, [0, np.nan, 1],
                                  [0, 0, 1], 0.0125, all_ends=False, monostatic=False)


# ---------------------------------------------------------------------------
# whole scattering stage: device engine against the host reference

@pytest.mark.parametrize("max_reflections", [0, 1, 2])
def test_wall_paths_match_host(runtime, max_reflections):
    sc = wall_scene()
    device, host = engines(sc, runtime)
    A, B = sc.radars
    for tx, rx in ((A, A), (A, B), (B, A)):
        kw = dict(tile_size_m=0.5, max_reflections=max_reflections, seed=7)
        assert_same_paths(scattering_paths(device, tx, rx, **kw),
                          scattering_paths(host, tx, rx, **kw),
                          f"{tx.name}->{rx.name} mr={max_reflections}", runtime)


@pytest.mark.parametrize("threshold_db, reference", [(-12.0, None), (-6.0, "strongest")])
def test_threshold_keeps_the_hosts_paths_and_dropped_count(runtime, threshold_db, reference):
    """The threshold applied to the device's rows keeps exactly the host's paths and counts
    the same dropped ones."""
    sc = wall_scene()
    device, host = engines(sc, runtime)
    A = sc.radars[0]
    full, _ = scattering_paths(host, A, A, tile_size_m=0.3, threshold_db=-300.0)
    ref = None if reference is None else full.gain[np.argmax(np.abs(full.gain))] * 0.7
    kw = dict(tile_size_m=0.3, threshold_db=threshold_db, reference_gain=ref)
    hst = scattering_paths(host, A, A, **kw)
    assert 0 < hst[0].n_paths < full.n_paths and hst[1] > 0
    assert_same_paths(scattering_paths(device, A, A, **kw), hst, f"threshold {threshold_db}",
                      runtime)


def turning_scene(origin=(0.0, 0.0, 0.0)):
    """The leafy wall turning about a vertical axis (tiles move with v + omega x r), radars
    with tilted frames, cosine patterns and a slanted (A) and a circular (B) polarisation
    (not circular at a monostatic radar, whose single-bounce returns cancel), a rough PEC
    car box that scatters too. ``origin`` shifts every position (and the rotation
    centre)."""
    o = np.asarray(origin, dtype=np.float64)

    def at(*p):
        return (np.asarray(p, dtype=np.float64) + o).tolist()

    return scene_from_dict({
        "scene": {"name": "turning", "carrier_hz": 24e9},
        "materials": [
            {"name": "leaves", "eps_r": [10.0, -6.0], "scattering_coefficient": 0.5,
             "cross_pol_share": 0.3},
            {"name": "rough_metal", "pec": True, "scattering_coefficient": 0.3,
             "cross_pol_share": 0.1}],
        "objects": [
            {"name": "road", "material": "concrete_road", "shape": "plane",
             "size": [30.0, 20.0], "position": at(8.0, 0.0, 0.0)},
            {"name": "wall", "material": "leaves", "shape": "box",
             "extents": [12.0, 0.4, 3.0], "position": at(8.0, 6.0, 1.5),
             "velocity": [0.3, 0.0, 0.0], "angular_velocity_deg_s": [0.0, 0.0, 20.0],
             "rotation_centre": at(8.0, 9.0, 0.0)},
            {"name": "car", "material": "rough_metal", "shape": "box",
             "extents": [3.8, 1.8, 1.5], "position": at(9.0, 2.5, 0.75),
             "velocity": [-5.0, 0.0, 0.0]}],
        "radars": [{"name": "A", "position": at(1.0, 0.0, 0.6), "velocity": [8.0, 0.5, 0.0],
                    "orientation_deg": [10.0, -5.0, 35.0],
                    "pattern": {"type": "cosine", "q": 2.0}, "polarization": [0.6, 0.8]},
                   {"name": "B", "role": "rx", "position": at(15.0, 1.0, 0.8),
                    "orientation_deg": [0.0, 3.0, 150.0],
                    "pattern": {"type": "cosine", "q": 1.0}, "polarization": "RHCP"}]})


@pytest.mark.parametrize("origin", [(0.0, 0.0, 0.0), (1000.0, -700.0, 20.0)])
def test_direct_fields_with_turning_tiles_tilted_antennas_and_pec(runtime, origin):
    """tile_fields against the host's _path_rows where every term of a direct path is
    exercised: turning tiles (Doppler with omega x r), tilted antenna frames, patterns
    that vary along the rows, a circular and a slanted polarisation (Gamma and the
    cross-polar share act on them), a PEC and a lossy scatterer; also 1.2 km from the
    origin, where the phases still agree to FIELD_RTOL (lengths and phases in double)."""
    sc = turning_scene(origin)
    device, host = engines(sc, runtime)
    A, B = sc.radars
    for tx, rx in ((A, A), (A, B), (B, A)):
        kw = dict(tile_size_m=0.4, seed=3, threshold_db=-300.0)
        dev, hst = scattering_paths(device, tx, rx, **kw), scattering_paths(host, tx, rx, **kw)
        assert len(np.unique(hst[0].object_id)) == 2  # wall and car both scatter
        assert np.ptp(hst[0].doppler_hz) > 10.0
        assert_same_paths(dev, hst, f"turning {tx.name}->{rx.name}", runtime)


def plate_scene(plate: bool):
    """The leafy wall and an isotropic radar in front of its middle; with ``plate`` a metal
    square 0.2 um in front of the radar covers the half-space x < 8 m of the radar's
    view."""
    objects = [{"name": "wall", "material": "leaves", "shape": "box",
                "extents": [12.0, 0.4, 3.0], "position": [8.0, 6.0, 1.5]}]
    if plate:
        objects.append({"name": "plate", "material": "metal", "shape": "plane",
                        "size": [0.2, 0.2], "position": [7.9, 2e-7, 0.6],
                        "rotation_deg": [90.0, 0.0, 0.0]})
    return scene_from_dict({
        "scene": {"name": "plate", "carrier_hz": 24e9},
        "materials": [{"name": "leaves", "eps_r": [10.0, -6.0], "scattering_coefficient": 0.5,
                       "cross_pol_share": 0.3}],
        "objects": objects,
        "radars": [{"name": "A", "position": [8.0, 0.0, 0.6], "pattern": "isotropic"}]})


def test_antenna_end_left_open_by_the_kernel_is_decided_on_the_host(runtime, monkeypatch):
    """A plate 0.2 um in front of the antenna: the float32 sight casts stop 1e-7 of their
    length (~0.6 um) short of it and miss the plate; the kernel leaves those rows open
    and the host's float64 antenna test (visibility.antenna_blocked) drops the ones whose
    sight line crosses the plate, as the host engine does."""
    kw = dict(tile_size_m=0.5, threshold_db=-300.0)
    open_sc = plate_scene(False)
    A = open_sc.radars[0]
    free, _ = scattering_paths(engines(open_sc, runtime)[1], A, A, **kw)
    assert np.any(free.points[:, 1, 0] < 7.9) and np.any(free.points[:, 1, 0] > 8.1)
    sc = plate_scene(True)
    device, host = engines(sc, runtime)
    A = sc.radars[0]
    opened = []
    tile_sight = device_scatter.tile_sight

    def spy(*a, **k):
        got = tile_sight(*a, **k)
        opened.append(int(np.count_nonzero(got.column("undecided"))))
        return got

    monkeypatch.setattr(device_scatter, "tile_sight", spy)
    dev = scattering_paths(device, A, A, **kw)
    hst = scattering_paths(host, A, A, **kw)
    assert opened[0] > 0  # the kernel left rows to the host
    q_x = hst[0].points[:, 1, 0]
    assert 0 < hst[0].n_paths < free.n_paths and q_x.min() > 7.99  # the plate's half gone
    assert_same_paths(dev, hst, "plate at the antenna", runtime)


def test_triangle_mask_keeps_phases_and_paths(runtime):
    sc = wall_scene()
    device, host = engines(sc, runtime)
    A = sc.radars[0]
    mask = np.ones(len(sc.triangles), dtype=bool)
    mask[np.flatnonzero(sc.tri_object == 1)[::2]] = False  # every other wall triangle
    kw = dict(tile_size_m=0.5, triangle_mask=mask)
    assert_same_paths(scattering_paths(device, A, A, **kw), scattering_paths(host, A, A, **kw),
                      "masked", runtime)


def test_golden_scene_links_match_host(runtime):
    sc = load_scene(ROOT / "tests" / "data" / "all_mechanisms.toml")
    device, host = engines(sc, runtime)
    A, B = sc.radars
    for tx, rx in ((A, A), (A, B)):
        kw = dict(tile_size_m=1.0, max_reflections=1)
        assert_same_paths(scattering_paths(device, tx, rx, **kw),
                          scattering_paths(host, tx, rx, **kw), f"golden {tx.name}->{rx.name}",
                          runtime)


def test_street_links_match_host(runtime):
    sc = load_scene(ROOT / "scenes" / "street" / "street.toml")
    device, host = engines(sc, runtime)
    A, D = sc.radars
    for tx, rx in ((A, A), (A, D)):
        assert_same_paths(scattering_paths(device, tx, rx), scattering_paths(host, tx, rx),
                          f"street {tx.name}->{rx.name}", runtime)


def test_scattering_triangles_are_kept_per_scene_until_its_arrays_change():
    sc = wall_scene()
    st = scattering._scattering_triangles(sc)
    assert scattering._scattering_triangles(sc) is st  # computed once per scene
    sel = np.flatnonzero(sc.material_scattering[sc.tri_material] > 0)
    np.testing.assert_array_equal(st.sel, sel)
    np.testing.assert_array_equal(st.longest, scattering._longest_edges(sc.triangles[sel]))
    sc.materials = [dataclasses.replace(m, scattering_coefficient=0.0)
                    for m in sc.materials]  # S changed: recomputed
    assert len(scattering._scattering_triangles(sc).sel) == 0
    sc.tri_material = sc.tri_material.copy()  # a new array: recomputed
    assert scattering._scattering_triangles(sc) is not st


def test_near_lists_hold_the_triangles_antenna_blocked_tests(runtime):
    """The kernel's near lists hold every triangle that visibility.antenna_blocked would
    test at the antenna: the plate just in front of it, not the wall 6 m away."""
    from clradcom.device.sbr import near_triangles
    from clradcom.device.visibility import confirm_margin_m

    sc = plate_scene(True)
    caster = build_geometry(sc, runtime).caster
    ant = np.asarray(sc.radars[0].position, dtype=np.float64)
    ends = np.array([ant, ant + [0.0, 0.0, 5.0]])
    radius = [2.0 * float(confirm_margin_m(e[None])[0]) for e in ends]
    for _ in range(2):  # the boxes scanned, then from the per-antenna shortlist
        first, tris = device_scatter._near_lists(caster, ends, radius)
        want_first, want = near_triangles(caster, ends)
        np.testing.assert_array_equal(first, want_first)
        np.testing.assert_array_equal(tris, want)
        assert len(tris) == 2 and set(sc.tri_object[tris]) == {1}  # the plate's two


def test_tile_sight_past_a_rim_is_decided_in_float64(runtime):
    """A tile centre whose sight line to tx passes a wall's rim closer than float32
    resolution (1 km from the origin): where the float32 cast calls it blocked, the
    kernel re-decides it in float64 as the host's surface_sees does (clear above the
    rim, blocked below it); a float32 "clear" stands, on both engines alike."""
    from clradcom.device.raycast import RayCaster
    from clradcom.device.visibility import surface_sees

    base = np.array([1000.0, 1000.0, 1000.0])
    top = base[2] + 1.0
    wall = np.array([[[0, -1, 0], [0, 1, 0], [0, 1, 1]], [[0, -1, 0], [0, 1, 1], [0, -1, 1]]],
                    dtype=np.float64) + base
    # one small triangle per offset, facing +x, its centroid 2 delta above the rim's
    # height at x = -5: the line to tx (x = +5, at the rim's height) meets the wall at
    # about delta above the rim
    deltas = np.array([-3e-5, -1e-5, -3e-6, -1e-7, 1e-7, 3e-6, 1e-5, 3e-5])
    facets = np.array([[[-5, -0.1, -0.1], [-5, 0.1, -0.1], [-5, 0.0, 0.2]]]) + base
    facets = np.repeat(facets, len(deltas), axis=0)
    facets[:, :, 2] += (top - base[2]) + 2.0 * deltas[:, None]
    tris = np.concatenate([wall, facets])
    caster = RayCaster(tris, runtime=runtime)
    tri_face = np.concatenate([[0, 0], 1 + np.arange(len(deltas))])
    tx = base + [5.0, 0.0, 1.0]
    rx = base + [-20.0, 0.0, 1.0]   # behind the facets: only tx matters here
    K = len(deltas)
    normals = np.tile([1.0, 0.0, 0.0], (K, 1))
    sight = device_scatter.tile_sight(
        caster, facets, normals, np.ones(K), np.ones(K), 2 + np.arange(K), np.ones(K, int),
        tx, rx, 0.0125, all_ends=True, monostatic=False, tri_face=tri_face)
    seen = (sight.flags & device_scatter.SEES_TX) != 0
    host = surface_sees(caster, sight.centres, normals, tx, 2 + np.arange(K),
                        tri_face=tri_face, engine="host")
    np.testing.assert_array_equal(seen, host)
    c = sight.centres
    crossing = c[:, 2] + (tx[2] - c[:, 2]) * (base[0] - c[:, 0]) / (tx[0] - c[:, 0])
    org = spawn_origins(c, normals, tx - c)
    rays = make_rays(org, tx - org, 0.0, 1.0 - SIGHT_STOP)
    blocked32 = caster.occluded(rays, ignore_prim=2 + np.arange(K))
    np.testing.assert_array_equal(seen[blocked32], (crossing > top)[blocked32])
    np.testing.assert_array_equal(seen[~blocked32], True)
    # some float32 "blocked" lines pass above the rim: the rescue is what sees them
    assert np.any(blocked32 & seen)
