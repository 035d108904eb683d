"""Property-based fuzzing of the scene importers (Mitsuba/Sionna XML, GeoJSON footprints)
and of the export writers (clradcom.export, tools/export.py), docs/reliability.md.

Any input -- an XML or GeoJSON document built from the elements, attributes and
properties the readers know with hostile values, the same texts mutated byte by byte, a
hostile snapshot or frequency list for the writers, a hostile command line for the tool
-- gives a result that keeps the loader's promises (tests/test_fuzz.py's check_scene) or
one of the project's errors; never another exception, never a numpy warning (a silently
wrong number), never a hang. A writer that refuses leaves no file behind, a tool that
fails leaves its output folder as it was, and no run changes an input.

Derandomized and small (the whole module about 20 s on two cores); CLRADCOM_FUZZ=deep
runs 50x the examples with a new seed each time (test_fuzz.fuzz).
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import io
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.io as sio
import trimesh
from hypothesis import given
from hypothesis import strategies as st
from test_fuzz import (
    check_scene,
    fuzz,
    huge_ints,
    load_or_refuse,
    no_hang,
    strict_warnings,
)
from tool_helpers import load_tool

from clradcom.errors import ArgumentError, ArgumentTypeError, SceneError, SnapshotError
from clradcom.export import save_mat, save_sionna
from clradcom.paths import Paths
from clradcom.scene import load_scene
from clradcom.snapshot import Link, Snapshot, load_snapshot, save_snapshot

# -- hostile XML, the files it names, byte mutations ----------------------------------------

#: Text XML 1.0 can hold (no control characters, no surrogates or non-characters).
XML_TEXT = st.text(st.characters(blacklist_categories=("Cs", "Cc"),
                                 blacklist_characters="\ufffe\uffff"), max_size=12)
#: Attribute and property values: numbers at and beyond every bound, lists of the wrong
#: length, text where numbers go, parameters, paths out of the folder, any text (control
#: characters included, which expat must refuse cleanly).
XML_VALUES = st.one_of(
    st.sampled_from(["0", "-0", "1", "-1", "2.5", "1e-320", "1e-300", "1e300", "1.7e308",
                     "1e999", "-1e999", "nan", "inf", "-inf", "0x10", "", " ", "1,2,3",
                     "1 2", "1 2 3", "0 0 0", "1 0 0", "0 0 1", "1e308 1e308 1e308",
                     "1 2 3 4 5 6 7 8 9", "1 0 0 0  0 1 0 0  0 0 1 0  0 0 0 1",
                     "1 0 0 0  0 1 0 0  0 0 1 0  0 0 1 1", "0 0 0 0 0 0 0 0 0",
                     "true", "false", "TRUE", "$p", "$missing", "$$", "concrete", "glass",
                     "cheese", "m.ply", "m.obj", "m.stl", "../m.ply", "/dev/null", "nul.ply",
                     "missing.ply", "m.PLY", "mat-itu_concrete", "mat-itu_metal.001",
                     "mat-custom", "mat-", "mesh-", "itu_brick", "3e8", "299792458"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    huge_ints.map(str), XML_TEXT, XML_TEXT,
    st.text(max_size=12).filter(lambda s: "\x00" not in s))

#: Tags an element may be changed to: the ones the reader knows, and some it does not.
XML_TAGS = ["shape", "bsdf", "ref", "transform", "translate", "rotate", "scale", "matrix",
            "lookat", "float", "string", "boolean", "vector", "point", "default", "include",
            "integrator", "shear", "rgb"]
XML_ATTR_NAMES = ["type", "id", "name", "value", "x", "y", "z", "angle", "origin",
                  "target", "up", "filename"]
XML_TYPE_VALUES = ["ply", "obj", "stl", "rectangle", "cube", "sphere", "serialized",
                   "twosided", "diffuse", "itu-radio-material", "radio-material",
                   "holder-material", "to_world"]


def el(tag: str, attrs: dict, *children) -> list:
    """An element as [tag, attributes, children] (edited in place, then written)."""
    return [tag, dict(attrs), list(children)]


def base_xml_tree() -> list:
    """VALID_XML as a tree (tests/test_fuzz_imports.py's test_the_valid_xml_loads loads
    what it writes)."""
    return el("scene", {"version": "3.0.0"},
              el("default", {"name": "p", "value": "2"}),
              el("bsdf", {"type": "itu-radio-material", "id": "mat-itu_concrete"},
                 el("string", {"name": "type", "value": "concrete"})),
              el("bsdf", {"type": "radio-material", "id": "mat-custom"},
                 el("float", {"name": "relative_permittivity", "value": "4.5"}),
                 el("float", {"name": "conductivity", "value": "0.2"}),
                 el("float", {"name": "scattering_coefficient", "value": "0.3"})),
              el("shape", {"type": "ply", "id": "mesh-a"},
                 el("string", {"name": "filename", "value": "m.ply"}),
                 el("ref", {"id": "mat-itu_concrete"}),
                 el("transform", {"name": "to_world"},
                    el("scale", {"value": "$p"}),
                    el("rotate", {"x": "0", "y": "0", "z": "1", "angle": "30"}),
                    el("translate", {"x": "5", "y": "0", "z": "0.25"})),
                 el("vector", {"name": "velocity", "x": "-5", "y": "0", "z": "0"})),
              el("shape", {"type": "obj", "id": "mesh-b"},
                 el("string", {"name": "filename", "value": "m.obj"}),
                 el("bsdf", {"type": "twosided", "id": "mat-itu_metal"},
                    el("bsdf", {"type": "diffuse"})),
                 el("transform", {"name": "to_world"},
                    el("matrix", {"value": "1 0 0 -2  0 1 0 3  0 0 1 0  0 0 0 1"}))),
              el("shape", {"type": "rectangle", "id": "floor"},
                 el("ref", {"id": "mat-custom"}),
                 el("boolean", {"name": "flip_normals", "value": "false"}),
                 el("transform", {"name": "to_world"},
                    el("scale", {"x": "20", "y": "20", "z": "1"}))),
              el("shape", {"type": "cube", "id": "mesh-c"},
                 el("ref", {"id": "mat-custom"}),
                 el("transform", {"name": "to_world"},
                    el("lookat", {"origin": "0 0 0", "target": "1 1 0", "up": "0 0 1"}),
                    el("translate", {"value": "0 -4 1"}))))


def xml_escape(s: str) -> str:
    return (s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
            .replace('"', "&quot;").replace("\t", "&#9;").replace("\n", "&#10;")
            .replace("\r", "&#13;"))


def xml_text(tree: list) -> str:
    tag, attrs, children = tree
    a = "".join(f' {k}="{xml_escape(v)}"' for k, v in attrs.items())
    if not children:
        return f"<{tag}{a}/>"
    return f"<{tag}{a}>" + "".join(xml_text(c) for c in children) + f"</{tag}>"


def xml_elements(tree: list) -> list[list]:
    out = [tree]
    for c in tree[2]:
        out += xml_elements(c)
    return out


@st.composite
def hostile_xml(draw) -> str:
    """The valid scene with one to four edits: an attribute set to a hostile value (or
    a value another element uses), deleted or added; an element deleted, duplicated,
    retagged, or given a child copied from elsewhere."""
    tree = base_xml_tree()
    for _ in range(draw(st.integers(1, 4))):
        nodes = xml_elements(tree)
        node = draw(st.sampled_from(nodes))
        kind = draw(st.sampled_from(["set"] * 5 + ["unset", "add", "delete", "duplicate",
                                                   "retag", "adopt"]))
        attrs, children = node[1], node[2]
        if kind == "set" and attrs:
            key = draw(st.sampled_from(sorted(attrs)))
            attrs[key] = draw(st.one_of(XML_VALUES, st.sampled_from(XML_TYPE_VALUES)))
        elif kind == "unset" and attrs:
            del attrs[draw(st.sampled_from(sorted(attrs)))]
        elif kind == "add":
            attrs[draw(st.sampled_from(XML_ATTR_NAMES))] = draw(XML_VALUES)
        elif kind in ("delete", "duplicate") and children:
            i = draw(st.integers(0, len(children) - 1))
            if kind == "delete":
                del children[i]
            else:
                children.insert(i, copy.deepcopy(children[i]))
        elif kind == "retag" and node is not tree:
            node[0] = draw(st.sampled_from(XML_TAGS))
        elif kind == "adopt":
            donor = draw(st.sampled_from(nodes))
            if donor is not tree:  # a copy: an ancestor adopted makes no cycle
                children.append(copy.deepcopy(donor))
    return xml_text(tree) + "\n"


def write_import_meshes(d: Path) -> None:
    box = trimesh.creation.box(extents=[1.0, 2.0, 0.5])
    for name in ("m.ply", "m.obj", "m.stl"):
        box.export(d / name)
    (d / "sub").mkdir(exist_ok=True)
    box.export(d / "sub" / "m.ply")


VALID_XML = xml_text(base_xml_tree())


@pytest.fixture(scope="module")
def import_folder(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("fuzz_imports")
    write_import_meshes(d)
    (d / "xml.toml").write_text('[scene]\ncarrier_hz = 24e9\nimport = "s.xml"\n'
                                '[[radars]]\nname = "r"\nposition = [0.0, 0.0, 1.0]\n')
    return d


@st.composite
def mutated(draw, source: bytes, tokens: list[bytes]) -> bytes:
    """``source`` with one to five byte-level mutations: flips, insertions of the format's
    punctuation, deletions, duplications, truncation, deep nesting."""
    data = bytearray(source)
    for _ in range(draw(st.integers(1, 5))):
        kind = draw(st.sampled_from(["flip", "insert", "insert", "delete", "duplicate",
                                     "truncate", "nest"]))
        n = len(data)
        at = draw(st.integers(0, n))
        if kind == "flip" and n:
            data[min(at, n - 1)] = draw(st.integers(0, 255))
        elif kind == "insert":
            data[at:at] = draw(st.one_of(st.binary(max_size=6), st.sampled_from(tokens)))
        elif kind == "delete":
            del data[at:at + draw(st.integers(1, 40))]
        elif kind == "duplicate":
            data[at:at] = data[at:at + draw(st.integers(1, 300))]
        elif kind == "truncate":
            del data[at:]
        else:
            depth = draw(st.integers(1, 3000))
            data[at:at] = tokens[0] * depth + tokens[1] * depth
    return bytes(data)


# -- the XML importer ---------------------------------------------------------------------------


def test_the_valid_xml_loads(import_folder):
    (import_folder / "s.xml").write_text(VALID_XML)
    s = load_scene_checked(import_folder / "xml.toml")
    assert [o.name for o in s.objects] == ["a", "b", "floor", "c"]


def load_scene_checked(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = load_scene(path)
    check_scene(s)
    return s


@fuzz(100)
@given(xml=hostile_xml())
def test_hostile_xml_scenes(import_folder, xml):
    (import_folder / "s.xml").write_text(xml, encoding="utf-8")
    load_or_refuse(import_folder / "xml.toml")


@fuzz(100)
@given(data=mutated(VALID_XML.encode(), [b"<shape>", b"</shape>", b"<", b">", b'"', b"/>",
                                         b"$p", b"&amp;", b"&#0;", b"&x;", b"<![CDATA[",
                                         b"<!DOCTYPE s [<!ENTITY x 'y'>]>", b"\xff\xfe",
                                         b"nan", b"1e999", b" -0 ", b"<include/>"]))
def test_mutated_xml_text(import_folder, data):
    (import_folder / "s.xml").write_bytes(data)
    load_or_refuse(import_folder / "xml.toml")


# -- the GeoJSON importer -----------------------------------------------------------------------

GEO_NUMBERS = st.one_of(st.floats(-50, 50), st.sampled_from(
    [0.0, -0.0, 5e-324, 1e-300, 1e-9, 1e300, 1.7e308, -1.7e308, 180.0, 180.0000001, -90.0,
     90.0000001, 11.5755, 48.1374, 1e6, 1e7]), huge_ints, st.integers(-3, 3))
#: JSON values json.dumps writes and json.loads reads (NaN and Infinity included: the
#: json module reads them though RFC 8259 has none).
JSON_SCALARS = st.one_of(st.none(), st.booleans(), GEO_NUMBERS,
                         st.floats(allow_nan=True, allow_infinity=True),
                         st.text(max_size=8), st.sampled_from(
                             ["12", "12.5 m", "40 ft", "1e999", "nan", "-3", " 7 m ",
                              "itu_brick", "itu_concrete", "cheese", "Polygon",
                              "MultiPolygon", "Feature", "FeatureCollection", "Point"]))
JSON_VALUES = st.recursive(JSON_SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=10)


def base_geojson() -> dict:
    return {"type": "FeatureCollection", "features": [
        {"type": "Feature", "id": "house", "properties": {"height": "12.5 m"},
         "geometry": {"type": "Polygon", "coordinates": [
             [[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]],
             [[3, 3], [3, 5], [5, 5], [5, 3], [3, 3]]]}},
        {"type": "Feature", "properties": {"building:levels": "4", "min_height": 2,
                                           "material": "itu_brick"},
         "geometry": {"type": "MultiPolygon", "coordinates": [
             [[[20, 0], [20, 8], [30, 8], [30, 0], [20, 0]]]]}}]}


def json_slots(tree, out=None) -> list:
    """(container, key) of every value in a JSON tree."""
    out = [] if out is None else out
    items = tree.items() if isinstance(tree, dict) else enumerate(tree) \
        if isinstance(tree, list) else ()
    for k, v in items:
        out.append((tree, k))
        json_slots(v, out)
    return out


def like_json(draw, v):
    """A value shaped like ``v`` (a number for a number, a corner for a corner ...), or
    anything hostile now and then."""
    if draw(st.integers(0, 3)) == 0:
        return draw(JSON_VALUES)
    if isinstance(v, bool) or v is None:
        return draw(JSON_SCALARS)
    if isinstance(v, int | float):
        return draw(GEO_NUMBERS)
    if isinstance(v, str):
        return draw(JSON_SCALARS)
    if isinstance(v, list) and v and all(isinstance(x, int | float) for x in v):
        return draw(st.lists(GEO_NUMBERS, min_size=0, max_size=4))
    return draw(JSON_VALUES)


HEIGHT_KEYS = ["height", "min_height", "building:levels", "building:min_level",
               "material", "crs", "bbox", "id"]


@st.composite
def hostile_geojson(draw) -> dict:
    """The valid footprints with one to four edits: a value set to one like it or a
    hostile one, a key deleted or added (height keys, crs, ...), a list item deleted or
    duplicated, corners scaled (to 1e-12 or 1e300 wide) or moved far away."""
    doc = base_geojson()
    for _ in range(draw(st.integers(1, 4))):
        slots = json_slots(doc)
        container, key = draw(st.sampled_from(slots))
        kind = draw(st.sampled_from(["set"] * 4 + ["delete", "add", "duplicate",
                                                   "scale"]))
        if kind == "set":
            container[key] = like_json(draw, container[key])
        elif kind == "delete":
            del container[key]
        elif kind == "add" and isinstance(container, dict):
            container[draw(st.sampled_from(HEIGHT_KEYS))] = draw(JSON_SCALARS)
        elif kind == "duplicate" and isinstance(container, list):
            container.insert(key, json.loads(json.dumps(container[key])))
        elif kind == "scale":
            factor = draw(st.sampled_from([1e-12, 1e-7, 1e3, 1e7, 1e300]))
            shift = draw(st.sampled_from([0.0, 0.0, 1e6, -1e9, 179.99]))
            feats = doc.get("features") if isinstance(doc, dict) else None
            for feat in feats if isinstance(feats, list) else []:
                geom = feat.get("geometry") if isinstance(feat, dict) else None
                if isinstance(geom, dict):
                    geom["coordinates"] = scaled(geom.get("coordinates"), factor, shift)
    return doc


def scaled(coords, factor, shift):
    if isinstance(coords, list) and len(coords) in (2, 3) and all(
            isinstance(x, float) or type(x) is int and abs(x) < 1e300 for x in coords):
        return [x * factor + shift for x in coords]
    if isinstance(coords, list):
        return [scaled(c, factor, shift) for c in coords]
    return coords


#: Floats for the scene file's entry (repr is TOML: nan, inf, -inf included).
TOML_FLOATS = st.one_of(st.floats(0.1, 200), st.sampled_from(
    [0.0, -0.0, 5e-324, -1.0, 1e300, 90.0, 3.0, 11.5755, 48.1374, math.nan, math.inf]))


@st.composite
def geojson_cases(draw) -> tuple[bytes, str]:
    """(GeoJSON bytes, the [[objects]] entry's extra keys): mostly projected metres;
    longitude/latitude (origin on or off the globe) and hostile heights now and then."""
    text = json.dumps(draw(hostile_geojson()), allow_nan=True).encode()
    entry = []
    if draw(st.integers(0, 3)):
        entry.append('coordinates = "metres"')
    else:
        entry.append(draw(st.sampled_from(['coordinates = "lonlat"', "",
                                           'coordinates = "degrees"'])))
        lon, lat = draw(st.sampled_from([(11.5755, 48.1374), (0.0, 0.0), (180.0, 90.0)])) \
            if draw(st.integers(0, 3)) else (draw(TOML_FLOATS), draw(TOML_FLOATS))
        entry.append(f"origin_lonlat = [{lon!r}, {lat!r}]")
    if draw(st.integers(0, 3)) == 0:
        key = draw(st.sampled_from(["height_m", "level_height_m"]))
        entry.append(f"{key} = {draw(TOML_FLOATS)!r}")
    return text, "\n".join(entry) + "\n"


def geojson_scene(folder: Path, entry: str) -> Path:
    p = folder / "geo.toml"
    p.write_text('[scene]\ncarrier_hz = 24e9\n[[objects]]\nname = "city"\n'
                 'geojson = "b.geojson"\nmaterial = "itu_concrete"\n' + entry)
    return p


VALID_GEOJSON = json.dumps(base_geojson(), indent=1).encode()


def test_the_valid_geojson_loads(import_folder):
    (import_folder / "b.geojson").write_bytes(VALID_GEOJSON)
    s = load_scene_checked(geojson_scene(import_folder, 'coordinates = "metres"\n'))
    assert [o.name for o in s.objects] == ["city/house", "city/1"]


@fuzz(120)
@given(case=geojson_cases())
def test_hostile_geojson_documents(import_folder, case):
    text, entry = case
    (import_folder / "b.geojson").write_bytes(text)
    load_or_refuse(geojson_scene(import_folder, entry))


@fuzz(80)
@given(data=mutated(VALID_GEOJSON, [b"[", b"]", b"{", b"}", b",", b":", b'"', b"NaN",
                                    b"Infinity", b"-1e999", b"1e308", b"null", b"\\u0000",
                                    b"\xff"]))
def test_mutated_geojson_text(import_folder, data):
    (import_folder / "b.geojson").write_bytes(data)
    load_or_refuse(geojson_scene(import_folder, 'coordinates = "metres"\n'))


# -- the export writers -------------------------------------------------------------------------

WRITER_ERRORS = (ArgumentError, ArgumentTypeError, SnapshotError)
NAMES = st.one_of(st.sampled_from(["A", "B", "", " ", "é", "名前", "a/b", "x" * 200]),
                  st.text(max_size=8))
FINITE = st.floats(-1e6, 1e6)
EXTREME = st.one_of(FINITE, st.sampled_from([0.0, -0.0, 1e-320, 1e-300, 1e300, 1.7e308,
                                             -1.7e308, 5e-324]))


@st.composite
def paths_of(draw) -> dict:
    n = draw(st.integers(0, 4))
    k = draw(st.integers(0, 2))
    inter = np.array(draw(st.lists(st.integers(0, k), min_size=n, max_size=n)), np.int16)
    active = np.arange(k)[None, :] < inter[:, None]
    pts = np.array(draw(st.lists(EXTREME, min_size=n * (k + 2) * 3,
                                 max_size=n * (k + 2) * 3))).reshape(n, k + 2, 3)
    pts[~(np.arange(k + 2)[None, :] < (inter + 2)[:, None])] = np.nan
    gains = np.array(draw(st.lists(EXTREME, min_size=2 * n, max_size=2 * n)))
    gain = gains[:n] + 1j * gains[n:] if n else np.zeros(0, complex)
    delay = np.array(draw(st.lists(st.one_of(st.floats(0, 1e-3), st.sampled_from(
        [0.0, 5e-324, 1e-6, 1.0, 1e300])), min_size=n, max_size=n)))
    return dict(gain=gain, matrix=np.ones((n, 2, 2), complex) * gain[:, None, None],
                delay_s=delay, doppler_hz=np.array(draw(st.lists(EXTREME, min_size=n,
                                                                 max_size=n))),
                n_interactions=inter, interaction=np.where(active, 1, 0).astype(np.int8),
                points=pts, object_id=np.where(active, 0, -1).astype(np.int32),
                face_id=np.where(active, 3, -1).astype(np.int32))


@st.composite
def snapshot_parts(draw) -> dict:
    """What a Snapshot is built from (built in the test: its own refusals count)."""
    names = draw(st.lists(NAMES, min_size=1, max_size=3, unique=True))
    links = []
    for t, r in draw(st.lists(st.tuples(st.integers(0, len(names) - 1),
                                        st.integers(0, len(names) - 1)),
                              min_size=0, max_size=3, unique=True)):
        links.append((names[t], names[r], t, r, draw(paths_of())))
    meta = draw(st.dictionaries(NAMES, st.one_of(st.integers(-10**18, 10**18), FINITE,
                                                 st.booleans(), NAMES), max_size=3))
    return dict(scene_name=draw(NAMES), carrier_hz=draw(st.sampled_from(
                    [24e9, 3e6, 3e12, 77e9])), scene_hash=draw(st.sampled_from(
                        ["", "ab" * 32])), links=links, time_s=draw(FINITE),
                object_names=draw(st.lists(NAMES, max_size=3)), metadata=meta)


def build_snapshot(parts: dict) -> Snapshot | None:
    """The Snapshot of ``parts``, or None where Paths or Snapshot refuse them (with the
    project's errors only)."""
    try:
        links = [Link(t, r, ti, ri, Paths(**p)) for t, r, ti, ri, p in parts["links"]]
        return Snapshot(**{**parts, "links": links})
    except WRITER_ERRORS as e:
        assert str(e) and "\n" not in str(e)
        return None


FREQUENCIES = st.one_of(
    st.none(), st.lists(FINITE, min_size=1, max_size=6),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
    st.sampled_from([[], [[1.0, 2.0]], "1e6", [1e300, -1e300], [np.nan], ["a"], 3.0,
                     [[]], np.zeros((2, 2)), [1.7e308]]))


def folder_state(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@fuzz(50)
@given(parts=snapshot_parts(), freqs=FREQUENCIES,
       carrier_phase=st.sampled_from([True, False, 1]))
def test_hostile_snapshots_and_frequencies_to_the_writers(tmp_path_factory, parts, freqs,
                                                           carrier_phase):
    """save_sionna and save_mat: the file read back holds what was written, or a refusal
    with the project's error and no file (nor a staging file) left behind."""
    snap = build_snapshot(parts)
    if snap is None:
        return
    out = tmp_path_factory.mktemp("w")
    with no_hang(), strict_warnings():
        try:
            path = save_sionna(out / "s.sionna.npz", snap, freqs, carrier_phase=carrier_phase)
        except WRITER_ERRORS as e:
            assert str(e) and "\n" not in str(e)
            assert folder_state(out) == {}, folder_state(out)
        else:
            with np.load(path) as z:
                n_paths = sum(lk.paths.n_paths for lk in snap.links)
                assert int(z["valid"].sum()) == n_paths
                assert set(z["tx_names"].tolist()) == {lk.tx_name for lk in snap.links}
                if freqs is not None:
                    assert z["h_freq"].shape[-1] == np.asarray(freqs).size
            assert folder_state(out).keys() == {"s.sionna.npz"}
        path = save_mat(out / "s.mat", snap)
    m = sio.loadmat(path)
    assert m["links"].shape == (1, len(snap.links))
    for i, lk in enumerate(snap.links):
        a = m["links"][0, i][0, 0]["a"]
        np.testing.assert_array_equal(a.reshape(-1), lk.paths.gain)
    assert not [p for p in out.iterdir() if p.name not in ("s.mat", "s.sionna.npz")]


# -- tools/export.py --------------------------------------------------------------------------

EXPORT_OPTIONS = {
    "--out": st.sampled_from(["out", "out/deeper", "snap.npz", "file.txt", "", ".",
                              "scene.toml", "out/../out"]),
    "--subcarriers": st.sampled_from(["8", "1", "0", "-3", "1e3", "x", "99999999999999999999",
                                      "2"]),
    "--spacing-hz": st.sampled_from(["1e6", "0", "-1", "nan", "inf", "1e308", "x", "5e-324"]),
    "--frequencies-hz": st.sampled_from(["1e6,2e6", "", ",", "nan", "1e308,-1e308", "x,1",
                                         "0", "1e999"]),
    "--scene": st.sampled_from(["scene.toml", "missing.toml", "snap.npz", "file.txt",
                                "out"]),
    "--link": st.sampled_from(["A->A", "A->B", "->", "", "A", "B->A->A"]),
    "--paths": st.sampled_from(["1", "0", "-1", "50", "x"]),
}
EXPORT_FLAGS = ["--mat", "--sionna", "--compressed", "--top-view", "--glb", "--html",
                "--no-carrier-phase"]

EXPORT_SCENE = """[scene]
name = "plate"
carrier_hz = 24e9

[[objects]]
name = "plate"
material = "metal"
shape = "plane"
size = [2.0, 2.0]
position = [5.0, 0.0, 1.0]
rotation_deg = [0.0, -90.0, 0.0]

[[radars]]
name = "A"
position = [0.0, 0.0, 1.0]
"""


@pytest.fixture(scope="module")
def export_tool():
    return load_tool("export")


@pytest.fixture(scope="module")
def export_inputs(tmp_path_factory) -> dict[str, bytes]:
    """A snapshot (two links), the scene it names, a text file: what each run starts from."""
    d = tmp_path_factory.mktemp("export_inputs")
    rng = np.random.default_rng(3)
    n = 3
    paths = Paths(gain=rng.normal(size=n) + 1j * rng.normal(size=n),
                  matrix=np.ones((n, 2, 2), complex), delay_s=np.array([3e-8, 4e-8, 5e-8]),
                  doppler_hz=np.zeros(n), n_interactions=np.array([1, 1, 0], np.int16),
                  interaction=np.array([[1], [1], [0]], np.int8),
                  points=np.array([[[0, 0, 1], [5, 0, 1], [0, 0, 1]],
                                   [[0, 0, 1], [5, 0.5, 1], [0, 0, 1]],
                                   [[0, 0, 1], [0, 0, 1], [np.nan] * 3]], float),
                  object_id=np.array([[0], [0], [-1]], np.int32),
                  face_id=np.array([[0], [1], [-1]], np.int32))
    snap = Snapshot("plate", 24e9, "", links=[Link("A", "A", 0, 0, paths)],
                    object_names=["plate"])
    save_snapshot(d / "snap.npz", snap)
    return {"snap.npz": (d / "snap.npz").read_bytes(),
            "scene.toml": EXPORT_SCENE.encode(), "file.txt": b"not a folder\n"}


@st.composite
def export_argvs(draw) -> list[str]:
    argv = [draw(st.sampled_from(["snap.npz"] * 6 + ["missing.npz", "scene.toml", "out",
                                                     "file.txt", "bad.npz"]))]
    for flag in draw(st.lists(st.sampled_from(EXPORT_FLAGS), max_size=3, unique=True)):
        argv.append(flag)
    for opt in draw(st.lists(st.sampled_from(sorted(EXPORT_OPTIONS)), max_size=3,
                             unique=True)):
        argv += [opt, draw(EXPORT_OPTIONS[opt])]
    return argv


@fuzz(60)
@given(argv=export_argvs(), corrupt=st.integers(0, 4))
def test_hostile_export_command_lines(tmp_path_factory, export_tool, export_inputs, argv,
                                      corrupt):
    """tools/export.py: exit 0 having written what it says, or exit 2 with one line on
    stderr (argparse: its usage line and one error line) and the folder as it was; the
    inputs never change."""
    d = tmp_path_factory.mktemp("x")
    for name, data in export_inputs.items():
        (d / name).write_bytes(data)
    (d / "bad.npz").write_bytes(export_inputs["snap.npz"][:corrupt * 50 + 20])
    before = folder_state(d)
    args = [str(d / a) if i == 0 or argv[i - 1] in ("--out", "--scene") else a
            for i, a in enumerate(argv)]
    err, out = io.StringIO(), io.StringIO()
    with no_hang(60), warnings.catch_warnings(), contextlib.redirect_stderr(err), \
            contextlib.redirect_stdout(out):
        warnings.simplefilter("ignore")
        try:
            code = export_tool.main(args)
        except SystemExit as exc:  # argparse's refusals
            code = exc.code
    after = folder_state(d)
    for name in before:  # inputs and earlier outputs never change
        assert after.get(name) == before[name], (name, err.getvalue())
    # the warning lines run_tool prints (each once, then a count) are not errors
    lines = [ln for ln in err.getvalue().splitlines()
             if not ln.startswith("export.py: warning") and "warning(s)" not in ln]
    if code == 0:
        wrote = [ln.split()[1] for ln in out.getvalue().splitlines() if ln.startswith("wrote")]
        assert wrote and set(after) - set(before) == {
            str(Path(w).resolve().relative_to(d.resolve())) for w in wrote}
        return
    assert code == 2, (code, err.getvalue())
    assert "Traceback" not in err.getvalue()
    assert set(after) == set(before), (sorted(set(after) - set(before)), err.getvalue())
    if lines and lines[0].startswith("usage:"):  # argparse names the program argv[0]
        assert ": error: argument " in lines[-1], err.getvalue()
    else:
        assert len(lines) == 1 and lines[0].startswith("export.py: "), err.getvalue()


def test_the_export_tool_writes_where_it_says(tmp_path, export_tool, export_inputs):
    for name, data in export_inputs.items():
        (tmp_path / name).write_bytes(data)
    with contextlib.redirect_stdout(io.StringIO()) as out:
        code = export_tool.main([str(tmp_path / "snap.npz"), "--mat", "--sionna",
                                 "--out", str(tmp_path / "o"), "--subcarriers", "4"])
    assert code == 0, out.getvalue()
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["snap.mat",
                                                                  "snap.sionna.npz"]
    assert load_snapshot(tmp_path / "snap.npz").links[0].paths.n_paths == 3
    with np.load(tmp_path / "o" / "snap.sionna.npz") as z:
        assert math.isfinite(float(z["carrier_hz"])) and z["h_freq"].shape == (1, 1, 4)


# -- what the fuzzers found, kept as plain examples ---------------------------------------------


def test_found_xml_filename_without_a_value(import_folder):
    """<string name="filename"/> gave a TypeError from pathlib."""
    tree = base_xml_tree()
    del tree[2][3][2][0][1]["value"]  # mesh-a's filename
    (import_folder / "s.xml").write_text(xml_text(tree))
    with pytest.raises(SceneError, match="missing attribute 'value'") as ei:
        load_scene(import_folder / "xml.toml")
    assert ei.value.key == "shape[mesh-a].filename" and ei.value.line == 1


def test_found_geojson_ring_geos_cannot_validate(import_folder):
    """A footprint 1e300 m wide: shapely's is_valid raised GEOSException."""
    doc = base_geojson()
    doc["features"][0]["geometry"]["coordinates"] = scaled(
        doc["features"][0]["geometry"]["coordinates"], 1e300, 0.0)
    (import_folder / "b.geojson").write_text(json.dumps(doc))
    with pytest.raises(SceneError, match="feature 0 of .*b.geojson: invalid footprint|"
                                         "outside|coordinate") as ei:
        load_scene(geojson_scene(import_folder, 'coordinates = "metres"\n'))
    assert ei.value.key.startswith("objects[0]")


@pytest.mark.parametrize("delay, freqs, match", [
    (1e300, None, "overflows: no phase"), (10.0, [1.7e308], "overflows: no phase")])
def test_found_sionna_phase_of_an_absurd_delay(tmp_path, delay, freqs, match):
    """carrier_phase=False or the CFR at delay x frequency beyond float64 gave NaN with a
    RuntimeWarning; now refused, nothing written."""
    paths = dict(gain=np.array([1e-3 + 0j]), matrix=np.ones((1, 2, 2), complex) * 1e-3,
                 delay_s=np.array([delay]), doppler_hz=np.zeros(1),
                 n_interactions=np.zeros(1, np.int16), interaction=np.zeros((1, 0), np.int8),
                 points=np.zeros((1, 2, 3)), object_id=np.zeros((1, 0), np.int32),
                 face_id=np.zeros((1, 0), np.int32))
    snap = Snapshot("s", 24e9, "", links=[Link("A", "A", 0, 0, Paths(**paths))])
    with strict_warnings(), pytest.raises(ArgumentError, match=match):
        save_sionna(tmp_path / "s.npz", snap, freqs, carrier_phase=freqs is not None)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("edit, entry, match", [
    (lambda d: d["features"][0]["properties"].update(height=10**400), "",
     "height = 1000.* is not finite"),
    (lambda d: d["features"][1]["geometry"].update(coordinates=scaled(
        d["features"][1]["geometry"]["coordinates"], 1e10, 0.0)), "",
     r"feature 1 of .*: coordinate 3e\+11 m beyond 1e\+08 m"),
    (lambda d: None, "level_height_m = 1e300\n", r"feature 1 of .*: height 4e\+300 m beyond"),
])
def test_found_geojson_numbers_beyond_any_building(import_folder, edit, entry, match):
    """A height int beyond float64 (OverflowError), footprints 3e11 m wide (trimesh's
    vertex hashing cast NaN) and levels times a 1e300 m storey (an infinite extrusion)."""
    doc = base_geojson()
    edit(doc)
    (import_folder / "b.geojson").write_text(json.dumps(doc))
    with strict_warnings(), pytest.raises(SceneError, match=match) as ei:
        load_scene(geojson_scene(import_folder, 'coordinates = "metres"\n' + entry))
    assert ei.value.key == "objects[0].geojson"


def test_a_footprint_of_picometres_extrudes_without_numpy_warnings(
        import_folder):
    doc = base_geojson()
    doc["features"] = doc["features"][:1]
    doc["features"][0]["geometry"]["coordinates"] = scaled(
        doc["features"][0]["geometry"]["coordinates"], 1e-12, 0.0)
    (import_folder / "b.geojson").write_text(json.dumps(doc))
    load_or_refuse(geojson_scene(import_folder, 'coordinates = "metres"\n'))
