"""Monostatic RCS of a PEC model against aspect angle: pure GO against PO + SBR.

A radar circles the model at range R and height h (:func:`aspect_scene`); aspect 0° looks
at the nose (+x), 90° at the left side, 180° at the rear. No ground: the model's own
returns only. Per aspect (:func:`aspect_rcs`):

* GO: image-method paths up to ``bounces`` reflections (candidates from a dense ray grid
  over the model, exact paths and fields as in :mod:`clradcom.mechanisms.specular`); a
  flat facet seen at its specular angle returns like an infinite mirror (pi R^2 at range
  R), any other facet nothing.
* PO + SBR: physical-optics facet integrals for the first bounce
  (:func:`clradcom.mechanisms.physical_optics.po_paths`), shooting-and-bouncing ray
  tubes with PO radiation for bounces 2..``bounces``
  (:func:`clradcom.mechanisms.sbr.sbr_paths`).

RCS here is the apparent one at the stated range, sigma = |a|^2 (4 pi)^3 R^4 / lambda^2
with the coherent sum a of all paths, isotropic antennas, VV and HH from the polarimetric
matrix (:func:`dbsm`). tools/rcs_aspect.py prints, writes and draws what these return.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from clradcom.device.runtime import Runtime
from clradcom.errors import ArgumentError
from clradcom.figures import new_figure
from clradcom.files import save_figure, write_csv
from clradcom.mechanisms import specular as sp
from clradcom.mechanisms.common import build_geometry
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.mechanisms.sbr import bounding_sphere, launch_tubes, sbr_paths
from clradcom.physics.em import C0
from clradcom.scene.models import car_mesh, rounded_car
from clradcom.scene.reader import scene_from_dict
from clradcom.scene.records import Scene

__all__ = ["CARRIER_HZ", "FLOOR_DBSM", "MAX_TUBES", "MODELS", "AspectRcs", "aspect_rcs",
           "aspect_scene", "check_aspect_grids", "dbsm", "grid_tubes", "model_mesh", "plot_rcs",
           "write_rcs_csv"]

CARRIER_HZ = 24e9
FLOOR_DBSM = -40.0  # plotted where a method returns nothing
#: the car models: "car" car_mesh(); "rounded" rounded_car(face_centred=True), whose nose
#: and side carry facets facing exactly +x and +y
MODELS = ("car", "rounded")
#: most GO candidate rays of one grid (the ``max_rays`` of
#: :func:`clradcom.mechanisms.sbr.launch_tubes`, which refuses more)
MAX_TUBES = 4_000_000


def dbsm(m, range_m: float, wavelength_m: float):
    """Apparent RCS in dBsm of the path sum ``m`` (matrix entry or gain) at a range:
    10 log10(|m|^2 (4 pi)^3 R^4 / lambda^2); -inf where m is 0."""
    s = np.abs(m) ** 2 * (4 * np.pi) ** 3 * range_m**4 / wavelength_m**2
    with np.errstate(divide="ignore"):
        return 10 * np.log10(s)


def model_mesh(model: str):
    """The trimesh of one of :data:`MODELS`."""
    if model == "car":
        return car_mesh()
    if model == "rounded":
        return rounded_car(face_centred=True)
    raise ArgumentError(f"must be one of {', '.join(map(repr, MODELS))}", argument="model",
                        value=model)


def aspect_scene(mesh, aspects_deg, range_m: float, height_m: float,
                 carrier_hz: float = CARRIER_HZ) -> Scene:
    """The PEC model (wheels on z = 0) and one isotropic txrx radar per aspect angle,
    named a000, a001, ..., at range_m from the origin and height_m above it."""
    positions = [[range_m * np.cos(np.radians(a)), range_m * np.sin(np.radians(a)), height_m]
                 for a in aspects_deg]
    return scene_from_dict({
        "scene": {"name": "rcs_aspect", "carrier_hz": carrier_hz},
        "objects": [{"name": "car", "material": "metal", "shape": "triangles",
                     "vertices": np.asarray(mesh.vertices).tolist(),
                     "faces": np.asarray(mesh.faces).tolist()}],
        "radars": [{"name": f"a{i:03d}", "position": p, "pattern": "isotropic"}
                   for i, p in enumerate(positions)]})


def grid_tubes(radius_m: float, distance_m: float, spacing_m: float) -> int:
    """Ray tubes of one square grid of pitch ``spacing_m`` over a sphere of ``radius_m``
    seen from ``distance_m`` away, counted as :func:`~clradcom.mechanisms.sbr.launch_tubes`
    counts them."""
    rho = radius_m * distance_m / np.sqrt(distance_m**2 - radius_m**2) + spacing_m
    return (2 * int(np.ceil(rho / spacing_m)) + 1) ** 2


def check_aspect_grids(scene: Scene, range_m: float, *, spacing_wavelengths: float = 0.5,
                       go_spacing_m: float = 0.01, names=None) -> None:
    """Refuse, before anything is traced, what :func:`aspect_rcs` cannot do: a radar
    inside (or on) the model's bounding sphere, and a GO candidate grid of more than
    :data:`MAX_TUBES` rays. :class:`~clradcom.errors.ArgumentError` names the argument
    (``names`` maps "range_m", "go_spacing_m", "spacing_wavelengths" to what the caller
    calls them, a command-line option say)."""
    names = {"range_m": "range_m", "go_spacing_m": "go_spacing_m",
             "spacing_wavelengths": "spacing_wavelengths", **(names or {})}
    for key, v in (("range_m", range_m), ("go_spacing_m", go_spacing_m),
                   ("spacing_wavelengths", spacing_wavelengths)):
        if isinstance(v, bool) or not isinstance(v, int | float) or not 0 < v < np.inf:
            raise ArgumentError("must be positive and finite", argument=names[key], value=v)
    centre, radius = bounding_sphere(scene.triangles)
    dist = min(float(np.linalg.norm(np.asarray(r.position) - centre)) for r in scene.radars)
    if dist <= radius * 1.001:
        raise ArgumentError(f"puts a radar {dist:.3g} m from the centre of the model's "
                            f"bounding sphere (radius {radius:.3g} m): it must lie outside it",
                            argument=names["range_m"], value=range_m)
    # the SBR tubes are streamed with no cap; the GO candidate rays are one grid in memory
    n = grid_tubes(radius, dist, go_spacing_m)
    if n > MAX_TUBES:
        raise ArgumentError(f"needs {n} ray tubes over the model's bounding sphere "
                            f"(radius {radius:.3g} m), more than {MAX_TUBES}; use a "
                            f"coarser spacing", argument=names["go_spacing_m"],
                            value=go_spacing_m)


@dataclass
class AspectRcs:
    """One aspect: its CSV row and what each method cost."""

    #: aspect_deg, {go,po_sbr,po_only}_{vv,hh}_dbsm, go_paths, po_facets, sbr_paths
    row: dict
    go_s: float
    po_s: float
    sbr_s: float
    #: about how many SBR tubes cover the model's bounding sphere from this radar
    tubes: int


def aspect_rcs(scene: Scene, aspects_deg, range_m: float, runtime: Runtime | None = None, *,
               bounces: int = 3, spacing_wavelengths: float = 0.5,
               go_spacing_m: float = 0.01) -> Iterator[AspectRcs]:
    """GO and PO + SBR RCS of the scene's object for each radar of an
    :func:`aspect_scene`, one aspect at a time (timed with time.perf_counter; the
    kernels are compiled before the first one).

    ``spacing_wavelengths``: SBR ray-tube pitch at the model; ``go_spacing_m``: pitch of
    the GO candidate rays at the model.
    """
    check_aspect_grids(scene, range_m, spacing_wavelengths=spacing_wavelengths,
                       go_spacing_m=go_spacing_m)
    lam = C0 / scene.carrier_hz
    geom = build_geometry(scene, runtime)
    sphere = bounding_sphere(scene.triangles)
    # compile the kernels outside the timed loops
    po_paths(geom, scene.radars[0], scene.radars[0])
    for a, radar in zip(aspects_deg, scene.radars, strict=True):
        dist = np.linalg.norm(np.asarray(radar.position) - sphere[0])
        t0 = time.perf_counter()
        grid = launch_tubes(radar.position, [sphere], go_spacing_m)
        seqs = sp.reflection_sequences(geom.caster, geom.faces.tri_face, radar.position,
                                       grid.directions, bounces)
        pg = sp.specular_paths(geom, radar.position, radar.position,
                               sp.unique_candidates(seqs), line_of_sight=False)
        go = sp.path_fields(geom, pg, radar, radar)
        t1 = time.perf_counter()
        po = po_paths(geom, radar, radar)
        t2 = time.perf_counter()
        sbr = sbr_paths(geom, radar, radar, objects=[0],
                        spacing_wavelengths=spacing_wavelengths, max_bounces=bounces)
        t3 = time.perf_counter()
        tubes = int(np.ceil(np.pi * (sphere[1] * dist / np.sqrt(dist**2 - sphere[1]**2))
                            ** 2 / (spacing_wavelengths * lam) ** 2))
        m_go, m_po, m_sbr = (p.matrix.sum(axis=0) for p in (go, po, sbr))
        row = {"aspect_deg": a}
        for pol, k in (("vv", 0), ("hh", 1)):
            row[f"go_{pol}_dbsm"] = dbsm(m_go[k, k], range_m, lam)
            row[f"po_sbr_{pol}_dbsm"] = dbsm(m_po[k, k] + m_sbr[k, k], range_m, lam)
            row[f"po_only_{pol}_dbsm"] = dbsm(m_po[k, k], range_m, lam)
        row.update(go_paths=len(go), po_facets=len(po), sbr_paths=len(sbr))
        yield AspectRcs(row=row, go_s=t1 - t0, po_s=t2 - t1, sbr_s=t3 - t2, tubes=tubes)


def write_rcs_csv(path, rows, *, inputs=()) -> None:
    """The rows of :func:`aspect_rcs` as CSV, floats to 0.001; written atomically
    (:func:`clradcom.files.write_csv`)."""
    if not len(rows):
        raise ArgumentError("has no rows to write", argument="rows", value=rows)
    header = list(rows[0])
    write_csv(path, [[(f"{r[k]:.3f}" if isinstance(r[k], float) else r[k]) for k in header]
                     for r in rows], header, inputs=inputs)


def plot_rcs(rows, *, model: str, range_m: float, height_m: float, bounces: int,
             go_s: float, po_sbr_s: float, path=None, inputs=()) -> Figure:
    """RCS against aspect: GO (VV), PO + SBR (VV, HH) and PO facets alone (VV), their run
    times in the legend, nothing returned drawn at :data:`FLOOR_DBSM`. Written to ``path``
    when given, atomically and byte-identically (:func:`clradcom.files.save_figure`)."""
    a = np.array([r["aspect_deg"] for r in rows])
    fig = new_figure(figsize=(9, 5.5), layout="constrained")
    ax = fig.add_subplot()
    for key, style, label in (
            ("go_vv_dbsm", dict(color="tab:red", lw=1.0, marker="o", ms=3),
             f"GO image method, VV ({go_s:.1f} s)"),
            ("po_sbr_vv_dbsm", dict(color="tab:blue", lw=1.6),
             f"PO + SBR, VV ({po_sbr_s:.1f} s)"),
            ("po_sbr_hh_dbsm", dict(color="tab:blue", lw=1.0, ls="--"), "PO + SBR, HH"),
            ("po_only_vv_dbsm", dict(color="tab:gray", lw=0.8, ls=":"),
             "PO facets only (no SBR), VV")):
        y = np.array([r[key] for r in rows])
        ax.plot(a, np.maximum(y, FLOOR_DBSM), label=label, **style)
    ax.set_xlabel("aspect angle (deg; 0 = nose, 90 = side, 180 = rear)")
    ax.set_ylabel("monostatic RCS (dBsm)")
    ax.set_title(f"Car model ({model}), 24 GHz, radar at {range_m:g} m, "
                 f"{height_m:g} m high, up to {bounces} bounces")
    ax.set_ylim(bottom=FLOOR_DBSM - 2)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    if path is not None:
        save_figure(fig, path, inputs=inputs, dpi=120)
    return fig
