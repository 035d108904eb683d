"""What the tools report about a radar's image: detection and truth tables, the static
returns at the radar's own speed, and the numbers of a two-radar interference run.

Plain functions of detections (``cfar.DETECTION_DTYPE``), radar images, the ground truth
of :mod:`clradcom.radar.truth` and the scene's records; tools/trace.py and
tools/interference.py print and write what they return.
"""

from __future__ import annotations

import math

import numpy as np

from clradcom.files import write_csv
from clradcom.radar.interference import InterferenceResult
from clradcom.radar.mixed_interference import MixedResult
from clradcom.radar.processing import RadarImage
from clradcom.radar.waveform import Waveform
from clradcom.scene.street import TABLE_III

__all__ = ["DETECTION_COLUMNS", "INTERFERENCE_IMAGES", "INTERFERENCE_TITLES", "STATIC_RANGE_M",
           "TRUTH_COLUMNS", "detection_rows", "display_range_db", "interference_detections",
           "interference_summary", "match_tolerances", "mixed_summary", "moving_objects",
           "paper_table_iii",
           "recovered_detections", "sorted_detections_line", "truth_table_lines",
           "scene_reach_m", "static_returns_beyond", "strongest_static_cell", "truth_rows",
           "write_table"]

#: The paper (Fig. 3): "object images at above 60 m are reflections from buildings along
#: the road, and they depict the velocity at which the radar is traveling".
STATIC_RANGE_M = 60.0

#: header of a detection table (:func:`detection_rows`); aliased: 1 where only a path
#: beyond the unambiguous range or velocity puts the detection there, folded
#: (:func:`clradcom.radar.pipeline.sort_detections`)
DETECTION_COLUMNS = ("range_m", "velocity_mps", "power_db", "snr_db", "aliased")
#: header of a truth table (:func:`truth_rows`)
TRUTH_COLUMNS = ("object", "range_centre_m", "range_nearest_m", "v_rel_mps",
                 "range_detected_m", "velocity_detected_mps")

#: the four images of a two-radar run, in the order they are shown
INTERFERENCE_IMAGES = ("clean", "interfered", "genie", "realistic")
INTERFERENCE_TITLES = {"clean": "A without D", "interfered": "A with D interfering",
                       "genie": "after cancelling D (genie)",
                       "realistic": "after cancelling D (realistic)"}


# ----------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------
def write_table(path, rows, header, *, inputs=()) -> None:
    """A CSV file: one header row, then the rows as they are; written atomically, never
    over a file in ``inputs`` (:func:`clradcom.files.write_csv`)."""
    write_csv(path, rows, header, inputs=inputs)


def detection_rows(detections, aliased=None) -> list[tuple[str, ...]]:
    """CFAR detections as text rows of :data:`DETECTION_COLUMNS` (mm, mm/s, 0.01 dB, and
    0/1 for ``aliased``, one bool per detection, none when not given)."""
    flags = np.zeros(len(detections), bool) if aliased is None else np.asarray(aliased, bool)
    return [(f"{d['range_m']:.3f}", f"{d['velocity_mps']:.3f}", f"{d['power_db']:.2f}",
             f"{d['snr_db']:.2f}", str(int(a))) for d, a in zip(detections, flags, strict=True)]


def sorted_detections_line(result) -> str:
    """One line on how a frame's detections were sorted against its paths
    (:class:`clradcom.radar.pipeline.FrameResult`): how many are aliased, and the noise
    false alarms beyond the longest path that were left out."""
    parts = []
    n_alias = int(np.count_nonzero(result.aliased))
    if n_alias:
        parts.append(f"{n_alias} aliased (a path beyond the unambiguous range or velocity, "
                     "shown folded)")
    if len(result.beyond):
        where = ", ".join(f"{d['range_m']:.1f} m / {d['velocity_mps']:+.1f} m/s"
                          for d in result.beyond[:4])
        parts.append(f"{len(result.beyond)} CFAR detection(s) beyond the longest path "
                     f"({result.longest_range_m:.1f} m) left out as noise: {where}")
    return "; ".join(parts)


def moving_objects(scene, radar) -> list[str]:
    """Names of the scene's moving objects other than the one the radar rides on: the
    targets whose ground truth the radar is checked against."""
    own = radar.rides_on
    return [o.name for i, o in enumerate(scene.objects)
            if i != own and np.any(np.asarray(o.velocity) != 0)]


def match_tolerances(waveform: Waveform) -> tuple[float, float]:
    """(range, velocity) tolerance of a detection matching a target: one range
    resolution cell plus 0.3 m (the echo starts before the target's centre), one velocity
    resolution cell."""
    return waveform.range_resolution + 0.3, waveform.velocity_resolution


def truth_rows(truth, matches) -> list[tuple[str, ...]]:
    """Text rows of :data:`TRUTH_COLUMNS`: each target's set range and relative velocity
    beside the detection that matches it (empty strings where none does)."""
    rows = []
    for t, m in zip(truth, matches, strict=True):
        rd = "" if m is None else f"{m['range_m']:.2f}"
        vd = "" if m is None else f"{m['velocity_mps']:.2f}"
        rows.append((t["name"], f"{t['range_centre_m']:.2f}", f"{t['range_nearest_m']:.2f}",
                     f"{t['v_rel_m_s']:.2f}", rd, vd))
    return rows


#: a target is the paper's car when its set range and closing speed along the road are
#: those of Table III within these (m, m/s): the same street, seen from radar A
PAPER_MATCH = (0.5, 0.5)


def paper_table_iii(radar_name: str, truth) -> list[dict | None]:
    """For each target of ``truth`` (:func:`clradcom.radar.truth.detection_truth`), the
    row of the paper's Table III (:data:`clradcom.scene.street.TABLE_III`: set R and v_rel,
    and the paper's simulated R and v_rel) when the target is that car of the paper's
    street as set (named ``car<letter>``, seen from radar ``A``, its set range and
    closing speed along the road within :data:`PAPER_MATCH` of the paper's); None for
    every other target, and for every target of any other scene or radar."""
    out: list[dict | None] = []
    for t in truth:
        row = TABLE_III.get(str(t["name"]).removeprefix("car")) \
            if str(t["name"]).startswith("car") and radar_name == "A" else None
        if row is not None and (
                abs(t["range_centre_m"] - row["range_set_m"]) > PAPER_MATCH[0]
                or abs(t["v_rel_along_m_s"] - row["v_rel_set_mps"]) > PAPER_MATCH[1]):
            row = None
        out.append(row)
    return out


def truth_table_lines(radar_name: str, truth, rows) -> list[str]:
    """The moving-object table a run prints: each target's set range and radial closing
    speed beside the detection that matches it, and, for the paper's street, the paper's
    Table III beside them (its set values and its own simulation's detections)."""
    paper = paper_table_iii(radar_name, truth)
    show = any(p is not None for p in paper)
    head = f"    {'object':<10} {'R set':>7} {'v set':>7} {'R det':>7} {'v det':>7}"
    lines = []
    if show:
        lines.append(f"    {'':<42} | paper (Sit et al.), Table III")
        head += f" | {'R set':>7} {'v set':>7} {'R sim':>7} {'v sim':>7}"
    lines.append(head)
    for t, (*_, rd, vd), p in zip(truth, rows, paper, strict=True):
        line = (f"    {t['name']:<10} {t['range_centre_m']:7.2f} {t['v_rel_m_s']:7.2f} "
                f"{rd or 'missed':>7} {vd:>7}")
        if p is not None:
            line += (f" | {p['range_set_m']:7.2f} {p['v_rel_set_mps']:7.2f} "
                     f"{p['range_sim_m']:7.2f} {p['v_rel_sim_mps']:7.2f}")
        lines.append(line)
    if show:
        lines.append("    (R: range of the car's centre, m; v: closing speed, m/s: the set v of "
                     "clradcom is the centre's range rate, the paper's the speed difference "
                     "along the road; R sim, v sim: the paper's own ray-tracing detections)")
    return lines


# ----------------------------------------------------------------------------------------
# static returns
# ----------------------------------------------------------------------------------------
def static_returns_beyond(detections, radar, range_m: float, tolerance_mps: float):
    """Ranges of detections beyond range_m that close at the radar's own speed (static
    objects nearly ahead), within tolerance_mps."""
    speed = float(np.linalg.norm(radar.velocity))
    far = (detections["range_m"] > range_m) & (
        np.abs(detections["velocity_mps"] - speed) <= tolerance_mps)
    return sorted(float(r) for r in detections["range_m"][far])


def strongest_static_cell(image: RadarImage, radar, range_m: float, reach_m: float,
                          tolerance_mps: float):
    """(range, dB over the image's median) of the strongest cell between range_m and the
    scene's reach at the radar's own speed (+- tolerance), or (None, None): static
    objects show in the image even where clutter around them keeps CFAR quiet."""
    speed = float(np.linalg.norm(radar.velocity))
    rows = (image.range_m > range_m) & (image.range_m <= reach_m)
    cols = np.abs(image.velocity_mps - speed) <= tolerance_mps
    if not rows.any() or not cols.any():
        return None, None
    sub = image.power_db[np.ix_(rows, cols)]
    i = np.unravel_index(np.argmax(sub), sub.shape)[0]
    return float(image.range_m[rows][i]), float(sub.max() - np.median(image.power_db))


def scene_reach_m(scene, position) -> float:
    """Distance from a point to the farthest triangle vertex of the scene (0 without
    triangles): no echo comes from farther away."""
    if not len(scene.triangles):
        return 0.0
    return float(np.linalg.norm(scene.triangles.reshape(-1, 3) - np.asarray(position),
                                axis=1).max())


def display_range_db(image: RadarImage, minimum_db: float = 20.0) -> float:
    """Colour range of an image picture that reaches down to its noise floor (the
    strongest cell over the median), so weak echoes beside the ground return show; at
    least ``minimum_db``, 50 dB for an image with no finite cell."""
    finite = image.power_db[np.isfinite(image.power_db)]
    span = float(finite.max() - np.median(finite)) if finite.size else 50.0
    return max(span, minimum_db)


# ----------------------------------------------------------------------------------------
# two radars
# ----------------------------------------------------------------------------------------
def interference_detections(result: InterferenceResult) -> dict:
    """The detections of each image of a two-radar run: the radar chain's own
    (:func:`clradcom.radar.pipeline.frame_result`, CFAR on the critical grid, refined,
    sorted against A's own paths), so that A's image without D has the detections of
    ``clradcom trace`` on the same paths and seed."""
    return {k: result.results[k].detections for k in INTERFERENCE_IMAGES}


def recovered_detections(reference, found, waveform: Waveform) -> list[bool]:
    """For each reference detection, whether one lies within one range and one velocity
    resolution cell in ``found``."""
    out = []
    for d in reference:
        ok = (np.abs(found["range_m"] - d["range_m"]) <= waveform.range_resolution) & \
             (np.abs(found["velocity_mps"] - d["velocity_mps"]) <= waveform.velocity_resolution)
        out.append(bool(ok.any()))
    return out


def _db(x: float) -> float:
    return 10 * math.log10(x) if x > 0 else -math.inf


def interference_summary(result: InterferenceResult, waveform: Waveform) -> list[tuple]:
    """(quantity, value) rows of a two-radar run: the floor rise measured against its
    prediction, the floors after cancellation, the realistic receiver's channel error and
    symbol-error rate and the residual they predict, and what the receiver estimated.
    Integers stay integers (counts and flags)."""
    res, e = result, result.estimate
    return [
        ("noise per cell re P_tx,A [dB]", _db(res.noise_variance)),
        ("interference power per sample, measured [dB]", _db(res.interference_power)),
        ("interference power predicted from D->A paths [dB]",
         _db(res.predicted_interference_power)),
        ("floor rise predicted (1 + INR) [dB]", res.predicted_floor_rise_db),
        ("floor rise measured [dB]", res.measured_floor_rise_db),
        ("floor after genie cancellation re without D [dB]",
         _db(res.floors["genie"] / res.floors["clean"])),
        ("floor after realistic cancellation re without D [dB]",
         _db(res.floors["realistic"] / res.floors["clean"])),
        ("residual interference re interference [dB]",
         _db(res.residual_power / res.interference_power)),
        ("channel NMSE (true data, estimated channel) [dB]", _db(res.channel_nmse)),
        ("symbol-error rate of D's decisions", res.symbol_error_rate),
        ("D symbols decided (inside A's frame)", int(res.symbols_decided)),
        ("predicted residual P_I(NMSE + SER E|d-d^|^2) re interference [dB]",
         _db(res.predicted_residual_power / res.interference_power)),
        ("predicted residual, errors weighted by |H^|^2 where they fall [dB]",
         _db(res.predicted_residual_weighted / res.interference_power)),
        ("D's decision SINR as the receiver judges it [dB]", e.sinr_db),
        ("cancelled (1) or judged unreliable and left alone (0)", int(e.cancel)),
        ("D timing found (CP start mod L) [samples]", e.theta),
        ("D frequency offset found (CFO + Doppler) [Hz]",
         e.eps * waveform.subcarrier_spacing_hz),
        ("D channel components fitted", int(e.components.amplitude.size)),
        ("own echoes removed before decoding D", int(e.own.amplitude.size)),
    ]


def mixed_summary(result: MixedResult) -> list[tuple]:
    """(quantity, value) rows of a pair with an FMCW radar (docs/interference.md §6):
    the floor rise measured against its closed form through the link, the burst length
    or the ghost's range against theirs, the link paths used, the mitigation and the
    floors it leaves. A figure that does not apply to the pair is left out."""
    res = result
    rows = [("victim kind (0 OFDM, 1 FMCW)", int(res.victim_kind == "fmcw")),
            ("interferer kind (0 OFDM, 1 FMCW)", int(res.interferer_kind == "fmcw")),
            ("link paths used (within 40 dB of the strongest)", int(res.link_paths_used)),
            ("link power left out (share)", res.link_power_left_out)]
    if not math.isnan(res.measured_floor_rise_db):
        rows += [("floor rise predicted through the link [dB]", res.predicted_floor_rise_db),
                 ("floor rise measured [dB]", res.measured_floor_rise_db)]
    if not math.isnan(res.predicted_burst_duration_s):
        rows += [("burst duration predicted 2 B_IF/|S_I - S_V| [us]",
                  res.predicted_burst_duration_s * 1e6),
                 ("burst duration measured [us]", res.burst_duration_s * 1e6)]
    if not math.isnan(res.predicted_ghost_range_m):
        rows += [("ghost range predicted [m]", res.predicted_ghost_range_m),
                 ("ghost range measured [m]", res.ghost_range_m)]
    rows += [("image floor without the interferer [dB]", _db(res.floors["clean"])),
             ("image floor with it, re without [dB]",
              _db(res.floors["interfered"] / res.floors["clean"])),
             ("image floor after mitigation, re without [dB]",
              _db(res.floors["mitigated"] / res.floors["clean"])),
             ("share of the frame mitigation replaced", res.mitigated_share)]
    return rows
