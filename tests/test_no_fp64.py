"""Devices without fp64 are first-class (issue #26, item 4): every kernel in the no-fp64
mode (``Runtime(name, fp64=False)``: ``-D CLRADCOM_NO_FP64=1``, kernels/precise.h's
double-float), forced on PoCL and on Intel's runtime where it is installed (the
``no_fp64`` fixture), against the host's float64 reference with physical tolerances;
and the street's main job without fp64 against the fp64 run: every stage on the device,
the same Table III detections, every link's channel within -50 dB NMSE.

Tolerances (tests/mode_helpers.py, shared with the conformance tests, which hold the
same contract when the session runs without fp64: ``--fp64=off``): double-float carries
~1e-14 of a value, so a point or a length is the host's to POINT_TOL_REL = 1e-12
(1 + |p|) m (1e-9 m at 1 km: 3e-7 of a wavelength at 77 GHz); a decision (inside a
face, blocked, on the lit side) is the host's except where the float64 quantity it
tests lies within DECISION_TOL_REL = 1e-13 (1 + |p|) of its threshold, where float64
decides by its own rounding; the fields without fp64 are float (FIELD_TOL_REL = 1e-5 of
the strongest).
"""

from __future__ import annotations

import importlib.util
import warnings
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
import test_diffraction_edges_device as edge_tests
import test_lattice_sequences as lattice_tests
import test_sbr_windows as window_tests
import test_scatter_device as scatter_tests
import test_visibility_device as vis_tests
from mode_helpers import (
    DECISION_TOL_REL,
    FIELD_TOL_REL,
    NO_FP64_NMSE_DB,
    POINT_TOL_REL,
    face_margins,
    segment_margins,
)
from test_visibility_device import edge_points, wall_and_floor

from clradcom.device import engines
from clradcom.device import scatter as device_scatter
from clradcom.device import silhouette as device_silhouette
from clradcom.device.precision import host_float64
from clradcom.device.raycast import RayCaster, make_rays, spawn_origins
from clradcom.device.runtime import OpenCLError, get_runtime, kernel_source
from clradcom.device.visibility import (
    SIGHT_STOP,
    confirm_slack,
    reaches_face,
    segments_clear,
)
from clradcom.errors import DeviceFallbackWarning, SurfaceContactWarning
from clradcom.geometry.triangles import triangle_normals_and_double_areas
from clradcom.geometry.wedges import extract_wedges
from clradcom.mechanisms import diffraction, sbr, scattering
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.scattering import make_tiles, scattering_paths
from clradcom.mechanisms.specular import image_points
from clradcom.physics.vectors import orthonormal_frame
from clradcom.radar.pipeline import process, radar_frame
from clradcom.radar.truth import detection_truth
from clradcom.radar.waveform import Waveform
from clradcom.scene import load_scene
from clradcom.trace import trace_scene

ROOT = Path(__file__).resolve().parent.parent
STREET = ROOT / "scenes" / "street" / "street.toml"
#: the issue's bound for the street's channels, no-fp64 against fp64
STREET_NMSE_DB = NO_FP64_NMSE_DB


def test_no_fp64_mode_is_what_the_kernels_see(no_fp64):
    assert not no_fp64.has_double and no_fp64.device_has_double


def test_a_kernel_that_names_double_does_not_build_without_fp64(no_fp64):
    """kernels/fp64.h hides double where the mode forbids it, so the forced mode on a
    device with fp64 builds what a device without it can (the kernels below all build);
    the same source builds with fp64."""
    source = kernel_source("fp64.h") + """
__kernel void uses_double(__global float *o) { double x = o[0]; o[0] = (float)(2 * x); }
"""
    with pytest.raises(OpenCLError, match="clradcom_no_fp64_build_uses_double"):
        no_fp64.build(source, "uses_double.cl")
    get_runtime(no_fp64.info.vendor).build(source, "uses_double.cl")


# ---------------------------------------------------------------------------
# ray casting: the watertight test's ties

def test_edge_function_ties_resolve_as_with_fp64(no_fp64):
    """Rays at a quad grid's diagonals, within 1e-9 .. 1e-6 of them: where an edge
    function rounds to 0 the test recomputes it (Kahan's fma determinant without fp64,
    double with), so the same triangle of the two is hit as with fp64 and none slips;
    without the recomputation some 0.15 % of these rays pick the other triangle."""
    xs = np.linspace(-1.0, 1.0, 21)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    p = np.stack([gx, gy, np.zeros_like(gx)], axis=-1)
    quads = np.stack([p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]], axis=2).reshape(-1, 4, 3)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    rng = np.random.default_rng(7)
    n = 60_000
    q = rng.integers(0, len(quads), n)
    diag = quads[q, 2] - quads[q, 0]
    perp = np.stack([-diag[:, 1], diag[:, 0], np.zeros(n)], axis=1)
    side = rng.choice([-1.0, 1.0], (n, 1)) * 10.0 ** rng.uniform(-9, -6, (n, 1))
    targets = quads[q, 0] + rng.uniform(0, 1, (n, 1)) * diag + side * perp
    origins = rng.uniform(-3, 3, (n, 3))
    origins[:, 2] = np.abs(origins[:, 2]) + 0.5
    rays = make_rays(origins, targets - origins)
    got = RayCaster(tris, runtime=no_fp64).closest_hit(rays)["prim"]
    want = RayCaster(tris, runtime=get_runtime(no_fp64.info.vendor)).closest_hit(rays)["prim"]
    assert (got >= 0).all()
    np.testing.assert_array_equal(got, want)


# ---------------------------------------------------------------------------
# visibility (kernels/visibility.cl, scene64.h)

@pytest.mark.parametrize("offset", [0.0, 1000.0])
def test_segments_decide_as_float64_but_at_their_thresholds(no_fp64, offset):
    """tests/test_visibility_device.py's segments past edges, seams and rims (at 0 and
    1e-13 .. 3e-5 of 1 + |p| from them): every decision that float64 makes with a margin
    is the host's; the ones that differ (points exactly on a rim or at a seam's
    tolerance, as the generator makes many) have none."""
    triangles, tri_face = wall_and_floor()
    triangles = triangles + offset
    caster = RayCaster(triangles, runtime=no_fp64)
    rng = np.random.default_rng(7)
    offsets = np.array([0.0, 1e-13, 1e-11, 1e-9, 3e-8, 1e-6, 3e-5]) * (1.0 + offset)
    p, _ = edge_points(triangles, rng, 6000, offsets)
    d = rng.normal(size=p.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    start, end = p - 3.0 * d, p + 3.0 * d
    differ = 0
    for tmin, tmax in ((0.0, 1.0), (0.3, 0.7), (rng.uniform(0, 0.5, len(p)), 1.0)):
        with engines.engine_log() as log:
            dev = segments_clear(caster, tri_face, start, end, tmin, tmax)
        assert log.engine_of("visibility.segments") == "device"
        host = segments_clear(caster, tri_face, start, end, tmin, tmax, engine="host")
        bad = host != dev
        margin = segment_margins(triangles, start, end, tmin, tmax)
        assert (margin[bad] <= DECISION_TOL_REL).all(), margin[bad].max()
        differ += bad.sum()
    assert differ < 0.01 * 3 * len(p)


@pytest.mark.parametrize("offset", [0.0, 1000.0])
def test_reaching_a_face_decides_as_float64_but_at_its_rims(no_fp64, offset):
    """tests/test_visibility_device.py's segments ending at edges, seams and rims: the
    same triangle as the host's, except for an end within DECISION_TOL_REL of a rim or a
    seam's tolerance."""
    triangles, tri_face = wall_and_floor()
    triangles = triangles + offset
    caster = RayCaster(triangles, runtime=no_fp64)
    rng = np.random.default_rng(11)
    scale = 1.0 + offset
    end, t = edge_points(triangles, rng, 6000,
                         np.array([0.0, 1e-12, 1e-9, 1e-7, 1e-5]) * scale)
    n = np.cross(triangles[t, 1] - triangles[t, 0], triangles[t, 2] - triangles[t, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    away = rng.normal(size=end.shape)
    away += 2.0 * n * np.where(rng.uniform(size=len(end)) < 0.8, 1.0, -1.0)[:, None]
    start = end + 2.5 * away
    slack = confirm_slack(end, np.linalg.norm(end - start, axis=1))
    host = reaches_face(caster, tri_face, start, end, tri_face[t], slack, engine="host")
    dev = reaches_face(caster, tri_face, start, end, tri_face[t], slack)
    bad = np.flatnonzero(host != dev)
    margin = face_margins(triangles, tri_face, end[bad], tri_face[t[bad]])
    assert (margin <= DECISION_TOL_REL).all(), margin.max()
    assert len(bad) < 0.01 * len(end) and (host >= 0).sum() > 100


def test_surface_sight_past_a_rim_without_fp64(no_fp64):
    """A sight line 1e-7 m above or below a wall's rim 1 km out: decided as float64 has
    it (tests/test_visibility_device.py's case, its exact answers)."""
    vis_tests.test_surface_sight_lines_past_a_rim_are_decided_in_float64(no_fp64)


# ---------------------------------------------------------------------------
# image points (kernels/images.cl)

@pytest.mark.parametrize("k", [1, 3, 6])
def test_image_points_within_picometres(no_fp64, k):
    """Random candidates 1 km out (tests/test_image_points.py's): the points within
    POINT_TOL_REL (1 + |p|) m of the host's, the unfolded lengths too (their phase at
    77 GHz within 1e-4 degree), the same paths."""
    rng = np.random.default_rng(k)
    normals = rng.normal(size=(40, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    tx = np.array([812.3, -455.1, 1.7])
    rx = np.array([790.9, -430.4, 2.2])
    offsets = rng.uniform(-30.0, 30.0, 40) + normals @ tx
    seqs = rng.integers(0, len(normals), (3000, k)).astype(np.int32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SurfaceContactWarning)
        want, want_ok = image_points(tx, rx, normals, offsets, seqs)
        got, got_ok = image_points(tx, rx, normals, offsets, seqs, runtime=no_fp64)
    np.testing.assert_array_equal(got_ok, want_ok)
    assert 0 < want_ok.sum() < len(seqs)
    # the paths' points (a candidate that is no path may be as ill-conditioned as its
    # random planes make it: its points are not used)
    got, want = got[want_ok], want[want_ok]
    err = np.abs(got - want).max(axis=2)
    assert (err <= POINT_TOL_REL * (1.0 + np.abs(want).max(axis=2))).all(), err.max()
    lengths = [np.linalg.norm(np.diff(x, axis=1), axis=2).sum(axis=1) for x in (got, want)]
    k77 = 2 * np.pi * 77e9 / 299_792_458.0
    assert np.degrees(k77 * np.abs(lengths[0] - lengths[1])).max() < 1e-4


# ---------------------------------------------------------------------------
# edge sight (kernels/edges.cl)

def test_edges_seen_as_the_host_sees_them(no_fp64):
    """tests/test_diffraction_edges_device.py's scene and antenna positions: the same
    wedges (sampled and kept) as the numpy reference, from one launch."""
    scene = edge_tests.edge_scene()
    geom = build_geometry(scene, no_fp64)
    wedges = extract_wedges(scene.triangles, scene.tri_object, scene.tri_material)
    for samples, depth in (((0.25, 0.5, 0.75), 4), ((0.5,), 0)):
        with engines.engine_log() as log:
            dev = diffraction._seeing_many(geom.caster, wedges, edge_tests.POINTS, samples,
                                           geom.faces.tri_face, depth)
        assert log.engine_of("diffraction.edge_sight") == "device"
        host = edge_tests.host_reference(geom, wedges, edge_tests.POINTS, samples, depth)
        for p, d, h in zip(edge_tests.POINTS, dev, host, strict=True):
            assert np.array_equal(d[0], h[0]) and np.array_equal(d[1], h[1]), p
        assert any((k & ~s).any() for s, k in host) and any((~k).any() for _, k in host)


# ---------------------------------------------------------------------------
# specular candidates (kernels/reflect.cl: the rotated launch lattice)

def test_rotated_lattice_without_fp64(no_fp64):
    """The lattice rotated in double-float rounds each direction to the float32 of the
    host's float64 rotation but for a component within ~1e-14 of a rounding boundary (one
    in ~10^6): tests/test_lattice_sequences.py's rays give the host-rotated sequences,
    keys and key set."""
    lattice_tests.test_lattice_sequences_are_the_host_rotated_rays_bit_for_bit(no_fp64)
    lattice_tests.test_lattice_keys_are_the_host_keys_of_the_sequences(no_fp64)
    lattice_tests.test_lattice_key_set_is_the_distinct_keys_and_survives_a_full_table(no_fp64)


# ---------------------------------------------------------------------------
# SBR launch windows (kernels/silhouette.cl)

def test_window_projection_within_rounding(no_fp64):
    """project_windows 500 m out without fp64: xy and extents within POINT_TOL_REL
    (1 + |eye|) of the host's projection (the differences p - eye carry the rounding of
    the coordinates)."""
    rng = np.random.default_rng(9)
    tri = rng.normal(size=(700, 3, 3)) * [3.0, 3.0, 2.0] + [400.5, -300.3, 9.0]
    eye = np.array([400.2, -300.1, -0.4])
    axes = rng.normal(size=(4, 3)) * 0.3 + [0.0, 0.0, 1.0]
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    u, v = orthonormal_frame(axes)
    D = rng.uniform(3.0, 15.0, 4)
    win = np.sort(rng.integers(0, 4, len(tri)))
    buf, ext = device_silhouette.project_windows(
        no_fp64, tri, win, np.column_stack([axes, u, v, D]), eye)
    raw = np.empty((len(tri), 3, 2))
    cl.enqueue_copy(no_fp64.queue, raw, buf, is_blocking=True)
    xy = host_float64(no_fp64, raw)
    want, depth = sbr._project(tri, eye, axes[win], u[win], v[win], D[win])
    tol = POINT_TOL_REL * (1.0 + np.abs(eye).max())
    assert np.abs(xy - want).max() <= tol
    want_ext = np.column_stack([depth.min(axis=1), want[..., 0].min(axis=1),
                                want[..., 0].max(axis=1), want[..., 1].min(axis=1),
                                want[..., 1].max(axis=1)])
    assert np.abs(ext - want_ext).max() <= tol


def test_window_masks_and_culls_are_the_hosts(no_fp64):
    """The street's and the raster's and the cull's cases of tests/test_sbr_windows.py:
    the same masks and culls (decisions) as numpy's."""
    window_tests.test_windows_at_once_are_the_loops_bit_for_bit(no_fp64, str(STREET), 1.0)
    window_tests.test_clip_cull_kernel_is_numpys_bit_for_bit(no_fp64)
    window_tests.test_many_grid_raster_is_each_grids_bit_for_bit(no_fp64)


# ---------------------------------------------------------------------------
# scattering tiles (kernels/scatter.cl)

def test_tile_centres_without_fp64(no_fp64):
    """Tile centres of triangles 500 m out, by the host's rule and order, within
    POINT_TOL_REL (1 + |q|) of the host's."""
    rng = np.random.default_rng(3)
    tris = rng.uniform(-40.0, 40.0, size=(40, 3, 3)) + 500.0
    caster = build_geometry(scatter_tests.wall_scene(), no_fp64).caster
    q, _, _, local = make_tiles(tris, 2.5)
    nrm, two_a = triangle_normals_and_double_areas(tris)
    n = scattering._subdivisions(tris, 2.5)
    far = [900.0, 900.0, 900.0]
    got = device_scatter.tile_sight(caster, tris, nrm, 0.5 * two_a / (n * n),
                                    np.ones(len(tris)), np.zeros(len(tris)), n, far, far,
                                    0.0125, all_ends=True, monostatic=True)
    assert len(got.centres) == len(q) > 1000
    assert (np.abs(got.centres - q) <= POINT_TOL_REL * (1.0 + np.abs(q))).all()


def test_tile_sight_flags_and_power_without_fp64(no_fp64):
    """tests/test_scatter_device.py's wall: the sight flags of the host's float32 casts,
    the centres within rounding, the Lambertian power (float) within FIELD_TOL_REL of its
    closed form."""
    sc = scatter_tests.wall_scene()
    geom = build_geometry(sc, no_fp64)
    sel, tris, nrm_t, tile_area, S, n = scatter_tests.triangle_inputs(sc, 0.4)
    A, B = sc.radars
    got = device_scatter.tile_sight(geom.caster, tris, nrm_t, tile_area, S, sel, n,
                                    A.position, B.position, sc.wavelength_m, all_ends=False,
                                    monostatic=False, want_tiles=True)
    q, area, nrm, local = make_tiles(tris, 0.4)
    prim = sel[local].astype(np.int32)

    def sees(end, idx):   # the float32 casts of visibility.surface_sees, by the host
        org = spawn_origins(q[idx], nrm[idx], end - q[idx])
        return ~geom.caster.occluded(make_rays(org, end - org, 0.0, 1.0 - SIGHT_STOP),
                                     ignore_prim=prim[idx])

    vis_t, vis_r = np.zeros(len(q), bool), np.zeros(len(q), bool)
    idx = np.flatnonzero((np.einsum("pi,pi->p", nrm, A.position - q) > 0)
                         & (np.einsum("pi,pi->p", nrm, B.position - q) > 0))
    vis_t[idx] = sees(A.position, idx)
    idx = idx[vis_t[idx]]
    vis_r[idx] = sees(B.position, idx)
    np.testing.assert_array_equal(got.flags, vis_t.astype(np.uint8) | (vis_r << 1))
    both = np.flatnonzero(vis_t & vis_r)
    assert 0 < len(both) and np.array_equal(got.tile, both)
    assert (np.abs(got.centre - q[both]) <= POINT_TOL_REL * (1 + np.abs(q[both]))).all()
    dt, dr = q[both] - A.position, B.position - q[both]
    ri, rs = np.linalg.norm(dt, axis=1), np.linalg.norm(dr, axis=1)
    power = (sc.wavelength_m ** 2 * S[local[both]] ** 2 * area[both]
             * -np.einsum("pi,pi->p", dt, nrm[both]) / ri
             * np.einsum("pi,pi->p", dr, nrm[both]) / rs
             / (16 * np.pi ** 3 * ri ** 2 * rs ** 2))
    np.testing.assert_allclose(got.power, power, rtol=FIELD_TOL_REL)


@pytest.mark.parametrize("max_reflections", [0, 1])
def test_scattering_paths_within_rounding(no_fp64, max_reflections):
    """The wall scene's scattering paths (direct ones with their fields from tile_fields,
    in float without fp64): tests/test_scatter_device.py's comparison in the no-fp64
    mode (the host's paths, points within POINT_TOL_REL, delays within 1e-18 s, gains and
    matrices within FIELD_TOL_REL of the strongest, Doppler within DOPPLER_TOL_HZ, the
    channel within -100 dB NMSE)."""
    sc = scatter_tests.wall_scene()
    device, host = scatter_tests.engines(sc, no_fp64)
    A, B = sc.radars
    for tx, rx in ((A, A), (A, B)):
        kw = dict(tile_size_m=0.5, max_reflections=max_reflections, seed=7)
        scatter_tests.assert_same_paths(scattering_paths(device, tx, rx, **kw),
                                        scattering_paths(host, tx, rx, **kw),
                                        f"{tx.name}->{rx.name} mr={max_reflections}", no_fp64)


# ---------------------------------------------------------------------------
# the street's main job: no-fp64 against fp64

def main_job_settings():
    spec = importlib.util.spec_from_file_location("bench_trace",
                                                  ROOT / "tools" / "bench_trace.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.main_job_settings(STREET)


def channel(paths, n=1024, df=90.909e3):
    """The channel at the radar's 1024 subcarriers (tests/test_sbr_engines.py's)."""
    k = np.arange(n)[:, None]
    return np.exp(-2j * np.pi * k * df * paths.delay_s[None, :]) @ paths.gain


def nmse_db(h, ref):
    return 10 * np.log10(np.sum(np.abs(h - ref) ** 2) / np.sum(np.abs(ref) ** 2))


@pytest.fixture(scope="module")
def street(no_fp64):
    """The street's main job (tools/trace.py's settings) traced once per mode on the
    device: {mode: (snapshot, warnings)}."""
    scene = load_scene(STREET)
    settings = main_job_settings()
    out = {}
    for mode, rt in (("no-fp64", no_fp64), ("fp64", get_runtime(no_fp64.info.vendor))):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            snap = trace_scene(scene, settings, runtime=rt)
        out[mode] = (snap, caught)
    return scene, out


def test_street_every_stage_on_the_device_in_both_modes(street):
    """The metadata names the device for every stage, in both modes, and no stage warns
    that it left the device."""
    _, runs = street
    for mode, (snap, caught) in runs.items():
        used = {k[len("engine."):]: v for k, v in snap.metadata.items()
                if k.startswith("engine.")}
        assert used == {stage: "device" for stage in engines.STAGES}, (mode, used)
        assert snap.metadata["device.fp64"] is (mode == "fp64")
        assert not [w for w in caught if issubclass(w.category, DeviceFallbackWarning)], mode


def test_street_channels_within_minus_50_db_of_fp64(street):
    """Every link's channel at the radar's 1024 subcarriers, no-fp64 against fp64."""
    _, runs = street
    a, b = runs["no-fp64"][0], runs["fp64"][0]
    assert len(a.links) == len(b.links) == 4
    for la, lb in zip(a.links, b.links, strict=True):
        assert (la.tx_name, la.rx_name) == (lb.tx_name, lb.rx_name)
        assert abs(la.paths.n_paths - lb.paths.n_paths) <= 1e-3 * lb.paths.n_paths
        got = nmse_db(channel(la.paths), channel(lb.paths))
        print(f"{la.tx_name}->{la.rx_name}: {got:.1f} dB, {la.paths.n_paths} paths")
        assert got < STREET_NMSE_DB, (la.tx_name, la.rx_name, got)


def table_iii(scene, snap):
    """Radar A's detections of cars B, C, D (tests/test_street_end_to_end.py's rule):
    {car: (range m, velocity m/s, power dB)} of the strongest detection within half a car
    and one velocity cell of the set values."""
    radar = scene.radars[scene.radar_index("A")]
    link = next(x for x in snap.links if x.tx_name == "A" and x.rx_name == "A")
    wf = Waveform(carrier_hz=scene.carrier_hz)
    D, Dr = radar_frame(link.paths, wf, seed=0, tx_power_w=radar.tx_power_w,
                        noise_figure_db=radar.noise_figure_db)
    _, dets = process(D, Dr, wf)
    out = {}
    for t in detection_truth(scene, "A", ["carB", "carC", "carD"]):
        near = (np.abs(dets["range_m"] - t["range_centre_m"]) <= 1.9) & (
            np.abs(dets["velocity_mps"] - t["v_rel_along_m_s"]) <= wf.velocity_resolution)
        assert near.any(), t["name"]
        best = np.flatnonzero(near)[np.argmax(dets["power_db"][near])]
        out[t["name"]] = (float(dets["range_m"][best]), float(dets["velocity_mps"][best]),
                          float(dets["power_db"][best]))
    return out


def test_street_table_iii_detections_as_with_fp64(street):
    """Radar A finds cars B, C and D at the same refined ranges (within 5 mm, under the
    table's centimetre), velocities (0.01 m/s) and powers (0.05 dB) with and without
    fp64: 14.89, 24.54, 33.49 m (the paper's own simulation: 16.1, 25.2, 34.4 m)."""
    scene, runs = street
    got, want = (table_iii(scene, runs[m][0]) for m in ("no-fp64", "fp64"))
    for car, (r, v, p) in want.items():
        assert abs(got[car][0] - r) < 5e-3 and abs(got[car][1] - v) < 1e-2, (car, got, want)
        assert abs(got[car][2] - p) < 0.05, car
    # the fp64 run's, since the SBR tube cells sit at half pitches and the CFAR trains on
    # 4x4 cells (issue #33), and the scattering tiles take their size from each surface's
    # nearest point (issue #27); before, 16.04, 24.54, 33.50 m. B's strongest peak is on
    # the car's rear (14.42 m nearest, 16.40 m centre) and moves with the tube grid (with
    # the 4x2 band: 14.89 / 14.85 / 14.93 / 15.05 / 14.74 m at sbr_accuracy_db 0.4 /
    # 0.45 / 0.5 / 0.55 / 0.6)
    assert [round(want[c][0], 2) for c in ("carB", "carC", "carD")] == [14.89, 24.54, 33.49]


def test_host_engine_records_itself_without_a_warning(no_fp64):
    """The host reference engine records "host" for its stages, as such: no warning."""
    scene = load_scene(ROOT / "scenes" / "canonical" / "plate.toml")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        snap = trace_scene(scene, main_job_settings().replace(engine="host",
                                                              specular__rays=2000),
                           runtime=no_fp64)
    used = {k: v for k, v in snap.metadata.items() if k.startswith("engine.")}
    assert used and set(used.values()) == {"host"}
    assert not [w for w in caught if issubclass(w.category, DeviceFallbackWarning)]
