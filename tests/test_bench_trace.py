"""tools/bench_trace.py and clradcom.evaluation.bench on tiny scenes and settings (a smoke
test of the whole tool; nothing here asserts a speed), and the extra benchmark scenes
(scenes/plate, scenes/truck77, scenes/guardrail): they load and are the sizes they say."""

import csv
import io
import json

import numpy as np
import pytest
from tool_helpers import CLOSING_PLATE_SCENE, ROOT, load_tool

from clradcom.errors import ArgumentError
from clradcom.evaluation.bench import (
    TraceTiming,
    child_main,
    median_timing,
    peak_rss_bytes,
    plate_rcs,
    run_in_subprocess,
    settings_from_dict,
    settings_to_dict,
)
from clradcom.geometry.triangles import triangle_double_areas, triangle_normals
from clradcom.scene.reader import load_scene
from clradcom.trace import TraceSettings

C0 = 299_792_458.0

#: a 1 m PEC plate at broadside 3 km from an isotropic radar: far field (2D^2/lambda = 160 m)
FAR_PLATE = """
[scene]
name = "far_plate"
carrier_hz = 24e9
[[objects]]
name = "plate"
material = "metal"
shape = "plane"
size = [1.0, 1.0]
position = [3000.0, 0.0, 0.0]
rotation_deg = [0.0, -90.0, 0.0]
[[radars]]
name = "radar"
position = [0.0, 0.0, 0.0]
pattern = "isotropic"
"""


def read_rows(path):
    with open(path) as fh:
        return {(r["scene"], r["engine"], r["quantity"]): r for r in csv.DictReader(fh)}


def test_bench_trace_tool_on_tiny_scenes(tmp_path, capsys):
    street = tmp_path / "closing.toml"
    street.write_text(CLOSING_PLATE_SCENE)
    plate = tmp_path / "far_plate.toml"
    plate.write_text(FAR_PLATE)
    out = tmp_path / "bench"
    tool = load_tool("bench_trace")
    # a large parent: the child's peak memory must be its own, not the parent's at fork
    ballast = np.ones(2**26)  # 512 MiB, touched
    parent_peak = peak_rss_bytes()
    assert tool.main(["--street", str(street), "--extra", str(plate), "--rays", "5000",
                      "--repeats", "1", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "host/device" in printed and "share in kernels" in printed
    rows = read_rows(out / "bench_trace.csv")
    for engine in ("device", "host"):
        trace_s = float(rows[("closing_plate", engine, "median:trace_s")]["value"])
        kernel_s = float(rows[("closing_plate", engine, "median:kernel_s")]["value"])
        assert 0.0 < kernel_s <= trace_s
        assert int(rows[("closing_plate", engine, "median:paths")]["value"]) > 0
        stages = [k for k in rows if k[:2] == ("closing_plate", engine)
                  and k[2].startswith("median:stage:")]
        assert {"median:stage:specular", "median:stage:physical optics"} <= {k[2] for k in stages}
    ratio = float(rows[("closing_plate", "", "host_over_device")]["value"])
    assert ratio == pytest.approx(
        float(rows[("closing_plate", "host", "median:trace_s")]["value"])
        / float(rows[("closing_plate", "device", "median:trace_s")]["value"]), rel=1e-3)
    assert rows[("far_plate", "device", "ok")]["value"] == "1"
    assert rows[("far_plate", "device", "warnings")]["value"] == "0"
    child_peak = float(rows[("far_plate", "device", "peak_rss")]["value"]) * 2**30
    assert 0.05 * 2**30 < child_peak < parent_peak - 0.4 * 2**30
    del ballast
    # the plate's PO return against 4 pi A^2 / lambda^2, computed here on its own
    lam = C0 / 24e9
    expected = 10 * np.log10(4 * np.pi * 1.0**2 / lam**2)
    assert float(rows[("far_plate", "device", "rcs_expected")]["value"]) == pytest.approx(
        expected, abs=1e-3)
    assert float(rows[("far_plate", "device", "rcs_po_paths")]["value"]) == pytest.approx(
        expected, abs=0.1)


def test_bench_trace_refuses_bad_options(capsys):
    tool = load_tool("bench_trace")
    for argv, message in ((["--extra", "moon"], "argument --extra: 'moon' is neither"),
                          (["--repeats", "0"], "argument --repeats: must be a positive"),
                          (["--sbr-spacing", "0"], "argument --sbr-spacing: must be a number "
                                                   "in [0.01, 100]")):
        with pytest.raises(SystemExit):
            tool.build_parser().parse_args(argv)
        assert message in capsys.readouterr().err


def test_bench_settings_are_the_trace_tools():
    bench, trace = load_tool("bench_trace"), load_tool("trace")
    path = str(ROOT / "scenes" / "street" / "street.toml")
    assert bench.main_job_settings(path) == trace.settings_from_args(
        trace.build_parser().parse_args([path]))
    s = bench.main_job_settings(path, rays=1234, sbr_spacing=2.0)
    assert s.specular.rays == 1234 and s.optics.sbr_spacing_wavelengths == 2.0


def test_settings_cross_the_process_boundary_unchanged():
    s = TraceSettings().replace(specular__rays=777, optics__mode="sbr", engine="host",
                                scattering__enabled=True)
    assert settings_from_dict(json.loads(json.dumps(settings_to_dict(s)))) == s


def test_a_child_that_fails_or_is_too_slow_is_reported_not_raised(tmp_path):
    out = io.StringIO()
    assert child_main(io.StringIO(json.dumps({
        "scene": str(tmp_path / "missing.toml"), "settings": settings_to_dict(TraceSettings()),
        "device": None})), out) == 0
    result = json.loads(out.getvalue())
    assert not result["ok"] and "SceneError" in result["error"] and "missing.toml" in \
        result["error"]
    assert result["peak_rss_bytes"] > 0
    plate = tmp_path / "p.toml"
    plate.write_text(FAR_PLATE)
    run = run_in_subprocess(plate, TraceSettings(), timeout_s=0.01)
    assert not run.ok and "no result within" in run.error


def test_a_childs_warnings_come_back_once_each(tmp_path):
    """A carrier below 1 GHz is traced with a ValidityRangeWarning (docs/scene-format.md)."""
    path = tmp_path / "low.toml"
    path.write_text(FAR_PLATE.replace("carrier_hz = 24e9", "carrier_hz = 0.5e9"))
    out = io.StringIO()
    settings = TraceSettings().replace(specular__rays=2000)
    child_main(io.StringIO(json.dumps({"scene": str(path), "device": None,
                                       "settings": settings_to_dict(settings)})), out)
    result = json.loads(out.getvalue())
    assert result["ok"], result
    hits = [w for w in result["warnings"] if w.startswith("ValidityRangeWarning: ")]
    assert len(hits) == 1 and "carrier" in hits[0]
    assert len(set(result["warnings"])) == len(result["warnings"])


def test_median_timing():
    runs = [TraceTiming("device", s, k, {"a": a}, n)
            for s, k, a, n in ((1.0, 0.5, 0.2, 10), (3.0, 0.1, 0.4, 12), (2.0, 0.3, 0.3, 11))]
    m = median_timing(runs)
    assert (m.seconds, m.kernel_seconds, m.stages, m.n_paths) == (2.0, 0.3, {"a": 0.3}, 11)
    assert m.kernel_share == pytest.approx(0.15)
    with pytest.raises(ArgumentError, match="mixes engines"):
        median_timing([runs[0], TraceTiming("host", 1.0, 0.0)])


# ----------------------------------------------------------------------------------------
# the extra scenes
# ----------------------------------------------------------------------------------------
def extent(scene, names):
    pts = np.concatenate([scene.triangles[scene.objects[scene.object_index(n)].tri_slice]
                          .reshape(-1, 3) for n in names])
    return pts.min(axis=0), pts.max(axis=0)


def test_plate_scene_is_a_10_m_plate_at_broadside_in_the_far_field():
    scene = load_scene(ROOT / "scenes" / "plate" / "plate.toml")
    assert scene.carrier_hz == 24e9 and len(scene.objects) == 1
    assert scene.material_pec[scene.objects[0].material]
    lo, hi = extent(scene, ["plate"])
    assert np.allclose(hi - lo, [0.0, 10.0, 10.0])
    area = 0.5 * triangle_double_areas(scene.triangles).sum()
    assert area == pytest.approx(100.0)
    radar = scene.radars[0]
    assert radar.role == "txrx" and radar.pattern.params()["type"] == "isotropic"
    to_plate = 0.5 * (lo + hi) - radar.position
    rng = np.linalg.norm(to_plate)
    # facing the radar, at broadside
    assert np.allclose(triangle_normals(scene.triangles), -to_plate / rng)
    # beyond 2 D^2 / lambda with D the plate's diagonal
    assert rng > 2 * (10.0 * np.sqrt(2)) ** 2 / scene.wavelength_m
    # what bench_trace compares: a plate check exists for it, with the far-field PO value
    check = plate_rcs(scene, [{"radar": 0, "sum_all": [1e-9, 0.0], "sum_po": [1e-9, 0.0]}])
    assert check.area_m2 == pytest.approx(100.0) and check.incidence_deg < 1e-6
    assert check.expected_dbsm == pytest.approx(
        10 * np.log10(4 * np.pi * 100.0**2 * (scene.carrier_hz / C0) ** 2))


def test_truck77_scene_is_a_10_m_pec_truck_on_a_road_at_77_ghz():
    scene = load_scene(ROOT / "scenes" / "truck77" / "truck77.toml")
    assert scene.carrier_hz == 77e9
    truck = [o.name for o in scene.objects if o.name != "road"]
    assert all(scene.material_pec[scene.objects[scene.object_index(n)].material]
               for n in truck)
    assert not scene.material_pec[scene.objects[scene.object_index("road")].material]
    lo, hi = extent(scene, truck)
    assert hi[0] - lo[0] == pytest.approx(10.0)
    assert 2.0 < hi[1] - lo[1] <= 2.6 and 3.5 < hi[2] <= 4.0
    radar = scene.radars[0]
    rear = np.array([lo[0], 0.0, radar.position[2]])
    assert 20.0 <= np.linalg.norm(rear - radar.position) <= 30.0
    # every part of the truck moves with it
    assert len({tuple(scene.objects[scene.object_index(n)].velocity) for n in truck}) == 1
    # nothing of the truck lies in the road's plane (no coincident faces)
    tri = np.concatenate([scene.triangles[scene.objects[scene.object_index(n)].tri_slice]
                          for n in truck])
    assert not np.any(np.all(np.abs(tri[:, :, 2]) < 1e-9, axis=1))
    assert plate_rcs(scene, [{"radar": 0, "sum_all": [0, 0], "sum_po": [0, 0]}]) is None


def test_guardrail_scene_is_a_60_m_w_beam_on_posts(tmp_path):
    scene = load_scene(ROOT / "scenes" / "guardrail" / "guardrail.toml")
    assert scene.carrier_hz == 24e9
    lo, hi = extent(scene, ["w_beam"])
    assert hi[0] - lo[0] == pytest.approx(60.0)
    assert hi[1] - lo[1] == pytest.approx(0.083) and hi[2] - lo[2] == pytest.approx(0.312)
    beam = scene.objects[scene.object_index("w_beam")]
    radar = scene.radars[0]
    # the beam faces the road and the radar
    n = triangle_normals(scene.triangles[beam.tri_slice])
    assert np.all(n[:, 1] < 0) and radar.position[1] < lo[1]
    posts = scene.objects[scene.object_index("posts")]
    assert posts.n_triangles == 31 * 12
    plo, phi = extent(scene, ["posts"])
    assert plo[2] < 0.0 < phi[2] and plo[1] > hi[1]  # in the ground, behind the beam
    for name in ("w_beam", "posts"):
        assert scene.material_pec[scene.objects[scene.object_index(name)].material]
    # the committed meshes are what tools/make_guardrail.py writes
    written = load_tool("make_guardrail").write_meshes(tmp_path)
    for path in written:
        committed = ROOT / "scenes" / "guardrail" / "meshes" / path.name
        assert committed.read_bytes() == path.read_bytes(), path.name
