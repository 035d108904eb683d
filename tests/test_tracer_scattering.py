"""Diffuse tile scattering wired into the tracer: energy split with the specular path."""

import numpy as np
import pytest

from clradcom.scene import scene_from_dict
from clradcom.snapshot import InteractionType
from clradcom.tracer import TraceSettings, trace_scene


def ground_scene(S):
    return scene_from_dict({
        "scene": {"name": "leafy", "carrier_hz": 24e9},
        "materials": [{"name": "leaves", "eps_r": [10.0, -6.0], "scattering_coefficient": S}],
        "objects": [{"name": "ground", "material": "leaves", "shape": "plane",
                     "size": [4.0, 4.0], "position": [3.0, 0.0, 0.0]}],
        "radars": [{"name": "tx", "role": "tx", "position": [0.0, 0.0, 1.0]},
                   {"name": "rx", "role": "rx", "position": [6.0, 0.0, 1.0],
                    "orientation_deg": [0.0, 0.0, 180.0]}]})


def test_scattering_takes_its_share_from_the_specular_path(runtime):
    settings = TraceSettings(max_reflections=1, rays=50_000, max_diffractions=0,
                             scattering=True)
    smooth = trace_scene(ground_scene(0.0), settings, runtime=runtime)
    leafy = trace_scene(ground_scene(0.5), settings, runtime=runtime)
    p0, p1 = smooth.links[0].paths, leafy.links[0].paths
    spec0 = p0.gain[p0.interaction[:, 0] == InteractionType.REFLECTION]
    spec1 = p1.gain[p1.interaction[:, 0] == InteractionType.REFLECTION]
    assert len(spec0) == len(spec1) == 1
    # effective roughness: the specular field keeps sqrt(1 - S^2)
    assert spec1[0] == pytest.approx(spec0[0] * np.sqrt(1 - 0.25), rel=1e-12)
    diffuse = p1.interaction[:, 0] == InteractionType.SCATTERING
    assert diffuse.sum() > 10 and not np.any(p0.interaction[:, 0] == InteractionType.SCATTERING)
    # every tile lies on the ground and its delay is its own tx -> tile -> rx length
    tiles = p1.points[diffuse, 1]
    np.testing.assert_allclose(tiles[:, 2], 0.0, atol=1e-12)
    length = (np.linalg.norm(tiles - [0, 0, 1], axis=1) + np.linalg.norm(tiles - [6, 0, 1], axis=1))
    np.testing.assert_allclose(p1.delay_s[diffuse] * 299792458.0, length, rtol=1e-12)
    assert "scattering.tiles_dropped" in leafy.metadata
    # diffuse power stays well below what the specular path lost, as a spread of weak tiles
    assert np.sum(np.abs(p1.gain[diffuse]) ** 2) < np.abs(spec0[0]) ** 2
