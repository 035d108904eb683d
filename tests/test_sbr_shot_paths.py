"""sbr_paths with a shot kept across receivers makes every receiver's paths at once (one
replay of the representatives' bounce points for all): each must be block_paths' of its
own receiver's rows bit for bit, and each is handed out once."""

from __future__ import annotations

import dataclasses
import pickle
import warnings

import numpy as np

from clradcom.mechanisms import sbr
from clradcom.mechanisms.common import build_geometry
from clradcom.scene import load_scene

STREET = "scenes/street/street.toml"


def test_shot_paths_are_each_receivers_block_paths(runtime):
    scene = load_scene(STREET)
    geom = build_geometry(scene, runtime, engine="device")
    cars = [i for i, o in enumerate(scene.objects) if o.name.startswith("car")]
    radars = list(scene.radars)
    tx = radars[1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        shot = sbr.shoot_sbr(geom, tx, cars, radars, spacing_wavelengths=2.0, max_bounces=3)
    assert shot.radars is not None and len(shot.sums) > 0
    got = [sbr.sbr_paths(geom, tx, rx, objects=cars, max_bounces=3, shot=shot)
           for rx in radars]
    assert shot._paths == {}   # every receiver's paths handed out
    for r, rx in enumerate(radars):
        rows = shot.sums.select(np.flatnonzero(shot.sums.receiver == r))
        want = sbr.block_paths(geom, shot.windows, rows, tx, rx, max_bounces=3)
        assert got[r].n_paths == want.n_paths > 0
        for f in dataclasses.fields(want):
            np.testing.assert_array_equal(getattr(got[r], f.name), getattr(want, f.name),
                                          err_msg=f.name)
    # asked again, a receiver's paths are made anew, the same
    again = sbr.sbr_paths(geom, tx, radars[0], objects=cars, max_bounces=3, shot=shot)
    np.testing.assert_array_equal(again.gain, got[0].gain)
    np.testing.assert_array_equal(again.points, got[0].points)
    # the paths made ahead (which hold the geometry) stay out of a pickled shot
    assert len(shot._paths) == 1
    copy = pickle.loads(pickle.dumps(shot))
    assert copy._paths == {} and len(copy.sums) == len(shot.sums)


def test_face_groups_are_unique_rows_inverse():
    """The face sequences' groups by one int64 key per row (and by unique_rows where the
    keys would not fit) number the rows as np.unique(axis=0) does."""
    rng = np.random.default_rng(1)
    for K, hi in ((5, 30), (3, 5000), (5, 4972), (2, 3), (6, 2**20)):
        f = rng.integers(-1, hi, size=(4000, K)).astype(np.int32)
        f[rng.random((4000, K)) < 0.3] = -1
        f[:1000] = f[1000:2000]
        want = np.unique(f, axis=0, return_inverse=True)[1].reshape(-1)
        np.testing.assert_array_equal(sbr.face_groups(f), want)
