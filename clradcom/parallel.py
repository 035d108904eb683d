"""Host-side work split over the machine's cores.

numpy lets go of the GIL inside its loops, so row-wise pure functions of large arrays
(a launch lattice's pattern field, the receive weights of a batch of segments) run on
several threads at once, in pieces whose results are put back in order: the same rows,
bit for bit, as one call over all of them. On a 2-core machine the OpenCL device (PoCL)
uses both cores while a kernel runs and the host's numpy one, so the host's share of a
radio map left one core idle.
"""

from __future__ import annotations

import os
import queue
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["MAX_HOST_THREADS", "host_threads", "in_pieces", "map_in_order", "prefetch",
           "take_rows"]

#: threads at most, whatever the machine: numpy's loops are memory-bound well before
MAX_HOST_THREADS = 8


def host_threads() -> int:
    """The cores this process may run on (its affinity where the OS tells it), at most
    :data:`MAX_HOST_THREADS`."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(1, min(MAX_HOST_THREADS, cores))


def map_in_order(fn: Callable, items: Iterable, threads: int | None = None) -> Iterator:
    """``fn(item)`` for each item on ``threads`` threads (None: :func:`host_threads`),
    yielded in the items' order, with at most ``threads`` items begun and not yet
    yielded (so at most that many results are held at once)."""
    threads = host_threads() if threads is None else max(1, min(int(threads),
                                                                host_threads()))
    if threads == 1:
        yield from map(fn, items)
        return
    with ThreadPoolExecutor(threads) as pool:
        pending: deque = deque()
        for item in items:
            if len(pending) == threads:
                yield pending.popleft().result()
            pending.append(pool.submit(fn, item))
        while pending:
            yield pending.popleft().result()


def in_pieces(fn: Callable, *arrays, piece: int = 1 << 16) -> np.ndarray:
    """``fn(*rows)`` over the arrays' first axis a ``piece`` of rows at a time on the
    host's threads, the pieces' results concatenated: for a function that maps each
    row on its own, the rows of ``fn(*arrays)``."""
    n = len(arrays[0])
    if n <= piece or host_threads() == 1:
        return fn(*arrays)
    starts = range(0, n, piece)
    return np.concatenate(list(map_in_order(
        lambda start: fn(*(a[start:start + piece] for a in arrays)), starts)))


def take_rows(a: np.ndarray, order: np.ndarray, piece: int = 1 << 18) -> np.ndarray:
    """``np.take(a, order, axis=0)`` filled a ``piece`` of rows at a time on the host's
    threads (a few million rows' gather is bound by paging in the new array)."""
    out = np.empty((len(order), *a.shape[1:]), dtype=a.dtype)
    if len(order) <= piece or host_threads() == 1:
        return np.take(a, order, axis=0, out=out)

    def fill(start):
        np.take(a, order[start:start + piece], axis=0, out=out[start:start + piece])

    for _ in map_in_order(fill, range(0, len(order), piece)):
        pass
    return out


_DONE = object()


def prefetch(iterable: Iterable, depth: int = 1) -> Iterator:
    """The items of ``iterable``, produced on a thread of their own up to ``depth`` items
    ahead of the one the caller works on: a device's next launch runs while the host
    weighs the last one's results. Items come in order; an exception raised by the
    iterable is raised here, at the item it stopped; closing this generator early stops
    the producer at its next item."""
    if host_threads() == 1:
        yield from iterable
        return
    items: queue.Queue = queue.Queue(maxsize=max(1, int(depth)))
    stop = threading.Event()

    def produce():
        try:
            for item in iterable:
                while not stop.is_set():
                    try:
                        items.put((item, None), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            items.put((_DONE, None))
        except BaseException as error:  # handed to the consumer, raised there
            items.put((_DONE, error))

    producer = threading.Thread(target=produce, name="clradcom-prefetch", daemon=True)
    producer.start()
    try:
        while True:
            item, error = items.get()
            if error is not None:
                raise error
            if item is _DONE:
                return
            yield item
    finally:
        stop.set()
        while producer.is_alive():
            try:   # let a producer blocked on a full queue see the stop
                items.get_nowait()
            except queue.Empty:
                pass
            producer.join(timeout=0.05)
