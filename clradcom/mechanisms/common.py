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

import hashlib
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from clradcom.device.raycast import InstancedCaster, RayCaster
from clradcom.device.runtime import Runtime, get_runtime
from clradcom.errors import ArgumentError, ArgumentTypeError
from clradcom.geometry.faces import (
    Faces,
    area_weighted_planes,
    merge_coplanar,
    triangle_planes,
)
from clradcom.scene.motion import scene_at
from clradcom.scene.records import Radar, Scene

__all__ = ["ENGINES", "KEPT_GEOMETRIES", "Geometry", "GeometryCache", "build_geometry",
           "check_number", "forget_geometries", "geometry_key", "kept_geometry",
           "moving_objects", "seen_by_antennas"]

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
    #: what a mechanism derives from this geometry alone and keeps for the next trace of
    #: it (the wedges, under a key of everything else they depend on); shared by the
    #: traces of a :func:`kept_geometry`
    memo: dict = field(default_factory=dict)


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


#: how many geometries :func:`kept_geometry` keeps per thread (the latest used)
KEPT_GEOMETRIES = 2

# per thread: [(geometry_key, runtime, faces, caster, memo)], most recently used last. Per
# thread because two traces running at once in two threads would otherwise share one
# caster's reused ray buffers.
_KEPT = threading.local()


def geometry_key(scene: Scene) -> bytes:
    """A digest of what :func:`build_geometry` builds from: the triangles (their float64
    bytes), each triangle's object and material. Two scenes with equal keys get the same
    faces and BVH, bit for bit."""
    h = hashlib.blake2b(digest_size=20)
    for array, dtype in ((scene.triangles, np.float64), (scene.tri_object, np.int32),
                         (scene.tri_material, np.int32)):
        a = np.ascontiguousarray(array, dtype=dtype)
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    return h.digest()


def kept_geometry(scene: Scene, runtime: Runtime | None = None,
                  engine: str = "device") -> Geometry:
    """:func:`build_geometry` of ``scene``, its planar faces and ray caster (BVH, device
    buffers, the visibility kernels' face tables that hang on the caster, the wedges in
    ``Geometry.memo``) reused when one
    of the last :data:`KEPT_GEOMETRIES` calls in this thread had the same geometry
    (:func:`geometry_key`: triangles, objects, materials, bit for bit) on the same
    runtime. What :func:`clradcom.trace.trace_scene` uses, so that tracing one scene
    again (more rays, other links, other settings) pays only the ray work. A scene whose
    triangles changed gets a new key and a new build; the kept caster holds its own
    read-only copy of the triangles, so changing a scene's arrays in place never
    changes a kept geometry. :func:`forget_geometries` lets them go."""
    if engine not in ENGINES:
        raise ArgumentError(f"must be one of {', '.join(ENGINES)}", argument="engine",
                            value=engine)
    runtime = runtime or get_runtime()
    if not len(scene.triangles):
        return build_geometry(scene, runtime, engine=engine)
    key = geometry_key(scene)
    kept = getattr(_KEPT, "entries", None)
    if kept is None:
        kept = _KEPT.entries = []
    for i, (k, rt, faces, caster, memo) in enumerate(kept):
        if k == key and rt is runtime:
            kept.append(kept.pop(i))
            return Geometry(scene=scene, faces=faces, caster=caster, runtime=runtime,
                            engine=engine, memo=memo)
    triangles = np.array(scene.triangles, dtype=np.float64)
    triangles.flags.writeable = False
    faces = merge_coplanar(triangles, scene.tri_object, scene.tri_material)
    for array in vars(faces).values():
        array.flags.writeable = False  # shared by every trace of this geometry
    caster = RayCaster(triangles, runtime=runtime)
    memo: dict = {}
    kept.append((key, runtime, faces, caster, memo))
    del kept[:-KEPT_GEOMETRIES]
    return Geometry(scene=scene, faces=faces, caster=caster, runtime=runtime, engine=engine,
                    memo=memo)


def forget_geometries() -> None:
    """Drop the geometries :func:`kept_geometry` keeps in this thread (their device
    buffers are freed with them)."""
    _KEPT.entries = []


def moving_objects(scene: Scene) -> list[int]:
    """Indices of the objects that move: a velocity, an angular velocity or a trajectory
    (:mod:`clradcom.scene.motion`). Radars riding on objects move with them but hold no
    triangles."""
    return [i for i, o in enumerate(scene.objects)
            if o.motion is not None or np.any(np.asarray(o.velocity) != 0)]


def _face_planes(triangles, tri_face, normal, offset, faces) -> None:
    """Area-weighted planes of ``faces`` (ids) from their ``triangles`` (world, float64)
    and the triangles' ``tri_face``, written into ``normal`` and ``offset``: the sums of
    :func:`~clradcom.geometry.faces.merge_coplanar` over the same triangles in the same
    order, so a face keeps the plane a full rebuild gives it."""
    if not len(faces):
        return
    n, _, area2 = triangle_planes(triangles)
    normal[faces], offset[faces] = area_weighted_planes(
        triangles, n, area2, np.searchsorted(faces, tri_face), len(faces))


class GeometryCache:
    """The geometry of one moving scene at many instants, without a rebuild per step
    (docs/bvh.md, "Two levels").

    Built once from ``scene`` (at its ``time_s``): the triangles of the objects that do
    not move (:func:`moving_objects`) form one bottom-level BVH, every moving object its
    own, in a frame centred on its box (an :class:`~clradcom.device.raycast.
    InstancedCaster`); the planar faces are grouped once. :meth:`at` moves the scene to
    ``t`` (:func:`~clradcom.scene.motion.scene_at`), places the moving objects by their
    rigid transforms (a new top-level tree over a few boxes) and recomputes only the
    moving objects' face planes, normals and boxes. A scene where nothing moves gets a
    plain :class:`~clradcom.device.raycast.RayCaster`, built once and reused as is.

    ``placement`` says how a moving object's tree follows it. "refit" (the default)
    rewrites the object's Tri4 groups from its world triangles and refits its boxes
    bottom up (O(triangles of the moving objects) per step): the kernels test exactly the
    float32 triangles of a full rebuild, so the paths are a rebuild's bit for bit and do
    not depend on the instant the cache was built at. "transform" places the tree by the
    object's rigid transform, the ray taken into its frame in float32 (Embree's and
    OptiX's instancing, O(1) per object and step); hits then differ from a rebuild's by
    float32 rounding where rays graze triangle edges (docs/bvh.md, "Two levels").

    Still O(T) per step: ``scene_at`` copies the scene's triangles (and moves the moving
    ones), :class:`Faces` arrays are copied, and ``trace_scene`` finds the diffracting
    wedges again.
    """

    PLACEMENTS = ("refit", "transform")

    def __init__(self, scene: Scene, runtime: Runtime | None = None,
                 engine: str = "device", placement: str = "refit"):
        if not isinstance(scene, Scene):
            raise ArgumentTypeError("must be a Scene (clradcom.scene.load_scene)",
                                    argument="scene", value=scene)
        if engine not in ENGINES:
            raise ArgumentError(f"must be one of {', '.join(ENGINES)}", argument="engine",
                                value=engine)
        if placement not in self.PLACEMENTS:
            raise ArgumentError(f"must be one of {', '.join(self.PLACEMENTS)}",
                                argument="placement", value=placement)
        self.scene = scene
        self.placement = placement
        self.runtime = runtime or get_runtime()
        self.engine = engine
        self.faces = merge_coplanar(scene.triangles, scene.tri_object, scene.tri_material)
        tri_object = np.asarray(scene.tri_object)
        self.moving = [i for i in moving_objects(scene) if np.any(tri_object == i)]
        self._parts: list[tuple[int, np.ndarray]] = []  # (object, its triangles' ids)
        self._centre: list[np.ndarray] = []
        self.caster: RayCaster | None = None
        #: seconds the last :meth:`at` spent in ``scene_at``, placing the parts and
        #: redoing the moved faces (for tools/bench_steps.py)
        self.last_times: dict[str, float] = {}
        if not len(scene.triangles):
            return
        if not self.moving:
            self.caster = RayCaster(scene.triangles, runtime=self.runtime)
            return
        static = np.flatnonzero(~np.isin(tri_object, self.moving))
        parts = []
        if static.size:
            parts.append((scene.triangles[static], static))
            self._parts.append((-1, static))
            self._centre.append(np.zeros(3))
        for i in self.moving:
            ids = np.flatnonzero(tri_object == i)
            tri = scene.triangles[ids]
            centre = 0.5 * (tri.min(axis=(0, 1)) + tri.max(axis=(0, 1)))
            parts.append((tri - centre, ids))
            self._parts.append((i, ids))
            self._centre.append(centre)
        self.caster = InstancedCaster(
            parts, runtime=self.runtime,
            refit=[placement == "refit" and i >= 0 for i, _ in self._parts])
        moving_tri = np.isin(tri_object, self.moving)
        self._moving_faces = np.unique(self.faces.tri_face[moving_tri])
        self._moving_tri = np.flatnonzero(moving_tri)

    def at(self, t: float) -> Geometry:
        """The :class:`Geometry` of the scene at ``t`` (s): its ``scene`` is
        ``scene_at(self.scene, t)``. The caster is shared by all steps (placed anew
        at every call), so a step's geometry is valid until the next call."""
        t0 = time.perf_counter()
        scene = scene_at(self.scene, t)
        faces = self.faces
        t1 = t2 = time.perf_counter()
        if isinstance(self.caster, InstancedCaster):
            n = len(self._parts)
            rot = np.empty((n, 3, 3))
            org = np.empty((n, 3))
            identity = np.zeros(n, bool)
            for k, ((i, _), c) in enumerate(zip(self._parts, self._centre, strict=True)):
                if i < 0:
                    rot[k], org[k], identity[k] = np.eye(3), 0.0, True
                    continue
                o0, o1 = self.scene.objects[i], scene.objects[i]
                # scene_at moves a body by x -> pos_t + turn (x - pos_0), turn = R_t R_0^T
                rot[k] = o1.rotation @ o0.rotation.T
                org[k] = o1.position + rot[k] @ (c - o0.position)
            self.caster.place(scene.triangles, rot, org, identity)
            t2 = time.perf_counter()
            normal, offset = faces.normal.copy(), faces.offset.copy()
            _face_planes(scene.triangles[self._moving_tri], faces.tri_face[self._moving_tri],
                         normal, offset, self._moving_faces)
            faces = Faces(tri_face=faces.tri_face, normal=normal, offset=offset,
                          object_id=faces.object_id, material_id=faces.material_id)
        self.last_times = {"scene_at": t1 - t0, "place": t2 - t1,
                           "faces": time.perf_counter() - t2}
        return Geometry(scene=scene, faces=faces, caster=self.caster, runtime=self.runtime,
                        engine=self.engine)


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
