"""Refactoring changes no number: a small scene with every mechanism on traces to exactly
the snapshot the tracer wrote before the package was reorganised.

``tests/data/all_mechanisms_v1.npz`` was traced by commit 2a77dfd (the flat 27-module
layout, snapshot format 1) from ``tests/data/all_mechanisms.toml`` with the settings
below, on PoCL's CPU device (1 m scattering tiles keep the file small: 814 paths,
208 KiB). Gains, matrices, delays, Doppler shifts, points, object and face ids of every
path but the SBR-PO ones (whose launch changed on purpose since) and the diffractions at
the floor edges of the wall, the car and the hedge (which stand on the road: no wedges
since issue 27, docs/wedges.md "Edges flush on another surface") must match bit for bit;
interaction codes too, once the physical-optics and SBR codes that format 2 added are
read as the REFLECTION that format 1 wrote for them. That holds on PoCL's CPU device with
fp64, where the reference was traced; without fp64 (--fp64=off) PoCL still finds the same
paths in the same order, bit for bit in their interactions, objects and faces. Any other
device (or PoCL without fp64) computes in other roundings (its own libm, fused
multiply-adds, float32 candidates), so there the snapshot is held to what a path's
physics can tell apart instead: the same paths (by their interactions, objects and
faces), delays within 1 ps (0.3 mm of path, 1/40 of a wavelength at 24 GHz), gains
within -60 dB of each path's and Doppler shifts within 1 mHz, and every link's channel
at the radar's 1024 subcarriers within -60 dB NMSE; a path that only one device finds
may be missing only if it carries under -60 dB of the link's power. Without fp64 a path
that cancels to nothing (the bistatic road bounce, -300 dB of the link) is held to -120
dB of the link's strongest instead of -60 dB of its own zero (tests/mode_helpers.py).
"""

from pathlib import Path

import numpy as np
import pytest
from mode_helpers import gain_tolerance

from clradcom.paths import InteractionType, select_paths
from clradcom.scene import load_scene
from clradcom.snapshot import load_snapshot
from clradcom.trace import (
    DiffractionSettings,
    OpticsSettings,
    ScatteringSettings,
    SpecularSettings,
    TraceSettings,
    trace_scene,
)

DATA = Path(__file__).parent / "data"
SETTINGS = TraceSettings(
    specular=SpecularSettings(max_reflections=3, rays=20_000),
    # the reference was traced when UTD still ran at the PO car's edges
    diffraction=DiffractionSettings(max_diffractions=2, max_reflections=1,
                                    po_object_edges=True),
    # and before PO facets in an antenna's near field were split (the box car's 4 m
    # faces are, 10 m from the radars); tests/test_po_near_field.py holds the split
    optics=OpticsSettings(mode="sbr", po_split="none"),
    scattering=ScatteringSettings(enabled=True, max_reflections=1, tile_size_m=1.0,
                                  floor=1e-11),
)
EXACT_FIELDS = ("gain", "matrix", "delay_s", "doppler_hz", "n_interactions", "points",
                "object_id", "face_id")
#: what stays bit for bit on the reference's implementation without fp64: which paths
DISCRETE_FIELDS = ("n_interactions", "object_id", "face_id")


def as_format_1(codes: np.ndarray) -> np.ndarray:
    old = np.array(codes, dtype=np.int8)
    old[np.isin(old, [InteractionType.PHYSICAL_OPTICS, InteractionType.SBR])] = (
        InteractionType.REFLECTION)
    return old


@pytest.fixture(scope="module")
def traced(runtime):
    reference = load_snapshot(DATA / "all_mechanisms_v1.npz")
    snap = trace_scene(load_scene(DATA / "all_mechanisms.toml"), SETTINGS, runtime=runtime)
    return reference, snap


def test_reference_is_the_old_format_read_by_conversion(traced):
    reference, _ = traced
    assert reference.metadata["snapshot.converted_from_version"] == 1
    assert reference.metadata["settings.physical_optics"] == "sbr"


def test_every_mechanism_is_exercised(traced):
    _, snap = traced
    codes = set(np.unique(np.concatenate([lk.paths.interaction.ravel() for lk in snap])))
    assert {int(t) for t in InteractionType} <= codes
    assert snap.metadata["scattering.triangles_below_floor"] > 0  # the floor prunes too
    assert snap.metadata["diffraction.paths"] > 0


def sbr_rows(paths, *, format_1: bool) -> np.ndarray:
    """The SBR-PO paths: by their code in format 2; in format 1, which wrote REFLECTION
    for them, as the all-reflection paths of two or more bounces ending on the car (the
    GO ones that SBR replaces are never kept beside it)."""
    if not format_1:
        return np.any(paths.interaction == InteractionType.SBR, axis=1)
    nk = paths.n_interactions.astype(np.int64)
    last = paths.object_id[np.arange(paths.n_paths), np.maximum(nk - 1, 0)]
    used = np.arange(paths.k_max)[None, :] < nk[:, None]
    all_refl = np.all((paths.interaction == InteractionType.REFLECTION) | ~used, axis=1)
    return (nk >= 2) & (last == 2) & all_refl


def flush_edge_rows(paths) -> np.ndarray:
    """The paths that diffract at an edge lying flush on the road: a diffraction point at
    z = 0 on an object other than the road is on a floor edge of the wall, the car or
    the hedge (their vertical edges end there, but no Keller point lies within 1 mm of an
    edge's end)."""
    used = np.arange(paths.k_max)[None, :] < paths.n_interactions[:, None]
    at = (paths.interaction == InteractionType.DIFFRACTION) & used
    floor = np.abs(paths.points[:, 1:-1, 2]) < 1e-9
    return np.any(at & floor & (paths.object_id != ROAD), axis=1)


#: the road's object id in all_mechanisms.toml
ROAD = 0


def compared(old_paths, new_paths, label):
    """The reference's and the new trace's paths that must agree: all but SBR-PO's and
    the reference's diffractions at edges flush on the road, of which the new trace must
    have none."""
    assert not flush_edge_rows(new_paths).any(), label
    keep_old = ~sbr_rows(old_paths, format_1=True) & ~flush_edge_rows(old_paths)
    return (select_paths(old_paths, keep_old),
            select_paths(new_paths, ~sbr_rows(new_paths, format_1=False)))


def test_reference_has_floor_edge_diffractions_and_the_trace_none(traced):
    reference, snap = traced
    assert sum(int(flush_edge_rows(lk.paths).sum()) for lk in reference) > 0
    assert not any(flush_edge_rows(lk.paths).any() for lk in snap)


def test_same_paths_bit_for_bit(traced, runtime):
    """Every path but SBR-PO's: those changed on purpose (tubes launched over silhouettes
    and mirror images, the chain's sqrt(1 - S^2)); tests/test_sbr_engines.py holds them.
    On the reference's implementation with fp64, where the reference was traced, every
    field; anywhere else (another implementation, or --fp64=off) the same paths in the
    same order, their interactions, objects and faces, while the test below holds their
    numbers to physical tolerances.  Paths are paired by their identity and points
    (:func:`match_paths`): those of chains of two or more edges may come in another
    order since issue 27 cut the wedges flush on the road."""
    exact = runtime.info.vendor == REFERENCE_VENDOR and runtime.has_double
    fields = EXACT_FIELDS if exact else DISCRETE_FIELDS
    reference, snap = traced
    assert [lk.label for lk in snap] == [lk.label for lk in reference]
    for old, new in zip(reference.links, snap.links, strict=True):
        old_sbr = sbr_rows(old.paths, format_1=True)
        new_sbr = sbr_rows(new.paths, format_1=False)
        assert old_sbr.any() and new_sbr.any(), old.label
        old_paths, new_paths = compared(old.paths, new.paths, old.label)
        assert new_paths.n_paths == old_paths.n_paths, old.label
        # the same paths; in the same order but for chains of two or more edges, whose
        # pair search (k-d trees over the wedges' midpoints) the cut wedges reorder
        i, j = match_paths(old_paths, path_keys(old_paths, format_1=True), new_paths,
                           path_keys(new_paths, format_1=False))
        assert len(i) == old_paths.n_paths and np.array_equal(i, np.arange(len(i))), old.label
        chain = np.sum(old_paths.interaction == InteractionType.DIFFRACTION, axis=1) >= 2
        assert np.all(np.diff(j[~chain]) > 0), old.label
        old_paths, new_paths = select_paths(old_paths, i), select_paths(new_paths, j)
        for name in fields:
            a, b = getattr(old_paths, name), getattr(new_paths, name)
            same = (a == b) | (np.isnan(a) & np.isnan(b)) if a.dtype.kind in "fc" else a == b
            if not np.all(same):
                worst = np.nanmax(np.abs(a - b)) if a.dtype.kind in "fc" else "-"
                raise AssertionError(f"{old.label}: {name} differs in "
                                     f"{np.count_nonzero(~same)} entries (largest {worst})")
        np.testing.assert_array_equal(as_format_1(new_paths.interaction),
                                      old_paths.interaction, err_msg=old.label)


#: the implementation the reference was traced on (PoCL's CPU device, with fp64)
REFERENCE_VENDOR = "pocl"


#: a path's tolerances off the reference's device (module docstring)
DELAY_TOL_S = 1e-12
POINT_TOL_M = 3e-4
DOPPLER_TOL_HZ = 1e-3
GAIN_TOL_DB = -60.0
CHANNEL_NMSE_DB = -60.0


def path_keys(paths, *, format_1: bool) -> list[tuple]:
    """Each path's identity: its interactions (in format 1's codes), objects and faces."""
    codes = paths.interaction if format_1 else as_format_1(paths.interaction)
    out = []
    for i, k in enumerate(paths.n_interactions.astype(int)):
        out.append((tuple(codes[i, :k].tolist()), tuple(paths.object_id[i, :k].tolist()),
                    tuple(paths.face_id[i, :k].tolist())))
    return out


def match_paths(old, old_keys, new, new_keys) -> tuple[np.ndarray, np.ndarray]:
    """(a, b): old path a[i] is new path b[i]. Paths of one key (PO facets and scattering
    tiles of one face share theirs) are told apart by their interaction points: each old
    path takes the nearest unclaimed new one of its key within POINT_TOL_M."""
    groups: dict[tuple, list[int]] = {}
    for j, key in enumerate(new_keys):
        groups.setdefault(key, []).append(j)
    a, b = [], []
    for i, key in enumerate(old_keys):
        free = groups.get(key, [])
        if not free:
            continue
        k = int(old.n_interactions[i])
        off = [np.max(np.abs(np.nan_to_num(new.points[j, :k] - old.points[i, :k])),
                      initial=0.0) for j in free]
        best = int(np.argmin(off))
        if off[best] <= POINT_TOL_M:
            a.append(i)
            b.append(free.pop(best))
    return np.array(a, dtype=int), np.array(b, dtype=int)


def channel(paths, n=1024, df=90.909e3):
    """The link's channel at the paper's 1024 subcarriers (baseband)."""
    k = np.arange(n)[:, None]
    return np.exp(-2j * np.pi * k * df * paths.delay_s[None, :]) @ paths.gain


def test_same_paths_within_physical_tolerances(traced, runtime):
    """On every device: the non-SBR paths of every link are the reference's within what
    their physics can tell apart (module docstring). On the reference's device this holds
    trivially (the bits are the same); on another it is the test that counts."""
    reference, snap = traced
    assert [lk.label for lk in snap] == [lk.label for lk in reference]
    for old, new in zip(reference.links, snap.links, strict=True):
        old_paths, new_paths = compared(old.paths, new.paths, old.label)
        a, b = match_paths(old_paths, path_keys(old_paths, format_1=True), new_paths,
                           path_keys(new_paths, format_1=False))
        total = float(np.sum(np.abs(old_paths.gain) ** 2))
        only_old = np.setdiff1d(np.arange(old_paths.n_paths), a)
        only_new = np.setdiff1d(np.arange(new_paths.n_paths), b)
        unmatched = (np.sum(np.abs(old_paths.gain[only_old]) ** 2)
                     + np.sum(np.abs(new_paths.gain[only_new]) ** 2))
        assert unmatched <= total * 10 ** (CHANNEL_NMSE_DB / 10), (
            old.label, len(only_old), len(only_new))
        ga, gb = old_paths.gain[a], new_paths.gain[b]
        if runtime.has_double:
            worst = np.max(np.abs(gb - ga) / np.abs(ga), initial=0.0)
            assert worst <= 10 ** (GAIN_TOL_DB / 20), (old.label, "gain", worst)
        else:
            # a path cancelled to nothing (A->B's road bounce, -300 dB: a cross-polar
            # projection) moves by the link's float64 rounding when its image point moves
            # by double-float's (tests/mode_helpers.py: gain_tolerance)
            tol = gain_tolerance(ga, strongest=np.abs(old_paths.gain).max())
            assert (np.abs(gb - ga) <= tol).all(), (old.label, "gain",
                                                    np.max(np.abs(gb - ga) / tol))
        np.testing.assert_allclose(new_paths.matrix[b], old_paths.matrix[a], rtol=0,
                                   atol=10 ** (GAIN_TOL_DB / 20)
                                   * np.max(np.abs(old_paths.matrix), initial=0.0),
                                   err_msg=old.label)
        np.testing.assert_allclose(new_paths.delay_s[b], old_paths.delay_s[a], rtol=0,
                                   atol=DELAY_TOL_S, err_msg=old.label)
        np.testing.assert_allclose(new_paths.doppler_hz[b], old_paths.doppler_hz[a], rtol=0,
                                   atol=DOPPLER_TOL_HZ, err_msg=old.label)
        np.testing.assert_allclose(np.nan_to_num(new_paths.points[b]),
                                   np.nan_to_num(old_paths.points[a]), rtol=0,
                                   atol=POINT_TOL_M, err_msg=old.label)
        h, ref = channel(new_paths), channel(old_paths)
        nmse = np.sum(np.abs(h - ref) ** 2) / np.sum(np.abs(ref) ** 2)
        assert nmse <= 10 ** (CHANNEL_NMSE_DB / 10), (old.label, 10 * np.log10(nmse))


def test_po_and_sbr_returns_carry_their_own_codes(traced):
    """Where format 1 wrote REFLECTION for a physical-optics facet, format 2 says so: PO
    returns are single-interaction paths on the PEC car, SBR ones bounce two or more
    times and end on it."""
    _, snap = traced
    car = 2  # objects: road, wall, car, hedge
    for lk in snap:
        p = lk.paths
        po = np.any(p.interaction == InteractionType.PHYSICAL_OPTICS, axis=1)
        sbr = np.any(p.interaction == InteractionType.SBR, axis=1)
        assert po.any() and sbr.any(), lk.label
        assert np.all(p.n_interactions[po] == 1) and np.all(p.object_id[po, 0] == car)
        assert np.all(p.n_interactions[sbr] >= 2)
        last = p.object_id[np.flatnonzero(sbr), p.n_interactions[sbr] - 1]
        assert np.all(last == car)
        # a path is one kind: no PO or SBR slot beside a GO reflection in the same path
        k = np.arange(p.k_max)[None, :] < p.n_interactions[:, None]
        assert np.all(p.interaction[po | sbr][k[po | sbr]] >= InteractionType.PHYSICAL_OPTICS)
