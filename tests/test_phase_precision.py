"""Phases of device path lengths against float64 (kernels/precise.h, docs/precision.md).

Issue #16: a path's phase k L at 24 and 77 GHz, 1 km from the origin, within 1 degree
of the float64 host value, on the device's fp64 and in the double-float fallback
(forced with CLRADCOM_NO_FP64); the same kernel in plain float32 misses that bound,
so the test can fail.
"""

from __future__ import annotations

import types
import warnings

import numpy as np
import pytest

from clradcom.device import precision
from clradcom.device.runtime import OpenCLError
from clradcom.errors import ArgumentError

C0 = 299_792_458.0
FREQS = (24e9, 77e9)
U = 2.0**-24  # float32 unit roundoff
PRECISE = ("auto", "double-float")  # auto: fp64 where the device has it

FAR = np.array([600.0, 780.0, 170.0])  # |FAR| = 1.0 km
NEAR = np.array([3.0, -2.0, 1.0])


def phase_error_deg(length, reference, freq):
    """|k (L - L_ref)| wrapped to [0, 180] degrees, k at freq."""
    k = 2 * np.pi * freq / C0
    diff = np.angle(np.exp(1j * k * (np.asarray(length) - np.asarray(reference))))
    return np.degrees(np.abs(diff))


def polylines(center, n_paths=256, n_vertices=7, seed=0):
    """(P, V, 3) paths of 5 interactions scattered over +-60 m around center."""
    rng = np.random.default_rng(seed)
    return center + rng.uniform(-60.0, 60.0, size=(n_paths, n_vertices, 3))


def host_lengths(points):
    return np.linalg.norm(np.diff(points, axis=1), axis=2).sum(axis=1)


def bounce_scene(center, n_paths=128, n_bounces=5, seed=1):
    """Rays and planes built in float64 so that every ray meets its planes 5-60 m on at
    no more than 70 degrees from normal; v0 is another point of each plane, so the
    kernel's plane hit has to find the hit point."""
    rng = np.random.default_rng(seed)
    origins = center + rng.uniform(-30.0, 30.0, size=(n_paths, 3))
    d0 = rng.normal(size=(n_paths, 3))
    d0 /= np.linalg.norm(d0, axis=1, keepdims=True)
    points, normals = [], []
    seq = np.arange(n_paths * n_bounces).reshape(n_paths, n_bounces)
    for p in range(n_paths):
        o, d = origins[p], d0[p]
        for _ in range(n_bounces):
            hit = o + rng.uniform(5.0, 60.0) * d
            while True:  # a normal facing the ray, cos of incidence >= 0.34
                n = rng.normal(size=3)
                n /= np.linalg.norm(n)
                n = -n if n @ d > 0 else n
                if -(n @ d) >= 0.34:
                    break
            in_plane = np.cross(n, rng.normal(size=3))
            points.append(hit + rng.uniform(1.0, 20.0) * in_plane / np.linalg.norm(in_plane))
            normals.append(n)
            d = d - 2 * (d @ n) * n
            o = hit
    return origins, d0, np.array(points), np.array(normals), seq


def host_bounces(origins, dirs, points, normals, seq):
    """The float64 reference: the same plane hits and mirror directions in numpy."""
    o, d = origins.copy(), dirs.copy()
    total = np.zeros(len(o))
    hits = np.zeros(seq.shape + (3,))
    for k in range(seq.shape[1]):
        v0, n = points[seq[:, k]], normals[seq[:, k]]
        t = np.einsum("ij,ij->i", n, v0 - o) / np.einsum("ij,ij->i", n, d)
        hits[:, k] = o + t[:, None] * d
        total += t * np.linalg.norm(d, axis=1)
        d = d - 2 * np.einsum("ij,ij->i", d, n)[:, None] * n
        o = hits[:, k]
    return total, hits


def test_modes_build_as_asked(runtime):
    assert precision.build_mode("auto", runtime) == ("fp64" if runtime.has_double
                                                     else "double-float")
    assert precision.build_mode("double-float", runtime) == "double-float"
    assert precision.build_mode("float32", runtime) == "float32"


@pytest.mark.parametrize("mode", ["fp64", "double-float"])
def test_scalar_ops_within_published_bounds(runtime, mode):
    """Each double-float operation against float64 on the same pairs, relative error in
    units of u^2 under the bound of its algorithm (kernels/precise.h), with random and
    cancelling operands; fp64 mode only loses the pair rounding of its output (u^2/2)."""
    if mode == "fp64" and not runtime.has_double:
        mode = "double-float"  # a device without fp64: its precise mode is double-float
    rng = np.random.default_rng(7)
    n = 20_000
    a = rng.uniform(-1e3, 1e3, n) * 10.0 ** rng.uniform(-3, 0, n)
    b = rng.uniform(-1e3, 1e3, n) * 10.0 ** rng.uniform(-6, 0, n)
    b[: n // 4] = -a[: n // 4] * (1 + rng.uniform(-1e-5, 1e-5, n // 4))  # cancellation
    a, b = (precision.join_pairs(precision.split_pairs(x)) for x in (a, b))
    b32 = b.astype(np.float32).astype(np.float64)
    exact = {"add": a + b, "sub": a - b, "mul": a * b, "div": a / b,
             "sqrt": np.sqrt(np.abs(a)), "add_f": a + b32, "mul_f": a * b32}
    # 3u^2 + 13u^3, 4u^2, 15u^2 + 56u^3, 25/8 u^2, 2u^2, 2u^2; fp64: the output pair
    bounds = {"add": 3.0, "sub": 3.0, "mul": 4.0, "div": 15.0, "sqrt": 25 / 8,
              "add_f": 2.0, "mul_f": 2.0}
    got = precision.precise_ops(a, b, mode, runtime)
    for name, ref in exact.items():
        rel = np.abs(got[name] - ref) / np.abs(ref)
        worst = float(rel.max()) / U**2
        bound = 0.5 if mode == "fp64" else bounds[name]
        # + u^2/16: the float64 reference's own rounding (2^-53 = u^2/32)
        assert worst <= bound + 1 / 16, (mode, name, worst)
        print(f"{mode} {name}: {worst:.2f} u^2 (bound {bound})")


@pytest.mark.parametrize("mode", ["fp64", "double-float"])
def test_decisions_and_conversions_are_exact(runtime, mode):
    """pr_lt, pr_le, pr_fmax, pr_fmin and pr_floor on pairs, against float64 on the same
    values: exact, also for pairs that tie in hi and differ in lo, integers with a lo
    below them (floor goes one down) and equal values; pr_phase_reduced within float
    rounding of the float64 phase of up to 10^6 radians, within a tenth of a radian of
    [-pi, pi]."""
    if mode == "fp64" and not runtime.has_double:
        mode = "double-float"
    rng = np.random.default_rng(5)
    n = 4000
    a = rng.uniform(-1e3, 1e3, n) * 10.0 ** rng.uniform(-4, 0, n)
    b = a + rng.normal(size=n) * np.abs(a) * 10.0 ** rng.uniform(-15, -6, n)
    b[:200] = a[:200]                                         # equal
    hi = np.float32(a[200:400]).astype(np.float64)
    a[200:400] = hi + np.abs(a[200:400]) * 2.0**-30           # hi ties, lo differs
    b[200:400] = hi - np.abs(b[200:400]) * 2.0**-31
    ints = rng.integers(-2**20, 2**20, 200).astype(np.float64)
    a[400:600] = ints - 2.0**-25 * np.maximum(np.abs(ints), 1)  # just below an integer
    a[600:800] = ints                                         # an integer
    a, b = (precision.join_pairs(precision.split_pairs(x)) for x in (a, b))
    got = precision.precise_decisions(a, b, mode, runtime)
    assert np.array_equal(got["lt"], a < b) and np.array_equal(got["le"], a <= b)
    assert np.array_equal(got["fmax"], np.fmax(a, b))
    assert np.array_equal(got["fmin"], np.fmin(a, b))
    assert np.array_equal(got["floor"], np.floor(a))
    assert (got["lt"] != got["le"]).sum() >= 200 and got["lt"][200:400].sum() == 0
    ph = rng.uniform(-1e6, 1e6, n)
    ph = precision.join_pairs(precision.split_pairs(ph))
    phase = precision.precise_decisions(ph, ph, mode, runtime)["phase"]
    err = np.angle(np.exp(1j * (phase - ph)))
    assert np.abs(phase).max() <= np.pi + 0.1   # the nearest turn by a float quotient
    assert np.abs(err).max() < 1e-6, np.abs(err).max()


@pytest.mark.parametrize("mode", PRECISE)
@pytest.mark.parametrize("center", [FAR, NEAR], ids=["1km", "origin"])
def test_polyline_phase_within_one_degree(runtime, mode, center):
    pts = polylines(center)
    ref = host_lengths(pts)
    got = precision.polyline_lengths(pts, mode, runtime)
    for freq in FREQS:
        err = phase_error_deg(got, ref, freq)
        assert err.max() < 1.0, (mode, freq, err.max())
    # far below the bound, in fact: micrometres would already be tenths of a degree
    assert np.abs(got - ref).max() < 1e-9


@pytest.mark.parametrize("mode", PRECISE)
@pytest.mark.parametrize("center", [FAR, NEAR], ids=["1km", "origin"])
def test_bounced_ray_phase_within_one_degree(runtime, mode, center):
    scene = bounce_scene(center)
    ref, ref_hits = host_bounces(*scene)
    got, hits = precision.bounce_lengths(*scene, mode=mode, runtime=runtime)
    for freq in FREQS:
        err = phase_error_deg(got, ref, freq)
        assert err.max() < 1.0, (mode, freq, err.max())
    assert np.abs(got - ref).max() < 1e-8
    assert np.abs(hits - ref_hits).max() < 1e-8


def test_float32_control_misses_the_bound_at_1km(runtime):
    """The same kernels in plain float32: at 1 km the 77 GHz phase errors pass 1 degree
    (float32 spacing there is 61 um, 1 degree is 11 um), so the tests above can fail."""
    pts = polylines(FAR)
    err = phase_error_deg(precision.polyline_lengths(pts, "float32", runtime),
                          host_lengths(pts), 77e9)
    assert err.max() > 1.0, err.max()
    scene = bounce_scene(FAR)
    ref, ref_hits = host_bounces(*scene)
    got, hits = precision.bounce_lengths(*scene, mode="float32", runtime=runtime)
    assert phase_error_deg(got, ref, 77e9).max() > 1.0
    assert np.abs(hits - ref_hits).max() > 1e-5
    print(f"float32 at 1 km, 77 GHz: polyline {err.max():.1f} deg, bounced "
          f"{phase_error_deg(got, ref, 77e9).max():.1f} deg")


def test_pairs_round_trip_to_2_pow_minus_48():
    x = np.random.default_rng(3).uniform(-2e3, 2e3, 1000)
    pairs = precision.split_pairs(x)
    assert pairs.dtype == np.float32 and pairs.shape == (1000, 2)
    assert (np.abs(precision.join_pairs(pairs) - x) <= 2.0**-48 * np.abs(x)).all()


def test_pairs_of_values_beyond_float_join_back_to_themselves():
    """inf (a PEC's permittivity crosses to scatter.cl so), NaN and values past float's
    range: lo = 0, no inf - inf = NaN, no warning."""
    x = np.array([np.inf, -np.inf, np.nan, 1e300, -1e300, 3.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pairs = precision.split_pairs(x)
    np.testing.assert_array_equal(pairs[:5, 1], 0.0)
    np.testing.assert_array_equal(precision.join_pairs(pairs),
                                  [np.inf, -np.inf, np.nan, np.inf, -np.inf, 3.0])


def test_bad_input_names_argument_and_value(runtime):
    with pytest.raises(ArgumentError, match="mode.*'single'"):
        precision.polyline_lengths(np.zeros((1, 2, 3)), "single", runtime)
    with pytest.raises(ArgumentError, match="no fp64"):
        precision.mode_defines("fp64", types.SimpleNamespace(has_double=False))
    bad = np.zeros((2, 3, 3))
    bad[1, 2, 0] = np.nan
    with pytest.raises(ArgumentError, match=r"points.*\[1, 2, 0\]"):
        precision.polyline_lengths(bad, "auto", runtime)
    with pytest.raises(ArgumentError, match="points.*shape"):
        precision.polyline_lengths(np.zeros((4, 3)), "auto", runtime)
    o = np.zeros((1, 3))
    d = np.array([[1.0, 0.0, 0.0]])
    plane = np.array([[5.0, 0.0, 0.0]])
    with pytest.raises(ArgumentError, match=r"plane_seq = 3: indices must lie in \[-1, 1\)"):
        precision.bounce_lengths(o, d, plane, -d, [[3]], runtime=runtime)
    with pytest.raises(ArgumentError, match="plane_normals.*zero"):
        precision.bounce_lengths(o, d, plane, 0 * d, [[0]], runtime=runtime)
    with pytest.raises(ArgumentError, match="directions.*zero"):
        precision.bounce_lengths(o, 0 * d, plane, -d, [[0]], runtime=runtime)
    # a -1 ends a sequence: one hit at x = 5, then nothing
    length, hits = precision.bounce_lengths(o, d, plane, -d, [[0, -1]], runtime=runtime)
    assert length[0] == 5.0 and hits[0, 0].tolist() == [5.0, 0.0, 0.0]
    assert not hits[0, 1].any()


def test_double_float_refuses_fast_relaxed_math(runtime):
    with pytest.raises(OpenCLError, match="fast-relaxed-math"):
        runtime.kernel("precision_probe.cl", "precise_mode",
                       options=("-cl-fast-relaxed-math",),
                       defines={"CLRADCOM_NO_FP64": 1})


def test_triangle_planes_as_pairs(runtime):
    """Planes of triangles far out, split by triangle_plane_pairs, bounce a ray exactly
    as the float64 planes do; a zero-area triangle is refused by index."""
    tri = FAR + np.array([[[0.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]],
                          [[-20.0, 0.0, 0.0], [-20.0, 0.0, 10.0], [-20.0, 10.0, 0.0]]])
    v0, n = triangle_pairs = precision.triangle_plane_pairs(tri)
    assert v0.shape == n.shape == (2, 3, 2)
    assert np.array_equal(precision.join_pairs(v0), precision.join_pairs(
        precision.split_pairs(tri[:, 0])))
    np.testing.assert_allclose(precision.join_pairs(n), [[1, 0, 0], [-1, 0, 0]], atol=1e-15)
    origin = FAR + np.array([[-7.3, 2.1, 3.3]])
    direction = np.array([[1.0, 0.37, 0.21]])
    length, hits = precision.bounce_lengths(
        origin, direction, precision.join_pairs(triangle_pairs[0]),
        precision.join_pairs(triangle_pairs[1]), [[0, 1]], runtime=runtime)
    ref, ref_hits = host_bounces(origin, direction, tri[:, 0],
                                 np.array([[1.0, 0, 0], [-1.0, 0, 0]]), np.array([[0, 1]]))
    assert abs(length[0] - ref[0]) < 1e-9 and np.abs(hits - ref_hits).max() < 1e-9
    assert hits[0, 0, 0] == pytest.approx(FAR[0], abs=1e-9)  # on the plane x = FAR_x
    with pytest.raises(ArgumentError, match="triangle 1 has zero area"):
        precision.triangle_plane_pairs(np.array([tri[0], [FAR, FAR, FAR]]))
