"""Edges flush on another surface (a box's floor edge on the road) are no wedges, and the
image-method pre-test of single-diffraction candidates only ever over-accepts.

The box-on-road scene is issue 27's: a box x -5..21 m, y -12..-7, z 0..10 on a road
square, both antennas 0.55 m above the road 5 m in front of the box; the floor edge's
Keller point (2, -7, 0) gave a -112 dB path although the box stands on the road.  Sionna
RT gives that path only without the road or with the box lifted 1 mm."""

from pathlib import Path

import numpy as np
import pytest

from clradcom.geometry import wedges as wedges_module
from clradcom.geometry.wedges import (
    FLUSH_PROBE_M,
    FLUSH_TOL_M,
    extract_wedges,
    free_wedges,
)
from clradcom.mechanisms import diffraction, specular
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.diffraction import (
    Chains,
    DiffractionSettings,
    diffraction_angles,
    diffraction_candidates,
    unfold_points,
)
from clradcom.paths import InteractionType
from clradcom.physics.em import C0
from clradcom.scene.reader import load_scene, scene_from_dict
from clradcom.trace import SpecularSettings, TraceSettings, trace_scene

STREET = Path(__file__).parents[1] / "scenes" / "street" / "street.toml"
TX = np.array([2.0, -1.95, 0.55])
RX = np.array([2.0, -1.55, 0.55])


def box_scene(lift=0.0, box_x=(-5.0, 21.0), road_half=40.0, wall=False):
    """Issue 27's box (x box_x, y -12..-7, z lift..lift + 10) on a road square of half
    width road_half at z = 0; ``wall``: a concrete wall at y = +6 for reflections."""
    x0, x1 = box_x
    objects = [
        {"name": "road", "material": "concrete_road", "shape": "plane",
         "size": [2 * road_half, 2 * road_half], "position": [0.0, 0.0, 0.0]},
        {"name": "box", "material": "concrete_building", "shape": "box",
         "extents": [x1 - x0, 5.0, 10.0], "position": [0.5 * (x0 + x1), -9.5, 5.0 + lift]}]
    if wall:
        objects.append({"name": "wall", "material": "concrete_building", "shape": "box",
                        "extents": [30.0, 0.5, 6.0], "position": [4.0, 6.25, 3.0]})
    return scene_from_dict({
        "scene": {"name": "box_on_road", "carrier_hz": 24e9},
        "objects": objects,
        "radars": [{"name": "tx", "role": "tx", "position": TX.tolist(),
                    "pattern": "isotropic"},
                   {"name": "rx", "role": "rx", "position": RX.tolist(),
                    "pattern": "isotropic"}]})


def scene_wedges(scene):
    return extract_wedges(scene.triangles, scene.tri_object, scene.tri_material, 20.0,
                          two_sided=scene.tri_two_sided)


def on_floor(wedges, z=0.0):
    return (np.abs(wedges.start[:, 2] - z) < 1e-9) & (np.abs(wedges.end[:, 2] - z) < 1e-9)


def test_floor_edges_of_a_box_on_the_road_are_dropped_the_rest_kept_bit_for_bit():
    scene = box_scene()
    wedges = scene_wedges(scene)
    box = scene.objects.index(next(o for o in scene.objects if o.name == "box"))
    floor = on_floor(wedges) & (wedges.object_id == box)
    assert floor.sum() == 4
    free = free_wedges(wedges, scene.triangles, scene.tri_object)
    assert free.stats["flush_dropped"] == 4 and free.stats["flush_clipped"] == 0
    assert not (on_floor(free) & (free.object_id == box)).any()
    kept = wedges.select(~floor)
    for name in ("start", "end", "direction", "length", "n", "normal0", "normal1", "tri0",
                 "tri1", "object_id", "half_plane"):
        np.testing.assert_array_equal(getattr(free, name), getattr(kept, name))
    # lifted 1 mm (10 flush tolerances) the box stands free: every edge stays
    lifted = box_scene(lift=1e-3)
    wl = scene_wedges(lifted)
    fl = free_wedges(wl, lifted.triangles, lifted.tri_object)
    assert len(fl) == len(wl) and fl.stats["flush_dropped"] == 0
    np.testing.assert_array_equal(fl.start, wl.start)
    # within the tolerance it still lies flush
    touching = box_scene(lift=0.5 * FLUSH_TOL_M)
    wt = scene_wedges(touching)
    assert free_wedges(wt, touching.triangles, touching.tri_object).stats[
        "flush_dropped"] == 4


def test_an_overhanging_box_keeps_its_floor_edges_where_they_stand_free():
    # road x, y -15..15; box x 5..25: its end overhangs the road's rim at x = 15
    scene = box_scene(box_x=(5.0, 25.0), road_half=15.0)
    wedges = scene_wedges(scene)
    free = free_wedges(wedges, scene.triangles, scene.tri_object)
    names = [o.name for o in scene.objects]
    box, road = names.index("box"), names.index("road")
    floor = free.select(on_floor(free) & (free.object_id == box))
    along_x = np.abs(floor.direction[:, 0]) > 0.5
    # the two long floor edges: only x 15..25 is free
    assert along_x.sum() == 2
    for s, e in zip(floor.start[along_x], floor.end[along_x], strict=True):
        assert sorted([s[0], e[0]]) == pytest.approx([15.0, 25.0], abs=2 * FLUSH_TOL_M)
    np.testing.assert_allclose(floor.length[along_x], 10.0, atol=2 * FLUSH_TOL_M)
    # the floor edge at x = 5 lies on the road, the one at x = 25 beyond it
    across = floor.start[~along_x]
    assert len(across) == 1 and across[0][0] == pytest.approx(25.0)
    # the road's rim at x = 15 is covered where the box stands on it (y -12..-7)
    rim = free.select(free.half_plane & (free.object_id == road)
                      & (np.abs(free.start[:, 0] - 15.0) < 1e-9)
                      & (np.abs(free.end[:, 0] - 15.0) < 1e-9))
    spans = sorted(sorted([s[1], e[1]]) for s, e in zip(rim.start, rim.end, strict=True))
    assert len(spans) == 2
    assert spans[0] == pytest.approx([-15.0, -12.0], abs=2 * FLUSH_TOL_M)
    assert spans[1] == pytest.approx([-7.0, 15.0], abs=2 * FLUSH_TOL_M)
    assert free.stats["flush_clipped"] == 3 and free.stats["flush_dropped"] == 1


def every_pair(wedges, faces_w, face_n, face_t, tri, tri_n, area2, usable, *rest):
    """The brute-force candidates of free_wedges: every face with every usable triangle."""
    faces = np.arange(len(faces_w))
    return np.repeat(faces, len(usable)), np.tile(usable, len(faces))


@pytest.mark.parametrize("box_x, road_half", [
    ((-5.0, 21.0), 40.0),   # on the road: four floor edges dropped
    ((5.0, 25.0), 15.0),    # overhanging the road's rim: clipped
    # its floor edge FLUSH_PROBE_M - FLUSH_TOL_M / 2 before the rim: the probe line lies
    # tol / 2 past the road's triangles, outside their boxes, and is still covered
    ((15.0 - FLUSH_PROBE_M + 0.5 * FLUSH_TOL_M, 25.0), 15.0),
    ((15.0 - FLUSH_PROBE_M + 1.5 * FLUSH_TOL_M, 25.0), 15.0),   # ... and here not
])
def test_candidate_pairs_lose_nothing_against_every_pair(monkeypatch, box_x, road_half):
    """free_wedges' candidates (planes, centroids, grown boxes) give the wedges that every
    (face, triangle) pair gives, bit for bit."""
    scene = box_scene(box_x=box_x, road_half=road_half)
    wedges = scene_wedges(scene)
    fast = free_wedges(wedges, scene.triangles, scene.tri_object)
    monkeypatch.setattr(wedges_module, "_flush_pairs", every_pair)
    brute = free_wedges(wedges, scene.triangles, scene.tri_object)
    assert fast.stats == brute.stats
    for name in ("start", "end", "direction", "length", "object_id", "tri0", "tri1"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(brute, name))
    assert fast.stats["flush_dropped"] + fast.stats["flush_clipped"] > 0


def floor_paths(paths, z):
    """Diffraction paths whose edge point lies on the box's floor edge y = -7, z."""
    d = paths.interaction[:, 0] == InteractionType.DIFFRACTION
    q = paths.points[:, 1]
    return np.flatnonzero(d & (paths.n_interactions == 1) & (np.abs(q[:, 1] + 7.0) < 1e-6)
                          & (np.abs(q[:, 2] - z) < 1e-6))


@pytest.mark.parametrize("engine", ["device", "host"])
def test_box_on_the_road_has_no_floor_edge_path_and_the_lifted_box_has_it(runtime, engine):
    settings = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=20_000),
                             diffraction=DiffractionSettings(max_diffractions=1),
                             engine=engine)
    paths = trace_scene(box_scene(), settings, runtime=runtime).links[0].paths
    assert (paths.interaction[:, 0] == InteractionType.DIFFRACTION).any()
    assert len(floor_paths(paths, 0.0)) == 0
    lifted = trace_scene(box_scene(lift=1e-3), settings, runtime=runtime).links[0].paths
    found = floor_paths(lifted, 1e-3)
    assert len(found) == 1
    q = lifted.points[found[0], 1]
    # Keller's point of the floor edge: straight across from the antennas (x = 2)
    np.testing.assert_allclose(q, [2.0, -7.0, 1e-3], atol=1e-9)
    length = np.linalg.norm(q - TX) + np.linalg.norm(RX - q)
    assert lifted.delay_s[found[0]] * C0 == pytest.approx(length, rel=1e-12)
    # the issue's -112.32 dB, 1 mm higher
    assert 20 * np.log10(abs(lifted.gain[found[0]])) == pytest.approx(-112.3, abs=0.5)


def test_pretest_keeps_every_candidate_the_exact_tests_keep(runtime):
    """Over the street's candidates with up to 2 reflections on either side of the edge
    (radar A to radar D): every candidate that unfold_points and diffraction_angles keep
    passes the pre-test, in the product's order, and the pre-test rejects most others."""
    scene = load_scene(STREET)
    geom = build_geometry(scene, runtime)
    budget = DiffractionSettings(max_reflections=2)
    wedges = diffraction.prepare(geom, budget)
    tx, rx = scene.radars[scene.radar_index("A")], scene.radars[scene.radar_index("D")]
    spec = SpecularSettings(max_reflections=2, rays=300)
    seq_tx, seq_rx = specular.prepare(geom, tx, spec), specular.prepare(geom, rx, spec)
    faces = geom.faces

    def exact(chains):
        pts, ok = unfold_points(chains, tx.position, rx.position, faces.normal, faces.offset,
                                wedges)
        return diffraction_angles(chains, pts, wedges, ok)[-1]

    def rows(with_pretest):
        out = {}
        kw = dict(face_normal=faces.normal, face_offset=faces.offset) if with_pretest else {}
        for ch in diffraction_candidates(geom.caster, wedges, tx.position, rx.position,
                                         seq_tx, seq_rx, budget, tri_face=faces.tri_face,
                                         **kw):
            out.setdefault(ch.pattern, []).append(ch.elements)
        return {p: np.concatenate(e) for p, e in out.items()}

    every, tested = rows(False), rows(True)
    total = sum(len(e) for e in every.values())
    assert total > 100_000 and len(every) == 5  # D, RD, RRD, DR, DRR
    n_tested = n_exact = 0
    for pattern, elements in every.items():
        good = exact(Chains(pattern, elements))
        kept = tested.get(pattern, np.zeros((0, len(pattern)), np.int64))
        n_tested += len(kept)
        n_exact += int(good.sum())
        # the pre-test keeps a superset of the exact tests' candidates, in the same order
        position = {tuple(r): i for i, r in enumerate(elements.tolist())}
        have = [position[tuple(r)] for r in kept.tolist()]
        assert have == sorted(have)
        assert set(np.flatnonzero(good).tolist()) <= set(have)
    assert n_exact > 100
    assert n_tested < 0.1 * total
