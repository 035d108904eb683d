"""Many traces at once on Dask (``dask.distributed``): a parameter sweep, or a drive.

The unit of work is a :class:`Task`: a module-level callable with picklable arguments
that returns a result (a :class:`~clradcom.snapshot.Snapshot`, or arrays). A sweep is a
list of them (:func:`trace_tasks`: one :func:`trace_task` per settings); a drive
sequence is one task per run of consecutive time steps (:func:`drive_tasks`: one
:func:`trace_steps_task` per chunk, each with its own
:class:`~clradcom.mechanisms.common.GeometryCache`), which :func:`run_drive` runs and
hands back in step order. :func:`run_tasks` runs a list

* serially in this process (``workers=0``): the reference every distributed run must
  equal bit for bit;
* on a ``LocalCluster`` it starts (``workers=N`` processes, one thread each);
* on a running scheduler (``scheduler="tcp://host:8786"``), whose workers may be on
  many machines;

and gives the results back in task order, as :class:`TaskResult` records (the value,
the worker's seconds, the warnings it raised, which are raised again here).

Every worker process opens its own OpenCL runtime once (:class:`DevicePlugin`, then
:func:`worker_runtime`, cached per process by
:func:`clradcom.device.runtime.get_runtime`): with ``devices=["0:0", "0:1"]`` worker
*i* takes device ``i mod 2`` (one worker per GPU), otherwise the worker's own
``CLRADCOM_DEVICE`` or the default device. On PoCL's CPU device a local cluster gives
each worker an equal share of the cores (``POCL_MAX_PTHREAD_COUNT``), so two workers
do not fight over them.

A task runs again when it raises (``retries`` times) and when its worker dies under it
(the scheduler's ``allowed-failures``, set to ``retries`` for a local cluster; a remote
scheduler keeps its own setting); past that bound :class:`TaskError` names the task.
docs/scale.md has the design, the determinism argument and the measured scaling.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import logging
import math
import os
import pickle
import signal
import time
import urllib.parse
import uuid
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from clradcom.device.runtime import Runtime, get_runtime
from clradcom.errors import (
    ArgumentError,
    ArgumentTypeError,
    SceneError,
    SnapshotError,
    TaskError,
)
from clradcom.scene.records import Scene
from clradcom.series import check_times, trace_steps
from clradcom.snapshot import Snapshot
from clradcom.trace import TraceSettings, trace_scene

try:  # a hard dependency (pyproject.toml); imported here so the error can say so
    import dask
    import distributed
    from distributed.diagnostics.plugin import WorkerPlugin
    from tornado.iostream import StreamClosedError
except ImportError as _exc:  # pragma: no cover - installed with clradcom
    raise ImportError(f"clradcom.distributed needs dask.distributed ({_exc}): "
                      "pip install distributed") from _exc

__all__ = ["DevicePlugin", "Task", "TaskError", "TaskResult", "connect", "drive_tasks",
           "local_cluster", "run_drive", "run_tasks", "steps_per_task", "trace_steps_task",
           "trace_task", "trace_tasks", "worker_count", "worker_device", "worker_runtime"]

#: PoCL's thread count for its CPU device, read when the platform is first opened
POCL_THREADS_ENV = "POCL_MAX_PTHREAD_COUNT"
#: the scheduler setting that bounds how often a task may take its worker down with it
ALLOWED_FAILURES = "distributed.scheduler.allowed-failures"
#: Address schemes of a Dask scheduler that --scheduler accepts (host and port required)
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss")
#: Seconds to wait for a scheduler to answer before the run is refused
CONNECT_TIMEOUT_S = 5.0
#: Refusals that a task meets alike on every attempt and every worker (bad input): they
#: come back at once, as in a serial run, instead of being tried again
REFUSALS = (SceneError, SnapshotError, ArgumentError, ArgumentTypeError)


#: set by :func:`quiet_dask_logs`: the workers a run connects to get :class:`QuietHangUps`
_quiet_logs = False


def quiet_dask_logs() -> None:
    """Dask's own log lines, in this process and the local clusters it starts later,
    errors only: at Ctrl-C every cancelled task and stopped worker logs a warning that is
    not the user's business, and a command's own errors reach them as one line. The
    errors a peer's hang-up raises are dropped too (:class:`QuietHangUps`). For the
    commands (``clradcom sweep``, ``drive``); a library caller keeps Dask's logging."""
    global _quiet_logs
    _quiet_logs = True
    os.environ["DASK_LOGGING__DISTRIBUTED"] = "error"   # read by each worker at start
    logging.getLogger("distributed").setLevel(logging.ERROR)
    _drop_hang_ups()


def _not_a_hang_up(record: logging.LogRecord) -> bool:
    """False for a record logged for an exception of a connection its peer closed (a
    cluster stopping while a worker still sends a result to a client or worker that is
    gone): a logging filter that drops those."""
    exc = record.exc_info[1] if record.exc_info else None
    return not isinstance(exc, (distributed.comm.CommClosedError, StreamClosedError,
                                BrokenPipeError, ConnectionResetError))


#: the logger tornado reports an exception in an event-loop callback to ("Exception in
#: callback ...", with its traceback): a comm's callback that meets a closed peer while
#: the cluster stops logs there, not under ``distributed``
TORNADO_CALLBACKS = "tornado.application"


def _drop_hang_ups() -> None:
    """Hang-ups (:func:`_not_a_hang_up`) kept off the handlers of Dask's ``distributed`` logger
    in this process (a filter on the handlers: a logger's own filter would miss the
    records of its children, ``distributed.worker`` among them), and off tornado's
    callback logger (its own filter: tornado logs those records to it directly)."""
    for handler in logging.getLogger("distributed").handlers:
        if _not_a_hang_up not in handler.filters:
            handler.addFilter(_not_a_hang_up)
    callbacks = logging.getLogger(TORNADO_CALLBACKS)
    if _not_a_hang_up not in callbacks.filters:
        callbacks.addFilter(_not_a_hang_up)


class QuietHangUps(WorkerPlugin):
    """The commands' quiet logging on each worker: Ctrl-C stops the cluster while a worker
    may still be sending data, and its ERROR record with a traceback ("failed during get
    data") is no news to the user, whose run already ends in one line."""

    name = "clradcom-quiet-hang-ups"

    def setup(self, worker) -> None:
        _drop_hang_ups()


def max_local_workers() -> int:
    """The most processes a local cluster may start: one per core (at least 2). More only
    queue on the same cores (each worker's PoCL device gets its share of them) while each
    holds its own interpreter, OpenCL runtime and scene."""
    return max(2, os.cpu_count() or 1)


def check_workers(workers, *, argument: str = "workers") -> int:
    """``workers`` if it is an integer in 0 .. :func:`max_local_workers`."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise ArgumentError("must be an integer >= 0", argument=argument, value=workers)
    limit = max_local_workers()
    if workers > limit:
        raise ArgumentError(f"more local worker processes than this machine has cores "
                            f"({limit}); give at most {limit}, or start workers on other "
                            "machines and give --scheduler", argument=argument, value=workers)
    return workers


def check_scheduler_address(address, *, argument: str = "scheduler") -> str:
    """``address`` if it has the form of a Dask scheduler's (``tcp://host:8786``)."""
    if not isinstance(address, str):
        raise ArgumentTypeError("must be a string such as tcp://host:8786",
                                argument=argument, value=address)
    try:
        parts = urllib.parse.urlsplit(address)
        port = parts.port
    except ValueError:
        parts, port = None, None
    if (parts is None or parts.scheme not in SCHEDULER_SCHEMES or not parts.hostname
            or port is None or parts.path not in ("", "/")):
        raise ArgumentError(f"is not a Dask scheduler address: write SCHEME://HOST:PORT "
                            f"with SCHEME one of {', '.join(SCHEDULER_SCHEMES)}, e.g. "
                            "tcp://127.0.0.1:8786", argument=argument, value=address)
    return address


@dataclass(frozen=True)
class Task:
    """One unit of work: ``fn(*args, **kwargs)`` on some worker.

    ``fn`` must be importable by the workers (a module-level function of an installed
    package); ``args``/``kwargs`` are pickled and shipped (scenes are small: the street
    is 1.7 MB). ``key`` names the task in errors and output files."""

    key: str
    fn: Callable[..., object]
    args: tuple = ()
    kwargs: Mapping = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.key, str) or not self.key:
            raise ArgumentError("must be a non-empty string", argument="Task.key",
                                value=self.key)
        if not callable(self.fn):
            raise ArgumentTypeError("must be callable", argument="Task.fn", value=self.fn)


@dataclass(frozen=True)
class TaskResult:
    """What a task gave back: ``value``, the wall seconds it ran on its worker, the
    worker's name (``"serial"`` in this process) and the warnings it raised as
    ``(category, message, filename, lineno)``."""

    key: str
    value: object
    seconds: float
    worker: str
    warnings: tuple = ()


# ----------------------------------------------------------------------------------------
# the worker side
# ----------------------------------------------------------------------------------------
_worker_device: str | None = None  # this process's device spec (DevicePlugin sets it)


def worker_device() -> str | None:
    """The device spec of this process (None: ``CLRADCOM_DEVICE``, else the default)."""
    return _worker_device


def worker_runtime() -> Runtime:
    """This process's OpenCL runtime, opened once (:func:`get_runtime` caches it)."""
    return get_runtime(_worker_device)


class DevicePlugin(WorkerPlugin):
    """Gives each worker its device and opens it once, before the worker's first task.

    ``devices``: specs (``"0:0"``, ``"gpu"``, a name fragment) shared out by the worker's
    number (a local cluster names its workers 0, 1, ...): worker *i* takes
    ``devices[i % len(devices)]``. A worker with another name, or no ``devices``, keeps
    its own ``CLRADCOM_DEVICE`` or the default device (start one worker per GPU with
    ``CLRADCOM_DEVICE=i dask worker ADDRESS``)."""

    name = "clradcom-device"

    def __init__(self, devices: Sequence[str] | None = None):
        self.devices = tuple(devices or ())

    def setup(self, worker) -> None:
        global _worker_device
        index = worker.name if isinstance(worker.name, int) else None
        if self.devices and index is not None:
            _worker_device = self.devices[index % len(self.devices)]
        worker_runtime()  # open it now: a device problem shows before any task runs


def _own_reduction_pickle(value) -> bytes:
    """``value`` pickled by its own ``__reduce_ex__``, past copyreg's table: Dask puts
    tblib's reducer there for every exception class a worker has sent back once, and that
    reducer takes the chained exceptions along (so a retry on the same worker would
    meet the unpicklable record the first attempt left behind)."""
    buffer = io.BytesIO()
    pickler = pickle.Pickler(buffer, protocol=pickle.HIGHEST_PROTOCOL)
    pickler.dispatch_table = {}
    pickler.dump(value)
    return buffer.getvalue()


def _portable(exc: BaseException) -> BaseException:
    """``exc`` as it can travel from a worker: a copy without the exceptions chained to
    it (a pyopencl error record among them cannot be pickled, and Dask pickles the chain),
    or, where ``exc`` itself does not survive pickling, a RuntimeError of its text."""
    try:
        copy = pickle.loads(_own_reduction_pickle(exc))
        if type(copy) is not type(exc) or str(copy) != str(exc):
            raise TypeError("changed in pickling")
    except Exception:  # noqa: BLE001 - whatever pickling refuses, the text travels
        copy = RuntimeError(f"{type(exc).__name__}: {exc}")
    copy.__cause__ = copy.__context__ = None
    copy.__suppress_context__ = True
    return copy


@dataclass(frozen=True)
class _Refused:
    """A task's refusal (:data:`REFUSALS`), returned instead of raised so that it is not
    tried again and reaches the caller as it would in a serial run."""

    error: BaseException


def _run(fn: Callable, args: tuple, kwargs: Mapping) -> tuple:
    """A task on its worker: value, seconds, worker name and the warnings it raised. A
    refusal comes back as the value (:class:`_Refused`); any other failure is raised
    without its chained exceptions (:func:`_portable`), outside the handler so that none
    is chained to it here either."""
    failure = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        try:
            value = fn(*args, **kwargs)
        except REFUSALS as exc:
            value = _Refused(_portable(exc))
        except Exception as exc:  # noqa: BLE001 - re-raised below, picklable
            failure = _portable(exc)
        seconds = time.perf_counter() - t0
    if failure is not None:
        raise failure
    try:
        name = str(distributed.get_worker().name)
    except ValueError:  # not inside a worker
        name = "serial"
    seen = {(w.category, str(w.message), w.filename, w.lineno) for w in caught}
    return value, seconds, name, tuple(sorted(seen, key=lambda w: (w[2], w[3], w[1])))


# ----------------------------------------------------------------------------------------
# traces as tasks
# ----------------------------------------------------------------------------------------
def trace_task(scene: Scene, settings: TraceSettings, links=None) -> Snapshot:
    """One trace on this process's device: :func:`clradcom.trace.trace_scene` with
    :func:`worker_runtime`."""
    return trace_scene(scene, settings, runtime=worker_runtime(), links=links)


def trace_tasks(scene: Scene, settings: Sequence[TraceSettings], keys=None,
                links=None) -> list[Task]:
    """One :func:`trace_task` per settings, keyed ``keys`` (default ``task-000``, ...)."""
    if not isinstance(scene, Scene):
        raise ArgumentTypeError("must be a Scene", argument="scene", value=scene)
    settings = list(settings)
    for s in settings:
        if not isinstance(s, TraceSettings):
            raise ArgumentTypeError("must hold TraceSettings", argument="settings", value=s)
    keys = [f"task-{i:03d}" for i in range(len(settings))] if keys is None else list(keys)
    if len(keys) != len(settings) or len(set(keys)) != len(keys):
        raise ArgumentError(f"must be {len(settings)} distinct names, one per settings",
                            argument="keys", value=keys)
    return [Task(k, trace_task, (scene, s), {} if links is None else {"links": links})
            for k, s in zip(keys, settings, strict=True)]


#: ``steps_topic`` -> callable of the drives running serially in this process: what a
#: Dask worker sends as an event, a serial run hands on here
_serial_step_hooks: dict[str, Callable[[], None]] = {}


def _step_traced(topic: str | None) -> None:
    """Tell the client a step of a drive is traced: an event on ``topic`` from a Dask
    worker (the client's :func:`run_drive` subscribed to it), or the hook of a serial run
    in this process. Nothing without a topic."""
    if topic is None:
        return
    try:
        worker = distributed.get_worker()
    except ValueError:  # not on a worker: a serial run here
        hook = _serial_step_hooks.get(topic)
        if hook is not None:
            hook()
        return
    worker.log_event(topic, 1)


def trace_steps_task(scene: Scene, settings: TraceSettings, times,
                     links=None, steps_topic: str | None = None
                     ) -> tuple[list[Snapshot], list[float]]:
    """Consecutive steps of a drive on this process's device, through one
    :class:`~clradcom.mechanisms.common.GeometryCache` (:func:`clradcom.series.
    trace_steps`): the snapshots and each step's seconds (the first with the cache's
    build). With ``steps_topic`` each step traced is announced at once (an event of that
    topic; :func:`run_drive`'s ``traced``), not only when the whole chunk returns."""
    seconds: list[float] = []
    clock = [time.perf_counter()]

    def each(k, t, snap):
        now = time.perf_counter()
        seconds.append(now - clock[0])
        clock[0] = now
        _step_traced(steps_topic)

    snaps = trace_steps(scene, settings, times, runtime=worker_runtime(), links=links,
                        each=each)
    return snaps, seconds


def steps_per_task(n_steps: int, workers: int) -> int:
    """The default chunk of a drive: the steps shared out evenly, one task per worker
    (each builds its :class:`~clradcom.mechanisms.common.GeometryCache` once; docs/scale.md
    has the measurement behind this choice)."""
    return max(1, math.ceil(n_steps / max(1, workers)))


def drive_tasks(scene: Scene, settings: TraceSettings, times=None, *, chunk: int = 1,
                links=None, steps_topic: str | None = None) -> list[Task]:
    """A drive as tasks: ``times`` (default the scene's ``[time]`` table) cut into runs of
    ``chunk`` consecutive steps, one :func:`trace_steps_task` each, keyed
    ``steps-FIRST-LAST`` (step numbers)."""
    if not isinstance(scene, Scene):
        raise ArgumentTypeError("must be a Scene", argument="scene", value=scene)
    if not isinstance(settings, TraceSettings):
        raise ArgumentTypeError("must be a TraceSettings", argument="settings", value=settings)
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ArgumentError("must be a positive integer", argument="chunk", value=chunk)
    t = check_times(scene, times)
    kwargs = {} if links is None else {"links": links}
    if steps_topic is not None:
        kwargs["steps_topic"] = steps_topic
    return [Task(f"steps-{a:05d}-{min(a + chunk, t.size) - 1:05d}", trace_steps_task,
                 (scene, settings, t[a:a + chunk]), kwargs)
            for a in range(0, t.size, chunk)]


# ----------------------------------------------------------------------------------------
# the client side
# ----------------------------------------------------------------------------------------
def local_cluster(workers: int, *, retries: int = 2, threads_per_worker: int | None = None,
                  **kwargs) -> distributed.LocalCluster:
    """A ``LocalCluster`` of ``workers`` processes with one thread each, no dashboard
    (its scheduler's HTTP routes on a free port, so that two runs at once do not meet on
    Dask's 8787), its scheduler allowing a task ``retries`` worker deaths. On PoCL each
    worker's CPU
    device gets ``threads_per_worker`` threads (default: the cores shared out evenly;
    an explicit ``POCL_MAX_PTHREAD_COUNT`` in the environment wins)."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ArgumentError("must be a positive integer", argument="workers", value=workers)
    check_workers(workers)
    _check_retries(retries)
    env = dict(kwargs.pop("env", {}))
    if POCL_THREADS_ENV not in os.environ:
        threads = threads_per_worker or max(1, (os.cpu_count() or 1) // workers)
        env.setdefault(POCL_THREADS_ENV, str(threads))
    with dask.config.set({ALLOWED_FAILURES: retries}), _interrupts_ignored():
        return distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
            scheduler_kwargs={"dashboard": False, "dashboard_address": ":0"}, env=env,
            **kwargs)


@contextlib.contextmanager
def _interrupts_ignored():
    """SIGINT ignored while the cluster's processes start, so that they inherit it
    ignored (Python leaves an ignored SIGINT so): Ctrl-C at a terminal then interrupts
    this process alone, which stops the cluster, instead of every worker printing its
    own KeyboardInterrupt traceback. Elsewhere than the main thread, nothing changes."""
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread: signals are not ours to set
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _check_retries(retries) -> None:
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ArgumentError("must be an integer >= 0", argument="retries", value=retries)


def _shared_args(client, tasks: Sequence[Task]) -> dict[int, object]:
    """Arguments that several tasks share (the same object, a scene): shipped once as a
    task of their own, which the scheduler can run again when the worker holding the
    value dies (a scattered value would be lost with it)."""
    seen: dict[int, object] = {}
    count: dict[int, int] = {}
    for task in tasks:
        for value in (*task.args, *task.kwargs.values()):
            if isinstance(value, str | bytes | int | float | bool | type(None)):
                continue
            seen[id(value)] = value
            count[id(value)] = count.get(id(value), 0) + 1
    return {i: client.submit(_identity, seen[i], pure=False,
                             key=f"clradcom-shared-{uuid.uuid4().hex[:12]}")
            for i, n in count.items() if n > 1}


def _identity(value):
    return value


def _reraise_warnings(result: TaskResult) -> None:
    for category, message, filename, lineno in result.warnings:
        warnings.warn_explicit(message, category, filename, lineno)


def run_tasks(tasks: Sequence[Task], *, workers: int = 2, scheduler: str | None = None,
              client=None, devices: Sequence[str] | None = None, retries: int = 2,
              on_result: Callable[[int, TaskResult], None] | None = None,
              keep: bool = True) -> list[TaskResult]:
    """Run ``tasks`` and return their :class:`TaskResult` in task order.

    Where: ``client`` (a ``distributed.Client`` the caller holds, e.g. one cluster for
    many sweeps), else ``scheduler`` (an address: workers started elsewhere with ``dask
    worker ADDRESS``), else a local cluster of ``workers`` processes started and stopped
    here; ``workers=0`` runs them one after the other in this process, without Dask.
    ``devices``: device specs shared out over the workers (:class:`DevicePlugin`).
    ``retries``: further attempts of a task that raised, and (local cluster) worker
    deaths a task may cause, before :class:`TaskError`. ``on_result(index, result)``
    hears each result as it arrives (in completion order), e.g. to write it out; with
    ``keep=False`` the results returned then hold no value (a long sweep's snapshots are
    not all held in memory)."""
    tasks = list(tasks)
    for task in tasks:
        if not isinstance(task, Task):
            raise ArgumentTypeError("must hold Task records", argument="tasks", value=task)
    if len({t.key for t in tasks}) != len(tasks):
        raise ArgumentError("task keys must be distinct", argument="tasks",
                            value=[t.key for t in tasks])
    with connect(workers, scheduler=scheduler, client=client, retries=retries) as own:
        if own is None:
            return _run_serial(tasks, devices, on_result, keep)
        return _run_on(own, tasks, devices, retries, on_result, keep)


@contextlib.contextmanager
def connect(workers: int = 2, *, scheduler: str | None = None, client=None,
            retries: int = 2):
    """The ``distributed.Client`` a run uses (:func:`run_tasks` has the rules): the
    caller's ``client``, one on ``scheduler``, or one on a local cluster of ``workers``
    processes (started here, stopped on leaving); None for ``workers=0`` (serial)."""
    _check_retries(retries)
    check_workers(workers)
    if client is not None:
        yield client
    elif scheduler is not None:
        check_scheduler_address(scheduler)
        try:
            own = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            raise ArgumentError(f"no Dask scheduler answered there within "
                                f"{CONNECT_TIMEOUT_S:g} s ({type(exc).__name__}); start one "
                                "(dask scheduler) or check the address", argument="scheduler",
                                value=scheduler) from None
        with own:
            yield own
    elif workers == 0:
        yield None
    else:
        with local_cluster(workers, retries=retries) as cluster, \
                distributed.Client(cluster) as own:
            yield own


def worker_count(client) -> int:
    """Workers connected to ``client``'s scheduler (1 for None: this process)."""
    return 1 if client is None else max(1, len(client.scheduler_info()["workers"]))


def run_drive(scene: Scene, settings: TraceSettings, times=None, *, workers: int = 2,
              scheduler: str | None = None, client=None,
              devices: Sequence[str] | None = None, retries: int = 2, links=None,
              chunk: int | None = None,
              each: Callable[[int, float, Snapshot, float], None] | None = None,
              traced: Callable[[], None] | None = None,
              ) -> tuple[list[Snapshot], list[float]]:
    """A drive (``scene`` at every instant of ``times``) traced as :func:`drive_tasks` on
    Dask (where: as :func:`run_tasks`; ``workers=0`` serially here): every step's
    snapshot, in step order, and its seconds on its worker. ``chunk``: steps per task
    (default :func:`steps_per_task` over the workers there are). ``each(step, t,
    snapshot, seconds)`` hears the steps in step order as soon as every earlier one is
    in. ``traced()`` hears every step as its worker finishes it, in no order and while
    its chunk still runs (a progress bar's tick: a chunk's snapshots come back whole). The
    snapshots equal :func:`clradcom.series.trace_steps`'s bit for bit (the
    GeometryCache's refit does not depend on where a chunk starts, docs/series.md)."""
    t = check_times(scene, times)
    topic = None if traced is None else f"clradcom-steps-{uuid.uuid4().hex}"
    with connect(workers, scheduler=scheduler, client=client, retries=retries) as own, \
            _step_events(own, topic, traced, t.size):
        size = steps_per_task(t.size, worker_count(own)) if chunk is None else chunk
        tasks = drive_tasks(scene, settings, t, chunk=size, links=links, steps_topic=topic)
        held: dict[int, TaskResult] = {}
        snaps: list[Snapshot] = []
        seconds: list[float] = []

        def arrived(i, result):  # chunk i is in: hand on every step now in order
            held[i] = result
            while len(snaps) < t.size and len(snaps) // size in held:
                got, secs = held.pop(len(snaps) // size).value
                for snap, s in zip(got, secs, strict=True):
                    k = len(snaps)
                    if each is not None:
                        each(k, float(t[k]), snap, s)
                    snaps.append(snap)
                    seconds.append(s)

        run_tasks(tasks, workers=0, client=own, devices=devices, retries=retries,
                  on_result=arrived, keep=False)
    return snaps, seconds


#: how long a drive whose chunks are all back waits for step events still on their way
#: from the scheduler (they travel apart from the results)
STEP_EVENTS_GRACE_S = 5.0


@contextlib.contextmanager
def _step_events(client, topic: str | None, traced: Callable[[], None] | None,
                 expected: int):
    """While a drive runs, its workers' step events (``topic``) reach ``traced``: through
    the client's subscription, or in this process for a serial run (``client`` None).
    On a normal exit the ``expected`` events have all been heard (or
    :data:`STEP_EVENTS_GRACE_S` has passed)."""
    if topic is None:
        yield
        return
    if client is None:
        _serial_step_hooks[topic] = traced
        try:
            yield
        finally:
            del _serial_step_hooks[topic]
        return
    heard = [0]

    def hear(event) -> None:
        heard[0] += 1
        traced()

    client.subscribe_topic(topic, hear)
    try:
        yield
        deadline = time.monotonic() + STEP_EVENTS_GRACE_S
        while heard[0] < expected and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        client.unsubscribe_topic(topic)


def _raise_refusal(task: Task, value) -> None:
    """A task's refusal, worded as the serial run words it wherever the task ran."""
    if isinstance(value, _Refused):
        exc = value.error
        raise TaskError(f"task {task.key!r} failed: {type(exc).__name__}: {exc}",
                        key=task.key) from None


def _run_serial(tasks, devices, on_result, keep) -> list[TaskResult]:
    global _worker_device
    old = _worker_device
    _worker_device = devices[0] if devices else old
    try:
        out = []
        for i, task in enumerate(tasks):
            try:
                value, seconds, name, caught = _run(task.fn, task.args, task.kwargs)
            except Exception as exc:
                raise TaskError(f"task {task.key!r} failed: {type(exc).__name__}: {exc}",
                                key=task.key) from exc
            _raise_refusal(task, value)
            result = TaskResult(task.key, value, seconds, name, caught)
            _reraise_warnings(result)
            if on_result is not None:
                on_result(i, result)
            out.append(result if keep else dataclasses.replace(result, value=None))
        return out
    finally:
        _worker_device = old


def _run_on(client, tasks, devices, retries, on_result, keep) -> list[TaskResult]:
    if _quiet_logs:
        client.register_plugin(QuietHangUps())
    client.register_plugin(DevicePlugin(devices))
    shared = _shared_args(client, tasks)

    def ship(value):
        return shared.get(id(value), value)

    run_id = uuid.uuid4().hex[:8]
    futures = [client.submit(_run, task.fn, tuple(ship(a) for a in task.args),
                             {k: ship(v) for k, v in task.kwargs.items()},
                             key=f"clradcom-{task.key}-{run_id}", pure=False,
                             retries=retries)
               for task in tasks]
    index = {f.key: i for i, f in enumerate(futures)}
    out: list[TaskResult | None] = [None] * len(tasks)
    try:
        for future in distributed.as_completed(futures):
            i = index[future.key]
            task = tasks[i]
            try:
                value, seconds, name, caught = future.result()
            except distributed.KilledWorker as exc:
                raise TaskError(
                    f"task {task.key!r}: its worker died more often than the retry bound "
                    f"allows ({exc})", key=task.key) from exc
            except Exception as exc:
                raise TaskError(f"task {task.key!r} failed after {retries + 1} attempts: "
                                f"{type(exc).__name__}: {exc}", key=task.key) from None
            _raise_refusal(task, value)
            result = TaskResult(task.key, value, seconds, name, caught)
            _reraise_warnings(result)
            if on_result is not None:
                on_result(i, result)
            out[i] = result if keep else dataclasses.replace(result, value=None)
            future.release()
    finally:
        client.cancel([f for f in futures if not f.done()])
    return out
