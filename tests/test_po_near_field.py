"""PO facets in an antenna's near zone are split until no piece is, and with
split="fresnel" until every piece lies in its far field (clradcom.physics.po.
far_field_pieces; docs/po.md "Facets near an antenna").

The reference is the PO radiation integral itself, summed point by point on a fine grid
over the plate: at each point the incident direction, 1/(R_t R_r) and phase of that
point, J = 2 n x H_inc (docs/po.md), turned into a gain by em.path_gains - no facet
integral and no subdivision rule in it.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from geometry_helpers import plate_tris

from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.physics import em
from clradcom.physics.em import C0
from clradcom.physics.po import FAR_FIELD_FACTOR, NEAR_SIZE_FACTOR, far_field_pieces
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import OpticsSettings

F_C = 24e9
LAM = C0 / F_C
K0 = 2 * np.pi / LAM
SIDE = 0.04          # plate side (m): two triangles of 5.7 cm, far field from 0.51 m
TILT_DEG = 30.0
GAP = 1e-3           # the case: an antenna 1 mm off the plate
FOOT = (0.005, 0.003)  # where its normal through the antenna meets the plate (y, z)
FAR = (-2.0, 0.3, 0.5)


def plate_frame():
    """Centre, unit normal (lit side, toward the antennas) and in-plane axes of the plate
    plate_tris(1, SIDE, 0, tilt_deg=TILT_DEG) builds."""
    th = np.radians(TILT_DEG)
    rot = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    return np.zeros(3), rot @ [-1.0, 0.0, 0.0], rot @ [0.0, 1.0, 0.0], rot @ [0.0, 0.0, 1.0]


def near_scene():
    c, n, ey, ez = plate_frame()
    near = c + FOOT[0] * ey + FOOT[1] * ez + GAP * n
    verts, faces = plate_tris(1, SIDE, 0.0, tilt_deg=TILT_DEG)
    return scene_from_dict({
        "scene": {"name": "near", "carrier_hz": F_C},
        "objects": [{"name": "plate", "material": "metal", "shape": "triangles",
                     "vertices": verts, "faces": faces}],
        "radars": [{"name": "near", "position": near.tolist(), "pattern": "isotropic"},
                   {"name": "far", "position": list(FAR), "pattern": "isotropic"}]})


def reference_gain(tx, rx, cells=400):
    """The plate's PO return tx -> rx by the midpoint rule on cells x cells squares
    (0.1 mm: a tenth of the gap)."""
    c, n, ey, ez = plate_frame()
    g = (np.arange(cells) + 0.5) / cells * SIDE - SIDE / 2
    u, v = np.meshgrid(g, g, indexing="ij")
    p = c + u.reshape(-1, 1) * ey + v.reshape(-1, 1) * ez
    dt = p - np.asarray(tx.position)
    dr = np.asarray(rx.position) - p
    R_t = np.linalg.norm(dt, axis=1)
    R_r = np.linalg.norm(dr, axis=1)
    k_i, s = dt / R_t[:, None], dr / R_r[:, None]
    L = R_t + R_r
    eye = np.eye(3)
    cross2 = k_i[:, :, None] * n[None, None, :] - (k_i @ n)[:, None, None] * eye
    proj = eye - s[:, :, None] * s[:, None, :]
    dA = (SIDE / cells) ** 2
    T = (-1j * K0 / (2 * np.pi) * L / (R_t * R_r) * dA)[:, None, None] * (proj @ cross2)
    gain, _ = em.path_gains(T, L, k_i, s, tx, rx, F_C)
    return gain.sum()


def db(x):
    return 20 * np.log10(abs(x))


def test_antenna_1_mm_off_a_tilted_plate_both_directions(runtime):
    """The issue's case: with the antenna 1 mm off the plate the split facets give the PO
    integral in both directions of the link (measured within 0.05 dB and 0.6 %), where
    the whole facets missed it by 12.6 and 21.6 dB; the two directions then differ by
    what the PO integral itself says (3.3 dB: PO is not reciprocal off the specular
    direction, and the near antenna sees the plate at other angles than the far one)."""
    scene = near_scene()
    geom = build_geometry(scene, runtime)
    near, far = scene.radars
    got, ref = {}, {}
    for name, (tx, rx) in {"near->far": (near, far), "far->near": (far, near)}.items():
        ref[name] = reference_gain(tx, rx)
        got[name] = po_paths(geom, tx, rx, min_relative_db=-300).gain.sum()
        whole = po_paths(geom, tx, rx, min_relative_db=-300, split="none").gain.sum()
        assert abs(db(got[name]) - db(ref[name])) < 0.1, (name, db(got[name]), db(ref[name]))
        assert abs(got[name] - ref[name]) < 0.02 * abs(ref[name]), name
        # the whole facets are out of their domain here: far from the integral
        assert abs(db(whole) - db(ref[name])) > 10.0, (name, db(whole), db(ref[name]))
    asym = db(got["near->far"]) - db(got["far->near"])
    assert asym == pytest.approx(db(ref["near->far"]) - db(ref["far->near"]), abs=0.1)


def test_far_facets_are_left_whole(runtime):
    """In both antennas' far field nothing is split: the same bits as without the rule."""
    scene = scene_from_dict({
        "scene": {"name": "far", "carrier_hz": F_C}, "objects": near_scene_objects(),
        "radars": [{"name": "other", "position": [-1.0, -1.5, 0.2], "pattern": "isotropic"},
                   {"name": "far", "position": list(FAR), "pattern": "isotropic"}]})
    geom = build_geometry(scene, runtime)
    a, b = scene.radars
    with_rule = po_paths(geom, a, b, min_relative_db=-300)
    without = po_paths(geom, a, b, min_relative_db=-300, split="none")
    assert len(with_rule) == 2
    np.testing.assert_array_equal(with_rule.gain, without.gain)
    np.testing.assert_array_equal(with_rule.matrix, without.matrix)


def near_scene_objects():
    verts, faces = plate_tris(1, SIDE, 0.0, tilt_deg=TILT_DEG)
    return [{"name": "plate", "material": "metal", "shape": "triangles",
             "vertices": verts, "faces": faces}]


def test_pieces_meet_the_criterion_and_tile_the_facet():
    """Every piece is in the far field of both antennas, pieces of a facet cover exactly
    its area, and only the facets that need it are split (the far one stays one piece)."""
    c, n, ey, ez = plate_frame()
    near = c + FOOT[0] * ey + FOOT[1] * ez + GAP * n
    verts, faces = plate_tris(1, SIDE, 0.0, tilt_deg=TILT_DEG)
    tris = np.asarray(verts)[np.asarray(faces)]
    far_tri = tris[:1] + np.array([50.0, 0.0, 0.0])
    all_tris = np.concatenate([tris, far_tri])
    pieces, parent, settled = far_field_pieces(all_tris, [near, FAR], LAM, "fresnel")
    assert settled.all()
    assert np.all(np.diff(parent) >= 0)
    assert np.count_nonzero(parent == 2) == 1
    D = np.sqrt(np.max(np.sum((pieces - pieces[:, [1, 2, 0]]) ** 2, axis=-1), axis=1))
    R = np.minimum(np.linalg.norm(pieces.mean(axis=1) - near, axis=1),
                   np.linalg.norm(pieces.mean(axis=1) - np.asarray(FAR), axis=1))
    assert np.all(R >= FAR_FIELD_FACTOR * D**2 / LAM) and np.all(R >= NEAR_SIZE_FACTOR * D)
    area = 0.5 * np.linalg.norm(np.cross(pieces[:, 1] - pieces[:, 0],
                                         pieces[:, 2] - pieces[:, 0]), axis=1)
    want = 0.5 * np.linalg.norm(np.cross(all_tris[:, 1] - all_tris[:, 0],
                                         all_tris[:, 2] - all_tris[:, 0]), axis=1)
    np.testing.assert_allclose(np.bincount(parent, area), want, rtol=1e-12)
    # graded: the pieces under the antenna are the small ones
    assert 50 < len(pieces) < 5000
    # the near-zone rule alone splits less, and only where R < 2 D
    few, few_parent, ok = far_field_pieces(all_tris, [near, FAR], LAM, "near")
    assert ok.all() and len(few) <= len(pieces)
    D = np.sqrt(np.max(np.sum((few - few[:, [1, 2, 0]]) ** 2, axis=-1), axis=1))
    R = np.minimum(np.linalg.norm(few.mean(axis=1) - near, axis=1),
                   np.linalg.norm(few.mean(axis=1) - np.asarray(FAR), axis=1))
    assert np.all(R >= NEAR_SIZE_FACTOR * D)
    np.testing.assert_array_equal(far_field_pieces(all_tris, [near, FAR], LAM, "none")[0],
                                  all_tris)


def test_an_antenna_on_the_facet_is_warned_once_per_object(runtime):
    """Where no subdivision reaches the far field (the antenna on the plate itself), the
    pieces stop at MAX_SUBDIVISION_LEVELS and one warning names the object and distance."""
    c, n, ey, ez = plate_frame()
    on = c + FOOT[0] * ey + FOOT[1] * ez + 1e-9 * n
    scene = scene_from_dict({
        "scene": {"name": "on", "carrier_hz": F_C}, "objects": near_scene_objects(),
        "radars": [{"name": "on", "position": on.tolist(), "pattern": "isotropic"},
                   {"name": "far", "position": list(FAR), "pattern": "isotropic"}]})
    geom = build_geometry(scene, runtime)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        po_paths(geom, scene.radars[0], scene.radars[1], min_relative_db=-300)
    msgs = [str(w.message) for w in caught if "near field" in str(w.message)]
    assert len(msgs) == 1 and "'plate'" in msgs[0]


@pytest.mark.parametrize("bad", ["yes", 1, True])
def test_setting_names_a_rule(bad):
    with pytest.raises(ValueError, match="OpticsSettings.po_split"):
        OpticsSettings(po_split=bad)


@pytest.mark.parametrize("distance_m, rule, warned", [
    (0.3, "near", True),      # beyond 2D = 0.11 m, inside 2D^2/lambda = 0.51 m
    (0.3, "fresnel", False),  # split into the far field: nothing to say
    (2.0, "near", False)])    # in the far field already
def test_facets_in_the_fresnel_zone_are_named_with_their_distance(runtime, distance_m,
                                                                   rule, warned):
    from clradcom.errors import FresnelZoneWarning
    c, n, _, _ = plate_frame()
    at = c + distance_m * n
    scene = scene_from_dict({
        "scene": {"name": "fresnel", "carrier_hz": F_C}, "objects": near_scene_objects(),
        "radars": [{"name": "radar", "position": at.tolist(), "pattern": "isotropic"}]})
    geom = build_geometry(scene, runtime)
    radar = scene.radars[0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        po_paths(geom, radar, radar, min_relative_db=-300, split=rule)
    msgs = [str(w.message) for w in caught if issubclass(w.category, FresnelZoneWarning)]
    assert len(msgs) == (1 if warned else 0), msgs
    if warned:
        assert "'plate' (2, the nearest 0.3" in msgs[0] and "of 'radar'," in msgs[0]
