"""A radar entry's ``pattern`` and ``polarization`` keys -> antenna :class:`Pattern`,
Jones vector (2,) complex and polarisation name."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clradcom.errors import SceneError
from clradcom.scene.antenna import (
    MAX_DIRECTIVITY,
    CosinePowerPattern,
    IsotropicPattern,
    Pattern,
    SectorPattern,
    load_pattern_file,
    polarization_jones,
)
from clradcom.scene.fields import FieldReader, is_file

__all__ = ["PATTERN_KEYS", "PATTERN_TYPES", "read_pattern", "read_polarization"]

PATTERN_TYPES = ("isotropic", "sector", "cosine", "file")
PATTERN_KEYS = {
    "isotropic": ("type",),
    "sector": ("type", "azimuth_width_deg", "elevation_width_deg"),
    "cosine": ("type", "q", "half_power_beamwidth_deg"),
    "file": ("type", "path", "normalize"),
}


def read_pattern(fields: FieldReader, tbl: dict, kp: str,
                 base_dir: Path) -> tuple[Pattern, np.ndarray, str]:
    """(pattern, Jones vector, polarisation name) of radar entry ``tbl``; a complex
    pattern file carries its own polarisation (its boresight field, name ``"file"``)."""
    k = f"{kp}.pattern"
    spec = _pattern_table(fields, tbl.get("pattern", "isotropic"), k)
    ptype = fields.get_str(spec, "type", k, choices=PATTERN_TYPES)
    fields.check_keys(spec, PATTERN_KEYS[ptype], k)
    pol, pol_name = read_polarization(fields, tbl, kp)
    jones = pol if pol is not None else polarization_jones("V")
    if ptype == "isotropic":
        pattern: Pattern = IsotropicPattern(polarization=jones)
    elif ptype == "sector":
        pattern = _sector_pattern(fields, spec, k, jones)
    elif ptype == "cosine":
        pattern = _cosine_pattern(fields, spec, k, jones)
    else:
        pattern = _file_pattern(fields, spec, k, pol, base_dir)
        if pattern.complex_field:
            c = pattern.field(np.array([[1.0, 0.0, 0.0]]))[0]
            nrm = np.linalg.norm(c)
            jones = c / nrm if nrm > 0 else polarization_jones("V")
            pol_name = "file"
    return pattern, np.asarray(jones, dtype=np.complex128), pol_name or "V"


def read_polarization(fields: FieldReader, tbl: dict, kp: str):
    """(Jones vector, name) from ``polarization``, or (None, None) when not given."""
    if "polarization" not in tbl:
        return None, None
    k = f"{kp}.polarization"
    v = tbl["polarization"]
    if isinstance(v, str):
        try:
            return polarization_jones(v), v.upper()
        except ValueError as exc:
            raise fields.err(k, v, str(exc)) from None
    if isinstance(v, list) and len(v) == 2:
        comps = []
        for c in v:
            if isinstance(c, list):
                re_, im = fields.vector(c, k, 2)
                comps.append(complex(re_, im))
            else:
                comps.append(complex(fields.number(c, k, "a Jones vector [C_theta, C_phi]")))
        try:
            return polarization_jones(comps), "jones"
        except ValueError as exc:
            raise fields.err(k, v, str(exc)) from None
    raise fields.err(k, v, "expected 'V', 'H', 'RHCP', 'LHCP' or a Jones vector "
                     "[C_theta, C_phi] (each a number or [real, imag])")


def _pattern_table(fields, spec, k) -> dict:
    """The pattern as a table: a bare name ``"sector"`` means ``{ type = "sector" }``."""
    if isinstance(spec, str):
        if spec not in PATTERN_TYPES:
            raise fields.err(k, spec, f"unknown pattern; use one of {', '.join(PATTERN_TYPES)}")
        if spec == "file":
            raise fields.err(k, spec, "a file pattern needs a table: "
                             "pattern = { type = 'file', path = '...' }")
        return {"type": spec}
    if not isinstance(spec, dict):
        raise fields.err(k, spec, "expected a pattern name or a table with a 'type' key")
    return spec


def _sector_pattern(fields, spec, k, jones) -> SectorPattern:
    az = fields.get_float(spec, "azimuth_width_deg", k, default=90.0, lo=0.0,
                          lo_open=True, hi=360.0, unit="deg")
    el = fields.get_float(spec, "elevation_width_deg", k, default=180.0, lo=0.0,
                          lo_open=True, hi=180.0, unit="deg")
    try:
        return SectorPattern(polarization=jones, azimuth_width_deg=az, elevation_width_deg=el)
    except ValueError as exc:
        raise fields.err(k, spec, str(exc)) from None


def _cosine_pattern(fields, spec, k, jones) -> CosinePowerPattern:
    """From exactly one of ``q`` or ``half_power_beamwidth_deg``."""
    if ("q" in spec) == ("half_power_beamwidth_deg" in spec):
        raise fields.err(k, spec, "give exactly one of q or half_power_beamwidth_deg")
    key = f"{k}.q" if "q" in spec else f"{k}.half_power_beamwidth_deg"
    if "q" in spec:
        q = fields.get_float(spec, "q", k, lo=0.0)
    else:
        hp = fields.get_float(spec, "half_power_beamwidth_deg", k, lo=0.0, lo_open=True,
                              unit="deg")
        if hp >= 180.0:
            raise fields.err(f"{k}.half_power_beamwidth_deg",
                             spec["half_power_beamwidth_deg"], "must be < 180")
        q = CosinePowerPattern.q_from_beamwidth(hp)
        if 2.0 * (q + 1.0) > MAX_DIRECTIVITY:  # q is inf where cos(hp/2) rounds to 1
            raise fields.err(key, spec["half_power_beamwidth_deg"],
                             f"so narrow a beam has a peak directivity 2 (q + 1) above "
                             f"{MAX_DIRECTIVITY:g} (120 dBi), beyond any antenna")
    try:
        return CosinePowerPattern(polarization=jones, q=q)
    except ValueError as exc:
        raise fields.err(key, spec[key.rsplit(".", 1)[1]], str(exc)) from None


def _file_pattern(fields, spec, k, polarization, base_dir) -> Pattern:
    """A tabulated pattern file (CSV or NPZ) relative to ``base_dir``."""
    rel = fields.get_str(spec, "path", k)
    normalize = fields.get_bool(spec, "normalize", k, default=True)
    path = base_dir / rel
    if not is_file(path):
        raise fields.err(f"{k}.path", rel, f"pattern file not found (looked for {path})")
    fields.note_read(path)
    try:
        return load_pattern_file(path, polarization=polarization, normalize=normalize)
    except SceneError as exc:
        raise fields.err(f"{k}.path", rel, f"bad pattern file: {exc}") from None
