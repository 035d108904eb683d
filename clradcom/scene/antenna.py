"""Antenna patterns and polarisation.

Every pattern answers one question: for unit directions given in the antenna's
local frame (boresight +x, z up; theta from +z, phi from +x towards +y), what
are the far-field pattern components ``(C_theta, C_phi)``?  They are normalised
so that ``G = |C_theta|^2 + |C_phi|^2`` is the directivity (linear), i.e.
``integral G dOmega = 4 pi`` over the sphere.  Amplitudes are square roots of
power; the polarisation is a unit Jones vector in the (theta-hat, phi-hat) basis.

Patterns: :class:`IsotropicPattern`, :class:`SectorPattern` (the paper's
90 deg azimuth x 180 deg elevation, G = 4 inside), :class:`CosinePowerPattern`
(G = 2(q+1) cos^q psi in the front half-space), :class:`TabulatedPattern`
(CSV / .npz grid in theta, phi of gain in dB or complex C_theta / C_phi).
"""

from __future__ import annotations

import csv
import hashlib
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from clradcom.errors import SceneError

__all__ = [
    "Pattern",
    "IsotropicPattern",
    "SectorPattern",
    "CosinePowerPattern",
    "TabulatedPattern",
    "load_pattern_file",
    "polarization_jones",
    "POLARIZATIONS",
    "directions_to_angles",
    "theta_phi_unit_vectors",
    "integrate_gain",
    "euler_deg_to_matrix",
]

_SQ2 = 1.0 / math.sqrt(2.0)

#: Named polarisations as Jones vectors (C_theta share, C_phi share).
#: With e^{+jwt} and an outgoing wave along r-hat (theta-hat x phi-hat = r-hat),
#: (1, -j)/sqrt2 rotates from theta-hat towards phi-hat: right-hand (IEEE) circular.
POLARIZATIONS: dict[str, np.ndarray] = {
    "V": np.array([1.0, 0.0], dtype=np.complex128),
    "H": np.array([0.0, 1.0], dtype=np.complex128),
    "RHCP": np.array([_SQ2, -1j * _SQ2], dtype=np.complex128),
    "LHCP": np.array([_SQ2, 1j * _SQ2], dtype=np.complex128),
}


def polarization_jones(pol) -> np.ndarray:
    """A unit Jones vector (2,) complex128 from a name or a 2-vector.

    Raises ``ValueError`` for an unknown name or a zero / non-finite vector.
    """
    if isinstance(pol, str):
        key = pol.upper()
        if key not in POLARIZATIONS:
            raise ValueError(f"unknown polarization {pol!r}; use one of {list(POLARIZATIONS)}"
                             " or a Jones vector [C_theta, C_phi]")
        return POLARIZATIONS[key].copy()
    vec = np.asarray(pol, dtype=np.complex128).reshape(-1)
    if vec.shape != (2,) or not np.all(np.isfinite(vec)):
        raise ValueError("a Jones vector needs 2 finite components (C_theta, C_phi)")
    big = float(np.max(np.abs(vec)))
    if big == 0:
        raise ValueError("a Jones vector must not be zero")
    if not 1e-150 < big < 1e150:  # so that |vec|^2 neither overflows nor underflows
        vec = vec / big
    return vec / np.linalg.norm(vec)


def euler_deg_to_matrix(angles_deg) -> np.ndarray:
    """Rotation matrix for ``[roll, pitch, yaw]`` in degrees.

    R = Rz(yaw) @ Ry(pitch) @ Rx(roll), acting on column vectors: roll about the
    fixed x axis first, then pitch about fixed y, then yaw about fixed z
    (extrinsic x-y-z; equivalently intrinsic z-y'-x'', the aerospace yaw-pitch-roll
    convention).  Positive angles turn counter-clockwise looking down the axis.
    """
    r, p, y = np.deg2rad(np.asarray(angles_deg, dtype=np.float64))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def directions_to_angles(directions) -> tuple[np.ndarray, np.ndarray]:
    """(theta, phi) in radians of (K,3) directions (normalised here): theta from +z
    in [0, pi], phi = atan2(y, x) in (-pi, pi]."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    # np.linalg.norm(d, axis=1) bit for bit (its row sum adds left to right;
    # tests/test_antenna.py), without its slow reduction over 3 columns: a radio map's
    # launch lattice evaluates its pattern at millions of directions
    squares = d * d
    n = squares[:, 0] + squares[:, 1]
    n += squares[:, 2]
    np.sqrt(n, out=n)
    if np.any(~np.isfinite(n)) or np.any(n == 0):
        raise ValueError("directions must be finite and non-zero")
    theta = np.arccos(np.clip(d[:, 2] / n, -1.0, 1.0))
    phi = np.arctan2(d[:, 1] / n, d[:, 0] / n)
    return theta, phi


def theta_phi_unit_vectors(theta, phi) -> tuple[np.ndarray, np.ndarray]:
    """theta-hat and phi-hat (K,3) in the same frame as the directions."""
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    ct, st, cp, sp = np.cos(theta), np.sin(theta), np.cos(phi), np.sin(phi)
    th = np.stack([ct * cp, ct * sp, -st], axis=-1)
    ph = np.stack([-sp, cp, np.zeros_like(phi)], axis=-1)
    return th, ph


@dataclass(eq=False)
class Pattern:
    """Base class: subclasses implement :meth:`gain` (linear directivity) and,
    unless they carry their own polarisation, use the Jones vector ``polarization``.
    """

    polarization: np.ndarray = field(default_factory=lambda: POLARIZATIONS["V"].copy())
    kind: str = field(default="base", init=False)

    def gain(self, directions_local) -> np.ndarray:  # pragma: no cover - abstract
        """Linear directivity G (K,) for (K,3) local directions."""
        raise NotImplementedError

    def support_box(self) -> tuple[float, float, float]:
        """(half azimuth width rad, largest |z|, least x) of the unit local directions
        where the pattern may have gain: a box that holds its support, for tests that
        skip the pattern where it cannot radiate; every direction unless a subclass
        knows better."""
        return math.pi, 1.0, -1.0

    def field(self, directions_local) -> np.ndarray:
        """(K,2) complex128 ``(C_theta, C_phi)`` with ``|C|^2 = G``."""
        g = self.gain(directions_local)
        amp = np.sqrt(np.maximum(g, 0.0))
        return amp[:, None] * np.asarray(self.polarization, dtype=np.complex128)[None, :]

    def field_vectors(self, directions_local) -> np.ndarray:
        """(K,3) complex field vectors C_theta theta-hat + C_phi phi-hat (local frame)."""
        theta, phi = directions_to_angles(directions_local)
        th, ph = theta_phi_unit_vectors(theta, phi)
        c = self.field(directions_local)
        return c[:, :1] * th + c[:, 1:] * ph

    def peak_gain_dbi(self) -> float:
        """Directivity at boresight (+x) in dBi."""
        return float(10.0 * np.log10(self.gain(np.array([[1.0, 0.0, 0.0]]))[0]))

    def params(self) -> dict:
        """Plain JSON-serialisable description (for hashes and snapshot metadata)."""
        pol = np.asarray(self.polarization, dtype=np.complex128)
        return {"type": self.kind, "polarization": [[repr(float(v.real)), repr(float(v.imag))]
                                                    for v in pol]}


@dataclass(eq=False)
class IsotropicPattern(Pattern):
    """G = 1 in every direction."""

    kind: str = field(default="isotropic", init=False)

    def gain(self, directions_local) -> np.ndarray:
        theta, _ = directions_to_angles(directions_local)
        return np.ones_like(theta)


#: Largest peak directivity a pattern may have (120 dBi): beyond any antenna (a 100 m dish
#: at 100 GHz has about 97 dBi), and far from where float64 gains overflow.
MAX_DIRECTIVITY = 1e12


@dataclass(eq=False)
class SectorPattern(Pattern):
    """Ideal sector: G = 4 pi / Omega inside ``|phi| <= az/2`` and
    ``|90 deg - theta| <= el/2``, 0 outside.  Omega = az_rad * 2 sin(el/2).
    The paper's antenna (90 deg x 180 deg) covers pi sr: G = 4 (6.02 dBi)."""

    azimuth_width_deg: float = 90.0
    elevation_width_deg: float = 180.0
    kind: str = field(default="sector", init=False)

    def __post_init__(self):
        if not 0 < self.azimuth_width_deg <= 360:
            raise ValueError("azimuth_width_deg must be in (0, 360]")
        if not 0 < self.elevation_width_deg <= 180:
            raise ValueError("elevation_width_deg must be in (0, 180]")
        if not self.solid_angle * MAX_DIRECTIVITY >= 4.0 * math.pi:
            raise ValueError(f"a sector this narrow has a directivity above "
                             f"{MAX_DIRECTIVITY:g} (120 dBi), beyond any antenna")

    @property
    def solid_angle(self) -> float:
        az = math.radians(self.azimuth_width_deg)
        el = math.radians(self.elevation_width_deg)
        return az * 2.0 * math.sin(el / 2.0)

    @property
    def inside_gain(self) -> float:
        return 4.0 * math.pi / self.solid_angle

    def gain(self, directions_local) -> np.ndarray:
        theta, phi = directions_to_angles(directions_local)
        half_az = math.radians(self.azimuth_width_deg) / 2.0
        half_el = math.radians(self.elevation_width_deg) / 2.0
        tol = 1e-12
        inside = (np.abs(phi) <= half_az + tol) & (np.abs(np.pi / 2 - theta) <= half_el + tol)
        return np.where(inside, self.inside_gain, 0.0)

    def support_box(self) -> tuple[float, float, float]:
        return (math.radians(self.azimuth_width_deg) / 2.0,
                math.sin(math.radians(self.elevation_width_deg) / 2.0), -1.0)

    def params(self) -> dict:
        p = super().params()
        p.update(azimuth_width_deg=repr(float(self.azimuth_width_deg)),
                 elevation_width_deg=repr(float(self.elevation_width_deg)))
        return p


@dataclass(eq=False)
class CosinePowerPattern(Pattern):
    """Power pattern G = 2(q+1) cos^q(psi) for psi < 90 deg, 0 behind; psi is the
    angle from boresight (+x).  The factor follows from
    integral_{hemisphere} cos^q psi dOmega = 2 pi / (q + 1)."""

    q: float = 1.0
    kind: str = field(default="cosine", init=False)

    def __post_init__(self):
        if not (math.isfinite(self.q) and self.q >= 0):
            raise ValueError("q must be a finite number >= 0")
        if 2.0 * (self.q + 1.0) > MAX_DIRECTIVITY:
            raise ValueError(f"q must be <= {MAX_DIRECTIVITY / 2 - 1:g}: the peak directivity "
                             f"2 (q + 1) would exceed {MAX_DIRECTIVITY:g} (120 dBi), beyond "
                             "any antenna")

    def support_box(self) -> tuple[float, float, float]:
        return math.pi, 1.0, 0.0   # the front half

    @staticmethod
    def q_from_beamwidth(hpbw_deg: float) -> float:
        """q such that the power pattern is -3.0103 dB at psi = hpbw/2."""
        half = math.radians(hpbw_deg) / 2.0
        if not 0 < half < math.pi / 2:
            raise ValueError("half-power beamwidth must be in (0, 180) degrees")
        log_cos = math.log(math.cos(half))
        return math.log(0.5) / log_cos if log_cos < 0 else math.inf  # cos rounds to 1

    def gain(self, directions_local) -> np.ndarray:
        d = np.asarray(directions_local, dtype=np.float64).reshape(-1, 3)
        n = np.linalg.norm(d, axis=1)
        if np.any(~np.isfinite(n)) or np.any(n == 0):
            raise ValueError("directions must be finite and non-zero")
        c = np.clip(d[:, 0] / n, 0.0, 1.0)
        g = 2.0 * (self.q + 1.0) * c**self.q
        return np.where(d[:, 0] > 0, g, 0.0)

    def params(self) -> dict:
        p = super().params()
        p.update(q=repr(float(self.q)))
        return p


#: Largest |gain_db| of a tabulated pattern (and |C| = 10^(MAX_TABLE_DB/20) of a complex
#: one): far beyond any antenna (the largest dishes reach about 90 dBi), and small enough
#: that squared amplitudes and their integral stay inside float64.
MAX_TABLE_DB = 300.0
MAX_TABLE_AMPLITUDE = 10.0 ** (MAX_TABLE_DB / 20.0)
#: Most bytes the arrays of an .npz pattern file may unpack to (as its zip directory
#: declares them), so that a small deflated file cannot expand to gigabytes.
MAX_PATTERN_NPZ_BYTES = 2**30


@dataclass(eq=False)
class TabulatedPattern(Pattern):
    """A pattern sampled on a regular (theta, phi) grid, bilinearly interpolated
    (phi periodic).  Either ``gain_db`` (power, with ``polarization``) or complex
    ``c_theta`` / ``c_phi`` (which carry their own polarisation) is given; shape
    (N_theta, N_phi).  ``theta_deg`` must span 0..180 and ``phi_deg`` 360 degrees.
    With ``normalize`` the table is scaled so that integral G dOmega = 4 pi."""

    theta_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    phi_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gain_db: np.ndarray | None = None
    c_theta: np.ndarray | None = None
    c_phi: np.ndarray | None = None
    normalize: bool = True
    source: str = ""
    kind: str = field(default="file", init=False)

    def __post_init__(self):
        th = np.asarray(self.theta_deg, dtype=np.float64)
        ph = np.asarray(self.phi_deg, dtype=np.float64)
        _check_grid(th, ph)
        self.theta_deg, self.phi_deg = th, ph
        self.complex_field = self.gain_db is None
        if self.complex_field:
            ct = np.asarray(self.c_theta, dtype=np.complex128)
            cp = np.asarray(self.c_phi, dtype=np.complex128)
            tables = [ct, cp]
        else:
            gdb = np.asarray(self.gain_db, dtype=np.float64)
            if not np.all(np.isfinite(gdb)):
                raise ValueError("pattern table holds NaN or inf values")
            if np.any(np.abs(gdb) > MAX_TABLE_DB):
                raise ValueError(f"gain_db outside +-{MAX_TABLE_DB:g} dB (largest magnitude "
                                 f"{np.max(np.abs(gdb)):g}): no antenna has such a gain")
            tables = [np.sqrt(10.0 ** (gdb / 10.0)).astype(np.complex128)]
        shape = (th.size, ph.size)
        for t in tables:
            if t.shape != shape:
                raise ValueError(f"pattern table has shape {t.shape}, expected "
                                 f"(len(theta_deg), len(phi_deg)) = {shape}")
            if not np.all(np.isfinite(t)):
                raise ValueError("pattern table holds NaN or inf values")
            if np.any(np.abs(t) > MAX_TABLE_AMPLITUDE):
                raise ValueError(f"pattern field amplitude above {MAX_TABLE_AMPLITUDE:g} "
                                 f"({MAX_TABLE_DB:g} dB; largest {np.max(np.abs(t)):g}): no "
                                 "antenna has such a gain")
        # periodic phi: append the wrap-around column when the grid is open
        ph_ext = ph
        if ph[-1] - ph[0] < 360.0 - 1e-9:
            ph_ext = np.append(ph, ph[0] + 360.0)
            tables = [np.concatenate([t, t[:, :1]], axis=1) for t in tables]
        self._phi0 = float(ph_ext[0])
        grid = (np.deg2rad(th), np.deg2rad(ph_ext))
        self._interp = [RegularGridInterpolator(grid, t, method="linear") for t in tables]
        self._scale = 1.0
        if self.normalize:
            total = integrate_gain(self, n_theta=360, n_phi=720)
            if not total > 0:
                raise ValueError("pattern is zero everywhere; cannot normalise")
            self._scale = 4.0 * math.pi / total
            if not math.isfinite(self._scale):
                raise ValueError(f"pattern too weak to normalise (integral of G {total:g})")
        peak = self._scale * float(np.max(sum(np.abs(t) ** 2 for t in tables)))
        if peak > MAX_DIRECTIVITY:
            raise ValueError(f"peak gain {peak:g} ({10 * math.log10(peak):.1f} dBi) above "
                             f"{MAX_DIRECTIVITY:g} (120 dBi), beyond any antenna")

    def _amplitudes(self, directions_local) -> list[np.ndarray]:
        theta, phi = directions_to_angles(directions_local)
        phi0 = math.radians(self._phi0)
        phi = np.mod(phi - phi0, 2.0 * np.pi) + phi0
        pts = np.stack([theta, phi], axis=-1)
        return [f(pts) for f in self._interp]

    def gain(self, directions_local) -> np.ndarray:
        amps = self._amplitudes(directions_local)
        return self._scale * sum(np.abs(a) ** 2 for a in amps)

    def field(self, directions_local) -> np.ndarray:
        amps = self._amplitudes(directions_local)
        s = math.sqrt(self._scale)
        if self.complex_field:
            return s * np.stack(amps, axis=-1)
        amp = s * np.abs(amps[0])
        return amp[:, None] * np.asarray(self.polarization, dtype=np.complex128)[None, :]

    def params(self) -> dict:
        p = super().params()
        h = hashlib.sha256()
        for a in (self.theta_deg, self.phi_deg, self.gain_db, self.c_theta, self.c_phi):
            if a is not None:
                h.update(np.ascontiguousarray(a).tobytes())
        p.update(table_sha256=h.hexdigest(), normalize=bool(self.normalize),
                 complex_field=bool(self.complex_field))
        return p


def _check_grid(th: np.ndarray, ph: np.ndarray) -> None:
    if th.ndim != 1 or ph.ndim != 1 or th.size < 2 or ph.size < 2:
        raise ValueError("theta_deg and phi_deg must be 1-D with at least 2 values each")
    if not (np.all(np.isfinite(th)) and np.all(np.isfinite(ph))):
        raise ValueError("theta_deg / phi_deg hold NaN or inf")
    if np.any(np.diff(th) <= 0) or np.any(np.diff(ph) <= 0):
        raise ValueError("theta_deg and phi_deg must be strictly increasing")
    if abs(th[0]) > 1e-9 or abs(th[-1] - 180.0) > 1e-9:
        raise ValueError(f"theta_deg must run from 0 to 180, got {th[0]:g}..{th[-1]:g}")
    span = ph[-1] - ph[0]
    gap = ph[0] + 360.0 - ph[-1]
    if span > 360.0 + 1e-9 or gap > np.max(np.diff(ph)) + 1e-9:
        raise ValueError(f"phi_deg must cover one full turn (360 deg) with no gap wider "
                         f"than its step, got {ph[0]:g}..{ph[-1]:g}")


def integrate_gain(pattern: Pattern, n_theta: int = 720, n_phi: int = 1440) -> float:
    """integral G dOmega over the sphere by the midpoint rule (4 pi for a
    normalised pattern)."""
    dth = np.pi / n_theta
    dph = 2 * np.pi / n_phi
    th = (np.arange(n_theta) + 0.5) * dth
    ph = -np.pi + (np.arange(n_phi) + 0.5) * dph
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    dirs = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], axis=-1)
    g = pattern.gain(dirs.reshape(-1, 3)).reshape(tt.shape)
    return float(np.sum(g * np.sin(tt)) * dth * dph)


# ---------------------------------------------------------------------------
# pattern files

_GAIN_COLUMNS = ("theta_deg", "phi_deg", "gain_db")
_COMPLEX_COLUMNS = ("theta_deg", "phi_deg", "c_theta_re", "c_theta_im", "c_phi_re", "c_phi_im")


def load_pattern_file(path, *, polarization=None, normalize: bool = True) -> TabulatedPattern:
    """Read a tabulated pattern from ``.csv`` or ``.npz``.

    CSV: a header row, then one row per grid point, columns ``theta_deg, phi_deg,
    gain_db`` or ``theta_deg, phi_deg, c_theta_re, c_theta_im, c_phi_re, c_phi_im``
    (lines starting with ``#`` are comments).  Every (theta, phi) pair of the
    regular grid must appear exactly once, in any order.

    NPZ: arrays ``theta_deg`` (N_t,), ``phi_deg`` (N_p,) and either ``gain_db``
    (N_t, N_p) or complex ``c_theta`` and ``c_phi`` (N_t, N_p).

    Raises :class:`SceneError` naming the pattern file, the column/array and value.
    """
    path = Path(path)
    try:
        found = path.is_file()
    except (OSError, ValueError):  # a name the OS refuses (too long, a NUL byte)
        found = False
    if not found:
        raise SceneError("pattern file not found", file=path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        arrays = _read_npz(path)
    elif suffix == ".csv":
        arrays = _read_csv(path)
    else:
        raise SceneError("unsupported pattern file type; use .csv or .npz", file=path,
                         value=path.suffix)
    if polarization is not None and "gain_db" not in arrays:
        raise SceneError("this pattern file gives complex c_theta/c_phi, which fix the "
                         "polarization; remove the polarization key",
                         file=path, key="polarization", value=polarization)
    pol = polarization_jones(polarization if polarization is not None else "V")
    try:
        return TabulatedPattern(polarization=pol, normalize=normalize, source=str(path),
                                **arrays)
    except ValueError as exc:
        raise SceneError(f"malformed pattern: {exc}", file=path) from None


def _read_npz(path: Path) -> dict:
    try:
        with zipfile.ZipFile(path) as zf:
            declared = sum(info.file_size for info in zf.infolist())
    except Exception as exc:  # noqa: BLE001 - any reader failure is a malformed file
        raise SceneError(f"cannot read .npz pattern file ({type(exc).__name__}: {exc})",
                         file=path) from None
    if declared > MAX_PATTERN_NPZ_BYTES:
        raise SceneError(f"its arrays unpack to {declared} bytes, more than "
                         f"{MAX_PATTERN_NPZ_BYTES} for a pattern table", file=path)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: np.asarray(z[k]) for k in z.files}
    except Exception as exc:  # noqa: BLE001 - any reader failure is a malformed file
        raise SceneError(f"cannot read .npz pattern file ({exc})", file=path) from None
    for k in ("theta_deg", "phi_deg"):
        if k not in data:
            raise SceneError(f"missing array '{k}' (has: {sorted(data)})", file=path, key=k)
    out = {"theta_deg": data["theta_deg"], "phi_deg": data["phi_deg"]}
    if "gain_db" in data:
        out["gain_db"] = data["gain_db"]
    elif "c_theta" in data and "c_phi" in data:
        out["c_theta"], out["c_phi"] = data["c_theta"], data["c_phi"]
    else:
        raise SceneError("needs array 'gain_db' or both 'c_theta' and 'c_phi' "
                         f"(has: {sorted(data)})", file=path)
    for k, v in out.items():
        if v.dtype.kind not in "iufc":
            raise SceneError(f"array '{k}' is not numeric (dtype {v.dtype})", file=path, key=k)
        if v.dtype.kind == "c" and k not in ("c_theta", "c_phi"):
            raise SceneError(f"array '{k}' must be real (dtype {v.dtype})", file=path, key=k)
    return out


def _read_csv(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"cannot read pattern file ({exc})", file=path) from None
    rows = [(i + 1, r) for i, r in enumerate(csv.reader(text.splitlines()))
            if r and not r[0].lstrip().startswith("#") and any(c.strip() for c in r)]
    if not rows:
        raise SceneError("empty pattern file", file=path)
    header = [c.strip() for c in rows[0][1]]
    if set(_GAIN_COLUMNS) <= set(header):
        cols = _GAIN_COLUMNS
    elif set(_COMPLEX_COLUMNS) <= set(header):
        cols = _COMPLEX_COLUMNS
    else:
        raise SceneError(
            f"header must name columns {', '.join(_GAIN_COLUMNS)} or "
            f"{', '.join(_COMPLEX_COLUMNS)}", file=path, key="header", value=header,
            line=rows[0][0])
    idx = [header.index(c) for c in cols]
    vals = np.empty((len(rows) - 1, len(cols)))
    for r, (lineno, row) in enumerate(rows[1:]):
        if len(row) != len(header):
            raise SceneError(f"row has {len(row)} fields, header has {len(header)}",
                             file=path, line=lineno, value=",".join(row))
        for j, (c, i) in enumerate(zip(cols, idx, strict=True)):
            try:
                v = float(row[i])
            except ValueError:
                raise SceneError("not a number", file=path, line=lineno, key=c,
                                 value=row[i]) from None
            if not math.isfinite(v):
                raise SceneError("NaN or inf not allowed", file=path, line=lineno, key=c,
                                 value=row[i])
            vals[r, j] = v
    if vals.shape[0] == 0:
        raise SceneError("no data rows", file=path)
    th = np.unique(vals[:, 0])
    ph = np.unique(vals[:, 1])
    if th.size * ph.size != vals.shape[0]:
        raise SceneError(
            f"rows do not form a full regular grid: {th.size} theta x {ph.size} phi values "
            f"but {vals.shape[0]} rows", file=path)
    it = np.searchsorted(th, vals[:, 0])
    ip = np.searchsorted(ph, vals[:, 1])
    seen = np.zeros((th.size, ph.size), dtype=bool)
    seen[it, ip] = True
    if not seen.all():
        raise SceneError("rows do not form a full regular grid (duplicate (theta, phi) pairs)",
                         file=path)
    out: dict = {"theta_deg": th, "phi_deg": ph}
    if cols is _GAIN_COLUMNS:
        g = np.empty((th.size, ph.size))
        g[it, ip] = vals[:, 2]
        out["gain_db"] = g
    else:
        ct = np.empty((th.size, ph.size), dtype=np.complex128)
        cp = np.empty_like(ct)
        ct[it, ip] = vals[:, 2] + 1j * vals[:, 3]
        cp[it, ip] = vals[:, 4] + 1j * vals[:, 5]
        out["c_theta"], out["c_phi"] = ct, cp
    return out


def pattern_peak_gain(pattern, n_directions: int = 20_000) -> float:
    """Largest directivity of an antenna pattern: boresight and a Fibonacci sphere of
    ``n_directions`` (exact for the sector, isotropic and cosine patterns)."""
    i = np.arange(n_directions) + 0.5
    z = 1.0 - 2.0 * i / n_directions
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = math.pi * (1.0 + 5.0**0.5) * i
    dirs = np.concatenate([[[1.0, 0.0, 0.0]],
                           np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)])
    return float(np.max(pattern.gain(dirs)))
