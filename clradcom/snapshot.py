"""Snapshots: the propagation paths of every tx -> rx link of a scene, as one file.

The tracer writes a :class:`Snapshot`; the radar back end reads it. On disk a snapshot is
an ``.npz`` archive (a zip of ``.npy`` members, stored or, on request, deflated) that plain
``numpy.load(path, allow_pickle=False)`` reads; ``docs/snapshot-format.md`` describes every
key. In memory:

* :class:`Paths` -- the paths of one link, as arrays of length ``P`` along axis 0
  (complex gain, 2x2 polarimetric matrix, delay, Doppler, interaction codes, points,
  object and face ids);
* :class:`Link` -- tx name/index, rx name/index and its :class:`Paths`;
* :class:`Snapshot` -- scene name, carrier, scene hash, scene time, the scene's object
  names, a metadata dict of scalars and the list of links.

The file also holds every path's angles of departure and arrival (computed from its
points by :func:`clradcom.paths.path_angles`), so that a reader with numpy alone has them.

:func:`save_snapshot` writes atomically (temporary file in the same directory, fsync,
``os.replace``) and deterministically: the same snapshot always gives the same bytes
(fixed member order, fixed zip timestamps, little-endian arrays, no compression unless
asked for, then a fixed deflate level).
:func:`load_snapshot` checks the format version, every key, dtype, shape and value, and
names the file and key of anything it refuses.
"""

from __future__ import annotations

import math
import os
import re
import zipfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clradcom.errors import ArgumentError, ArgumentTypeError, SnapshotError
from clradcom.files import atomic_write
from clradcom.paths import (
    PATH_FIELD_NAMES,
    PATH_FIELDS,
    InteractionType,
    PathAngles,
    Paths,
    path_angles,
    paths_difference,
)

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "InteractionType",
    "Link",
    "Paths",
    "Snapshot",
    "SnapshotError",
    "assert_snapshot_equal",
    "load_snapshot",
    "save_snapshot",
    "write_npz",
]

#: Value of the ``meta/format`` key: marks a file as a clradcom snapshot.
FORMAT_NAME = "clradcom-snapshot"
#: The format version this module writes (and the newest it reads).
FORMAT_VERSION = 3
#: Older versions load_snapshot still reads, converting them to FORMAT_VERSION: version 1
#: tagged physical-optics facet and SBR returns as REFLECTION (codes 4 and 5 came with 2);
#: versions 1 and 2 have no object names (read as none: unknown), an optional time
#: (read as 0 s when absent) and no angles (computed from the points on reading).
READABLE_VERSIONS = (1, 2, 3)
#: Per-path angle keys of a version-3 file (radians, world frame), in file order.
ANGLE_FIELD_NAMES = PathAngles._fields
#: Largest difference (rad) between a file's stored angles and those its points give.
ANGLE_TOLERANCE_RAD = 1e-9
#: zlib level of a compressed snapshot (fixed, so that one zlib gives one byte stream).
COMPRESS_LEVEL = 6

#: Fixed timestamp of every zip member, so identical snapshots give identical bytes.
_ZIP_DATE_TIME = (1980, 1, 1, 0, 0, 0)
#: Unix permission bits recorded in every zip member (what numpy.savez records).
_ZIP_EXTERNAL_ATTR = 0o600 << 16

_HEX = re.compile(r"[0-9a-fA-F]*")
_META_KEY = re.compile(r"[A-Za-z0-9_.\-]+")


# ---------------------------------------------------------------------------
# Link and Snapshot


def _check_name(value, key: str) -> str:
    if not isinstance(value, str):
        raise SnapshotError(f"must be a str, got {type(value).__name__} {value!r}", key=key)
    if "\x00" in value:
        raise SnapshotError(f"must not contain NUL characters: {value!r}", key=key)
    return value


def _check_index(value, key: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise SnapshotError(f"must be an int, got {type(value).__name__} {value!r}", key=key)
    if not 0 <= int(value) <= np.iinfo(np.int64).max:
        raise SnapshotError(f"must be >= 0, got {value}", key=key)
    return int(value)


@dataclass(frozen=True, eq=False)
class Link:
    """One transmitter -> receiver link: names and indices (in the scene's radar list)
    of both ends, and the link's :class:`Paths`. ``tx == rx`` is a monostatic radar."""

    tx_name: str
    rx_name: str
    tx_index: int
    rx_index: int
    paths: Paths

    def __post_init__(self) -> None:
        object.__setattr__(self, "tx_name", _check_name(self.tx_name, "tx_name"))
        object.__setattr__(self, "rx_name", _check_name(self.rx_name, "rx_name"))
        object.__setattr__(self, "tx_index", _check_index(self.tx_index, "tx_index"))
        object.__setattr__(self, "rx_index", _check_index(self.rx_index, "rx_index"))
        if not isinstance(self.paths, Paths):
            raise SnapshotError(f"must be a Paths, got {type(self.paths).__name__}",
                                key="paths")

    @property
    def label(self) -> str:
        return f"{self.tx_name}->{self.rx_name}"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Link):
            return NotImplemented
        return _link_difference(self, other) is None

    __hash__ = None


MetaValue = bool | int | float | str


def _check_metadata(metadata) -> dict[str, MetaValue]:
    if not isinstance(metadata, Mapping):
        raise SnapshotError(f"must be a dict, got {type(metadata).__name__}", key="metadata")
    out: dict[str, MetaValue] = {}
    for key in sorted(metadata, key=lambda k: (not isinstance(k, str), str(k))):
        value = metadata[key]
        if not isinstance(key, str) or not _META_KEY.fullmatch(key):
            raise SnapshotError(
                f"key {key!r} must be a non-empty str of letters, digits, '_', '.', '-'",
                key="metadata")
        kp = f"metadata.{key}"
        if isinstance(value, (bool, np.bool_)):
            out[key] = bool(value)
        elif isinstance(value, (int, np.integer)):
            if not np.iinfo(np.int64).min <= int(value) <= np.iinfo(np.int64).max:
                raise SnapshotError(f"int {value} does not fit in int64", key=kp)
            out[key] = int(value)
        elif isinstance(value, (float, np.floating)):
            out[key] = float(value)
        elif isinstance(value, str):
            out[key] = _check_name(value, kp)
        else:
            raise SnapshotError(
                f"value {value!r} of type {type(value).__name__}: only bool, int, float and "
                "str are stored", key=kp)
    return out


@dataclass(frozen=True, eq=False)
class Snapshot:
    """All links of one scene at one instant.

    Attributes
    ----------
    scene_name : str
    carrier_hz : float
        Carrier frequency f_c (Hz), finite and > 0.
    scene_hash : str
        Hex digest of the scene (:meth:`clradcom.scene.Scene.content_hash`); ``""`` for a
        snapshot not made from a scene (synthetic test data).
    links : tuple of Link
        At most one link per (tx_name, rx_name); a name always has the same index.
    time_s : float
        Scene time of the snapshot (s), finite; 0 by default (a static scene, or the
        instant the scene file describes).
    metadata : dict of str -> bool | int | float | str
        Tracer settings and provenance (``max_reflections``, ``rays``,
        ``clradcom_version`` ...). Stored sorted by key.
    object_names : tuple of str
        The scene's object names in scene order: ``object_id`` of a path indexes it.
        Empty when unknown (a synthetic snapshot, or a file of format 1 or 2); when given,
        every ``object_id`` of every link must index it.
    version : int
        Format version; only :data:`FORMAT_VERSION` can be built.
    """

    scene_name: str
    carrier_hz: float
    scene_hash: str
    links: tuple[Link, ...] = ()
    time_s: float = 0.0
    metadata: dict[str, MetaValue] = field(default_factory=dict)
    object_names: tuple[str, ...] = ()
    version: int = FORMAT_VERSION

    def __post_init__(self) -> None:
        if isinstance(self.version, bool) or not isinstance(self.version, (int, np.integer)) \
                or int(self.version) != FORMAT_VERSION:
            raise SnapshotError(
                f"only format version {FORMAT_VERSION} can be built, got {self.version!r}",
                key="version")
        object.__setattr__(self, "version", int(self.version))
        object.__setattr__(self, "scene_name", _check_name(self.scene_name, "scene_name"))
        carrier = _real_scalar(self.carrier_hz, "carrier_hz")
        if not (math.isfinite(carrier) and carrier > 0):
            raise SnapshotError(f"must be finite and > 0, got {self.carrier_hz!r}",
                                key="carrier_hz")
        object.__setattr__(self, "carrier_hz", carrier)
        h = _check_name(self.scene_hash, "scene_hash")
        if not _HEX.fullmatch(h):
            raise SnapshotError(f"must be a hex digest (or ''), got {h!r}", key="scene_hash")
        t = _real_scalar(self.time_s, "time_s")
        if not math.isfinite(t):
            raise SnapshotError(f"must be finite (s), got {self.time_s!r}", key="time_s")
        object.__setattr__(self, "time_s", t)
        object.__setattr__(self, "metadata", _check_metadata(self.metadata))
        if isinstance(self.object_names, str) or not isinstance(
                self.object_names, (list, tuple, np.ndarray)):
            raise SnapshotError(f"must be a list of str, got "
                                f"{type(self.object_names).__name__}", key="object_names")
        object.__setattr__(self, "object_names", tuple(
            _check_name(name, f"object_names[{i}]")
            for i, name in enumerate(self.object_names)))

        links = tuple(self.links)
        seen: dict[tuple[str, str], int] = {}
        name_to_index: dict[str, int] = {}
        index_to_name: dict[int, str] = {}
        for i, link in enumerate(links):
            if not isinstance(link, Link):
                raise SnapshotError(f"must be a Link, got {type(link).__name__}",
                                    key=f"links[{i}]")
            pair = (link.tx_name, link.rx_name)
            if pair in seen:
                raise SnapshotError(
                    f"link {link.label} appears twice (links[{seen[pair]}] and links[{i}])",
                    key=f"links[{i}]")
            seen[pair] = i
            ids = link.paths.object_id
            if self.object_names and ids.size and int(ids.max()) >= len(self.object_names):
                j = np.unravel_index(int(np.argmax(ids)), ids.shape)
                raise SnapshotError(
                    f"object id {int(ids[j])} at [{j[0]}, {j[1]}] has no name: the snapshot "
                    f"names {len(self.object_names)} objects", key=f"links[{i}].object_id")
            for name, idx, what in ((link.tx_name, link.tx_index, "tx"),
                                    (link.rx_name, link.rx_index, "rx")):
                if name_to_index.setdefault(name, idx) != idx:
                    raise SnapshotError(
                        f"{what} {name!r} has index {idx} here but {name_to_index[name]} in "
                        "an earlier link", key=f"links[{i}].{what}_index")
                if index_to_name.setdefault(idx, name) != name:
                    raise SnapshotError(
                        f"{what} index {idx} is {name!r} here but {index_to_name[idx]!r} in "
                        "an earlier link", key=f"links[{i}].{what}_name")
        object.__setattr__(self, "links", links)

    # -- conveniences ----------------------------------------------------------------

    def link(self, tx: str | int, rx: str | int) -> Link:
        """The link ``tx -> rx`` by names (or by radar indices when both are ints)."""
        by_index = isinstance(tx, (int, np.integer)) and isinstance(rx, (int, np.integer))
        for link in self.links:
            if by_index:
                if (link.tx_index, link.rx_index) == (int(tx), int(rx)):
                    return link
            elif (link.tx_name, link.rx_name) == (tx, rx):
                return link
        have = ", ".join(lk.label for lk in self.links) or "none"
        raise KeyError(f"snapshot {self.scene_name!r} has no link {tx!r} -> {rx!r} "
                       f"(links: {have})")

    def __iter__(self) -> Iterator[Link]:
        return iter(self.links)

    def __len__(self) -> int:
        return len(self.links)

    @property
    def total_paths(self) -> int:
        """Number of paths over all links."""
        return sum(link.paths.n_paths for link in self.links)

    def object_name(self, object_id: int) -> str:
        """The name of scene object ``object_id``, or ``"object <id>"`` when the snapshot
        has no names (format 1 or 2, synthetic)."""
        if self.object_names and 0 <= int(object_id) < len(self.object_names):
            return self.object_names[int(object_id)]
        return f"object {int(object_id)}"

    def summary(self) -> str:
        """A few lines for humans: links, path counts, strongest path (dB), delay span."""
        h = self.scene_hash[:12] if self.scene_hash else "none"
        names = (f"{len(self.object_names)} named objects" if self.object_names
                 else "object names unknown")
        lines = [
            f"snapshot of {self.scene_name!r} (v{self.version}, scene hash {h}), "
            f"carrier {self.carrier_hz / 1e9:.6g} GHz, t = {self.time_s:g} s",
            f"{len(self.links)} links, {self.total_paths} paths, {names}",
        ]
        if self.links:
            width = max(len(lk.label) for lk in self.links)
            width = max(width, len("link"))
            lines.append(f"  {'link':<{width}}  {'paths':>6}  {'max K':>5}  "
                         f"{'strongest dB':>12}  {'delay min..max ns':>21}")
            for lk in self.links:
                p = lk.paths
                if p.n_paths:
                    peak = float(np.max(np.abs(p.gain)))
                    db = 20 * math.log10(peak) if peak > 0 else -math.inf
                    dmin, dmax = float(p.delay_s.min()) * 1e9, float(p.delay_s.max()) * 1e9
                    kmax = int(p.n_interactions.max())
                    strongest = f"{db:12.2f}"
                    delays = f"{dmin:10.3f}..{dmax:<10.3f}"
                else:
                    kmax, strongest, delays = 0, f"{'-':>12}", f"{'-':>21}"
                lines.append(f"  {lk.label:<{width}}  {p.n_paths:>6}  {kmax:>5}  "
                             f"{strongest}  {delays}".rstrip())
        for key, value in self.metadata.items():
            lines.append(f"  {key} = {value!r}")
        return "\n".join(lines)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Snapshot):
            return NotImplemented
        return _snapshot_difference(self, other) is None

    __hash__ = None


def _real_scalar(value, key: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                      np.floating)):
        raise SnapshotError(f"must be a real number, got {type(value).__name__} {value!r}",
                            key=key)
    return float(value)


# ---------------------------------------------------------------------------
# exact comparison


def _link_difference(a: Link, b: Link) -> str | None:
    for name in ("tx_name", "rx_name", "tx_index", "rx_index"):
        if getattr(a, name) != getattr(b, name):
            return f"{name}: {getattr(a, name)!r} != {getattr(b, name)!r}"
    return paths_difference(a.paths, b.paths)


def _same_scalar(x, y) -> bool:
    if type(x) is not type(y):
        return False
    if isinstance(x, float):
        return x == y or (math.isnan(x) and math.isnan(y))
    return x == y


def _snapshot_difference(a: Snapshot, b: Snapshot) -> str | None:
    for name in ("version", "scene_name", "carrier_hz", "scene_hash", "time_s"):
        if not _same_scalar(getattr(a, name), getattr(b, name)):
            return f"{name}: {getattr(a, name)!r} != {getattr(b, name)!r}"
    if a.object_names != b.object_names:
        return f"object_names: {a.object_names!r} != {b.object_names!r}"
    if list(a.metadata) != list(b.metadata):
        return f"metadata keys: {sorted(a.metadata)} != {sorted(b.metadata)}"
    for key in a.metadata:
        if not _same_scalar(a.metadata[key], b.metadata[key]):
            return f"metadata.{key}: {a.metadata[key]!r} != {b.metadata[key]!r}"
    if len(a.links) != len(b.links):
        return f"number of links: {len(a.links)} != {len(b.links)}"
    for i, (la, lb) in enumerate(zip(a.links, b.links, strict=True)):
        diff = _link_difference(la, lb)
        if diff is not None:
            return f"links[{i}] ({la.label}).{diff}"
    return None


def assert_snapshot_equal(a: Snapshot, b: Snapshot) -> None:
    """Raise AssertionError naming the first difference unless ``a`` and ``b`` are
    exactly equal: same scalars, metadata (and types), link order, dtypes, shapes and
    array values (NaN equals NaN; +0.0 equals -0.0)."""
    diff = _snapshot_difference(a, b)
    if diff is not None:
        raise AssertionError(f"snapshots differ: {diff}")


# ---------------------------------------------------------------------------
# writing


def _scalar_array(value: MetaValue) -> np.ndarray:
    if isinstance(value, bool):
        return np.array(value, dtype=np.bool_)
    if isinstance(value, int):
        return np.array(value, dtype=np.int64)
    if isinstance(value, float):
        return np.array(value, dtype=np.float64)
    return np.array(value, dtype=np.str_)


def _str_array(values: list[str]) -> np.ndarray:
    if not values:
        return np.zeros(0, dtype="<U1")
    return np.array(values, dtype=np.str_)


def _entries(snapshot: Snapshot) -> list[tuple[str, np.ndarray]]:
    """Every (key, array) of the file, in file order."""
    out: list[tuple[str, np.ndarray]] = [
        ("meta/format", np.array(FORMAT_NAME)),
        ("meta/version", np.array(snapshot.version, dtype=np.int64)),
        ("meta/scene_name", np.array(snapshot.scene_name, dtype=np.str_)),
        ("meta/carrier_hz", np.array(snapshot.carrier_hz, dtype=np.float64)),
        ("meta/scene_hash", np.array(snapshot.scene_hash, dtype=np.str_)),
        ("meta/time_s", np.array(snapshot.time_s, dtype=np.float64)),
        ("meta/object_names", _str_array(list(snapshot.object_names))),
    ]
    for key in sorted(snapshot.metadata):
        out.append((f"metadata/{key}", _scalar_array(snapshot.metadata[key])))
    links = snapshot.links
    out += [
        ("links/tx_name", _str_array([lk.tx_name for lk in links])),
        ("links/rx_name", _str_array([lk.rx_name for lk in links])),
        ("links/tx_index", np.array([lk.tx_index for lk in links], dtype=np.int64)),
        ("links/rx_index", np.array([lk.rx_index for lk in links], dtype=np.int64)),
    ]
    for i, lk in enumerate(links):
        for name in PATH_FIELD_NAMES:
            out.append((f"link{i}/{name}", getattr(lk.paths, name)))
        for name, values in zip(ANGLE_FIELD_NAMES, path_angles(lk.paths), strict=True):
            out.append((f"link{i}/{name}", values))
    return out


def _write_member(zf: zipfile.ZipFile, key: str, array: np.ndarray,
                  compress: bool = False) -> None:
    """One ``key.npy`` member: fixed timestamp and attributes, little-endian, C order."""
    arr = np.asarray(array, order="C")  # (ascontiguousarray would make 0-d arrays 1-d)
    arr = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
    info = zipfile.ZipInfo(key + ".npy", date_time=_ZIP_DATE_TIME)
    info.compress_type = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    if compress:  # ZipInfo.compress_level from Python 3.13, _compresslevel before
        setattr(info, "compress_level" if hasattr(info, "compress_level")
                else "_compresslevel", COMPRESS_LEVEL)
    info.create_system = 3  # "unix", whatever the writing OS, for identical bytes
    info.external_attr = _ZIP_EXTERNAL_ATTR
    with zf.open(info, "w", force_zip64=True) as member:
        np.lib.format.write_array(member, arr, allow_pickle=False)


def write_npz(fileobj, entries, compress: bool = False) -> None:
    """Write ``(key, array)`` pairs as an ``.npz`` that plain ``numpy.load`` reads, the
    way snapshots are written: members in the given order, fixed timestamps, little-endian
    C-order arrays, stored (or deflated at :data:`COMPRESS_LEVEL`): identical arrays give
    identical bytes."""
    with zipfile.ZipFile(fileobj, "w", compression=zipfile.ZIP_STORED) as zf:
        for key, array in entries:
            _write_member(zf, key, array, compress)


def _write_zip(fileobj, snapshot: Snapshot, compress: bool = False) -> None:
    write_npz(fileobj, _entries(snapshot), compress)


def save_snapshot(path: str | os.PathLike, snapshot: Snapshot, *,
                  compress: bool = False) -> Path:
    """Write ``snapshot`` to ``path`` (an ``.npz`` zip; the name is used as given).

    ``compress=True`` deflates every member (zlib level :data:`COMPRESS_LEVEL`, what
    ``numpy.savez_compressed`` does): plain ``numpy.load`` still reads it; the bytes are
    then identical for identical snapshots on one zlib build (other zlib builds may
    deflate differently).

    Atomic (:func:`clradcom.files.atomic_write`): the data go to an unnamed temporary
    file in the same directory, which is fsynced, takes the permissions of the file it
    replaces and is then renamed over ``path``. On any error or interrupt (including
    KeyboardInterrupt) an existing file at ``path`` is left as it was and no temporary
    file remains. Deterministic: the same snapshot gives the same bytes.
    Returns ``path`` as a :class:`~pathlib.Path`.
    """
    if not isinstance(snapshot, Snapshot):
        raise TypeError(f"save_snapshot needs a Snapshot, got {type(snapshot).__name__}")
    if not isinstance(compress, bool | np.bool_):
        raise ArgumentTypeError(f"must be True or False, got {type(compress).__name__}",
                                argument="compress", value=compress)
    return atomic_write(path, lambda fh: _write_zip(fh, snapshot, bool(compress)))


# ---------------------------------------------------------------------------
# reading


class _Reader:
    """Checked access to the members of one npz file."""

    def __init__(self, path: Path, npz) -> None:
        self.path = path
        self.npz = npz
        self.keys = set(npz.files)
        self.used: set[str] = set()

    def err(self, key: str | None, reason: str) -> SnapshotError:
        return SnapshotError(reason, file=self.path, key=key)

    def get(self, key: str, kind: str, ndim: int | None = None,
            itemsize: int | None = None) -> np.ndarray:
        if key not in self.keys:
            raise self.err(key, "missing key (the file is incomplete or not a snapshot of "
                                "this format version)")
        self.used.add(key)
        try:
            arr = self.npz[key]
        except Exception as exc:
            raise self.err(key, f"cannot read the array ({type(exc).__name__}: {exc}); "
                                "the file is corrupt") from None
        if not isinstance(arr, np.ndarray):  # numpy gives a member that is no .npy as bytes
            raise self.err(key, "not a .npy array (a member of other content); the file "
                                "is corrupt or not a snapshot")
        if arr.dtype.kind not in kind or (itemsize is not None
                                          and arr.dtype.itemsize != itemsize):
            want = {"U": "a unicode string", "i": "an integer", "f": "a float",
                    "b": "a bool"}.get(kind, kind)
            if itemsize is not None:
                want = f"{want} of {itemsize} bytes"
            raise self.err(key, f"dtype {arr.dtype}, want {want}")
        if ndim is not None and arr.ndim != ndim:
            raise self.err(key, f"shape {arr.shape}, want {ndim} dimension(s)")
        if arr.dtype.byteorder == (">" if np.little_endian else "<"):
            arr = arr.astype(arr.dtype.newbyteorder("="))
        return arr

    def scalar(self, key: str, kind: str, itemsize: int | None = None):
        return self.get(key, kind, 0, itemsize).item()


#: Most bytes the arrays of one snapshot may unpack to (load_snapshot's max_bytes).
MAX_SNAPSHOT_BYTES = 4 * 2**30


def _check_member_sizes(path: Path, max_bytes: int) -> None:
    """Refuse, before anything is unpacked, an archive whose members or arrays would take
    more than ``max_bytes`` or whose members claim more data than they hold (a zip bomb:
    a few MB of deflated zeros that numpy would unpack into gigabytes).

    For a compressed (deflated) file the limit holds for the uncompressed sizes the
    archive declares, member by member as they add up; zipfile never inflates a member
    past its declared size, so nothing read later can exceed them."""
    total = 0
    declared = 0
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                declared += info.file_size
                if declared > max_bytes:
                    what = ("compressed members" if info.compress_type != zipfile.ZIP_STORED
                            else "members")
                    raise SnapshotError(
                        f"its {what} unpack to more than {max_bytes} bytes (max_bytes; "
                        f"{declared} bytes declared up to this member, "
                        f"{path.stat().st_size} on disk); pass a larger max_bytes to "
                        f"load_snapshot to read it", file=path,
                        key=info.filename.removesuffix(".npy"))
                with zf.open(info) as member:
                    try:
                        version = np.lib.format.read_magic(member)
                        read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                       else np.lib.format.read_array_header_2_0)
                        shape, _, dtype = read_header(member, max_header_size=10_000)
                    except Exception:
                        continue  # not an array: np.load and the key checks refuse it
                    if dtype.hasobject:
                        continue  # refused later (allow_pickle=False)
                    nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
                    if nbytes > info.file_size:
                        raise SnapshotError(
                            f"the array header promises {nbytes} bytes but the member holds "
                            f"{info.file_size}: the file is corrupt or malicious",
                            file=path, key=info.filename.removesuffix(".npy"))
                    total += nbytes
                    if total > max_bytes:
                        raise SnapshotError(
                            f"its arrays unpack to more than {max_bytes} bytes (max_bytes); "
                            f"pass a larger max_bytes to load_snapshot to read it",
                            file=path, key=info.filename.removesuffix(".npy"))
    except SnapshotError:
        raise
    except Exception as exc:  # noqa: BLE001 - BadZipFile, OSError, EOFError, a member name
        # that is not the UTF-8 it claims (UnicodeDecodeError), ...: all mean corrupt
        raise SnapshotError(f"cannot read the zip archive ({type(exc).__name__}: {exc})",
                            file=path) from None


def load_snapshot(path: str | os.PathLike, *, max_bytes: int = MAX_SNAPSHOT_BYTES
                  ) -> Snapshot:
    """Read a snapshot written by :func:`save_snapshot`.

    Refuses (with a :class:`SnapshotError` naming the file and key) a file that is not a
    zip/npz, not a clradcom snapshot, of a newer format version, with a missing or unknown
    key, a wrong dtype or shape, or invalid values, and, before unpacking anything, one
    whose arrays would take more than ``max_bytes`` of memory. A missing file raises
    FileNotFoundError; a ``path`` that is no str or os.PathLike, or a ``max_bytes`` that is
    no int >= 0, an ArgumentTypeError or ArgumentError naming it.
    """
    if not isinstance(path, str | os.PathLike):
        raise ArgumentTypeError(f"must be a str or os.PathLike path, got "
                                f"{type(path).__name__}", argument="path", value=path)
    if isinstance(max_bytes, bool) or not isinstance(max_bytes, int | np.integer):
        raise ArgumentTypeError(f"must be an int, got {type(max_bytes).__name__}",
                                argument="max_bytes", value=max_bytes)
    if max_bytes < 0:
        raise ArgumentError("must be >= 0", argument="max_bytes", value=max_bytes)
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such snapshot file")
    if not zipfile.is_zipfile(p):
        raise SnapshotError("not a snapshot: not a zip (.npz) file, or the file is "
                            "truncated or corrupt", file=p)
    _check_member_sizes(p, max_bytes)
    try:
        npz = np.load(p, allow_pickle=False)
    except Exception as exc:
        raise SnapshotError(f"cannot open as .npz ({type(exc).__name__}: {exc})",
                            file=p) from None
    with npz:
        if not isinstance(npz, np.lib.npyio.NpzFile):  # pragma: no cover - is_zipfile said so
            raise SnapshotError("not an .npz archive", file=p)
        return _read(_Reader(p, npz))


def _read(r: _Reader) -> Snapshot:
    if "meta/format" not in r.keys:
        raise r.err("meta/format", "missing key: this .npz is not a clradcom snapshot")
    fmt = r.scalar("meta/format", "U")
    if fmt != FORMAT_NAME:
        raise r.err("meta/format", f"is {fmt!r}, not {FORMAT_NAME!r}: not a clradcom snapshot")
    version = r.scalar("meta/version", "i")
    if version > FORMAT_VERSION:
        raise r.err("meta/version",
                    f"snapshot format version {version} is newer than this clradcom reads "
                    f"(up to version {FORMAT_VERSION}); upgrade clradcom to read it")
    if version not in READABLE_VERSIONS:
        raise r.err("meta/version", f"invalid snapshot format version {version} (this "
                                    f"clradcom reads versions {READABLE_VERSIONS})")

    scene_name = r.scalar("meta/scene_name", "U")
    carrier_hz = r.scalar("meta/carrier_hz", "f", 8)
    scene_hash = r.scalar("meta/scene_hash", "U")
    if version >= 3 or "meta/time_s" in r.keys:
        time_s = r.scalar("meta/time_s", "f", 8)
    else:  # optional before version 3: a file without it was of a static scene
        time_s = 0.0
    object_names: tuple[str, ...] = ()
    if version >= 3:
        object_names = tuple(str(n) for n in r.get("meta/object_names", "U", 1))
    metadata: dict[str, MetaValue] = {}
    for key in sorted(k for k in r.keys if k.startswith("metadata/")):
        arr = r.get(key, "bifU", 0)
        if arr.dtype.kind in "if" and arr.dtype.itemsize != 8:
            raise r.err(key, f"dtype {arr.dtype}, want int64, float64, bool or str")
        metadata[key[len("metadata/"):]] = arr.item()
    if version < FORMAT_VERSION:
        # the paths' arrays mean the same; record where they came from
        metadata["snapshot.converted_from_version"] = int(version)
        metadata = dict(sorted(metadata.items()))

    tx_name = r.get("links/tx_name", "U", 1)
    n_links = tx_name.shape[0]
    columns = {"links/tx_name": tx_name}
    for key, kind in (("links/rx_name", "U"), ("links/tx_index", "i"),
                      ("links/rx_index", "i")):
        columns[key] = r.get(key, kind, 1)
        if columns[key].shape != (n_links,):
            raise r.err(key, f"shape {columns[key].shape}, want ({n_links},) like "
                             "links/tx_name")

    links = []
    for i in range(n_links):
        arrays = {}
        for name, dtype, _ in PATH_FIELDS:
            key = f"link{i}/{name}"
            arrays[name] = r.get(key, dtype.kind, None, dtype.itemsize)
        try:
            paths = Paths(**arrays)
            if version == 1 and np.any(paths.interaction > InteractionType.SCATTERING):
                bad = np.argwhere(paths.interaction > InteractionType.SCATTERING)[0]
                raise SnapshotError(
                    f"code {int(paths.interaction[tuple(bad)])} at "
                    f"[{bad[0]}, {bad[1]}]: format version 1 knows codes 0 to 3 only",
                    key="interaction")
            link = Link(tx_name=str(columns["links/tx_name"][i]),
                        rx_name=str(columns["links/rx_name"][i]),
                        tx_index=int(columns["links/tx_index"][i]),
                        rx_index=int(columns["links/rx_index"][i]), paths=paths)
        except SnapshotError as exc:
            key = exc.key or ""
            if key.split("[")[0] in PATH_FIELD_NAMES:
                key = f"link{i}/{key}"
            else:  # a Link field: tx_name, rx_index, ...
                key = f"links/{key}[{i}]"
            raise r.err(key, exc.reason) from None
        if version >= 3:
            _check_angles(r, i, link.paths)
        links.append(link)

    unknown = sorted(r.keys - r.used)
    if unknown:
        raise r.err(unknown[0], f"unknown key for format version {version} "
                                f"({len(unknown)} unknown in all)")
    try:
        return Snapshot(scene_name=scene_name, carrier_hz=carrier_hz, scene_hash=scene_hash,
                        links=tuple(links), time_s=time_s, metadata=metadata,
                        object_names=object_names)
    except SnapshotError as exc:
        key = {"scene_name": "meta/scene_name", "carrier_hz": "meta/carrier_hz",
               "scene_hash": "meta/scene_hash", "time_s": "meta/time_s",
               "version": "meta/version"}.get(exc.key or "", exc.key)
        m = re.fullmatch(r"links\[(\d+)\]\.object_id", key or "")
        if m:
            key = f"link{m.group(1)}/object_id"
        elif (key or "").startswith("object_names"):
            key = "meta/object_names"
        raise r.err(key, exc.reason) from None


def _check_angles(r: _Reader, i: int, paths: Paths) -> None:
    """A version-3 file's stored angles of link ``i``: float64 (P,), NaN exactly where the
    points give no direction, else within :data:`ANGLE_TOLERANCE_RAD` of the angles the
    points give (azimuths compared around the circle)."""
    for name, want in zip(ANGLE_FIELD_NAMES, path_angles(paths), strict=True):
        key = f"link{i}/{name}"
        got = r.get(key, "f", 1, 8)
        if got.shape != want.shape:
            raise r.err(key, f"shape {got.shape}, want (P,) = {want.shape}")
        nan_got, nan_want = np.isnan(got), np.isnan(want)
        with np.errstate(all="ignore"):
            diff = np.abs(np.angle(np.exp(1j * (got - want)))) if name.startswith("phi") \
                else np.abs(got - want)
        bad = (nan_got != nan_want) | (~nan_want & ~(diff <= ANGLE_TOLERANCE_RAD))
        if np.any(bad):
            k = int(np.argmax(bad))
            raise r.err(f"{key}[{k}]", f"stored angle {got[k]!r} rad, but the path's points "
                                       f"give {want[k]!r} rad: the file is inconsistent")

