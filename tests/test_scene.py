"""Scene files: loading, transforms, rides_on, mesh files, flattened arrays, hashing, and
one test per refusal (each message names file, key path and value)."""

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from clradcom.errors import (
    ArgumentTypeError,
    PhysicsWarning,
    SceneError,
    SceneWarning,
    ValidityRangeWarning,
)
from clradcom.scene.antenna import SectorPattern
from clradcom.scene.reader import load_scene, scene_from_dict

CANON = Path(__file__).resolve().parents[1] / "scenes" / "canonical"


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


HEAD = '[scene]\nname = "t"\ncarrier_hz = 24e9\n'
PLANE = '[[objects]]\nname = "p"\nmaterial = "metal"\nshape = "plane"\nsize = [1.0, 1.0]\n'


# -- canonical scenes ---------------------------------------------------------------------


@pytest.mark.parametrize("name", ["plate", "two_ray", "dihedral", "corner", "corner_mesh",
                                  "moving_car"])
def test_canonical_scenes_load_with_plain_arrays(name):
    s = load_scene(CANON / f"{name}.toml")
    t = s.triangles
    assert t.dtype == np.float64 and t.ndim == 3 and t.shape[1:] == (3, 3)
    assert t.flags.c_contiguous
    assert s.tri_object.dtype == np.int32 and s.tri_object.shape == (t.shape[0],)
    assert s.tri_material.dtype == np.int32 and s.tri_material.shape == (t.shape[0],)
    assert s.object_velocity.dtype == np.float64
    assert s.object_velocity.shape == (len(s.objects), 3)
    assert s.carrier_hz == 24e9
    assert s.wavelength_m == pytest.approx(0.0124914, abs=1e-7)
    for i, o in enumerate(s.objects):
        assert np.all(s.tri_object[o.tri_slice] == i)
        assert np.all(s.tri_material[o.tri_slice] == o.material)


def test_plate_faces_radar_at_10m():
    s = load_scene(CANON / "plate.toml")
    t = s.triangles
    assert t.shape == (2, 3, 3)
    assert np.allclose(t[..., 0], 10.0)
    assert np.allclose(np.sort(np.unique(np.round(t[..., 1], 12))), [-0.5, 0.5])
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert np.allclose(n / np.linalg.norm(n, axis=1)[:, None], [-1, 0, 0])
    assert 0.5 * np.linalg.norm(n, axis=1).sum() == pytest.approx(1.0)
    assert s.materials[0].pec and s.radars[0].position.tolist() == [0, 0, 0]


def test_two_ray_geometry_and_road_material():
    s = load_scene(CANON / "two_ray.toml")
    assert np.allclose(s.triangles[..., 2], 0.0)
    road = s.materials[s.objects[0].material]
    assert road.eps_r == complex(5, -0.1) and road.roughness_m == pytest.approx(4e-4)
    tx, rx = s.radars
    assert (tx.role, rx.role) == ("tx", "rx")
    assert tx.position.tolist() == [0, 0, 0.5] and rx.position.tolist() == [10, 0, 0.5]
    assert np.allclose(rx.boresight, [-1, 0, 0])


def test_corner_axis_points_at_radar_and_mesh_file_matches():
    s = load_scene(CANON / "corner.toml")
    o = s.objects[0]
    axis = o.rotation @ (np.ones(3) / math.sqrt(3))
    assert np.allclose(axis, [-1, 0, 0])
    normals = np.cross(s.triangles[:, 1] - s.triangles[:, 0],
                       s.triangles[:, 2] - s.triangles[:, 0])
    # every plate faces the radar side (into the corner)
    assert np.all(normals @ np.array([-1.0, 0, 0]) > 0)
    m = load_scene(CANON / "corner_mesh.toml")
    assert m.objects[0].mesh.endswith("trihedral.obj")
    assert np.allclose(m.triangles, s.triangles, atol=1e-15)
    assert m.content_hash() == s.content_hash()


def test_dihedral_plates_are_perpendicular():
    s = load_scene(CANON / "dihedral.toml")
    t = s.triangles
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    assert n[0] @ n[2] == pytest.approx(0.0, abs=1e-12)
    assert np.all(n[:, 0] < 0)  # both face the radar at the origin
    assert 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]),
                                axis=1).sum() == pytest.approx(0.02)


def test_moving_car_radar_rides_on_car_a():
    s = load_scene(CANON / "moving_car.toml")
    r = s.radars[0]
    a = s.object_index("carA")
    assert r.rides_on == a
    assert np.allclose(r.position, [1.95, 0.0, 0.5])
    assert np.allclose(r.velocity, [12.9, 0, 0])
    assert isinstance(r.pattern, SectorPattern) and r.pattern.inside_gain == 4.0
    assert r.tx_power_w == 0.01 and r.noise_figure_db == 10.0
    assert np.allclose(s.object_velocity[s.object_index("carB")], [-13.3, 0, 0])
    # box car B: 12 outward-facing triangles, 8 corners at +-1.9, +-0.925, 0..1.7
    b = s.objects[s.object_index("carB")]
    tb = s.triangles[b.tri_slice]
    assert b.n_triangles == 12
    assert np.allclose([tb[..., 0].min(), tb[..., 0].max()], [14.5, 18.3])
    assert np.allclose([tb[..., 2].min(), tb[..., 2].max()], [0.0, 1.7])


# -- transforms --------------------------------------------------------------------------


def test_transform_scale_then_rotate_then_translate(tmp_path):
    p = write(tmp_path, HEAD + '[[objects]]\nname = "t"\nmaterial = "metal"\n'
              'shape = "triangles"\nvertices = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], '
              '[0.0, 0.0, 1.0]]\nfaces = [[0, 1, 2]]\nscale = [2.0, 3.0, 4.0]\n'
              'rotation_deg = [90.0, 0.0, 90.0]\nposition = [10.0, 20.0, 30.0]\n')
    s = load_scene(p)
    # roll 90 (about x) then yaw 90 (about z): x->y, y->z, z->x
    # (1,0,0)*2 -> (0,2,0); (0,1,0)*3 -> (0,0,3); (0,0,1)*4 -> (4,0,0); then + position
    assert np.allclose(s.triangles[0], [[10, 22, 30], [10, 20, 33], [14, 20, 30]])
    o = s.objects[0]
    assert o.scale.tolist() == [2, 3, 4] and o.rotation_deg.tolist() == [90, 0, 90]


def test_rides_on_composes_rotation_and_position(tmp_path):
    p = write(tmp_path, HEAD + '[[objects]]\nname = "car"\nmaterial = "metal"\nshape = "box"\n'
              'extents = [4.0, 2.0, 1.5]\nposition = [5.0, 1.0, 0.75]\n'
              'rotation_deg = [0.0, 0.0, 90.0]\nscale = 2.0\nvelocity = [0.0, 10.0, 0.0]\n'
              '[[radars]]\nname = "r"\nrides_on = "car"\nposition = [2.0, 0.0, 0.5]\n'
              'orientation_deg = [0.0, 0.0, 30.0]\npattern = "sector"\n')
    s = load_scene(p)
    r = s.radars[0]
    # car frame x axis points along world +y after the 90 deg yaw; offset not scaled
    assert np.allclose(r.position, [5.0, 3.0, 1.25])
    assert np.allclose(r.velocity, [0, 10, 0])
    assert np.allclose(r.boresight, [-math.sin(math.radians(30)), math.cos(math.radians(30)),
                                     0])
    assert np.allclose(r.position_local, [2, 0, 0.5])
    d = r.world_to_local(r.boresight[None, :])
    assert np.allclose(d, [[1, 0, 0]])
    assert np.allclose(s.radar_position, [r.position]) and s.radar_orientation.shape == (1, 3,
                                                                                          3)


def test_free_radar_velocity_and_polarisation(tmp_path):
    p = write(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 1.0]\n'
              'velocity = [1.0, 2.0, 3.0]\npolarization = [[1.0, 0.0], [0.0, -1.0]]\n'
              'pattern = { type = "cosine", half_power_beamwidth_deg = 60.0 }\n')
    s = load_scene(p)
    r = s.radars[0]
    assert r.velocity.tolist() == [1, 2, 3] and r.rides_on == -1
    assert np.allclose(r.polarization, np.array([1, -1j]) / math.sqrt(2))
    assert r.polarization_name == "jones"
    assert s.triangles.shape == (0, 3, 3) and s.object_velocity.shape == (0, 3)


def test_pattern_file_in_scene(tmp_path):
    th = np.linspace(0, 180, 37)
    ph = np.linspace(-180, 170, 36)
    np.savez(tmp_path / "pat.npz", theta_deg=th, phi_deg=ph, gain_db=np.zeros((37, 36)))
    p = write(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 1.0]\n'
              'polarization = "H"\npattern = { type = "file", path = "pat.npz" }\n')
    r = load_scene(p).radars[0]
    assert r.pattern.gain(np.array([[0, 0, 1.0]]))[0] == pytest.approx(1.0, rel=1e-3)
    assert np.allclose(r.pattern.field(np.array([[1.0, 0, 0]]))[0, 0], 0)


# -- mesh files ------------------------------------------------------------------------------


@pytest.mark.parametrize("ext", ["ply", "stl", "obj", "glb"])
def test_mesh_formats_load_in_world_frame(tmp_path, ext):
    box = trimesh.creation.box(extents=[1.0, 2.0, 3.0])
    box.export(tmp_path / f"box.{ext}")
    p = write(tmp_path, HEAD + f'[[objects]]\nname = "b"\nmaterial = "metal"\n'
              f'mesh = "box.{ext}"\nposition = [0.0, 0.0, 1.5]\n')
    s = load_scene(p)
    assert s.triangles.shape == (12, 3, 3)
    lo, hi = s.triangles.reshape(-1, 3).min(0), s.triangles.reshape(-1, 3).max(0)
    assert np.allclose(lo, [-0.5, -1, 0]) and np.allclose(hi, [0.5, 1, 3])


def test_glb_with_several_geometries_is_concatenated(tmp_path):
    a = trimesh.creation.box(extents=[1, 1, 1])
    b = trimesh.creation.box(extents=[1, 1, 1])
    b.apply_translation([5, 0, 0])
    trimesh.Scene([a, b]).export(tmp_path / "two.glb")
    p = write(tmp_path, HEAD + '[[objects]]\nname = "b"\nmaterial = "metal"\nmesh = "two.glb"\n')
    s = load_scene(p)
    assert s.triangles.shape == (24, 3, 3)
    assert s.triangles[..., 0].max() == pytest.approx(5.5)


def test_same_mesh_used_twice_and_drop_degenerate_warns(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n")
    p = write(tmp_path, HEAD + '[[objects]]\nname = "a"\nmaterial = "metal"\nmesh = "m.obj"\n'
              'drop_degenerate = true\n[[objects]]\nname = "b"\nmaterial = "metal"\n'
              'mesh = "m.obj"\nposition = [0.0, 0.0, 1.0]\ndrop_degenerate = true\n')
    with pytest.warns(SceneWarning, match="degenerate"):
        s = load_scene(p)
    assert s.triangles.shape == (2, 3, 3)
    assert [o.tri_start for o in s.objects] == [0, 1]


# -- hashing -----------------------------------------------------------------------------------


def test_content_hash_stable_and_sensitive(tmp_path):
    text = (CANON / "moving_car.toml").read_text()
    h1 = load_scene(CANON / "moving_car.toml").content_hash()
    assert h1 == load_scene(write(tmp_path, text, "copy.toml")).content_hash()
    assert len(h1) == 64 and int(h1, 16) >= 0
    changed = text.replace("velocity = [-13.3, 0.0, 0.0]", "velocity = [-13.4, 0.0, 0.0]")
    assert load_scene(write(tmp_path, changed, "c2.toml")).content_hash() != h1
    described = text.replace('name = "moving_car"', 'name = "other"')
    assert load_scene(write(tmp_path, described, "c3.toml")).content_hash() == h1


def test_scene_from_dict():
    s = scene_from_dict({"scene": {"carrier_hz": 5.8e9},
                         "objects": [{"name": "g", "material": "itu_wet_ground",
                                      "shape": "plane", "size": [10, 10]}]})
    assert s.materials[0].eps_r.real == pytest.approx(30 * 5.8**-0.4)


# -- refusals: one test each; message names file, key path and value -------------------------------


def refused(tmp_path, text, key, value, *fragments, name="s.toml"):
    p = write(tmp_path, text, name)
    with pytest.raises(SceneError) as ei:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            load_scene(p)
    e = ei.value
    msg = str(e)
    assert e.file == str(p) and name in msg
    assert e.key == key and key in msg
    if value is not None:
        assert e.value == value
        assert repr(value)[:60] in msg
    for f in fragments:
        assert f in msg, msg
    return e


def test_err_toml_syntax_reports_line(tmp_path):
    p = write(tmp_path, HEAD + "[[objects]]\nname = \n")
    with pytest.raises(SceneError) as ei:
        load_scene(p)
    assert ei.value.line == 5 and f"{p}:5" in str(ei.value) and "TOML syntax" in str(ei.value)


def test_err_scene_file_missing(tmp_path):
    with pytest.raises(SceneError, match="not found") as ei:
        load_scene(tmp_path / "nope.toml")
    assert "nope.toml" in str(ei.value)


def test_err_unknown_top_level_key(tmp_path):
    refused(tmp_path, HEAD + '[[object]]\nname = "x"\n', "object", [{"name": "x"}],
            "did you mean 'objects'")


def test_err_unknown_nested_key(tmp_path):
    refused(tmp_path, HEAD + PLANE + "velocty = [1.0, 0.0, 0.0]\n", "objects[0].velocty",
            [1.0, 0.0, 0.0], "did you mean 'velocity'")


def test_err_unknown_scene_key(tmp_path):
    refused(tmp_path, HEAD + "carrier = 24e9\n", "scene.carrier", 24e9, "carrier_hz")


def test_err_missing_scene_table(tmp_path):
    refused(tmp_path, PLANE, "scene", None, "missing")


def test_err_missing_carrier(tmp_path):
    refused(tmp_path, '[scene]\nname = "x"\n', "scene.carrier_hz", None, "missing required")


@pytest.mark.parametrize("value", ["0.0", "-24e9"])
def test_err_carrier_not_positive(tmp_path, value):
    refused(tmp_path, f"[scene]\ncarrier_hz = {value}\n", "scene.carrier_hz", float(value),
            "> 0")


def test_err_carrier_wrong_type(tmp_path):
    refused(tmp_path, '[scene]\ncarrier_hz = "24 GHz"\n', "scene.carrier_hz", "24 GHz",
            "expected a number (Hz)")


def test_err_missing_object_name(tmp_path):
    refused(tmp_path, HEAD + '[[objects]]\nmaterial = "metal"\nshape = "plane"\n'
            'size = [1.0, 1.0]\n', "objects[0].name", None, "missing required")


def test_err_objects_not_array_of_tables(tmp_path):
    refused(tmp_path, HEAD + '[objects]\nname = "x"\n', "objects", {"name": "x"},
            "[[objects]]")


def test_err_wrong_type_vector(tmp_path):
    refused(tmp_path, HEAD + PLANE + 'velocity = "fast"\n', "objects[0].velocity", "fast",
            "array of 3 numbers (m/s)")


def test_err_wrong_length_vector(tmp_path):
    refused(tmp_path, HEAD + PLANE + "position = [1.0, 2.0]\n", "objects[0].position",
            [1.0, 2.0], "array of 3 numbers")


def test_err_nan_coordinate(tmp_path):
    refused(tmp_path, HEAD + PLANE + "position = [1.0, nan, 0.0]\n", "objects[0].position",
            None, "NaN or inf")


def test_err_inf_velocity(tmp_path):
    refused(tmp_path, HEAD + PLANE + "velocity = [inf, 0.0, 0.0]\n", "objects[0].velocity",
            [math.inf, 0.0, 0.0], "NaN or inf")


def test_err_nan_in_inline_vertices(tmp_path):
    refused(tmp_path, HEAD + '[[objects]]\nname = "t"\nmaterial = "metal"\nshape = "triangles"\n'
            "vertices = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, nan, 0.0]]\n"
            "faces = [[0, 1, 2]]\n", "objects[0].vertices[2]", None, "NaN or inf")


def test_err_bool_is_not_a_number(tmp_path):
    refused(tmp_path, HEAD + PLANE + "scale = true\n", "objects[0].scale", True,
            "expected a number")


@pytest.mark.parametrize("value", ["0.0", "-1.0", "[1.0, 0.0, 1.0]"])
def test_err_scale_not_positive(tmp_path, value):
    refused(tmp_path, HEAD + PLANE + f"scale = {value}\n", "objects[0].scale", None, "> 0",
            value)


def test_err_duplicate_object_name(tmp_path):
    refused(tmp_path, HEAD + PLANE + PLANE, "objects[1].name", "p", "duplicate object",
            "objects[0]")


def test_err_duplicate_radar_name(tmp_path):
    r = '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
    refused(tmp_path, HEAD + r + r, "radars[1].name", "r", "duplicate radar")


def test_err_rides_on_unknown_object(tmp_path):
    refused(tmp_path, HEAD + PLANE + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            'rides_on = "P"\n', "radars[0].rides_on", "P", "no object", "objects: p")


def test_err_rides_on_with_velocity(tmp_path):
    refused(tmp_path, HEAD + PLANE + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            'rides_on = "p"\nvelocity = [1.0, 0.0, 0.0]\n', "radars[0].velocity",
            [1.0, 0.0, 0.0], "moves with it")


def test_err_mesh_and_shape_both(tmp_path):
    refused(tmp_path, HEAD + PLANE + 'mesh = "x.ply"\n', "objects[0]", None, "exactly one of")


def test_err_unknown_shape(tmp_path):
    refused(tmp_path, HEAD + '[[objects]]\nname = "s"\nmaterial = "metal"\nshape = "sphere"\n',
            "objects[0].shape", "sphere", "box, plane, triangles")


def test_err_shape_parameter_for_other_shape(tmp_path):
    refused(tmp_path, HEAD + PLANE + "extents = [1.0, 1.0, 1.0]\n", "objects[0].extents",
            [1.0, 1.0, 1.0], "only applies to shape = 'box'")


def test_err_box_extents_not_positive(tmp_path):
    refused(tmp_path, HEAD + '[[objects]]\nname = "b"\nmaterial = "metal"\nshape = "box"\n'
            "extents = [1.0, 0.0, 1.0]\n", "objects[0].extents", [1.0, 0.0, 1.0], "> 0")


def test_err_face_index_out_of_range(tmp_path):
    refused(tmp_path, HEAD + '[[objects]]\nname = "t"\nmaterial = "metal"\nshape = "triangles"\n'
            "vertices = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]\n"
            "faces = [[0, 1, 3]]\n", "objects[0].faces[0]", [0, 1, 3], "out of range 0..2")


def test_err_degenerate_inline_triangle(tmp_path):
    refused(tmp_path, HEAD + '[[objects]]\nname = "t"\nmaterial = "metal"\nshape = "triangles"\n'
            "vertices = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0]]\n"
            "faces = [[0, 1, 3], [0, 1, 2]]\n", "objects[0].faces", 1, "triangle 1",
            "degenerate", "drop_degenerate")


def test_err_missing_mesh_file(tmp_path):
    refused(tmp_path, HEAD + '[[objects]]\nname = "m"\nmaterial = "metal"\n'
            'mesh = "meshes/car.ply"\n', "objects[0].mesh", "meshes/car.ply",
            "mesh file not found", str(tmp_path / "meshes" / "car.ply"))


def test_err_unsupported_mesh_type(tmp_path):
    (tmp_path / "car.blend").write_bytes(b"x")
    refused(tmp_path, HEAD + '[[objects]]\nname = "m"\nmaterial = "metal"\nmesh = "car.blend"\n',
            "objects[0].mesh", "car.blend", "unsupported mesh file type")


def test_err_unreadable_mesh(tmp_path):
    (tmp_path / "car.glb").write_bytes(b"this is not a glb file at all")
    refused(tmp_path, HEAD + '[[objects]]\nname = "m"\nmaterial = "metal"\nmesh = "car.glb"\n',
            "objects[0].mesh", "car.glb", "cannot read mesh file")


def test_err_mesh_without_triangles(tmp_path):
    (tmp_path / "empty.obj").write_text("v 0 0 0\nv 1 0 0\n")
    refused(tmp_path, HEAD + '[[objects]]\nname = "m"\nmaterial = "metal"\nmesh = "empty.obj"\n',
            "objects[0].mesh", "empty.obj", "no triangles")


def test_err_nan_in_mesh_file(tmp_path):
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n")
    refused(tmp_path, HEAD + '[[objects]]\nname = "m"\nmaterial = "metal"\nmesh = "nan.obj"\n',
            "objects[0].mesh", "nan.obj", "vertex 2", "NaN or inf", "nan.obj")


def test_err_degenerate_triangle_in_mesh_file(tmp_path):
    (tmp_path / "deg.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n")
    refused(tmp_path, HEAD + '[[objects]]\nname = "m"\nmaterial = "metal"\nmesh = "deg.obj"\n',
            "objects[0].mesh", "deg.obj", "triangle 1 of", "deg.obj", "degenerate")


def test_err_unknown_pattern(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            'pattern = "dipole"\n', "radars[0].pattern", "dipole", "isotropic, sector")


def test_err_pattern_unknown_parameter(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            'pattern = { type = "sector", azimuth_deg = 90.0 }\n',
            "radars[0].pattern.azimuth_deg", 90.0, "azimuth_width_deg")


def test_err_cosine_needs_exactly_one_parameter(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            'pattern = { type = "cosine" }\n', "radars[0].pattern", {"type": "cosine"},
            "exactly one of q or half_power_beamwidth_deg")


def test_err_sector_width_out_of_range(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            'pattern = { type = "sector", elevation_width_deg = 200.0 }\n',
            "radars[0].pattern.elevation_width_deg", 200.0, "<= 180")


def test_err_pattern_file_missing(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            'pattern = { type = "file", path = "ant.csv" }\n', "radars[0].pattern.path",
            "ant.csv", "pattern file not found")


def test_err_pattern_file_malformed(tmp_path):
    (tmp_path / "ant.csv").write_text("theta_deg,phi_deg,gain_db\n0,0,1\n180,0,x\n")
    e = refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
                'pattern = { type = "file", path = "ant.csv" }\n', "radars[0].pattern.path",
                "ant.csv", "bad pattern file", "not a number", "'x'")
    assert str(tmp_path / "ant.csv") + ":3" in str(e)


def test_err_bad_polarization(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            'polarization = "slant"\n', "radars[0].polarization", "slant", "unknown polarization")


def test_err_zero_jones_vector(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            "polarization = [0.0, 0.0]\n", "radars[0].polarization", [0.0, 0.0], "zero")


def test_err_bad_role(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            'role = "both"\n', "radars[0].role", "both", "txrx, tx, rx")


def test_err_negative_tx_power(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            "tx_power_w = -1.0\n", "radars[0].tx_power_w", -1.0, ">= 0")


def test_err_radar_missing_position(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\n', "radars[0].position", None,
            "missing required")


def test_error_is_a_value_error_with_fields(tmp_path):
    e = refused(tmp_path, HEAD + PLANE + "scale = -2.0\n", "objects[0].scale", -2.0)
    assert isinstance(e, ValueError) and e.reason and e.line is None
    assert str(e).startswith(f"{e.file}: objects[0].scale = -2.0: ")


def test_docs_scene_format_example_loads(tmp_path):
    import re

    doc = (CANON.parents[1] / "docs" / "scene-format.md").read_text()
    block = re.findall(r"```toml\n(.*?)```", doc, re.S)[0]
    (tmp_path / "meshes").mkdir()
    trimesh.creation.box(extents=[3.8, 1.85, 1.7]).export(tmp_path / "meshes" / "car.ply")
    s = load_scene(write(tmp_path, block, "example.toml"))
    assert [o.name for o in s.objects] == ["road", "carA"]
    assert s.materials[0].name == "wet_concrete" and s.materials[0].roughness_m == 0.002
    assert np.allclose(s.radars[0].position, [1.95, 0.0, 0.5])
    assert np.allclose(s.radars[0].velocity, [12.9, 0, 0])


# -- physical bounds (docs/scene-format.md "Physical bounds") --------------------------------


def loads_quietly(tmp_path, text, name="s.toml"):
    """The scene, asserting that loading it warns of nothing."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return load_scene(write(tmp_path, text, name))


def warns_once(tmp_path, text, *fragments, name="s.toml"):
    """The scene and the one ValidityRangeWarning loading it gives (with ``fragments``)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        s = load_scene(write(tmp_path, text, name))
    got = [w for w in caught if issubclass(w.category, ValidityRangeWarning)]
    assert len(got) == 1, [str(w.message) for w in caught]
    assert issubclass(got[0].category, SceneWarning)
    assert issubclass(got[0].category, PhysicsWarning)
    for f in fragments:
        assert f in str(got[0].message), str(got[0].message)
    return s


@pytest.mark.parametrize("value, fragment", [("1e30", "3 THz"), ("3.1e12", "3 THz"),
                                             ("1.0", "3 MHz"), ("2.9e6", "3 MHz")])
def test_err_carrier_outside_radio(tmp_path, value, fragment):
    refused(tmp_path, f"[scene]\ncarrier_hz = {value}\n", "scene.carrier_hz", float(value),
            fragment)


@pytest.mark.parametrize("value", ["3e6", "0.5e9", "400e9", "3e12"])
def test_carrier_outside_the_methods_range_warns(tmp_path, value):
    s = warns_once(tmp_path, f"[scene]\ncarrier_hz = {value}\n", "scene.carrier_hz",
                   "1-300 GHz", "s.toml")
    assert s.carrier_hz == float(value)


@pytest.mark.parametrize("value", ["1e9", "24e9", "77e9", "300e9"])
def test_carrier_inside_the_methods_range_is_quiet(tmp_path, value):
    assert loads_quietly(tmp_path, f"[scene]\ncarrier_hz = {value}\n").carrier_hz == float(value)


def test_err_object_at_the_speed_of_light(tmp_path):
    refused(tmp_path, HEAD + PLANE + "velocity = [-299792458.0, 0.0, 0.0]\n",
            "objects[0].velocity", [-299792458.0, 0.0, 0.0], "speed of light")


def test_err_radar_faster_than_light(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            "velocity = [6e8, 8e8, 0.0]\n", "radars[0].velocity", [6e8, 8e8, 0.0],
            "speed 1e+09 m/s is not below the speed of light")


def test_fast_objects_and_radars_warn_once_naming_them(tmp_path):
    fast = HEAD + PLANE + "velocity = [0.0, 4e5, 0.0]\n" + PLANE.replace('"p"', '"q"') + (
        "velocity = [1e8, 0.0, 0.0]\n[[radars]]\nname = \"r\"\nposition = [0.0, 0.0, 0.0]\n"
        "velocity = [0.0, 0.0, -5e5]\n")
    s = warns_once(tmp_path, fast, "objects[0].velocity (400000 m/s)",
                   "objects[1].velocity (1e+08 m/s)", "radars[0].velocity (500000 m/s)",
                   "first-order Doppler")
    assert s.object_velocity[1, 0] == 1e8


def test_road_speeds_and_aircraft_are_quiet(tmp_path):
    loads_quietly(tmp_path, HEAD + PLANE + "velocity = [250.0, 0.0, 0.0]\n"
                  "[[radars]]\nname = \"r\"\nposition = [0.0, 0.0, 0.0]\n"
                  "velocity = [0.0, 299.0, 0.0]\n")


def test_err_negative_noise_figure(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            "noise_figure_db = -60.0\n", "radars[0].noise_figure_db", -60.0, ">= 0 dB",
            "by definition")


def test_err_noise_figure_beyond_any_receiver(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            "noise_figure_db = 5000\n", "radars[0].noise_figure_db", 5000, "<= 300 dB")


@pytest.mark.parametrize("text, value, fragment", [("inf", math.inf, "NaN or inf"),
                                                   ("1e13", 1e13, "<= 1e+12 W")])
def test_err_tx_power_infinite_or_beyond_any_transmitter(tmp_path, text, value, fragment):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
            f"tx_power_w = {text}\n", "radars[0].tx_power_w", value, fragment)


def test_zero_tx_power_and_zero_noise_figure_load(tmp_path):
    r = loads_quietly(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]\n'
                      "tx_power_w = 0\nnoise_figure_db = 0\n").radars[0]
    assert r.tx_power_w == 0.0 and r.noise_figure_db == 0.0


# -- numbers, nesting and geometry beyond what float64 / float32 hold -------------------------


def test_err_integer_too_large_for_a_float(tmp_path):
    big = int("9" * 401)
    refused(tmp_path, f"[scene]\ncarrier_hz = {big}\n", "scene.carrier_hz", big,
            "too large")
    refused(tmp_path, HEAD + PLANE + f"velocity = [{big}, 0, 0]\n", "objects[0].velocity",
            [big, 0, 0], "too large")


def test_err_integer_with_more_digits_than_python_converts(tmp_path):
    p = write(tmp_path, "[scene]\ncarrier_hz = " + "9" * 5000 + "\n")
    with pytest.raises(SceneError, match="TOML value refused") as ei:
        load_scene(p)
    assert ei.value.file == str(p)


@pytest.mark.parametrize("doc", ["[scene]\ncarrier_hz = 24e9\nx = " + "[" * 50_000
                                 + "]" * 50_000 + "\n",
                                 "a = " + "{b = " * 50_000 + "1" + "}" * 50_000 + "\n"])
def test_err_toml_nested_50000_deep(tmp_path, doc):
    p = write(tmp_path, doc)
    with pytest.raises(SceneError, match="nested too deeply") as ei:
        load_scene(p)
    assert ei.value.file == str(p)


def test_err_value_nested_too_deep_for_repr_still_names_key():
    v: list = []
    for _ in range(100_000):
        v = [v]
    with pytest.raises(SceneError) as ei:
        scene_from_dict({"scene": {"carrier_hz": 24e9}, "objects": [
            {"name": "p", "material": "metal", "shape": "plane", "size": [1, 1],
             "velocity": v}]})
    assert ei.value.key == "objects[0].velocity" and "[[[" in str(ei.value)


def test_err_scale_overflowing_the_vertices_names_scale(tmp_path):
    refused(tmp_path, HEAD + PLANE + "scale = 1e307\n", "objects[0].scale", 1e307,
            "not finite", "float32")


def test_err_scale_flattening_triangles_names_scale(tmp_path):
    refused(tmp_path, HEAD + PLANE + "scale = [1.0, 1e-200, 1.0]\n", "objects[0].scale",
            [1.0, 1e-200, 1.0], "triangle 0", "flattens it")


def test_err_position_beyond_the_kernels_names_position(tmp_path):
    refused(tmp_path, HEAD + PLANE + "position = [0.0, 1e30, 0.0]\n", "objects[0].position",
            [0.0, 1e30, 0.0], "float32")


def test_err_position_rounding_a_triangle_away_names_position(tmp_path):
    refused(tmp_path, HEAD + PLANE + "position = [1e17, 0.0, 0.0]\n", "objects[0].position",
            [1e17, 0.0, 0.0], "triangle 0", "far from the origin")


def test_err_mesh_vertex_beyond_the_kernels_names_mesh(tmp_path):
    (tmp_path / "far.obj").write_text("v 0 0 0\nv 1e30 0 0\nv 0 1 0\nf 1 2 3\n")
    refused(tmp_path, HEAD + '[[objects]]\nname = "m"\nmaterial = "metal"\nmesh = "far.obj"\n',
            "objects[0].mesh", "far.obj", "far.obj", "point 1")


def test_err_box_extents_beyond_the_kernels(tmp_path):
    refused(tmp_path, HEAD + '[[objects]]\nname = "b"\nmaterial = "metal"\nshape = "box"\n'
            "extents = [1e300, 1.0, 1.0]\n", "objects[0].extents", [1e300, 1.0, 1.0], "box")


def test_err_radar_position_beyond_the_kernels(tmp_path):
    refused(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [1e300, 0.0, 0.0]\n',
            "radars[0].position", [1e300, 0.0, 0.0], "float32")


def test_geometry_rounded_by_more_than_a_wavelength_warns(tmp_path):
    # 24 GHz: float32 rounds by more than lambda = 12.5 mm beyond 2.1e5 m from the origin
    warns_once(tmp_path, HEAD + PLANE + "position = [3e5, 0.0, 0.0]\n", "objects[0]",
               "float32", "wavelength")
    warns_once(tmp_path, HEAD + '[[radars]]\nname = "r"\nposition = [0.0, -4e5, 0.0]\n',
               "radars[0].position")
    loads_quietly(tmp_path, HEAD + PLANE + "position = [1e5, 0.0, 0.0]\n")


# -- mesh files that are not what they claim ---------------------------------------------------


def test_err_random_bytes_as_obj_names_mesh_and_key(tmp_path):
    (tmp_path / "r.obj").write_bytes(bytes(range(256)) * 8)
    refused(tmp_path, HEAD + '[[objects]]\nname = "m"\nmaterial = "metal"\nmesh = "r.obj"\n',
            "objects[0].mesh", "r.obj", "not a text OBJ file", "NUL byte at offset 0")


@pytest.mark.parametrize("ext, text", [
    ("obj", b"# caf\xe9 \xb0\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
    ("off", b"OFF\n# \xe9\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
    ("stl", b"solid caf\xe9\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
            b"vertex 0 1 0\nendloop\nendfacet\nendsolid caf\xe9\n"),
])
def test_latin1_text_meshes_load(tmp_path, ext, text):
    (tmp_path / f"l.{ext}").write_bytes(text)
    s = loads_quietly(tmp_path, HEAD + f'[[objects]]\nname = "m"\nmaterial = "metal"\n'
                      f'mesh = "l.{ext}"\n')
    assert s.triangles.shape == (1, 3, 3)
    assert np.allclose(np.sort(s.triangles[0], axis=0), [[0, 0, 0], [0, 0, 0], [1, 1, 0]])


# -- library entry points ---------------------------------------------------------------------


@pytest.mark.parametrize("value", [None, 3, b"s.toml", ["s.toml"]])
def test_load_scene_wants_a_path(value):
    with pytest.raises(ArgumentTypeError, match="path = .*must be a str or os.PathLike"):
        load_scene(value)


def test_scene_from_dict_checks_its_arguments():
    with pytest.raises(ArgumentTypeError, match="file = None"):
        scene_from_dict({"scene": {"carrier_hz": 24e9}}, file=None)
    with pytest.raises(ArgumentTypeError, match="base_dir = 3"):
        scene_from_dict({"scene": {"carrier_hz": 24e9}}, base_dir=3)
    with pytest.raises(SceneError, match="keys must be strings") as ei:
        scene_from_dict({"scene": {"carrier_hz": 24e9, 1: 2}})
    assert ei.value.key == "scene" and ei.value.value == 1


def test_scene_file_name_the_os_refuses(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        load_scene(str(tmp_path / "a\0b.toml"))
    with pytest.raises(SceneError, match="not found"):
        load_scene(tmp_path / ("x" * 5000 + ".toml"))
