"""A radar's antenna arrays in the scene file: ``array`` (one array that both transmits
and receives), or ``tx_array`` and ``rx_array`` -> :class:`ArrayLayout` records.

An array table is a uniform linear array (``kind = "ula"``: ``count``, ``spacing_*``,
``axis``), a uniform planar array (``kind = "upa"``: ``counts``, ``spacing_*``, ``axes``)
or explicit element positions (``kind = "positions"``), all in the radar's own frame
(boresight local +x, local z up), in wavelengths at the scene's carrier or in metres.
ULA and UPA are centred on the radar's position; explicit positions are offsets from it.
Every element has the radar's pattern and polarisation unless the array table gives its
own (``pattern``/``polarization``: every element of this array) or ``elements`` gives one
element's (a list of E tables with ``pattern``/``polarization``, element order as the
positions); each key falls back element -> array -> radar. Every refusal names the file,
key and value (docs/scene-format.md, "Arrays").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clradcom.scene.fields import FieldReader, key_path
from clradcom.scene.read_patterns import read_pattern
from clradcom.scene.records import ARRAY_KINDS, ArrayLayout

__all__ = ["ARRAY_KEYS", "MAX_ELEMENTS", "read_arrays"]

ARRAY_KEYS = ("kind", "count", "counts", "spacing_wavelengths", "spacing_m", "axis", "axes",
              "positions_wavelengths", "positions_m", "pattern", "polarization", "elements")
#: the keys of one entry of an array's ``elements`` list
ELEMENT_KEYS = ("pattern", "polarization")
#: the keys every kind of array takes besides its geometry
_SHARED_KEYS = {"kind", "pattern", "polarization", "elements"}
#: elements per array at most (a frame per element pair is synthesised)
MAX_ELEMENTS = 4096
#: an array larger than this (m) is refused: the radar model is one position per radar
MAX_EXTENT_M = 100.0


def read_arrays(fields: FieldReader, tbl: dict, kp: str, wavelength_m: float,
                base_dir: Path | None = None):
    """(tx_array, rx_array) of one ``[[radars]]`` entry; None where not given.
    ``base_dir``: where pattern files are looked for (the scene file's folder)."""
    base = Path(".") if base_dir is None else Path(base_dir)
    shared = "array" in tbl
    if shared and ("tx_array" in tbl or "rx_array" in tbl):
        key = "tx_array" if "tx_array" in tbl else "rx_array"
        raise fields.err(key_path(kp, key), tbl[key],
                         "give either 'array' (one array for transmit and receive) or "
                         "'tx_array'/'rx_array', not both")
    if shared:
        a = _read_array(fields, tbl["array"], key_path(kp, "array"), wavelength_m, tbl, base)
        return a, a
    tx = (_read_array(fields, tbl["tx_array"], key_path(kp, "tx_array"), wavelength_m, tbl,
                      base) if "tx_array" in tbl else None)
    rx = (_read_array(fields, tbl["rx_array"], key_path(kp, "rx_array"), wavelength_m, tbl,
                      base) if "rx_array" in tbl else None)
    return tx, rx


def _unit(fields, key, v, wavelength_m):
    if key.endswith("_m"):
        return 1.0
    if wavelength_m is None:
        raise fields.err(key, v, "a length in wavelengths needs the scene's carrier_hz")
    return float(wavelength_m)


def _count(fields, v, key, lo=1):
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= MAX_ELEMENTS:
        raise fields.err(key, v, f"expected a whole number in [{lo}, {MAX_ELEMENTS}]")
    return int(v)


def _scale(fields, spec, kp, wavelength_m, n_values):
    """Spacing(s) in metres from exactly one of spacing_wavelengths / spacing_m."""
    have = [k for k in ("spacing_wavelengths", "spacing_m") if k in spec]
    if len(have) != 1:
        raise fields.err(key_path(kp, "spacing_wavelengths"), spec.get(have[-1]) if have
                         else None, "give exactly one of spacing_wavelengths, spacing_m")
    key = have[0]
    unit = _unit(fields, key_path(kp, key), spec[key], wavelength_m)
    v = spec[key]
    vals = v if isinstance(v, list) else [v] * n_values
    if len(vals) != n_values:
        raise fields.err(key_path(kp, key), v,
                         f"expected a number or an array of {n_values} numbers")
    out = np.array([fields.number(x, key_path(kp, key)) for x in vals]) * unit
    if np.any(out <= 0):
        raise fields.err(key_path(kp, key), v, "spacing must be > 0")
    return out


def _axis(fields, v, key):
    a = fields.vector(v, key, 3)
    n = float(np.linalg.norm(a))
    if n == 0:
        raise fields.err(key, v, "an axis must not be the zero vector")
    return a / n


def _element_patterns(fields, spec, kp, n, radar_tbl, base_dir):
    """(E,) patterns of the elements, or None where the array names none."""
    elements = spec.get("elements")
    if elements is not None and (not isinstance(elements, list) or len(elements) != n
                                 or not all(isinstance(e, dict) for e in elements)):
        raise fields.err(key_path(kp, "elements"), elements,
                         f"expected a list of {n} tables (one per element, e.g. "
                         "{ pattern = \"sector\", polarization = \"H\" })")
    if elements is None and "pattern" not in spec and "polarization" not in spec:
        return None
    out = []
    for e in range(n):
        merged = {k: radar_tbl[k] for k in ELEMENT_KEYS if k in radar_tbl}
        merged.update({k: spec[k] for k in ELEMENT_KEYS if k in spec})
        where = kp
        if elements is not None:
            where = f"{key_path(kp, 'elements')}[{e}]"
            fields.check_keys(elements[e], ELEMENT_KEYS, where)
            merged.update(elements[e])
        pattern, _, _ = read_pattern(fields, merged, where, base_dir)  # Jones inside
        out.append(pattern)
    return tuple(out)


def _read_array(fields: FieldReader, spec, kp: str, wavelength_m: float, radar_tbl=None,
                base_dir: Path | None = None) -> ArrayLayout:
    if not isinstance(spec, dict):
        raise fields.err(kp, spec, "expected a table (e.g. { kind = \"ula\", count = 4, "
                                   "spacing_wavelengths = 0.5 })")
    fields.check_keys(spec, ARRAY_KEYS, kp)
    kind = fields.get_str(spec, "kind", kp, choices=ARRAY_KINDS)
    allowed = _SHARED_KEYS | {"ula": {"count", "spacing_wavelengths", "spacing_m", "axis"},
                              "upa": {"counts", "spacing_wavelengths", "spacing_m", "axes"},
                              "positions": {"positions_wavelengths", "positions_m"}}[kind]
    for k in spec:
        if k not in allowed:
            raise fields.err(key_path(kp, k), spec[k],
                             f"not a key of kind = \"{kind}\"; its keys: "
                             f"{', '.join(sorted(allowed))}")
    if kind == "ula":
        n = _count(fields, fields.get(spec, "count", kp), key_path(kp, "count"))
        d = _scale(fields, spec, kp, wavelength_m, 1)[0]
        axis = _axis(fields, spec.get("axis", [0.0, 1.0, 0.0]), key_path(kp, "axis"))
        pos = np.outer((np.arange(n) - (n - 1) / 2.0) * d, axis)
    elif kind == "upa":
        c = fields.get(spec, "counts", kp)
        if not isinstance(c, list) or len(c) != 2:
            raise fields.err(key_path(kp, "counts"), c, "expected [n_1, n_2]")
        n1, n2 = (_count(fields, x, key_path(kp, "counts")) for x in c)
        if n1 * n2 > MAX_ELEMENTS:
            raise fields.err(key_path(kp, "counts"), c,
                             f"at most {MAX_ELEMENTS} elements in all")
        d = _scale(fields, spec, kp, wavelength_m, 2)
        ax = spec.get("axes", [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        if not isinstance(ax, list) or len(ax) != 2:
            raise fields.err(key_path(kp, "axes"), ax, "expected two axes [[x,y,z], [x,y,z]]")
        a1, a2 = (_axis(fields, v, key_path(kp, "axes")) for v in ax)
        if abs(a1 @ a2) > 1e-9:
            raise fields.err(key_path(kp, "axes"), ax, "the two axes must be perpendicular")
        i1 = (np.arange(n1) - (n1 - 1) / 2.0) * d[0]
        i2 = (np.arange(n2) - (n2 - 1) / 2.0) * d[1]
        g1, g2 = np.meshgrid(i1, i2, indexing="ij")  # element (i, j) at row i * n2 + j
        pos = g1.reshape(-1, 1) * a1 + g2.reshape(-1, 1) * a2
    else:
        have = [k for k in ("positions_wavelengths", "positions_m") if k in spec]
        if len(have) != 1:
            raise fields.err(key_path(kp, "positions_m"), None,
                             "give exactly one of positions_wavelengths, positions_m")
        key = key_path(kp, have[0])
        v = spec[have[0]]
        if not isinstance(v, list) or not 1 <= len(v) <= MAX_ELEMENTS:
            raise fields.err(key, v, f"expected an array of 1 to {MAX_ELEMENTS} [x, y, z]")
        pos = np.array([fields.vector(p, key, 3) for p in v])
        pos = pos * _unit(fields, key, v, wavelength_m)
        _, first = np.unique(pos, axis=0, return_index=True)
        if first.size != len(v):
            dup = sorted(set(range(len(v))) - set(first.tolist()))[0]
            raise fields.err(key, v[dup], f"element {dup} repeats another element's position")
    extent = float(np.max(np.linalg.norm(pos, axis=1)))
    if extent > MAX_EXTENT_M:
        raise fields.err(kp, spec, f"an element lies {extent:g} m from the radar's position;"
                                   f" at most {MAX_EXTENT_M:g} m")
    patterns = _element_patterns(fields, spec, kp, pos.shape[0], radar_tbl or {},
                                 Path(".") if base_dir is None else base_dir)
    return ArrayLayout(kind=kind, positions_local=pos, patterns=patterns)
