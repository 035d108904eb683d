"""`clradcom drive --radar`: the radar chain at every step of a drive, the detection table
with its time column, the GIF, the tracks against the cars' true trajectories; the
street's drive variant; refusals (clradcom.radar.video, clradcom.commands.drive)."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from clradcom import cli
from clradcom.errors import ArgumentError
from clradcom.radar.video import (
    DETECTION_TABLE_COLUMNS,
    FRAME_COLUMNS,
    ffmpeg_available,
    save_gif,
    save_mp4,
)
from clradcom.scene.reader import load_scene

ROOT = Path(__file__).resolve().parent.parent
CAR = ROOT / "scenes" / "street" / "meshes" / "car.ply"
# a radar driving at VA (no car under it: the road right below it is its own strong
# return at 0.5 m), car B oncoming in the other lane, car C ahead in its lane, faster
VA, VB, VC = 12.9, -13.3, 27.0
XB, XC = 30.0, 20.0
RADAR = np.array([1.95, -1.75, 0.5])
STEP, COUNT = 0.05, 4

SCENE = f"""
[scene]
name = "two_cars"
carrier_hz = 24e9

[time]
start_s = 0.0
step_s = {STEP}
count = {COUNT}

[[objects]]
name = "road"
material = "concrete_road"
shape = "plane"
size = [120.0, 16.0]
position = [20.0, 0.0, 0.0]

[[objects]]
name = "carB"
material = "metal"
mesh = "{CAR.as_posix()}"
position = [{XB}, 1.75, 0.0]
rotation_deg = [0.0, 0.0, 180.0]
velocity = [{VB}, 0.0, 0.0]

[[objects]]
name = "carC"
material = "metal"
mesh = "{CAR.as_posix()}"
position = [{XC}, -1.75, 0.0]
velocity = [{VC}, 0.0, 0.0]

[[radars]]
name = "radarA"
position = {RADAR.tolist()}
velocity = [{VA}, 0.0, 0.0]
pattern = {{ type = "sector", azimuth_width_deg = 90.0, elevation_width_deg = 180.0 }}
tx_power_w = 0.01
noise_figure_db = 10.0

# the same radar with a 2 tx x 4 rx array (8-element virtual ULA at lambda/2)
[[radars]]
name = "radarM"
position = {RADAR.tolist()}
velocity = [{VA}, 0.0, 0.0]
pattern = {{ type = "sector", azimuth_width_deg = 90.0, elevation_width_deg = 180.0 }}
tx_power_w = 0.01
noise_figure_db = 10.0
tx_array = {{ kind = "ula", count = 2, spacing_wavelengths = 2.0 }}
rx_array = {{ kind = "ula", count = 4, spacing_wavelengths = 0.5 }}
"""

ARGS = ["--radar", "radarA", "--preset", "fast", "--symbols", "128", "--workers", "0"]


def _csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


@pytest.fixture(scope="module")
def drive(tmp_path_factory, runtime):
    folder = tmp_path_factory.mktemp("drive")
    scene = folder / "two_cars.toml"
    scene.write_text(SCENE)
    out = folder / "out"
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        code = cli.main(["drive", str(scene), "--out", str(out), *ARGS])
    return code, text.getvalue(), out


def test_drive_radar_writes_table_video_and_tracks(drive):
    code, text, out = drive
    assert code == 0, text
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["series.npz"] + [f"radarA_{n}" for n in (
            "detections.csv", "tracks.csv", "track_truth.csv", "tracks.png", "video.gif",
            "frames.csv")])
    # the detection table: its columns (no azimuth: one antenna) and time = frame x step
    head, rows = _csv(out / "radarA_detections.csv")
    assert tuple(head) == tuple(c for c in DETECTION_TABLE_COLUMNS if c != "azimuth_deg")
    frames = np.array([int(r[1]) for r in rows])
    np.testing.assert_allclose([float(r[0]) for r in rows], frames * STEP, atol=1e-6)
    assert set(frames.tolist()) == set(range(COUNT))
    assert {r[2] for r in rows} == {"radarA"}
    # the video: one GIF frame per step
    with Image.open(out / "radarA_video.gif") as im:
        assert im.n_frames == COUNT
    head, rows = _csv(out / "radarA_frames.csv")
    assert tuple(head) == FRAME_COLUMNS and len(rows) == COUNT
    # the truth: each car's closing speed is the closed form for its centre, seen from
    # the radar riding on car A, and both cars are tracked within one range and one
    # velocity cell at every step
    head, rows = _csv(out / "radarA_track_truth.csv")
    col = {k: i for i, k in enumerate(head)}
    for r in rows:
        rng, v_rel, _ = _closed_form(r[col["object"]], float(r[col["time_s"]]))
        assert float(r[col["range_centre_m"]]) == pytest.approx(rng, abs=0.01)
        assert float(r[col["velocity_true_mps"]]) == pytest.approx(v_rel, abs=0.02)
        assert r[col["visible"]] == "1"
        assert r[col["within"]] == "1", r
    tracks = {r[col["object"]]: r[col["track"]] for r in rows}
    assert len(set(tracks.values())) == 2  # one track each, not shared
    for name in ("carB", "carC"):
        assert {r[col["track"]] for r in rows if r[col["object"]] == name} == {tracks[name]}


def test_drive_radar_prints_the_summary(drive):
    _, text, _ = drive
    assert "time per frame: trace" in text
    for name in ("carB", "carC"):
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(name))
        assert f"{COUNT}/{COUNT}" in line and "all visible frames within one cell" in line


def _closed_form(name, t):
    """(range of the centre, closing velocity, azimuth in degrees) of a car at t."""
    radar = RADAR + np.array([VA * t, 0.0, 0.0])
    v, x0, y = (VB, XB, 1.75) if name == "carB" else (VC, XC, -1.75)
    centre = np.array([x0 + v * t, y, 0.85])  # the car mesh is 1.7 m tall
    d = centre - radar
    u = d / np.linalg.norm(d)
    return (float(np.linalg.norm(d)), float(-(np.array([v - VA, 0.0, 0.0]) @ u)),
            float(np.degrees(np.arctan2(d[1], d[0]))))


def test_drive_array_radar_tracks_azimuth(tmp_path):
    scene = tmp_path / "two_cars.toml"
    scene.write_text(SCENE)
    out = tmp_path / "o"
    with contextlib.redirect_stdout(io.StringIO()):
        code = cli.main(["drive", str(scene), "--out", str(out), "--radar", "radarM",
                         "--preset", "fast", "--symbols", "128", "--count", "3",
                         "--no-video", "--workers", "0"])
    assert code == 0
    head, rows = _csv(out / "radarM_detections.csv")
    assert tuple(head) == DETECTION_TABLE_COLUMNS
    head, rows = _csv(out / "radarM_track_truth.csv")
    col = {k: i for i, k in enumerate(head)}
    for r in rows:
        _, _, az = _closed_form(r[col["object"]], float(r[col["time_s"]]))
        assert float(r[col["azimuth_true_deg"]]) == pytest.approx(az, abs=0.01)
        assert r[col["within"]] == "1", r
        # one azimuth FFT bin of the 8-element array is 2/8 in sin(az), 14 deg: the track
        # is far closer than that
        assert float(r[col["azimuth_track_deg"]]) == pytest.approx(az, abs=1.5)


def _exit_code(argv) -> int:
    try:
        return cli.main(argv)
    except SystemExit as exc:  # refused by argparse where it is parsed
        return int(exc.code)


@pytest.mark.parametrize("extra, needle", [
    (["--radar", "nosuch"], "--radar"),
    (["--no-video"], "--no-video"),
    (["--radar", "radarA", "--fps", "0"], "--fps"),
    (["--radar", "radarA", "--min-snr-db", "nan"], "--min-snr-db"),
    (["--radar", "radarA", "--subcarriers", "0"], "--subcarriers"),
])
def test_drive_radar_refuses_bad_options(tmp_path, capsys, extra, needle):
    scene = tmp_path / "two_cars.toml"
    scene.write_text(SCENE)
    assert _exit_code(["drive", str(scene), "--out", str(tmp_path / "o"), *extra]) == 2
    assert needle in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_mp4_needs_ffmpeg(tmp_path, capsys, monkeypatch):
    """Refused, before any work, where ffmpeg is missing (made missing here, so that the
    refusal is tested where ffmpeg is installed too)."""
    which = shutil.which
    monkeypatch.setattr(shutil, "which", lambda name, *a, **kw:
                        None if name == "ffmpeg" else which(name, *a, **kw))
    assert not ffmpeg_available()
    scene = tmp_path / "two_cars.toml"
    scene.write_text(SCENE)
    code = cli.main(["drive", str(scene), "--out", str(tmp_path / "o"), "--radar", "radarA",
                     "--mp4"])
    assert code == 2
    assert "ffmpeg" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    with pytest.raises(ArgumentError, match="needs ffmpeg"):
        save_mp4(tmp_path / "x.mp4", [np.zeros((8, 8, 3), np.uint8)])
    assert not (tmp_path / "x.mp4").exists()


def mp4_frames(n: int, h: int, w: int) -> list[np.ndarray]:
    """Frames of flat colour blocks that move and change from frame to frame (flat
    areas survive H.264 and 4:2:0 chroma nearly unchanged)."""
    frames = []
    for i in range(n):
        f = np.zeros((h, w, 3), np.uint8)
        f[:, :] = (30 + 40 * i, 200 - 30 * i, 90)
        x = 8 + 8 * i
        f[8:24, x:x + 16] = (250, 250, 40 * i)
        frames.append(f)
    return frames


@pytest.mark.skipif(not ffmpeg_available(),
                    reason="ffmpeg is not on the PATH: save_mp4's success path runs where "
                           "it is (.ci/run installs Debian's ffmpeg)")
def test_save_mp4_writes_frames_ffmpeg_reads_back(tmp_path):
    """An odd-sized frame (H.264 needs even sides: padded) at 5 fps: ffprobe finds an
    H.264 video of the padded size, the frame count and the rate; ffmpeg decodes frames
    whose picture is the one written, within H.264's loss on flat colours."""
    n, h, w = 5, 45, 63
    frames = mp4_frames(n, h, w)
    path = save_mp4(tmp_path / "v.mp4", frames, fps=5.0)
    assert path == tmp_path / "v.mp4" and sorted(tmp_path.iterdir()) == [path]
    probe = subprocess.run(
        [shutil.which("ffprobe") or "ffprobe", "-v", "error", "-select_streams", "v:0",
         "-count_frames", "-show_entries",
         "stream=codec_name,width,height,r_frame_rate,nb_read_frames", "-of", "json",
         str(path)], capture_output=True, text=True, check=True)
    stream = json.loads(probe.stdout)["streams"][0]
    assert stream["codec_name"] == "h264"
    assert (stream["width"], stream["height"]) == (64, 46)
    assert stream["r_frame_rate"] == "5/1" and int(stream["nb_read_frames"]) == n
    raw = subprocess.run([shutil.which("ffmpeg"), "-v", "error", "-i", str(path), "-f",
                          "rawvideo", "-pix_fmt", "rgb24", "-"], capture_output=True,
                         check=True).stdout
    back = np.frombuffer(raw, np.uint8).reshape(n, 46, 64, 3)[:, :h, :w].astype(int)
    for i, (got, want) in enumerate(zip(back, frames, strict=True)):
        # away from the blocks' edges (where 4:2:0 chroma and the codec blur)
        inner = np.ones((h, w), bool)
        inner[4:28, :] = False
        assert np.abs(got[inner] - want[inner]).mean() < 4, i
        assert np.abs(got[12:20, 12 + 8 * i:20 + 8 * i] - want[12:20, 12 + 8 * i:20 + 8 * i]
                      ).mean() < 6, i


def test_save_gif_refuses_frames_of_different_sizes(tmp_path):
    a = np.zeros((10, 12, 3), np.uint8)
    b = np.zeros((10, 14, 3), np.uint8)
    with pytest.raises(ArgumentError, match="frames"):
        save_gif(tmp_path / "x.gif", [a, b])
    with pytest.raises(ArgumentError, match="frames"):
        save_gif(tmp_path / "x.gif", [])
    save_gif(tmp_path / "x.gif", [a, a + 255])
    with Image.open(tmp_path / "x.gif") as im:
        assert im.n_frames == 2


def test_street_drive_variant_is_one_second_in_20_frames():
    scene = load_scene(ROOT / "scenes" / "street" / "street_drive.toml")
    street = load_scene(ROOT / "scenes" / "street" / "street.toml")
    assert scene.name == "street_drive"
    np.testing.assert_allclose(scene.time_axis.times, 0.05 * np.arange(20), atol=1e-12)
    np.testing.assert_array_equal(scene.triangles, street.triangles)
    assert [o.velocity.tolist() for o in scene.objects] == [
        o.velocity.tolist() for o in street.objects]
