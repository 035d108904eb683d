"""The radio map's rays stage on the device (kernels/map_walk.cl, clradcom/device/map_walk.py)
against the numpy walk it replaced (MapSettings(engine="host"), the reference).

Both walks cast the same float32 rays with the same closest-hit traversal. With fp64 the
device carries hit points, mirror directions, spawn offsets and fields in double as the
host does in float64: the same rays take the same paths, the same hits start the same
diffuse rays with the same random numbers, and the maps differ by the float32 cell sums'
order of addition (measured 1e-5 of a cell at most): held to the same segment counts and
1e-4 of every converged cell's value.

Without fp64 the device's geometry and fields are float32: a bounce's mirror direction
is off by ~1e-7 rad, so now and then a ray that grazes a triangle's edge takes another
path (0.07 to 0.2 % of the segments differ in the small scene, 0.01 % on the street),
and a cell crossed by a few such rays moves by their share: measured up to 1.3 % of the
largest value among the cell and its eight neighbours, 5e-7 at the median. Held to 3 %
of that neighbourhood, 1e-5 at the median, 0.5 % of the segments. One such ray also
shifts the diffuse rays' random numbers of every later hit (one stream serves them in
order), so without fp64 the maps are compared without scattering.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import maximum_filter
from test_paths import ROAD, box, plane, radar, scene_dict

from clradcom.device.map_walk import WalkTables, walk_rays
from clradcom.maps import MIN_SEGMENTS, MapGrid, MapSettings, _launch_of, radio_map
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.optics import object_optics
from clradcom.scene import load_scene
from clradcom.scene.reader import scene_from_dict

STREET = Path(__file__).resolve().parent.parent / "scenes" / "street" / "street.toml"

#: a rough (Ament) road, a wall rough by Boithias' model that scatters, a metal car (PO
#: facets under the paper preset's optics)
MATERIALS = [dict(ROAD, roughness_m=0.001),
             {"name": "wall", "base": "itu_concrete", "roughness_m": 0.002,
              "roughness_model": "boithias", "scattering_coefficient": 0.4,
              "cross_pol_share": 0.2}]


def small_scene():
    # the boxes' faces off the cells' edges (a face on an edge splits the last
    # millimetres of the segments ending on it between two cells by float rounding)
    objects = [plane("ground", "road", (60.0, 60.0)),
               box("wall", "wall", (1.0, 16.0, 4.0), (11.13, 0.0, 2.0)),
               box("car", "metal", (4.0, 2.0, 1.5), (5.13, -4.13, 0.75)),
               box("kiosk", "itu_glass", (2.0, 2.0, 3.0), (3.13, 5.13, 1.5))]
    tx = radar("tx", [0, 0, 1.0], role="tx", polarization="V", orientation_deg=[0, 5, 10],
               pattern={"type": "cosine", "half_power_beamwidth_deg": 120.0})
    rx = radar("rx", [5, 0, 1.0], role="rx", polarization="H", orientation_deg=[0, 0, 170],
               pattern={"type": "sector", "azimuth_width_deg": 120.0,
                        "elevation_width_deg": 160.0})
    return scene_from_dict(scene_dict(objects=objects, materials=MATERIALS, radars=[tx, rx]))


def both(scene, grid, runtime, rx="rx", **settings):
    maps = [radio_map(scene, "tx", grid, rx=rx, runtime=runtime,
                      settings=MapSettings(engine=engine, **settings))
            for engine in ("host", "device")]
    return maps


def relative(host, device):
    ok = host.count >= MIN_SEGMENTS
    return ok, np.abs(device.gain - host.gain)[ok] / host.gain[ok]


def check_agreement(host, device, fp64: bool) -> None:
    """The module docstring's bounds: with fp64 the same counts and 1e-4 of every
    converged cell; without, 0.5 % of the segments, 1e-5 at the median and 3 % of the
    cell's 3 x 3 neighbourhood's largest value."""
    ok, rel = relative(host, device)
    counts = np.abs(device.count - host.count).sum() / host.count.sum()
    if fp64:
        assert counts <= 1e-4 and rel.max() <= 1e-4, (counts, rel.max())
        return
    local = np.abs(device.gain - host.gain)[ok] / maximum_filter(host.gain, size=3)[ok]
    assert counts <= 5e-3 and np.median(rel) <= 1e-5 and local.max() <= 3e-2, (
        counts, np.median(rel), local.max())


def scattering_where_exact(runtime) -> dict:
    """Diffuse scattering where the walks take the same paths (fp64; the docstring)."""
    if not runtime.info.has_double:
        return {}
    return dict(scattering=True, scattering_reflections=1, diffuse_rays=2)


@pytest.mark.parametrize("rx, line_of_sight", [("rx", True), (None, False)])
def test_device_walk_is_the_host_walk_cell_by_cell(runtime, rx, line_of_sight):
    """Ground, a scattering wall rough by Boithias, a metal car under PO, a glass kiosk;
    three reflections, diffuse rays from the first two orders (with fp64), a rotated
    transmitter and receiver (or none, every polarisation): the bounds of the module's
    docstring, the diffuse rays drawing the same random numbers in the same order."""
    scene = small_scene()
    assert (np.array(object_optics(scene, "sbr")) != "go").any()  # the car is PO
    grid = MapGrid(-4, 16, -10, 10, 1.0, cell_m=0.5)
    host, device = both(scene, grid, runtime, rx=rx, rays=60_000, max_reflections=3,
                        line_of_sight=line_of_sight, optics="sbr", batch=1 << 14,
                        **scattering_where_exact(runtime))
    ok, _ = relative(host, device)
    assert ok.sum() > 300
    check_agreement(host, device, runtime.info.has_double)
    # the walk is not trivially the same everywhere: the scene's mechanisms shape the map
    assert host.gain[ok].max() > 30 * host.gain[ok].min()


def test_device_walk_on_a_street_crop(runtime):
    """The paper's street around radar A (40 m x 20 m of it), five reflections, diffuse
    scattering and the paper preset's optics, received with D's antenna: the device walk
    against the host walk as above."""
    scene = load_scene(STREET)
    d = scene.radars[scene.radar_index("D")]
    grid = MapGrid(-10, 30, -10, 10, float(d.position[2]), cell_m=0.5)
    scattering = {"scattering": True} if runtime.info.has_double else {}
    maps = [radio_map(scene, "A", grid, rx="D", runtime=runtime, settings=MapSettings(
        rays=100_000, max_reflections=5, optics="sbr", engine=engine, batch=1 << 15,
        **scattering)) for engine in ("host", "device")]
    ok, _ = relative(*maps)
    assert ok.sum() > 500
    check_agreement(*maps, runtime.info.has_double)


def test_device_walk_without_fp64_within_float32(no_fp64):
    """The forced no-fp64 build (float32 geometry and fields) against the host walk on
    the same device, no receiver and no line of sight (the case that differs most):
    the float32 bounds of the module's docstring."""
    scene = small_scene()
    grid = MapGrid(-4, 16, -10, 10, 1.0, cell_m=0.5)
    host, device = both(scene, grid, no_fp64, rx=None, rays=60_000, max_reflections=3,
                        line_of_sight=False, optics="sbr", batch=1 << 14)
    ok, _ = relative(host, device)
    assert ok.sum() > 300
    check_agreement(host, device, fp64=False)


def test_device_walk_on_a_few_rays(runtime):
    """Oclgrind's size: a ground and a scattering wall, 400 rays, two reflections and
    diffuse rays from every order, 8 x 8 cells."""
    objects = [plane("ground", "road", (30.0, 30.0)),
               box("wall", "wall", (1.0, 8.0, 3.0), (6.0, 0.0, 1.5))]
    tx = radar("tx", [0, 0, 1.0], role="tx", polarization="V", pattern="isotropic")
    rx = radar("rx", [3, 0, 1.0], role="rx", polarization="V",
               pattern={"type": "cosine", "half_power_beamwidth_deg": 150.0})
    scene = scene_from_dict(scene_dict(objects=objects, materials=MATERIALS,
                                       radars=[tx, rx]))
    grid = MapGrid(0, 8, -4, 4, 1.0, cell_m=1.0)
    host, device = both(scene, grid, runtime, rays=400, max_reflections=2,
                        scattering=True, scattering_reflections=2, diffuse_rays=2,
                        batch=128)
    assert host.count.sum() > 150
    reached = host.count > 0
    if runtime.info.has_double:
        assert np.array_equal(device.count, host.count)
        assert np.allclose(device.gain[reached], host.gain[reached], rtol=1e-4)
    else:  # a float32 ray's other path shifts the diffuse rays: the docstring
        assert np.abs(device.count - host.count).sum() <= 0.2 * host.count.sum()
        assert np.isclose(device.gain.sum(), host.gain.sum(), rtol=0.2)


def test_device_walk_drops_sbr_exits_on_a_few_rays(runtime):
    """Oclgrind's size for the SBR exit marks: a metal box on the ground under the paper
    preset's optics, 1500 rays, two reflections, 8 x 8 cells: the footprint map's walks
    agree and hold fewer segments than the exit rays' (the road -> box exits dropped)."""
    objects = [plane("ground", "road", (30.0, 30.0)),
               box("van", "metal", (2.0, 2.0, 1.5), (5.13, 0.13, 0.75))]
    tx = radar("tx", [0, 0, 1.0], role="tx", polarization="V",
               pattern={"type": "cosine", "half_power_beamwidth_deg": 40.0})
    rx = radar("rx", [3, 0, 1.0], role="rx", polarization="V", pattern="isotropic")
    scene = scene_from_dict(scene_dict(objects=objects, materials=MATERIALS,
                                       radars=[tx, rx]))
    grid = MapGrid(-4, 4, -4, 4, 1.0, cell_m=1.0)
    kw = dict(rays=1500, max_reflections=2, optics="sbr", batch=512)
    host, device = both(scene, grid, runtime, sbr="footprints", **kw)
    kept = both(scene, grid, runtime, sbr="exit-rays", **kw)
    assert host.count.sum() < kept[0].count.sum()
    if runtime.info.has_double:
        assert np.array_equal(device.count, host.count)
        assert np.array_equal(kept[1].count, kept[0].count)
        reached = host.count > 0
        assert np.allclose(device.gain[reached], host.gain[reached], rtol=1e-4)
    else:
        assert device.count.sum() < kept[1].count.sum()


def test_walk_runs_a_batch_again_when_its_records_overflow(runtime):
    """Room for one segment and one hit: the walk counts what did not fit, runs the
    batch again with room for all, and returns the records a roomy first run returns."""
    scene = small_scene()
    geom = build_geometry(scene, runtime)
    tables = WalkTables.of(runtime, scene, geom.caster.normals64(),
                           np.zeros(len(scene.tri_object), dtype=bool))
    tx, rx = scene.radars
    launch = _launch_of(2000, tx.pattern)
    slab = MapGrid(-4, 16, -10, 10, 1.0, cell_m=0.5).slab()
    runs = [walk_rays(geom.caster, launch.on(runtime), tables, tx.orientation, tx.position,
                      slab, 1e-3, 500.0, 0, len(launch.local), 3, True, 3,
                      rx_frame=rx.orientation, capacity=capacity)
            for capacity in ((1, 1), None)]
    (tight, tight_hits), (roomy, roomy_hits) = runs
    assert roomy.count > 1000 and len(roomy_hits.ray) > 100
    assert tight.count == roomy.count
    # the segments' slots follow the device's order: compare them as sets of rows
    assert np.array_equal(np.unique(tight.receive, axis=0), np.unique(roomy.receive, axis=0))
    # the hits come back in (order, ray) order
    assert np.array_equal(tight_hits.ray, roomy_hits.ray)
    assert np.array_equal(tight_hits.fields, roomy_hits.fields)
    assert np.all(np.diff(roomy_hits.order * len(launch.local) + roomy_hits.ray) > 0)


def test_diffuse_rounds_on_threads_add_up_to_the_serial_map(runtime, monkeypatch):
    """The diffuse rays' rounds run two at a time on the host's threads
    (clradcom.parallel.map_in_order), their directions drawn beforehand in the serial
    order: the scattering map is the one of a single thread, counts exactly and gains up
    to the device's float32 accumulation order, on both walks."""
    import clradcom.parallel as parallel

    scene = small_scene()
    grid = MapGrid(-4, 16, -10, 10, 1.0, cell_m=0.5)
    for engine in ("host", "device"):
        settings = MapSettings(rays=20_000, max_reflections=2, scattering=True,
                               scattering_reflections=1, diffuse_rays=4, batch=1 << 13,
                               engine=engine)
        runs = []
        for threads in (4, 1):
            monkeypatch.setattr(parallel, "host_threads", lambda threads=threads: threads)
            runs.append(radio_map(scene, "tx", grid, rx="rx", runtime=runtime,
                                  settings=settings))
        threaded, serial = runs
        np.testing.assert_array_equal(threaded.count, serial.count)
        reached = serial.count > 0
        assert reached.sum() > 300
        np.testing.assert_allclose(threaded.gain[reached], serial.gain[reached], rtol=1e-5)


def test_both_walks_drop_the_exit_segments_the_sbr_footprints_stand_for(runtime):
    """With the SBR footprints (MapSettings(sbr="footprints")), the car's exit segments
    after a second or later bounce along a direction its tubes were shot in are left out,
    by the device walk (the ray marked in the segment's record) as by the host's: the
    two maps agree as above, and hold fewer segments than with the exit rays kept, cell
    by cell and in all (each walk against itself: without fp64 the two walks differ
    slightly, the docstring's bound)."""
    scene = small_scene()
    grid = MapGrid(-4, 16, -10, 10, 1.0, cell_m=0.5)
    kw = dict(rays=60_000, max_reflections=3, optics="sbr", batch=1 << 14)
    host, device = both(scene, grid, runtime, sbr="footprints", **kw)
    check_agreement(host, device, runtime.info.has_double)
    for dropped, kept in zip((host, device), both(scene, grid, runtime, sbr="exit-rays", **kw),
                             strict=True):
        assert (dropped.count <= kept.count).all()
        assert dropped.count.sum() < kept.count.sum()
