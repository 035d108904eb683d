"""The coherent radio map (MapSettings(coherent=True), docs/maps.md "The coherent sum").

The device's per-cell records against the summed accumulation; the two-ray ground
plane's interference pattern against its closed form cell by cell; the coherent map
against the coherent sum of trace_scene's paths to receivers at sample cell centres,
for reflections and for edge diffraction.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_maps import MAP_SCENE, diffraction_links
from test_paths import ETA_ROAD, K0, LAM, ROAD, box, fresnel, plane, radar, scene_dict

from clradcom import cli
from clradcom.device.maps import Slab, accumulate_segments_host, segment_cells
from clradcom.maps import MIN_SEGMENTS, MapGrid, MapSettings, radio_map
from clradcom.radar.maps import received_power_map
from clradcom.scene.reader import load_scene, scene_from_dict
from clradcom.trace import (
    DiffractionSettings,
    SpecularSettings,
    TraceSettings,
    trace_scene,
)

H = 1.0  # the antennas' and the map's height


def test_segment_records_add_up_to_the_accumulated_cells(runtime):
    """Every segment's records (cell, length inside) summed per cell give the float64
    reference's length sums and counts; a first guess of capacity that is too small is
    grown, not truncated."""
    rng = np.random.default_rng(11)
    slab = Slab(x0=-3.0, y0=-2.0, cell_x=0.5, cell_y=0.25, nx=12, ny=16, z_lo=0.7, z_hi=1.3)
    n = 300
    origins = rng.uniform([-5, -4, 0], [5, 4, 2], size=(n, 3))
    dirs = rng.normal(size=(n, 3))
    dirs[:40, 2] = 0.0
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    lengths = rng.uniform(0.1, 8.0, size=n)
    lengths[::7] = np.inf
    weights = rng.uniform(0.5, 2.0, size=n)
    ref, ref_count, _ = accumulate_segments_host(slab, origins, dirs, lengths, weights)
    seg, cell, length = segment_cells(runtime, slab, origins, dirs, lengths, capacity=10)
    assert len(seg) > 10  # the guess was too small
    got = np.bincount(cell, weights[seg] * length, minlength=slab.nx * slab.ny)
    count = np.bincount(cell, minlength=slab.nx * slab.ny)
    assert np.allclose(got.reshape(ref.shape), ref, rtol=2e-5, atol=2e-6 * ref.max())
    assert np.abs(count.reshape(ref.shape) - ref_count).sum() <= 0.01 * ref_count.sum()
    # each segment's records lie on its own line, each cell at most once
    assert len(np.unique(seg * slab.nx * slab.ny + cell)) == len(seg)


def two_ray_scene(pol):
    return scene_from_dict(scene_dict(
        objects=[plane("ground", "road", (200.0, 200.0))], materials=[ROAD],
        radars=[radar("tx", [0, 0, H], role="tx", pattern="isotropic", polarization=pol),
                radar("rx", [5, 0, H], role="rx", pattern="isotropic", polarization=pol)]))


@pytest.mark.parametrize("rx", ["rx", None])
def test_two_ray_ground_holds_the_coherent_closed_form_cell_by_cell(runtime, rx):
    """A smooth concrete ground, H polarisation (|r_TE| 0.5 to 0.8 here, far from
    Brewster's angle, so the fringes are deep), 5 cm cells from 3 to 6 m: the coherent
    map over the incoherent closed form is the interference factor
    |e^{-jk d1}/d1 + r_TE e^{-jk d2}/d2|^2 / (1/d1^2 + |r_TE|^2/d2^2), which swings from
    0.03 to 1.9 over the fringes (a fringe every 0.14 to 0.6 m), within 0.05 at the median
    and 0.15 at the 95th percentile in the cells that satisfy the rule; a phase 0.3 rad
    off would miss by 0.18 at the median. The incoherent sum kept beside it stays at
    1 + |r|^2 (d1/d2)^2, flat. The same with the H receiver's scalar projection and
    without a receiver (the field vectors summed: both are horizontal here)."""
    grid = MapGrid(3, 6, -0.5, 0.5, H, cell_m=0.05)
    centres = grid.centres()
    d = np.hypot(centres[..., 0], centres[..., 1])
    d2 = np.hypot(d, 2 * H)
    r_te, _ = fresnel(ETA_ROAD, 2 * H / d2)
    incoherent = (LAM / (4 * np.pi)) ** 2 * (1 / d**2 + np.abs(r_te) ** 2 / d2**2)
    field = np.exp(-1j * K0 * d) / d + r_te * np.exp(-1j * K0 * d2) / d2
    factor = (LAM / (4 * np.pi)) ** 2 * np.abs(field) ** 2 / incoherent
    assert factor.min() < 0.1 and factor.max() > 1.8
    m = radio_map(two_ray_scene("H"), "tx", grid, rx=rx, runtime=runtime,
                  settings=MapSettings(rays=2_000_000, max_reflections=1, coherent=True))
    assert m.coherent and m.incoherent_gain is not None
    ok = m.converged
    assert ok.sum() > 0.3 * ok.size
    # the rule asks it of each wavefront: the reflection's group is the sparser one
    assert (m.group_count[ok] >= MIN_SEGMENTS).all()
    assert (m.group_count <= m.count).all()
    err = np.abs(m.gain / incoherent - factor)[ok]
    assert np.median(err) <= 0.05 and np.percentile(err, 95) <= 0.15, np.sort(err)[-5:]
    flat = m.incoherent_gain / incoherent
    assert np.abs(10 * np.log10(flat[ok])).max() < 0.75
    # the squares the host's records sum are the device accumulation's of the same rays
    # (the host's walk and the device's: without fp64 a segment's end may fall in the next
    # cell on one of them, which moves a cell's effective count by up to 3 %)
    plain = radio_map(two_ray_scene("H"), "tx", grid, rx=rx, runtime=runtime,
                      settings=MapSettings(rays=2_000_000, max_reflections=1))
    rel = np.abs(m.effective_count[ok] / plain.effective_count[ok] - 1.0)
    assert np.median(rel) < 1e-4 and rel.max() < 0.05, (np.median(rel), rel.max())
    assert np.median(m.effective_count[ok] / m.count[ok]) < 0.9


def test_coherent_map_is_the_traced_coherent_sum_at_sample_cells(runtime):
    """Ground and a metal wall, up to two reflections, a cosine transmitter and a
    receiver turned sideways: at 40 sample cells (10 cm) that satisfy the rule the coherent map
    and |sum_k a_k|^2 of trace_scene's paths to a receiver at the centre differ by at
    most 0.05 of the incoherent power at the median and 0.15 at the 95th percentile
    (measured 0.005 and 0.016), where the incoherent power alone misses the coherent
    one by 0.46 at the median (a metal wall's reflection and the line of sight, both
    in the receiver's beam, interfere)."""
    objects = [plane("ground", "road", (200.0, 200.0)),
               box("wall", "metal", (1.0, 20.0, 4.0), (8.5, 0.0, 2.0))]
    tx = radar("tx", [0, 0, H], role="tx", polarization="V",
               pattern={"type": "cosine", "half_power_beamwidth_deg": 90.0})
    rx_kw = dict(role="rx", polarization="V", orientation_deg=[0.0, 0.0, 90.0],
                 pattern={"type": "cosine", "half_power_beamwidth_deg": 150.0})
    scene = scene_from_dict(scene_dict(objects=objects, materials=[ROAD],
                                       radars=[tx, radar("rx", [5, 0, H], **rx_kw)]))
    grid = MapGrid(3, 7, -1.5, 1.5, H, cell_m=0.1)
    m = radio_map(scene, "tx", grid, rx="rx", runtime=runtime, settings=MapSettings(
        rays=2_000_000, max_reflections=2, coherent=True))
    cells = np.argwhere(m.converged)
    assert len(cells) > 300
    pick = cells[np.random.default_rng(5).choice(len(cells), 40, replace=False)]
    centres = grid.centres()
    sample = scene_from_dict(scene_dict(objects=objects, materials=[ROAD], radars=[
        tx, *(radar(f"r{i}", centres[iy, ix], **rx_kw) for i, (iy, ix) in enumerate(pick))]))
    settings = TraceSettings(specular=SpecularSettings(max_reflections=2, rays=100_000),
                             diffraction=DiffractionSettings(max_diffractions=0))
    snap = trace_scene(sample, settings, runtime=runtime)
    coherent = np.array([abs(np.sum(link.paths.gain)) ** 2 for link in snap.links])
    incoherent = np.array([np.sum(np.abs(link.paths.gain) ** 2) for link in snap.links])
    got = m.gain[pick[:, 0], pick[:, 1]]
    err = np.abs(got - coherent) / incoherent
    assert np.median(err) <= 0.05 and np.percentile(err, 95) <= 0.15, np.sort(err)[-5:]
    blind = np.abs(incoherent - coherent) / incoherent
    assert np.median(blind) > 0.3, np.median(blind)
    # the incoherent map beside it is the incoherent trace
    inc = m.incoherent_gain[pick[:, 0], pick[:, 1]]
    assert np.median(np.abs(10 * np.log10(inc / incoherent))) <= 0.5


def test_coherent_edge_diffraction_is_the_traced_coherent_sum(runtime):
    """Behind a concrete screen (an open sheet: its four rims are half-planes), only
    first-order diffraction: the waves of its top, bottom and side rims interfere. The
    coherent map (each rim's wave's phase the Keller path tx - edge - centre, float64
    on the host, and the UTD coefficient's) against |sum_k a_k|^2 of the tracer's
    diffracted paths at 30 cells of the shadow: within 0.08 of the incoherent power at
    the median and 0.25 at the 95th percentile (measured 0.024 and 0.09), where the
    incoherent sum misses by 0.63 at the median."""
    objects = [plane("screen", "itu_concrete", (1.6, 3.0), (8.0, 0.0, 0.8), (0.0, 90.0, 0.0))]
    kw = dict(pattern="isotropic", polarization="V")
    tx = radar("tx", [0, 0, H], role="tx", **kw)
    scene = scene_from_dict(scene_dict(objects=objects,
                                       radars=[tx, radar("rx", [5, 0, H], **kw)]))
    grid = MapGrid(11, 14, -1, 1, H, cell_m=0.1)
    m = radio_map(scene, "tx", grid, rx="rx", runtime=runtime, settings=MapSettings(
        rays=1000, max_reflections=0, line_of_sight=False, diffraction=True,
        edge_step_m=0.01, cone_step_deg=0.25, coherent=True))
    cells = np.argwhere(m.converged & (m.gain > 0))
    assert len(cells) > 200
    pick = cells[np.random.default_rng(2).choice(len(cells), 30, replace=False)]
    gains = diffraction_links(objects, tx, grid.centres()[pick[:, 0], pick[:, 1]], runtime,
                              **kw)
    coherent = np.array([abs(np.sum(g)) ** 2 for g in gains])
    incoherent = np.array([np.sum(np.abs(g) ** 2) for g in gains])
    assert all(len(g) >= 2 for g in gains)
    err = np.abs(m.gain[pick[:, 0], pick[:, 1]] - coherent) / incoherent
    assert np.median(err) <= 0.08 and np.percentile(err, 95) <= 0.25, np.sort(err)[-5:]
    blind = np.abs(incoherent - coherent) / incoherent
    assert np.median(blind) > 0.3, np.median(blind)


def test_map_command_writes_the_coherent_map(tmp_path, capsys):
    """clradcom map --coherent: the layer is the function's coherent map (not the
    incoherent one, which differs over the ground's fringes), and says so in its meta."""
    scene_path = tmp_path / "lane.toml"
    scene_path.write_text(MAP_SCENE)
    out = tmp_path / "out"
    argv = ["map", str(scene_path), "--kind", "gain", "--tx", "A", "--rx", "D",
            "--area=4,8,-1,1", "--cell", "0.1", "--reflections", "1", "--rays", "100000",
            "--out", str(out), "-q"]
    assert cli.main([*argv, "--coherent"]) == 0
    assert "coherent" in capsys.readouterr().out
    data = np.load(out / "map.npz")
    assert str(data["meta.coherent"]) == "True"
    grid = MapGrid(4, 8, -1, 1, 0.5, cell_m=0.1)
    scene = load_scene(scene_path)
    settings = MapSettings(rays=100000, max_reflections=1)
    coherent = received_power_map(scene, "A", grid, rx="D",
                                  settings=MapSettings(**{**settings.__dict__,
                                                          "coherent": True}))
    incoherent = received_power_map(scene, "A", grid, rx="D", settings=settings)
    reached = np.isfinite(coherent.value_db)
    assert reached.sum() > 0.5 * reached.size
    assert np.allclose(data["value_db"][reached], coherent.value_db[reached], atol=1e-6)
    assert np.abs(coherent.value_db - incoherent.value_db)[reached].max() > 3.0

