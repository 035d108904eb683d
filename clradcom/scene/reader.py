"""TOML scene files -> :class:`Scene` (plain arrays for the kernels).

A scene file has four parts (docs/scene-format.md is the full reference)::

    [scene]        name, carrier_hz
    [[materials]]  user-defined materials (the built-in ones need no entry)
    [[objects]]    a mesh file (PLY/OBJ/STL/GLB via trimesh) or a built-in shape,
                   with material, position, rotation_deg, scale, velocity
    [[radars]]     antennas: position, rides_on, orientation_deg, pattern,
                   polarization, role, tx_power_w, noise_figure_db
    [waveform]     optional radar frame: subcarriers, symbols, subcarrier_spacing_hz,
                   cyclic_prefix_s / _samples, modulation (:mod:`~clradcom.scene.read_waveform`)

``[scene] import = "canyon.xml"`` adds the shapes of a Mitsuba 3 / Sionna RT XML scene
(:mod:`~clradcom.scene.import_xml`) before the ``[[objects]]``; an ``[[objects]]`` entry
with ``geojson`` adds extruded building footprints (:mod:`~clradcom.scene.geojson`).

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

import copy
import os
import re
import tomllib
from pathlib import Path

import numpy as np

from clradcom.errors import ArgumentTypeError, SceneError
from clradcom.scene.bounds import check_carrier, warn_far_geometry, warn_speeds
from clradcom.scene.fields import REQUIRED, FieldReader, is_file
from clradcom.scene.import_xml import read_xml_scene
from clradcom.scene.materials import C0
from clradcom.scene.motion import read_time_axis
from clradcom.scene.read_geometry import MESH_SUFFIXES, SHAPES
from clradcom.scene.read_materials import read_materials
from clradcom.scene.read_objects import read_objects
from clradcom.scene.read_radars import read_radars
from clradcom.scene.read_waveform import read_waveform
from clradcom.scene.records import Radar, Scene, SceneDocument, SceneObject

__all__ = ["load_scene", "scene_from_dict", "SHAPES", "MESH_SUFFIXES"]

TOP_KEYS = ("scene", "materials", "objects", "radars", "time", "waveform")
SCENE_KEYS = ("name", "carrier_hz", "description", "import")


#: what :func:`load_scene` reads besides TOML: Mitsuba / Sionna RT XML and GeoJSON
XML_SUFFIXES = (".xml",)
GEOJSON_SUFFIXES = (".geojson", ".json")


def load_scene(path, *, carrier_hz: float | None = None, **geojson_keys) -> Scene:
    """Read and validate a scene file; mesh and pattern paths are relative to the scene
    file's folder.  Raises :class:`SceneError` on any bad input
    (:class:`~clradcom.errors.ArgumentTypeError` when ``path`` is not a path).

    A TOML scene file says everything itself. A Mitsuba 3 / Sionna RT XML scene or a
    GeoJSON file of building footprints holds no carrier and no radars: with
    ``carrier_hz`` it is read as the TOML file that imports it would be (``[scene] import
    = "<file>"``, or one ``[[objects]]`` entry with ``geojson = "<file>"`` and
    ``geojson_keys``, e.g. ``material="itu_concrete"``, ``coordinates="metres"``), the
    same objects; radars are added in Python (:func:`clradcom.scene.edit.add_radar`)."""
    path = _path_argument(path, "path")
    if not is_file(path):
        raise SceneError("scene file not found", file=path)
    suffix = path.suffix.lower()
    if suffix in XML_SUFFIXES + GEOJSON_SUFFIXES:
        return _load_import(path, carrier_hz, geojson_keys)
    if carrier_hz is not None or geojson_keys:
        given = ["carrier_hz"] * (carrier_hz is not None) + sorted(geojson_keys)
        raise SceneError(f"{', '.join(given)}: only for an XML or GeoJSON file; a TOML "
                         "scene file gives its own ([scene] carrier_hz, [[objects]])",
                         file=path)
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
    except RecursionError:
        raise SceneError("TOML nested too deeply (arrays or tables inside each other "
                         "hundreds of levels deep)", file=path) from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        raise SceneError(f"TOML value refused: {exc}", file=path) from None
    return scene_from_dict(data, file=path, base_dir=path.parent)


def _load_import(path: Path, carrier_hz, geojson_keys: dict) -> Scene:
    """An XML or GeoJSON file read through the document that imports it."""
    xml = path.suffix.lower() in XML_SUFFIXES
    what = ("an XML (Mitsuba / Sionna RT) scene" if xml
            else "a GeoJSON file of building footprints")
    if carrier_hz is None:
        how = (f"[scene] import = '{path.name}'" if xml
               else f"an [[objects]] entry with geojson = '{path.name}'")
        raise SceneError(f"{what} holds no carrier frequency and no radars: give "
                         f"load_scene(..., carrier_hz=...) and add radars in Python, or "
                         f"load a TOML scene file with carrier_hz, {how} and [[radars]] "
                         "(docs/scene-format.md, docs/scene-api.md)", file=path)
    if xml and geojson_keys:
        raise SceneError(f"{', '.join(sorted(geojson_keys))}: only for a GeoJSON file",
                         file=path)
    table = {"name": path.stem, "carrier_hz": carrier_hz}
    if xml:
        data = {"scene": {**table, "import": path.name}}
    else:
        data = {"scene": table,
                "objects": [{"name": path.stem, "geojson": path.name, **geojson_keys}]}
    return scene_from_dict(data, file=path, base_dir=path.parent)


def scene_from_dict(data: dict, *, file="<dict>", base_dir=".", mesh_cache=None) -> Scene:
    """Build a :class:`Scene` from an already parsed TOML document (a dict); the scene
    keeps a copy of it (``scene.document``) for the edits of :mod:`clradcom.scene.edit`.
    ``mesh_cache`` (resolved path -> (vertices, faces)) holds mesh files already read."""
    file = _path_argument(file, "file")
    base_dir = _path_argument(base_dir, "base_dir")
    fields = FieldReader(file)
    if not isinstance(data, dict):
        raise fields.err(None, data, "scene document must be a table")
    mesh_cache = {} if mesh_cache is None else mesh_cache
    fields.check_keys(data, TOP_KEYS, "")
    name, description, carrier = _read_scene_table(fields, data)
    time_axis = read_time_axis(fields, data)
    waveform = read_waveform(fields, data)
    span = (0.0, 0.0) if time_axis is None else (
        time_axis.start_s, float(time_axis.times[-1]))
    materials = read_materials(fields, fields.array_of_tables(data, "materials"), carrier)
    placed = []
    if "import" in data["scene"]:
        rel = fields.get_str(data["scene"], "import", "scene")
        placed = read_xml_scene(fields, rel, "scene.import", materials, carrier, base_dir)
    objects, triangles = read_objects(fields, fields.array_of_tables(data, "objects"),
                                      materials, carrier, base_dir, placed, span,
                                      mesh_cache)
    radars = read_radars(fields, fields.array_of_tables(data, "radars"), objects, base_dir,
                         C0 / carrier, span)
    _warn_out_of_range(fields, carrier, objects, triangles, radars)
    scene = _assemble_scene(file, name, description, carrier, materials.materials, objects,
                            triangles, radars)
    own = [file] if scene.source is not None else []
    scene.input_files = tuple(own + [p for p in fields.read_files if p not in own])
    if time_axis is not None:
        scene.time_s, scene.time_axis = time_axis.start_s, time_axis
    scene.waveform = waveform
    # copied once read (a value nested too deeply for copy was refused by then); the
    # caller may change its dict afterwards
    scene.__dict__["_document"] = SceneDocument(copy.deepcopy(data), base_dir, file,
                                                mesh_cache)
    return scene


def _path_argument(value, argument: str) -> Path:
    """``value`` as a Path; anything but a str or os.PathLike is an ArgumentTypeError."""
    if isinstance(value, Path):
        return value
    if not isinstance(value, str | os.PathLike):
        raise ArgumentTypeError(f"must be a str or os.PathLike path, got "
                                f"{type(value).__name__}", argument=argument, value=value)
    try:
        return Path(value)
    except TypeError:  # an os.PathLike whose __fspath__ gives bytes
        raise ArgumentTypeError("must be a str path", argument=argument,
                                value=value) from None


def _warn_out_of_range(fields: FieldReader, carrier: float, objects: list[SceneObject],
                       tris: list[np.ndarray], radars: list[Radar]) -> None:
    """The warnings of docs/scene-format.md "Physical bounds" about speeds and geometry
    far from the origin, once per scene (the carrier warns where it is read)."""
    speeds = [(f"objects[{i}].velocity", float(np.linalg.norm(o.velocity)))
              for i, o in enumerate(objects)]
    speeds += [(f"radars[{i}].velocity", float(np.linalg.norm(r.velocity)))
               for i, r in enumerate(radars) if r.rides_on < 0]
    warn_speeds(fields, speeds)
    far, where = 0.0, ""
    for i, t in enumerate(tris):
        m = float(np.max(np.abs(t), initial=0.0))
        if m > far:
            far, where = m, f"objects[{i}]"
    for i, r in enumerate(radars):
        m = float(np.max(np.abs(r.position)))
        if m > far:
            far, where = m, f"radars[{i}].position"
    warn_far_geometry(fields, far, carrier, where)


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
    check_carrier(fields, sc["carrier_hz"], carrier, "scene.carrier_hz")
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
