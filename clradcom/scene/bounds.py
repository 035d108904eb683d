"""Physical bounds of scene values (docs/scene-format.md "Physical bounds").

Two kinds of limit, each with its reason in the docs:

* **refused** (:class:`~clradcom.errors.SceneError` naming file, key and value): values no
  radio ray tracer can mean -- a carrier outside 3 MHz - 3 THz (above, not radio; below,
  wavelengths longer than the objects), a speed at or above the speed of light, a
  negative noise figure, geometry beyond what the float32 kernels can hold;
* **warned** (:class:`~clradcom.errors.ValidityRangeWarning`, once per scene and key):
  values that are legal but outside where the methods and models hold -- a carrier
  outside 1-300 GHz, a speed above 1e-3 c (first-order Doppler off by more than 0.1 %),
  geometry so far from the origin that float32 rounds it by more than a wavelength.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from clradcom.errors import ValidityRangeWarning
from clradcom.scene.fields import FieldReader
from clradcom.scene.materials import C0

__all__ = ["CARRIER_HZ_REFUSED", "CARRIER_HZ_VALID", "MAX_COORDINATE_M",
           "NOISE_FIGURE_MAX_DB", "SPEED_WARN_FRACTION", "TX_POWER_MAX_W",
           "check_carrier", "check_coordinates", "check_speed", "warn_far_geometry",
           "warn_speeds"]

#: Carriers outside [lo, hi] Hz are refused: below, the wavelength exceeds 100 m (street
#: objects are far smaller than a wavelength; ground and surface waves, not modelled,
#: carry the signal); above 3 THz (the ITU Radio Regulations' upper limit of radio
#: waves) it is infrared, not radio.
CARRIER_HZ_REFUSED = (3e6, 3e12)
#: Carriers outside [lo, hi] Hz are accepted with a warning: below 1 GHz (wavelength
#: > 30 cm) metre-sized objects are only a few wavelengths large, where the asymptotic
#: GO/UTD/PO methods lose accuracy, and most ITU-R P.2040 materials start at 1 GHz; above
#: 300 GHz (wavelength < 1 mm) millimetre roughness is no longer small against the
#: wavelength, and gaseous absorption, which the tracer does not model, grows large.
CARRIER_HZ_VALID = (1e9, 300e9)
#: Speeds above this fraction of c are accepted with a warning: the first-order Doppler
#: f_D = -(1/lambda) dL/dt the tracer uses differs from the exact two-way shift
#: (-2 f v / (c + v)) by the relative amount v / c, so 1e-3 keeps it within 0.1 %.
SPEED_WARN_FRACTION = 1e-3
#: Noise figures above this (dB) are refused: no receiver comes near (real ones are
#: 0-20 dB), and the cap keeps 10^(F/10) and every power made from it well inside float64.
NOISE_FIGURE_MAX_DB = 300.0
#: Transmit powers above this (W) are refused: a terawatt, far above any transmitter
#: built; the cap keeps received powers and their squares inside float64.
TX_POWER_MAX_W = 1e12
#: World coordinates beyond this (m) are refused: the kernels hold geometry in float32,
#: whose squared lengths overflow near 1.8e19 m (and 1e18 m is a hundred light-years).
MAX_COORDINATE_M = 1e18
#: float32 rounds a coordinate x to within x * 2**-24; geometry farther from the origin
#: than wavelength / FLOAT32_HALF_ULP is rounded in the kernels by more than a wavelength.
FLOAT32_HALF_ULP = 2.0**-24


def check_carrier(fields: FieldReader, value, carrier: float, key: str) -> None:
    """Refuse a carrier outside radio; warn outside the range the methods hold."""
    lo, hi = CARRIER_HZ_REFUSED
    if carrier < lo:
        raise fields.err(key, value, f"must be >= {lo:g} Hz (3 MHz): below, the wavelength "
                         "exceeds 100 m, far larger than the objects geometrical optics "
                         "and UTD need to be many wavelengths large, and ground waves, "
                         "which are not modelled, carry the signal")
    if carrier > hi:
        raise fields.err(key, value, f"must be <= {hi:g} Hz (3 THz): above, it is not "
                         "radio but infrared (the ITU Radio Regulations end radio waves "
                         "at 3000 GHz)")
    vlo, vhi = CARRIER_HZ_VALID
    if not vlo <= carrier <= vhi:
        why = ("below 1 GHz objects of a few metres are only a few wavelengths large, "
               "where GO/UTD/PO lose accuracy" if carrier < vlo else
               "above 300 GHz millimetre surface roughness is no longer small against "
               "the wavelength and gaseous absorption, which is not modelled, grows large")
        warnings.warn(f"{fields.file}: {key} = {value!r} is outside 1e9-3e11 Hz "
                      f"(1-300 GHz), where the tracer's methods hold: {why}",
                      ValidityRangeWarning, stacklevel=4)


def check_speed(fields: FieldReader, velocity: np.ndarray, value, key: str) -> float:
    """Refuse a speed |v| >= c; returns |v| (m/s) for :func:`warn_speeds`."""
    big = float(np.max(np.abs(velocity)))
    speed = big * float(np.linalg.norm(velocity / big)) if big > 0 else 0.0  # no overflow
    if not speed < C0:
        raise fields.err(key, value, f"speed {speed:.9g} m/s is not below the speed of "
                         f"light ({C0:.0f} m/s)")
    return speed


def warn_speeds(fields: FieldReader, speeds: list[tuple[str, float]]) -> None:
    """One warning for every (key, speed) above SPEED_WARN_FRACTION * c."""
    fast = [(k, s) for k, s in speeds if s > SPEED_WARN_FRACTION * C0]
    if not fast:
        return
    listed = ", ".join(f"{k} ({s:g} m/s)" for k, s in fast[:5])
    more = f" and {len(fast) - 5} more" if len(fast) > 5 else ""
    warnings.warn(f"{fields.file}: {listed}{more}: faster than {SPEED_WARN_FRACTION:g} c "
                  f"({SPEED_WARN_FRACTION * C0:g} m/s), where the first-order Doppler "
                  "-(1/lambda) dL/dt is off by more than 0.1 % (the error is about "
                  "v_rel / c)", ValidityRangeWarning, stacklevel=4)


def check_coordinates(fields: FieldReader, points: np.ndarray, key: str, value,
                      what: str) -> None:
    """Refuse non-finite points or coordinates beyond MAX_COORDINATE_M, blaming ``key``."""
    pts = np.asarray(points, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(pts) | (np.abs(pts) > MAX_COORDINATE_M)
    if not bad.any():
        return
    j = int(np.flatnonzero(bad.reshape(len(pts), -1).any(axis=1))[0]) if pts.ndim > 1 else 0
    example = pts[j].tolist() if pts.ndim > 1 else pts.tolist()
    raise fields.err(key, value, f"{what} gives coordinates {example} (point {j}) beyond "
                     f"+-{MAX_COORDINATE_M:g} m or not finite: the float32 kernels cannot "
                     "hold them")


def warn_far_geometry(fields: FieldReader, max_abs: float, carrier: float,
                      where: str) -> None:
    """Warn when float32 rounds the farthest coordinate by more than a wavelength."""
    wavelength = C0 / carrier
    if max_abs * FLOAT32_HALF_ULP <= wavelength or not math.isfinite(max_abs):
        return
    warnings.warn(f"{fields.file}: {where} lies {max_abs:g} m from the origin, where the "
                  f"kernels' float32 geometry is rounded by {max_abs * FLOAT32_HALF_ULP:g} m,"
                  f" more than the wavelength {wavelength:g} m: paths may be missed; move "
                  "the origin into the scene", ValidityRangeWarning, stacklevel=4)
