"""Faces that behave as users expect (issue #19, 5): a closed mesh wound inside out gives
the paths of the correctly wound one (re-oriented at load, with a warning naming the
object), an open sheet reflects and diffracts on both sides, and ``sides = "as_wound"``
keeps the old one-sided behaviour (which loses the paths: the regression).

The reference for every mechanism is the same scene with the mesh wound correctly, traced
by the same code: a flipped mesh must not change a path (docs/scene-format.md, "Sides").
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

from clradcom.errors import SceneError, SceneWarning
from clradcom.geometry.shells import orient_shells
from clradcom.geometry.wedges import extract_wedges
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.paths import InteractionType, paths_difference
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import (
    DiffractionSettings,
    OpticsSettings,
    SpecularSettings,
    TraceSettings,
    trace_scene,
)

GO_UTD = TraceSettings(specular=SpecularSettings(max_reflections=2, rays=20_000),
                       diffraction=DiffractionSettings(max_diffractions=1, max_reflections=0))
RADARS = [{"name": "a", "position": [0.0, -2.0, 1.5], "pattern": "isotropic"},
          {"name": "b", "position": [0.0, 2.0, 1.5], "pattern": "isotropic"}]


def scene_of(objects, radars=RADARS):
    return scene_from_dict({"scene": {"name": "sides", "carrier_hz": 24e9},
                            "objects": objects, "radars": radars})


def mesh_object(name, vertices, faces, material="itu_concrete", **kw):
    return {"name": name, "material": material, "shape": "triangles",
            "vertices": np.asarray(vertices, float).tolist(),
            "faces": np.asarray(faces).tolist(), **kw}


def house(flip: bool, **kw):
    """A closed box building 6 m in front of the radars, wound outward (or inside out)."""
    box = trimesh.creation.box(extents=[4.0, 6.0, 5.0])
    box.apply_translation([8.0, 0.0, 2.5])
    faces = box.faces[:, ::-1] if flip else box.faces
    return mesh_object("house", box.vertices, faces, **kw)


def plate(flip: bool, x=10.0, half=0.4, **kw):
    """An open metal square in the plane x = ``x`` facing -x (the radars), or wound away."""
    v = [[x, -half, 1.5 - half], [x, half, 1.5 - half], [x, half, 1.5 + half],
         [x, -half, 1.5 + half]]
    faces = np.array([[0, 2, 1], [0, 3, 2]])  # normal (v2 - v0) x (v1 - v0) ... -> -x
    return mesh_object("plate", v, faces[:, ::-1] if flip else faces, material="metal",
                       **kw)


def quiet_scene(objects, radars=RADARS):
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)
        return scene_of(objects, radars)


def diffraction_count(snap) -> int:
    return sum(int(np.any(link.paths.interaction == InteractionType.DIFFRACTION, axis=1)
                   .sum()) for link in snap.links)


# ---- load time -------------------------------------------------------------------------

def test_plate_helper_faces_the_radars():
    tri = quiet_scene([plate(False)]).triangles
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(n[:, 0] < 0)


def test_inside_out_house_is_reoriented_with_a_warning_naming_it():
    good = quiet_scene([house(False)])
    with pytest.warns(SceneWarning, match=r"objects\[0\]: object 'house' .*1 of its 1 "
                      r"closed shell.*re-oriented 12 triangle.*sides = \"as_wound\""):
        fixed = scene_of([house(True)])
    np.testing.assert_array_equal(fixed.triangles, good.triangles)
    assert not fixed.objects[0].two_sided and not good.objects[0].two_sided
    assert fixed.content_hash() == good.content_hash()
    # as_wound keeps it inside out, silently
    kept = quiet_scene([house(True, sides="as_wound")])
    assert orient_shells(kept.triangles).n_inward == 1
    assert kept.content_hash() != fixed.content_hash()


def test_open_sheets_are_two_sided_and_the_key_overrides():
    s = quiet_scene([plate(True), house(False, sides="two_sided"),
                     {"name": "road", "material": "concrete_road", "shape": "plane",
                      "size": [10.0, 10.0]},
                     {"name": "one", "material": "metal", "shape": "plane",
                      "size": [1.0, 1.0], "position": [0.0, 0.0, 5.0],
                      "sides": "as_wound"}])
    assert [o.two_sided for o in s.objects] == [True, True, True, False]
    assert s.tri_two_sided.tolist() == [True] * 14 + [True] * 2 + [False] * 2


def test_a_bad_sides_value_names_key_and_value():
    with pytest.raises(SceneError, match=r"objects\[0\]\.sides = 'both'.*auto, as_wound, "
                       "two_sided"):
        scene_of([house(False, sides="both")])


def test_shells_of_a_soup():
    out = trimesh.creation.box(extents=[1, 1, 1])
    inv = trimesh.creation.box(extents=[1, 1, 1])
    inv.apply_translation([3, 0, 0])
    inv.invert()
    sheet = trimesh.creation.box(extents=[1, 1, 1]).triangles[:2] + [0, 6, 0]
    shells = orient_shells(np.concatenate([out.triangles, inv.triangles, sheet]))
    assert shells.closed.tolist() == [True, True, False]
    assert shells.inward.tolist() == [False, True, False]
    assert shells.open_triangles.tolist() == [False] * 24 + [True] * 2
    assert shells.inward_triangles.tolist() == [False] * 12 + [True] * 12 + [False] * 2


# ---- GO and UTD ------------------------------------------------------------------------

def test_inside_out_house_gives_the_paths_of_the_outward_one(runtime):
    ref = trace_scene(quiet_scene([house(False)]), GO_UTD, runtime=runtime)
    with pytest.warns(SceneWarning):
        flipped = trace_scene(scene_of([house(True)]), GO_UTD, runtime=runtime)
    assert diffraction_count(ref) >= 8  # four vertical edges, two links each way
    for a, b in zip(ref.links, flipped.links, strict=True):
        assert paths_difference(a.paths, b.paths) is None
    # the regression: wound inside out and trusted as wound, its edges are concave
    # creases, and its diffraction paths are lost
    lost = trace_scene(quiet_scene([house(True, sides="as_wound")]), GO_UTD,
                       runtime=runtime)
    assert diffraction_count(lost) == 0


def folded_sheet(flip: bool, **kw):
    """An open metal sheet folded along the vertical line x = 8, y = 0 (a corner pointing
    at the radars, the 90-degree edge a convex wedge seen from them), wound towards them
    (or away)."""
    v = [[10.0, -2.0, 0.0], [8.0, 0.0, 0.0], [8.0, 0.0, 4.0], [10.0, -2.0, 4.0],
         [10.0, 2.0, 0.0], [10.0, 2.0, 4.0]]
    faces = np.array([[0, 2, 1], [0, 3, 2], [1, 5, 4], [1, 2, 5]])
    return mesh_object("fold", v, faces[:, ::-1] if flip else faces, material="metal",
                       **kw)


def test_a_fold_of_an_open_sheet_diffracts_whichever_way_it_is_wound(runtime):
    radars = [{"name": "a", "position": [0.0, -1.0, 1.5], "pattern": "isotropic"},
              {"name": "b", "position": [0.0, 1.0, 1.5], "pattern": "isotropic"}]
    scenes = [quiet_scene([folded_sheet(f)], radars) for f in (False, True)]
    for s in scenes:
        w = extract_wedges(s.triangles, s.tri_object, s.tri_material,
                           two_sided=s.tri_two_sided)
        crease = ~w.half_plane
        # the fold and its twin: one convex (n = 1.5, the side the radars see), one concave
        assert sorted(np.round(w.n[crease], 9).tolist()) == [0.5, 1.5]
        assert w.stats["two_sided_creases"] == 1
    traced = [trace_scene(s, GO_UTD, runtime=runtime) for s in scenes]
    for a, b in zip(*[t.links for t in traced], strict=True):
        pa, pb = a.paths, b.paths
        assert pa.n_paths == pb.n_paths
        oa, ob = np.lexsort((pa.delay_s, pa.n_interactions)), np.lexsort(
            (pb.delay_s, pb.n_interactions))
        np.testing.assert_allclose(pb.delay_s[ob], pa.delay_s[oa], rtol=1e-12)
        np.testing.assert_allclose(pb.gain[ob], pa.gain[oa], rtol=1e-6, atol=1e-15)
    assert diffraction_count(traced[0]) >= 4
    # trusted as wound away, the fold is a concave crease and diffracts nothing seen
    # from the radars; only the rims do
    one_sided = trace_scene(quiet_scene([folded_sheet(True, sides="as_wound")], radars),
                            GO_UTD, runtime=runtime)
    assert diffraction_count(one_sided) < diffraction_count(traced[0])


# ---- physical optics and SBR ----------------------------------------------------------

def po_of(scene, runtime):
    geom = build_geometry(scene, runtime)
    r = scene.radars[0]
    return po_paths(geom, r, r, objects=[0])


def test_po_facets_of_a_sheet_wound_away_are_lit(runtime):
    radar = [{"name": "r", "position": [0.0, 0.0, 1.5], "pattern": "isotropic"}]
    # 0.2 m square at 20 m: beyond 2 D^2 / lambda = 12.8 m, the far field
    towards = po_of(quiet_scene([plate(False, x=20.0, half=0.1)], radar), runtime)
    away = po_of(quiet_scene([plate(True, x=20.0, half=0.1)], radar), runtime)
    assert towards.n_paths == away.n_paths == 2
    # the two windings split the plate the same way: the same facets, the same returns
    np.testing.assert_allclose(away.gain.sum(), towards.gain.sum(), rtol=1e-9)
    np.testing.assert_allclose(away.delay_s, towards.delay_s, rtol=1e-12)
    # the plate's PO return is its flat-plate RCS 4 pi A^2 / lambda^2 (broadside)
    lam = 299792458.0 / 24e9
    sigma = abs(towards.gain.sum()) ** 2 * (4 * np.pi) ** 3 * 20.0 ** 4 / lam ** 2
    assert sigma == pytest.approx(4 * np.pi * 0.2 ** 4 / lam ** 2, rel=0.02)
    # one-sided as wound, the back is dark
    dark = po_of(quiet_scene([plate(True, sides="as_wound")], radar), runtime)
    assert dark.n_paths == 0


def test_sbr_lights_a_sheet_wound_away(runtime):
    radar = [{"name": "r", "position": [0.0, 0.0, 1.5], "pattern": "isotropic"}]
    settings = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=2_000),
                             diffraction=DiffractionSettings(max_diffractions=0),
                             optics=OpticsSettings(mode="sbr", sbr_mirrors=False))
    gains = []
    for flip in (False, True):
        snap = trace_scene(quiet_scene([plate(flip)], radar), settings, runtime=runtime)
        p = snap.links[0].paths
        assert p.n_paths > 0
        gains.append(p.gain.sum())
    np.testing.assert_allclose(gains[1], gains[0], rtol=1e-6)
