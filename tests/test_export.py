"""Exports of a snapshot: Sionna-style arrays with the channel frequency response, and
MATLAB .mat files read back with scipy."""

import cmath
import math
import subprocess
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scipy.io as sio

from clradcom.errors import ArgumentError
from clradcom.export import (
    channel_frequency_response,
    mat_variables,
    save_mat,
    save_sionna,
    sionna_arrays,
)
from clradcom.radar.synthesis import channel_transfer_function
from clradcom.radar.waveform import Waveform
from clradcom.snapshot import Link, Snapshot, load_snapshot, save_snapshot

REPO = Path(__file__).resolve().parents[1]
V1_FILE = REPO / "tests" / "data" / "all_mechanisms_v1.npz"


@pytest.fixture(scope="module")
def snap():
    s = load_snapshot(V1_FILE)
    return replace(s, time_s=0.5, object_names=[f"obj{i}" for i in range(20)])


def test_cfr_equals_the_radar_models_transfer_function(snap):
    """h_freq at the paper's subcarrier frequencies n * delta_f is the radar model's
    H(n, 0) (clradcom.radar.synthesis, one outer product per path), link by link."""
    wf = Waveform(n_subcarriers=256, n_symbols=2)
    f = np.arange(wf.n_subcarriers) * wf.subcarrier_spacing_hz
    out = sionna_arrays(snap, f)
    for link in snap:
        r = list(out["rx_names"]).index(link.rx_name)
        t = list(out["tx_names"]).index(link.tx_name)
        p = link.paths
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # paths beyond the cyclic prefix: irrelevant
            want = channel_transfer_function(p.gain, p.delay_s, p.doppler_hz, wf,
                                             method="direct")[:, 0]
        scale = np.sum(np.abs(p.gain))
        assert np.max(np.abs(out["h_freq"][r, t] - want)) < 1e-12 * scale


def test_cfr_equals_a_scalar_sum_over_the_paths(snap):
    """Brute force with Python's cmath, path by path, at radio-frequency offsets spread
    over +-100 MHz (and 0), where the reduced phase matters."""
    f = np.array([-1e8, -12345.678, 0.0, 3.3e7, 1e8])
    out = sionna_arrays(snap, f)
    link = snap.link("A", "B")
    r, t = list(out["rx_names"]).index("B"), 0
    for j, fj in enumerate(f):
        want = sum(complex(a) * cmath.exp(-2j * math.pi * float(fj) * float(tau))
                   for a, tau in zip(link.paths.gain, link.paths.delay_s, strict=True))
        assert abs(out["h_freq"][r, t, j] - want) < 1e-12 * np.sum(np.abs(link.paths.gain))


def test_carrier_phase_off_gives_sionnas_a_and_leaves_the_channel(snap):
    """--no-carrier-phase exports Sionna RT's passband a (a = g e^{+j2pi f_c tau}); the
    CFR stays the channel at f_c + f, bit for bit: before, h_freq was summed from that a
    and so left every path's carrier phase out (Sionna's cir() puts it back), a different
    channel (docs/snapshot-format.md, "Sionna's cfr()")."""
    fc = snap.carrier_hz
    offsets = np.array([0.0, 1e6, -2.5e6])
    ours = sionna_arrays(snap, offsets)
    theirs = sionna_arrays(snap, offsets, carrier_phase=False)
    ok = ours["valid"]
    want = ours["a"][ok] * np.exp(2j * np.pi * fc * ours["tau"][ok])
    np.testing.assert_allclose(theirs["a"][ok], want, rtol=1e-9)
    np.testing.assert_array_equal(theirs["h_freq"], ours["h_freq"])


def sionna_cfr(a_passband, tau, carrier_hz, f, normalize_delays):
    """Sionna RT's Paths.cir() and cfr() as their documentation writes them, path by path
    with cmath: a_b = a e^{-j2pi f_c tau'}, H(f) = sum a_b e^{-j2pi f tau'}, tau' = tau less
    the link's first delay when normalize_delays (its default)."""
    shift = min(tau) if normalize_delays else 0.0
    out = []
    for fj in f:
        total = 0j
        for a, t in zip(a_passband, tau, strict=True):
            t = float(t) - shift
            total += complex(a) * cmath.exp(-2j * math.pi * carrier_hz * t) \
                * cmath.exp(-2j * math.pi * float(fj) * t)
        out.append(total)
    return np.array(out)


@pytest.mark.parametrize("normalize_delays", [False, True])
def test_h_freq_is_sionnas_cfr_with_and_without_its_delay_normalisation(snap,
                                                                        normalize_delays):
    f = np.array([-4.6e7, -1e6, 0.0, 90.909e3, 4.6e7])
    out = sionna_arrays(snap, f, carrier_phase=False, normalize_delays=normalize_delays)
    assert bool(out["normalize_delays"]) is normalize_delays
    for link in snap:
        r = list(out["rx_names"]).index(link.rx_name)
        t = list(out["tx_names"]).index(link.tx_name)
        ok = out["valid"][r, t]
        want = sionna_cfr(out["a"][r, t, ok], out["tau"][r, t, ok], snap.carrier_hz, f,
                          normalize_delays)
        scale = np.sum(np.abs(link.paths.gain))
        assert np.max(np.abs(out["h_freq"][r, t] - want)) < 1e-9 * scale
    # the normalisation turns each link's H by e^{+j2pi (f_c + f) tau_min}: |H| the same
    plain = sionna_arrays(snap, f)["h_freq"]
    np.testing.assert_allclose(np.abs(out["h_freq"]), np.abs(plain), rtol=1e-9, atol=1e-15)


def test_sionna_layout_padding_and_angles(snap):
    out = sionna_arrays(snap)
    assert "h_freq" not in out
    assert list(out["tx_names"]) == ["A"] and list(out["rx_names"]) == ["A", "B"]
    n = [snap.link("A", name).paths.n_paths for name in ("A", "B")]
    assert out["a"].shape == (2, 1, max(n))
    for r, name in enumerate(("A", "B")):
        p = snap.link("A", name).paths
        assert out["valid"][r, 0].sum() == p.n_paths
        np.testing.assert_array_equal(out["a"][r, 0, :p.n_paths], p.gain)
        np.testing.assert_array_equal(out["theta_r"][r, 0, :p.n_paths], p.angles.theta_r)
        assert np.all(out["tau"][r, 0, p.n_paths:] == -1)
        assert np.all(out["a"][r, 0, p.n_paths:] == 0)


def test_bad_frequencies_are_refused_by_name(snap):
    for bad in ([], [[1.0, 2.0]], [1.0, np.nan], "abc"):
        with pytest.raises(ArgumentError, match="frequencies_hz"):
            sionna_arrays(snap, bad)
    with pytest.raises(ArgumentError, match="delays_s"):
        channel_frequency_response([1, 2], [0.0], [0.0])
    with pytest.raises(TypeError, match="snapshot"):
        sionna_arrays("street.npz")


def test_sionna_file_is_plain_npz_and_deterministic(snap, tmp_path):
    f = np.linspace(0, 1e8, 5)
    a = save_sionna(tmp_path / "a.npz", snap, f)
    b = save_sionna(tmp_path / "b.npz", snap, f)
    assert a.read_bytes() == b.read_bytes()
    with np.load(a, allow_pickle=False) as z:
        np.testing.assert_array_equal(z["h_freq"], sionna_arrays(snap, f)["h_freq"])
        assert float(z["time_s"]) == 0.5


def test_mat_file_reads_back_with_scipy(snap, tmp_path):
    path = save_mat(tmp_path / "s.mat", snap)
    m = sio.loadmat(path, squeeze_me=False)
    assert str(m["scene_name"][0]) == snap.scene_name
    assert float(m["carrier_hz"][0, 0]) == snap.carrier_hz and float(m["time_s"][0, 0]) == 0.5
    assert [str(c[0]) for c in m["object_names"][0]][:2] == ["obj0", "obj1"]
    assert m["links"].shape == (1, 2)
    for i, link in enumerate(snap):
        s = m["links"][0, i][0, 0]
        p = link.paths
        assert str(s["tx_name"][0]) == link.tx_name and str(s["rx_name"][0]) == link.rx_name
        np.testing.assert_array_equal(s["a"][:, 0], p.gain)
        np.testing.assert_array_equal(s["tau"][:, 0], p.delay_s)
        np.testing.assert_array_equal(s["doppler_hz"][:, 0], p.doppler_hz)
        np.testing.assert_array_equal(s["matrix"], p.matrix)
        np.testing.assert_array_equal(s["points"], p.points)
        np.testing.assert_array_equal(s["interaction"], p.interaction)
        np.testing.assert_array_equal(s["object_id"], p.object_id)
        np.testing.assert_array_equal(s["phi_t"][:, 0], p.angles.phi_t)
        k = int(np.argmax(p.n_interactions))
        assert len(str(s["pattern"][k, 0][0])) == p.n_interactions[k]
    keys = [str(c[0]) for c in m["metadata_keys"][0]]
    assert keys == list(snap.metadata)
    assert save_mat(tmp_path / "again.mat", snap).read_bytes() == path.read_bytes()


def test_mat_of_an_empty_link_and_no_names(tmp_path):
    from clradcom.paths import Paths

    snap = Snapshot("e", 24e9, "", links=[Link("A", "A", 0, 0, Paths.empty(2))])
    v = mat_variables(snap)
    assert v["object_names"].shape == (1, 0)
    m = sio.loadmat(save_mat(tmp_path / "e.mat", snap))
    assert m["links"][0, 0][0, 0]["points"].shape[0] == 0


def test_tool_writes_every_export(snap, tmp_path):
    src = save_snapshot(tmp_path / "in.npz", snap)
    out = tmp_path / "out"
    run = subprocess.run(
        [sys.executable, str(REPO / "tools" / "export.py"), str(src), "--out", str(out),
         "--mat", "--sionna", "--compressed", "--subcarriers", "8",
         "--spacing-hz", "1e6"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert load_snapshot(out / "in.compressed.npz") == snap
    assert sio.loadmat(out / "in.mat")["links"].shape == (1, 2)
    with np.load(out / "in.sionna.npz") as z:
        assert z["h_freq"].shape == (2, 1, 8)
    bad = subprocess.run([sys.executable, str(REPO / "tools" / "export.py"), str(src),
                          "--out", str(out), "--sionna", "--subcarriers", "-3"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "--subcarriers" in bad.stderr
