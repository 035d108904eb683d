"""Equal rows of a float array, counted by one lexicographic sort.

``np.unique(rows, axis=0)`` sorts the rows as a structured array, field by field, which
costs some 3x a plain ``np.lexsort`` of the columns; where only how often each row occurs
is wanted (the seams and outlines of planar faces), :func:`row_counts` gives the same
counts, and :func:`unique_rows` np.unique's groups in its order. Rows are compared as
floats, as np.unique compares them: -0.0 equals 0.0 (rows must hold no NaN, which
np.unique would group and these do not).
"""

from __future__ import annotations

import numpy as np

from clradcom.errors import ArgumentError

__all__ = ["row_counts", "unique_rows"]


def _groups(rows):
    """(order, group, new): the lexicographic order of ``rows`` (column 0 first), the id
    of each sorted row's run of equal rows, and where each run starts."""
    rows = np.asarray(rows)
    if rows.ndim != 2:
        raise ArgumentError(f"rows must have shape (N, K), got {rows.shape}",
                            argument="rows", value=rows.shape)
    n = len(rows)
    order = np.lexsort(rows.T[::-1])
    srt = rows[order]
    new = np.ones(n, dtype=bool)
    new[1:] = np.any(srt[1:] != srt[:-1], axis=1)
    return order, np.cumsum(new) - 1, new


def unique_rows(rows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(unique (U, K), inverse (N,), counts (U,)): ``np.unique(rows, axis=0,
    return_inverse=True, return_counts=True)`` by one lexsort: the distinct rows in
    lexicographic order, each row's index among them and how often each occurs. Of
    rows equal as floats (0.0 and -0.0) the first in the sort stands for them all."""
    rows = np.asarray(rows)
    order, group, new = _groups(rows)
    if len(rows) == 0:
        return rows[:0], np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    inverse = np.empty(len(rows), dtype=np.int64)
    inverse[order] = group
    return rows[order[new]], inverse, np.bincount(group)


def row_counts(rows) -> np.ndarray:
    """(N,) how many rows of ``rows`` (N, K) equal each one, column for column, i.e.
    ``counts[inverse]`` of ``np.unique(rows, axis=0, return_inverse=True,
    return_counts=True)``. Rows equal in every column are neighbours in the
    lexicographic order, so one sort and one pass over neighbours count them."""
    rows = np.asarray(rows)
    if rows.ndim == 2 and len(rows) == 0:
        return np.zeros(0, dtype=np.int64)
    _, inverse, counts = unique_rows(rows)
    return counts[inverse]
