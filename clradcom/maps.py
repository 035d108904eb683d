"""Radio maps: one transmitter's path gain over a grid of cells, by shooting rays.

Not one link per cell: rays leave the transmitter over its pattern's support, each ray
tube carrying the solid angle dOmega of its lattice cell, and bounce specularly off the
scene (the polarimetric Fresnel dyad of each face's material as the tracer applies it:
:func:`clradcom.physics.em.reflected_fields`), walked through all their bounces on the
device in one launch per batch (:func:`clradcom.device.map_walk.walk_rays`;
``MapSettings(engine="host")``: bounce by bounce in numpy, the reference). Every
segment of every ray is then accumulated on the device into the cells of a measurement
slab (:func:`clradcom.device.maps.accumulate_segments`): a horizontal layer of thickness
``thickness_m`` centred on ``height_m``, clipped to a rectangle. The estimator
(docs/maps.md) is the track-length form of the ray-density one Sionna RT's radio maps
use: a tube of a ray with field vector E carries the power
(lambda / 4 pi)^2 |p(E)|^2 dOmega / L^2 per unit cross-section at unfolded length L, its
cross-section is dOmega L^2, so inside a cell of volume V it adds

    g += (lambda / 4 pi)^2 |p(E)|^2 dOmega * (length of the segment inside the cell) / V

to the cell's mean path gain, L cancelling; p(E) is the receiver's projection (its
pattern and polarisation at the arrival direction, the bilinear form of
:func:`clradcom.physics.em.path_gains`) or |E|^2 for a receiver that takes every
polarisation with gain 1. For a thin slab this is Sionna's crossing weight
1 / |cos theta| per crossing; unlike it, a ray that runs along the slab (a radar at the
map's height) is counted. The sum is incoherent: the mean over the cell of the sum of
|a_k|^2 over the paths, what :func:`clradcom.trace.trace_scene` gives to a receiver in
the cell summed incoherently. Mechanisms: line of sight and specular reflections; with
``MapSettings(scattering=True)`` diffuse scattering (the tracer's Lambertian tiles,
sampled by diffuse rays) and with ``MapSettings(diffraction=True)`` first-order UTD edge
diffraction (Keller-cone rays from the lit edges).

With ``MapSettings(coherent=True)`` the cell's value is instead the coherent sum at its
centre (:class:`CellSums`): the segments grouped by wavefront (the image source of
their reflections, or their wedge), each group's mean power as above and its phase at
the centre from its unfolded length there (float64 on the host), the groups added as
complex fields; diffuse scattering adds in power.

With ``MapSettings(optics=...)`` the objects the tracer gives physical optics (the cars
under the paper preset) return their PO facets' fields evaluated at the cell centres
instead of their GO single reflections (:func:`_po_facets`); their later bounces are
the rays' GO exit segments or, with ``MapSettings(sbr="footprints")``, the tracer's
SBR-PO tubes' footprints radiated to the centres (:func:`_sbr_footprints`).

The estimate converges where enough segments pass through a cell: at least
:data:`MIN_SEGMENTS`, and :data:`MIN_EFFECTIVE_SEGMENTS` of them effective where their
weights differ (``RadioMap.converged``, ``RadioMap.effective_count``; docs/maps.md,
tests/test_maps.py).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from clradcom.device.map_walk import (
    LaunchLattice,
    WalkTables,
    receive_weights,
    walk_rays,
)
from clradcom.device.maps import (
    Slab,
    accumulate_rows,
    accumulate_segments,
    accumulation_copies,
    po_facet_fields,
    po_pairs,
    segment_cells,
)
from clradcom.device.raycast import pack_rays, spawn_origins
from clradcom.device.runtime import Runtime
from clradcom.device.visibility import surface_sees
from clradcom.errors import ArgumentError, ArgumentTypeError
from clradcom.geometry.ray_order import MORTON_BITS, morton_codes, octahedral_coordinates
from clradcom.geometry.triangles import triangle_normals
from clradcom.mechanisms import diffraction, sbr
from clradcom.mechanisms.common import Geometry, build_geometry, check_number
from clradcom.mechanisms.diffraction import DiffractionSettings
from clradcom.mechanisms.optics import MODES as OPTICS_MODES
from clradcom.mechanisms.optics import object_optics
from clradcom.mechanisms.specular import fibonacci_cap_polar, fibonacci_sphere
from clradcom.memory import check_memory
from clradcom.parallel import map_in_order, prefetch, take_rows
from clradcom.physics import utd
from clradcom.physics.em import (
    C0,
    fresnel_coefficients,
    material_reflection_dyad,
    reflected_fields,
)
from clradcom.physics.po import (
    MAX_SUBDIVISION_LEVELS,
    NEAR_SIZE_FACTOR,
    po_currents,
    po_transfer,
)
from clradcom.physics.vectors import perpendicular
from clradcom.scene.records import Radar, Scene

__all__ = ["MIN_EFFECTIVE_SEGMENTS", "MIN_SEGMENTS", "CellSums", "MapGrid", "MapSettings",
           "RadioMap", "Wave", "find_radar", "launch_lattice", "map_memory_bytes",
           "radio_map"]

#: The convergence rule: a cell's value is trusted where at least this many ray segments
#: ran through it (within 1 dB of the per-link tracer there; docs/maps.md).
MIN_SEGMENTS = 20

#: ... and carried by as many effective segments (RadioMap.effective_count): the count
#: alone passes a cell where a few heavy rays among many light ones set the value (UTD
#: cone rays near a shadow boundary; docs/maps.md, "The convergence rule").
MIN_EFFECTIVE_SEGMENTS = MIN_SEGMENTS

#: Host bytes one ray of a batch holds at its peak: float64 origin and direction, the
#: complex field vector, the reflection's and the receive projection's temporaries, the
#: hit record and the float32 rows sent to the device. Measured by tracemalloc on the
#: street (batches of 2^16 rays, 3 reflections): 520 bytes a ray, 610 with diffraction
#: (its Keller-cone rounds hold at most a batch of rays); twice that for a margin. The
#: device walk holds less: its lists' room (88 bytes a segment, three segments a ray at
#: first, 116 bytes a scattering hit) and the host's copy of the segments' 56-byte
#: receive rows.
BYTES_PER_RAY = 1200

#: A coherent map's (segment, cell) records a launched ray makes: measured 2.6 on the
#: street (radar A, 20 m x 10 m at 5 cm cells, 3 reflections: 11 cells for each segment
#: that reaches the layer), rounded up; and the host bytes one record holds while its
#: batch is weighed (its indices, length, phase, complex term and the sort's copies).
#: A bound, not a measure: tracemalloc saw the records' arrays after the ray batch's
#: peak, not on it (2^18 rays of that map, 331,169 records in the batch: a 143 MB peak
#: against 140 MB for the incoherent map).
COHERENT_RECORDS_PER_RAY = 4
BYTES_PER_RECORD = 160

#: Host bytes a facet-cell pair of the PO stage holds while its round is weighed (the
#: transfer dyads, directions, the facet integral's temporaries, the sight rays): a bound
#: for the pairs a device launch returns too (measured by tracemalloc on the street: 710
#: to 820 bytes each, the whole facet table and launches included).
BYTES_PER_PO_PAIR = 2000

#: how a map carries SBR objects' later bounces (MapSettings.sbr)
SBR_MODES = ("exit-rays", "footprints")
#: footprint-cell terms of the SBR footprint stage weighed together per PO pair of
#: MapSettings.po_batch, and the host bytes each holds meanwhile (its vectors, the
#: sight ray, the PO integral's temporaries)
FOOTPRINT_TERMS_PER_PO_PAIR = 2
BYTES_PER_FOOTPRINT_TERM = 1000


@dataclass(frozen=True)
class MapSettings:
    """How densely and how deep a radio map shoots."""

    rays: int = 1_000_000  #: launched over the transmit pattern's support
    max_reflections: int = 2
    line_of_sight: bool = True
    #: diffuse (Lambertian) scattering off materials with a scattering coefficient S > 0
    #: (the tracer's model, docs/scattering.md): every hit on such a face sends
    #: ``diffuse_rays`` rays into the hemisphere, cosine-weighted, sharing S^2 Gamma^2 of
    #: the tube's power; they reach the layer directly (no reflection after the tile)
    scattering: bool = False
    #: specular reflections a ray may have had before it scatters (as the tracer's
    #: ScatteringSettings.max_reflections for the reflection before the tile)
    scattering_reflections: int = 0
    diffuse_rays: int = 4
    #: first-order UTD edge diffraction from the transmitter (the tracer's wedges and
    #: coefficients, docs/utd.md): every wedge the transmitter lights is sampled every
    #: ``edge_step_m`` and each sample sends rays around its Keller cone every
    #: ``cone_step_deg`` of the exterior angle
    diffraction: bool = False
    edge_step_m: float = 0.05
    cone_step_deg: float = 1.0
    seed: int = 0  #: of the diffuse rays' directions and nothing else
    #: the coherent sum for small cells (docs/maps.md "The coherent sum"): per cell the
    #: rays grouped by wavefront (the image source of their reflections, or the edge they
    #: left), each group's mean power as the incoherent map estimates it and its phase at
    #: the cell's centre, the groups added as complex fields; diffuse scattering, random
    #: in phase as the tracer's tiles are, adds in power
    coherent: bool = False
    #: physical optics as the tracer's OpticsSettings.mode ("none", "pec", "sbr": the
    #: paper preset's) chooses it per object (objects' own ``optics`` keys first,
    #: docs/po.md): the first bounce off an object with PO optics is its PO facets'
    #: field evaluated at the cell centres instead of the GO reflection, and with "po"
    #: optics (SBR) its later bounces are as ``sbr`` says
    optics: str = "none"
    #: facet-cell pairs of the PO stage weighed together on the host (host memory
    #: ~2 kB each): the pairs a device launch returns at most, or the host's round
    po_batch: int = 1 << 16
    #: SBR objects' later bounces (optics "po"): "exit-rays" carries the rays' GO exit
    #: segments on through the cells (the GO limit of the tubes' radiation, fast);
    #: "footprints" radiates the tracer's SBR-PO tubes' footprints to the cell centres
    #: (its windows and PO integrals; a face sequence's footprints summed as fields), and
    #: drops the exit segments of the directions its tubes were shot in
    sbr: str = "exit-rays"
    #: pitch of the footprint tubes (wavelengths) where an object has no
    #: ``sbr_spacing_wavelengths`` key of its own (the tracer's key)
    sbr_spacing_wavelengths: float = 4.0
    #: None: a face sequence's footprints radiate to every centre on their face's lit
    #: side; a number: only into its beam widened by that many diffraction lobes (lambda
    #: over the sequence's size) each side, faster but without the far sidelobes
    sbr_lobe_widths: float | None = None
    #: how the PO stage finds its pairs and weighs the PEC facets' fields: "device" (the
    #: pairs made, tested and weighed in one launch each, double about the grid's corner
    #: where the device has fp64, the carrier phase in float64 on the host) or "host"
    #: (pair by pair, float64 numpy: the tracer's po_transfer)
    po_engine: str = "device"
    #: where the rays stage walks the launched rays through their bounces: "device" (one
    #: launch per batch, kernels/map_walk.cl; coherent maps stay on the host, whose image
    #: sources need float64) or "host" (numpy, the closest hits on the device: the
    #: reference the device walk is tested against)
    engine: str = "device"
    batch: int = 1 << 18  #: rays traced together (host memory: BYTES_PER_RAY each)

    def __post_init__(self):
        check_number("MapSettings", "rays", self.rays, low=1, integer=True)
        check_number("MapSettings", "max_reflections", self.max_reflections, low=0,
                     high=16, integer=True)
        check_number("MapSettings", "batch", self.batch, low=1, integer=True)
        for name in ("line_of_sight", "scattering", "coherent"):
            if not isinstance(getattr(self, name), bool):
                raise ArgumentError("must be True or False", argument=f"MapSettings.{name}",
                                    value=getattr(self, name))
        check_number("MapSettings", "scattering_reflections", self.scattering_reflections,
                     low=0, high=16, integer=True)
        check_number("MapSettings", "diffuse_rays", self.diffuse_rays, low=1, high=1024,
                     integer=True)
        check_number("MapSettings", "seed", self.seed, low=0, integer=True)
        if not isinstance(self.diffraction, bool):
            raise ArgumentError("must be True or False", argument="MapSettings.diffraction",
                                value=self.diffraction)
        check_number("MapSettings", "edge_step_m", self.edge_step_m, low=0.0, low_open=True)
        check_number("MapSettings", "cone_step_deg", self.cone_step_deg, low=0.0,
                     high=90.0, low_open=True)
        if self.optics not in OPTICS_MODES:
            raise ArgumentError(f"must be one of {', '.join(map(repr, OPTICS_MODES))} "
                                "(OpticsSettings.mode)", argument="MapSettings.optics",
                                value=self.optics)
        check_number("MapSettings", "po_batch", self.po_batch, low=1, integer=True)
        check_number("MapSettings", "sbr_spacing_wavelengths", self.sbr_spacing_wavelengths,
                     low=0.01, high=100.0)
        if self.sbr not in SBR_MODES:
            raise ArgumentError(f"must be one of {', '.join(map(repr, SBR_MODES))}",
                                argument="MapSettings.sbr", value=self.sbr)
        if self.sbr_lobe_widths is not None:
            check_number("MapSettings", "sbr_lobe_widths", self.sbr_lobe_widths, low=0.0,
                         low_open=True, high=100.0)
        if self.po_engine not in ("device", "host"):
            raise ArgumentError("must be 'device' or 'host'", argument="MapSettings.po_engine",
                                value=self.po_engine)
        if self.engine not in ("device", "host"):
            raise ArgumentError("must be 'device' or 'host'", argument="MapSettings.engine",
                                value=self.engine)


@dataclass(frozen=True)
class MapGrid:
    """The measurement surface: cells of ``cell_m`` from (x_min, y_min) covering the
    rectangle up to (x_max, y_max) (the last row and column may reach past it, by less
    than a cell), in a horizontal layer ``thickness_m`` thick (None: ``cell_m``)
    centred on ``height_m``."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    height_m: float
    cell_m: float = 0.5
    thickness_m: float | None = None

    def __post_init__(self):
        for name in ("x_min", "x_max", "y_min", "y_max", "height_m"):
            check_number("MapGrid", name, getattr(self, name))
        check_number("MapGrid", "cell_m", self.cell_m, low=0.0, low_open=True)
        if self.thickness_m is not None:
            check_number("MapGrid", "thickness_m", self.thickness_m, low=0.0, low_open=True)
        if not (self.x_max > self.x_min and self.y_max > self.y_min):
            raise ArgumentError("the rectangle must have x_max > x_min and y_max > y_min",
                                argument="MapGrid", value=(self.x_min, self.x_max,
                                                           self.y_min, self.y_max))

    @property
    def nx(self) -> int:
        return max(1, math.ceil((self.x_max - self.x_min) / self.cell_m - 1e-9))

    @property
    def ny(self) -> int:
        return max(1, math.ceil((self.y_max - self.y_min) / self.cell_m - 1e-9))

    @property
    def n_cells(self) -> int:
        return self.nx * self.ny

    @property
    def thickness(self) -> float:
        return self.cell_m if self.thickness_m is None else float(self.thickness_m)

    @property
    def x_centres(self) -> np.ndarray:
        return self.x_min + self.cell_m * (np.arange(self.nx) + 0.5)

    @property
    def y_centres(self) -> np.ndarray:
        return self.y_min + self.cell_m * (np.arange(self.ny) + 0.5)

    def centres(self) -> np.ndarray:
        """(ny, nx, 3) world centres of the cells."""
        x, y = np.meshgrid(self.x_centres, self.y_centres)
        return np.stack([x, y, np.full_like(x, self.height_m)], axis=-1)

    def slab(self) -> Slab:
        half = 0.5 * self.thickness
        return Slab(x0=float(self.x_min), y0=float(self.y_min), cell_x=float(self.cell_m),
                    cell_y=float(self.cell_m), nx=self.nx, ny=self.ny,
                    z_lo=float(self.height_m) - half, z_hi=float(self.height_m) + half)

    def extent(self) -> tuple[float, float, float, float]:
        """(left, right, bottom, top) of the cells, for imshow."""
        return (self.x_min, self.x_min + self.nx * self.cell_m,
                self.y_min, self.y_min + self.ny * self.cell_m)


@dataclass
class RadioMap:
    """A map's cells: ``gain`` (ny, nx) the mean path gain over each cell (linear, both
    antennas' patterns inside), ``count`` (ny, nx) the ray segments through it."""

    grid: MapGrid
    gain: np.ndarray
    count: np.ndarray
    tx_name: str
    rx_name: str | None  #: whose antenna receives; None: gain 1, every polarisation
    rays: int  #: launched
    tx_power_w: float = 1.0
    #: True where ``gain`` is the coherent sum (MapSettings.coherent); the incoherent one
    #: is then ``incoherent_gain``
    coherent: bool = False
    incoherent_gain: np.ndarray | None = None
    #: coherent maps: the fewest segments of a wavefront group holding >= 1 % of a
    #: cell's power (CellSums.group_count)
    group_count: np.ndarray | None = None
    #: wall seconds of the stages: "launch lattice" (made, or kept from an earlier map),
    #: "rays" (launch, bounces, scattering, accumulation), "physical optics",
    #: "sbr" (footprints), "diffraction", "coherent sum"
    stage_seconds: dict[str, float] | None = None
    #: (ny, nx) the sum of the squares of the segments' terms (weight x length inside
    #: the cell, in gain units): what :attr:`effective_count` compares the cell's power to
    square: np.ndarray | None = None

    @property
    def effective_count(self) -> np.ndarray:
        """(ny, nx) the number of equal segments that would carry the cell's power with
        the spread its own terms have: (incoherent power)^2 / sum of the squared terms.
        The segment count where all terms are equal; far fewer where a few heavy
        segments carry the cell (UTD cone rays near a shadow boundary). Power evaluated
        at the centre (the PO facets) adds to the numerator alone, being exact. 0 where
        no term's square is known (no segment, or every square 190 dB under its batch's
        largest term and lost to float32); the count for a map made without the squares
        (``square`` None)."""
        if self.square is None:
            return self.count.astype(np.float64)
        power = self.gain if self.incoherent_gain is None else self.incoherent_gain
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.square > 0, power * power / self.square, 0.0)

    @property
    def converged(self) -> np.ndarray:
        """(ny, nx) bool: cells that satisfy the convergence rule: :data:`MIN_SEGMENTS`
        segments, :data:`MIN_EFFECTIVE_SEGMENTS` of them effective
        (:attr:`effective_count`), and for a coherent map :data:`MIN_SEGMENTS` in each
        wavefront group that holds 1 % of the cell's power or more."""
        ok = (self.count >= MIN_SEGMENTS) & (self.effective_count >= MIN_EFFECTIVE_SEGMENTS)
        if self.coherent and self.group_count is not None:
            ok &= self.group_count >= MIN_SEGMENTS
        return ok

    def gain_db(self, floor_db: float = -300.0) -> np.ndarray:
        with np.errstate(divide="ignore"):
            return np.maximum(10.0 * np.log10(self.gain), floor_db)

    @property
    def received_power_w(self) -> np.ndarray:
        return self.tx_power_w * self.gain


def launch_lattice(n_rays: int, pattern) -> tuple[np.ndarray, float]:
    """(local directions (R, 3), solid angle per ray sr): a Fibonacci lattice of about
    ``n_rays`` directions where ``pattern`` (None: isotropic) radiates, every ray
    standing for the same solid angle of the cap around boresight (+x) that holds the
    pattern's support (as :func:`clradcom.mechanisms.specular.launch_directions` lays
    it), the directions of zero gain dropped."""
    if pattern is None:
        return fibonacci_sphere(n_rays), 4.0 * np.pi / n_rays
    local, solid_angle, _, _ = _cap_with_field(n_rays, pattern)
    return local, solid_angle


def _cap_with_field(n_rays: int, pattern):
    """(directions (R, 3), solid angle per ray, field (R, 2), Morton codes (R,)): the
    directions of the pattern's cap lattice where it radiates (|C|^2 > 0), in lattice
    order, with the pattern's (C_theta, C_phi) and the Morton codes of
    :func:`clradcom.geometry.ray_order.coherent_order` at them. The lattice is laid over
    the cap around boresight (+x) that holds the support as seen on a probe lattice, at
    the density that puts about ``n_rays`` inside; the field is evaluated only where
    :func:`_support_bounds` says the pattern may have gain (a superset by SECTOR_MARGIN
    of a sector's box: the exact test is the pattern's), so a sector pays for its own
    share of the cap, not all of it."""
    probe = fibonacci_sphere(1 << 16)
    inside = np.asarray(pattern.gain(probe)) > 0
    if not inside.any():
        raise ArgumentError("the transmit pattern has zero gain everywhere",
                            argument="pattern", value=pattern.kind)
    spacing = np.sqrt(4.0 * np.pi / len(probe))
    half_angle = min(np.pi, float(np.arccos(probe[inside, 0].min())) + 2.0 * spacing)
    in_cap = probe[:, 0] >= np.cos(half_angle)
    share = float(inside[in_cap].mean())
    n_cap = int(np.ceil(n_rays / share))
    solid_angle = 2.0 * np.pi * (1.0 - np.cos(half_angle)) / n_cap
    bounds = _support_bounds(pattern)
    # a piece at a time (their temporaries stay in the core's cache), the pieces on the
    # host's cores (numpy lets go of the GIL in its loops), into arrays that can hold the
    # whole cap but are written (paged in) only as far as the rows reach
    local = np.empty((n_cap, 3))
    field = np.empty((n_cap, 2), dtype=np.complex128)
    codes = np.empty(n_cap, dtype=np.uint16 if MORTON_BITS <= 8 else np.uint32)
    rows = 0
    pieces = range(0, n_cap, _LATTICE_PIECE)
    for got in map_in_order(
            lambda start: _lattice_piece(pattern, n_cap, half_angle, bounds, start), pieces):
        if got is None:
            continue
        piece, c, piece_codes = got
        m = len(piece)
        local[rows:rows + m] = piece
        field[rows:rows + m] = c
        codes[rows:rows + m] = piece_codes
        rows += m
    return local[:rows], solid_angle, field[:rows], codes[:rows]


def _lattice_piece(pattern, n_cap: int, half_angle: float, bounds, start: int):
    """(directions, field, Morton codes) of rows ``start`` .. ``start + _LATTICE_PIECE``
    of the cap lattice where ``pattern`` radiates (:func:`_cap_with_field`), None where
    none of them lies inside its support ``bounds`` (:func:`_support_bounds`)."""
    cos_azimuth, z_max, x_min = bounds
    x, r, phi = fibonacci_cap_polar(n_cap, half_angle, start, start + _LATTICE_PIECE)
    y = np.cos(phi)
    y *= r
    maybe = np.ones(len(x), dtype=bool)
    if x_min > -1.0:
        maybe &= x >= x_min
    if cos_azimuth > -1.0:
        # cos(azimuth) = x / hypot(x, y) >= the bound; the pole (x = y = 0) is in
        maybe &= x >= cos_azimuth * np.hypot(x, y)
    if z_max < 1.0:
        z = np.sin(phi)
        z *= r
        maybe &= np.abs(z) <= z_max
        z = z[maybe]
    else:
        z = np.sin(phi[maybe])
        z *= r[maybe]
    if not len(z):   # the piece is outside the support (a pattern may fail on none)
        return None
    piece = np.stack([x[maybe], y[maybe], z], axis=1)
    c = np.asarray(pattern.field(piece), dtype=np.complex128)
    radiates = (np.abs(c[:, 0]) ** 2 + np.abs(c[:, 1]) ** 2) > 0
    if not radiates.all():
        piece, c = piece[radiates], c[radiates]
    return piece, c, morton_codes(*octahedral_coordinates(piece))


#: rows of a launch lattice made at once: the temporaries of its per-row stages (the
#: pattern's field, the Morton codes) stay in the core's cache
_LATTICE_PIECE = 1 << 16


def map_memory_bytes(settings: MapSettings, grid: MapGrid) -> int:
    """Host memory a map holds at its peak: a batch of rays (:data:`BYTES_PER_RAY` each),
    the launch lattice (24 bytes a ray), and the grid's float64 sums and squares and
    int64 counts (24 bytes a cell) with the accumulation's float32/int32 copies of them
    (:func:`clradcom.device.maps.accumulation_copies`, 12 bytes a cell each); a coherent
    map adds its records (:data:`COHERENT_RECORDS_PER_RAY` a launched ray,
    :data:`BYTES_PER_RECORD` each while a batch's are weighed, 40 bytes each kept as a
    (cell, group) sum); physical optics a round of :attr:`MapSettings.po_batch`
    facet-cell pairs (:data:`BYTES_PER_PO_PAIR` each) and, with SBR footprints, a round
    of their terms (:data:`FOOTPRINT_TERMS_PER_PO_PAIR` per pair,
    :data:`BYTES_PER_FOOTPRINT_TERM` each)."""
    need = (min(settings.batch, settings.rays) * BYTES_PER_RAY + 24 * settings.rays
            + (24 + 12 * accumulation_copies(grid.n_cells)) * grid.n_cells)
    if settings.optics != "none":
        need += settings.po_batch * BYTES_PER_PO_PAIR
        if settings.sbr == "footprints":
            need += (settings.po_batch * FOOTPRINT_TERMS_PER_PO_PAIR
                     * BYTES_PER_FOOTPRINT_TERM)
    if settings.coherent:
        need += COHERENT_RECORDS_PER_RAY * (
            min(settings.batch, settings.rays) * BYTES_PER_RECORD + 40 * settings.rays)
    return need


def _rotate(v, m) -> np.ndarray:
    """v @ m for (R, 3) rows and a 3 x 3 matrix, by einsum: BLAS's threaded matmul of
    such thin products stalls when the cores are busy (262,144 rows: 1.6 ms at best, a
    median of 260 to 610 ms on the shared 2-core machine, against einsum's 34 to 73 ms)."""
    return np.einsum("ij,jk->ik", v, m)


def _basis(directions_world, orientation):
    """theta-hat, phi-hat (R, 3) world of the antenna frame ``orientation`` at unit world
    directions: those of :func:`clradcom.scene.antenna.theta_phi_unit_vectors` at the
    local direction's angles (phi = 0 on the axis, as atan2(0, 0) gives), written with
    cos phi = x / rho, sin phi = y / rho instead of the angles."""
    d = _rotate(directions_world, orientation)
    rho = np.hypot(d[:, 0], d[:, 1])
    axis = rho == 0
    safe = np.where(axis, 1.0, rho)
    cos_p = np.where(axis, 1.0, d[:, 0] / safe)
    sin_p = np.where(axis, 0.0, d[:, 1] / safe)
    th = np.stack([d[:, 2] * cos_p, d[:, 2] * sin_p, -rho], axis=1)
    ph = np.stack([-sin_p, cos_p, np.zeros_like(rho)], axis=1)
    rot_t = np.ascontiguousarray(orientation.T)
    return _rotate(th, rot_t), _rotate(ph, rot_t)


def _projection(field, directions, rx: Radar | None, pattern=None) -> np.ndarray:
    """The receiver's complex projection p(E) (..., R, 1) of field vectors E (..., R, 3)
    (several fields per direction share its pattern's evaluation) arriving along
    ``directions`` (R, 3) (em.path_gains' bilinear form at -direction), or E itself
    without a receiver: what a coherent sum adds, |p|^2 the power. ``pattern``: the
    receiver's (local directions, (C_theta, C_phi)) at -directions, when known
    (:func:`_rx_pattern`)."""
    if rx is None:
        return np.asarray(field, dtype=np.complex128)
    rot = np.asarray(rx.orientation, dtype=np.float64)
    # theta-hat . E in the antenna's frame: (th_local R^T) . E = th_local . (E R), so the
    # arrival direction and the field are rotated once and theta-hat, phi-hat never
    # formed (_basis's vectors, cos phi = x / rho, sin phi = y / rho)
    d, c = _rx_pattern(directions, rx) if pattern is None else pattern
    e = np.einsum("...ij,jk->...ik", np.asarray(field, dtype=np.complex128), rot)
    rho = np.hypot(d[:, 0], d[:, 1])
    axis = rho == 0
    safe = np.where(axis, 1.0, rho)
    cos_p = np.where(axis, 1.0, d[:, 0] / safe)
    sin_p = np.where(axis, 0.0, d[:, 1] / safe)
    along_x = cos_p * e[..., 0] + sin_p * e[..., 1]
    e_theta = d[:, 2] * along_x - rho * e[..., 2]
    e_phi = cos_p * e[..., 1] - sin_p * e[..., 0]
    return (c[:, 0] * e_theta + c[:, 1] * e_phi)[..., None]


def _rx_pattern(directions, rx: Radar) -> tuple[np.ndarray, np.ndarray]:
    """(local (R, 3), (C_theta, C_phi) (R, 2) complex): the receiver's frame's arrival
    directions -directions and its pattern there."""
    d = _rotate(-directions, np.asarray(rx.orientation, dtype=np.float64))
    return d, np.asarray(rx.pattern.field(d), dtype=np.complex128)


def _received(field, directions, rx: Radar | None) -> np.ndarray:
    """|p(E)|^2 (..., R): the power the receiver takes from field vectors E (..., R, 3)
    arriving along ``directions`` (R, 3): the bilinear projection onto its pattern's
    (C_theta, C_phi) at -direction (em.path_gains), or |E|^2 without a receiver."""
    return np.sum(np.abs(_projection(field, directions, rx)) ** 2, axis=-1)


def _reaches(slab: Slab, origins, directions, lengths, margin: float = 1e-3) -> np.ndarray:
    """(R,) bool: segments that may pass through the slab's box (grown by ``margin`` m,
    so the kernel's float32 clipping never sees one this skipped). Most segments do not
    (rays into the sky, between walls above the layer): their receive projections are
    not worth computing."""
    t0 = np.zeros(len(origins))
    t1 = np.minimum(lengths, 1e30)
    lo = (slab.x0 - margin, slab.y0 - margin, slab.z_lo - margin)
    hi = (slab.x0 + slab.nx * slab.cell_x + margin, slab.y0 + slab.ny * slab.cell_y + margin,
          slab.z_hi + margin)
    ok = np.ones(len(origins), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(3):
            o, d = origins[:, axis], directions[:, axis]
            flat = d == 0
            ok &= ~flat | ((o >= lo[axis]) & (o <= hi[axis]))
            a = (lo[axis] - o) / d
            b = (hi[axis] - o) / d
            t0 = np.where(flat, t0, np.maximum(t0, np.minimum(a, b)))
            t1 = np.where(flat, t1, np.minimum(t1, np.maximum(a, b)))
    return ok & (t0 <= t1)


#: Image sources closer than this (m) are one wavefront: coplanar triangles of one wall
#: mirror the source onto the same point up to float64 rounding.
IMAGE_SOURCE_TOLERANCE_M = 1e-4


@dataclass
class Wave:
    """What the coherent sum needs of a batch of segments besides their power: ``polar``
    (S, C) the received complex amplitude per segment (the receiver's projection p(E),
    C = 1, or the field vector E without a receiver, C = 3), ``group`` (S, G) int64 rows
    naming the wavefront each belongs to, and ``path_length(rows, points)`` the unfolded
    length (m, float64) from the transmitter along the wavefront of segments ``rows`` to
    the world ``points``."""

    polar: np.ndarray
    group: np.ndarray
    path_length: Callable[[np.ndarray, np.ndarray], np.ndarray]


class CellSums:
    """The sums a map's cells collect. Incoherent: each segment's weight x length in each
    cell (on the device) and the segment counts. Coherent (``coherent=True``): in
    addition, per cell and wavefront group, W the summed weight x length (the group's
    mean power over the cell) and Z the same terms times the segment's unit polarisation
    phasor with the carrier phase e^{-jkL} of its wavefront's length to the cell's centre
    (float64 on the host); a group's complex field at the centre is sqrt(W) Z / |Z|.
    Segments given without a :class:`Wave` (diffuse scattering) add in power only."""

    def __init__(self, runtime, grid: MapGrid, wavenumber: float, coherent: bool):
        self.runtime = runtime
        self.grid = grid
        self.slab = grid.slab()
        self.wavenumber = float(wavenumber)
        self.coherent = coherent
        shape = (grid.ny, grid.nx)
        self.power = np.zeros(shape)
        self.count = np.zeros(shape, dtype=np.int64)
        self.square = np.zeros(shape)  # the segments' weight x length terms squared
        self.power_only = np.zeros(shape) if coherent else self.power
        self._groups: dict[tuple, int] = {}
        self._keys = np.zeros(0, dtype=np.int64)
        self._w = np.zeros(0)
        self._n = np.zeros(0, dtype=np.int64)
        self._z = np.zeros((0, 1), dtype=np.complex128)
        self._centres = grid.centres().reshape(-1, 3)
        self._points: np.ndarray | None = None  # fields evaluated at the centres

    def add(self, origins, directions, lengths, weights, wave: Wave | None = None) -> None:
        """Segments (origin, unit direction, length to their end, weight per metre)."""
        if not self.coherent or wave is None:
            accumulate_segments(self.runtime, self.slab, origins, directions, lengths,
                                weights, self.power_only, self.count, self.square)
            return
        seg, cell, length = segment_cells(self.runtime, self.slab, origins, directions,
                                          lengths)
        keep = weights[seg] > 0
        seg, cell, length = seg[keep], cell[keep], length[keep]
        wl = weights[seg] * length
        n_cells = self.grid.n_cells
        self.power += np.bincount(cell, wl, minlength=n_cells).reshape(self.power.shape)
        self.count += np.bincount(cell, minlength=n_cells).reshape(self.count.shape)
        self.square += np.bincount(cell, wl * wl, minlength=n_cells).reshape(self.square.shape)
        if not len(seg):
            return
        polar = np.asarray(wave.polar, dtype=np.complex128)
        size = np.linalg.norm(polar, axis=1)
        unit = polar / np.where(size > 0, size, 1.0)[:, None]
        phase = np.exp(-1j * self.wavenumber * wave.path_length(seg, self._centres[cell]))
        z = (wl * phase)[:, None] * unit[seg]
        keys = self._group_ids(wave.group)[seg] * n_cells + cell
        if self._z.shape[1] != z.shape[1]:
            self._z = np.zeros((0, z.shape[1]), dtype=np.complex128)
        keys = np.concatenate([self._keys, keys])
        self._keys, inverse = np.unique(keys, return_inverse=True)
        self._w = np.bincount(inverse, np.concatenate([self._w, wl]))
        self._n = np.bincount(inverse, np.concatenate([self._n, np.ones(len(wl))])).astype(
            np.int64)
        zz = np.concatenate([self._z, z])
        self._z = np.stack([np.bincount(inverse, zz[:, c].real)
                            + 1j * np.bincount(inverse, zz[:, c].imag)
                            for c in range(zz.shape[1])], axis=1)

    def add_at_centres(self, cell, amplitude) -> None:
        """Complex amplitudes (S, C) evaluated at the centres of cells ``cell`` (S,)
        (the PO facets' fields): their power adds to the incoherent sums and, coherent,
        the amplitudes themselves to the cell's field, each exact at the centre."""
        cell = np.asarray(cell, dtype=np.int64)
        amplitude = np.asarray(amplitude, dtype=np.complex128)
        n_cells = self.grid.n_cells
        power = np.sum(np.abs(amplitude) ** 2, axis=1)
        self.power += np.bincount(cell, power, minlength=n_cells).reshape(self.power.shape)
        if not self.coherent:
            return
        if self._points is None:
            self._points = np.zeros((n_cells, amplitude.shape[1]), dtype=np.complex128)
        for c in range(amplitude.shape[1]):
            self._points[:, c] += (np.bincount(cell, amplitude[:, c].real, minlength=n_cells)
                                   + 1j * np.bincount(cell, amplitude[:, c].imag,
                                                      minlength=n_cells))

    def _group_ids(self, rows: np.ndarray) -> np.ndarray:
        unique, inverse = np.unique(np.asarray(rows, dtype=np.int64), axis=0,
                                    return_inverse=True)
        ids = np.array([self._groups.setdefault(tuple(r), len(self._groups))
                        for r in unique.tolist()], dtype=np.int64)
        return ids[inverse.reshape(-1)]

    @property
    def groups(self) -> int:
        """Wavefront groups seen so far."""
        return len(self._groups)

    def incoherent(self) -> np.ndarray:
        return self.power if self.power_only is self.power else self.power + self.power_only

    def group_count(self, share: float = 0.01) -> np.ndarray:
        """(ny, nx) int64: the fewest segments of any wavefront group that holds at least
        ``share`` of its cell's coherent-summed power (every group's W), 0 where none
        does: the coherent map's convergence count, since each group's power is
        estimated from its own segments."""
        n_cells = self.grid.n_cells
        cell = self._keys % n_cells
        total = np.bincount(cell, self._w, minlength=n_cells)
        significant = self._w >= share * total[cell]
        fewest = np.full(n_cells, np.iinfo(np.int64).max)
        np.minimum.at(fewest, cell[significant], self._n[significant])
        fewest[fewest == np.iinfo(np.int64).max] = 0
        return fewest.reshape(self.power.shape)

    def coherent_gain(self) -> np.ndarray:
        """(ny, nx): |sum over groups of sqrt(W) Z / |Z| plus the fields evaluated at the
        centres|^2, plus the power-only sums."""
        n_cells = self.grid.n_cells
        size = np.linalg.norm(self._z, axis=1)
        amplitude = np.sqrt(self._w)[:, None] * self._z / np.where(size > 0, size,
                                                                    1.0)[:, None]
        cell = self._keys % n_cells
        field = np.stack([np.bincount(cell, amplitude[:, c].real, minlength=n_cells)
                          + 1j * np.bincount(cell, amplitude[:, c].imag,
                                             minlength=n_cells)
                          for c in range(amplitude.shape[1])], axis=1)
        if self._points is not None:
            field = field + self._points if len(self._keys) else self._points
        gain = np.sum(np.abs(field) ** 2, axis=1).reshape(self.power.shape)
        return gain + self.power_only


def _beside_the_device(runtime) -> int:
    """Threads for rounds that each cast on the device and then weigh on the host: two
    (one's numpy beside the other's cast) where the device takes calls from two threads at
    once (:attr:`Runtime.concurrent_calls`), else one."""
    return 2 if runtime.concurrent_calls else 1


def _cosine_directions(normals, rng, frame=None) -> np.ndarray:
    """One unit direction per row, cosine-weighted over the hemisphere about ``normals``
    (R, 3) unit (Malley's method: a uniform point of the unit disc lifted onto it);
    ``frame`` the tangents (u, v) of :func:`_tangents` where the normals' are known."""
    r = np.sqrt(rng.random(len(normals)))
    phi = 2.0 * np.pi * rng.random(len(normals))
    a, b = r * np.cos(phi), r * np.sin(phi)
    c = np.sqrt(np.maximum(1.0 - r * r, 0.0))
    u, v = _tangents(normals) if frame is None else frame
    return a[:, None] * u + b[:, None] * v + c[:, None] * normals


def _tangents(normals) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents (u, v) (R, 3) completing unit ``normals`` to right-handed frames."""
    u = perpendicular(normals)
    return u, np.cross(normals, u)


def _te_tm(k, n):
    """TE (k x n, normalised) and TM (te x k) unit vectors (R, 3) of directions k at a
    surface of normal n (any perpendicular TE along the normal)."""
    te = np.cross(k, n)
    size = np.linalg.norm(te, axis=1)
    along = size < 1e-9
    te = np.where(along[:, None], perpendicular(n), te / np.where(along, 1.0, size)[:, None])
    return te, np.cross(te, k)


def _scatter(scene, geom, slab, org, dirs, field, t, prim, normals, receiver, scale,
             settings, rng, sums: CellSums) -> None:
    """Diffuse rays from the hits ``prim`` of rays (org, dirs, field) on faces whose
    material scatters (S > 0), accumulated into the layer: the tracer's Lambertian tile
    model (:mod:`clradcom.mechanisms.scattering`) sampled. A tube of power P (its
    (lambda/4 pi)^2 |E|^2 dOmega) scatters S^2 Gamma^2 P into the hemisphere with the
    density cos(theta_s)/pi, Gamma the power-weighted Fresnel magnitude of the arriving
    polarisation; ``diffuse_rays`` directions drawn from that density carry equal shares.
    The polarisation: the co-polar part R0 E (TE/TM of the incidence onto those of the
    scattered direction, -I at normal incidence) with 1 - K of the power, the
    cross-polar s x R0 E with K (the material's cross-polarisation share); the tracer's
    random phases between them average out in the power."""
    mat = np.asarray(scene.tri_material)[prim]
    s_coef = scene.material_scattering[mat]
    keep = s_coef > 0
    if not keep.any():
        return
    org, dirs, field, t, prim, mat = (a[keep] for a in (org, dirs, field, t, prim, mat))
    s_coef = s_coef[keep]
    n = normals[prim]
    n = np.where((np.einsum("ij,ij->i", dirs, n) > 0)[:, None], -n, n)  # the lit side
    point = org + t[:, None] * dirs
    cos_i = np.abs(np.einsum("ij,ij->i", dirs, n))
    r_te, r_tm = fresnel_coefficients(scene.material_eps_r[mat], cos_i,
                                      scene.material_pec[mat])
    te_i, tm_i = _te_tm(dirs, n)
    e_te = np.einsum("ij,ij->i", te_i, field)
    e_tm = np.einsum("ij,ij->i", tm_i, field)
    p_in = np.abs(e_te) ** 2 + np.abs(e_tm) ** 2
    gamma2 = (np.abs(r_te * e_te) ** 2 + np.abs(r_tm * e_tm) ** 2) / np.where(
        p_in > 0, p_in, 1.0)
    share = scene.material_cross_pol_share[mat]
    m = settings.diffuse_rays
    frame = _tangents(n)  # the same normals for every diffuse ray
    # the random directions drawn here in the serial order, the rounds two at a time on
    # the host's threads (one's numpy beside the other's cast) where the device takes
    # calls from two threads at once, added in their order
    rounds = [_cosine_directions(n, rng, frame) for _ in range(m)]

    def diffuse(out):
        origins = spawn_origins(point, n, out)
        lengths = geom.caster.closest_hit(pack_rays(origins, out))["t"].astype(np.float64)
        near = _reaches(slab, origins, out, lengths)
        if not near.any():
            return None
        # the polarisation only of the rays that reach the layer
        te_s, tm_s = _te_tm(out[near], n[near])
        co = -e_te[near, None] * te_s + e_tm[near, None] * tm_s  # R0 E
        cross = np.cross(out[near], co)
        both = _received(np.stack([co, cross]), out[near], receiver)
        received = (1.0 - share[near]) * both[0] + share[near] * both[1]
        weights = scale * (s_coef[near] ** 2 * gamma2[near] / m) * received
        return origins[near], out[near], lengths[near], weights

    for got in map_in_order(diffuse, rounds, threads=_beside_the_device(geom.runtime)):
        if got is not None:
            sums.add(*got)


def _edge_samples(wedges, step: float):
    """(wedge index, point, length) of every piece of ``step`` or less the wedges are cut
    into, each piece's middle point."""
    pieces = np.maximum(1, np.ceil(wedges.length / step).astype(np.int64))
    w = np.repeat(np.arange(len(wedges)), pieces)
    first = np.cumsum(pieces) - pieces
    frac = (np.arange(len(w)) - first[w] + 0.5) / pieces[w]
    points = wedges.start[w] + frac[:, None] * (wedges.end[w] - wedges.start[w])
    return w, points, wedges.length[w] / pieces[w]


def _diffract(scene, geom, slab, wedges, tx: Radar, receiver, scale, settings,
              sums: CellSums) -> None:
    """First-order UTD diffraction into the layer (:attr:`MapSettings.diffraction`).

    Each edge piece Q of length dl that the transmitter sees (a cast from tx to a point 1 mm
    off the edge toward it) and that lies outside its wedge sends rays on its Keller cone
    (s . e = s' . e = cos beta0) every dphi of the exterior angle (0, n pi). A ray carries
    the field D E_i(Q) (the tracer's dyad: :func:`clradcom.physics.utd.diffraction_dyad`
    of :func:`~clradcom.physics.utd.diffraction_coefficients`, E_i = E_tx / s') and the
    tube power |D E_i|^2 sin^2(beta0) dphi dl: the diffracted power density
    |D E_i|^2 rho / (s (rho + s)) (rho = s', the spherical-incidence spreading of
    :func:`~clradcom.physics.utd.spreading_factor`) times the tube's cross-section
    s sin(beta0) dphi x dl sin(beta0) (rho + s) / rho, constant along the ray, so its
    track length in a cell is weighed as a launched ray's is. The distance parameter L of
    the transition functions is taken where the ray meets the layer (the middle of its
    run inside the slab's box)."""
    w, q, dl = _edge_samples(wedges, settings.edge_step_m)
    tx_pos = np.asarray(tx.position, dtype=np.float64)
    to_q = q - tx_pos
    s_p = np.linalg.norm(to_q, axis=1)
    k_in = to_q / s_p[:, None]
    e = wedges.direction[w]
    n0 = wedges.normal0[w]
    t0 = np.cross(n0, e)
    cos_b = np.einsum("ij,ij->i", k_in, e)
    sin_b = np.sqrt(np.maximum(1.0 - cos_b**2, 0.0))
    # the source side: phi' inside the wedge's exterior (0, n pi), not along the edge
    phi_p = np.mod(np.arctan2(-np.einsum("ij,ij->i", k_in, n0),
                              -np.einsum("ij,ij->i", k_in, t0)), 2.0 * np.pi)
    n_w = wedges.n[w]
    lit = (sin_b > 1e-3) & (phi_p > 1e-6) & (phi_p < n_w * np.pi - 1e-6)
    c_tx = np.zeros((len(q), 2), dtype=np.complex128)
    rot = np.asarray(tx.orientation, dtype=np.float64)
    c_tx[lit] = tx.pattern.field(_rotate(k_in[lit], rot))
    lit &= np.abs(c_tx).sum(axis=1) > 0
    # sight: tx to a point 1 mm off the edge toward tx (off the wedge's own faces)
    away = -k_in + cos_b[:, None] * e
    away /= np.maximum(np.linalg.norm(away, axis=1), 1e-12)[:, None]
    target = q + 1e-3 * away
    idx = np.flatnonzero(lit)
    if len(idx):
        rays = pack_rays(np.broadcast_to(tx_pos, (len(idx), 3)), target[idx] - tx_pos, tmax=1.0)
        lit[idx[geom.caster.occluded(rays)]] = False
    idx = np.flatnonzero(lit)
    if not len(idx):
        return
    th, ph = _basis(k_in[idx], rot)
    e_inc = (c_tx[idx, :1] * th + c_tx[idx, 1:] * ph) / s_p[idx, None]
    k = 2.0 * np.pi / scene.wavelength_m
    step = np.deg2rad(settings.cone_step_deg)
    # pieces per round: at most a batch of rays (n <= 2: 2 pi / step rays a piece), so the
    # memory bound of map_memory_bytes holds
    chunk = max(1, settings.batch // int(np.ceil(2.0 * np.pi / step)))

    def cone_rays(start):
        """The segments of the chunk's cone rays that reach the layer, with their weights
        and wave; None where none does."""
        part = idx[start:start + chunk]
        ei = e_inc[start:start + chunk]
        n_phi = np.maximum(1, np.ceil(n_w[part] * np.pi / step).astype(np.int64))
        rows = np.repeat(np.arange(len(part)), n_phi)
        first = np.cumsum(n_phi) - n_phi
        dphi = n_w[part] * np.pi / n_phi
        phi = (np.arange(len(rows)) - first[rows] + 0.5) * dphi[rows]
        j = part[rows]
        cb, sb, cos_phi, sin_phi = cos_b[j], sin_b[j], np.cos(phi), np.sin(phi)
        # the ray's z first (the cone rays' third column, the same operations): one
        # that cannot turn toward the layer is not made
        rise = cb * e[j, 2] + sb * (cos_phi * t0[j, 2] + sin_phi * n0[j, 2])
        can = _may_turn_to(slab, q[j, 2], rise)
        rows, j, phi, cb, sb, cos_phi, sin_phi = (
            a[can] for a in (rows, j, phi, cb, sb, cos_phi, sin_phi))
        along = cb[:, None] * e[j]
        out = along + sb[:, None] * (cos_phi[:, None] * t0[j] + sin_phi[:, None] * n0[j])
        out /= np.linalg.norm(out, axis=1)[:, None]
        radial = out - along
        radial /= np.linalg.norm(radial, axis=1)[:, None]
        origins = q[j] + 1e-3 * radial
        may = _may_reach_unblocked(slab, origins, out)
        if not may.any():
            return None
        rows, j, out, origins, phi = (a[may] for a in (rows, j, out, origins, phi))
        lengths = geom.caster.closest_hit(pack_rays(origins, out))["t"].astype(np.float64)
        near = _reaches(slab, origins, out, lengths)
        if not near.any():
            return None
        rows, j, out, origins, lengths, phi = (a[near] for a in (rows, j, out, origins,
                                                                 lengths, phi))
        # the distance parameter where the ray runs through the layer
        s_mid = _layer_distance(slab, origins, out, lengths)
        m0, m1 = wedges.material0[w[j]], wedges.material1[w[j]]
        d_soft, d_hard = utd.diffraction_coefficients(
            phi, phi_p[j], np.arccos(np.clip(cos_b[j], -1.0, 1.0)), n_w[j], k,
            utd.distance_parameter(s_mid, s_p[j], np.arccos(np.clip(cos_b[j], -1, 1))),
            eps_r_0=scene.material_eps_r[m0], eps_r_n=scene.material_eps_r[m1],
            pec=scene.material_pec[m0] & scene.material_pec[m1])
        basis = utd.edge_fixed_basis(k_in[j], out, e[j])
        dyad = utd.diffraction_dyad(d_soft, d_hard, *basis)
        field = np.einsum("rij,rj->ri", dyad, ei[rows])
        polar = _projection(field, out, receiver)
        weights = (scale * sin_b[j] ** 2 * dphi[rows] * dl[j]
                   * np.sum(np.abs(polar) ** 2, axis=1))
        wedge = w[j]
        return origins, out, lengths, weights, Wave(
            polar=polar, group=np.stack([np.ones_like(wedge), wedge], axis=1),
            path_length=lambda rows, points, wedge=wedge: _edge_path_length(
                tx_pos, wedges.start[wedge[rows]], wedges.direction[wedge[rows]],
                points))

    # two chunks at a time on the host's threads where the device takes calls from two
    # threads at once (one's numpy beside the other's cast, which takes the caster's
    # lock), their sums added here in the chunks' order
    for got in map_in_order(cone_rays, range(0, len(idx), chunk),
                            threads=_beside_the_device(geom.runtime)):
        if got is not None:
            sums.add(*got)


def _may_turn_to(slab: Slab, z, rise) -> np.ndarray:
    """(R,) bool: rays from edge points at height ``z`` whose direction has the z
    component ``rise`` (of any length: its sign is the unit vector's) that may reach
    the slab's box as :func:`_reaches` grows it; a ray from above the box that does not
    go down, or from below it that does not go up, cannot (its origin is at most 1 mm
    from the edge point). It drops 61 % of the street's 870,921 cone rays."""
    above = z - 2e-3 > slab.z_hi + 1e-3
    below = z + 2e-3 < slab.z_lo - 1e-3
    return ~((above & (rise >= 0.0)) | (below & (rise <= 0.0)))


def _may_reach_unblocked(slab: Slab, origins, directions) -> np.ndarray:
    """:func:`_reaches` of rays of unbounded length: those that the layer's box is not
    even in front of need no cast (the test is monotone in the length, so the cast ones
    reach it as before; the street: 88,322 more of its cone rays, 71 % not cast in all)."""
    return _reaches(slab, origins, directions, np.full(len(origins), np.inf))


#: The device's receiver test (kernels/maps_po.cl) is grown by this much (rad of azimuth,
#: and in the arrival's components) so that its rounding never drops a pair the host's
#: exact pattern test keeps.
SECTOR_MARGIN = 1e-5

#: Facet-cell pairs a launch of the PO stage considers: the device holds nothing per
#: pair (they are made from the work item's index), only the ones that pass.
PO_PAIRS_PER_LAUNCH = 1 << 22


@dataclass
class _LitFacets:
    """The facets of the PO objects lit from the transmitter and what their pairs need:
    triangle ids, vertices (F, 3, 3), lit-side unit normals, centroids, the
    transmitter's field at them (F, 3) complex, PEC flags and materials, longest edges
    and distances from the transmitter."""

    tri: np.ndarray
    v: np.ndarray
    normal: np.ndarray
    centroid: np.ndarray
    e_tx: np.ndarray
    pec: np.ndarray
    material: np.ndarray
    size: np.ndarray
    from_tx: np.ndarray


def _lit_facets(scene, geom, tx: Radar, objects) -> _LitFacets | None:
    """The facets of ``objects`` lit from tx: front side (or either side of a two-sided
    object, its normal turned to tx), inside tx's pattern, the centroid seeing tx
    (surface_sees); None where none is."""
    tri = np.flatnonzero(np.isin(scene.tri_object, objects))
    if not len(tri):
        return None
    v = np.asarray(scene.triangles)[tri]
    normal = triangle_normals(v)
    centroid = v.mean(axis=1)
    tx_pos = np.asarray(tx.position, dtype=np.float64)
    side = np.einsum("ij,ij->i", normal, tx_pos - centroid)
    two_sided = np.asarray(scene.tri_two_sided)[tri]
    normal = np.where((two_sided & (side < 0))[:, None], -normal, normal)
    lit = (side > 0) | (two_sided & (side < 0))
    to_facet = centroid - tx_pos
    k_dep = to_facet / np.linalg.norm(to_facet, axis=1)[:, None]
    rot = np.asarray(tx.orientation, dtype=np.float64)
    c_tx = np.asarray(tx.pattern.field(_rotate(k_dep, rot)), dtype=np.complex128)
    lit &= np.abs(c_tx).sum(axis=1) > 0
    idx = np.flatnonzero(lit)
    if len(idx):
        lit[idx[~surface_sees(geom.caster, centroid[idx], normal[idx], tx_pos, tri[idx],
                              tri_face=geom.faces.tri_face, engine=geom.engine)]] = False
    keep = np.flatnonzero(lit)
    if not len(keep):
        return None
    tri, v, normal, centroid, k_dep, c_tx = (a[keep] for a in (tri, v, normal, centroid,
                                                               k_dep, c_tx))
    th, ph = _basis(k_dep, rot)
    material = np.asarray(scene.tri_material)[tri]
    return _LitFacets(
        tri=tri, v=v, normal=normal, centroid=centroid,
        e_tx=c_tx[:, :1] * th + c_tx[:, 1:] * ph, material=material,
        pec=np.asarray(scene.material_pec)[material],
        size=np.sqrt(np.max(np.sum((v - v[:, [1, 2, 0]]) ** 2, axis=-1), axis=1)),
        from_tx=np.linalg.norm(centroid - tx_pos, axis=1))


def _po_facets(scene, geom, grid: MapGrid, tx: Radar, receiver, objects, settings,
               sums: CellSums) -> None:
    """The PO facet returns of ``objects`` at every cell centre: the tracer's
    :func:`clradcom.mechanisms.physical_optics.po_paths` with a receiver at each centre.
    A facet lit from tx (front side, or either side of a two-sided object; inside tx's
    pattern; its centroid seeing tx) radiates to the centres on its lit side that its
    centroid sees, E = (lambda / 4 pi) T e_tx e^{-jkL} / L with T of
    :func:`clradcom.physics.po.po_transfer` (PEC current, or a penetrable material's
    Fresnel-weighted currents), received as the map's receiver takes a field. Pairs
    with the centre in a facet's near zone (closer than 2 D) are split into far-field
    pieces as the tracer's default ``split="near"`` does. The tracer's floor (facets
    80 dB under the link's strongest dropped) is not applied: such terms add nothing
    visible to a power. ``po_engine="device"``: the pairs found and the PEC fields
    evaluated in one launch per round (:func:`_po_pairs_device`); "host": the
    pair-wise float64 reference (:func:`_po_pairs`)."""
    lit = _lit_facets(scene, geom, tx, objects)
    if lit is None:
        return
    tx_pos = np.asarray(tx.position, dtype=np.float64)
    if settings.po_engine == "host":
        pairs = _po_pairs(scene, geom, grid, tx_pos, receiver, lit, settings, engine=None)
    else:
        pairs = _po_pairs_device(scene, geom, grid, tx_pos, receiver, lit, settings)
    for _, cell, amplitude in pairs:
        sums.add_at_centres(cell, amplitude)


def _po_pairs(scene, geom, grid: MapGrid, tx_pos, receiver, lit: _LitFacets, settings,
              engine=None):
    """The pair-wise PO stage, the reference of :func:`_po_pairs_device`: per round of
    facets the host lists every facet-cell pair on the lit side, drops the arrivals
    outside the receiver's pattern, casts one sight ray per pair and weighs the fields
    of those that see each other (the PEC ones on ``engine``'s device when given). Yields
    ``(facet, cell, amplitude)`` per round: int64 rows of ``lit`` and cell indices in
    ascending (facet, cell) order, and the receiver's complex amplitudes (P, C)."""
    centres = grid.centres().reshape(-1, 3)
    n_cells = len(centres)
    per_round = max(1, settings.po_batch // n_cells)
    offset = np.einsum("ij,ij->i", lit.normal, lit.centroid)
    rx_rot = None if receiver is None else np.asarray(receiver.orientation, np.float64)
    for start in range(0, len(lit.tri), per_round):
        block = slice(start, min(start + per_round, len(lit.tri)))
        # the centres on each facet's lit side: n . centre > n . centroid
        front = np.einsum("ij,kj->ik", lit.normal[block], centres) > offset[block, None]
        f, cell = np.nonzero(front)
        if not len(f):
            continue
        f += start
        toward = centres[cell] - lit.centroid[f]
        to_centre = np.linalg.norm(toward, axis=1)
        if receiver is not None:
            # arrivals outside the receiver's pattern take nothing (po_paths drops them):
            # no sight ray, no field (a 90-degree sector keeps a quarter of the pairs)
            arrival = toward / to_centre[:, None]
            seen = np.asarray(receiver.pattern.gain(_rotate(-arrival, rx_rot))) > 0
            f, cell, toward, to_centre = f[seen], cell[seen], toward[seen], to_centre[seen]
            if not len(f):
                continue
        # one float32 sight ray per pair: a cell centre stands in free space, not on a
        # face, so the tracer's float64 confirmation of an antenna's last millimetres
        # (surface_sees) decides nothing here and costs 20x the cast
        origin = spawn_origins(lit.centroid[f], lit.normal[f], toward)
        sees = ~geom.caster.occluded(pack_rays(origin, centres[cell] - origin,
                                           tmax=1.0 - 1e-6), ignore_prim=lit.tri[f])
        f, cell = f[sees], cell[sees]
        if not len(f):
            continue
        yield f, cell, _po_amplitudes(scene, grid, tx_pos, receiver, lit, f, cell,
                                      to_centre[sees], engine)


def _po_pairs_device(scene, geom, grid: MapGrid, tx_pos, receiver, lit: _LitFacets,
                     settings):
    """:func:`_po_pairs` with the pairs made, tested and the PEC fields weighed on the
    device, one launch each (:func:`clradcom.device.maps.po_pairs`: lit side,
    the receiver's sector grown by :data:`SECTOR_MARGIN`, the sight cast, the field);
    the host then keeps the exact pattern test, adds the carrier phase in float64 and
    takes the receive projection of the pairs that passed, and weighs the near-zone
    and penetrable ones itself. The same pairs and amplitudes, in the same order."""
    centres = grid.centres().reshape(-1, 3)
    corner = np.array([grid.x_min, grid.y_min, grid.height_m])
    k = 2.0 * np.pi / scene.wavelength_m
    rx_rot = None if receiver is None else np.asarray(receiver.orientation, np.float64)
    # the sight rays leave the centroids as spawn_origins pushes them toward a point on
    # the lit side (the same for every centre the front test keeps)
    origins = spawn_origins(lit.centroid, lit.normal, lit.normal)
    rounds = po_pairs(
        geom.caster, corner, k, tx_pos, lit.v, lit.centroid, lit.normal, lit.e_tx, origins,
        NEAR_SIZE_FACTOR * lit.size, lit.from_tx, lit.tri, lit.pec, centres,
        rx_rotation=rx_rot,
        rx_bounds=None if receiver is None else _support_bounds(receiver.pattern),
        capacity=settings.po_batch, pairs_per_launch=PO_PAIRS_PER_LAUNCH)
    lam = scene.wavelength_m
    # the next launch runs on the device while the host weighs this one's pairs (where the
    # device takes calls from two threads at once)
    if geom.runtime.concurrent_calls:
        rounds = prefetch(rounds)
    for f, cell, whole, field in rounds:
        toward = centres[cell] - lit.centroid[f]
        to_centre = np.linalg.norm(toward, axis=1)   # the reference's rounding of L
        arrival = toward / to_centre[:, None]
        pattern = None
        if receiver is not None:
            # the pattern itself (the device's test only bounds its support): |C|^2 = G
            local, c = _rx_pattern(arrival, receiver)
            seen = np.flatnonzero(np.sum(c.real ** 2 + c.imag ** 2, axis=1) > 0)
            if len(seen) < len(f):
                f, cell, whole, field, arrival, to_centre, local, c = (
                    a[seen] for a in (f, cell, whole, field, arrival, to_centre, local, c))
            pattern = (local, c)
        if not len(f):
            continue
        # the carrier phase of the float64 lengths, then the receive projection (the
        # rows the device left to the host are overwritten below)
        amplitude = _pec_received(field, lit.from_tx[f], to_centre, arrival, receiver, k,
                                  lam, pattern)
        rest = np.flatnonzero(~whole)
        if len(rest):
            amplitude[rest] = _po_amplitudes(scene, grid, tx_pos, receiver, lit, f[rest],
                                             cell[rest], to_centre[rest], geom.runtime)
        yield f, cell, amplitude


def _support_bounds(pattern) -> np.ndarray:
    """(cos of the half azimuth width, largest |z|, least x) of the unit directions in
    the antenna's frame where ``pattern`` may have gain (its ``support_box``), each
    widened by :data:`SECTOR_MARGIN`."""
    half_azimuth, z_max, x_min = pattern.support_box()
    return np.array([math.cos(min(half_azimuth + SECTOR_MARGIN, np.pi)),
                     z_max + SECTOR_MARGIN, x_min - SECTOR_MARGIN])


def _po_amplitudes(scene, grid: MapGrid, tx_pos, receiver, lit: _LitFacets, f, cell,
                   to_centre, engine) -> np.ndarray:
    """The receiver's amplitudes (P, C) of facet-cell pairs (rows ``f`` of ``lit``, cells
    ``cell``, ``to_centre`` their distances) that see each other: pairs with tx or the
    centre in a facet's near zone (po.py's rule "near") split into far-field pieces,
    each pair its own, summed back per pair as fields, as po_paths does; the others
    whole (the PEC fields on ``engine``'s device when given)."""
    centres = grid.centres().reshape(-1, 3)
    corner = np.array([grid.x_min, grid.y_min, grid.height_m])
    k = 2.0 * np.pi / scene.wavelength_m
    lam = scene.wavelength_m
    near = np.minimum(to_centre, lit.from_tx[f]) < NEAR_SIZE_FACTOR * lit.size[f]
    amplitude = np.empty((len(f), 1 if receiver is not None else 3), np.complex128)
    whole = np.flatnonzero(~near)
    if len(whole):
        rows = f[whole]
        amplitude[whole] = _po_received(
            scene, lit.v[rows], lit.normal[rows], lit.pec[rows], lit.material[rows],
            tx_pos, centres[cell[whole]], lit.e_tx[rows], receiver, k, lam,
            runtime=engine, corner=corner, centroid=lit.centroid[rows])
    split = np.flatnonzero(near)
    if len(split):
        pieces, parent = _near_zone_pieces(lit.v[f[split]], tx_pos, centres[cell[split]])
        rows = f[split][parent]
        each = _po_received(scene, pieces, lit.normal[rows], lit.pec[rows],
                            lit.material[rows], tx_pos, centres[cell[split]][parent],
                            lit.e_tx[rows], receiver, k, lam, runtime=engine, corner=corner)
        amplitude[split] = np.stack(
            [np.bincount(parent, each[:, c].real, minlength=len(split))
             + 1j * np.bincount(parent, each[:, c].imag, minlength=len(split))
             for c in range(each.shape[1])], axis=1)
    return amplitude


def _near_zone_pieces(v, source, points) -> tuple[np.ndarray, np.ndarray]:
    """(pieces (P, 3, 3), parent (P,)): facet-point pairs (v (S, 3, 3), points (S, 3))
    cut into midpoint quarters until neither ``source`` nor the pair's point lies in a
    piece's near zone (closer than NEAR_SIZE_FACTOR times its longest edge), at most
    MAX_SUBDIVISION_LEVELS times: :func:`clradcom.physics.po.far_field_pieces`' rule
    "near" with each pair's own antennas, so one call serves every cell."""
    parent = np.arange(len(v))
    done_v, done_p = [], []
    for level in range(MAX_SUBDIVISION_LEVELS + 1):
        size = np.sqrt(np.max(np.sum((v - v[:, [1, 2, 0]]) ** 2, axis=-1), axis=1))
        centre = v.mean(axis=1)
        reach = np.minimum(np.linalg.norm(centre - source, axis=1),
                           np.linalg.norm(centre - points[parent], axis=1))
        ok = reach >= NEAR_SIZE_FACTOR * size
        if level == MAX_SUBDIVISION_LEVELS or ok.all():
            done_v.append(v)
            done_p.append(parent)
            break
        done_v.append(v[ok])
        done_p.append(parent[ok])
        split = v[~ok]
        mids = 0.5 * (split + split[:, [1, 2, 0]])  # m01, m12, m20
        v = np.stack([np.stack([split[:, 0], mids[:, 0], mids[:, 2]], axis=1),
                      np.stack([mids[:, 0], split[:, 1], mids[:, 1]], axis=1),
                      np.stack([mids[:, 2], mids[:, 1], split[:, 2]], axis=1),
                      mids], axis=1).reshape(-1, 3, 3)
        parent = np.repeat(parent[~ok], 4)
    return np.concatenate(done_v), np.concatenate(done_p)


def _po_received(scene, v, normal, pec, material, tx_pos, points, e_tx, receiver, k,
                 lam, runtime=None, corner=None, centroid=None) -> np.ndarray:
    """The receiver's amplitude (S, C) of PO facets (or pieces) ``v`` lit by tx's field
    ``e_tx`` at ``points``: the PEC rows with the PEC current, the others with their
    material's reflection dyad (:func:`~clradcom.physics.em.material_reflection_dyad`),
    as :mod:`clradcom.mechanisms.physical_optics` takes them. With a ``runtime`` the
    PEC rows' fields are the device's (:func:`clradcom.device.maps.po_facet_fields`,
    positions relative to ``corner``; ``centroid`` (S, 3) the facets' own, when known);
    without, the host's float64 reference."""
    amplitude = None
    for rows, metal in ((np.flatnonzero(pec), True), (np.flatnonzero(~pec), False)):
        if not len(rows):
            continue
        if metal and runtime is not None:
            # the PEC facets on the device, the carrier phase of the float64 length here
            mid = v[rows].mean(axis=1) if centroid is None else centroid[rows]
            field = po_facet_fields(runtime, corner, v[rows], normal[rows], e_tx[rows],
                                    tx_pos, points[rows], k, centroids=mid)
            to_point = points[rows] - mid
            r_r = np.linalg.norm(to_point, axis=1)
            p = _pec_received(field, np.linalg.norm(mid - tx_pos, axis=1), r_r,
                              to_point / r_r[:, None], receiver, k, lam)
        else:
            reflection = None if metal else (
                lambda k_in, n, m=material[rows]: material_reflection_dyad(scene, m, k_in,
                                                                           n))
            T, L, _, _, k_arr = po_transfer(v[rows], normal[rows], tx_pos, points[rows],
                                            scene.carrier_hz, reflection)
            field = (np.einsum("rij,rj->ri", T, e_tx[rows])
                     * (lam / (4.0 * np.pi) * np.exp(-1j * k * L) / L)[:, None])
            p = _projection(field, k_arr, receiver)
        if amplitude is None:
            amplitude = np.zeros((len(v), p.shape[1]), dtype=np.complex128)
        amplitude[rows] = p
    return amplitude


@dataclass
class _Optics:
    """A map's physical optics as the tracer chooses it per object: ``po_objects`` (PO
    facets for the first bounce), ``sbr_objects`` (SBR-PO for the later ones) and the
    transmitter's SBR ``windows`` (None unless its SBR footprints are asked for:
    MapSettings(sbr="footprints"))."""

    po_objects: np.ndarray
    sbr_objects: np.ndarray
    windows: sbr.TubeWindows | None

    def radiated(self, launch: _Launch, rotation, rays) -> np.ndarray:
        """Which lattice ``rays`` (indices) leave the transmitter along a direction the
        SBR tubes were shot in (:func:`clradcom.mechanisms.sbr.launched`): their exit
        segments off an SBR object after a second or later bounce are the footprint
        stage's (:func:`_sbr_footprints`), the others stay GO, as in the tracer
        (optics.replaced_paths)."""
        rays = np.asarray(rays, dtype=np.int64)
        if self.windows is None or not len(rays):
            return np.zeros(len(rays), dtype=bool)
        return sbr.launched(self.windows, _rotate(launch.local[rays], rotation.T))


def _optics_of(scene, geom, tx: Radar, settings: MapSettings) -> _Optics:
    modes = np.array(object_optics(scene, settings.optics))
    po_objects = np.flatnonzero(modes != "go")
    sbr_objects = np.flatnonzero(modes == "po")
    windows = None
    if (settings.sbr == "footprints" and len(sbr_objects) and settings.max_reflections >= 2
            and geom.caster is not None):
        windows = sbr.blocks_in_pattern(sbr.launch_windows(
            geom, tx.position, sbr_objects,
            sbr.object_spacing_m(geom, sbr_objects, settings.sbr_spacing_wavelengths),
            tx_name=tx.name), tx)
    return _Optics(po_objects=po_objects, sbr_objects=sbr_objects, windows=windows)


@dataclass
class _Footprints:
    """SBR-PO footprints (H rows) and what their radiation needs: ``point``, lit-side
    ``normal``, incidence ``k_in``, unfolded ``length`` from tx, the footprint's two
    projected edges ``edge1``/``edge2`` (H, 3) and ``area``; the current vectors ``a``,
    ``b`` (H, 3) complex of the field 0.5 [(I - s s^T) a + s x b] it radiates per
    unit of the PO integral; ``group`` (H,) its sequence of planar faces; ``triangle``."""

    point: np.ndarray
    normal: np.ndarray
    k_in: np.ndarray
    length: np.ndarray
    edge1: np.ndarray
    edge2: np.ndarray
    area: np.ndarray
    a: np.ndarray
    b: np.ndarray
    group: np.ndarray
    triangle: np.ndarray


def _footprints(scene, geom, tx: Radar, optics: _Optics, max_bounces: int) -> _Footprints | None:
    """The footprints of tx's SBR tubes (the tracer's windows, :func:`sbr.shoot_tubes`) at
    their second and later bounces on SBR objects, each with the currents the tube's
    field drives there (the tracer's :func:`sbr._radiate`, docs/po.md: the PEC current,
    or a penetrable facet's Fresnel-weighted electric and magnetic currents)."""
    windows = optics.windows
    if windows is None or windows.n_tubes == 0:
        return None
    tubes, owned = sbr.window_tubes(windows, np.arange(windows.n_tubes))
    keep = np.flatnonzero(owned)
    tubes = sbr.TubeGrid(directions=tubes.directions[keep],
                         solid_angle=tubes.solid_angle[keep], edge1=tubes.edge1[keep],
                         edge2=tubes.edge2[keep])
    hits = sbr.shoot_tubes(geom, tx.position, tubes, max_bounces, 2,
                           np.isin(scene.tri_object, optics.sbr_objects))
    if not len(hits.tube):
        return None
    rot = np.asarray(tx.orientation, dtype=np.float64)
    k0 = tubes.directions[hits.tube]
    c_tx = np.asarray(tx.pattern.field(_rotate(k0, rot)), dtype=np.complex128)
    th, ph = _basis(k0, rot)
    e_tx = c_tx[:, :1] * th + c_tx[:, 1:] * ph
    e_in = np.einsum("hij,hj->hi", hits.chain, e_tx)
    n, k_in = hits.normal, hits.k_in
    edge1, edge2, area = sbr.footprint_shape(hits, tubes)
    a, b = po_currents(n, k_in, e_in)
    material = np.asarray(scene.tri_material)[hits.triangle]
    pen = np.flatnonzero(~np.asarray(scene.material_pec)[material])
    if len(pen):
        a[pen], b[pen] = po_currents(n[pen], k_in[pen], e_in[pen], material_reflection_dyad(
            scene, material[pen], k_in[pen], n[pen]))
    face = np.where(hits.tri_history >= 0,
                    geom.faces.tri_face[np.maximum(hits.tri_history, 0)], -1)
    return _Footprints(point=hits.point, normal=n, k_in=k_in, length=hits.length,
                       edge1=edge1, edge2=edge2, area=area, a=a, b=b,
                       group=sbr.face_groups(face), triangle=hits.triangle)


def _sbr_footprints(scene, geom, grid: MapGrid, tx: Radar, receiver, optics: _Optics,
                    settings, sums: CellSums) -> None:
    """SBR-PO's later bounces at every cell centre: each footprint's PO integral
    (docs/po.md, "Multi-bounce"), the footprints of one sequence of planar faces summed
    as fields (one path of the tracer's), the sequences in power. A sequence radiates
    to the centres on its face's lit side (inside its lobe, :func:`_lobe_cells`, where
    ``sbr_lobe_widths`` is a number), each footprint to those it sees."""
    fp = _footprints(scene, geom, tx, optics, settings.max_reflections)
    if fp is None:
        return
    centres = grid.centres().reshape(-1, 3)
    k = 2.0 * np.pi / scene.wavelength_m
    lam = scene.wavelength_m
    order = np.argsort(fp.group, kind="stable")
    starts = np.searchsorted(fp.group[order], np.arange(fp.group.max() + 2))
    members = [order[starts[g]:starts[g + 1]] for g in range(len(starts) - 1)]
    group_cells = _lobe_cells(fp, members, centres, lam, settings.sbr_lobe_widths)
    rx_rot = None if receiver is None else np.asarray(receiver.orientation, np.float64)
    pair_g = np.repeat(np.arange(len(group_cells)), [len(c) for c in group_cells])
    if not len(pair_g):
        return
    pair_c = np.concatenate(group_cells)
    size = np.array([len(m) for m in members])
    # the footprint-cell terms a few at a time, summed per pair
    per_pair = size[pair_g]
    ends = np.cumsum(per_pair)
    limit = max(1, settings.po_batch * FOOTPRINT_TERMS_PER_PO_PAIR)
    start = 0
    while start < len(pair_g):
        stop = int(np.searchsorted(ends, (ends[start - 1] if start else 0) + limit,
                                   side="right"))
        stop = max(stop, start + 1)
        rows = np.arange(start, stop)
        counts = per_pair[rows]
        pair = np.repeat(rows, counts)
        foot = np.concatenate([members[g] for g in pair_g[rows]])
        points = centres[pair_c[pair]]
        if receiver is not None:
            # arrivals outside the receiver's pattern take nothing: no sight ray
            toward = points - fp.point[foot]
            arrival = toward / np.linalg.norm(toward, axis=1)[:, None]
            seen = np.asarray(receiver.pattern.gain(_rotate(-arrival, rx_rot))) > 0
            pair, foot, points = pair[seen], foot[seen], points[seen]
        # each footprint's own sight line, as the tracer's (a float32 cast: a centre
        # stands in free space, see _po_pairs)
        origin = spawn_origins(fp.point[foot], fp.normal[foot], points - fp.point[foot])
        sees = np.flatnonzero(~geom.caster.occluded(
            pack_rays(origin, points - origin, tmax=1.0 - 1e-6),
            ignore_prim=fp.triangle[foot]))
        amplitude = _footprint_amplitudes(fp, foot[sees], points[sees], receiver, k, lam)
        pair = pair[sees]
        summed = np.stack([np.bincount(pair - start, amplitude[:, c].real,
                                       minlength=len(rows))
                           + 1j * np.bincount(pair - start, amplitude[:, c].imag,
                                              minlength=len(rows))
                           for c in range(amplitude.shape[1])], axis=1)
        sums.add_at_centres(pair_c[rows], summed)
        start = stop


def _lobe_cells(fp: _Footprints, members, centres, lam: float,
                widths: float | None) -> list:
    """Per face sequence, the cells its footprints may radiate into: those on its face's
    lit side and, where ``widths`` is a number, inside the cone from its image source
    (each footprint's point less its unfolded length along its mirror direction) around
    the mean mirror direction, as wide as the footprints' own spread plus ``widths``
    times lambda over the sequence's size (its aperture's, or one footprint's where
    larger): its beam, diffraction-widened ``widths`` lobes each side."""
    out = []
    norm2 = np.einsum("ij,ij->i", centres, centres)
    for m in members:
        n0 = fp.normal[m[0]]
        inside = centres @ n0 > float(np.max(fp.point[m] @ n0))
        if widths is not None:
            inside &= _in_beam(fp, m, centres, norm2, lam, widths)
        out.append(np.flatnonzero(inside))
    return out


def _in_beam(fp: _Footprints, m, centres, norm2, lam: float, widths: float) -> np.ndarray:
    """Whether each centre lies in the beam of the face sequence of footprints ``m``
    (:func:`_lobe_cells`); ``norm2`` the centres' squared norms."""
    kn = np.einsum("ij,ij->i", fp.k_in[m], fp.normal[m])
    mirror = fp.k_in[m] - 2.0 * kn[:, None] * fp.normal[m]
    axis = mirror.mean(axis=0)
    axis /= np.linalg.norm(axis)
    apex = (fp.point[m] - fp.length[m, None] * mirror).mean(axis=0)
    spread = float(np.arccos(np.clip(mirror @ axis, -1.0, 1.0)).max())
    extent = fp.point[m].max(axis=0) - fp.point[m].min(axis=0)
    size = max(float(np.linalg.norm(extent)), float(np.sqrt(np.max(fp.area[m]))))
    half = min(spread + widths * lam / size, 0.5 * np.pi)
    along = centres @ axis - apex @ axis
    dist = np.sqrt(np.maximum(norm2 - 2.0 * (centres @ apex) + apex @ apex, 0.0))
    return along >= np.cos(half) * dist


def _footprint_amplitudes(fp: _Footprints, foot, points, receiver, k: float,
                          lam: float) -> np.ndarray:
    """The receiver's amplitude (S, C) of footprints ``foot`` (S,) at ``points`` (S, 3):
    (lambda / 4 pi) (-j k / 2 pi) I_fp e^{-jk(L_in + R)} / (L_in R) times the field
    0.5 [(I - s s^T) a + s x b], I_fp the footprint's parallelogram integral
    |e1' x e2'| sinc(q.e1'/2) sinc(q.e2'/2), q = k (s - k_in) (docs/po.md)."""
    toward = points - fp.point[foot]
    r = np.linalg.norm(toward, axis=1)
    s = toward / r[:, None]
    i_fp = sbr.footprint_integral(k * (s - fp.k_in[foot]), fp.edge1[foot], fp.edge2[foot],
                                  fp.area[foot])
    a, b = fp.a[foot], fp.b[foot]
    field = 0.5 * (a - s * np.einsum("ij,ij->i", s, a)[:, None] + np.cross(s, b))
    length = fp.length[foot]
    scale = (lam / (4.0 * np.pi) * (-1j * k / (2.0 * np.pi)) * i_fp
             * np.exp(-1j * k * (length + r)) / (length * r))
    return _projection(field * scale[:, None], s, receiver)


def _rays_host(scene, geom, slab, transmitter, receiver, launch, scale, optics: _Optics,
               settings, rng, sums: CellSums, steps) -> None:
    """The rays stage in numpy (``MapSettings(engine="host")``, and coherent maps): each
    batch's rays cast bounce by bounce on the device, their fields reflected, projected
    and accumulated here in float64 (docs/maps.md); the reference of
    :func:`_rays_device`."""
    local = launch.local
    rot = np.asarray(transmitter.orientation, dtype=np.float64)
    origin = np.asarray(transmitter.position, dtype=np.float64)
    normals = geom.caster.normals64() if geom.caster is not None else None
    corners = geom.caster.triangles[:, 0] if geom.caster is not None else None
    tri_material = np.asarray(scene.tri_material)
    tri_object = np.asarray(scene.tri_object)
    n_batches = -(-len(local) // settings.batch)
    for b, start in enumerate(range(0, len(local), settings.batch)):
        if steps is not None:
            steps(b, n_batches)
        loc = local[start:start + settings.batch]
        dirs = _rotate(loc, rot.T)
        ray = np.arange(start, start + len(loc))
        c = launch.field[start:start + settings.batch]
        th, ph = _basis(dirs, rot)
        field = c[:, :1] * th + c[:, 1:] * ph
        org = np.broadcast_to(origin, dirs.shape).copy()
        # every segment's wavefront is a sphere about its image source: the transmitter
        # mirrored in the planes of the faces it reflected off (float64, from the faces'
        # own corners, so the hit points' float32 rounding does not enter)
        image = org.copy() if settings.coherent else None
        last_prim = np.full(len(dirs), -1)
        for order in range(settings.max_reflections + 1):
            if geom.caster is not None and len(dirs):
                hits = geom.caster.closest_hit(pack_rays(org, dirs))
                t = hits["t"].astype(np.float64)
                prim = hits["prim"]
            else:
                t = np.full(len(dirs), np.inf)
                prim = np.full(len(dirs), -1)
            if order > 0 or settings.line_of_sight:
                near = _reaches(slab, org, dirs, t)
                if order == 1 and len(optics.po_objects):
                    near &= ~np.isin(tri_object[last_prim], optics.po_objects)
                if order >= 2 and optics.windows is not None:
                    exits = np.flatnonzero(near & np.isin(tri_object[last_prim],
                                                          optics.sbr_objects))
                    near[exits[optics.radiated(launch, rot, ray[exits])]] = False
                polar = _projection(field[near], dirs[near], receiver)
                weights = scale * np.sum(np.abs(polar) ** 2, axis=1)
                wave = None
                if settings.coherent:
                    src = image[near]
                    quantised = np.round(src / IMAGE_SOURCE_TOLERANCE_M).astype(np.int64)
                    group = np.column_stack([np.zeros(len(src), np.int64),
                                             np.full(len(src), order), quantised])
                    wave = Wave(polar=polar, group=group,
                                path_length=lambda rows, points, src=src: np.linalg.norm(
                                    points - src[rows], axis=1))
                sums.add(org[near], dirs[near], t[near], weights, wave)
            hit = prim >= 0
            if settings.scattering and order <= settings.scattering_reflections \
                    and hit.any():
                _scatter(scene, geom, slab, org[hit], dirs[hit], field[hit], t[hit],
                         prim[hit], normals, receiver, scale, settings, rng, sums)
            if order == settings.max_reflections or not hit.any():
                break
            # one index array for the five takes: a boolean mask is scanned once each
            hit = np.flatnonzero(hit)
            org, dirs, field, t, prim, ray = (a[hit] for a in (org, dirs, field, t, prim,
                                                               ray))
            if settings.coherent:
                image = image[hit]
            last_prim = prim
            n = normals[prim]
            point = org + t[:, None] * dirs
            field = reflected_fields(scene, tri_material[prim], dirs, n, field)
            if settings.coherent:
                image = image - 2.0 * np.einsum("ij,ij->i", image - corners[prim],
                                                n)[:, None] * n
            dirs = dirs - 2.0 * np.einsum("ij,ij->i", dirs, n)[:, None] * n
            dirs /= np.linalg.norm(dirs, axis=1)[:, None]
            org = spawn_origins(point, n, dirs)


def _rays_device(scene, geom, slab, transmitter, receiver, launch, scale, optics: _Optics,
                 settings, rng, sums: CellSums, steps) -> None:
    """The rays stage on the device (``MapSettings(engine="device")``): one launch a batch
    walks every ray through its bounces (:func:`clradcom.device.map_walk.walk_rays`);
    the host projects the segments that reach the slab onto the receiver, accumulates
    them and starts the diffuse rays at the scattering hits, in the order
    :func:`_rays_host` does."""
    caster = geom.caster
    rt = caster.runtime
    tri_object = np.asarray(scene.tri_object)
    normals = caster.normals64()
    tables = WalkTables.of(rt, scene, normals, np.isin(tri_object, optics.po_objects),
                           None if optics.windows is None
                           else np.isin(tri_object, optics.sbr_objects))
    rot = np.asarray(transmitter.orientation, dtype=np.float64)
    scatter_orders = settings.scattering_reflections if settings.scattering else -1
    device_lattice = launch.on(rt)
    rx_frame = None if receiver is None else receiver.orientation
    rx_pattern = None if receiver is None else receiver.pattern
    n = len(launch.local)
    n_batches = -(-n // settings.batch)
    # the lists' room: three segments and a quarter of a hit a ray at first, then a
    # quarter more than the fullest batch so far (a batch that outgrows it runs again)
    room = (3 * settings.batch, settings.batch // 4 + 64)
    workspace: dict = {}
    for b, start in enumerate(range(0, n, settings.batch)):
        if steps is not None:
            steps(b, n_batches)
        count = min(settings.batch, n - start)
        # the slab's box grown by _reaches' 1 mm: the accumulation's float32 clipping
        # never sees a segment this skipped
        segments, hits = walk_rays(
            caster, device_lattice, tables, transmitter.orientation, transmitter.position,
            slab, 1e-3, 2.0 * np.pi / scene.wavelength_m, start, count,
            settings.max_reflections, settings.line_of_sight, scatter_orders,
            rx_frame=rx_frame, capacity=room, workspace=workspace)
        room = (max(room[0], segments.count * 5 // 4), max(room[1], len(hits.ray) * 5 // 4))
        weights = scale * receive_weights(segments, rx_pattern)
        if optics.windows is not None:
            ray = segments.exit_ray
            exits = np.flatnonzero(ray >= 0)
            weights[exits[optics.radiated(launch, rot, ray[exits])]] = 0.0
        accumulate_rows(rt, slab, segments.org, segments.dir, segments.count, weights,
                        sums.power_only, sums.count, sums.square)
        for order in np.unique(hits.order):
            rows = np.flatnonzero(hits.order == order)
            _scatter(scene, geom, slab, hits.origins[rows], hits.directions[rows],
                     hits.fields[rows], hits.lengths[rows], hits.prim[rows], normals,
                     receiver, scale, settings, rng, sums)


@dataclass
class _Launch:
    """A transmit pattern's launch lattice (:func:`launch_lattice`): ``local`` (N, 3)
    directions, ``solid_angle`` per ray, ``field`` (N, 2) the pattern's (C_theta, C_phi)
    at them, and its device copies per runtime."""

    local: np.ndarray
    solid_angle: float
    field: np.ndarray
    device: dict

    def on(self, runtime) -> LaunchLattice:
        key = id(runtime)
        if key not in self.device:
            self.device[key] = LaunchLattice(self.local, self.field, runtime)
        return self.device[key]


#: the last few launch lattices, by ray count and pattern (as the tracer keeps its own:
#: mechanisms.specular._lattice_of): the lattice of 2e6 rays of a sector and its field
#: took 0.75 s of each map of the street (0.4 s since it is made a piece at a time)
_LAUNCHES: dict = {}


def _launch_of(n_rays: int, pattern) -> _Launch:
    key = (int(n_rays), json.dumps(pattern.params(), sort_keys=True))
    if key not in _LAUNCHES:
        if len(_LAUNCHES) >= 2:
            _LAUNCHES.pop(next(iter(_LAUNCHES)))
        local, solid_angle, field, codes = _cap_with_field(n_rays, pattern)
        # in coherent order (geometry.ray_order: along a Morton curve of the directions'
        # octahedral map): a work-group's rays leave in a narrow cone and meet the same
        # nodes and faces; the device walk of the street's 2e6 rays took 40 % less time.
        # (the codes are per row, so this is coherent_order(local); one take of each
        # array, not fancy indexing: 3x faster; on the host's threads)
        order = np.argsort(codes, kind="stable")
        local, field = take_rows(local, order), take_rows(field, order)
        for a in (local, field):
            a.flags.writeable = False
        _LAUNCHES[key] = _Launch(local, solid_angle, field, {})
    return _LAUNCHES[key]


def _pec_received(field, r_t, r_r, arrival, receiver, k, lam, pattern=None) -> np.ndarray:
    """The receiver's amplitudes (S, C) of the device's PEC facet fields ``field`` (S, 3)
    (:func:`clradcom.device.maps.po_facet_fields`: without the carrier phase) at float64
    lengths ``r_t`` from tx to the facet and ``r_r`` on to the point:
    (lambda / 4 pi) e^{-jk(r_t + r_r)} times the field, taken by the receiver along the
    unit ``arrival`` direction (``pattern``: as :func:`_projection` takes it)."""
    field = field * (lam / (4.0 * np.pi) * np.exp(-1j * k * (r_t + r_r)))[:, None]
    return _projection(field, arrival, receiver, pattern)


def _edge_path_length(source, start, direction, points) -> np.ndarray:
    """The shortest length (m) from ``source`` (3,) via the infinite line through
    ``start`` along unit ``direction`` (R, 3) to ``points`` (R, 3): the unfolded length of
    the diffracted ray through each point (Keller's law puts its edge point where the two
    legs make equal angles with the edge), sqrt((b - a)^2 + (r_1 + r_2)^2) with a, b the
    positions of source and point along the edge and r_1, r_2 their distances from it."""
    to_source = source - start
    to_point = points - start
    a = np.einsum("ij,ij->i", to_source, direction)
    b = np.einsum("ij,ij->i", to_point, direction)
    r1 = np.linalg.norm(to_source - a[:, None] * direction, axis=1)
    r2 = np.linalg.norm(to_point - b[:, None] * direction, axis=1)
    return np.hypot(b - a, r1 + r2)


def _layer_distance(slab: Slab, origins, directions, lengths) -> np.ndarray:
    """The distance along each ray to the middle of its run inside the slab's box
    (clipped as :func:`_reaches` clips), at least 1 mm."""
    t0 = np.zeros(len(origins))
    t1 = np.minimum(lengths, 1e30)
    lo = (slab.x0, slab.y0, slab.z_lo)
    hi = (slab.x0 + slab.nx * slab.cell_x, slab.y0 + slab.ny * slab.cell_y, slab.z_hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(3):
            o, d = origins[:, axis], directions[:, axis]
            flat = d == 0
            a, b = (lo[axis] - o) / d, (hi[axis] - o) / d
            t0 = np.where(flat, t0, np.maximum(t0, np.minimum(a, b)))
            t1 = np.where(flat, t1, np.minimum(t1, np.maximum(a, b)))
    return np.maximum(0.5 * (t0 + np.maximum(t1, t0)), 1e-3)


def find_radar(scene: Scene, which, argument: str) -> Radar | None:
    """The radar ``which`` of ``scene`` (its name, index or the Radar itself; None stays
    None), refused naming ``argument`` and the scene's radars."""
    if which is None:
        return None
    if isinstance(which, Radar):
        return which
    if isinstance(which, str):
        names = [r.name for r in scene.radars]
        if which not in names:
            raise ArgumentError(f"is no radar of scene {scene.name!r} (radars: "
                                f"{', '.join(names)})", argument=argument, value=which)
        return scene.radars[names.index(which)]
    if isinstance(which, int) and not isinstance(which, bool) and \
            0 <= which < len(scene.radars):
        return scene.radars[which]
    raise ArgumentTypeError("must be a radar's name, index or Radar", argument=argument,
                            value=which)


def radio_map(scene: Scene, tx, grid: MapGrid, rx=None, settings: MapSettings | None = None,
              runtime: Runtime | None = None, geometry: Geometry | None = None,
              steps: Callable[[int, int], None] | None = None,
              budget_bytes: float | None = None) -> RadioMap:
    """The mean path gain of every cell of ``grid`` from transmitter ``tx`` (a radar of
    ``scene``: name, index or Radar) to a receiver ``rx`` placed in the cell with the
    pattern, orientation and polarisation of that radar (None: gain 1 and every
    polarisation, the power density times lambda^2 / 4 pi). ``steps(done, total)``
    hears each batch of rays; the run is refused before it starts where its memory
    (:func:`map_memory_bytes`) exceeds the budget."""
    if not isinstance(scene, Scene):
        raise ArgumentTypeError("must be a Scene (clradcom.scene.load_scene)",
                                argument="scene", value=scene)
    if not isinstance(grid, MapGrid):
        raise ArgumentTypeError("must be a MapGrid", argument="grid", value=grid)
    settings = MapSettings() if settings is None else settings
    if not isinstance(settings, MapSettings):
        raise ArgumentTypeError("must be a MapSettings", argument="settings", value=settings)
    transmitter = find_radar(scene, tx, "tx")
    receiver = find_radar(scene, rx, "rx")
    need = map_memory_bytes(settings, grid)
    check_memory(need, what=f"a radio map of {grid.n_cells} cells with {settings.rays} rays "
                            f"in batches of {settings.batch}",
                 argument="rays", value=settings.rays,
                 advice="launch fewer rays, use smaller batches or fewer cells",
                 budget_bytes=budget_bytes)
    geom = geometry or build_geometry(scene, runtime)
    rt = geom.runtime
    slab = grid.slab()
    lam = C0 / float(scene.carrier_hz)
    clock = time.perf_counter()
    launch = _launch_of(settings.rays, transmitter.pattern)
    lattice_seconds = time.perf_counter() - clock
    scale = (lam / (4.0 * np.pi)) ** 2 * launch.solid_angle / slab.cell_volume
    sums = CellSums(rt, grid, 2.0 * np.pi / lam, settings.coherent)
    # physical optics as the tracer chooses it (optics.replaced_paths): an object with PO
    # facets gives no GO single reflection; one with SBR-PO no GO exit segment after a
    # later bounce where its tubes were shot (their footprints radiate instead)
    optics = _optics_of(scene, geom, transmitter, settings)
    po_objects = optics.po_objects
    n_batches = -(-len(launch.local) // settings.batch)
    rng = np.random.default_rng(settings.seed)
    clock = time.perf_counter()
    seconds: dict[str, float] = {"launch lattice": lattice_seconds}
    on_device = (settings.engine == "device" and not settings.coherent
                 and geom.caster is not None)
    walk = _rays_device if on_device else _rays_host
    walk(scene, geom, slab, transmitter, receiver, launch, scale, optics, settings, rng,
         sums, steps)
    seconds["rays"] = time.perf_counter() - clock
    if len(po_objects) and geom.caster is not None:
        clock = time.perf_counter()
        _po_facets(scene, geom, grid, transmitter, receiver, po_objects, settings, sums)
        seconds["physical optics"] = time.perf_counter() - clock
    if optics.windows is not None:
        clock = time.perf_counter()
        _sbr_footprints(scene, geom, grid, transmitter, receiver, optics, settings, sums)
        seconds["sbr"] = time.perf_counter() - clock
    clock = time.perf_counter()
    if settings.diffraction and geom.caster is not None:
        wedges = diffraction.prepare(geom, DiffractionSettings(max_diffractions=1),
                                     po_objects)
        if wedges is not None and len(wedges):
            _diffract(scene, geom, slab, wedges, transmitter, receiver,
                      scale / launch.solid_angle,
                      settings, sums)
    if steps is not None:
        steps(n_batches, n_batches)
    seconds["diffraction"] = time.perf_counter() - clock
    clock = time.perf_counter()
    incoherent = sums.incoherent()
    gain = sums.coherent_gain() if settings.coherent else incoherent
    seconds["coherent sum"] = time.perf_counter() - clock
    return RadioMap(grid=grid, gain=gain, count=sums.count, square=sums.square,
                    tx_name=transmitter.name,
                    rx_name=None if receiver is None else receiver.name,
                    rays=len(launch.local),
                    tx_power_w=float(transmitter.tx_power_w), coherent=settings.coherent,
                    incoherent_gain=incoherent if settings.coherent else None,
                    group_count=sums.group_count() if settings.coherent else None,
                    stage_seconds=seconds)
