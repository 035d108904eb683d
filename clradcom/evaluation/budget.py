"""Accuracy budget: the radar's noise floor as a power bound, pruning, cheapest settings.

docs/tradeoff.md gives the reasoning; in short:

* The radar frame measures F = D_r/D on N·M cells with thermal noise σ² = kTBF/P_tx per
  cell (the project's convention, :func:`clradcom.radar.add_thermal_noise`). The range and
  Doppler transforms add a path's NM cells coherently and the noise incoherently, so a
  path of gain a stands |a|²·G_p/σ² above the noise of its image cell, G_p the
  processing gain (NM for rectangular windows, less for tapered ones). A path with
  |a|² < σ²/G_p (the *noise floor* :func:`noise_floor`, optionally shifted by a margin)
  stays under the noise after processing.
* Best case of a k-fold specular path (:func:`order_bounds`): GO spreading over the
  shortest length such a path can have, both antennas' peak directivity, the largest
  reflection magnitude of the scene's materials to the k-th power. An order whose best
  case lies below the floor need never be traced.
* A scattering triangle's tiles together carry at most
  λ² S² A G_t G_r / (16 π³ r_i² r_s²)
  (:func:`clradcom.mechanisms.scattering.scattering_triangle_bounds`); a triangle below the
  floor need never be tiled.
* Paths found below the floor are dropped before synthesis (:func:`prune_paths`), unless
  the weak paths of their range-Doppler cell add up above it (the tiles of one tree).
* :func:`choose_settings` picks the cheapest record of a sweep (tools/tradeoff.py) that
  meets an accuracy target, or says why none does.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.evaluation.accuracy import path_kind
from clradcom.geometry.triangles import point_triangle_distance
from clradcom.paths import select_paths
from clradcom.physics import em
from clradcom.radar.processing import get_window
from clradcom.radar.synthesis import thermal_noise_power
from clradcom.radar.waveform import Waveform
from clradcom.scene.antenna import pattern_peak_gain

__all__ = [
    "AccuracyTarget",
    "BudgetChoice",
    "NoiseFloor",
    "OrderBound",
    "PruneReport",
    "choose_settings",
    "max_path_length",
    "min_gamma_product",
    "noise_floor",
    "order_bounds",
    "processing_gain",
    "prune_paths",
    "radar_cells",
    "read_records",
    "relative_threshold_db",
    "scene_gamma_max",
    "shortest_path_length",
]


def _positive(name, v) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float | np.floating | np.integer):
        raise ArgumentError(f"{name} must be a positive number, got {v!r}")
    x = float(v)
    if not (math.isfinite(x) and x > 0):
        raise ArgumentError(f"{name} must be positive and finite, got {v!r}")
    return x


def _finite(name, v) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float | np.floating | np.integer):
        raise ArgumentError(f"{name} must be a finite number, got {v!r}")
    x = float(v)
    if not math.isfinite(x):
        raise ArgumentError(f"{name} must be finite, got {v!r}")
    return x


# ----------------------------------------------------------------------------------------
# the noise floor
# ----------------------------------------------------------------------------------------
def processing_gain(n_subcarriers: int, n_symbols: int, window_range="hann",
                    window_doppler="hann") -> float:
    """SNR gain of the range/Doppler transforms for one point target.

    G_p = (Σw_n)²/Σw_n² · (Σw_μ)²/Σw_μ²: N·M for rectangular windows, about
    (2/3)²·N·M (−3.5 dB) for Hann. Windows as :func:`clradcom.radar.get_window`.
    """
    out = 1.0
    for name, length, win in (("n_subcarriers", n_subcarriers, window_range),
                              ("n_symbols", n_symbols, window_doppler)):
        if isinstance(length, bool) or not isinstance(length, int | np.integer) or length < 1:
            raise ArgumentError(f"{name} must be a positive integer, got {length!r}")
        w = get_window(win, int(length))
        out *= float(np.sum(w)) ** 2 / float(np.sum(w**2))
    return out


@dataclass(frozen=True)
class NoiseFloor:
    """The weakest path gain a radar frame can lift above its thermal noise."""

    noise_variance: float  #: σ² per cell of F = D_r/D, in the units of |a|²
    processing_gain: float  #: G_p of the range/Doppler transforms
    margin_db: float  #: floor = σ²/G_p · 10^(margin/10)

    @property
    def power(self) -> float:
        """|a|² of a path that reaches exactly the floor (0 dB SNR + margin in its cell)."""
        return self.noise_variance / self.processing_gain * 10.0 ** (self.margin_db / 10.0)

    @property
    def power_db(self) -> float:
        return 10.0 * math.log10(self.power)

    @property
    def amplitude(self) -> float:
        return math.sqrt(self.power)


def noise_floor(waveform: Waveform, tx_power_w: float, noise_figure_db: float, *,
                margin_db: float = 0.0, window_range="hann", window_doppler="hann",
                temperature_k: float = 290.0) -> NoiseFloor:
    """Noise floor of a radar frame in path-gain units (|a|²).

    σ² = k·T·B·F / P_tx per cell (B the waveform's bandwidth), exactly what
    :func:`clradcom.radar.add_thermal_noise` adds; the floor is σ²/G_p shifted by
    ``margin_db`` (negative: keep paths that far below the noise too).
    """
    if not isinstance(waveform, Waveform):
        raise ArgumentError(f"waveform must be a clradcom.radar.Waveform, got {type(waveform)!r}")
    p_tx = _positive("tx_power_w", tx_power_w)
    nf = _finite("noise_figure_db", noise_figure_db)
    margin = _finite("margin_db", margin_db)
    var = thermal_noise_power(waveform.bandwidth, nf, _positive("temperature_k",
                                                                temperature_k)) / p_tx
    gp = processing_gain(waveform.n_subcarriers, waveform.n_symbols, window_range,
                         window_doppler)
    return NoiseFloor(noise_variance=var, processing_gain=gp, margin_db=margin)


# ----------------------------------------------------------------------------------------
# best-case bounds
# ----------------------------------------------------------------------------------------
def _free_space_power(wavelength_m, length_m, g_tx, g_rx):
    return (wavelength_m / (4.0 * math.pi * length_m)) ** 2 * g_tx * g_rx


def max_path_length(floor_power: float, wavelength_m: float, gamma_product: float = 1.0,
                    g_tx: float = 1.0, g_rx: float = 1.0) -> float:
    """Longest unfolded path length L whose GO gain |a|² = (λ/4πL)² G_t G_r |ΠΓ|² still
    reaches ``floor_power``; 0 when ``gamma_product`` is 0."""
    p = _positive("floor_power", floor_power)
    lam = _positive("wavelength_m", wavelength_m)
    g = _finite("gamma_product", gamma_product)
    if not 0.0 <= g <= 1.0:
        raise ArgumentError(f"gamma_product must lie in [0, 1], got {gamma_product!r}")
    amp = lam / (4.0 * math.pi) * math.sqrt(_positive("g_tx", g_tx) * _positive("g_rx", g_rx))
    return amp * g / math.sqrt(p)


def min_gamma_product(floor_power: float, wavelength_m: float, length_m: float,
                      g_tx: float = 1.0, g_rx: float = 1.0) -> float:
    """Smallest product of reflection magnitudes |ΠΓ| that a GO path of unfolded length
    ``length_m`` needs to reach ``floor_power`` (> 1: no such path can)."""
    p = _positive("floor_power", floor_power)
    fs = _free_space_power(_positive("wavelength_m", wavelength_m),
                           _positive("length_m", length_m), _positive("g_tx", g_tx),
                           _positive("g_rx", g_rx))
    return math.sqrt(p / fs)


def scene_gamma_max(scene, n_angles: int = 181) -> float:
    """Largest reflection magnitude any material of the scene can give a specular path.

    max over the materials on the scene's triangles and over incidence angles (grazing
    included) of max(|r_TE|, |r_TM|)·√(1 − S²) (the specular share left by diffuse
    scattering). Roughness only lowers it and is left out. Every dielectric reaches
    |Γ| → 1 at grazing, so this is 1 unless every material scatters: the bound is honest,
    and loose.
    """
    used = np.unique(np.asarray(scene.tri_material))
    if used.size == 0:
        return 0.0
    cos = np.linspace(0.0, 1.0, n_angles)
    best = 0.0
    for m in used:
        r_te, r_tm = em.fresnel_coefficients(np.full(cos.shape, scene.material_eps_r[m]), cos,
                                             np.full(cos.shape, bool(scene.material_pec[m])))
        g = float(max(np.abs(r_te).max(), np.abs(r_tm).max()))
        s = float(scene.material_scattering[m])
        best = max(best, min(g, 1.0) * math.sqrt(max(0.0, 1.0 - s * s)))
    return best


def shortest_path_length(scene, tx_position, rx_position, order: int) -> float:
    """Lower bound on the unfolded length of a path with ``order`` interactions.

    Order 0: |tx − rx|. Order ≥ 1: the path must touch a surface, so it is at least
    d(tx, scene) + d(rx, scene) (distances to the nearest triangle) and at least |tx − rx|.
    """
    if isinstance(order, bool) or not isinstance(order, int | np.integer) or order < 0:
        raise ArgumentError(f"order must be an integer >= 0, got {order!r}")
    tx = np.asarray(tx_position, dtype=np.float64)
    rx = np.asarray(rx_position, dtype=np.float64)
    direct = float(np.linalg.norm(rx - tx))
    if order == 0 or len(scene.triangles) == 0:
        return direct
    d = float(point_triangle_distance(tx, scene.triangles).min()
              + point_triangle_distance(rx, scene.triangles).min())
    return max(direct, d)


@dataclass(frozen=True)
class OrderBound:
    """Best case of the k-fold specular paths of one link."""

    order: int
    min_length_m: float
    gamma_max: float
    best_power: float  #: |a|² upper bound
    floor_power: float

    @property
    def above_floor(self) -> bool:
        return self.best_power >= self.floor_power

    @property
    def headroom_db(self) -> float:
        """How far the best case lies above (+) or below (−) the floor, dB."""
        if self.best_power == 0:
            return -math.inf
        return 10.0 * math.log10(self.best_power / self.floor_power)


def order_bounds(scene, tx, rx, floor_power: float, max_order: int, *,
                 gamma_max: float | None = None) -> list[OrderBound]:
    """Best-case |a|² of the specular paths of each order 0..max_order of a link.

    |a|² ≤ (λ / 4π L_min,k)² · G_tx,max · G_rx,max · Γ_max^{2k}, with L_min,k from
    :func:`shortest_path_length` and Γ_max from :func:`scene_gamma_max` (or the caller's
    ``gamma_max``). Flat facets do not focus, so GO spreading over the unfolded length is
    the most a specular path can keep.
    """
    p = _positive("floor_power", floor_power)
    if isinstance(max_order, bool) or not isinstance(max_order, int | np.integer) \
            or max_order < 0:
        raise ArgumentError(f"max_order must be an integer >= 0, got {max_order!r}")
    gmax = scene_gamma_max(scene) if gamma_max is None else _finite("gamma_max", gamma_max)
    if not 0.0 <= gmax <= 1.0:
        raise ArgumentError(f"gamma_max must lie in [0, 1], got {gamma_max!r}")
    g_tx, g_rx = pattern_peak_gain(tx.pattern), pattern_peak_gain(rx.pattern)
    lam = scene.wavelength_m
    out = []
    for k in range(int(max_order) + 1):
        L = shortest_path_length(scene, tx.position, rx.position, k)
        best = 0.0 if L == 0 else _free_space_power(lam, L, g_tx, g_rx) * gmax ** (2 * k)
        if L == 0:  # coincident tx/rx: the line of sight is not a path, nothing bounds k>=1
            best = 0.0 if k == 0 else math.inf
        out.append(OrderBound(order=k, min_length_m=L, gamma_max=gmax, best_power=best,
                              floor_power=p))
    return out


def max_useful_order(bounds: list[OrderBound]) -> int:
    """Largest order whose best case reaches the floor (−1: none does). Γ_max ≤ 1 and the
    shortest length does not shrink with k, so every order above it is below too."""
    above = [b.order for b in bounds if b.above_floor]
    return max(above, default=-1)


def relative_threshold_db(floor_power: float, strongest_power: float) -> float:
    """The relative threshold (dB below the strongest path, as
    :func:`clradcom.mechanisms.scattering.scattering_paths` takes it) that equals an absolute floor.

    Use an upper bound of the strongest path (e.g. the largest of
    :func:`scattering_triangle_bounds`) before tracing: the threshold then keeps every
    path above the floor (and some below). 0 when the strongest is itself below it.
    """
    p = _positive("floor_power", floor_power)
    s = _positive("strongest_power", strongest_power)
    return max(0.0, 10.0 * math.log10(s / p))


# ----------------------------------------------------------------------------------------
# pruning found paths
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PruneReport:
    """What :func:`prune_paths` dropped."""

    n_in: int
    n_kept: int
    dropped_by_kind: dict = field(default_factory=dict)  #: reflection/diffraction/scattering
    dropped_power: float = 0.0  #: Σ|a|² of the dropped paths
    strongest_dropped: float = 0.0  #: largest |a|² dropped
    kept_below_floor: int = 0  #: paths below the floor kept because their cell adds up

    @property
    def n_dropped(self) -> int:
        return self.n_in - self.n_kept

    def describe(self) -> str:
        kinds = ", ".join(f"{v} {k}" for k, v in sorted(self.dropped_by_kind.items()) if v)
        extra = (f"; {self.kept_below_floor} weak paths kept, their range-Doppler cells add "
                 "up above it" if self.kept_below_floor else "")
        return (f"{self.n_dropped} of {self.n_in} paths below the floor dropped"
                + (f" ({kinds})" if kinds else "") + extra)


def radar_cells(delays_s, dopplers_hz, waveform: Waveform) -> np.ndarray:
    """Range-Doppler cell of each path in the radar image (before zero padding):
    range bin round(τ·NΔf) mod N, Doppler bin round(f_D·M·T_sym) mod M, as one index."""
    n, m = waveform.n_subcarriers, waveform.n_symbols
    r = np.mod(np.rint(np.asarray(delays_s, float) * n * waveform.subcarrier_spacing_hz), n)
    d = np.mod(np.rint(np.asarray(dopplers_hz, float) * m * waveform.symbol_duration), m)
    return (r.astype(np.int64) * m + d.astype(np.int64))


def prune_paths(paths, floor_power: float, waveform: Waveform | None = None):
    """Drop paths whose contribution stays below ``floor_power``: ``(kept, PruneReport)``.

    Without ``waveform`` every path with |a|² < floor is dropped. Many such paths in one
    range-Doppler cell (the tiles of one tree) add up there, so with ``waveform`` a weak
    path is dropped only when all the weak paths of its cell (:func:`radar_cells`)
    together stay below the floor even added in phase: (Σ|a|)² < floor.
    """
    p = _finite("floor_power", floor_power)
    if p < 0:
        raise ArgumentError(f"floor_power must be >= 0, got {floor_power!r}")
    if waveform is not None and not isinstance(waveform, Waveform):
        raise ArgumentError(f"waveform must be a clradcom.radar.Waveform, got {type(waveform)!r}")
    gain = np.asarray(paths.gain)
    power = np.abs(gain) ** 2
    weak = power < p
    keep = ~weak
    kept_weak = 0
    if waveform is not None and weak.any():
        cell = radar_cells(np.asarray(paths.delay_s)[weak], np.asarray(paths.doppler_hz)[weak],
                           waveform)
        uniq, inv = np.unique(cell, return_inverse=True)
        amp_sum = np.bincount(inv, weights=np.abs(gain[weak]), minlength=len(uniq))
        loud = amp_sum[inv] ** 2 >= p
        keep[np.flatnonzero(weak)[loud]] = True
        kept_weak = int(loud.sum())
    kind = path_kind(paths.interaction)
    dropped = {k: int(np.sum((kind == k) & ~keep))
               for k in ("reflection", "diffraction", "scattering")}
    report = PruneReport(n_in=len(power), n_kept=int(keep.sum()), dropped_by_kind=dropped,
                         dropped_power=float(power[~keep].sum()),
                         strongest_dropped=float(power[~keep].max(initial=0.0)),
                         kept_below_floor=kept_weak)
    return select_paths(paths, keep), report


# ----------------------------------------------------------------------------------------
# choosing settings from a sweep
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AccuracyTarget:
    """What a setting must achieve; None leaves a criterion free.

    channel_nmse_db / error_to_noise_db / image_error_db: upper bounds (dB) on
    :func:`~clradcom.evaluation.accuracy.channel_nmse_db`,
    :func:`~clradcom.evaluation.accuracy.error_to_noise_db`,
    :func:`~clradcom.evaluation.accuracy.image_error_to_noise_db`;
    range_error_m / velocity_error_mps: at least ``min_targets_found`` moving targets
    detected (default: all of them) and every detected one within these;
    power_share / count_share: lower bounds on the path-set completeness (0..1).
    ``min_targets_found`` alone asks only for that many detections.
    """

    channel_nmse_db: float | None = None
    error_to_noise_db: float | None = None
    image_error_db: float | None = None
    range_error_m: float | None = None
    velocity_error_mps: float | None = None
    power_share: float | None = None
    count_share: float | None = None
    min_targets_found: int | None = None

    def __post_init__(self):
        for name in ("channel_nmse_db", "error_to_noise_db", "image_error_db"):
            v = getattr(self, name)
            if v is not None:
                _finite(name, v)
        m = self.min_targets_found
        if m is not None and (isinstance(m, bool) or not isinstance(m, int | np.integer)
                              or m < 0):
            raise ArgumentError(f"min_targets_found must be an integer >= 0, got {m!r}")
        for name in ("range_error_m", "velocity_error_mps"):
            v = getattr(self, name)
            if v is not None and _finite(name, v) < 0:
                raise ArgumentError(f"{name} must be >= 0, got {v!r}")
        for name in ("power_share", "count_share"):
            v = getattr(self, name)
            if v is not None and not 0.0 <= _finite(name, v) <= 1.0:
                raise ArgumentError(f"{name} must lie in [0, 1], got {v!r}")
        if all(getattr(self, n) is None for n in self.__dataclass_fields__):
            raise ArgumentError("an accuracy target needs at least one criterion")

    def shortfalls(self, record: dict) -> list[str]:
        """Why a sweep record misses this target (empty: it meets it)."""
        return [text for text, _ in self._misses(record)]

    def _misses(self, record: dict) -> list[tuple[str, float]]:
        """(why, how far: dB/10, share/0.1, a unit per missed target, error/limit)."""
        out = []

        def num(key):
            if key not in record:
                raise ArgumentError(f"sweep record has no {key!r} column (has "
                                 f"{sorted(record)})")
            try:
                return float(record[key])
            except (TypeError, ValueError):
                raise ArgumentError(f"sweep record's {key!r} is not a number: "
                                 f"{record[key]!r}") from None

        for key in ("channel_nmse_db", "error_to_noise_db", "image_error_db"):
            lim = getattr(self, key)
            if lim is not None:
                v = num(key)
                if not v <= lim:
                    out.append((f"{key} {v:.1f} > {lim:g}",
                                (v - lim) / 10.0 if math.isfinite(v) else math.inf))
        if (self.range_error_m is not None or self.velocity_error_mps is not None
                or self.min_targets_found is not None):
            found, total = num("targets_found"), num("targets")
            need = total if self.min_targets_found is None else self.min_targets_found
            if found < need:
                out.append((f"found {found:.0f} of {total:.0f} targets (need {need:.0f})",
                            need - found))
            for key, lim in (("range_error_m", self.range_error_m),
                             ("velocity_error_mps", self.velocity_error_mps)):
                if lim is not None and found >= need and found > 0:
                    v = num(key)
                    if not v <= lim:
                        out.append((f"{key} {v:.3f} > {lim:g}",
                                    v / lim if lim > 0 and math.isfinite(v) else math.inf))
        for key in ("power_share", "count_share"):
            lim = getattr(self, key)
            if lim is not None:
                v = num(key)
                if not v >= lim:
                    out.append((f"{key} {v:.3f} < {lim:g}",
                                (lim - v) / 0.1 if math.isfinite(v) else math.inf))
        return out


@dataclass(frozen=True)
class BudgetChoice:
    """The cheapest record meeting a target (``record`` None when none does)."""

    record: dict | None
    n_meeting: int
    message: str

    @property
    def ok(self) -> bool:
        return self.record is not None


def choose_settings(records, target: AccuracyTarget, cost_key: str = "seconds"
                    ) -> BudgetChoice:
    """Cheapest sweep record (by ``cost_key``) that meets ``target``.

    The cheapest record that meets a set of bounds is never dominated in cost and those
    criteria, so it lies on the sweep's Pareto front. When no record meets the target
    the message names the closest one (smallest summed shortfall: dB/10, share/0.1,
    one per missed target, error/limit; then cheapest) and what it misses.
    """
    records = list(records)
    if not isinstance(target, AccuracyTarget):
        raise ArgumentError(f"target must be an AccuracyTarget, got {type(target)!r}")
    if not records:
        return BudgetChoice(None, 0, "no sweep records to choose from")
    scored = []
    for i, r in enumerate(records):
        if cost_key not in r:
            raise ArgumentError(f"sweep record {i} has no {cost_key!r} column")
        cost = float(r[cost_key])
        if not math.isfinite(cost):
            raise ArgumentError(f"sweep record {i}: {cost_key} = {r[cost_key]!r} is not finite")
        scored.append((cost, i, target._misses(r)))
    meeting = [s for s in scored if not s[2]]
    if meeting:
        cost, i, _ = min(meeting)
        return BudgetChoice(records[i], len(meeting),
                            f"cheapest of {len(meeting)} settings meeting the target: "
                            f"{cost:.3g} {cost_key}")
    cost, i, miss = min(scored, key=lambda s: (sum(m for _, m in s[2]), s[0]))
    return BudgetChoice(None, 0, f"no setting of the {len(records)} in the sweep meets the "
                        f"target; closest (row {i}, {cost:.3g} {cost_key}) misses: "
                        + "; ".join(text for text, _ in miss))


def _parse(v: str):
    if v in ("True", "False"):
        return v == "True"
    for conv in (int, float):
        try:
            return conv(v)
        except ValueError:
            pass
    return v


def read_records(path) -> list[dict]:
    """Rows of a tools/tradeoff.py CSV as dicts, numbers and booleans parsed."""
    with open(path, newline="") as fh:
        return [{k: _parse(v) for k, v in row.items()} for row in csv.DictReader(fh)]
