"""A snapshot for other tools: MATLAB ``.mat`` files and Sionna-style channel arrays.

* :func:`sionna_arrays` -- every link's paths as arrays laid out like Sionna RT's
  (``a``, ``tau``, angles of departure and arrival, ``[num_rx, num_tx, num_paths]``) and
  the channel frequency response ``h_freq`` at given frequencies,
  H(f) = sum_k a_k exp(-j 2 pi f tau_k) (:func:`channel_frequency_response`);
  :func:`save_sionna` writes them as a plain ``.npz``.
* :func:`mat_variables` / :func:`save_mat` -- the whole snapshot as MATLAB variables
  (scipy.io.savemat, MAT 5): scene scalars, object names and one struct per link.

docs/snapshot-format.md ("Exports") lists every variable and array. Both files are
written atomically (:func:`clradcom.files.atomic_write`) and byte-identically for the
same snapshot (the MAT header's creation date is replaced by a fixed text).
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from clradcom.errors import ArgumentError, ArgumentTypeError
from clradcom.files import atomic_write, write_csv
from clradcom.maps import MapGrid
from clradcom.paths import interaction_patterns
from clradcom.snapshot import FORMAT_VERSION, Snapshot, write_npz

__all__ = ["channel_frequency_response", "map_geotransform", "save_map_csv", "save_map_npz",
           "mat_variables", "save_mat", "save_sionna",
           "sionna_arrays"]

#: Paths summed per block in channel_frequency_response (bounds its temporary memory to
#: block x frequencies complex numbers).
_CFR_BLOCK = 2048

#: The 116-byte descriptive text at the head of every MAT file clradcom writes (scipy
#: puts the creation date there; a fixed text keeps identical snapshots identical).
MAT_HEADER_TEXT = b"MATLAB 5.0 MAT-file, written by clradcom.export (docs/snapshot-format.md)"


def _check_snapshot(snapshot) -> Snapshot:
    if not isinstance(snapshot, Snapshot):
        raise ArgumentTypeError("must be a Snapshot (clradcom.snapshot.load_snapshot reads "
                                "one)", argument="snapshot", value=snapshot)
    return snapshot


def _check_frequencies(frequencies_hz) -> np.ndarray:
    try:
        f = np.asarray(frequencies_hz, dtype=np.float64)
    except (TypeError, ValueError):
        raise ArgumentError("must be a 1-D array of frequencies in Hz",
                            argument="frequencies_hz", value=frequencies_hz) from None
    if f.ndim != 1 or f.size == 0:
        raise ArgumentError(f"must be a non-empty 1-D array of frequencies in Hz, got shape "
                            f"{f.shape}", argument="frequencies_hz", value=frequencies_hz)
    bad = np.flatnonzero(~np.isfinite(f))
    if bad.size:
        raise ArgumentError(f"must be finite, got {f[bad[0]]!r} at index {bad[0]}",
                            argument="frequencies_hz", value=frequencies_hz)
    return f


def channel_frequency_response(gains, delays_s, frequencies_hz) -> np.ndarray:
    """H(f) = sum_k a_k exp(-j 2 pi f tau_k) at every frequency (complex128, shape (F,)).

    With clradcom's gains (carrier phase -2 pi f_c tau inside) and ``f`` the offset from
    the carrier (baseband, e.g. subcarrier n at n * delta_f), H(f) is the channel at the
    radio frequency f_c + f, Doppler phases taken at the snapshot's instant. The phase
    2 pi f tau is formed in float64 from the exact product, so it holds for delays of
    microseconds at GHz offsets.
    """
    a = np.asarray(gains, dtype=np.complex128).ravel()
    tau = np.asarray(delays_s, dtype=np.float64).ravel()
    if a.shape != tau.shape:
        raise ArgumentError(f"gains ({a.size}) and delays_s ({tau.size}) differ in length",
                            argument="delays_s", value=tau.size)
    f = _check_frequencies(frequencies_hz)
    _check_phase_cycles(f, tau)
    h = np.zeros(f.size, dtype=np.complex128)
    for start in range(0, a.size, _CFR_BLOCK):
        sl = slice(start, start + _CFR_BLOCK)
        cycles = np.multiply.outer(f, tau[sl])  # (F, block) f * tau in cycles
        cycles -= np.round(cycles)  # exact reduction keeps the phase small and accurate
        with np.errstate(over="ignore", invalid="ignore"):
            h += np.exp(-2j * np.pi * cycles) @ a[sl]
    if not np.all(np.isfinite(h)):
        with np.errstate(over="ignore"):
            largest = float(np.abs(a).max())
        raise ArgumentError(f"the sum of the paths' gains (largest |a| = {largest!r}) "
                            f"overflows float64", argument="gains", value=largest)
    return h


def _radar_axes(snapshot: Snapshot):
    """Transmitters and receivers of the snapshot's links, ordered by radar index."""
    tx = sorted({(lk.tx_index, lk.tx_name) for lk in snapshot.links})
    rx = sorted({(lk.rx_index, lk.rx_name) for lk in snapshot.links})
    return tx, rx


def sionna_arrays(snapshot: Snapshot, frequencies_hz=None, *,
                  carrier_phase: bool = True,
                  normalize_delays: bool = False) -> dict[str, np.ndarray]:
    """Every link's paths laid out like Sionna RT's ``Paths`` (single antennas).

    Returns a dict of arrays: ``a`` complex128 and ``tau``, ``doppler_hz``, ``theta_t``,
    ``phi_t``, ``theta_r``, ``phi_r`` float64 of shape ``[num_rx, num_tx, max_num_paths]``
    (Sionna's ``[num_rx, num_rx_ant, num_tx, num_tx_ant, num_paths]`` without the antenna
    axes: ``np.expand_dims(a, (1, 3))`` restores them); ``valid`` bool of that shape
    (padding slots hold a = 0, tau = -1, Doppler and angles 0, as Sionna pads);
    ``tx_names``, ``rx_names``, ``tx_index``, ``rx_index`` (the radars along the axes);
    ``carrier_hz``, ``time_s``; and with ``frequencies_hz`` (1-D, Hz) also
    ``frequencies_hz``, ``normalize_delays`` and ``h_freq`` complex128 ``[num_rx,
    num_tx, num_frequencies]``: the channel at the radio frequencies f_c + f for
    baseband offsets f, H(f) = sum over the valid paths of g exp(-j 2 pi f tau) with
    clradcom's gains g (carrier phase inside; :func:`channel_frequency_response`), which
    is Sionna RT's ``Paths.cfr(f, normalize_delays=False)``.

    ``carrier_phase=True`` (default) exports clradcom's gain as ``a``: the carrier phase
    -2 pi f_c tau is inside. ``carrier_phase=False`` exports a = g exp(+j 2 pi f_c tau),
    Sionna RT's passband ``Paths.a`` (its ``cir()`` puts the carrier phase back); it
    changes ``a`` only, never ``h_freq``. ``normalize_delays=True`` gives ``h_freq`` as
    Sionna's ``cfr()`` with its default ``normalize_delays=True``: every link's delays less
    its first path's, in the carrier phase too, which turns the link's H by
    exp(+j 2 pi (f_c + f) tau_min) (docs/snapshot-format.md, "Sionna's cfr()").
    """
    snapshot = _check_snapshot(snapshot)
    for name, flag in (("carrier_phase", carrier_phase),
                       ("normalize_delays", normalize_delays)):
        if not isinstance(flag, bool | np.bool_):
            raise ArgumentTypeError("must be True or False", argument=name, value=flag)
    f = None if frequencies_hz is None else _check_frequencies(frequencies_hz)
    tx, rx = _radar_axes(snapshot)
    t_pos = {name: i for i, (_, name) in enumerate(tx)}
    r_pos = {name: i for i, (_, name) in enumerate(rx)}
    n_max = max((lk.paths.n_paths for lk in snapshot.links), default=0)
    shape = (len(rx), len(tx), n_max)
    out = {
        "a": np.zeros(shape, np.complex128),
        "tau": np.full(shape, -1.0),
        "doppler_hz": np.zeros(shape),
        "theta_t": np.zeros(shape), "phi_t": np.zeros(shape),
        "theta_r": np.zeros(shape), "phi_r": np.zeros(shape),
        "valid": np.zeros(shape, bool),
    }
    for lk in snapshot.links:
        p = lk.paths
        r, t, n = r_pos[lk.rx_name], t_pos[lk.tx_name], p.n_paths
        a = p.gain if carrier_phase else p.gain * np.exp(
            2j * np.pi * _reduced_cycles(snapshot.carrier_hz, p.delay_s))
        out["a"][r, t, :n] = a
        out["tau"][r, t, :n] = p.delay_s
        out["doppler_hz"][r, t, :n] = p.doppler_hz
        for name, values in p.angles._asdict().items():
            out[name][r, t, :n] = values
        out["valid"][r, t, :n] = True
    out["tx_names"] = np.array([name for _, name in tx], dtype=np.str_).reshape(len(tx))
    out["rx_names"] = np.array([name for _, name in rx], dtype=np.str_).reshape(len(rx))
    out["tx_index"] = np.array([i for i, _ in tx], dtype=np.int64)
    out["rx_index"] = np.array([i for i, _ in rx], dtype=np.int64)
    out["carrier_hz"] = np.array(snapshot.carrier_hz)
    out["time_s"] = np.array(snapshot.time_s)
    if f is not None:
        h = np.zeros((len(rx), len(tx), f.size), np.complex128)
        for lk in snapshot.links:
            h[r_pos[lk.rx_name], t_pos[lk.tx_name]] = _link_cfr(
                lk.paths, f, snapshot.carrier_hz, bool(normalize_delays))
        out["frequencies_hz"] = f.copy()
        out["normalize_delays"] = np.array(bool(normalize_delays))
        out["h_freq"] = h
    return out


def _link_cfr(paths, frequencies_hz, carrier_hz: float, normalize_delays: bool):
    """One link's channel at f_c + f from its gains (carrier phase inside); with
    ``normalize_delays`` Sionna's default: tau -> tau - tau_min in the carrier phase and
    in the baseband one, i.e. the gains turned by exp(+j 2 pi f_c tau_min) and the delays
    less tau_min."""
    gain, tau = paths.gain, paths.delay_s
    if normalize_delays and tau.size:
        tau_min = float(tau.min())
        gain = gain * np.exp(2j * np.pi * _reduced_cycles(carrier_hz,
                                                          np.array([tau_min]))[0])
        tau = tau - tau_min
    return channel_frequency_response(gain, tau, frequencies_hz)


def _check_phase_cycles(frequencies_hz: np.ndarray, delays_s: np.ndarray) -> None:
    """Refuse delays and frequencies whose product f * tau (the phase in cycles)
    overflows float64: its phase would be NaN (a delay of 1e300 s, found by
    tests/test_fuzz_imports.py)."""
    if frequencies_hz.size == 0 or delays_s.size == 0:
        return
    f_max = float(np.max(np.abs(frequencies_hz)))
    tau = np.abs(delays_s)
    with np.errstate(over="ignore", invalid="ignore"):
        bad = np.flatnonzero(~np.isfinite(tau * f_max))
    if bad.size:
        raise ArgumentError(f"delay {delays_s[bad[0]]!r} s times frequency {f_max!r} Hz "
                            f"overflows: no phase can be formed", argument="delays_s",
                            value=float(delays_s[bad[0]]))


def _reduced_cycles(frequency_hz: float, delays_s: np.ndarray) -> np.ndarray:
    delays_s = np.asarray(delays_s, dtype=np.float64)
    _check_phase_cycles(np.array([frequency_hz]), delays_s)
    cycles = frequency_hz * delays_s
    return cycles - np.round(cycles)


def save_sionna(path: str | os.PathLike, snapshot: Snapshot, frequencies_hz=None, *,
                carrier_phase: bool = True, normalize_delays: bool = False,
                inputs=()) -> Path:
    """Write :func:`sionna_arrays` to ``path`` as an uncompressed ``.npz`` (plain
    ``numpy.load`` reads it), atomically and byte-identically for the same input (keys
    in sorted order). Returns the path."""
    arrays = sionna_arrays(snapshot, frequencies_hz, carrier_phase=carrier_phase,
                           normalize_delays=normalize_delays)
    entries = sorted(arrays.items())
    return atomic_write(path, lambda fh: write_npz(fh, entries), inputs=inputs)


def _cell(strings) -> np.ndarray:
    """A MATLAB cell array (1 x n) of char rows."""
    cell = np.empty((1, len(strings)), dtype=object)
    for i, s in enumerate(strings):
        cell[0, i] = str(s)
    return cell


def mat_variables(snapshot: Snapshot) -> dict:
    """The snapshot as MATLAB variables (the dict scipy.io.savemat writes).

    Scalars ``scene_name``, ``scene_hash``, ``carrier_hz``, ``time_s``,
    ``snapshot_format_version``; cell arrays ``object_names`` (``object_id + 1`` indexes
    it in MATLAB), ``metadata_keys`` and ``metadata_values`` (values as text); ``links``:
    a 1 x L cell array of structs with ``tx_name``, ``rx_name``, ``tx_index``,
    ``rx_index`` (0-based radar indices), ``a`` (P x 1 complex gains), ``tau`` (s),
    ``doppler_hz``, ``matrix`` (P x 2 x 2), ``n_interactions``, ``interaction`` (P x K
    codes), ``pattern`` (cell of letters such as 'RD'), ``points`` (P x (K+2) x 3, NaN
    padded), ``object_id``, ``face_id`` (0-based, -1 padded), ``theta_t``, ``phi_t``,
    ``theta_r``, ``phi_r`` (rad).
    """
    snapshot = _check_snapshot(snapshot)
    links = np.empty((1, len(snapshot.links)), dtype=object)
    for i, lk in enumerate(snapshot.links):
        p = lk.paths
        ang = p.angles
        links[0, i] = {
            "tx_name": lk.tx_name, "rx_name": lk.rx_name,
            "tx_index": np.int64(lk.tx_index), "rx_index": np.int64(lk.rx_index),
            "a": p.gain.reshape(-1, 1), "tau": p.delay_s.reshape(-1, 1),
            "doppler_hz": p.doppler_hz.reshape(-1, 1), "matrix": p.matrix,
            "n_interactions": p.n_interactions.reshape(-1, 1),
            "interaction": p.interaction, "pattern": _cell(interaction_patterns(p)).T,
            "points": p.points, "object_id": p.object_id, "face_id": p.face_id,
            "theta_t": ang.theta_t.reshape(-1, 1), "phi_t": ang.phi_t.reshape(-1, 1),
            "theta_r": ang.theta_r.reshape(-1, 1), "phi_r": ang.phi_r.reshape(-1, 1),
        }
    return {
        "scene_name": snapshot.scene_name,
        "scene_hash": snapshot.scene_hash,
        "carrier_hz": np.float64(snapshot.carrier_hz),
        "time_s": np.float64(snapshot.time_s),
        "snapshot_format_version": np.int64(FORMAT_VERSION),
        "object_names": _cell(snapshot.object_names),
        "metadata_keys": _cell(list(snapshot.metadata)),
        "metadata_values": _cell([str(v) for v in snapshot.metadata.values()]),
        "links": links,
    }


def mat_bytes(snapshot: Snapshot) -> bytes:
    """The bytes of :func:`save_mat`'s file (MAT 5, compressed variables)."""
    from scipy.io import savemat  # scipy is a dependency; imported where it is used

    buffer = io.BytesIO()
    savemat(buffer, mat_variables(snapshot), do_compression=True, oned_as="column",
            long_field_names=True)
    data = bytearray(buffer.getvalue())
    data[:116] = MAT_HEADER_TEXT.ljust(116)  # the text header: no creation date
    return bytes(data)


def save_mat(path: str | os.PathLike, snapshot: Snapshot, *, inputs=()) -> Path:
    """Write the snapshot as a MATLAB ``.mat`` file (:func:`mat_variables`), atomically
    and byte-identically for the same snapshot. Returns the path."""
    data = mat_bytes(snapshot)
    return atomic_write(path, lambda fh: fh.write(data), inputs=inputs)


# ---------------------------------------------------------------------------------------
# radio maps


def map_geotransform(grid: MapGrid) -> np.ndarray:
    """GDAL's six-number affine geotransform of a map's rows and columns (GeoTIFF's
    georeference): x = g0 + col g1 + row g2, y = g3 + col g4 + row g5 at a cell's corner,
    here in the scene's own metres (row 0 is y_min: a north-up raster reads it flipped)."""
    return np.array([grid.x_min, grid.cell_m, 0.0, grid.y_min, 0.0, grid.cell_m])


def _map_layers(layers: dict, grid: MapGrid) -> list[tuple[str, np.ndarray]]:
    out = []
    for name, values in layers.items():
        arr = np.asarray(values)
        if arr.shape != (grid.ny, grid.nx):
            raise ArgumentError(f"must be a (ny, nx) = ({grid.ny}, {grid.nx}) array",
                                argument=f"layers[{name!r}]", value=arr.shape)
        out.append((name, arr))
    return out


def save_map_npz(path: str | os.PathLike, grid: MapGrid, layers: dict, *,
                 metadata: dict | None = None, inputs=()) -> Path:
    """A map's (ny, nx) ``layers`` (name -> array) with its georeference: ``x_centres``,
    ``y_centres``, ``geotransform`` (:func:`map_geotransform`), ``height_m``,
    ``thickness_m``, and ``metadata`` as ``meta.<key>`` strings; plain ``numpy.load``
    reads it; written atomically, identical bytes for identical maps."""
    entries = [("x_centres", grid.x_centres), ("y_centres", grid.y_centres),
               ("geotransform", map_geotransform(grid)),
               ("height_m", np.array(float(grid.height_m))),
               ("thickness_m", np.array(float(grid.thickness)))]
    entries += _map_layers(layers, grid)
    entries += [(f"meta.{k}", np.array(str(v))) for k, v in sorted((metadata or {}).items())]
    return atomic_write(path, lambda fh: write_npz(fh, entries), inputs=inputs)


def save_map_csv(path: str | os.PathLike, grid: MapGrid, layers: dict, *,
                 inputs=()) -> Path:
    """One row per cell: x, y, z of its centre (m) and each layer's value (NaN written
    as ``nan``), cells in row-major order from (x_min, y_min)."""
    named = _map_layers(layers, grid)
    centres = grid.centres().reshape(-1, 3)
    columns = [np.asarray(a).reshape(-1) for _, a in named]
    rows = []
    for i, (x, y, z) in enumerate(centres):
        rows.append([f"{x:.4f}", f"{y:.4f}", f"{z:.4f}",
                     *(f"{c[i]:.6g}" if np.issubdtype(c.dtype, np.floating) else str(c[i])
                       for c in columns)])
    return write_csv(path, rows, ["x_m", "y_m", "z_m", *(n for n, _ in named)],
                     inputs=inputs)
