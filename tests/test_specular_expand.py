"""Candidate expansion after the ray launch (SpecularSettings.expand_rounds,
clradcom.mechanisms.specular.expanded_paths): paths one reflection away from the
confirmed ones, confirmed by the same image method and visibility test.

Checked here: the candidates are exactly the one-step neighbours (a brute-force
enumeration), the launch's paths stay bit for bit, and on the street (isotropic antennas,
A -> D) a 3e4-ray launch with expansion finds paths it missed, among them one that even
a 1e6-ray launch misses; every added path obeys the law of reflection on its triangles
and its delay is its length over c (independent closed forms, from the scene's own
triangles). And where expansion cannot reach: a path off a face that no confirmed path
touches, which only more rays find."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

from clradcom.errors import ArgumentError
from clradcom.evaluation.peer import distinct_paths, match_paths, sequences_of
from clradcom.mechanisms.specular import (
    SpecularSettings,
    _rows_not_in,
    _TriedSequences,
    both_ways,
    expansion_candidates,
    key_base,
)
from clradcom.paths import InteractionType
from clradcom.physics.em import C0
from clradcom.scene.antenna import IsotropicPattern
from clradcom.scene.motion import scene_at
from clradcom.scene.reader import load_scene, scene_from_dict
from clradcom.trace import TraceSettings, trace_scene

STREET = Path(__file__).resolve().parents[1] / "scenes" / "street" / "street.toml"


def brute_force_neighbours(sequences, pool, max_order):
    out = set()
    for q in map(tuple, sequences):
        if len(q) < max_order:
            for at, f in itertools.product(range(len(q) + 1), pool):
                out.add(q[:at] + (f,) + q[at:])
        for at in range(len(q)):
            out.add(q[:at] + q[at + 1:])
    return {c for c in out if c and all(a != b for a, b in zip(c, c[1:], strict=False))}


def test_expansion_candidates_are_the_one_step_neighbours():
    sequences = [np.array([4, 7]), np.array([7]), np.array([1, 4, 1])]
    pool = [1, 4, 7, 9]
    got = expansion_candidates(sequences, pool, 3)
    flat = {tuple(int(f) for f in row) for rows in got.values() for row in rows}
    assert flat == brute_force_neighbours(sequences, pool, 3)
    for k, rows in got.items():
        assert rows.shape[1] == k
        assert np.array_equal(rows, np.unique(rows, axis=0))  # distinct and sorted
    assert max(got) == 3  # never past max_order


def test_rows_not_in():
    known = np.array([[1, 2], [3, 4]], np.int32)
    rows = np.array([[3, 4], [5, 6], [1, 3]], np.int32)
    assert _rows_not_in(rows, known).tolist() == [[5, 6], [1, 3]]
    assert _rows_not_in(rows, None).tolist() == rows.tolist()


def distinct_rows_without_repeats(rng, n, k, n_faces):
    rows = rng.integers(0, n_faces, size=(n, k)).astype(np.int32)
    rows = rows[np.all(rows[:, 1:] != rows[:, :-1], axis=1)]
    return np.unique(rows, axis=0)


@pytest.mark.parametrize("keyed", [True, False])
def test_tried_sequences_hand_out_each_sequence_once(keyed):
    """Exact int64 keys (where the faces fit one) and rows per order (where not) both
    hand out exactly the rows not tried before: the launch's, then earlier proposals'."""
    rng = np.random.default_rng(3)
    n_faces, max_order = 40, 5
    launch = {k: distinct_rows_without_repeats(rng, 300, k, n_faces)
              for k in range(1, max_order + 1)}
    tried = _TriedSequences(launch, key_base(n_faces, max_order) if keyed else None)
    seen = {tuple(r) for rows in launch.values() for r in rows.tolist()}
    for _ in range(3):
        for k in range(1, max_order + 1):
            rows = distinct_rows_without_repeats(rng, 200, k, n_faces)
            expect = [r for r in rows.tolist() if tuple(r) not in seen]
            assert tried.add_new(k, rows).tolist() == expect
            seen.update(map(tuple, rows.tolist()))
            assert not len(tried.add_new(k, rows))  # now all tried


def test_both_ways_reverses_the_receivers_sequences():
    tx = {1: np.array([[3], [5]], np.int32), 2: np.array([[3, 5]], np.int32)}
    rx = {1: np.array([[5], [8]], np.int32), 2: np.array([[5, 3], [9, 8]], np.int32),
          3: np.array([[1, 2, 4]], np.int32)}
    got = both_ways(tx, rx)
    assert {k: v.tolist() for k, v in got.items()} == {
        1: [[3], [5], [8]], 2: [[3, 5], [8, 9]], 3: [[4, 2, 1]]}


def test_expand_rounds_is_checked():
    with pytest.raises(ArgumentError, match="expand_rounds"):
        SpecularSettings(expand_rounds=-1)
    with pytest.raises(ArgumentError, match="expand_rounds"):
        SpecularSettings(expand_rounds=1.5)
    with pytest.raises(ArgumentError, match="from_receiver"):
        SpecularSettings(from_receiver=1)


@pytest.fixture(scope="module")
def street_iso():
    scene = load_scene(STREET)
    return dataclasses.replace(scene, radars=[dataclasses.replace(
        r, pattern=IsotropicPattern()) for r in scene.radars])


def go(rays, expand=None, from_receiver=None):
    return TraceSettings.preset("go", specular__rays=rays, specular__max_reflections=5,
                                diffraction__max_diffractions=0,
                                specular__expand_rounds=expand,
                                specular__from_receiver=from_receiver)


def link_of(scene, settings, runtime):
    snap = trace_scene(scene, settings, runtime=runtime, links=[(0, 1)])
    p = snap.links[0].paths
    return p, sequences_of(p.interaction, p.n_interactions, p.object_id, snap.object_names)


def check_real(paths, sequences, indices, triangles):
    """Paths ``indices`` obey the law of reflection on their triangles, tau = L / c."""
    for i in indices:
        k = int(paths.n_interactions[i])
        pts = paths.points[i, :k + 2]
        # the image method mirrors in the face's plane (merge_coplanar's area-weighted
        # plane of triangles coplanar within 1e-5 rad and 1e-5 m), not the triangle's;
        # 10 um and 10 urad are far below a wavelength (12.5 mm)
        assert reflection_law_residual(pts, triangles[paths.face_id[i, :k]]) < 1e-5, \
            sequences[i]
        length = np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
        assert paths.delay_s[i] == pytest.approx(length / C0, rel=1e-12)


def reflection_law_residual(points, triangles):
    """Largest of: distance of each point from its triangle's plane, its distance outside
    the triangle, and the mismatch of the outgoing direction with the mirrored incoming
    one (unit vectors)."""
    worst = 0.0
    for j, tri in enumerate(triangles):
        a, b, c = tri
        n = np.cross(b - a, c - a)
        n /= np.linalg.norm(n)
        p = points[j + 1]
        worst = max(worst, abs(float(n @ (p - a))))
        # barycentric coordinates of p in the triangle: all >= 0 inside
        m = np.column_stack([b - a, c - a])
        uv = np.linalg.lstsq(m, p - a, rcond=None)[0]
        worst = max(worst, -min(uv[0], uv[1], 1 - uv[0] - uv[1], 0.0))
        d_in = (p - points[j]) / np.linalg.norm(p - points[j])
        d_out = (points[j + 2] - p) / np.linalg.norm(points[j + 2] - p)
        worst = max(worst, float(np.linalg.norm(d_out - (d_in - 2 * (d_in @ n) * n))))
    return worst


def test_expansion_finds_what_the_launch_missed_and_each_added_path_is_real(street_iso,
                                                                             runtime):
    launch, launch_seq = link_of(street_iso, go(30_000), runtime)
    expanded, expanded_seq = link_of(street_iso, go(30_000, expand=4), runtime)
    dense, dense_seq = link_of(street_iso, go(1_000_000), runtime)

    # the launch's paths come first, bit for bit
    n = len(launch.delay_s)
    np.testing.assert_array_equal(expanded.delay_s[:n], launch.delay_s)
    np.testing.assert_array_equal(expanded.gain[:n], launch.gain)
    assert expanded_seq[:n] == launch_seq
    assert len(expanded.delay_s) >= n + 3
    # no path twice
    assert len(distinct_paths(expanded_seq, expanded.delay_s)) == len(expanded.delay_s)

    check_real(expanded, expanded_seq, range(n, len(expanded.delay_s)), street_iso.triangles)

    # more than the dense launch finds in places: it confirms a path 1e6 rays miss
    vs_dense = match_paths(dense_seq, dense.delay_s, expanded_seq, expanded.delay_s)
    assert len(vs_dense.only_b) >= 1
    assert len(vs_dense.pairs) > len(match_paths(dense_seq, dense.delay_s, launch_seq,
                                                 launch.delay_s).pairs)


def test_the_receivers_launch_adds_the_paths_next_to_it(street_iso, runtime):
    one_way, one_seq = link_of(street_iso, go(30_000, expand=4), runtime)
    two_ways, two_seq = link_of(street_iso, go(30_000, expand=4, from_receiver=True),
                                runtime)
    m = match_paths(one_seq, one_way.delay_s, two_seq, two_ways.delay_s)
    assert len(m.only_a) == 0  # nothing lost
    assert len(m.only_b) >= 5
    assert len(distinct_paths(two_seq, two_ways.delay_s)) == len(two_ways.delay_s)
    check_real(two_ways, two_seq, m.only_b, street_iso.triangles)


def specular_only(specular):
    """The main job's specular search alone (no edges, optics or scattering)."""
    return dataclasses.replace(TraceSettings.preset("go", diffraction__max_diffractions=0),
                               specular=specular)


@pytest.mark.parametrize("t", [0.0, 0.9])
def test_the_main_jobs_specular_paths_hold_every_path_of_a_1e6_ray_launch(t, runtime):
    """The paper preset's specular search (3e5 rays + expansion) on the street's four
    links (sector antennas, cars where the paper has them and 0.9 s later): every path a
    1e6-ray launch finds (same object sequence, |d tau| < 1 ps), and each path beyond
    them real. At 0.9 s the 1e6-ray launch misses a path that expansion finds (and that
    1e7 rays find: docs/performance.md)."""
    scene = scene_at(load_scene(STREET), t)
    main = TraceSettings.preset("paper").specular
    assert main.rays < 1_000_000 and main.expand_rounds
    ours = trace_scene(scene, specular_only(main), runtime=runtime)
    dense = trace_scene(scene, specular_only(dataclasses.replace(
        main, rays=1_000_000, expand_rounds=None)), runtime=runtime)
    extra = 0
    for mine, theirs in zip(ours.links, dense.links, strict=True):
        p, q = mine.paths, theirs.paths
        seq = sequences_of(p.interaction, p.n_interactions, p.object_id, ours.object_names)
        ref = sequences_of(q.interaction, q.n_interactions, q.object_id, ours.object_names)
        m = match_paths(ref, q.delay_s, seq, p.delay_s)
        assert not len(m.only_a), (t, mine.tx_name, mine.rx_name, [ref[i] for i in m.only_a])
        check_real(p, seq, m.only_b, scene.triangles)
        extra += len(m.only_b)
    assert extra >= (1 if t == 0.9 else 0)


def blind_spot_scene():
    """Radars A at the origin and B 4 m along y, both isotropic; a 10 m wall at x = 10
    facing them, and a 0.3 m metal plate at x = -20 facing +x, centred on the specular
    point of A -> plate -> B, (-20, 2, 0). From A the plate subtends about 2e-4 sr: a
    launch of 2e3 rays over the sphere puts none on it, one of 2e6 some 40."""
    def plane(name, size, position, rotation_deg):
        return {"name": name, "material": "metal", "shape": "plane", "size": [size, size],
                "position": position, "rotation_deg": rotation_deg}
    return scene_from_dict({
        "scene": {"carrier_hz": 24e9, "name": "blind_spot"},
        "objects": [plane("wall", 10.0, [10.0, 2.0, 0.0], [0.0, -90.0, 0.0]),
                    plane("plate", 0.3, [-20.0, 2.0, 0.0], [0.0, 90.0, 0.0])],
        "radars": [{"name": "A", "position": [0.0, 0.0, 0.0]},
                   {"name": "B", "position": [0.0, 4.0, 0.0]}]}, file="blind_spot.toml")


def test_expansion_cannot_reach_a_face_no_confirmed_path_touches(runtime):
    """Where expansion can still miss (docs/performance.md): the plate's reflection is
    a real path, but no ray of a sparse launch reaches the plate, and the only confirmed
    reflection is off the wall, so no candidate of any round holds the plate. A dense
    launch finds the path, at the image method's closed-form delay."""
    scene = blind_spot_scene()

    def found(rays, expand=None):
        settings = TraceSettings.preset(
            "go", specular__rays=rays, specular__max_reflections=2,
            diffraction__max_diffractions=0, specular__expand_rounds=expand)
        p = trace_scene(scene, settings, runtime=runtime, links=[(0, 1)]).links[0].paths
        names = [o.name for o in scene.objects]
        return p, sequences_of(p.interaction, p.n_interactions, p.object_id, names)

    wall_path, plate_path = (((int(InteractionType.REFLECTION), name),)
                             for name in ("wall", "plate"))
    sparse, sparse_seq = found(2_000)
    assert wall_path in sparse_seq and plate_path not in sparse_seq
    expanded, expanded_seq = found(2_000, expand=4)
    assert wall_path in expanded_seq and plate_path not in expanded_seq

    dense, dense_seq = found(2_000_000)
    assert plate_path in dense_seq
    i = dense_seq.index(plate_path)
    length = 2.0 * np.hypot(20.0, 2.0)   # A -> (-20, 2, 0) -> B
    assert dense.delay_s[i] == pytest.approx(length / C0, rel=1e-9)
    check_real(dense, dense_seq, [i], scene.triangles)
