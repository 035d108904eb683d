"""Snapshot format 3: angles of departure and arrival, object names and time, optional
compression with the reader's size limit on what the archive unpacks to."""

import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from clradcom.errors import SnapshotError
from clradcom.paths import Paths, path_angles
from clradcom.snapshot import Link, Snapshot, load_snapshot, save_snapshot

V1_FILE = Path(__file__).parent / "data" / "all_mechanisms_v1.npz"


def polyline_paths(polylines) -> Paths:
    """Paths whose points are the given polylines (tx, interactions..., rx)."""
    k = max(len(p) for p in polylines) - 2
    n = len(polylines)
    pts = np.full((n, k + 2, 3), np.nan)
    n_int = np.zeros(n, np.int16)
    for i, line in enumerate(polylines):
        pts[i, :len(line)] = line
        n_int[i] = len(line) - 2
    active = np.arange(k)[None, :] < n_int[:, None]
    return Paths(gain=np.ones(n, complex), matrix=np.ones((n, 2, 2), complex),
                 delay_s=np.full(n, 1e-8), doppler_hz=np.zeros(n), n_interactions=n_int,
                 interaction=np.where(active, 1, 0), points=pts,
                 object_id=np.where(active, 0, -1), face_id=np.where(active, 0, -1))


def test_angles_of_hand_made_paths():
    s2 = np.sqrt(2.0)
    paths = polyline_paths([
        [(0, 0, 0), (1, 1, s2)],                       # line of sight, up at 45 deg
        [(0, 0, 1), (0, 0, 6), (3, 0, 6), (3, -4, 6)],  # straight up, then two legs
        [(2, 2, 2), (2, 2, 2)],                       # zero length: no direction
    ])
    a = path_angles(paths)
    deg = {name: np.degrees(v) for name, v in a._asdict().items()}
    np.testing.assert_allclose([deg["theta_t"][0], deg["phi_t"][0]], [45, 45], atol=1e-12)
    # arrival: from the rx back to the tx, (-1, -1, -sqrt 2)
    np.testing.assert_allclose([deg["theta_r"][0], deg["phi_r"][0]], [135, -135], atol=1e-12)
    assert deg["theta_t"][1] == 0.0  # departs along +z
    # arrives from the last interaction (3, 0, 6): from the rx that is +y, horizontal
    np.testing.assert_allclose([deg["theta_r"][1], deg["phi_r"][1]], [90, 90], atol=1e-12)
    assert all(np.isnan(v[2]) for v in a)


def test_angles_give_back_the_directions_of_a_traced_snapshot():
    """Independent check on 814 traced paths: the unit vector r(theta, phi) (Sionna's
    primer, eq. 1) is the normalised first leg and the reversed last leg."""
    snap = load_snapshot(V1_FILE)
    for link in snap:
        p = link.paths
        a = p.angles
        rows = np.arange(p.n_paths)
        n = p.n_interactions.astype(int)
        for theta, phi, d in ((a.theta_t, a.phi_t, p.points[rows, 1] - p.points[rows, 0]),
                              (a.theta_r, a.phi_r, p.points[rows, n] - p.points[rows, n + 1])):
            r = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                          np.cos(theta)], axis=1)
            np.testing.assert_allclose(r, d / np.linalg.norm(d, axis=1)[:, None], atol=1e-12)
            assert np.all((theta >= 0) & (theta <= np.pi) & (np.abs(phi) <= np.pi))


def test_trace_style_snapshot_keeps_names_time_and_angles(tmp_path):
    snap = load_snapshot(V1_FILE)
    names = [f"object {i}" for i in range(20)]
    names[3] = "car"
    timed = replace(snap, time_s=2.5, object_names=names, metadata={})
    back = load_snapshot(save_snapshot(tmp_path / "t.npz", timed))
    assert back == timed and back.time_s == 2.5 and back.object_name(3) == "car"
    with np.load(tmp_path / "t.npz", allow_pickle=False) as f:
        for i, link in enumerate(snap):
            for name, values in link.paths.angles._asdict().items():
                np.testing.assert_array_equal(f[f"link{i}/{name}"], values)


def test_compressed_snapshot_is_smaller_and_read_by_numpy_alone(tmp_path):
    snap = load_snapshot(V1_FILE)
    plain = save_snapshot(tmp_path / "plain.npz", snap)
    packed = save_snapshot(tmp_path / "packed.npz", snap, compress=True)
    assert packed.stat().st_size < 0.6 * plain.stat().st_size
    with zipfile.ZipFile(packed) as zf:
        assert {i.compress_type for i in zf.infolist()} == {zipfile.ZIP_DEFLATED}
    with np.load(packed, allow_pickle=False) as f, np.load(plain, allow_pickle=False) as g:
        assert sorted(f.files) == sorted(g.files)
        for key in g.files:
            np.testing.assert_array_equal(f[key], g[key])
    assert load_snapshot(packed) == snap
    again = save_snapshot(tmp_path / "again.npz", load_snapshot(packed), compress=True)
    assert again.read_bytes() == packed.read_bytes()
    with pytest.raises(TypeError, match="compress"):
        save_snapshot(tmp_path / "x.npz", snap, compress="yes")


def test_compressed_file_is_refused_beyond_the_limit_naming_it(tmp_path):
    snap = load_snapshot(V1_FILE)
    packed = save_snapshot(tmp_path / "packed.npz", snap, compress=True)
    with zipfile.ZipFile(packed) as zf:
        declared = sum(i.file_size for i in zf.infolist())
    assert declared > 2 * packed.stat().st_size
    assert load_snapshot(packed, max_bytes=declared) == snap
    with pytest.raises(SnapshotError, match="compressed members unpack to more than") as ei:
        load_snapshot(packed, max_bytes=declared - 1)
    assert str(packed) in str(ei.value)


def test_a_deflated_member_that_is_no_array_is_refused_before_inflating(tmp_path):
    """numpy reads a member without the .npy magic whole: a deflate bomb under a key
    the reader asks for is caught by the declared size, not by an array header."""
    path = tmp_path / "bomb.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("meta/format.npy", "w", force_zip64=True) as m:
            chunk = bytes(2**24)
            for _ in range(16):  # 256 MiB of zeros, about 0.3 MB deflated
                m.write(chunk)
    with pytest.raises(SnapshotError, match=r"meta/format: .*more than 1048576 bytes"):
        load_snapshot(path, max_bytes=2**20)


def test_time_is_settable_and_zero_by_default():
    snap = Snapshot("s", 24e9, "", links=[Link("A", "A", 0, 0, Paths.empty())])
    assert snap.time_s == 0.0 and replace(snap, time_s=0.04).time_s == 0.04
    assert "t = 0.04 s" in replace(snap, time_s=0.04).summary()
