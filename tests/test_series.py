"""Coherent path series over time (clradcom.series, clradcom drive).

The drive-by: a PEC triangular trihedral (apex at the origin, plates of edge a on the
planes x = 0, y = 0, z = 0) and a radar driving past it on a straight line at v, closest
approach D at t = 0. Transmit and receive antennas sit at m +- d around the radar's
reference point m (d = (delta, 0, -delta): the three mirrors' crossing order stays the
same over the pass, so the triple bounce is one path throughout). The triple-bounce image
of the transmitter is -tx, so the unfolded path length is exactly
    L = |rx - (-tx)| = |tx + rx| = 2 |m| = 2 R(t),
its phase -2 pi L / lambda = -4 pi R(t) / lambda: the SAR quadratic phase history
(R(t) ~ D + (v t)^2 / (2 D)), its Doppler -(1/lambda) dL/dt = -(2/lambda) v . m / |m|.
"""

from __future__ import annotations

import numpy as np
import pytest

from clradcom import cli
from clradcom.errors import ArgumentError, SnapshotError
from clradcom.paths import concat_paths, select_paths
from clradcom.physics.em import C0
from clradcom.scene.reader import scene_from_dict
from clradcom.series import (
    load_series,
    match_paths,
    path_keys,
    save_series,
    trace_series,
    unwrap_phase,
)
from clradcom.trace import DiffractionSettings, SpecularSettings, TraceSettings

F_C = 24e9
LAM = C0 / F_C
A, D, V, T = 1.0, 10.0, 10.0, 0.3
CLOSEST = D * np.ones(3) / np.sqrt(3)
U = np.array([1.0, -1.0, 0.0]) / np.sqrt(2)  # horizontal, across the corner's axis
OFFSET = np.array([0.05, 0.0, -0.05])
SETTINGS = TraceSettings(specular=SpecularSettings(max_reflections=3, rays=200_000),
                         diffraction=DiffractionSettings(max_diffractions=0))


def drive_by_doc(count=61):
    def trajectory(off):
        return [[-T, *(CLOSEST - V * T * U + off)], [T, *(CLOSEST + V * T * U + off)]]

    corner = {"name": "corner", "material": "metal", "shape": "triangles",
              "vertices": [[0, 0, 0], [A, 0, 0], [0, A, 0], [0, 0, A]],
              "faces": [[0, 2, 3], [0, 3, 1], [0, 1, 2]]}
    return {"scene": {"name": "drive_by", "carrier_hz": F_C}, "objects": [corner],
            "radars": [{"name": "tx", "role": "tx", "trajectory": trajectory(OFFSET)},
                       {"name": "rx", "role": "rx", "trajectory": trajectory(-OFFSET)}],
            "time": {"start_s": -T, "step_s": 2 * T / (count - 1), "count": count}}


@pytest.fixture(scope="module")
def drive_by(runtime):
    scene = scene_from_dict(drive_by_doc())
    snaps = []
    series = trace_series(scene, SETTINGS, runtime=runtime,
                          each=lambda k, t, s: snaps.append(s))
    return scene, series, snaps


def test_drive_by_phase_history_is_the_sar_quadratic_phase(drive_by):
    scene, series, snaps = drive_by
    assert series.n_steps == 61
    assert [s.time_s for s in snaps] == pytest.approx(series.time_s)
    triple = [n for n in range(series.n_tracks) if series.n_interactions[n] == 3]
    assert len(triple) == 1  # one path, followed over the whole pass
    n = triple[0]
    assert series.present[:, n].all()
    assert sorted(series.face_id[n, :3]) == [0, 1, 2]
    t = series.time_s
    m = CLOSEST + V * t[:, None] * U
    R = np.linalg.norm(m, axis=1)
    k0 = int(np.argmin(R))
    assert t[k0] == pytest.approx(0.0, abs=1e-12)
    want = -4 * np.pi * (R - R[k0]) / LAM
    got = unwrap_phase(series, n)
    got = got - got[k0]
    assert np.abs(want).max() > 2 * np.pi * 50  # the pass spans 70 turns of phase
    assert np.degrees(np.abs(got - want)).max() < 1.0
    # delay 2R/c, continuous: it never moves faster than the radar's speed allows
    np.testing.assert_allclose(series.delay_s[:, n], 2 * R / C0, rtol=1e-12)
    dt = t[1] - t[0]
    assert np.abs(np.diff(series.delay_s[:, n])).max() <= 2 * V * dt / C0 * (1 + 1e-9)
    np.testing.assert_allclose(series.doppler_hz[:, n], -(2 / LAM) * (m @ (V * U)) / R,
                               rtol=1e-9, atol=1e-9)
    # plain numpy.unwrap of the same phases aliases at these steps (up to ~2.6 turns each)
    assert np.degrees(np.abs(np.unwrap(np.angle(series.gain[:, n])) - np.angle(
        series.gain[k0, n]) - want)).max() > 90


def test_matching_pairs_paths_by_identity(drive_by):
    _, _, snaps = drive_by
    a = snaps[10].links[0].paths
    b = snaps[11].links[0].paths
    i, j = match_paths(a, b)
    assert len(i) == len(a.gain) == len(b.gain)
    assert [path_keys(a)[k] for k in i] == [path_keys(b)[k] for k in j]
    # reorder the second step: the pairs follow the paths, not their places
    rev = select_paths(b, np.arange(len(b.gain))[::-1])
    i2, j2 = match_paths(a, rev)
    assert len(i2) == len(a.gain)
    assert np.array_equal(j2, len(b.gain) - 1 - j[np.argsort(i)][i2])
    for x, y in zip(i2, j2, strict=True):
        assert path_keys(a)[x] == path_keys(rev)[y]
    # a path that vanishes is left unpaired; a duplicate key pairs by delay
    only_los = select_paths(b, b.n_interactions == 0)
    i3, j3 = match_paths(a, only_los)
    assert len(i3) == 1 and a.n_interactions[i3[0]] == 0
    twice = concat_paths([a, a])
    i4, j4 = match_paths(twice, twice)
    assert np.array_equal(i4, j4)


def test_series_file_round_trip_and_refusals(drive_by, tmp_path):
    _, series, _ = drive_by
    path = save_series(tmp_path / "series.npz", series)
    back = load_series(path)
    for name in ("time_s", "link", "n_interactions", "interaction", "object_id", "face_id",
                 "present", "gain", "delay_s", "doppler_hz", "tx_index", "rx_index"):
        assert np.array_equal(getattr(back, name), getattr(series, name), equal_nan=True) \
            if getattr(series, name).dtype.kind in "fc" else np.array_equal(
                getattr(back, name), getattr(series, name)), name
    assert back.tx_name == ("tx",) and back.rx_name == ("rx",)
    assert back.scene_hash == series.scene_hash and len(set(back.scene_hash)) == 61
    assert save_series(tmp_path / "again.npz", back).read_bytes() == path.read_bytes()
    with np.load(path) as z:
        assert str(z["meta/format"]) == "clradcom-series" and int(z["meta/version"]) == 1
        data = {k: z[k] for k in z.files}
    data["meta/version"] = np.array(2)
    np.savez(tmp_path / "v2.npz", **data)
    with pytest.raises(SnapshotError, match="version") as exc:
        load_series(tmp_path / "v2.npz")
    assert exc.value.key == "meta/version"
    data["meta/version"] = np.array(1)
    data["values/gain"] = data["values/gain"][:3]
    np.savez(tmp_path / "short.npz", **data)
    with pytest.raises(SnapshotError, match="shape") as exc:
        load_series(tmp_path / "short.npz")
    assert exc.value.key == "values/gain"


def test_trace_series_refuses_bad_times(runtime):
    scene = scene_from_dict(drive_by_doc())
    for bad in ([], [0.0, 0.0], [0.0, float("nan")], "soon"):
        with pytest.raises(ArgumentError) as exc:
            trace_series(scene, SETTINGS, bad, runtime=runtime)
        assert exc.value.argument == "times"
    with pytest.raises(ArgumentError, match="outside the trajectory"):
        trace_series(scene, SETTINGS, [0.0, 1.0], runtime=runtime)


def test_drive_command_writes_the_series(drive_by, tmp_path, capsys):
    scene_file = tmp_path / "drive_by.toml"
    scene_file.write_text(_toml(drive_by_doc()))
    out = tmp_path / "out"
    # every 10th instant of the fixture's pass: the same paths, the same numbers
    code = cli.main(["drive", str(scene_file), "--out", str(out), "--preset", "go",
                     "--rays", "200000", "--reflections", "3", "--step", "0.1",
                     "--count", "7", "--snapshots", "--no-scattering", "--workers", "0"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "step 7/7" in text
    written = load_series(out / "series.npz")
    assert sorted(p.name for p in out.iterdir()) == ["series.npz"] + [
        f"snapshot_{k:04d}.npz" for k in range(7)]
    _, series, _ = drive_by
    np.testing.assert_allclose(written.time_s, series.time_s[::10], atol=1e-15)
    n = int(np.flatnonzero(series.n_interactions == 3)[0])
    w = int(np.flatnonzero(written.n_interactions == 3)[0])
    np.testing.assert_allclose(written.delay_s[:, w], series.delay_s[::10, n], rtol=1e-12)
    # without a [time] table the command asks for --step and --count
    doc = drive_by_doc()
    del doc["time"]
    doc["radars"] = [{"name": "r", "position": [5.0, 5.0, 5.0]}]
    (tmp_path / "still.toml").write_text(_toml(doc))
    assert cli.main(["drive", str(tmp_path / "still.toml"), "--out", str(out)]) == 2
    assert "--step" in capsys.readouterr().err


def _toml(doc) -> str:
    """A small TOML writer for the test scene (tables, arrays of tables, numbers)."""
    def value(v):
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, list | tuple | np.ndarray):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(float(v)) if isinstance(v, float | np.floating) else str(v)
    lines = []
    for key in ("scene", "time"):
        if key not in doc:
            continue
        lines.append(f"[{key}]")
        lines += [f"{k} = {value(v)}" for k, v in doc[key].items()]
    for key in ("objects", "radars"):
        for tbl in doc[key]:
            lines.append(f"[[{key}]]")
            lines += [f"{k} = {value(v)}" for k, v in tbl.items()]
    return "\n".join(lines) + "\n"
