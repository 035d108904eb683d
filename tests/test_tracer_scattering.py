"""Diffuse tile scattering wired into the tracer: energy split with the specular path,
ground-bounce paths of a tree over the road (specular prefix/suffix), settings."""

import numpy as np
import pytest
import trimesh

from clradcom.mechanisms.scattering import make_tiles, scattering_paths, scattering_triangle_bounds
from clradcom.paths import InteractionType
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import TraceSettings, build_geometry, trace_scene


def ground_scene(S):
    return scene_from_dict({
        "scene": {"name": "leafy", "carrier_hz": 24e9},
        "materials": [{"name": "leaves", "eps_r": [10.0, -6.0], "scattering_coefficient": S}],
        "objects": [{"name": "ground", "material": "leaves", "shape": "plane",
                     "size": [4.0, 4.0], "position": [3.0, 0.0, 0.0]}],
        "radars": [{"name": "tx", "role": "tx", "position": [0.0, 0.0, 1.0]},
                   {"name": "rx", "role": "rx", "position": [6.0, 0.0, 1.0],
                    "orientation_deg": [0.0, 0.0, 180.0]}]})


def test_scattering_takes_its_share_from_the_specular_path(runtime):
    settings = TraceSettings(max_reflections=1, rays=50_000, max_diffractions=0,
                             scattering=True)
    smooth = trace_scene(ground_scene(0.0), settings, runtime=runtime)
    leafy = trace_scene(ground_scene(0.5), settings, runtime=runtime)
    p0, p1 = smooth.links[0].paths, leafy.links[0].paths
    spec0 = p0.gain[p0.interaction[:, 0] == InteractionType.REFLECTION]
    spec1 = p1.gain[p1.interaction[:, 0] == InteractionType.REFLECTION]
    assert len(spec0) == len(spec1) == 1
    # effective roughness: the specular field keeps sqrt(1 - S^2)
    assert spec1[0] == pytest.approx(spec0[0] * np.sqrt(1 - 0.25), rel=1e-12)
    diffuse = p1.interaction[:, 0] == InteractionType.SCATTERING
    assert diffuse.sum() > 10 and not np.any(p0.interaction[:, 0] == InteractionType.SCATTERING)
    # every tile lies on the ground and its delay is its own tx -> tile -> rx length
    tiles = p1.points[diffuse, 1]
    np.testing.assert_allclose(tiles[:, 2], 0.0, atol=1e-12)
    length = (np.linalg.norm(tiles - [0, 0, 1], axis=1) + np.linalg.norm(tiles - [6, 0, 1], axis=1))
    np.testing.assert_allclose(p1.delay_s[diffuse] * 299792458.0, length, rtol=1e-12)
    assert "scattering.tiles_dropped" in leafy.metadata
    # diffuse power stays well below what the specular path lost, as a spread of weak tiles
    assert np.sum(np.abs(p1.gain[diffuse]) ** 2) < np.abs(spec0[0]) ** 2


TREE_AT = np.array([10.0, 5.5, 4.3])
RADAR_AT = np.array([0.0, 0.0, 0.5])


def tree_scene():
    """The paper's materials: one low-poly tree crown (as tools/make_street.py: an
    icosphere of r = 1.5 m at 4.3 m) over a concrete road, a radar at bumper height."""
    crown = trimesh.creation.icosphere(subdivisions=1, radius=1.5)
    return scene_from_dict({
        "scene": {"name": "tree", "carrier_hz": 24e9},
        "objects": [
            {"name": "road", "material": "concrete_road", "shape": "plane",
             "size": [40.0, 30.0], "position": [10.0, 0.0, 0.0]},
            {"name": "tree", "material": "trees", "shape": "triangles",
             "vertices": (crown.vertices + TREE_AT).tolist(), "faces": crown.faces.tolist(),
             "position": [0.0, 0.0, 0.0]}],
        "radars": [{"name": "A", "role": "txrx", "position": RADAR_AT.tolist()}]})


def test_tree_over_ground_gives_ground_bounce_tile_paths(runtime):
    sc = tree_scene()
    geom = build_geometry(sc, runtime)
    r = sc.radars[0]
    p, dropped = scattering_paths(geom, r, r, tile_size_m=0.5, threshold_db=-200,
                                  max_reflections=2)
    assert dropped == 0
    # brute force: the crown is convex and the road flat, so a tile is reached from a
    # point (the radar or its image under the road) exactly when its front faces it
    # and, for the image, the line to it crosses the road inside the plane's extent
    tree_tris = sc.triangles[sc.tri_object == 1]
    q, _, n, _ = make_tiles(tree_tris, 0.5)
    image = RADAR_AT * [1, 1, -1]
    faces_radar = np.einsum("pi,pi->p", n, RADAR_AT - q) > 0
    t = q[:, 2] / (q[:, 2] + RADAR_AT[2])
    foot = q + t[:, None] * (image - q)
    on_road = (np.abs(foot[:, 0] - 10.0) < 20.0) & (np.abs(foot[:, 1]) < 15.0)
    faces_image = (np.einsum("pi,pi->p", n, image - q) > 0) & on_road
    S, R = int(InteractionType.SCATTERING), int(InteractionType.REFLECTION)
    kinds = [tuple(p.interaction[k, :p.n_interactions[k]]) for k in range(len(p))]
    want = {(S,): faces_radar, (R, S): faces_image & faces_radar,
            (S, R): faces_radar & faces_image, (R, S, R): faces_image}
    for kind, mask in want.items():
        rows = [k for k in range(len(p)) if kinds[k] == kind]
        assert len(rows) == mask.sum() > 0, kind
        j = kind.index(S)
        got = np.sort(p.points[rows, 1 + j].round(9), axis=0)
        np.testing.assert_allclose(got, np.sort(q[mask].round(9), axis=0), atol=1e-9)
        for k in rows:
            assert [p.object_id[k, i] for i in range(len(kind))] == [
                1 if c == S else 0 for c in kind]
            tile = p.points[k, 1 + j]
            # the unfolded length runs to the image wherever a reflection is
            ends = [image if (i == 0 and kind[0] == R) or (i == 1 and kind[-1] == R)
                    else RADAR_AT for i in range(2)]
            length = sum(np.linalg.norm(tile - e) for e in ends)
            assert p.delay_s[k] * 299792458.0 == pytest.approx(length, rel=1e-12)
            for i, c in enumerate(kind):
                if c == R:
                    assert p.points[k, 1 + i, 2] == pytest.approx(0.0, abs=1e-9)

    # pruning: the count of dropped paths is the count below the threshold
    some, n_drop = scattering_paths(geom, r, r, tile_size_m=0.5, threshold_db=-12,
                                    max_reflections=2)
    mag = np.abs(p.gain)
    below = mag < mag.max() * 10 ** (-12 / 20)
    assert n_drop == below.sum() > 0 and len(some) == len(p) - n_drop
    np.testing.assert_allclose(np.sort(np.abs(some.gain)), np.sort(mag[~below]), rtol=1e-12)


def test_trace_scene_carries_tree_ground_paths_and_settings(runtime):
    sc = tree_scene()
    base = dict(max_reflections=1, rays=20_000, max_diffractions=0, scattering=True,
                scattering_tile_size_m=0.5, scattering_threshold_db=-200.0)
    snaps = {m: trace_scene(sc, TraceSettings(**base, scattering_max_reflections=m),
                            runtime=runtime) for m in (0, 1)}
    kinds = {m: {tuple(row[:n]) for row, n in zip(s.links[0].paths.interaction,
                                                   s.links[0].paths.n_interactions,
                                                   strict=True)} for m, s in snaps.items()}
    S, R = int(InteractionType.SCATTERING), int(InteractionType.REFLECTION)
    assert (S,) in kinds[0] and (R, S) not in kinds[0] and (S, R) not in kinds[0]
    assert {(S,), (R, S), (S, R)} <= kinds[1] and (R, S, R) not in kinds[1]
    meta = snaps[1].metadata
    assert meta["settings.scattering_max_reflections"] == 1
    assert meta["scattering.tiles_dropped"] == 0
    # the tree paths equal what scattering_paths gives for the same settings
    direct, _ = scattering_paths(build_geometry(sc, runtime), sc.radars[0], sc.radars[0],
                                 tile_size_m=0.5, threshold_db=-200.0, max_reflections=1)
    tree = snaps[1].links[0].paths
    on_tree = np.any(tree.interaction == S, axis=1)
    np.testing.assert_allclose(np.sort(np.abs(tree.gain[on_tree])), np.sort(np.abs(direct.gain)),
                               rtol=1e-12)


@pytest.mark.parametrize("key, value", [("scattering_max_reflections", 3),
                                        ("scattering_max_reflections", 1.0),
                                        ("scattering_threshold_db", 10.0),
                                        ("scattering_tile_size_m", -0.1),
                                        ("scattering_min_face_area_m2", float("nan"))])
def test_scattering_settings_refuse_bad_values(key, value):
    with pytest.raises(ValueError, match=key):
        TraceSettings(**{key: value})


def test_scattering_floor_never_traces_triangles_that_cannot_reach_it(runtime):
    """Two leafy plates, one near and one far: with the floor between their bounds the
    far plate's tiles are not traced (counted in the metadata), the near plate's paths
    are exactly those of the unpruned trace (tile phases do not depend on the mask),
    and no dropped tile could have reached the floor."""
    spec = {"scene": {"name": "two-plates", "carrier_hz": 24e9},
            "materials": [{"name": "leaves", "eps_r": [10.0, -6.0],
                           "scattering_coefficient": 0.5}],
            "objects": [{"name": "near", "material": "leaves", "shape": "plane",
                         "size": [1.0, 1.0], "position": [4.0, 0.0, 0.0],
                         "rotation_deg": [0.0, -90.0, 0.0]},
                        {"name": "far", "material": "leaves", "shape": "plane",
                         "size": [1.0, 1.0], "position": [40.0, 10.0, 0.0],
                         "rotation_deg": [0.0, -90.0, 0.0]}],
            "radars": [{"name": "r", "position": [0.0, 0.0, 0.0]}]}
    scene = scene_from_dict(spec)
    radar = scene.radars[0]
    ids, best, _ = scattering_triangle_bounds(scene, radar, radar, 1.0)
    far = scene.tri_object[ids] == 1
    floor = np.sqrt(best[far].max() * best[~far].min())  # between the two plates
    assert best[far].max() < floor < best[~far].min()
    base = dict(max_reflections=0, rays=1000, max_diffractions=0, scattering=True,
                scattering_threshold_db=-300.0)
    full = trace_scene(scene, TraceSettings(**base), runtime=runtime)
    pruned = trace_scene(scene, TraceSettings(**base, scattering_floor=float(floor)),
                         runtime=runtime)
    p, q = full.links[0].paths, pruned.links[0].paths
    from_far = p.object_id[:, 0] == 1
    assert from_far.any() and (~from_far).any()
    assert np.all(q.object_id[:, 0] == 0)
    np.testing.assert_array_equal(q.gain, p.gain[~from_far])
    assert pruned.metadata["scattering.triangles_below_floor"] == int(far.sum())
    assert np.abs(p.gain[from_far]).max() ** 2 < floor
    with pytest.raises(ValueError, match="scattering_floor"):
        TraceSettings(scattering_floor=-1.0)
