"""The radio map's diffraction stage makes and casts only the Keller-cone rays that may
reach the layer (clradcom.maps._may_turn_to, _may_reach_unblocked): against the same
stage with every cone ray made and cast."""

import numpy as np
from test_maps import H
from test_paths import box, radar, scene_dict

from clradcom import maps
from clradcom.maps import MapGrid, MapSettings
from clradcom.scene.reader import scene_from_dict


def test_cone_rays_that_cannot_reach_the_layer_are_dropped_without_changing_the_map(
        runtime, monkeypatch):
    """The diffraction stage makes and casts only the Keller-cone rays that may reach the
    layer's box (maps._may_turn_to, maps._may_reach_unblocked): the map equals the one
    with every cone ray made and cast, up to the device's float32 accumulation order,
    in every converged cell; and the filters do drop rays (roof edges above the layer)."""
    objects = [box("block", "itu_concrete", (4.0, 8.0, 3.0), (12.0, -6.0, 1.5)),
               box("wall", "itu_brick", (0.3, 6.0, 5.0), (8.0, 6.0, 2.5))]
    kw = dict(pattern="isotropic", polarization="V")
    scene = scene_from_dict(scene_dict(objects=objects, radars=[
        radar("tx", [0, 0, H], role="tx", **kw), radar("rx", [5, 0, H], role="rx", **kw)]))
    grid = MapGrid(-2, 25, -9, 9, H, cell_m=0.5)
    settings = MapSettings(rays=5000, max_reflections=1, diffraction=True)
    dropped = []

    def counting(filter_):
        def wrapped(*args):
            keep = filter_(*args)
            dropped.append(int((~keep).sum()))
            return keep
        return wrapped

    monkeypatch.setattr(maps, "_may_turn_to", counting(maps._may_turn_to))
    monkeypatch.setattr(maps, "_may_reach_unblocked", counting(maps._may_reach_unblocked))
    fast = maps.radio_map(scene, "tx", grid, rx="rx", runtime=runtime, settings=settings)
    assert sum(dropped) > 0
    monkeypatch.setattr(maps, "_may_turn_to", lambda slab, z, rise: np.ones(len(z), bool))
    monkeypatch.setattr(maps, "_may_reach_unblocked",
                        lambda slab, origins, directions: np.ones(len(origins), bool))
    every = maps.radio_map(scene, "tx", grid, rx="rx", runtime=runtime, settings=settings)
    np.testing.assert_array_equal(fast.count, every.count)
    cells = every.converged & (every.gain > 0)
    assert cells.sum() > 500
    np.testing.assert_allclose(fast.gain[cells], every.gain[cells], rtol=1e-5)


def test_the_diffraction_chunks_on_threads_add_up_to_the_serial_map(runtime, monkeypatch):
    """The diffraction stage's chunks of cone rays run two at a time on the host's
    threads (clradcom.parallel.map_in_order) and add their sums in the chunks' order:
    small batches make many chunks, and the map, incoherent and coherent, is the one of
    a single thread, counts exactly and gains up to the device's float32 accumulation
    order."""
    import clradcom.parallel as parallel

    objects = [box("block", "itu_concrete", (4.0, 8.0, 3.0), (12.0, -6.0, 1.5))]
    kw = dict(pattern="isotropic", polarization="V")
    scene = scene_from_dict(scene_dict(objects=objects, radars=[
        radar("tx", [0, 0, H], role="tx", **kw), radar("rx", [5, 0, H], role="rx", **kw)]))
    grid = MapGrid(-2, 25, -9, 9, H, cell_m=0.5)
    chunks = []
    real_map = parallel.map_in_order

    def counting(fn, items, threads=None):
        items = list(items)
        chunks.append(len(items))
        return real_map(fn, items, threads)

    monkeypatch.setattr(maps, "map_in_order", counting)
    for coherent in (False, True):
        settings = MapSettings(rays=2000, max_reflections=0, diffraction=True,
                               batch=1 << 12, coherent=coherent)
        monkeypatch.setattr(parallel, "host_threads", lambda: 4)
        threaded = maps.radio_map(scene, "tx", grid, rx="rx", runtime=runtime,
                                  settings=settings)
        monkeypatch.setattr(parallel, "host_threads", lambda: 1)
        serial = maps.radio_map(scene, "tx", grid, rx="rx", runtime=runtime,
                                settings=settings)
        np.testing.assert_array_equal(threaded.count, serial.count)
        cells = serial.gain > 0
        assert cells.sum() > 500
        np.testing.assert_allclose(threaded.gain[cells], serial.gain[cells], rtol=1e-6)
    assert max(chunks) > 4
