"""Antenna patterns: normalisation (integral G dOmega = 4 pi), sector gain, cosine power,
tabulated files, polarisation, Euler rotations."""

import math

import numpy as np
import pytest

from clradcom.errors import SceneError
from clradcom.scene.antenna import (
    CosinePowerPattern,
    IsotropicPattern,
    SectorPattern,
    TabulatedPattern,
    directions_to_angles,
    euler_deg_to_matrix,
    integrate_gain,
    load_pattern_file,
    polarization_jones,
    theta_phi_unit_vectors,
)

FOUR_PI = 4 * math.pi


def sph(theta_deg, phi_deg):
    t, p = np.broadcast_arrays(np.deg2rad(theta_deg), np.deg2rad(phi_deg))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


# -- normalisation -------------------------------------------------------------------


def test_isotropic_integrates_to_4pi():
    p = IsotropicPattern()
    assert integrate_gain(p, 90, 180) == pytest.approx(FOUR_PI, rel=1e-4)
    assert np.allclose(p.gain(sph([0, 90, 180], [0, 45, -170])), 1.0)


@pytest.mark.parametrize("az, el", [(90, 180), (60, 30), (360, 180), (120, 90)])
def test_sector_integrates_to_4pi(az, el):
    p = SectorPattern(azimuth_width_deg=az, elevation_width_deg=el)
    assert integrate_gain(p, 720, 1440) == pytest.approx(FOUR_PI, rel=2e-3)


def test_paper_sector_is_6dbi_and_covers_pi_sr():
    p = SectorPattern()  # 90 deg az x 180 deg el
    assert p.solid_angle == pytest.approx(math.pi)
    assert p.inside_gain == pytest.approx(4.0)
    assert p.peak_gain_dbi() == pytest.approx(6.0206, abs=1e-4)
    inside = sph([90, 10, 170, 90], [44.9, 0, -30, -44.9])
    outside = sph([90, 90, 90], [45.1, 180, -60])
    assert np.allclose(p.gain(inside), 4.0)
    assert np.allclose(p.gain(outside), 0.0)


@pytest.mark.parametrize("q", [0.0, 1.0, 4.0, 10.5])
def test_cosine_power_integrates_to_4pi(q):
    p = CosinePowerPattern(q=q)
    assert p.gain(np.array([[1.0, 0, 0]]))[0] == pytest.approx(2 * (q + 1))
    assert integrate_gain(p, 720, 1440) == pytest.approx(FOUR_PI, rel=2e-3)
    assert p.gain(np.array([[-1.0, 0, 0], [0, 1.0, 0]]))[1] <= 2.0 + 1e-12
    assert p.gain(np.array([[-1.0, 0, 0]]))[0] == 0.0


def test_cosine_q_from_beamwidth_is_half_power():
    q = CosinePowerPattern.q_from_beamwidth(60.0)
    p = CosinePowerPattern(q=q)
    g = p.gain(sph([90, 90], [0, 30]))
    assert g[1] / g[0] == pytest.approx(0.5)


def test_gain_is_field_magnitude_squared():
    for p in (IsotropicPattern(), SectorPattern(), CosinePowerPattern(q=3.0)):
        d = sph(np.linspace(1, 179, 13), np.linspace(-179, 179, 13))
        c = p.field(d)
        assert c.shape == (13, 2) and c.dtype == np.complex128
        assert np.allclose(np.sum(np.abs(c) ** 2, axis=1), p.gain(d))


# -- polarisation --------------------------------------------------------------------


def test_polarization_v_and_h_components():
    d = sph([90, 60], [0, 20])
    v = IsotropicPattern(polarization=polarization_jones("V")).field(d)
    h = IsotropicPattern(polarization=polarization_jones("H")).field(d)
    assert np.allclose(v[:, 0], 1) and np.allclose(v[:, 1], 0)
    assert np.allclose(h[:, 0], 0) and np.allclose(h[:, 1], 1)
    # V at boresight: theta-hat at (theta=90, phi=0) is -z
    e = IsotropicPattern().field_vectors(np.array([[1.0, 0, 0]]))[0]
    assert np.allclose(e, [0, 0, -1])


def test_rhcp_rotates_right_handed_about_propagation():
    # e^{+jwt}: E(t) = Re{C e^{jwt}}; RHCP turns from theta-hat to phi-hat, and
    # theta-hat x phi-hat = r-hat (the propagation direction).
    jones = polarization_jones("RHCP")
    th, ph = theta_phi_unit_vectors(np.array([1.0]), np.array([0.4]))
    r = sph(np.degrees(1.0), np.degrees(0.4))
    assert np.allclose(np.cross(th[0], ph[0]), r)
    e = jones[0] * th[0] + jones[1] * ph[0]
    e0 = np.real(e)  # wt = 0
    e1 = np.real(e * np.exp(1j * 0.1))  # a moment later
    assert np.dot(np.cross(e0, e1), r) > 0
    assert np.allclose(polarization_jones("LHCP"), np.conj(jones))


def test_jones_vector_normalised_and_validated():
    j = polarization_jones([3.0, 4.0j])
    assert np.allclose(j, [0.6, 0.8j])
    for bad in ([0, 0], [1, 2, 3], [np.nan, 1], "diagonal"):
        with pytest.raises(ValueError):
            polarization_jones(bad)


def test_directions_are_normalised_and_angles():
    th, ph = directions_to_angles(np.array([[0, 2.0, 0], [0, 0, -5.0]]))
    assert np.allclose(th, [np.pi / 2, np.pi]) and ph[0] == pytest.approx(np.pi / 2)
    with pytest.raises(ValueError):
        directions_to_angles(np.zeros((1, 3)))


# -- rotations ---------------------------------------------------------------------------


def test_euler_convention():
    assert np.allclose(euler_deg_to_matrix([0, 0, 90]) @ [1, 0, 0], [0, 1, 0])  # yaw
    assert np.allclose(euler_deg_to_matrix([0, -90, 0]) @ [0, 0, 1], [-1, 0, 0])  # pitch
    assert np.allclose(euler_deg_to_matrix([90, 0, 0]) @ [0, 1, 0], [0, 0, 1])  # roll
    # extrinsic x-y-z: roll first, then yaw: x stays x under roll, then yaw takes it to y
    r = euler_deg_to_matrix([90, 0, 90])
    assert np.allclose(r @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(r @ [0, 1, 0], [0, 0, 1])
    assert np.allclose(r @ r.T, np.eye(3)) and np.linalg.det(r) == pytest.approx(1.0)


# -- tabulated patterns ---------------------------------------------------------------------


def cosine_table(q=2.0, step=2.0):
    th = np.arange(0, 180 + step / 2, step)
    ph = np.arange(-180, 180, step)
    d = sph(th[:, None], ph[None, :]).reshape(-1, 3)
    g = CosinePowerPattern(q=q).gain(d).reshape(th.size, ph.size)
    return th, ph, 10 * np.log10(np.maximum(g, 1e-20))


def write_csv(path, th, ph, gdb):
    lines = ["# test pattern", "theta_deg,phi_deg,gain_db"]
    for i, t in enumerate(th):
        for j, p in enumerate(ph):
            lines.append(f"{t:.6f},{p:.6f},{gdb[i, j]:.9f}")
    path.write_text("\n".join(lines) + "\n")


def test_tabulated_csv_matches_source_and_integrates(tmp_path):
    th, ph, gdb = cosine_table()
    f = tmp_path / "cos.csv"
    write_csv(f, th, ph, gdb)
    p = load_pattern_file(f, polarization="H", normalize=False)
    ref = CosinePowerPattern(q=2.0)
    d = sph([90, 30, 60, 120], [0, 10, -50, 179])
    assert np.allclose(p.gain(d), ref.gain(d), rtol=2e-3, atol=1e-3)
    assert integrate_gain(p, 360, 720) == pytest.approx(FOUR_PI, rel=5e-3)
    c = p.field(d)
    assert np.allclose(c[:, 0], 0) and np.allclose(np.abs(c[:, 1]) ** 2, p.gain(d))


def test_tabulated_normalize_rescales_to_4pi(tmp_path):
    th, ph, gdb = cosine_table()
    f = tmp_path / "cos.npz"
    np.savez(f, theta_deg=th, phi_deg=ph, gain_db=gdb - 7.0)  # 7 dB of "losses"
    p = load_pattern_file(f)
    assert integrate_gain(p, 360, 720) == pytest.approx(FOUR_PI, rel=1e-3)
    assert p.peak_gain_dbi() == pytest.approx(10 * math.log10(6.0), abs=0.05)


def test_tabulated_complex_npz_keeps_polarisation(tmp_path):
    th = np.linspace(0, 180, 91)
    ph = np.linspace(0, 360, 181)  # closed grid: 0 and 360 both present
    ct = np.full((91, 181), 1.0 + 0j)
    cp = np.full((91, 181), -1j)
    f = tmp_path / "circ.npz"
    np.savez(f, theta_deg=th, phi_deg=ph, c_theta=ct, c_phi=cp)
    p = load_pattern_file(f)
    c = p.field(sph([90, 45], [0, -90]))
    assert np.allclose(c, np.array([[1, -1j], [1, -1j]]) / math.sqrt(2))
    assert integrate_gain(p, 180, 360) == pytest.approx(FOUR_PI, rel=1e-3)
    with pytest.raises(SceneError, match="polarization"):
        load_pattern_file(f, polarization="V")


def test_tabulated_interpolates_across_phi_wrap():
    th = np.array([0.0, 90.0, 180.0])
    ph = np.array([0.0, 90.0, 180.0, 270.0])  # open grid, wraps 270 -> 360
    g = np.zeros((3, 4))
    g[:, 3] = 10.0  # 10 dB at phi = 270, 0 dB elsewhere
    p = TabulatedPattern(theta_deg=th, phi_deg=ph, gain_db=g, normalize=False)
    # phi = -45 deg = 315 deg: halfway between 270 (amplitude sqrt10) and 360 (1)
    amp = (math.sqrt(10) + 1) / 2
    assert p.gain(sph([90], [-45]))[0] == pytest.approx(amp**2)


@pytest.mark.parametrize(
    "content, fragment",
    [
        ("theta,phi,gain\n0,0,0\n", "header must name columns"),
        ("theta_deg,phi_deg,gain_db\n0,0,abc\n", "not a number"),
        ("theta_deg,phi_deg,gain_db\n0,0,nan\n", "NaN or inf"),
        ("theta_deg,phi_deg,gain_db\n0,0,0\n180,0,0\n180,180,0\n", "full regular grid"),
        ("theta_deg,phi_deg,gain_db\n0,0,0\n0,180,0\n90,0,0\n90,180,0\n", "0 to 180"),
        ("theta_deg,phi_deg,gain_db\n0,0\n", "fields"),
        ("", "empty"),
    ],
    ids=["header", "not-number", "nan", "incomplete-grid", "theta-span", "short-row", "empty"],
)
def test_malformed_csv_pattern_refused(tmp_path, content, fragment):
    f = tmp_path / "bad.csv"
    f.write_text(content)
    with pytest.raises(SceneError) as ei:
        load_pattern_file(f)
    assert "bad.csv" in str(ei.value) and fragment in str(ei.value)


def test_malformed_npz_pattern_refused(tmp_path):
    f = tmp_path / "bad.npz"
    np.savez(f, theta_deg=np.array([0.0, 180.0]), phi_deg=np.array([0.0, 180.0]))
    with pytest.raises(SceneError, match="gain_db"):
        load_pattern_file(f)
    g = tmp_path / "shape.npz"
    np.savez(g, theta_deg=np.array([0.0, 180.0]), phi_deg=np.array([0.0, 180.0]),
             gain_db=np.zeros((3, 2)))
    with pytest.raises(SceneError, match="shape"):
        load_pattern_file(g)
    h = tmp_path / "junk.npz"
    h.write_bytes(b"not a zip")
    with pytest.raises(SceneError, match="junk.npz"):
        load_pattern_file(h)


def test_directions_to_angles_equal_the_plain_expressions_bit_for_bit():
    # the norm is summed left to right as np.linalg.norm(d, axis=1) sums a row (a radio
    # map's launch lattice must not move); directions of every scale, signed zeros, poles
    rng = np.random.default_rng(11)
    d = rng.standard_normal((200_000, 3)) * np.exp(30.0 * rng.standard_normal((200_000, 1)))
    d[:5] = [[0.0, 0.0, 1.0], [-0.0, 0.0, -3.0], [-1.0, -0.0, 0.0], [-1.0, 0.0, 0.0],
             [1e-150, -1e-150, 0.0]]
    unit = d / np.linalg.norm(d, axis=1)[:, None]
    theta = np.arccos(np.clip(unit[:, 2], -1.0, 1.0))
    phi = np.arctan2(unit[:, 1], unit[:, 0])
    got = directions_to_angles(d)
    np.testing.assert_array_equal(got[0].view(np.int64), theta.view(np.int64))
    np.testing.assert_array_equal(got[1].view(np.int64), phi.view(np.int64))
