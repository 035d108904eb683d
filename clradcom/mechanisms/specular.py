"""Specular paths: candidate search on the device, exact geometry on the host.

Stages (each plain arrays in and out):

1. :func:`launch_directions` - a Fibonacci lattice over the transmit
   pattern's support (directions where its gain is non-zero).
2. :func:`reflection_sequences` - the device
   (:meth:`clradcom.device.raycast.RayCaster.specular_sequences`) follows every
   ray through up to ``max_order`` specular bounces and returns the faces it
   reflects off, in order.
3. :func:`unique_candidates` - every prefix of every sequence is a
   candidate for a path to any receiver (the approach of Sionna RT's
   shooting-and-bouncing candidate stage); duplicates go.
4. :func:`image_points` - the image method in float64 gives the exact
   reflection points of a candidate for one tx/rx pair and rejects those
   whose line to an image misses the plane between its ends (wrong side).
5. :func:`clradcom.device.visibility.confirm_paths` - one closest-hit query
   per segment: the segment toward a reflection point must first meet exactly
   that face there (so the point lies inside the face and nothing blocks it),
   and the last segment must reach the receiver unobstructed.

The ray density only decides which candidates are proposed; every kept path
is exact, and the set stops growing once the lattice is dense enough.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass

import numpy as np

from clradcom.device import engines
from clradcom.device import images as device_images
from clradcom.device.raycast import RayCaster
from clradcom.device.visibility import confirm_paths, containing_triangles
from clradcom.errors import ArgumentError, SurfaceContactWarning
from clradcom.geometry.ray_order import coherent_order
from clradcom.mechanisms.common import Geometry, check_number, seen_by_antennas
from clradcom.paths import InteractionType, Paths, concat_paths, select_paths
from clradcom.physics import em
from clradcom.scene.records import Radar

#: An antenna this close to a face's plane, relative to 1 + its largest coordinate
#: (float64 rounding, as visibility.INSIDE_TOL_REL), is on it.
CONTACT_TOL_REL = 1e-9


def fibonacci_cap(n: int, half_angle: float = np.pi) -> np.ndarray:
    """n nearly uniform unit vectors (golden-angle spiral) within half_angle of +x.

    half_angle = pi covers the whole sphere. Uniform steps in x = cos(angle
    from +x) give equal areas, so the lattice density is the same everywhere.
    """
    x, r, phi = fibonacci_cap_polar(n, half_angle)
    return np.stack([x, r * np.cos(phi), r * np.sin(phi)], axis=1)


def fibonacci_cap_polar(n: int, half_angle: float = np.pi, start: int = 0,
                        stop: int | None = None):
    """(x, r, phi) (n,) each of :func:`fibonacci_cap`'s lattice: direction k is
    (x_k, r_k cos phi_k, r_k sin phi_k) bit for bit, so a caller can test x and the
    azimuth before it pays for the rest (radio maps' launch lattice). Computed in place,
    each operation as the plain expressions 1 - (1 - cos h)(k + 1/2)/n,
    sqrt(max(1 - x^2, 0)) and (k pi)(3 - sqrt 5) round it. ``start``, ``stop``: only
    the directions k in [start, stop) of the n (a piece at a time)."""
    if n < 1:
        raise ArgumentError(f"need at least one direction, got n={n}")
    k = np.arange(start, n if stop is None else min(stop, n), dtype=np.float64)
    phi = np.multiply(k, np.pi)
    phi *= 3.0 - np.sqrt(5.0)
    x = k
    x += 0.5
    x *= 1.0 - np.cos(half_angle)
    x /= n
    np.subtract(1.0, x, out=x)
    r = np.multiply(x, x)
    np.subtract(1.0, r, out=r)
    np.maximum(r, 0.0, out=r)
    np.sqrt(r, out=r)
    return x, r, phi


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors over the whole sphere, float64 (n, 3)."""
    return fibonacci_cap(n, np.pi)


def launch_directions(n_rays: int, gain_fn=None, orientation=None) -> np.ndarray:
    """About n_rays world directions covering where the pattern radiates.

    gain_fn maps local unit directions (K,3) to gain; orientation (3,3) has
    the antenna's local axes as columns. The lattice is laid over the
    smallest cap around boresight (+x) that holds the pattern's support, at
    the density that puts about n_rays inside the support, so a narrow beam
    costs no more than a wide one.
    """
    if gain_fn is None:
        return fibonacci_sphere(n_rays)
    local = _pattern_lattice(n_rays, gain_fn)
    if orientation is None:
        return local
    return local @ np.asarray(orientation, dtype=np.float64).T


def _pattern_lattice(n_rays: int, gain_fn) -> np.ndarray:
    """The local lattice of :func:`launch_directions` (before the antenna's rotation)."""
    probe = fibonacci_sphere(1 << 16)
    inside = np.asarray(gain_fn(probe)) > 0
    if not inside.any():
        raise ArgumentError("the antenna pattern has zero gain everywhere (or in a region "
                         "narrower than 0.01 sr)")
    spacing = np.sqrt(4.0 * np.pi / len(probe))
    half_angle = min(np.pi, float(np.arccos(probe[inside, 0].min())) + 2.0 * spacing)
    in_cap = probe[:, 0] >= np.cos(half_angle)
    share = float(inside[in_cap].mean())
    local = fibonacci_cap(int(np.ceil(n_rays / share)), half_angle)
    return local[np.asarray(gain_fn(local)) > 0]


def reflection_sequences(caster: RayCaster, tri_face, origin, directions, max_order: int,
                         batch: int = 1 << 20) -> np.ndarray:
    """(R, max_order) int32 face ids of each ray's specular bounces, -1 after it escapes."""
    return caster.specular_sequences(origin, directions, tri_face, max_order, batch)


def _unique_rows(seq: np.ndarray) -> np.ndarray:
    """The distinct rows of an int32 array, in the order of np.unique's lexicographic
    sort: rows are hashed to one uint64 each (a cheap 1-D sort of a million keys), and
    the hash is trusted only once every row is checked equal to its key's first row;
    any collision falls back to the exact row sort."""
    h = np.zeros(len(seq), dtype=np.uint64)
    with np.errstate(over="ignore"):
        for k in range(seq.shape[1]):
            h = h * np.uint64(0x100000001B3) ^ (seq[:, k].astype(np.int64).astype(np.uint64)
                                                + np.uint64(0x9E3779B97F4A7C15))
    _, first, inverse = np.unique(h, return_index=True, return_inverse=True)
    if np.array_equal(seq, seq[first[inverse.ravel()]]):
        rows = seq[first]
    else:  # a hash collision: the exact (slower) sort decides
        rows = seq
    void = np.ascontiguousarray(rows).view(
        np.dtype((np.void, rows.dtype.itemsize * rows.shape[1]))).ravel()
    return rows[np.unique(void, return_index=True)[1]]


def _decode_keys(key: np.ndarray, base: int, k: int) -> np.ndarray:
    """(len(key), k) int32 rows of exact row keys (digits id + 1 in ``base``)."""
    rows = np.empty((len(key), k), dtype=np.int32)
    rest = key
    for col in range(k - 1, -1, -1):
        rest, digit = np.divmod(rest, base)
        rows[:, col] = digit - 1
    return rows


def key_base(n_faces: int, max_order: int) -> int | None:
    """The base of exact sequence keys for face ids below ``n_faces`` (digits id + 1),
    or None where ``max_order`` digits overflow an int64."""
    base = int(n_faces) + 1
    return base if max_order >= 1 and base**max_order < 2**63 else None


def sequence_keys(face_seq: np.ndarray, base: int) -> np.ndarray:
    """(R,) int64 exact key of each row of face ids: digits id + 1 in ``base``, first face
    most significant, 0 (as after an escape, -1) from the first face that repeats the one
    before it on: a planar face cannot reflect a ray twice in a row, so the rest of such a
    ray is a float32 artefact of re-hitting a neighbouring triangle of the face it left.
    Keys sort as the rows do lexicographically, and a prefix of k faces is the key's
    first k digits (the device writes the same keys: RayCaster.lattice_keys)."""
    seq = np.asarray(face_seq)
    key = np.zeros(len(seq), dtype=np.int64)
    cut = np.zeros(len(seq), dtype=bool)
    for col in range(seq.shape[1]):
        face = seq[:, col]
        if col:
            cut |= (face == seq[:, col - 1]) & (face >= 0)
        key = key * base + np.where(cut, 0, face.astype(np.int64) + 1)
    return key


def candidates_from_keys(key: np.ndarray, base: int, max_order: int) -> dict[int, np.ndarray]:
    """Unique face sequences of each length 1..max_order from all prefixes of the rays'
    :func:`sequence_keys`, sorted lexicographically."""
    out: dict[int, np.ndarray] = {}
    key = np.unique(key)
    for k in range(max_order, 0, -1):
        # the k-face prefixes that have a k-th face, sorted, distinct
        pref = key[key % base != 0]
        out[k] = _decode_keys(np.unique(pref), base, k)
        key //= base
    return dict(sorted(out.items()))


def unique_candidates(face_seq: np.ndarray) -> dict[int, np.ndarray]:
    """Unique face sequences of each length 1..max_order from all prefixes.

    Sequences that reflect off one plane twice in a row are cut there
    (:func:`sequence_keys`). Rays repeat each other massively, so whole rows are
    de-duplicated first and prefixes are taken from the few unique rows.  Where the
    face ids are few enough (:func:`key_base`), each row is one exact int64 key
    (:func:`sequence_keys`, :func:`candidates_from_keys`). Else rows are de-duplicated
    by checked hashes (:func:`_unique_rows`).
    """
    seq = np.ascontiguousarray(face_seq, dtype=np.int32)
    k_max = seq.shape[1]
    out: dict[int, np.ndarray] = {}
    base = key_base(int(seq.max(initial=-1)) + 1, k_max)
    if len(seq) and base is not None:
        return candidates_from_keys(sequence_keys(seq, base), base, k_max)
    if k_max > 1:
        repeat = np.zeros(seq.shape, dtype=bool)
        repeat[:, 1:] = (seq[:, 1:] == seq[:, :-1]) & (seq[:, 1:] >= 0)
        cut = np.cumsum(repeat, axis=1) > 0
        seq = np.where(cut, -1, seq)
    if len(seq):
        seq = _unique_rows(seq)
    for k in range(1, k_max + 1):
        pref = seq[seq[:, k - 1] >= 0, :k]
        out[k] = np.unique(pref, axis=0) if len(pref) else np.zeros((0, k), np.int32)
    return out


def mirror(points, normal, offset):
    """Reflect points (C,3) across planes n.x = d (n unit), all float64."""
    dist = np.einsum("ij,ij->i", points, normal) - offset
    return points - 2.0 * dist[:, None] * normal


def image_points(tx, rx, normals, offsets, seqs: np.ndarray, runtime=None):
    """Exact reflection points for candidate face sequences, by the image method.

    tx, rx: (3,) positions; normals (F,3) unit and offsets (F,) of the
    faces' planes; seqs (C,k) face ids. Returns points (C, k+2, 3) - tx, the
    k reflection points, rx - and a mask of candidates whose every point lies
    strictly between its neighbours' image line ends (so each reflection
    happens on the side both segments are on). With a ``runtime`` (the device engine)
    the points come from its kernel unless
    :func:`clradcom.device.images.device_refusal` gives a reason: the same bit for bit
    with fp64, within ~1e-14 relative without. Where the points were computed is
    recorded (stage "specular.image_points": :func:`clradcom.device.engines.record`).
    """
    seqs = np.asarray(seqs)
    C, k = seqs.shape
    tx = np.asarray(tx, dtype=np.float64)
    rx = np.asarray(rx, dtype=np.float64)
    refusal = None if runtime is None else device_images.device_refusal(runtime)
    if C and k:
        if runtime is None:
            engines.record("specular.image_points", "host", fallback=False)
        elif refusal is not None:
            engines.record("specular.image_points", "host", refusal)
        else:
            engines.record("specular.image_points", "device")
    if runtime is not None and C and k and refusal is None:
        points, ok, failed_last, failed_first = device_images.image_points(
            runtime, tx, rx, normals, offsets, seqs)
        for what, point, failed, i in (("receiver", rx, failed_last, k - 1),
                                       ("transmitter", tx, failed_first, 0)):
            if failed.any():
                _warn_surface_contact(point, what, normals[seqs[:, i]],
                                      offsets[seqs[:, i]], seqs[:, i], failed)
        return points, ok
    points = np.empty((C, k + 2, 3))
    points[:, 0] = tx
    points[:, -1] = rx
    ok = np.ones(C, dtype=bool)
    if C == 0:
        return points, ok
    images = np.empty((C, k, 3))
    current = np.broadcast_to(tx, (C, 3))
    for i in range(k):
        n = normals[seqs[:, i]]
        d = offsets[seqs[:, i]]
        current = mirror(current, n, d)
        images[:, i] = current
    target = np.broadcast_to(rx, (C, 3)).copy()
    for i in range(k - 1, -1, -1):
        n = normals[seqs[:, i]]
        d = offsets[seqs[:, i]]
        line = images[:, i] - target
        denom = np.einsum("ij,ij->i", line, n)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (d - np.einsum("ij,ij->i", target, n)) / denom
        good = np.isfinite(s) & (s > 1e-12) & (s < 1.0 - 1e-12)
        ends = ([("receiver", rx)] if i == k - 1 else []) + (
            [("transmitter", tx)] if i == 0 else [])
        for what, point in ends if not good.all() else ():
            _warn_surface_contact(point, what, n, d, seqs[:, i], ok & ~good)
        ok &= good
        s = np.where(good, s, 0.5)
        target = target + s[:, None] * line
        points[:, i + 1] = target
    return points, ok


def _warn_surface_contact(point, what, normals, offsets, faces, dropped):
    """Warn when candidates were dropped because an antenna lies on their face's plane:
    the reflection point then coincides with the antenna, and the path with the line
    of sight (geometrical optics has no wave guided along the surface)."""
    dist = np.abs(normals @ point - offsets)
    on = dropped & (dist <= CONTACT_TOL_REL * (1.0 + np.abs(point).max()))
    if on.any():
        warnings.warn(f"the {what} at {point.tolist()} lies on the plane of face(s) "
                      f"{np.unique(faces[on]).tolist()}: the reflection off it coincides with "
                      "the line of sight and the image method cannot place it; the tracer "
                      "adds it as the limit of the merging rays where the line of sight "
                      "exists (specular.surface_contact_paths)", SurfaceContactWarning,
                      stacklevel=5)


# ---------------------------------------------------------------------------
# the mechanism: settings, per-transmitter candidates, paths of a link


@dataclass(frozen=True)
class SpecularSettings:
    """Line of sight and specular reflections: how deep and how densely to search."""

    max_reflections: int = 5
    rays: int = 1_000_000  # launched per transmitter over its pattern's support
    line_of_sight: bool = True
    #: rounds of candidate expansion after the launch (:func:`expanded_paths`): each
    #: round tries, per link, every confirmed path with one more reflection off a face
    #: some confirmed path reflects off, inserted anywhere, and with one reflection left
    #: out; it stops early when a round confirms nothing new. None (or 0): the launch's
    #: candidates only
    expand_rounds: int | None = None
    #: a bistatic link also takes the receiver's own launch (its rays' face sequences,
    #: reversed) as candidates: the faces next to the receiver, which few of the
    #: transmitter's rays reach, come from its rays. None (or False): the transmitter's
    from_receiver: bool | None = None

    def __post_init__(self):
        check_number("SpecularSettings", "max_reflections", self.max_reflections, low=0,
                     high=16, integer=True)
        check_number("SpecularSettings", "rays", self.rays, low=1, integer=True)
        if self.from_receiver is not None and not isinstance(self.from_receiver, bool):
            raise ArgumentError("must be True, False or None",
                                argument="SpecularSettings.from_receiver",
                                value=self.from_receiver)
        if self.expand_rounds is not None:
            check_number("SpecularSettings", "expand_rounds", self.expand_rounds, low=0,
                         high=16, integer=True)
        if not isinstance(self.line_of_sight, bool):
            raise ArgumentError("must be True or False", argument="SpecularSettings.line_of_sight",
                                value=self.line_of_sight)


#: Candidate face sequences of one transmitter: reflection order -> (C, order) int32.
Candidates = dict[int, np.ndarray]


#: the last few local launch lattices, by ray count and pattern: radars that share an
#: antenna (the street's two) share it, rotated to each one's orientation
_LATTICES: dict = {}


def _lattice_of(n_rays: int, pattern) -> np.ndarray:
    """The local launch lattice of ``n_rays`` over ``pattern``, in coherent order
    (:func:`clradcom.geometry.ray_order.coherent_order`: the work-groups' rays leave in
    narrow cones, 10-17 % less CPU for the candidate launch at 1e6-1e7 rays; the
    candidates do not depend on the order), kept for the next transmitter and trace."""
    key = (int(n_rays), json.dumps(pattern.params(), sort_keys=True))
    if key not in _LATTICES:
        if len(_LATTICES) >= 2:
            _LATTICES.pop(next(iter(_LATTICES)))
        lattice = _pattern_lattice(n_rays, pattern.gain)
        lattice = np.ascontiguousarray(lattice[coherent_order(lattice)])
        lattice.flags.writeable = False
        _LATTICES[key] = lattice
    return _LATTICES[key]


def prepare(geom: Geometry, tx: Radar, settings: SpecularSettings) -> Candidates:
    """Unique face sequences proposed by tx's rays (shared by all of tx's receivers)."""
    if settings.max_reflections == 0 or geom.caster is None:
        return {}
    local = _lattice_of(settings.rays, tx.pattern)
    rot = np.asarray(tx.orientation, dtype=np.float64)
    # local @ rot.T by columns (a (n,3) x (3,3) product that BLAS threads only slow down),
    # on the device, where the lattice stays between transmitters: the same rays
    k = settings.max_reflections
    base = key_base(geom.faces.n_faces, k)
    stage = "specular.candidates"
    if geom.engine == "host":
        engines.record(stage, "host", fallback=False)
    else:
        engines.record(stage, "device")
    if geom.engine == "device" and base is not None:
        # each ray's sequence becomes one exact key on the device, and only the set of
        # distinct keys leaves it: no (R, k) rows to download, encode and sort on the
        # host (the reference engine does that)
        keys = geom.caster.lattice_key_set(
            tx.position, local, rot, geom.faces.tri_face, k, base,
            on_host=lambda reason: engines.record(stage, "host", reason))
        return candidates_from_keys(keys, base, k)
    if geom.engine == "device":
        engines.record(stage, "host", f"{geom.faces.n_faces} faces and {k} reflections: a "
                       "face sequence does not fit one 64-bit key, the host de-duplicates "
                       "the sequences")
    seqs = geom.caster.lattice_sequences(tx.position, local, rot, geom.faces.tri_face, k)
    return unique_candidates(seqs)


def link_paths(geom: Geometry, candidates: Candidates, tx: Radar, rx: Radar,
               settings: SpecularSettings) -> Paths:
    """Line of sight and specular reflections of one link, with their fields; an antenna
    lying on a face adds that face's reflection merged with the line of sight."""
    pg = specular_paths(geom, tx.position, rx.position, candidates, settings.line_of_sight)
    if settings.expand_rounds:
        pg = expanded_paths(geom, tx.position, rx.position, candidates, pg,
                            settings.max_reflections, settings.expand_rounds)
    paths = path_fields(geom, pg, tx, rx)
    if settings.line_of_sight and np.any(pg.n_interactions == 0):
        paths = concat_paths([paths, surface_contact_paths(geom, tx, rx)])
    return paths


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


def specular_paths(geom: Geometry, tx_pos, rx_pos, candidates, line_of_sight=True
                   ) -> PathGeometry:
    """Exact, confirmed specular paths (and line of sight) between two points."""
    tx_pos = np.asarray(tx_pos, dtype=np.float64)
    rx_pos = np.asarray(rx_pos, dtype=np.float64)
    k_max = max(candidates.keys(), default=0)
    # every candidate of the link (the line of sight first, then the orders ascending)
    # padded to k_max reflections, confirmed in one batch per segment index
    blocks = []
    if line_of_sight and np.linalg.norm(rx_pos - tx_pos) > 0:
        blocks.append((np.stack([tx_pos, rx_pos])[None], np.zeros((1, 0), np.int32),
                       np.ones(1, dtype=bool)))
    for k in sorted(candidates):
        seqs = candidates[k]
        if len(seqs):
            pts, ok = image_points(tx_pos, rx_pos, geom.faces.normal, geom.faces.offset, seqs,
                                   runtime=geom.runtime if geom.engine == "device" else None)
            blocks.append((pts, seqs, ok))
    P = sum(len(b[0]) for b in blocks)
    points = np.full((P, k_max + 2, 3), np.nan)
    n_int = np.zeros(P, dtype=np.int16)
    faces = np.full((P, k_max), -1, dtype=np.int32)
    ok = np.zeros(P, dtype=bool)
    row = 0
    for pts, seqs, good in blocks:
        n, k = len(pts), seqs.shape[1]
        points[row:row + n, :k + 2] = pts
        n_int[row:row + n] = k
        faces[row:row + n, :k] = seqs
        ok[row:row + n] = good
        row += n
    if geom.caster is None:  # free space: nothing can block the line of sight
        keep, triangles = ok & (n_int == 0), np.full((P, k_max), -1, dtype=np.int32)
    else:
        keep, triangles = confirm_paths(geom.caster, geom.faces.tri_face, geom.faces.normal,
                                        points, faces, ok, engine=geom.engine,
                                        n_interactions=n_int)
    points, n_int, faces, triangles = points[keep], n_int[keep], faces[keep], triangles[keep]
    return PathGeometry(points=points, n_interactions=n_int, faces=faces, triangles=triangles)


def both_ways(tx_candidates: Candidates, rx_candidates: Candidates) -> Candidates:
    """The candidates of a link from both ends: the transmitter's and the receiver's
    reversed (a path tx -> f1 ... fk -> rx is the path rx -> fk ... f1 -> tx), distinct
    rows per order, sorted."""
    out: Candidates = {}
    for k in sorted(set(tx_candidates) | set(rx_candidates)):
        blocks = [np.asarray(c[k], dtype=np.int32).reshape(-1, k)
                  for c in (tx_candidates, rx_candidates) if k in c]
        if k in rx_candidates:
            blocks[-1] = blocks[-1][:, ::-1]
        out[k] = np.unique(np.concatenate(blocks), axis=0)
    return out


def path_sequences(pg: PathGeometry) -> list[np.ndarray]:
    """The face sequence of every reflected path of ``pg`` (line of sight left out)."""
    return [pg.faces[i, :n] for i, n in enumerate(pg.n_interactions) if n > 0]


def expansion_candidates(sequences, pool, max_order: int) -> dict[int, np.ndarray]:
    """Face sequences one step from ``sequences``: each with one face of ``pool``
    inserted at any place (up to ``max_order`` faces), and each with one face left out;
    never the same face twice in a row (a reflection cannot follow itself). Distinct
    rows per order, sorted."""
    pool = np.asarray(pool, dtype=np.int32)
    rows: dict[int, list[np.ndarray]] = {}
    for q in sequences:
        q = np.asarray(q, dtype=np.int32)
        n = len(q)
        if n < max_order and len(pool):
            for at in range(n + 1):
                block = np.empty((len(pool), n + 1), dtype=np.int32)
                block[:, :at], block[:, at], block[:, at + 1:] = q[:at], pool, q[at:]
                rows.setdefault(n + 1, []).append(block)
        if n > 1:
            rows.setdefault(n - 1, []).append(
                np.stack([np.delete(q, at) for at in range(n)]))
    out = {}
    for k, blocks in sorted(rows.items()):
        block = np.unique(np.concatenate(blocks), axis=0)
        block = block[np.all(block[:, 1:] != block[:, :-1], axis=1)]
        if len(block):
            out[k] = block
    return out


def _rows_not_in(rows: np.ndarray, known: np.ndarray | None) -> np.ndarray:
    """The rows of ``rows`` (distinct) that ``known`` does not hold."""
    if known is None or not len(known) or not len(rows):
        return rows
    both = np.concatenate([np.asarray(known, dtype=np.int32), rows])
    _, inverse = np.unique(both, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    seen = np.zeros(int(inverse.max()) + 1, dtype=bool)
    seen[inverse[:len(known)]] = True
    return rows[~seen[inverse[len(known):]]]


class _TriedSequences:
    """The face sequences a link has tried, of every order: one sorted set of exact
    int64 keys (:func:`sequence_keys`; a key's order is its number of digits) where the
    faces fit one key, which a round's proposals are looked up in by bisection (the
    rows' ``np.unique(axis=0)`` against the launch's ~10^4 candidates per order took
    0.08 s a link on the street); rows per order where they do not."""

    def __init__(self, candidates: Candidates, base: int | None):
        self.base = base
        if base is None:
            self.rows = {k: np.asarray(v, dtype=np.int32) for k, v in candidates.items()}
            return
        keys = [sequence_keys(np.asarray(v, dtype=np.int32).reshape(-1, k), base)
                for k, v in candidates.items()]
        # the launch's rows are distinct per order, and keys of two orders never meet
        self.keys = np.sort(np.concatenate(keys)) if keys else np.zeros(0, np.int64)

    def add_new(self, k: int, rows: np.ndarray) -> np.ndarray:
        """The rows (distinct, ``k`` faces, no face twice in a row) not tried before;
        from now on they count as tried."""
        if self.base is None:
            fresh = _rows_not_in(rows, self.rows.get(k))
            self.rows[k] = fresh if k not in self.rows else np.concatenate(
                [self.rows[k], fresh])
            return fresh
        keys = sequence_keys(rows, self.base)
        at = np.minimum(np.searchsorted(self.keys, keys), max(len(self.keys) - 1, 0))
        new = self.keys[at] != keys if len(self.keys) else np.ones(len(keys), bool)
        # distinct rows have distinct keys, none of them known: a sort merges them
        self.keys = np.sort(np.concatenate([self.keys, keys[new]]))
        return rows[new]


def concat_path_geometry(parts: list[PathGeometry]) -> PathGeometry:
    """The paths of ``parts`` in order, padded to the widest."""
    k_max = max(p.faces.shape[1] for p in parts)

    def pad(a, width, fill):
        out = np.full((len(a), width, *a.shape[2:]), fill, dtype=a.dtype)
        out[:, :a.shape[1]] = a
        return out

    return PathGeometry(
        points=np.concatenate([pad(p.points, k_max + 2, np.nan) for p in parts]),
        n_interactions=np.concatenate([p.n_interactions for p in parts]),
        faces=np.concatenate([pad(p.faces, k_max, -1) for p in parts]),
        triangles=np.concatenate([pad(p.triangles, k_max, -1) for p in parts]))


def expanded_paths(geom: Geometry, tx_pos, rx_pos, candidates, found: PathGeometry,
                   max_order: int, rounds: int) -> PathGeometry:
    """``found`` (the launch's confirmed paths of one link) with the paths that candidate
    expansion adds (docs/performance.md, "Complete path sets from fewer rays").

    A ray launch misses a path whose ray tube is narrower than the lattice spacing. Such
    a path is usually one reflection away from a path it did find (another bounce off
    the road or a facade on the way, or one less), so each round proposes, per link,
    every confirmed path with a face that a confirmed path reflects off inserted at any
    place, and with one face left out (:func:`expansion_candidates`), minus every
    sequence tried before. They go through the same exact image method and visibility
    confirmation as the launch's candidates (:func:`specular_paths`), so every path
    added is as real as the launch's; face sequences are unique, so none is found twice.
    Stops after ``rounds`` rounds or one that confirms nothing new."""
    tried = _TriedSequences(candidates, key_base(geom.faces.n_faces, max_order))
    parts = [found]
    sequences = path_sequences(found)
    for _ in range(rounds):
        pool = np.unique(np.concatenate(sequences)) if sequences else np.zeros(0, np.int32)
        proposed = {}
        for k, rows in expansion_candidates(sequences, pool, max_order).items():
            rows = tried.add_new(k, rows)
            if len(rows):
                proposed[k] = rows
        if not proposed:
            break
        more = specular_paths(geom, tx_pos, rx_pos, proposed, line_of_sight=False)
        if not more.n_paths:
            break
        parts.append(more)
        sequences += path_sequences(more)
    return concat_path_geometry(parts) if len(parts) > 1 else found


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
        tol = CONTACT_TOL_REL * (1.0 + np.abs(end).max())
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
    vel[:, 1:k_max + 1] = np.where(active[..., None], scene.point_velocity(
        np.maximum(obj, 0), pts[:, 1:k_max + 1]), 0.0)
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
