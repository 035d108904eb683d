"""Diffuse (Lambertian, effective-roughness) tile scattering (clradcom.mechanisms.scattering).

Reference: docs/reference/propagation-physics.md §3 (hemisphere power
S^2 Gamma^2 P_inc; tile RCS sigma = 4 S^2 Gamma^2 A cos^2 theta, -25.0 dBsm for
A = 0.01 m^2, S = 0.5, Gamma = 0.562; incoherent sum independent of tile size).
Radar equation with isotropic antennas: |a|^2 = lambda^2 sigma / ((4 pi)^3 R^4).
"""

from __future__ import annotations

import numpy as np
import pytest
from geometry_helpers import plate_tris

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


def test_default_tile_size_and_cap(runtime):
    v, f = plate(2.0, x=5.0)
    sc = make_scene([obj("p", v, f)], [radar((0.0, 0.0, 0.0))])
    geom = build_geometry(sc, runtime)
    r = sc.radars[0]
    p, _ = scattering_paths(geom, r, r, threshold_db=-200)
    d = choose_tile_size(LAM, np.linalg.norm(geom.scene.triangles.mean(axis=1), axis=-1).min())
    n = int(np.ceil(2 * np.sqrt(2) / d))
    assert len(p) == 2 * n * n
    small, _ = scattering_paths(geom, r, r, threshold_db=-200, max_tiles=50)
    assert 0 < len(small) <= 50
    with pytest.raises(ValueError, match="max_tiles"):
        scattering_paths(geom, r, r, tile_size_m=0.01, max_tiles=1000)


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
