"""Micro-Doppler of rolling wheels (issue 18, item 5): the wheeled car scene
(scenes/microdoppler/car_wheels.toml, tools/make_microdoppler.py), the Doppler of every
return from a wheel against the closed form of a point on a rotating body, the interval
the wheels can give, and the per-frame spectrogram (clradcom.radar.microdoppler).

The closed forms here are computed from the scene file's numbers as written (read with
tomllib, not through the scene reader): a point p of an object with translation v,
angular velocity omega about the centre c moves at v + omega x (p - c), and a path
p_0 .. p_{n+1} has the Doppler -(1/lambda) sum_j u_j . (v_{j+1} - v_j),
u_j = (p_{j+1} - p_j)/|p_{j+1} - p_j| (DESIGN: f_D = -(1/lambda) dL/dt).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
import trimesh

from clradcom import cli
from clradcom.errors import ArgumentError
from clradcom.physics.em import C0
from clradcom.radar.microdoppler import (
    RotatingPart,
    doppler_interval,
    doppler_spectrum,
    microdoppler_run,
    path_spread,
    rotating_parts,
    save_microdoppler,
    spread_edges,
)
from clradcom.radar.synthesis import channel_transfer_function
from clradcom.radar.waveform import Waveform
from clradcom.scene.motion import scene_at
from clradcom.scene.reader import load_scene, scene_from_dict
from clradcom.scene.wheeled_car import WheeledCar, microdoppler_toml, wheel_mesh
from clradcom.series import match_paths
from clradcom.trace import TraceSettings, trace_scene

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "scenes" / "microdoppler" / "car_wheels.toml"
DOC = tomllib.loads(SCENE.read_text(encoding="utf-8"))
LAM = C0 / DOC["scene"]["carrier_hz"]
WHEELS = [o for o in DOC["objects"] if "angular_velocity_deg_s" in o]
V_CAR = np.array(next(o for o in DOC["objects"] if o["name"] == "car")["velocity"])
R = WheeledCar().wheel_radius
#: the wheels' returns come from PO facets (optics = "both"), whatever the rays
GO_FAST = TraceSettings.preset("go").replace(specular__rays=100_000)


def closed_form_velocity(obj: dict, points) -> np.ndarray:
    """v + omega x (p - c) from an object's entry in the scene file."""
    v = np.array(obj.get("velocity", [0.0, 0.0, 0.0]))
    if "angular_velocity_deg_s" not in obj:
        return np.broadcast_to(v, np.shape(points)).copy()
    w = np.radians(obj["angular_velocity_deg_s"])
    return v + np.cross(w, np.asarray(points) - np.array(obj["rotation_centre"]))


def closed_form_doppler(doc: dict, paths) -> np.ndarray:
    """Every path's -(1/lambda) dL/dt from its polyline and the closed-form velocities
    of its interaction points (the radar at rest)."""
    out = np.empty(len(paths.gain))
    for i in range(len(paths.gain)):
        n = int(paths.n_interactions[i])
        pts = paths.points[i, :n + 2]
        vel = np.zeros_like(pts)
        for j in range(n):
            vel[j + 1] = closed_form_velocity(doc["objects"][paths.object_id[i, j]], pts[j + 1])
        seg = np.diff(pts, axis=0)
        u = seg / np.linalg.norm(seg, axis=1, keepdims=True)
        out[i] = -np.sum(u * np.diff(vel, axis=0)) / LAM
    return out


def wheel_path_mask(scene, paths) -> np.ndarray:
    ids = [p.object_id for p in rotating_parts(scene)]
    k = np.arange(paths.object_id.shape[1])[None, :]
    return np.any((k < paths.n_interactions[:, None]) & np.isin(paths.object_id, ids), axis=1)


@pytest.fixture(scope="module")
def scene():
    return load_scene(SCENE)


def test_scene_file_is_what_the_tool_writes():
    assert SCENE.read_text(encoding="utf-8") == microdoppler_toml(WheeledCar())
    verts, faces = wheel_mesh(WheeledCar())
    mesh = trimesh.Trimesh(verts, faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    # the closed cylinder's volume, less the 48-gon's shortfall
    n = WheeledCar().sections
    area = 0.5 * n * R**2 * np.sin(2 * np.pi / n)
    assert mesh.volume == pytest.approx(area * WheeledCar().wheel_width, rel=1e-12)


def test_wheels_load_as_rolling_parts(scene):
    parts = rotating_parts(scene)
    assert [p.name for p in parts] == [o["name"] for o in WHEELS] and len(parts) == 4
    speed = np.linalg.norm(V_CAR)
    for part in parts:
        assert part.radius == pytest.approx(R, rel=1e-7)  # PLY vertices are float32
        np.testing.assert_array_equal(part.velocity, V_CAR)
        assert part.centre[2] == pytest.approx(R)
        # rolling without slip: |omega| r = |v|, the axle across the motion
        assert np.linalg.norm(part.omega) * part.radius == pytest.approx(speed, rel=1e-7)
        assert abs(part.omega @ V_CAR) < 1e-9


def test_every_wheel_point_moves_as_the_closed_form(scene):
    speed = np.linalg.norm(V_CAR)
    for obj in WHEELS:
        i = scene.object_index(obj["name"])
        pts = scene.triangles[scene.objects[i].tri_slice].reshape(-1, 3)
        got = scene.point_velocity(np.full(len(pts), i), pts)
        np.testing.assert_allclose(got, closed_form_velocity(obj, pts), rtol=0, atol=1e-12)
        # the contact point (lowest vertex, on the road) at rest, the top at 2 v
        low, top = np.argmin(pts[:, 2]), np.argmax(pts[:, 2])
        # (the PLY's float32 vertices put it within 1e-7 m of the road)
        assert pts[low, 2] == pytest.approx(0.0, abs=1e-7)
        assert np.linalg.norm(got[low]) < 1e-6 * speed
        np.testing.assert_allclose(got[top], 2 * V_CAR, atol=1e-6 * speed)
        # speeds grow with the distance from the contact line along the axle:
        # |v_p| = |omega| |p - p0| across the axle
        w = np.linalg.norm(np.radians(obj["angular_velocity_deg_s"]))
        contact = np.array(obj["rotation_centre"]) - [0.0, 0.0, R]
        np.testing.assert_allclose(np.linalg.norm(got, axis=1), w * np.linalg.norm(
            (pts - contact) * [1, 0, 1], axis=1), atol=1e-6)


def test_doppler_interval_against_brute_force_over_the_disc():
    """The interval's ends are the extremes over a densely sampled disc (and never
    exceeded), for a line of sight with a component along the axle."""
    c = np.array([10.0, 2.0, 0.3])
    v = np.array([-8.0, 0.0, 0.0])
    omega = np.cross([0, 0, 1.0], v) / 0.3
    part = RotatingPart(0, "w", c, v, omega, 0.3)
    s = np.array([0.0, -1.0, 1.2])
    lo, hi = doppler_interval(part, s, np.zeros(3), 24e9)
    rr, aa = np.meshgrid(np.linspace(0, 0.3, 61), np.linspace(0, 2 * np.pi, 721))
    pts = c + np.stack([rr * np.cos(aa), 0 * rr, rr * np.sin(aa)], -1).reshape(-1, 3)
    u = s - c
    u = u / np.linalg.norm(u)  # far field: one line of sight for the whole disc
    fd = 2 / LAM * (v + np.cross(omega, pts - c)) @ u
    span = hi - lo
    assert fd.min() >= lo - 1e-9 * span and fd.max() <= hi + 1e-9 * span
    assert fd.min() == pytest.approx(lo, abs=1e-4 * span)
    assert fd.max() == pytest.approx(hi, abs=1e-4 * span)
    # per point, with each point's own line of sight, the interval still holds
    plo, phi = doppler_interval(part, s, np.zeros(3), 24e9, points=pts)
    u_p = (s - pts) / np.linalg.norm(s - pts, axis=1, keepdims=True)
    fd_p = 2 / LAM * np.sum((v + np.cross(omega, pts - c)) * u_p, axis=1)
    assert np.all(fd_p >= plo - 1e-9) and np.all(fd_p <= phi + 1e-9)


def test_wheel_returns_span_the_interval_and_follow_the_closed_form(scene, runtime):
    """One instant, the PO facets (optics = "both") of the wheels: every path's Doppler is
    that of its own interaction point, closed form and central differences of scene_at;
    together they span the interval (2/lambda)(u.v -/+ omega r |u_perp|) and never leave
    it."""
    snap = trace_scene(scene, GO_FAST, runtime, links=[(0, 0)])
    p = snap.links[0].paths
    on_wheel = wheel_path_mask(scene, p)
    assert on_wheel.sum() > 500
    np.testing.assert_allclose(p.doppler_hz, closed_form_doppler(DOC, p), rtol=1e-10,
                               atol=1e-6)
    # the single-bounce facet returns against -(1/lambda) dL/dt of the facet centroids as
    # scene_at turns and moves the triangles (independent of point_velocity)
    one = np.flatnonzero(on_wheel & (p.n_interactions == 1))
    tri = p.face_id[one, 0]
    np.testing.assert_allclose(p.points[one, 1], scene.triangles[tri].mean(axis=1),
                               atol=1e-12)
    s = scene.radars[0].position
    dt = 1e-6
    lengths = [2 * np.linalg.norm(s - scene_at(scene, t).triangles[tri].mean(axis=1), axis=1)
               for t in (-dt, dt)]
    fd = -(lengths[1] - lengths[0]) / (2 * dt) / LAM
    np.testing.assert_allclose(p.doppler_hz[one], fd, rtol=1e-6, atol=1e-2)
    # never outside the interval of the point's own line of sight
    by_obj = {part.object_id: part for part in rotating_parts(scene)}
    for i in one:
        lo, hi = doppler_interval(by_obj[p.object_id[i, 0]], s, np.zeros(3),
                                  scene.carrier_hz, points=p.points[i, 1][None])
        assert lo[0] - 1e-6 <= p.doppler_hz[i] <= hi[0] + 1e-6
    # and the near wheels' returns reach both ends of the hub's line-of-sight interval
    speed = np.linalg.norm(V_CAR)
    for name in ("wheel_rear_left", "wheel_front_left"):
        part = next(q for q in rotating_parts(scene) if q.name == name)
        lo, hi = doppler_interval(part, s, np.zeros(3), scene.carrier_hz)
        assert lo == pytest.approx(0.0, abs=0.01 * 2 * speed / LAM)   # contact point
        assert hi == pytest.approx(4 * speed / LAM, rel=0.01)          # top: 2 v
        f_lo, f_hi, n = path_spread(p, [part.object_id])
        assert n > 100
        assert f_lo >= lo - 0.01 * (hi - lo) and f_hi <= hi + 0.01 * (hi - lo)
        assert f_lo <= lo + 0.01 * (hi - lo) and f_hi >= hi - 0.01 * (hi - lo)


def test_tyre_scattering_tiles_and_sbr_move_with_their_points(runtime):
    """Rubber tyres (a lossy dielectric with a scattering coefficient, optics = "po"):
    Lambertian tiles, PO facets and SBR tubes on the wheels all carry the closed-form
    Doppler of their interaction points, and the tiles spread over the whole interval."""
    doc = tomllib.loads(SCENE.read_text(encoding="utf-8"))
    doc["materials"] = [{"name": "tyre", "eps_r": [4.0, -0.5], "scattering_coefficient": 0.5}]
    for o in doc["objects"]:
        if o["name"].startswith("wheel"):
            o.update(material="tyre", optics="po")
    scene = scene_from_dict(doc, base_dir=SCENE.parent)
    settings = TraceSettings.preset("paper", specular__rays=100_000)
    p = trace_scene(scene, settings, runtime, links=[(0, 0)]).links[0].paths
    codes = {int(c) for c in np.unique(p.interaction[wheel_path_mask(scene, p)])} - {0}
    assert {3, 4, 5} <= codes  # scattering tiles, PO facets, SBR
    np.testing.assert_allclose(p.doppler_hz, closed_form_doppler(doc, p), rtol=1e-10,
                               atol=1e-6)
    tiles = wheel_path_mask(scene, p) & np.all((p.interaction == 3) | (p.interaction == 0),
                                               axis=1)
    part = next(q for q in rotating_parts(scene) if q.name == "wheel_front_left")
    lo, hi = doppler_interval(part, scene.radars[0].position, np.zeros(3), scene.carrier_hz)
    fd = p.doppler_hz[tiles & np.any(p.object_id == part.object_id, axis=1)]
    assert fd.size > 50
    assert fd.min() <= lo + 0.1 * (hi - lo) and fd.max() >= hi - 0.1 * (hi - lo)


def tone_frame(waveform, ranges, dopplers, amps):
    return channel_transfer_function(np.asarray(amps, complex), 2 * np.asarray(ranges) / C0,
                                     np.asarray(dopplers), waveform, method="direct")


def test_doppler_spectrum_puts_known_tones_in_their_bins():
    wf = Waveform(carrier_hz=24e9, n_subcarriers=128, n_symbols=64)
    bin_hz = 1 / (wf.n_symbols * wf.symbol_duration)
    dr = C0 / (2 * wf.n_subcarriers * wf.subcarrier_spacing_hz)
    # two tones at 20 m (on bins 3 and 9) and a strong one at 150 m (bin -5), outside
    F = tone_frame(wf, [20.0, 20.0, 150.0], [3 * bin_hz, 9 * bin_hz, -5 * bin_hz],
                   [1.0, 0.3, 10.0])
    f, power = doppler_spectrum(F, wf, (19.0, 21.0))
    assert f.size == wf.n_symbols and f[wf.n_symbols // 2] == 0.0
    np.testing.assert_allclose(np.diff(f), bin_hz)
    peaks = np.flatnonzero((power > np.roll(power, 1)) & (power > np.roll(power, -1))
                           & (power > 1e-3 * power.max()))
    assert f[peaks] == pytest.approx([3 * bin_hz, 9 * bin_hz])
    assert power[f == 9 * bin_hz][0] / power[f == 3 * bin_hz][0] == pytest.approx(0.09, rel=0.05)
    # the 150 m tone (100 times the power) is not in these cells: at its bin only the
    # Hann window's range leakage, 11 cells away
    assert power[np.argmin(abs(f + 5 * bin_hz))] < 1e-4 * power.max()
    f2, power2 = doppler_spectrum(F, wf, (149.0, 151.0))
    assert f2[np.argmax(power2)] == pytest.approx(-5 * bin_hz)
    # a band of tones on bins 3 .. 7 (powers 0, -6, -10.5, -14, -20 dB), a rectangular
    # window (no leakage between bins): the spread ends where the band falls below the
    # dynamic range
    band = np.arange(3, 8)
    G = tone_frame(wf, np.full(5, 20.0), band * bin_hz, [1.0, 0.5, 0.3, 0.2, 0.1])
    f3, power3 = doppler_spectrum(G, wf, (19.0, 21.0), window="rect")
    np.testing.assert_allclose(power3[wf.n_symbols // 2 + band] / power3.max(),
                               [1.0, 0.25, 0.09, 0.04, 0.01], rtol=1e-9)
    assert spread_edges(f3, power3, 25.0) == pytest.approx((3 * bin_hz, 7 * bin_hz))
    assert spread_edges(f3, power3, 15.0) == pytest.approx((3 * bin_hz, 6 * bin_hz))
    with pytest.raises(ArgumentError) as exc:
        doppler_spectrum(F, wf, (5 * dr * wf.n_subcarriers, 6 * dr * wf.n_subcarriers))
    assert exc.value.argument == "range_m"


def test_spread_edges_stop_at_the_noise():
    f = np.arange(-8, 8) * 100.0
    p = np.full(16, 1e-3)
    p[9:12] = [1.0, 0.1, 0.003]  # 0.003 is 4.8 dB above the median: below the 6 dB margin
    assert spread_edges(f, p, 60.0) == (100.0, 200.0)
    assert spread_edges(f, p, 60.0, noise_margin_db=3.0) == (100.0, 300.0)
    # a noise spike away from the returns does not widen the spread
    p[2] = 0.5
    assert spread_edges(f, p, 60.0) == (100.0, 200.0)
    assert np.isnan(spread_edges(f, np.zeros(16))[0])
    with pytest.raises(ArgumentError):
        spread_edges(f, p, -1.0)


def test_spectrogram_over_frames_shows_the_wheel_spread(scene, runtime, tmp_path):
    wf = Waveform(carrier_hz=scene.carrier_hz)
    res = microdoppler_run(scene, GO_FAST, waveform=wf,
                           times=[0.0, 0.6], runtime=runtime, noise=False)
    bin_hz = res.doppler_hz[1] - res.doppler_hz[0]
    assert res.power.shape == (2, wf.n_symbols)
    # the car body's Doppler is the strongest column cell, the wheels spread 0 .. 2v
    for k in range(2):
        peak = res.doppler_hz[np.argmax(res.power[k])]
        assert abs(peak - res.body_hz[k, 0]) <= bin_hz
        pos = np.array(DOC["objects"][1]["position"]) + V_CAR * res.times_s[k]
        u = (scene.radars[0].position - pos) / np.linalg.norm(scene.radars[0].position - pos)
        assert res.body_hz[k, 0] == pytest.approx(2 * u @ V_CAR / LAM, rel=1e-12)
        assert abs(res.measured_lo_hz[k] - res.expected_lo_hz[k]) <= 1.5 * bin_hz
        assert abs(res.measured_hi_hz[k] - res.expected_hi_hz[k]) <= 1.5 * bin_hz
        assert res.paths_lo_hz[k] >= res.expected_lo_hz[k] - 1e-6
        assert res.paths_hi_hz[k] <= res.expected_hi_hz[k] + 1e-6
    # without the wheels' rotation the spread collapses onto the body's bins
    still = {**DOC, "objects": [{k: v for k, v in o.items() if k not in (
        "angular_velocity_deg_s", "rotation_centre")} for o in DOC["objects"]]}
    still["objects"][2]["angular_velocity_deg_s"] = [0.0, 1e-9, 0.0]  # one part to name
    s2 = scene_from_dict(still, base_dir=SCENE.parent)
    r2 = microdoppler_run(s2, GO_FAST, waveform=wf, times=[0.0],
                          runtime=runtime, noise=False)
    assert r2.measured_hi_hz[0] - r2.measured_lo_hz[0] <= 4 * bin_hz
    assert res.measured_hi_hz[0] - res.measured_lo_hz[0] >= 9 * bin_hz
    written = save_microdoppler(res, tmp_path)
    assert [w.name for w in written] == ["spectrogram.png", "spectrogram.csv",
                                         "microdoppler.csv"]
    lines = (tmp_path / "spectrogram.csv").read_text().splitlines()
    assert len(lines) == 1 + 2 * wf.n_symbols
    assert (tmp_path / "microdoppler.csv").read_text().splitlines()[0].startswith(
        "time_s,expected_lo_hz")


def test_refusals_name_the_argument(scene):
    wf = Waveform(carrier_hz=scene.carrier_hz)
    with pytest.raises(ArgumentError) as exc:
        microdoppler_run(scene, waveform=wf, times=[0.0], radar="nobody")
    assert exc.value.argument == "radar" and exc.value.value == "nobody"
    with pytest.raises(ArgumentError) as exc:
        microdoppler_run(scene, waveform=Waveform(carrier_hz=77e9), times=[0.0])
    assert exc.value.argument == "waveform"
    with pytest.raises(ArgumentError) as exc:
        microdoppler_run(scene, waveform=wf, times=[0.1, 0.0])
    assert exc.value.argument == "times"
    flat = load_scene(ROOT / "scenes" / "canonical" / "moving_car.toml")
    with pytest.raises(ArgumentError, match="no turning object") as exc:
        microdoppler_run(flat, waveform=wf, times=[0.0])
    assert exc.value.argument == "scene"


def test_microdoppler_command_writes_the_spectrogram(tmp_path, capsys):
    out = tmp_path / "md"
    code = cli.main(["microdoppler", str(SCENE), "--out", str(out), "--preset", "go",
                     "--count", "2", "--step", "0.5", "--symbols", "128", "--no-noise",
                     "--rays", "100000"])
    assert code == 0
    assert sorted(p.name for p in out.iterdir()) == ["microdoppler.csv", "spectrogram.csv",
                                                    "spectrogram.png"]
    rows = (out / "microdoppler.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[1].startswith("0,") and rows[2].startswith("0.5,")
    assert "spectrogram edges against the expected interval" in capsys.readouterr().out
    # a scene without turning objects: one line naming the scene, exit code 2
    code = cli.main(["microdoppler", str(ROOT / "scenes" / "canonical" / "moving_car.toml"),
                     "--out", str(tmp_path / "x"), "--count", "1", "--preset", "go"])
    assert code == 2
    err = capsys.readouterr().err
    assert "no turning object" in err and len(err.strip().splitlines()) <= 2


def test_specular_and_diffraction_dopplers_on_a_turning_box(runtime):
    """The GO mechanisms on a turning object: a metal box driving and turning about an
    off-centre vertical axis, seen by a bistatic pair over a road. Every path's Doppler
    (line of sight, specular, edge diffraction, mixed with the road) equals
    -(1/lambda) dL/dt by central differences of the same path's traced length at t -/+ dt
    (paths matched by interactions, objects and faces), and the turn changes it."""
    box = {"name": "box", "material": "metal", "shape": "box", "extents": [2.0, 1.0, 1.0],
           "position": [10.0, 0.0, 1.0], "velocity": [-5.0, 1.0, 0.0],
           "angular_velocity_deg_s": [0.0, 0.0, 40.0], "rotation_centre": [10.3, 0.2, 1.0]}
    doc = {"scene": {"name": "turning_box", "carrier_hz": 24e9},
           "objects": [{"name": "road", "material": "concrete_road", "shape": "plane",
                        "size": [40.0, 20.0], "position": [10.0, 0.0, 0.0]}, box],
           "radars": [{"name": "tx", "position": [0.0, -1.0, 1.2], "role": "tx",
                       "pattern": "isotropic"},
                      {"name": "rx", "position": [0.0, 1.0, 0.9], "role": "rx",
                       "pattern": "isotropic"}]}
    scene = scene_from_dict(doc)
    settings = TraceSettings.preset("go").replace(
        specular__rays=100_000, specular__max_reflections=2, diffraction__max_diffractions=1,
        diffraction__max_reflections=1)
    dt = 1e-4
    at = {t: trace_scene(scene_at(scene, t), settings, runtime).links[0].paths
          for t in (-dt, 0.0, dt)}
    p = at[0.0]
    on_box = np.any(p.object_id == 1, axis=1)
    kinds = {tuple(p.interaction[i, :p.n_interactions[i]]) for i in np.flatnonzero(on_box)}
    assert {(1,), (2,)} <= kinds and ({(1, 2), (2, 1)} & kinds)
    before, now = match_paths(at[-dt], p)
    now2, after = match_paths(p, at[dt])
    later = dict(zip(now2.tolist(), after.tolist(), strict=True))
    checked = 0
    for i_before, i in zip(before.tolist(), now.tolist(), strict=True):
        if i not in later:
            continue
        dl = (at[dt].delay_s[later[i]] - at[-dt].delay_s[i_before]) * C0
        fd = -dl / (2 * dt) / LAM
        assert p.doppler_hz[i] == pytest.approx(fd, rel=1e-7, abs=1e-4)
        checked += on_box[i]
    assert checked >= 8
    # the turn matters: the same paths with the box's translation alone differ by Hz
    plain = [{k: v for k, v in o.items() if k not in ("angular_velocity_deg_s",
                                                      "rotation_centre")}
             for o in doc["objects"]]
    assert np.max(np.abs(closed_form_doppler(doc, p) - closed_form_doppler(
        {**doc, "objects": plain}, p))[on_box]) > 10.0
    np.testing.assert_allclose(p.doppler_hz, closed_form_doppler(doc, p), rtol=1e-10,
                               atol=1e-6)
