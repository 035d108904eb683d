"""The radio map's launch lattice (clradcom.maps._launch_of, launch_lattice) against the
plain construction it replaced, kept here as the reference: the pattern's field over the
whole cap lattice (fibonacci_cap), its zero-gain directions dropped, then put in
coherent order. The fast one tests the support first and works a piece at a time; it
must give the same directions in the same order and the same field, bit for bit."""

import numpy as np
import pytest

from clradcom import maps
from clradcom.geometry.ray_order import coherent_order
from clradcom.mechanisms.specular import fibonacci_cap, fibonacci_cap_polar, fibonacci_sphere
from clradcom.scene.antenna import (
    CosinePowerPattern,
    IsotropicPattern,
    SectorPattern,
    TabulatedPattern,
)


def _reference_launch(n_rays, pattern):
    probe = fibonacci_sphere(1 << 16)
    inside = np.asarray(pattern.gain(probe)) > 0
    spacing = np.sqrt(4.0 * np.pi / len(probe))
    half_angle = min(np.pi, float(np.arccos(probe[inside, 0].min())) + 2.0 * spacing)
    share = float(inside[probe[:, 0] >= np.cos(half_angle)].mean())
    n_cap = int(np.ceil(n_rays / share))
    local = fibonacci_cap(n_cap, half_angle)
    field = np.asarray(pattern.field(local), dtype=np.complex128)
    keep = (np.abs(field[:, 0]) ** 2 + np.abs(field[:, 1]) ** 2) > 0
    local, field = local[keep], field[keep]
    order = coherent_order(local)
    return local[order], 2.0 * np.pi * (1.0 - np.cos(half_angle)) / n_cap, field[order]


def _front_table():
    """A complex table pattern that is zero behind (x < 0) and over part of the front."""
    th, ph = np.arange(0.0, 181.0, 5.0), np.arange(-180.0, 180.0, 5.0)
    t, p = np.meshgrid(np.radians(th), np.radians(ph), indexing="ij")
    front = np.clip(np.sin(t) * np.cos(p), 0.0, None) * (np.abs(ph) < 70.0)[None, :]
    return TabulatedPattern(theta_deg=th, phi_deg=ph, c_theta=front * np.exp(1j * p),
                            c_phi=0.3j * front * np.cos(t), normalize=False)


PATTERNS = {
    "street sector": SectorPattern(azimuth_width_deg=90.0, elevation_width_deg=180.0),
    "narrow sector": SectorPattern(azimuth_width_deg=30.0, elevation_width_deg=20.0,
                                   polarization=np.array([1.0, 1.0j]) / np.sqrt(2.0)),
    "wide sector": SectorPattern(azimuth_width_deg=250.0, elevation_width_deg=60.0),
    "omni sector": SectorPattern(azimuth_width_deg=360.0, elevation_width_deg=180.0),
    "cosine": CosinePowerPattern(q=3.0),
    "isotropic": IsotropicPattern(),
    "complex table": _front_table(),
}


@pytest.mark.parametrize("name", list(PATTERNS))
def test_launch_lattice_equals_the_plain_construction_bit_for_bit(name):
    pattern = PATTERNS[name]
    local, solid_angle, field = _reference_launch(150_000, pattern)
    maps._LAUNCHES.clear()
    launch = maps._launch_of(150_000, pattern)
    maps._LAUNCHES.clear()
    assert launch.solid_angle == solid_angle
    np.testing.assert_array_equal(launch.local, local)
    np.testing.assert_array_equal(launch.field, field)
    # the public lattice is the same rows in lattice (Fibonacci) order
    plain, plain_solid_angle = maps.launch_lattice(150_000, pattern)
    assert plain_solid_angle == solid_angle
    np.testing.assert_array_equal(plain[coherent_order(plain)], local)


@pytest.mark.parametrize("n, half_angle", [(1, np.pi), (70_001, 1.6), (5, 0.2)])
def test_cap_in_pieces_is_the_whole_cap(n, half_angle):
    whole = fibonacci_cap(n, half_angle)
    pieces = [np.stack([x, r * np.cos(phi), r * np.sin(phi)], axis=1)
              for x, r, phi in (fibonacci_cap_polar(n, half_angle, s, s + 4096)
                                for s in range(0, n, 4096))]
    np.testing.assert_array_equal(np.concatenate(pieces), whole)



class _NeverEmpty(CosinePowerPattern):
    """A cosine pattern that refuses to be evaluated at no direction (as a table's
    interpolator might)."""

    def field(self, directions_local):
        assert len(directions_local), "evaluated at no direction"
        return super().field(directions_local)


def test_pieces_outside_the_support_are_skipped(monkeypatch):
    # pieces of 64 directions: the cap's rim behind a cosine pattern (x < 0, kept by the
    # cap's two-spacing margin) fills whole pieces that the support test empties
    pattern = _NeverEmpty(q=1.0)
    local, solid_angle, field = _reference_launch(20_000, pattern)
    monkeypatch.setattr(maps, "_LATTICE_PIECE", 64)
    maps._LAUNCHES.clear()
    launch = maps._launch_of(20_000, pattern)
    maps._LAUNCHES.clear()
    np.testing.assert_array_equal(launch.local, local)
    np.testing.assert_array_equal(launch.field, field)
