"""The ``[[materials]]`` entries of a scene file -> :class:`MaterialTable`, and the lookup
of an object's ``material`` name in it (built-ins join the table on first use)."""

from __future__ import annotations

import difflib
import math
import warnings
from dataclasses import dataclass, field
from typing import Any

from clradcom.errors import NOVALUE, SceneError, SceneWarning
from clradcom.scene.fields import FieldReader
from clradcom.scene.materials import (
    ROUGHNESS_MODELS,
    Material,
    builtin_material,
    builtin_material_names,
    conductivity_to_eps_imag,
    itu_conductivity,
    itu_permittivity,
    with_overrides,
    xpd_db_to_cross_pol_share,
)

__all__ = ["MATERIAL_KEYS", "MaterialTable", "material_index", "read_materials"]

MATERIAL_KEYS = ("name", "base", "itu", "eps_r", "conductivity_s_m", "pec", "roughness_m",
                 "roughness_model", "scattering_coefficient", "cross_pol_share", "xpd_db",
                 "allow_extrapolation", "description")
_SOURCES = ("base", "itu", "eps_r", "pec")


@dataclass
class MaterialTable:
    """A scene's materials: the user's in file order, then built-ins in order of first use."""

    materials: list[Material] = field(default_factory=list)
    index: dict[str, int] = field(default_factory=dict)  # name -> position in materials
    user_names: list[str] = field(default_factory=list)  # the [[materials]] names


def read_materials(fields: FieldReader, entries: list, carrier: float) -> MaterialTable:
    """Read the ``[[materials]]`` entries (user materials only) at the carrier frequency."""
    table = MaterialTable()
    seen: dict = {}
    builtins = set(builtin_material_names())
    for i, tbl in enumerate(entries):
        kp = f"materials[{i}]"
        fields.check_keys(tbl, MATERIAL_KEYS, kp)
        name = fields.unique_name(tbl, kp, seen, "material")
        if name in builtins:
            raise fields.err(f"{kp}.name", name,
                             "this name belongs to a built-in material; pick another name "
                             f"and write base = '{name}' to start from it")
        material = _read_material(fields, tbl, kp, name, table, carrier)
        table.index[name] = len(table.materials)  # only now: no entry is its own base
        table.materials.append(material)
    table.user_names = list(table.index)
    return table


def material_index(fields: FieldReader, table: MaterialTable, name: str, key: str,
                   carrier: float) -> int:
    """Index of material ``name`` in ``table``; a built-in is appended on first use."""
    if name in table.index:
        return table.index[name]
    try:
        mat = builtin_material(name, carrier, file=fields.file, key=key)
    except KeyError:
        raise unknown_material_error(fields, key, name, table.user_names) from None
    table.index[name] = len(table.materials)
    table.materials.append(mat)
    return table.index[name]


def unknown_material_error(fields: FieldReader, key: str, name: str,
                           user_names) -> SceneError:
    """Refusal of an unknown material name; the hint looks among ``user_names`` and the
    built-ins, the list shown is the built-ins."""
    known = list(user_names) + builtin_material_names()
    close = difflib.get_close_matches(name, known, n=1)
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    return fields.err(key, name, f"unknown material{hint}; define it under [[materials]] or "
                      f"use a built-in: {', '.join(builtin_material_names())}")


def _read_material(fields, tbl, kp, name, table: MaterialTable, carrier) -> Material:
    source = _material_source(fields, tbl, kp)
    if source == "base":
        mat = _base_material(fields, tbl, kp, name, table, carrier)
    elif source == "itu":
        mat = _itu_material(fields, tbl, kp, name, carrier)
    elif source == "pec":
        mat = Material(name, complex(math.inf, 0.0), pec=True)
    else:
        mat = _permittivity_material(fields, tbl, kp, name, carrier)
    changes = _surface_changes(fields, tbl, kp)
    return with_overrides(mat, **changes) if changes else mat


def _material_source(fields, tbl, kp) -> str:
    """Which one of base, itu, eps_r or pec = true the entry gives."""
    sources = [k for k in ("base", "itu", "eps_r") if k in tbl]
    pec = fields.get_bool(tbl, "pec", kp, default=False)
    if pec:
        sources.append("pec")
    if len(sources) != 1:
        value = {k: tbl[k] for k in _SOURCES if k in tbl}
        raise fields.err(kp, value if value else NOVALUE,
                         "give exactly one of base, itu, eps_r or pec = true"
                         + (f" (got {', '.join(sources)})" if sources else ""))
    source = sources[0]
    if "allow_extrapolation" in tbl and source != "itu":
        raise fields.err(f"{kp}.allow_extrapolation", tbl["allow_extrapolation"],
                         "only applies together with itu")
    if "conductivity_s_m" in tbl and source != "eps_r":
        raise fields.err(f"{kp}.conductivity_s_m", tbl["conductivity_s_m"],
                         "only applies together with eps_r")
    return source


def _base_material(fields, tbl, kp, name, table: MaterialTable, carrier) -> Material:
    """A copy of an earlier user material or a built-in (the hint of an unknown base looks
    among the built-ins only)."""
    base_name = fields.get_str(tbl, "base", kp)
    if base_name == name:
        raise fields.err(f"{kp}.base", base_name, "a material cannot be its own base; name "
                         "a built-in or an earlier [[materials]] entry")
    if base_name in table.index:
        base = table.materials[table.index[base_name]]
    else:
        try:
            base = builtin_material(base_name, carrier, file=fields.file, key=f"{kp}.base")
        except KeyError:
            raise unknown_material_error(fields, f"{kp}.base", base_name, ()) from None
    return with_overrides(base, name=name, source=f"user (base {base_name})")


def _itu_material(fields, tbl, kp, name, carrier) -> Material:
    itu = fields.get_str(tbl, "itu", kp)
    extrapolate = fields.get_bool(tbl, "allow_extrapolation", kp, default=False)
    eps = itu_permittivity(itu, carrier, extrapolate=extrapolate, file=fields.file,
                           key=f"{kp}.itu")
    with warnings.catch_warnings():  # already warned (or refused) just above
        warnings.simplefilter("ignore", SceneWarning)
        sigma = itu_conductivity(itu, carrier, extrapolate=True)
    return Material(name, eps, conductivity_s_m=sigma, source=f"user (itu {itu})")


def _permittivity_material(fields, tbl, kp, name, carrier) -> Material:
    """``eps_r`` (a number or [real, imag]), plus ``conductivity_s_m`` when given."""
    k = f"{kp}.eps_r"
    v = tbl["eps_r"]
    if isinstance(v, list):
        re_, im = fields.vector(v, k, 2)
    else:
        re_, im = fields.number(v, k, "a number or [real, imag]"), 0.0
    if im > 0:
        raise fields.err(k, v, "positive imaginary part: clradcom uses the e^{+j omega t} "
                         "convention, so a lossy permittivity is eps' - j eps'' and its "
                         f"imaginary part must be <= 0 (write [{re_:g}, {-im:g}])")
    if re_ <= 0:
        raise fields.err(k, v, "real part must be > 0 (for a metal use pec = true)")
    sigma = math.nan
    if "conductivity_s_m" in tbl:
        sigma = fields.get_float(tbl, "conductivity_s_m", kp, lo=0.0, unit="S/m")
        im -= conductivity_to_eps_imag(sigma, carrier)
        if not math.isfinite(im):
            raise fields.err(f"{kp}.conductivity_s_m", tbl["conductivity_s_m"],
                             "so large that eps'' = sigma / (2 pi f eps0) overflows at the "
                             "carrier; for a metal use pec = true")
    return Material(name, complex(re_, im), conductivity_s_m=sigma)


def _surface_changes(fields, tbl, kp) -> dict[str, Any]:
    """Roughness, scattering and cross-polarisation keys given on top of the source."""
    changes: dict[str, Any] = {}
    if "roughness_m" in tbl:
        changes["roughness_m"] = fields.get_float(tbl, "roughness_m", kp, lo=0.0, unit="m")
    if "roughness_model" in tbl:
        changes["roughness_model"] = fields.get_str(tbl, "roughness_model", kp,
                                                    choices=ROUGHNESS_MODELS)
    if "scattering_coefficient" in tbl:
        changes["scattering_coefficient"] = fields.get_float(
            tbl, "scattering_coefficient", kp, lo=0.0, hi=1.0)
    if "cross_pol_share" in tbl and "xpd_db" in tbl:
        raise fields.err(f"{kp}.xpd_db", tbl["xpd_db"],
                         "give cross_pol_share or xpd_db, not both")
    if "cross_pol_share" in tbl:
        changes["cross_pol_share"] = fields.get_float(tbl, "cross_pol_share", kp,
                                                      lo=0.0, hi=1.0)
    if "xpd_db" in tbl:
        changes["cross_pol_share"] = xpd_db_to_cross_pol_share(
            fields.get_float(tbl, "xpd_db", kp, unit="dB"))
    return changes
