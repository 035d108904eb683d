"""The fast forms inside extract_wedges against the numpy expressions they replace
(clradcom.geometry.wedges: _edge_groups, _norm3, _max_abs3), value for value."""

import numpy as np

from clradcom.geometry import wedges
from clradcom.geometry.rows import unique_rows


def reference_groups(obj, lo, hi):
    _, inverse, counts = unique_rows(np.column_stack([obj, lo, hi]))
    order = np.argsort(inverse, kind="stable")
    return order, np.searchsorted(inverse[order], np.arange(len(counts))), counts


def test_edge_groups_match_unique_rows_with_small_and_huge_ids():
    """One int64 key per edge where the ids fit, the lexsort path where they do not: the
    same order (ties in row order), run starts and counts as np.unique's groups."""
    rng = np.random.default_rng(11)
    for span in (5, 50, 2**31):   # the last overflows the key: the unique_rows path
        n = 3000
        obj = rng.integers(0, 4, n)
        a, b = rng.integers(0, span, n), rng.integers(0, span, n)
        dup = rng.integers(0, n, n // 2)   # repeated edges, in shuffled row order
        obj[n // 2:], a[n // 2:], b[n // 2:] = obj[dup], b[dup], a[dup]
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        got = wedges._edge_groups(obj, lo, hi)
        want = reference_groups(obj, lo, hi)
        assert (want[2] >= 2).any()
        for g, w in zip(got, want, strict=True):
            assert np.array_equal(g, w)


def test_norm_and_max_abs_are_numpys_bit_for_bit():
    rng = np.random.default_rng(5)
    v = rng.normal(size=(4000, 3)) * 10.0 ** rng.integers(-8, 8, (4000, 1))
    v[:10] = [[0.0, -0.0, 0.0], [3.0, 4.0, 0.0], [1e-200, 1e-200, 1e-200], [1e200, 1.0, -1e200],
              [-0.0, 0.0, -0.0], [1.0, 1.0, 1.0], [np.nextafter(1.0, 2.0), 1.0, -1.0],
              [2.0**-30, 1.0, 2.0**-30], [7.0, -7.0, 7.0], [0.1, 0.2, 0.3]]
    with np.errstate(over="ignore"):   # the 1e200 row overflows to inf in both
        assert np.array_equal(wedges._norm3(v).view(np.int64),
                              np.linalg.norm(v, axis=-1).view(np.int64))
        assert np.array_equal(wedges._norm3(v.reshape(2, 2000, 3)),
                              np.linalg.norm(v.reshape(2, 2000, 3), axis=-1))
    assert np.array_equal(wedges._max_abs3(v), np.max(np.abs(v), axis=-1))
