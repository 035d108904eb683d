"""Traces on a two-worker Dask cluster equal the serial run bit for bit; a worker that
dies under a task costs one retry; a task that fails every time stops the run with an
error naming it after the bound."""

from __future__ import annotations

import copyreg
import os
import pickle
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


class _Unpicklable:
    def __reduce__(self):
        raise TypeError("cannot pickle '_Record' object")


def fail_like_a_kernel_build(counter: str):
    """An OpenCLError chained from an exception that cannot be pickled, as pyopencl's
    error records are; counts its attempts in ``counter``."""
    from clradcom.device.runtime import OpenCLError
    with open(counter, "a") as fh:
        fh.write("x")
    try:
        raise RuntimeError(_Unpicklable())
    except RuntimeError as exc:
        raise OpenCLError("OpenCL build of kernels/x.cl failed on the test device") from exc


def refuse_a_scene(counter: str):
    from clradcom.errors import SceneError
    with open(counter, "a") as fh:
        fh.write("x")
    raise SceneError("missing required key", file="scene.toml", key="scene.carrier_hz")


def test_a_worker_fault_comes_back_as_one_picklable_line(client, tmp_path, capfd):
    counter = tmp_path / "attempts"
    with pytest.raises(cd.TaskError) as info:
        cd.run_tasks([cd.Task("build", fail_like_a_kernel_build, (str(counter),))],
                     client=client, retries=1)
    text = str(info.value)
    assert text == ("task 'build' failed after 2 attempts: OpenCLError: OpenCL build of "
                    "kernels/x.cl failed on the test device")
    assert counter.read_text() == "xx"
    # nothing chained to it that a traceback would print, nothing pickling refused
    assert info.value.__cause__ is None and info.value.__suppress_context__
    assert "pickle" not in capfd.readouterr().err


def test_a_fault_stays_portable_once_dask_has_sent_its_class_back(tmp_path):
    # a worker's first failure makes Dask register tblib's chain-carrying reducer for the
    # exception's class; the retry on that worker must still travel without the chain
    tblib = pytest.importorskip("tblib.pickling_support")
    try:
        fail_like_a_kernel_build(str(tmp_path / "attempts"))
    except RuntimeError as exc:
        raised = exc
    before = dict(copyreg.dispatch_table)
    try:
        tblib.install(raised)
        with pytest.raises(TypeError, match="cannot pickle"):
            pickle.dumps(raised)  # what a plain pickle of it now does
        copy = cd._portable(raised)
        assert type(copy) is type(raised) and str(copy) == str(raised)
        assert copy.__cause__ is None and copy.__suppress_context__
        assert type(pickle.loads(pickle.dumps(copy))) is type(raised)
    finally:  # the table is the pickle module's own object: restored in place
        copyreg.dispatch_table.clear()
        copyreg.dispatch_table.update(before)


def test_a_refusal_on_a_worker_reads_as_in_a_serial_run_and_is_not_retried(client, tmp_path):
    counter = tmp_path / "attempts"
    with pytest.raises(cd.TaskError) as serial:
        cd.run_tasks([cd.Task("scene", refuse_a_scene, (str(counter),))], workers=0)
    with pytest.raises(cd.TaskError) as remote:
        cd.run_tasks([cd.Task("scene", refuse_a_scene, (str(counter),))], client=client,
                     retries=2)
    assert str(remote.value) == str(serial.value) == (
        "task 'scene' failed: SceneError: scene.toml: scene.carrier_hz: missing required key")
    assert counter.read_text() == "xx"   # once serially, once on the worker: no retries


def test_local_workers_are_bounded_by_the_cores():
    limit = cd.max_local_workers()
    assert limit >= 2 and limit >= (os.cpu_count() or 1)
    assert cd.check_workers(limit) == limit
    with pytest.raises(ArgumentError, match=r"workers = 10000: more local worker processes"):
        cd.local_cluster(10_000)
    with pytest.raises(ArgumentError, match=r"workers = .*at most"):
        cd.run_tasks([], workers=limit + 1)


@pytest.mark.parametrize("address", ["not-a-url", "127.0.0.1:8786", "http://host:8786",
                                     "tcp://host", "tcp://:8786", "tcp://host:99999",
                                     "tcp://host:8786/path"])
def test_a_scheduler_address_of_the_wrong_form_is_refused(address):
    with pytest.raises(ArgumentError, match="is not a Dask scheduler address"):
        cd.check_scheduler_address(address)


def test_an_unreachable_scheduler_is_refused_in_seconds():
    import socket
    import time
    with socket.socket() as s:   # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.perf_counter()
    with pytest.raises(ArgumentError, match=r"no Dask scheduler answered there within 5 s"):
        cd.run_tasks([cd.Task("a", always_raise, (1,))], scheduler=f"tcp://127.0.0.1:{port}")
    assert time.perf_counter() - t0 < 30


def test_quiet_logs_drop_a_peer_hang_up_but_keep_other_errors():
    """At Ctrl-C a worker still sending data to a client or worker that is gone logs
    "failed during get data" with a traceback, and a comm's event-loop callback that
    meets the closed peer makes tornado log "Exception in callback" with one; the
    commands' quiet logging drops both (on the workers through QuietHangUps) and keeps
    every other error."""
    import subprocess
    import sys

    script = """
import logging
from distributed.comm import CommClosedError
from clradcom import distributed as cd
cd.quiet_dask_logs()
cd.QuietHangUps().setup(worker=None)   # a second install adds no second filter
log = logging.getLogger("distributed.worker")
for exc in (BrokenPipeError(32, "Broken pipe"), ConnectionResetError(104, "reset"),
            CommClosedError("in <TCP ...>: Stream is closed"), ValueError("a real fault")):
    try:
        raise exc
    except Exception:
        log.exception("failed during get data with %s", type(exc).__name__)
log.error("an error without an exception")
print(sum(len(h.filters) for h in logging.getLogger("distributed").handlers))
from tornado.iostream import StreamClosedError
app = logging.getLogger("tornado.application")
for exc in (StreamClosedError(), CommClosedError("Stream is closed"), KeyError("own fault")):
    try:
        raise exc
    except Exception:
        app.error("Exception in callback %s", type(exc).__name__, exc_info=True)
print(len(app.filters))
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["1", "1"]
    assert "failed during get data with ValueError" in proc.stderr
    # tornado's "Exception in callback" of a comm that met a closed peer: the same
    assert "Exception in callback KeyError" in proc.stderr
    for dropped in ("callback StreamClosedError", "callback CommClosedError"):
        assert dropped not in proc.stderr, proc.stderr
    assert "ValueError: a real fault" in proc.stderr
    assert "an error without an exception" in proc.stderr
    for dropped in ("BrokenPipeError", "ConnectionResetError", "CommClosedError"):
        assert dropped not in proc.stderr, proc.stderr
