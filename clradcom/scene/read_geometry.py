"""The local geometry of one ``[[objects]]`` entry: vertices (V, 3), faces (F, 3) and a
label, from a mesh file (read with trimesh) or a built-in shape (box, plane, inline
triangles)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from clradcom.errors import NOVALUE, SceneError
from clradcom.scene.fields import FieldReader, is_file

__all__ = ["MESH_SUFFIXES", "SHAPES", "MeshCache", "box_geometry", "load_mesh",
           "plane_geometry", "read_object_geometry"]

#: Mesh file types accepted for ``objects[].mesh`` (read with trimesh).
MESH_SUFFIXES = (".ply", ".obj", ".stl", ".glb", ".gltf", ".off")
#: Built-in shapes for ``objects[].shape``.
SHAPES = ("box", "plane", "triangles")
#: The keys each shape needs; they apply to no other shape and not to meshes.
SHAPE_KEYS = {"box": ("extents",), "plane": ("size",), "triangles": ("vertices", "faces")}

#: Mesh files read so far for one scene: resolved path -> (vertices, faces).
MeshCache = dict[Path, tuple[np.ndarray, np.ndarray]]


def read_object_geometry(fields: FieldReader, tbl: dict, kp: str, base_dir: Path,
                         mesh_cache: MeshCache) -> tuple[np.ndarray, np.ndarray, str]:
    """(vertices, faces, label) of an object: the mesh file's path, or ``shape:<name>``."""
    has_mesh, has_shape = "mesh" in tbl, "shape" in tbl
    if has_mesh == has_shape:
        raise SceneError("give exactly one of mesh (a file) or shape (box, plane, "
                         "triangles)", file=fields.file, key=kp,
                         value={k: tbl[k] for k in ("mesh", "shape") if k in tbl}
                         if has_mesh else NOVALUE)
    shape = None
    if has_shape:
        shape = fields.get_str(tbl, "shape", kp, choices=SHAPES)
    for extra in ("extents", "size", "vertices", "faces"):
        if extra in tbl and (shape is None or extra not in SHAPE_KEYS[shape]):
            raise fields.err(f"{kp}.{extra}", tbl[extra],
                             f"only applies to shape = "
                             f"'{[s for s, n in SHAPE_KEYS.items() if extra in n][0]}'")
    if has_mesh:
        rel = fields.get_str(tbl, "mesh", kp)
        return load_mesh(fields, base_dir, rel, f"{kp}.mesh", mesh_cache)
    if shape == "box":
        ext = fields.get_vec3(tbl, "extents", kp, unit="m")
        if np.any(ext <= 0):
            raise fields.err(f"{kp}.extents", tbl["extents"], "extents must be > 0")
        return *box_geometry(ext), "shape:box"
    if shape == "plane":
        k = f"{kp}.size"
        v = fields.get(tbl, "size", kp)
        size = fields.vector(v, k, 2, "m")
        if np.any(size <= 0):
            raise fields.err(k, v, "size must be > 0")
        return *plane_geometry(size), "shape:plane"
    return *_read_inline_triangles(fields, tbl, kp), "shape:triangles"


def box_geometry(extents) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box centred on the origin: 8 vertices, 12 outward-facing triangles."""
    hx, hy, hz = extents / 2
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
    return verts, faces


def plane_geometry(size) -> tuple[np.ndarray, np.ndarray]:
    """Rectangle ``size`` = (sx, sy) in the xy plane centred on the origin, normal +z."""
    hx, hy = size / 2
    verts = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return verts, faces


def _read_inline_triangles(fields, tbl, kp) -> tuple[np.ndarray, np.ndarray]:
    """``vertices`` and ``faces`` written in the scene file."""
    kv, kf = f"{kp}.vertices", f"{kp}.faces"
    vv = fields.get(tbl, "vertices", kp)
    ff = fields.get(tbl, "faces", kp)
    if isinstance(vv, np.ndarray) or isinstance(ff, np.ndarray):
        return _inline_arrays(fields, vv, ff, kv, kf)
    if not isinstance(vv, list) or not vv:
        raise fields.err(kv, vv, "expected a non-empty array of [x, y, z] points (m)")
    verts = np.array([fields.vector(p, f"{kv}[{j}]", 3, "m") for j, p in enumerate(vv)])
    if not isinstance(ff, list) or not ff:
        raise fields.err(kf, ff, "expected a non-empty array of [i, j, k] vertex indices")
    faces = np.zeros((len(ff), 3), dtype=np.int64)
    for j, f in enumerate(ff):
        ok = (isinstance(f, list) and len(f) == 3
              and all(isinstance(x, int) and not isinstance(x, bool) for x in f))
        if not ok:
            raise fields.err(f"{kf}[{j}]", f, "expected 3 integer vertex indices")
        if any(x < 0 or x >= len(verts) for x in f):
            raise fields.err(f"{kf}[{j}]", f, f"vertex index out of range 0..{len(verts) - 1}")
        faces[j] = f
    return verts, faces


def _inline_arrays(fields, vv, ff, kv, kf) -> tuple[np.ndarray, np.ndarray]:
    """``vertices`` (V, 3) and ``faces`` (F, 3) given as numpy arrays (a scene built in
    Python, :func:`clradcom.scene.edit.add_object`), checked as a whole: the same
    refusals as the lists of a file, without a Python loop over a large mesh."""
    verts = np.asarray(vv)
    if verts.ndim != 2 or verts.shape[1] != 3 or len(verts) == 0:
        raise fields.err(kv, f"array of shape {verts.shape}",
                         "expected a non-empty array of [x, y, z] points (m)")
    if not (np.issubdtype(verts.dtype, np.floating) or np.issubdtype(verts.dtype, np.integer)):
        raise fields.err(kv, f"array of {verts.dtype}", "expected numbers (m)")
    verts = verts.astype(np.float64)
    bad = ~np.all(np.isfinite(verts), axis=1)
    if bad.any():
        j = int(np.flatnonzero(bad)[0])
        raise fields.err(f"{kv}[{j}]", verts[j].tolist(), "expected finite numbers (m)")
    faces = np.asarray(ff)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise fields.err(kf, f"array of shape {faces.shape}",
                         "expected a non-empty array of [i, j, k] vertex indices")
    if not np.issubdtype(faces.dtype, np.integer):
        raise fields.err(kf, f"array of {faces.dtype}", "expected 3 integer vertex indices")
    out = (faces < 0) | (faces >= len(verts))
    if out.any():
        j = int(np.flatnonzero(out.any(axis=1))[0])
        raise fields.err(f"{kf}[{j}]", faces[j].tolist(),
                         f"vertex index out of range 0..{len(verts) - 1}")
    return verts, faces.astype(np.int64)


def load_mesh(fields: FieldReader, base_dir: Path, rel: str, key: str,
              mesh_cache: MeshCache) -> tuple[np.ndarray, np.ndarray, str]:
    """(vertices, faces, path) of mesh file ``rel`` (relative to ``base_dir``), faces as
    stored; each file is read once per scene (``mesh_cache``)."""
    path = (base_dir / rel)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise fields.err(key, rel, f"unsupported mesh file type '{path.suffix}'; use "
                         f"{', '.join(MESH_SUFFIXES)}")
    if not is_file(path):
        raise fields.err(key, rel, f"mesh file not found (looked for {path})")
    rp = path.resolve()
    fields.note_read(path)
    if rp in mesh_cache:
        v, f = mesh_cache[rp]
        return v, f, str(path)
    import trimesh  # local import: loading trimesh is slow-ish

    try:
        text = _text_mesh_bytes(path)
    except OSError as exc:
        raise fields.err(key, rel, f"cannot read mesh file {path} ({exc})") from None
    except ValueError as exc:
        raise fields.err(key, rel, f"mesh file {path} {exc}") from None
    try:
        if text is None:
            mesh = trimesh.load(str(path), force="mesh", process=False)
        else:
            mesh = trimesh.load(io.BytesIO(text), file_type=path.suffix.lower()[1:],
                                resolver=trimesh.resolvers.FilePathResolver(str(path)),
                                force="mesh", process=False)
        verts = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces, dtype=np.int64)
    except Exception as exc:  # noqa: BLE001 - any reader failure means unreadable
        raise fields.err(key, rel, f"cannot read mesh file {path} "
                         f"({type(exc).__name__}: {_first_line(exc)})") from None
    if faces.ndim != 2 or faces.shape[0] == 0 or faces.shape[1] != 3:
        raise fields.err(key, rel, f"mesh file {path} holds no triangles")
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise fields.err(key, rel, f"mesh file {path}: its vertices are not 3-D points "
                         f"(array of shape {verts.shape})")
    if faces.min() < 0 or faces.max() >= len(verts):
        raise fields.err(key, rel, f"mesh file {path} has face indices out of range")
    bad = ~np.all(np.isfinite(verts), axis=1)
    if bad.any():
        j = int(np.flatnonzero(bad)[0])
        raise fields.err(key, rel, f"mesh file {path}: vertex {j} has NaN or inf "
                         f"coordinates {verts[j].tolist()}")
    declared = _declared_counts(path)
    if declared is not None:
        n_verts, n_faces = declared
        if len(verts) != n_verts or len(faces) < n_faces:
            raise fields.err(key, rel, f"mesh file {path} declares {n_verts} vertices and "
                             f"{n_faces} faces in its header but holds {len(verts)} "
                             f"vertices and {len(faces)} triangles (a truncated file?)")
    mesh_cache[rp] = (verts, faces)
    return verts, faces, str(path)


#: The largest mesh header read for its element counts.
_HEADER_LIMIT = 1 << 16


def _declared_counts(path: Path) -> tuple[int, int] | None:
    """(vertices, faces) that a PLY or OFF file's header declares, or None for a format
    without such a header (OBJ, STL, GLB: trimesh checks a binary file's lengths itself).
    A polygon face becomes one triangle or more, so the faces read are at least as many."""
    suffix = path.suffix.lower()
    if suffix not in (".ply", ".off"):
        return None
    with open(path, "rb") as fh:
        head = fh.read(_HEADER_LIMIT)
    if suffix == ".ply":
        end = head.find(b"end_header")
        if end < 0:
            return None  # trimesh refuses it
        counts = {}
        for line in head[:end].decode("latin-1").splitlines():
            words = line.split()
            if len(words) == 3 and words[0] == "element" and words[2].isdigit():
                counts[words[1]] = int(words[2])
        if "vertex" not in counts:
            return None
        return counts["vertex"], counts.get("face", 0)
    # OFF: the first line that is neither the keyword nor a comment holds nv nf ne
    lines = [ln.split("#")[0].strip() for ln in head.decode("latin-1").splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines or not lines[0].upper().endswith("OFF"):
        return None
    rest = lines[0][len("OFF"):].split() if lines[0].upper() != "OFF" else []
    words = rest or (lines[1].split() if len(lines) > 1 else [])
    if len(words) < 2 or not all(w.isdigit() for w in words[:2]):
        return None
    return int(words[0]), int(words[1])


def _first_line(exc: Exception, limit: int = 200) -> str:
    text = str(exc).strip().splitlines()
    line = text[0] if text else ""
    return line if len(line) <= limit else line[:limit - 3] + "..."


#: Mesh formats that are text (STL only in its ASCII form).
_TEXT_MESH_SUFFIXES = (".obj", ".off", ".stl")


def _text_mesh_bytes(path: Path) -> bytes | None:
    """The bytes to give trimesh for a text mesh file that is not UTF-8, re-encoded as
    UTF-8 from Latin-1 (every byte is a Latin-1 character; the numbers and keywords are
    ASCII either way), or None to let trimesh read the file itself. trimesh would guess
    the encoding with the optional charset_normalizer package, and fail without it.
    Raises ValueError for NUL bytes, which no text mesh holds."""
    suffix = path.suffix.lower()
    if suffix not in _TEXT_MESH_SUFFIXES:
        return None
    data = path.read_bytes()
    if suffix == ".stl" and len(data) >= 84:
        count = int.from_bytes(data[80:84], "little")
        if len(data) == 84 + 50 * count:  # binary STL: trimesh reads it as is
            return None
    nul = data.find(b"\0")
    if nul >= 0:
        raise ValueError(f"is not a text {suffix[1:].upper()} file (a NUL byte at offset "
                         f"{nul}; binary data?)")
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1").encode("utf-8")
    return None
