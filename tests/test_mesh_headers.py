"""Mesh files whose header declares more than they hold are refused (issue #28): a
truncated ASCII PLY or OFF loads its first faces without a word otherwise, through a
TOML scene and an XML import alike."""

from __future__ import annotations

from pathlib import Path

import pytest

from clradcom.errors import SceneError
from clradcom.scene import load_scene

PLY_HEAD = """ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
element face {faces}
property list uchar int vertex_indices
end_header
0 0 0
1 0 0
0 1 0
0 0 1
"""
TETRA_FACES = ["3 0 2 1", "3 0 1 3", "3 0 3 2", "3 1 2 3"]

SCENE = """\
[scene]
name = "mesh"
carrier_hz = 24e9
{import_line}
{objects}
[[radars]]
name = "radar"
position = [-5.0, 0.3, 0.2]
role = "txrx"
"""
OBJECT = """\
[[objects]]
name = "tetra"
material = "metal"
mesh = "{mesh}"
"""
XML = """<scene version="2.1.0">
  <bsdf type="itu-radio-material" id="mat-itu_metal"><string name="type" value="metal"/>
  </bsdf>
  <shape type="ply" id="mesh-tetra"><string name="filename" value="{mesh}"/>
    <ref id="mat-itu_metal" name="bsdf"/></shape>
</scene>
"""


def _ply(path: Path, declared: int, faces) -> Path:
    path.write_text(PLY_HEAD.format(faces=declared) + "".join(f + "\n" for f in faces))
    return path


def _scene(folder: Path, mesh: str, via_xml: bool) -> Path:
    path = folder / "scene.toml"
    if via_xml:
        (folder / "s.xml").write_text(XML.format(mesh=mesh))
        path.write_text(SCENE.format(import_line='import = "s.xml"', objects=""))
    else:
        path.write_text(SCENE.format(import_line="", objects=OBJECT.format(mesh=mesh)))
    return path


@pytest.mark.parametrize("via_xml", [False, True], ids=["toml", "xml"])
def test_a_truncated_ascii_ply_is_refused(tmp_path, via_xml):
    _ply(tmp_path / "tetra.ply", 12, TETRA_FACES[:2])
    with pytest.raises(SceneError, match=r"declares 4 vertices and 12 faces .* holds 4 "
                                         r"vertices and 2 triangles") as err:
        load_scene(_scene(tmp_path, "tetra.ply", via_xml))
    assert "tetra.ply" in str(err.value)


@pytest.mark.parametrize("via_xml", [False, True], ids=["toml", "xml"])
def test_a_whole_ply_loads_every_face(tmp_path, via_xml):
    _ply(tmp_path / "tetra.ply", 4, TETRA_FACES)
    assert len(load_scene(_scene(tmp_path, "tetra.ply", via_xml)).triangles) == 4


def test_a_quad_face_counts_as_the_triangles_it_becomes(tmp_path):
    (tmp_path / "quad.ply").write_text(
        PLY_HEAD.format(faces=1).replace("0 0 1\n", "1 1 0\n") + "4 0 1 3 2\n")
    scene = load_scene(_scene(tmp_path, "quad.ply", False))
    assert len(scene.triangles) == 2


def test_a_truncated_off_is_refused(tmp_path):
    (tmp_path / "tetra.off").write_text("OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
                                        + "".join(f + "\n" for f in TETRA_FACES[:3]))
    with pytest.raises(SceneError, match=r"declares 4 vertices and 4 faces .* 3 triangles"):
        load_scene(_scene(tmp_path, "tetra.off", False))
    (tmp_path / "tetra.off").write_text("OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
                                        + "".join(f + "\n" for f in TETRA_FACES))
    assert len(load_scene(_scene(tmp_path, "tetra.off", False)).triangles) == 4
