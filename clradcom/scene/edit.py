"""Scenes built and edited in Python: add a mesh with a material and a velocity, add a
radar with its pattern and array, move, turn or remove either, and trace again.

A scene remembers the document it was read from (``scene.document``: the TOML tables of
``load_scene``, the dict of ``scene_from_dict``, or an earlier edit's). Every function
here returns a **new** scene, read again by the same reader from the document with the
one change made, so an object built in code meets the same rules as one written in a
file and is refused with the same one-line :class:`~clradcom.errors.SceneError` (naming
``objects[i].key`` and the value), and the scene it returns hashes like the file that
says the same (:meth:`~clradcom.scene.records.Scene.content_hash`). The scene passed in
is left as it was. Mesh files are read once for a scene and all its edits.

    scene = new_scene("street", carrier_hz=24e9)
    scene = add_object(scene, "road", shape="plane", size=[100, 14], material="asphalt")
    scene = add_object(scene, "car", mesh=car_mesh(), material="pec",
                       position=[20, 1.75, 0], velocity=[-10, 0, 0])
    scene = add_radar(scene, "A", position=[0, -1.75, 0.5], pattern="isotropic")
    snap = trace_scene(scene)
    snap2 = trace_scene(move(scene, "car", position=[25, 1.75, 0]))
    save_scene(scene, "out/street.toml")   # the CLI reads it: clradcom trace out/street.toml

The keywords are the scene file's keys (docs/scene-format.md): numpy arrays and tuples
are accepted wherever the file takes an array. Objects that come whole from an imported
XML scene or a GeoJSON entry are edited in their source file (removing or moving one is
refused with a message that says so). docs/scene-api.md is the guide.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import tomli_w

from clradcom.errors import ArgumentTypeError, SceneError
from clradcom.files import atomic_write
from clradcom.scene.meshfiles import ply_bytes
from clradcom.scene.reader import scene_from_dict
from clradcom.scene.records import Scene, SceneDocument

__all__ = ["add_material", "add_object", "add_radar", "move", "new_scene", "remove",
           "save_scene", "set_waveform"]

#: where a saved scene's in-memory meshes go, beside the TOML file
MESH_FOLDER = "meshes"


def new_scene(name: str = "scene", carrier_hz: float = 24e9, *, description: str = "",
              base_dir=".") -> Scene:
    """An empty scene (no objects, no radars) at ``carrier_hz``; mesh and pattern files
    named in later edits are looked for relative to ``base_dir``."""
    table = {"name": name, "carrier_hz": carrier_hz}
    if description:
        table["description"] = description
    return scene_from_dict(_plain({"scene": table}), file="<scene built in Python>",
                           base_dir=base_dir)


def add_material(scene: Scene, name: str, **keys) -> Scene:
    """``scene`` with the material ``[[materials]]`` entry ``name`` and ``keys`` (``base``,
    ``itu``, ``eps_r``, ``conductivity_s_m``, ``pec``, ``roughness_m``,
    ``scattering_coefficient``, ...). Built-in materials need no entry."""
    data = _data(scene)
    data.setdefault("materials", []).append(_plain({"name": name, **keys}))
    return _rebuilt(scene, data)


def add_object(scene: Scene, name: str, mesh=None, *, material: str, **keys) -> Scene:
    """``scene`` with one more object: ``mesh`` is a mesh file (path, relative to the
    scene's folder), a mesh object with ``vertices`` and ``faces`` (a ``trimesh.Trimesh``)
    or a ``(vertices (V, 3), faces (F, 3))`` pair in the object's own frame; or no mesh and
    ``shape="box"`` / ``"plane"`` with ``extents`` / ``size``. ``keys`` are the object
    keys of a scene file: ``position``, ``rotation_deg``, ``scale``, ``velocity``,
    ``optics``, ``sides``, ``angular_velocity_deg_s``, ``trajectory``, ..."""
    entry = {"name": name, "material": material}
    if mesh is not None:
        entry.update(_mesh_keys(mesh))
    entry.update(keys)
    data = _data(scene)
    data.setdefault("objects", []).append(_plain(entry))
    return _rebuilt(scene, data)


def add_radar(scene: Scene, name: str, position=None, **keys) -> Scene:
    """``scene`` with one more radar at ``position`` (world m, or in the frame of the
    object it ``rides_on``); ``keys`` are the radar keys of a scene file:
    ``orientation_deg``, ``pattern`` (a name or a table such as
    ``{"type": "cosine", "half_power_beamwidth_deg": 60}``), ``polarization``, ``role``,
    ``tx_power_w``, ``noise_figure_db``, ``array`` (``{"kind": "ula", "count": 4,
    "spacing_wavelengths": 0.5}``), ``rides_on``, ``velocity``, ..."""
    entry = {"name": name}
    if position is not None:
        entry["position"] = position
    entry.update(keys)
    data = _data(scene)
    data.setdefault("radars", []).append(_plain(entry))
    return _rebuilt(scene, data)


def set_waveform(scene: Scene, radar: str | None = None, **keys) -> Scene:
    """``scene`` with its ``[waveform]`` table replaced by ``keys`` (``subcarriers``,
    ``symbols``, ``subcarrier_spacing_hz``, ``cyclic_prefix_s``, ``modulation``, ...;
    ``kind="fmcw"`` and the chirp's keys for an FMCW radar); no keys removes it (the
    commands' options and the paper's frame then apply). With ``radar`` (a radar's
    name): that radar's own ``waveform`` table instead, which it runs in place of the
    scene's (no keys: it follows the scene's again)."""
    data = _data(scene)
    if radar is not None:
        kind, target = _entry(scene, data, radar)
        if kind != "radars":
            raise SceneError("names an object; only a radar has a waveform",
                             file=_document(scene).file, key="radar", value=radar)
    else:
        target = data
    if keys:
        target["waveform"] = _plain(keys)
    else:
        target.pop("waveform", None)
    return _rebuilt(scene, data)


def move(scene: Scene, name: str, *, position=None, rotation_deg=None,
         orientation_deg=None, velocity=None) -> Scene:
    """``scene`` with object or radar ``name`` placed anew: each key given replaces the
    entry's (``rotation_deg`` for an object, ``orientation_deg`` for a radar; a radar
    riding on an object takes ``position`` in that object's frame). A radar riding on
    the object moves with it."""
    data = _data(scene)
    kind, entry = _entry(scene, data, name)
    given = {"position": position, "velocity": velocity,
             "rotation_deg": rotation_deg, "orientation_deg": orientation_deg}
    wrong = "orientation_deg" if kind == "objects" else "rotation_deg"
    if given[wrong] is not None:
        right = "rotation_deg" if kind == "objects" else "orientation_deg"
        raise SceneError(f"{'an object' if kind == 'objects' else 'a radar'} turns by "
                         f"{right}, not {wrong}", file=_document(scene).file,
                         key=f"{kind}[{data[kind].index(entry)}].{wrong}",
                         value=given[wrong])
    for key, value in given.items():
        if value is not None:
            entry[key] = _plain(value)
    return _rebuilt(scene, data)


def remove(scene: Scene, name: str) -> Scene:
    """``scene`` without object or radar ``name`` (a radar riding on a removed object is
    refused by name: remove or move it first)."""
    data = _data(scene)
    kind, entry = _entry(scene, data, name)
    data[kind].remove(entry)
    return _rebuilt(scene, data)


def save_scene(scene: Scene, path) -> Path:
    """Write ``scene``'s document as a TOML scene file at ``path`` that ``load_scene`` (and
    every command) reads back as the same scene (the same :meth:`Scene.content_hash`).
    Meshes given in Python are written beside it as float64 PLY files
    (``meshes/<object>.ply``); paths to files the scene reads are rewritten relative to
    the new file's folder (created when missing). Returns the path written."""
    if not isinstance(path, str | os.PathLike):
        raise ArgumentTypeError(f"must be a str or os.PathLike path, got "
                                f"{type(path).__name__}", argument="path", value=path)
    doc = _document(scene)
    target = Path(path)
    folder = target.parent
    data = _data(scene)
    _relocate_paths(data, doc.base_dir, folder)
    folder.mkdir(parents=True, exist_ok=True)
    written: set[str] = set()
    for entry in data.get("objects", []):
        if isinstance(entry.get("vertices"), np.ndarray):
            rel = _mesh_file_name(entry["name"], written)
            verts, faces = entry.pop("vertices"), entry.pop("faces")
            del entry["shape"]
            (folder / MESH_FOLDER).mkdir(parents=True, exist_ok=True)
            atomic_write(folder / rel, lambda fh, v=verts, f=faces: fh.write(
                ply_bytes(v, f, double=True, comment="clradcom save_scene")),
                inputs=scene.input_files)
            entry["mesh"] = rel
    text = tomli_w.dumps(data)
    atomic_write(target, lambda fh: fh.write(text.encode("utf-8")), inputs=scene.input_files)
    return target


# -- the document ------------------------------------------------------------------

def _document(scene: Scene) -> SceneDocument:
    if not isinstance(scene, Scene):
        raise ArgumentTypeError(f"must be a clradcom Scene, got {type(scene).__name__}",
                                argument="scene", value=scene)
    doc = scene.document
    if doc is None:
        raise SceneError("this scene has no document to edit: it was derived from a read "
                         "scene (scene_at, with_object_optics, dataclasses.replace) or "
                         "built field by field; edit the scene load_scene, scene_from_dict "
                         "or new_scene gave, then derive", file=scene.source)
    return doc


def _data(scene: Scene) -> dict:
    """A copy of the scene's document to change (tables copied; arrays shared, never
    written)."""
    data = _copy_tables(_document(scene).data)
    table = data.setdefault("scene", {})
    # the name stays the scene's own when the edited document is read under another label
    table.setdefault("name", scene.name)
    return data


def _copy_tables(value):
    if isinstance(value, dict):
        return {k: _copy_tables(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copy_tables(v) for v in value]
    return value


def _rebuilt(scene: Scene, data: dict) -> Scene:
    doc = _document(scene)
    # messages name the file the scene came from, marked as edited since
    label = (doc.file if str(doc.file).startswith("<")
             else Path(f"<{doc.file}, edited in Python>"))
    return scene_from_dict(data, file=label, base_dir=doc.base_dir,
                           mesh_cache=doc.mesh_cache)


def _entry(scene: Scene, data: dict, name: str) -> tuple[str, dict]:
    """("objects" or "radars", the entry named ``name``), refused when there is none (an
    imported object names its source), or when an object and a radar share it."""
    if not isinstance(name, str):
        raise ArgumentTypeError(f"must be an object or radar name (str), got "
                                f"{type(name).__name__}", argument="name", value=name)
    hits = [(kind, e) for kind in ("objects", "radars") for e in data.get(kind, [])
            if isinstance(e, dict) and e.get("name") == name]
    file = _document(scene).file
    if len(hits) > 1:
        raise SceneError("an object and a radar share this name; rename one to edit it",
                         file=file, key="name", value=name)
    if hits:
        return hits[0]
    for o in scene.objects:
        if o.name == name:
            raise SceneError(f"object {name!r} comes whole from {o.mesh} (an imported "
                             "XML scene or a GeoJSON entry): edit it there, or add it "
                             "as an object of its own", file=file, key="name", value=name)
    names = [o.name for o in scene.objects] + [r.name for r in scene.radars]
    shown = ", ".join(names[:12]) + (", ..." if len(names) > 12 else "")
    raise SceneError(f"no object or radar of the scene has this name (it has: "
                     f"{shown or 'none'})", file=file, key="name", value=name)


def _mesh_keys(mesh) -> dict:
    """The object keys of ``mesh``: a file, a mesh object or a (vertices, faces) pair."""
    if isinstance(mesh, str | os.PathLike):
        return {"mesh": os.fspath(mesh)}
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        verts, faces = mesh.vertices, mesh.faces
    elif isinstance(mesh, tuple | list) and len(mesh) == 2:
        verts, faces = mesh
    else:
        raise ArgumentTypeError("must be a mesh file path, a mesh with vertices and faces "
                                "(trimesh.Trimesh) or a (vertices, faces) pair, got "
                                f"{type(mesh).__name__}", argument="mesh", value=mesh)
    return {"shape": "triangles", "vertices": np.array(verts), "faces": np.array(faces)}


def _plain(value):
    """``value`` as the scene file would hold it: tuples and numpy arrays as lists,
    numpy scalars as Python numbers, a key whose value is None left out (TOML has no
    null: the file's default applies); a mesh's vertex and face arrays stay arrays."""
    if isinstance(value, dict):
        return {k: (v if k in ("vertices", "faces") and isinstance(v, np.ndarray)
                    else _plain(v)) for k, v in value.items() if v is not None}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value


def _mesh_file_name(name: str, taken: set[str]) -> str:
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._") or "object"
    rel, n = f"{MESH_FOLDER}/{stem}.ply", 1
    while rel in taken:
        n += 1
        rel = f"{MESH_FOLDER}/{stem}_{n}.ply"
    taken.add(rel)
    return rel


def _relocate_paths(data: dict, base_dir: Path, folder: Path) -> None:
    """Rewrite the document's relative file paths (meshes, imports, GeoJSON, pattern
    files) from ``base_dir`` to ``folder``."""
    def moved(rel: str) -> str:
        if Path(rel).is_absolute():
            return rel
        return Path(os.path.relpath(base_dir / rel, folder)).as_posix()

    table = data.get("scene", {})
    if isinstance(table.get("import"), str):
        table["import"] = moved(table["import"])
    for entry in data.get("objects", []):
        for key in ("mesh", "geojson"):
            if isinstance(entry.get(key), str):
                entry[key] = moved(entry[key])

    def patterns(value):
        if isinstance(value, dict):
            if value.get("type") == "file" and isinstance(value.get("path"), str):
                value["path"] = moved(value["path"])
            for v in value.values():
                patterns(v)
        elif isinstance(value, list):
            for v in value:
                patterns(v)

    patterns(data.get("radars", []))
