"""Interaction patterns of paths ("RD": a reflection, then a diffraction) and their counts
(clradcom.paths; tools/bench_paths.py prints them)."""

import numpy as np

from clradcom.paths import InteractionType, Paths, interaction_patterns, pattern_counts


def test_interaction_patterns_and_their_counts():
    R, D, S = (int(InteractionType.REFLECTION), int(InteractionType.DIFFRACTION),
               int(InteractionType.SCATTERING))
    rows = [[], [R], [R, D], [D, R], [D], [S, R]]
    p, k = len(rows), 2
    inter = np.zeros((p, k), np.int8)
    for i, r in enumerate(rows):
        inter[i, :len(r)] = r
    n = np.array([len(r) for r in rows], np.int16)
    pts = np.full((p, k + 2, 3), np.nan)
    pts[:, 0] = 0.0
    for i, r in enumerate(rows):
        pts[i, 1:len(r) + 1] = [0.5, 0.1 * (i + 1), 0.0]
        pts[i, len(r) + 1] = [1.0, 0.0, 0.0]
    ids = np.where(inter > 0, 0, -1).astype(np.int32)
    paths = Paths(gain=np.ones(p, complex), matrix=np.zeros((p, 2, 2), complex),
                  delay_s=np.full(p, 1e-8), doppler_hz=np.zeros(p), n_interactions=n,
                  interaction=inter, points=pts, object_id=ids, face_id=ids)
    assert interaction_patterns(paths) == ["", "R", "RD", "DR", "D", "SR"]
    assert pattern_counts([paths, paths], containing="D") == {"RD": 2, "DR": 2, "D": 2}
    assert pattern_counts([paths])[""] == 1
