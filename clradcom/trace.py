"""Trace every tx -> rx link of a scene into a snapshot.

Stages, each a function of plain arrays (see :mod:`clradcom.specular` for
the geometric ones):

``build_geometry``   scene -> planar faces, BVH, ray caster (once per scene)
``candidate_sequences`` one transmitter -> unique face sequences (OpenCL)
``specular_paths``   candidates + one tx/rx pair -> exact, confirmed paths
``path_fields``      paths -> complex gain, 2x2 matrix, delay, Doppler
``trace_scene``      all of it for every link -> :class:`Snapshot`

Geometry is float32 only inside the kernels that propose candidates and
confirm visibility; every point, length, delay and phase of a kept path is
computed in float64 on the host.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from clradcom import __version__
from clradcom.device.raycast import RayCaster
from clradcom.device.runtime import Runtime, get_runtime
from clradcom.device.visibility import confirm_paths, containing_triangles
from clradcom.evaluation import budget
from clradcom.geometry.faces import Faces, merge_coplanar
from clradcom.geometry.wedges import extract_wedges
from clradcom.mechanisms import diffraction as diff
from clradcom.mechanisms import specular as sp
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.mechanisms.scattering import scattering_paths
from clradcom.paths import InteractionType, Paths, concat_paths, select_paths
from clradcom.physics import em
from clradcom.scene.records import Radar, Scene
from clradcom.snapshot import Link, Snapshot


@dataclass(frozen=True)
class TraceSettings:
    """What the tracer models and how hard it searches."""

    max_reflections: int = 5
    rays: int = 1_000_000  # launched per transmitter over its pattern's support
    line_of_sight: bool = True
    max_diffractions: int = 1  # UTD edge diffractions per path, 0 (off) to 3
    wedge_angle_deg: float = 20.0  # faces turning less than this meet in no wedge
    # most reflections in a path that also diffracts (never more than max_reflections),
    # taken from the rays' own face sequences on one side of the edges
    diffraction_reflections: int = 0
    # most distance between consecutive edges of a multi-diffraction chain (m)
    diffraction_hop_m: float = 20.0
    # default optics of PEC objects without their own ``optics`` key (docs/po.md):
    # "none": GO image paths; "pec": PO facet integrals for the first bounce (a facet's
    # true RCS, not an infinite mirror's), GO for later ones; "sbr": PO facets plus
    # shooting-and-bouncing ray tubes with PO for bounces 2..max_reflections
    physical_optics: str = "none"
    # pitch of the SBR ray-tube grid at each target, in wavelengths
    sbr_spacing_wavelengths: float = 0.5
    # single Lambertian scattering from tiles of materials with S > 0 (trees); their
    # specular reflections then carry sqrt(1 - S^2) of the field (effective roughness)
    scattering: bool = False
    # specular reflections around a tile (docs/scattering.md): 0 tx-tile-rx only; 1 also
    # one reflection before or after it; 2 also one on each side
    scattering_max_reflections: int = 0
    # tiles more than this far (dB) below the link's strongest tile are dropped
    scattering_threshold_db: float = -60.0
    # tile edge (m); 0 picks it from the wavelength and distance (choose_tile_size)
    scattering_tile_size_m: float = 0.0
    # faces smaller than this (m^2) reflect into no scattering path
    scattering_min_face_area_m2: float = 1.0
    # |a|^2 below which a scattering triangle's tiles are never traced, from an upper
    # bound of all its tiles together (clradcom.budget.scattering_triangle_bounds; e.g.
    # the radar's processed noise floor, budget.noise_floor); 0 traces every triangle
    scattering_floor: float = 0.0

    @property
    def reflections_beside_edges(self) -> int:
        """Reflections a diffracted path may have: never more than max_reflections."""
        return min(self.diffraction_reflections, self.max_reflections)

    def __post_init__(self):
        if self.physical_optics not in ("none", "pec", "sbr"):
            raise ValueError(f"physical_optics must be 'none', 'pec' or 'sbr', got "
                             f"{self.physical_optics!r}")
        if not (isinstance(self.sbr_spacing_wavelengths, (int, float))
                and 0.01 <= float(self.sbr_spacing_wavelengths) <= 100.0):
            raise ValueError(f"sbr_spacing_wavelengths must be a number in [0.01, 100], got "
                             f"{self.sbr_spacing_wavelengths!r}")
        if self.max_diffractions not in (0, 1, 2, 3):
            raise ValueError(f"max_diffractions must be 0, 1, 2 or 3, got "
                             f"{self.max_diffractions!r}")
        if not (isinstance(self.diffraction_reflections, int)
                and 0 <= self.diffraction_reflections <= 16):
            raise ValueError(f"diffraction_reflections must be an integer 0..16, got "
                             f"{self.diffraction_reflections!r}")
        if not float(self.diffraction_hop_m) > 0.0:
            raise ValueError(f"diffraction_hop_m must be > 0, got {self.diffraction_hop_m!r}")
        if not (0.0 < float(self.wedge_angle_deg) < 180.0):
            raise ValueError(f"wedge_angle_deg must lie in (0, 180), got "
                             f"{self.wedge_angle_deg!r}")
        if not (isinstance(self.max_reflections, int) and 0 <= self.max_reflections <= 16):
            raise ValueError(f"max_reflections must be an integer 0..16, got "
                             f"{self.max_reflections!r}")
        if not (isinstance(self.rays, int) and self.rays >= 1):
            raise ValueError(f"rays must be a positive integer, got {self.rays!r}")
        smr = self.scattering_max_reflections
        if isinstance(smr, bool) or not isinstance(smr, int) or smr not in (0, 1, 2):
            raise ValueError(f"scattering_max_reflections must be 0, 1 or 2, got "
                             f"{self.scattering_max_reflections!r}")
        for name in ("scattering_threshold_db", "scattering_tile_size_m",
                     "scattering_min_face_area_m2", "scattering_floor"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    np.isfinite(value) and (value <= 0 if name.endswith("_db") else value >= 0)):
                raise ValueError(f"{name} must be a finite number "
                                 f"{'<= 0' if name.endswith('_db') else '>= 0'}, got {value!r}")


@dataclass
class Geometry:
    """What the kernels need about a scene, built once."""

    scene: Scene
    faces: Faces
    caster: RayCaster | None  # None for a scene without triangles (free space)
    runtime: Runtime


@dataclass
class PathGeometry:
    """Exact paths of one link before fields: padded to k_max interactions."""

    points: np.ndarray  # (P, k_max+2, 3)
    n_interactions: np.ndarray  # (P,)
    faces: np.ndarray  # (P, k_max) planar face ids, -1 padding
    triangles: np.ndarray  # (P, k_max) scene triangle ids, -1 padding

    @property
    def n_paths(self) -> int:
        return len(self.n_interactions)


@dataclass
class StageTimes:
    """Wall-clock seconds per stage, for reports and benchmarks."""

    seconds: dict[str, float] = field(default_factory=dict)

    def add(self, stage: str, dt: float) -> None:
        self.seconds[stage] = self.seconds.get(stage, 0.0) + dt


def build_geometry(scene: Scene, runtime: Runtime | None = None) -> Geometry:
    runtime = runtime or get_runtime()
    faces = merge_coplanar(scene.triangles, scene.tri_object, scene.tri_material)
    # a BVH needs triangles; a free-space scene has only line-of-sight paths
    caster = RayCaster(scene.triangles, runtime=runtime) if len(scene.triangles) else None
    return Geometry(scene=scene, faces=faces, caster=caster, runtime=runtime)


def candidate_sequences(geom: Geometry, tx: Radar, settings: TraceSettings):
    """Unique face sequences (dict order -> (C, order) int32) proposed by tx's rays."""
    if settings.max_reflections == 0 or geom.caster is None:
        return {}
    dirs = sp.launch_directions(settings.rays, tx.pattern.gain, tx.orientation)
    seqs = sp.reflection_sequences(geom.caster, geom.faces.tri_face, tx.position, dirs,
                                   settings.max_reflections)
    return sp.unique_candidates(seqs)


def specular_paths(geom: Geometry, tx_pos, rx_pos, candidates, line_of_sight=True
                   ) -> PathGeometry:
    """Exact, confirmed specular paths (and line of sight) between two points."""
    tx_pos = np.asarray(tx_pos, dtype=np.float64)
    rx_pos = np.asarray(rx_pos, dtype=np.float64)
    k_max = max(candidates.keys(), default=0)
    blocks = []
    if line_of_sight and np.linalg.norm(rx_pos - tx_pos) > 0:
        pts = np.stack([tx_pos, rx_pos])[None]
        if geom.caster is None:  # free space: nothing can block it
            keep = np.ones(1, dtype=bool)
        else:
            keep, _ = confirm_paths(geom.caster, geom.faces.tri_face, geom.faces.normal,
                                    pts, np.zeros((1, 0), dtype=np.int32))
        if keep[0]:
            blocks.append((pts, np.zeros((1, 0), np.int32), np.zeros((1, 0), np.int32)))
    for k in sorted(candidates):
        seqs = candidates[k]
        if len(seqs) == 0:
            continue
        pts, ok = sp.image_points(tx_pos, rx_pos, geom.faces.normal, geom.faces.offset, seqs)
        keep, tris = confirm_paths(geom.caster, geom.faces.tri_face, geom.faces.normal,
                                   pts, seqs, ok)
        if keep.any():
            blocks.append((pts[keep], seqs[keep], tris[keep]))
    P = sum(len(b[0]) for b in blocks)
    points = np.full((P, k_max + 2, 3), np.nan)
    n_int = np.zeros(P, dtype=np.int16)
    faces = np.full((P, k_max), -1, dtype=np.int32)
    triangles = np.full((P, k_max), -1, dtype=np.int32)
    row = 0
    for pts, seqs, tris in blocks:
        n, k = len(pts), seqs.shape[1]
        points[row:row + n, :k + 2] = pts
        n_int[row:row + n] = k
        faces[row:row + n, :k] = seqs
        triangles[row:row + n, :k] = tris
        row += n
    return PathGeometry(points=points, n_interactions=n_int, faces=faces, triangles=triangles)


def surface_contact_paths(geom: Geometry, tx: Radar, rx: Radar) -> Paths:
    """The reflection of an antenna lying on a face, as the limit of two merging rays.

    With tx (or rx) on a face and the other end off its plane, the reflected ray and
    the line of sight coincide: the image method cannot place the reflection (its point
    is the antenna itself, a zero-length segment). Its field is the limit h -> 0 of the
    two-ray geometry: the wave leaves tx along the mirror image of the line of sight
    (into the face), reflects at tx with the face's Fresnel x roughness x sqrt(1 - S^2)
    dyad and travels the line of sight; so the total tends to (1 + r) x LOS for an
    isotropic antenna, continuous through h = 0. Call only when the line of sight
    exists (it is this path's second segment).
    """
    scene, faces = geom.scene, geom.faces
    tx_pos = np.asarray(tx.position, dtype=np.float64)
    rx_pos = np.asarray(rx.position, dtype=np.float64)
    los = rx_pos - tx_pos
    length = float(np.linalg.norm(los))
    if geom.caster is None or length == 0 or faces.n_faces == 0:
        return Paths.empty(1)
    k_los = los / length
    rows = []
    for end, other, at_tx in ((tx_pos, rx_pos, True), (rx_pos, tx_pos, False)):
        tol = sp.CONTACT_TOL_REL * (1.0 + np.abs(end).max())
        dist = faces.normal @ end - faces.offset
        off = faces.normal @ other - faces.offset
        on = np.flatnonzero((np.abs(dist) <= tol) & (np.abs(off) > tol))
        if len(on) == 0:
            continue
        tri = containing_triangles(np.broadcast_to(end, (len(on), 3)), on,
                                   np.full(len(on), -1), scene.triangles, faces.tri_face)
        for f, t in zip(on[tri >= 0], tri[tri >= 0], strict=True):
            rows.append((int(f), int(t), at_tx))
    if not rows:
        return Paths.empty(1)
    f = np.array([r[0] for r in rows])
    t = np.array([r[1] for r in rows], dtype=np.int32)
    at_tx = np.array([r[2] for r in rows])
    n = faces.normal[f]
    mirrored = k_los - 2.0 * (n @ k_los)[:, None] * n
    k_dep = np.where(at_tx[:, None], mirrored, k_los)
    k_arr = np.where(at_tx[:, None], k_los, mirrored)
    T = em.material_reflection_dyad(scene, faces.material_id[f], k_dep, n) @ (
        np.eye(3)[None] - k_dep[:, :, None] * k_dep[:, None, :])
    P = len(rows)
    gain, M = em.path_gains(T, np.full(P, length), k_dep, k_arr, tx, rx, scene.carrier_hz)
    contact = np.where(at_tx[:, None], tx_pos, rx_pos)
    points = np.stack([np.broadcast_to(tx_pos, (P, 3)), contact,
                       np.broadcast_to(rx_pos, (P, 3))], axis=1)
    # the merged rays share the line of sight's Doppler
    los_pts = np.stack([tx_pos, rx_pos])[None]
    los_vel = np.stack([tx.velocity, rx.velocity])[None]
    doppler = np.full(P, em.doppler_hz(los_pts, los_vel, scene.wavelength_m)[0])
    seen = seen_by_antennas(tx, rx, k_dep, k_arr)
    return select_paths(Paths(
        gain=gain, matrix=M, delay_s=np.full(P, em.delay_s(np.array([length]))[0]),
        doppler_hz=doppler, n_interactions=np.ones(P, np.int16),
        interaction=np.full((P, 1), int(InteractionType.REFLECTION), np.int8),
        points=points, object_id=faces.object_id[f][:, None].astype(np.int32),
        face_id=t[:, None]), seen)


def seen_by_antennas(tx: Radar, rx: Radar, k_dep, k_arr) -> np.ndarray:
    """Paths that leave inside tx's pattern and arrive inside rx's (non-zero gain)."""
    return (np.asarray(tx.pattern.gain(k_dep @ np.asarray(tx.orientation))) > 0) & (
        np.asarray(rx.pattern.gain(-k_arr @ np.asarray(rx.orientation))) > 0)


def with_physical_optics(geom: Geometry, paths: Paths, tx: Radar, rx: Radar,
                         settings: TraceSettings | None = None,
                         sbr_cache: dict | None = None) -> Paths:
    """Swap GO returns for physical optics on the objects that ask for it.

    A GO image path off a flat facet is the return of an infinite mirror; the PO
    integral over the lit facets gives the facet's own strength and its off-specular
    lobes, and SBR-PO does the same for corners (docs/po.md). Per object
    (:func:`clradcom.sbr.object_optics`: its ``optics`` key, else the default that
    ``settings.physical_optics`` gives PEC objects):

    * "both": its single GO reflections make way for PO facet returns; multi-bounce
      paths stay GO;
    * "po": every GO reflection path that ends on it makes way for PO facet returns
      (first bounce) and SBR-PO tube returns (bounces 2..max_reflections);
    * "go": untouched.

    Without ``settings`` this is ``physical_optics="pec"`` (PO facets on PEC objects).
    """
    from clradcom.mechanisms.sbr import object_optics, sbr_paths, shoot_sbr

    settings = settings or TraceSettings(physical_optics="pec")
    modes = np.array(object_optics(geom.scene, settings.physical_optics))
    po_objects = np.flatnonzero(modes != "go")
    if geom.caster is None or len(po_objects) == 0:
        return paths
    sbr_objects = np.flatnonzero(modes == "po")
    drop = np.zeros(paths.n_paths, dtype=bool)
    if paths.k_max and paths.n_paths:
        nk = paths.n_interactions.astype(np.int64)
        last = np.maximum(nk - 1, 0)
        rows = np.arange(paths.n_paths)
        refl = int(InteractionType.REFLECTION)
        all_refl = np.all((paths.interaction == refl)
                          | (np.arange(paths.k_max)[None, :] >= nk[:, None]), axis=1)
        ends_on = np.where(nk > 0, paths.object_id[rows, last], -1)
        drop = (nk == 1) & np.isin(ends_on, po_objects)
        drop |= (nk > 1) & np.isin(ends_on, sbr_objects)
        drop &= all_refl
    parts = [select_paths(paths, ~drop), po_paths(geom, tx, rx, objects=po_objects)]
    if len(sbr_objects) and settings.max_reflections >= 2:
        # the tubes depend on tx only: shot once, radiated to every receiver
        key = (tx.name, tuple(int(o) for o in sbr_objects))
        cache = sbr_cache if sbr_cache is not None else {}
        if key not in cache:
            cache[key] = shoot_sbr(geom, tx, sbr_objects,
                                   spacing_wavelengths=settings.sbr_spacing_wavelengths,
                                   max_bounces=settings.max_reflections)
        parts.append(sbr_paths(geom, tx, rx, objects=sbr_objects,
                               spacing_wavelengths=settings.sbr_spacing_wavelengths,
                               max_bounces=settings.max_reflections, shot=cache[key]))
    return concat_paths(parts)


def diffraction_paths(geom: Geometry, wedges, tx: Radar, rx: Radar, settings: TraceSettings,
                      tx_sequences=None, rx_sequences=None, stats=None) -> Paths:
    """UTD diffraction paths of one link, up to settings.max_diffractions edges mixed
    with reflections from the rays' face sequences (see clradcom.diffraction)."""
    budget = diff.DiffractionBudget(max_diffractions=settings.max_diffractions,
                                    max_reflections=settings.reflections_beside_edges,
                                    max_hop_m=settings.diffraction_hop_m)
    parts, counts = diff.diffraction_link_paths(
        geom.scene, geom.faces, geom.caster, wedges, tx, rx, tx_sequences or {},
        rx_sequences or {}, budget, keep_fn=lambda d, a: seen_by_antennas(tx, rx, d, a))
    if stats is not None:
        for key, value in counts.items():
            stats[key] = stats.get(key, 0) + value
    return concat_paths(parts) if parts else Paths.empty(1)


def path_fields(geom: Geometry, pg: PathGeometry, tx: Radar, rx: Radar) -> Paths:
    """Gains, polarimetric matrices, delays and Doppler of exact paths -> :class:`Paths`."""
    scene = geom.scene
    P, k_max = pg.faces.shape
    if P == 0:
        return Paths.empty(k_max)
    nk = pg.n_interactions.astype(np.int64)
    face = np.maximum(pg.faces, 0)
    active = pg.faces >= 0
    mat = geom.faces.material_id[face]
    obj = np.where(active, geom.faces.object_id[face], -1)
    pts = pg.points  # NaN padding past each path's rx point is ignored by em (masked by nk)
    T, L = em.path_transfer(
        pts, geom.faces.normal[face],
        scene.material_eps_r[mat], scene.material_pec[mat],
        scene.material_roughness_m[mat], scene.material_roughness_model[mat],
        scene.carrier_hz, num_interactions=nk)
    k_dep, k_arr = em.path_directions(pts, nk)
    gain, M = em.path_gains(T, L, k_dep, k_arr, tx, rx, scene.carrier_hz)
    # effective roughness: a share S^2 of the reflected power goes into diffuse scattering
    s_coef = np.where(active, scene.material_scattering[mat], 0.0)
    specular_share = np.prod(np.sqrt(1.0 - s_coef**2), axis=1)
    gain = gain * specular_share
    M = M * specular_share[:, None, None]
    vel = np.zeros_like(pts)
    vel[:, 0] = tx.velocity
    vel[:, 1:k_max + 1] = np.where(active[..., None], scene.object_velocity[np.maximum(obj, 0)],
                                   0.0)
    vel[np.arange(P), nk + 1] = rx.velocity
    doppler = em.doppler_hz(pts, vel, scene.wavelength_m, num_interactions=nk)
    interaction = np.where(active, int(InteractionType.REFLECTION), 0).astype(np.int8)
    # a path leaving or arriving outside an antenna's pattern carries nothing: model no more
    # than the link can see
    seen = seen_by_antennas(tx, rx, k_dep, k_arr)
    return Paths(gain=gain[seen], matrix=M[seen], delay_s=em.delay_s(L)[seen],
                 doppler_hz=doppler[seen], n_interactions=pg.n_interactions[seen],
                 interaction=interaction[seen], points=pg.points[seen],
                 object_id=obj.astype(np.int32)[seen], face_id=pg.triangles[seen])


def trace_scene(scene: Scene, settings: TraceSettings | None = None,
                runtime: Runtime | None = None, links=None,
                progress: Callable[[str], None] | None = None,
                times: StageTimes | None = None) -> Snapshot:
    """Trace the links of a scene (default: every transmitter to every receiver)."""
    settings = settings or TraceSettings()
    times = times if times is not None else StageTimes()
    say = progress or (lambda msg: None)
    t0 = time.perf_counter()
    geom = build_geometry(scene, runtime)
    times.add("geometry", time.perf_counter() - t0)
    txs = [i for i, r in enumerate(scene.radars) if r.role in ("txrx", "tx")]
    rxs = [i for i, r in enumerate(scene.radars) if r.role in ("txrx", "rx")]
    if links is None:
        links = [(t, r) for t in txs for r in rxs]
    out = []
    cache = {}
    n_dropped_tiles = 0
    n_below_floor = 0
    sbr_cache: dict = {}  # one SBR tube shot per transmitter, for all its receivers
    diffraction_stats: dict[str, int] = {}
    wedges = None
    if settings.max_diffractions and len(scene.triangles):
        t0 = time.perf_counter()
        wedges = extract_wedges(scene.triangles, scene.tri_object, scene.tri_material,
                                settings.wedge_angle_deg)
        times.add("wedges", time.perf_counter() - t0)
    for t_idx, r_idx in links:
        tx, rx = scene.radars[t_idx], scene.radars[r_idx]
        if t_idx not in cache:
            say(f"candidates from {tx.name}")
            t0 = time.perf_counter()
            cache[t_idx] = candidate_sequences(geom, tx, settings)
            times.add("candidates", time.perf_counter() - t0)
        say(f"paths {tx.name} -> {rx.name}")
        t0 = time.perf_counter()
        pg = specular_paths(geom, tx.position, rx.position, cache[t_idx],
                            settings.line_of_sight)
        times.add("exact paths", time.perf_counter() - t0)
        t0 = time.perf_counter()
        paths = path_fields(geom, pg, tx, rx)
        if settings.line_of_sight and np.any(pg.n_interactions == 0):
            paths = concat_paths([paths, surface_contact_paths(geom, tx, rx)])
        times.add("fields", time.perf_counter() - t0)
        if settings.physical_optics != "none" or any(o.optics for o in scene.objects):
            t0 = time.perf_counter()
            paths = with_physical_optics(geom, paths, tx, rx, settings, sbr_cache)
            times.add("physical optics", time.perf_counter() - t0)
        if settings.scattering and geom.caster is not None:
            t0 = time.perf_counter()
            mask = None
            if settings.scattering_floor > 0:
                mask = np.ones(len(scene.triangles), dtype=bool)
                ids, _, above = budget.scattering_triangle_bounds(scene, tx, rx,
                                                                  settings.scattering_floor)
                mask[ids[~above]] = False
                n_below_floor += int(np.count_nonzero(~above))
            diffuse, dropped = scattering_paths(
                geom, tx, rx, tile_size_m=settings.scattering_tile_size_m or None,
                threshold_db=settings.scattering_threshold_db,
                max_reflections=settings.scattering_max_reflections,
                min_face_area_m2=settings.scattering_min_face_area_m2, triangle_mask=mask)
            paths = concat_paths([paths, diffuse])
            n_dropped_tiles += dropped
            times.add("scattering", time.perf_counter() - t0)
        if wedges is not None:
            t0 = time.perf_counter()
            rx_seqs = {}
            if settings.reflections_beside_edges:
                if r_idx not in cache:
                    cache[r_idx] = candidate_sequences(geom, rx, settings)
                rx_seqs = cache[r_idx]
            paths = concat_paths([paths, diffraction_paths(
                geom, wedges, tx, rx, settings, cache[t_idx], rx_seqs, diffraction_stats)])
            times.add("diffraction", time.perf_counter() - t0)
        out.append(Link(tx_name=tx.name, rx_name=rx.name, tx_index=t_idx, rx_index=r_idx,
                        paths=paths))
    meta = {f"settings.{k}": v for k, v in asdict(settings).items()}
    meta["clradcom_version"] = __version__
    if settings.scattering:
        meta["scattering.tiles_dropped"] = int(n_dropped_tiles)
        meta["scattering.triangles_below_floor"] = n_below_floor
    for key, value in diffraction_stats.items():
        meta[f"diffraction.{key}"] = int(value)
    meta["device"] = geom.runtime.info.device_name.strip()
    return Snapshot(scene_name=scene.name, carrier_hz=float(scene.carrier_hz),
                    scene_hash=scene.content_hash(), links=tuple(out), metadata=meta)
