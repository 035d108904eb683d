"""Physical optics in the radio maps (MapSettings.optics, docs/maps.md "Physical optics").

The map's PO facet fields and SBR-PO footprints at the cell centres against the
tracer's PO and SBR paths to receivers there, on the paper's car mesh.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from test_paths import ROAD, plane, radar, scene_dict

from clradcom import cli
from clradcom import maps as maps_module
from clradcom.maps import MapGrid, MapSettings, radio_map
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.optics import object_optics
from clradcom.paths import InteractionType
from clradcom.scene.reader import load_scene, scene_from_dict
from clradcom.trace import (
    DiffractionSettings,
    OpticsSettings,
    SpecularSettings,
    TraceSettings,
    trace_scene,
)

STREET = Path(__file__).resolve().parent.parent / "scenes" / "street"
CAR = {"name": "car", "material": "metal", "mesh": "meshes/car.ply",
       "position": [8.0, 0.0, 0.0], "rotation_deg": [0.0, 0.0, 30.0]}


def car_scene(radars, objects=(CAR,)):
    return scene_from_dict(scene_dict(objects=list(objects), radars=radars,
                                      materials=[ROAD]), base_dir=STREET)


@pytest.mark.filterwarnings("ignore::clradcom.errors.FresnelZoneWarning")
def test_po_facets_at_the_cell_centres_are_the_tracers_po_paths(runtime):
    """The paper's PEC car mesh (748 facets), a single bounce and no line of sight, under
    the paper preset's optics ("sbr": the car's first bounce is PO), a receiver with a
    120-degree sector turned to 150 degrees (facets outside it take nothing, in both):
    the map's PO facet fields at the cell centres against trace_scene's PO paths to
    receivers there, at 30 cells around the car, 2 to 8 m from it (facets near a centre
    split into far-field pieces as the tracer's): within 0.02 dB (the same facets,
    visibility and integrals; measured 0.007 dB at most, 2e-14 dB at the median: the
    tracer drops facets 80 dB under a link's strongest, the map keeps them), and the
    coherent map within 2e-3 of the incoherent power
    from the traced |sum_k a_k|^2 (the facets' fields add exactly at the centre). The GO
    map of the same car misses them by far: a faceted body gives GO a glint only where a
    facet's normal bisects the directions."""
    tx = radar("tx", [0, 0, 0.5], role="tx", polarization="V",
               pattern={"type": "cosine", "half_power_beamwidth_deg": 90.0})
    rx_kw = dict(role="rx", polarization="V", orientation_deg=[0.0, 0.0, 150.0],
                 pattern={"type": "sector", "azimuth_width_deg": 120.0,
                          "elevation_width_deg": 180.0})
    scene = car_scene([tx, radar("rx", [5, 0, 0.5], **rx_kw)])
    grid = MapGrid(2, 16, -8, 8, 0.5, cell_m=0.5)
    single = dict(rays=20_000, max_reflections=1, line_of_sight=False)
    m = radio_map(scene, "tx", grid, rx="rx", runtime=runtime,
                  settings=MapSettings(**single, optics="sbr"))
    go = radio_map(scene, "tx", grid, rx="rx", runtime=runtime,
                   settings=MapSettings(**single))
    coherent = radio_map(scene, "tx", grid, rx="rx", runtime=runtime,
                         settings=MapSettings(**single, optics="sbr", coherent=True))
    centres = grid.centres()
    # the car's footprint (3.8 x 1.85 m turned by 30 degrees about (8, 0)) and 2 m round it
    rel = centres[..., :2] - [8.0, 0.0]
    along = rel @ [np.cos(np.pi / 6), np.sin(np.pi / 6)]
    across = rel @ [-np.sin(np.pi / 6), np.cos(np.pi / 6)]
    outside = (np.abs(along) > 1.9 + 0.3) | (np.abs(across) > 0.93 + 0.3)
    cells = np.argwhere(outside & (m.gain > 0))
    assert len(cells) > 200
    pick = cells[np.random.default_rng(0).choice(len(cells), 30, replace=False)]
    sample = car_scene([tx, *(radar(f"r{i}", centres[iy, ix], **rx_kw)
                              for i, (iy, ix) in enumerate(pick))])
    settings = TraceSettings(
        specular=SpecularSettings(max_reflections=1, line_of_sight=False),
        diffraction=DiffractionSettings(max_diffractions=0),
        optics=OpticsSettings(mode="sbr"))
    snap = trace_scene(sample, settings, runtime=runtime)
    traced = np.array([np.sum(np.abs(link.paths.gain) ** 2) for link in snap.links])
    assert (traced > 0).all()
    err = np.abs(10 * np.log10(m.gain[pick[:, 0], pick[:, 1]] / traced))
    assert err.max() <= 0.02, np.sort(err)[-5:]
    traced_coherent = np.array([abs(np.sum(link.paths.gain)) ** 2 for link in snap.links])
    err = np.abs(coherent.gain[pick[:, 0], pick[:, 1]] - traced_coherent) / traced
    assert err.max() <= 2e-3, np.sort(err)[-5:]
    with np.errstate(divide="ignore"):
        go_err = np.abs(10 * np.log10(go.gain[pick[:, 0], pick[:, 1]] / traced))
    assert np.median(go_err) > 3.0, np.median(go_err)


def device_vs_host(runtime, grid=None):
    """(worst |device - host| of the coherent map, of the incoherent one), each over the
    incoherent power, on the car at 0.25 m cells (~10^5 facet-cell pairs, near-zone
    pieces among them), or on ``grid``."""
    tx = radar("tx", [0, 0, 0.5], role="tx", polarization="V",
               pattern={"type": "cosine", "half_power_beamwidth_deg": 90.0})
    scene = car_scene([tx, radar("rx", [5, 0, 0.5], role="rx", polarization="H",
                                 pattern="isotropic")])
    grid = grid or MapGrid(2, 16, -8, 8, 0.5, cell_m=0.25)
    maps = {engine: radio_map(scene, "tx", grid, rx="rx", runtime=runtime,
                              settings=MapSettings(rays=1000, max_reflections=1,
                                                   line_of_sight=False, optics="sbr",
                                                   coherent=True, po_engine=engine))
            for engine in ("device", "host")}
    power = maps["host"].incoherent_gain
    reached = power > 0
    assert reached.mean() > 0.5
    assert np.array_equal(maps["device"].incoherent_gain > 0, reached)
    return tuple(float((np.abs(getattr(maps["device"], layer) - getattr(maps["host"], layer))
                        [reached] / power[reached]).max())
                 for layer in ("gain", "incoherent_gain"))


@pytest.mark.filterwarnings("ignore::clradcom.errors.FresnelZoneWarning")
def test_device_po_fields_match_the_float64_host_reference(runtime, no_fp64):
    """The PEC facets' PO fields on the device (about the grid's corner, the carrier
    phase in float64 on the host) against the host's float64 po_transfer: in double
    (fp64 devices) to 1e-9 of the incoherent power (measured 1.3e-11); in float32
    (devices without fp64) to 1e-2 (0.04 dB; measured 4.9e-3 on PoCL), the far
    sidelobes' edge sums losing what float32 loses of terms 500 times the lobe."""
    if runtime.info.has_double:  # not so in the device matrix's no-fp64 session
        assert max(device_vs_host(runtime)) < 1e-9
    coherent, incoherent = device_vs_host(no_fp64)
    assert coherent < 1e-2 and incoherent < 1e-2, (coherent, incoherent)


@pytest.mark.filterwarnings("ignore::clradcom.errors.FresnelZoneWarning")
def test_device_po_fields_on_a_few_cells(runtime):
    """The same on 16 cells beside the car (a few thousand facet-cell pairs: small
    enough for Oclgrind with its checks on), on the session's device: double where it
    has fp64, else its float32 mode's bound."""
    coherent, incoherent = device_vs_host(runtime, MapGrid(4, 6, -3, -1, 0.5, cell_m=0.5))
    bound = 1e-9 if runtime.info.has_double else 1e-2
    assert coherent < bound and incoherent < bound, (coherent, incoherent)


def one_launch_against_pairwise(runtime, grid, receiver, po_batch=1 << 16):
    """The one-launch PO stage (maps._po_pairs_device) and the pair-wise path it replaced
    (maps._po_pairs, the PEC fields on the same device) on the car: (their pairs, worst
    |amplitude difference| over the pair's largest component, that floored at 1e-12 of
    the largest pair's: a projection that cancels to 0 in one order of the float64
    products leaves 1e-17 of it in another)."""
    tx = radar("tx", [0, 0, 0.5], role="tx", polarization="V",
               pattern={"type": "cosine", "half_power_beamwidth_deg": 90.0})
    scene = car_scene([tx] if receiver is None
                      else [tx, radar("rx", [5, 0, 0.5], **receiver)])
    rx = None if receiver is None else scene.radars[1]
    geom = build_geometry(scene, runtime)
    objects = np.flatnonzero(np.array(object_optics(scene, "sbr")) != "go")
    lit = maps_module._lit_facets(scene, geom, scene.radars[0], objects)
    tx_pos = np.asarray(scene.radars[0].position, dtype=np.float64)
    settings = MapSettings(po_batch=po_batch)
    runs = [list(maps_module._po_pairs(scene, geom, grid, tx_pos, rx, lit, settings,
                                       engine=runtime)),
            list(maps_module._po_pairs_device(scene, geom, grid, tx_pos, rx, lit,
                                              settings))]
    (f_ref, cell_ref, a_ref), (f, cell, a) = (
        [np.concatenate([r[i] for r in run]) for i in range(3)] for run in runs)
    assert np.array_equal(f, f_ref) and np.array_equal(cell, cell_ref), (len(f), len(f_ref))
    size = np.abs(a_ref).max(axis=1)
    return len(f), float((np.abs(a - a_ref).max(axis=1)
                          / np.maximum(size, 1e-12 * size.max())).max())


SECTOR_RX = dict(role="rx", polarization="V", orientation_deg=[0.0, 0.0, 150.0],
                 pattern={"type": "sector", "azimuth_width_deg": 120.0,
                          "elevation_width_deg": 120.0})


@pytest.mark.filterwarnings("ignore::clradcom.errors.FresnelZoneWarning")
@pytest.mark.parametrize("receiver", [SECTOR_RX, None], ids=["sector", "no receiver"])
def test_one_launch_po_stage_is_the_pairwise_one_pair_for_pair(runtime, monkeypatch,
                                                              receiver):
    """The PO stage in one launch (the pairs made on the device from its index, lit side,
    the receiver's sector widened by SECTOR_MARGIN, the sight cast and the PEC field;
    the host's exact pattern test, carrier phase and projection after) against the
    pair-wise path it replaced, on the car at 0.25 m cells (3584 cells, ~10^5 pairs
    with the centre on a lit facet's side; near-zone pairs among them): the same
    (facet, cell) pairs in the same order and the same amplitudes, to 1e-9 of a pair's
    largest component in double (the same device fields: measured 1e-12) and 1e-2 in
    float32. Also with launches of 5,000 pairs returning at most 2,000 (each launch
    resumes where its list filled) and a receiver sector 120 x 120 degrees turned away
    from the car's far side (its azimuth and elevation bounds both drop pairs), and
    without a receiver (the field vectors themselves)."""
    grid = MapGrid(2, 16, -8, 8, 0.5, cell_m=0.25)
    n, worst = one_launch_against_pairwise(runtime, grid, receiver)
    assert n > 10_000, n
    bound = 1e-9 if runtime.info.has_double else 1e-2
    assert worst < bound, worst
    monkeypatch.setattr(maps_module, "PO_PAIRS_PER_LAUNCH", 5000)
    n_small, worst = one_launch_against_pairwise(runtime, grid, receiver, po_batch=2000)
    assert n_small == n and worst < bound, (n_small, worst)


@pytest.mark.filterwarnings("ignore::clradcom.errors.FresnelZoneWarning")
def test_one_launch_po_stage_on_a_few_cells(runtime, monkeypatch):
    """The same on 16 cells beside the car, the sector turned toward it, in launches of
    1,000 pairs returning at most 100 (small enough for Oclgrind with its checks on)."""
    monkeypatch.setattr(maps_module, "PO_PAIRS_PER_LAUNCH", 1000)
    toward_car = {**SECTOR_RX, "orientation_deg": [0.0, 0.0, 20.0]}
    n, worst = one_launch_against_pairwise(runtime, MapGrid(4, 6, -3, -1, 0.5, cell_m=0.5),
                                           toward_car, po_batch=100)
    assert n > 100, n
    assert worst < (1e-9 if runtime.info.has_double else 1e-2), worst


BOX_SCENE = """
[scene]
name = "box"
carrier_hz = 24e9

[[objects]]
name = "van"
material = "metal"
shape = "box"
extents = [4.0, 2.0, 2.0]
position = [10.0, 0.0, 1.0]

[[radars]]
name = "A"
position = [0.0, 0.0, 0.5]
polarization = "V"
"""


@pytest.mark.filterwarnings("ignore::clradcom.errors.FresnelZoneWarning")
def test_map_command_takes_the_optics_of_the_tracer(tmp_path, capsys):
    """clradcom map --optics sbr: the map is the function's with MapSettings(optics=
    "sbr") (the metal van's PO facets at the centres), not the GO one."""
    path = tmp_path / "box.toml"
    path.write_text(BOX_SCENE)
    out = tmp_path / "out"
    argv = ["map", str(path), "--tx", "A", "--area=4,16,-4,4", "--cell", "0.5",
            "--reflections", "1", "--rays", "20000", "-q", "--out", str(out)]
    assert cli.main([*argv, "--optics", "sbr"]) == 0
    assert "optics sbr" in capsys.readouterr().out
    data = np.load(out / "map.npz")
    assert str(data["meta.optics"]) == "sbr"
    scene = load_scene(path)
    grid = MapGrid(4, 16, -4, 4, 0.5, cell_m=0.5)
    po = radio_map(scene, "A", grid, settings=MapSettings(rays=20000, max_reflections=1,
                                                          optics="sbr"))
    go = radio_map(scene, "A", grid, settings=MapSettings(rays=20000, max_reflections=1))
    reached = po.gain > 0
    power_db = 10 * np.log10(po.received_power_w[reached])
    assert np.allclose(data["value_db"][reached], power_db, atol=1e-6)
    # beside the line of sight the van's PO facets and its GO glints differ by 2.4 dB
    assert np.abs(10 * np.log10(po.gain[reached] / go.gain[reached])).max() > 1.0


@pytest.mark.filterwarnings("ignore::clradcom.errors.FresnelZoneWarning")
def test_map_command_takes_the_sbr_footprints(tmp_path, capsys):
    """clradcom map --optics sbr --sbr footprints: the function's map with
    MapSettings(sbr="footprints") (the van's road -> van bounces radiated by its tubes'
    footprints), which differs from the exit rays' where those bounces arrive."""
    path = tmp_path / "van.toml"
    path.write_text(BOX_SCENE + """
[[objects]]
name = "road"
material = "concrete_road"
shape = "plane"
size = [40.0, 40.0]
position = [8.0, 0.0, 0.0]
""")
    out = tmp_path / "out"
    argv = ["map", str(path), "--tx", "A", "--area=4,16,-4,4", "--cell", "0.5",
            "--reflections", "2", "--rays", "20000", "--optics", "sbr", "-q", "--out",
            str(out)]
    assert cli.main([*argv, "--sbr", "footprints"]) == 0
    capsys.readouterr()
    data = np.load(out / "map.npz")
    assert str(data["meta.sbr"]) == "footprints"
    scene = load_scene(path)
    grid = MapGrid(4, 16, -4, 4, 0.5, cell_m=0.5)
    settings = MapSettings(rays=20000, max_reflections=2, optics="sbr")
    footprints = radio_map(scene, "A", grid,
                           settings=dataclasses.replace(settings, sbr="footprints"))
    exits = radio_map(scene, "A", grid, settings=settings)
    reached = footprints.gain > 0
    assert np.allclose(data["value_db"][reached],
                       10 * np.log10(footprints.received_power_w[reached]), atol=1e-6)
    both = reached & (exits.gain > 0)
    assert np.abs(10 * np.log10(footprints.gain[both] / exits.gain[both])).max() > 0.1


@pytest.mark.filterwarnings("ignore::clradcom.errors.FresnelZoneWarning")
def test_sbr_footprints_at_the_cell_centres_are_the_tracers_sbr_paths(runtime):
    """The paper's car on a road, three bounces, an isotropic receiver (the tracer
    takes a pattern at a launch block's representative footprint, the map at each
    footprint: they differ where a sector's edge crosses a block): the map's SBR
    footprint stage (MapSettings(sbr="footprints"):
    the tracer's windows and tubes at 4 wavelengths, each footprint's PO integral to the
    cell centres it sees, a face sequence's footprints summed as fields) against
    trace_scene's SBR paths at the same pitch to receivers at 40 of those centres:
    within 0.05 dB (measured 0.02 dB at most: the tracer drops groups 80 dB under a
    link's strongest).
    Cut to each face sequence's beam and 3 diffraction lobes (sbr_lobe_widths=3), the
    map loses the far sidelobes: never more power, and less in most cells."""
    tx = radar("tx", [0, 0, 0.5], role="tx", polarization="V",
               pattern={"type": "cosine", "half_power_beamwidth_deg": 90.0})
    rx_kw = dict(role="rx", polarization="V")
    road = plane("road", "road", [40, 40], position=[8, 0, 0])
    scene = car_scene([tx, radar("rx", [5, 0, 0.5], **rx_kw)], objects=(CAR, road))
    geom = build_geometry(scene, runtime)
    grid = MapGrid(2, 20, -9, 9, 0.5, cell_m=1.0)
    settings = MapSettings(max_reflections=3, line_of_sight=False, optics="sbr",
                           sbr="footprints")

    def footprints(settings):
        tx_radar, rx_radar = scene.radars
        sums = maps_module.CellSums(runtime, grid, 2 * np.pi / scene.wavelength_m, False)
        optics = maps_module._optics_of(scene, geom, tx_radar, settings)
        maps_module._sbr_footprints(scene, geom, grid, tx_radar, rx_radar, optics,
                                    settings, sums)
        return sums.power

    power = footprints(settings)
    cells = np.argwhere(power > 0)
    assert len(cells) > 100
    pick = cells[np.random.default_rng(0).choice(len(cells), 40, replace=False)]
    centres = grid.centres()
    sample = car_scene([tx, *(radar(f"r{i}", centres[iy, ix], **rx_kw)
                              for i, (iy, ix) in enumerate(pick))], objects=(CAR, road))
    traced = trace_scene(sample, TraceSettings(
        specular=SpecularSettings(max_reflections=3, line_of_sight=False),
        diffraction=DiffractionSettings(max_diffractions=0),
        optics=OpticsSettings(mode="sbr", sbr_spacing_wavelengths=4.0)), runtime=runtime)
    sbr = np.array([np.sum(np.abs(link.paths.gain[np.any(
        link.paths.interaction == InteractionType.SBR, axis=1)]) ** 2)
        for link in traced.links])
    assert (sbr > 0).all()
    err = np.abs(10 * np.log10(power[pick[:, 0], pick[:, 1]] / sbr))
    assert err.max() <= 0.05, np.sort(err)[-5:]
    cut = footprints(dataclasses.replace(settings, sbr_lobe_widths=3.0))
    assert (cut <= power * (1 + 1e-9)).all()
    assert np.median(cut[power > 0] / power[power > 0]) < 0.99
