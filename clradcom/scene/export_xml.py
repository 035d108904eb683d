"""A loaded scene -> a Mitsuba 3 / Sionna RT XML scene (the reverse of
:mod:`clradcom.scene.import_xml`), so another ray tracer traces the very same triangles.

:func:`write_xml_scene` writes ``<folder>/<name>.xml`` and one binary PLY per object
under ``<folder>/meshes/``: the object's world triangles (float32 vertices, as Mitsuba
holds them, three per triangle, in the scene's winding, no ``to_world``), a ``<shape
type="ply">`` whose id is the object's name, and one ``<bsdf type="radio-material">``
per material used (id: :data:`BSDF_PREFIX` + name) (``relative_permittivity`` = eps',
``conductivity`` = eps'' omega eps0 at the scene's carrier, ``scattering_coefficient``).
Mitsuba and Sionna have no perfect conductor: a PEC material is written with
:data:`PEC_CONDUCTIVITY_S_M` (ITU-R P.2040-3's metal). Radars, velocities and the
carrier are not written (Sionna sets them in Python). ``thickness_m`` (optional) is
written into every material: Sionna >= 1.0 reflects off a slab of that thickness,
clradcom off a half-space; a slab a few skin depths thick reflects as the half-space
does.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import trimesh

from clradcom.errors import ArgumentError
from clradcom.files import atomic_write
from clradcom.scene.materials import EPS0
from clradcom.scene.records import Scene

__all__ = ["BSDF_PREFIX", "PEC_CONDUCTIVITY_S_M", "write_xml_scene"]

#: BSDF ids are the material names behind this prefix: Sionna refuses a custom material
#: named like one of its ITU materials ("metal", "concrete")
BSDF_PREFIX = "clradcom_"
#: conductivity a PEC material is written with (S/m): ITU-R P.2040-3 Table 3's metal
PEC_CONDUCTIVITY_S_M = 1e7


def _mesh_ply(triangles: np.ndarray) -> bytes:
    """Binary PLY of (T, 3, 3) world triangles, three vertices per triangle (shared
    corners are not merged: the file holds exactly the scene's triangles)."""
    vertices = np.ascontiguousarray(triangles, dtype=np.float64).reshape(-1, 3)
    faces = np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    return mesh.export(file_type="ply", encoding="binary")


def _material_xml(material, carrier_hz: float, thickness_m: float | None) -> str:
    if material.pec:
        eps_real, sigma = 1.0, PEC_CONDUCTIVITY_S_M
    else:
        eps_real = float(material.eps_r.real)
        sigma = -float(material.eps_r.imag) * 2.0 * math.pi * carrier_hz * EPS0
    lines = [f'    <bsdf type="radio-material" id={quoteattr(BSDF_PREFIX + material.name)}>',
             f'        <float name="relative_permittivity" value="{eps_real!r}"/>',
             f'        <float name="conductivity" value="{sigma!r}"/>',
             f'        <float name="scattering_coefficient" '
             f'value="{float(material.scattering_coefficient)!r}"/>']
    if thickness_m is not None:
        lines.append(f'        <float name="thickness" value="{float(thickness_m)!r}"/>')
    lines.append("    </bsdf>")
    return "\n".join(lines)


def write_xml_scene(scene: Scene, folder: str | os.PathLike, *,
                    thickness_m: float | None = None) -> Path:
    """Write ``scene``'s geometry and materials as ``<folder>/<scene.name>.xml`` with its
    meshes under ``<folder>/meshes/``; returns the XML file's path. ``folder`` must
    exist."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ArgumentError("must be an existing folder", argument="folder", value=str(folder))
    if thickness_m is not None and not (math.isfinite(thickness_m) and thickness_m > 0):
        raise ArgumentError("must be a finite number > 0 (m)", argument="thickness_m",
                            value=thickness_m)
    meshes = folder / "meshes"
    meshes.mkdir(exist_ok=True)
    used = sorted({o.material for o in scene.objects if o.n_triangles})
    parts = ['<scene version="2.1.0">',
             *(_material_xml(scene.materials[m], scene.carrier_hz, thickness_m)
               for m in used)]
    for obj in scene.objects:
        if not obj.n_triangles:
            continue
        ply = meshes / f"{obj.name}.ply"
        data = _mesh_ply(scene.triangles[obj.tri_slice])
        atomic_write(ply, lambda fh, data=data: fh.write(data))
        parts += [f'    <shape type="ply" id={quoteattr(obj.name)}>',
                  f'        <string name="filename" value={quoteattr("meshes/" + ply.name)}/>',
                  f'        <ref id={quoteattr(BSDF_PREFIX + obj.material_name)} name="bsdf"/>',
                  "    </shape>"]
    parts.append("</scene>\n")
    text = "\n".join(parts).encode()
    target = folder / f"{scene.name}.xml"
    atomic_write(target, lambda fh: fh.write(text))
    return target
