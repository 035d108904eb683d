"""Stability suite: what clradcom does where its methods stop working (issue #10, part 3).

Each test states in its docstring what happens there physically and what the code does,
and asserts exactly that: a finite, bounded result; continuity where the physics is
continuous; or a specific warning (:class:`clradcom.errors.PhysicsWarning` subclasses).
docs/stability.md is the table of cases, with the tests elsewhere that cover parts of it.
"""

from __future__ import annotations

import contextlib
import math
import warnings

import numpy as np
import pytest
from dsp_helpers import small_waveform
from scipy.special import fresnel as scipy_fresnel
from test_paths import (
    ETA_ROAD,
    K0,
    LAM,
    ROAD,
    fresnel,
    plane,
    radar,
    scene_dict,
    sigma_eq,
    spreading,
    two_ray_dict,
)

from clradcom.errors import (
    AliasingWarning,
    CausticWarning,
    CyclicPrefixWarning,
    NearFieldWarning,
    PhysicsWarning,
    SurfaceContactWarning,
)
from clradcom.geometry.faces import merge_coplanar
from clradcom.geometry.wedges import extract_wedges
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.diffraction import GRAZING_RAD
from clradcom.physics.em import (
    ament,
    boithias,
    fresnel_coefficients,
    path_transfer,
    reflection_dyad,
)
from clradcom.radar import (
    channel_transfer_function,
    ofdm_demodulate,
    radar_image,
    random_symbols,
    spectral_estimate,
    synthesize_frequency_domain,
    synthesize_time_domain,
)
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import DiffractionSettings, SpecularSettings, TraceSettings, trace_scene

GO = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=5_000),
                   diffraction=DiffractionSettings(max_diffractions=0))


def link(data, settings=GO, runtime=None):
    snap = trace_scene(scene_from_dict(data), settings, runtime=runtime)
    assert len(snap.links) == 1
    return snap.links[0].paths


def assert_finite(paths):
    for name in ("gain", "matrix", "delay_s", "doppler_hz"):
        assert np.all(np.isfinite(getattr(paths, name))), name


@contextlib.contextmanager
def no_physics_warnings():
    """A context in which any PhysicsWarning fails the test."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", PhysicsWarning)
        yield


# ---------------------------------------------------------------------------
# 1. grazing incidence, theta -> 90 deg


@pytest.mark.parametrize("eps_r", [ETA_ROAD, 10 - 6j, 0.5 + 0j, 1 - 7.5e6j, 80 - 0.0j])
def test_fresnel_tends_to_minus_one_at_grazing(eps_r):
    """Physics: any non-PEC half-space reflects r_te = r_tm = -1 at grazing incidence,
    approached linearly in cos(theta): 1 + r_te ~ 2c/a, 1 + r_tm ~ 2 eps c / a with
    a = sqrt(eps - 1).  Code: em.fresnel_coefficients follows that limit continuously
    down to cos(theta) = 1e-12 and gives -1 exactly at 0; |r| <= 1 throughout."""
    c = np.concatenate([np.logspace(-1, -12, 23), [0.0]])
    r_te, r_tm = fresnel_coefficients(eps_r, c)
    assert np.all(np.isfinite(r_te)) and np.all(np.isfinite(r_tm))
    assert np.all(np.abs(r_te) <= 1 + 1e-12) and np.all(np.abs(r_tm) <= 1 + 1e-12)
    assert abs(r_te[-1] + 1) < 1e-15 and abs(r_tm[-1] + 1) < 1e-15
    a = np.sqrt(eps_r - 1 + 0j)
    a = a.real - 1j * abs(a.imag)
    small = (c < 1e-7) & (c > 0)
    for r, lin in ((r_te, 2 * c / a), (r_tm, 2 * eps_r * c / a)):
        # -1 + the linear term, up to its square (and float64 rounding of r near -1)
        dev = np.abs(r[small] - (-1 + lin[small]))
        assert np.all(dev <= 1e-15 + 2 * np.abs(lin[small]) ** 2), dev
    # monotone approach: no wiggle on the way to -1
    assert np.all(np.diff(np.abs(1 + r_te)) <= 1e-15)
    assert np.all(np.diff(np.abs(1 + r_tm[c < 1e-4])) <= 1e-15)


def test_no_interface_reflects_nothing_even_at_grazing():
    """Physics: eps_r = 1 is no interface: r = 0 at every angle, grazing included.
    Code: em.fresnel_coefficients forms eps - sin^2 theta as (eps - 1) + cos^2 theta, so
    cos^2 theta survives next to eps = 1 (written as eps - (1 - cos^2) it rounded to 0
    below cos theta = 1e-8 and gave total reflection, r = +1); at cos theta = 0 exactly
    the 0/0 is the limit 0.  NaN permittivities still give NaN, never a number."""
    c = np.array([0.5, 1e-6, 1e-9, 1e-12, 0.0])
    for r in fresnel_coefficients(1.0 + 0j, c):
        np.testing.assert_array_equal(r, 0)
    # a faint interface, eps = 1 + 1e-6: r turns to -1 only once cos theta << 1e-3
    r_te, r_tm = fresnel_coefficients(1.0 + 1e-6 + 0j, c)
    assert abs(r_te[0]) < 1e-5 and np.all(np.abs(r_te[3:] + 1) < 1e-5)
    assert np.all(np.isfinite(r_tm)) and np.all(np.abs(r_tm) <= 1)
    assert np.isnan(fresnel_coefficients(np.nan + 0j, 0.0)[0])


def test_roughness_and_dyad_at_grazing():
    """Physics: a rough surface looks smooth at grazing (Rayleigh criterion: the phase
    spread 2 k sigma cos(theta) -> 0); the reflected field of a grazing ray stays a
    bounded transverse field.  Code: Ament and Boithias factors -> 1; the reflection
    dyad stays finite, maps a unit field to at most unit norm, and keeps the reflected
    field transverse to the reflected direction, down to a grazing angle of 1e-12 rad."""
    c = np.array([1e-2, 1e-6, 1e-12, 0.0])
    assert np.all(np.abs(ament(5e-3, c, K0) - 1) <= 2 * (K0 * 5e-3 * c) ** 2 + 1e-15)
    assert boithias(5e-3, 0.0, K0) == 1.0 and ament(5e-3, 0.0, K0) == 1.0
    k_in = np.stack([np.cos(np.arcsin(c)), np.zeros(4), -c], axis=1)
    normal = np.tile([0.0, 0.0, 1.0], (4, 1))
    r_te, r_tm = fresnel_coefficients(ETA_ROAD, c)
    D = reflection_dyad(k_in, normal, r_te, r_tm)
    assert np.all(np.isfinite(D))
    k_r = k_in * [1, 1, -1]
    for e_in in (np.array([0.0, 1.0, 0.0]), np.cross(k_in, [0.0, 1.0, 0.0])):
        e_out = np.einsum("pij,pj->pi", D, np.broadcast_to(e_in, (4, 3)))
        assert np.all(np.linalg.norm(e_out, axis=1) <= 1 + 1e-12)
        assert np.all(np.abs(np.sum(e_out * k_r, axis=1)) < 1e-12)
    # V (in the plane of incidence) at grazing: r_tm = -1 flips the field
    e_v = np.cross([0.0, 1.0, 0.0], k_in[-1])
    np.testing.assert_allclose(D[-1] @ e_v, -np.cross([0.0, 1.0, 0.0], k_r[-1]), atol=1e-15)


@pytest.mark.parametrize("pol", ["V", "H"])
def test_two_ray_through_the_tracer_down_to_grazing(runtime, pol):
    """Physics: antennas at height h over a smooth road, 20 m apart: the reflection tends to
    grazing as h -> 0, r -> -1, and the total field vanishes like |1 + r| + 2 k h^2 / d
    (the GO two-ray limit; no surface wave).  Code: the tracer finds the reflection down
    to h = 0.1 mm, its gain is the closed-form Fresnel coefficient times spherical
    spreading, and the sum of both paths follows the closed form continuously to zero."""
    d = 20.0
    free = LAM / (4 * np.pi * d)
    prev = np.inf
    for h in (0.05, 1e-2, 1e-3, 1e-4):
        p = link(two_ray_dict(d, pol, h_t=h, h_r=h), runtime=runtime)
        assert sorted(p.n_interactions.tolist()) == [0, 1]
        i_ref = int(np.flatnonzero(p.n_interactions == 1)[0])
        l_ref = math.hypot(d, 2 * h)
        r_te, r_tm = fresnel(ETA_ROAD, 2 * h / l_ref)
        # H: facing antennas have opposite phi-hat, both paths carry a factor -1
        sign, r = (1, r_tm) if pol == "V" else (-1, r_te)
        np.testing.assert_allclose(p.gain[i_ref], sign * r * spreading(l_ref), rtol=1e-6)
        total = abs(p.gain.sum()) / free
        expected = abs(spreading(d) + r * spreading(l_ref)) / free
        assert total == pytest.approx(expected, rel=1e-5, abs=1e-9)
        assert total < prev  # tends to zero, monotonically
        prev = total
    # 1 + r ~ 2 cos(theta) / sqrt(eps - 1) and the phase lag 2 k h^2 / d, at h = 0.1 mm
    bound = 2 * (2e-4 / d) / abs(np.sqrt(ETA_ROAD - 1)) * (abs(ETA_ROAD) if pol == "V" else 1)
    assert prev < 1.1 * (bound + 2 * K0 * 1e-8 / d)

# ---------------------------------------------------------------------------
# 2. a receiver on a shadow or reflection boundary (GO + UTD through the tracer)


def utd_settings(max_reflections=1):
    """Single diffraction without reflections around it (when the tracer can do those)."""
    return TraceSettings(
        specular=SpecularSettings(max_reflections=max_reflections, rays=2_000),
        diffraction=DiffractionSettings(max_diffractions=1, max_reflections=0))


def knife_edge(h, pol, offset=(0.0, 0.0, 0.0)):
    """tx and rx 10 m either side of a 100 m PEC screen whose top edge is h above their
    line (h < 0: the line of sight is clear)."""
    o = np.asarray(offset, dtype=float)
    return scene_dict(
        objects=[plane("screen", "metal", (100.0, 100.0), o + [0.0, 0.0, h - 50.0],
                       (0.0, -90.0, 0.0))],
        radars=[radar("tx", o + [-10.0, 0.0, 0.0], role="tx", polarization=pol),
                radar("rx", o + [10.0, 0.0, 0.0], role="rx", polarization=pol,
                      orientation_deg=[0.0, 0.0, 180.0])])


def relative_field(paths, d=20.0):
    """Total received field over the free-space line of sight (complex, with its phase)."""
    return paths.gain.sum() / spreading(d)


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (0.0, 0.0, 1000.0), (731.3, 689.7, 12.1)],
                         ids=["origin", "z1km", "xy1km"])
def test_shadow_boundary_is_continuous(runtime, offset):
    """Physics: crossing the shadow boundary of an edge the line of sight switches off and
    the diffracted field jumps by the same amount: the total (Fresnel's knife edge,
    |E/E0| = 1/2 on the boundary) is continuous.  Code: the line of sight is confirmed by a
    float32 any-hit cast that is re-decided in float64 against the face it hit
    (visibility.blocked_in_float64), so it switches off where the float64 UTD coefficient
    changes side, down to 1e-6 m of the edge even 1 km from the origin; the complex total
    is continuous across the boundary within 0.01 of the free-space field.  (Without the
    float64 re-check a 30 um band under the edge at 1 km lost the line of sight while the
    UTD field was still on its lit side: the total's phase flipped by pi.)"""
    fields = {}
    for h in (-1e-4, -1e-5, -3e-6, 3e-6, 1e-5, 1e-4):
        p = link(knife_edge(h, "V", offset), utd_settings(0), runtime=runtime)
        assert_finite(p)
        assert (0 in p.n_interactions.tolist()) == (h < 0), h  # LOS iff the edge is below
        fields[h] = relative_field(p)
    values = np.array(list(fields.values()))
    assert np.all(np.abs(np.abs(values) - 0.5) < 0.01)  # J(0) = 6 dB
    assert np.max(np.abs(np.diff(values))) < 0.01


def fresnel_knife_edge(nu):
    """Fresnel's knife-edge field over the free-space one (e^{+j omega t}), the closed form
    independent of clradcom: F(nu) = (1 + j)/2 int_nu^inf e^{-j pi t^2 / 2} dt;
    F(0) = 1/2, F(-inf) = 1, |dF/dnu| = 1/sqrt(2)."""
    s_nu, c_nu = scipy_fresnel(nu)
    return (1 + 1j) / 2 * ((1 - 1j) / 2 - c_nu + 1j * s_nu)


#: the sweep across a boundary: the angle off it runs down to ~1e-12 rad, and onto it
SWEEP = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 5e-12)


def assert_follows_knife_edge(values, nus, go, tol):
    """``values`` (complex, by increasing nu) match go x F(nu) within ``tol`` and step no
    more than the knife edge's own slope allows (|go| |dnu| / sqrt(2), + 1e-6 for the
    other edges' smooth terms and rounding): a jump of the GO field would be ~|go|."""
    values, nus = np.asarray(values), np.asarray(nus)
    expected = go * fresnel_knife_edge(nus)
    assert np.max(np.abs(values - expected)) < tol, np.abs(values - expected)
    allowed = abs(go) * np.abs(np.diff(nus)) / np.sqrt(2) * 1.2 + 1e-6
    assert np.all(np.abs(np.diff(values)) <= allowed), np.abs(np.diff(values)) / allowed


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (0.0, 0.0, 1000.0), (731.3, 689.7, 12.1)],
                         ids=["origin", "z1km", "xy1km"])
def test_shadow_boundary_sweep_follows_the_knife_edge(runtime, offset):
    """Physics: the field behind a screen's edge is Fresnel's knife edge F(nu), continuous
    through the shadow boundary (F(0) = 1/2).  Code: the screen's edge h = +-1e-4 ...
    +-5e-12 m off the line of sight (1e-5 ... 1e-12 rad seen from the edge) and exactly on
    it: the total matches F(nu) within 0.01 (0.004: the PEC screen's face terms), never
    steps more than F's own slope allows, and no BoundaryWarning: the line of sight is
    decided in float64 at the rim with no tolerance band, and the edge's UTD term, within
    float32 resolution of its boundary, takes the side of that decision (GO_MATCH_REL),
    also exactly on the boundary, where it used to give the mean of its sides (|E| ~ 0,
    with a BoundaryWarning), and 1 km away, where the line of sight went off 1e-6 m
    early."""
    nu_per_m = np.sqrt(2 * 20.0 / (LAM * 10.0 * 10.0))
    hs = sorted([-h for h in SWEEP] + [0.0] + list(SWEEP))
    values = []
    for h in hs:
        with no_physics_warnings():
            p = link(knife_edge(h, "V", offset), utd_settings(0), runtime=runtime)
        assert_finite(p)
        values.append(relative_field(p))
    assert_follows_knife_edge(values, np.asarray(hs) * nu_per_m, 1.0, 0.01)


def plate_rim_scene(shift, pol, offset=(0.0, 0.0, 0.0)):
    """A 1 m PEC plate on the ground whose near rim lies ``shift`` metres before the
    specular point of tx (0, 0, 0.8) -> rx (6, 0, 1.6); shift < 0: the point is off it."""
    o = np.asarray(offset, dtype=float)
    x_spec = 6.0 * 0.8 / 2.4
    return scene_dict(objects=[plane("plate", "metal", (1.0, 1.0),
                                     o + [x_spec + 0.5 - shift, 0.0, 0.0])],
                      radars=[radar("tx", o + [0.0, 0.0, 0.8], role="tx", polarization=pol),
                              radar("rx", o + [6.0, 0.0, 1.6], role="rx", polarization=pol)])


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (1000.0, -300.0, 0.0)],
                         ids=["origin", "1km"])
@pytest.mark.parametrize("pol", ["V", "H"])
def test_reflection_boundary_is_continuous(runtime, pol, offset):
    """Physics: as the specular point crosses the rim of a plate the reflected ray vanishes
    and the rim's diffracted field takes over continuously.  Code: whether the exact
    (float64) reflection point lies inside the plate is decided in float64
    (visibility.containing_triangles), not by the float32 hit, so the reflection appears
    exactly where the rim's UTD coefficient changes side; the complex sum of reflection
    and diffraction is continuous within 1e-3 of the line of sight across +-1e-7 m (at
    1 km: +-2e-5 m, inside the float32 resolution there) and smooth to +-1e-4 m.
    (The float32 decision alone kept the reflection up to ~2e-7 m outside the rim at the
    origin: the total jumped by ~0.9 of the line of sight.)"""
    small = 1e-7 if offset == (0.0, 0.0, 0.0) else 2e-5
    fields = {}
    for shift in (-1e-4, -small, small, 1e-4):
        p = link(plate_rim_scene(shift, pol, offset), utd_settings(1), runtime=runtime)
        assert_finite(p)
        n = p.n_interactions.tolist()
        reflected = [i for i in range(len(n)) if n[i] == 1 and p.interaction[i, 0] == 1]
        assert bool(reflected) == (shift > 0), shift
        los = p.gain[np.asarray(n) == 0].sum()
        fields[shift] = (p.gain.sum() - los) / los
    assert abs(fields[small] - fields[-small]) < 1e-3
    assert abs(fields[1e-4] - fields[-1e-4]) < 0.02
    assert 0.3 < abs(fields[small]) < 0.7  # about half the reflection, as for a half-plane


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (1000.0, -300.0, 0.0)],
                         ids=["origin", "1km"])
@pytest.mark.parametrize("pol", ["V", "H"])
def test_reflection_boundary_sweep_follows_the_knife_edge(runtime, pol, offset):
    """Physics: near the rim of a plate its reflection is the image source's wave cut by a
    knife edge: reflected field x F(nu), continuous through the reflection boundary.
    Code: the rim +-1e-4 ... +-5e-12 m from the specular point (down to ~1e-12 rad) and
    exactly on it: the reflection plus that rim's diffraction matches (the GO reflection)
    x F(nu) within 0.03 of the line of sight (0.019: the rim's terms for the incident
    wave, which a knife edge has not), steps no more than F's slope allows, and
    no BoundaryWarning: the reflection point is inside exactly up to the rim (the
    INSIDE_TOL_REL rounding allowance is for seams only) and the rim's UTD term takes the
    side of that decision.  (The allowance kept the reflection up to 1e-9 (1 + |p|) m past
    the rim: the total was off by the whole reflection there, and exactly on the rim by
    half of it.)"""
    x_spec, h_t, h_r = 2.0, 0.8, 1.6
    d1, d2 = math.hypot(x_spec, h_t), math.hypot(6.0 - x_spec, h_r)
    # the rim's distance from the image line (tx' -> rx) per metre of shift
    nu_per_m = -(h_t + h_r) / math.hypot(6.0, h_t + h_r) * np.sqrt(
        2 * (d1 + d2) / (LAM * d1 * d2))
    shifts = sorted([-s for s in SWEEP] + [0.0] + list(SWEEP))
    values, go = [], None
    for shift in shifts:
        with no_physics_warnings():
            p = link(plate_rim_scene(shift, pol, offset), utd_settings(1), runtime=runtime)
        assert_finite(p)
        n = p.n_interactions
        reflected = np.flatnonzero((n == 1) & (p.interaction[:, 0] == 1))
        assert len(reflected) == (shift > 0 or (shift == 0 and len(reflected))), shift
        rim = np.flatnonzero((n == 1) & (p.interaction[:, 0] == 2) & (np.abs(
            p.points[:, 1, 0] - offset[0] - (x_spec - shift)) < 1e-6))
        assert len(rim) == 1, shift
        los = p.gain[n == 0].sum()
        if shift == SWEEP[-1]:
            go = p.gain[reflected[0]] / los
        values.append(p.gain[np.concatenate([reflected, rim])].sum() / los)
    order = np.argsort(np.asarray(shifts) * nu_per_m)
    assert_follows_knife_edge(np.asarray(values)[order], (np.asarray(shifts) * nu_per_m)[order],
                              go, 0.03)


# ---------------------------------------------------------------------------
# 3. caustics and edges seen end-on


def end_on_scene(delta, h=0.3):
    """tx and rx 60 m either side of a 100 m screen's top edge (z = h, along y), both
    ``delta`` off the edge's line: as delta -> 0 each sees the edge end-on (beta0 -> 0),
    where the diffracted rays' Keller cone collapses onto the edge (a caustic)."""
    return scene_dict(
        objects=[plane("screen", "metal", (100.0, 100.0), (0.0, 0.0, h - 50.0),
                       (0.0, -90.0, 0.0))],
        radars=[radar("tx", (delta, -60.0, h + 0.5 * delta), role="tx"),
                radar("rx", (delta, 60.0, h + 0.5 * delta), role="rx",
                      orientation_deg=[0.0, 0.0, 180.0])])


def top_edge_paths(p, h=0.3):
    return [i for i in range(p.n_paths) if p.n_interactions[i] == 1
            and p.interaction[i, 0] == 2 and abs(p.points[i, 1, 2] - h) < 1e-9
            and abs(p.points[i, 1, 1]) < 50.0]


def test_edge_seen_end_on_through_the_tracer(runtime):
    """Physics: UTD's D ~ sqrt(L) / sin(beta0) with L ~ sin^2(beta0) stays finite as the
    edge is seen end-on, so the diffracted field tends to a finite limit (the edge
    caustic itself needs more than UTD).  Code: the top edge's diffracted path converges
    as delta goes from 0.1 m to 1e-7 m (successive changes shrink, the gain stays below
    the line of sight's); exactly end-on (and within 1e-9 rad of it) the Keller cone is
    undefined, the edge contributes no path and a CausticWarning says so; every result
    stays finite.  The utd
    module's own limits: tests/test_utd.py::test_edge_seen_end_on."""
    free = LAM / (4 * np.pi * 120.0)
    mags = []
    for delta in (1e-1, 1e-2, 1e-3, 1e-5, 1e-7):
        p = link(end_on_scene(delta), utd_settings(0), runtime=runtime)
        assert_finite(p)
        top = top_edge_paths(p)
        assert len(top) == 1, delta
        mags.append(abs(p.gain[top[0]]) / free)
    steps = np.abs(np.diff(mags))
    assert np.all(steps[1:] < steps[:-1]) and steps[-1] < 1e-3
    assert max(mags) < 1.0
    with pytest.warns(CausticWarning, match="end-on"):
        p = link(end_on_scene(0.0), utd_settings(0), runtime=runtime)
    assert_finite(p)
    assert top_edge_paths(p) == [] and 0 in p.n_interactions.tolist()


@pytest.mark.xfail(strict=True, reason="clradcom/mechanisms/diffraction.py drops a Keller point "
                   "whose ray runs within 1e-9 rad of the edge, so the end-on edge's finite UTD "
                   "limit (0.2 of the line of sight here) jumps to nothing")
def test_edge_seen_end_on_is_continuous(runtime):
    """Physics: the field is continuous as the edge turns end-on.  Code (today): the
    diffracted path vanishes below delta ~ 1e-8 m."""
    got = []
    for delta in (1e-7, 0.0):
        p = link(end_on_scene(delta), utd_settings(0), runtime=runtime)
        got.append(p.gain[top_edge_paths(p)].sum())
    assert abs(got[1] - got[0]) < 1e-3 * abs(got[0])

# ---------------------------------------------------------------------------
# 4. coincident transmitter and receiver


def _plate_and(radars):
    return scene_dict(objects=[plane("plate", "metal", (2.0, 2.0), (6.0, 0.0, 0.0),
                                     (0.0, -90.0, 0.0))], radars=radars)


def test_coincident_tx_and_rx_are_a_monostatic_radar(runtime):
    """Physics: a transmitter and a receiver at one point are a monostatic radar: no direct
    path (zero length, the antenna's own coupling is not a propagation path), the
    plate return sigma = pi R^2.  Code: separate tx and rx radars at the same position
    give exactly the single path of a txrx radar there, with no line of sight and no
    zero-length segment (em would refuse one), all finite; with UTD on, the rims add the
    same monostatic diffraction returns to both; two such radars in empty space have no
    path at all."""
    mono = link(_plate_and([radar("r", (0.0, 0.0, 0.0))]), runtime=runtime)
    bi = link(_plate_and([radar("tx", (0.0, 0.0, 0.0), role="tx"),
                          radar("rx", (0.0, 0.0, 0.0), role="rx")]), runtime=runtime)
    assert bi.n_interactions.tolist() == [1] == mono.n_interactions.tolist()
    assert_finite(bi)
    assert bi.gain[0] == mono.gain[0] and bi.delay_s[0] == mono.delay_s[0]
    assert sigma_eq(bi.gain[0], 6.0) == pytest.approx(np.pi * 36.0, rel=1e-9)
    # with edge diffraction the rims add monostatic returns, the same for both set-ups
    bi_utd = link(_plate_and([radar("tx", (0.0, 0.0, 0.0), role="tx"),
                              radar("rx", (0.0, 0.0, 0.0), role="rx")]), utd_settings(1),
                  runtime=runtime)
    mono_utd = link(_plate_and([radar("r", (0.0, 0.0, 0.0))]), utd_settings(1), runtime=runtime)
    assert_finite(bi_utd)
    assert bi_utd.n_paths == mono_utd.n_paths > 1 and 0 not in bi_utd.n_interactions.tolist()
    np.testing.assert_allclose(np.sort(bi_utd.delay_s), np.sort(mono_utd.delay_s), rtol=1e-15)
    empty = link(scene_dict(radars=[radar("tx", (1.0, 2.0, 3.0), role="tx"),
                                    radar("rx", (1.0, 2.0, 3.0), role="rx")]), runtime=runtime)
    assert empty.n_paths == 0


def test_antennas_closer_than_a_wavelength_warn(runtime):
    """Physics: within a wavelength there is no far field; the Friis amplitude
    lambda/(4 pi L) exceeds 1 below L = lambda/(4 pi) and diverges as L -> 0.  Code:
    the gain is still the finite closed form (so a result stays reproducible) but a
    NearFieldWarning names the shortest path; a wavelength apart nothing is said."""
    def los(sep):
        return link(scene_dict(radars=[radar("tx", (0.0, 0.0, 0.0), role="tx"),
                                       radar("rx", (sep, 0.0, 0.0), role="rx",
                                             orientation_deg=[0.0, 0.0, 180.0])]),
                    runtime=runtime)
    with pytest.warns(NearFieldWarning, match="shorter than a wavelength"):
        p = los(1e-3)
    assert_finite(p)
    assert abs(p.gain[0]) == pytest.approx(LAM / (4 * np.pi * 1e-3), rel=1e-12)
    with no_physics_warnings():
        p = los(LAM)
    assert abs(p.gain[0]) == pytest.approx(1 / (4 * np.pi), rel=1e-12)


def test_em_refuses_zero_length_segments():
    """Code: a path with two coincident consecutive points has no direction; em says which
    path and segment instead of dividing by zero."""
    pts = np.array([[[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]]])
    with pytest.raises(ValueError, match="path 0 has a zero-length segment 1"):
        path_transfer(pts, np.array([[[1.0, 0, 0]]]), 5.0, False, 0.0, 0, 24e9)

# ---------------------------------------------------------------------------
# 5. a source (or receiver) on a surface


def test_source_on_a_surface_warns_and_folds_the_reflection(runtime):
    """Physics: lowering a transmitter onto a road, the reflected ray merges with the direct
    one and the GO field tends to (1 + r(theta)) times the line of sight, theta the angle
    from the normal towards the receiver.  Code: above the surface (down to 10 um) both
    paths are traced and their sum converges to that limit; exactly on the surface the
    image method cannot place the reflection (its point is the transmitter, a zero-length
    segment) and says so with a SurfaceContactWarning naming the antenna and the face;
    the tracer adds the reflection as the limit of the merging rays
    (specular.surface_contact_paths): the line of sight and one reflection at the antenna,
    both finite, the reflection r x the line of sight."""
    d, h_r = 20.0, 0.5
    l0 = math.hypot(d, h_r)
    r_te, r_tm = fresnel(ETA_ROAD, h_r / l0)
    limit = abs(1 + r_tm)  # V polarisation: r_tm
    got = []
    for h in (1e-3, 1e-4, 1e-5):
        with no_physics_warnings():
            p = link(two_ray_dict(d, "V", h_t=h, h_r=h_r), runtime=runtime)
        got.append(abs(p.gain.sum()) / abs(spreading(l0)))
    assert abs(got[-1] - limit) < 1e-3 and abs(got[-1] - limit) < abs(got[0] - limit)
    with pytest.warns(SurfaceContactWarning, match="transmitter at .* lies on the plane"):
        p = link(two_ray_dict(d, "V", h_t=0.0, h_r=h_r), runtime=runtime)
    assert sorted(p.n_interactions.tolist()) == [0, 1]
    assert_finite(p)
    los, refl = p.gain[p.n_interactions == 0][0], p.gain[p.n_interactions == 1][0]
    assert abs(los) == pytest.approx(abs(spreading(l0)), rel=1e-3)
    assert refl / los == pytest.approx(r_tm, rel=1e-9)
    assert p.delay_s[0] == p.delay_s[1]
    with pytest.warns(SurfaceContactWarning, match="receiver at"):
        link(two_ray_dict(d, "V", h_t=h_r, h_r=0.0), runtime=runtime)


def test_source_on_a_surface_is_continuous(runtime):
    """Physics: the GO limit (1 + r) x LOS holds on the surface too.  Code: at h = 0 the
    folded reflection gives it, so the field does not jump (also with the antennas
    swapped: a receiver on the road)."""
    d, h_r = 20.0, 0.5
    l0 = math.hypot(d, h_r)
    _, r_tm = fresnel(ETA_ROAD, h_r / l0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SurfaceContactWarning)
        p = link(two_ray_dict(d, "V", h_t=0.0, h_r=h_r), runtime=runtime)
    assert abs(p.gain.sum()) / abs(spreading(l0)) == pytest.approx(abs(1 + r_tm), abs=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SurfaceContactWarning)
        q = link(two_ray_dict(d, "V", h_t=h_r, h_r=0.0), runtime=runtime)
    assert abs(q.gain.sum()) / abs(spreading(l0)) == pytest.approx(abs(1 + r_tm), abs=1e-3)

# ---------------------------------------------------------------------------
# 5b. an antenna just behind an opaque face


def both_ways(data, settings, runtime=None):
    """(a -> b, b -> a) paths of a scene whose radars are a and b."""
    snap = trace_scene(scene_from_dict(data), settings, runtime=runtime, links=[(0, 1), (1, 0)])
    return snap.links[0].paths, snap.links[1].paths


def assert_reciprocal(ab, ba):
    """Every path of a -> b has its reverse in b -> a: same delay, same gain."""
    assert ab.n_paths == ba.n_paths
    i, j = np.argsort(ab.delay_s, kind="stable"), np.argsort(ba.delay_s, kind="stable")
    np.testing.assert_allclose(ba.delay_s[j], ab.delay_s[i], rtol=0, atol=1e-15)
    np.testing.assert_allclose(ba.gain[j], ab.gain[i], rtol=1e-9, atol=1e-18)


def plate_and_antennas(a, b, offset=(0.0, 0.0, 0.0), pol="V"):
    """A 1 m PEC plate in x = 0 (normal x, centred on the x axis) and radars a, b."""
    o = np.asarray(offset, dtype=float)
    return scene_dict(objects=[plane("plate", "metal", (1.0, 1.0), o, (0.0, -90.0, 0.0))],
                      radars=[radar("a", o + a, role="tx", polarization=pol),
                              radar("b", o + b, role="rx", polarization=pol)])


@pytest.mark.parametrize("offset, deltas", [
    ((0.0, 0.0, 0.0), (0.99e-3, 0.5e-3, 1e-6, 1e-9, 1e-12)),
    ((1000.0, -300.0, 0.0), (0.99e-3, 0.5e-3, 1e-6, 1e-9))], ids=["origin", "1km"])
def test_antenna_just_behind_a_face_is_blocked_both_ways(runtime, offset, deltas):
    """Physics: a metal plate between two antennas blocks every GO path between them, however
    close to its back an antenna sits, and the link is reciprocal.  Code: the blocking test of
    a segment decides the last millimetre before an antenna (and the first after one) in
    float64 (visibility.antenna_blocked), so a receiver 1 mm ... 1e-12 m behind the plate
    (1e-9 m 1 km from the origin, where float64 resolves 1e-10 m) gets no line of sight,
    exactly as when it transmits; with edge diffraction on, the rims' paths are the same
    both ways.  (The last segment used to stop 1 mm short of the receiver: a receiver up to
    1 mm behind the plate got the free-space path, -74.03 dB, and with the antennas swapped
    nothing.)"""
    utd = utd_settings(1)
    for delta in deltas:
        for a, b in (((-5.0, 0.0, 0.0), (delta, 0.0, 0.0)),
                     ((5.0, 0.1, -0.2), (-delta, 0.1, -0.2))):
            ab, ba = both_ways(plate_and_antennas(a, b, offset), GO, runtime)
            assert ab.n_paths == 0 and ba.n_paths == 0, (delta, a)
            ab, ba = both_ways(plate_and_antennas(a, b, offset), utd, runtime)
            assert 0 not in ab.n_interactions.tolist(), (delta, a)
            assert np.all(ab.interaction[:, 0] == 2)  # the rims' diffraction alone
            assert_reciprocal(ab, ba)


def test_antenna_on_a_face_keeps_its_surface_contact_paths(runtime):
    """An antenna exactly on the plate (x = 0) is not behind it: it keeps the line of sight
    and the folded surface-contact reflection (specular.surface_contact_paths), from either
    side and in either direction (transmitting or receiving)."""
    for a in ((-5.0, 0.0, 0.0), (5.0, 0.1, 0.0)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SurfaceContactWarning)
            ab, ba = both_ways(plate_and_antennas(a, (0.0, 0.0, 0.0)), GO, runtime)
        assert sorted(ab.n_interactions.tolist()) == [0, 1], a
        assert_reciprocal(ab, ba)


def test_ground_reflection_does_not_leak_through_a_face_behind_the_receiver(runtime):
    """Physics: a receiver just behind a metal plate standing on a road sees neither the
    transmitter nor its road reflection: both rays cross the plate within a millimetre of
    the receiver.  Code: no path either way (both used to reach the receiver, while the
    swapped link had none)."""
    for delta in (0.99e-3, 0.3e-3, 1e-9):
        data = scene_dict(
            objects=[plane("road", "road", (60.0, 20.0), (5.0, 0.0, 0.0)),
                     plane("plate", "metal", (1.0, 1.0), (10.0, 0.0, 1.0), (0.0, -90.0, 0.0))],
            radars=[radar("a", (0.0, 0.0, 1.0), role="tx"),
                    radar("b", (10.0 + delta, 0.0, 1.0), role="rx")],
            materials=[ROAD])
        ab, ba = both_ways(data, GO, runtime)
        assert ab.n_paths == 0 and ba.n_paths == 0, delta


@pytest.mark.parametrize("pol", ["V", "H"])
def test_receiver_just_behind_a_half_plane_follows_the_diffracted_field(runtime, pol):
    """Physics: behind a PEC half-plane (here the 100 m knife-edge screen, its top edge 0.2 m
    above the receiver) only diffracted fields arrive.  At the screen's back face the top
    edge's field with E along the edge (H, soft) vanishes like the distance d from the face
    (Dirichlet), the one with E across it (V, hard) tends to a finite value (Neumann).  Code:
    for d from 5 mm down to 1e-9 m no line of sight, the top edge's path follows that (soft
    |E|/d and hard |E| within 1% of their values at 5 mm; closer than GRAZING_RAD as seen
    from the edge the receiver is put on the face, where D_s = 0), the total stays within
    1e-3 of the free-space field of its value at 2 mm, and the link is reciprocal.  (A
    receiver less than 1 mm behind the face used to get the line of sight as well: 28 dB
    too much (hard), 85-146 dB (soft); and one within GRAZING_RAD of the back face was put
    on the front face, which flipped the sign of the edges' fields.)"""
    free = abs(spreading(10.0))

    def fields(d):
        data = knife_edge(0.2, pol)
        data["radars"][1]["position"] = [d, 0.0, 0.0]
        ab, ba = both_ways(data, utd_settings(0), runtime)
        assert 0 not in ab.n_interactions.tolist() and 0 not in ba.n_interactions.tolist(), d
        assert_reciprocal(ab, ba)
        top = [i for i in range(ab.n_paths) if abs(ab.points[i, 1, 2] - 0.2) < 1e-9]
        assert len(top) == 1
        return abs(ab.gain[top[0]]) / free, ab.gain.sum() / free

    top_ref, _ = fields(5e-3)
    _, total_ref = fields(2e-3)
    for d in (0.99e-3, 0.5e-3, 1e-6, 1e-7, 1e-9):
        top, total = fields(d)
        if pol == "V":  # hard: finite at the face
            assert top == pytest.approx(top_ref, rel=1e-2), d
        elif d / 0.2 > GRAZING_RAD:  # soft: proportional to the distance from the face
            assert top / d == pytest.approx(top_ref / 5e-3, rel=1e-2), d
        else:  # closer than GRAZING_RAD, seen from the edge: on the face, where D_s = 0
            assert top < 1e-12, d
        assert abs(total - total_ref) < 1e-3, d


# ---------------------------------------------------------------------------
# 6. paths longer than the cyclic prefix; 7. beyond r_max and v_max


def test_paths_beyond_the_cyclic_prefix():
    """Physics: an echo delayed past T_CP leaks the previous symbol into the FFT window
    (ISI): its peak drops to the useful fraction f = 1 - (tau - T_CP)/T of the window.
    Code: the time-domain synthesis models that (the peak is f) and says nothing; the
    frequency-domain model has no ISI, keeps |H| = 1, and raises a CyclicPrefixWarning
    naming the path, its delay and T_CP.  Inside the CP neither warns."""
    wf = small_waveform(n=256, m=16)
    d = random_symbols(wf, 3)
    tau = wf.cp_duration + 0.25 * wf.useful_duration
    with no_physics_warnings():
        synthesize_frequency_domain(d, [1.0], [0.99 * wf.cp_duration], [0.0], wf)
        y = synthesize_time_domain(d, [1.0], [tau], [0.0], wf)
    # the remedy named as a user of the command gives it (the option), and in Python
    with pytest.warns(CyclicPrefixWarning, match=r"delays_s\[1\] = .* > T_CP.*"
                      r"\(--synthesis exact; in Python method=\"exact\""):
        h = channel_transfer_function([1.0, 0.5], [0.0, tau], [0.0, 0.0], wf)
    with pytest.warns(CyclicPrefixWarning):
        h = channel_transfer_function([1.0], [tau], [0.0], wf, method="matmul")
    np.testing.assert_allclose(np.abs(h), 1.0, rtol=1e-12)
    f = spectral_estimate(ofdm_demodulate(y, wf), d)[:, 1:]
    coherent = np.mean(f / h[:, 1:])
    assert abs(coherent) == pytest.approx(0.75, abs=0.04)


def _peak_position(wf, tau, fd, exact=False):
    d = random_symbols(wf, 5)
    if exact:
        dr = ofdm_demodulate(synthesize_time_domain(d, [1.0], [tau], [fd], wf), wf)
    else:
        dr = synthesize_frequency_domain(d, [1.0], [tau], [fd], wf, method="matmul",
                                         time_origin_s=wf.fft_window_centre)
    img = radar_image(spectral_estimate(dr, d), wf, "rect", "rect")
    i, j = np.unravel_index(np.argmax(img.power), img.power.shape)
    return img.range_m[i], img.velocity_mps[j]


@pytest.mark.parametrize("exact", [False, True])
def test_beyond_r_max_and_v_max_alias_with_a_warning(exact):
    """Physics: the range IDFT over subcarriers is periodic in tau with period 1/delta_f and
    the Doppler DFT over symbols in f_D with period 1/T_sym: a target beyond r_max shows
    at r mod r_max, one beyond +-v_max at ((v + v_max) mod 2 v_max) - v_max.  Code: both
    synthesis models put the peak exactly there (tests/test_dsp_processing.py checks more
    wraps) and raise an AliasingWarning for each axis, naming the path and the limit; a
    target inside both limits raises nothing.  (In the exact model an echo from beyond
    r_max is mostly ISI: only delays within T_CP past 1/delta_f keep a peak, at the
    useful fraction of the window.)"""
    wf = small_waveform(n=256, m=16)
    dr, dv = wf.range_resolution, wf.velocity_resolution
    rmax, vmax = wf.max_range, wf.max_velocity
    with no_physics_warnings():
        r, v = _peak_position(wf, wf.range_to_delay(3 * dr), wf.velocity_to_doppler(-2 * dv),
                              exact)
    assert (r, v) == (pytest.approx(3 * dr), pytest.approx(-2 * dv))
    cases = [(rmax + 2 * dr, 3 * dv), (7 * dr, vmax + 2 * dv), (rmax + 3 * dr, -(vmax + 5 * dv))]
    if not exact:
        cases.append((3 * rmax + 40 * dr, 2 * vmax + 3 * dv))
    for r_true, v_true in cases:
        with pytest.warns(AliasingWarning) as rec, warnings.catch_warnings():
            warnings.simplefilter("ignore", CyclicPrefixWarning)
            r, v = _peak_position(wf, wf.range_to_delay(r_true), wf.velocity_to_doppler(v_true),
                                  exact)
        assert r == pytest.approx(np.mod(r_true, rmax), abs=1e-6)
        assert v == pytest.approx(np.mod(v_true + vmax, 2 * vmax) - vmax, abs=1e-6)
        msgs = [str(w.message) for w in rec if issubclass(w.category, AliasingWarning)]
        assert any("unambiguous range" in m for m in msgs) == (r_true > rmax)
        assert any("Doppler" in m for m in msgs) == (abs(v_true) > vmax)


def test_absurd_doppler_spread_is_refused_by_name():
    """Physics: a Doppler spread of many subcarrier spacings (tens of km/s at 24 GHz) is no
    radar scene.  Code: the exact synthesis would need more than 400 interpolation
    nodes; it refuses with a ValueError naming dopplers_hz, their span and delta_f,
    instead of running out of memory; a spread of 10 delta_f is still synthesised finite."""
    wf = small_waveform(n=64, m=16)
    d = random_symbols(wf, 0)
    df = wf.subcarrier_spacing_hz
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AliasingWarning)
        y = synthesize_time_domain(d, [1.0, 1.0], [1e-7, 2e-7], [0.0, 10 * df], wf)
        assert np.all(np.isfinite(y))
        with pytest.raises(ValueError, match=r"dopplers_hz span \[0\.0, .*Δf"):
            synthesize_time_domain(d, [1.0, 1.0], [1e-7, 2e-7], [0.0, 100 * df], wf)

# ---------------------------------------------------------------------------
# 8. nearly degenerate and non-manifold meshes


A, B, C, D = [0.0, -1.0, -1.0], [0.0, 1.0, -1.0], [0.0, 1.0, 1.0], [0.0, -1.0, 1.0]
PLATE = [[A, C, B], [A, D, C]]  # a 2 m square in x = 0, normal -x


def messy_plate(*extra):
    """The plate plus extra triangles, as one object at x = 6 m in front of the radar."""
    tris = [*PLATE, *extra]
    verts = [v for t in tris for v in t]
    faces = [[3 * i, 3 * i + 1, 3 * i + 2] for i in range(len(tris))]
    return scene_dict(objects=[{"name": "plate", "material": "metal", "shape": "triangles",
                                "vertices": verts, "faces": faces,
                                "position": [6.0, 0.0, 0.0]}],
                      radars=[radar("r", (0.0, 0.3, 0.2))])


SLIVER = [A, B, [0.0, 0.0, -1.0 - 1e-8]]  # 2 area / longest^2 = 5e-9, above the 1e-10 cut
DUPLICATE = PLATE[0]
FIN = [A, C, [-1.0, 0.0, 0.0]]  # a third face on the plate's diagonal, towards the radar


@pytest.mark.parametrize("extra", [(), (SLIVER,), (DUPLICATE,), (FIN,), (SLIVER, DUPLICATE)],
                         ids=["clean", "sliver", "duplicate", "fin", "sliver+duplicate"])
def test_messy_meshes_give_the_clean_plate_return(runtime, extra):
    """Physics: a sliver 1e-8 m wide, a duplicated triangle or a fin standing on the plate
    do not change the plate's mirror return (sigma = pi R^2 monostatic at its normal).
    Code: scene_from_dict accepts them (none is degenerate by its 1e-10 area test);
    merge_coplanar puts the sliver and the duplicate in the plate's face (one reflector,
    so no second path); the BVH and the float64 face test find the same single plate
    path with the clean plate's exact gain; the fin is a second face, and an edge shared
    by three triangles (the diagonal with the fin, or with the duplicate) is skipped by
    extract_wedges as non-manifold (counted in its stats), never a wedge of nonsense
    angle; with diffraction on every result stays finite."""
    data = messy_plate(*extra)
    scene = scene_from_dict(data)
    faces = build_geometry(scene, runtime).faces
    assert faces.n_faces == (2 if FIN in extra else 1)
    p = link(data, GO.replace(specular__max_reflections=2, specular__rays=20_000),
             runtime=runtime)
    plate_paths = [i for i in range(p.n_paths) if p.n_interactions[i] == 1
                   and abs(p.points[i, 1, 0] - 6.0) < 1e-9]
    assert len(plate_paths) == 1
    i = plate_paths[0]
    np.testing.assert_allclose(p.points[i, 1], [6.0, 0.3, 0.2], atol=1e-12)
    assert sigma_eq(p.gain[i], 6.0) == pytest.approx(np.pi * 36.0, rel=1e-9)
    w = extract_wedges(scene.triangles, scene.tri_object, scene.tri_material)
    uses = {}  # brute force: triangles per (unordered) edge of the messy plate
    for t in [*PLATE, *extra]:
        for a, b in ((0, 1), (1, 2), (2, 0)):
            key = frozenset((tuple(t[a]), tuple(t[b])))
            uses[key] = uses.get(key, 0) + 1
    assert w.stats["nonmanifold"] == sum(n >= 3 for n in uses.values())
    assert w.stats["nonmanifold"] >= (FIN in extra or DUPLICATE in extra)
    assert np.all((w.n > 0) & (w.n <= 2)) and np.all(np.isfinite(w.direction))
    if extra == (DUPLICATE,):  # its rim edges pair the two copies: half-planes again
        assert len(w) == 4 and np.all(w.n == 2)
    assert_finite(link(data, utd_settings(1), runtime=runtime))


def test_zero_area_triangles_are_refused_or_dropped():
    """Physics: a zero-area triangle has no plane, so it cannot reflect.  Code: the scene
    refuses it naming the key, triangle and fix (or drops it with a SceneWarning when
    drop_degenerate = true, tests/test_scene.py); merge_coplanar, fed one directly, names
    the triangle instead of producing a NaN normal; extract_wedges ignores and counts it."""
    tris = np.array([*PLATE, [A, B, [0.0, 0.0, -1.0]]])  # collinear
    with pytest.raises(Exception, match=r"objects\[0\]\.faces.*degenerate"):
        scene_from_dict(messy_plate([A, B, [0.0, 0.0, -1.0]]))
    with pytest.raises(ValueError, match="triangle 2 is degenerate"):
        merge_coplanar(tris, np.zeros(3, int), np.zeros(3, int))
    w = extract_wedges(tris, np.zeros(3, int), np.zeros(3, int))
    assert w.stats["degenerate"] == 1 and len(w) == 4 and np.all(w.half_plane)

# ---------------------------------------------------------------------------
# 9. float32 geometry 1 km from the origin (specular: tests/test_paths.py)


@pytest.mark.parametrize("offset", [(1000.0, 0.0, 0.0), (0.0, 0.0, 1000.0),
                                    (-731.3, 689.7, 12.1)], ids=["x1km", "z1km", "xyz1km"])
def test_diffraction_far_from_the_origin(runtime, offset):
    """Physics: translating a scene changes nothing.  Code: wedges, Keller points, delays
    and UTD fields are float64; only the visibility casts are float32 (with 1 mm
    clearance at the edge).  The knife edge 1 km away gives the same diffracted delays to
    1 fs and the same complex gains to 1e-6 rad of phase as at the origin."""
    def top(o):
        p = link(knife_edge(0.2, "V", o), utd_settings(0), runtime=runtime)
        i = top_edge_index(p, o)
        return p.delay_s[i], p.gain[i], p.points[i, 1] - np.asarray(o)
    d0, g0, q0 = top((0.0, 0.0, 0.0))
    d1, g1, q1 = top(offset)
    assert abs(d1 - d0) < 1e-15
    np.testing.assert_allclose(q1, q0, atol=1e-9)
    assert abs(np.angle(g1 / g0)) < 1e-6 and abs(abs(g1) / abs(g0) - 1) < 1e-9


def top_edge_index(p, o):
    diffracted = [i for i in range(p.n_paths) if p.n_interactions[i] == 1
                  and p.interaction[i, 0] == 2]
    return min(diffracted, key=lambda i: p.delay_s[i])


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (-731.3, 689.7, 12.1)], ids=["origin", "1km"])
def test_seams_of_a_tessellated_wall_stay_closed(runtime, offset):
    """Physics: a wall tessellated into 32 triangles blocks every ray through it, seams and
    vertices included.  Code: the float64 re-check of a blocked line of sight
    (visibility.blocked_in_float64) tests the crossing point against every triangle of the
    hit face with a 1e-9 relative tolerance, so oblique lines of sight through shared
    vertices, along-grid seams and diagonal seams of a tilted wall (where rounding puts
    the crossing a hair outside the triangle the float32 cast hit) stay blocked, 1 km
    from the origin too; lines 1 mm past the rim are clear."""
    from geometry_helpers import plate_tris

    o = np.asarray(offset)
    tilt = 23.0
    verts, faces = plate_tris(4, 2.0, 5.0, centre=(0.3, -0.2), tilt_deg=tilt)
    wall = {"name": "wall", "material": "metal", "shape": "triangles",
            "vertices": (np.asarray(verts) + o).tolist(), "faces": faces}
    th = np.radians(tilt)
    rot = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])

    def on_wall(y, z):
        return o + rot @ [0.0, y, z] + [5.0, 0.3, -0.2]

    rng = np.random.default_rng(4)
    grid = np.linspace(-1, 1, 5)
    seams = [(y, z) for y in grid[1:-1] for z in grid[1:-1]]  # vertices
    seams += [(rng.uniform(-1, 1), float(z)) for z in grid[1:-1] for _ in range(2)]
    cell = rng.integers(0, 4, (6, 2))
    f = rng.uniform(0.1, 0.9, 6)
    seams += [(grid[i] + 0.5 * fi, grid[j] + 0.5 * fi) for (i, j), fi in zip(cell, f, strict=True)]
    u = np.array([1.0, 0.37, -0.21]) / np.linalg.norm([1.0, 0.37, -0.21])
    cases = [(on_wall(y, z), True) for y, z in seams]
    cases += [(on_wall(1.001, 0.3), False), (on_wall(-0.4, -1.001), False)]
    for point, blocked in cases:
        data = scene_dict(objects=[wall], radars=[radar("tx", point - 5 * u, role="tx"),
                                                  radar("rx", point + 5 * u, role="rx")])
        p = link(data, runtime=runtime)  # tx and rx on opposite sides: the LOS alone
        assert (p.n_paths == 0) == blocked, point - o
