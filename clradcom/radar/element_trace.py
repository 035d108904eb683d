"""Exact per-element channels of a radar with arrays: the scene traced once per element
pair (docs/dsp.md §9, "Three ways to the per-element channel"; docs/snapshot-format.md,
"Element-pair snapshots").

The synthetic array and the path-length correction (:mod:`clradcom.radar.array`) start
from the paths of the radar's reference point. Here nothing is taken from them: every
transmit element becomes a transmit-only radar at its own world position and every
receive element a receive-only radar at its own, each with the radar's orientation,
velocity, power and noise figure and the element's own pattern and polarisation (the
radar's where the array gives none), and :func:`clradcom.trace.trace_scene` traces every
transmit element -> receive element link: E_tx launches of the tracer, E_tx·E_rx links.
Each link's paths are then exact for its two elements: image points, edge points,
visibility, spreading, patterns and the paths that exist at all are those of the element
positions, so this is the form for targets in the array's near field (D²/(λR) not small)
and for arrays large enough that a path may be seen by some elements and not by others.

The element radars are named ``<radar>/tx<i>`` and ``<radar>/rx<j>`` and appended to the
scene's radars (:func:`element_scene`); the links come back i-major (link i·E_rx + j is
element pair (i, j)). Line-of-sight paths between two elements of the same radar (the
direct coupling over a few centimetres, which the monostatic reference link does not
have) are left out.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from clradcom.errors import ArgumentError, SnapshotError
from clradcom.paths import Paths, select_paths
from clradcom.snapshot import Link, Snapshot
from clradcom.trace import trace_scene

__all__ = ["element_names", "element_pair_paths", "element_scene", "pair_channel_arrays",
           "trace_elements"]


def element_names(radar) -> tuple[list[str], list[str]]:
    """Names of the element radars of ``radar``: ``<name>/tx<i>``, ``<name>/rx<j>``."""
    et = 1 if radar.tx_array is None else radar.tx_array.n_elements
    er = 1 if radar.rx_array is None else radar.rx_array.n_elements
    return ([f"{radar.name}/tx{i}" for i in range(et)],
            [f"{radar.name}/rx{j}" for j in range(er)])


def _element_radars(scene, radar, layout, role, names):
    r = np.asarray(radar.orientation, dtype=np.float64)
    local = np.zeros((1, 3)) if layout is None else np.asarray(layout.positions_local)
    patterns = None if layout is None else layout.patterns
    out = []
    for e, name in enumerate(names):
        offset = r @ local[e]
        pos_local = np.asarray(radar.position_local, dtype=np.float64)
        if radar.rides_on >= 0:  # the element rides on the same object, offset in its frame
            rot = np.asarray(scene.objects[radar.rides_on].rotation, dtype=np.float64)
            pos_local = pos_local + rot.T @ offset
        pattern = radar.pattern if patterns is None else patterns[e]
        jones = np.asarray(pattern.polarization, dtype=np.complex128)
        out.append(dataclasses.replace(
            radar, name=name, position=np.asarray(radar.position, float) + offset,
            position_local=pos_local, pattern=pattern,
            polarization=radar.polarization if patterns is None else jones,
            polarization_name=radar.polarization_name if patterns is None else "element",
            role=role, tx_array=None, rx_array=None))
    return out


def element_scene(scene, radar_index: int):
    """(scene with the element radars appended, transmit element indices, receive element
    indices) for radar ``radar_index`` (module docstring)."""
    if isinstance(radar_index, bool) or not isinstance(radar_index, int | np.integer) \
            or not 0 <= radar_index < len(scene.radars):
        raise ArgumentError(f"must be a radar index of scene {scene.name!r}",
                            argument="radar_index", value=radar_index)
    radar = scene.radars[radar_index]
    if radar.tx_array is None and radar.rx_array is None:
        raise ArgumentError("has no tx_array/rx_array (or array): no elements to trace",
                            argument="radar", value=radar.name)
    if radar.role != "txrx":
        raise ArgumentError("must transmit and receive (role 'txrx') for its own echoes",
                            argument="radar", value=radar.name)
    tx_names, rx_names = element_names(radar)
    taken = {r.name for r in scene.radars} & set(tx_names + rx_names)
    if taken:
        raise ArgumentError("the scene already has a radar of an element's name",
                            argument="radar", value=sorted(taken)[0])
    tx = _element_radars(scene, radar, radar.tx_array, "tx", tx_names)
    rx = _element_radars(scene, radar, radar.rx_array, "rx", rx_names)
    n0 = len(scene.radars)
    new = dataclasses.replace(scene, radars=[*scene.radars, *tx, *rx])
    return (new, list(range(n0, n0 + len(tx))),
            list(range(n0 + len(tx), n0 + len(tx) + len(rx))))


def _without_direct_coupling(paths: Paths) -> Paths:
    keep = np.asarray(paths.n_interactions) > 0
    return paths if keep.all() else select_paths(paths, keep)


def trace_elements(scene, radar_index: int, settings=None, *, runtime=None,
                   progress=None, steps=None) -> Snapshot:
    """Trace every transmit element -> receive element link of radar ``radar_index``
    (module docstring). Returns a snapshot of the element scene (its ``scene_hash``)
    with the E_tx·E_rx links, i-major."""
    escene, txs, rxs = element_scene(scene, radar_index)
    links = [(i, j) for i in txs for j in rxs]
    snap = trace_scene(escene, settings, runtime=runtime, links=links, progress=progress,
                       steps=steps)
    out = tuple(Link(lk.tx_name, lk.rx_name, lk.tx_index, lk.rx_index,
                     _without_direct_coupling(lk.paths)) for lk in snap.links)
    return dataclasses.replace(snap, links=out)


def element_pair_paths(snapshot, radar) -> list[list[Paths]]:
    """The paths of every element pair of ``radar`` in an element-pair snapshot,
    [i][j] = transmit element i -> receive element j; a missing link is refused naming
    it."""
    tx_names, rx_names = element_names(radar)
    by_name = {(lk.tx_name, lk.rx_name): lk.paths for lk in snapshot.links}
    out = []
    for t in tx_names:
        row = []
        for r in rx_names:
            if (t, r) not in by_name:
                raise SnapshotError(f"holds no element link {t!r} -> {r!r}: trace the "
                                    "elements (clradcom cube --array-channel exact)",
                                    key="links")
            row.append(by_name[(t, r)])
        out.append(row)
    return out


def pair_channel_arrays(pair_paths):
    """Gains, delays (s) and Dopplers (Hz), each (E_tx, E_rx, P_max), of per-pair path
    lists, zero-gain padded where a pair has fewer paths (a padded path has delay 0 and
    Doppler 0 and adds nothing)."""
    et, er = len(pair_paths), len(pair_paths[0]) if pair_paths else 0
    p = max((len(pp.gain) for row in pair_paths for pp in row), default=0)
    g = np.zeros((et, er, p), complex)
    tau = np.zeros((et, er, p))
    fd = np.zeros((et, er, p))
    for i, row in enumerate(pair_paths):
        for j, pp in enumerate(row):
            k = len(pp.gain)
            g[i, j, :k], tau[i, j, :k], fd[i, j, :k] = pp.gain, pp.delay_s, pp.doppler_hz
    return g, tau, fd
