"""Snapshot files: exact round trip, deterministic bytes, atomic writes, clear refusals."""

import io
import os
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from clradcom import snapshot as snapmod
from clradcom.paths import PATH_FIELD_NAMES, InteractionType, Paths
from clradcom.snapshot import (
    FORMAT_VERSION,
    Link,
    Snapshot,
    SnapshotError,
    assert_snapshot_equal,
    load_snapshot,
    save_snapshot,
)

# -- builders ------------------------------------------------------------------------


def make_paths(n_interactions, *, seed=0, k_max=None, gains=None, delays=None):
    """Valid Paths with the given interaction counts (random values, fixed seed)."""
    rng = np.random.default_rng(seed)
    n = np.asarray(n_interactions, dtype=np.int16)
    p = n.size
    k = int(n.max(initial=0)) if k_max is None else k_max
    active = np.arange(k)[None, :] < n[:, None]
    codes = rng.integers(1, 4, size=(p, k))
    pts = rng.normal(size=(p, k + 2, 3)) * 20
    pts[~(np.arange(k + 2)[None, :] < (n + 2)[:, None])] = np.nan
    return Paths(
        gain=rng.normal(size=p) + 1j * rng.normal(size=p) if gains is None else gains,
        matrix=rng.normal(size=(p, 2, 2)) + 1j * rng.normal(size=(p, 2, 2)),
        delay_s=rng.uniform(1e-8, 1e-6, size=p) if delays is None else delays,
        doppler_hz=rng.normal(size=p) * 2e3,
        n_interactions=n,
        interaction=np.where(active, codes, 0),
        points=pts,
        object_id=np.where(active, rng.integers(0, 10, size=(p, k)), -1),
        face_id=np.where(active, rng.integers(0, 10_000, size=(p, k)), -1),
    )


def make_snapshot(**overrides):
    """The paper's four links: A->A and D->D monostatic, A->D and D->A bistatic."""
    kw = dict(
        scene_name="street",
        carrier_hz=24e9,
        scene_hash="0123456789abcdef" * 4,
        links=[
            Link("A", "A", 0, 0, make_paths([0, 1, 2, 2, 3], seed=1)),
            Link("A", "D", 0, 1, make_paths([0, 1], seed=2)),
            Link("D", "D", 1, 1, Paths.empty(k_max=3)),
            Link("D", "A", 1, 0, make_paths([0, 0, 0], seed=3)),  # K_max = 0: LoS only
        ],
        time_s=0.125,
        metadata={"max_reflections": 3, "rays": 1e6, "clradcom_version": "0.1.0",
                  "diffraction": True},
        object_names=["road", "car B", "car C", "car D", "tree", "house 1", "house 2",
                      "guard rail", "sign", "lamp"],  # make_paths's object ids are 0..9
    )
    kw.update(overrides)
    return Snapshot(**kw)


def rewrite(src, dst, change):
    """Copy the npz ``src`` to ``dst`` (bare numpy), replacing/adding keys given as arrays
    and deleting keys mapped to None."""
    with np.load(src, allow_pickle=False) as f:
        data = {k: f[k] for k in f.files}
    for key, value in change.items():
        if value is None:
            del data[key]
        else:
            data[key] = value
    np.savez(dst, **data)
    return dst


# -- hypothesis strategies -------------------------------------------------------------

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
names = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"),
                min_size=0, max_size=6)


@st.composite
def paths_strategy(draw):
    p = draw(st.integers(0, 4))
    k = draw(st.integers(0, 3))
    n = draw(hnp.arrays(np.int16, p, elements=st.integers(0, k)))
    active = np.arange(k)[None, :] < n[:, None]
    used = np.arange(k + 2)[None, :] < (n + 2)[:, None]
    codes = draw(hnp.arrays(np.int8, (p, k), elements=st.sampled_from([1, 2, 3])))
    ids = draw(hnp.arrays(np.int32, (p, k), elements=st.integers(0, 2**31 - 1)))
    faces = draw(hnp.arrays(np.int32, (p, k), elements=st.integers(0, 2**31 - 1)))
    pts = draw(hnp.arrays(np.float64, (p, k + 2, 3), elements=finite))
    pts[~used] = np.nan
    return Paths(
        gain=draw(hnp.arrays(np.complex128, p, elements=st.complex_numbers(
            allow_nan=False, allow_infinity=False))),
        matrix=draw(hnp.arrays(np.complex128, (p, 2, 2), elements=st.complex_numbers(
            allow_nan=False, allow_infinity=False))),
        delay_s=draw(hnp.arrays(np.float64, p, elements=st.floats(
            0, 1e-3, allow_nan=False))),
        doppler_hz=draw(hnp.arrays(np.float64, p, elements=finite)),
        n_interactions=n,
        interaction=np.where(active, codes, 0),
        points=pts,
        object_id=np.where(active, ids, -1),
        face_id=np.where(active, faces, -1),
    )


@st.composite
def snapshot_strategy(draw):
    n_radars = draw(st.integers(1, 3))
    radar_names = draw(st.lists(names, min_size=n_radars, max_size=n_radars, unique=True))
    pairs = draw(st.lists(st.tuples(st.integers(0, n_radars - 1),
                                    st.integers(0, n_radars - 1)), unique=True, max_size=4))
    links = [Link(radar_names[t], radar_names[r], t, r, draw(paths_strategy()))
             for t, r in pairs]
    meta_values = st.one_of(st.booleans(), st.integers(-2**63, 2**63 - 1),
                            st.floats(width=64), names)
    metadata = draw(st.dictionaries(st.from_regex(r"[A-Za-z0-9_.\-]{1,8}", fullmatch=True),
                                    meta_values, max_size=4))
    return Snapshot(
        scene_name=draw(names),
        carrier_hz=draw(st.floats(1.0, 1e12)),
        scene_hash=draw(st.from_regex(r"[0-9a-f]{0,64}", fullmatch=True)),
        links=links,
        time_s=draw(finite),
        metadata=metadata,
    )


# -- round trip ------------------------------------------------------------------------


def assert_bitwise_equal(a: Snapshot, b: Snapshot):
    """Stricter than ==: every array has the same bytes (-0.0 vs 0.0, NaN payloads)."""
    assert_snapshot_equal(a, b)
    for la, lb in zip(a.links, b.links, strict=True):
        for name in PATH_FIELD_NAMES:
            x, y = getattr(la.paths, name), getattr(lb.paths, name)
            assert x.dtype == y.dtype and x.shape == y.shape
            assert x.tobytes() == y.tobytes(), name


@settings(deadline=None, max_examples=60,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(snap=snapshot_strategy())
def test_round_trip_is_exact(tmp_path, snap):
    path = tmp_path / "s.npz"
    save_snapshot(path, snap)
    back = load_snapshot(path)
    assert back == snap
    assert_bitwise_equal(back, snap)
    # the same snapshot again gives the same bytes, through the loaded copy too
    first = path.read_bytes()
    save_snapshot(path, back)
    assert path.read_bytes() == first


def test_round_trip_fixed_snapshot_keeps_types_and_edge_cases(tmp_path):
    snap = make_snapshot()
    back = load_snapshot(save_snapshot(tmp_path / "s.npz", snap))
    assert back == snap
    assert_bitwise_equal(back, snap)
    assert back.metadata == {"clradcom_version": "0.1.0", "diffraction": True,
                             "max_reflections": 3, "rays": 1e6}
    assert [type(v) for v in back.metadata.values()] == [str, bool, int, float]
    assert back.time_s == 0.125 and back.version == FORMAT_VERSION == 3
    assert back.object_names[1] == "car B" and back.object_name(1) == "car B"
    empty = back.link("D", "D").paths
    assert empty.n_paths == 0 and empty.k_max == 3 and empty.points.shape == (0, 5, 3)
    los = back.link("D", "A").paths
    assert los.k_max == 0 and los.points.shape == (3, 2, 3) and los.interaction.shape == (3, 0)
    # NaN padding survives where it should, and only there
    aa = back.link("A", "A").paths
    assert np.isnan(aa.points[0, 2:]).all() and np.isfinite(aa.points[0, :2]).all()
    assert np.isfinite(aa.points[4]).all()  # 3 interactions of K = 3: no padding


def test_round_trip_without_time_names_and_links(tmp_path):
    snap = Snapshot("nothing", 77e9, "", links=[])
    back = load_snapshot(save_snapshot(tmp_path / "s.npz", snap))
    assert back == snap and back.time_s == 0.0 and len(back) == 0 and back.total_paths == 0
    assert back.object_names == () and back.object_name(3) == "object 3"
    with np.load(tmp_path / "s.npz", allow_pickle=False) as f:
        assert float(f["meta/time_s"]) == 0.0 and f["meta/object_names"].shape == (0,)


def test_loaded_arrays_have_documented_dtypes_and_are_read_only(tmp_path):
    back = load_snapshot(save_snapshot(tmp_path / "s.npz", make_snapshot()))
    p = back.link("A", "A").paths
    want = {"gain": np.complex128, "matrix": np.complex128, "delay_s": np.float64,
            "doppler_hz": np.float64, "n_interactions": np.int16, "interaction": np.int8,
            "points": np.float64, "object_id": np.int32, "face_id": np.int32}
    for name, dtype in want.items():
        arr = getattr(p, name)
        assert arr.dtype == np.dtype(dtype), name
        assert not arr.flags.writeable, name
    with pytest.raises(ValueError):
        p.delay_s[0] = -1.0


def test_paths_copy_their_input():
    delays = np.array([1e-8, 2e-8])
    p = make_paths([0, 0], delays=delays)
    delays[0] = -5.0
    assert p.delay_s[0] == 1e-8


# -- deterministic bytes ---------------------------------------------------------------


def test_two_saves_are_byte_identical_whatever_the_clock(tmp_path, monkeypatch):
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    save_snapshot(a, make_snapshot())
    # a different wall clock (zip members would normally carry it) and a metadata dict
    # built in another order must not change a byte
    later = time.time() + 10 * 365 * 86400
    monkeypatch.setattr(time, "time", lambda: later)
    monkeypatch.setattr(time, "localtime", lambda *args: time.gmtime(later))
    meta = dict(reversed(list(make_snapshot().metadata.items())))
    save_snapshot(b, make_snapshot(metadata=meta))
    assert a.read_bytes() == b.read_bytes()
    with zipfile.ZipFile(b) as zf:
        infos = zf.infolist()
    assert {i.date_time for i in infos} == {(1980, 1, 1, 0, 0, 0)}
    assert {i.compress_type for i in infos} == {zipfile.ZIP_STORED}


def test_different_content_gives_different_bytes(tmp_path):
    a = save_snapshot(tmp_path / "a.npz", make_snapshot())
    b = save_snapshot(tmp_path / "b.npz", make_snapshot(time_s=0.25))
    assert a.read_bytes() != b.read_bytes()


# -- a reader needs only numpy -----------------------------------------------------------


def test_bare_numpy_reads_the_file(tmp_path):
    snap = make_snapshot()
    path = save_snapshot(tmp_path / "s.npz", snap)
    with np.load(path, allow_pickle=False) as f:
        assert str(f["meta/format"]) == "clradcom-snapshot"
        assert int(f["meta/version"]) == 3
        assert float(f["meta/carrier_hz"]) == 24e9
        assert float(f["meta/time_s"]) == 0.125
        assert list(f["meta/object_names"])[:2] == ["road", "car B"]
        assert list(f["links/tx_name"]) == ["A", "A", "D", "D"]
        assert list(f["links/rx_name"]) == ["A", "D", "D", "A"]
        i = list(zip(f["links/tx_name"], f["links/rx_name"], strict=True)).index(("A", "D"))
        gain = f[f"link{i}/gain"]
        assert gain.dtype == np.complex128
        np.testing.assert_array_equal(gain, snap.link("A", "D").paths.gain)
        np.testing.assert_array_equal(f["link0/gain"], snap.link("A", "A").paths.gain)
        assert int(f["metadata/max_reflections"]) == 3
        # the documented docs example: sum of path powers per link
        assert np.isclose(np.sum(np.abs(f["link0/gain"]) ** 2),
                          np.sum(np.abs(snap.links[0].paths.gain) ** 2))


# -- atomic writes ---------------------------------------------------------------------


def _fail_after(monkeypatch, n_ok, exc):
    real = snapmod._write_member
    calls = {"n": 0}

    def flaky(zf, key, array, compress=False):
        calls["n"] += 1
        if calls["n"] > n_ok:
            raise exc
        real(zf, key, array, compress)

    monkeypatch.setattr(snapmod, "_write_member", flaky)
    return calls


@pytest.mark.parametrize("exc", [RuntimeError("disk on fire"), KeyboardInterrupt()])
def test_failed_write_leaves_old_file_and_no_temp(tmp_path, monkeypatch, exc):
    path = save_snapshot(tmp_path / "s.npz", make_snapshot())
    old = path.read_bytes()
    calls = _fail_after(monkeypatch, 7, exc)
    with pytest.raises(type(exc)):
        save_snapshot(path, make_snapshot(time_s=9.0))
    assert calls["n"] == 8  # it really failed half way through
    assert path.read_bytes() == old
    assert os.listdir(tmp_path) == ["s.npz"]
    assert load_snapshot(path) == make_snapshot()


def test_failed_first_write_leaves_nothing(tmp_path, monkeypatch):
    _fail_after(monkeypatch, 3, OSError("no space left on device"))
    with pytest.raises(OSError, match="no space"):
        save_snapshot(tmp_path / "new.npz", make_snapshot())
    assert os.listdir(tmp_path) == []


def test_interrupt_at_fsync_leaves_old_file(tmp_path, monkeypatch):
    path = save_snapshot(tmp_path / "s.npz", make_snapshot())
    old = path.read_bytes()

    def interrupted(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(snapmod.os, "fsync", interrupted)
    with pytest.raises(KeyboardInterrupt):
        save_snapshot(path, make_snapshot(time_s=3.0))
    assert path.read_bytes() == old and os.listdir(tmp_path) == ["s.npz"]


def test_save_uses_exact_name_and_replaces(tmp_path):
    path = tmp_path / "snap.bin"  # no .npz appended behind the user's back
    save_snapshot(path, make_snapshot())
    save_snapshot(path, make_snapshot(time_s=1.0))
    assert os.listdir(tmp_path) == ["snap.bin"]
    assert load_snapshot(path).time_s == 1.0


# -- refusing bad files ----------------------------------------------------------------


@pytest.fixture
def good(tmp_path):
    return save_snapshot(tmp_path / "good.npz", make_snapshot())


def test_future_version_is_refused_naming_file_and_version(good, tmp_path):
    bad = rewrite(good, tmp_path / "future.npz", {"meta/version": np.array(4)})
    with pytest.raises(SnapshotError) as ei:
        load_snapshot(bad)
    msg = str(ei.value)
    assert str(bad) in msg and "version 4" in msg and "upgrade clradcom" in msg
    assert "up to version 3" in msg
    assert ei.value.file == str(bad) and ei.value.key == "meta/version"


#: traced by commit 2a77dfd (the flat layout, format 1) from data/all_mechanisms.toml with
#: max_reflections=3, rays=20_000, max_diffractions=2, diffraction_reflections=1,
#: physical_optics="sbr", scattering=True, scattering_max_reflections=1,
#: scattering_floor=1e-11 on PoCL's CPU device (tests/test_golden_snapshot.py uses it too)
V1_FILE = Path(__file__).parent / "data" / "all_mechanisms_v1.npz"


def test_format_1_file_of_the_old_tracer_loads_as_format_3(tmp_path):
    """A file the format-1 tracer wrote reads as a format-3 snapshot that says where it
    came from; every array is the file's own (format 1 differs only in tagging PO facet
    and SBR returns REFLECTION), object names unknown, time 0, angles from the points,
    and it saves back as format 3."""
    with np.load(V1_FILE, allow_pickle=False) as f:
        assert int(f["meta/version"]) == 1
        raw = {k: f[k] for k in f.files if k.startswith("link")}
    snap = load_snapshot(V1_FILE)
    assert snap.version == FORMAT_VERSION == 3
    assert snap.metadata["snapshot.converted_from_version"] == 1
    assert snap.object_names == () and snap.time_s == 0.0
    # the old flat settings keys are kept as written
    assert snap.metadata["settings.physical_optics"] == "sbr"
    assert snap.metadata["settings.diffraction_reflections"] == 1
    assert list(snap.metadata) == sorted(snap.metadata)
    assert [lk.label for lk in snap] == ["A->A", "A->B"]
    codes = set()
    for i, lk in enumerate(snap.links):
        assert lk.paths.n_paths > 100
        for name in PATH_FIELD_NAMES:
            np.testing.assert_array_equal(getattr(lk.paths, name), raw[f"link{i}/{name}"],
                                          err_msg=f"{lk.label} {name}")
        codes |= set(np.unique(lk.paths.interaction).tolist())
    assert codes == {0, 1, 2, 3}  # no PO or SBR codes in format 1
    again = load_snapshot(save_snapshot(tmp_path / "v3.npz", snap))
    assert_snapshot_equal(again, snap)
    assert again.metadata["snapshot.converted_from_version"] == 1
    with np.load(tmp_path / "v3.npz", allow_pickle=False) as f:
        assert int(f["meta/version"]) == 3
        # the angles written for the converted file are those of its points
        ang = snap.links[0].paths.angles
        np.testing.assert_array_equal(f["link0/theta_r"], ang.theta_r)


def as_old_format(good, dst, version, *, keep_time=True):
    """``good`` (format 3) rewritten as a file of format 1 or 2: no object names, no
    angles, and (keep_time=False) no time."""
    with np.load(good) as f:
        v3_only = [k for k in f.files if k == "meta/object_names"
                   or k.split("/")[-1] in snapmod.ANGLE_FIELD_NAMES]
    change = {"meta/version": np.array(version), **dict.fromkeys(v3_only)}
    if not keep_time:
        change["meta/time_s"] = None
    return rewrite(good, dst, change)


@pytest.mark.parametrize("version", [1, 2])
def test_older_format_rewritten_file_is_converted(good, tmp_path, version):
    snap = load_snapshot(as_old_format(good, tmp_path / "old.npz", version))
    assert snap.version == 3 and snap.metadata["snapshot.converted_from_version"] == version
    assert "snapshot.converted_from_version" not in load_snapshot(good).metadata
    assert snap.links == load_snapshot(good).links
    assert snap.object_names == () and snap.time_s == 0.125
    untimed = load_snapshot(as_old_format(good, tmp_path / "untimed.npz", version,
                                          keep_time=False))
    assert untimed.time_s == 0.0
    assert "object names unknown" in untimed.summary()


def test_version_3_needs_time_names_and_angles(good, tmp_path):
    for key in ("meta/time_s", "meta/object_names", "link0/phi_t", "link3/theta_r"):
        with pytest.raises(SnapshotError, match="missing key") as ei:
            load_snapshot(rewrite(good, tmp_path / "x.npz", {key: None}))
        assert ei.value.key == key


def test_stored_angles_must_match_the_points(good, tmp_path):
    with np.load(good) as f:
        phi = f["link0/phi_r"].copy()
    phi[2] += 1e-6
    bad = rewrite(good, tmp_path / "ang.npz", {"link0/phi_r": phi})
    with pytest.raises(SnapshotError, match=r"link0/phi_r\[2\]: stored angle .*inconsistent"):
        load_snapshot(bad)
    phi[2] -= 1e-6 - 2 * np.pi  # the same azimuth one turn on: accepted
    assert load_snapshot(rewrite(good, tmp_path / "turn.npz", {"link0/phi_r": phi})) \
        == load_snapshot(good)


def test_object_ids_must_have_names(good, tmp_path):
    with pytest.raises(SnapshotError, match=r"link0/object_id: object id \d+ .* names 2 "
                                            "objects") as ei:
        load_snapshot(rewrite(good, tmp_path / "n.npz",
                              {"meta/object_names": np.array(["road", "car"])}))
    assert str(tmp_path / "n.npz") in str(ei.value)


def test_invalid_version_is_refused(good, tmp_path):
    bad = rewrite(good, tmp_path / "v0.npz", {"meta/version": np.array(0)})
    with pytest.raises(SnapshotError, match="invalid snapshot format version 0"):
        load_snapshot(bad)


@pytest.mark.parametrize("key", ["link0/delay_s", "meta/carrier_hz", "links/rx_name",
                                 "link3/face_id", "meta/version"])
def test_missing_key_is_named(good, tmp_path, key):
    bad = rewrite(good, tmp_path / "missing.npz", {key: None})
    with pytest.raises(SnapshotError, match="missing key") as ei:
        load_snapshot(bad)
    assert ei.value.key == key and str(bad) in str(ei.value) and key in str(ei.value)


def test_unknown_key_is_refused(good, tmp_path):
    bad = rewrite(good, tmp_path / "extra.npz", {"link4/gain": np.zeros(1, complex)})
    with pytest.raises(SnapshotError, match="unknown key") as ei:
        load_snapshot(bad)
    assert ei.value.key == "link4/gain"


@pytest.mark.parametrize("key, value, words", [
    ("link0/gain", np.zeros(5, np.complex64), ["link0/gain", "complex64"]),
    ("link1/n_interactions", np.zeros(2, np.int64), ["link1/n_interactions", "int64"]),
    ("link0/delay_s", np.array(["a"] * 5), ["link0/delay_s", "<U1"]),
    ("meta/carrier_hz", np.array("24e9"), ["meta/carrier_hz", "<U4"]),
    ("meta/scene_name", np.array([1, 2]), ["meta/scene_name", "int64"]),
])
def test_wrong_dtype_is_named(good, tmp_path, key, value, words):
    bad = rewrite(good, tmp_path / "dtype.npz", {key: value})
    with pytest.raises(SnapshotError) as ei:
        load_snapshot(bad)
    assert ei.value.key == key
    for w in [str(bad), "dtype", *words]:
        assert w in str(ei.value)


@pytest.mark.parametrize("key, value, words", [
    ("link0/matrix", np.zeros((5, 2, 3), complex), ["(5, 2, 3)", "(P, 2, 2)"]),
    ("link0/points", np.zeros((5, 4, 3)), ["(5, 4, 3)", "K+2"]),
    ("link2/gain", np.zeros((1,), complex), ["P = 1"]),
    ("links/tx_index", np.array([0, 0, 1]), ["(3,)", "(4,)"]),
])
def test_wrong_shape_is_named(good, tmp_path, key, value, words):
    bad = rewrite(good, tmp_path / "shape.npz", {key: value})
    with pytest.raises(SnapshotError) as ei:
        load_snapshot(bad)
    assert str(bad) in str(ei.value)
    for w in words:
        assert w in str(ei.value)


def test_bad_value_in_file_is_named_with_index(good, tmp_path):
    with np.load(good) as f:
        delays = f["link0/delay_s"].copy()
    delays[3] = -1e-9
    bad = rewrite(good, tmp_path / "neg.npz", {"link0/delay_s": delays})
    with pytest.raises(SnapshotError, match=r"link0/delay_s\[3\].*>= 0") as ei:
        load_snapshot(bad)
    assert str(bad) in str(ei.value)


def test_inconsistent_link_table_is_refused(good, tmp_path):
    bad = rewrite(good, tmp_path / "dup.npz", {"links/rx_name": np.array(["A", "A", "D", "A"])})
    with pytest.raises(SnapshotError, match="appears twice"):
        load_snapshot(bad)


def test_corrupted_data_is_refused(good, tmp_path):
    raw = bytearray(good.read_bytes())
    with zipfile.ZipFile(good) as zf:
        info = zf.getinfo("link0/points.npy")
    # flip a byte inside the member's data (past its local header): the CRC catches it
    raw[info.header_offset + 200] ^= 0xFF
    bad = tmp_path / "flipped.npz"
    bad.write_bytes(bytes(raw))
    with pytest.raises(SnapshotError, match="corrupt") as ei:
        load_snapshot(bad)
    assert str(bad) in str(ei.value) and ei.value.key == "link0/points"


def test_truncated_and_foreign_files_are_refused(good, tmp_path):
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[: len(good.read_bytes()) // 2])
    with pytest.raises(SnapshotError, match="not a zip") as ei:
        load_snapshot(cut)
    assert str(cut) in str(ei.value)

    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(SnapshotError, match="not a zip"):
        load_snapshot(text)

    npy = tmp_path / "array.npy"
    np.save(npy, np.arange(3))
    with pytest.raises(SnapshotError, match="not a zip"):
        load_snapshot(npy)

    other = tmp_path / "other.npz"
    np.savez(other, x=np.arange(3))
    with pytest.raises(SnapshotError, match="not a clradcom snapshot"):
        load_snapshot(other)

    pickled = tmp_path / "pickled.npz"
    buf = io.BytesIO()
    np.save(buf, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with zipfile.ZipFile(pickled, "w") as zf:
        with np.load(good) as f:
            for k in f.files:
                b = io.BytesIO()
                np.save(b, f[k])
                zf.writestr(k + ".npy", b.getvalue())
        zf.writestr("metadata/evil.npy", buf.getvalue())
    with pytest.raises(SnapshotError, match="metadata/evil"):
        load_snapshot(pickled)

    with pytest.raises(FileNotFoundError, match="missing.npz"):
        load_snapshot(tmp_path / "missing.npz")


# -- validation on construction --------------------------------------------------------


def _paths_kw(**change):
    p = make_paths([0, 1, 2], seed=5)
    kw = {name: np.array(getattr(p, name)) for name in PATH_FIELD_NAMES}
    for key, fn in change.items():
        kw[key] = fn(kw[key])
    return kw


def _set(index, value):
    def fn(a):
        a = a.copy()
        a[index] = value
        return a
    return fn


@pytest.mark.parametrize("change, pattern", [
    ({"delay_s": _set(2, -1e-12)}, r"delay_s\[2\].*>= 0"),
    ({"delay_s": _set(1, np.inf)}, r"delay_s\[1\].*finite"),
    ({"gain": _set(2, complex(np.nan, 0))}, r"gain\[2\].*finite"),
    ({"matrix": _set((1, 0, 1), np.inf)}, r"matrix\[1, 0, 1\].*finite"),
    ({"doppler_hz": _set(0, np.nan)}, r"doppler_hz\[0\].*finite"),
    ({"n_interactions": _set(2, 3)}, r"n_interactions\[2\].*\[0, K = 2\]"),
    ({"n_interactions": _set(0, -1)}, r"n_interactions\[0\]"),
    ({"interaction": _set((2, 1), 6)}, r"interaction\[2, 1\].*code 1"),
    ({"interaction": _set((1, 0), 0)}, r"interaction\[1, 0\].*code 1"),
    ({"interaction": _set((1, 1), 2)}, r"interaction\[1, 1\].*padding.*0"),
    ({"object_id": _set((2, 0), -1)}, r"object_id\[2, 0\].*>= 0"),
    ({"face_id": _set((0, 1), 7)}, r"face_id\[0, 1\].*-1"),
    ({"points": _set((1, 2, 0), np.nan)}, r"points\[1, 2, 0\].*finite"),
    ({"points": _set((0, 3, 2), 1.0)}, r"points\[0, 3, 2\].*NaN"),
    ({"object_id": lambda a: _set((2, 1), 2**31)(a.astype(np.int64))},
     r"object_id.*does not fit in int32"),
    ({"matrix": lambda a: a[:, :, :1]}, r"matrix: shape \(3, 2, 1\)"),
    ({"face_id": lambda a: a[:2]}, r"face_id: shape \(2, 2\)"),
    ({"interaction": lambda a: a.astype(float)}, r"interaction.*not an integer"),
    ({"delay_s": lambda a: a + 0j}, r"delay_s.*not real"),
    ({"gain": lambda a: a.reshape(3, 1)}, r"gain: shape \(3, 1\)"),
])
def test_paths_refuse_bad_values_naming_field_and_index(change, pattern):
    with pytest.raises(ValueError, match=pattern):
        Paths(**_paths_kw(**change))


def test_paths_accept_lists_and_real_gains():
    p = Paths(gain=[0.5], matrix=[[[1, 0], [0, -1]]], delay_s=[0.0], doppler_hz=[-3],
              n_interactions=[0], interaction=[[]], points=[[[0, 0, 0], [1, 2, 3]]],
              object_id=[[]], face_id=[[]])
    assert p.gain.dtype == np.complex128 and p.k_max == 0 and len(p) == 1
    assert Paths.empty() == Paths.empty(0) and Paths.empty(0) != Paths.empty(1)
    with pytest.raises(ValueError, match="k_max"):
        Paths.empty(-1)


def test_interaction_type_codes():
    assert [int(t) for t in InteractionType] == [0, 1, 2, 3, 4, 5]
    assert InteractionType.REFLECTION == 1 and InteractionType(3).name == "SCATTERING"
    assert InteractionType(4).name == "PHYSICAL_OPTICS" and InteractionType(5).name == "SBR"
    p = make_snapshot().link("A", "A").paths
    assert set(np.unique(p.interaction)) <= {int(t) for t in InteractionType}


@pytest.mark.parametrize("change, pattern", [
    ({"carrier_hz": 0.0}, "carrier_hz"),
    ({"carrier_hz": float("nan")}, "carrier_hz"),
    ({"scene_hash": "xyz"}, "scene_hash.*hex"),
    ({"scene_name": 3}, "scene_name.*str"),
    ({"scene_name": "a\x00b"}, "scene_name.*NUL"),
    ({"time_s": float("inf")}, "time_s"),
    ({"time_s": None}, "time_s.*real number"),
    ({"object_names": "road"}, "object_names.*list of str"),
    ({"object_names": ["road", 3]}, r"object_names\[1\].*str"),
    ({"object_names": ["road"]}, r"links\[0\].object_id.*names 1 objects"),
    ({"metadata": {"rays": [1, 2]}}, "metadata.rays.*only bool, int, float and str"),
    ({"metadata": {"bad key": 1}}, "metadata.*'bad key'"),
    ({"metadata": {"big": 2**64}}, "metadata.big.*int64"),
    ({"version": 2}, "only format version 3 can be built, got 2"),
    ({"version": 4}, "only format version 3 can be built, got 4"),
    ({"links": [Link("A", "A", 0, 0, Paths.empty()), Link("A", "A", 0, 0, Paths.empty())]},
     r"links\[1\].*A->A appears twice"),
    ({"links": [Link("A", "A", 0, 0, Paths.empty()), Link("A", "D", 1, 1, Paths.empty())]},
     r"links\[1\].tx_index.*'A' has index 1"),
    ({"links": [Link("A", "A", 0, 0, Paths.empty()), Link("D", "D", 0, 0, Paths.empty())]},
     r"links\[1\].tx_name.*index 0"),
    ({"links": ["A->A"]}, r"links\[0\].*Link"),
])
def test_snapshot_refuses_bad_fields(change, pattern):
    with pytest.raises(ValueError, match=pattern):
        make_snapshot(**change)


def test_link_refuses_bad_fields():
    with pytest.raises(ValueError, match="tx_index.*>= 0"):
        Link("A", "A", -1, 0, Paths.empty())
    with pytest.raises(ValueError, match="rx_index.*int"):
        Link("A", "A", 0, 1.0, Paths.empty())
    with pytest.raises(ValueError, match="paths.*Paths"):
        Link("A", "A", 0, 0, None)


# -- conveniences and comparison -------------------------------------------------------


def test_lookup_iteration_and_counts():
    snap = make_snapshot()
    assert snap.link("A", "D").paths.n_paths == 2
    assert snap.link(1, 0) is snap.link("D", "A")
    assert [lk.label for lk in snap] == ["A->A", "A->D", "D->D", "D->A"]
    assert len(snap) == 4 and snap.total_paths == 5 + 2 + 0 + 3
    with pytest.raises(KeyError, match="no link 'D' -> 'X'.*A->A, A->D, D->D, D->A"):
        snap.link("D", "X")


def test_summary_reports_counts_power_and_delays():
    gains = np.array([1e-3, 1e-5j])  # strongest: 20 log10(1e-3) = -60 dB
    delays = np.array([40e-9, 125e-9])
    snap = make_snapshot(links=[Link("A", "A", 0, 0, make_paths([1, 0], gains=gains,
                                                                delays=delays)),
                                Link("A", "D", 0, 1, Paths.empty())])
    text = snap.summary()
    assert "'street'" in text and "24 GHz" in text and "2 links, 2 paths" in text
    row = next(line for line in text.splitlines() if line.strip().startswith("A->A"))
    assert row.split()[1:] == ["2", "1", "-60.00", "40.000..125.000"]
    row = next(line for line in text.splitlines() if line.strip().startswith("A->D"))
    assert row.split()[1:] == ["0", "0", "-", "-"]
    assert "max_reflections = 3" in text


def test_equality_is_exact_and_names_the_difference():
    a = make_snapshot()
    assert a == make_snapshot() and a != make_snapshot(time_s=0.0)
    with pytest.raises(AssertionError, match="object_names"):
        assert_snapshot_equal(a, make_snapshot(object_names=[*a.object_names, "extra"]))
    kw = {n: np.array(getattr(a.links[0].paths, n)) for n in PATH_FIELD_NAMES}
    kw["doppler_hz"][4] = np.nextafter(kw["doppler_hz"][4], np.inf)  # one ulp
    b = make_snapshot(links=[Link("A", "A", 0, 0, Paths(**kw)), *a.links[1:]])
    assert a != b
    with pytest.raises(AssertionError, match=r"links\[0\] \(A->A\).doppler_hz: at \[4\]"):
        assert_snapshot_equal(a, b)
    with pytest.raises(AssertionError, match="metadata.rays"):
        assert_snapshot_equal(a, make_snapshot(metadata={**a.metadata, "rays": 1_000_000}))
    assert make_snapshot(metadata={"x": float("nan")}) == make_snapshot(
        metadata={"x": float("nan")})
