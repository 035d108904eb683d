"""Building footprints from GeoJSON (what OpenStreetMap exports give), extruded into
closed, outward-facing meshes with shapely and trimesh.

A scene file names the GeoJSON file in an ``[[objects]]`` entry (docs/scene-format.md,
"Buildings from GeoJSON")::

    [[objects]]
    name = "buildings"
    geojson = "buildings.geojson"
    material = "itu_concrete"        # for features without a "material" property
    origin_lonlat = [11.5755, 48.1374]

Every Polygon or MultiPolygon feature is one building: its footprint (holes kept) is
extruded from ``min_height`` (or ``building:min_level`` levels; default 0) up to
``height`` (metres; a number or a string such as ``"12"`` or ``"12.5 m"``), or to
``building:levels`` times ``level_height_m``, or to the entry's ``height_m``.

Coordinates are longitude/latitude in degrees on WGS 84 (RFC 7946, the default,
``coordinates = "lonlat"``) or already projected metres (``coordinates = "metres"``).
Longitude/latitude become local east/north metres on the tangent plane at
``origin_lonlat`` (:func:`lonlat_to_local`). A file that names its coordinate reference
system in a ``"crs"`` member (the 2008 GeoJSON form, which RFC 7946 dropped but QGIS and
GDAL still write) is read in it: a projected CRS such as EPSG:3857 is reprojected to
WGS 84 longitude/latitude with pyproj (then to the tangent plane, so ``origin_lonlat`` is
needed as for any longitude/latitude); a CRS that pyproj does not know, or one given
beside ``coordinates = "metres"``, is refused by name.
"""

from __future__ import annotations

import json
import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clradcom.errors import NOVALUE, SceneWarning
from clradcom.scene.fields import FieldReader, is_file
from clradcom.scene.records import OPTICS

__all__ = ["COORDINATES", "DEFAULT_LEVEL_HEIGHT_M", "GEOJSON_KEYS", "MAX_FOOTPRINT_M",
           "WGS84_A", "WGS84_F",
           "Building", "extrude_footprint", "lonlat_to_local", "read_geojson_buildings"]

#: Keys of an ``[[objects]]`` entry that names a GeoJSON file.
GEOJSON_KEYS = ("name", "geojson", "material", "coordinates", "origin_lonlat",
                "level_height_m", "height_m", "position", "velocity", "optics",
                "description")
#: ``coordinates``: longitude/latitude in degrees (RFC 7946), or projected metres.
COORDINATES = ("lonlat", "metres")
#: Storey height (m) that turns ``building:levels`` into a height, unless the entry says.
DEFAULT_LEVEL_HEIGHT_M = 3.0
#: Largest footprint coordinate or height (m) read: no projected coordinate on Earth is
#: larger (Web Mercator's reach ~2e7 m), and trimesh's extrusion fails beyond ~1e10 m.
MAX_FOOTPRINT_M = 1e8
#: Corners of one footprint from which its loading is announced: extruding and
#: triangulating it, and the trace over its ~4 triangles per corner, take minutes
#: (1e5 corners: 9 s to load at load 7; 1e6: 381 s to load at load 9)
LARGE_FOOTPRINT_CORNERS = 100_000
#: WGS 84 ellipsoid: semi-major axis (m) and flattening.
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563

_HEIGHT_RE = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(m)?\s*$")


@dataclass(eq=False)
class Building:
    """One extruded footprint: local vertices (V, 3) in metres (x east, y north, z up),
    outward-facing faces (F, 3), and where it came from."""

    index: int  #: the feature's position in the file
    label: str  #: the feature's ``id`` when it has one, else its index
    file: str
    material: str | None  #: the feature's ``material`` property, if any
    vertices: np.ndarray
    faces: np.ndarray
    optics: str | None = None  #: the feature's ``optics`` property, if any


def lonlat_to_local(lon_deg, lat_deg, origin_lonlat) -> tuple[np.ndarray, np.ndarray]:
    """East and north metres of points (lon, lat) in degrees on the WGS 84 ellipsoid
    (height 0), on the local tangent plane at ``origin_lonlat``: the east and north
    components of the exact ECEF -> ENU rotation of the point's offset from the origin.
    The up component (the Earth's curvature, about d^2 / (2 R): 8 cm at 1 km) is dropped,
    so every footprint stands on z = 0."""
    lon0, lat0 = (math.radians(float(v)) for v in origin_lonlat)
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    e2 = WGS84_F * (2.0 - WGS84_F)

    def ecef(lo, la):
        n = WGS84_A / np.sqrt(1.0 - e2 * np.sin(la) ** 2)
        return (n * np.cos(la) * np.cos(lo), n * np.cos(la) * np.sin(lo),
                n * (1.0 - e2) * np.sin(la))

    x, y, z = ecef(lon, lat)
    x0, y0, z0 = ecef(lon0, lat0)
    dx, dy, dz = x - x0, y - y0, z - z0
    east = -math.sin(lon0) * dx + math.cos(lon0) * dy
    north = (-math.sin(lat0) * math.cos(lon0) * dx - math.sin(lat0) * math.sin(lon0) * dy
             + math.cos(lat0) * dz)
    return east, north


def extrude_footprint(polygon, bottom: float, top: float) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a shapely Polygon or MultiPolygon (metres) extruded from
    z = ``bottom`` to z = ``top``: closed, faces wound counter-clockwise seen from outside
    (``trimesh.creation.extrude_polygon`` on each part, holes kept)."""
    import shapely
    import trimesh

    parts = list(polygon.geoms) if polygon.geom_type == "MultiPolygon" else [polygon]
    verts, faces, offset = [], [], 0
    for part in parts:
        part = shapely.geometry.polygon.orient(part, 1.0)
        mesh = trimesh.creation.extrude_polygon(part, top - bottom)
        with np.errstate(divide="ignore", invalid="ignore"):  # a footprint of ~zero
            volume = mesh.volume  # area: trimesh's centre of mass divides by it
        if volume < 0:  # defensive: the extrusion is outward by construction
            mesh.invert()
        v = np.asarray(mesh.vertices, dtype=np.float64).copy()
        v[:, 2] += bottom
        verts.append(v)
        faces.append(np.asarray(mesh.faces, dtype=np.int64) + offset)
        offset += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def read_geojson_buildings(fields: FieldReader, tbl: dict, kp: str,
                           base_dir: Path) -> list[Building]:
    """The buildings of the GeoJSON file an ``[[objects]]`` entry names, in file order.
    Refusals name the scene file, the entry's key and the feature."""
    import shapely

    rel = fields.get_str(tbl, "geojson", kp)
    key = f"{kp}.geojson"
    path = base_dir / rel
    if not is_file(path):
        raise fields.err(key, rel, f"GeoJSON file not found (looked for {path})")
    fields.note_read(path)
    coords = fields.get_str(tbl, "coordinates", kp, default="lonlat", choices=COORDINATES)
    level_h = fields.get_float(tbl, "level_height_m", kp, default=DEFAULT_LEVEL_HEIGHT_M,
                               lo=0.0, lo_open=True, unit="m")
    default_h = fields.get_float(tbl, "height_m", kp, default=None, lo=0.0, lo_open=True,
                                 unit="m")
    origin = None
    if coords == "lonlat":
        if "origin_lonlat" not in tbl:
            raise fields.err(f"{kp}.origin_lonlat", NOVALUE,
                             "required with coordinates = 'lonlat': the [longitude, "
                             "latitude] (deg) that becomes x = y = 0 (radar positions are "
                             "given in that frame)")
        origin = fields.vector(tbl["origin_lonlat"], f"{kp}.origin_lonlat", 2, "deg")
        if abs(origin[0]) > 180 or abs(origin[1]) > 90:
            raise fields.err(f"{kp}.origin_lonlat", tbl["origin_lonlat"],
                             "longitude must be in [-180, 180], latitude in [-90, 90]")
    elif "origin_lonlat" in tbl:
        raise fields.err(f"{kp}.origin_lonlat", tbl["origin_lonlat"],
                         "only applies with coordinates = 'lonlat'")
    features, crs = _features(fields, path, key, rel)
    to_lonlat = _crs_to_lonlat(fields, key, rel, path, crs, coords)
    out: list[Building] = []
    skipped = []
    for i, feat in enumerate(features):
        where = f"feature {i}"
        geom = feat.get("geometry")
        gtype = geom.get("type") if isinstance(geom, dict) else None
        if gtype not in ("Polygon", "MultiPolygon"):
            skipped.append(i)
            continue
        props = feat.get("properties") or {}
        if not isinstance(props, dict):
            raise fields.err(key, rel, f"{where} of {path}: 'properties' is not an object")
        try:
            poly = shapely.geometry.shape(geom)
        except Exception as exc:  # noqa: BLE001 - any shapely refusal is a bad geometry
            raise fields.err(key, rel, f"{where} of {path}: unreadable {gtype} "
                             f"({type(exc).__name__}: {exc})") from None
        if poly.is_empty:
            raise fields.err(key, rel, f"{where} of {path}: empty {gtype}")
        if to_lonlat is not None:
            poly = shapely.transform(poly, lambda p: np.column_stack(
                to_lonlat.transform(p[:, 0], p[:, 1])))
        if origin is not None:
            xy = shapely.get_coordinates(poly)
            if np.any(np.abs(xy[:, 0]) > 180) or np.any(np.abs(xy[:, 1]) > 90):
                raise fields.err(key, rel, f"{where} of {path}: coordinates "
                                 f"{xy[0].tolist()} are not longitude/latitude in degrees; "
                                 "for projected metres write coordinates = 'metres'")
            poly = shapely.transform(poly, lambda p: np.column_stack(
                lonlat_to_local(p[:, 0], p[:, 1], origin)))
        xy = shapely.get_coordinates(poly)
        if len(xy) >= LARGE_FOOTPRINT_CORNERS:
            warnings.warn(f"{fields.file}: {key}: {where} of {path} has {len(xy):,} corners: "
                          f"its walls and roofs become about {4 * len(xy):,} triangles, "
                          "which take minutes to build and trace (1e6 corners: some 6 "
                          "minutes to load); simplify the footprint (e.g. shapely's "
                          "simplify to a centimetre) if that detail is not needed",
                          SceneWarning, stacklevel=3)
        if not np.all(np.isfinite(xy)):
            raise fields.err(key, rel, f"{where} of {path}: NaN or inf coordinates")
        if np.abs(xy).max() > MAX_FOOTPRINT_M:
            raise fields.err(key, rel, f"{where} of {path}: coordinate "
                             f"{np.abs(xy).max():g} m beyond {MAX_FOOTPRINT_M:g} m (no "
                             "projected coordinate on Earth is)")
        try:
            valid = poly.is_valid
        except shapely.errors.GEOSException as exc:  # GEOS cannot even tell (found by
            # tests/test_fuzz_imports.py: rings 1e300 m wide)
            raise fields.err(key, rel, f"{where} of {path}: invalid footprint "
                             f"({exc})") from None
        if not valid:
            from shapely.validation import explain_validity
            raise fields.err(key, rel, f"{where} of {path}: invalid footprint "
                             f"({explain_validity(poly)})")
        poly = poly.simplify(0.0)  # drop repeated and collinear corners
        bottom, top = _heights(fields, key, rel, path, where, props, level_h, default_h)
        material = props.get("material")
        if material is not None and not isinstance(material, str):
            raise fields.err(key, rel, f"{where} of {path}: property material = "
                             f"{material!r} is not a string")
        optics = props.get("optics")
        if optics is not None and optics not in OPTICS:
            raise fields.err(key, rel, f"{where} of {path}: property optics = {optics!r} "
                             f"must be one of {', '.join(OPTICS)}")
        verts, faces = extrude_footprint(poly, bottom, top)
        fid = feat.get("id")
        label = str(fid) if isinstance(fid, str | int) and not isinstance(fid, bool) \
            else str(i)
        out.append(Building(i, label, str(path), material, verts, faces, optics))
    if skipped:
        warnings.warn(f"{fields.file}: {key}: {len(skipped)} feature(s) of {path} are not "
                      f"Polygon or MultiPolygon and were left out (first {skipped[:10]})",
                      SceneWarning, stacklevel=3)
    if not out:
        raise fields.err(key, rel, f"{path} holds no Polygon or MultiPolygon features")
    return out


#: Names of WGS 84 longitude/latitude, the RFC 7946 default, that need no reprojection.
_LONLAT_CRS_NAMES = ("urn:ogc:def:crs:OGC:1.3:CRS84", "urn:ogc:def:crs:OGC::CRS84",
                     "OGC:CRS84", "CRS84", "EPSG:4326", "urn:ogc:def:crs:EPSG::4326")


def _crs_name(fields, key, rel, path, crs) -> str:
    """The name a GeoJSON 2008 ``crs`` member gives: {"type": "name", "properties":
    {"name": ...}} (a linked CRS is refused: the file would depend on a download)."""
    ok = (isinstance(crs, dict) and crs.get("type") == "name"
          and isinstance(crs.get("properties"), dict)
          and isinstance(crs["properties"].get("name"), str))
    if not ok:
        raise fields.err(key, rel, f"{path}: its 'crs' member {json.dumps(crs)[:120]} is not "
                         "a named CRS ({\"type\": \"name\", \"properties\": {\"name\": "
                         "\"EPSG:3857\"}}); give the name or drop the member for WGS 84")
    return crs["properties"]["name"]


def _crs_to_lonlat(fields, key, rel, path, crs, coords):
    """A pyproj Transformer from the file's ``crs`` to WGS 84 longitude/latitude, or None
    where the file has no ``crs`` or names WGS 84 longitude/latitude itself."""
    if crs is None:
        return None
    name = _crs_name(fields, key, rel, path, crs)
    if name.strip() in _LONLAT_CRS_NAMES:
        return None
    if coords == "metres":
        raise fields.err(key, rel, f"{path} names its coordinate system '{name}', but the "
                         "entry says coordinates = 'metres' (local metres, no CRS): drop "
                         "coordinates = 'metres' to reproject it to WGS 84, or drop the "
                         "file's crs member")
    import pyproj

    try:
        source = pyproj.CRS.from_user_input(name)
    except pyproj.exceptions.CRSError as exc:
        raise fields.err(key, rel, f"{path}: its crs '{name}' is not a coordinate "
                         f"reference system pyproj knows ({exc})") from None
    if source.is_geographic and source.equals(pyproj.CRS("OGC:CRS84"),
                                              ignore_axis_order=True):
        return None
    return pyproj.Transformer.from_crs(source, "OGC:CRS84", always_xy=True)


def _features(fields: FieldReader, path: Path, key: str,
              rel: str) -> tuple[list[dict], object]:
    """The file's features and its ``crs`` member (None without one)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise fields.err(key, rel, f"cannot read GeoJSON file {path} ({exc})") from None
    except (json.JSONDecodeError, RecursionError) as exc:
        raise fields.err(key, rel, f"{path} is not JSON ({exc})") from None
    kind = data.get("type") if isinstance(data, dict) else None
    if kind == "FeatureCollection":
        feats = data.get("features")
        if not isinstance(feats, list) or not all(isinstance(f, dict) for f in feats):
            raise fields.err(key, rel, f"{path}: 'features' is not a list of objects")
        return feats, data.get("crs")
    if kind == "Feature":
        return [data], data.get("crs")
    raise fields.err(key, rel, f"{path} is not a GeoJSON FeatureCollection or Feature "
                     f"(type {kind!r})")


def _metres(value, what: str) -> float:
    """A height property: a number, or a string of one with an optional ``m``."""
    if isinstance(value, bool):
        raise ValueError(f"{what} = {value!r} is not a number of metres")
    if isinstance(value, int | float):
        try:
            x = float(value)
        except OverflowError:  # an int beyond float64 (found by tests/test_fuzz_imports.py)
            raise ValueError(f"{what} = {value!r} is not finite") from None
    elif isinstance(value, str) and (m := _HEIGHT_RE.match(value)):
        x = float(m.group(1))
    else:
        raise ValueError(f"{what} = {value!r} is not a number of metres (write e.g. 12 "
                         "or '12 m')")
    if not math.isfinite(x):
        raise ValueError(f"{what} = {value!r} is not finite")
    return x


def _heights(fields, key, rel, path, where, props, level_h, default_h) -> tuple[float, float]:
    """(bottom, top) of a building from its properties (docs/scene-format.md)."""
    try:
        if "height" in props:
            top = _metres(props["height"], "height")
        elif "building:levels" in props:
            top = _metres(props["building:levels"], "building:levels") * level_h
        elif default_h is not None:
            top = default_h
        else:
            raise ValueError("has no height or building:levels property; give the entry "
                             "a height_m for such buildings")
        bottom = 0.0
        if "min_height" in props:
            bottom = _metres(props["min_height"], "min_height")
        elif "building:min_level" in props:
            bottom = _metres(props["building:min_level"], "building:min_level") * level_h
    except ValueError as exc:
        raise fields.err(key, rel, f"{where} of {path}: {exc}") from None
    if not (top > bottom >= 0.0):
        raise fields.err(key, rel, f"{where} of {path}: height {top:g} m must be above "
                         f"its base {bottom:g} m (and the base >= 0)")
    if top > MAX_FOOTPRINT_M:
        raise fields.err(key, rel, f"{where} of {path}: height {top:g} m beyond "
                         f"{MAX_FOOTPRINT_M:g} m")
    return bottom, top
