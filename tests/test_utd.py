"""UTD wedge diffraction (clradcom.physics.utd) against exact solutions and closed forms.

References: docs/reference/propagation-physics.md §2 (KP 1974, Luebbers 1984),
§6.3 (Sommerfeld half-plane), §6.4 (wedge eigen-series), §6.5 (knife edge J(nu));
formulas in docs/utd.md.  Every reference value is computed here independently of
clradcom.physics.utd (quadrature, Fresnel integrals, Bessel series).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import fresnel, jv, wofz

from clradcom.physics.em import C0, fresnel_coefficients
from clradcom.physics.utd import (
    F_ASYMPTOTIC_MIN,
    F_SERIES_MAX,
    a_plus_minus,
    boundary_epsilons,
    diffraction_coefficients,
    diffraction_dyad,
    distance_parameter,
    edge_fixed_basis,
    multi_edge_spreading,
    spreading_factor,
    transition_function,
    wedge_angles,
)

LAM = C0 / 24e9
K0 = 2 * np.pi / LAM
PI = np.pi


# ---------------------------------------------------------------------------
# references

def f_quad(x):
    """F(x) by brute quadrature.  Rotating the contour tau = sqrt(x) + e^{-j pi/4} t::

        F(x) = 2 e^{j pi/4} sqrt(x) int_0^inf exp(-t^2 - 2 sqrt(x) e^{j pi/4} t) dt

    (a smooth, exponentially decaying integrand)."""
    b = 2 * math.sqrt(x) * complex(math.cos(PI / 4), math.sin(PI / 4))
    opts = dict(epsabs=1e-15, epsrel=1e-13, limit=400)
    re = quad(lambda t: math.exp(-t * t - b.real * t) * math.cos(b.imag * t), 0, np.inf,
              **opts)[0]
    im = quad(lambda t: -math.exp(-t * t - b.real * t) * math.sin(b.imag * t), 0, np.inf,
              **opts)[0]
    return 2 * complex(math.cos(PI / 4), math.sin(PI / 4)) * math.sqrt(x) * (re + 1j * im)


def f_faddeeva(x):
    """F(x) = e^{j pi/4} sqrt(pi x) w(e^{j 3pi/4} sqrt(x)) (Faddeeva function)."""
    x = np.asarray(x, dtype=float)
    return np.exp(1j * PI / 4) * np.sqrt(PI * x) * wofz(np.exp(3j * PI / 4) * np.sqrt(x))


def sommerfeld_u(beta, krho):
    """U(beta) = e^{j k rho cos beta} e^{j pi/4}/sqrt(pi) int_{-inf}^{a} e^{-j tau^2} d tau,
    a = sqrt(2 k rho) cos(beta/2)."""
    a = np.sqrt(2 * krho) * np.cos(beta / 2)
    S, C = fresnel(a * np.sqrt(2 / PI))
    integral = np.sqrt(PI) / 2 * np.exp(-1j * PI / 4) + np.sqrt(PI / 2) * (C - 1j * S)
    return np.exp(1j * krho * np.cos(beta)) * np.exp(1j * PI / 4) / np.sqrt(PI) * integral


def halfplane_exact(phi, phi_p, krho, soft):
    sign = -1.0 if soft else 1.0
    return sommerfeld_u(phi - phi_p, krho) + sign * sommerfeld_u(phi + phi_p, krho)


def wedge_series(phi, phi_p, krho, n, soft):
    """Exact eigen-series of a plane wave on a wedge (Macdonald)."""
    m_max = int(n * (krho + 60 + 4 * krho ** (1 / 3))) + 10
    m = np.arange(0 if not soft else 1, m_max)[:, None]
    nu = m / n
    amp = np.exp(1j * PI * nu / 2) * jv(nu, krho)
    if soft:
        return 4 / n * np.sum(amp * np.sin(nu * phi) * np.sin(nu * phi_p), axis=0)
    eps = np.where(m == 0, 1.0, 2.0)
    return 2 / n * np.sum(eps * amp * np.cos(nu * phi) * np.cos(nu * phi_p), axis=0)


def step(x):
    """Shadow indicator: 1 for x > 0, 1/2 at 0, 0 below."""
    return 0.5 * (1 + np.sign(x))


def utd_total(phi, phi_p, krho, n, soft, eps_r=None):
    """GO (incident + face reflections with shadow indicators) + UTD diffracted field of a
    unit plane wave (phase reference at the edge), beta0 = 90 deg, L = rho."""
    phi = np.asarray(phi, dtype=float)
    rho = krho / K0
    pec = eps_r is None
    Ds, Dh = diffraction_coefficients(phi, phi_p, PI / 2, n, K0, rho, eps_r, eps_r, pec)
    D = Ds if soft else Dh
    if pec:
        r0 = rn = -1.0 if soft else 1.0
    else:
        te0, tm0 = fresnel_coefficients(eps_r, np.sin(phi_p))
        ten, tmn = fresnel_coefficients(eps_r, np.sin(n * PI - phi))
        r0, rn = (te0, ten) if soft else (tm0, tmn)
    u = step(PI - np.abs(phi - phi_p)) * np.exp(1j * krho * np.cos(phi - phi_p))
    u = u + r0 * step(PI - (phi + phi_p)) * np.exp(1j * krho * np.cos(phi + phi_p))
    u = u + rn * step(phi + phi_p - (2 * n - 1) * PI) * np.exp(
        1j * krho * np.cos(phi + phi_p - 2 * n * PI))
    return u + D * np.exp(-1j * krho) / np.sqrt(rho)


# ---------------------------------------------------------------------------
# transition function

@pytest.mark.parametrize("x", [1e-3, 1e-2, 0.1, 0.3, 1.0, 10.0, 40.0, 100.0, 1e3])
def test_transition_function_vs_quadrature(x):
    assert abs(transition_function(x) - f_quad(x)) < 2e-14


def test_transition_function_published_values():
    # propagation-physics.md §2 (4-5 digits)
    F = transition_function([0.1, 1.0, 10.0])
    np.testing.assert_allclose(F, [0.3681 + 0.2345j, 0.8095 + 0.2322j, 0.99304 + 0.04835j],
                               atol=6e-5)
    assert transition_function(0.0) == 0
    assert abs(transition_function(1e8) - 1) < 1e-8


def test_transition_function_dense_and_asymptotes():
    x = np.logspace(-12, 5, 4001)
    F = transition_function(x)
    assert np.max(np.abs(F - f_faddeeva(x))) < 3e-14
    # KP small/large argument forms
    xs = x[x < 1e-3]
    small = (np.sqrt(PI * xs) - 2 * xs * np.exp(1j * PI / 4)) * np.exp(1j * (PI / 4 + xs))
    assert np.max(np.abs(transition_function(xs) - small)) < 1e-6
    xl = x[x > 1e3]
    asym = 1 + 0.5j / xl - 0.75 / xl**2 - 15j / (8 * xl**3)
    assert np.max(np.abs(transition_function(xl) - asym)) < 1e-11


@pytest.mark.parametrize("x0", [F_SERIES_MAX, F_ASYMPTOTIC_MIN])
def test_transition_function_continuous_at_switch_points(x0):
    below, at = np.nextafter(x0, 0), x0
    jump = abs(transition_function(at) - transition_function(below))
    assert jump < 1e-14
    x = x0 * (1 + np.linspace(-1e-3, 1e-3, 201))
    steps = np.abs(np.diff(transition_function(x)))  # smooth: equal steps, none stands out
    assert steps.max() / steps.min() < 1.01


def test_transition_function_input_checks():
    with pytest.raises(ValueError):
        transition_function(-1.0)
    assert np.isnan(transition_function(np.nan))
    assert transition_function(np.ones((2, 3))).shape == (2, 3)


# ---------------------------------------------------------------------------
# a+-

@pytest.mark.parametrize("n", [0.7, 1.0, 1.5, 1.8, 2.0])
def test_a_plus_minus_vs_definition(n):
    beta = np.linspace(-2 * PI, 4 * PI, 1237)
    ap, am = a_plus_minus(beta, n)
    # N+- by brute force over integers: the ones that best satisfy 2 pi n N -+ ... = +-pi
    N = np.arange(-6, 7)[:, None]
    np_ = N[np.argmin(np.abs(2 * PI * n * N - beta - PI), axis=0), 0]
    nm_ = N[np.argmin(np.abs(2 * PI * n * N - beta + PI), axis=0), 0]
    np.testing.assert_allclose(ap, 2 * np.cos((2 * n * PI * np_ - beta) / 2) ** 2, atol=1e-13)
    np.testing.assert_allclose(am, 2 * np.cos((2 * n * PI * nm_ - beta) / 2) ** 2, atol=1e-13)
    # zeros exactly on the boundaries
    assert a_plus_minus(PI, n)[1] == 0 and a_plus_minus(-PI, n)[0] == 0


# ---------------------------------------------------------------------------
# half-plane vs Sommerfeld

def _away_from_boundaries(phi, phi_p, n, margin):
    bounds = np.array([PI + phi_p, PI - phi_p, phi_p - PI, (2 * n - 1) * PI - phi_p])
    return np.all(np.abs(phi[:, None] - bounds[None, :]) > margin, axis=1)


@pytest.mark.parametrize("krho", [5.0, 20.0, 100.0])
@pytest.mark.parametrize("soft", [True, False])
@pytest.mark.parametrize("phi_p_deg", [30.0, 60.0, 135.0, 250.0])
def test_halfplane_vs_sommerfeld(krho, soft, phi_p_deg):
    phi_p = np.radians(phi_p_deg)
    phi = np.linspace(1e-3, 2 * PI - 1e-3, 721)
    phi = phi[_away_from_boundaries(phi, phi_p, 2.0, 1e-3)]
    err = np.abs(utd_total(phi, phi_p, krho, 2.0, soft) - halfplane_exact(phi, phi_p, krho, soft))
    assert err.max() < 2e-13, err.max()


@pytest.mark.parametrize("soft", [True, False])
def test_halfplane_on_the_boundaries(soft):
    # near the boundaries (incl. 1e-9 rad) the guarded cot*F keeps UTD exact too
    phi_p = np.radians(40.0)
    krho = 20.0
    d = np.array([-1e-2, -1e-5, -1e-9, 1e-9, 1e-5, 1e-2])
    for b in (PI + phi_p, PI - phi_p):
        phi = b + d
        err = np.abs(utd_total(phi, phi_p, krho, 2.0, soft)
                     - halfplane_exact(phi, phi_p, krho, soft))
        assert err.max() < 1e-11, err.max()
        # exactly on it: indicator 1/2 and the mean of the one-sided limits
        e0 = abs(utd_total(b, phi_p, krho, 2.0, soft) - halfplane_exact(b, phi_p, krho, soft))
        assert e0 < 1e-8


@pytest.mark.parametrize("soft", [True, False])
def test_go_sides_take_the_branch_of_the_go_decision(soft):
    """Exactly on a boundary (and within rounding of it) a caller that keeps its GO field
    whole (present: +1, absent: -1) gets the one-sided UTD branch of that side, and the
    total is Sommerfeld's exact half-plane field there either way."""
    phi_p, krho = np.radians(40.0), 20.0
    rho = krho / K0
    for k, b in ((1, PI + phi_p), (3, PI - phi_p)):  # D2: shadow, D4: 0-face reflection
        eps = boundary_epsilons(b, phi_p, 2.0)
        assert abs(eps[k]) < 1e-15
        exact = halfplane_exact(b, phi_p, krho, soft)
        r0 = -1.0 if soft else 1.0
        go_field = np.exp(1j * krho * np.cos(b - phi_p)) if k == 1 else r0 * np.exp(
            1j * krho * np.cos(b + phi_p))
        rest = utd_total(b, phi_p, krho, 2.0, soft) - 0.5 * go_field  # the other GO terms
        rest -= diffraction_coefficients(b, phi_p, PI / 2, 2.0, K0, rho)[0 if soft else 1] * (
            np.exp(-1j * krho) / np.sqrt(rho))
        for side in (1, -1):
            sides = [0, 0, 0, 0]
            sides[k] = side
            D = diffraction_coefficients(b, phi_p, PI / 2, 2.0, K0, rho, go_sides=sides)
            d = D[0 if soft else 1] * np.exp(-1j * krho) / np.sqrt(rho)
            total = rest + (side > 0) * go_field + d
            assert abs(total - exact) < 1e-10, (k, side)


# ---------------------------------------------------------------------------
# 90-degree wedge vs eigen-series

@pytest.mark.parametrize("krho, tol", [(10.0, 5e-3), (50.0, 8e-4)])
@pytest.mark.parametrize("soft", [True, False])
def test_right_angle_wedge_vs_eigen_series(krho, tol, soft):
    n = 1.5
    for phi_p in np.radians([30.0, 70.0, 110.0]):
        phi = np.linspace(0.05, n * PI - 0.05, 181)
        phi = phi[_away_from_boundaries(phi, phi_p, n, 0.05)]
        err = np.abs(utd_total(phi, phi_p, krho, n, soft) - wedge_series(phi, phi_p, krho, n, soft))
        assert err.max() < tol, (phi_p, err.max())


def test_eigen_series_reproduces_sommerfeld():
    # sanity of the reference itself
    phi = np.linspace(0.1, 2 * PI - 0.1, 50)
    for soft in (True, False):
        a = wedge_series(phi, 0.7, 20.0, 2.0, soft)
        b = halfplane_exact(phi, 0.7, 20.0, soft)
        assert np.max(np.abs(a - b)) < 1e-12


# ---------------------------------------------------------------------------
# knife edge

def j_nu_db(nu):
    S, C = fresnel(nu)
    return -20 * np.log10(np.sqrt((1 - C - S) ** 2 + (C - S) ** 2) / 2)


def knife_edge_loss_db(nu, d1=10.0, d2=10.0):
    """UTD absorbing screen (n = 2, rho_0 = rho_n = 0), point source: loss re free space."""
    h = nu / np.sqrt(2 * (d1 + d2) / (LAM * d1 * d2))
    # edge at the origin, screen along -y; phi from the screen's tx-side face
    tx, rx = np.array([-d1, -h]), np.array([d2, -h])
    phi_p = np.mod(1.5 * PI - np.arctan2(tx[1], tx[0]), 2 * PI)
    phi = np.mod(1.5 * PI - np.arctan2(rx[1], rx[0]), 2 * PI)
    sp, s, d = np.hypot(*tx), np.hypot(*rx), d1 + d2
    L = distance_parameter(s, sp, PI / 2)
    Ds, Dh = diffraction_coefficients(phi, phi_p, PI / 2, 2.0, K0, L, rho_0=0.0, rho_n=0.0)
    assert Ds == Dh
    e_d = np.exp(-1j * K0 * sp) / sp * Ds * spreading_factor(s, sp) * np.exp(-1j * K0 * s)
    e_go = step(PI - abs(phi - phi_p)) * np.exp(-1j * K0 * d) / d
    return -20 * np.log10(abs((e_go + e_d) / (np.exp(-1j * K0 * d) / d)))


def test_knife_edge_j_nu():
    assert abs(j_nu_db(0.0) - 6.0206) < 1e-3 and abs(j_nu_db(1.0) - 13.86) < 5e-3
    assert abs(knife_edge_loss_db(0.0) - 6.0206) < 0.01  # exactly on the shadow boundary
    assert abs(knife_edge_loss_db(1.0) - 13.86) < 0.01
    for nu in (-0.2, -1e-9, 1e-9, 0.566, 1.6):
        assert abs(knife_edge_loss_db(nu) - j_nu_db(nu)) < 0.01, nu


# ---------------------------------------------------------------------------
# continuity, grazing, end-on

@pytest.mark.parametrize("n", [1.5, 2.0])
@pytest.mark.parametrize("soft", [True, False])
@pytest.mark.parametrize("lossy", [False, True])
def test_total_field_continuous_across_boundaries(n, soft, lossy):
    eps = 5 - 0.1j if lossy else None
    phi_p = np.radians(50.0)
    krho = 40.0
    for b in (PI + phi_p, PI - phi_p):
        phi = b + 1e-6 * np.arange(-50, 51)
        u = utd_total(phi, phi_p, krho, n, soft, eps)
        assert np.all(np.isfinite(u))
        jumps = np.abs(np.diff(u))
        assert jumps.max() < 1e-4, jumps.max()  # GO jumps by ~1 (or |R|) there


def test_coefficients_finite_everywhere():
    rng = np.random.default_rng(1)
    n = rng.choice([0.8, 1.0, 1.25, 1.5, 2.0], 2000)
    phi = rng.uniform(0, 1, 2000) * n * PI
    phi_p = rng.uniform(0, 1, 2000) * n * PI
    # add exact boundaries and grazing angles
    phi_p[:100] = 0.0
    phi[100:200] = PI + phi_p[100:200]
    phi[200:300] = PI - phi_p[200:300]
    phi_p[300:400] = n[300:400] * PI
    for pec, eps in ((True, None), (False, 5 - 0.1j), (False, 10 - 6j)):
        Ds, Dh = diffraction_coefficients(phi, phi_p, rng.uniform(0.01, PI - 0.01, 2000), n,
                                          K0, rng.uniform(0, 30, 2000), eps, eps, pec)
        assert np.all(np.isfinite(Ds)) and np.all(np.isfinite(Dh))


@pytest.mark.parametrize("phi_p", [0.0, 1e-12, 1e-7])
@pytest.mark.parametrize("soft", [True, False])
def test_grazing_incidence(phi_p, soft):
    # phi' -> 0: the incident SB and the 0-face RB merge at phi = pi (the GO field jumps
    # by 2 there for hard, by 0 for soft); D stays finite and the total field continuous
    phi = PI + 1e-6 * np.arange(-20, 21)
    Ds, Dh = diffraction_coefficients(phi, phi_p, PI / 2, 1.5, K0, 1.0)
    assert np.all(np.isfinite(Ds)) and np.all(np.isfinite(Dh))
    if phi_p == 0.0:
        assert np.max(np.abs(Ds)) < 1e-15  # soft PEC: incident and reflected cancel
    u = utd_total(phi, phi_p, 30.0, 1.5, soft)
    assert np.max(np.abs(np.diff(u))) < 1e-4


def test_edge_seen_end_on():
    # beta0 -> 0 with L = s s' sin^2 b0 / (s + s'): D converges, no NaN (exact 0 at b0 = 0)
    b0 = np.array([1e-2, 1e-4, 1e-6, 1e-8, 1e-12])
    L = distance_parameter(2.0, 3.0, b0)
    Ds, Dh = diffraction_coefficients(1.0, 0.4, b0, 1.5, K0, L)
    assert np.all(np.isfinite(Ds)) and np.all(np.isfinite(Dh))
    # D(b0) - D(0) ~ sqrt(k L) ~ sin(b0)
    np.testing.assert_allclose(Ds[3:], Ds[-1], rtol=1e-5)
    np.testing.assert_allclose(Dh[3:], Dh[-1], rtol=1e-5)
    for D in (Ds, Dh):
        assert abs(D[2] - D[-1]) < 0.02 * abs(D[1] - D[-1])
    D0 = diffraction_coefficients(1.0, 0.4, 0.0, 1.5, K0, distance_parameter(2.0, 3.0, 0.0))
    assert np.isfinite(D0[0]) and np.isfinite(D0[1])


def test_luebbers_pec_limit_and_face_terms():
    phi, phi_p, L = np.linspace(0.2, 4.5, 50), 0.6, 2.0
    pec = diffraction_coefficients(phi, phi_p, 1.2, 1.5, K0, L)
    metal = diffraction_coefficients(phi, phi_p, 1.2, 1.5, K0, L, np.inf, np.inf, False)
    np.testing.assert_allclose(metal, pec, atol=1e-15)
    lossy = diffraction_coefficients(phi, phi_p, 1.2, 1.5, K0, L, 1e12 - 1e12j, 1e12 - 1e12j,
                                     False)
    np.testing.assert_allclose(lossy, pec, atol=1e-5)
    # absorbing faces: soft == hard
    ab = diffraction_coefficients(phi, phi_p, 1.2, 1.5, K0, L, rho_0=0, rho_n=0)
    np.testing.assert_allclose(ab[0], ab[1], atol=0)
    with pytest.raises(ValueError):
        diffraction_coefficients(phi, phi_p, 1.2, 1.5, K0, L, pec=False)
    with pytest.raises(ValueError):
        diffraction_coefficients(phi, phi_p, 1.2, 2.5, K0, L)
    with pytest.raises(ValueError):
        diffraction_coefficients(phi, phi_p, 1.2, 1.5, K0, -1.0)


def test_spreading_and_distance_parameter():
    assert distance_parameter(2.0, np.inf, PI / 2) == 2.0
    np.testing.assert_allclose(distance_parameter(2.0, 3.0, PI / 6), 2 * 3 * 0.25 / 5)
    np.testing.assert_allclose(spreading_factor(2.0, 3.0), np.sqrt(3 / (2 * 5)))
    assert spreading_factor(4.0, wave="plane") == 0.5
    assert spreading_factor(4.0, np.inf) == 0.5
    # single edge: KP spherical; two parallel edges: Keller's tube 1/sqrt(s0 s1 s2 (s0+s1+s2))
    A, L = multi_edge_spreading([3.0, 2.0], 1.0)
    np.testing.assert_allclose(A, spreading_factor(2.0, 3.0))
    np.testing.assert_allclose(L, [distance_parameter(2.0, 3.0, 1.0)])
    s = np.array([[3.0, 0.5, 2.0], [1.0, 4.0, 7.0]])
    A, L = multi_edge_spreading(s)
    np.testing.assert_allclose(A / s[:, 0],
                               1 / np.sqrt(s.prod(axis=1) * s.sum(axis=1)), rtol=1e-14)
    np.testing.assert_allclose(L[:, 1], s[:, 1] * s[:, 2] / (s[:, 1] + s[:, 2]))


# ---------------------------------------------------------------------------
# edge-fixed basis and dyad

def _rand_unit(rng, shape):
    v = rng.normal(size=shape + (3,))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_edge_fixed_basis_orthonormal_right_handed():
    rng = np.random.default_rng(3)
    e = _rand_unit(rng, (100,))
    si, so = _rand_unit(rng, (100,)), _rand_unit(rng, (100,))
    bp, pp, b, p = edge_fixed_basis(si, so, e)
    for x, y, z in ((bp, pp, si), (b, p, so)):
        np.testing.assert_allclose(np.cross(x, y), z, atol=1e-14)
        np.testing.assert_allclose(np.linalg.norm(x, axis=-1), 1, atol=1e-14)
    # phi_hat', phi_hat perpendicular to the edge; the dyad is invariant under e -> -e
    assert np.max(np.abs(np.sum(pp * e, -1))) < 1e-14
    d1 = diffraction_dyad(0.3 + 0.1j, -0.2j, *edge_fixed_basis(si, so, e))
    d2 = diffraction_dyad(0.3 + 0.1j, -0.2j, *edge_fixed_basis(si, so, -e))
    np.testing.assert_allclose(d1, d2, atol=1e-15)
    with pytest.raises(ValueError):
        edge_fixed_basis(e, so, e)


def test_dyad_reduces_to_scalar_forms():
    # edge along z, face 0 along +x (n0 = +y), normal incidence: E_z^d = D_s E_z^i and
    # H_z^d = D_h H_z^i (E = eta H x s for a plane wave)
    e, n0 = np.array([0, 0, 1.0]), np.array([0, 1.0, 0])
    phi_p, phi = 0.7, 3.9
    si = -np.array([np.cos(phi_p), np.sin(phi_p), 0])  # from the source towards the edge
    so = np.array([np.cos(phi), np.sin(phi), 0])
    got = wedge_angles(si, so, e, n0)
    np.testing.assert_allclose(got, [phi_p, phi, PI / 2], atol=1e-14)
    ds, dh = 0.4 - 0.3j, -0.1 + 0.2j
    Dd = diffraction_dyad(ds, dh, *edge_fixed_basis(si, so, e, n0))
    np.testing.assert_allclose(Dd @ np.array([0, 0, 1.0]), [0, 0, ds], atol=1e-15)
    e_in = np.cross(np.array([0, 0, 1.0]), si)  # H_z = 1: E = eta H x s' (eta = 1)
    e_out = Dd @ e_in
    h_out = np.cross(so, e_out)  # H = s x E / eta
    np.testing.assert_allclose(h_out, [0, 0, dh], atol=1e-15)


def test_wedge_angles_screen_and_oblique():
    rng = np.random.default_rng(5)
    e = np.array([0, 0, 1.0])
    n0 = np.array([0, 1.0, 0])
    phi = rng.uniform(0, 2 * PI, 50)
    phi_p = rng.uniform(0, 2 * PI, 50)
    b0 = rng.uniform(0.2, PI - 0.2, 50)
    # Keller cone: s' and s make the same angle b0 with e
    src_dir = np.stack([np.sin(b0) * np.cos(phi_p), np.sin(b0) * np.sin(phi_p),
                        -np.cos(b0)], -1)  # from Q towards the source
    si = -src_dir
    so = np.stack([np.sin(b0) * np.cos(phi), np.sin(b0) * np.sin(phi), np.cos(b0)], -1)
    got_p, got, got_b = wedge_angles(si, so, e, n0)
    np.testing.assert_allclose(got_p, phi_p, atol=1e-12)
    np.testing.assert_allclose(got, phi, atol=1e-12)
    np.testing.assert_allclose(got_b, b0, atol=1e-12)
