"""SBR-PO's device engine (kernels/sbr.cl) against the host reference, its launch windows
over silhouettes and mirror images, its unbounded tube count, and the pitch rule.

The host engine (clradcom.mechanisms.sbr: shoot_tubes, _radiate, em.polarimetric_matrix,
then _sum_blocks) and the device kernel sum the same footprints per launch block; they
must agree block for block, and the paths built from them path for path.
"""

from __future__ import annotations

import contextlib
import warnings

import numpy as np
import pytest
from mode_helpers import (
    FIELD_TOL_REL,
    SBR_DIRECTION_TOL_REL,
    SBR_DOPPLER_TOL_HZ,
    SBR_SUM_TOL_REL,
    off_symmetry,
    sbr_row_tolerance,
)
from test_po_sbr import LAM, dihedral, scene_of, sigma, trihedral

from clradcom.device import sbr as device_sbr
from clradcom.device.raycast import InstancedCaster
from clradcom.geometry.silhouette import BLOCK, block_coverage
from clradcom.mechanisms import sbr
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.optics import OpticsSettings
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.scene import load_scene
from clradcom.scene.antenna import pattern_peak_gain
from clradcom.scene.reader import scene_from_dict

DATA = "tests/data/all_mechanisms.toml"
STREET = "scenes/street/street.toml"


def both_engines(scene, runtime):
    return {e: build_geometry(scene, runtime, engine=e) for e in ("host", "device")}


@contextlib.contextmanager
def host_footprints():
    """The host engine's footprints, before :func:`sbr._sum_blocks` sums them: a list that
    gets one dict per host shot (tube, bounce, receiver, M, L, point, tri, face, norm)."""
    kept = []
    sum_blocks = sbr._sum_blocks

    def keep(tube, bounce, receiver, M, L, point, tri, tri_face, max_bounces):
        face = np.where(tri >= 0, tri_face[np.maximum(tri, 0)], -1)
        kept.append(dict(tube=tube, bounce=bounce, receiver=receiver, M=M, L=L, point=point,
                         tri=tri, face=face,
                         norm=np.sqrt(np.sum(np.abs(M.reshape(len(M), 4)) ** 2, axis=1))))
        return sum_blocks(tube, bounce, receiver, M, L, point, tri, tri_face, max_bounces)

    sbr._sum_blocks = keep
    try:
        yield kept
    finally:
        sbr._sum_blocks = sum_blocks


def shots(geoms, tx, objects, receivers, **kw):
    """Each engine's shot, and the host's footprints ("footprints") to judge the device's
    without fp64 (:func:`assert_same_sums`)."""
    with host_footprints() as kept:
        out = {"host": sbr.shoot_sbr(geoms["host"], tx, objects, receivers, **kw)}
    out["device"] = sbr.shoot_sbr(geoms["device"], tx, objects, receivers, **kw)
    out["footprints"] = kept[0] if kept else None
    return out


def assert_same_sums(a: sbr.BlockSums, b: sbr.BlockSums, runtime, wavenumber, footprints):
    """Block sums, host ``a`` against device ``b``: with fp64 the same footprints summed in
    another order; without, the no-fp64 contract (tests/mode_helpers.py): the same blocks
    and face sequences, the representative the host's but where its norm ties the
    group's largest within float rounding, its length and point within the float tube
    direction's displacement, the sums within :func:`sbr_row_tolerance` and SBR_SUM_TOL_REL
    of the strongest block's norms."""
    assert len(a) == len(b) > 0
    if runtime.has_double:
        for key in ("receiver", "bounce", "count", "face", "tube", "tri"):
            np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)
        scale = np.abs(a.matrix).max()
        assert np.abs(a.matrix - b.matrix).max() <= 1e-9 * scale
        np.testing.assert_allclose(a.length, b.length, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.weight, b.weight, rtol=1e-9)
        return
    for key in ("receiver", "bounce", "count", "face"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)
    # the host's values of the device's representatives
    length, point, tri = a.length.copy(), a.point.copy(), a.tri.copy()
    tied = np.flatnonzero(a.tube != b.tube)
    assert len(tied) <= 0.01 * len(a), len(tied)
    fp = footprints
    for i in tied:
        group = np.flatnonzero((fp["tube"] // (BLOCK * BLOCK) == a.tube[i] // (BLOCK * BLOCK))
                               & (fp["bounce"] == a.bounce[i])
                               & (fp["receiver"] == a.receiver[i])
                               & np.all(fp["face"] == a.face[i], axis=1))
        j = group[fp["tube"][group] == b.tube[i]]
        assert len(j) == 1, (i, b.tube[i])
        # a tie: the device's norms are float, its largest may be another of equals
        assert fp["norm"][j[0]] >= (1 - FIELD_TOL_REL) * fp["norm"][group].max(), i
        length[i], point[i], tri[i] = fp["L"][j[0]], fp["point"][j[0]], fp["tri"][j[0]]
    np.testing.assert_array_equal(b.tri, tri, err_msg="tri")
    moved = SBR_DIRECTION_TOL_REL * length
    assert (np.abs(b.length - length) <= moved).all(), np.max(np.abs(b.length - length) / length)
    assert (np.abs(b.point - point).max(axis=1) <= moved).all()
    tol = np.minimum(sbr_row_tolerance(a.weight, a.length, wavenumber),
                     SBR_SUM_TOL_REL * a.weight.max())
    assert (np.abs(a.matrix - b.matrix).max(axis=(1, 2)) <= tol).all()
    assert (np.abs(a.weight - b.weight) <= tol).all()


def path_faces(paths, tri_face) -> list[tuple]:
    """Each SBR path's planar face sequence (its representative's triangles' faces)."""
    return [tuple(np.where(t >= 0, tri_face[np.maximum(t, 0)], -1).tolist())
            for t in paths.face_id]


def assert_same_paths(p, q, runtime, *, sums=None, receiver=0, wavenumber=None,
                      tri_face=None, patterns=(1.0, 1.0), min_relative_db=-300.0):
    """SBR paths, host ``p`` against device ``q``: with fp64 the same to rounding; without,
    each path's matrix within the sum of its rows' :func:`sbr_row_tolerance` (host
    ``sums``, rows of ``receiver``) and SBR_SUM_TOL_REL of the strongest path's sum of
    footprint norms, its gain within that times the patterns' peak field
    amplitudes (``patterns``: the peak gains), its delay within the float direction's
    displacement, Doppler within SBR_DOPPLER_TOL_HZ; a path only one engine keeps lies within
    its tolerance of the ``min_relative_db`` threshold."""
    if runtime.has_double:
        assert p.n_paths == q.n_paths > 0
        np.testing.assert_array_equal(p.n_interactions, q.n_interactions)
        np.testing.assert_array_equal(p.face_id, q.face_id)
        assert np.abs(p.gain - q.gain).max() <= 1e-9 * np.abs(p.gain).max()
        np.testing.assert_allclose(p.delay_s, q.delay_s, rtol=0, atol=1e-18)
        np.testing.assert_allclose(p.doppler_hz, q.doppler_hz, rtol=1e-12, atol=1e-9)
        return
    assert p.n_paths > 0 and q.n_paths > 0
    rows = np.flatnonzero(sums.receiver == receiver)
    tol_of: dict[tuple, float] = {}
    weight_of: dict[tuple, float] = {}
    for f, t, w in zip(map(tuple, sums.face[rows].tolist()),
                       sbr_row_tolerance(sums.weight[rows], sums.length[rows], wavenumber),
                       sums.weight[rows], strict=True):
        tol_of[f] = tol_of.get(f, 0.0) + t
        weight_of[f] = weight_of.get(f, 0.0) + w
    strongest = max(weight_of.values())
    tol_of = {f: min(t, SBR_SUM_TOL_REL * strongest) for f, t in tol_of.items()}
    amp = float(np.sqrt(patterns[0] * patterns[1]))
    fp, fq = path_faces(p, tri_face), path_faces(q, tri_face)
    tol_p, tol_q = (np.array([tol_of[f] for f in fs]) for fs in (fp, fq))
    threshold = 10 ** (-abs(min_relative_db) / 20)
    for paths, faces, tol, other in ((p, fp, tol_p, fq), (q, fq, tol_q, fp)):
        top = np.argmax(np.abs(paths.gain))
        for i in (i for i, f in enumerate(faces) if f not in other):
            # kept by one engine only: at the threshold within the two gains' tolerances
            assert (np.abs(paths.gain[i]) - amp * tol[i]
                    <= threshold * (np.abs(paths.gain[top]) + amp * tol[top])), faces[i]
    common = [f for f in fp if f in fq]
    assert len(common) >= 0.99 * max(p.n_paths, q.n_paths)
    i, j = [fp.index(f) for f in common], [fq.index(f) for f in common]
    np.testing.assert_array_equal(p.n_interactions[i], q.n_interactions[j])
    assert (np.abs(p.matrix[i] - q.matrix[j]).max(axis=(1, 2)) <= tol_p[i]).all()
    assert (np.abs(p.gain[i] - q.gain[j]) <= amp * tol_p[i]).all()
    length = p.delay_s[i] * 299_792_458.0
    np.testing.assert_array_less(np.abs(p.delay_s[i] - q.delay_s[j]) * 299_792_458.0,
                                 SBR_DIRECTION_TOL_REL * length)
    np.testing.assert_allclose(p.doppler_hz[i], q.doppler_hz[j], rtol=0,
                               atol=SBR_DOPPLER_TOL_HZ)


def channel(paths, n=1024, df=90.909e3):
    """The channel at the radar's subcarriers, one symbol: H(n) = sum a e^{-j 2 pi n df tau}."""
    k = np.arange(n)[:, None]
    return np.exp(-2j * np.pi * k * df * paths.delay_s[None, :]) @ paths.gain


def nmse_db(h, ref):
    return 10 * np.log10(np.sum(np.abs(h - ref) ** 2) / np.sum(np.abs(ref) ** 2))


# ---------------------------------------------------------------------------
# device == host


@pytest.mark.parametrize("case", ["golden", "dihedral", "trihedral", "dihedral_itu_metal",
                                  "dihedral_itu_glass"])
def test_device_engine_equals_the_host_reference(runtime, case):
    """Also on corners of a finite conductor (itu_metal) and a dielectric (itu_glass),
    whose bounces take the material's Fresnel dyad and whose footprints radiate the
    penetrable currents (docs/po.md; tests/test_po_dielectric.py and
    tests/test_optics_choice.py hold them to closed forms): the two engines agree there
    too."""
    if case == "golden":
        scene = load_scene(DATA)
        objects, tx, receivers = [2], scene.radars[0], list(scene.radars)
        kw = {"spacing_wavelengths": 1.0}
    else:
        material = case.partition("_")[2] or "metal"
        obj = (dihedral(0.12, 0.08, material=material) if case.startswith("dihedral")
               else trihedral(0.1))
        pos = [(3.0, 0.4, 0.3), (2.5, -0.6, 1.0)]
        scene = scene_of([obj], pos)
        objects, tx, receivers = [0], scene.radars[0], list(scene.radars)
        kw = {"spacing_wavelengths": 0.25}
    geoms = both_engines(scene, runtime)
    got = shots(geoms, tx, objects, receivers, max_bounces=3, **kw)
    k = 2 * np.pi / scene.wavelength_m
    assert_same_sums(got["host"].sums, got["device"].sums, runtime, k, got["footprints"])
    for r, rx in enumerate(receivers):
        p = {e: sbr.sbr_paths(geoms[e], tx, rx, objects=objects, max_bounces=3,
                              shot=got[e], min_relative_db=-300) for e in geoms}
        assert_same_paths(p["host"], p["device"], runtime, sums=got["host"].sums,
                          receiver=r, wavenumber=k, tri_face=geoms["host"].faces.tri_face,
                          patterns=(pattern_peak_gain(tx.pattern),
                                    pattern_peak_gain(rx.pattern)))


def test_street_channel_device_against_host(runtime):
    """Radar A's SBR returns on the paper's street (every car, road and facade mirror):
    path for path, and the channel at the radar's 1024 subcarriers within -60 dB."""
    scene = load_scene(STREET)
    a = scene.radar_index("A")
    tx = scene.radars[a]
    cars = [i for i, o in enumerate(scene.objects) if o.name.startswith("car")]
    geoms = both_engines(scene, runtime)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # carA holds the radar: skipped, and said so
        got = shots(geoms, tx, cars, [tx], spacing_wavelengths=1.5, max_bounces=3)
    k = 2 * np.pi / scene.wavelength_m
    assert_same_sums(got["host"].sums, got["device"].sums, runtime, k, got["footprints"])
    p = {e: sbr.sbr_paths(geoms[e], tx, tx, objects=cars, max_bounces=3, shot=got[e])
         for e in geoms}
    peak = pattern_peak_gain(tx.pattern)
    assert_same_paths(p["host"], p["device"], runtime, sums=got["host"].sums, wavenumber=k,
                      tri_face=geoms["host"].faces.tri_face, patterns=(peak, peak),
                      min_relative_db=-80.0)
    assert nmse_db(channel(p["device"]), channel(p["host"])) < -60.0
    # the mirrors are there: returns lit through the road
    road = next(i for i, o in enumerate(scene.objects) if o.name == "road")
    assert np.any(p["device"].object_id[:, 0] == road)


def trihedral_runs(runtime):
    """A small trihedral's tubes: run(batch_tubes) -> records, and the whole batch's."""
    scene = scene_of([trihedral(0.1)], [(2.0, 1.5, 1.0)])
    geom = build_geometry(scene, runtime)
    r = scene.radars[0]
    windows = sbr.launch_windows(geom, r.position, [0], 0.05 * LAM)
    assert windows.n_tubes > 4 * 4096

    def run(batch):
        return device_sbr.shoot_and_radiate(
            geom.caster, scene, geom.faces.tri_face, windows, r.orientation, [r.position],
            [r.orientation], wavenumber=2 * np.pi / LAM, wavelength=LAM, max_bounces=3,
            first_bounce=2, record_triangles=np.ones(len(scene.triangles), bool),
            batch_tubes=batch)

    return run, run(device_sbr.BATCH_TUBES)


def launched_kernels(runtime, monkeypatch) -> list:
    """The names of the kernels ``runtime`` launches from now on (the list fills)."""
    names = []
    orig = type(runtime).launch

    def launch(self, kernel, *args, name=None, **kw):
        names.append(name)
        return orig(self, kernel, *args, name=name, **kw)

    monkeypatch.setattr(type(runtime), "launch", launch)
    return names


def test_batches_and_runs_give_the_same_records(runtime):
    run, whole = trihedral_runs(runtime)
    assert len(whole) > 0
    assert whole.tobytes() == run(4096).tobytes() == run(device_sbr.BATCH_TUBES).tobytes()


def test_bounces_in_one_launch_give_the_wavefront_records(runtime, monkeypatch):
    """sbr_bounces (a launch block's tubes and all their bounces in one work item, cast in
    packets, for scalar CPU devices) and the wavefront (a launch into a queue, then one
    launch per bounce, the live tubes compacted between) give the same records, bit for bit,
    whichever the device would take by itself; each mode is the one that runs (checked by
    the kernels launched). Where the device takes sbr_bounces by itself (PoCL) the records
    are the same bit for bit; a device forced into it computes a footprint's illumination in
    sbr_radiate rather than sbr_illuminate, and Intel's compiler rounds the same formulas in
    the two kernels a last bit apart (about 3e-16 of the largest matrix): there the faces,
    tubes, counts, points and lengths are the same and the sums within 1e-13."""
    run, _ = trihedral_runs(runtime)
    native = device_sbr.persistent_bounces(runtime)
    names = launched_kernels(runtime, monkeypatch)
    records = {}
    for mode in ((runtime.info.vendor,), ()):
        monkeypatch.setattr(device_sbr, "PERSISTENT_BOUNCE_VENDORS", mode)
        names.clear()
        persistent = device_sbr.persistent_bounces(runtime)
        records[persistent] = run(4096)
        assert ("sbr_bounces (sbr.cl)" in names) == persistent
        assert ("sbr_bounce (sbr.cl)" in names) == (not persistent)
        assert ("sbr_launch (sbr.cl)" in names) == (not persistent)
    if runtime.info.device_type == "CPU":
        assert set(records) == {True, False}
        persistent, wavefront = records[True], records[False]
        assert len(persistent) > 0
        if native:
            assert persistent.tobytes() == wavefront.tobytes()
        rounded = ("M", "weight", "weighted_length", "rep_weight")
        for name in persistent.dtype.names:
            if name in rounded:
                scale = np.abs(wavefront[name]).max()
                np.testing.assert_allclose(persistent[name], wavefront[name], rtol=0,
                                           atol=1e-13 * scale, err_msg=name)
            else:
                np.testing.assert_array_equal(persistent[name], wavefront[name],
                                              err_msg=name)


def test_last_bounce_test_leaves_the_records_as_the_full_cast_makes_them(runtime,
                                                                        monkeypatch):
    """sbr_bounces skips a tube's last cast where its ray meets no recorded triangle in
    their own tree (device_sbr.recorded_tree): the records are the full cast's, bit for
    bit, last-bounce footprints among them. A trihedral with two of its three plates
    recorded: third bounces off the unrecorded plate, and those that leave the corner,
    meet no recorded triangle; every device runs the one-launch bounces here."""
    scene = scene_of([trihedral(0.1)], [(2.0, 1.5, 1.0)])
    geom = build_geometry(scene, runtime)
    r = scene.radars[0]
    windows = sbr.launch_windows(geom, r.position, [0], 0.05 * LAM)
    record = np.zeros(len(scene.triangles), bool)
    record[len(record) // 3:] = True
    monkeypatch.setattr(device_sbr, "PERSISTENT_BOUNCE_VENDORS", (runtime.info.vendor,))

    def run():
        return device_sbr.shoot_and_radiate(
            geom.caster, scene, geom.faces.tri_face, windows, r.orientation, [r.position],
            [r.orientation], wavenumber=2 * np.pi / LAM, wavelength=LAM, max_bounces=3,
            first_bounce=2, record_triangles=record)

    tree = device_sbr.recorded_tree(geom.caster, record)
    assert tree is not None and len(tree.triangles) == record.sum()
    assert device_sbr.recorded_tree(geom.caster, record) is tree   # kept per caster, mask
    tested = run()
    monkeypatch.setattr(device_sbr, "recorded_tree", lambda caster, record_triangles: None)
    full = run()
    assert (full["bounce"] == 3).sum() > 0 and (full["bounce"] == 2).sum() > 0
    assert tested.tobytes() == full.tobytes()


def test_recorded_tree_only_for_a_single_level_caster(runtime):
    """No last-bounce tree where it could round apart from the scene's (a two-level
    caster) or where nothing is recorded."""
    scene = scene_of([trihedral(0.1)], [(2.0, 1.5, 1.0)])
    caster = build_geometry(scene, runtime).caster
    assert device_sbr.recorded_tree(caster, np.zeros(len(scene.triangles), bool)) is None
    instanced = InstancedCaster([(scene.triangles, np.arange(len(scene.triangles)))],
                                runtime=runtime)
    assert device_sbr.recorded_tree(instanced, np.ones(len(scene.triangles), bool)) is None


def test_records_beyond_the_buffer_reduce_the_bounce_again(runtime, monkeypatch):
    run, whole = trihedral_runs(runtime)
    names = launched_kernels(runtime, monkeypatch)
    run(device_sbr.BATCH_TUBES)
    roomy = names.count("sbr_reduce (sbr.cl)")
    # a buffer of 16 records at first: a bounce overflows it, grows it and is reduced
    # again; nothing else runs again
    monkeypatch.setattr(device_sbr, "MAX_START_RECORDS", 16)
    monkeypatch.setattr(device_sbr, "RECORDS_PER_BLOCK_RX", 0)
    names.clear()
    assert len(whole) > 16 * 4
    assert run(device_sbr.BATCH_TUBES).tobytes() == whole.tobytes()
    assert names.count("sbr_reduce (sbr.cl)") == roomy + 1   # one overflow, one rerun
    assert run(4096).tobytes() == whole.tobytes()


# ---------------------------------------------------------------------------
# launch windows


def test_window_covers_the_silhouette_and_little_else(runtime):
    """Every direction toward a point of the box's visible faces lies in a launched cell of
    its window, and the window's area is the silhouette's, grown by at most a block."""
    box = {"name": "box", "material": "metal", "shape": "box", "extents": [2.0, 1.0, 0.5],
           "position": [0.0, 0.0, 0.0], "rotation_deg": [10.0, 20.0, 30.0]}
    tx = np.array([12.0, 3.0, 2.0])
    scene = scene_from_dict({"scene": {"name": "w", "carrier_hz": 24e9}, "objects": [box],
                             "radars": [{"name": "r", "position": tx.tolist()}]})
    geom = build_geometry(scene, runtime)
    s = 0.02
    w = sbr.launch_windows(geom, tx, [0], s, mirrors=False)
    assert w.n_windows == 1 and w.mirror_face[0] == -1
    rng = np.random.default_rng(1)
    tri = scene.triangles
    pick = rng.integers(0, len(tri), 20_000)
    uv = rng.random((len(pick), 2))
    uv = np.where(uv.sum(1, keepdims=True) > 1, 1 - uv, uv)
    pts = tri[pick, 0] + uv[:, :1] * (tri[pick, 1] - tri[pick, 0]) + uv[:, 1:] * (
        tri[pick, 2] - tri[pick, 0])
    d = pts - tx
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    assert np.all(sbr._covers(w, 0, d))
    # the box's silhouette area on the window plane, by rasterising finely
    from clradcom.geometry.silhouette import project_to_plane
    x, y, _ = project_to_plane(tri, tx, w.axis[0], w.u[0], w.v[0], w.distance[0])
    xy = np.stack([x, y], axis=-1)
    fine = 0.002
    lo = xy.reshape(-1, 2).min(0)
    shape = np.ceil((xy.reshape(-1, 2).max(0) - lo) / fine).astype(int) + 1
    silhouette = block_coverage(xy, fine, lo, shape).sum() * fine**2
    launched = w.n_tubes * s * s
    assert silhouette < launched < silhouette * 1.35


def test_mirror_windows_reach_the_object_through_the_road(runtime):
    """A PEC box on a road: with mirrors, tubes aimed at the box's image under the road
    hit the road first and then the box; without, no SBR path starts on the road."""
    road = {"name": "road", "material": "concrete_road", "shape": "plane",
            "size": [60.0, 20.0], "position": [10.0, 0.0, 0.0]}
    car = {"name": "car", "material": "metal", "shape": "box", "extents": [3.8, 1.8, 1.5],
           "position": [15.0, 0.5, 0.75], "rotation_deg": [0.0, 0.0, 20.0]}
    scene = scene_from_dict({"scene": {"name": "m", "carrier_hz": 24e9},
                             "objects": [road, car],
                             "radars": [{"name": "r", "position": [0.0, 0.0, 0.6]}]})
    geom = build_geometry(scene, runtime)
    r = scene.radars[0]
    with_m = sbr.shoot_sbr(geom, r, [1], [r], spacing_wavelengths=2.0, max_bounces=3)
    without = sbr.shoot_sbr(geom, r, [1], [r], spacing_wavelengths=2.0, max_bounces=3,
                            mirrors=False)
    assert set(with_m.windows.mirror_face.tolist()) > {-1}
    assert np.all(without.windows.mirror_face == -1)
    p = sbr.sbr_paths(geom, r, r, objects=[1], max_bounces=3, shot=with_m)
    q = sbr.sbr_paths(geom, r, r, objects=[1], max_bounces=3, shot=without)
    # the car's own window brushes the road beside it; its mirror window brings the rest
    road_first = [np.abs(x.gain[x.object_id[:, 0] == 0]).sum() for x in (p, q)]
    assert road_first[0] > 2 * road_first[1]
    # a road-then-car path is longer than the direct distance to the car's near side
    first = p.object_id[:, 0] == 0
    assert np.all(p.delay_s[first] * 299_792_458.0 > 2 * 12.0)


# ---------------------------------------------------------------------------
# no cap, and the materials along the chain


def test_a_10_m_plate_needs_no_tube_cap(runtime):
    """The old launch (bounding sphere, 4 M tubes at most) refused a 10 m plate at
    lambda/2; the silhouette launch streams its 2.6 M tubes in batches."""
    plate = {"name": "plate", "material": "metal", "shape": "plane", "size": [10.0, 10.0],
             "position": [0.0, 0.0, 0.0], "rotation_deg": [0.0, 90.0, 0.0]}
    scene = scene_from_dict({"scene": {"name": "p", "carrier_hz": 24e9}, "objects": [plate],
                             "radars": [{"name": "r", "position": [60.0, 0.0, 0.0]}]})
    geom = build_geometry(scene, runtime)
    r = scene.radars[0]
    shot = sbr.shoot_sbr(geom, r, [0], [r], spacing_wavelengths=0.5, max_bounces=2)
    assert shot.windows.n_tubes > 2 * device_sbr.BATCH_TUBES
    assert 2.5e6 < shot.windows.n_tubes < 2.9e6
    assert len(shot.sums) == 0  # a flat plate has no second bounce


def test_chain_carries_the_specular_share_of_a_scattering_face(runtime):
    """A dihedral whose faces scatter S = 0.6 of the field diffusely: its double bounce
    is sqrt(1 - S^2)^2 = 0.64 of the same smooth material's (the first face's dyad in the
    chain, the second face's in its penetrable currents), on both engines."""
    from test_po_dielectric import CONCRETE

    out = {}
    for s_coef in (0.0, 0.6):
        mat = {"name": "rough", "eps_r": [CONCRETE.real, CONCRETE.imag],
               "scattering_coefficient": s_coef}
        obj = dihedral(0.12, 0.08)
        obj["material"] = "rough"
        # without fp64 just off the dihedral's plane of symmetry (tests/mode_helpers.py)
        at = off_symmetry([100.0, 0.0, 0.0], runtime).tolist()
        scene = scene_from_dict({"scene": {"name": "s", "carrier_hz": 24e9},
                                 "materials": [mat], "objects": [obj],
                                 "radars": [{"name": "r", "position": at}]})
        for engine in ("host", "device"):
            geom = build_geometry(scene, runtime, engine=engine)
            r = scene.radars[0]
            p = sbr.sbr_paths(geom, r, r, objects=[0], spacing_wavelengths=0.25,
                              max_bounces=2, min_relative_db=-300)
            out[s_coef, engine] = p.matrix.sum(axis=0)
    for engine in ("host", "device"):
        ratio = np.diag(out[0.6, engine]) / np.diag(out[0.0, engine])
        # exactly 1 - S^2 at the specular direction, where the second face's currents
        # are linear in its dyad; the tubes fan out by a milliradian around it
        np.testing.assert_allclose(ratio, 1 - 0.6**2, rtol=1e-3)
    if runtime.has_double:
        # the cross-polar terms are rounding (1e-20 of the co-polar ones), held to that
        np.testing.assert_allclose(out[0.6, "device"], out[0.6, "host"], rtol=1e-9,
                                   atol=1e-15 * np.abs(out[0.6, "host"]).max())
    else:   # float fields
        np.testing.assert_allclose(out[0.6, "device"], out[0.6, "host"], rtol=0,
                                   atol=FIELD_TOL_REL * np.abs(out[0.6, "host"]).max())


# ---------------------------------------------------------------------------
# the pitch rule


@pytest.mark.parametrize("accuracy_db", [0.5, 1.5])
@pytest.mark.parametrize("corner", ["dihedral", "trihedral"])
def test_pitch_rule_meets_its_accuracy_on_the_closed_forms(runtime, corner, accuracy_db):
    """At the pitch sbr.spacing_for_accuracy chooses, the corner's monostatic RCS (PO
    facets + SBR) lies within accuracy_db of the closed form (Knott, table 6.1)."""
    if corner == "dihedral":
        a, b, R = 0.2, 0.15, 200.0
        scene = scene_of([dihedral(a, b)], [(R, 0.0, 0.0)])
        want = 8 * np.pi * a**2 * b**2 / LAM**2
    else:
        a, R = 0.15, 200.0
        scene = scene_of([trihedral(a)], [R * np.ones(3) / np.sqrt(3)])
        want = 12 * np.pi * a**4 / LAM**2
    geom = build_geometry(scene, runtime)
    s = sbr.spacing_for_accuracy(geom, [0], accuracy_db)[0]
    feature = sbr.feature_size_m(geom, [0])[0]
    assert s == pytest.approx(max(accuracy_db * feature / sbr.ERROR_DB_PER_PITCH,
                                  sbr.MIN_SPACING_WAVELENGTHS * LAM))
    r = scene.radars[0]
    p1 = po_paths(geom, r, r, min_relative_db=-300)
    p2 = sbr.sbr_paths(geom, r, r, objects=[0], accuracy_db=accuracy_db, max_bounces=3,
                       min_relative_db=-300)
    M = p1.matrix.sum(axis=0) + p2.matrix.sum(axis=0)
    for pol in (0, 1):
        assert abs(10 * np.log10(sigma(M[pol, pol], R) / want)) < accuracy_db


def test_pitch_precedence_object_key_then_setting_then_rule(runtime):
    obj = trihedral(0.1)
    obj["sbr_spacing_wavelengths"] = 0.75
    scene = scene_of([obj, {**dihedral(0.1, 0.1), "name": "d"}], [(3.0, 2.0, 1.0)])
    geom = build_geometry(scene, runtime)
    lam = scene.wavelength_m
    np.testing.assert_allclose(sbr.object_spacing_m(geom, [0, 1], None, 0.5),
                               [0.75 * lam, sbr.spacing_for_accuracy(geom, [1], 0.5)[0]])
    np.testing.assert_allclose(sbr.object_spacing_m(geom, [0, 1], 2.0), [0.75 * lam, 2 * lam])
    with pytest.raises(ValueError, match="OpticsSettings.sbr_accuracy_db"):
        OpticsSettings(sbr_accuracy_db=0.1)
    with pytest.raises(TypeError, match="OpticsSettings.sbr_mirrors"):
        OpticsSettings(sbr_mirrors="yes")


def test_block_coverage_is_conservative():
    """A thin sliver and a big triangle: every block a triangle touches is marked, none
    that it misses by more than a block."""
    rng = np.random.default_rng(7)
    for _ in range(20):
        tri = rng.uniform(-3, 3, (1, 3, 2))
        mask = block_coverage(tri, 0.25, (-4.0, -4.0), (32, 32))
        # points inside the triangle
        uv = rng.random((4000, 2))
        uv = np.where(uv.sum(1, keepdims=True) > 1, 1 - uv, uv)
        t = tri[0]
        p = t[0] + uv[:, :1] * (t[1] - t[0]) + uv[:, 1:] * (t[2] - t[0])
        ij = np.floor((p + 4.0) / 0.25).astype(int)
        assert np.all(mask[ij[:, 0], ij[:, 1]])
        # a marked block's centre lies within a block diagonal of the triangle
        centres = (np.argwhere(mask) + 0.5) * 0.25 - 4.0
        from clradcom.geometry.triangles import point_triangle_distance
        t3 = np.concatenate([t, np.zeros((3, 1))], axis=1)[None]
        far = [point_triangle_distance(np.append(c, 0.0), t3)[0] for c in centres]
        assert max(far) <= 0.25 * np.sqrt(2) / 2 + 1e-12
    assert BLOCK == 8


def test_an_object_around_the_radar_is_split_not_skipped(runtime):
    """A 60 m rail beside the radar: no single window plane can hold it (the radar lies
    inside its bounding sphere), so it is split into groups that each can, and its
    corner returns come back; the old launch skipped it with a warning."""
    scene = load_scene("scenes/guardrail/guardrail.toml")
    geom = build_geometry(scene, runtime)
    r = scene.radars[0]
    rail = [i for i, o in enumerate(scene.objects) if scene.material_pec[o.material]]
    c, rad = sbr.bounding_sphere(scene.triangles[np.isin(scene.tri_object, rail)])
    assert np.linalg.norm(c - r.position) < rad
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing dropped, nothing skipped
        w = sbr.launch_windows(geom, r.position, rail, 0.5 * scene.wavelength_m)
    assert w.n_windows > len(rail) and w.n_tubes > 0
    p = sbr.sbr_paths(geom, r, r, objects=rail, spacing_wavelengths=2.0, max_bounces=2)
    assert p.n_paths > 0 and set(p.n_interactions.tolist()) == {2}


def test_blocks_outside_the_antenna_pattern_are_not_launched(runtime):
    """The street's radar A (a 90 deg sector on its own bumper): tubes toward its own car
    and behind it would radiate nothing, so their blocks are dropped before launch."""
    scene = load_scene(STREET)
    geom = build_geometry(scene, runtime)
    tx = scene.radars[scene.radar_index("A")]
    cars = [i for i, o in enumerate(scene.objects) if o.name.startswith("car")]
    with pytest.warns(UserWarning, match="carA"):
        w = sbr.launch_windows(geom, tx.position, cars, 2 * scene.wavelength_m)
    kept = sbr.blocks_in_pattern(w, tx)
    assert 0 < kept.n_tubes < 0.6 * w.n_tubes
    grid, _ = sbr.window_tubes(kept, np.arange(0, kept.n_tubes, 7))
    centre = sbr.window_tubes(w, np.arange(0, w.n_tubes, 7))[0]
    gain = lambda d: np.asarray(tx.pattern.gain(d @ np.asarray(tx.orientation)))  # noqa: E731
    # every dropped tube was outside the pattern; most kept ones are inside
    assert np.mean(gain(grid.directions) > 0) > 0.95
    assert np.sum(gain(centre.directions) > 0) <= len(grid.directions) * 1.01 + 64


def test_utd_leaves_the_edges_of_po_objects_to_po(runtime):
    """A 1 m PEC plate at broadside: with physical optics its RCS is 4 pi A^2/lambda^2
    from the facet integrals alone; UTD at its rim on top would add the edge field a second
    time (po_object_edges=True shows it)."""
    from clradcom.trace import DiffractionSettings, OpticsSettings, TraceSettings, trace_scene

    plate = {"name": "plate", "material": "metal", "shape": "plane", "size": [1.0, 1.0],
             "position": [0.0, 0.0, 0.0], "rotation_deg": [0.0, 90.0, 0.0]}
    R = 3000.0
    scene = scene_from_dict({"scene": {"name": "p", "carrier_hz": 24e9}, "objects": [plate],
                             "radars": [{"name": "r", "position": [R, 0.0, 0.0]}]})
    want = 4 * np.pi * 1.0 / LAM**2
    out = {}
    for edges in (False, True):
        settings = TraceSettings(optics=OpticsSettings(mode="pec"),
                                 diffraction=DiffractionSettings(po_object_edges=edges))
        snap = trace_scene(scene, settings.replace(specular__rays=2000), runtime=runtime)
        out[edges] = 10 * np.log10(sigma(snap.links[0].paths.gain.sum(), R) / want)
    assert abs(out[False]) < 0.1
    assert out[True] > 3.0


# ---------------------------------------------------------------------------
# precision: devices without fp64


def test_record_layout_matches_the_device_in_both_precisions(runtime):
    # a device without fp64 (or the forced no-fp64 mode) builds the double-float layout only
    precisions = ("fp64", "double-float") if runtime.info.has_double else ("double-float",)
    for precision in precisions:
        for bounces in (2, 3, 5):
            assert (device_sbr.record_size(runtime, bounces, precision)
                    == device_sbr.record_dtype(bounces, precision).itemsize)


@pytest.mark.parametrize("carrier", [24e9, 77e9])
def test_double_float_engine_keeps_phases_1_km_from_the_origin(runtime, carrier):
    """Without fp64 the engine carries hit points and lengths in double-float pairs
    (kernels/precise.h) and the fields in float: a dihedral 1 km from the origin, seen
    from 30 m, keeps each SBR path's phase within 1 degree of the float64 host reference
    at 24 and 77 GHz (one degree is 11 um of path at 77 GHz; float32 alone resolves 61 um
    there), and its magnitude within 0.01 dB. The plain-float control misses."""
    # coordinates no float32 holds exactly (round ones would hide its rounding)
    far = np.array([1000.1234567, 999.9876543, 0.0123457])
    obj = dihedral(0.3, 0.2)
    obj["position"] = far.tolist()
    scene = scene_of([obj], [far + (30.0437171, 1.0311113, 0.5123457)], carrier=carrier)
    lam = 299_792_458.0 / carrier
    r = scene.radars[0]
    paths = {}
    for engine, precision in (("host", "auto"), ("device", "double-float")):
        geom = build_geometry(scene, runtime, engine=engine)
        shot = sbr.shoot_sbr(geom, r, [0], [r], spacing_wavelengths=2.0, max_bounces=2,
                             precision=precision)
        paths[engine] = sbr.sbr_paths(geom, r, r, objects=[0], max_bounces=2, shot=shot,
                                      min_relative_db=-300)
    h, d = paths["host"], paths["device"]
    assert h.n_paths == d.n_paths > 0
    np.testing.assert_array_equal(h.face_id, d.face_id)
    strong = np.abs(h.gain) > 1e-3 * np.abs(h.gain).max()
    dphi = np.degrees(np.angle(d.gain[strong] / h.gain[strong]))
    assert np.abs(dphi).max() < 1.0, dphi
    assert np.abs(20 * np.log10(np.abs(d.gain[strong] / h.gain[strong]))).max() < 0.01
    # the delay comes from a representative footprint: within a footprint of the host's
    assert np.abs(d.delay_s - h.delay_s).max() * 299_792_458.0 < 2.0 * 2.0 * lam
    if carrier > 50e9:
        # the control: the same kernel with plain float32 positions and lengths
        geom = build_geometry(scene, runtime, engine="device")
        shot = sbr.shoot_sbr(geom, r, [0], [r], spacing_wavelengths=2.0, max_bounces=2,
                             precision=device_sbr.CONTROL_PRECISION)
        c = sbr.sbr_paths(geom, r, r, objects=[0], max_bounces=2, shot=shot,
                          min_relative_db=-300)
        assert c.n_paths == h.n_paths
        bad = np.degrees(np.angle(c.gain[strong] / h.gain[strong]))
        assert np.abs(bad).max() > 1.0, bad


def test_tube_sight_past_a_rim_is_decided_in_float64_on_both_engines(runtime):
    """A tube hit whose sight line to the receiver passes a screen's rim by less than
    float32 resolution, 1 km from the origin: where the float32 cast calls it blocked,
    the SBR kernel re-decides it in float64 as the host's surface_sees does (the line
    passes above the rim: seen), and the two engines' block sums stay equal."""
    from test_po_sbr import quad, tri_object

    from clradcom.device.raycast import make_rays, spawn_origins
    from clradcom.device.visibility import SIGHT_STOP, surface_sees

    base = np.array([1000.0, 1000.0, 1000.0])
    X, Y, Z = np.eye(3)
    plate = tri_object("plate", [quad(base - 0.1 * Y - 0.1 * Z, 0.2 * Y, 0.2 * Z, 1, 1, X)])
    tx_pos, rx_pos = base + 5.0 * X, base + 5.0 * X + 5.0 * Y + 2.0 * Z
    radars = [tx_pos, rx_pos]
    scene = scene_of([plate], radars)
    geom = build_geometry(scene, runtime, engine="host")
    tx = scene.radars[0]
    windows = sbr.blocks_in_pattern(sbr.launch_windows(
        geom, tx.position, [0], sbr.object_spacing_m(geom, [0], 0.5, 0.5)), tx)
    grid, owned = sbr.window_tubes(windows, np.arange(windows.n_tubes))
    hits = sbr.shoot_tubes(geom, tx.position, grid, 1, 1, np.ones(2, bool))
    rescued = 0
    for k in np.linspace(0, len(hits.point) - 1, 4).astype(int):
        p0 = hits.point[k]
        org = spawn_origins(p0[None], X[None], (rx_pos - p0)[None])[0]
        seg = rx_pos - org
        mid = org + 0.5 * seg
        across = np.cross(seg, Z)
        across /= np.linalg.norm(across)
        for delta in (1e-7, 1e-6, 3e-6):
            # a screen across the sight line at its middle, its top rim delta below it
            top = mid - delta * Z
            screen = tri_object("screen", [quad(top - 0.3 * across - 0.3 * Z, 0.6 * across,
                                                0.3 * Z, 1, 1, seg)])
            sc = scene_of([plate, screen], radars)
            geoms = both_engines(sc, runtime)
            got = shots(geoms, sc.radars[0], [0], [sc.radars[1]], spacing_wavelengths=0.5,
                        max_bounces=1, first_bounce=1)
            assert_same_sums(got["host"].sums, got["device"].sums, runtime,
                             2 * np.pi / LAM, got["footprints"])
            caster = geoms["host"].caster
            ray = make_rays(org[None], seg[None], 0.0, 1.0 - SIGHT_STOP)
            blocked32 = caster.occluded(ray, ignore_prim=np.array([hits.triangle[k]]))[0]
            seen = surface_sees(caster, p0[None], X[None], rx_pos,
                                np.array([hits.triangle[k]]), leave_direction=seg[None],
                                tri_face=geoms["host"].faces.tri_face, engine="host")[0]
            assert seen   # the float64 line passes above the rim
            rescued += bool(blocked32)
    assert rescued > 0   # some of these lines the float32 cast alone would have blocked
