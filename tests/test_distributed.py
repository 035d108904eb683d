"""Traces on a two-worker Dask cluster equal the serial run bit for bit; a worker that
dies under a task costs one retry; a task that fails every time stops the run with an
error naming it after the bound."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from clradcom import distributed as cd
from clradcom.errors import ArgumentError
from clradcom.scene.reader import load_scene
from clradcom.snapshot import assert_snapshot_equal, save_snapshot
from clradcom.trace import TraceSettings

SCENES = Path(__file__).resolve().parents[1] / "scenes" / "canonical"


def _sweep():
    """Five small traces over two scenes and three presets (GO, PO facets, PO + SBR with
    scattering): every mechanism and both kinds of PO."""
    corner = load_scene(SCENES / "corner.toml")
    car = load_scene(SCENES / "moving_car.toml")
    tasks = [
        cd.Task("corner-go", cd.trace_task,
                (corner, TraceSettings.preset("go", specular__rays=20_000))),
        cd.Task("corner-paper", cd.trace_task,
                (corner, TraceSettings.preset("paper", specular__rays=20_000))),
        cd.Task("car-fast", cd.trace_task,
                (car, TraceSettings.preset("fast", specular__rays=20_000))),
        cd.Task("car-paper", cd.trace_task,
                (car, TraceSettings.preset("paper", specular__rays=30_000))),
        cd.Task("car-go-2", cd.trace_task,
                (car, TraceSettings.preset("go", specular__rays=10_000,
                                           diffraction__max_diffractions=2))),
    ]
    return tasks


@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("distributed")  # a dependency: never skipped in CI
    with cd.local_cluster(2, retries=1) as cluster, distributed.Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def serial():
    return cd.run_tasks(_sweep(), workers=0)


def _assert_same(results, serial, tmp_path):
    assert [r.key for r in results] == [r.key for r in serial]
    for got, want in zip(results, serial, strict=True):
        assert_snapshot_equal(got.value, want.value)  # every array, dtype and value exact
        a, b = tmp_path / f"{got.key}-got.npz", tmp_path / f"{got.key}-want.npz"
        save_snapshot(a, got.value)
        save_snapshot(b, want.value)
        assert a.read_bytes() == b.read_bytes(), got.key


def test_two_workers_equal_the_serial_run(client, serial, tmp_path):
    assert sum(lk.paths.n_paths for r in serial for lk in r.value) > 20  # real traces
    results = cd.run_tasks(_sweep(), client=client)
    _assert_same(results, serial, tmp_path)
    # both workers took part, each with its own device opened once
    assert {r.worker for r in results} == {"0", "1"}
    assert all(r.seconds > 0 for r in results)


def trace_or_die(marker: str, scene, settings):
    """Kill the worker process on the first attempt (no marker yet), trace on the next."""
    if not os.path.exists(marker):
        Path(marker).write_text("died once\n")
        os._exit(1)
    return cd.trace_task(scene, settings)


def always_die():
    os._exit(1)


def always_raise(n):
    raise ValueError(f"bad value {n}")


def test_a_dead_worker_costs_one_retry(client, serial, tmp_path):
    tasks = _sweep()
    marker = tmp_path / "attempted"
    first = tasks[1]
    tasks[1] = cd.Task(first.key, trace_or_die, (str(marker), *first.args))
    results = cd.run_tasks(tasks, client=client)
    assert marker.exists()  # the worker did die once under it
    _assert_same(results, serial, tmp_path)


def test_a_task_failing_every_time_is_named(client):
    with pytest.raises(cd.TaskError, match="'doomed'.*died") as info:
        cd.run_tasks([cd.Task("doomed", always_die)], client=client)
    assert info.value.key == "doomed"
    with pytest.raises(cd.TaskError, match=r"'bad' failed after 2 attempts: ValueError: "
                                           r"bad value 7"):
        cd.run_tasks([cd.Task("bad", always_raise, (7,))], client=client, retries=1)


def test_serial_run_names_the_failing_task():
    with pytest.raises(cd.TaskError, match="'bad' failed: ValueError"):
        cd.run_tasks([cd.Task("bad", always_raise, (1,))], workers=0)


def test_bad_arguments_are_refused():
    with pytest.raises(ArgumentError, match="retries"):
        cd.run_tasks([], workers=0, retries=-1)
    with pytest.raises(ArgumentError, match="distinct"):
        cd.run_tasks([cd.Task("a", always_die), cd.Task("a", always_die)], workers=0)
    with pytest.raises(ArgumentError, match="Task.key"):
        cd.Task("", always_die)
    with pytest.raises(ArgumentError, match="workers"):
        cd.local_cluster(0)
