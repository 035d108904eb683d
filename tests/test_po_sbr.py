"""SBR-PO multi-bounce returns (clradcom.mechanisms.sbr) and the per-object optics switch.

Closed forms (Knott, Shaeffer & Tuley, *Radar Cross Section*, 2nd ed., table 6.1;
docs/reference/propagation-physics.md §6), monostatic, PEC:

* 90° dihedral, fold length a, plate width b, incidence perpendicular to the fold
  at 45° to both plates: sigma = 8 pi a^2 b^2 / lambda^2; BSA matrix ~ diag(1, -1)
  with the fold along V (two mirrors about planes holding the fold: E along the fold
  keeps its sign, E across it flips);
* square trihedral, edge a, along its symmetry axis: sigma = 12 pi a^4 / lambda^2,
  all of the aperture sqrt(3) a^2 triple-bounced; BSA matrix ~ I (three mirrors
  about orthogonal planes give -I on the field, three PEC sign flips undo it);
* PEC sphere, physical optics, radius a: the lit-hemisphere integral
  sigma = 16 pi^3 a^4/lambda^2 |e^{jb}/(jb) + (e^{jb} - 1)/b^2|^2, b = 2 k a, which
  tends to pi a^2 (ripple 1/(k a)).

sigma = |M_pp|^2 (4 pi)^3 R^4 / lambda^2 for isotropic antennas at range R.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

from clradcom.errors import SceneError
from clradcom.evaluation.corners import quad, triangles_object
from clradcom.mechanisms import specular as sp
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.optics import object_optics
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.mechanisms.sbr import launch_tubes, sbr_paths
from clradcom.mechanisms.specular import path_fields, specular_paths
from clradcom.paths import InteractionType
from clradcom.physics.em import C0
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import (
    DiffractionSettings,
    OpticsSettings,
    SpecularSettings,
    TraceSettings,
    trace_scene,
)

F_C = 24e9
LAM = C0 / F_C
K0 = 2 * np.pi / LAM
S2 = 1 / np.sqrt(2)


tri_object = triangles_object


def dihedral(a, b, n=2, **kw):
    """Fold of length a along z through the origin, plates of width b opening to +x."""
    z = np.array([0.0, 0.0, a])
    p0 = np.array([0.0, 0.0, -a / 2])
    return tri_object("dihedral", [
        quad(p0, b * np.array([S2, S2, 0.0]), z, n, n, np.array([S2, -S2, 0.0])),
        quad(p0, b * np.array([S2, -S2, 0.0]), z, n, n, np.array([S2, S2, 0.0]))], **kw)


def trihedral(a, n=2):
    X, Y, Z = np.eye(3)
    o = np.zeros(3)
    return tri_object("trihedral", [quad(o, a * Y, a * Z, n, n, X),
                                    quad(o, a * X, a * Z, n, n, Y),
                                    quad(o, a * X, a * Y, n, n, Z)])


def scene_of(objects, positions, carrier=F_C):
    radars = [{"name": f"r{i}", "position": [float(x) for x in p], "pattern": "isotropic"}
              for i, p in enumerate(positions)]
    return scene_from_dict({"scene": {"name": "sbr", "carrier_hz": carrier},
                            "objects": objects, "radars": radars})


def sigma(m, R):
    return np.abs(m) ** 2 * (4 * np.pi) ** 3 * R**4 / LAM**2


def monostatic(geom, radar, spacing=0.125, max_bounces=3):
    """PO facets (first bounce) + SBR (later bounces), each (P,2,2) matrix summed."""
    p1 = po_paths(geom, radar, radar, min_relative_db=-300)
    p2 = sbr_paths(geom, radar, radar, objects=[0], spacing_wavelengths=spacing,
                   max_bounces=max_bounces, min_relative_db=-300)
    return p1, p2


# ---------------------------------------------------------------------------
# corners


def test_dihedral_rcs_and_polarimetry(runtime):
    a, b, R = 0.12, 0.08, 100.0  # 2 D^2/lambda ~ 2.3 m
    scene = scene_of([dihedral(a, b)], [(R, 0.0, 0.0)])
    geom = build_geometry(scene, runtime)
    p1, p2 = monostatic(geom, scene.radars[0])
    assert set(p2.n_interactions.tolist()) == {2}
    M = p1.matrix.sum(axis=0) + p2.matrix.sum(axis=0)
    want = 8 * np.pi * a**2 * b**2 / LAM**2
    # tube grid lambda/8: the aperture edges are stair-stepped to ~1 % of the area; the
    # single-bounce plate sidelobes (-33 dB) beat against the corner by +-0.2 dB
    for pol in (0, 1):
        assert abs(10 * np.log10(sigma(M[pol, pol], R) / want)) < 0.3, pol
    m2 = p2.matrix.sum(axis=0)
    assert abs(10 * np.log10(sigma(m2[0, 0], R) / want)) < 0.15
    # fold along V: VV = -HH, no cross-polarisation
    assert abs(m2[0, 0] / m2[1, 1] + 1) < 0.01
    assert abs(m2[0, 1]) < 1e-3 * abs(m2[0, 0]) and abs(m2[1, 0]) < 1e-3 * abs(m2[0, 0])


def test_dihedral_rolled_45_degrees_is_all_cross_polar(runtime):
    """Fold at 45° to V: diag(1,-1) rotated by 45° is [[0,1],[1,0]]: co-pol vanishes."""
    a, b, R = 0.1, 0.1, 100.0
    obj = dihedral(a, b, rotation_deg=[45.0, 0.0, 0.0])
    scene = scene_of([obj], [(R, 0.0, 0.0)])
    geom = build_geometry(scene, runtime)
    _, p2 = monostatic(geom, scene.radars[0])
    m2 = p2.matrix.sum(axis=0)
    assert abs(m2[0, 0]) < 0.02 * abs(m2[0, 1]) and abs(m2[1, 1]) < 0.02 * abs(m2[0, 1])
    assert abs(10 * np.log10(sigma(m2[0, 1], R) / (8 * np.pi * a**4 / LAM**2))) < 0.15


def test_square_trihedral_rcs_polarimetry_and_go_phase(runtime):
    a, R = 0.1, 100.0
    pos = R * np.ones(3) / np.sqrt(3)
    scene = scene_of([trihedral(a)], [pos])
    geom = build_geometry(scene, runtime)
    radar = scene.radars[0]
    p1, p2 = monostatic(geom, radar)
    want = 12 * np.pi * a**4 / LAM**2
    M = p1.matrix.sum(axis=0) + p2.matrix.sum(axis=0)
    for pol in (0, 1):
        assert abs(10 * np.log10(sigma(M[pol, pol], R) / want)) < 0.3, pol
    m3 = p2.matrix[p2.n_interactions == 3].sum(axis=0)
    assert abs(10 * np.log10(sigma(m3[0, 0], R) / want)) < 0.15
    assert abs(m3[0, 0] / m3[1, 1] - 1) < 0.01  # odd bounce: VV = HH
    # two bounces only: no retro-reflection, nothing comes back
    p2b = sbr_paths(geom, radar, radar, objects=[0], spacing_wavelengths=0.125,
                    max_bounces=2, min_relative_db=-300)
    assert sigma(p2b.matrix.sum(axis=0)[0, 0], R) < 1e-3 * want
    # against the GO image path of the same corner (em.path_transfer, image method): the
    # aperture's PO is j A_eff L / (lambda R_t R_r) times the GO mirror, A_eff = sqrt(3) a^2.
    # Monostatic GO is degenerate (the image -tx lies on the line through the apex), so
    # rx moves 5 cm aside: 0.5 mrad, deep inside the corner's lobe (lambda / a ~ 0.1 rad)
    rx_pos = pos + 0.05 * np.array([1.0, -1.0, 0.0]) / np.sqrt(2)
    scene2 = scene_of([trihedral(a)], [pos, rx_pos])
    geom2 = build_geometry(scene2, runtime)
    tx, rx = scene2.radars
    grid = launch_tubes(pos, [(np.full(3, a / 2), a)], 0.01)
    seqs = sp.reflection_sequences(geom2.caster, geom2.faces.tri_face, pos, grid.directions, 3)
    pg = specular_paths(geom2, pos, rx_pos, sp.unique_candidates(seqs), line_of_sight=False)
    go = path_fields(geom2, pg, tx, rx)
    go3 = go.matrix[go.n_interactions == 3]
    assert len(go3) == 1  # one order of the three mirrors reaches rx exactly
    sb = sbr_paths(geom2, tx, rx, objects=[0], spacing_wavelengths=0.125,
                   min_relative_db=-300)
    m3 = sb.matrix[sb.n_interactions == 3].sum(axis=0)
    fraunhofer = 1j * np.sqrt(3) * a**2 * (R + np.linalg.norm(rx_pos)) / (
        LAM * R * np.linalg.norm(rx_pos))
    # every order retro-reflects alike, so the one GO path stands for the whole aperture
    ratio = m3[[0, 1], [0, 1]] / (fraunhofer * go3[0][[0, 1], [0, 1]])
    np.testing.assert_allclose(ratio, 1.0, atol=0.03)  # measured 0.992 - 0.017j
    assert abs(m3[0, 1]) < 1e-2 * abs(m3[0, 0]) and abs(m3[1, 0]) < 1e-2 * abs(m3[0, 0])


# ---------------------------------------------------------------------------
# faceted sphere


def test_faceted_sphere_converges_to_pi_a2(runtime):
    a, R = 0.1, 100.0  # k a = 50
    b = 2 * K0 * a
    po_sphere = 16 * np.pi**3 * a**4 / LAM**2 * abs(
        np.exp(1j * b) / (1j * b) + (np.exp(1j * b) - 1) / b**2) ** 2
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(4, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rms = []
    for sub in (2, 3, 4, 5):  # 320 .. 20480 facets, edges 0.9 .. 0.05 a
        m = trimesh.creation.icosphere(subdivisions=sub, radius=a)
        obj = {"name": "sphere", "material": "metal", "shape": "triangles",
               "vertices": m.vertices.tolist(), "faces": m.faces.tolist()}
        scene = scene_of([obj], R * dirs)
        geom = build_geometry(scene, runtime)
        sig = np.array([sigma(po_paths(geom, r, r, min_relative_db=-300).gain.sum(), R)
                        for r in scene.radars])
        rms.append(float(np.sqrt(np.mean(np.square(sig / po_sphere - 1.0)))))
        if sub == 3:  # convex: no tube comes back to the body, SBR adds nothing
            r = scene.radars[0]
            assert len(sbr_paths(geom, r, r, objects=[0], min_relative_db=-300)) == 0
    # measured rms: 0.35, 0.12, 0.073, 0.0023
    assert all(x > y for x, y in zip(rms, rms[1:], strict=False)), rms
    assert rms[-1] < 0.01
    # and so toward the optical limit pi a^2, up to the smooth sphere's own PO ripple
    assert abs(po_sphere / (np.pi * a * a) - 1) < 1.0 / (K0 * a)
    np.testing.assert_allclose(sig / (np.pi * a * a), 1.0, atol=0.01)


# ---------------------------------------------------------------------------
# tubes, bookkeeping


def test_tube_grid_covers_the_cone_once():
    tx = np.array([0.0, 0.0, 0.0])
    c1, r1 = np.array([10.0, 0.0, 0.0]), 1.0
    g = launch_tubes(tx, [(c1, r1)], 0.01)
    cone = 2 * np.pi * (1 - np.sqrt(1 - (r1 / 10.0) ** 2))
    # every lattice cell inside the cone is a tube; the grid overshoots by one pitch
    assert cone < g.solid_angle.sum() < cone * (1 + 2 * 0.01 / 1.0 * 1.2)
    assert np.all(np.einsum("ij,ij->i", g.directions, g.edge1) < 1e-12)
    # a second sphere overlapping the first cone: the overlap is shot once
    c2 = np.array([20.0, 1.5, 0.0])
    g2 = launch_tubes(tx, [(c1, r1), (c2, 1.0)], 0.01)
    np.testing.assert_array_equal(g2.directions[:len(g)], g.directions)
    rest = g2.directions[len(g):]
    assert len(rest) > 1000 and np.all(rest @ (c1 / 10.0) < np.sqrt(1 - 0.01))
    with pytest.raises(ValueError, match="inside the bounding sphere"):
        launch_tubes(c1, [(c1, r1)], 0.01)
    with pytest.raises(ValueError, match="spacing_m"):
        launch_tubes(tx, [(c1, r1)], -1.0)
    with pytest.raises(ValueError, match="max_rays"):
        launch_tubes(tx, [(c1, r1)], 1e-4, max_rays=1000)


def test_moving_dihedral_doppler_delay_and_points(runtime):
    a, R, v = 0.1, 30.0, 3.0
    obj = dihedral(a, a, velocity=[v, 0.0, 0.0])  # closing on the radar at +x
    scene = scene_of([obj], [(R, 0.0, 0.0)])
    geom = build_geometry(scene, runtime)
    r = scene.radars[0]
    p = sbr_paths(geom, r, r, objects=[0], spacing_wavelengths=0.25)
    assert len(p) >= 1 and np.all(p.n_interactions == 2)
    # a corner's double bounce retro-reflects across the fold: unfolded length 2 R and
    # Doppler 2 v / lambda, up to the tube's height on the fold (z/R)^2 ~ 1e-6
    np.testing.assert_allclose(p.doppler_hz, 2 * v / LAM, rtol=1e-5)
    np.testing.assert_allclose(p.delay_s, 2 * R / C0, rtol=1e-5)
    seg = np.linalg.norm(np.diff(p.points[:, :4], axis=1), axis=2).sum(axis=1)
    np.testing.assert_allclose(seg, p.delay_s * C0, rtol=1e-12)
    assert np.all(p.object_id[:, :2] == 0) and np.all(p.face_id[:, :2] >= 0)


# ---------------------------------------------------------------------------
# the per-object switch through trace_scene


def dihedral_aperture_factor(a, b, tx, rx, n=96):
    """|field of a finite 90-degree dihedral's double bounce| / |GO's (infinite corner)|
    for the fold of length ``a`` along z and plates of width ``b`` of :func:`dihedral`,
    tx and rx near its axis (+x): the double bounce is the field of tx's image (tx turned
    half a turn about the fold), seen through the corner's mouth projected on the plane
    x = 0, |y| <= b / sqrt 2, |z| <= a / 2 (exact for a wave along the axis). Kirchhoff's
    integral with exact spherical phases and unit obliquity:
    F = (j / lambda) int L / (rho1 rho2) e^{-j k (rho1 + rho2 - L)} dA, rho1 and rho2
    the distances to the image and to rx, L = |rx - image| (|F| -> 1 for an infinite
    aperture: stationary phase). Knott, Shaeffer & Tuley ch. 5; Born & Wolf §8.3."""
    image = np.array([-tx[0], -tx[1], tx[2]])
    L = np.linalg.norm(rx - image)
    x, w = np.polynomial.legendre.leggauss(n)
    half_y, half_z = b * S2, a / 2
    y, z = np.meshgrid(half_y * x, half_z * x, indexing="ij")
    weight = np.outer(w, w) * half_y * half_z
    pts = np.stack([np.zeros_like(y), y, z], axis=-1)
    rho1 = np.linalg.norm(pts - image, axis=-1)
    rho2 = np.linalg.norm(pts - rx, axis=-1)
    f = 1j / LAM * np.sum(weight * L / (rho1 * rho2) * np.exp(-1j * K0 * (rho1 + rho2 - L)))
    return abs(f)


def go_po_trace(runtime, obj_optics, physical_optics, R=3.0):
    """tx -> rx paths off a dihedral; rx 10 cm aside of tx, since the monostatic GO double
    bounce of a dihedral is degenerate (its image path runs through the fold)."""
    obj = dihedral(0.1, 0.1)
    if obj_optics is not None:
        obj["optics"] = obj_optics
    scene = scene_from_dict({
        "scene": {"name": "sbr", "carrier_hz": F_C}, "objects": [obj],
        "radars": [{"name": "tx", "position": [R, 0.0, 0.0], "role": "tx"},
                   {"name": "rx", "position": [R, 0.1, 0.0], "role": "rx"}]})
    st = TraceSettings(
        specular=SpecularSettings(max_reflections=2, rays=200_000, line_of_sight=False),
        diffraction=DiffractionSettings(max_diffractions=0),
        optics=OpticsSettings(mode=physical_optics, sbr_spacing_wavelengths=0.25))
    return trace_scene(scene, st, runtime=runtime).links[0].paths


def test_optics_switch_per_object(runtime):
    go = go_po_trace(runtime, None, "none")
    # pure GO: the dihedral's double bounce is one image path
    assert np.all(go.n_interactions == 2) and len(go) == 1
    forced_go = go_po_trace(runtime, "go", "sbr")
    np.testing.assert_allclose(forced_go.gain, go.gain, rtol=1e-12)
    po = go_po_trace(runtime, "po", "none")
    assert set(po.n_interactions.tolist()) == {1, 2}
    assert np.sum(po.n_interactions == 1) == 16  # every facet of both plates is lit
    two = po.gain[po.n_interactions == 2]
    assert len(two) >= 1 and not np.any(np.isin(two, go.gain))  # SBR, not GO
    same = go_po_trace(runtime, None, "sbr")  # the scene-level default for PEC objects
    np.testing.assert_allclose(np.sort_complex(same.gain), np.sort_complex(po.gain),
                               rtol=1e-12)
    both = go_po_trace(runtime, "both", "none")
    np.testing.assert_allclose(np.sort_complex(both.gain[both.n_interactions == 2]),
                               np.sort_complex(go.gain), rtol=1e-12)
    assert np.sum(both.n_interactions == 1) == 16
    # "both": PO facets for the first bounce, the GO double bounce kept as REFLECTION
    one = both.n_interactions == 1
    assert np.all(both.interaction[one, 0] == InteractionType.PHYSICAL_OPTICS)
    assert np.all(both.interaction[~one] == InteractionType.REFLECTION)
    assert np.all(go.interaction == InteractionType.REFLECTION)
    # 3 m is inside the corner's Fraunhofer distance: GO's image path is the field of an
    # infinite corner, SBR-PO the finite corner's; their ratio is the Kirchhoff factor of
    # the corner's aperture (a closed form of the geometry: dihedral_aperture_factor).
    # 1 dB: the mouth projected along the axis is the double-bounce aperture of a plane
    # wave; from 3 m the spherical wave's differs by ~b/R (3 % of its width, 0.3 dB), and
    # tubes at lambda/4 stair-step its edges by up to 3 mm on 14 x 10 cm (+-0.4 dB)
    ratio = abs(two.sum()) / abs(go.gain.sum())
    want = dihedral_aperture_factor(0.1, 0.1, np.array([3.0, 0.0, 0.0]),
                                    np.array([3.0, 0.1, 0.0]))
    error_db = 20 * np.log10(ratio / want)
    print(f"SBR / GO double bounce at 3 m: {ratio:.4f}, aperture factor {want:.4f} "
          f"({error_db:+.2f} dB)")
    assert abs(error_db) < 1.0, (ratio, want)
    np.testing.assert_allclose(po.delay_s[po.n_interactions == 2], go.delay_s[0], rtol=1e-3)


def test_po_and_sbr_returns_carry_their_own_codes(runtime):
    """Format 2 tells the mechanisms apart: a PEC plate whose optics is "po" returns PO
    facet paths coded PHYSICAL_OPTICS in place of its GO mirror path (REFLECTION); a
    dihedral's two-bounce SBR returns are coded SBR at both bounces."""
    plate = tri_object("plate", [quad(np.array([2.0, -0.1, -0.1]), np.array([0.0, 0.2, 0.0]),
                                      np.array([0.0, 0.0, 0.2]), 1, 1,
                                      np.array([-1.0, 0.0, 0.0]))])
    settings = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=20_000),
                             diffraction=DiffractionSettings(max_diffractions=0))
    go = trace_scene(scene_of([plate], [(0.0, 0.0, 0.0)]), settings,
                     runtime=runtime).links[0].paths
    assert go.n_paths == 1 and go.interaction.tolist() == [[InteractionType.REFLECTION]]
    po = trace_scene(scene_of([{**plate, "optics": "po"}], [(0.0, 0.0, 0.0)]), settings,
                     runtime=runtime).links[0].paths
    assert po.n_paths == 2 and np.all(po.n_interactions == 1)  # one per triangle
    assert np.all(po.interaction[:, 0] == InteractionType.PHYSICAL_OPTICS)
    assert sorted(po.face_id[:, 0].tolist()) == [0, 1] and np.all(po.object_id[:, 0] == 0)

    corner = go_po_trace(runtime, "po", "none")
    two = corner.n_interactions == 2
    assert two.any() and np.all(corner.interaction[two] == InteractionType.SBR)
    assert np.all(corner.interaction[~two, 0] == InteractionType.PHYSICAL_OPTICS)
    assert not np.any(corner.interaction == InteractionType.REFLECTION)


def test_optics_key_in_the_scene_file():
    obj = dihedral(0.1, 0.1, optics="po")
    scene = scene_of([obj], [(3.0, 0.0, 0.0)])
    assert scene.objects[0].optics == "po"
    assert object_optics(scene, "none") == ["po"]
    plain = scene_of([dihedral(0.1, 0.1)], [(3.0, 0.0, 0.0)])
    assert plain.objects[0].optics is None
    assert [object_optics(plain, m)[0] for m in ("none", "pec", "sbr")] == ["go", "both", "po"]
    assert plain.content_hash() != scene.content_hash()
    concrete = scene_of([dihedral(0.1, 0.1, material="itu_concrete")], [(3.0, 0.0, 0.0)])
    assert object_optics(concrete, "sbr") == ["go"]  # the default: conductors and bodies only
    with pytest.raises(SceneError, match=r"objects\[0\]\.optics.*mirror"):
        scene_of([dihedral(0.1, 0.1, optics="mirror")], [(3.0, 0.0, 0.0)])
    # "po" is an object's optics, not a scene-level mode
    with pytest.raises(ValueError, match=r"OpticsSettings\.mode = 'po': must be one of"):
        OpticsSettings(mode="po")
    with pytest.raises(ValueError,
                       match=r"^OpticsSettings\.sbr_spacing_wavelengths = 0\.0: must"):
        OpticsSettings(sbr_spacing_wavelengths=0.0)


def test_radar_inside_an_sbr_object_is_skipped_with_a_warning(runtime):
    scene = scene_of([dihedral(0.3, 0.3)], [(0.05, 0.0, 0.0)])
    geom = build_geometry(scene, runtime)
    r = scene.radars[0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        p = sbr_paths(geom, r, r, objects=[0])
    assert len(p) == 0
    assert any("dihedral" in str(w.message) for w in caught)


# ---------------------------------------------------------------------------
# tools/rcs_aspect.py


def test_rcs_aspect_tool_go_mirror_and_outputs(tmp_path, capsys):
    """The face-centred rounded car has facets whose normals are exactly +x and +y, so GO
    sees an infinite plane mirror at d = R - length/2 (nose) and R - width/2 (side):
    |a| = lambda / (8 pi d), i.e. an apparent sigma(R) = pi R^4 / d^2."""
    import csv

    from tool_helpers import load_tool

    tool = load_tool("rcs_aspect")
    R = 20.0
    rc = tool.main(["--out", str(tmp_path), "--model", "rounded", "--range-m", str(R),
                    "--start-deg", "0", "--stop-deg", "90", "--step-deg", "90",
                    "--bounces", "2", "--spacing-wavelengths", "2"])
    assert rc == 0
    rows = list(csv.DictReader(open(tmp_path / "rcs_aspect.csv")))
    assert [float(r["aspect_deg"]) for r in rows] == [0.0, 90.0]
    for row, half in zip(rows, (3.8 / 2, 1.85 / 2), strict=True):
        d = R - half
        want = 10 * np.log10(np.pi * R**4 / d**2)
        assert float(row["go_vv_dbsm"]) == pytest.approx(want, abs=0.01)
        assert float(row["go_hh_dbsm"]) == pytest.approx(want, abs=0.01)
        assert np.isfinite(float(row["po_sbr_vv_dbsm"])) and int(row["po_facets"]) > 10
    assert (tmp_path / "rcs_aspect.png").stat().st_size > 10_000
    out = capsys.readouterr().out
    assert "time GO" in out and "time PO+SBR" in out


def ground_then_plate(runtime, plate_optics, mirrors):
    """tx 0.2 m and rx 1 m above a 6 x 6 m concrete road, a 0.4 m PEC plate facing them
    2 m away: the path tx -> ground -> plate -> rx meets the plate 0.4 m up."""
    ground = tri_object("ground", [quad(np.array([-3.0, -3.0, 0.0]), np.array([6.0, 0.0, 0.0]),
                                       np.array([0.0, 6.0, 0.0]), 1, 1,
                                       np.array([0.0, 0.0, 1.0]))],
                        material="concrete_road")
    plate = tri_object("plate", [quad(np.array([2.0, -0.05, 0.2]), np.array([0.0, 0.4, 0.0]),
                                      np.array([0.0, 0.0, 0.4]), 2, 2,
                                      np.array([-1.0, 0.0, 0.0]))], optics=plate_optics)
    scene = scene_from_dict({
        "scene": {"name": "mirror", "carrier_hz": F_C}, "objects": [ground, plate],
        "radars": [{"name": "tx", "position": [0.0, 0.0, 0.2], "role": "tx"},
                   {"name": "rx", "position": [0.0, 0.3, 1.0], "role": "rx"}]})
    st = TraceSettings(
        specular=SpecularSettings(max_reflections=2, rays=200_000, line_of_sight=False),
        diffraction=DiffractionSettings(max_diffractions=0),
        optics=OpticsSettings(mode="none", sbr_spacing_wavelengths=0.5, sbr_mirrors=mirrors))
    return trace_scene(scene, st, runtime=runtime).links[0].paths


def test_a_multi_bounce_path_no_tube_was_shot_along_stays_go(runtime):
    """SBR-PO replaces a GO path ending on its object only where its tubes were shot:
    with the ground's mirror window (sbr_mirrors) the ground -> plate path is the SBR
    tubes'; without it no tube leaves toward the ground, so the GO reflection stays, with
    the pure GO trace's gain and delay (before, it was dropped and the path lost)."""
    go = ground_then_plate(runtime, "go", True)
    via_ground = [i for i in range(go.n_paths)
                  if go.object_id[i, :go.n_interactions[i]].tolist() == [0, 1]]
    assert len(via_ground) == 1
    g = via_ground[0]

    def sequence(paths, kind):
        return [i for i in range(paths.n_paths)
                if paths.object_id[i, :paths.n_interactions[i]].tolist() == [0, 1]
                and np.all(paths.interaction[i, :2] == kind)]

    mirrored = ground_then_plate(runtime, "po", True)
    assert sequence(mirrored, InteractionType.REFLECTION) == []
    assert len(sequence(mirrored, InteractionType.SBR)) >= 1
    plain = ground_then_plate(runtime, "po", False)
    assert sequence(plain, InteractionType.SBR) == []
    kept = sequence(plain, InteractionType.REFLECTION)
    assert len(kept) == 1
    np.testing.assert_allclose(plain.gain[kept[0]], go.gain[g], rtol=1e-12)
    np.testing.assert_allclose(plain.delay_s[kept[0]], go.delay_s[g], rtol=1e-12)
    # the SBR tubes' return along the same path is the GO one's, to the plate's PO
    # (a 0.4 m plate at 2 m: its aperture, not an infinite mirror)
    sbr_gain = mirrored.gain[sequence(mirrored, InteractionType.SBR)].sum()
    assert abs(20 * np.log10(abs(sbr_gain) / abs(go.gain[g]))) < 3.0
