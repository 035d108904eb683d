"""The propagation paths of one link in memory, and what happens at each interaction.

:class:`Paths` holds ``P`` paths as arrays along axis 0 (complex gain, 2x2 polarimetric
matrix, delay, Doppler, interaction codes, points, object and face ids);
:class:`InteractionType` names the code of every interaction slot. Every mechanism
returns :class:`Paths`; :func:`concat_paths` and :func:`select_paths` join and filter
them. The file that stores them is :mod:`clradcom.snapshot`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from clradcom.errors import SnapshotError

__all__ = ["INTERACTION_LETTERS", "PATH_FIELDS", "PATH_FIELD_NAMES", "InteractionType",
           "PathAngles", "Paths", "concat_paths", "interaction_patterns", "path_angles",
           "paths_difference", "pattern_counts", "select_paths"]


class InteractionType(IntEnum):
    """What happens to a path at one interaction point (``Paths.interaction`` codes).

    Codes, not bit flags: every interaction slot holds exactly one of them; ``NONE``
    pads the slots past a path's ``n_interactions``. Snapshots store them (format
    version 2; version 1 tagged PO facet and SBR returns as REFLECTION).
    """

    NONE = 0
    #: specular reflection at an exact image-method point (GO)
    REFLECTION = 1
    #: UTD edge diffraction at a Keller point
    DIFFRACTION = 2
    #: Lambertian scattering off a tile (the tile's centre)
    SCATTERING = 3
    #: a physical-optics facet return: the facet (its centroid) radiates the current the
    #: incident wave induces on it
    PHYSICAL_OPTICS = 4
    #: a bounce of a shooting-and-bouncing ray tube (SBR-PO); the path's last one radiates
    #: its PO footprint
    SBR = 5


#: one letter per interaction code, for patterns such as "RDR" (reflection, diffraction,
#: reflection)
INTERACTION_LETTERS = {InteractionType.REFLECTION: "R", InteractionType.DIFFRACTION: "D",
                       InteractionType.SCATTERING: "S", InteractionType.PHYSICAL_OPTICS: "P",
                       InteractionType.SBR: "B"}

_VALID_CODES = np.array([int(t) for t in InteractionType if t != InteractionType.NONE],
                        dtype=np.int8)


#: (field, dtype, shape in terms of P and K) in file order.
PATH_FIELDS: tuple[tuple[str, np.dtype, str], ...] = (
    ("gain", np.dtype(np.complex128), "(P,)"),
    ("matrix", np.dtype(np.complex128), "(P, 2, 2)"),
    ("delay_s", np.dtype(np.float64), "(P,)"),
    ("doppler_hz", np.dtype(np.float64), "(P,)"),
    ("n_interactions", np.dtype(np.int16), "(P,)"),
    ("interaction", np.dtype(np.int8), "(P, K)"),
    ("points", np.dtype(np.float64), "(P, K+2, 3)"),
    ("object_id", np.dtype(np.int32), "(P, K)"),
    ("face_id", np.dtype(np.int32), "(P, K)"),
)
PATH_FIELD_NAMES = tuple(name for name, _, _ in PATH_FIELDS)


def _expected_shape(spec: str, p: int, k: int) -> tuple[int, ...]:
    return {
        "(P,)": (p,),
        "(P, 2, 2)": (p, 2, 2),
        "(P, K)": (p, k),
        "(P, K+2, 3)": (p, k + 2, 3),
    }[spec]


def _index_str(idx) -> str:
    return "[" + ", ".join(str(int(i)) for i in idx) + "]"


def _first_bad(mask: np.ndarray) -> tuple[int, ...] | None:
    """Row-major index of the first True in ``mask`` (None if there is none)."""
    flat = np.flatnonzero(mask)
    if flat.size == 0:
        return None
    return tuple(int(i) for i in np.unravel_index(flat[0], mask.shape))


def _coerce(name: str, value, dtype: np.dtype) -> np.ndarray:
    """A C-contiguous, native-order copy of ``value`` as ``dtype``, refusing lossy casts."""
    try:
        arr = np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise SnapshotError(f"cannot be read as an array: {exc}", key=name) from None
    if arr.dtype.kind == "O":
        raise SnapshotError("object arrays are not allowed; give numbers", key=name)
    kind = arr.dtype.kind
    if arr.size == 0 and kind in "biufc":
        pass  # an empty list is float64 to numpy; any numeric empty array will do
    elif dtype.kind == "c":
        if kind not in "iufc":
            raise SnapshotError(f"dtype {arr.dtype} is not numeric (want {dtype})", key=name)
    elif dtype.kind == "f":
        if kind not in "iuf":
            raise SnapshotError(f"dtype {arr.dtype} is not real (want {dtype})", key=name)
    else:  # integer target
        if kind not in "iu":
            raise SnapshotError(f"dtype {arr.dtype} is not an integer type (want {dtype})",
                                key=name)
        if arr.size:
            info = np.iinfo(dtype)
            bad = _first_bad((arr < info.min) | (arr > info.max))
            if bad is not None:
                raise SnapshotError(
                    f"value {arr[bad]} does not fit in {dtype} at index {_index_str(bad)}",
                    key=name)
    out = np.array(arr, dtype=dtype, order="C", copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Paths:
    """The propagation paths of one link: ``P`` paths, at most ``K`` interactions each.

    All arrays are copied on construction, converted to the dtypes below and made
    read-only; the constructor refuses inconsistent or invalid values with a
    :class:`SnapshotError` (a ``ValueError``) naming the field and the first bad index.

    Attributes
    ----------
    gain : complex128 (P,)
        Baseband channel coefficient a_k (carrier phase -2 pi f_c tau_k, antenna
        patterns and polarization inside): the received baseband signal is
        sum_k a_k x(t - tau_k) exp(j 2 pi f_D,k t). Finite.
    matrix : complex128 (P, 2, 2)
        Polarimetric transfer matrix: rx field [E_theta, E_phi] = matrix @ tx field
        [E_theta, E_phi], in the tx/rx antenna's spherical bases (theta-hat, phi-hat) along
        the departure/arrival directions, without antenna patterns. Finite.
    delay_s : float64 (P,)
        Propagation delay tau_k (s), finite and >= 0.
    doppler_hz : float64 (P,)
        Doppler shift f_D,k = -(1/lambda) dL/dt (Hz), finite.
    n_interactions : int16 (P,)
        Number n of interactions of each path, 0 <= n <= K.
    interaction : int8 (P, K)
        :class:`InteractionType` code of interaction j (j < n: 1 to 5); 0 past n.
    points : float64 (P, K+2, 3)
        Polyline of the path (m): row 0 the tx point, rows 1..n the interaction points,
        row n+1 the rx point; rows past n+1 are NaN. Rows 0..n+1 are finite.
    object_id : int32 (P, K)
        Scene object index hit at interaction j (>= 0 for j < n); -1 past n.
    face_id : int32 (P, K)
        Scene triangle index hit at interaction j (>= 0 for j < n; for a diffraction, a
        triangle that owns the edge); -1 past n.
    """

    gain: np.ndarray
    matrix: np.ndarray
    delay_s: np.ndarray
    doppler_hz: np.ndarray
    n_interactions: np.ndarray
    interaction: np.ndarray
    points: np.ndarray
    object_id: np.ndarray
    face_id: np.ndarray

    def __post_init__(self) -> None:
        for name, dtype, _ in PATH_FIELDS:
            object.__setattr__(self, name, _coerce(name, getattr(self, name), dtype))
        self._check_shapes()
        self._check_values()

    # -- construction helpers ------------------------------------------------------

    @classmethod
    def empty(cls, k_max: int = 0) -> Paths:
        """A link without paths (P = 0) whose arrays are K = ``k_max`` wide."""
        k = int(k_max)
        if k < 0:
            raise SnapshotError(f"must be >= 0, got {k_max}", key="k_max")
        return cls(
            gain=np.zeros(0, np.complex128),
            matrix=np.zeros((0, 2, 2), np.complex128),
            delay_s=np.zeros(0),
            doppler_hz=np.zeros(0),
            n_interactions=np.zeros(0, np.int16),
            interaction=np.zeros((0, k), np.int8),
            points=np.zeros((0, k + 2, 3)),
            object_id=np.zeros((0, k), np.int32),
            face_id=np.zeros((0, k), np.int32),
        )

    # -- checks ----------------------------------------------------------------------

    def _check_shapes(self) -> None:
        if self.gain.ndim != 1:
            raise SnapshotError(f"shape {self.gain.shape}, want (P,)", key="gain")
        if self.interaction.ndim != 2:
            raise SnapshotError(f"shape {self.interaction.shape}, want (P, K)",
                                key="interaction")
        p = self.gain.shape[0]
        k = self.interaction.shape[1]
        for name, _, spec in PATH_FIELDS:
            want = _expected_shape(spec, p, k)
            got = getattr(self, name).shape
            if got != want:
                raise SnapshotError(
                    f"shape {got}, want {spec} = {want} (P = {p} from gain, "
                    f"K = {k} from interaction)", key=name)

    def _check_values(self) -> None:
        def refuse(name, idx, value, reason):
            raise SnapshotError(f"{reason} (value {value!r})", key=f"{name}{_index_str(idx)}")

        for name in ("gain", "matrix", "delay_s", "doppler_hz"):
            arr = getattr(self, name)
            bad = _first_bad(~np.isfinite(arr))
            if bad is not None:
                refuse(name, bad, arr[bad].item(), "must be finite")
        bad = _first_bad(self.delay_s < 0)
        if bad is not None:
            refuse("delay_s", bad, self.delay_s[bad].item(), "delays must be >= 0")

        k = self.k_max
        n = self.n_interactions.astype(np.int64)
        bad = _first_bad((n < 0) | (n > k))
        if bad is not None:
            refuse("n_interactions", bad, int(n[bad]), f"must lie in [0, K = {k}]")

        active = np.arange(k)[None, :] < n[:, None]  # (P, K) real interaction slots
        code = self.interaction
        bad = _first_bad(active & ~np.isin(code, _VALID_CODES))
        if bad is not None:
            refuse("interaction", bad, int(code[bad]),
                   "slot below n_interactions needs a code 1 (reflection), 2 (diffraction), "
                   "3 (scattering), 4 (physical optics) or 5 (SBR)")
        bad = _first_bad(~active & (code != InteractionType.NONE))
        if bad is not None:
            refuse("interaction", bad, int(code[bad]),
                   "padding slot (at or past n_interactions) must be 0")
        for name in ("object_id", "face_id"):
            arr = getattr(self, name)
            bad = _first_bad(active & (arr < 0))
            if bad is not None:
                refuse(name, bad, int(arr[bad]), "a real interaction needs an id >= 0")
            bad = _first_bad(~active & (arr != -1))
            if bad is not None:
                refuse(name, bad, int(arr[bad]),
                       "padding slot (at or past n_interactions) must be -1")

        used = np.arange(k + 2)[None, :] < (n + 2)[:, None]  # (P, K+2) polyline rows
        finite = np.isfinite(self.points)
        bad = _first_bad(used[:, :, None] & ~finite)
        if bad is not None:
            refuse("points", bad, self.points[bad].item(),
                   "tx, interaction and rx points must be finite")
        bad = _first_bad(~used[:, :, None] & ~np.isnan(self.points))
        if bad is not None:
            refuse("points", bad, self.points[bad].item(),
                   "rows past the rx point (row n_interactions + 1) must be NaN")

    # -- conveniences ----------------------------------------------------------------

    @property
    def n_paths(self) -> int:
        """P, the number of paths."""
        return int(self.gain.shape[0])

    @property
    def k_max(self) -> int:
        """K, the width of the interaction arrays (0: line of sight only)."""
        return int(self.interaction.shape[1])

    def __len__(self) -> int:
        return self.n_paths

    @property
    def angles(self) -> PathAngles:
        """Angles of departure and arrival of every path (:func:`path_angles`)."""
        return path_angles(self)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Paths):
            return NotImplemented
        return paths_difference(self, other) is None

    __hash__ = None  # mutable-looking arrays inside: not hashable


class PathAngles(NamedTuple):
    """Zenith and azimuth (rad) of the departure and arrival directions of ``P`` paths,
    each float64 (P,), in the world frame (Sionna RT's ``theta_t, phi_t, theta_r, phi_r``).
    """

    theta_t: np.ndarray
    phi_t: np.ndarray
    theta_r: np.ndarray
    phi_r: np.ndarray


def _theta_phi(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zenith theta in [0, pi] and azimuth phi in [-pi, pi] of the vectors v (P, 3), NaN
    for a zero or non-finite vector (no direction). atan2 of (|v_xy|, v_z) needs no
    normalisation and keeps full precision near the poles, where arccos(z) does not."""
    with np.errstate(all="ignore"):
        theta = np.arctan2(np.hypot(v[:, 0], v[:, 1]), v[:, 2])
        phi = np.arctan2(v[:, 1], v[:, 0])
    undefined = ~np.all(np.isfinite(v), axis=1) | ~np.any(v != 0, axis=1)
    theta[undefined] = np.nan
    phi[undefined] = np.nan
    return theta, phi


def path_angles(paths: Paths) -> PathAngles:
    """Angles of departure and arrival of every path, from its points (world frame, rad).

    Departure: the direction k_t from the tx point to the path's first interaction point
    (the rx point for line of sight). Arrival: the direction from the rx point back to
    the last interaction point (the tx point for line of sight), i.e. where the wave
    arrives from, minus its propagation direction -- Sionna RT's convention. For a unit
    vector (x, y, z): theta = arccos(z) (zenith, 0 is +z), phi = atan2(y, x) (azimuth from
    +x towards +y). A segment of zero length has no direction: both angles NaN.
    """
    n = paths.n_interactions.astype(np.intp)
    rows = np.arange(paths.n_paths)
    pts = paths.points
    with np.errstate(all="ignore"):  # differences of huge coordinates may overflow
        k_t = pts[rows, 1] - pts[rows, 0]
        k_r = pts[rows, n] - pts[rows, n + 1]
    return PathAngles(*_theta_phi(k_t), *_theta_phi(k_r))


def _array_difference(a: np.ndarray, b: np.ndarray) -> str | None:
    if a.dtype != b.dtype:
        return f"dtype {a.dtype} != {b.dtype}"
    if a.shape != b.shape:
        return f"shape {a.shape} != {b.shape}"
    if a.dtype.kind in "fc":
        ra, rb = (a.view(np.float64), b.view(np.float64)) if a.dtype.kind == "c" else (a, b)
        same = (ra == rb) | (np.isnan(ra) & np.isnan(rb))
        if a.dtype.kind == "c":
            same = same.reshape(*a.shape, 2).all(axis=-1)
    else:
        same = a == b
    bad = _first_bad(~np.asarray(same))
    if bad is None:
        return None
    return f"at {_index_str(bad)}: {a[bad]!r} != {b[bad]!r}"


def paths_difference(a: Paths, b: Paths) -> str | None:
    for name in PATH_FIELD_NAMES:
        diff = _array_difference(getattr(a, name), getattr(b, name))
        if diff is not None:
            return f"{name}: {diff}"
    return None


def concat_paths(parts: list[Paths]) -> Paths:
    """One Paths from several, padded to the largest number of interactions."""
    k_max = max((p.k_max for p in parts), default=0)
    fields = {}
    for name in ("gain", "matrix", "delay_s", "doppler_hz", "n_interactions"):
        fields[name] = np.concatenate([getattr(p, name) for p in parts])
    pads = {"interaction": 0, "object_id": -1, "face_id": -1}
    for name, fill in pads.items():
        fields[name] = np.concatenate([
            np.pad(getattr(p, name), ((0, 0), (0, k_max - p.k_max)), constant_values=fill)
            for p in parts])
    fields["points"] = np.concatenate([
        np.pad(p.points, ((0, 0), (0, k_max - p.k_max), (0, 0)), constant_values=np.nan)
        for p in parts])
    return Paths(**fields)


def select_paths(paths: Paths, mask) -> Paths:
    """The paths where mask is true."""
    return Paths(**{name: getattr(paths, name)[mask] for name in (
        "gain", "matrix", "delay_s", "doppler_hz", "n_interactions", "interaction", "points",
        "object_id", "face_id")})


def interaction_patterns(paths: Paths) -> list[str]:
    """Each path's interactions in order as letters (:data:`INTERACTION_LETTERS`); ""
    for a line-of-sight path."""
    letters = {int(code): letter for code, letter in INTERACTION_LETTERS.items()}
    return ["".join(letters[int(c)] for c in row[:k])
            for row, k in zip(paths.interaction, paths.n_interactions, strict=True)]


def pattern_counts(paths_list, containing: str = "") -> dict[str, int]:
    """How many paths of every :class:`Paths` in ``paths_list`` have each interaction
    pattern, counting only patterns with every letter of ``containing`` (e.g. "D": the
    diffracted paths)."""
    counts: dict[str, int] = {}
    for paths in paths_list:
        for pattern in interaction_patterns(paths):
            if all(letter in pattern for letter in containing):
                counts[pattern] = counts.get(pattern, 0) + 1
    return counts
