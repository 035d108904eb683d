"""The scene in memory: objects, radars and the flattened arrays the tracer consumes.

:func:`clradcom.scene.reader.load_scene` builds these records from a TOML file; any
code may also build them directly.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.scene.antenna import Pattern
from clradcom.scene.materials import C0, ROUGHNESS_MODELS, Material

__all__ = ["ARRAY_KINDS", "MODULATIONS", "OPTICS", "ROLES", "SBR_SPACING_WAVELENGTHS", "SIDES",
           "ArrayLayout", "FMCW_IF_TYPES", "FmcwSpec", "Motion", "Radar", "Scene",
           "SceneDocument", "SceneObject", "TimeAxis", "WaveformSpec", "with_object_optics"]

#: the radar's modulations (``[waveform] modulation``, ``Waveform.modulation``)
MODULATIONS = ("bpsk", "qpsk", "8psk", "16psk", "16qam", "64qam", "256qam")

#: ``objects[].optics``: how the tracer models the object's returns (docs/po.md)
OPTICS = ("go", "po", "both")
#: ``objects[].sbr_spacing_wavelengths``: the range (inclusive, in wavelengths) of an
#: object's own SBR ray-tube pitch, that of ``OpticsSettings.sbr_spacing_wavelengths``
SBR_SPACING_WAVELENGTHS = (0.01, 100.0)
#: ``objects[].sides``: which sides of its triangles reflect (docs/scene-format.md, "Sides"):
#: "auto" re-orients closed shells wound inside out and makes the object two-sided when
#: any part of it is open; "as_wound" trusts the winding; "two_sided" lights both sides
SIDES = ("auto", "as_wound", "two_sided")
#: What a radar does: transmit and receive, only transmit, only receive.
ROLES = ("txrx", "tx", "rx")
#: ``radars[].array.kind``: uniform linear, uniform planar, explicit element positions
ARRAY_KINDS = ("ula", "upa", "positions")


@dataclass(eq=False)
class ArrayLayout:
    """A radar's antenna array: element positions in the radar's own frame (m; boresight
    local +x, local z up), offsets from the radar's position, and each element's pattern
    with its polarisation, or None where every element shares the radar's
    (docs/scene-format.md, "Arrays")."""

    kind: str  #: one of :data:`ARRAY_KINDS`
    positions_local: np.ndarray  #: (E, 3) float64, m
    #: (E,) antenna patterns (each with its Jones vector), or None: the radar's own
    patterns: tuple | None = None

    @property
    def n_elements(self) -> int:
        return int(self.positions_local.shape[0])


@dataclass(eq=False)
class Motion:
    """Rigid motion beyond a constant velocity (docs/scene-format.md, "Motion"): a turn
    at ``angular_velocity_deg_s`` about an axis through ``rotation_centre``, and/or a
    piecewise-linear ``trajectory`` of the position. ``None`` fields are absent."""

    #: (3,) deg/s, a world vector along the axis (right hand), or None
    angular_velocity_deg_s: np.ndarray | None = None
    #: (3,) world point on the axis at the scene's time (m); it moves with the position
    rotation_centre: np.ndarray | None = None
    #: (N, 4) float64 rows [t (s), x, y, z (m)], times strictly increasing, or None
    trajectory: np.ndarray | None = None

    @property
    def angular_velocity(self) -> np.ndarray:
        """(3,) rad/s (zeros when the object does not turn)."""
        if self.angular_velocity_deg_s is None:
            return np.zeros(3)
        return np.radians(self.angular_velocity_deg_s)

    def hash_params(self) -> list:
        def vec(a):
            return [repr(float(x)) for x in np.asarray(a, dtype=np.float64).reshape(-1)]
        return [[key, vec(getattr(self, key))]
                for key in ("angular_velocity_deg_s", "rotation_centre", "trajectory")
                if getattr(self, key) is not None]


@dataclass(frozen=True)
class TimeAxis:
    """The ``[time]`` table: ``count`` instants ``start_s + i * step_s``."""

    start_s: float
    step_s: float
    count: int

    @property
    def times(self) -> np.ndarray:
        return self.start_s + self.step_s * np.arange(self.count, dtype=np.float64)


@dataclass(eq=False)
class SceneObject:
    """One object: a mesh placed in the world with a material and a velocity."""

    name: str
    mesh: str  #: mesh file path (as resolved) or ``"shape:<name>"``
    material: int  #: index into Scene.materials
    material_name: str
    position: np.ndarray  #: (3,) float64, m
    rotation_deg: np.ndarray  #: (3,) float64, [roll, pitch, yaw]
    rotation: np.ndarray  #: (3,3) float64, world = rotation @ (scale * local) + position
    scale: np.ndarray  #: (3,) float64
    velocity: np.ndarray  #: (3,) float64, m/s
    tri_start: int  #: first triangle of this object in Scene.triangles
    tri_stop: int  #: one past its last triangle
    #: "go" / "po" / "both", or None to follow TraceSettings.physical_optics
    optics: str | None = None
    #: pitch of this object's SBR ray tubes in wavelengths, or None to follow
    #: ``OpticsSettings.sbr_spacing_wavelengths``
    sbr_spacing_wavelengths: float | None = None
    #: rotation and/or trajectory (None: constant ``velocity`` only)
    motion: Motion | None = None
    #: the ``sides`` key as given (one of :data:`SIDES`)
    sides: str = "auto"
    #: both sides of its triangles reflect (an open sheet under "auto", or "two_sided"):
    #: PO facets and wedges are lit from either side, not only where the winding faces
    two_sided: bool = False

    @property
    def tri_slice(self) -> slice:
        return slice(self.tri_start, self.tri_stop)

    @property
    def n_triangles(self) -> int:
        return self.tri_stop - self.tri_start

    def __repr__(self) -> str:
        moving = (f", velocity {_short_vec(self.velocity)} m/s"
                  if np.any(self.velocity != 0) else "")
        return (f"SceneObject({self.name!r}: {self.n_triangles} triangles of "
                f"{self.material_name}, at {_short_vec(self.position)} m{moving})")


@dataclass(eq=False)
class Radar:
    """One antenna (transmitter, receiver or both) with its pattern."""

    name: str
    position: np.ndarray  #: (3,) float64, world m
    rides_on: int  #: object index or -1
    orientation: np.ndarray  #: (3,3) float64; columns = local x, y, z axes in world
    pattern: Pattern
    polarization: np.ndarray  #: (2,) complex128 unit Jones vector (C_theta, C_phi), local
    polarization_name: str  #: "V", "H", "RHCP", "LHCP", "jones" or "file"
    velocity: np.ndarray  #: (3,) float64, m/s (the carrier object's when riding)
    role: str = "txrx"  #: "txrx", "tx" or "rx"
    tx_power_w: float = 1.0
    noise_figure_db: float | None = None
    position_local: np.ndarray = field(default_factory=lambda: np.zeros(3))
    orientation_deg: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: transmit / receive arrays (None: a single element at ``position``); the paths of a
    #: snapshot start and end at ``position``, the array's reference point
    tx_array: ArrayLayout | None = None
    rx_array: ArrayLayout | None = None
    #: rotation and/or trajectory of a radar that rides on nothing (None: ``velocity``)
    motion: Motion | None = None
    #: the radar's own ``waveform`` table (OFDM or FMCW), or None: the scene's
    #: ``[waveform]`` then applies (:meth:`Scene.radar_waveform`)
    waveform: WaveformSpec | FmcwSpec | None = None

    def world_to_local(self, directions_world) -> np.ndarray:
        """(K,3) world directions -> antenna-frame directions (R^T d)."""
        return np.asarray(directions_world, dtype=np.float64) @ self.orientation

    def local_to_world(self, directions_local) -> np.ndarray:
        return np.asarray(directions_local, dtype=np.float64) @ self.orientation.T

    @property
    def boresight(self) -> np.ndarray:
        return self.orientation[:, 0].copy()

    def __repr__(self) -> str:
        on = f" on object {self.rides_on}" if self.rides_on >= 0 else ""
        arrays = "".join(f", {key} {a.kind} of {a.n_elements}"
                         for key, a in (("tx_array", self.tx_array),
                                        ("rx_array", self.rx_array)) if a is not None)
        return (f"Radar({self.name!r}: {self.role}, {self.pattern.kind} pattern, at "
                f"{_short_vec(self.position)} m{on}, boresight "
                f"{_short_vec(self.boresight)}{arrays})")


@dataclass(frozen=True)
class WaveformSpec:
    """The scene file's ``[waveform]`` table as written: each field None where the file
    leaves it out (the command's options, then the paper's Table I, fill it in).
    Checked one value at a time by the reader; whether the values fit together (a
    cyclic prefix given twice, T against Δf, a prefix longer than the symbol) is decided
    where the frame is built (:func:`clradcom.commands.options.run_waveform`)."""

    subcarriers: int | None = None
    symbols: int | None = None
    subcarrier_spacing_hz: float | None = None
    useful_duration_s: float | None = None
    cyclic_prefix_s: float | None = None
    cyclic_prefix_samples: int | None = None
    modulation: str | None = None

    def hash_params(self) -> list:
        """The keys given, in a fixed order, for :meth:`Scene.content_hash`."""
        return [[k, repr(v)] for k, v in (
            ("subcarriers", self.subcarriers), ("symbols", self.symbols),
            ("subcarrier_spacing_hz", self.subcarrier_spacing_hz),
            ("useful_duration_s", self.useful_duration_s),
            ("cyclic_prefix_s", self.cyclic_prefix_s),
            ("cyclic_prefix_samples", self.cyclic_prefix_samples),
            ("modulation", self.modulation)) if v is not None]


@dataclass(frozen=True, eq=False)
class SceneDocument:
    """How a scene was written, kept for the Python edits (:mod:`clradcom.scene.edit`):
    the TOML document (plain tables and values; meshes given in Python may be arrays),
    the folder its relative paths start from, the file its messages name, and the mesh
    files read for it (path -> (vertices, faces)), read once for all the edits."""

    data: dict
    base_dir: Path
    file: Path
    mesh_cache: dict


#: the IF sampling of an FMCW radar (``[waveform] if_type``)
FMCW_IF_TYPES = ("complex", "real")


@dataclass(frozen=True)
class FmcwSpec:
    """The scene file's ``[waveform]`` table with ``kind = "fmcw"``, as written: each
    field None where the file leaves it out (:class:`clradcom.radar.fmcw.FmcwWaveform`'s
    defaults fill it in). Checked one value at a time by the reader; whether they fit
    together (the ADC window inside the chirp, the IF band the ADC takes, the sweep
    around the scene's carrier) is decided where the frame is built
    (:func:`clradcom.commands.options.run_waveform`)."""

    start_frequency_hz: float | None = None
    sweep_bandwidth_hz: float | None = None
    chirp_duration_s: float | None = None
    idle_duration_s: float | None = None
    chirps: int | None = None
    adc_sample_rate_hz: float | None = None
    samples_per_chirp: int | None = None
    adc_start_s: float | None = None
    if_type: str | None = None
    if_bandwidth_hz: float | None = None
    if_filter_order: int | None = None
    phase_noise_offsets_hz: tuple | None = None
    phase_noise_dbc_per_hz: tuple | None = None

    kind = "fmcw"

    def given(self) -> dict:
        """{key: value} of the keys the file gave."""
        return {k: v for k, v in self.__dict__.items() if v is not None}

    def hash_params(self) -> list:
        """``kind`` and the keys given, in a fixed order, for :meth:`Scene.content_hash`."""
        return [["kind", "'fmcw'"]] + [[k, repr(v)] for k, v in self.given().items()]


@dataclass(eq=False)
class Scene:
    """A loaded scene.  The flattened arrays are what the BVH builder and the
    tracer consume; the lists keep the per-item details.

    Arrays
    ------
    triangles : (T,3,3) float64, world coordinates [triangle, vertex, xyz], m
    tri_object : (T,) int32, object index per triangle
    tri_material : (T,) int32, material index per triangle
    object_velocity : (O,3) float64, m/s
    """

    name: str
    carrier_hz: float
    source: Path | None
    materials: list[Material]
    objects: list[SceneObject]
    radars: list[Radar]
    triangles: np.ndarray
    tri_object: np.ndarray
    tri_material: np.ndarray
    object_velocity: np.ndarray
    description: str = ""
    #: the instant the poses and velocities hold for (s); :func:`clradcom.scene.motion.
    #: scene_at` moves the scene to another
    time_s: float = 0.0
    #: the file's ``[time]`` table, or None
    time_axis: TimeAxis | None = None
    #: the file's ``[waveform]`` table (an FMCW one with ``kind = "fmcw"``), or None
    waveform: WaveformSpec | FmcwSpec | None = None
    #: every file reading the scene opened: the scene file, its meshes, pattern tables
    #: and imports (XML, GeoJSON); outputs of a run are refused over any of them
    input_files: tuple[Path, ...] = ()

    def __repr__(self) -> str:
        """A few lines: the objects, triangles, radars and materials, each list cut
        short (``scene.objects``, ``scene.radars`` and ``scene.materials`` hold them all)."""
        origin = self.source
        if origin is None and self.document is not None and str(self.document.file) != "<dict>":
            origin = self.document.file
        where = f" ({origin})" if origin is not None else ""
        when = f", t = {self.time_s:g} s" if self.time_s != 0.0 else ""
        lines = [f"Scene {self.name!r} at {self.carrier_hz / 1e9:g} GHz{when}{where}",
                 f"  {len(self.objects)} object(s), {len(self.triangles):,} triangles: "
                 + _names([f"{o.name} ({o.n_triangles})" for o in self.objects]),
                 f"  {len(self.radars)} radar(s): " + _names(
                     [f"{r.name} ({r.role} at {_short_vec(r.position)})" for r in self.radars]),
                 f"  {len(self.materials)} material(s): "
                 + _names([m.name for m in self.materials])]
        if self.waveform is not None:
            given = ", ".join(f"{k} {v}" for k, v in self.waveform.hash_params())
            lines.append(f"  waveform: {given}")
        return "\n".join(lines)

    @property
    def document(self) -> SceneDocument | None:
        """The document this scene was read from (:func:`~clradcom.scene.reader.
        scene_from_dict`, ``load_scene`` or an edit), or None. Not a field: a scene
        derived with ``dataclasses.replace`` (``scene_at``, ``with_object_optics``) is no
        longer what the document says, and has none."""
        return self.__dict__.get("_document")

    def __getstate__(self) -> dict:
        # a pickled scene (a Dask task) travels without the document: the arrays are all
        # a trace needs, and the document's meshes would double the bytes
        state = dict(self.__dict__)
        state.pop("_document", None)
        return state

    # -- convenience -------------------------------------------------------
    @property
    def wavelength_m(self) -> float:
        return C0 / self.carrier_hz

    def _index(self, items, name: str, what: str) -> int:
        for i, it in enumerate(items):
            if it.name == name:
                return i
        raise KeyError(f"no {what} named {name!r}")

    def object_index(self, name: str) -> int:
        return self._index(self.objects, name, "object")

    def radar_index(self, name: str) -> int:
        return self._index(self.radars, name, "radar")

    def material_index(self, name: str) -> int:
        return self._index(self.materials, name, "material")

    def radar_waveform(self, index: int | None) -> tuple[WaveformSpec | FmcwSpec | None, str]:
        """(the waveform table radar ``index`` runs, the key its refusals name): its own
        ``radars[i].waveform`` where it has one, else the scene's ``waveform`` (None when
        neither is given; also for ``index`` None)."""
        if index is not None and self.radars[index].waveform is not None:
            return self.radars[index].waveform, f"radars[{index}].waveform"
        return self.waveform, "waveform"

    @property
    def moving(self) -> bool:
        """True when anything turns or follows a trajectory (the velocities then depend
        on time or on the point)."""
        return any(x.motion is not None for x in (*self.objects, *self.radars))

    def point_velocity(self, object_ids, points) -> np.ndarray:
        """Velocity (m/s) of material points of objects: ``v + omega x (p - c)`` with the
        object's translation velocity v, angular velocity omega and rotation centre c.

        ``object_ids`` (...) int, ``points`` (..., 3) world m -> (..., 3). For objects that
        do not turn this is exactly ``object_velocity[object_ids]`` (the points are not
        read), so scenes without rotation give the same Doppler, bit for bit."""
        ids = np.asarray(object_ids)
        base = self.object_velocity[ids]
        turning = [i for i, o in enumerate(self.objects)
                   if o.motion is not None and o.motion.angular_velocity_deg_s is not None]
        if not turning:
            return base
        omega = np.zeros((len(self.objects), 3))
        centre = np.zeros((len(self.objects), 3))
        for i in turning:
            omega[i] = self.objects[i].motion.angular_velocity
            centre[i] = self.objects[i].motion.rotation_centre
        sel = np.isin(ids, turning)
        out = base.copy()
        p = np.asarray(points, dtype=np.float64)[sel]
        out[sel] = base[sel] + np.cross(omega[ids[sel]], p - centre[ids[sel]])
        return out

    @property
    def tri_two_sided(self) -> np.ndarray:
        """(T,) bool: the triangle's object is two-sided (``SceneObject.two_sided``)."""
        flags = np.array([o.two_sided for o in self.objects], dtype=bool)
        return flags[self.tri_object] if len(flags) else np.zeros(0, dtype=bool)

    # -- material arrays (M,) --------------------------------------------------
    @property
    def material_eps_r(self) -> np.ndarray:
        """(M,) complex128; ``inf`` for PEC rows (branch on material_pec)."""
        return np.array([m.eps_r for m in self.materials], dtype=np.complex128)

    @property
    def material_pec(self) -> np.ndarray:
        return np.array([m.pec for m in self.materials], dtype=bool)

    @property
    def material_roughness_m(self) -> np.ndarray:
        return np.array([m.roughness_m for m in self.materials], dtype=np.float64)

    @property
    def material_roughness_model(self) -> np.ndarray:
        """(M,) int32: 0 = Ament, 1 = Boithias."""
        return np.array([ROUGHNESS_MODELS.index(m.roughness_model) for m in self.materials],
                        dtype=np.int32)

    @property
    def material_scattering(self) -> np.ndarray:
        return np.array([m.scattering_coefficient for m in self.materials], dtype=np.float64)

    @property
    def material_cross_pol_share(self) -> np.ndarray:
        return np.array([m.cross_pol_share for m in self.materials], dtype=np.float64)

    # -- radar arrays (R,) -------------------------------------------------------
    @property
    def radar_position(self) -> np.ndarray:
        return np.array([r.position for r in self.radars], dtype=np.float64).reshape(-1, 3)

    @property
    def radar_velocity(self) -> np.ndarray:
        return np.array([r.velocity for r in self.radars], dtype=np.float64).reshape(-1, 3)

    @property
    def radar_orientation(self) -> np.ndarray:
        return np.array([r.orientation for r in self.radars],
                        dtype=np.float64).reshape(-1, 3, 3)

    def content_hash(self) -> str:
        """sha256 hex digest over the carrier, materials, object/radar parameters
        and the flattened arrays; stable across runs and machines (names count,
        the scene's name, description and file location do not)."""
        def f(x):
            return repr(float(x))

        def vec(a):
            return [f(x) for x in np.asarray(a, dtype=np.float64).reshape(-1)]

        params = {
            "format": "clradcom-scene-hash-1",
            "carrier_hz": f(self.carrier_hz),
            "materials": [m.hash_params() for m in self.materials],
            # optics and the SBR pitch only when set, so scenes without them keep
            # their hashes
            "objects": [[o.name, o.material, vec(o.velocity), o.tri_start, o.tri_stop]
                        + ([o.optics] if o.optics is not None else [])
                        + ([["sbr_spacing_wavelengths", f(o.sbr_spacing_wavelengths)]]
                           if o.sbr_spacing_wavelengths is not None else [])
                        # motion only when set, so scenes without it keep their hashes
                        + ([["motion", o.motion.hash_params()]]
                           if o.motion is not None else [])
                        # the sides key only when not "auto" (what "auto" makes of the
                        # mesh follows from the triangles, which are hashed)
                        + ([["sides", o.sides]] if o.sides != "auto" else [])
                        for o in self.objects],
            "radars": [
                [r.name, vec(r.position), r.rides_on, vec(r.orientation), r.pattern.params(),
                 [[f(c.real), f(c.imag)] for c in r.polarization], vec(r.velocity), r.role,
                 f(r.tx_power_w), None if r.noise_figure_db is None else f(r.noise_figure_db)]
                # arrays only when set, so scenes without them keep their hashes
                + [[key, a.kind, vec(a.positions_local)]
                   + ([[p.params() for p in a.patterns]] if a.patterns is not None else [])
                   for key, a in (("tx_array", r.tx_array), ("rx_array", r.rx_array))
                   if a is not None]
                + ([["motion", r.motion.hash_params()]] if r.motion is not None else [])
                # a radar's own waveform only when set, so scenes without keep their hashes
                + ([["waveform", r.waveform.hash_params()]] if r.waveform is not None
                   else [])
                for r in self.radars
            ],
        }
        # the time only when a scene has one, so scenes without it keep their hashes
        if self.time_s != 0.0 or self.time_axis is not None:
            params["time_s"] = f(self.time_s)
        if self.time_axis is not None:
            ta = self.time_axis
            params["time_axis"] = [f(ta.start_s), f(ta.step_s), int(ta.count)]
        # the waveform only when a scene has one, so scenes without it keep their hashes
        if self.waveform is not None:
            params["waveform"] = self.waveform.hash_params()
        h = hashlib.sha256()
        h.update(json.dumps(params, sort_keys=True, separators=(",", ":")).encode())
        for arr, dt in ((self.triangles, "<f8"), (self.tri_object, "<i4"),
                        (self.tri_material, "<i4"), (self.object_velocity, "<f8")):
            a = np.ascontiguousarray(arr, dtype=dt)
            h.update(repr(a.shape).encode())
            h.update(a.tobytes())
        return h.hexdigest()


def _short_vec(v) -> str:
    """[x, y, z] with 3 significant digits, for the records' reprs."""
    return "[" + ", ".join(f"{float(x):.3g}" for x in np.asarray(v).reshape(-1)) + "]"


def _names(items: list[str], limit: int = 80) -> str:
    """``items`` joined until about ``limit`` characters, then how many more."""
    out: list[str] = []
    used = 0
    for i, item in enumerate(items):
        if out and used + len(item) > limit:
            return ", ".join(out) + f", ... and {len(items) - i} more"
        out.append(item)
        used += len(item) + 2
    return ", ".join(out) if out else "(none)"


def with_object_optics(scene: Scene, overrides, argument: str = "overrides") -> Scene:
    """A copy of ``scene`` whose objects matching each ``(pattern, optics)`` of
    ``overrides`` (a name, or an fnmatch pattern such as ``buildings/*``; later pairs win)
    have that ``optics`` key, as if the scene file had set it. A pattern that matches no
    object, or an optics not in :data:`OPTICS`, is refused naming
    ``argument`` and the pair."""
    objects = list(scene.objects)
    names = [o.name for o in objects]
    for pattern, optics in (overrides.items() if isinstance(overrides, dict) else overrides):
        value = f"{pattern}={optics}"
        if optics not in OPTICS:
            raise ArgumentError(f"the optics must be one of {', '.join(OPTICS)}",
                                argument=argument, value=value)
        hits = [i for i, n in enumerate(names) if fnmatch.fnmatchcase(n, str(pattern))]
        if not hits:
            shown = ", ".join(names[:10]) + (", ..." if len(names) > 10 else "")
            raise ArgumentError(f"no object of scene {scene.name!r} is named so (its "
                                f"objects: {shown})", argument=argument, value=value)
        for i in hits:
            objects[i] = replace(objects[i], optics=optics)
    return replace(scene, objects=objects)
