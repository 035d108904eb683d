"""Scenes built and edited in Python (clradcom.scene.edit): the same scene as its TOML
file (hash and trace), the same refusals as the reader, copy-on-edit, moves that the
hash follows, save_scene round trips, and a short repr."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from test_scene_import import F_C, SQUARE, feature, geojson_scene, write_scene

from clradcom.errors import SceneError
from clradcom.scene import (
    add_material,
    add_object,
    add_radar,
    load_scene,
    move,
    new_scene,
    remove,
    save_scene,
    scene_from_dict,
    set_waveform,
)
from clradcom.scene.models import car_mesh
from clradcom.scene.motion import scene_at
from clradcom.trace import TraceSettings, trace_scene

ROOT = Path(__file__).resolve().parents[1]
STREET = ROOT / "scenes" / "street" / "street.toml"

# a car parked on a road, a radar looking at it: the same scene in code and in a file
CAR = car_mesh()
CAR_VERTS = np.asarray(CAR.vertices, dtype=np.float64)
CAR_FACES = np.asarray(CAR.faces, dtype=np.int64)


def built_in_code():
    scene = new_scene("parked", carrier_hz=24e9)
    scene = add_material(scene, "asphalt", eps_r=[3.2, -0.1], roughness_m=0.0004)
    scene = add_object(scene, "road", shape="plane", size=(60.0, 14.0), material="asphalt")
    scene = add_object(scene, "car", mesh=CAR, material="metal",
                       position=np.array([15.0, 1.0, 0.0]), rotation_deg=(0, 0, 20),
                       velocity=[-5.0, 0.0, 0.0])
    scene = add_radar(scene, "A", position=[0.0, 0.0, 0.6],
                      pattern={"type": "cosine", "half_power_beamwidth_deg": 60.0},
                      array={"kind": "ula", "count": 2, "spacing_wavelengths": 0.5})
    return set_waveform(scene, subcarriers=256, symbols=64)


def the_same_document() -> dict:
    """What a scene file says for :func:`built_in_code` (mesh inline, as TOML lists)."""
    return {
        "scene": {"name": "parked", "carrier_hz": 24e9},
        "materials": [{"name": "asphalt", "eps_r": [3.2, -0.1], "roughness_m": 0.0004}],
        "objects": [
            {"name": "road", "shape": "plane", "size": [60.0, 14.0], "material": "asphalt"},
            {"name": "car", "shape": "triangles", "vertices": CAR_VERTS.tolist(),
             "faces": CAR_FACES.tolist(), "material": "metal", "position": [15.0, 1.0, 0.0],
             "rotation_deg": [0, 0, 20], "velocity": [-5.0, 0.0, 0.0]}],
        "radars": [{"name": "A", "position": [0.0, 0.0, 0.6],
                    "pattern": {"type": "cosine", "half_power_beamwidth_deg": 60.0},
                    "array": {"kind": "ula", "count": 2, "spacing_wavelengths": 0.5}}],
        "waveform": {"subcarriers": 256, "symbols": 64},
    }


SETTINGS = TraceSettings.preset("fast", specular__rays=20_000)


def test_a_scene_built_in_code_traces_like_its_file(tmp_path):
    code = built_in_code()
    path = tmp_path / "parked.toml"
    path.write_text(tomli_w.dumps(the_same_document()))
    file = load_scene(path)
    assert code.content_hash() == file.content_hash()
    a, b = trace_scene(code, SETTINGS), trace_scene(file, SETTINGS)
    assert a.scene_hash == b.scene_hash
    assert len(a.links) == len(b.links) == 1
    pa, pb = a.links[0].paths, b.links[0].paths
    assert len(pa.gain) > 0
    np.testing.assert_array_equal(pa.gain, pb.gain)
    np.testing.assert_array_equal(pa.delay_s, pb.delay_s)
    np.testing.assert_array_equal(pa.doppler_hz, pb.doppler_hz)


def test_moving_the_car_changes_its_echo_and_the_hash():
    scene = built_in_code()
    moved = move(scene, "car", position=[25.0, 1.0, 0.0])
    assert moved.content_hash() != scene.content_hash()
    # the car's triangles moved by exactly the displacement, nothing else did
    car = scene.objects[scene.object_index("car")].tri_slice
    np.testing.assert_allclose(moved.triangles[car] - scene.triangles[car],
                               np.broadcast_to([10.0, 0.0, 0.0], scene.triangles[car].shape),
                               atol=1e-12)
    road = scene.objects[scene.object_index("road")].tri_slice
    np.testing.assert_array_equal(moved.triangles[road], scene.triangles[road])
    # the car's strongest return arrives 2 * 10 m / c later, within the car's own extent
    near = trace_scene(scene, SETTINGS).links[0].paths
    far = trace_scene(moved, SETTINGS).links[0].paths
    car_id = scene.object_index("car")

    def strongest_car_delay(paths):
        on_car = np.any(paths.object_id[:, :1] == car_id, axis=1)
        k = np.flatnonzero(on_car)[np.argmax(np.abs(paths.gain[on_car]))]
        return paths.delay_s[k]

    shift = strongest_car_delay(far) - strongest_car_delay(near)
    assert abs(shift - 2 * 10.0 / 299_792_458.0) < 2 * 2.0 / 299_792_458.0


def test_an_edit_leaves_the_scene_it_was_given_and_the_hash_comes_back():
    scene = built_in_code()
    before = scene.content_hash()
    there = move(scene, "car", position=[30.0, 1.0, 0.0], rotation_deg=[0, 0, 90])
    assert scene.content_hash() == before
    back = move(there, "car", position=[15.0, 1.0, 0.0], rotation_deg=[0, 0, 20])
    assert back.content_hash() == before
    # an edit that changes nothing keeps the hash
    assert move(scene, "car", velocity=[-5.0, 0.0, 0.0]).content_hash() == before


def test_a_keyword_given_as_none_is_the_files_default():
    scene = built_in_code()
    plain = add_radar(scene, "B", position=[1.0, 0.0, 0.6])
    nones = add_radar(scene, "B", position=[1.0, 0.0, 0.6], noise_figure_db=None,
                      pattern=None, velocity=None)
    assert plain.content_hash() == nones.content_hash()


def test_a_radar_riding_on_a_car_moves_with_it():
    scene = add_radar(built_in_code(), "B", position=[2.0, 0.0, 0.8], rides_on="car",
                      orientation_deg=[0, 0, 180])
    moved = move(scene, "car", position=[20.0, -1.0, 0.0], rotation_deg=[0, 0, 0])
    b = moved.radars[moved.radar_index("B")]
    np.testing.assert_allclose(b.position, [22.0, -1.0, 0.8], atol=1e-12)
    np.testing.assert_allclose(b.boresight, [-1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(b.velocity, [-5.0, 0.0, 0.0])


@pytest.mark.parametrize("entry, key", [
    ({"material": "unobtainium"}, "material"),
    ({"velocity": [float("nan"), 0.0, 0.0]}, "velocity"),
    ({"scale": -1.0}, "scale"),
    ({"optics": "rays"}, "optics"),
])
def test_an_object_built_in_code_is_refused_like_the_file(entry, key):
    doc = the_same_document()
    doc["objects"][1].update(entry)
    with pytest.raises(SceneError) as from_file:
        scene_from_dict(doc, file="parked.toml")
    scene = remove(built_in_code(), "car")
    with pytest.raises(SceneError) as from_code:
        add_object(scene, "car", mesh=(CAR_VERTS, CAR_FACES), position=[15.0, 1.0, 0.0],
                   rotation_deg=[0, 0, 20], **{"material": "metal", "velocity": [-5, 0, 0],
                                               **entry})
    assert from_code.value.key == from_file.value.key == f"objects[1].{key}"
    assert from_code.value.reason == from_file.value.reason


def test_bad_mesh_arrays_and_names_are_refused_by_key():
    scene = built_in_code()
    faces = CAR_FACES.copy()
    faces[3] = [0, 1, len(CAR_VERTS)]
    with pytest.raises(SceneError, match=r"objects\[2\]\.faces\[3\].*out of range"):
        add_object(scene, "bad", mesh=(CAR_VERTS, faces), material="metal")
    with pytest.raises(SceneError, match=r"objects\[2\]\.name.*duplicate"):
        add_object(scene, "car", mesh=CAR, material="metal")
    with pytest.raises(SceneError, match="'lorry': no object or radar"):
        move(scene, "lorry", position=[0, 0, 0])
    riding = add_radar(remove(scene, "A"), "B", position=[0, 0, 1], rides_on="car")
    with pytest.raises(SceneError, match=r"radars\[0\]\.rides_on"):
        remove(riding, "car")
    with pytest.raises(SceneError, match="turns by rotation_deg"):
        move(scene, "car", orientation_deg=[0, 0, 1])


def test_a_derived_scene_is_not_edited_silently():
    scene = built_in_code()
    later = scene_at(scene, 0.5)
    with pytest.raises(SceneError, match="no document to edit"):
        move(later, "car", position=[0.0, 0.0, 0.0])


def test_save_scene_round_trips_a_scene_built_in_code(tmp_path):
    scene = built_in_code()
    path = save_scene(scene, tmp_path / "out" / "parked.toml")
    text = path.read_text()
    assert 'mesh = "meshes/car.ply"' in text
    assert tomllib.loads(text)["waveform"] == {"subcarriers": 256, "symbols": 64}
    again = load_scene(path)
    assert again.content_hash() == scene.content_hash()


def test_save_scene_moves_the_street_files_paths(tmp_path):
    street = load_scene(STREET)
    edited = move(street, "carB", position=[12.0, -1.75, 0.0])
    path = save_scene(edited, tmp_path / "elsewhere" / "street_edited.toml")
    again = load_scene(path)
    assert again.content_hash() == edited.content_hash() != street.content_hash()


def test_repr_is_a_few_lines():
    street = load_scene(STREET)
    text = repr(street)
    assert len(text.splitlines()) <= 6 and len(text) < 600
    assert "61 object(s), 21,450 triangles" in text and "2 radar(s)" in text
    assert len(repr(street.objects[1])) < 150 and len(repr(street.radars[0])) < 200


def test_the_scene_api_example_runs_as_written(tmp_path, monkeypatch):
    """docs/scene-api.md's example, with fewer rays: the moved car is found nearer."""
    text = (ROOT / "docs" / "scene-api.md").read_text()
    (code,) = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    old = 'TraceSettings.preset("fast")'
    assert code.count(old) == 1
    code = code.replace(old, 'TraceSettings.preset("fast", specular__rays=20_000)')
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(code, "docs/scene-api.md", "exec"), ns)
    car = ns["scene"].object_index("car0")

    def nearest_car_delay(snapshot):
        paths = snapshot.links[0].paths
        return paths.delay_s[np.any(paths.object_id[:, :1] == car, axis=1)].min()

    # car0 moved 6 m away from the radar: its nearest return 2 * ~6 m / c later
    shift = nearest_car_delay(ns["snapshot2"]) - nearest_car_delay(ns["snapshot"])
    assert abs(shift * 299_792_458.0 / 2 - 6.0) < 0.5
    assert (tmp_path / "out" / "meshes" / "car0.ply").is_file()


def test_load_scene_reads_xml_and_geojson_as_the_toml_that_imports_them(tmp_path):
    """A Mitsuba/Sionna XML scene or a GeoJSON file, given a carrier, are the objects of
    the TOML file that imports them; radars added in code make the very same scene."""
    toml = write_scene(tmp_path)
    from_toml = load_scene(toml)
    xml = load_scene(tmp_path / "canyon.xml", carrier_hz=F_C)
    assert [o.name for o in xml.objects] == [o.name for o in from_toml.objects]
    assert xml.radars == [] and xml.name == "canyon"
    xml = add_radar(xml, "tx", role="tx", position=[0.0, -2.0, 1.5])
    xml = add_radar(xml, "rx", role="rx", position=[0.0, 3.0, 1.5])
    assert xml.content_hash() == from_toml.content_hash()
    # and saved, the CLI reads it back as the same scene
    assert load_scene(save_scene(xml, tmp_path / "out" / "canyon.toml")).content_hash() \
        == from_toml.content_hash()
    with pytest.raises(SceneError, match=r"carrier_hz=\.\.\.\).*import = 'canyon.xml'"):
        load_scene(tmp_path / "canyon.xml")
    with pytest.raises(SceneError, match="carrier_hz: only for an XML or GeoJSON file"):
        load_scene(toml, carrier_hz=F_C)
    # an imported shape is edited in its file: moving it here is refused, naming that
    with pytest.raises(SceneError, match=r"object 'wall' comes whole from .*wall\.ply"):
        move(xml, "wall", position=[0.0, 0.0, 0.0])

    city = load_scene(geojson_scene(tmp_path, [feature("house", [SQUARE], height=9)]))
    geo = load_scene(tmp_path / "buildings.geojson", carrier_hz=F_C,
                     material="itu_concrete", coordinates="metres")
    assert [o.name for o in geo.objects] == ["buildings/house"]
    np.testing.assert_array_equal(geo.triangles, city.triangles)
    with pytest.raises(SceneError, match=r"objects\[0\]\.material"):
        load_scene(tmp_path / "buildings.geojson", carrier_hz=F_C, coordinates="metres")


def test_the_scene_api_loads_no_mesh_library_until_a_mesh_file_is_read():
    """clradcom.scene (and so the tracer) imports without trimesh: save_scene's PLY
    writer is numpy (clradcom.scene.meshfiles), trimesh comes with the first mesh file."""
    probe = ("import sys, clradcom.scene, clradcom.trace; "
             "print(sorted(m for m in ('trimesh', 'shapely') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"
