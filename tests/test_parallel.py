"""clradcom.parallel: host work split over threads gives the rows of one call, in order."""

from __future__ import annotations

import numpy as np
import pytest

import clradcom.parallel as parallel
from clradcom.maps import _cap_with_field
from clradcom.scene.antenna import SectorPattern


@pytest.fixture(params=[1, 4], ids=["one thread", "four threads"])
def threads(request, monkeypatch):
    monkeypatch.setattr(parallel, "host_threads", lambda: request.param)
    return request.param


def test_pieces_are_the_rows_of_one_call(threads):
    rng = np.random.default_rng(3)
    a = rng.normal(size=(100_003, 3))
    b = rng.normal(size=100_003)

    def rowwise(x, y):
        return np.sin(x[:, 0]) * y + np.hypot(x[:, 1], x[:, 2])

    got = parallel.in_pieces(rowwise, a, b, piece=1000)
    assert np.array_equal(got, rowwise(a, b))
    order = rng.permutation(len(a))
    assert np.array_equal(parallel.take_rows(a, order, piece=777), a[order])
    assert list(parallel.map_in_order(lambda i: i * i, range(50))) == [i * i for i in
                                                                       range(50)]


def test_a_launch_lattice_is_the_same_on_any_number_of_threads(monkeypatch):
    pattern = SectorPattern(azimuth_width_deg=90.0, elevation_width_deg=60.0)
    monkeypatch.setattr(parallel, "host_threads", lambda: 1)
    one = _cap_with_field(300_000, pattern)
    monkeypatch.setattr(parallel, "host_threads", lambda: 4)
    four = _cap_with_field(300_000, pattern)
    assert one[1] == four[1]
    for k in (0, 2, 3):   # directions, field, Morton codes
        assert np.array_equal(one[k], four[k])
    assert len(one[0]) > 100_000


def test_host_threads_is_bounded():
    assert 1 <= parallel.host_threads() <= parallel.MAX_HOST_THREADS


def test_prefetch_keeps_order_raises_where_the_producer_failed_and_stops_early(threads):
    assert list(parallel.prefetch(iter(range(100)), depth=2)) == list(range(100))

    def failing():
        yield 1
        yield 2
        raise ValueError("the producer's own error")

    got = []
    with pytest.raises(ValueError, match="the producer's own error"):
        for item in parallel.prefetch(failing()):
            got.append(item)
    assert got == [1, 2]

    made = []

    def endless():
        for i in range(10_000):
            made.append(i)
            yield i

    stream = parallel.prefetch(endless(), depth=1)
    assert [next(stream) for _ in range(3)] == [0, 1, 2]
    stream.close()
    # the producer stopped within its depth and the item it was making
    assert len(made) <= 6
