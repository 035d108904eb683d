"""Scene model: TOML scene files -> :class:`Scene` (plain arrays for the kernels).

A scene file has four parts (docs/scene-format.md is the full reference)::

    [scene]        name, carrier_hz
    [[materials]]  user-defined materials (the built-in ones need no entry)
    [[objects]]    a mesh file (PLY/OBJ/STL/GLB via trimesh) or a built-in shape,
                   with material, position, rotation_deg, scale, velocity
    [[radars]]     antennas: position, rides_on, orientation_deg, pattern,
                   polarization, role, tx_power_w, noise_figure_db

Every refusal is a :class:`clradcom.errors.SceneError` naming the file, the key
path (``objects[2].velocity``) and the offending value.

Transforms: object vertices are scaled, then rotated by
``R = Rz(yaw) Ry(pitch) Rx(roll)`` (``rotation_deg = [roll, pitch, yaw]``,
extrinsic x-y-z), then translated by ``position``: ``v_world = R (s * v) + p``.
A radar that ``rides_on`` an object gives ``position`` and ``orientation_deg``
in that object's frame (metres, rotated but not scaled):
``p_world = p_obj + R_obj p_local``, ``R_world = R_obj R_local``; it moves with
the object's velocity.
"""

from __future__ import annotations

import difflib
import math
import re
import tomllib
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from clradcom.errors import NOVALUE, SceneError, SceneWarning
from clradcom.geometry.triangles import triangle_double_areas
from clradcom.scene.antenna import (
    CosinePowerPattern,
    IsotropicPattern,
    Pattern,
    SectorPattern,
    euler_deg_to_matrix,
    load_pattern_file,
    polarization_jones,
)
from clradcom.scene.materials import (
    ROUGHNESS_MODELS,
    Material,
    builtin_material,
    builtin_material_names,
    conductivity_to_eps_imag,
    itu_conductivity,
    itu_permittivity,
    with_overrides,
    xpd_db_to_cross_pol_share,
)
from clradcom.scene.records import OPTICS, ROLES, Radar, Scene, SceneObject

__all__ = ["load_scene", "scene_from_dict", "SHAPES", "MESH_SUFFIXES"]

#: Mesh file types accepted for ``objects[].mesh`` (read with trimesh).
MESH_SUFFIXES = (".ply", ".obj", ".stl", ".glb", ".gltf", ".off")
#: Built-in shapes for ``objects[].shape``.
SHAPES = ("box", "plane", "triangles")
PATTERN_TYPES = ("isotropic", "sector", "cosine", "file")

_TOP_KEYS = ("scene", "materials", "objects", "radars")
_SCENE_KEYS = ("name", "carrier_hz", "description")
_MATERIAL_KEYS = ("name", "base", "itu", "eps_r", "conductivity_s_m", "pec", "roughness_m",
                  "roughness_model", "scattering_coefficient", "cross_pol_share", "xpd_db",
                  "allow_extrapolation", "description")
_OBJECT_KEYS = ("name", "material", "mesh", "shape", "extents", "size", "vertices", "faces",
                "position", "rotation_deg", "scale", "velocity", "drop_degenerate",
                "optics", "description")
_RADAR_KEYS = ("name", "position", "rides_on", "orientation_deg", "velocity", "pattern",
               "polarization", "role", "tx_power_w", "noise_figure_db", "description")
_PATTERN_KEYS = {
    "isotropic": ("type",),
    "sector": ("type", "azimuth_width_deg", "elevation_width_deg"),
    "cosine": ("type", "q", "half_power_beamwidth_deg"),
    "file": ("type", "path", "normalize"),
}

#: Relative area threshold for "degenerate": 2*area <= _DEGENERATE_REL * longest_edge^2.
_DEGENERATE_REL = 1e-10

_REQUIRED = object()


# ---------------------------------------------------------------------------
# loading


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
    return _Builder(data, Path(file) if not isinstance(file, Path) else file,
                    Path(base_dir)).build()


class _Builder:
    def __init__(self, data: dict, file: Path, base_dir: Path):
        self.data = data
        self.file = file
        self.base_dir = base_dir
        self._mesh_cache: dict[Path, tuple[np.ndarray, np.ndarray]] = {}

    # -- error and value helpers ----------------------------------------------
    def err(self, key, value, reason) -> SceneError:
        return SceneError(reason, file=self.file, key=key, value=value)

    def check_keys(self, tbl: dict, allowed, kp: str) -> None:
        for k in tbl:
            if k not in allowed:
                close = difflib.get_close_matches(k, allowed, n=1)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                where = f"{kp}.{k}" if kp else k
                raise self.err(where, tbl[k], f"unknown key '{k}'{hint}; allowed keys: "
                               f"{', '.join(allowed)}")

    def kp(self, base: str, key: str) -> str:
        return f"{base}.{key}" if base else key

    def get(self, tbl, key, kp, default=_REQUIRED):
        if key in tbl:
            return tbl[key]
        if default is _REQUIRED:
            raise SceneError("missing required key", file=self.file, key=self.kp(kp, key))
        return default

    def get_str(self, tbl, key, kp, default=_REQUIRED, choices=None):
        v = self.get(tbl, key, kp, default)
        if v is default and key not in tbl:
            return v
        if not isinstance(v, str):
            raise self.err(self.kp(kp, key), v, "expected a string")
        if choices is not None and v not in choices:
            raise self.err(self.kp(kp, key), v, f"must be one of {', '.join(choices)}")
        return v

    def get_bool(self, tbl, key, kp, default=_REQUIRED):
        v = self.get(tbl, key, kp, default)
        if key in tbl and not isinstance(v, bool):
            raise self.err(self.kp(kp, key), v, "expected true or false")
        return v

    def number(self, v, key, what="a number"):
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self.err(key, v, f"expected {what}")
        x = float(v)
        if not math.isfinite(x):
            raise self.err(key, v, "NaN or inf is not allowed")
        return x

    def get_float(self, tbl, key, kp, default=_REQUIRED, *, lo=None, lo_open=False, hi=None,
                  unit=""):
        if key not in tbl:
            return self.get(tbl, key, kp, default)
        k = self.kp(kp, key)
        x = self.number(tbl[key], k, f"a number{(' (' + unit + ')') if unit else ''}")
        if lo is not None and (x <= lo if lo_open else x < lo):
            raise self.err(k, tbl[key], f"must be {'>' if lo_open else '>='} {lo:g}")
        if hi is not None and x > hi:
            raise self.err(k, tbl[key], f"must be <= {hi:g}")
        return x

    def vector(self, v, key, n, unit=""):
        what = f"an array of {n} numbers" + (f" ({unit})" if unit else "")
        if not isinstance(v, list) or len(v) != n:
            raise self.err(key, v, f"expected {what}")
        for x in v:
            if isinstance(x, bool) or not isinstance(x, int | float):
                raise self.err(key, v, f"expected {what}")
        a = np.array(v, dtype=np.float64)
        if not np.all(np.isfinite(a)):
            raise self.err(key, v, "NaN or inf is not allowed")
        return a

    def get_vec3(self, tbl, key, kp, default=_REQUIRED, unit=""):
        if key not in tbl:
            d = self.get(tbl, key, kp, default)
            return np.array(d, dtype=np.float64)
        return self.vector(tbl[key], self.kp(kp, key), 3, unit)

    def array_of_tables(self, key) -> list:
        v = self.data.get(key, [])
        if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
            raise self.err(key, v, f"expected an array of tables, written [[{key}]]")
        return v

    def unique_name(self, tbl, kp, seen: dict, what: str) -> str:
        name = self.get_str(tbl, "name", kp)
        if not name:
            raise self.err(self.kp(kp, "name"), name, "must not be empty")
        if name in seen:
            raise self.err(self.kp(kp, "name"), name,
                           f"duplicate {what} name (already used by {seen[name]})")
        seen[name] = kp
        return name

    # -- build -------------------------------------------------------------------
    def build(self) -> Scene:
        if not isinstance(self.data, dict):
            raise self.err(None, self.data, "scene document must be a table")
        self.check_keys(self.data, _TOP_KEYS, "")
        sc = self.data.get("scene", _REQUIRED)
        if sc is _REQUIRED:
            raise SceneError("missing required table [scene]", file=self.file, key="scene")
        if not isinstance(sc, dict):
            raise self.err("scene", sc, "expected a table, written [scene]")
        self.check_keys(sc, _SCENE_KEYS, "scene")
        name = self.get_str(sc, "name", "scene", default=self.file.stem)
        description = self.get_str(sc, "description", "scene", default="")
        carrier = self.get_float(sc, "carrier_hz", "scene", lo=0.0, lo_open=True, unit="Hz")
        self.carrier = carrier

        materials, mat_index = self.build_materials()
        objects_raw = self.array_of_tables("objects")
        objects: list[SceneObject] = []
        tris: list[np.ndarray] = []
        seen: dict = {}
        start = 0
        for i, tbl in enumerate(objects_raw):
            obj, t = self.build_object(i, tbl, seen, materials, mat_index, start)
            objects.append(obj)
            tris.append(t)
            start += t.shape[0]
        triangles = (np.concatenate(tris, axis=0) if tris else np.zeros((0, 3, 3)))
        tri_object = np.concatenate(
            [np.full(o.n_triangles, i, dtype=np.int32) for i, o in enumerate(objects)]
        ) if objects else np.zeros(0, dtype=np.int32)
        tri_material = np.concatenate(
            [np.full(o.n_triangles, o.material, dtype=np.int32) for o in objects]
        ) if objects else np.zeros(0, dtype=np.int32)
        object_velocity = np.array([o.velocity for o in objects],
                                   dtype=np.float64).reshape(-1, 3)

        radars = self.build_radars(objects)
        return Scene(
            name=name, carrier_hz=carrier,
            source=self.file if isinstance(self.file, Path) and self.file.exists() else None,
            materials=materials, objects=objects, radars=radars,
            triangles=np.ascontiguousarray(triangles, dtype=np.float64),
            tri_object=tri_object.astype(np.int32), tri_material=tri_material.astype(np.int32),
            object_velocity=object_velocity, description=description,
        )

    # -- materials ------------------------------------------------------------------
    def build_materials(self):
        materials: list[Material] = []
        index: dict[str, int] = {}
        seen: dict = {}
        builtins = set(builtin_material_names())
        for i, tbl in enumerate(self.array_of_tables("materials")):
            kp = f"materials[{i}]"
            self.check_keys(tbl, _MATERIAL_KEYS, kp)
            name = self.unique_name(tbl, kp, seen, "material")
            if name in builtins:
                raise self.err(f"{kp}.name", name,
                               "this name belongs to a built-in material; pick another name "
                               f"and write base = '{name}' to start from it")
            index[name] = len(materials)
            materials.append(self.build_material(tbl, kp, name, materials, index))
        self._user_names = list(index)
        return materials, index

    def build_material(self, tbl, kp, name, materials, index) -> Material:
        sources = [k for k in ("base", "itu", "eps_r") if k in tbl]
        pec = self.get_bool(tbl, "pec", kp, default=False)
        if pec:
            sources.append("pec")
        if len(sources) != 1:
            value = {k: tbl[k] for k in ("base", "itu", "eps_r", "pec") if k in tbl}
            raise self.err(kp, value if value else NOVALUE,
                           "give exactly one of base, itu, eps_r or pec = true"
                           + (f" (got {', '.join(sources)})" if sources else ""))
        src = sources[0]
        if "allow_extrapolation" in tbl and src != "itu":
            raise self.err(f"{kp}.allow_extrapolation", tbl["allow_extrapolation"],
                           "only applies together with itu")
        if "conductivity_s_m" in tbl and src != "eps_r":
            raise self.err(f"{kp}.conductivity_s_m", tbl["conductivity_s_m"],
                           "only applies together with eps_r")
        if src == "base":
            base_name = self.get_str(tbl, "base", kp)
            if base_name in index:
                base = materials[index[base_name]]
            else:
                try:
                    base = builtin_material(base_name, self.carrier, file=self.file,
                                            key=f"{kp}.base")
                except KeyError:
                    raise self.unknown_material(f"{kp}.base", base_name) from None
            mat = with_overrides(base, name=name, source=f"user (base {base_name})")
        elif src == "itu":
            itu = self.get_str(tbl, "itu", kp)
            extrapolate = self.get_bool(tbl, "allow_extrapolation", kp, default=False)
            k = f"{kp}.itu"
            eps = itu_permittivity(itu, self.carrier, extrapolate=extrapolate, file=self.file,
                                   key=k)
            with warnings.catch_warnings():  # already warned (or refused) just above
                warnings.simplefilter("ignore", SceneWarning)
                sigma = itu_conductivity(itu, self.carrier, extrapolate=True)
            mat = Material(name, eps, conductivity_s_m=sigma, source=f"user (itu {itu})")
        elif src == "pec":
            mat = Material(name, complex(math.inf, 0.0), pec=True)
        else:
            mat = self.parse_eps(tbl, kp, name)
        changes: dict[str, Any] = {}
        if "roughness_m" in tbl:
            changes["roughness_m"] = self.get_float(tbl, "roughness_m", kp, lo=0.0, unit="m")
        if "roughness_model" in tbl:
            changes["roughness_model"] = self.get_str(tbl, "roughness_model", kp,
                                                      choices=ROUGHNESS_MODELS)
        if "scattering_coefficient" in tbl:
            changes["scattering_coefficient"] = self.get_float(
                tbl, "scattering_coefficient", kp, lo=0.0, hi=1.0)
        if "cross_pol_share" in tbl and "xpd_db" in tbl:
            raise self.err(f"{kp}.xpd_db", tbl["xpd_db"],
                           "give cross_pol_share or xpd_db, not both")
        if "cross_pol_share" in tbl:
            changes["cross_pol_share"] = self.get_float(tbl, "cross_pol_share", kp,
                                                        lo=0.0, hi=1.0)
        if "xpd_db" in tbl:
            changes["cross_pol_share"] = xpd_db_to_cross_pol_share(
                self.get_float(tbl, "xpd_db", kp, unit="dB"))
        return with_overrides(mat, **changes) if changes else mat

    def parse_eps(self, tbl, kp, name) -> Material:
        k = f"{kp}.eps_r"
        v = tbl["eps_r"]
        if isinstance(v, list):
            re_, im = self.vector(v, k, 2)
        else:
            re_, im = self.number(v, k, "a number or [real, imag]"), 0.0
        if im > 0:
            raise self.err(k, v, "positive imaginary part: clradcom uses the e^{+j omega t} "
                           "convention, so a lossy permittivity is eps' - j eps'' and its "
                           f"imaginary part must be <= 0 (write [{re_:g}, {-im:g}])")
        if re_ <= 0:
            raise self.err(k, v, "real part must be > 0 (for a metal use pec = true)")
        sigma = math.nan
        if "conductivity_s_m" in tbl:
            sigma = self.get_float(tbl, "conductivity_s_m", kp, lo=0.0, unit="S/m")
            im -= conductivity_to_eps_imag(sigma, self.carrier)
        return Material(name, complex(re_, im), conductivity_s_m=sigma)

    def unknown_material(self, key, name) -> SceneError:
        known = self._user_names + builtin_material_names() if hasattr(self, "_user_names") \
            else builtin_material_names()
        close = difflib.get_close_matches(name, known, n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        return self.err(key, name, f"unknown material{hint}; define it under [[materials]] or "
                        f"use a built-in: {', '.join(builtin_material_names())}")

    def material_for(self, name, key, materials, index) -> int:
        if name in index:
            return index[name]
        try:
            mat = builtin_material(name, self.carrier, file=self.file, key=key)
        except KeyError:
            raise self.unknown_material(key, name) from None
        index[name] = len(materials)
        materials.append(mat)
        return index[name]

    # -- objects ------------------------------------------------------------------------
    def build_object(self, i, tbl, seen, materials, mat_index, start):
        kp = f"objects[{i}]"
        self.check_keys(tbl, _OBJECT_KEYS, kp)
        name = self.unique_name(tbl, kp, seen, "object")
        mat_name = self.get_str(tbl, "material", kp)
        mat = self.material_for(mat_name, f"{kp}.material", materials, mat_index)
        position = self.get_vec3(tbl, "position", kp, default=(0.0, 0.0, 0.0), unit="m")
        rot_deg = self.get_vec3(tbl, "rotation_deg", kp, default=(0.0, 0.0, 0.0), unit="deg")
        velocity = self.get_vec3(tbl, "velocity", kp, default=(0.0, 0.0, 0.0), unit="m/s")
        scale = np.ones(3)
        if "scale" in tbl:
            v = tbl["scale"]
            k = f"{kp}.scale"
            if isinstance(v, list):
                scale = self.vector(v, k, 3)
            else:
                scale = np.full(3, self.number(v, k, "a number or an array of 3 numbers"))
            if np.any(scale <= 0):
                raise self.err(k, v, "scale must be > 0 (mirroring is not supported)")
        drop = self.get_bool(tbl, "drop_degenerate", kp, default=False)
        optics = self.get_str(tbl, "optics", kp, default=None, choices=OPTICS)

        verts, faces, label = self.object_geometry(tbl, kp)
        rotation = euler_deg_to_matrix(rot_deg)
        world = (verts * scale) @ rotation.T + position
        tri = world[faces]  # (F,3,3)
        tri = self.check_degenerate(tri, kp, label, drop, tbl.get("mesh"))
        obj = SceneObject(
            name=name, mesh=label, material=mat, material_name=mat_name, position=position,
            rotation_deg=rot_deg, rotation=rotation, scale=scale, velocity=velocity,
            tri_start=start, tri_stop=start + tri.shape[0], optics=optics,
        )
        return obj, tri

    def object_geometry(self, tbl, kp):
        has_mesh, has_shape = "mesh" in tbl, "shape" in tbl
        if has_mesh == has_shape:
            raise SceneError("give exactly one of mesh (a file) or shape (box, plane, "
                             "triangles)", file=self.file, key=kp,
                             value={k: tbl[k] for k in ("mesh", "shape") if k in tbl}
                             if has_mesh else NOVALUE)
        shape = None
        if has_shape:
            shape = self.get_str(tbl, "shape", kp, choices=SHAPES)
        needs = {"box": ("extents",), "plane": ("size",), "triangles": ("vertices", "faces")}
        for extra in ("extents", "size", "vertices", "faces"):
            if extra in tbl and (shape is None or extra not in needs[shape]):
                raise self.err(f"{kp}.{extra}", tbl[extra],
                               f"only applies to shape = "
                               f"'{[s for s, n in needs.items() if extra in n][0]}'")
        if has_mesh:
            rel = self.get_str(tbl, "mesh", kp)
            verts, faces, label = self.load_mesh(rel, f"{kp}.mesh")
            return verts, faces, label
        if shape == "box":
            ext = self.get_vec3(tbl, "extents", kp, unit="m")
            if np.any(ext <= 0):
                raise self.err(f"{kp}.extents", tbl["extents"], "extents must be > 0")
            hx, hy, hz = ext / 2
            verts = np.array([[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1)
                              for sz in (-1, 1)])
            # vertex index = 4*(x>0) + 2*(y>0) + (z>0); outward-facing, counter-clockwise
            faces = np.array([
                [0, 1, 3], [0, 3, 2],  # -x
                [4, 6, 7], [4, 7, 5],  # +x
                [0, 4, 5], [0, 5, 1],  # -y
                [2, 3, 7], [2, 7, 6],  # +y
                [0, 2, 6], [0, 6, 4],  # -z
                [1, 5, 7], [1, 7, 3],  # +z
            ])
            return verts, faces, "shape:box"
        if shape == "plane":
            k = f"{kp}.size"
            v = self.get(tbl, "size", kp)
            sz = self.vector(v, k, 2, "m")
            if np.any(sz <= 0):
                raise self.err(k, v, "size must be > 0")
            hx, hy = sz / 2
            verts = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]])
            faces = np.array([[0, 1, 2], [0, 2, 3]])
            return verts, faces, "shape:plane"
        # inline triangles
        kv, kf = f"{kp}.vertices", f"{kp}.faces"
        vv = self.get(tbl, "vertices", kp)
        ff = self.get(tbl, "faces", kp)
        if not isinstance(vv, list) or not vv:
            raise self.err(kv, vv, "expected a non-empty array of [x, y, z] points (m)")
        verts = np.array([self.vector(p, f"{kv}[{j}]", 3, "m") for j, p in enumerate(vv)])
        if not isinstance(ff, list) or not ff:
            raise self.err(kf, ff, "expected a non-empty array of [i, j, k] vertex indices")
        faces = np.zeros((len(ff), 3), dtype=np.int64)
        for j, f in enumerate(ff):
            ok = (isinstance(f, list) and len(f) == 3
                  and all(isinstance(x, int) and not isinstance(x, bool) for x in f))
            if not ok:
                raise self.err(f"{kf}[{j}]", f, "expected 3 integer vertex indices")
            if any(x < 0 or x >= len(verts) for x in f):
                raise self.err(f"{kf}[{j}]", f, f"vertex index out of range 0..{len(verts) - 1}")
            faces[j] = f
        return verts, faces, "shape:triangles"

    def load_mesh(self, rel: str, key: str):
        path = (self.base_dir / rel)
        if path.suffix.lower() not in MESH_SUFFIXES:
            raise self.err(key, rel, f"unsupported mesh file type '{path.suffix}'; use "
                           f"{', '.join(MESH_SUFFIXES)}")
        if not path.is_file():
            raise self.err(key, rel, f"mesh file not found (looked for {path})")
        rp = path.resolve()
        if rp in self._mesh_cache:
            v, f = self._mesh_cache[rp]
            return v, f, str(path)
        import trimesh  # local import: loading trimesh is slow-ish

        try:
            mesh = trimesh.load(str(path), force="mesh", process=False)
            verts = np.asarray(mesh.vertices, dtype=np.float64)
            faces = np.asarray(mesh.faces, dtype=np.int64)
        except Exception as exc:  # noqa: BLE001 - any reader failure means unreadable
            raise self.err(key, rel, f"cannot read mesh file {path} "
                           f"({type(exc).__name__}: {exc})") from None
        if faces.ndim != 2 or faces.shape[0] == 0 or faces.shape[1] != 3:
            raise self.err(key, rel, f"mesh file {path} holds no triangles")
        if faces.min() < 0 or faces.max() >= len(verts):
            raise self.err(key, rel, f"mesh file {path} has face indices out of range")
        bad = ~np.all(np.isfinite(verts), axis=1)
        if bad.any():
            j = int(np.flatnonzero(bad)[0])
            raise self.err(key, rel, f"mesh file {path}: vertex {j} has NaN or inf "
                           f"coordinates {verts[j].tolist()}")
        self._mesh_cache[rp] = (verts, faces)
        return verts, faces, str(path)

    def check_degenerate(self, tri, kp, label, drop, written=None):
        e1 = tri[:, 1] - tri[:, 0]
        e2 = tri[:, 2] - tri[:, 0]
        e3 = tri[:, 2] - tri[:, 1]
        cross = triangle_double_areas(tri)  # 2 * area
        longest = np.max(np.stack([np.einsum("ij,ij->i", e, e) for e in (e1, e2, e3)]), axis=0)
        bad = cross <= _DEGENERATE_REL * longest
        if not bad.any():
            return tri
        idx = np.flatnonzero(bad)
        what = label if not label.startswith("shape:") else f"{kp} ({label})"
        if not drop:
            j = int(idx[0])
            key = f"{kp}.mesh" if not label.startswith("shape:") else f"{kp}.faces"
            value = written if not label.startswith("shape:") else j
            raise self.err(key, value,
                           f"triangle {j} of {what} is degenerate (zero area; vertices "
                           f"{np.round(tri[j], 9).tolist()}); {len(idx)} such triangle(s) in "
                           "all; fix the mesh or set drop_degenerate = true")
        warnings.warn(f"{self.file}: {kp}: dropped {len(idx)} degenerate (zero-area) "
                      f"triangle(s) of {what}, first indices {idx[:10].tolist()}",
                      SceneWarning, stacklevel=2)
        return tri[~bad]

    # -- radars ---------------------------------------------------------------------------
    def build_radars(self, objects: list[SceneObject]) -> list[Radar]:
        radars = []
        seen: dict = {}
        names = [o.name for o in objects]
        for i, tbl in enumerate(self.array_of_tables("radars")):
            kp = f"radars[{i}]"
            self.check_keys(tbl, _RADAR_KEYS, kp)
            name = self.unique_name(tbl, kp, seen, "radar")
            pos_local = self.get_vec3(tbl, "position", kp, unit="m")
            ori_deg = self.get_vec3(tbl, "orientation_deg", kp, default=(0.0, 0.0, 0.0),
                                    unit="deg")
            r_local = euler_deg_to_matrix(ori_deg)
            rides = -1
            if "rides_on" in tbl:
                obj_name = self.get_str(tbl, "rides_on", kp)
                if obj_name not in names:
                    close = difflib.get_close_matches(obj_name, names, n=1)
                    hint = f" (did you mean '{close[0]}'?)" if close else ""
                    raise self.err(f"{kp}.rides_on", obj_name,
                                   f"no object with this name{hint}; objects: "
                                   f"{', '.join(names) if names else '(none)'}")
                if "velocity" in tbl:
                    raise self.err(f"{kp}.velocity", tbl["velocity"],
                                   "a radar that rides_on an object moves with it; remove "
                                   "velocity (set it on the object)")
                rides = names.index(obj_name)
                obj = objects[rides]
                position = obj.position + obj.rotation @ pos_local
                orientation = obj.rotation @ r_local
                velocity = obj.velocity.copy()
            else:
                position = pos_local
                orientation = r_local
                velocity = self.get_vec3(tbl, "velocity", kp, default=(0.0, 0.0, 0.0),
                                         unit="m/s")
            role = self.get_str(tbl, "role", kp, default="txrx", choices=ROLES)
            power = self.get_float(tbl, "tx_power_w", kp, default=1.0, lo=0.0, unit="W")
            nf = self.get_float(tbl, "noise_figure_db", kp, default=None, unit="dB")
            pattern, pol, pol_name = self.build_pattern(tbl, kp)
            radars.append(Radar(
                name=name, position=np.asarray(position, dtype=np.float64), rides_on=rides,
                orientation=orientation, pattern=pattern, polarization=pol,
                polarization_name=pol_name, velocity=velocity, role=role, tx_power_w=power,
                noise_figure_db=nf, position_local=pos_local, orientation_deg=ori_deg,
            ))
        return radars

    def parse_polarization(self, tbl, kp):
        if "polarization" not in tbl:
            return None, None
        k = f"{kp}.polarization"
        v = tbl["polarization"]
        if isinstance(v, str):
            try:
                return polarization_jones(v), v.upper()
            except ValueError as exc:
                raise self.err(k, v, str(exc)) from None
        if isinstance(v, list) and len(v) == 2:
            comps = []
            for c in v:
                if isinstance(c, list):
                    re_, im = self.vector(c, k, 2)
                    comps.append(complex(re_, im))
                else:
                    comps.append(complex(self.number(c, k, "a Jones vector [C_theta, C_phi]")))
            try:
                return polarization_jones(comps), "jones"
            except ValueError as exc:
                raise self.err(k, v, str(exc)) from None
        raise self.err(k, v, "expected 'V', 'H', 'RHCP', 'LHCP' or a Jones vector "
                       "[C_theta, C_phi] (each a number or [real, imag])")

    def build_pattern(self, tbl, kp):
        k = f"{kp}.pattern"
        spec = tbl.get("pattern", "isotropic")
        if isinstance(spec, str):
            if spec not in PATTERN_TYPES:
                raise self.err(k, spec, f"unknown pattern; use one of {', '.join(PATTERN_TYPES)}")
            if spec == "file":
                raise self.err(k, spec, "a file pattern needs a table: "
                               "pattern = { type = 'file', path = '...' }")
            spec = {"type": spec}
        elif not isinstance(spec, dict):
            raise self.err(k, spec, "expected a pattern name or a table with a 'type' key")
        ptype = self.get_str(spec, "type", k, choices=PATTERN_TYPES)
        self.check_keys(spec, _PATTERN_KEYS[ptype], k)
        pol, pol_name = self.parse_polarization(tbl, kp)
        jones = pol if pol is not None else polarization_jones("V")
        if ptype == "isotropic":
            pattern: Pattern = IsotropicPattern(polarization=jones)
        elif ptype == "sector":
            az = self.get_float(spec, "azimuth_width_deg", k, default=90.0, lo=0.0,
                                lo_open=True, hi=360.0, unit="deg")
            el = self.get_float(spec, "elevation_width_deg", k, default=180.0, lo=0.0,
                                lo_open=True, hi=180.0, unit="deg")
            pattern = SectorPattern(polarization=jones, azimuth_width_deg=az,
                                    elevation_width_deg=el)
        elif ptype == "cosine":
            if ("q" in spec) == ("half_power_beamwidth_deg" in spec):
                raise self.err(k, spec, "give exactly one of q or half_power_beamwidth_deg")
            if "q" in spec:
                q = self.get_float(spec, "q", k, lo=0.0)
            else:
                hp = self.get_float(spec, "half_power_beamwidth_deg", k, lo=0.0, lo_open=True,
                                    unit="deg")
                if hp >= 180.0:
                    raise self.err(f"{k}.half_power_beamwidth_deg",
                                   spec["half_power_beamwidth_deg"], "must be < 180")
                q = CosinePowerPattern.q_from_beamwidth(hp)
            pattern = CosinePowerPattern(polarization=jones, q=q)
        else:
            rel = self.get_str(spec, "path", k)
            normalize = self.get_bool(spec, "normalize", k, default=True)
            path = self.base_dir / rel
            if not path.is_file():
                raise self.err(f"{k}.path", rel, f"pattern file not found (looked for {path})")
            try:
                pattern = load_pattern_file(path, polarization=pol, normalize=normalize)
            except SceneError as exc:
                raise self.err(f"{k}.path", rel, f"bad pattern file: {exc}") from None
            if pattern.complex_field:
                c = pattern.field(np.array([[1.0, 0.0, 0.0]]))[0]
                nrm = np.linalg.norm(c)
                jones = c / nrm if nrm > 0 else polarization_jones("V")
                pol_name = "file"
        return pattern, np.asarray(jones, dtype=np.complex128), pol_name or "V"
