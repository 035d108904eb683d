"""Scene import: Mitsuba 3 / Sionna RT XML scenes and GeoJSON building footprints.

The XML scenes are written here in Sionna RT's conventions (PLY meshes under
``meshes/`` written with trimesh, ``mat-itu_*`` BSDF ids of Sionna <= 0.19 and
``itu-radio-material`` / ``radio-material`` BSDFs of Sionna >= 1.0, a ``to_world``
transform); expected triangles come from trimesh's own transformation matrices,
permittivities from the ITU-R P.2040 power law written out, delays and Doppler from the
image method.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import shapely.geometry
import trimesh
from trimesh import transformations as tf

from clradcom.errors import SceneError, SceneWarning
from clradcom.scene import load_scene
from clradcom.scene.geojson import WGS84_A, WGS84_F, lonlat_to_local
from clradcom.scene.import_xml import inward_closed_shells
from clradcom.scene.materials import C0, EPS0
from clradcom.trace import DiffractionSettings, SpecularSettings, TraceSettings, trace_scene

F_C = 24e9

WALL_XML = """\
<scene version="2.1.0">
  <default name="wall_material" value="mat-itu_metal.001"/>
  <!-- Sionna <= 0.19 / Blender export: a visual BSDF whose id names the material -->
  <bsdf type="twosided" id="mat-itu_concrete" name="mat-itu_concrete">
    <bsdf type="diffuse" name="bsdf">
      <rgb value="0.539479 0.539479 0.539480" name="reflectance"/>
    </bsdf>
  </bsdf>
  <bsdf type="twosided" id="mat-itu_metal.001" name="mat-itu_metal.001">
    <bsdf type="diffuse" name="bsdf"/>
  </bsdf>
  <!-- Sionna >= 1.0 -->
  <bsdf type="itu-radio-material" id="mat-itu_glass" name="mat-itu_glass">
    <string name="type" value="glass"/>
    <float name="thickness" value="0.01"/>
  </bsdf>
  <bsdf type="radio-material" id="mat-custom" name="mat-custom">
    <float name="relative_permittivity" value="4.5"/>
    <float name="conductivity" value="0.2"/>
    <float name="scattering_coefficient" value="0.3"/>
    <float name="xpd_coefficient" value="0.1"/>
  </bsdf>
  <integrator type="path" id="elm__0"><integer name="max_depth" value="12"/></integrator>

  <shape type="ply" id="mesh-floor" name="mesh-floor">
    <string name="filename" value="meshes/floor.ply"/>
    <boolean name="face_normals" value="true"/>
    <ref id="mat-itu_concrete" name="bsdf"/>
  </shape>
  <shape type="ply" id="mesh-wall" name="mesh-wall">
    <string name="filename" value="meshes/wall.ply"/>
    <boolean name="face_normals" value="true"/>
    <ref id="$wall_material" name="bsdf"/>
    <transform name="to_world">
      <rotate z="1" angle="90"/>
      <translate x="10.125" y="0" z="2"/>
    </transform>
    <vector name="velocity" x="-5" y="0" z="0"/>
  </shape>
  <shape type="ply" id="mesh-kiosk">
    <string name="filename" value="meshes/kiosk.ply"/>
    <ref id="mat-itu_glass"/>
    <transform name="to_world">
      <scale value="0.5 1 2"/>
      <rotate value="1 1 0" angle="30"/>
      <translate value="-20 15 1"/>
    </transform>
  </shape>
  <shape type="ply" id="mesh-sign">
    <string name="filename" value="meshes/kiosk.ply"/>
    <ref id="mat-custom"/>
    <transform name="to_world">
      <matrix value="1 0 0 -20  0 1 0 -15  0 0 1 1  0 0 0 1"/>
    </transform>
  </shape>
</scene>
"""

TOML = """\
[scene]
carrier_hz = {carrier}
import = "{xml}"

[[radars]]
name = "tx"
role = "tx"
position = [0.0, -2.0, 1.5]

[[radars]]
name = "rx"
role = "rx"
position = [0.0, 3.0, 1.5]
"""


def write_meshes(folder: Path) -> dict[str, trimesh.Trimesh]:
    """The PLY meshes of WALL_XML, written with trimesh (binary PLY, as Sionna's)."""
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    floor = trimesh.Trimesh(vertices=[[-30, -30, 0], [30, -30, 0], [30, 30, 0],
                                      [-30, 30, 0]], faces=[[0, 1, 2], [0, 2, 3]],
                            process=False)
    meshes = {"floor": floor,
              "wall": trimesh.creation.box(extents=[8.0, 0.25, 4.0]),
              "kiosk": trimesh.creation.box(extents=[1.0, 1.0, 1.0])}
    for name, mesh in meshes.items():
        mesh.export(folder / "meshes" / f"{name}.ply")
    # as read back: PLY holds float32 vertices
    return {name: trimesh.load(folder / "meshes" / f"{name}.ply", process=False)
            for name in meshes}


def write_scene(folder: Path, xml: str = WALL_XML, toml: str = TOML) -> Path:
    write_meshes(folder)
    (folder / "canyon.xml").write_text(xml)
    path = folder / "scene.toml"
    path.write_text(toml.format(carrier=F_C, xml="canyon.xml"))
    return path


def itu_eps(a, c, d, f_hz=F_C):
    """ITU-R P.2040-3 eq. (28)-(29) with b = 0: eps' = a, sigma = c f_GHz^d."""
    sigma = c * (f_hz / 1e9) ** d
    return complex(a, -sigma / (2 * math.pi * f_hz * EPS0))


# ---------------------------------------------------------------------------
# XML


def test_xml_scene_loads_objects_triangles_materials_and_velocities(tmp_path):
    path = write_scene(tmp_path)
    meshes = write_meshes(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)  # closed meshes face outwards
        scene = load_scene(path)
    names = [o.name for o in scene.objects]
    assert names == ["floor", "wall", "kiosk", "sign"]  # Sionna drops "mesh-"

    def world(obj_name, matrix):
        mesh = meshes[{"sign": "kiosk"}.get(obj_name, obj_name)]
        v = trimesh.transform_points(mesh.vertices, matrix)
        return v[mesh.faces]

    wall_m = tf.concatenate_matrices(tf.translation_matrix([10.125, 0, 2]),
                                     tf.rotation_matrix(math.pi / 2, [0, 0, 1]))
    kiosk_m = tf.concatenate_matrices(tf.translation_matrix([-20, 15, 1]),
                                      tf.rotation_matrix(math.radians(30), [1, 1, 0]),
                                      np.diag([0.5, 1, 2, 1]))
    sign_m = tf.translation_matrix([-20, -15, 1])
    for name, m in (("floor", np.eye(4)), ("wall", wall_m), ("kiosk", kiosk_m),
                    ("sign", sign_m)):
        obj = scene.objects[scene.object_index(name)]
        np.testing.assert_allclose(scene.triangles[obj.tri_slice], world(name, m),
                                   rtol=0, atol=1e-12, err_msg=name)
    wall = scene.objects[1]
    np.testing.assert_allclose(wall.position, [10.125, 0, 2])
    np.testing.assert_allclose(wall.rotation_deg, [0, 0, 90], atol=1e-12)
    np.testing.assert_array_equal(wall.velocity, [-5, 0, 0])
    np.testing.assert_array_equal(scene.object_velocity[[0, 2, 3]], 0.0)
    # the wall's front face is at x = 10 (box 0.25 thick, rotated, moved to 10.125)
    assert scene.triangles[wall.tri_slice][..., 0].min() == pytest.approx(10.0, abs=1e-12)

    by_name = {o.name: scene.materials[o.material] for o in scene.objects}
    assert [by_name[n].name for n in names] == ["itu_concrete", "itu_metal", "itu_glass",
                                                "custom"]
    assert by_name["floor"].eps_r == pytest.approx(itu_eps(5.24, 0.0462, 0.7822))
    assert by_name["wall"].eps_r == pytest.approx(itu_eps(1.0, 1e7, 0.0))
    assert by_name["kiosk"].eps_r == pytest.approx(itu_eps(6.31, 0.0036, 1.3394))
    custom = by_name["sign"]
    assert custom.eps_r == pytest.approx(complex(4.5, -0.2 / (2 * math.pi * F_C * EPS0)))
    assert (custom.scattering_coefficient, custom.cross_pol_share) == (0.3, 0.1)
    # per-triangle arrays follow the objects
    assert np.all(scene.tri_material[wall.tri_slice] == wall.material)
    assert np.all(scene.tri_object[wall.tri_slice] == 1)


def test_reflection_off_imported_wall_has_image_method_delay_and_doppler(tmp_path, runtime):
    scene = load_scene(write_scene(tmp_path))
    settings = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=20_000),
                             diffraction=DiffractionSettings(max_diffractions=0))
    paths = trace_scene(scene, settings, runtime=runtime).links[0].paths
    wall = scene.object_index("wall")
    hit_wall = (paths.n_interactions == 1) & (paths.object_id[:, 0] == wall)
    assert hit_wall.sum() == 1
    tx, rx = np.array([0.0, -2.0, 1.5]), np.array([0.0, 3.0, 1.5])
    image = tx * [-1, 1, 1] + [20.0, 0, 0]  # mirrored in the plane x = 10
    length = np.linalg.norm(rx - image)
    assert paths.delay_s[hit_wall][0] == pytest.approx(length / C0, rel=1e-12)
    # the plane moves at -5 m/s along x: the image at 2 x_wall - x_tx moves at -10 m/s
    dl_dt = (image - rx)[0] / length * (-10.0)
    assert paths.doppler_hz[hit_wall][0] == pytest.approx(-dl_dt * F_C / C0, rel=1e-9)
    # and the floor (itu_concrete, static) gives its own image path
    floor_hit = (paths.n_interactions == 1) & (paths.object_id[:, 0] == 0)
    floor_len = np.linalg.norm(rx - tx * [1, 1, -1])
    assert paths.delay_s[floor_hit] == pytest.approx([floor_len / C0], rel=1e-12)


def test_inside_out_closed_mesh_warns_naming_the_object(tmp_path):
    xml = WALL_XML.replace('<string name="filename" value="meshes/kiosk.ply"/>\n'
                           '    <ref id="mat-itu_glass"/>',
                           '<string name="filename" value="meshes/inverted.ply"/>\n'
                           '    <ref id="mat-itu_glass"/>')
    path = write_scene(tmp_path, xml)
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    box.invert()
    box.export(tmp_path / "meshes" / "inverted.ply")
    with pytest.warns(SceneWarning, match=r"object 'kiosk' .*1 of its 1 closed shell.*"
                      r"re-oriented 12 triangle"):
        scene = load_scene(path)
    assert scene.objects[2].n_triangles == 12
    assert inward_closed_shells(scene.triangles[scene.objects[2].tri_slice]) == (0, 1)
    assert not scene.objects[2].two_sided
    # flip_normals turns it the right way round as written: no warning, the same
    # triangles as the re-oriented ones
    fixed = xml.replace('value="meshes/inverted.ply"/>',
                        'value="meshes/inverted.ply"/>\n'
                        '    <boolean name="flip_normals" value="true"/>')
    (tmp_path / "canyon.xml").write_text(fixed)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)
        flipped = load_scene(path)
    np.testing.assert_array_equal(flipped.triangles[flipped.objects[2].tri_slice],
                                  scene.triangles[scene.objects[2].tri_slice])


def test_inward_closed_shells_counts_shells_of_a_welded_soup():
    out = trimesh.creation.box(extents=[1, 1, 1])
    inv = trimesh.creation.box(extents=[1, 1, 1])
    inv.apply_translation([3, 0, 0])
    inv.invert()
    soup = np.concatenate([out.triangles, inv.triangles])  # vertices repeated per face
    assert inward_closed_shells(soup) == (1, 2)
    assert inward_closed_shells(out.triangles[:-1]) == (0, 0)  # open: no volume


@pytest.mark.parametrize("old, new, key, value", [
    ('<ref id="mat-itu_concrete" name="bsdf"/>', '<ref id="mat-unobtainium"/>',
     "shape[mesh-floor].ref", "mat-unobtainium"),
    ('id="mat-itu_concrete" name="mat-itu_concrete"', 'id="mat-adamantium"',
     "bsdf[mat-adamantium].id", "mat-adamantium"),
    ('<string name="type" value="glass"/>', '<string name="type" value="kryptonite"/>',
     "bsdf[mat-itu_glass].type", "kryptonite"),
    ('value="meshes/floor.ply"', 'value="meshes/nowhere.ply"',
     "shape[mesh-floor].filename", "meshes/nowhere.ply"),
    ('<shape type="ply" id="mesh-floor"', '<shape type="sphere" id="mesh-floor"',
     "shape[mesh-floor].type", "sphere"),
    ('<ref id="$wall_material" name="bsdf"/>', '<ref id="$nothing" name="bsdf"/>',
     "shape[mesh-wall].ref", "$nothing"),
])
def test_bad_xml_is_refused_naming_file_element_and_value(tmp_path, old, new, key, value):
    assert old in WALL_XML
    xml = WALL_XML.replace(old, new, 1)
    if "adamantium" in new:  # the floor refers to it by its new id
        xml = xml.replace('<ref id="mat-itu_concrete" name="bsdf"/>',
                          '<ref id="mat-adamantium" name="bsdf"/>')
    path = write_scene(tmp_path, xml)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    err = info.value
    assert Path(err.file) == tmp_path / "canyon.xml"
    assert (err.key, err.value) == (key, value)
    assert err.line is not None and value.strip("$") in xml.splitlines()[err.line - 1]
    assert str(err).startswith(f"{tmp_path / 'canyon.xml'}:{err.line}: {key} = ")


def test_xml_material_never_takes_a_builtin_name(tmp_path):
    xml = WALL_XML.replace('id="mat-custom" name="mat-custom"', 'id="mat-itu_brick"').replace(
        '<ref id="mat-custom"/>', '<ref id="mat-itu_brick"/>')
    toml = TOML + ('\n[[objects]]\nname = "shed"\nmaterial = "itu_brick"\nshape = "box"\n'
                   'extents = [1.0, 1.0, 1.0]\nposition = [0.0, -20.0, 0.5]\n')
    scene = load_scene(write_scene(tmp_path, xml, toml))
    sign = scene.materials[scene.objects[scene.object_index("sign")].material]
    shed = scene.materials[scene.objects[scene.object_index("shed")].material]
    assert sign.name == "mat-itu_brick@canyon.xml" and sign.eps_r.real == 4.5
    assert shed.name == "itu_brick" and shed.eps_r == pytest.approx(itu_eps(3.91, 0.0238,
                                                                             0.16))


def test_unknown_material_may_come_from_the_scene_file(tmp_path):
    xml = WALL_XML.replace('id="mat-itu_concrete" name="mat-itu_concrete"',
                           'id="mat-wet_concrete"').replace(
        '<ref id="mat-itu_concrete" name="bsdf"/>', '<ref id="mat-wet_concrete"/>')
    toml = TOML + ('\n[[materials]]\nname = "wet_concrete"\nbase = "concrete_building"\n'
                   'roughness_m = 0.003\n')
    scene = load_scene(write_scene(tmp_path, xml, toml))
    floor = scene.materials[scene.objects[0].material]
    assert (floor.name, floor.roughness_m, floor.eps_r) == ("wet_concrete", 0.003, 5 - 0.1j)


def test_missing_xml_and_xml_without_companion_are_refused(tmp_path):
    path = write_scene(tmp_path)
    path.write_text(TOML.format(carrier=F_C, xml="elsewhere.xml"))
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert (info.value.file, info.value.key, info.value.value) == (
        str(path), "scene.import", "elsewhere.xml")
    with pytest.raises(SceneError, match=r"import = 'canyon.xml'"):
        load_scene(tmp_path / "canyon.xml")
    (tmp_path / "canyon.xml").write_text("<scene><shape type='ply'></scene>")
    path.write_text(TOML.format(carrier=F_C, xml="canyon.xml"))
    with pytest.raises(SceneError, match="XML syntax error") as info:
        load_scene(path)
    assert info.value.line == 1


def test_object_names_of_xml_and_toml_must_differ(tmp_path):
    toml = TOML + ('\n[[objects]]\nname = "wall"\nmaterial = "metal"\nshape = "plane"\n'
                   'size = [1.0, 1.0]\n')
    with pytest.raises(SceneError, match=r"duplicate object name \(already used by "
                                         r"shape\[mesh-wall\]\)"):
        load_scene(write_scene(tmp_path, toml=toml))


def test_radar_rides_on_an_imported_object(tmp_path):
    toml = TOML.replace('position = [0.0, 3.0, 1.5]',
                        'position = [1.0, 0.0, 0.0]\nrides_on = "wall"')
    scene = load_scene(write_scene(tmp_path, toml=toml))
    rx = scene.radars[1]
    # the wall's frame: rotated 90 deg about z, at (10.125, 0, 2): local +x is world +y
    np.testing.assert_allclose(rx.position, [10.125, 1.0, 2.0], atol=1e-12)
    np.testing.assert_array_equal(rx.velocity, [-5, 0, 0])


# ---------------------------------------------------------------------------
# GeoJSON

SQUARE = [[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]]  # counter-clockwise
L_SHAPE = [[20, 0], [20, 8], [30, 8], [30, 4], [26, 4], [26, 0], [20, 0]]  # clockwise
HOLE = [[3, 3], [3, 5], [5, 5], [5, 3], [3, 3]]


def feature(fid, rings, **props):
    return {"type": "Feature", "id": fid, "properties": props,
            "geometry": {"type": "Polygon", "coordinates": rings}}


def geojson_scene(tmp_path, features, entry=""):
    (tmp_path / "buildings.geojson").write_text(json.dumps(
        {"type": "FeatureCollection", "features": features}))
    path = tmp_path / "city.toml"
    path.write_text(f'[scene]\ncarrier_hz = {F_C}\n\n[[objects]]\nname = "city"\n'
                    f'geojson = "buildings.geojson"\nmaterial = "itu_concrete"\n'
                    f'coordinates = "metres"\n{entry}')
    return path


def test_geojson_buildings_extrude_to_closed_outward_meshes(tmp_path):
    features = [feature("house", [SQUARE, HOLE], height="12.5 m"),
                feature(7, [L_SHAPE], **{"building:levels": "4", "min_height": 2,
                                         "material": "itu_brick"}),
                {"type": "Feature", "properties": {},
                 "geometry": {"type": "Point", "coordinates": [0, 0]}}]
    with pytest.warns(SceneWarning, match="1 feature.*not Polygon"):
        scene = load_scene(geojson_scene(tmp_path, features))
    assert [o.name for o in scene.objects] == ["city/house", "city/7"]
    assert [o.material_name for o in scene.objects] == ["itu_concrete", "itu_brick"]
    for obj, ring, holes, bottom, top in ((scene.objects[0], SQUARE, [HOLE], 0.0, 12.5),
                                          (scene.objects[1], L_SHAPE, [], 2.0, 12.0)):
        tri = scene.triangles[obj.tri_slice]
        mesh = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(tri.size // 3).reshape(-1, 3))
        mesh.merge_vertices()
        assert mesh.is_watertight and mesh.is_winding_consistent
        area = shapely.geometry.Polygon(ring, holes).area
        assert mesh.volume == pytest.approx(area * (top - bottom), rel=1e-12)  # > 0: outward
        assert (tri[..., 2].min(), tri[..., 2].max()) == (bottom, top)
        # outward everywhere: each face's normal points away from the centroid of the
        # cap or wall it belongs to -- the roof up, the floor down, the walls sideways
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        roof = np.all(tri[..., 2] == top, axis=1)
        floor = np.all(tri[..., 2] == bottom, axis=1)
        assert np.all(normals[roof, 2] > 0) and np.all(normals[floor, 2] < 0)
        assert 0.5 * np.linalg.norm(normals[roof], axis=1).sum() == pytest.approx(area)


def test_geojson_lonlat_uses_the_local_tangent_plane(tmp_path):
    lon0, lat0 = 11.5755, 48.1374
    dlon, dlat = 2e-4, 1e-4
    east, north = lonlat_to_local([lon0 + dlon, lon0], [lat0, lat0 + dlat], (lon0, lat0))
    # small offsets: east = N cos(lat) dlon, north = M dlat (prime-vertical and meridian
    # radii of curvature of WGS 84)
    e2 = WGS84_F * (2 - WGS84_F)
    s = math.sin(math.radians(lat0))
    n_radius = WGS84_A / math.sqrt(1 - e2 * s * s)
    m_radius = WGS84_A * (1 - e2) / (1 - e2 * s * s) ** 1.5
    assert east[0] == pytest.approx(n_radius * math.cos(math.radians(lat0))
                                    * math.radians(dlon), rel=1e-6)
    assert north[1] == pytest.approx(m_radius * math.radians(dlat), rel=1e-6)
    assert abs(north[0]) < 1e-3 and abs(east[1]) < 1e-9
    ring = [[lon0 + x * dlon, lat0 + y * dlat] for x, y in SQUARE]
    path = geojson_scene(tmp_path, [feature("a", [ring], height=10)],
                         f"origin_lonlat = [{lon0}, {lat0}]\n").read_text()
    (tmp_path / "city.toml").write_text(path.replace('coordinates = "metres"\n', ""))
    scene = load_scene(tmp_path / "city.toml")
    corners = np.column_stack(lonlat_to_local(*np.array(ring[:4]).T, (lon0, lat0)))
    xy = np.unique(scene.triangles[..., :2].reshape(-1, 2), axis=0)
    np.testing.assert_allclose(xy, corners[np.lexsort(corners.T[::-1])], rtol=0, atol=1e-9)
    assert corners[2] == pytest.approx([10 * east[0], 10 * north[1]], rel=1e-4)


@pytest.mark.parametrize("props, entry, match", [
    ({}, "", r"feature 0 of .*buildings.geojson: has no height"),
    ({"height": "40 ft"}, "", r"height = '40 ft' is not a number of metres"),
    ({"height": 5, "min_height": 6}, "", r"height 5 m must be above its base 6 m"),
    ({"height": 5, "material": "cheese"}, "", r"unknown material"),
    ({"height": 5}, 'origin_lonlat = [0.0, 0.0]\n', r"only applies with coordinates"),
])
def test_bad_geojson_is_refused_naming_the_feature(tmp_path, props, entry, match):
    path = geojson_scene(tmp_path, [feature("a", [SQUARE], **props)], entry)
    with pytest.raises(SceneError, match=match) as info:
        load_scene(path)
    assert info.value.file == str(path)
    assert info.value.key.startswith("objects[0]")


def test_geojson_default_height_and_lonlat_checks(tmp_path):
    path = geojson_scene(tmp_path, [feature("a", [SQUARE])], "height_m = 6.0\n")
    scene = load_scene(path)
    assert scene.triangles[..., 2].max() == 6.0
    text = path.read_text().replace('coordinates = "metres"\n', "")
    path.write_text(text)
    with pytest.raises(SceneError, match="origin_lonlat: required"):
        load_scene(path)
    path.write_text(text + "origin_lonlat = [0.0, 0.0]\n")
    far = [[x * 100, y * 100] for x, y in SQUARE]  # metres read as degrees
    (tmp_path / "buildings.geojson").write_text(json.dumps(
        {"type": "FeatureCollection", "features": [feature("a", [far], height=3)]}))
    with pytest.raises(SceneError, match="not longitude/latitude.*coordinates = 'metres'"):
        load_scene(path)


def test_primitive_shapes_nested_and_held_materials_and_lookat(tmp_path):
    xml = """<scene version="3.0.0">
  <bsdf type="holder-material" id="holder-mat-itu_wood">
    <bsdf type="itu-radio-material" id="mat-itu_wood"><string name="type" value="wood"/>
    </bsdf>
  </bsdf>
  <shape type="rectangle" id="ceiling">
    <ref id="holder-mat-itu_wood" name="bsdf"/>
    <transform name="to_world">
      <scale value="3"/>
      <lookat origin="1, 2, 5" target="1, 2, 0" up="0, 1, 0"/>
    </transform>
  </shape>
  <shape type="cube">
    <bsdf type="diffuse" id="mat-itu_marble.002"/>
    <point name="velocity" value="0 2 0"/>
  </shape>
</scene>
"""
    (tmp_path / "room.xml").write_text(xml)
    path = tmp_path / "room.toml"
    path.write_text(f'[scene]\ncarrier_hz = {F_C}\nimport = "room.xml"\n')
    scene = load_scene(path)
    ceiling, cube = scene.objects
    assert (ceiling.name, ceiling.material_name) == ("ceiling", "itu_wood")
    assert (cube.name, cube.material_name) == ("shape1", "itu_marble")
    tri = scene.triangles[ceiling.tri_slice]
    # look-at: local +z along target - origin (down), so the rectangle faces down at z=5
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    np.testing.assert_allclose(normals / np.linalg.norm(normals, axis=1)[:, None],
                               [[0, 0, -1]] * 2, atol=1e-15)
    np.testing.assert_allclose(np.sort(np.unique(tri[..., 0])), [-2, 4], atol=1e-12)
    np.testing.assert_allclose(np.sort(np.unique(tri[..., 1])), [-1, 5], atol=1e-12)
    assert np.all(tri[..., 2] == 5)
    np.testing.assert_array_equal(cube.velocity, [0, 2, 0])
    assert inward_closed_shells(scene.triangles[cube.tri_slice]) == (0, 1)
    # entity declarations (billion laughs) are refused before they expand
    (tmp_path / "room.xml").write_text('<!DOCTYPE s [<!ENTITY a "aaaa">]>\n<scene/>')
    with pytest.raises(SceneError, match="entity declarations"):
        load_scene(path)


def test_two_sided_sheet_is_closed_but_not_inward():
    sheet = trimesh.creation.box(extents=[1, 1, 1]).triangles[:1]
    assert inward_closed_shells(np.concatenate([sheet, sheet[:, ::-1]])) == (0, 1)
