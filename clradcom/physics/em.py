"""Field physics of an exact propagation path (host side, numpy float64).

From a path's interaction points and surfaces to its complex baseband gain, its
2x2 polarimetric matrix, delay and Doppler.  Every function takes and returns
plain arrays and is vectorised over paths ``P``.  docs/physics.md gives each
formula with its source; the equation labels below refer to it.

Conventions (docs/architecture.md, "Contracts kept between the parts"): SI units,
time factor e^{+jwt}, lossy permittivity
``eps_r = eps' - j eps''`` (imag <= 0).  A path's gain ``a`` is its baseband
channel coefficient (received baseband = sum_k a_k x(t - tau_k) e^{j2 pi f_D,k t})
with the carrier phase e^{-jkL} inside ``a``.

Field bookkeeping: one complex 3-vector per path in world coordinates.  The
transmitter launches E = C_theta theta_hat + C_phi phi_hat (its own antenna frame
mapped to world), each reflection applies a 3x3 dyad (eq. P3), the receiver
projects onto its own theta_hat / phi_hat (eq. P6).

Polarimetric matrix (eq. P6), per path::

    M[i, j] = (lambda / 4 pi) e^{-jkL} / L  *  b_rx[i] . T . b_tx[j]

    b_tx = (theta_hat_tx, phi_hat_tx) at the departure direction k_dep,
    b_rx = (theta_hat_rx, phi_hat_rx) at the direction -k_arr (towards where
           the wave comes from), both of the antenna's own frame mapped to world,

so ``M = [[VV, VH], [HV, HH]]`` (row: receive port, column: transmit port;
V = theta, H = phi) without the antenna patterns, and the gain is the bilinear
(reciprocity) form ``a = c_rx^T M c_tx`` with the patterns' complex amplitudes
``c = (C_theta, C_phi)`` (which include each antenna's Jones vector).  For
linear (real) polarisations this equals ``c_rx^H M c_tx``; for circular ones
the bilinear form is the one that is reciprocal (swapping tx and rx gives the
same ``a``) and lets two facing same-handed antennas couple fully -- see
docs/physics.md "Receive projection".
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.special import i0e

from clradcom.errors import ArgumentError, NearFieldWarning
from clradcom.physics.vectors import checked_unit, cross, dot, perpendicular
from clradcom.scene.antenna import directions_to_angles, theta_phi_unit_vectors

__all__ = [
    "C0",
    "check_path_lengths",
    "ROUGHNESS_AMENT",
    "ROUGHNESS_BOITHIAS",
    "fresnel_coefficients",
    "ament",
    "boithias",
    "roughness_factor",
    "reflection_dyad",
    "reflected_fields",
    "path_segments",
    "path_directions",
    "path_transfer",
    "polarimetric_matrix",
    "path_gains",
    "delay_s",
    "doppler_hz",
]

#: Speed of light in vacuum (m/s), exact.
C0 = 299_792_458.0
#: ``roughness_model`` codes (as in ``Scene.material_roughness_model``).
ROUGHNESS_AMENT = 0
ROUGHNESS_BOITHIAS = 1

#: Below this |k_hat x n_hat| the incidence counts as normal (eq. P3 fallback).
_NORMAL_INCIDENCE_TOL = 1e-12


# ---------------------------------------------------------------------------
# Fresnel, roughness

def fresnel_coefficients(eps_r, cos_theta, pec=None):
    """Fresnel reflection coefficients (r_te, r_tm) for a wave from air (eq. P1).

    ``c = |cos theta|`` (theta from the normal), ``a = sqrt(eps_r - sin^2 theta)``
    on the principal branch (Im a <= 0, the decaying transmitted wave for
    e^{+jwt}; for a lossless eps_r < sin^2 theta the lossy-side limit is taken)::

        r_te = r_perp = (c - a) / (c + a)
        r_tm = r_par  = (eps_r c - a) / (eps_r c + a)

    [Sionna RT em_primer eq. fresnel_vac; ITU-R P.2040-3; Balanis, Advanced
    Engineering Electromagnetics, ch. 5].  In the
    basis of :func:`reflection_dyad` a PEC has r_te = -1, r_tm = +1 (not Balanis'
    Gamma_par = -1: never mix conventions).  PEC is chosen by ``pec`` (bool,
    broadcast) or by an infinite ``eps_r``.

    Parameters
    ----------
    eps_r : array_like complex
        Relative permittivity eps' - j eps''.
    cos_theta : array_like float
        Cosine of the angle of incidence (its sign is ignored).
    pec : array_like bool, optional

    Returns
    -------
    r_te, r_tm : ndarray complex128, the broadcast shape.
    """
    eps = np.asarray(eps_r, dtype=np.complex128)
    c = np.clip(np.abs(np.asarray(cos_theta, dtype=np.float64)), 0.0, 1.0)
    is_pec = np.isinf(eps.real) | np.isinf(eps.imag)  # NaN stays NaN, never PEC
    if pec is not None:
        is_pec = is_pec | np.asarray(pec, dtype=bool)
    eps, c, is_pec = np.broadcast_arrays(eps, c, is_pec)
    eps_d = np.where(is_pec, 1.0 + 0.0j, eps)  # dummy for PEC rows, replaced below
    # eps - sin^2 = (eps - 1) + c^2: written so, c^2 survives next to eps = 1 at grazing
    # (1 - c^2 rounds to 1 below c = 1e-8, which made eps = 1 reflect totally there)
    a = np.sqrt((eps_d - 1.0) + c * c)
    a = a.real - 1j * np.abs(a.imag)  # Im a <= 0 (passive medium)
    with np.errstate(invalid="ignore", divide="ignore"):
        r_te = (c - a) / (c + a)
        r_tm = (eps_d * c - a) / (eps_d * c + a)
    # 0/0 only for eps = 1 at c = 0: no interface, nothing reflected (the limit c -> 0)
    r_te = np.where((c + a == 0) & ~np.isnan(a), 0.0 + 0.0j, r_te)
    r_tm = np.where((eps_d * c + a == 0) & ~np.isnan(a), 0.0 + 0.0j, r_tm)
    r_te = np.where(is_pec, -1.0 + 0.0j, r_te)
    r_tm = np.where(is_pec, 1.0 + 0.0j, r_tm)
    return r_te, r_tm


def _k_sigma_cos_sq(roughness_m, cos_theta, k):
    s = np.asarray(roughness_m, dtype=np.float64)
    c = np.abs(np.asarray(cos_theta, dtype=np.float64))
    return (np.asarray(k, dtype=np.float64) * s * c) ** 2


def ament(roughness_m, cos_theta, k):
    """Ament / Kirchhoff scalar roughness factor (eq. P2a)::

        rho_A = exp(-2 (k sigma_h cos theta)^2) = exp(-g / 2),  g = (2 k sigma_h cos theta)^2

    theta from the normal, sigma_h the RMS height (m), k = 2 pi / lambda
    [Ament 1953; Beckmann & Spizzichino 1963; Landron et al., IEEE TAP 44(3) 1996].
    """
    return np.exp(-2.0 * _k_sigma_cos_sq(roughness_m, cos_theta, k))


def boithias(roughness_m, cos_theta, k):
    """Boithias roughness factor (eq. P2b)::

        rho_B = rho_A * I0(2 (k sigma_h cos theta)^2) = i0e(2 (k sigma_h cos theta)^2)

    (``i0e(z) = exp(-z) I0(z)``, so this never overflows)
    [Boithias 1987, *Radio Wave Propagation*; Landron et al. 1996].
    """
    return i0e(2.0 * _k_sigma_cos_sq(roughness_m, cos_theta, k))


def roughness_factor(roughness_m, cos_theta, k, model=ROUGHNESS_AMENT):
    """rho per interaction: :func:`ament` where ``model == 0``, :func:`boithias`
    where ``model == 1`` (broadcast).  Unknown codes raise ``ValueError``."""
    model = np.asarray(model)
    if np.any((model != ROUGHNESS_AMENT) & (model != ROUGHNESS_BOITHIAS)):
        raise ArgumentError(f"roughness_model codes must be 0 (Ament) or 1 (Boithias), "
                         f"got {np.unique(model)}")
    return np.where(model == ROUGHNESS_BOITHIAS, boithias(roughness_m, cos_theta, k),
                    ament(roughness_m, cos_theta, k))


# ---------------------------------------------------------------------------
# geometry helpers

# ---------------------------------------------------------------------------
# reflection dyad

def reflection_dyad(k_in, normal, r_te, r_tm):
    """3x3 reflection dyad per path (eq. P3)::

        E_r = [ r_perp e_perp e_perp^T + r_par e_par,r e_par,i^T ] E_i
        e_perp = k_i x n / |k_i x n|,  e_par,i = e_perp x k_i,  e_par,r = e_perp x k_r,
        k_r = k_i - 2 (k_i . n) n

    [Sionna RT em_primer eqs. fresnel_in_vectors, fresnel_out_vectors].  The normal
    may point to either side: it is flipped to face the incoming ray (the dyad is
    invariant under n -> -n anyway).  At normal incidence (|k_i x n| < 1e-12)
    e_perp = n x a / |n x a| with ``a`` the world axis least aligned with n; any
    choice gives the same dyad r_perp (I - k k^T) there because r_par = -r_perp and
    e_par,r = -e_par,i.  The dyad maps the field transverse to k_i onto the field
    transverse to k_r and annihilates the k_i component.

    Parameters
    ----------
    k_in : (P,3) propagation direction of the incident ray (normalised here).
    normal : (P,3) face normal (normalised here).
    r_te, r_tm : (P,) complex (include any roughness factor).

    Returns
    -------
    D : (P,3,3) complex128.
    """
    k = checked_unit(np.asarray(k_in, dtype=np.float64).reshape(-1, 3), "k_in")
    n = checked_unit(np.asarray(normal, dtype=np.float64).reshape(-1, 3), "normal")
    if k.shape != n.shape:
        raise ArgumentError(f"k_in {k.shape} and normal {n.shape} differ in shape")
    r_te = np.broadcast_to(np.asarray(r_te, dtype=np.complex128), k.shape[:1])
    r_tm = np.broadcast_to(np.asarray(r_tm, dtype=np.complex128), k.shape[:1])
    e_perp, e_par_i, e_par_r = _reflection_basis(k, n, dot(k, n))
    return (r_te[:, None, None] * e_perp[:, :, None] * e_perp[:, None, :]
            + r_tm[:, None, None] * e_par_r[:, :, None] * e_par_i[:, None, :])


def _reflection_basis(k, n, kn):
    """(e_perp, e_par,i, e_par,r) of :func:`reflection_dyad` for unit k_in and normals
    (P, 3) with kn = k_in . n: the normal flipped to face the incoming ray, e_perp from
    :func:`perpendicular` only at normal incidence."""
    n = np.where(kn[:, None] > 0, -n, n)
    k_r = k + 2.0 * np.abs(kn)[:, None] * n
    x = cross(k, n)
    sx = np.linalg.norm(x, axis=-1)
    normal_inc = sx < _NORMAL_INCIDENCE_TOL
    e_perp = x / np.where(normal_inc, 1.0, sx)[:, None]
    if np.any(normal_inc):
        e_perp[normal_inc] = perpendicular(n[normal_inc])
    return e_perp, cross(e_perp, k), cross(e_perp, k_r)


def _material_coefficients(scene, mat, cos_t):
    """(rho r_te, rho r_tm) off scene materials ``mat`` at cos theta: Fresnel x roughness
    factor x sqrt(1 - S^2) (the specular share of :func:`material_reflection_dyad`)."""
    r_te, r_tm = fresnel_coefficients(scene.material_eps_r[mat], cos_t, scene.material_pec[mat])
    rho = roughness_factor(scene.material_roughness_m[mat], cos_t, 2.0 * np.pi / scene.wavelength_m,
                           scene.material_roughness_model[mat])
    rho = rho * np.sqrt(1.0 - scene.material_scattering[mat] ** 2)
    return rho * r_te, rho * r_tm


def material_reflection_dyad(scene, material, k_in, normal):
    """Specular reflection dyad (P,3,3) off faces of scene materials ``material`` (P,):
    Fresnel coefficients x roughness factor x sqrt(1 - S^2) (effective roughness: S^2 of
    the power goes into diffuse scattering), at cos theta = |k_in . n|.  The factor
    every single reflection off a scene face carries (mixed diffraction paths, mirror legs
    of scattering, an antenna on a face), as :func:`path_transfer` and the tracer's
    specular share give it to chains of reflections."""
    mat = np.asarray(material)
    k_in = np.asarray(k_in, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    cos_t = np.abs(dot(k_in, n) / (np.linalg.norm(k_in, axis=-1) * np.linalg.norm(n, axis=-1)))
    return reflection_dyad(k_in, n, *_material_coefficients(scene, mat, cos_t))


def reflected_fields(scene, material, k_in, normal, field):
    """The field vectors (P, 3) complex after one specular reflection off faces of scene
    materials ``material`` (P,): :func:`material_reflection_dyad` applied to ``field``
    (P, 3) without forming the dyads,
    r_perp rho (e_perp . E) e_perp + r_par rho (e_par,i . E) e_par,r (eq. P3), for many
    rays at once (radio maps). ``k_in`` and ``normal`` unit (P, 3)."""
    mat = np.asarray(material)
    k = np.asarray(k_in, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    kn = np.einsum("ij,ij->i", k, n)
    r_perp, r_par = _material_coefficients(scene, mat, np.abs(kn))
    e_perp, e_par_i, e_par_r = _reflection_basis(k, n, kn)
    E = np.asarray(field, dtype=np.complex128)
    along_perp = r_perp * np.einsum("ij,ij->i", e_perp, E)
    along_par = r_par * np.einsum("ij,ij->i", e_par_i, E)
    return along_perp[:, None] * e_perp + along_par[:, None] * e_par_r


# ---------------------------------------------------------------------------
# path transfer

def _num_interactions(num_interactions, n_paths, k_max):
    if num_interactions is None:
        return np.full(n_paths, k_max, dtype=np.int64)
    nk = np.asarray(num_interactions)
    if nk.shape != (n_paths,) or nk.dtype.kind not in "iu":
        raise ArgumentError(f"num_interactions must be ({n_paths},) integers, got "
                         f"shape {nk.shape} dtype {nk.dtype}")
    if np.any(nk < 0) or np.any(nk > k_max):
        raise ArgumentError(f"num_interactions must lie in [0, {k_max}]")
    return nk.astype(np.int64)


def _check_points(points):
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[-1] != 3 or pts.shape[1] < 2:
        raise ArgumentError(f"points must have shape (P, K+2, 3), got {pts.shape}")
    return pts


def _point_mask(n_paths, n_pts, nk):
    """(P, K+2) bool: the points a path uses (tx, its n interactions, rx)."""
    return np.arange(n_pts)[None, :] <= nk[:, None] + 1


def path_segments(points, num_interactions=None):
    """Unit segment directions and lengths of padded paths.

    ``points`` (P, K+2, 3): tx, the K interaction points, rx.  A path ``p`` with
    ``num_interactions[p] = n < K`` uses ``points[p, :n+2]`` (rx at index n+1);
    the rest is padding and is ignored (it may hold NaN).  Non-finite used points
    and zero-length used segments raise ``ValueError``.

    Returns
    -------
    u : (P, K+1, 3) unit directions start -> end (zeros on padding segments).
    s : (P, K+1) segment lengths (0 on padding).
    active : (P, K+1) bool, which segments belong to the path.
    """
    pts = _check_points(points)
    n_paths, n_pts = pts.shape[:2]
    nk = _num_interactions(num_interactions, n_paths, n_pts - 2)
    used = _point_mask(n_paths, n_pts, nk)
    if not np.all(np.isfinite(pts[used])):
        bad = np.argwhere(used & ~np.all(np.isfinite(pts), axis=-1))[0]
        raise ArgumentError(f"points hold NaN or inf (path {bad[0]}, point {bad[1]})")
    pts = np.where(used[..., None], pts, 0.0)
    d = pts[:, 1:] - pts[:, :-1]
    s = np.linalg.norm(d, axis=-1)
    active = np.arange(n_pts - 1)[None, :] <= nk[:, None]
    if np.any(active & (s == 0)):
        bad = np.argwhere(active & (s == 0))[0]
        raise ArgumentError(f"path {bad[0]} has a zero-length segment {bad[1]} "
                         "(two consecutive points coincide)")
    s = np.where(active, s, 0.0)
    u = np.where(active[..., None], d / np.where(s > 0, s, 1.0)[..., None], 0.0)
    return u, s, active


def path_directions(points, num_interactions=None):
    """(k_dep, k_arr), each (P,3): the unit propagation direction leaving the
    transmitter (first segment) and arriving at the receiver (last active segment)."""
    u, _, _ = path_segments(points, num_interactions)
    n_paths, k_max = u.shape[0], u.shape[1] - 1
    nk = _num_interactions(num_interactions, n_paths, k_max)
    return u[:, 0].copy(), u[np.arange(n_paths), nk].copy()


def path_transfer(points, face_normals, eps_r, pec, roughness_m, roughness_model, carrier_hz,
                  num_interactions=None):
    """Dyad chain T and unfolded length L of specular paths (eqs. P3, P4).

    ::

        T = D_K ... D_2 D_1 (I - k_0 k_0^T),   L = sum_i |x_{i+1} - x_i|

    with D_i = :func:`reflection_dyad` at interaction i, its Fresnel coefficients
    (:func:`fresnel_coefficients`) multiplied by the roughness factor
    (:func:`roughness_factor`, eq. P2) at cos theta_i = |k_{i-1} . n_i|.  For K = 0
    (line of sight) T is the transverse projector I - k k^T.  Spherical spreading
    is applied later on the unfolded length (image method: a chain of planar
    reflections has divergence factor 1/L_total), see :func:`polarimetric_matrix`.

    The incident direction of each interaction is the actual segment from the
    points; the outgoing basis uses the reflection law (for an exact specular
    path the two agree).

    Variable numbers of interactions: all arrays are padded to the longest path
    K; ``num_interactions`` (P,) int gives each path's own n <= K (default: K
    for all).  Interactions i >= n and points beyond n+1 are ignored (any
    values, NaN included).

    Parameters
    ----------
    points : (P, K+2, 3) float  tx, interaction points, rx (world, m).
    face_normals : (P, K, 3) float  normal of the face at each interaction (either side).
    eps_r : (P, K) complex  relative permittivity (broadcast); ignored where PEC.
    pec : (P, K) bool  PEC flag (broadcast).
    roughness_m : (P, K) float  RMS height sigma_h (broadcast).
    roughness_model : (P, K) int  0 Ament, 1 Boithias (broadcast).
    carrier_hz : float
    num_interactions : (P,) int, optional

    Returns
    -------
    T : (P,3,3) complex128,  L : (P,) float64.
    """
    pts = _check_points(points)
    n_paths, k_max = pts.shape[0], pts.shape[1] - 2
    nk = _num_interactions(num_interactions, n_paths, k_max)
    nrm = np.asarray(face_normals, dtype=np.float64)
    if nrm.shape != (n_paths, k_max, 3):
        raise ArgumentError(f"face_normals must have shape {(n_paths, k_max, 3)}, got {nrm.shape}")
    shape = (n_paths, k_max)
    eps = np.broadcast_to(np.asarray(eps_r, dtype=np.complex128), shape)
    pec_a = np.broadcast_to(np.asarray(pec, dtype=bool), shape)
    rough = np.broadcast_to(np.asarray(roughness_m, dtype=np.float64), shape)
    model = np.broadcast_to(np.asarray(roughness_model), shape)
    u, s, _ = path_segments(pts, nk)
    k0 = 2.0 * np.pi * float(carrier_hz) / C0

    T = np.eye(3)[None] - u[:, 0, :, None] * u[:, 0, None, :]
    T = T.astype(np.complex128)
    for i in range(k_max):
        act = nk > i
        if not np.any(act):
            continue
        idx = np.nonzero(act)[0]
        k_in = u[idx, i]
        n_i = nrm[idx, i]
        n_i = checked_unit(n_i, f"face_normals[:, {i}]")
        cos_t = np.abs(dot(k_in, n_i))
        r_te, r_tm = fresnel_coefficients(eps[idx, i], cos_t, pec_a[idx, i])
        rho = roughness_factor(rough[idx, i], cos_t, k0, model[idx, i])
        D = reflection_dyad(k_in, n_i, rho * r_te, rho * r_tm)
        T[idx] = D @ T[idx]
    return T, s.sum(axis=1)


# ---------------------------------------------------------------------------
# antenna bases, polarimetric matrix, gains

def _antenna_basis_world(directions_world, orientation):
    """theta_hat, phi_hat (P,3) of the antenna frame (columns of ``orientation`` =
    local axes in world) at world directions, mapped back to world."""
    R = np.asarray(orientation, dtype=np.float64)
    if R.shape != (3, 3):
        raise ArgumentError(f"orientation must be (3,3), got {R.shape}")
    d_loc = np.asarray(directions_world, dtype=np.float64).reshape(-1, 3) @ R
    theta, phi = directions_to_angles(d_loc)
    th, ph = theta_phi_unit_vectors(theta, phi)
    return d_loc, th @ R.T, ph @ R.T


def check_path_lengths(L, wavelength: float, stacklevel: int = 2) -> None:
    """Refuse path lengths L (m) that are not finite and positive; warn
    (:class:`NearFieldWarning`; ``stacklevel`` as warnings.warn would take it where this
    is called) of those shorter than a wavelength: 1/L is finite for any L > 0, but
    below a wavelength it is not a field any more (|a| > 1 below lambda/(4 pi)), so say
    so rather than hand back a silent number."""
    L = np.asarray(L, dtype=np.float64)
    if np.any(~np.isfinite(L)) or np.any(L <= 0):
        raise ArgumentError("path lengths L must be finite and > 0")
    short = L < wavelength
    if short.any():
        i = int(np.argmin(L))
        warnings.warn(f"{int(short.sum())} path(s) shorter than a wavelength (L[{i}] = "
                      f"{L[i]!r} m < lambda = {wavelength!r} m): the far-field spreading "
                      "lambda/(4 pi L) does not hold there", NearFieldWarning,
                      stacklevel=stacklevel + 1)


def polarimetric_matrix(T, L, k_dep, k_arr, tx_orientation, rx_orientation, carrier_hz):
    """2x2 polarimetric matrix per path without antenna patterns (eqs. P5, P6)::

        M[i, j] = (lambda / 4 pi) e^{-jkL} / L * b_rx[i] . T . b_tx[j]

    b_tx = (theta_hat, phi_hat) of the tx frame at k_dep; b_rx = (theta_hat,
    phi_hat) of the rx frame at -k_arr; M = [[VV, VH], [HV, HH]].  For a
    monostatic radar (same frame, k_arr = -k_dep) this is the backscatter-
    alignment (BSA) basis: a PEC plate at normal incidence gives M ~ -I.

    Parameters
    ----------
    T : (P,3,3) complex, L : (P,) float (from :func:`path_transfer`).
    k_dep, k_arr : (P,3) unit propagation directions leaving tx / arriving at rx (world).
    tx_orientation, rx_orientation : (3,3) float, columns = local axes in world.
    carrier_hz : float

    Returns
    -------
    M : (P,2,2) complex128.
    """
    T = np.asarray(T, dtype=np.complex128)
    L = np.asarray(L, dtype=np.float64).reshape(-1)
    if T.ndim != 3 or T.shape[1:] != (3, 3) or T.shape[0] != L.shape[0]:
        raise ArgumentError(f"T must be (P,3,3) and L (P,), got {T.shape} and {L.shape}")
    lam = C0 / float(carrier_hz)
    check_path_lengths(L, lam, stacklevel=3)
    _, th_t, ph_t = _antenna_basis_world(k_dep, tx_orientation)
    _, th_r, ph_r = _antenna_basis_world(-np.asarray(k_arr, dtype=np.float64), rx_orientation)
    b_tx = np.stack([th_t, ph_t], axis=-1)  # (P,3,2)
    b_rx = np.stack([th_r, ph_r], axis=-1)
    scale = lam / (4.0 * np.pi) * np.exp(-1j * (2.0 * np.pi / lam) * L) / L
    return scale[:, None, None] * (np.swapaxes(b_rx, 1, 2) @ T @ b_tx)


def path_gains(T, L, k_dep, k_arr, tx, rx, carrier_hz):
    """Complex baseband gain a (P,) and polarimetric matrix M (P,2,2) (eqs. P5-P7)::

        a = c_rx^T M c_tx = (lambda/4 pi) e^{-jkL}/L * E_rx . T . E_tx

    with c_tx = tx.pattern.field(k_dep in the tx frame) and c_rx =
    rx.pattern.field(-k_arr in the rx frame), each (C_theta, C_phi) with
    |c|^2 = directivity and the antenna's polarisation (Jones vector) included,
    E = C_theta theta_hat + C_phi phi_hat in world.  The receive projection is the
    bilinear reciprocity form (Sionna's C_R^H T C_T for real patterns; see the
    module docstring).

    ``tx`` and ``rx`` are :class:`clradcom.scene.Radar` objects or anything with
    ``orientation`` (3,3) and ``pattern`` (a :class:`clradcom.scene.antenna.Pattern`).
    """
    M = polarimetric_matrix(T, L, k_dep, k_arr, tx.orientation, rx.orientation, carrier_hz)
    d_tx = np.asarray(k_dep, dtype=np.float64).reshape(-1, 3) @ np.asarray(tx.orientation)
    d_rx = -np.asarray(k_arr, dtype=np.float64).reshape(-1, 3) @ np.asarray(rx.orientation)
    c_tx = np.asarray(tx.pattern.field(d_tx), dtype=np.complex128)
    c_rx = np.asarray(rx.pattern.field(d_rx), dtype=np.complex128)
    a = np.einsum("pi,pij,pj->p", c_rx, M, c_tx)
    return a, M


# ---------------------------------------------------------------------------
# delay, Doppler

def delay_s(L):
    """Propagation delay tau = L / c0 (s), c0 = 299 792 458 m/s."""
    return np.asarray(L, dtype=np.float64) / C0


def doppler_hz(points, velocities, wavelength, num_interactions=None):
    """Doppler shift f_D = -(1/lambda) dL/dt per path (eq. P8)::

        dL/dt = sum_i (v_{i+1} - v_i) . u_i,   u_i = (x_{i+1} - x_i) / |x_{i+1} - x_i|

    over the active segments, each vertex moving with its object (tx and rx with
    theirs; v + omega x r for a rotating body).  For a specular reflection on a
    moving planar face the reflection point slides over the face, but by
    Fermat's principle L is stationary with respect to that sliding, so to first
    order dL/dt is the same as if the point were glued to the face (likewise
    Keller's law for edge diffraction); for a scattering tile the vertex is a
    material point and the formula is exact [physics reference §4; Sionna RT
    paths.py ``doppler``; Wiffen et al. 2018].  A closing monostatic reflector
    gives +2 v / lambda (160.11 Hz per m/s at 24 GHz).

    Parameters
    ----------
    points, velocities : (P, K+2, 3) float  positions (m) and velocities (m/s).
    wavelength : float  (m)
    num_interactions : (P,) int, optional (padding as in :func:`path_segments`;
        padding velocities may hold NaN).

    Returns
    -------
    f_D : (P,) float64 (Hz).
    """
    u, _, active = path_segments(points, num_interactions)
    v = np.asarray(velocities, dtype=np.float64)
    if v.shape != np.shape(points):
        raise ArgumentError(f"velocities {v.shape} must match points {np.shape(points)}")
    n_paths, n_pts = v.shape[:2]
    used = _point_mask(n_paths, n_pts, _num_interactions(num_interactions, n_paths, n_pts - 2))
    if not np.all(np.isfinite(v[used])):
        raise ArgumentError("velocities hold NaN or inf")
    v = np.where(used[..., None], v, 0.0)
    dv = np.where(active[..., None], v[:, 1:] - v[:, :-1], 0.0)
    dLdt = np.sum(dv * u, axis=(1, 2))
    return -dLdt / float(wavelength)
