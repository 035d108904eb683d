"""Directions in coherent order (clradcom.geometry.ray_order): the octahedral map against
its closed-form inverse, Morton codes against bit-by-bit interleaving, and the launch
lattice's order (neighbours on the sphere next to each other, every ray kept)."""

import numpy as np
import pytest

from clradcom.errors import ArgumentError
from clradcom.geometry.ray_order import coherent_order, morton_codes, octahedral_coordinates
from clradcom.mechanisms import specular as sp
from clradcom.mechanisms.specular import fibonacci_sphere
from clradcom.scene.antenna import SectorPattern


def _unmap(u, v):
    """The octahedral map's inverse (Cigolle et al. 2014, listing 2), unit vectors."""
    z = 1.0 - np.abs(u) - np.abs(v)
    x = np.where(z < 0, (1.0 - np.abs(v)) * np.where(u < 0, -1.0, 1.0), u)
    y = np.where(z < 0, (1.0 - np.abs(u)) * np.where(v < 0, -1.0, 1.0), v)
    d = np.stack([x, y, z], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _angles_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


def test_octahedral_map_inverts_and_fills_the_square():
    d = fibonacci_sphere(20000)
    u, v = octahedral_coordinates(3.7 * d)   # any length
    assert np.all(np.abs(u) <= 1.0) and np.all(np.abs(v) <= 1.0)
    np.testing.assert_allclose(_unmap(u, v), d, atol=1e-12)
    # the axes land on the square's centre, edge midpoints and (for -z) its corner
    axes = np.array([[0, 0, 1], [1, 0, 0], [0, -1, 0], [0, 0, -1]], float)
    u, v = octahedral_coordinates(axes)
    np.testing.assert_array_equal(np.stack([u, v], axis=1),
                                  [[0, 0], [1, 0], [0, -1], [1, 1]])
    # equal areas of the sphere cover the square evenly: every one of 16 x 16 cells holds
    # between a quarter and four times its share of a uniform lattice
    counts = np.bincount(morton_codes(*octahedral_coordinates(d), bits=4), minlength=256)
    assert counts.min() > 0.25 * len(d) / 256 and counts.max() < 4 * len(d) / 256


def test_morton_codes_interleave_the_cell_indices_bit_by_bit():
    rng = np.random.default_rng(3)
    u, v = rng.uniform(-1, 1, 500), rng.uniform(-1, 1, 500)
    for bits in (3, 8, 11):
        got = morton_codes(u, v, bits)
        assert got.dtype == (np.uint16 if bits <= 8 else np.uint32)
        cells = 1 << bits
        for k in range(len(u)):
            iu = min(int((u[k] + 1) / 2 * cells), cells - 1)
            iv = min(int((v[k] + 1) / 2 * cells), cells - 1)
            want = sum((((iu >> b) & 1) << (2 * b)) | (((iv >> b) & 1) << (2 * b + 1))
                       for b in range(bits))
            assert int(got[k]) == want
    # the square's edges fall into its first and last cells
    np.testing.assert_array_equal(morton_codes([-1.0, 1.0], [-1.0, 1.0], 8), [0, 65535])


def test_coherent_order_keeps_every_direction_and_puts_neighbours_together():
    d = fibonacci_sphere(100_000)
    order = coherent_order(d)
    np.testing.assert_array_equal(np.sort(order), np.arange(len(d)))
    ordered = d[order]
    # the Fibonacci lattice turns by the golden angle from ray to ray; in coherent order
    # the next ray is a lattice neighbour or two away (spacing ~0.64 deg here)
    assert np.mean(_angles_deg(d[1:], d[:-1])) > 60.0
    assert np.mean(_angles_deg(ordered[1:], ordered[:-1])) < 2.0
    # 64 consecutive rays (one work-group) stay within a narrow cone, as a rule
    groups = ordered[: len(d) // 64 * 64].reshape(-1, 64, 3)
    mean = groups.mean(axis=1)
    mean /= np.linalg.norm(mean, axis=1, keepdims=True)
    spread = _angles_deg(groups.reshape(-1, 3), np.repeat(mean, 64, axis=0)).reshape(-1, 64)
    assert np.median(spread.max(axis=1)) < 10.0


def test_launch_lattice_is_the_pattern_lattice_in_coherent_order():
    pattern = SectorPattern(azimuth_width_deg=90.0, elevation_width_deg=60.0)
    local = sp._lattice_of(30_000, pattern)
    plain = sp._pattern_lattice(30_000, pattern.gain)
    np.testing.assert_array_equal(local, plain[coherent_order(plain)])
    assert not local.flags.writeable and sp._lattice_of(30_000, pattern) is local


@pytest.mark.parametrize("bad", [np.zeros((2, 3)), np.array([[1.0, np.nan, 0.0]]),
                                 np.ones((3, 2))])
def test_bad_directions_are_refused_by_name(bad):
    with pytest.raises(ArgumentError, match="directions"):
        coherent_order(bad)


@pytest.mark.parametrize("bits", [0, 17, 2.5, True])
def test_bad_bits_are_refused(bits):
    with pytest.raises(ArgumentError, match="bits"):
        morton_codes([0.0], [0.0], bits)


def test_octahedral_coordinates_equal_the_plain_expressions_bit_for_bit():
    # the L1 norm is added left to right as np.abs(d).sum(axis=1) adds a row (the launch
    # lattice's order must not move); directions of every scale, signed zeros included
    rng = np.random.default_rng(5)
    d = rng.standard_normal((200_000, 3)) * np.exp(20.0 * rng.standard_normal((200_000, 1)))
    d[:4] = [[0.0, 0.0, -1.0], [-0.0, 0.0, -1.0], [0.0, -0.0, -2.0], [-1.0, -0.0, 0.0]]
    norm1 = np.abs(d).sum(axis=1)
    x, y, z = (d[:, k] / norm1 for k in range(3))
    u = np.where(z < 0, (1.0 - np.abs(y)) * np.where(x < 0, -1.0, 1.0), x)
    v = np.where(z < 0, (1.0 - np.abs(x)) * np.where(y < 0, -1.0, 1.0), y)
    got = octahedral_coordinates(d)
    np.testing.assert_array_equal(got[0].view(np.int64), u.view(np.int64))
    np.testing.assert_array_equal(got[1].view(np.int64), v.view(np.int64))
