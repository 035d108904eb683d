"""Corner reflectors against their closed forms: the sweep behind the SBR pitch rule.

:func:`clradcom.mechanisms.sbr.spacing_for_accuracy` promises that a corner's RCS errs by
at most ``accuracy_db`` at the pitch it chooses.  This module holds it to that on the two
corners whose return has a closed form (Knott, Shaeffer & Tuley, *Radar Cross Section*,
2nd ed., table 6.1), monostatic, PEC, isotropic antennas, in the far field:

* the 90 degree dihedral, fold of length a, plates of width b, seen perpendicular to the
  fold at 45 degrees to both plates: sigma = 8 pi a^2 b^2 / lambda^2 (double bounce);
* the square trihedral of edge a along its symmetry axis: sigma = 12 pi a^4 / lambda^2
  (triple bounce).

Per corner, size and target (:func:`corner_error`) it measures the SBR part (bounces 2
and 3, what the closed form describes) and the total (PO facets of the first bounce +
SBR) against the closed form, VV and HH, at a range where the corner is deep in its far
field (:data:`RANGE_FACTOR`).  tools/sbr_pitch.py prints the sweep (docs/po.md shows it);
tests/test_sbr_pitch.py runs a coarse one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.mechanisms import sbr
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.physics.em import C0
from clradcom.scene.reader import scene_from_dict

__all__ = ["CARRIER_HZ", "CORNERS", "RANGE_FACTOR", "CornerError", "closed_form_m2", "quad",
           "corner_error", "corner_object", "corner_scene", "pitch_sweep", "triangles_object"]

CARRIER_HZ = 24e9
CORNERS = ("dihedral", "trihedral")
#: the radar sits RANGE_FACTOR D^2 / lambda from the corner (D its bounding diameter):
#: the aperture's Fresnel phase k (D/2)^2 / 2R stays below pi / (4 RANGE_FACTOR), whose
#: loss (< 0.01 dB at 16) is not the pitch's
RANGE_FACTOR = 16.0
#: quads per plate side: the plates' triangles (their PO facets stay far-field too)
PLATE_DIVISIONS = 2


def quad(p0, u, v, nu: int, nv: int, n_want) -> tuple[np.ndarray, list[list[int]]]:
    """nu x nv squares (2 nu nv triangles) of the parallelogram p0 + [0,1]u + [0,1]v,
    wound so that their normal points along n_want."""
    verts = np.array([p0 + u * i / nu + v * j / nv for i in range(nu + 1)
                      for j in range(nv + 1)])
    faces = []
    for i in range(nu):
        for j in range(nv):
            a = i * (nv + 1) + j
            c = a + nv + 1
            for t in ([a, c, c + 1], [a, c + 1, a + 1]):
                normal = np.cross(verts[t[1]] - verts[t[0]], verts[t[2]] - verts[t[0]])
                faces.append(t if normal @ n_want > 0 else [t[0], t[2], t[1]])
    return verts, faces


def corner_object(kind: str, size_m: float, width_m: float | None = None) -> dict:
    """The PEC corner as a scene object (``shape = "triangles"``).  Dihedral: fold of
    length ``size_m`` along z through the origin, plates of width ``width_m`` (default
    ``size_m``) opening to +x at +-45 degrees.  Trihedral: edges ``size_m`` along +x, +y,
    +z from the origin."""
    if kind not in CORNERS:
        raise ArgumentError(f"must be one of {', '.join(CORNERS)}", argument="kind",
                            value=kind)
    a = float(size_m)
    n = PLATE_DIVISIONS
    if kind == "dihedral":
        b = a if width_m is None else float(width_m)
        h = 1.0 / np.sqrt(2.0)
        z = np.array([0.0, 0.0, a])
        p0 = np.array([0.0, 0.0, -a / 2])
        parts = [quad(p0, b * np.array([h, h, 0.0]), z, n, n, np.array([h, -h, 0.0])),
                 quad(p0, b * np.array([h, -h, 0.0]), z, n, n, np.array([h, h, 0.0]))]
    else:
        X, Y, Z = np.eye(3)
        o = np.zeros(3)
        parts = [quad(o, a * Y, a * Z, n, n, X), quad(o, a * X, a * Z, n, n, Y),
                 quad(o, a * X, a * Y, n, n, Z)]
    return triangles_object(kind, parts)


def triangles_object(name: str, parts, **keys) -> dict:
    """A PEC ``[[objects]]`` entry of shape "triangles" made of ``parts``, (vertices,
    faces) pairs as :func:`quad` gives them, their faces renumbered into one list."""
    verts, faces, off = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces += [[k + off for k in t] for t in f]
        off += len(v)
    return {"name": name, "material": "metal", "shape": "triangles",
            "vertices": np.vstack(verts).tolist(), "faces": faces, **keys}


def closed_form_m2(kind: str, size_m: float, wavelength_m: float,
                   width_m: float | None = None) -> float:
    """The corner's multi-bounce RCS (m^2) seen along its axis (Knott table 6.1)."""
    a = float(size_m)
    if kind == "dihedral":
        b = a if width_m is None else float(width_m)
        return 8.0 * np.pi * a**2 * b**2 / wavelength_m**2
    return 12.0 * np.pi * a**4 / wavelength_m**2


def corner_scene(kind: str, size_m: float, width_m: float | None = None,
                 carrier_hz: float = CARRIER_HZ):
    """(scene, range_m): the corner and one isotropic radar on its axis, RANGE_FACTOR
    D^2 / lambda away."""
    obj = corner_object(kind, size_m, width_m)
    lam = C0 / carrier_hz
    verts = np.asarray(obj["vertices"])
    centre, radius = sbr.bounding_sphere(verts)
    diameter = 2.0 * radius
    range_m = max(RANGE_FACTOR * diameter**2 / lam, 10.0 * diameter)
    axis = np.array([1.0, 0.0, 0.0]) if kind == "dihedral" else np.ones(3) / np.sqrt(3.0)
    radar = {"name": "r", "position": (range_m * axis).tolist(), "pattern": "isotropic"}
    scene = scene_from_dict({"scene": {"name": kind, "carrier_hz": carrier_hz},
                             "objects": [obj], "radars": [radar]})
    return scene, range_m


@dataclass(frozen=True)
class CornerError:
    """One point of the sweep: the corner, its size and width (m), the target (dB), the
    pitch the rule chose (m), and the errors (dB, measured - closed form) of the SBR part
    and of the total, VV and HH each."""

    kind: str
    size_m: float
    width_m: float
    accuracy_db: float
    spacing_m: float
    sbr_db: tuple[float, float]
    total_db: tuple[float, float]

    @property
    def worst_sbr_db(self) -> float:
        return max(self.sbr_db, key=abs)

    @property
    def worst_total_db(self) -> float:
        return max(self.total_db, key=abs)


def corner_error(kind: str, size_m: float, accuracy_db: float, runtime=None, *,
                 width_m: float | None = None, engine: str = "device") -> CornerError:
    """The corner's monostatic RCS at the pitch ``spacing_for_accuracy`` chooses for
    ``accuracy_db``, against its closed form (module docstring)."""
    scene, R = corner_scene(kind, size_m, width_m)
    geom = build_geometry(scene, runtime, engine=engine)
    lam = scene.wavelength_m
    radar = scene.radars[0]
    spacing = float(sbr.spacing_for_accuracy(geom, [0], accuracy_db)[0])
    first = po_paths(geom, radar, radar, min_relative_db=-300)
    multi = sbr.sbr_paths(geom, radar, radar, objects=[0], accuracy_db=accuracy_db,
                          max_bounces=3, min_relative_db=-300)
    want = closed_form_m2(kind, size_m, lam, width_m)
    m_sbr = multi.matrix.sum(axis=0)
    m_all = first.matrix.sum(axis=0) + m_sbr

    def err(m):
        sigma = np.abs(m) ** 2 * (4 * np.pi) ** 3 * R**4 / lam**2
        with np.errstate(divide="ignore"):
            return tuple(float(10 * np.log10(sigma[p, p] / want)) for p in (0, 1))

    return CornerError(kind=kind, size_m=float(size_m),
                       width_m=float(size_m if width_m is None else width_m),
                       accuracy_db=float(accuracy_db), spacing_m=spacing,
                       sbr_db=err(m_sbr), total_db=err(m_all))


def pitch_sweep(kinds, sizes_wavelengths, accuracies_db, runtime=None, *,
                width_ratio: float = 1.0, engine: str = "device") -> list[CornerError]:
    """:func:`corner_error` over every corner, size (in wavelengths at CARRIER_HZ) and
    target; dihedrals' plates ``width_ratio`` times their fold."""
    lam = C0 / CARRIER_HZ
    out = []
    for kind in kinds:
        for size in sizes_wavelengths:
            a = float(size) * lam
            w = a * width_ratio if kind == "dihedral" else None
            for acc in accuracies_db:
                out.append(corner_error(kind, a, acc, runtime, width_m=w, engine=engine))
    return out
