"""Diffuse (Lambertian, effective-roughness) tile scattering (clradcom.mechanisms.scattering).

Reference: docs/reference/propagation-physics.md §3 (hemisphere power
S^2 Gamma^2 P_inc; tile RCS sigma = 4 S^2 Gamma^2 A cos^2 theta, -25.0 dBsm for
A = 0.01 m^2, S = 0.5, Gamma = 0.562; incoherent sum independent of tile size).
Radar equation with isotropic antennas: |a|^2 = lambda^2 sigma / ((4 pi)^3 R^4).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from geometry_helpers import plate_tris
from scipy.integrate import quad

from clradcom.errors import TileSizeWarning
from clradcom.geometry.triangles import point_triangle_distance
from clradcom.mechanisms import scattering
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.scattering import (
    choose_tile_size,
    make_tiles,
    scattering_paths,
    tile_transfer,
)
from clradcom.paths import InteractionType
from clradcom.physics import em
from clradcom.physics.em import C0
from clradcom.scene.reader import scene_from_dict

F_C = 24e9
LAM = C0 / F_C
S = 0.5
# |r| = 0.562 at normal incidence: sqrt(eps) = 1.562 / 0.438
EPS_0562 = (1.562 / 0.438) ** 2


def plate(size, x=0.0, n=1, tilt_deg=0.0):
    """Square plate of side ``size`` in the x = const plane facing -x (2 n^2 triangles),
    rotated by tilt_deg about z."""
    return plate_tris(n, size, x, tilt_deg=tilt_deg)


def make_scene(objects, radars, materials=None):
    mats = materials if materials is not None else [
        {"name": "rough", "eps_r": [EPS_0562, 0.0], "scattering_coefficient": S},
        {"name": "roughpec", "pec": True, "scattering_coefficient": S},
    ]
    return scene_from_dict({"scene": {"name": "scat", "carrier_hz": F_C},
                            "materials": mats, "objects": objects, "radars": radars})


def obj(name, verts, faces, material="rough", velocity=(0.0, 0.0, 0.0)):
    return {"name": name, "material": material, "shape": "triangles", "vertices": verts,
            "faces": faces, "position": [0.0, 0.0, 0.0], "velocity": list(velocity)}


def radar(pos, name="r"):
    return {"name": name, "position": [float(p) for p in pos], "pattern": "isotropic"}


def hemisphere_power(tx, e_tx, gamma, K, area=0.01, r_s=2.0, n=48):
    """int_hemisphere |E_s|^2 r_s^2 dOmega for one tile at the origin, normal +z."""
    mu, w = np.polynomial.legendre.leggauss(n)
    mu, w = 0.5 * (mu + 1), 0.5 * w  # cos theta_s in (0, 1)
    phi = np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    M, P = np.meshgrid(mu, phi, indexing="ij")
    W = np.repeat(w[:, None], len(phi), axis=1) * (2 * np.pi / len(phi))
    st = np.sqrt(1 - M**2)
    rx = r_s * np.stack([st * np.cos(P), st * np.sin(P), M], axis=-1).reshape(-1, 3)
    N = len(rx)
    T, L, _, _ = tile_transfer(np.zeros((N, 3)), np.full(N, area), np.tile([0, 0, 1.0], (N, 1)),
                               tx, rx, S, gamma, K, np.zeros((N, 2)))
    E = np.einsum("pij,j->pi", T, e_tx) / L[:, None]
    return np.sum(W.ravel() * np.sum(np.abs(E) ** 2, axis=-1) * r_s**2)


# ---------------------------------------------------------------------------
# tiles


def test_make_tiles_areas_sum_exactly_and_sizes():
    rng = np.random.default_rng(1)
    tris = rng.normal(size=(5, 3, 3))
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]),
                                axis=-1)
    c, a, nrm, ids = make_tiles(tris, 0.3)
    for t in range(5):
        m = ids == t
        n = int(np.ceil(np.max(np.linalg.norm(tris[t, [1, 2, 0]] - tris[t], axis=-1)) / 0.3))
        assert m.sum() == n * n
        assert a[m].sum() == pytest.approx(area[t], rel=1e-12)
        # centroids of the sub-triangles average to the triangle's centroid
        np.testing.assert_allclose(c[m].mean(axis=0), tris[t].mean(axis=0), atol=1e-12)
        # on the triangle's plane
        np.testing.assert_allclose((c[m] - tris[t, 0]) @ nrm[m][0], 0.0, atol=1e-12)
    assert np.all(np.diff(ids) >= 0)


def test_choose_tile_size_rule():
    d = choose_tile_size(LAM, 10.0, 0.05)
    # dphi = pi D^2 / (2 lambda R) = sqrt(45 * 0.05 / 4)
    assert np.pi * d**2 / (2 * LAM * 10.0) == pytest.approx(np.sqrt(45 * 0.05 / 4))
    assert choose_tile_size(LAM, 40.0, 0.05) == pytest.approx(2 * d)
    assert 0.2 < d < 0.3


# ---------------------------------------------------------------------------
# normalisation


@pytest.mark.parametrize("theta_i", [0.0, 30.0, 70.0])
@pytest.mark.parametrize("K", [0.0, 0.3])
def test_hemisphere_power_equals_s2_gamma2_incident(theta_i, K):
    th = np.radians(theta_i)
    r_i = 3.0
    tx = r_i * np.array([np.sin(th), 0.0, np.cos(th)])
    e = np.array([0.0, 1.0, 0.0])  # transverse to k_i, |e| = 1
    gamma, area = 0.562, 0.01
    p_inc = area * np.cos(th) / r_i**2  # |E_i|^2 A cos(theta_i)
    p_s = hemisphere_power(tx, e, gamma, K, area=area)
    assert p_s == pytest.approx(S**2 * gamma**2 * p_inc, rel=1e-6)


def test_energy_never_exceeds_incident():
    """(1 - S^2) Gamma^2 (specular) + scattered (hemisphere integral) = Gamma^2 <= 1."""
    r_i = 3.0
    for eps in (EPS_0562, 3.0 - 0.2j, 80.0 - 30j):
        for theta_i in (0.0, 20.0, 45.0, 70.0, 85.0):
            th = np.radians(theta_i)
            tx = r_i * np.array([np.sin(th), 0.0, np.cos(th)])
            ki = -tx / r_i
            r_te, r_tm = em.fresnel_coefficients(eps, np.cos(th))
            te = np.array([0.0, 1.0, 0.0])
            tm = np.cross(te, ki)
            for e, r in ((te, r_te), (tm, r_tm)):
                g2 = abs(r) ** 2
                p_inc = np.cos(th) / r_i**2
                frac = hemisphere_power(tx, e, np.sqrt(g2), 0.2, area=1.0, n=24) / p_inc
                assert frac == pytest.approx(S**2 * g2, rel=1e-6)
                assert (1 - S**2) * g2 + frac <= g2 * (1 + 1e-9) <= 1.0 + 1e-12


@pytest.mark.parametrize("tilt", [0.0, 40.0])
def test_monostatic_tile_rcs(runtime, tilt):
    R = 20.0
    v, f = plate(0.1, x=R, tilt_deg=tilt)  # A = 0.01 m^2, facing -x, tilted about z
    sc = make_scene([obj("p", v, f)], [radar((0.0, 0.0, 0.0))])
    geom = build_geometry(sc, runtime)
    r = sc.radars[0]
    paths, dropped = scattering_paths(geom, r, r, tile_size_m=1.0)
    assert len(paths) == 2 and dropped == 0
    sigma = np.sum(np.abs(paths.gain) ** 2) * (4 * np.pi) ** 3 * R**4 / LAM**2
    th = np.radians(tilt)
    r_te, r_tm = em.fresnel_coefficients(EPS_0562, np.cos(th))
    # V-pol radar, plate turned about z: the incident field is TE (along z)
    g2 = abs(r_te) ** 2
    expect = 4 * S**2 * g2 * 0.01 * np.cos(th) ** 2
    assert sigma == pytest.approx(expect, rel=2e-3)
    if tilt == 0.0:
        assert 10 * np.log10(sigma) == pytest.approx(-25.0, abs=0.02)
    assert np.all(paths.interaction[:, 0] == int(InteractionType.SCATTERING))
    assert set(paths.face_id[:, 0]) == {0, 1}
    np.testing.assert_allclose(paths.delay_s,
                               2 * np.linalg.norm(paths.points[:, 1], axis=-1) / C0,
                               rtol=1e-12)
    np.testing.assert_allclose(paths.delay_s, 2 * R / C0, rtol=1e-3)


def test_cross_pol_share_splits_monostatic_power(runtime):
    R = 20.0
    v, f = plate(0.1, x=R)
    mats = [{"name": "rough", "eps_r": [EPS_0562, 0.0], "scattering_coefficient": S,
             "cross_pol_share": 0.25}]
    sc = make_scene([obj("p", v, f)], [radar((0.0, 0.0, 0.0))], materials=mats)
    r = sc.radars[0]
    paths, _ = scattering_paths(build_geometry(sc, runtime), r, r, tile_size_m=1.0)
    sigma_co = np.sum(np.abs(paths.gain) ** 2) * (4 * np.pi) ** 3 * R**4 / LAM**2
    # matrix: total (co + cross) for a theta-polarised tx
    tot = np.sum(np.abs(paths.matrix[:, :, 0]) ** 2) * (4 * np.pi) ** 3 * R**4 / LAM**2
    assert sigma_co == pytest.approx(0.75 * 10 ** -2.5, rel=5e-3)
    assert tot == pytest.approx(10 ** -2.5, rel=5e-3)


def test_bistatic_pattern_follows_cos_theta_s(runtime):
    R = 10.0
    v, f = plate(0.05)  # at the origin facing -x
    out = []
    angles = np.array([0.0, 20.0, 40.0, 60.0, 80.0])
    for ang in angles:
        a = np.radians(ang)
        rxp = (-R * np.cos(a), R * np.sin(a), 0.0)
        sc = make_scene([obj("p", v, f, material="roughpec")],
                        [radar((-R, 0.0, 0.0), "t"), radar(rxp, "r")])
        geom = build_geometry(sc, runtime)
        p, _ = scattering_paths(geom, sc.radars[0], sc.radars[1], tile_size_m=1.0)
        # power of a theta-polarised tx, both rx polarisations (Gamma = 1 for PEC)
        pw = np.sum(np.abs(p.matrix[:, :, 0]) ** 2)
        out.append(pw * (4 * np.pi) ** 2 * R**4 / LAM**2 / (S**2 * 0.05**2 / np.pi))
    np.testing.assert_allclose(out, np.cos(np.radians(angles)), rtol=2e-3, atol=1e-4)


def test_incoherent_sum_independent_of_tile_size(runtime):
    v, f = plate(1.0, x=5.0, tilt_deg=25.0)
    sc = make_scene([obj("p", v, f)], [radar((0.0, 0.0, 0.5), "t"), radar((0.0, 1.0, 0.0), "r")])
    geom = build_geometry(sc, runtime)
    t, r = sc.radars
    sums, counts = [], []
    for size in (0.25, 0.05):
        p, _ = scattering_paths(geom, t, r, tile_size_m=size, threshold_db=-200)
        sums.append(np.sum(np.abs(p.matrix[:, :, 0]) ** 2))
        counts.append(len(p))
    assert counts[1] > 10 * counts[0]
    assert sums[1] == pytest.approx(sums[0], rel=1e-3)  # measured 1e-4


def test_threshold_drops_and_counts(runtime):
    v, f = plate(4.0, x=2.0, n=2)
    sc = make_scene([obj("p", v, f)], [radar((0.0, 0.0, 0.0))])
    geom = build_geometry(sc, runtime)
    r = sc.radars[0]
    allp, d0 = scattering_paths(geom, r, r, tile_size_m=0.2, threshold_db=-200)
    assert d0 == 0
    some, d1 = scattering_paths(geom, r, r, tile_size_m=0.2, threshold_db=-6)
    assert d1 > 0 and len(some) + d1 == len(allp)
    top = np.abs(allp.gain).max()
    assert np.all(np.abs(some.gain) >= top * 10 ** (-6 / 20))
    assert np.sum(np.abs(allp.gain) < top * 10 ** (-6 / 20)) == d1
    none, d2 = scattering_paths(geom, r, r, tile_size_m=0.2, reference_gain=1e6 * top)
    assert len(none) == 0 and d2 == len(allp)


def test_doppler_per_tile_of_moving_plate(runtime):
    vel = np.array([-3.0, 1.5, 0.5])
    v, f = plate(1.0, x=6.0, tilt_deg=15.0)
    tx, rx = np.array([0.0, 0.0, 0.0]), np.array([0.5, -2.0, 0.3])
    sc = make_scene([obj("p", v, f, velocity=vel)], [radar(tx, "t"), radar(rx, "r")])
    p, _ = scattering_paths(build_geometry(sc, runtime), sc.radars[0], sc.radars[1],
                            tile_size_m=0.3, threshold_db=-200)
    assert len(p) > 10
    q = p.points[:, 1]
    dt = 1e-6

    def length(qq):
        return np.linalg.norm(qq - tx, axis=-1) + np.linalg.norm(rx - qq, axis=-1)

    dLdt = (length(q + vel * dt) - length(q - vel * dt)) / (2 * dt)
    np.testing.assert_allclose(p.doppler_hz, -dLdt / LAM, rtol=1e-6, atol=1e-6)
    assert np.ptp(p.doppler_hz) > 1.0  # a spread, not one value


def test_occlusion_and_back_side(runtime):
    v, f = plate(0.5, x=5.0)
    bv, bf = plate(2.0, x=2.5)
    blocker = obj("b", bv, bf, material="metal")
    r = radar((0.0, 0.0, 0.0))
    geom = build_geometry(make_scene([obj("p", v, f), blocker], [r]), runtime)
    rr = geom.scene.radars[0]
    p, d = scattering_paths(geom, rr, rr, tile_size_m=0.1)
    assert len(p) == 0 and d == 0
    # radar behind the plate: back side, nothing
    sc = make_scene([obj("p", v, f)], [radar((10.0, 0.0, 0.0))])
    geom = build_geometry(sc, runtime)
    p, _ = scattering_paths(geom, sc.radars[0], sc.radars[0], tile_size_m=0.1)
    assert len(p) == 0


def test_random_phases_fixed_by_seed(runtime):
    v, f = plate(1.0, x=5.0)
    sc = make_scene([obj("p", v, f)], [radar((0.0, 0.0, 0.0))])
    geom = build_geometry(sc, runtime)
    r = sc.radars[0]
    a, _ = scattering_paths(geom, r, r, tile_size_m=0.2, seed=3)
    b, _ = scattering_paths(geom, r, r, tile_size_m=0.2, seed=3)
    c, _ = scattering_paths(geom, r, r, tile_size_m=0.2, seed=4)
    np.testing.assert_array_equal(a.gain, b.gain)
    np.testing.assert_allclose(np.abs(a.gain), np.abs(c.gain), rtol=1e-12)
    assert not np.allclose(a.gain, c.gain)


def test_no_scattering_material_gives_nothing(runtime):
    v, f = plate(1.0, x=5.0)
    sc = make_scene([obj("p", v, f, material="metal")], [radar((0.0, 0.0, 0.0))])
    r = sc.radars[0]
    p, d = scattering_paths(build_geometry(sc, runtime), r, r)
    assert len(p) == 0 and d == 0


def test_default_tiles_are_within_their_bound_at_the_nearest_point(runtime):
    # a long strip whose centroid lies 10 m from the radar but whose near end is 1 m away:
    # the bound there is the nearest point's (0.077 m), not the centroid's (0.24 m)
    verts = [[1.0, -0.5, -0.5], [1.0, 0.5, -0.5], [21.0, 0.5, -0.5], [21.0, -0.5, -0.5]]
    sc = make_scene([obj("s", verts, [[0, 2, 1], [0, 3, 2]], material="roughpec")],
                    [radar((0.0, 0.0, 0.0))])
    st = scattering._scattering_triangles(sc)
    plan = scattering.tile_plan(st, np.zeros(3), np.zeros(3), LAM)
    tris = sc.triangles[st.sel]
    nearest = point_triangle_distance(np.zeros(3), tris)
    assert nearest.min() == pytest.approx(np.sqrt(1.25))
    assert np.linalg.norm(tris.mean(axis=1), axis=1).min() > 7.0  # the centroids
    # every tile within the bound at the nearest point of its piece (so at its own)
    piece_nearest = point_triangle_distance(np.zeros(3), plan.vertices)
    bound = np.array([choose_tile_size(LAM, d) for d in piece_nearest])
    assert np.all(plan.tile_edges <= bound * (1 + 1e-9))
    q, local = scattering._cut_tiles(plan.vertices, plan.n)
    edge = plan.tile_edges[local]
    assert edge.max() > 3 * edge.min()  # farther tiles are larger (adaptive)
    # the tiles cover the strip exactly: areas add up, every centre on it
    assert np.sum(plan.tile_area * plan.n**2) == pytest.approx(20.0, rel=1e-12)
    r = sc.radars[0]
    p, _ = scattering_paths(build_geometry(sc, runtime), r, r, threshold_db=-300)
    assert len(p) == plan.first[-1]
    near = np.linalg.norm(p.points[:, 1], axis=1) < 1.3
    assert near.any()
    # near the radar the tiles are within the bound there; the centroid rule's tiles were
    # more than twice as large
    centroid_rule = choose_tile_size(LAM, np.linalg.norm(tris.mean(axis=1), axis=1).min())
    assert edge[np.linalg.norm(q, axis=1) < 1.3].max() <= choose_tile_size(LAM, 1.3)
    assert centroid_rule > 2 * choose_tile_size(LAM, 1.3)


def test_explicit_tiles_coarser_than_the_bound_warn_naming_the_surface(runtime):
    v, f = plate(2.0, x=5.0)
    sc = make_scene([obj("hedge", v, f)], [radar((0.0, 0.0, 0.0))])
    geom = build_geometry(sc, runtime)
    r = sc.radars[0]
    bound = choose_tile_size(LAM, 5.0)
    with pytest.warns(TileSizeWarning, match=r"'hedge'.*accuracy bound 0\.17"):
        scattering_paths(geom, r, r, tile_size_m=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", TileSizeWarning)
        scattering_paths(geom, r, r, tile_size_m=bound * 0.99)  # within it: silent
    # no cap: more than the 200 000 tiles that used to be refused, streamed in batches, and
    # their incoherent sum is the coarse tiles' (the areas add up exactly)
    v, f = plate(1.0, x=5.0)
    sc = make_scene([obj("hedge", v, f, material="roughpec")], [radar((0.0, 0.0, 0.0))])
    geom = build_geometry(sc, runtime)
    r = sc.radars[0]
    fine, _ = scattering_paths(geom, r, r, tile_size_m=0.004, threshold_db=-300)
    plan = scattering.tile_plan(scattering._scattering_triangles(sc), r.position, r.position,
                                LAM, tile_size_m=0.004)
    assert len(fine) == plan.first[-1] > 200_000
    coarse, _ = scattering_paths(geom, r, r, tile_size_m=0.1, threshold_db=-300)
    assert np.sum(np.abs(fine.gain) ** 2) == pytest.approx(np.sum(np.abs(coarse.gain) ** 2),
                                                          rel=1e-3)


def _square_road(a, material="roughpec"):
    verts = [[-a, -a, 0.0], [a, -a, 0.0], [a, a, 0.0], [-a, a, 0.0]]
    return obj("road", verts, [[0, 1, 2], [0, 2, 3]], material=material)


def lambertian_square_integral(a, h):
    """I = int int_{[-a, a]^2} h^2 / (h^2 + x^2 + y^2)^3 dx dy (docs/scattering.md
    "A Lambertian plane"): the radial integral in closed form, the angle by quadrature."""
    def radial(theta):
        return 2.0 * h**2 * (1.0 / h**4 - 1.0 / (h**2 + (a / np.cos(theta)) ** 2) ** 2)

    return quad(radial, 0.0, np.pi / 4, epsabs=0.0, epsrel=1e-13)[0]


def test_lambertian_square_integral_closed_form():
    h = 0.55
    # the infinite plane: pi / (2 h^2); the corners' share of a finite square by brute force
    assert lambertian_square_integral(1e5, h) == pytest.approx(np.pi / (2 * h**2), rel=1e-12)
    x = np.linspace(-2.0, 2.0, 2001)
    X, Y = np.meshgrid(x, x)
    brute = np.trapezoid(np.trapezoid(h**2 / (h**2 + X**2 + Y**2) ** 3, x), x)
    assert lambertian_square_integral(2.0, h) == pytest.approx(brute, rel=1e-4)
    # the closed form of docs/scattering.md
    assert lambertian_square_closed_form(2.0, h) == pytest.approx(
        lambertian_square_integral(2.0, h), rel=1e-10)


def lambertian_square_closed_form(a, h):
    """docs/scattering.md: I = pi/(2 h^2) - 2 h^2 J, J in closed form (b^2 = 1 + h^2/a^2)."""
    b = np.sqrt(1.0 + h**2 / a**2)
    c = h**2 / a**2
    at = np.arctan(1.0 / b)
    inner = ((np.pi / 4 - at / b) / c**2
             - (1.0 / (2 * b**2 * (1 + b**2)) + at / (2 * b**3)) / c)
    return np.pi / (2 * h**2) - 2 * h**2 * inner / a**4


@pytest.mark.parametrize("half_width", [10.0, 200.0])
def test_road_square_diffuse_power_follows_the_lambertian_plane(runtime, half_width):
    # the case: a monostatic radar 0.55 m over a PEC road square (S = 0.5); the
    # incoherent sum of the tiles against lambda^2 S^2 / (16 pi^3) x I(a, h). With one tile
    # size for the whole square from the 200 000-tile cap (1.88 m) it was 6.3 dB low.
    h = 0.55
    sc = make_scene([_square_road(half_width)], [radar((0.0, 0.0, h))])
    r = sc.radars[0]
    geom = build_geometry(sc, runtime)
    # tiles 80 dB under the strongest (beyond ~22 m: |a|^2 ~ A/r^6 with A ~ r) carry
    # ~1e-6 of the power; all ~1.2 million tiles of the 200 m square are streamed through
    p, dropped = scattering_paths(geom, r, r, threshold_db=-80)
    power = np.sum(np.abs(p.gain) ** 2)
    expect = LAM**2 * S**2 / (16 * np.pi**3) * lambertian_square_integral(half_width, h)
    assert 10 * np.log10(power / expect) == pytest.approx(0.0, abs=0.02)
    # every tile within its bound
    st = scattering._scattering_triangles(sc)
    plan = scattering.tile_plan(st, r.position, r.position, LAM)
    assert np.all(plan.tile_edges <= plan.bound * (1 + 1e-9))
    assert len(p) + dropped == plan.first[-1]  # every tile lit and seen


def test_streamed_batches_give_the_same_paths(runtime):
    h = 0.55
    sc = make_scene([_square_road(3.0)], [radar((0.0, 0.0, h))])
    r = sc.radars[0]
    for engine in ("device", "host"):
        geom = build_geometry(sc, runtime, engine=engine)
        whole, d0 = scattering_paths(geom, r, r, threshold_db=-30)
        parts, d1 = scattering_paths(geom, r, r, threshold_db=-30, batch_tiles=500)
        assert d0 == d1 > 0
        for name in ("gain", "matrix", "delay_s", "doppler_hz", "points", "face_id"):
            np.testing.assert_array_equal(getattr(parts, name), getattr(whole, name))


def test_batch_phases_are_the_rows_of_one_draw():
    first = np.array([0, 4, 5, 14, 30, 31, 47])
    every = np.random.default_rng(11).uniform(0.0, 2.0 * np.pi, size=(47, 2))
    for kb in ([0, 1, 2, 3, 4, 5], [1, 3, 4], [5], [2, 3]):
        rows = np.concatenate([np.arange(first[k], first[k + 1]) for k in kb])
        np.testing.assert_array_equal(scattering._batch_phases(11, first, kb), every[rows])


# ---------------------------------------------------------------------------
# specular prefix / suffix (image method)

MIRROR_EPS = 5.0 - 0.5j
MIRROR_ROUGH = 0.2e-3
TILE_VEL = np.array([-2.0, 1.0, 0.5])
MIRROR_VEL = np.array([0.7, 3.0, 0.0])
TX_M, RX_M = np.array([0.0, -2.0, 0.0]), np.array([4.0, 0.5, 0.0])


def mirror_scene(s_mirror=0.0, tile_material="rough", tx=TX_M, rx=RX_M, k_x=0.0):
    """A 0.1 m tile plate at x = 2 facing +x (its back to tx, so tx reaches it only
    via the mirror) and an 8 m mirror plate at x = 6 facing -x."""
    mats = [{"name": "rough", "eps_r": [EPS_0562, 0.0], "scattering_coefficient": S},
            {"name": "roughpec", "pec": True, "scattering_coefficient": S,
             "cross_pol_share": k_x},
            {"name": "mirror", "eps_r": [MIRROR_EPS.real, MIRROR_EPS.imag],
             "roughness_m": MIRROR_ROUGH, "scattering_coefficient": s_mirror}]
    tv, tf = plate_tris(1, 0.1, 2.0, centre=(2.0, 0.0), tilt_deg=180.0)
    mv, mf = plate_tris(1, 8.0, 6.0)
    return make_scene([obj("tile", tv, tf, material=tile_material, velocity=TILE_VEL.tolist()),
                       obj("mirror", mv, mf, material="mirror", velocity=MIRROR_VEL.tolist())],
                      [radar(tx, "a"), radar(rx, "b")], materials=mats)


def image_closed_form(c, src, dst, s_mirror):
    """|a|^2 of the tile (centroid c, normal +x, area 0.005) lit from ``src`` and seen
    from ``dst``, one of them the image of an end in the mirror x = 6: the tile's
    bistatic RCS 4 S^2 Gamma^2 A cos_i cos_s times the mirror's |r_te rho|^2 (1 - S_m^2)
    over (4 pi)^3 r_i^2 r_s^2, the image leg's length unfolded.  Gamma is taken at
    the tile's own incidence angle (from src); the field is along z, so TE throughout."""
    r_i = np.linalg.norm(c - src)
    r_s = np.linalg.norm(dst - c)
    cos_i = (src - c)[0] / r_i
    cos_s = (dst - c)[0] / r_s
    img = src if src[0] > 6 else dst
    cos_m = abs((c - img)[0]) / np.linalg.norm(c - img)  # at the mirror, unfolded
    r_te_m, _ = em.fresnel_coefficients(MIRROR_EPS, cos_m)
    rho = np.exp(-2 * (2 * np.pi / LAM * MIRROR_ROUGH * cos_m) ** 2)  # Ament
    g_t = abs(em.fresnel_coefficients(EPS_0562, cos_i)[0])
    sigma = 4 * S**2 * g_t**2 * 0.005 * cos_i * cos_s
    return (LAM**2 * sigma * abs(r_te_m * rho) ** 2 * (1 - s_mirror**2)
            / ((4 * np.pi) ** 3 * r_i**2 * r_s**2))


@pytest.mark.parametrize("s_mirror", [0.0, 0.4])
def test_tile_behind_mirror_prefix_and_suffix_match_image_closed_form(runtime, s_mirror):
    sc = mirror_scene(s_mirror)
    geom = build_geometry(sc, runtime)
    a, b = sc.radars
    tile_tris = geom.scene.triangles[:2]
    img_a = TX_M * [-1, 1, 1] + [12.0, 0, 0]  # tx mirrored in x = 6
    # without reflections the tile is dark: its back faces a
    p0, _ = scattering_paths(geom, a, b, tile_size_m=1.0, threshold_db=-200)
    assert not np.isin(p0.object_id[:, 0], [0]).any()
    for forward in (True, False):
        t, r = (a, b) if forward else (b, a)
        p, dropped = scattering_paths(geom, t, r, tile_size_m=1.0, threshold_db=-200,
                                      max_reflections=1)
        on_tile = np.flatnonzero((p.object_id == 0).any(axis=1))
        assert len(on_tile) == 2 and dropped == 0  # one tile per triangle, prefix or suffix
        code = [int(InteractionType.REFLECTION), int(InteractionType.SCATTERING)]
        for k in on_tile:
            codes = p.interaction[k, :2].tolist()
            assert codes == (code if forward else code[::-1])
            j_m, j_t = (0, 1) if forward else (1, 0)
            assert p.object_id[k, j_m] == 1 and p.face_id[k, j_m] in (2, 3)
            c = tile_tris[p.face_id[k, j_t]].mean(axis=0)
            np.testing.assert_allclose(p.points[k, 1 + j_t], c, atol=1e-12)
            pm = p.points[k, 1 + j_m]
            assert pm[0] == pytest.approx(6.0, abs=1e-9)
            # the reflection point lies on the line from the tile to the image of tx
            u = (img_a - c) / np.linalg.norm(img_a - c)
            np.testing.assert_allclose(np.cross(pm - c, u), 0.0, atol=1e-9)
            length = np.linalg.norm(c - img_a) + np.linalg.norm(RX_M - c)
            assert p.delay_s[k] * C0 == pytest.approx(length, rel=1e-12)
            src, dst = (img_a, RX_M) if forward else (RX_M, img_a)
            # 1e-3: the tile centroids sit 17 mm off the plane z = 0 of tx and rx, which
            # tilts the planes of incidence and mixes ~4e-5 of TM into the TE field
            ratio = abs(p.gain[k]) ** 2 / image_closed_form(c, src, dst, s_mirror)
            assert ratio == pytest.approx(1.0, rel=1e-3)

            # Doppler: the unfolded length with the tile and the mirror plane moving
            def unfolded(dt, c=c):
                cc = c + TILE_VEL * dt
                img = img_a + [2 * MIRROR_VEL[0] * dt, 0, 0]  # plane x = 6 + v_x t
                return np.linalg.norm(cc - img) + np.linalg.norm(RX_M - cc)

            dLdt = (unfolded(1e-5) - unfolded(-1e-5)) / 2e-5
            assert p.doppler_hz[k] == pytest.approx(-dLdt / LAM, rel=1e-6)


@pytest.mark.parametrize("k_x", [0.0, 0.3])
def test_prefix_and_suffix_paths_are_reciprocal(runtime, k_x):
    tx, rx = np.array([0.0, -2.0, 0.7]), np.array([4.0, 0.5, -0.4])
    sc = mirror_scene(0.3, tile_material="roughpec", tx=tx, rx=rx, k_x=k_x)
    geom = build_geometry(sc, runtime)
    a, b = sc.radars
    ab, _ = scattering_paths(geom, a, b, tile_size_m=0.5, threshold_db=-200,
                             max_reflections=2)
    ba, _ = scattering_paths(geom, b, a, tile_size_m=0.5, threshold_db=-200,
                             max_reflections=2)

    def through_tile(p):
        # tile paths only: the dielectric mirror's own tiles take Gamma from the tx's
        # polarisation (the reference's definition), which is not reciprocal
        out = {}
        for k in range(len(p)):
            n = p.n_interactions[k]
            if 0 in p.object_id[k, :n]:
                out[tuple(p.face_id[k, :n])] = k
        return out

    fwd, rev = through_tile(ab), through_tile(ba)
    # one tile per tile triangle, each lit via the mirror: prefix and prefix + suffix
    assert len(fwd) == 4 and {key[::-1] for key in fwd} == set(rev)
    kinds = {tuple(ab.interaction[k, :ab.n_interactions[k]]) for k in fwd.values()}
    assert kinds == {(1, 3), (1, 3, 1)}  # tx sees only the tile's back: no direct/suffix
    i = np.array(list(fwd.values()))
    j = np.array([rev[key[::-1]] for key in fwd])
    np.testing.assert_allclose(ba.delay_s[j], ab.delay_s[i], rtol=1e-12)
    if k_x == 0.0:
        np.testing.assert_allclose(ba.gain[j], ab.gain[i], rtol=1e-9)
        np.testing.assert_allclose(ba.matrix[j], np.swapaxes(ab.matrix[i], 1, 2), rtol=1e-9,
                                   atol=1e-15)
    else:
        # the cross-polarised term is a 90-degree turn about s, which flips sign on
        # reversal (docs/scattering.md); the total polarimetric power is reciprocal
        np.testing.assert_allclose(np.sum(np.abs(ba.matrix[j]) ** 2, axis=(1, 2)),
                                   np.sum(np.abs(ab.matrix[i]) ** 2, axis=(1, 2)), rtol=1e-9)
