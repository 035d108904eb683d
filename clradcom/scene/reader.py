"""TOML scene files -> :class:`Scene` (plain arrays for the kernels).

A scene file has four parts (docs/scene-format.md is the full reference)::

    [scene]        name, carrier_hz
    [[materials]]  user-defined materials (the built-in ones need no entry)
    [[objects]]    a mesh file (PLY/OBJ/STL/GLB via trimesh) or a built-in shape,
                   with material, position, rotation_deg, scale, velocity
    [[radars]]     antennas: position, rides_on, orientation_deg, pattern,
                   polarization, role, tx_power_w, noise_figure_db

Every refusal is a :class:`clradcom.errors.SceneError` naming the file, the key
path (``objects[2].velocity``) and the offending value.

This module parses the file, checks the top level and ``[scene]`` and assembles the
Scene; each array of tables has its own reader: :mod:`~clradcom.scene.read_materials`,
:mod:`~clradcom.scene.read_objects` (with :mod:`~clradcom.scene.read_geometry` for mesh
files and shapes), :mod:`~clradcom.scene.read_radars` (with
:mod:`~clradcom.scene.read_patterns`); :mod:`~clradcom.scene.fields` checks single values.

Transforms: object vertices are scaled, then rotated by
``R = Rz(yaw) Ry(pitch) Rx(roll)`` (``rotation_deg = [roll, pitch, yaw]``,
extrinsic x-y-z), then translated by ``position``: ``v_world = R (s * v) + p``.
A radar that ``rides_on`` an object gives ``position`` and ``orientation_deg``
in that object's frame (metres, rotated but not scaled):
``p_world = p_obj + R_obj p_local``, ``R_world = R_obj R_local``; it moves with
the object's velocity.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import numpy as np

from clradcom.errors import SceneError
from clradcom.scene.fields import REQUIRED, FieldReader
from clradcom.scene.read_geometry import MESH_SUFFIXES, SHAPES
from clradcom.scene.read_materials import read_materials
from clradcom.scene.read_objects import read_objects
from clradcom.scene.read_radars import read_radars
from clradcom.scene.records import Radar, Scene, SceneObject

__all__ = ["load_scene", "scene_from_dict", "SHAPES", "MESH_SUFFIXES"]

TOP_KEYS = ("scene", "materials", "objects", "radars")
SCENE_KEYS = ("name", "carrier_hz", "description")


def load_scene(path) -> Scene:
    """Read and validate a TOML scene file; mesh and pattern paths are relative
    to the scene file's folder.  Raises :class:`SceneError` on any bad input."""
    path = Path(path)
    if not path.is_file():
        raise SceneError("scene file not found", file=path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"cannot read scene file ({exc})", file=path) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = re.search(r"at line (\d+)", msg)
        line = int(m.group(1)) if m else None
        raise SceneError(f"TOML syntax error: {msg}", file=path, line=line) from None
    return scene_from_dict(data, file=path, base_dir=path.parent)


def scene_from_dict(data: dict, *, file="<dict>", base_dir=".") -> Scene:
    """Build a :class:`Scene` from an already parsed TOML document (a dict)."""
    file = Path(file) if not isinstance(file, Path) else file
    fields = FieldReader(file)
    if not isinstance(data, dict):
        raise fields.err(None, data, "scene document must be a table")
    fields.check_keys(data, TOP_KEYS, "")
    name, description, carrier = _read_scene_table(fields, data)
    materials = read_materials(fields, fields.array_of_tables(data, "materials"), carrier)
    objects, triangles = read_objects(fields, fields.array_of_tables(data, "objects"),
                                      materials, carrier, Path(base_dir))
    radars = read_radars(fields, fields.array_of_tables(data, "radars"), objects,
                         Path(base_dir))
    return _assemble_scene(file, name, description, carrier, materials.materials, objects,
                           triangles, radars)


def _read_scene_table(fields: FieldReader, data: dict) -> tuple[str, str, float]:
    """(name, description, carrier_hz) from the required ``[scene]`` table."""
    sc = data.get("scene", REQUIRED)
    if sc is REQUIRED:
        raise SceneError("missing required table [scene]", file=fields.file, key="scene")
    if not isinstance(sc, dict):
        raise fields.err("scene", sc, "expected a table, written [scene]")
    fields.check_keys(sc, SCENE_KEYS, "scene")
    name = fields.get_str(sc, "name", "scene", default=fields.file.stem)
    description = fields.get_str(sc, "description", "scene", default="")
    carrier = fields.get_float(sc, "carrier_hz", "scene", lo=0.0, lo_open=True, unit="Hz")
    return name, description, carrier


def _assemble_scene(file: Path, name, description, carrier, materials,
                    objects: list[SceneObject], tris: list[np.ndarray],
                    radars: list[Radar]) -> Scene:
    """The Scene with its flat per-triangle and per-object arrays."""
    triangles = (np.concatenate(tris, axis=0) if tris else np.zeros((0, 3, 3)))
    tri_object = np.concatenate(
        [np.full(o.n_triangles, i, dtype=np.int32) for i, o in enumerate(objects)]
    ) if objects else np.zeros(0, dtype=np.int32)
    tri_material = np.concatenate(
        [np.full(o.n_triangles, o.material, dtype=np.int32) for o in objects]
    ) if objects else np.zeros(0, dtype=np.int32)
    object_velocity = np.array([o.velocity for o in objects],
                               dtype=np.float64).reshape(-1, 3)
    return Scene(
        name=name, carrier_hz=carrier,
        source=file if isinstance(file, Path) and file.exists() else None,
        materials=materials, objects=objects, radars=radars,
        triangles=np.ascontiguousarray(triangles, dtype=np.float64),
        tri_object=tri_object.astype(np.int32), tri_material=tri_material.astype(np.int32),
        object_velocity=object_velocity, description=description,
    )
