"""Equal rows of a float array, counted by one lexicographic sort.

``np.unique(rows, axis=0)`` sorts the rows as a structured array, field by field, which
costs some 3x a plain ``np.lexsort`` of the columns; where only how often each row occurs
is wanted (the seams and outlines of planar faces), :func:`row_counts` gives the same
counts. Rows are compared as floats, as np.unique compares them: -0.0 equals 0.0.
"""

from __future__ import annotations

import numpy as np

from clradcom.errors import ArgumentError

__all__ = ["row_counts"]


def row_counts(rows) -> np.ndarray:
    """(N,) how many rows of ``rows`` (N, K) equal each one, column for column, i.e.
    ``counts[inverse]`` of ``np.unique(rows, axis=0, return_inverse=True,
    return_counts=True)``. Rows equal in every column are neighbours in the
    lexicographic order, so one sort and one pass over neighbours count them."""
    rows = np.asarray(rows)
    if rows.ndim != 2:
        raise ArgumentError(f"rows must have shape (N, K), got {rows.shape}",
                            argument="rows", value=rows.shape)
    n = len(rows)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.lexsort(rows.T[::-1])
    srt = rows[order]
    new = np.ones(n, dtype=bool)
    new[1:] = np.any(srt[1:] != srt[:-1], axis=1)
    group = np.cumsum(new) - 1
    out = np.empty(n, dtype=np.int64)
    out[order] = np.bincount(group)[group]
    return out
