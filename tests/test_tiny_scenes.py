"""Cases small enough for Oclgrind with all its checks on: the whole trace of the flat
plate and the dihedral (2000 rays, every mechanism of the paper preset), the device
engine against the host reference as tests/test_engines_whole_trace.py holds the larger
scenes, and the edge-visibility kernel on a box beside a wall. On Oclgrind
(tests/test_device_matrix.py) a kernel that reads out of bounds, races or reads an
uninitialised value fails these tests by its report."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mode_helpers import NO_FP64_NMSE_DB, scene_in_mode
from test_engines_whole_trace import both, channel, nmse_db

from clradcom.device import edges as device_edges
from clradcom.geometry.wedges import extract_wedges
from clradcom.mechanisms import diffraction
from clradcom.mechanisms.common import build_geometry
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import TraceSettings

CANONICAL = Path(__file__).resolve().parent.parent / "scenes" / "canonical"
SETTINGS = TraceSettings.preset("paper").replace(specular__rays=2000)
#: device against host: -60 dB NMSE; without fp64 (or --fp64=off) issue #26's target for
#: that mode (tests/mode_helpers.py)
NMSE_DB = -60.0


@pytest.mark.parametrize("name", ["plate", "dihedral"])
def test_device_and_host_agree(runtime, name):
    # without fp64 the radar just off the scene's plane of symmetry (tests/mode_helpers.py:
    # OFF_SYMMETRY_M), where SBR tubes aim exactly at the dihedral's crease
    scene = scene_in_mode(CANONICAL / f"{name}.toml", runtime)
    dev, host = both(scene, runtime, SETTINGS)
    limit = NMSE_DB if runtime.has_double else NO_FP64_NMSE_DB
    assert dev.links and len(dev.links) == len(host.links)
    for a, b in zip(dev.links, host.links, strict=True):
        assert a.paths.n_paths == b.paths.n_paths > 0, a.label
        assert nmse_db(channel(a.paths), channel(b.paths)) < limit, a.label


def test_edge_visibility_kernel_keeps_the_hosts_wedges(runtime):
    """kernels/edges.cl on one box beside a wall, seen from two antenna positions (one
    sample per wedge, one halving): the same sampled and kept masks as the host's
    reference (tests/test_diffraction_edges_device.py holds a larger scene)."""
    scene = scene_from_dict({
        "scene": {"name": "edge", "carrier_hz": 24e9},
        "objects": [
            {"name": "box", "material": "metal", "shape": "box", "extents": [1.0, 1.0, 2.0],
             "position": [4.0, 0.5, 1.0]},
            {"name": "wall", "material": "concrete_building", "shape": "plane",
             "size": [4.0, 6.0], "position": [8.0, 0.0, 2.0], "rotation_deg": [0.0, -90.0, 0.0]},
        ],
        "radars": [{"name": "r", "position": [0.0, -1.0, 1.0]}]})
    geom = build_geometry(scene, runtime)
    wedges = extract_wedges(scene.triangles, scene.tri_object, scene.tri_material)
    points = [[0.0, -1.0, 1.0], [6.0, 2.5, 1.5]]
    samples, depth = (0.5,), 1
    assert device_edges.usable(geom.caster, "device", len(samples), depth)
    device = diffraction._seeing_many(geom.caster, wedges, points, samples,
                                      geom.faces.tri_face, depth, engine="device")
    for p, (d_sampled, d_kept) in zip(points, device, strict=True):
        h_sampled, h_kept = diffraction._seeing(geom.caster, wedges, p, samples,
                                                geom.faces.tri_face, depth, outlines={})
        assert np.array_equal(d_sampled, h_sampled), p
        assert np.array_equal(d_kept, h_kept), p
        assert d_kept.any() and not d_kept.all(), p   # some wedges seen, some hidden
