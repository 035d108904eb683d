"""A drive on Dask (clradcom.distributed.run_drive, ``clradcom drive --workers/--scheduler``):
a two-worker local cluster gives the serial run's snapshots and series.npz bit for bit,
whatever the chunking; a worker dying under a chunk costs one retry; bad options are
refused. The scene: two box cars on a road, one turning, radar A riding on the other, 4
steps of 50 ms, preset fast (a few hundred milliseconds a trace)."""

from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path

import numpy as np
import pytest

from clradcom import cli
from clradcom import distributed as cd
from clradcom.errors import ArgumentError, ArgumentTypeError
from clradcom.scene.reader import load_scene
from clradcom.series import save_series, series_from_snapshots, trace_series, trace_steps
from clradcom.snapshot import assert_snapshot_equal, save_snapshot
from clradcom.trace import TraceSettings

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = TraceSettings.preset("fast", specular__rays=20_000)
STEPS = 4


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    text = (ROOT / "scenes" / "canonical" / "moving_car.toml").read_text()
    turning = "velocity = [-13.3, 0.0, 0.0]"
    assert turning in text
    text = text.replace(turning, turning + "\nangular_velocity_deg_s = [0.0, 0.0, 20.0]")
    text += f"\n[time]\nstart_s = 0.0\nstep_s = 0.05\ncount = {STEPS}\n"
    path = tmp_path_factory.mktemp("drive") / "turning_car.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def scene(scene_file):
    return load_scene(scene_file)


@pytest.fixture(scope="module")
def serial(scene):
    """The reference: every step in this process through one GeometryCache."""
    return trace_steps(scene, SETTINGS)


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")  # a dependency: never skipped in CI
    with cd.local_cluster(2, retries=1) as c, distributed.Client(c) as client:
        yield c, client


def _same_bytes(a, b, tmp_path: Path, name: str) -> bool:
    pa, pb = tmp_path / f"{name}-a.npz", tmp_path / f"{name}-b.npz"
    save_snapshot(pa, a)
    save_snapshot(pb, b)
    return pa.read_bytes() == pb.read_bytes()


def test_two_workers_give_the_serial_drive_bit_for_bit(scene, serial, cluster, tmp_path):
    _, client = cluster
    n_paths = [sum(lk.paths.n_paths for lk in s) for s in serial]
    assert min(n_paths) >= 3 and len(set(n_paths)) > 1  # real traces; the turn ends a path
    want = tmp_path / "want.npz"
    save_series(want, trace_series(scene, SETTINGS))
    for chunk in (None, 1, 3):  # one chunk per worker, one step per task, uneven chunks
        heard: list = []
        snaps, seconds = cd.run_drive(scene, SETTINGS, client=client, chunk=chunk,
                                      each=lambda k, t, s, sec, h=heard: h.append((k, t)))
        assert heard == [(k, float(t)) for k, t in enumerate(scene.time_axis.times)]
        assert len(seconds) == STEPS and all(s > 0 for s in seconds)
        for k, (got, ref) in enumerate(zip(snaps, serial, strict=True)):
            assert got.time_s == ref.time_s
            assert_snapshot_equal(got, ref)
            assert _same_bytes(got, ref, tmp_path, f"{chunk}-{k}"), (chunk, k)
        got_file = tmp_path / f"series-{chunk}.npz"
        save_series(got_file, series_from_snapshots(snaps))
        assert got_file.read_bytes() == want.read_bytes(), chunk


@pytest.mark.parametrize("on_dask", [False, True])
def test_every_step_is_heard_as_it_is_traced_not_when_its_chunk_returns(scene, cluster,
                                                                        on_dask):
    """One chunk of all the steps: `each` hears them only once the chunk is back, while
    `traced` heard each step as its worker finished it (a progress bar that moves)."""
    _, client = cluster
    events: list = []
    cd.run_drive(scene, SETTINGS, client=client if on_dask else None, workers=0,
                 chunk=STEPS, traced=lambda: events.append("traced"),
                 each=lambda k, t, s, sec: events.append(k))
    # a client's topic events arrive on its own thread, apart from the results: run_drive
    # returns once all of them are in
    assert events.count("traced") == STEPS
    assert [e for e in events if e != "traced"] == list(range(STEPS))
    if not on_dask:
        assert events == ["traced"] * STEPS + list(range(STEPS))


def test_chunks_are_shared_out_over_both_workers(scene, serial, cluster):
    _, client = cluster
    tasks = cd.drive_tasks(scene, SETTINGS, chunk=1)
    assert [t.key for t in tasks] == [f"steps-{k:05d}-{k:05d}" for k in range(STEPS)]
    results = cd.run_tasks(tasks, client=client)
    assert {r.worker for r in results} == {"0", "1"}
    for r, ref in zip(results, serial, strict=True):
        (snap,), _ = r.value
        assert_snapshot_equal(snap, ref)
    assert cd.worker_count(client) == 2 and cd.worker_count(None) == 1
    assert cd.steps_per_task(4, 2) == 2 and cd.steps_per_task(5, 2) == 3
    assert cd.steps_per_task(3, 8) == 1 and cd.steps_per_task(7, 1) == 7


def steps_or_die(marker: str, *args, **kwargs):
    """Kill the worker on the first attempt (no marker yet), trace the chunk on the next."""
    if not os.path.exists(marker):
        Path(marker).write_text("died once\n")
        os._exit(1)
    return cd.trace_steps_task(*args, **kwargs)


def test_a_dead_worker_costs_one_retry(scene, serial, cluster, tmp_path):
    _, client = cluster
    tasks = cd.drive_tasks(scene, SETTINGS, chunk=2)
    assert [t.key for t in tasks] == ["steps-00000-00001", "steps-00002-00003"]
    marker = tmp_path / "attempted"
    tasks[1] = cd.Task(tasks[1].key, steps_or_die, (str(marker), *tasks[1].args))
    results = cd.run_tasks(tasks, client=client, retries=1)
    assert marker.exists()  # the worker did die once under the second chunk
    snaps = [s for r in results for s in r.value[0]]
    for k, (got, ref) in enumerate(zip(snaps, serial, strict=True)):
        assert_snapshot_equal(got, ref)
        assert _same_bytes(got, ref, tmp_path, f"retry-{k}")


def _drive(argv) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            code = cli.main(["drive", *argv])
        except SystemExit as exc:  # argparse refusals
            code = exc.code
    return code, out.getvalue()


def test_drive_command_on_a_scheduler_equals_the_serial_command(scene_file, cluster,
                                                               tmp_path):
    c, _ = cluster
    common = [str(scene_file), "--preset", "fast", "--rays", "20000", "--snapshots",
              "--radar", "radarA", "--no-video", "--no-noise", "--subcarriers", "256",
              "--symbols", "64"]
    a, b = tmp_path / "serial", tmp_path / "dask"
    code, text = _drive([*common, "--out", str(a), "--workers", "0"])
    assert code == 0, text
    assert "this process (serial)" in text
    code, text = _drive([*common, "--out", str(b), "--scheduler", c.scheduler_address,
                         "--retries", "1"])  # default chunks: 2 steps on each worker
    assert code == 0, text
    assert f"scheduler {c.scheduler_address}" in text
    assert text.index("step 1/4") < text.index("step 4/4")  # in step order
    names = ["series.npz", *(f"snapshot_{k:04d}.npz" for k in range(STEPS)),
             "radarA_detections.csv", "radarA_tracks.csv", "radarA_track_truth.csv"]
    for name in names:
        assert (b / name).read_bytes() == (a / name).read_bytes(), name
    with np.load(b / "series.npz") as z:
        assert z["values/present"].shape[0] == STEPS and z["values/present"].any()


@pytest.mark.parametrize("extra, needle", [
    (["--workers", "-1"], "--workers"),
    (["--retries", "-2"], "--retries"),
    (["--chunk", "0"], "--chunk"),
    (["--devices", "0:0,,0:1"], "--devices"),
    (["--device", "cpu", "--devices", "cpu,cpu"], "--device"),
])
def test_drive_refuses_bad_cluster_options(scene_file, tmp_path, extra, needle):
    code, text = _drive([str(scene_file), "--out", str(tmp_path / "o"), *extra])
    assert code == 2
    assert needle in text
    assert not (tmp_path / "o").exists()


def test_run_drive_refuses_bad_arguments(scene):
    with pytest.raises(ArgumentError, match="chunk"):
        cd.drive_tasks(scene, SETTINGS, chunk=0)
    with pytest.raises(ArgumentTypeError, match="settings"):
        cd.drive_tasks(scene, "fast")
    with pytest.raises(ArgumentError, match="times"):
        cd.run_drive(scene, SETTINGS, [0.1, 0.0], workers=0)
    with pytest.raises(ArgumentError, match="workers"):
        cd.run_drive(scene, SETTINGS, workers=-1)
    with pytest.raises(ArgumentError, match="retries"):
        cd.run_drive(scene, SETTINGS, workers=0, retries=-1)
