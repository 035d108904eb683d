"""Refactoring changes no number: a small scene with every mechanism on traces to exactly
the snapshot the tracer wrote before the package was reorganised.

``tests/data/all_mechanisms_v1.npz`` was traced by commit 2a77dfd (the flat 27-module
layout, snapshot format 1) from ``tests/data/all_mechanisms.toml`` with the settings
below, on PoCL's CPU device (1 m scattering tiles keep the file small: 814 paths,
208 KiB). Gains, matrices, delays, Doppler shifts, points, object and face ids of every
path but the SBR-PO ones (whose launch changed on purpose since) must match bit for bit;
interaction codes too, once the physical-optics and SBR codes that format 2 added are
read as the REFLECTION that format 1 wrote for them. Kernels on
another OpenCL device may propose other candidates in float32; this reference holds for
the PoCL CPU device the suite runs on.
"""

from pathlib import Path

import numpy as np
import pytest

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
    optics=OpticsSettings(mode="sbr"),
    scattering=ScatteringSettings(enabled=True, max_reflections=1, tile_size_m=1.0,
                                  floor=1e-11),
)
EXACT_FIELDS = ("gain", "matrix", "delay_s", "doppler_hz", "n_interactions", "points",
                "object_id", "face_id")


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


def test_same_paths_bit_for_bit(traced):
    """Every path but SBR-PO's: those changed on purpose (tubes launched over silhouettes
    and mirror images, the chain's sqrt(1 - S^2)); tests/test_sbr_engines.py holds them."""
    reference, snap = traced
    assert [lk.label for lk in snap] == [lk.label for lk in reference]
    for old, new in zip(reference.links, snap.links, strict=True):
        old_sbr = sbr_rows(old.paths, format_1=True)
        new_sbr = sbr_rows(new.paths, format_1=False)
        assert old_sbr.any() and new_sbr.any(), old.label
        old_paths = select_paths(old.paths, ~old_sbr)
        new_paths = select_paths(new.paths, ~new_sbr)
        assert new_paths.n_paths == old_paths.n_paths, old.label
        for name in EXACT_FIELDS:
            a, b = getattr(old_paths, name), getattr(new_paths, name)
            same = (a == b) | (np.isnan(a) & np.isnan(b)) if a.dtype.kind in "fc" else a == b
            if not np.all(same):
                worst = np.nanmax(np.abs(a - b)) if a.dtype.kind in "fc" else "-"
                raise AssertionError(f"{old.label}: {name} differs in "
                                     f"{np.count_nonzero(~same)} entries (largest {worst})")
        np.testing.assert_array_equal(as_format_1(new_paths.interaction),
                                      old_paths.interaction, err_msg=old.label)


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
