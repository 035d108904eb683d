"""Physical optics of penetrable (lossy dielectric) facets against closed forms.

The currents are J = n x H_tot and M = -n x E_tot of the incident plus the locally
Fresnel-reflected field (docs/po.md, "Penetrable facets").  Closed forms, e^{+jwt},
eps_r = eps' - j eps'', isotropic antennas, sigma = |a|^2 (4 pi)^3 R_t^2 R_r^2 / lambda^2:

* square plate of area A at broadside, far field: sigma = |Gamma(0)|^2 4 pi A^2 / lambda^2,
  Gamma(0) = (1 - sqrt(eps_r)) / (1 + sqrt(eps_r)) (Knott, Shaeffer & Tuley, *Radar
  Cross Section*, 2nd ed., table 6.1, times the normal-incidence Fresnel power);
* the same plate bistatic, rx in the specular direction at incidence theta, far field:
  sigma_pp = 4 pi A^2 cos^2(theta) |r_pp(theta)|^2 / lambda^2 with pp = TE (E normal to the
  plane of incidence) or TM, r from ITU-R P.2040 / Balanis (em.fresnel_coefficients);
* circular cylinder of radius a and length L at broadside (PO, stationary phase,
  k a >> 1): sigma = 2 pi a L^2 |Gamma(0)|^2 / lambda (Knott et al., table 6.1);
* 90 deg dihedral at 45 deg to both faces: sigma_pp = 8 pi a^2 b^2 |r_pp(45 deg)|^4 / lambda^2.
"""

from __future__ import annotations

import numpy as np
import pytest
from geometry_helpers import plate_tris

from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.optics import object_optics
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.mechanisms.sbr import sbr_paths
from clradcom.paths import InteractionType
from clradcom.physics import em
from clradcom.physics.po import penetrable_po_operator, po_currents, po_transfer
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import SpecularSettings, TraceSettings, trace_scene

F_C = 24e9
LAM = em.C0 / F_C
K0 = 2 * np.pi / LAM
CONCRETE = 5.0 - 0.1j  # the paper's concrete, here without its roughness
SKIN = 16.0 - 16.0j  # skin-like at 24 GHz (Gabriel: eps' ~ 18, sigma ~ 20 S/m)


def gamma0(eps):
    return (1 - np.sqrt(eps)) / (1 + np.sqrt(eps))


def material(name, eps, **kw):
    return {"name": name, "eps_r": [float(np.real(eps)), float(np.imag(eps))], **kw}


def scene_of(objects, radars, materials=()):
    return scene_from_dict({"scene": {"name": "po_diel", "carrier_hz": F_C},
                            "materials": list(materials), "objects": objects,
                            "radars": radars})


def tri_object(verts, faces, mat, **kw):
    return {"name": "target", "material": mat, "shape": "triangles", "vertices": verts,
            "faces": faces, **kw}


def radar(name, pos, **kw):
    return {"name": name, "position": [float(p) for p in pos], "pattern": "isotropic", **kw}


def link_matrix(scene, runtime, **kw):
    """Summed PO matrix of all the scene's facets (object 0) for radars[0] -> radars[-1]."""
    geom = build_geometry(scene, runtime)
    p = po_paths(geom, scene.radars[0], scene.radars[-1], objects=[0], min_relative_db=-300,
                 **kw)
    assert np.all(p.interaction[:, 0] == int(InteractionType.PHYSICAL_OPTICS))
    return p.matrix.sum(axis=0), len(p)


def sigma(m, R_t, R_r):
    return np.abs(m) ** 2 * (4 * np.pi) ** 3 * R_t**2 * R_r**2 / LAM**2


def db(x):
    return 10 * np.log10(x)


def random_geometry(rng, n):
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    ki = rng.normal(size=(n, 3))
    ki /= np.linalg.norm(ki, axis=1, keepdims=True)
    ki = np.where((np.sum(ki * nrm, axis=1) > 0)[:, None], -ki, ki)  # lit side
    s = rng.normal(size=(n, 3))
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    return nrm, ki, s


# ---------------------------------------------------------------------------
# the operator


def test_operator_pec_limit_and_specular_identity():
    """A PEC dyad (r_te = -1, r_tm = +1) gives K = 2 (I - ss)[n x (k_i x .)] on transverse
    fields (M = 0, J = 2 n x H_inc); in the specular direction s = k_r the incident
    field's currents radiate nothing (extinction) and K = -2 cos(theta) D for any D."""
    rng = np.random.default_rng(3)
    nrm, ki, s = random_geometry(rng, 500)
    eye = np.eye(3)
    transverse = eye - ki[:, :, None] * ki[:, None, :]
    K = penetrable_po_operator(nrm, ki, s, em.reflection_dyad(ki, nrm, -1.0, 1.0))
    kn = np.sum(nrm * ki, axis=1)
    pec = 2 * (eye - s[:, :, None] * s[:, None, :]) @ (
        ki[:, :, None] * nrm[:, None, :] - kn[:, None, None] * eye)
    assert np.abs((K - pec) @ transverse).max() < 1e-14
    kr = ki - 2 * kn[:, None] * nrm
    r_te = rng.normal(size=500) + 1j * rng.normal(size=500)
    r_tm = rng.normal(size=500) + 1j * rng.normal(size=500)
    D = em.reflection_dyad(ki, nrm, r_te, r_tm)
    K = penetrable_po_operator(nrm, ki, kr, D)
    assert np.abs(K @ transverse + 2 * np.abs(kn)[:, None, None] * D).max() < 1e-14


def test_currents_radiate_the_operators_field_toward_every_direction():
    """po_currents (the radio maps' SBR footprints: one pair of currents per footprint,
    many directions): (I - s s^T) a + s x b is penetrable_po_operator's K E for random
    geometry, reflection dyads and fields, and for a PEC (no dyad) its PEC current."""
    rng = np.random.default_rng(11)
    nrm, ki, s = random_geometry(rng, 400)
    r_te = rng.normal(size=400) + 1j * rng.normal(size=400)
    r_tm = rng.normal(size=400) + 1j * rng.normal(size=400)
    field = rng.normal(size=(400, 3)) + 1j * rng.normal(size=(400, 3))
    proj = np.eye(3) - s[:, :, None] * s[:, None, :]
    # the PEC's K holds on transverse fields (the operator's own test above)
    transverse = field - ki * np.sum(ki * field, axis=1)[:, None]
    for D, e, dyad in ((em.reflection_dyad(ki, nrm, r_te, r_tm), field, None),
                       (None, transverse, em.reflection_dyad(ki, nrm, -1.0, 1.0))):
        a, b = po_currents(nrm, ki, e, D)
        got = np.einsum("fij,fj->fi", proj, a) + np.cross(s, b)
        K = penetrable_po_operator(nrm, ki, s, D if dyad is None else dyad)
        assert np.abs(got - np.einsum("fij,fj->fi", K, e)).max() < 1e-12


def test_po_transfer_with_a_pec_dyad_equals_the_pec_transfer():
    rng = np.random.default_rng(5)
    v = rng.normal(size=(200, 3, 3)) * 0.05 + [3.0, 1.0, 0.5]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    tx = np.array([0.0, 0.0, 0.0])
    rx = np.array([0.5, 4.0, -1.0])
    c = v.mean(axis=1)
    lit = np.sum((tx - c) * n, axis=1) > 0
    n = np.where(lit[:, None], n, -n)
    T0, L0, *_ = po_transfer(v, n, tx, rx, F_C)
    T1, L1, *_ = po_transfer(v, n, tx, rx, F_C,
                             lambda k, m: em.reflection_dyad(k, m, -1.0, 1.0))
    k_dep = (c - tx) / np.linalg.norm(c - tx, axis=1, keepdims=True)
    transverse = np.eye(3) - k_dep[:, :, None] * k_dep[:, None, :]
    err = np.abs((T1 - T0) @ transverse).max(axis=(1, 2))
    assert np.all(err <= 1e-12 * np.abs(T0).max(axis=(1, 2)))
    np.testing.assert_array_equal(L0, L1)


# ---------------------------------------------------------------------------
# plates


@pytest.mark.parametrize("eps", [CONCRETE, SKIN, "itu_concrete"])
def test_dielectric_plate_broadside(runtime, eps):
    D, R = 0.1, 3000.0  # far field: 2 D^2 / lambda = 1.6 m
    verts, faces = plate_tris(1, D, R)
    mats = [] if isinstance(eps, str) else [material("diel", eps)]
    scene = scene_of([tri_object(verts, faces, eps if isinstance(eps, str) else "diel")],
                     [radar("r", (0, 0, 0))], mats)
    eps_r = scene.material_eps_r[scene.objects[0].material]
    M, n = link_matrix(scene, runtime)
    assert n == 2
    want = abs(gamma0(eps_r)) ** 2 * 4 * np.pi * D**4 / LAM**2
    for pol in (0, 1):
        assert abs(db(sigma(M[pol, pol], R, R) / want)) < 1e-3, pol  # measured < 1e-5 dB
    # polarimetric: Gamma(0) (= r_te(0)) times the PEC plate's matrix, sign included
    pec = scene_of([tri_object(verts, faces, "metal")], [radar("r", (0, 0, 0))])
    M_pec, _ = link_matrix(pec, runtime)
    np.testing.assert_allclose(M, -gamma0(eps_r) * M_pec, rtol=1e-6, atol=1e-9 * abs(M).max())


def test_rough_plate_carries_the_specular_share(runtime):
    """Roughness and the diffuse share act on the PO currents as on a GO reflection:
    sigma = rho^2 (1 - S^2) |Gamma(0)|^2 4 pi A^2/lambda^2, rho = exp(-2 (k sigma_h)^2)."""
    D, R, h, S = 0.1, 3000.0, 1e-3, 0.5
    verts, faces = plate_tris(1, D, R)
    scene = scene_of([tri_object(verts, faces, "rough")], [radar("r", (0, 0, 0))],
                     [material("rough", CONCRETE, roughness_m=h, scattering_coefficient=S)])
    M, _ = link_matrix(scene, runtime)
    rho = np.exp(-2 * (K0 * h) ** 2)
    want = rho**2 * (1 - S**2) * abs(gamma0(CONCRETE)) ** 2 * 4 * np.pi * D**4 / LAM**2
    assert abs(db(sigma(M[0, 0], R, R) / want)) < 1e-3


def test_pec_limit_of_a_large_permittivity(runtime):
    """|eps_r| -> infinity: the full bistatic polarimetric matrix of an oblique plate tends
    to the PEC plate's (r_te + 1, r_tm - 1 ~ 1/sqrt|eps_r|)."""
    verts, faces = plate_tris(3, 0.1, 20.0, centre=(0.3, -0.2), tilt_deg=20.0)
    radars = [radar("t", (0, 0, 0), role="tx"), radar("x", (1.0, 8.0, 3.0), role="rx")]
    M_pec, n = link_matrix(scene_of([tri_object(verts, faces, "metal")], radars), runtime)
    assert n == 18
    for eps, tol in ((1e12 * (1 - 1j), 1e-5), (1e6 - 1e6j, 5e-3)):
        scene = scene_of([tri_object(verts, faces, "big")], radars, [material("big", eps)])
        M, _ = link_matrix(scene, runtime)
        assert np.linalg.norm(M - M_pec) < tol * np.linalg.norm(M_pec), eps


@pytest.mark.parametrize("theta_deg", [30.0, 60.0, 80.0])
@pytest.mark.parametrize("eps", [CONCRETE, SKIN])
def test_bistatic_specular_far_field_follows_te_and_tm(runtime, eps, theta_deg):
    """Plate in the x = 0 plane facing -x; tx and rx at 3 km, at +-theta in the xy plane
    (rx in the specular direction).  V = -z is TE, H lies in the plane of incidence (TM):
    sigma_VV = 4 pi A^2 cos^2 theta |r_te|^2 / lambda^2, sigma_HH likewise with r_tm."""
    D, R = 0.1, 3000.0
    th = np.radians(theta_deg)
    verts, faces = plate_tris(1, D, 0.0)
    radars = [radar("t", (-R * np.cos(th), -R * np.sin(th), 0), role="tx"),
              radar("x", (-R * np.cos(th), R * np.sin(th), 0), role="rx")]
    scene = scene_of([tri_object(verts, faces, "diel")], radars, [material("diel", eps)])
    M, _ = link_matrix(scene, runtime)
    r_te, r_tm = em.fresnel_coefficients(eps, np.cos(th))
    plate = 4 * np.pi * D**4 * np.cos(th) ** 2 / LAM**2
    got_te, got_tm = sigma(M[0, 0], R, R), sigma(M[1, 1], R, R)
    assert abs(db(got_te / (plate * abs(r_te) ** 2))) < 1e-3
    assert abs(db(got_tm / (plate * abs(r_tm) ** 2))) < 1e-3
    assert abs(M[0, 1]) < 1e-6 * abs(M[0, 0]) and abs(M[1, 0]) < 1e-6 * abs(M[0, 0])
    # the complex TM/TE ratio is the GO reflection's (phases of r_te, r_tm included)
    go = _go_matrix(scene, eps)
    np.testing.assert_allclose(M[1, 1] / M[0, 0], go[1, 1] / go[0, 0], rtol=1e-6)
    # the normal-incidence weight -r_te(0) of old missed this by up to 16 dB (TM at 60°)
    if theta_deg == 60.0 and eps == CONCRETE:
        assert db(got_tm / (plate * abs(gamma0(eps)) ** 2)) < -10


def _go_matrix(scene, eps):
    """GO image-path matrix (em, eqs. P3-P6) of the plate's centre between radars 0, 1."""
    tx, rx = scene.radars[0], scene.radars[-1]
    pts = np.array([[tx.position, [0.0, 0.0, 0.0], rx.position]], dtype=float)
    T, L = em.path_transfer(pts, np.array([[[-1.0, 0.0, 0.0]]]), eps, False, 0.0, 0, F_C)
    k_dep, k_arr = em.path_directions(pts)
    return em.polarimetric_matrix(T, L, k_dep, k_arr, tx.orientation, rx.orientation, F_C)[0]


@pytest.mark.parametrize("theta_deg", [30.0, 45.0])
def test_large_oblique_plate_equals_go_reflection(runtime, theta_deg):
    """1 m plate, tx and rx 2 m from its centre at +-theta (near field: ~20 Fresnel zones
    across): PO converges to the GO reflection of the material, TE and TM each.  The
    finite plate's edge ripple is what separates them; the PEC plate measures it
    (PO/GO = -0.2 ... -0.6 dB here), and the dielectric's PO/GO equals the PEC's within
    0.1 dB (the rest: r varies over the first Fresnel zone, ~3 deg wide)."""
    size, d, n = 1.0, 2.0, 50  # 2 cm facets: each in its own far field
    th = np.radians(theta_deg)
    verts, faces = plate_tris(n, size, 0.0)
    radars = [radar("t", (-d * np.cos(th), -d * np.sin(th), 0), role="tx"),
              radar("x", (-d * np.cos(th), d * np.sin(th), 0), role="rx")]
    pec = scene_of([tri_object(verts, faces, "metal")], radars)
    M_pec, _ = link_matrix(pec, runtime)
    go_pec = _go_matrix(pec, np.inf)
    edge = np.abs(np.diag(M_pec / go_pec)) ** 2
    assert np.all(np.abs(db(edge)) < 1.0), db(edge)
    for eps in (CONCRETE, SKIN):
        scene = scene_of([tri_object(verts, faces, "diel")], radars, [material("diel", eps)])
        M, _ = link_matrix(scene, runtime)
        ratio = np.abs(np.diag(M / _go_matrix(scene, eps))) ** 2
        assert np.all(np.abs(db(ratio)) < 1.0), (eps, db(ratio))
        assert np.all(np.abs(db(ratio / edge)) < 0.1), (eps, db(ratio / edge))


# ---------------------------------------------------------------------------
# a pedestrian-sized cylinder, and which objects get PO


def cylinder(a, h, n):
    """Open vertical tube of n flat panels (2n triangles), radius a, from z = 0 to h,
    wound with outward normals."""
    ang = 2 * np.pi * np.arange(n) / n
    bot = np.stack([a * np.cos(ang), a * np.sin(ang), np.zeros(n)], axis=1)
    verts = np.vstack([bot, bot + [0.0, 0.0, h]])
    faces = []
    for i in range(n):
        j = (i + 1) % n
        faces += [[i, j, n + j], [i, n + j, n + i]]
    return verts.tolist(), faces


def test_dielectric_cylinder_broadside_through_trace_scene(runtime):
    """Skin-like cylinder, a = 15 cm, L = 1.7 m (k a = 75), optics = "po", monostatic at
    3 km (2 L^2/lambda = 460 m): sigma = 2 pi a L^2 |Gamma(0)|^2 / lambda.  Faceting: with
    256 panels (3.7 mm, 0.3 lambda, against a Fresnel-zone width sqrt(lambda a / 2) = 31 mm)
    the facet sum is within 0.01 dB; 128 panels give -0.3 dB, 64 give -1.0 dB."""
    a, h, n, R = 0.15, 1.7, 256, 3000.0
    verts, faces = cylinder(a, h, n)
    want = 2 * np.pi * a * h**2 * abs(gamma0(SKIN)) ** 2 / LAM
    settings = TraceSettings(specular=SpecularSettings(max_reflections=2, rays=20_000))
    for optics in ("po", "both"):
        scene = scene_of([tri_object(verts, faces, "skin", optics=optics)],
                         [radar("r", (R, 0.0, h / 2))], [material("skin", SKIN)])
        p = trace_scene(scene, settings, runtime=runtime).links[0].paths
        assert p.n_paths == n  # the lit half of the 2n triangles; no SBR path (convex)
        assert np.all(p.interaction[:, 0] == int(InteractionType.PHYSICAL_OPTICS))
        got = sigma(p.matrix.sum(axis=0)[0, 0], R, R)
        assert abs(db(got / want)) < 0.1, (optics, db(got / want))
    # without its own optics key skin (|Gamma(0)|^2 = -3.4 dB) is a body, a target: it
    # takes the mode's default like a metal; concrete (-8.4 dB) stays GO
    scene = scene_of([tri_object(verts, faces, "skin")], [radar("r", (R, 0.0, h / 2))],
                     [material("skin", SKIN)])
    assert [object_optics(scene, m)[0] for m in ("none", "pec", "sbr")] == ["go", "both",
                                                                            "po"]
    wall = scene_of([tri_object(verts, faces, "wall")], [radar("r", (R, 0.0, h / 2))],
                    [material("wall", CONCRETE)])
    assert [object_optics(wall, m)[0] for m in ("none", "pec", "sbr")] == ["go"] * 3
    p = trace_scene(scene, settings, runtime=runtime).links[0].paths  # mode "none"
    assert not np.any(p.interaction == int(InteractionType.PHYSICAL_OPTICS))


# ---------------------------------------------------------------------------
# SBR: the radiating bounce on a dielectric


def dihedral(a, b, mat, n=2):
    """Fold of length a along z through the origin, plates of width b opening to +x."""
    s2 = 1 / np.sqrt(2)
    verts, faces = [], []
    for u, n_want in (((s2, s2, 0.0), (s2, -s2, 0.0)), ((s2, -s2, 0.0), (s2, s2, 0.0))):
        u, n_want = b * np.array(u), np.array(n_want)
        off = len(verts)
        p0 = np.array([0.0, 0.0, -a / 2])
        z = np.array([0.0, 0.0, a])
        verts += [p0 + u * i / n + z * j / n for i in range(n + 1) for j in range(n + 1)]
        for i in range(n):
            for j in range(n):
                q = off + i * (n + 1) + j
                r = q + n + 1
                for t in ([q, r, r + 1], [q, r + 1, q + 1]):
                    nn = np.cross(verts[t[1]] - verts[t[0]], verts[t[2]] - verts[t[0]])
                    faces.append(t if nn @ n_want > 0 else [t[0], t[2], t[1]])
    return tri_object(np.array(verts).tolist(), faces, mat)


def test_sbr_dielectric_dihedral(runtime):
    """Double bounce of a concrete dihedral at 45 deg to both faces (fold along V):
    VV is TE at both faces and HH is TM, so the SBR return is the PEC corner's times
    r_te(45)^2 and r_tm(45)^2: the chain's first Fresnel dyad times the radiating
    footprint's penetrable currents, and sigma_pp = 8 pi a^2 b^2 |r_pp|^4/lambda^2."""
    a, b, R = 0.12, 0.08, 100.0
    m = {}
    for mat in ("metal", "diel"):
        scene = scene_of([dihedral(a, b, mat)], [radar("r", (R, 0.0, 0.0))],
                         [material("diel", CONCRETE)])
        geom = build_geometry(scene, runtime)
        r = scene.radars[0]
        p = sbr_paths(geom, r, r, objects=[0], spacing_wavelengths=0.125, max_bounces=2,
                      min_relative_db=-300)
        assert set(p.n_interactions.tolist()) == {2}
        m[mat] = p.matrix.sum(axis=0)
    r_te, r_tm = em.fresnel_coefficients(CONCRETE, np.cos(np.pi / 4))
    ratio = np.diag(m["diel"]) / np.diag(m["metal"])
    np.testing.assert_allclose(ratio, [r_te**2, r_tm**2], rtol=2e-3)  # tubes fan out by 1 mrad
    corner = 8 * np.pi * a**2 * b**2 / LAM**2
    for pol, r in ((0, r_te), (1, r_tm)):
        # tube pitch lambda/8 stair-steps the aperture (PEC: 0.994 of the closed form)
        assert abs(db(sigma(m["diel"][pol, pol], R, R) / (corner * abs(r) ** 4))) < 0.15
