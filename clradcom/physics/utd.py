"""UTD wedge-diffraction coefficients (host side, numpy float64; issue 5).

Kouyoumjian & Pathak's uniform geometrical theory of diffraction for a straight
wedge of exterior angle ``n*pi`` (``n = 2``: a half-plane / thin screen) with
Luebbers' heuristic for lossy (finite-conductivity) faces.  Every function takes
and returns plain arrays and broadcasts.  docs/utd.md gives the formulas with their
sources; the equation labels below (U1 ...) refer to it.

Conventions (as :mod:`clradcom.physics.em`): time factor e^{+jwt}, lossy permittivity
``eps_r = eps' - j eps''``, wave number ``k = 2 pi f / c0``.  Angles follow the
face-0 convention of :mod:`clradcom.geometry.wedges`: ``e`` is the unit edge vector, ``n0``
the outward normal of face 0, ``t0 = n0 x e`` the unit vector in face 0 pointing
away from the edge; ``phi'`` (source) and ``phi`` (observer) are measured from
face 0 (``phi = 0``) about ``e`` through the exterior to face n (``phi = n pi``);
``beta0`` is the angle between the incident ray and the edge (Keller's cone).

Scalar use (``beta0 = 90 deg``, the 2-D problem)::

    u_d(s) = u_i(Q) * D * A(s) * exp(-j k s)

with ``D = D_soft`` for the field component parallel to the edge (Dirichlet /
TM_z, E_z) and ``D = D_hard`` for H_z (Neumann / TE_z).  Vector use: the 3x3 dyad
of :func:`diffraction_dyad` in the edge-fixed bases of :func:`edge_fixed_basis`.

References
----------
[KP74] R. G. Kouyoumjian, P. H. Pathak, "A uniform geometrical theory of
       diffraction for an edge in a perfectly conducting surface", Proc. IEEE
       62(11), 1448-1461, 1974.
[L84]  R. J. Luebbers, "Finite conductivity uniform GTD versus knife edge
       diffraction in prediction of propagation path loss", IEEE TAP 32(1),
       70-76, 1984.
[MPK90] D. A. McNamara, C. W. I. Pistorius, J. A. G. Malherbe, *Introduction to
       the Uniform Geometrical Theory of Diffraction*, Artech House, 1990.
[P526] ITU-R P.526 (knife-edge J(nu)).  Sionna RT em_primer "Diffraction" uses
       the same formulas (see docs/reference/propagation-physics.md §2).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import fresnel

from clradcom.errors import ArgumentError
from clradcom.physics.em import fresnel_coefficients
from clradcom.physics.vectors import checked_unit, dot

__all__ = [
    "transition_function",
    "a_plus_minus",
    "boundary_epsilons",
    "diffraction_coefficients",
    "distance_parameter",
    "spreading_factor",
    "multi_edge_spreading",
    "wedge_angles",
    "edge_fixed_basis",
    "diffraction_dyad",
]

# transition-function regimes (docs/utd.md "Transition function")
#: below: convergent power series; above: Fresnel integrals
F_SERIES_MAX = 0.3
#: above: asymptotic series (30 terms, truncation error < 3e-17 at x = 40)
F_ASYMPTOTIC_MIN = 40.0
_N_SERIES = 18  # x^19 / (18! * 37) < 1e-27 at x = 0.3
_N_ASYMPTOTIC = 30
_SERIES_COEF = tuple(1.0 / (math.factorial(m) * (2 * m + 1)) for m in range(_N_SERIES + 1))
#: sin(beta0) is clamped to at least this (beta0 = 0 or pi: the edge is a caustic)
SIN_BETA0_MIN = 1e-150

_SQRT_PI = math.sqrt(math.pi)
_E_JPI4 = complex(math.cos(math.pi / 4), math.sin(math.pi / 4))


# ---------------------------------------------------------------------------
# transition function

def _g_series(x):
    """F(x)/sqrt(x) from the convergent series (eq. U2a), accurate for small x."""
    # int_0^sqrt(x) e^{-j t^2} dt = sqrt(x) sum_m (-j x)^m / (m! (2m+1)), Horner in -jx
    y = -1j * x
    acc = np.full(x.shape, _SERIES_COEF[-1], dtype=np.complex128)
    for c in _SERIES_COEF[-2::-1]:
        acc = acc * y + c
    return np.exp(1j * x) * (_SQRT_PI * _E_JPI4 - 2j * np.sqrt(x) * acc)


def _g_fresnel(x):
    """F(x)/sqrt(x) from the Fresnel integrals S, C (eq. U2b)."""
    S, C = fresnel(np.sqrt(2.0 * x / np.pi))
    return math.sqrt(math.pi / 2) * np.exp(1j * x) * ((1 + 1j) - 2.0 * (S + 1j * C))


def _g_asymptotic(x):
    """F(x)/sqrt(x) from the asymptotic series (eq. U2c), x >= F_ASYMPTOTIC_MIN."""
    u = 1j / (2.0 * x)
    acc = np.ones_like(u)
    for m in range(_N_ASYMPTOTIC, 0, -1):  # sum_m (2m-1)!! u^m, Horner
        acc = 1.0 + (2 * m - 1) * u * acc
    return acc / np.sqrt(x)


def _transition_over_sqrt(x):
    """G(x) = F(x)/sqrt(x) for x >= 0 (finite at 0: G(0) = sqrt(pi) e^{j pi/4})."""
    x = np.asarray(x, dtype=np.float64)
    g = np.empty(x.shape, dtype=np.complex128)
    small = x < F_SERIES_MAX
    large = x >= F_ASYMPTOTIC_MIN
    mid = ~(small | large)
    g[small] = _g_series(x[small])
    g[mid] = _g_fresnel(x[mid])
    g[large] = _g_asymptotic(x[large])
    return g


def transition_function(x):
    """KP transition function (eq. U2) [KP74 eq. (25); MPK90 §4.5]::

        F(x) = 2j sqrt(x) e^{jx} int_{sqrt(x)}^inf e^{-j tau^2} d tau,   x >= 0

    Three regimes, each accurate to ~1e-14 absolute (docs/utd.md):

    * ``x < 0.3``: the convergent series (U2a)
      ``F = e^{jx} [sqrt(pi x) e^{j pi/4} - 2j sum_m (-j)^m x^{m+1} / (m! (2m+1))]``
      (19 terms; its first three are KP's small-argument form);
    * ``0.3 <= x < 40``: the Fresnel integrals (U2b)
      ``F = sqrt(pi x/2) e^{jx} [1 + j - 2 (S(z) + j C(z))]``, ``z = sqrt(2x/pi)``,
      with scipy's double-precision ``fresnel`` (S, C normalised as
      int_0^z sin / cos(pi t^2 / 2) dt);
    * ``x >= 40``: the asymptotic series (U2c) ``F ~ sum_m (2m-1)!! (j/(2x))^m
      = 1 + j/(2x) - 3/(4x^2) - 15j/(8x^3) + 105/(16x^4) ...`` (31 terms).

    F(0) = 0, F(x) -> 1 as x -> inf.  Negative x raises ``ValueError`` (KP's
    arguments k L a^{+-} are never negative); NaN propagates.
    """
    x = np.asarray(x, dtype=np.float64)
    if np.any(x < 0):
        raise ArgumentError("transition_function: x must be >= 0")
    out = np.sqrt(x) * _transition_over_sqrt(np.where(np.isnan(x), 1.0, x))
    return np.where(np.isnan(x), np.nan + 0j, out)


# ---------------------------------------------------------------------------
# a+-, and the guarded cot * F product

def _epsilons(beta, n):
    """(eps+, eps-) = (pi + beta - 2 pi n N+, pi - beta + 2 pi n N-), |eps| <= n pi,
    with N+- = round((beta +- pi) / (2 pi n)) [KP74 eqs. (27)-(28)]."""
    beta = np.asarray(beta, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    two_pi_n = 2.0 * np.pi * n
    n_plus = np.round((beta + np.pi) / two_pi_n)
    n_minus = np.round((beta - np.pi) / two_pi_n)
    return np.pi + beta - two_pi_n * n_plus, np.pi - beta + two_pi_n * n_minus


def a_plus_minus(beta, n):
    """KP's a+-(beta) (eq. U3) [KP74 eq. (26)-(28)]::

        a+-(beta) = 2 cos^2((2 n pi N+- - beta) / 2)

    with N+- the integers that most nearly satisfy 2 pi n N+ - beta = pi and
    2 pi n N- - beta = -pi, i.e. N+- = round((beta +- pi) / (2 pi n)).  Evaluated
    as ``2 sin^2(eps/2)`` with ``eps+ = pi + beta - 2 pi n N+`` and ``eps- = pi -
    beta + 2 pi n N-`` (the same number, without the cancellation of cos near
    pi/2 at the shadow and reflection boundaries, where a = 0).

    Returns
    -------
    a_plus, a_minus : ndarray float64 in [0, 2].
    """
    ep, em = _epsilons(beta, n)
    return 2.0 * np.sin(ep / 2) ** 2, 2.0 * np.sin(em / 2) ** 2


def boundary_epsilons(phi, phi_p, n):
    """(eps1, eps2, eps3, eps4): the signed angles (rad) of the four cot*F terms D1-D4 of
    eq. U4 from their boundaries, |eps| <= n pi.

    Each is 0 on its boundary and > 0 on the side where the GO field that jumps there is
    present: the incident field for D1 (phi' - phi = pi) and D2 (phi - phi' = pi), the
    reflection off face n for D3 (phi + phi' = (2n - 1) pi), off face 0 for D4
    (phi + phi' = pi).  Far from its boundary a term's eps is just a number; the sign
    statement is for the term near 0.
    """
    phi = np.asarray(phi, dtype=np.float64)
    phi_p = np.asarray(phi_p, dtype=np.float64)
    ep_i, em_i = _epsilons(phi - phi_p, n)
    ep_r, em_r = _epsilons(phi + phi_p, n)
    return ep_i, em_i, ep_r, em_r


def _cot_f_over_sqrt_2kl(eps, n, kl, side=None):
    """cot(eps/(2n)) F(2 kL sin^2(eps/2)) / sqrt(2 kL), finite everywhere (eq. U5).

    With x = 2 kL sin^2(eps/2) and F(x) = sqrt(x) G(x)::

        cot(eps/2n) F(x) = sqrt(2kL) sgn(eps) cos(eps/2n) |sin(eps/2)/sin(eps/2n)| G(x)
        |sin(eps/2)/sin(eps/2n)| = n sinc(eps/2pi) / sinc(eps/(2 n pi))

    (np.sinc(t) = sin(pi t)/(pi t); |eps| <= n pi keeps both sincs positive).
    At eps -> 0 (a shadow or reflection boundary) this tends to
    sgn(eps) n sqrt(pi) e^{j pi/4} (KP's boundary limit, ref. §2), at eps = 0
    exactly to 0, the mean of the two one-sided limits (GO indicator 1/2 there).
    The product is sgn(eps) times an even function of eps: ``side`` (+1, -1, or 0 for
    sgn(eps)) picks the sign, i.e. the one-sided branch, where given.
    """
    x = 2.0 * kl * np.sin(eps / 2) ** 2
    ratio = n * np.sinc(eps / (2 * np.pi)) / np.sinc(eps / (2 * np.pi * n))
    sign = np.sign(eps) if side is None else np.where(side != 0, np.sign(side), np.sign(eps))
    return sign * np.cos(eps / (2 * n)) * ratio * _transition_over_sqrt(x)


# ---------------------------------------------------------------------------
# diffraction coefficients

def diffraction_coefficients(phi, phi_p, beta0, n, k, L, eps_r_0=None, eps_r_n=None, pec=True,
                             *, rho_0=1.0, rho_n=1.0, go_sides=None):
    """UTD wedge-diffraction coefficients (D_soft, D_hard) (eq. U4) [KP74 eq. (24);
    L84 eq. (6)]::

        D = -e^{-j pi/4} / (2 n sqrt(2 pi k) sin beta0) * [
                 cot((pi + (phi - phi')) / 2n) F(k L a+(phi - phi'))      (D1, incident SB)
               + cot((pi - (phi - phi')) / 2n) F(k L a-(phi - phi'))      (D2, incident SB)
               + R_n cot((pi + (phi + phi')) / 2n) F(k L a+(phi + phi'))  (D3, n-face RB)
               + R_0 cot((pi - (phi + phi')) / 2n) F(k L a-(phi + phi')) ] (D4, 0-face RB)

    PEC (``pec`` true, or an infinite ``eps_r``): R_0 = R_n = -1 for D_soft and +1
    for D_hard, KP's D_s / D_h.  Lossy faces (Luebbers' heuristic): R_0 = r(eps_r_0)
    at the incidence angle on face 0 and R_n = r(eps_r_n) at the reflection angle on
    face n, with ``r = r_te`` (r_perp) for D_soft and ``r = r_tm`` (r_par, PEC -> +1)
    for D_hard from :func:`clradcom.physics.em.fresnel_coefficients` at::

        cos theta_0 = sin(beta0) |sin phi'|,   cos theta_n = sin(beta0) |sin(n pi - phi)|

    (theta from the face normal; Luebbers' 2-D grazing angles phi' and n pi - phi,
    extended to oblique incidence by the sin(beta0) factor, which is exact for
    the ray directions).  ``rho_0``, ``rho_n`` multiply R_0, R_n (roughness,
    sqrt(1 - S^2) factors); ``rho_0 = rho_n = 0`` drops the face terms (an
    absorbing screen, the knife-edge model).

    Each cot * F product is evaluated in the guarded form of eq. U5 (no switch):
    finite and continuous through the shadow and reflection boundaries (where
    cot -> inf and F -> 0); exactly on a boundary it gives the mean of the two
    one-sided limits, so the GO field must use the indicator 1/2 there.  The
    factor sqrt(L) / sin(beta0) is formed explicitly with sin(beta0) clamped to
    ``SIN_BETA0_MIN``: with L from :func:`distance_parameter` (which carries
    sin^2 beta0) D stays finite as beta0 -> 0; exactly end-on (beta0 = 0 or pi, a
    caustic) it is 0.

    Parameters
    ----------
    phi, phi_p : array_like float
        Observation and source angles (rad) from face 0, nominally in [0, n pi]
        (the formula is 2 pi-periodic and defined for any real value).
    beta0 : array_like float
        Angle (rad) between the incident ray and the edge.
    n : array_like float
        Exterior wedge angle / pi, 0 < n <= 2 (n = 2: half-plane).
    k : array_like float
        Wave number (rad/m), > 0.
    L : array_like float
        Distance parameter (m), >= 0 (:func:`distance_parameter`).
    eps_r_0, eps_r_n : array_like complex, optional
        Relative permittivity of face 0 / face n; required where not PEC.
    pec : array_like bool
        PEC faces (both).  Where false, Luebbers' lossy form.
    rho_0, rho_n : array_like, keyword-only
        Extra factors on R_0, R_n (default 1).
    go_sides : sequence of four array_like, keyword-only
        Per term D1-D4: +1 where the caller's GO field of that term's boundary is
        present, -1 where it is absent, 0 for sgn(eps) (:func:`boundary_epsilons`).  A
        non-zero side takes the term's one-sided branch of that side at |eps|: for a
        term within rounding of its boundary, so that the GO and UTD fields are cut
        at one decision (clradcom.mechanisms.diffraction), and exactly on it, where
        sgn(eps) = 0 would give the mean of the two branches.

    Returns
    -------
    D_soft, D_hard : ndarray complex128 (m^{1/2}), the broadcast shape.
    """
    phi = np.asarray(phi, dtype=np.float64)
    phi_p = np.asarray(phi_p, dtype=np.float64)
    beta0 = np.asarray(beta0, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    k = np.asarray(k, dtype=np.float64)
    L = np.asarray(L, dtype=np.float64)
    if np.any(~((n > 0) & (n <= 2))):
        raise ArgumentError("diffraction_coefficients: n must lie in (0, 2]")
    if np.any(~(k > 0)):
        raise ArgumentError("diffraction_coefficients: k must be > 0")
    if np.any(~(L >= 0)):
        raise ArgumentError("diffraction_coefficients: L must be >= 0 (and not NaN)")
    for name, v in (("phi", phi), ("phi_p", phi_p), ("beta0", beta0)):
        if not np.all(np.isfinite(v)):
            raise ArgumentError(f"diffraction_coefficients: {name} must be finite")
    pec = np.asarray(pec, dtype=bool)
    sin_b = np.maximum(np.abs(np.sin(beta0)), SIN_BETA0_MIN)
    kl = k * L

    sides = (None,) * 4 if go_sides is None else tuple(np.asarray(g) for g in go_sides)

    def term(eps, side):
        return _cot_f_over_sqrt_2kl(eps, n, kl, side)

    ep_i, em_i, ep_r, em_r = boundary_epsilons(phi, phi_p, n)
    t_inc = term(ep_i, sides[0]) + term(em_i, sides[1])
    t_n = term(ep_r, sides[2])  # n-face reflection boundary phi + phi' = (2n - 1) pi
    t_0 = term(em_r, sides[3])  # 0-face reflection boundary phi + phi' = pi

    if np.all(pec):
        r0_s = rn_s = np.asarray(-1.0 + 0j)
        r0_h = rn_h = np.asarray(1.0 + 0j)
    else:
        if eps_r_0 is None or eps_r_n is None:
            raise ArgumentError("diffraction_coefficients: eps_r_0 and eps_r_n are required "
                             "where pec is false")
        cos0 = sin_b * np.abs(np.sin(phi_p))
        cosn = sin_b * np.abs(np.sin(n * np.pi - phi))
        r0_s, r0_h = fresnel_coefficients(eps_r_0, cos0, pec)
        rn_s, rn_h = fresnel_coefficients(eps_r_n, cosn, pec)
    rho_0 = np.asarray(rho_0)
    rho_n = np.asarray(rho_n)
    # -e^{-j pi/4} / (2n sqrt(2 pi k) sin b0) * sqrt(2kL) * [terms of U5]
    pref = -np.conj(_E_JPI4) / (2.0 * n * _SQRT_PI) * np.sqrt(L) / sin_b
    d_soft = pref * (t_inc + rho_n * rn_s * t_n + rho_0 * r0_s * t_0)
    d_hard = pref * (t_inc + rho_n * rn_h * t_n + rho_0 * r0_h * t_0)
    return d_soft.astype(np.complex128), d_hard.astype(np.complex128)


# ---------------------------------------------------------------------------
# distance parameter and spreading

def distance_parameter(s, s_prime=np.inf, beta0=np.pi / 2):
    """KP distance parameter L (eq. U6) [KP74 eqs. (29)-(30); MPK90 §6.5]::

        spherical (point source at s'):      L = s s' sin^2(beta0) / (s + s')
        plane wave (s' = inf):               L = s sin^2(beta0)
        cylindrical (line source || edge):   L = rho rho' / (rho + rho')
                                             (s, s' = rho, rho' perpendicular to the edge,
                                              beta0 = pi/2)

    Evaluated as ``s sin^2(beta0) / (1 + s/s')`` so ``s' = inf`` is the plane-wave
    limit; sin(beta0) is clamped to ``SIN_BETA0_MIN`` like
    :func:`diffraction_coefficients`.
    """
    s = np.asarray(s, dtype=np.float64)
    s_prime = np.asarray(s_prime, dtype=np.float64)
    sin_b = np.maximum(np.abs(np.sin(np.asarray(beta0, dtype=np.float64))), SIN_BETA0_MIN)
    if np.any(~(s > 0)) or np.any(~(s_prime > 0)):
        raise ArgumentError("distance_parameter: s and s_prime must be > 0")
    return s * sin_b**2 / (1.0 + s / s_prime)


def spreading_factor(s, s_prime=np.inf, wave="spherical"):
    """Spreading factor A(s) of the diffracted ray (eq. U7) [KP74 eq. (23)]::

        spherical incidence (source at s'):  A = sqrt(s' / (s (s + s')))
        plane or cylindrical incidence:      A = 1 / sqrt(s)

    ``wave`` is ``"spherical"`` (default; ``s' = inf`` gives 1/sqrt(s)), ``"plane"``
    or ``"cylindrical"``.  The diffracted field is
    ``E_d = E_i(Q) D A(s) e^{-jks}`` (scalar) with E_i(Q) the incident field at the
    diffraction point.
    """
    s = np.asarray(s, dtype=np.float64)
    if np.any(~(s > 0)):
        raise ArgumentError("spreading_factor: s must be > 0")
    if wave in ("plane", "cylindrical"):
        return 1.0 / np.sqrt(s)
    if wave != "spherical":
        raise ArgumentError(f"spreading_factor: unknown wave {wave!r}")
    s_prime = np.asarray(s_prime, dtype=np.float64)
    if np.any(~(s_prime > 0)):
        raise ArgumentError("spreading_factor: s_prime must be > 0")
    return 1.0 / np.sqrt(s * (1.0 + s / s_prime))


def multi_edge_spreading(segment_lengths, beta0=np.pi / 2):
    """Per-edge L and the product of per-edge spreading factors of a chain of N
    diffractions from a point source (eq. U8; docs/utd.md "Multiple diffraction").

    ``segment_lengths`` (..., N+1): s_0 = source -> Q_1 (unfolded over any
    reflections), s_i = Q_i -> Q_{i+1}, s_N = Q_N -> observer.  Edge i = 1..N::

        rho_i = s_0 + ... + s_{i-1}                         (incident radius along the edge)
        A_i   = sqrt(rho_i / (s_i (rho_i + s_i)))
        L_i   = s_{i-1} s_i sin^2(beta0_i) / (s_{i-1} + s_i)

    and the field is ``E = E_0 e^{-jk sum s} / s_0 * prod_i (D_i A_i)`` (scalar,
    D_i with L_i).  For i = 1 this is KP's spherical-incidence result.  For i > 1
    it treats the wave diffracted by edge i-1 as having its caustics at edge i-1
    (transverse radius s_{i-1}, which sets L_i) and at the source (radius rho_i in
    the plane of the ray and the edge, which sets A_i): exact for parallel edges
    (the total spreading is then 1/sqrt(s_0 ... s_N (s_0 + ... + s_N)), Keller's
    ray tube), an approximation for skew edges, where the principal directions of
    the incident wavefront are not aligned with the new edge.  The common cruder
    choice rho_i = s_{i-1} underestimates the amplitude of a multi-edge path.

    Returns
    -------
    A : (...,) float64  prod_i A_i (excluding the source's 1/s_0).
    L : (..., N) float64.
    """
    s = np.asarray(segment_lengths, dtype=np.float64)
    if s.ndim < 1 or s.shape[-1] < 2:
        raise ArgumentError("multi_edge_spreading: need (..., N+1) segment lengths, N >= 1")
    if np.any(~(s > 0)):
        raise ArgumentError("multi_edge_spreading: segment lengths must be > 0")
    rho = np.cumsum(s, axis=-1)[..., :-1]
    s_out = s[..., 1:]
    A = np.prod(np.sqrt(rho / (s_out * (rho + s_out))), axis=-1)
    L = distance_parameter(s_out, s[..., :-1], beta0)
    return A, L


# ---------------------------------------------------------------------------
# edge-fixed geometry

def wedge_angles(s_hat_in, s_hat_out, edge_dir, face0_normal):
    """(phi', phi, beta0) of a diffraction in KP's face-0 convention (eq. U9).

    ``s_hat_in`` is the incident propagation direction (source -> Q), ``s_hat_out``
    the diffracted one (Q -> observer), ``edge_dir`` the unit edge vector e and
    ``face0_normal`` the outward normal n0 of face 0, with e oriented so that
    ``t0 = n0 x e`` lies in face 0 pointing away from the edge (``e = t0 x n0``,
    :class:`clradcom.geometry.wedges.Wedges`' ``direction``).  n0 is made orthogonal to e.
    With v_t the part of v perpendicular to e::

        phi  = atan2(s_t . n0,  s_t . t0)  mod 2 pi
        phi' = atan2(-s'_t . n0, -s'_t . t0) mod 2 pi      (the source lies along -s')
        beta0 = arccos(s' . e)  in [0, pi]

    Returns ndarrays (...,) float64.  For an exact Keller path s . e = s' . e.
    """
    si = checked_unit(s_hat_in, "s_hat_in")
    so = checked_unit(s_hat_out, "s_hat_out")
    e = checked_unit(edge_dir, "edge_dir")
    n0 = np.asarray(face0_normal, dtype=np.float64)
    n0 = checked_unit(n0 - dot(n0, e)[..., None] * e, "face0_normal (orthogonal to edge_dir)")
    t0 = np.cross(n0, e)
    two_pi = 2.0 * np.pi
    phi = np.mod(np.arctan2(dot(so, n0), dot(so, t0)), two_pi)
    phi_p = np.mod(np.arctan2(-dot(si, n0), -dot(si, t0)), two_pi)
    beta0 = np.arccos(np.clip(dot(si, e), -1.0, 1.0))
    return phi_p, phi, beta0


def edge_fixed_basis(s_hat_in, s_hat_out, edge_dir, face0_normal=None):
    """KP edge-fixed unit vectors (eq. U10) [KP74 eqs. (6)-(9)]::

        phi_hat'   = -(e x s') / |e x s'|,   beta0_hat' = phi_hat' x s'
        phi_hat    =  (e x s)  / |e x s|,    beta0_hat  = phi_hat x s

    (s' = ``s_hat_in``, the incident propagation direction; s = ``s_hat_out``;
    (beta0_hat', phi_hat', s') and (beta0_hat, phi_hat, s) are right-handed
    orthonormal triads; phi_hat' and phi_hat point in the direction of increasing
    phi at the source and at the observer).  The diffracted field is::

        [E_beta0; E_phi]^d = -diag(D_s, D_h) [E_beta0'; E_phi']^i * A(s) e^{-jks}

    i.e. the 3x3 dyad ``-D_s beta0_hat beta0_hat'^T - D_h phi_hat phi_hat'^T``
    (:func:`diffraction_dyad`).  Sign check (docs/utd.md): for beta0 = 90 deg the
    two basis flips cancel the minus sign, so E_z^d = D_s E_z^i and H_z^d = D_h
    H_z^i, the scalar 2-D forms.  Flipping e flips all four vectors and leaves the
    dyad unchanged; e only matters for the angles (:func:`wedge_angles`), which
    is where ``face0_normal`` is used -- here it is only checked to be orthogonal
    to e when given.

    Raises ``ValueError`` when a ray runs along the edge (|e x s| < 1e-12, beta0 =
    0 or pi: the basis is undefined there).

    Returns
    -------
    beta0_hat_p, phi_hat_p, beta0_hat, phi_hat : ndarrays (..., 3) float64.
    """
    si = checked_unit(s_hat_in, "s_hat_in")
    so = checked_unit(s_hat_out, "s_hat_out")
    e = checked_unit(edge_dir, "edge_dir")
    if face0_normal is not None:
        n0 = checked_unit(face0_normal, "face0_normal")
        if np.any(np.abs(dot(n0, e)) > 1e-6):
            raise ArgumentError("edge_fixed_basis: face0_normal must be orthogonal to edge_dir")
    xi = np.cross(e, si)
    xo = np.cross(e, so)
    ni = np.linalg.norm(xi, axis=-1, keepdims=True)
    no = np.linalg.norm(xo, axis=-1, keepdims=True)
    if np.any(ni < 1e-12) or np.any(no < 1e-12):
        raise ArgumentError("edge_fixed_basis: a ray runs along the edge (beta0 = 0 or pi)")
    phi_hat_p = -xi / ni
    phi_hat = xo / no
    beta_hat_p = np.cross(phi_hat_p, si)
    beta_hat = np.cross(phi_hat, so)
    return beta_hat_p, phi_hat_p, beta_hat, phi_hat


def diffraction_dyad(d_soft, d_hard, beta_hat_p, phi_hat_p, beta_hat, phi_hat):
    """3x3 diffraction dyad (eq. U10) [KP74 eq. (5)]::

        D = -D_s beta0_hat beta0_hat'^T - D_h phi_hat phi_hat'^T,   E_d = D E_i(Q) A(s) e^{-jks}

    from the coefficients of :func:`diffraction_coefficients` and the vectors of
    :func:`edge_fixed_basis`.  Returns (..., 3, 3) complex128.
    """
    ds = np.asarray(d_soft, dtype=np.complex128)[..., None, None]
    dh = np.asarray(d_hard, dtype=np.complex128)[..., None, None]
    bb = np.asarray(beta_hat)[..., :, None] * np.asarray(beta_hat_p)[..., None, :]
    pp = np.asarray(phi_hat)[..., :, None] * np.asarray(phi_hat_p)[..., None, :]
    return -ds * bb - dh * pp
