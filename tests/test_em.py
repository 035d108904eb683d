"""Field physics of exact paths (clradcom.physics.em) against closed forms.

Reference numbers: docs/reference/propagation-physics.md (§1 Fresnel and
roughness, §4 Doppler, §6 canonical cases); formulas in docs/physics.md.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from clradcom.physics.em import (
    C0,
    ament,
    boithias,
    delay_s,
    doppler_hz,
    fresnel_coefficients,
    material_reflection_dyad,
    path_directions,
    path_gains,
    path_transfer,
    polarimetric_matrix,
    reflected_fields,
    reflection_dyad,
    roughness_factor,
)
from clradcom.scene.antenna import IsotropicPattern, SectorPattern, euler_deg_to_matrix
from clradcom.scene.antenna import polarization_jones as jones
from clradcom.scene.reader import load_scene
from clradcom.scene.records import Radar

F_C = 24e9
LAM = C0 / F_C
K0 = 2 * np.pi / LAM
ETA_CONCRETE = 5 - 0.1j
I3 = np.eye(3)
FACING_MINUS_X = euler_deg_to_matrix([0, 0, 180])  # boresight -x


def antenna(pol="V", orientation=I3, pattern=None):
    pattern = pattern if pattern is not None else IsotropicPattern(polarization=jones(pol))
    return SimpleNamespace(orientation=np.asarray(orientation, dtype=float), pattern=pattern)


def image_path(src, dst, planes):
    """Exact specular path src -> planes[0] -> ... -> dst by the image method.

    planes: list of (point, normal).  Returns (K+2, 3) points and (K, 3) normals.
    """
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    imgs = [src]
    for p, n in planes:
        n = np.asarray(n, float) / np.linalg.norm(n)
        s = imgs[-1]
        imgs.append(s - 2 * np.dot(s - p, n) * n)
    pts, cur = [], dst
    for k in reversed(range(len(planes))):
        p, n = np.asarray(planes[k][0], float), np.asarray(planes[k][1], float)
        d = imgs[k + 1] - cur
        t = np.dot(p - cur, n) / np.dot(d, n)
        cur = cur + t * d
        pts.append(cur)
    points = np.array([src, *reversed(pts), dst])
    normals = np.array([np.asarray(n, float) / np.linalg.norm(n) for _, n in planes])
    return points, normals.reshape(-1, 3)


def pec_transfer(points, normals):
    P = points[None]
    K = normals.shape[0]
    return path_transfer(P, normals[None], np.full((1, K), np.inf + 0j), np.ones((1, K), bool),
                         0.0, 0, F_C)


# ---------------------------------------------------------------------------
# Fresnel


@pytest.mark.parametrize(("deg", "te", "tm"), [
    (0, 0.382, 0.382), (45, 0.500, 0.250), (60, 0.610, 0.096), (80, 0.841, 0.396),
    (89, 0.983, 0.916)])
def test_fresnel_magnitudes_concrete_table(deg, te, tm):
    r_te, r_tm = fresnel_coefficients(ETA_CONCRETE, math.cos(math.radians(deg)))
    assert abs(r_te) == pytest.approx(te, abs=5e-4)
    assert abs(r_tm) == pytest.approx(tm, abs=5e-4)


def test_fresnel_against_snell_form_and_normal_incidence():
    """Independent form via the complex refraction angle (Hecht): r_perp =
    (cos t - n cos t_t)/(cos t + n cos t_t), r_par = (n cos t - cos t_t)/(n cos t + cos t_t)
    (the r_par sign that makes a PEC +1).  At normal incidence r_par = -r_perp =
    (sqrt(eps) - 1)/(sqrt(eps) + 1)."""
    th = np.deg2rad(np.linspace(0, 89.9, 50))
    for eps in (ETA_CONCRETE, 10 - 6j, 2.73 - 0.126j, 1.48 - 0.025j):
        nn = np.sqrt(eps)
        cos_t = np.sqrt(1 - np.sin(th) ** 2 / eps)
        ref_te = (np.cos(th) - nn * cos_t) / (np.cos(th) + nn * cos_t)
        ref_tm = (nn * np.cos(th) - cos_t) / (nn * np.cos(th) + cos_t)
        r_te, r_tm = fresnel_coefficients(eps, np.cos(th))
        np.testing.assert_allclose(r_te, ref_te, rtol=0, atol=1e-13)
        np.testing.assert_allclose(r_tm, ref_tm, rtol=0, atol=1e-13)
        assert r_tm[0] == pytest.approx((nn - 1) / (nn + 1), abs=1e-14)
        assert r_te[0] == pytest.approx(-(nn - 1) / (nn + 1), abs=1e-14)


def test_pseudo_brewster_minimum_and_phase_jump():
    th = np.deg2rad(np.linspace(60.0, 70.0, 100_001))
    _, r_tm = fresnel_coefficients(ETA_CONCRETE, np.cos(th))
    i = int(np.argmin(np.abs(r_tm)))
    assert math.degrees(th[i]) == pytest.approx(65.907, abs=1e-3)
    assert abs(r_tm[i]) == pytest.approx(0.0040, abs=5e-5)
    phase = np.angle(r_tm, deg=True)
    assert phase[0] < 0 and phase[0] > -3  # below: near 0 deg (slightly negative, loss)
    assert phase[-1] < -177  # above: near -180 deg
    _, r0 = fresnel_coefficients(ETA_CONCRETE, 1.0)
    assert np.angle(r0, deg=True) == pytest.approx(-0.6, abs=0.05)
    # lossless eps = 5: exact zero at the Brewster angle atan(sqrt 5) = 65.905 deg
    _, rb = fresnel_coefficients(5.0 + 0j, math.cos(math.atan(math.sqrt(5))))
    assert abs(rb) < 1e-15


def test_trees_normal_incidence():
    r_te, r_tm = fresnel_coefficients(10 - 6j, 1.0)
    assert abs(r_te) == pytest.approx(0.562, abs=5e-4)
    assert abs(r_tm) == pytest.approx(0.562, abs=5e-4)


def test_fresnel_pec_and_grazing():
    c = np.array([1.0, 0.5, 0.0])
    for r_te, r_tm in (fresnel_coefficients(np.inf + 0j, c),
                       fresnel_coefficients(5 - 0.1j, c, pec=True)):
        np.testing.assert_array_equal(r_te, -1)
        np.testing.assert_array_equal(r_tm, 1)
    assert np.isnan(fresnel_coefficients(np.nan + 0j, 0.5)[0])  # NaN is not PEC
    # mixed per element
    r_te, r_tm = fresnel_coefficients([5 - 0.1j, 5 - 0.1j], [0.3, 0.3], pec=[False, True])
    assert r_te[1] == -1 and r_tm[1] == 1 and abs(r_te[0] + 1) > 0.1
    # dielectric at grazing incidence: both -1
    r_te, r_tm = fresnel_coefficients(ETA_CONCRETE, 0.0)
    assert r_te == pytest.approx(-1, abs=1e-15) and r_tm == pytest.approx(-1, abs=1e-15)
    # a very good conductor (ITU metal, 1 - j7.5e6) tends to the PEC values:
    # 1 + r_te ~ 2c/sqrt(eps), 1 - r_tm ~ 2/(c sqrt(eps)) -> O(1e-3) at c = 0.7
    r_te, r_tm = fresnel_coefficients(1 - 7.5e6j, 0.7)
    assert abs(1 + r_te) < 2 * 0.7 / math.sqrt(7.5e6) * 1.01
    assert abs(1 - r_tm) < 2 / (0.7 * math.sqrt(7.5e6)) * 1.01


def test_fresnel_passive_below_unity():
    rng = np.random.default_rng(1)
    eps = rng.uniform(0.2, 20, 1000) - 1j * rng.uniform(0, 10, 1000)
    c = rng.uniform(0, 1, 1000)
    r_te, r_tm = fresnel_coefficients(eps, c)
    assert np.all(np.abs(r_te) <= 1 + 1e-12) and np.all(np.abs(r_tm) <= 1 + 1e-12)
    # lossless eps < 1 beyond the critical angle: total reflection, |r| = 1
    r_te, r_tm = fresnel_coefficients(0.5 + 0j, math.cos(math.radians(60)))
    assert abs(r_te) == pytest.approx(1, abs=1e-14) and abs(r_tm) == pytest.approx(1, abs=1e-14)


# ---------------------------------------------------------------------------
# roughness


def test_roughness_factors_at_24ghz():
    db = lambda x: 20 * np.log10(x)  # noqa: E731 - amplitude factor in dB
    c0 = 1.0
    assert ament(1e-3, c0, K0) == pytest.approx(0.603, abs=5e-4)
    assert boithias(1e-3, c0, K0) == pytest.approx(0.642, abs=5e-4)
    assert db(ament(1e-3, c0, K0)) == pytest.approx(-4.40, abs=6e-3)
    assert db(boithias(1e-3, c0, K0)) == pytest.approx(-3.85, abs=6e-3)
    for deg, a_db, b_db in ((45, -2.20, -2.06), (60, -1.10, -1.06), (80, -0.13, -0.13)):
        c = math.cos(math.radians(deg))
        assert db(ament(1e-3, c, K0)) == pytest.approx(a_db, abs=6e-3)
        assert db(boithias(1e-3, c, K0)) == pytest.approx(b_db, abs=6e-3)
    assert db(ament(0.4e-3, 1.0, K0)) == pytest.approx(-0.70, abs=6e-3)
    assert db(boithias(0.4e-3, 1.0, K0)) == pytest.approx(-0.69, abs=6e-3)
    c = np.cos(np.deg2rad(np.linspace(60.01, 90, 20)))
    assert np.all(db(ament(0.4e-3, c, K0)) > -0.2)
    # definition: rho_B = rho_A I0(2 (k sigma cos)^2); Boithias >= Ament; both 1 when smooth
    x = (K0 * 2e-3 * 0.8) ** 2
    from scipy.special import i0
    assert boithias(2e-3, 0.8, K0) == pytest.approx(math.exp(-2 * x) * i0(2 * x), rel=1e-13)
    assert ament(0.0, 0.3, K0) == 1 and boithias(0.0, 0.3, K0) == 1
    # no overflow for very rough surfaces (i0e); Boithias tends to 1/sqrt(4 pi x)
    big = boithias(0.1, 1.0, K0)
    assert np.isfinite(big) and big == pytest.approx(1 / math.sqrt(4 * math.pi * (K0 * 0.1) ** 2),
                                                      rel=1e-3)


def test_roughness_factor_switch():
    s, c = np.array([1e-3, 1e-3]), np.array([1.0, 1.0])
    rho = roughness_factor(s, c, K0, np.array([0, 1]))
    assert rho[0] == ament(1e-3, 1.0, K0) and rho[1] == boithias(1e-3, 1.0, K0)
    with pytest.raises(ValueError, match="roughness_model"):
        roughness_factor(s, c, K0, np.array([0, 2]))


# ---------------------------------------------------------------------------
# reflection dyad


def _random_units(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_pec_dyad_is_minus_e_plus_2_n_dot_e_n():
    rng = np.random.default_rng(7)
    n_paths = 2000
    k = _random_units(rng, n_paths)
    n = _random_units(rng, n_paths)  # either side of the face
    D = reflection_dyad(k, n, -np.ones(n_paths), np.ones(n_paths))
    e = rng.normal(size=(n_paths, 3)) + 1j * rng.normal(size=(n_paths, 3))
    e -= np.sum(e * k, axis=1, keepdims=True) * k  # transverse incident field
    ref = -e + 2 * np.sum(n * e, axis=1, keepdims=True) * n
    got = np.einsum("pij,pj->pi", D, e)
    err = np.abs(got - ref) / np.linalg.norm(e, axis=1, keepdims=True)
    assert np.max(err) < 1e-14
    # the longitudinal component is annihilated
    np.testing.assert_allclose(np.einsum("pij,pj->pi", D, k), 0, atol=1e-15)
    # flipping the normal changes nothing
    np.testing.assert_allclose(reflection_dyad(k, -n, -1.0, 1.0), D, atol=1e-15)


def test_dielectric_dyad_maps_into_reflected_transverse_plane():
    rng = np.random.default_rng(3)
    k = _random_units(rng, 500)
    n = _random_units(rng, 500)
    cos_t = np.abs(np.sum(k * n, axis=1))
    r_te, r_tm = fresnel_coefficients(ETA_CONCRETE, cos_t)
    D = reflection_dyad(k, n, r_te, r_tm)
    k_r = k - 2 * np.sum(k * n, axis=1, keepdims=True) * n
    # output is transverse to k_r
    np.testing.assert_allclose(np.einsum("pi,pij->pj", k_r, D), 0, atol=1e-15)
    # singular values are |r_te| and |r_tm| (and 0)
    sv = np.linalg.svd(D, compute_uv=False)
    ref = np.sort(np.stack([np.abs(r_te), np.abs(r_tm), np.zeros(500)], axis=1), axis=1)[:, ::-1]
    np.testing.assert_allclose(sv, ref, atol=1e-14)


def test_dyad_at_and_near_normal_incidence():
    n = np.array([[0.3, -0.4, 0.866]])
    n /= np.linalg.norm(n)
    k = -n
    r_te, r_tm = fresnel_coefficients(ETA_CONCRETE, 1.0)
    D = reflection_dyad(k, n, r_te, r_tm)
    np.testing.assert_allclose(D[0], r_te * (I3 - np.outer(k[0], k[0])), atol=1e-15)
    # continuous: a tilt of 1e-7 rad changes the dyad by O(1e-7) at most
    t = np.cross(n[0], [1.0, 0, 0])
    t /= np.linalg.norm(t)
    k2 = (-n[0] * math.cos(1e-7) + t * math.sin(1e-7))[None]
    r2 = fresnel_coefficients(ETA_CONCRETE, math.cos(1e-7))
    D2 = reflection_dyad(k2, n, *r2)
    assert np.max(np.abs(D2 - D)) < 1e-6


# ---------------------------------------------------------------------------
# path transfer and gains


def test_free_space_gain_isotropic():
    for d in (1.0, 7.3, 123.456):
        pts = np.array([[[0, 0, 0], [d, 0, 0]]], float)
        T, L = path_transfer(pts, np.zeros((1, 0, 3)), np.zeros((1, 0)), np.zeros((1, 0), bool),
                             np.zeros((1, 0)), np.zeros((1, 0), int), F_C)
        np.testing.assert_allclose(T[0], np.diag([0, 1, 1]), atol=0)
        k_dep, k_arr = path_directions(pts)
        for rx_orient in (I3, FACING_MINUS_X):
            a, M = path_gains(T, L, k_dep, k_arr, antenna("V"), antenna("V", rx_orient), F_C)
            ref = LAM / (4 * np.pi * d) * np.exp(-1j * K0 * d)
            assert a[0] == pytest.approx(ref, rel=1e-12)
            # cross-pol is zero, co-pol H has the theta/phi convention sign
            assert abs(M[0, 0, 1]) < 1e-18 and abs(M[0, 1, 0]) < 1e-18
        assert 20 * np.log10(abs(ref)) == pytest.approx(-60.05 + 20 * np.log10(1 / d), abs=5e-3)
        assert delay_s(L)[0] == d / 299_792_458.0


def test_free_space_los_transfer_is_transverse_projector():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 2, 3)) * 10
    T, L = path_transfer(pts, np.zeros((50, 0, 3)), 1.0, False, 0.0, 0, F_C)
    u = (pts[:, 1] - pts[:, 0]) / L[:, None]
    np.testing.assert_allclose(T, I3 - u[:, :, None] * u[:, None, :], atol=1e-15)


def _scalar_two_ray(d, h_t, h_r, eps, sigma_h):
    """Independent scalar two-ray model over a flat rough ground (Snell form of
    Fresnel, Ament factor); returns d1, d2, (r_te, r_tm) * rho."""
    d1 = math.hypot(d, h_t - h_r)
    d2 = math.hypot(d, h_t + h_r)
    cos_i = (h_t + h_r) / d2
    sin_i = d / d2
    nn = np.sqrt(eps)
    cos_t = np.sqrt(1 - sin_i**2 / eps)
    r_te = (cos_i - nn * cos_t) / (cos_i + nn * cos_t)
    r_tm = (nn * cos_i - cos_t) / (nn * cos_i + cos_t)
    rho = math.exp(-8 * (math.pi * sigma_h * cos_i / LAM) ** 2)
    return d1, d2, r_te * rho, r_tm * rho


def _two_ray_paths(d, h_t, h_r):
    xr = d * h_t / (h_t + h_r)  # specular point on z = 0
    pts = np.array([[[0, 0, h_t], [d, 0, h_r], [0, 0, 0]],  # LOS, padded
                    [[0, 0, h_t], [xr, 0, 0], [d, 0, h_r]]], float)
    normals = np.array([[[0, 0, 1.0]], [[0, 0, 1.0]]])
    return pts, normals, np.array([0, 1])


@pytest.mark.parametrize(("d", "te_db", "tm_db"), [(10, -19.37, -7.90), (20, -26.04, -13.04),
                                                   (50, 1.30, 0.99)])
def test_two_ray_smooth_matches_reference_table(d, te_db, tm_db):
    pts, normals, nk = _two_ray_paths(d, 0.5, 0.5)
    T, L = path_transfer(pts, normals, ETA_CONCRETE, False, 0.0, 0, F_C, num_interactions=nk)
    k_dep, k_arr = path_directions(pts, nk)
    tx_v, rx_v = antenna("V"), antenna("V", FACING_MINUS_X)
    tx_h, rx_h = antenna("H"), antenna("H", FACING_MINUS_X)
    a_v, _ = path_gains(T, L, k_dep, k_arr, tx_v, rx_v, F_C)
    a_h, _ = path_gains(T, L, k_dep, k_arr, tx_h, rx_h, F_C)
    assert 20 * np.log10(abs(a_h.sum() / a_h[0])) == pytest.approx(te_db, abs=0.006)
    assert 20 * np.log10(abs(a_v.sum() / a_v[0])) == pytest.approx(tm_db, abs=0.006)
    if d == 10:
        assert L[1] == pytest.approx(10.049876, abs=1e-6)
        r_h, r_v = a_h[1] / a_h[0] * L[1] / L[0], a_v[1] / a_v[0] * L[1] / L[0]
        r_h *= np.exp(1j * K0 * (L[1] - L[0]))
        r_v *= np.exp(1j * K0 * (L[1] - L[0]))
        assert abs(r_h) == pytest.approx(0.9053, abs=5e-5)
        assert np.angle(r_h, deg=True) == pytest.approx(179.93, abs=0.005)
        assert abs(r_v) == pytest.approx(0.6020, abs=5e-5)
        assert np.angle(r_v, deg=True) == pytest.approx(-179.77, abs=0.005)


@pytest.mark.parametrize("d", [10.0, 20.0, 50.0])
def test_two_ray_rough_road_against_scalar_formula(d):
    """The paper's road (5 - j0.1, sigma_h 0.4 mm, Ament), h_t = h_r = 0.5 m, and an
    unequal-height case; complex gains of both paths and the TE / TM totals."""
    for h_t, h_r in ((0.5, 0.5), (0.5, 1.2)):
        pts, normals, nk = _two_ray_paths(d, h_t, h_r)
        T, L = path_transfer(pts, normals, ETA_CONCRETE, False, 0.4e-3, 0, F_C,
                             num_interactions=nk)
        k_dep, k_arr = path_directions(pts, nk)
        d1, d2, r_te, r_tm = _scalar_two_ray(d, h_t, h_r, ETA_CONCRETE, 0.4e-3)
        np.testing.assert_allclose(L, [d1, d2], rtol=1e-15)
        np.testing.assert_allclose(delay_s(L), np.array([d1, d2]) / C0, rtol=1e-15)
        g = LAM / (4 * np.pi) * np.exp(-1j * K0 * np.array([d1, d2])) / np.array([d1, d2])
        # V: theta-hat at both ends; the LOS component is +1, the reflected one r_tm
        a_v, M = path_gains(T, L, k_dep, k_arr, antenna("V"), antenna("V", FACING_MINUS_X), F_C)
        np.testing.assert_allclose(a_v, g * [1, r_tm], rtol=1e-12)
        # H: phi-hat of two facing antennas are opposite: both paths carry -1
        a_h, _ = path_gains(T, L, k_dep, k_arr, antenna("H"), antenna("H", FACING_MINUS_X), F_C)
        np.testing.assert_allclose(a_h, -g * [1, r_te], rtol=1e-12)
        np.testing.assert_allclose(a_h.sum(), -(g[0] + g[1] * r_te), rtol=1e-12)
        np.testing.assert_allclose(a_v.sum(), g[0] + g[1] * r_tm, rtol=1e-12)
        # in the vertical plane of incidence there is no cross-polarisation
        assert np.max(np.abs(M[:, 0, 1])) < 1e-15 and np.max(np.abs(M[:, 1, 0])) < 1e-15


def test_radar_object_is_accepted():
    radar = Radar(name="r", position=np.zeros(3), rides_on=-1, orientation=I3,
                  pattern=IsotropicPattern(), polarization=jones("V"), polarization_name="V",
                  velocity=np.zeros(3))
    pts = np.array([[[0, 0, 0], [3, 0, 0], [0, 0, 0]]], float)
    T, L = pec_transfer(pts[0], np.array([[-1.0, 0, 0]]))
    a, _ = path_gains(T, L, *path_directions(pts), radar, radar, F_C)
    assert a[0] == pytest.approx(-LAM / (4 * np.pi * 6) * np.exp(-1j * K0 * 6), rel=1e-12)


@pytest.mark.parametrize("R", [1.0, 10.0, 37.5])
def test_pec_plate_monostatic_equivalent_rcs(R):
    """Image method: a radar at R from an infinite PEC plane sees its image at 2R:
    |a| = lambda / (4 pi 2R), sigma_eq = (4 pi)^3 R^4 |a|^2 / (lambda^2 G^2) = pi R^2."""
    n = np.array([1.0, 2.0, -0.5])
    n /= np.linalg.norm(n)
    radar_pos = np.array([0.3, -1.0, 2.0])
    foot = radar_pos + R * n
    pts = np.array([radar_pos, foot, radar_pos])
    T, L = pec_transfer(pts, n[None])
    assert L[0] == pytest.approx(2 * R, rel=1e-14)
    k_dep, k_arr = path_directions(pts[None])
    for pattern, G in ((IsotropicPattern(), 1.0), (SectorPattern(), 4.0)):
        # boresight towards the plate
        ax = n
        y = np.cross([0, 0, 1.0], ax)
        y /= np.linalg.norm(y)
        orient = np.stack([ax, y, np.cross(ax, y)], axis=1)
        rad = antenna(orientation=orient, pattern=pattern)
        a, M = path_gains(T, L, k_dep, k_arr, rad, rad, F_C)
        sigma = (4 * np.pi) ** 3 * R**4 * abs(a[0]) ** 2 / (LAM**2 * G**2)
        assert sigma == pytest.approx(np.pi * R**2, rel=1e-12)
        assert a[0] == pytest.approx(-G * LAM / (8 * np.pi * R) * np.exp(-2j * K0 * R), rel=1e-12)
    if R == 10.0:
        assert 20 * np.log10(LAM / (4 * np.pi * 2 * R)) == pytest.approx(-86.07, abs=5e-3)


# ---------------------------------------------------------------------------
# polarimetric corner signatures (PEC, monostatic, BSA basis)


def _scale(L):
    return LAM / (4 * np.pi) * np.exp(-1j * K0 * L) / L


def _normalised_M(points, normals, orient=I3):
    T, L = pec_transfer(points, normals)
    k_dep, k_arr = path_directions(points[None])
    M = polarimetric_matrix(T, L, k_dep, k_arr, orient, orient, F_C)
    return M[0] / _scale(L[0]), k_dep[0], k_arr[0]


def test_plate_normal_incidence_is_minus_identity():
    R = 4.0
    pts = np.array([[0, 0, 0], [R, 0, 0], [0, 0, 0]], float)
    M, _, _ = _normalised_M(pts, np.array([[1.0, 0, 0]]))  # normal on the far side: fine
    np.testing.assert_allclose(M, -np.eye(2), atol=1e-15)


def test_trihedral_is_plus_identity():
    """Faces x = 0, y = 0, z = 0 (interior: positive octant); tx and rx a few mm apart
    so that the triple-bounce path misses the corner; a PEC trihedral retro-reflects
    exactly (k_arr = -k_dep), so M = +I in the BSA basis."""
    tx = np.array([6.0, 5.0, 4.0])
    rx = tx + np.array([0.004, -0.003, 0.002])
    faces = [((0, 0, 0), e) for e in np.eye(3)]
    best = None
    import itertools
    for order in itertools.permutations(range(3)):
        pts, nrm = image_path(tx, rx, [faces[i] for i in order])
        if np.all(pts[1:-1] >= -1e-12):  # every point on its physical face
            best = (pts, nrm)
    assert best is not None
    M, k_dep, k_arr = _normalised_M(*best)
    np.testing.assert_allclose(k_arr, -k_dep, atol=1e-14)
    np.testing.assert_allclose(M, np.eye(2), atol=1e-13)


def _dihedral(crease, opening=(-1.0, 0.0, 0.0)):
    """Two faces through the origin containing ``crease``, at +-45 deg around the
    opening direction (90 deg dihedral); returns planes and the in-plane offset axis."""
    c = np.asarray(crease, float) / np.linalg.norm(crease)
    opening = np.asarray(opening, float)
    q = np.cross(c, opening)
    q /= np.linalg.norm(q)
    dir_a, dir_b = (opening + q) / math.sqrt(2), (opening - q) / math.sqrt(2)
    planes = [((0, 0, 0), np.cross(c, dir_a)), ((0, 0, 0), np.cross(c, dir_b))]
    return planes, q, (dir_a, dir_b)


@pytest.mark.parametrize(("roll_deg", "expected"), [
    (0, np.diag([1.0, -1.0])),  # crease vertical (z): VV = +1, HH = -1
    (90, np.diag([-1.0, 1.0])),  # crease horizontal (y): diag(-1, +1) as in the reference
    (45, np.array([[0, -1.0], [-1.0, 0]])),  # rolled 45 deg: pure cross-pol
])
def test_dihedral_signatures(roll_deg, expected):
    r = math.radians(roll_deg)
    crease = np.array([0.0, math.sin(r), math.cos(r)])
    planes, q, (dir_a, dir_b) = _dihedral(crease)
    centre = np.array([-20.0, 0, 0])
    tx, rx = centre + 0.01 * q, centre - 0.03 * q
    found = []
    for pl, dirs in ((planes, (dir_a, dir_b)), (planes[::-1], (dir_b, dir_a))):
        pts, nrm = image_path(tx, rx, pl)
        on_faces = all(np.dot(p, d) > 0 for p, d in zip(pts[1:-1], dirs, strict=True))
        if on_faces:
            found.append((pts, nrm))
    assert len(found) == 1
    M, k_dep, k_arr = _normalised_M(*found[0])
    np.testing.assert_allclose(k_arr, -k_dep, atol=1e-14)
    # tx/rx sit 1-3 cm off the axis at 20 m: the BSA basis is tilted by ~1e-3 rad
    # against the crease, which leaks O(1e-7) into the zero entries
    np.testing.assert_allclose(M, expected, atol=1e-6)
    assert M[1, 1] == pytest.approx(-M[0, 0], abs=1e-12)  # HH = -VV whatever the roll


# ---------------------------------------------------------------------------
# circular polarisation and reciprocity (why the receive projection is bilinear)


def test_circular_polarisation_coupling():
    d = 5.0
    pts = np.array([[[0, 0, 0], [d, 0, 0]]], float)
    T, L = path_transfer(pts, np.zeros((1, 0, 3)), 1.0, False, 0.0, 0, F_C)
    kd, ka = path_directions(pts)
    ref = LAM / (4 * np.pi * d) * np.exp(-1j * K0 * d)
    a, _ = path_gains(T, L, kd, ka, antenna("RHCP"), antenna("RHCP", FACING_MINUS_X), F_C)
    assert a[0] == pytest.approx(ref, rel=1e-12)  # facing same-handed antennas couple fully
    a, _ = path_gains(T, L, kd, ka, antenna("RHCP"), antenna("LHCP", FACING_MINUS_X), F_C)
    assert abs(a[0]) < 1e-15 * abs(ref)
    # monostatic: a plate (odd bounce) returns the opposite hand; a dihedral the same hand
    plate = np.array([[0, 0, 0], [4.0, 0, 0], [0, 0, 0]])
    T, L = pec_transfer(plate, np.array([[-1.0, 0, 0]]))
    kd, ka = path_directions(plate[None])
    a_same, _ = path_gains(T, L, kd, ka, antenna("RHCP"), antenna("RHCP"), F_C)
    a_opp, _ = path_gains(T, L, kd, ka, antenna("RHCP"), antenna("LHCP"), F_C)
    assert abs(a_same[0]) < 1e-15 * abs(_scale(L[0]))
    assert abs(a_opp[0]) == pytest.approx(abs(_scale(L[0])), rel=1e-12)
    planes, q, _ = _dihedral([0, 0, 1.0])
    pts, nrm = image_path(np.array([-20.0, 0, 0]) + 0.01 * q, np.array([-20.0, 0, 0]) - 0.03 * q,
                          planes)
    T, L = pec_transfer(pts, nrm)
    kd, ka = path_directions(pts[None])
    a_same, _ = path_gains(T, L, kd, ka, antenna("RHCP"), antenna("RHCP"), F_C)
    assert abs(a_same[0]) == pytest.approx(abs(_scale(L[0])), rel=1e-9)


def test_reciprocity_two_bounce_lossy_elliptical():
    rng = np.random.default_rng(11)
    planes = [((0, 0, 0), np.array([0.1, 0.0, 1.0])), ((0, 8.0, 0), np.array([0.0, -1.0, 0.2]))]
    A, B = np.array([1.0, 2.0, 3.0]), np.array([7.0, 3.0, 2.5])
    pts, nrm = image_path(A, B, planes)
    eps = np.array([[ETA_CONCRETE, 10 - 6j]])
    rough = np.array([[1e-3, 0.4e-3]])
    model = np.array([[0, 1]])
    T_f, L_f = path_transfer(pts[None], nrm[None], eps, False, rough, model, F_C)
    T_r, L_r = path_transfer(pts[::-1][None], nrm[::-1][None], eps[:, ::-1], False,
                             rough[:, ::-1], model[:, ::-1], F_C)
    np.testing.assert_allclose(T_r[0], T_f[0].T, atol=1e-15)  # reversed chain = transpose
    assert L_r[0] == pytest.approx(L_f[0], rel=1e-15)
    o1 = euler_deg_to_matrix(rng.uniform(-180, 180, 3))
    o2 = euler_deg_to_matrix(rng.uniform(-180, 180, 3))
    j1 = rng.normal(size=2) + 1j * rng.normal(size=2)
    j2 = rng.normal(size=2) + 1j * rng.normal(size=2)
    ant1, ant2 = antenna(j1, o1), antenna(j2, o2)
    a_f, M_f = path_gains(T_f, L_f, *path_directions(pts[None]), ant1, ant2, F_C)
    a_r, M_r = path_gains(T_r, L_r, *path_directions(pts[::-1][None]), ant2, ant1, F_C)
    np.testing.assert_allclose(M_r[0], M_f[0].T, rtol=1e-12)
    assert a_r[0] == pytest.approx(a_f[0], rel=1e-12)
    # the Hermitian projection would not be reciprocal for elliptical antennas
    c1 = ant1.pattern.field(path_directions(pts[None])[0] @ o1)[0]
    c2 = ant2.pattern.field(-path_directions(pts[None])[1] @ o2)[0]
    c1r = ant1.pattern.field(-path_directions(pts[::-1][None])[1] @ o1)[0]
    c2r = ant2.pattern.field(path_directions(pts[::-1][None])[0] @ o2)[0]
    herm_f = np.conj(c2) @ M_f[0] @ c1
    herm_r = np.conj(c1r) @ M_r[0] @ c2r
    assert abs(herm_f - herm_r) > 1e-3 * abs(herm_f)


def test_padded_paths_equal_separate_calls():
    rng = np.random.default_rng(5)
    planes = [((0, 0, 0), np.array([0.0, 0.0, 1.0])), ((0, 6.0, 0), np.array([0.0, -1.0, 0.0])),
              ((9.0, 0, 0), np.array([-1.0, 0.0, 0.1]))]
    A, B = np.array([1.0, 2.0, 1.5]), np.array([4.0, 1.0, 2.0])
    eps = np.array([ETA_CONCRETE, 10 - 6j, 2.7 - 0.1j])
    pec = np.array([False, False, True])
    rough = np.array([1e-3, 0.0, 0.4e-3])
    model = np.array([1, 0, 0])
    k_max = 3
    P_pts = np.zeros((k_max + 1, k_max + 2, 3))
    P_nrm = np.zeros((k_max + 1, k_max, 3))
    singles = []
    for K in range(k_max + 1):
        pts, nrm = image_path(A, B, planes[:K])
        P_pts[K, :K + 2] = pts
        P_nrm[K, :K] = nrm
        P_nrm[K, K:] = rng.normal(size=(k_max - K, 3))  # junk padding
        singles.append(path_transfer(pts[None], nrm[None], eps[None, :K], pec[None, :K],
                                     rough[None, :K], model[None, :K], F_C))
    nk = np.arange(k_max + 1)
    T, L = path_transfer(P_pts, P_nrm, eps[None], pec[None], rough[None], model[None], F_C,
                         num_interactions=nk)
    for K in range(k_max + 1):
        np.testing.assert_allclose(T[K], singles[K][0][0], atol=1e-15)
        assert L[K] == singles[K][1][0]
    kd, ka = path_directions(P_pts, nk)
    np.testing.assert_allclose(ka[0], (B - A) / np.linalg.norm(B - A), atol=1e-15)


def test_bad_input_is_refused():
    pts = np.array([[[0, 0, 0], [0, 0, 0]]], float)
    with pytest.raises(ValueError, match="zero-length"):
        path_transfer(pts, np.zeros((1, 0, 3)), 1.0, False, 0.0, 0, F_C)
    with pytest.raises(ValueError, match="face_normals"):
        path_transfer(np.ones((2, 3, 3)) * [[[0, 0, 0], [1, 0, 0], [2, 1, 0]]],
                      np.zeros((2, 2, 3)), 1.0, False, 0.0, 0, F_C)
    with pytest.raises(ValueError, match="num_interactions"):
        path_directions(np.zeros((1, 3, 3)) + [[0, 0, 0], [1, 0, 0], [2, 0, 0]],
                        num_interactions=np.array([2]))
    with pytest.raises(ValueError, match="NaN"):
        path_transfer(np.full((1, 2, 3), np.nan), np.zeros((1, 0, 3)), 1.0, False, 0.0, 0, F_C)


# ---------------------------------------------------------------------------
# Doppler


def test_doppler_monostatic_closing_reflector():
    pts = np.array([[[0, 0, 0], [25.0, 0, 0], [0, 0, 0]]])
    vel = np.array([[[0, 0, 0], [-1.0, 0, 0], [0, 0, 0]]])  # closing at 1 m/s
    f = doppler_hz(pts, vel, LAM)
    assert f[0] == pytest.approx(2 * 1.0 * F_C / C0, rel=1e-14)
    assert f[0] == pytest.approx(160.11, abs=5e-3)
    # the radar closing instead gives the same (only relative motion counts)
    vel2 = np.array([[[1.0, 0, 0], [0, 0, 0], [1.0, 0, 0]]])
    assert doppler_hz(pts, vel2, LAM)[0] == pytest.approx(f[0], rel=1e-14)


def test_doppler_los_moving_tx_and_rx():
    rng = np.random.default_rng(2)
    A, B = rng.normal(size=3) * 10, rng.normal(size=3) * 10
    vA, vB = rng.normal(size=3) * 20, rng.normal(size=3) * 20
    u = (B - A) / np.linalg.norm(B - A)
    f = doppler_hz(np.array([[A, B]]), np.array([[vA, vB]]), LAM)
    assert f[0] == pytest.approx(-np.dot(vB - vA, u) / LAM, rel=1e-13)


def _fd(fun, h=1e-5):
    return (fun(h) - fun(-h)) / (2 * h)


def test_doppler_bistatic_material_points_finite_difference():
    """Tile-like scatterers (material points) on moving objects, moving tx and rx:
    exact against a central difference of L(t)."""
    rng = np.random.default_rng(4)
    for n_int in (1, 2, 3):
        x0 = rng.normal(size=(n_int + 2, 3)) * 15
        v = rng.normal(size=(n_int + 2, 3)) * 15

        def length(t, x0=x0, v=v):
            x = x0 + v * t
            return np.sum(np.linalg.norm(np.diff(x, axis=0), axis=1))

        f = doppler_hz(x0[None], v[None], LAM)[0]
        assert f == pytest.approx(-_fd(length) / LAM, rel=1e-7, abs=1e-6)


@pytest.mark.parametrize("n_planes", [1, 2])
def test_doppler_moving_planes_fermat(n_planes):
    """Specular reflections on moving planes: the exact reflection points slide,
    yet dL/dt equals the formula with each point moving with its face (Fermat)."""
    rng = np.random.default_rng(8 + n_planes)
    base = [((0, 0, 0), np.array([0.05, 0.0, 1.0])), ((0, 9.0, 0), np.array([0.1, -1.0, 0.0]))]
    planes0 = [(np.asarray(p, float), n / np.linalg.norm(n)) for p, n in base[:n_planes]]
    v_planes = rng.normal(size=(n_planes, 3)) * 10  # any translation, tangential part too
    A0, B0 = np.array([-4.0, 3.0, 1.5]), np.array([12.0, 4.0, 2.5])
    vA, vB = rng.normal(size=3) * 10, rng.normal(size=3) * 10

    def geometry(t):
        planes = [(p + vp * t, n) for (p, n), vp in zip(planes0, v_planes, strict=True)]
        return image_path(A0 + vA * t, B0 + vB * t, planes)

    def length(t):
        pts, _ = geometry(t)
        return np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1))

    pts, _ = geometry(0.0)
    vel = np.array([vA, *v_planes, vB])
    f = doppler_hz(pts[None], vel[None], LAM)[0]
    assert f == pytest.approx(-_fd(length, 1e-6) / LAM, rel=1e-6, abs=1e-4)
    # and the reflection points do slide (the test is not trivial)
    p_later, _ = geometry(1e-3)
    slide = p_later[1] - (pts[1] + v_planes[0] * 1e-3)
    assert np.linalg.norm(slide) > 1e-4


def test_doppler_padding_and_shapes():
    pts = np.array([[[0, 0, 0], [10.0, 0, 0], [99, 99, 99]]])
    vel = np.array([[[0, 0, 0], [-2.0, 0, 0], [50, 50, 50]]])
    f = doppler_hz(pts, vel, LAM, num_interactions=np.array([0]))
    assert f[0] == pytest.approx(2.0 / LAM, rel=1e-14)
    with pytest.raises(ValueError, match="velocities"):
        doppler_hz(pts, vel[:, :2], LAM)
    # padding may hold NaN (points and velocities); used points may not
    pts_nan, vel_nan = pts.copy(), vel.copy()
    pts_nan[0, 2], vel_nan[0, 2] = np.nan, np.nan
    assert doppler_hz(pts_nan, vel_nan, LAM, num_interactions=np.array([0]))[0] == f[0]
    T, L = path_transfer(pts_nan, np.full((1, 1, 3), np.nan), np.nan, False, np.nan, 0, F_C,
                         num_interactions=np.array([0]))
    assert L[0] == 10.0 and np.all(np.isfinite(T))
    with pytest.raises(ValueError, match="NaN"):
        doppler_hz(pts_nan, vel, LAM)


def test_reflected_fields_apply_the_material_dyad_without_forming_it():
    """em.reflected_fields (radio maps' bounce) equals material_reflection_dyad @ E for
    every material of the street, random incidences and normal incidence alike."""
    scene = load_scene(Path(__file__).resolve().parent.parent / "scenes/street/street.toml")
    rng = np.random.default_rng(0)
    k = rng.normal(size=(500, 3))
    k /= np.linalg.norm(k, axis=1)[:, None]
    n = rng.normal(size=(500, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    n[:5] = -k[:5]
    mat = rng.integers(0, len(scene.materials), 500)
    field = rng.normal(size=(500, 3)) + 1j * rng.normal(size=(500, 3))
    expected = np.einsum("rij,rj->ri", material_reflection_dyad(scene, mat, k, n), field)
    assert np.allclose(reflected_fields(scene, mat, k, n, field), expected, rtol=0,
                       atol=1e-14)
