"""Path sets of two ray tracers matched one to one (tools/bench_peer.py: clradcom against
Sionna RT on the same scene).

Two paths are the same path when they have the same *sequence*, the interaction types
and the objects hit in order from the transmitter to the receiver, and their delays
differ by less than a tolerance (1 ps by default: 0.3 mm of path length, far below the
centimetres that separate two distinct paths of one sequence in a street, far above the
float32 rounding of either tracer's geometry). Within one sequence the pairs are chosen
by the smallest total delay difference (scipy's linear_sum_assignment), so a sequence
with several paths (a reflection off two coplanar faces of one object) matches each
path once.

Plain arrays in and out: a tracer's paths are given as a list of sequences (tuples of
(type, object name)) and an array of delays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from clradcom.errors import ArgumentError

__all__ = ["PathMatch", "distinct_paths", "match_paths", "sequences_of"]

#: delays closer than this are one path when their sequences agree (s)
DELAY_TOLERANCE_S = 1e-12


@dataclass(frozen=True)
class PathMatch:
    """Indices of the paths of tracers a and b: ``pairs`` (M, 2) matched (a index, b
    index), ``only_a`` and ``only_b`` the rest; ``delay_error_s`` (M,) b's delay minus
    a's for each pair."""

    pairs: np.ndarray
    only_a: np.ndarray
    only_b: np.ndarray
    delay_error_s: np.ndarray


def sequences_of(interaction, n_interactions, object_id, object_names) -> list[tuple]:
    """The sequences of a clradcom :class:`~clradcom.paths.Paths`' arrays:
    ((type code, object name), ...) per path, () for line of sight."""
    names = list(object_names)
    n = np.asarray(n_interactions)
    kinds, objs = np.asarray(interaction), np.asarray(object_id)
    return [tuple((int(kinds[p, j]), names[int(objs[p, j])]) for j in range(int(n[p])))
            for p in range(len(n))]


def match_paths(sequences_a, delays_a, sequences_b, delays_b, *,
                tolerance_s: float = DELAY_TOLERANCE_S) -> PathMatch:
    """Match the paths of tracer a to those of tracer b one to one (module doc)."""
    delays_a = np.asarray(delays_a, dtype=np.float64).reshape(-1)
    delays_b = np.asarray(delays_b, dtype=np.float64).reshape(-1)
    for name, seqs, delays in (("a", sequences_a, delays_a), ("b", sequences_b, delays_b)):
        if len(seqs) != len(delays):
            raise ArgumentError(f"{len(seqs)} sequences but {len(delays)} delays",
                                argument=f"sequences_{name}", value=len(seqs))
        if not np.all(np.isfinite(delays)):
            raise ArgumentError("delays must be finite", argument=f"delays_{name}",
                                value=delays[~np.isfinite(delays)][0])
    if not (np.isfinite(tolerance_s) and tolerance_s > 0):
        raise ArgumentError("must be a finite number > 0 (s)", argument="tolerance_s",
                            value=tolerance_s)
    groups: dict[tuple, tuple[list[int], list[int]]] = {}
    for i, s in enumerate(sequences_a):
        groups.setdefault(tuple(s), ([], []))[0].append(i)
    for i, s in enumerate(sequences_b):
        groups.setdefault(tuple(s), ([], []))[1].append(i)
    pairs: list[tuple[int, int]] = []
    for ia, ib in groups.values():
        if not ia or not ib:
            continue
        gap = np.abs(delays_a[ia][:, None] - delays_b[ib][None, :])
        # pairs beyond the tolerance must never be chosen over a valid one: a cost above
        # any sum of valid ones
        cost = np.where(gap < tolerance_s, gap, tolerance_s * (len(ia) + len(ib) + 1))
        rows, cols = linear_sum_assignment(cost)
        pairs += [(ia[r], ib[c]) for r, c in zip(rows, cols, strict=True)
                  if gap[r, c] < tolerance_s]
    pairs.sort()
    pairs_arr = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return PathMatch(
        pairs=pairs_arr,
        only_a=np.setdiff1d(np.arange(len(delays_a)), pairs_arr[:, 0]),
        only_b=np.setdiff1d(np.arange(len(delays_b)), pairs_arr[:, 1]),
        delay_error_s=delays_b[pairs_arr[:, 1]] - delays_a[pairs_arr[:, 0]])


def distinct_paths(sequences, delays, *, tolerance_s: float = DELAY_TOLERANCE_S) -> np.ndarray:
    """Ascending indices of one path of each group of repeats in one tracer's set: a path
    is a repeat of an earlier one with the same sequence and a delay within the tolerance
    (a tracer that keeps paths per triangle, as Sionna RT does, finds a reflection off a
    face split into coplanar triangles once per triangle the rays hit near it)."""
    delays = np.asarray(delays, dtype=np.float64).reshape(-1)
    if len(sequences) != len(delays):
        raise ArgumentError(f"{len(sequences)} sequences but {len(delays)} delays",
                            argument="sequences", value=len(sequences))
    kept: dict[tuple, list[float]] = {}
    out = []
    for i, (s, t) in enumerate(zip(sequences, delays, strict=True)):
        seen = kept.setdefault(tuple(s), [])
        if not any(abs(t - u) < tolerance_s for u in seen):
            seen.append(t)
            out.append(i)
    return np.array(out, dtype=np.int64)
