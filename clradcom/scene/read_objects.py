"""The ``[[objects]]`` entries of a scene file -> :class:`SceneObject` records and their
world triangles: material, pose (scale, then rotate, then translate), velocity, optics
and its SBR ray-tube pitch, and the refusal (or dropping) of degenerate triangles.

Objects that come whole from elsewhere (an imported Mitsuba/Sionna XML scene,
:mod:`~clradcom.scene.import_xml`) arrive as :class:`PlacedMesh` records, already in world
coordinates; an entry with ``geojson`` becomes one object per building footprint
(:mod:`~clradcom.scene.geojson`)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clradcom.errors import NOVALUE, SceneWarning
from clradcom.geometry.shells import orient_shells
from clradcom.geometry.triangles import triangle_double_areas
from clradcom.scene.antenna import euler_deg_to_matrix
from clradcom.scene.bounds import check_coordinates, check_speed
from clradcom.scene.fields import FieldReader
from clradcom.scene.geojson import GEOJSON_KEYS, read_geojson_buildings
from clradcom.scene.motion import (
    MOTION_KEYS,
    read_motion,
    trajectory_position,
    trajectory_velocity,
)
from clradcom.scene.read_geometry import MeshCache, read_object_geometry
from clradcom.scene.read_materials import MaterialTable, material_index
from clradcom.scene.records import OPTICS, SBR_SPACING_WAVELENGTHS, SIDES, SceneObject

__all__ = ["DEGENERATE_REL", "OBJECT_KEYS", "PlacedMesh", "drop_or_refuse_degenerate",
           "orient_sides", "read_objects"]

OBJECT_KEYS = ("name", "material", "mesh", "shape", "extents", "size", "vertices", "faces",
               "position", "rotation_deg", "scale", "velocity", "drop_degenerate",
               "optics", "sbr_spacing_wavelengths", "sides", "description", *MOTION_KEYS)

#: Relative area threshold for "degenerate": 2*area <= DEGENERATE_REL * longest_edge^2.
DEGENERATE_REL = 1e-10


@dataclass(eq=False)
class PlacedMesh:
    """An object whose world triangles were made elsewhere (an XML import, a GeoJSON
    footprint): everything a :class:`SceneObject` needs but its triangle range."""

    name: str
    key: str  #: where it was defined, for messages (``shape[mesh-wall]``, ``objects[2]``)
    mesh: str  #: label: the mesh file, or ``<geojson file>#<feature>``
    triangles: np.ndarray  #: (F, 3, 3) float64 world coordinates
    material: int
    material_name: str
    position: np.ndarray
    rotation: np.ndarray
    scale: np.ndarray
    velocity: np.ndarray
    #: "go" / "po" / "both" (:data:`OPTICS`), or None to follow the tracer's default
    optics: str | None = None


def read_objects(fields: FieldReader, entries: list, materials: MaterialTable,
                 carrier: float, base_dir: Path, placed=(), span=(0.0, 0.0),
                 mesh_cache: MeshCache | None = None
                 ) -> tuple[list[SceneObject], list[np.ndarray]]:
    """Objects (``placed`` ones first, then the entries in file order) and each one's world
    triangles (F, 3, 3); built-in materials they name join ``materials``. ``span`` is the
    first and last instant traced (trajectories must cover it; poses are at the first).
    ``mesh_cache`` holds the mesh files read so far (new ones join it)."""
    objects: list[SceneObject] = []
    triangles: list[np.ndarray] = []
    seen: dict = {}
    mesh_cache = {} if mesh_cache is None else mesh_cache
    start = 0

    def add(obj: SceneObject, tri: np.ndarray) -> None:
        nonlocal start
        objects.append(obj)
        triangles.append(tri)
        start += tri.shape[0]

    for p in placed:
        if p.name in seen:
            raise fields.err(p.key, p.name, f"duplicate object name (already used by "
                             f"{seen[p.name]})")
        seen[p.name] = p.key
        add(*_placed_object(fields, p, start))
    for i, tbl in enumerate(entries):
        kp = f"objects[{i}]"
        if isinstance(tbl, dict) and "geojson" in tbl:
            for p in _read_geojson_entry(fields, kp, tbl, seen, materials, carrier,
                                         base_dir):
                add(*_placed_object(fields, p, start))
            continue
        add(*_read_object(fields, kp, tbl, seen, materials, carrier, base_dir, mesh_cache,
                          start, span))
    return objects, triangles


def _placed_object(fields: FieldReader, p: PlacedMesh, start: int
                   ) -> tuple[SceneObject, np.ndarray]:
    tri, two_sided = orient_sides(fields, p.key, p.name, p.mesh, p.triangles, "auto")
    obj = SceneObject(
        name=p.name, mesh=p.mesh, material=p.material, material_name=p.material_name,
        position=p.position, rotation_deg=matrix_to_euler_deg(p.rotation),
        rotation=p.rotation, scale=p.scale, velocity=p.velocity, tri_start=start,
        tri_stop=start + tri.shape[0], optics=p.optics, two_sided=two_sided)
    return obj, tri


def orient_sides(fields: FieldReader, kp: str, name: str, label: str, tri: np.ndarray,
                 mode: str) -> tuple[np.ndarray, bool]:
    """(triangles, two_sided) of one object under its ``sides`` mode (:data:`SIDES`).

    "auto": every closed, consistently wound shell that encloses its volume with inward
    normals is re-oriented (each triangle's vertex order reversed, so its winding normal
    points out of the material) with a SceneWarning naming the object and its mesh; the
    object is two-sided when any of its triangles is not part of a closed shell (an open
    sheet such as a plane, a screen, a mesh with holes or inconsistent winding).
    "as_wound": the triangles as given, one-sided. "two_sided": as given, two-sided."""
    if mode == "as_wound":
        return tri, False
    if mode == "two_sided":
        return tri, True
    shells = orient_shells(tri)
    if shells.n_inward:
        flip = shells.inward_triangles
        tri = tri.copy()
        tri[flip] = tri[flip][:, ::-1]
        warnings.warn(f"{fields.file}: {kp}: object '{name}' ({label}): {shells.n_inward} of "
                      f"its {shells.n_closed} closed shell(s) had inward-facing normals "
                      f"(inside out); re-oriented {int(np.count_nonzero(flip))} triangle(s) "
                      "so their normals point outwards. Fix the mesh, or set sides = "
                      "\"as_wound\" on the object to keep its winding (docs/scene-format.md, "
                      "Sides)", SceneWarning, stacklevel=2)
    return tri, bool(shells.open_triangles.any())


def matrix_to_euler_deg(rotation: np.ndarray) -> np.ndarray:
    """[roll, pitch, yaw] (deg) of ``R = Rz(yaw) Ry(pitch) Rx(roll)``, the inverse of
    :func:`~clradcom.scene.antenna.euler_deg_to_matrix` (pitch in [-90, 90])."""
    r = np.asarray(rotation, dtype=np.float64)
    pitch = np.arcsin(np.clip(-r[2, 0], -1.0, 1.0))
    if abs(r[2, 0]) < 1.0 - 1e-12:
        roll = np.arctan2(r[2, 1], r[2, 2])
        yaw = np.arctan2(r[1, 0], r[0, 0])
    else:  # gimbal lock: only yaw - roll (or yaw + roll) is defined; put it all in yaw
        roll = 0.0
        yaw = np.arctan2(-r[0, 1], r[1, 1])
    return np.degrees([roll, pitch, yaw]) + 0.0  # no -0.0


def _read_geojson_entry(fields, kp, tbl, seen, materials, carrier, base_dir):
    """One :class:`PlacedMesh` per building of an ``[[objects]]`` entry with ``geojson``:
    named ``<name>/<feature id or index>``, standing on z = 0 plus ``position``."""
    fields.check_keys(tbl, GEOJSON_KEYS, kp)
    name = fields.unique_name(tbl, kp, seen, "object")
    default_mat = fields.get_str(tbl, "material", kp, default=None)
    position = fields.get_vec3(tbl, "position", kp, default=(0.0, 0.0, 0.0), unit="m")
    velocity = fields.get_vec3(tbl, "velocity", kp, default=(0.0, 0.0, 0.0), unit="m/s")
    if "velocity" in tbl:
        check_speed(fields, velocity, tbl["velocity"], f"{kp}.velocity")
    default_optics = fields.get_str(tbl, "optics", kp, default=None, choices=OPTICS)
    out = []
    for b in read_geojson_buildings(fields, tbl, kp, base_dir):
        bname = f"{name}/{b.label}"
        if bname in seen:
            raise fields.err(f"{kp}.geojson", tbl["geojson"],
                             f"building '{bname}' (feature {b.index}) has the name of "
                             f"{seen[bname]}; give the features unique ids")
        seen[bname] = f"{kp} feature {b.index}"
        mat_name = b.material if b.material is not None else default_mat
        mat_key = (f"{kp}.geojson feature {b.index} material" if b.material is not None
                   else f"{kp}.material")
        if mat_name is None:
            raise fields.err(f"{kp}.material", NOVALUE,
                             f"feature {b.index} of {b.file} has no 'material' property: "
                             "give a default material for the buildings")
        mat = material_index(fields, materials, mat_name, mat_key, carrier)
        world = b.vertices + position
        check_coordinates(fields, world, f"{kp}.position", tbl.get("position", NOVALUE),
                          f"position plus the buildings of {b.file}")
        label = f"{b.file}#{b.index}"
        tri = drop_or_refuse_degenerate(fields, world[b.faces], kp, label, True,
                                        tbl["geojson"])
        out.append(PlacedMesh(
            name=bname, key=f"{kp} feature {b.index}", mesh=label, triangles=tri,
            material=mat, material_name=mat_name, position=position.copy(),
            rotation=np.eye(3), scale=np.ones(3), velocity=velocity.copy(),
            optics=b.optics if b.optics is not None else default_optics))
    return out


def _read_object(fields, kp, tbl, seen, materials, carrier, base_dir, mesh_cache, start,
                 span=(0.0, 0.0)):
    fields.check_keys(tbl, OBJECT_KEYS, kp)
    name = fields.unique_name(tbl, kp, seen, "object")
    mat_name = fields.get_str(tbl, "material", kp)
    mat = material_index(fields, materials, mat_name, f"{kp}.material", carrier)
    position = fields.get_vec3(tbl, "position", kp, default=(0.0, 0.0, 0.0), unit="m")
    rot_deg = fields.get_vec3(tbl, "rotation_deg", kp, default=(0.0, 0.0, 0.0), unit="deg")
    velocity = fields.get_vec3(tbl, "velocity", kp, default=(0.0, 0.0, 0.0), unit="m/s")
    if "velocity" in tbl:
        check_speed(fields, velocity, tbl["velocity"], f"{kp}.velocity")
    motion = read_motion(fields, tbl, kp, position, span)
    if motion is not None and motion.trajectory is not None:
        position = trajectory_position(motion.trajectory, span[0])
        velocity = trajectory_velocity(motion.trajectory, span[0])
    scale = _read_scale(fields, tbl, kp)
    drop = fields.get_bool(tbl, "drop_degenerate", kp, default=False)
    optics = fields.get_str(tbl, "optics", kp, default=None, choices=OPTICS)
    sbr_spacing = _read_sbr_spacing(fields, tbl, kp)
    sides = fields.get_str(tbl, "sides", kp, default="auto", choices=SIDES)

    verts, faces, label = read_object_geometry(fields, tbl, kp, base_dir, mesh_cache)
    rotation = euler_deg_to_matrix(rot_deg)
    world = _world_vertices(fields, tbl, kp, verts, scale, rotation, position, label)
    tri = world[faces]  # (F,3,3)
    if not drop:
        _refuse_flattened(fields, tbl, kp, label, tri, verts[faces], scale)
    tri = drop_or_refuse_degenerate(fields, tri, kp, label, drop, tbl.get("mesh"))
    tri, two_sided = orient_sides(fields, kp, name, label, tri, sides)
    obj = SceneObject(
        name=name, mesh=label, material=mat, material_name=mat_name, position=position,
        rotation_deg=rot_deg, rotation=rotation, scale=scale, velocity=velocity,
        tri_start=start, tri_stop=start + tri.shape[0], optics=optics,
        sbr_spacing_wavelengths=sbr_spacing, motion=motion, sides=sides, two_sided=two_sided,
    )
    return obj, tri


def _read_sbr_spacing(fields, tbl, kp) -> float | None:
    """``sbr_spacing_wavelengths``: the object's own SBR ray-tube pitch, a number of
    wavelengths in :data:`SBR_SPACING_WAVELENGTHS`, or None when absent."""
    value = fields.get_float(tbl, "sbr_spacing_wavelengths", kp, default=None,
                             unit="wavelengths")
    low, high = SBR_SPACING_WAVELENGTHS
    if value is not None and not low <= value <= high:
        raise fields.err(f"{kp}.sbr_spacing_wavelengths", tbl["sbr_spacing_wavelengths"],
                         f"the SBR ray-tube pitch must be between {low:g} and {high:g} "
                         "wavelengths")
    return value


def _read_scale(fields, tbl, kp) -> np.ndarray:
    """``scale``: one number or [sx, sy, sz], all > 0 (default 1)."""
    scale = np.ones(3)
    if "scale" in tbl:
        v = tbl["scale"]
        k = f"{kp}.scale"
        if isinstance(v, list):
            scale = fields.vector(v, k, 3)
        else:
            scale = np.full(3, fields.number(v, k, "a number or an array of 3 numbers"))
        if np.any(scale <= 0):
            raise fields.err(k, v, "scale must be > 0 (mirroring is not supported)")
    return scale


def _world_vertices(fields, tbl, kp, verts, scale, rotation, position, label):
    """``R (s * v) + p``, refused (naming the key to blame) where the local vertices,
    their scaling or their translation leave what float64 and the float32 kernels hold."""
    if label.startswith("shape:"):
        shape = label.removeprefix("shape:")
        key = {"box": "extents", "plane": "size", "triangles": "vertices"}[shape]
        check_coordinates(fields, verts, f"{kp}.{key}", tbl.get(key, NOVALUE),
                          f"the {shape}")
    else:
        check_coordinates(fields, verts, f"{kp}.mesh", tbl.get("mesh"),
                          f"mesh file {label}")
    with np.errstate(over="ignore", invalid="ignore"):
        scaled = verts * scale
        check_coordinates(fields, scaled, f"{kp}.scale", tbl.get("scale", NOVALUE),
                          "scale times the object's vertices")
        world = scaled @ rotation.T + position
    check_coordinates(fields, world, f"{kp}.position", tbl.get("position", NOVALUE),
                      "position plus the rotated, scaled vertices")
    return world


def _degenerate(tri) -> np.ndarray:
    """(F,) bool: 2 * area <= DEGENERATE_REL * (longest edge)^2."""
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    e3 = tri[:, 2] - tri[:, 1]
    cross = triangle_double_areas(tri)  # 2 * area
    longest = np.max(np.stack([np.einsum("ij,ij->i", e, e) for e in (e1, e2, e3)]), axis=0)
    return cross <= DEGENERATE_REL * longest


def _refuse_flattened(fields, tbl, kp, label, tri, local, scale) -> None:
    """Refuse, naming ``scale`` or ``position``, the first degenerate world triangle that
    is not degenerate as written: a tiny (or very uneven) scale flattened it, or float64
    rounding far from the origin did. Triangles degenerate as written are left to
    :func:`drop_or_refuse_degenerate`."""
    bad = np.flatnonzero(_degenerate(tri))
    if bad.size == 0:
        return
    j = int(bad[0])
    if _degenerate(local[j:j + 1])[0]:
        return
    what = label if not label.startswith("shape:") else f"{kp} ({label})"
    if _degenerate(local[j:j + 1] * scale)[0]:
        raise fields.err(f"{kp}.scale", tbl.get("scale", NOVALUE),
                         f"triangle {j} of {what} has an area but this scale flattens it "
                         "to a degenerate one (or to nothing, below the smallest float)")
    raise fields.err(f"{kp}.position", tbl.get("position", NOVALUE),
                     f"triangle {j} of {what} has an area but is degenerate once moved "
                     "this far from the origin (float64 rounding there is larger than the "
                     "triangle); move the origin nearer to the scene")


def drop_or_refuse_degenerate(fields: FieldReader, tri, kp, label, drop, written=None):
    """``tri`` without its degenerate (zero or sliver area) triangles when ``drop`` (with a
    SceneWarning); otherwise the first one is refused, naming the mesh file (``written``,
    as the scene file gives it) or the inline faces."""
    bad = _degenerate(tri)
    if not bad.any():
        return tri
    idx = np.flatnonzero(bad)
    what = label if not label.startswith("shape:") else f"{kp} ({label})"
    if not drop:
        j = int(idx[0])
        key = f"{kp}.mesh" if not label.startswith("shape:") else f"{kp}.faces"
        value = written if not label.startswith("shape:") else j
        raise fields.err(key, value,
                         f"triangle {j} of {what} is degenerate (zero area; vertices "
                         f"{np.round(tri[j], 9).tolist()}); {len(idx)} such triangle(s) in "
                         "all; fix the mesh or set drop_degenerate = true")
    warnings.warn(f"{fields.file}: {kp}: dropped {len(idx)} degenerate (zero-area) "
                  f"triangle(s) of {what}, first indices {idx[:10].tolist()}",
                  SceneWarning, stacklevel=2)
    return tri[~bad]
