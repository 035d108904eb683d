"""Mitsuba 3 / Sionna RT XML scenes -> placed objects with world triangles and materials.

A scene file imports one XML scene with ``[scene] import = "canyon.xml"``; the carrier
frequency and the radars, which the XML does not hold, stay in the scene file
(docs/scene-format.md, "Importing a Mitsuba / Sionna RT scene"). What is read:

* ``<default name="..." value="..."/>`` parameters, substituted for ``$name`` in every
  attribute value;
* top-level ``<bsdf>`` elements by ``id``, and a ``<bsdf>`` nested in a shape. Sionna RT
  >= 1.0 writes ``<bsdf type="itu-radio-material">`` with ``<string name="type"
  value="concrete"/>``, or ``type="radio-material"`` with ``relative_permittivity``,
  ``conductivity``; both may give ``scattering_coefficient`` and ``xpd_coefficient``.
  Sionna <= 0.19 and Blender exports write a visual BSDF (``twosided``, ``diffuse``, ...)
  whose id names the material: ``mat-itu_concrete`` (the ``mat-`` prefix and a Blender
  ``.001`` suffix are dropped). ``itu_<name>`` maps to clradcom's ITU-R P.2040-3 material;
  another name must be a ``[[materials]]`` entry of the scene file. Sionna's
  ``holder-material`` wrapper is looked through; ``thickness`` is read and not used
  (clradcom reflects off half-spaces);
* ``<shape type="ply|obj|stl">`` with ``<string name="filename">`` (relative to the
  XML file's folder, read with trimesh, faces as stored), or ``type="rectangle"``
  (z = 0, [-1, 1]^2, normal +z) and ``type="cube"`` ([-1, 1]^3); the object is named
  after the shape's id without Sionna's ``mesh-`` prefix;
* ``<transform name="to_world">`` with ``translate``, ``rotate``, ``scale``, ``matrix``
  and ``lookat`` children, applied in the order written (Mitsuba's rule);
  ``<boolean name="flip_normals" value="true"/>`` reverses the faces' winding;
* ``<vector name="velocity" x=".." y=".." z=".."/>`` (or ``<point>``, or
  ``value="vx vy vz"``) in a shape: the object's velocity in m/s, the property Sionna's
  ``SceneObject.velocity`` sets;
* ``<string name="optics" value="po"/>`` (or ``go``, ``both``) in a shape: the object's
  ``optics`` key, how the tracer models its returns (docs/po.md). Mitsuba itself does not
  know this property; a file meant for both keeps it out and gives the optics from the
  command line (``clradcom trace --optics NAME=po``).

Render-only elements (integrator, sensor, emitter, ...) are ignored. Zero-area triangles
of imported meshes are dropped with a warning. Imported objects follow the ``sides =
"auto"`` rule of the scene reader (:func:`clradcom.scene.read_objects.orient_sides`): a
closed shell whose faces point inwards (common in converted Sionna scenes) is re-oriented
with a :class:`~clradcom.errors.SceneWarning` naming the object, and an open mesh reflects
on both sides (docs/scene-format.md, "Sides").
"""

from __future__ import annotations

import math
import re
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clradcom.errors import SceneError
from clradcom.geometry.shells import orient_shells
from clradcom.scene.bounds import check_coordinates, check_speed
from clradcom.scene.fields import FieldReader, is_file
from clradcom.scene.materials import (
    ITU_P2040_TABLE3,
    ITU_PREFIX,
    Material,
    builtin_material_names,
    conductivity_to_eps_imag,
    with_overrides,
)
from clradcom.scene.read_geometry import MeshCache, box_geometry, load_mesh, plane_geometry
from clradcom.scene.read_materials import MaterialTable, material_index
from clradcom.scene.read_objects import PlacedMesh, drop_or_refuse_degenerate
from clradcom.scene.records import OPTICS

__all__ = ["MESH_SHAPES", "PRIMITIVE_SHAPES", "XmlNode", "inward_closed_shells",
           "parse_xml", "read_xml_scene", "transform_matrix"]

#: Mitsuba shape plugins read from a mesh file, and the file type each reads.
MESH_SHAPES = {"ply": ".ply", "obj": ".obj", "stl": ".stl"}
#: Mitsuba's built-in flat shapes clradcom knows.
PRIMITIVE_SHAPES = ("rectangle", "cube")
#: Top-level elements that only matter to a renderer.
_RENDER_ONLY = ("integrator", "sensor", "emitter", "film", "sampler", "rfilter", "texture",
                "spectrum", "medium", "phase", "volume", "path")
_RADIO_BSDFS = ("itu-radio-material", "radio-material")
_BLENDER_SUFFIX = re.compile(r"\.\d{3}$")
_PARAM = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


@dataclass(eq=False)
class XmlNode:
    """One element of the XML file, with the line it starts on."""

    tag: str
    attrib: dict[str, str]
    line: int
    children: list[XmlNode] = field(default_factory=list)

    def find_all(self, tag: str) -> list[XmlNode]:
        return [c for c in self.children if c.tag == tag]


def parse_xml(path: Path) -> XmlNode:
    """The XML file's root element (expat, so every element knows its line). Raises
    SceneError naming the file and line on a syntax error."""
    stack: list[XmlNode] = []
    root: list[XmlNode] = []
    parser = xml.parsers.expat.ParserCreate()

    def start(tag, attrib):
        node = XmlNode(tag, dict(attrib), parser.CurrentLineNumber)
        (stack[-1].children if stack else root).append(node)
        stack.append(node)

    def end(tag):
        stack.pop()

    def no_entities(*args):
        raise SceneError("XML entity declarations are not allowed in a scene", file=path,
                         line=parser.CurrentLineNumber)

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.EntityDeclHandler = no_entities
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SceneError(f"cannot read XML scene ({exc})", file=path) from None
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as exc:
        raise SceneError(f"XML syntax error: {xml.parsers.expat.ErrorString(exc.code)}",
                         file=path, line=exc.lineno) from None
    return root[0]


class _Reader:
    """The XML file's refusals: each names the file, the line, the element and value."""

    def __init__(self, path: Path, params: dict[str, str]):
        self.path = path
        self.params = params

    def err(self, node: XmlNode, key: str, value, reason: str) -> SceneError:
        return SceneError(reason, file=self.path, key=key, value=value, line=node.line)

    def attr(self, node: XmlNode, name: str, key: str, default=None) -> str | None:
        """An attribute with ``$parameters`` substituted."""
        raw = node.attrib.get(name)
        if raw is None:
            return default

        def sub(m):
            if m.group(1) not in self.params:
                raise self.err(node, key, raw, f"unknown parameter ${m.group(1)}; declare "
                               f"it with <default name=\"{m.group(1)}\" value=\"...\"/>")
            return self.params[m.group(1)]
        return _PARAM.sub(sub, raw)

    def numbers(self, node: XmlNode, name: str, key: str, count=None) -> list[float]:
        raw = self.attr(node, name, key)
        if raw is None:
            raise self.err(node, key, None, f"missing attribute '{name}'")
        try:
            vals = [float(t) for t in raw.replace(",", " ").split()]
        except ValueError:
            raise self.err(node, key, raw, "expected numbers") from None
        if count is not None and len(vals) not in (count if isinstance(count, tuple)
                                                    else (count,)):
            raise self.err(node, key, raw, f"expected {count} numbers, got {len(vals)}")
        if not all(math.isfinite(v) for v in vals):
            raise self.err(node, key, raw, "NaN or inf is not allowed")
        return vals

    def xyz(self, node: XmlNode, key: str, default: float) -> np.ndarray:
        """A 3-vector written ``value="x y z"`` or as ``x``, ``y``, ``z`` attributes."""
        if "value" in node.attrib:
            v = self.numbers(node, "value", key, (1, 3))
            return np.array(v * 3 if len(v) == 1 else v)
        return np.array([self.numbers(node, a, f"{key}.{a}", 1)[0] if a in node.attrib
                         else default for a in "xyz"])

    def properties(self, node: XmlNode) -> dict[str, XmlNode]:
        """The named property children (``<float name=..>``, ``<string ..>``, ...)."""
        return {c.attrib["name"]: c for c in node.children if "name" in c.attrib
                and c.tag not in ("bsdf", "ref", "shape")}


def read_xml_scene(fields: FieldReader, rel: str, key: str, materials: MaterialTable,
                   carrier: float, base_dir: Path) -> list[PlacedMesh]:
    """The shapes of the XML scene ``rel`` (relative to ``base_dir``) as placed objects
    in file order; the materials they use join ``materials``. ``fields`` and ``key`` are
    the scene file's, blamed when the XML file is missing."""
    path = base_dir / rel
    if not is_file(path):
        raise fields.err(key, rel, f"XML scene not found (looked for {path})")
    fields.note_read(path)
    root = parse_xml(path)
    if root.tag != "scene":
        raise SceneError("not a Mitsuba scene: the root element must be <scene>",
                         file=path, key=root.tag, line=root.line)
    params: dict[str, str] = {}
    rd = _Reader(path, params)
    for d in root.find_all("default"):
        name = d.attrib.get("name")
        if not name or "value" not in d.attrib:
            raise rd.err(d, "default", d.attrib, "a <default> needs name and value")
        params.setdefault(name, d.attrib["value"])
    xml_fields = FieldReader(path, fields.read_files)
    bsdfs: dict[str, XmlNode] = {}
    for b in root.find_all("bsdf"):
        if "id" in b.attrib:
            bsdfs[rd.attr(b, "id", "bsdf.id")] = b
    for c in root.children:
        if c.tag == "include":
            raise rd.err(c, "include", c.attrib.get("filename"),
                         "<include> is not supported; put the shapes in one file")
    mats = _Materials(rd, xml_fields, materials, carrier, bsdfs)
    cache: MeshCache = {}
    out: list[PlacedMesh] = []
    seen: dict[str, int] = {}
    for i, shape in enumerate(root.find_all("shape")):
        placed = _read_shape(rd, xml_fields, shape, i, mats, cache)
        if placed.name in seen:
            raise rd.err(shape, placed.key, placed.name, f"duplicate object name (shape on "
                         f"line {seen[placed.name]} has it too)")
        seen[placed.name] = shape.line
        out.append(placed)
    return out


class _Materials:
    """BSDF elements -> material indices in the scene's table, each BSDF once."""

    def __init__(self, rd: _Reader, fields: FieldReader, table: MaterialTable,
                 carrier: float, bsdfs: dict[str, XmlNode]):
        self.rd, self.fields, self.table, self.carrier = rd, fields, table, carrier
        self.bsdfs = bsdfs
        self.done: dict[int, int] = {}  # id(node) -> material index

    def of_shape(self, shape: XmlNode, key: str) -> int:
        refs = [c for c in shape.find_all("ref") if c.attrib.get("name", "bsdf") == "bsdf"]
        nested = shape.find_all("bsdf")
        if len(refs) + len(nested) != 1:
            raise self.rd.err(shape, key, len(refs) + len(nested),
                              "a shape needs exactly one material: <ref id=\"mat-...\"/> or "
                              "a nested <bsdf>")
        if refs:
            ref = self.rd.attr(refs[0], "id", f"{key}.ref")
            if ref not in self.bsdfs:
                raise self.rd.err(refs[0], f"{key}.ref", ref,
                                  "refers to no <bsdf> of this file")
            return self.of_bsdf(self.bsdfs[ref])
        return self.of_bsdf(nested[0])

    def of_bsdf(self, node: XmlNode) -> int:
        if id(node) not in self.done:
            self.done[id(node)] = self._resolve(node)
        return self.done[id(node)]

    def _resolve(self, node: XmlNode) -> int:
        rd = self.rd
        bid = rd.attr(node, "id", "bsdf.id")
        key = f"bsdf[{bid}]" if bid else "bsdf"
        kind = rd.attr(node, "type", f"{key}.type")
        if kind == "holder-material":
            inner = node.find_all("bsdf") + node.find_all("ref")
            if len(inner) != 1:
                raise rd.err(node, key, len(inner), "a holder-material holds one material")
            if inner[0].tag == "bsdf":
                return self.of_bsdf(inner[0])
            ref = rd.attr(inner[0], "id", f"{key}.ref")
            if ref not in self.bsdfs:
                raise rd.err(inner[0], f"{key}.ref", ref, "refers to no <bsdf> of this file")
            return self.of_bsdf(self.bsdfs[ref])
        name = _material_name(bid) if bid else None
        if kind not in _RADIO_BSDFS:  # a visual BSDF: the id names the material
            if name is None:
                raise rd.err(node, key, kind, "a visual BSDF without an id names no "
                             "material; give it id=\"mat-itu_<material>\"")
            if name in self.table.user_names or (
                    name.startswith(ITU_PREFIX)
                    and name[len(ITU_PREFIX):] in ITU_P2040_TABLE3):
                return self._index(node, f"{key}", name)
            raise rd.err(node, f"{key}.id", bid, _unknown_material(name, self.table))
        props = rd.properties(node)
        if kind == "itu-radio-material":
            if "type" not in props:
                raise rd.err(node, key, None, "an itu-radio-material needs "
                             "<string name=\"type\" value=\"concrete\"/> (or another "
                             "ITU-R P.2040 name)")
            itu = rd.attr(props["type"], "value", f"{key}.type")
            if itu not in ITU_P2040_TABLE3:
                raise rd.err(props["type"], f"{key}.type", itu,
                             f"unknown ITU-R P.2040 material; known: "
                             f"{', '.join(ITU_P2040_TABLE3)}")
            base = self.table.materials[self._index(props["type"], f"{key}.type",
                                                    ITU_PREFIX + itu)]
        else:
            eps = self._float(props, "relative_permittivity", key, 1.0)
            sigma = self._float(props, "conductivity", key, 0.0)
            if eps <= 0 or sigma < 0:
                raise rd.err(node, key, [eps, sigma], "relative_permittivity must be > 0 "
                             "and conductivity >= 0")
            base = Material(name or "radio-material", complex(
                eps, -conductivity_to_eps_imag(sigma, self.carrier)),
                conductivity_s_m=sigma, source=f"xml {self.rd.path.name}")
        s = self._float(props, "scattering_coefficient", key, 0.0)
        kx = self._float(props, "xpd_coefficient", key, 0.0)
        for v, what in ((s, "scattering_coefficient"), (kx, "xpd_coefficient")):
            if not 0.0 <= v <= 1.0:
                raise rd.err(props[what], f"{key}.{what}", v, "must be in [0, 1]")
        if kind == "itu-radio-material" and s == 0.0 and kx == 0.0:
            return self.table.index[base.name]
        own = name if name else f"xml-bsdf-line{node.line}"
        if own in self.table.index or own in builtin_material_names():
            own = f"{bid}@{self.rd.path.name}"  # never under a built-in or user name
        if own in self.table.index:
            raise rd.err(node, f"{key}.id", bid, "two materials of this name")
        mat = with_overrides(base, name=own, scattering_coefficient=s, cross_pol_share=kx,
                             source=f"xml {self.rd.path.name} ({base.source})")
        self.table.index[own] = len(self.table.materials)
        self.table.materials.append(mat)
        return self.table.index[own]

    def _float(self, props, name, key, default) -> float:
        if name not in props:
            return default
        return self.rd.numbers(props[name], "value", f"{key}.{name}", 1)[0]

    def _index(self, node: XmlNode, key: str, name: str) -> int:
        """A built-in or ``[[materials]]`` material, with the XML's line in refusals
        (an ITU material outside its frequency range, say)."""
        try:
            return material_index(self.fields, self.table, name, key, self.carrier)
        except SceneError as exc:
            raise SceneError(exc.reason, file=exc.file, key=exc.key, value=exc.value,
                             line=node.line) from None


def _material_name(bsdf_id: str) -> str:
    """``mat-itu_concrete.001`` -> ``itu_concrete`` (Sionna's prefix, Blender's suffix)."""
    name = bsdf_id.removeprefix("mat-")
    return _BLENDER_SUFFIX.sub("", name)


def _unknown_material(name: str, table: MaterialTable) -> str:
    known = ", ".join(ITU_PREFIX + n for n in ITU_P2040_TABLE3)
    user = (f"; or one of the scene file's [[materials]]: {', '.join(table.user_names)}"
            if table.user_names else "; or define it under [[materials]] in the scene file")
    return (f"unknown material '{name}': name the BSDF mat-<material> with an ITU-R "
            f"P.2040 material ({known}){user}")


def _read_shape(rd: _Reader, fields: FieldReader, shape: XmlNode, i: int, mats: _Materials,
                cache: MeshCache) -> PlacedMesh:
    sid = rd.attr(shape, "id", "shape.id")
    key = f"shape[{sid}]" if sid else f"shape[{i}]"
    name = sid.removeprefix("mesh-") if sid else f"shape{i}"
    kind = rd.attr(shape, "type", f"{key}.type")
    props = rd.properties(shape)
    if kind in MESH_SHAPES:
        if "filename" not in props:
            raise rd.err(shape, f"{key}.filename", None,
                         "a mesh shape needs <string name=\"filename\" value=\"...\"/>")
        rel = rd.attr(props["filename"], "value", f"{key}.filename")
        if rel is None:
            raise rd.err(props["filename"], f"{key}.filename", None,
                         "missing attribute 'value' (the mesh file's name)")
        if Path(rel).suffix.lower() != MESH_SHAPES[kind]:
            raise rd.err(props["filename"], f"{key}.filename", rel,
                         f"a shape of type '{kind}' reads {MESH_SHAPES[kind]} files")
        try:
            verts, faces, label = load_mesh(fields, rd.path.parent, rel, f"{key}.filename",
                                            cache)
        except SceneError as exc:
            raise SceneError(exc.reason, file=exc.file, key=exc.key, value=exc.value,
                             line=props["filename"].line) from None
    elif kind == "rectangle":
        verts, faces = plane_geometry(np.array([2.0, 2.0]))
        label = "shape:rectangle"
    elif kind == "cube":
        verts, faces = box_geometry(np.array([2.0, 2.0, 2.0]))
        label = "shape:cube"
    else:
        raise rd.err(shape, f"{key}.type", kind, "unsupported shape type; clradcom reads "
                     f"{', '.join([*MESH_SHAPES, *PRIMITIVE_SHAPES])}")
    material = mats.of_shape(shape, key)
    matrix = np.eye(4)
    for t in shape.find_all("transform"):
        if t.attrib.get("name", "to_world") == "to_world":
            matrix = transform_matrix(rd, t, f"{key}.to_world")
    lin, offset = matrix[:3, :3], matrix[:3, 3]
    if "flip_normals" in props and _boolean(rd, props["flip_normals"],
                                            f"{key}.flip_normals"):
        faces = faces[:, ::-1]
    velocity = np.zeros(3)
    if "velocity" in props:
        node = props["velocity"]
        velocity = rd.xyz(node, f"{key}.velocity", 0.0)
        try:
            check_speed(fields, velocity, velocity.tolist(), f"{key}.velocity")
        except SceneError as exc:
            raise rd.err(node, exc.key, exc.value, exc.reason) from None
    optics = None
    if "optics" in props:
        optics = rd.attr(props["optics"], "value", f"{key}.optics")
        if optics not in OPTICS:
            raise rd.err(props["optics"], f"{key}.optics", optics,
                         f"must be one of {', '.join(OPTICS)}")
    world = verts @ lin.T + offset
    try:
        check_coordinates(fields, world, f"{key}.to_world", label,
                          "the shape's vertices moved by its to_world")
    except SceneError as exc:
        raise rd.err(shape, exc.key, exc.value, exc.reason) from None
    tri = drop_or_refuse_degenerate(fields, world[faces], key, label, True, label)
    rotation, scale = _rotation_scale(lin)
    return PlacedMesh(name=name, key=key, mesh=label, triangles=tri, material=material,
                      material_name=mats.table.materials[material].name, position=offset,
                      rotation=rotation, scale=scale, velocity=velocity, optics=optics)


def _boolean(rd: _Reader, node: XmlNode, key: str) -> bool:
    v = rd.attr(node, "value", key)
    if v not in ("true", "false"):
        raise rd.err(node, key, v, "expected true or false")
    return v == "true"


def _rotation_scale(lin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, s) with ``lin = R diag(s)`` when the linear part is a rotation times a scale
    along the local axes; otherwise (I, 1): the object's frame is then unrotated (for
    ``rides_on``), the triangles keep the whole transform either way."""
    s = np.linalg.norm(lin, axis=0)
    if np.all(s > 0):
        r = lin / s
        if np.allclose(r.T @ r, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0:
            return r, s
    return np.eye(3), np.ones(3)


def transform_matrix(rd: _Reader, node: XmlNode, key: str) -> np.ndarray:
    """4x4 matrix of a ``<transform>``: each child is applied after the ones before it
    (M = T_n ... T_2 T_1). ``rotate`` turns by ``angle`` degrees counter-clockwise about
    its axis (right-hand rule); ``matrix`` is row-major (16 or 9 numbers)."""
    m = np.eye(4)
    for j, c in enumerate(node.children):
        k = f"{key}.{c.tag}[{j}]"
        t = np.eye(4)
        if c.tag == "translate":
            t[:3, 3] = rd.xyz(c, k, 0.0)
        elif c.tag == "scale":
            t[:3, :3] = np.diag(rd.xyz(c, k, 1.0))
        elif c.tag == "rotate":
            axis = rd.xyz(c, k, 0.0)
            n = float(np.linalg.norm(axis))
            if n == 0:
                raise rd.err(c, k, c.attrib, "rotation axis is zero")
            angle = math.radians(rd.numbers(c, "angle", f"{k}.angle", 1)[0])
            t[:3, :3] = _axis_angle(axis / n, angle)
        elif c.tag == "matrix":
            v = rd.numbers(c, "value", k, (9, 16))
            if len(v) == 9:
                t[:3, :3] = np.reshape(v, (3, 3))
            else:
                t = np.reshape(v, (4, 4))
                if not np.allclose(t[3], [0, 0, 0, 1]):
                    raise rd.err(c, k, c.attrib.get("value"), "a projective matrix (last "
                                 "row not 0 0 0 1) is not a placement")
        elif c.tag == "lookat":
            t = _look_at(rd, c, k)
        else:
            raise rd.err(c, k, c.tag, "unknown transform; use translate, rotate, scale, "
                         "matrix or lookat")
        m = t @ m
    if abs(np.linalg.det(m[:3, :3])) < 1e-300:
        raise rd.err(node, key, None, "the transform is singular (flattens the shape)")
    return m


def _axis_angle(u: np.ndarray, a: float) -> np.ndarray:
    """Rodrigues: rotation by ``a`` rad about unit axis ``u``."""
    k = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * (k @ k)


def _look_at(rd: _Reader, c: XmlNode, k: str) -> np.ndarray:
    """Mitsuba's look-at frame: local +z towards the target, local +y near ``up``."""
    origin = np.array(rd.numbers(c, "origin", f"{k}.origin", 3))
    target = np.array(rd.numbers(c, "target", f"{k}.target", 3))
    up = np.array(rd.numbers(c, "up", f"{k}.up", 3)) if "up" in c.attrib \
        else np.array([0.0, 1.0, 0.0])
    d = target - origin
    left = np.cross(up, d)
    if np.linalg.norm(d) == 0 or np.linalg.norm(left) == 0:
        raise rd.err(c, k, c.attrib, "origin equals target, or up is along the view")
    d = d / np.linalg.norm(d)
    left = left / np.linalg.norm(left)
    new_up = np.cross(d, left)
    t = np.eye(4)
    t[:3, 0], t[:3, 1], t[:3, 2], t[:3, 3] = left, new_up, d, origin
    return t


def inward_closed_shells(triangles: np.ndarray) -> tuple[int, int]:
    """(inward, closed): of the closed, consistently wound shells of a triangle soup, how
    many enclose a negative volume (their normals point inwards), and how many there are
    (:func:`clradcom.geometry.shells.orient_shells`, which the scene reader uses to
    re-orient them)."""
    shells = orient_shells(triangles)
    return shells.n_inward, shells.n_closed
