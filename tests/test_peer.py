"""What tools/bench_peer.py stands on, without Sionna RT: the one-to-one path matching
(clradcom.evaluation.peer) and the Mitsuba XML export of a scene
(clradcom.scene.export_xml), read back by clradcom's own XML importer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clradcom.errors import ArgumentError
from clradcom.evaluation.peer import distinct_paths, match_paths, sequences_of
from clradcom.scene.export_xml import PEC_CONDUCTIVITY_S_M, write_xml_scene
from clradcom.scene.materials import conductivity_to_eps_imag
from clradcom.scene.reader import load_scene

REPO = Path(__file__).resolve().parents[1]
STREET = REPO / "scenes" / "street" / "street.toml"

WALL = ((1, "wall"),)
ROAD_WALL = ((1, "road"), (1, "wall"))


def test_match_pairs_each_path_once_by_sequence_and_delay():
    a_seq = [(), WALL, ROAD_WALL, WALL]
    a_tau = [100e-9, 120e-9, 130e-9, 125e-9]
    # b: the same paths shuffled, delays off by 0.4 ps; plus one of another sequence at
    # the very delay of a's WALL path, and one WALL path 3 ps away from any of a's
    b_seq = [WALL, ROAD_WALL, (), WALL, ((1, "road"),), WALL]
    b_tau = [125e-9 + 0.4e-12, 130e-9 - 0.4e-12, 100e-9, 120e-9 + 0.4e-12, 120e-9,
             120e-9 + 3e-12]
    m = match_paths(a_seq, a_tau, b_seq, b_tau)
    assert m.pairs.tolist() == [[0, 2], [1, 3], [2, 1], [3, 0]]
    assert m.only_a.tolist() == []
    assert m.only_b.tolist() == [4, 5]
    np.testing.assert_allclose(m.delay_error_s, [0.0, 0.4e-12, -0.4e-12, 0.4e-12],
                               rtol=0, atol=1e-16)


def test_match_chooses_the_assignment_not_the_first_nearest():
    # a0 is nearest to b0 but a1 can only match b0: greedy nearest-first would pair
    # (a0, b0) and leave a1 unmatched; the assignment pairs both
    a_tau = [10e-9, 10e-9 + 0.9e-12]
    b_tau = [10e-9 + 0.5e-12, 10e-9 - 0.5e-12]
    m = match_paths([WALL, WALL], a_tau, [WALL, WALL], b_tau)
    assert sorted(m.pairs.tolist()) == [[0, 1], [1, 0]]


def test_match_tolerance_and_bad_input():
    m = match_paths([WALL], [1e-8], [WALL], [1e-8 + 2e-12])
    assert len(m.pairs) == 0 and m.only_a.tolist() == [0] and m.only_b.tolist() == [0]
    assert len(match_paths([WALL], [1e-8], [WALL], [1e-8 + 2e-12],
                           tolerance_s=5e-12).pairs) == 1
    with pytest.raises(ArgumentError, match="sequences_a"):
        match_paths([WALL, WALL], [1e-8], [], [])
    with pytest.raises(ArgumentError, match="delays_b"):
        match_paths([WALL], [1e-8], [WALL], [np.nan])


def test_distinct_paths_keeps_the_first_of_each_repeat():
    seqs = [WALL, WALL, ROAD_WALL, WALL, WALL]
    tau = [1e-8, 1e-8 + 0.3e-12, 1e-8, 1e-8 + 5e-12, 1e-8 - 0.2e-12]
    assert distinct_paths(seqs, tau).tolist() == [0, 2, 3]
    with pytest.raises(ArgumentError, match="sequences"):
        distinct_paths(seqs, tau[:2])


def test_sequences_of_snapshot_arrays():
    seqs = sequences_of(np.array([[1, 1], [0, 0], [1, 0]], np.int8), np.array([2, 0, 1]),
                        np.array([[0, 2], [-1, -1], [1, -1]]), ["road", "car", "wall"])
    assert seqs == [ROAD_WALL, (), ((1, "car"),)]


def test_xml_export_reads_back_as_the_same_scene(tmp_path):
    scene = load_scene(STREET)
    out = tmp_path / "xml"
    out.mkdir()
    xml = write_xml_scene(scene, out, thickness_m=1.0)
    toml = out / "imported.toml"
    toml.write_text(f'[scene]\ncarrier_hz = {scene.carrier_hz!r}\nimport = "{xml.name}"\n')
    back = load_scene(toml)
    assert [o.name for o in back.objects] == [o.name for o in scene.objects]
    # PLY holds float32 vertices: 10 um at the street's 80 m
    np.testing.assert_allclose(back.triangles, scene.triangles, rtol=0, atol=1e-5)
    np.testing.assert_array_equal(back.tri_object, scene.tri_object)
    for a, b in zip(scene.objects, back.objects, strict=True):
        ma, mb = scene.materials[a.material], back.materials[b.material]
        if ma.pec:
            assert mb.eps_r.imag == pytest.approx(
                -conductivity_to_eps_imag(PEC_CONDUCTIVITY_S_M, scene.carrier_hz))
        else:
            assert mb.eps_r == pytest.approx(ma.eps_r, rel=1e-12)
            assert mb.scattering_coefficient == ma.scattering_coefficient


def test_xml_export_refuses_a_missing_folder_and_bad_thickness(tmp_path):
    scene = load_scene(STREET)
    with pytest.raises(ArgumentError, match="folder"):
        write_xml_scene(scene, tmp_path / "nowhere")
    with pytest.raises(ArgumentError, match="thickness_m"):
        write_xml_scene(scene, tmp_path, thickness_m=0.0)
