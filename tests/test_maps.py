"""Radio maps (clradcom.maps, kernels/maps.cl) against closed forms and the per-link tracer.

The device accumulation against its float64 numpy reference; a free-space plane against
Friis in every cell; a ground plane against the incoherent two-ray closed form; the
convergence rule (MIN_SEGMENTS) against the errors it separates; the map against
trace_scene to receivers at sample cell centres in a scene with a wall and a car.
"""

from __future__ import annotations

import base64

import numpy as np
import pytest
from matplotlib import colormaps
from test_paths import ETA_ROAD, LAM, ROAD, box, fresnel, plane, radar, scene_dict

import clradcom.device.maps as device_maps
from clradcom import cli
from clradcom.device.maps import Slab, accumulate_segments, accumulate_segments_host
from clradcom.errors import ArgumentError, MemoryBudgetError
from clradcom.export import map_geotransform
from clradcom.maps import (
    MIN_EFFECTIVE_SEGMENTS,
    MIN_SEGMENTS,
    MapGrid,
    MapSettings,
    radio_map,
)
from clradcom.radar.comms import awgn_error_rates
from clradcom.radar.maps import inr_map, radar_snr_map, sinr_map
from clradcom.radar.synthesis import thermal_noise_power
from clradcom.radar.waveform import Waveform
from clradcom.scene.reader import load_scene, scene_from_dict
from clradcom.trace import (
    DiffractionSettings,
    ScatteringSettings,
    SpecularSettings,
    TraceSettings,
    trace_scene,
)
from clradcom.views import page_payload

H = 1.0  # the antennas' and the map's height


def free_space_scene(pattern="isotropic", **kw):
    return scene_from_dict(scene_dict(radars=[
        radar("tx", [0, 0, H], role="tx", pattern=pattern, polarization="V", **kw),
        radar("rx", [5, 0, H], role="rx", pattern="isotropic", polarization="V")]))


def friis(grid, origin=(0.0, 0.0, H)):
    d = np.linalg.norm(grid.centres() - np.asarray(origin), axis=-1)
    return (LAM / (4 * np.pi * d)) ** 2, d


def db_error(value, reference):
    return 10 * np.log10(value / reference)


def test_device_accumulation_matches_the_float64_reference(runtime):
    """Segments in every direction (along an axis, vertical, horizontal inside the slab,
    escaping, starting inside and outside it) add the same length-weighted sums and the
    same counts on the device as the numpy reference cuts them."""
    rng = np.random.default_rng(7)
    slab = Slab(x0=-3.0, y0=-2.0, cell_x=0.5, cell_y=0.25, nx=12, ny=16, z_lo=0.7, z_hi=1.3)
    n = 400
    origins = rng.uniform([-5, -4, 0], [5, 4, 2], size=(n, 3))
    dirs = rng.normal(size=(n, 3))
    dirs[:40, 2] = 0.0  # horizontal: inside the slab or never
    dirs[40:60, :2] = 0.0  # vertical
    dirs[60:80, 1:] = 0.0  # along x
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    lengths = rng.uniform(0.1, 8.0, size=n)
    lengths[::7] = np.inf
    weights = rng.uniform(0.0, 2.0, size=n) * 10.0 ** rng.uniform(-30, -10, size=n)
    weights[::11] = 0.0
    ref, ref_count, ref_square = accumulate_segments_host(slab, origins, dirs, lengths,
                                                          weights)
    got, count, square = accumulate_segments(runtime, slab, origins, dirs, lengths, weights)
    assert ref.max() > 0 and (ref_count > 0).sum() > 50
    # float32 sums of float32 lengths relative to the corner: ~1e-6 of the largest term
    assert np.allclose(got, ref, rtol=2e-5, atol=2e-6 * ref.max())
    # the squares of the same terms: their sum's ~1e-6 relative, its square's 2e-6
    assert ref_square.max() > 0
    assert np.allclose(square, ref_square, rtol=4e-5, atol=4e-6 * ref_square.max())
    # a cell's squares are those of its terms, not of their sum: never above the sum's
    # square, and well below it somewhere
    assert np.all(square <= got ** 2 * (1 + 1e-5))
    assert np.any(square < 0.5 * got ** 2)
    # a piece shorter than float32 resolves may be counted on one side only
    assert np.abs(count - ref_count).sum() <= 0.01 * ref_count.sum()


def test_accumulation_copies_add_up_where_every_segment_shares_the_cells(runtime,
                                                                        monkeypatch):
    """20,000 segments fanning out from one point inside the slab, as a transmitter's
    rays do, in hundreds of work groups that take the sums' copies in turn and race for
    the same cells near the point: the copies add up to what one shared sum gets, cell
    by cell (counts exactly), and their total is every segment's weight x the length it
    runs inside the slab's box, nothing lost to a failed compare-and-swap or counted twice.
    """
    rng = np.random.default_rng(11)
    slab = Slab(x0=0.0, y0=0.0, cell_x=0.5, cell_y=0.5, nx=8, ny=8, z_lo=0.0, z_hi=1.0)
    n = 20_000
    centre = np.array([2.1, 1.9, 0.5])
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n)
    dirs = np.stack([np.cos(azimuth), np.sin(azimuth), np.zeros(n)], axis=1)
    weights = rng.uniform(0.5, 2.0, n)
    assert device_maps.accumulation_copies(slab.nx * slab.ny) == 16
    shared = accumulate_segments(runtime, slab, np.tile(centre, (n, 1)), dirs,
                                 np.full(n, 10.0), weights)
    monkeypatch.setattr(device_maps, "ACCUMULATION_COPIES", 1)
    single = accumulate_segments(runtime, slab, np.tile(centre, (n, 1)), dirs,
                                 np.full(n, 10.0), weights)
    assert np.array_equal(shared[1], single[1])
    assert np.allclose(shared[0], single[0], rtol=1e-5)
    assert np.allclose(shared[2], single[2], rtol=1e-5)
    # the length from the point to the box's side along each direction
    with np.errstate(divide="ignore"):
        to_x = np.where(dirs[:, 0] > 0, 4.0 - centre[0], -centre[0]) / dirs[:, 0]
        to_y = np.where(dirs[:, 1] > 0, 4.0 - centre[1], -centre[1]) / dirs[:, 1]
    inside = np.minimum(np.where(to_x > 0, to_x, np.inf), np.where(to_y > 0, to_y, np.inf))
    assert shared[0].sum() == pytest.approx(float(weights @ inside), rel=1e-5)
    # every segment starts in the same cell
    assert shared[1][3, 4] == n


def test_free_space_plane_holds_friis_in_every_converged_cell(runtime):
    """No scene: the mean path gain over each cell is (lambda / 4 pi d)^2 at its centre
    (isotropic V to isotropic V: the polarisations match in every direction); the cells
    that satisfy the convergence rule hold it within 0.5 dB, and doubling the rays ten
    times over shrinks the error."""
    scene = free_space_scene()
    grid = MapGrid(-20, 20, -20, 20, H, cell_m=1.0)
    reference, d = friis(grid)
    far = d > 3  # the cell mean of 1/d^2 departs from its centre value near the antenna
    maps = [radio_map(scene, "tx", grid, rx="rx", settings=MapSettings(rays=rays),
                      runtime=runtime) for rays in (20_000, 200_000)]
    for m in maps:
        ok = m.converged & far
        assert ok.sum() > 0.15 * far.sum()
        assert np.abs(db_error(m.gain, reference))[ok].max() < 0.5
    # on the cells the sparse map trusts, the dense one is closer: it converges
    common = maps[0].converged & far
    median = [np.median(np.abs(db_error(m.gain, reference))[common]) for m in maps]
    assert median[1] < 0.5 * median[0], median
    assert maps[1].converged.sum() > 2 * maps[0].converged.sum()
    m = maps[1]
    assert m.converged[far].all()


def test_the_convergence_rule_separates_trusted_cells(runtime):
    """At a low ray count the cells below the rule stray beyond 1 dB of Friis, those at
    or above it stay within 0.5 dB: the rule is what makes a cell's value trustworthy."""
    scene = free_space_scene()
    grid = MapGrid(-20, 20, -20, 20, H, cell_m=1.0)
    reference, d = friis(grid)
    m = radio_map(scene, "tx", grid, rx="rx", settings=MapSettings(rays=20_000),
                  runtime=runtime)
    err = np.abs(db_error(m.gain, reference))
    few = (m.count > 0) & (m.count < MIN_SEGMENTS // 2) & (d > 3)
    assert few.sum() > 100 and err[few].max() > 1.0
    enough = (m.count >= MIN_SEGMENTS) & (d > 3)
    assert err[enough].max() < 0.5


def test_directional_transmitter_follows_its_pattern(runtime):
    """A cosine pattern (20 degree beam along +x): Friis times the pattern's gain toward
    each cell centre; no ray leaves behind the antenna."""
    scene = free_space_scene(pattern={"type": "cosine", "half_power_beamwidth_deg": 40.0})
    grid = MapGrid(2, 42, -10, 10, H, cell_m=1.0)
    reference, d = friis(grid)
    tx = scene.radars[0]
    toward = grid.centres() - tx.position
    gain = tx.pattern.gain((toward / d[..., None]).reshape(-1, 3)).reshape(d.shape)
    m = radio_map(scene, "tx", grid, rx="rx", settings=MapSettings(rays=100_000),
                  runtime=runtime)
    ok = m.converged & (gain > 0.1 * gain.max())
    assert ok.sum() > 200
    err = np.abs(db_error(m.gain, reference * gain))[ok]
    assert np.median(err) < 0.1 and err.max() < 0.5
    behind = radio_map(scene, "tx", MapGrid(-20, -2, -10, 10, H, cell_m=1.0), rx="rx",
                       settings=MapSettings(rays=20_000), runtime=runtime)
    assert behind.gain.max() == 0.0


def test_ground_plane_holds_the_incoherent_two_ray_closed_form(runtime):
    """A smooth concrete ground (eps_r = 5 - j0.1): line of sight plus the reflection,
    summed in power, (lambda/4 pi)^2 (1/d_1^2 + |r_TM(theta)|^2 / d_2^2) for V
    polarisation (the field lies in the plane of incidence), within 0.5 dB in every
    converged cell beyond 3 m."""
    scene = scene_from_dict(scene_dict(
        objects=[plane("ground", "road", (200.0, 200.0))], materials=[ROAD],
        radars=[radar("tx", [0, 0, H], role="tx", pattern="isotropic", polarization="V"),
                radar("rx", [5, 0, H], role="rx", pattern="isotropic", polarization="V")]))
    grid = MapGrid(-30, 30, -30, 30, H, cell_m=1.0)
    d = np.hypot(*np.moveaxis(grid.centres()[..., :2], -1, 0))
    d2 = np.hypot(d, 2 * H)
    _, r_tm = fresnel(ETA_ROAD, 2 * H / d2)
    two_ray = (LAM / (4 * np.pi)) ** 2 * (1 / d**2 + np.abs(r_tm) ** 2 / d2**2)
    m = radio_map(scene, "tx", grid, rx="rx",
                  settings=MapSettings(rays=200_000, max_reflections=1), runtime=runtime)
    ok = m.converged & (d > 3)
    assert ok.sum() > 0.8 * (d > 3).sum()
    err = np.abs(db_error(m.gain, two_ray))[ok]
    assert np.median(err) < 0.1 and err.max() < 0.5
    # the line of sight alone misses the reflection by up to ~1.5 dB: the test sees it
    los = radio_map(scene, "tx", grid, rx="rx",
                    settings=MapSettings(rays=200_000, max_reflections=0), runtime=runtime)
    assert np.abs(db_error(los.gain, two_ray))[ok].max() > 1.0


def test_map_agrees_with_the_per_link_tracer_at_sample_cells(runtime):
    """Ground, a concrete wall and a metal car, two reflections: at 240 sample cells whose
    centres lie outside the objects and that satisfy the rule, the map's value and the
    incoherent power trace_scene finds to a receiver at the centre (a directional
    transmitter, a receiver with its own rotated pattern) agree with median <= 0.5 dB and
    95th percentile <= 1.5 dB; cells straddling a shadow boundary may differ more (the
    cell's mean is not its centre's value there)."""
    objects = [plane("ground", "road", (200.0, 200.0)),
               box("wall", "itu_concrete", (2.0, 20.0, 4.0), (12.0, 0.0, 2.0)),
               box("car", "metal", (4.0, 2.0, 1.5), (5.0, -6.0, 0.75))]
    tx = radar("tx", [0, 0, H], role="tx", polarization="V",
               pattern={"type": "cosine", "half_power_beamwidth_deg": 120.0})
    rx_kw = dict(role="rx", polarization="V", orientation_deg=[0.0, 0.0, 180.0],
                 pattern={"type": "cosine", "half_power_beamwidth_deg": 150.0})
    scene = scene_from_dict(scene_dict(objects=objects, materials=[ROAD],
                                       radars=[tx, radar("rx", [5, 0, H], **rx_kw)]))
    grid = MapGrid(-2, 10, -10, 10, H, cell_m=0.5)
    m = radio_map(scene, "tx", grid, rx="rx",
                  settings=MapSettings(rays=400_000, max_reflections=2), runtime=runtime)
    centres = grid.centres()
    outside = ~(((np.abs(centres[..., 0] - 5) < 2.5) & (np.abs(centres[..., 1] + 6) < 1.5))
                | (centres[..., 0] > 10.5))
    candidates = np.argwhere(m.converged & outside & (m.gain > 0))
    assert len(candidates) > 300
    pick = candidates[np.random.default_rng(3).choice(len(candidates), 240, replace=False)]
    receivers = [radar(f"r{i}", centres[iy, ix], **rx_kw) for i, (iy, ix) in enumerate(pick)]
    sample = scene_from_dict(scene_dict(objects=objects, materials=[ROAD],
                                        radars=[tx, *receivers]))
    settings = TraceSettings(specular=SpecularSettings(max_reflections=2, rays=100_000),
                             diffraction=DiffractionSettings(max_diffractions=0))
    snap = trace_scene(sample, settings, runtime=runtime)
    traced = np.array([np.sum(np.abs(link.paths.gain) ** 2) for link in snap.links])
    err = np.abs(db_error(m.gain[pick[:, 0], pick[:, 1]], traced))
    assert np.median(err) <= 0.5 and np.percentile(err, 95) <= 1.5, np.sort(err)[-5:]
    assert (err <= 1.0).mean() >= 0.9


def test_diffuse_scattering_agrees_with_the_tracers_tiles(runtime):
    """A concrete wall with S = 0.6 and a 20 % cross-polar share, only its diffuse
    scattering (no line of sight, no reflections): the map's cosine-weighted diffuse rays
    against the tracer's Lambertian tiles (ScatteringSettings) at 30 sample cell
    centres, median |dB| <= 0.5, 95th percentile <= 1.5, no bias beyond 0.3 dB (the
    field behind a wall of tiles is smooth: the centre is the cell's mean)."""
    materials = [{"name": "rough", "base": "itu_concrete", "scattering_coefficient": 0.6,
                  "cross_pol_share": 0.2}]
    objects = [box("wall", "rough", (1.0, 16.0, 4.0), (10.0, 0.0, 2.0))]
    tx = radar("tx", [0, 0, H], role="tx", pattern="isotropic", polarization="V")
    rx_kw = dict(role="rx", polarization="V",
                 pattern={"type": "cosine", "half_power_beamwidth_deg": 150.0})
    scene = scene_from_dict(scene_dict(objects=objects, materials=materials,
                                       radars=[tx, radar("rx", [5, 0, H], **rx_kw)]))
    grid = MapGrid(1, 9, -6, 6, H, cell_m=0.5)
    m = radio_map(scene, "tx", grid, rx="rx", runtime=runtime, settings=MapSettings(
        rays=200_000, max_reflections=0, line_of_sight=False, scattering=True,
        diffuse_rays=8))
    assert m.converged.all()
    centres = grid.centres()
    cells = np.argwhere(m.gain > 0)
    pick = cells[np.random.default_rng(0).choice(len(cells), 30, replace=False)]
    sample = scene_from_dict(scene_dict(objects=objects, materials=materials, radars=[
        tx, *(radar(f"r{i}", centres[iy, ix], **rx_kw) for i, (iy, ix) in enumerate(pick))]))
    settings = TraceSettings(
        specular=SpecularSettings(max_reflections=0, line_of_sight=False),
        diffraction=DiffractionSettings(max_diffractions=0),
        scattering=ScatteringSettings(enabled=True, threshold_db=-200.0))
    snap = trace_scene(sample, settings, runtime=runtime)
    traced = np.array([np.sum(np.abs(link.paths.gain) ** 2) for link in snap.links])
    err = db_error(m.gain[pick[:, 0], pick[:, 1]], traced)
    assert abs(np.median(err)) <= 0.3
    assert np.median(np.abs(err)) <= 0.5 and np.percentile(np.abs(err), 95) <= 1.5, err
    plain = radio_map(scene, "tx", grid, rx="rx", runtime=runtime, settings=MapSettings(
        rays=20_000, max_reflections=0, line_of_sight=False))
    assert plain.gain.max() == 0.0  # nothing but the scattering reaches the layer


def diffraction_links(objects, tx, points, runtime, **radar_keys):
    """trace_scene's first-order diffraction alone (no line of sight, no reflection)
    from the radar record ``tx`` among ``objects`` to a receiver at each of ``points``
    (``radar_keys`` their pattern and polarisation): the links' gains, in order."""
    sample = scene_from_dict(scene_dict(objects=objects, radars=[
        tx, *(radar(f"r{i}", p, role="rx", **radar_keys) for i, p in enumerate(points))]))
    settings = TraceSettings(
        specular=SpecularSettings(max_reflections=0, line_of_sight=False),
        diffraction=DiffractionSettings(max_diffractions=1))
    snap = trace_scene(sample, settings, runtime=runtime)
    return [link.paths.gain for link in snap.links]


def block_diffraction(runtime, pol, edge_step_m, cone_step_deg):
    """A concrete block in free space, only its first-order edge diffraction: the map's
    Keller-cone rays, the cells more than 1 m from the corners' shadow and reflection
    boundaries (the transition regions, where a cell's mean and its centre's value differ
    by up to 4 dB), and a function tracing the tracer's UTD paths to cells' centres."""
    objects = [box("block", "itu_concrete", (4.0, 8.0, 3.0), (12.0, -6.0, 1.5))]
    kw = dict(pattern="isotropic", polarization=pol)
    tx = radar("tx", [0, 0, H], role="tx", **kw)
    scene = scene_from_dict(scene_dict(objects=objects,
                                       radars=[tx, radar("rx", [5, 0, H], role="rx", **kw)]))
    grid = MapGrid(15, 25, -9, 3, H, cell_m=0.5)
    m = radio_map(scene, "tx", grid, rx="rx", runtime=runtime, settings=MapSettings(
        rays=1000, max_reflections=0, line_of_sight=False, diffraction=True,
        edge_step_m=edge_step_m, cone_step_deg=cone_step_deg))
    centres = grid.centres()
    x, y = centres[..., 0], centres[..., 1]
    # shadow boundaries of the lit corners (10, -2), (14, -2) and reflection boundaries of
    # the side face y = -2 (its image source at (0, -4)): lines y = a + b x
    clear = np.ones(x.shape, dtype=bool)
    for a, b in ((0.0, -0.2), (0.0, -1 / 7), (-4.0, 0.2), (-4.0, 1 / 7)):
        clear &= np.abs(y - a - b * x) / np.hypot(1.0, b) > 1.0

    def traced(cells):
        gains = diffraction_links(objects, tx, centres[cells[:, 0], cells[:, 1]], runtime,
                                  **kw)
        return np.array([np.sum(np.abs(g) ** 2) for g in gains])

    return m, clear, traced


@pytest.mark.parametrize("pol", ["V", "H"])
def test_edge_diffraction_agrees_with_the_tracers_utd(runtime, pol):
    """The block's edge diffraction (edges cut every 5 cm, a cone ray every degree)
    against the tracer's UTD paths at 40 cells behind and beside it, in the block's
    shadow and out of it, clear of the transition regions: bias <= 0.3 dB, median |dB|
    <= 0.5, 95th percentile <= 1.5."""
    m, clear, traced = block_diffraction(runtime, pol, 0.05, 1.0)
    cells = np.argwhere(m.converged & (m.gain > 0) & clear)
    assert len(cells) > 120
    pick = cells[np.random.default_rng(0).choice(len(cells), 40, replace=False)]
    err = db_error(m.gain[pick[:, 0], pick[:, 1]], traced(pick))
    assert abs(np.median(err)) <= 0.3
    assert np.median(np.abs(err)) <= 0.5 and np.percentile(np.abs(err), 95) <= 1.5, err


def test_the_effective_count_flags_cells_a_few_heavy_cone_rays_carry(runtime):
    """The block's diffraction from coarse cone rays (edges cut every 10 cm, a ray every
    1.5 degrees): every cell clear of the transition regions that holds MIN_SEGMENTS
    segments, traced. The UTD weights vary along a cone, so most of those cells owe
    their value to fewer effective rays: the ones under MIN_EFFECTIVE_SEGMENTS stray
    (measured: median 1.02 dB, 95th percentile 1.62) where the converged ones hold within
    0.5 dB (measured 0.18 at the 95th percentile) - the segment count alone would pass
    them all."""
    m, clear, traced = block_diffraction(runtime, "V", 0.1, 1.5)
    counted = np.argwhere((m.count >= MIN_SEGMENTS) & (m.gain > 0) & clear)
    err = np.abs(db_error(m.gain[counted[:, 0], counted[:, 1]], traced(counted)))
    few = m.effective_count[counted[:, 0], counted[:, 1]] < MIN_EFFECTIVE_SEGMENTS
    ok = m.converged[counted[:, 0], counted[:, 1]]
    assert np.array_equal(ok, ~few)
    assert few.sum() >= 40 and ok.sum() >= 8, (few.sum(), ok.sum())
    assert np.median(err[few]) > 0.7 and np.percentile(err[few], 95) > 1.2, err[few]
    assert np.percentile(err[ok], 95) <= 0.5, err[ok]


def test_receiver_without_pattern_takes_every_polarisation(runtime):
    """rx=None: gain 1 and both polarisations, so an H transmitter's free-space map is
    Friis too (an H-polarised receiver of the scene would take nothing from above)."""
    scene = scene_from_dict(scene_dict(radars=[
        radar("tx", [0, 0, H], role="tx", pattern="isotropic", polarization="H")]))
    grid = MapGrid(-10, 10, -10, 10, H, cell_m=1.0)
    reference, d = friis(grid)
    m = radio_map(scene, "tx", grid, settings=MapSettings(rays=100_000), runtime=runtime)
    assert m.rx_name is None
    ok = m.converged & (d > 3)
    assert np.abs(db_error(m.gain, reference))[ok].max() < 0.5


def test_bad_input_is_refused_by_name():
    scene = free_space_scene()
    with pytest.raises(ArgumentError, match="x_max > x_min"):
        MapGrid(5, 1, 0, 1, H)
    with pytest.raises(ArgumentError, match="MapGrid.cell_m"):
        MapGrid(0, 1, 0, 1, H, cell_m=0.0)
    with pytest.raises(ArgumentError, match="MapSettings.rays"):
        MapSettings(rays=0)
    grid = MapGrid(0, 10, 0, 10, H)
    with pytest.raises(ArgumentError, match="tx = 'nope': is no radar"):
        radio_map(scene, "nope", grid)
    with pytest.raises(MemoryBudgetError, match="rays"):
        radio_map(scene, "tx", grid, settings=MapSettings(rays=10**6), budget_bytes=1e6)


# ---------------------------------------------------------------------------
# the RadCom maps (clradcom.radar.maps)


def radcom_scene(objects=(), materials=()):
    """A at the origin and I at (0, 6) facing +x, D at (15, 4) facing -x: cosine beams of
    90 degrees, 10 dB noise figures; A 1 W, D and I 0.5 W."""
    beam = {"type": "cosine", "half_power_beamwidth_deg": 90.0}
    return scene_from_dict(scene_dict(objects=objects, materials=materials, radars=[
        radar("A", [0, 0, H], pattern=beam, polarization="V", noise_figure_db=10.0,
              tx_power_w=1.0),
        radar("D", [15, 4, H], pattern=beam, polarization="V", noise_figure_db=10.0,
              tx_power_w=0.5, orientation_deg=[0.0, 0.0, 180.0]),
        radar("I", [0, 6, H], pattern=beam, polarization="V", noise_figure_db=10.0,
              tx_power_w=0.5)]))


def free_space_gain(scene, tx, grid, rx=None):
    """Friis with both patterns toward each cell centre (rx None: gain 1), V to V."""
    t = scene.radars[scene.radar_index(tx)]
    toward = grid.centres() - t.position
    d = np.linalg.norm(toward, axis=-1)
    k = (toward / d[..., None]).reshape(-1, 3)
    g = t.pattern.gain(k @ t.orientation).reshape(d.shape)
    if rx is not None:
        r = scene.radars[scene.radar_index(rx)]
        g = g * r.pattern.gain(-k @ r.orientation).reshape(d.shape)
    return (LAM / (4 * np.pi * d)) ** 2 * g, d


def test_sinr_and_ber_maps_against_the_free_space_link_budget(runtime):
    """A's frame received with D's antenna in each cell, I transmitting too: SINR = P_A
    g_A / (P_I g_I + kTBF) with Friis and both patterns, within 0.5 dB where both maps
    converged; the BER is the comms model's at that SINR, and without the interferer the
    SINR is the SNR."""

    scene = radcom_scene()
    waveform = Waveform()
    grid = MapGrid(2, 14, -8, 8, H, cell_m=0.5)
    settings = MapSettings(rays=100_000)
    out = sinr_map(scene, "A", "D", "I", grid, waveform, settings=settings, runtime=runtime)
    noise = thermal_noise_power(waveform.bandwidth, 10.0)
    g_a, d_a = free_space_gain(scene, "A", grid, "D")
    g_d, d_d = free_space_gain(scene, "I", grid, "D")
    sinr = 1.0 * g_a / (0.5 * g_d + noise)
    ok = out.converged & (g_a > 0.05 * g_a.max()) & (g_d > 0.05 * g_d.max()) & (d_d > 3)
    assert ok.sum() > 30
    assert np.abs(out.value_db - 10 * np.log10(sinr))[ok].max() < 0.5
    assert np.allclose(out.extra["ber"][ok],
                       awgn_error_rates("qpsk", out.value_db[ok])[1])
    # I's interference costs SINR where it is strong: the map sees the interferer
    alone = sinr_map(scene, "A", "D", None, grid, waveform, settings=settings,
                     runtime=runtime)
    assert (alone.value_db - out.value_db)[ok].max() > 10.0
    snr = 1.0 * g_a / noise
    assert np.abs(alone.value_db - 10 * np.log10(snr))[ok].max() < 0.5


def test_radar_snr_map_is_the_radar_equation_after_processing(runtime):
    """A 10 m^2 point target in each cell: P G^2 lambda^2 sigma / ((4 pi)^3 d^4) times the
    processing gain N M over kTBF (rect windows: 54.2 dB on the paper's frame)."""

    scene = radcom_scene()
    waveform = Waveform()
    grid = MapGrid(2, 30, -8, 8, H, cell_m=1.0)
    out = radar_snr_map(scene, "A", grid, waveform, rcs_m2=10.0,
                        settings=MapSettings(rays=100_000), runtime=runtime)
    assert abs(out.extra["processing_gain_db"] - 10 * np.log10(1024 * 256)) < 1e-9
    a = scene.radars[0]
    toward = grid.centres() - a.position
    d = np.linalg.norm(toward, axis=-1)
    gain = a.pattern.gain((toward / d[..., None]).reshape(-1, 3)).reshape(d.shape)
    snr = (1.0 * gain**2 * LAM**2 * 10.0 / ((4 * np.pi) ** 3 * d**4) * 1024 * 256
           / thermal_noise_power(waveform.bandwidth, 10.0))
    ok = out.converged & (gain > 0.05 * gain.max())
    assert ok.sum() > 100
    assert np.abs(out.value_db - 10 * np.log10(snr))[ok].max() < 1.0
    hann = radar_snr_map(scene, "A", grid, waveform, rcs_m2=10.0,
                         settings=MapSettings(rays=100_000), runtime=runtime,
                         window_range="hann", window_doppler="hann")
    assert np.allclose((out.value_db - hann.value_db)[ok], 2 * 10 * np.log10(1.5))


def test_inr_map_is_the_traced_link_from_each_position_by_reciprocity(runtime):
    """The INR D causes in A's receiver when D stands in a cell: one map shot from A
    with D's antenna as receiver; at 40 sample cells, trace_scene from D placed at the
    cell centre (its own pattern and orientation) to A gives the same incoherent power
    (median <= 0.5 dB, 95th percentile <= 1.5 dB) over ground and a wall."""

    objects = [plane("ground", "road", (200.0, 200.0)),
               box("wall", "itu_concrete", (20.0, 1.0, 3.0), (10.0, 9.0, 1.5))]
    scene = radcom_scene(objects, [ROAD])
    waveform = Waveform()
    grid = MapGrid(3, 25, -6, 6, H, cell_m=0.5)
    out = inr_map(scene, "A", "D", grid, waveform,
                  settings=MapSettings(rays=300_000, max_reflections=2), runtime=runtime)
    candidates = np.argwhere(out.converged & np.isfinite(out.value_db))
    assert len(candidates) > 200
    pick = candidates[np.random.default_rng(5).choice(len(candidates), 40, replace=False)]
    centres = grid.centres()
    d_kw = dict(role="tx", polarization="V", tx_power_w=0.5,
                orientation_deg=[0.0, 0.0, 180.0],
                pattern={"type": "cosine", "half_power_beamwidth_deg": 90.0})
    a_kw = dict(role="rx", polarization="V",
                pattern={"type": "cosine", "half_power_beamwidth_deg": 90.0})
    sample = scene_from_dict(scene_dict(objects=objects, materials=[ROAD], radars=[
        radar("A", [0, 0, H], **a_kw),
        *(radar(f"D{i}", centres[iy, ix], **d_kw) for i, (iy, ix) in enumerate(pick))]))
    settings = TraceSettings(specular=SpecularSettings(max_reflections=2, rays=100_000),
                             diffraction=DiffractionSettings(max_diffractions=0))
    snap = trace_scene(sample, settings, runtime=runtime)
    by_tx = {link.tx_name: np.sum(np.abs(link.paths.gain) ** 2) for link in snap.links}
    noise = thermal_noise_power(waveform.bandwidth, 10.0)
    traced_db = 10 * np.log10([0.5 * by_tx[f"D{i}"] / noise for i in range(len(pick))])
    err = np.abs(out.value_db[pick[:, 0], pick[:, 1]] - traced_db)
    assert np.median(err) <= 0.5 and np.percentile(err, 95) <= 1.5, np.sort(err)[-5:]


def test_radcom_maps_refuse_what_they_cannot_compute(runtime):

    scene = free_space_scene()  # radars without a noise figure
    grid = MapGrid(0, 4, 0, 4, H)
    with pytest.raises(ArgumentError, match="noise_figure_db"):
        radar_snr_map(scene, "tx", grid, Waveform(), runtime=runtime)
    with pytest.raises(ArgumentError, match="BER covers"):
        sinr_map(radcom_scene(), "A", "D", None, grid, Waveform(), modulation="8psk",
                 runtime=runtime)
    with pytest.raises(ArgumentError, match="rcs_m2"):
        radar_snr_map(radcom_scene(), "A", grid, Waveform(), rcs_m2=-1.0, runtime=runtime)
    with pytest.raises(ArgumentError, match="no radar"):
        radar_snr_map(radcom_scene(), "Z", grid, Waveform(), runtime=runtime)


# ---------------------------------------------------------------------------
# the command (clradcom map)

MAP_SCENE = """
[scene]
name = "lane"
carrier_hz = 24e9

[[objects]]
name = "ground"
material = "concrete_road"
shape = "plane"
size = [60.0, 30.0]
position = [15.0, 0.0, 0.0]

[[objects]]
name = "wall"
material = "concrete_building"
shape = "box"
extents = [20.0, 1.0, 4.0]
position = [15.0, 8.0, 2.0]

[[radars]]
name = "A"
position = [0.0, 0.0, 0.5]
pattern = { type = "sector", azimuth_width_deg = 90.0, elevation_width_deg = 180.0 }
polarization = "V"
tx_power_w = 0.01
noise_figure_db = 10.0

[[radars]]
name = "D"
position = [25.0, 2.0, 0.5]
orientation_deg = [0.0, 0.0, 180.0]
pattern = { type = "sector", azimuth_width_deg = 90.0, elevation_width_deg = 180.0 }
polarization = "V"
tx_power_w = 0.01
noise_figure_db = 10.0
"""


def test_map_command_writes_the_picture_and_the_georeferenced_grid(tmp_path, capsys):
    """clradcom map --kind sinr: map.png, map.npz (layers, the cell centres and GDAL's
    geotransform) and map.csv (a row per cell) whose SINR is the function's; a run over
    the memory budget and a kind without its radar are refused in one line."""

    scene_path = tmp_path / "lane.toml"
    scene_path.write_text(MAP_SCENE)
    out = tmp_path / "out"
    argv = ["map", str(scene_path), "--kind", "sinr", "--tx", "A", "--rx", "D",
            "--area=0,30,-6,6", "--cell", "1", "--rays", "40000", "--out", str(out), "-q"]
    assert cli.main(argv) == 0
    assert "SINR (dB)" in capsys.readouterr().out
    assert {p.name for p in out.iterdir()} == {"map.png", "map.html", "map.npz", "map.csv"}
    assert '"map_label":"SINR (dB)"' in (out / "map.html").read_text()
    data = np.load(out / "map.npz")
    grid = MapGrid(0, 30, -6, 6, 0.5, cell_m=1.0)
    assert data["value_db"].shape == (12, 30)
    assert np.array_equal(data["geotransform"], map_geotransform(grid))
    assert np.allclose(data["x_centres"], np.arange(30) + 0.5)
    assert str(data["meta.kind"]) == "sinr"
    expected = sinr_map(load_scene(scene_path), "A", "D", None, grid, Waveform(),
                        settings=MapSettings(rays=40000))
    assert np.allclose(data["value_db"], expected.value_db, equal_nan=True, atol=1e-6)
    assert np.allclose(data["ber"], expected.extra["ber"], atol=1e-9)
    assert np.array_equal(data["converged"], expected.converged.astype(np.uint8))
    assert np.all(data["effective_segments"] <= data["segments"] * (1 + 1e-9))
    rows = (out / "map.csv").read_text().splitlines()
    assert rows[0] == "x_m,y_m,z_m,value_db,converged,segments,effective_segments,ber"
    assert len(rows) == 1 + 12 * 30
    x, y, z, value = (float(v) for v in rows[1].split(",")[:4])
    assert (x, y, z) == (0.5, -5.5, 0.5)
    assert value == pytest.approx(data["value_db"][0, 0], abs=1e-4) or np.isnan(value)

    assert cli.main([*argv[:-3], "--out", str(tmp_path / "big"), "--memory-budget", "1M"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--rays" in err[0] and "memory" in err[0]
    assert not (tmp_path / "big").exists()
    with pytest.raises(SystemExit) as exc:
        cli.main(["map", str(scene_path), "--kind", "inr"])
    assert exc.value.code == 2
    assert "--interferer" in capsys.readouterr().err
    assert cli.main(["map", str(scene_path), "--tx", "Q", "--out", str(tmp_path / "q")]) == 2
    assert "--tx = 'Q'" in capsys.readouterr().err


def test_html_view_carries_the_map_as_coloured_cells():
    """views.page_payload with a radio map: two triangles per cell that holds a value, at
    the layer's height, coloured by viridis from the 1st percentile to the maximum."""
    scene = free_space_scene()
    grid = MapGrid(0, 3, 0, 2, H, cell_m=1.0)
    values = np.array([[-80.0, -70.0, np.nan], [-60.0, -90.0, -65.0]])
    data = page_payload(scene, radio_map=(grid, values, "gain (dB)"))
    tri = np.frombuffer(base64.b64decode(data["map"]), "<f4").reshape(-1, 3, 3)
    rgb = np.frombuffer(base64.b64decode(data["map_rgb"]), np.uint8).reshape(-1, 3)
    assert len(tri) == 2 * 5 and np.all(tri[..., 2] == H)
    lo, hi = data["map_range"]
    assert hi == -60.0 and lo == pytest.approx(np.percentile(values[np.isfinite(values)], 1))
    centroid = tri.mean(axis=1)
    strongest = (centroid[:, 0] < 1) & (centroid[:, 1] > 1)  # the cell of -60 dB
    assert strongest.sum() == 2
    top = 255 * np.array(colormaps["viridis"](1.0)[:3])
    assert np.all(np.abs(rgb[strongest] - top) <= 1)
    assert np.all(np.abs(rgb[~strongest] - top).max(axis=1) > 10)
    assert data["map_label"] == "gain (dB)"
