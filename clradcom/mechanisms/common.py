"""What every propagation mechanism shares: the prepared scene and the antennas' reach.

Every mechanism module (:mod:`~clradcom.mechanisms.specular`,
:mod:`~clradcom.mechanisms.diffraction`, :mod:`~clradcom.mechanisms.optics`,
:mod:`~clradcom.mechanisms.scattering`) has the same shape:

* a frozen settings dataclass (``SpecularSettings``, ...) that checks its own values;
* ``prepare(geom, tx, settings)``: what one transmitter shares with all its receivers
  (ray-launched candidates, SBR ray tubes, ...), computed once per transmitter;
* ``link_paths(geom, prepared, tx, rx, settings)``: the mechanism's :class:`Paths` of one
  tx -> rx link.

:mod:`clradcom.trace` wires them together and keeps the per-transmitter caches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clradcom.device.raycast import RayCaster
from clradcom.device.runtime import Runtime, get_runtime
from clradcom.errors import ArgumentError
from clradcom.geometry.faces import Faces, merge_coplanar
from clradcom.scene.records import Radar, Scene

__all__ = ["ENGINES", "Geometry", "build_geometry", "check_number", "seen_by_antennas"]

#: How the interactions are resolved: "device" in OpenCL kernels (the default), "host" in
#: numpy over ray casts (the reference the device engine is tested against).
ENGINES = ("device", "host")


@dataclass
class Geometry:
    """What the mechanisms need about a scene, built once: planar faces and the caster."""

    scene: Scene
    faces: Faces
    caster: RayCaster | None  # None for a scene without triangles (free space)
    runtime: Runtime
    engine: str = "device"  # one of ENGINES


def build_geometry(scene: Scene, runtime: Runtime | None = None,
                   engine: str = "device") -> Geometry:
    if engine not in ENGINES:
        raise ArgumentError(f"must be one of {', '.join(ENGINES)}", argument="engine",
                            value=engine)
    runtime = runtime or get_runtime()
    faces = merge_coplanar(scene.triangles, scene.tri_object, scene.tri_material)
    # a BVH needs triangles; a free-space scene has only line-of-sight paths
    caster = RayCaster(scene.triangles, runtime=runtime) if len(scene.triangles) else None
    return Geometry(scene=scene, faces=faces, caster=caster, runtime=runtime, engine=engine)


def seen_by_antennas(tx: Radar, rx: Radar, k_dep, k_arr) -> np.ndarray:
    """Paths that leave inside tx's pattern and arrive inside rx's (non-zero gain)."""
    return (np.asarray(tx.pattern.gain(k_dep @ np.asarray(tx.orientation))) > 0) & (
        np.asarray(rx.pattern.gain(-k_arr @ np.asarray(rx.orientation))) > 0)


def check_number(owner: str, name: str, value, *, low=None, high=None, integer=False,
                 low_open=False) -> None:
    """Refuse a settings field that is not a (finite, in-range) number, naming it.

    ``owner`` names the settings class (``SpecularSettings``); bounds are inclusive
    unless ``low_open``.
    """
    kinds = (int,) if integer else (int, float)
    ok = not isinstance(value, bool) and isinstance(value, kinds) and np.isfinite(value)
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value <= high
    if not ok:
        what = "an integer" if integer else "a finite number"
        rng = "" if low is None and high is None else " in " + (
            f"({low}" if low_open else f"[{low}" if low is not None else "(-inf") + ", " + (
            f"{high}]" if high is not None else "inf)")
        raise ArgumentError(f"must be {what}{rng}", argument=f"{owner}.{name}", value=value)
