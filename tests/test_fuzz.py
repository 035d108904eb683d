"""Property-based fuzzing of everything clradcom reads from disk (docs/reliability.md).

Any input -- a scene document built from the real keys with hostile values, a mutated
scene text, random or mutated mesh and pattern files, a mutated, truncated or random
snapshot file -- gives a result that keeps the loader's promises, or one of the project's
errors (SceneError, SnapshotError, ArgumentError); never another exception, never a hang.

Fast and reproducible by default (derandomized, a few hundred examples per test). Set
CLRADCOM_FUZZ=deep for a long, random run (50x the examples, a new seed each time).
"""

from __future__ import annotations

import io
import math
import os
import signal
import warnings
import zipfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clradcom.errors import ArgumentError, ArgumentTypeError, SceneError, SnapshotError
from clradcom.paths import Paths
from clradcom.scene import antenna, bounds
from clradcom.scene.materials import C0
from clradcom.scene.read_materials import MATERIAL_KEYS
from clradcom.scene.read_objects import OBJECT_KEYS
from clradcom.scene.read_patterns import PATTERN_KEYS
from clradcom.scene.read_radars import RADAR_KEYS
from clradcom.scene.reader import SCENE_KEYS, load_scene, scene_from_dict
from clradcom.scene.records import Scene
from clradcom.snapshot import Link, Snapshot, load_snapshot, save_snapshot

DEEP = os.environ.get("CLRADCOM_FUZZ", "") == "deep"
#: Seconds one example may take before it counts as a hang.
HANG_S = 20.0


def fuzz(examples: int):
    """Hypothesis settings of one fuzz test: ``examples`` examples, derandomized (CI)."""
    return settings(max_examples=examples * (50 if DEEP else 1), derandomize=not DEEP,
                    deadline=None, database=None, print_blob=True,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])


class Hang(BaseException):
    """Raised by the alarm: a BaseException, so no ``except Exception`` can swallow it."""


@contextmanager
def no_hang(seconds: float = HANG_S):
    """Fail an example that runs longer than ``seconds`` (SIGALRM; main thread only)."""
    def alarm(signum, frame):
        raise Hang(f"took more than {seconds} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@contextmanager
def strict_warnings():
    """numpy's overflow/invalid RuntimeWarnings in the loaders become errors (a silently
    wrong number); the project's own warnings are expected and ignored."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        warnings.simplefilter("error", RuntimeWarning)
        yield


# -- a small valid scene, its files, and TOML text ------------------------------------------


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """A folder with the files the base scene names (a PLY mesh, CSV and NPZ patterns)."""
    d = tmp_path_factory.mktemp("fuzz")
    write_files(d)
    return d


def write_files(d: Path) -> None:
    trimesh.creation.box(extents=[1.0, 2.0, 0.5]).export(d / "box.ply")
    th, ph = np.linspace(0, 180, 7), np.linspace(-180, 150, 12)
    np.savez(d / "pat.npz", theta_deg=th, phi_deg=ph, gain_db=np.zeros((7, 12)))
    rows = ["theta_deg,phi_deg,gain_db"] + [f"{t:g},{p:g},0" for t in th for p in ph]
    (d / "pat.csv").write_text("\n".join(rows) + "\n")


def base_document() -> dict:
    """A scene using every table and most keys, all valid."""
    return {
        "scene": {"name": "fuzz", "carrier_hz": 24e9, "description": "base"},
        "materials": [
            {"name": "wet", "base": "concrete_building", "roughness_m": 0.002},
            {"name": "glass", "itu": "glass", "scattering_coefficient": 0.2},
            {"name": "lossy", "eps_r": [5.0, -0.5], "conductivity_s_m": 0.01,
             "roughness_model": "boithias", "xpd_db": 10.0},
            {"name": "pec2", "pec": True, "cross_pol_share": 0.1},
        ],
        "objects": [
            {"name": "road", "material": "concrete_road", "shape": "plane",
             "size": [20.0, 6.0]},
            {"name": "car", "material": "metal", "mesh": "box.ply",
             "position": [5.0, 0.0, 0.25], "rotation_deg": [0.0, 0.0, 30.0], "scale": 2.0,
             "velocity": [10.0, 0.0, 0.0], "optics": "po"},
            {"name": "wall", "material": "wet", "shape": "box",
             "extents": [1.0, 4.0, 3.0], "position": [10.0, 5.0, 1.5],
             "scale": [1.0, 1.0, 2.0]},
            {"name": "tri", "material": "lossy", "shape": "triangles",
             "vertices": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0],
                          [1.0, 1.0, 0.0]],
             "faces": [[0, 1, 2], [1, 3, 2]], "drop_degenerate": True},
        ],
        "radars": [
            {"name": "A", "rides_on": "car", "position": [1.0, 0.0, 0.5],
             "orientation_deg": [0.0, 0.0, 0.0], "tx_power_w": 0.01,
             "noise_figure_db": 10.0,
             "pattern": {"type": "sector", "azimuth_width_deg": 90.0}},
            {"name": "B", "position": [0.0, 3.0, 1.0], "velocity": [0.0, -1.0, 0.0],
             "role": "rx", "polarization": [[1.0, 0.0], [0.0, -1.0]],
             "pattern": {"type": "cosine", "half_power_beamwidth_deg": 60.0}},
            {"name": "C", "position": [0.0, -3.0, 1.0], "polarization": "RHCP",
             "pattern": {"type": "file", "path": "pat.csv"}},
            {"name": "D", "position": [0.0, -5.0, 1.0],
             "pattern": {"type": "file", "path": "pat.npz", "normalize": False}},
        ],
    }


def toml_key(key: str) -> str:
    return toml_string(key)


def toml_string(s: str) -> str:
    out = []
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def toml_value(v) -> str:
    """A TOML 1.0 value (inline tables and arrays) that tomllib reads back as ``v``."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, Deep):
        return "[" * v.depth + "1.0" + "]" * v.depth
    raise TypeError(type(v))


def toml_document(doc: dict) -> str:
    return "".join(f"{toml_key(k)} = {toml_value(v)}\n" for k, v in doc.items())


def test_toml_writer_round_trips_the_base_scene(folder):
    import tomllib

    doc = base_document()
    assert tomllib.loads(toml_document(doc)) == doc
    (folder / "base.toml").write_text(toml_document(doc), encoding="utf-8")
    s = load_scene(folder / "base.toml")
    assert len(s.objects) == 4 and len(s.radars) == 4 and s.triangles.shape[0] > 20


# -- what a loaded scene promises --------------------------------------------------------------


def check_scene(s: Scene) -> None:
    """The promises of docs/scene-format.md that a fuzzed scene must keep."""
    assert isinstance(s, Scene)
    lo, hi = bounds.CARRIER_HZ_REFUSED
    assert lo <= s.carrier_hz <= hi
    t = s.triangles
    assert t.dtype == np.float64 and t.ndim == 3 and t.shape[1:] == (3, 3)
    assert np.all(np.isfinite(t)) and np.all(np.abs(t) <= bounds.MAX_COORDINATE_M)
    assert s.tri_object.shape == s.tri_material.shape == (t.shape[0],)
    assert np.all(np.linalg.norm(s.object_velocity, axis=1) < C0)
    for r in s.radars:
        assert np.all(np.isfinite(r.position)) and np.linalg.norm(r.velocity) < C0
        assert 0 <= r.tx_power_w <= bounds.TX_POWER_MAX_W
        assert r.noise_figure_db is None or 0 <= r.noise_figure_db <= bounds.NOISE_FIGURE_MAX_DB
        assert np.isclose(np.linalg.norm(r.polarization), 1.0)
    for m in s.materials:
        assert m.pec or (m.eps_r.real > 0 and m.eps_r.imag <= 0 and np.isfinite(m.eps_r))
        assert 0 <= m.scattering_coefficient <= 1 and 0 <= m.cross_pol_share <= 1
        assert m.roughness_m >= 0
    s.content_hash()


def check_scene_error(e: SceneError) -> None:
    text = str(e)  # never fails, whatever the value
    assert text and e.reason
    assert e.key is None or isinstance(e.key, str)


def load_or_refuse(path) -> None:
    """load_scene(path): a Scene keeping its promises, or a SceneError; nothing else."""
    with no_hang(), strict_warnings():
        try:
            s = load_scene(path)
        except SceneError as e:
            check_scene_error(e)
            return
    check_scene(s)


# -- strategies: hostile values at the real keys ----------------------------------------------

huge_ints = st.integers(min_value=-(10**400), max_value=10**400)
floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
special_floats = st.sampled_from([0.0, -0.0, 1e-320, 1e-300, 1e300, 1.7e308, -1.7e308,
                                  math.inf, -math.inf, math.nan, C0, -C0, 3e6, 3e12,
                                  2.99e6, 3.01e12, 1e18, 1.0000001e18])
text = st.text(max_size=20)
scalars = st.one_of(floats, special_floats, st.integers(-10, 10), huge_ints, st.booleans(),
                    text, st.sampled_from(["", "metal", "box", "plane", "triangles",
                                           "box.ply", "pat.csv", "pat.npz", "car", "A",
                                           "isotropic", "sector", "cosine", "file", "V",
                                           "RHCP", "tx", "rx", "po", "itu_glass",
                                           "concrete", "../box.ply", "/dev/null",
                                           "nul\x00byte.ply"]))
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=5),
                            st.dictionaries(text, inner, max_size=4)),
    max_leaves=12)
vectors = st.lists(st.one_of(floats, special_floats, huge_ints, st.integers(-3, 3)),
                   min_size=0, max_size=4)


class Deep:
    """An array nested ``depth`` deep (expanded only when written or passed on, so that
    hypothesis can print the example)."""

    def __init__(self, depth: int) -> None:
        self.depth = depth

    def __repr__(self) -> str:
        return f"Deep({self.depth})"

    def expand(self) -> list:
        v: list = [1.0]
        for _ in range(self.depth):
            v = [v]
        return v


def expand(v):
    """``v`` with every Deep replaced by its nested lists."""
    if isinstance(v, Deep):
        return v.expand()
    if isinstance(v, list):
        return [expand(x) for x in v]
    if isinstance(v, dict):
        return {k: expand(x) for k, x in v.items()}
    return v


hostile = st.one_of(values, vectors, special_floats, huge_ints, st.integers(1, 3000).map(Deep))

#: The keys each kind of table knows (the loaders' own lists), so that most mutations
#: reach the checks of a value rather than the unknown-key check.
TABLE_KEYS = {"scene": SCENE_KEYS, "materials": MATERIAL_KEYS, "objects": OBJECT_KEYS,
              "radars": RADAR_KEYS,
              "pattern": tuple(sorted({k for ks in PATTERN_KEYS.values() for k in ks}))}
KEYS = sorted({k for ks in TABLE_KEYS.values() for k in ks})

numbers = st.one_of(special_floats, st.floats(-1e4, 1e4), st.integers(-5, 100), floats,
                    huge_ints)


def like(v) -> st.SearchStrategy:
    """Values shaped like ``v`` (a number for a number, a 3-vector for a 3-vector ...),
    often valid, often at or beyond a bound; now and then anything hostile."""
    if isinstance(v, bool):
        same = st.booleans()
    elif isinstance(v, int | float):
        same = numbers
    elif isinstance(v, str):
        same = scalars.filter(lambda x: isinstance(x, str))
    elif isinstance(v, list) and v and all(isinstance(x, list) for x in v):
        inner = st.lists(st.one_of(numbers, st.integers(-1, 5)), min_size=3, max_size=3)
        same = st.lists(inner, min_size=1, max_size=5)
    elif isinstance(v, list):
        same = st.lists(numbers, min_size=len(v), max_size=len(v))
    else:
        same = values
    return st.one_of(same, same, same, hostile)


def tables(doc: dict) -> list[tuple[str, dict]]:
    """(kind, table) for every table of the document, radars' pattern tables included."""
    out = []
    if isinstance(doc.get("scene"), dict):
        out.append(("scene", doc["scene"]))
    for kind in ("materials", "objects", "radars"):
        entries = doc.get(kind)
        for t in entries if isinstance(entries, list) else []:
            if isinstance(t, dict):
                out.append((kind, t))
                if kind == "radars" and isinstance(t.get("pattern"), dict):
                    out.append(("pattern", t["pattern"]))
    return out


@st.composite
def hostile_documents(draw) -> dict:
    """The base scene with one to three changes: a key set to a value like its own or a
    hostile one, a key deleted, a key of that kind of table (or any text) added, a
    top-level table dropped or replaced, an entry duplicated."""
    doc = base_document()
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["set"] * 6 + ["delete", "add", "add", "table",
                                                   "duplicate"]))
        if kind == "table":
            key = draw(st.sampled_from(["scene", "materials", "objects", "radars",
                                        "extra"]))
            if draw(st.booleans()):
                doc.pop(key, None)
            else:
                doc[key] = draw(hostile)
            continue
        if kind == "duplicate":
            for v in doc.values():
                entries = [x for x in v if isinstance(x, dict)] if isinstance(v, list) else []
                if entries and draw(st.booleans()):
                    v.append(dict(draw(st.sampled_from(entries))))
            continue
        tbls = tables(doc)
        if not tbls:
            continue
        tkind, tbl = draw(st.sampled_from(tbls))
        if kind == "delete" and tbl:
            tbl.pop(draw(st.sampled_from(sorted(tbl))))
        elif kind == "add":
            key = draw(st.one_of(st.sampled_from(TABLE_KEYS[tkind]), st.sampled_from(KEYS),
                                 text))
            tbl[key] = draw(like(tbl.get(key, 1.0)))
        elif tbl:
            key = draw(st.sampled_from(sorted(tbl)))
            tbl[key] = draw(like(tbl[key]))
    return doc


# -- the scene loader -------------------------------------------------------------------------


@fuzz(250)
@given(doc=hostile_documents())
def test_hostile_scene_documents(folder, doc):
    path = folder / "doc.toml"
    path.write_text(toml_document(doc), encoding="utf-8")
    load_or_refuse(path)


python_values = st.one_of(st.none(), st.just((0.0, 1.0, 2.0)), st.just(b"bytes"),
                          st.just(np.float64(24e9)), st.just(np.int64(3)),
                          st.just(np.array([1.0, 2.0, 3.0])), st.just(float),
                          st.just({1: 2}), st.just(object()),
                          st.builds(Deep, st.integers(1000, 100_000)))


@fuzz(150)
@given(doc=hostile_documents(), which=st.integers(0, 99), key=st.sampled_from(KEYS),
       extra=python_values)
def test_hostile_dicts_to_scene_from_dict(folder, doc, which, key, extra):
    """scene_from_dict takes Python objects TOML cannot write: None, tuples, bytes,
    numpy scalars and arrays, non-string keys, lists nested deeper than repr goes."""
    tbls = tables(doc)
    if tbls:
        tbls[which % len(tbls)][1][key] = extra
    with no_hang(), strict_warnings():
        try:
            s = scene_from_dict(expand(doc), file=folder / "dict.toml", base_dir=folder)
        except SceneError as e:
            check_scene_error(e)
            return
    check_scene(s)


@st.composite
def mutated_text(draw, source: str) -> bytes:
    """``source`` as UTF-8 with a few byte-level mutations: flips, insertions (bytes,
    TOML punctuation, brackets by the thousand), deletions, duplications, truncation."""
    data = bytearray(source.encode("utf-8"))
    for _ in range(draw(st.integers(1, 6))):
        kind = draw(st.sampled_from(["flip", "insert", "delete", "duplicate", "truncate",
                                     "number", "nest"]))
        n = len(data)
        at = draw(st.integers(0, n))
        if kind == "flip" and n:
            data[min(at, n - 1)] = draw(st.integers(0, 255))
        elif kind == "insert":
            data[at:at] = draw(st.one_of(st.binary(max_size=8), st.sampled_from(
                [b"[", b"]", b"{", b"}", b"=", b",", b'"', b"'''", b"\n", b"\\u0000",
                 b"[[objects]]\n", b"inf", b"nan", b"1e999", b"-0", b"0x", b"\xff\xfe"])))
        elif kind == "delete":
            del data[at:at + draw(st.integers(1, 40))]
        elif kind == "duplicate":
            data[at:at] = data[at:at + draw(st.integers(1, 200))]
        elif kind == "truncate":
            del data[at:]
        elif kind == "number":
            data[at:at] = str(draw(huge_ints)).encode()
        else:
            depth = draw(st.integers(1, 5000))
            data[at:at] = b"[" * depth + b"]" * depth
    return bytes(data)


@fuzz(250)
@given(data=mutated_text(toml_document(base_document())))
def test_mutated_scene_text(folder, data):
    path = folder / "mutated.toml"
    path.write_bytes(data)
    load_or_refuse(path)


# -- mesh and pattern files -------------------------------------------------------------------


def valid_meshes() -> dict[str, bytes]:
    """A small mesh in each format the scene reads (PLY and STL in ASCII and binary)."""
    box = trimesh.creation.box(extents=[1.0, 2.0, 3.0])
    out = {}
    for name, ftype, kw in [("a.ply", "ply", {"encoding": "ascii"}),
                            ("b.ply", "ply", {"encoding": "binary"}),
                            ("a.stl", "stl_ascii", {}), ("b.stl", "stl", {}),
                            ("a.obj", "obj", {}), ("a.off", "off", {}),
                            ("a.glb", "glb", {})]:
        data = box.export(file_type=ftype, **kw)
        out[name] = data.encode() if isinstance(data, str) else bytes(data)
    return out


MESHES = valid_meshes()


@st.composite
def mutated_bytes(draw, sources: dict[str, bytes]) -> tuple[str, bytes]:
    """(name, bytes): a source file with byte mutations and number tokens replaced by
    hostile numbers, or random bytes under a mesh name."""
    name = draw(st.sampled_from(sorted(sources)))
    if draw(st.integers(0, 5)) == 0:
        return name, draw(st.binary(max_size=600))
    data = bytearray(sources[name])
    for _ in range(draw(st.integers(1, 5))):
        kind = draw(st.sampled_from(["flip", "insert", "delete", "truncate", "number",
                                     "number", "duplicate"]))
        n = len(data)
        at = draw(st.integers(0, max(n - 1, 0)))
        if kind == "flip" and n:
            data[at] = draw(st.integers(0, 255))
        elif kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
        elif kind == "delete":
            del data[at:at + draw(st.integers(1, 64))]
        elif kind == "truncate":
            del data[at:]
        elif kind == "duplicate":
            data[at:at] = data[at:at + draw(st.integers(1, 400))]
        else:  # replace the digits of a number token at or after ``at``
            j = next((i for i in range(at, n) if chr(data[i]).isdigit()), None)
            if j is None:
                continue
            k = j
            while k < n and chr(data[k]) in "0123456789.eE+-":
                k += 1
            token = draw(st.sampled_from(["0", "-1", "3", "999999999", "4294967295",
                                          "99999999999999999999", "1e308", "1e999",
                                          "nan", "inf", "-inf", "1e-320", "2.5", "-0"]))
            data[j:k] = token.encode()
    return name, bytes(data)


def mesh_scene(folder: Path, mesh: str) -> Path:
    p = folder / "mesh.toml"
    p.write_text('[scene]\ncarrier_hz = 24e9\n[[objects]]\nname = "m"\nmaterial = "metal"\n'
                 f'mesh = "{mesh}"\n')
    return p


@fuzz(300)
@given(case=mutated_bytes(MESHES))
def test_mutated_and_random_mesh_files(folder, case):
    name, data = case
    (folder / name).write_bytes(data)
    with no_hang(), strict_warnings():
        try:
            s = load_scene(mesh_scene(folder, name))
        except SceneError as e:
            check_scene_error(e)
            # any failure of the mesh names the object's mesh key and the file
            assert e.key == "objects[0].mesh", str(e)
            assert e.value == name and name in str(e)
            return
    check_scene(s)


def pattern_files() -> dict[str, bytes]:
    th, ph = np.linspace(0, 180, 5), np.linspace(-180, 90, 4)
    rows = ["theta_deg,phi_deg,gain_db"] + [f"{t:g},{p:g},{t / 30:g}" for t in th for p in ph]
    crow = ["theta_deg,phi_deg,c_theta_re,c_theta_im,c_phi_re,c_phi_im"] + [
        f"{t:g},{p:g},1,0,0,{p / 180:g}" for t in th for p in ph]
    buf = io.BytesIO()
    np.savez(buf, theta_deg=th, phi_deg=ph, gain_db=np.ones((5, 4)))
    return {"g.csv": ("\n".join(rows) + "\n").encode(),
            "c.csv": ("\n".join(crow) + "\n").encode(), "p.npz": buf.getvalue()}


PATTERNS = pattern_files()


@fuzz(150)
@given(case=mutated_bytes(PATTERNS))
def test_mutated_and_random_pattern_files(folder, case):
    name, data = case
    (folder / name).write_bytes(data)
    p = folder / "pattern.toml"
    p.write_text('[scene]\ncarrier_hz = 24e9\n[[radars]]\nname = "r"\n'
                 f'position = [0.0, 0.0, 0.0]\npattern = {{ type = "file", path = "{name}" }}\n')
    with no_hang(), strict_warnings():
        try:
            s = load_scene(p)
        except SceneError as e:
            check_scene_error(e)
            assert e.key.startswith("radars[0].pattern"), str(e)
            return
    check_scene(s)
    g = s.radars[0].pattern.gain(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    assert np.all(np.isfinite(g)) and np.all(g >= 0)


# -- the snapshot reader ----------------------------------------------------------------------


def small_snapshot_bytes() -> bytes:
    rng = np.random.default_rng(7)
    p, k = 3, 2
    n = np.array([0, 1, 2], dtype=np.int16)
    active = np.arange(k)[None, :] < n[:, None]
    pts = rng.normal(size=(p, k + 2, 3))
    pts[~(np.arange(k + 2)[None, :] < (n + 2)[:, None])] = np.nan
    paths = Paths(gain=rng.normal(size=p) + 1j, matrix=np.ones((p, 2, 2), complex),
                  delay_s=np.array([1e-8, 2e-8, 3e-8]), doppler_hz=np.array([0.0, 5.0, -5.0]),
                  n_interactions=n, interaction=np.where(active, 1, 0), points=pts,
                  object_id=np.where(active, 0, -1), face_id=np.where(active, 3, -1))
    snap = Snapshot(scene_name="s", carrier_hz=24e9, scene_hash="ab" * 32,
                    links=[Link("A", "A", 0, 0, paths), Link("A", "B", 0, 1, paths)],
                    time_s=0.5, metadata={"rays": 1000, "x": 1.5, "ok": True, "v": "1"})
    buf = io.BytesIO()
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        save_snapshot(Path(d) / "s.npz", snap)
        buf.write((Path(d) / "s.npz").read_bytes())
    return buf.getvalue()


SNAPSHOT = small_snapshot_bytes()


def read_or_refuse(path: Path) -> None:
    with no_hang(), strict_warnings():
        try:
            snap = load_snapshot(path)
        except SnapshotError as e:
            assert str(e) and e.reason
            return
    assert isinstance(snap, Snapshot)
    for link in snap.links:
        assert isinstance(link.paths, Paths)


def test_the_valid_snapshot_loads(folder):
    (folder / "ok.npz").write_bytes(SNAPSHOT)
    assert len(load_snapshot(folder / "ok.npz").links) == 2


@fuzz(300)
@given(case=mutated_bytes({"s.npz": SNAPSHOT}))
def test_mutated_and_truncated_snapshots(folder, case):
    (folder / "snap.npz").write_bytes(case[1])
    read_or_refuse(folder / "snap.npz")


npy_arrays = st.one_of(
    st.just(np.array("clradcom-snapshot")), st.just(np.array(2, dtype=np.int64)),
    st.builds(lambda n, dt: np.zeros(n, dtype=dt), st.integers(0, 5),
              st.sampled_from(["<f8", ">f8", "<i8", "<i2", "<i1", "<c16", "?", "<U3", "<f4",
                               "V4", "<M8[s]", [("a", "<f8")]])),
    st.builds(lambda s: np.zeros(s), st.lists(st.integers(0, 3), max_size=4)),
)


@st.composite
def random_zips(draw) -> bytes:
    """Zips of .npy members with snapshot-like names, odd dtypes and shapes, non-npy
    members, deflated members, duplicate names."""
    names = st.one_of(st.sampled_from(
        ["meta/format", "meta/version", "meta/scene_name", "meta/carrier_hz",
         "meta/scene_hash", "meta/time_s", "links/tx_name", "links/rx_name",
         "links/tx_index", "links/rx_index", "link0/gain", "link0/delay_s",
         "metadata/x", "link0/points"]), st.text(max_size=10))
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # duplicate member names
        with zipfile.ZipFile(buf, "w") as zf:
            for _ in range(draw(st.integers(0, 8))):
                name = draw(names) + draw(st.sampled_from([".npy", ".npy", "", ".txt"]))
                comp = draw(st.sampled_from([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED]))
                if draw(st.booleans()):
                    member = io.BytesIO()
                    np.save(member, draw(npy_arrays), allow_pickle=False)
                    data = member.getvalue()
                else:
                    data = draw(st.binary(max_size=64))
                zf.writestr(zipfile.ZipInfo(name or "x"), data, compress_type=comp)
    return buf.getvalue()


@fuzz(200)
@given(data=random_zips())
def test_random_zips_as_snapshots(folder, data):
    (folder / "zip.npz").write_bytes(data)
    read_or_refuse(folder / "zip.npz")


@pytest.mark.parametrize("value", [None, 3, ["s.npz"]])
def test_load_snapshot_wants_a_path(value):
    with pytest.raises(ArgumentTypeError, match="path = .*must be a str or os.PathLike"):
        load_snapshot(value)


def test_load_snapshot_checks_max_bytes(folder):
    (folder / "ok.npz").write_bytes(SNAPSHOT)
    with pytest.raises(ArgumentTypeError, match="max_bytes = '1 GB': must be an int"):
        load_snapshot(folder / "ok.npz", max_bytes="1 GB")
    with pytest.raises(ArgumentError, match="max_bytes = -1: must be >= 0"):
        load_snapshot(folder / "ok.npz", max_bytes=-1)


def test_project_errors_are_value_or_type_errors():
    """What the fuzzers accept as a refusal is catchable as ValueError/TypeError."""
    assert issubclass(SceneError, ValueError) and issubclass(SnapshotError, ValueError)
    assert issubclass(ArgumentError, ValueError) and issubclass(ArgumentTypeError, TypeError)


# -- what the fuzzers found, kept as plain examples ---------------------------------------------


def test_found_obj_vertex_with_two_coordinates(folder):
    (folder / "v2.obj").write_text("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(SceneError, match="not 3-D points") as ei:
        load_scene(mesh_scene(folder, "v2.obj"))
    assert ei.value.key == "objects[0].mesh" and ei.value.value == "v2.obj"


def test_found_mesh_name_too_long_for_the_os(folder):
    name = "m" * 300 + ".ply"
    with pytest.raises(SceneError, match="mesh file not found") as ei:
        load_scene(mesh_scene(folder, name))
    assert ei.value.key == "objects[0].mesh"


@pytest.mark.parametrize("row, match", [("1e308", "outside"), ("4000", "outside"),
                                        ("-301", "outside")])
def test_found_pattern_gain_beyond_any_antenna(folder, row, match):
    th, ph = [0, 90, 180], [-180, 0]
    rows = ["theta_deg,phi_deg,gain_db"] + [f"{t},{p},{row if t == 90 else 0}"
                                            for t in th for p in ph]
    (folder / "big.csv").write_text("\n".join(rows) + "\n")
    p = folder / "big.toml"
    p.write_text('[scene]\ncarrier_hz = 24e9\n[[radars]]\nname = "r"\n'
                 'position = [0.0, 0.0, 0.0]\npattern = { type = "file", path = "big.csv" }\n')
    with strict_warnings(), pytest.raises(SceneError, match=match) as ei:
        load_scene(p)
    assert ei.value.key == "radars[0].pattern.path"


def test_found_complex_pattern_amplitude_beyond_any_antenna(folder):
    th, ph = np.array([0.0, 90.0, 180.0]), np.array([-180.0, 0.0])
    big = np.full((3, 2), 1e200, dtype=complex)
    np.savez(folder / "c.npz", theta_deg=th, phi_deg=ph, c_theta=big, c_phi=big)
    p = folder / "c.toml"
    p.write_text('[scene]\ncarrier_hz = 24e9\n[[radars]]\nname = "r"\n'
                 'position = [0.0, 0.0, 0.0]\npattern = { type = "file", path = "c.npz" }\n')
    with strict_warnings(), pytest.raises(SceneError, match="amplitude above"):
        load_scene(p)


def test_pattern_npz_that_would_unpack_to_gigabytes_is_refused_unread(folder, monkeypatch):
    monkeypatch.setattr(antenna, "MAX_PATTERN_NPZ_BYTES", 10_000)  # 1 GiB in real life
    with zipfile.ZipFile(folder / "bomb.npz", "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("gain_db.npy", bytes(20_000))
    p = folder / "bomb.toml"
    p.write_text('[scene]\ncarrier_hz = 24e9\n[[radars]]\nname = "r"\n'
                 'position = [0.0, 0.0, 0.0]\npattern = { type = "file", path = "bomb.npz" }\n')
    with pytest.raises(SceneError, match="unpack to"):
        load_scene(p)


def test_found_snapshot_member_that_is_not_npy(folder):
    with zipfile.ZipFile(folder / "raw.npz", "w") as zf:
        zf.writestr("meta/format.npy", b"")
    with pytest.raises(SnapshotError, match="not a .npy array") as ei:
        load_snapshot(folder / "raw.npz")
    assert ei.value.key == "meta/format"


@pytest.mark.parametrize("xpd, share", [(1e300, 0.0), (-1e300, 1.0), (3001.0, 0.0)])
def test_found_xpd_too_large_for_a_power_of_ten(folder, xpd, share):
    doc = {"scene": {"carrier_hz": 24e9},
           "materials": [{"name": "m", "eps_r": 5.0, "xpd_db": xpd}],
           "objects": [{"name": "p", "material": "m", "shape": "plane", "size": [1, 1]}]}
    with strict_warnings():
        assert scene_from_dict(doc).materials[0].cross_pol_share == share


def test_found_conductivity_overflowing_the_permittivity(folder):
    doc = {"scene": {"carrier_hz": 3e6},
           "materials": [{"name": "m", "eps_r": 5.0, "conductivity_s_m": 1e305}]}
    with strict_warnings(), pytest.raises(SceneError, match="overflows") as ei:
        scene_from_dict(doc)
    assert ei.value.key == "materials[0].conductivity_s_m"


def test_found_velocity_whose_square_overflows(folder):
    doc = {"scene": {"carrier_hz": 24e9},
           "radars": [{"name": "r", "position": [0, 0, 0], "velocity": [1e300, 1e300, 0]}]}
    with strict_warnings(), pytest.raises(SceneError, match="speed of light") as ei:
        scene_from_dict(doc)
    assert ei.value.key == "radars[0].velocity"


@pytest.mark.parametrize("jones", [[1e300, 1e300], [1e-200, 0.0], [[0.0, 1e-170], 1e-170]])
def test_found_jones_vector_whose_square_overflows_or_underflows(jones):
    doc = {"scene": {"carrier_hz": 24e9},
           "radars": [{"name": "r", "position": [0, 0, 0], "polarization": jones}]}
    with strict_warnings():
        pol = scene_from_dict(doc).radars[0].polarization
    assert np.linalg.norm(pol) == pytest.approx(1.0)


def test_found_snapshot_member_name_not_the_utf8_it_claims(folder):
    data = bytearray(SNAPSHOT)
    at = data.index(b"meta/format.npy")  # the first local header's name
    data[at + 1] = 0xC4  # the header says UTF-8 names (flag 0x800 set below)
    data[at - 24:at - 22] = (0x0800).to_bytes(2, "little")
    (folder / "utf.npz").write_bytes(bytes(data))
    with pytest.raises(SnapshotError):
        load_snapshot(folder / "utf.npz")


@pytest.mark.parametrize("pattern, key, match", [
    ('{ type = "cosine", half_power_beamwidth_deg = 1e-300 }',
     "radars[0].pattern.half_power_beamwidth_deg", "120 dBi"),
    ('{ type = "cosine", half_power_beamwidth_deg = 1e-4 }',
     "radars[0].pattern.half_power_beamwidth_deg", "120 dBi"),
    ('{ type = "cosine", q = 1e300 }', "radars[0].pattern.q", "q must be <="),
    ('{ type = "sector", azimuth_width_deg = 1e-320 }', "radars[0].pattern", "120 dBi"),
    ('{ type = "sector", azimuth_width_deg = 1e-9, elevation_width_deg = 1e-9 }',
     "radars[0].pattern", "120 dBi"),
])
def test_found_patterns_narrower_than_any_antenna(folder, pattern, key, match):
    """A beamwidth so small that cos(hpbw/2) rounds to 1 divided by zero; q = 1e300 or a
    1e-320 degree sector gave infinite gains."""
    p = folder / "narrow.toml"
    p.write_text('[scene]\ncarrier_hz = 24e9\n[[radars]]\nname = "r"\n'
                 f'position = [0.0, 0.0, 0.0]\npattern = {pattern}\n')
    with strict_warnings(), pytest.raises(SceneError, match=match) as ei:
        load_scene(p)
    assert ei.value.key == key


def test_found_unnormalised_table_above_any_antenna(folder):
    th, ph = np.array([0.0, 90.0, 180.0]), np.array([-180.0, 0.0])
    np.savez(folder / "hi.npz", theta_deg=th, phi_deg=ph, gain_db=np.full((3, 2), 200.0))
    p = folder / "hi.toml"
    p.write_text('[scene]\ncarrier_hz = 24e9\n[[radars]]\nname = "r"\nposition = [0.0, 0.0, 0.0]'
                 '\npattern = { type = "file", path = "hi.npz", normalize = false }\n')
    with strict_warnings(), pytest.raises(SceneError, match="200.0 dBi"):
        load_scene(p)


def test_found_material_based_on_itself():
    doc = {"scene": {"carrier_hz": 24e9}, "materials": [{"name": "m", "base": "m"}]}
    with pytest.raises(SceneError, match="its own base") as ei:
        scene_from_dict(doc)
    assert ei.value.key == "materials[0].base" and ei.value.value == "m"
