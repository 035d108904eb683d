"""The SBR pitch rule keeps its promise (issue #33): at the pitch
sbr.spacing_for_accuracy chooses for a target, the 90 degree dihedral's and the square
trihedral's multi-bounce returns lie within the target of their closed forms (Knott,
table 6.1) from lambda to 100 lambda (clradcom.evaluation.corners; tools/sbr_pitch.py
runs the full sweep shown in docs/po.md, this is a coarse one)."""

from __future__ import annotations

import numpy as np
import pytest

from clradcom.evaluation.corners import corner_scene, pitch_sweep
from clradcom.mechanisms import sbr
from clradcom.mechanisms.common import build_geometry

ACCURACIES = (0.25, 0.5, 1.0)
#: lambda (the pitch at its lambda/8 floor), and two sizes where the rule's pitch is
#: accuracy * feature / ERROR_DB_PER_PITCH unclipped (30 lambda and 100 lambda)
SIZES = (1.0, 30.0, 100.0)


@pytest.mark.parametrize("kind", ["dihedral", "trihedral"])
def test_multi_bounce_return_within_the_target(runtime, kind):
    for e in pitch_sweep([kind], SIZES, ACCURACIES, runtime):
        for pol, err in zip("VH", e.sbr_db, strict=True):
            assert abs(err) <= e.accuracy_db, (kind, e.size_m, e.accuracy_db, pol, err)


def test_non_square_dihedral_within_the_target(runtime):
    """Plates 0.6 of the fold: its rims fall elsewhere on the grid."""
    for e in pitch_sweep(["dihedral"], (13.0, 45.0), ACCURACIES, runtime, width_ratio=0.6):
        assert max(abs(x) for x in e.sbr_db) <= e.accuracy_db, e


def test_no_tube_runs_along_the_fold(runtime):
    """The window is aimed at the corner's centre, on its fold; its tubes straddle the
    fold (cells centred at half-integer pitches) instead of ending on it."""
    scene, _ = corner_scene("dihedral", 0.3)
    geom = build_geometry(scene, runtime)
    r = scene.radars[0]
    s = sbr.spacing_for_accuracy(geom, [0], 0.5)[0]
    w = sbr.launch_windows(geom, r.position, [0], s, mirrors=False)
    grid, _ = sbr.window_tubes(w, np.arange(w.n_tubes))
    # offset of each tube's line from the fold (the z axis), in pitches at the window
    x = grid.directions[:, 1] / grid.directions[:, 0] * w.distance[0] / s
    assert np.abs(x).min() == pytest.approx(0.5, abs=1e-6)
