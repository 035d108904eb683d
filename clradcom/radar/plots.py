"""Radar image plot in the style of the paper's Fig. 3 (range–velocity map, dB colour), and
the images of a two-radar run side by side (the paper's Figs. 4 and 5).

Uses matplotlib's object API with the Agg canvas directly, so importing this module never
changes pyplot's global backend or state.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from clradcom.errors import ArgumentError
from clradcom.figures import new_figure
from clradcom.files import save_figure
from clradcom.paths import Paths
from clradcom.physics.em import C0
from clradcom.radar.processing import RadarImage
from clradcom.radar.report import INTERFERENCE_TITLES

#: a radar's own mounting return lies below this range: the bumper behind the antenna
#: (7.5 cm in the street) and the road right under it (0.5 m)
MOUNTING_RETURN_M = 1.0


#: the colour map of every radar image: perceptually uniform (viridis), never jet
IMAGE_CMAP = "viridis"


def mounting_range_m(range_resolution_m: float) -> float:
    """Range below which an image's cells belong to the radar's own mounting return:
    :data:`MOUNTING_RETURN_M` plus two range cells (the main lobe of the Hann window is
    ±2 cells wide), so its main lobe is not taken as a target or as the 0 dB reference."""
    return MOUNTING_RETURN_M + 2.0 * float(range_resolution_m)


def mounting_paths(paths: Paths) -> np.ndarray:
    """Mask of a monostatic link's paths that come from the radar's own mounting: echoes
    (at least one interaction) whose range, half the path length, is below
    :data:`MOUNTING_RETURN_M`."""
    return (np.asarray(paths.n_interactions) > 0) & (
        0.5 * C0 * np.asarray(paths.delay_s) < MOUNTING_RETURN_M)


def mounting_return_range_m(paths: Paths, range_resolution_m: float) -> float | None:
    """:func:`mounting_range_m` where the radar's own echoes ``paths`` hold a return from
    its mounting (:func:`mounting_paths`), else None: then no cell is the mounting return
    (a noise cell near the radar is not labelled so) and the image's 0 dB is its
    strongest cell."""
    if not mounting_paths(paths).any():
        return None
    return mounting_range_m(range_resolution_m)


def image_title(radar_name: str, scene_name: str, what: str = "range–Doppler image") -> str:
    """The title of a radar's picture: names the radar and the scene."""
    return f"Radar {radar_name}, scene {scene_name}: {what}"


def _limits(name, lim):
    try:
        lo, hi = (float(x) for x in lim)
    except (TypeError, ValueError):
        raise ArgumentError("must be a (low, high) pair of numbers", argument=name,
                            value=lim) from None
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ArgumentError("must be an increasing pair of finite numbers", argument=name,
                            value=lim)
    return lo, hi


def plot_radar_image(image: RadarImage, detections=None, range_lim_m=(0.0, 100.0),
                     velocity_lim_mps=(-30.0, 30.0), dynamic_range_db: float = 50.0,
                     title: str | None = "Radar image", figsize=(7.0, 4.5), *, truth=(),
                     mount_range_m: float | None = None) -> Figure:
    """Figure with range on x, relative velocity on y (approaching positive), colour in dB
    relative to the strongest cell shown; detections (``cfar.detect`` output) as circles.

    ``truth``: rows of :func:`clradcom.radar.truth.detection_truth`, each marked by a
    black-edged square at (``range_centre_m``, ``v_rel_m_s``) labelled with its name.
    ``mount_range_m`` (e.g. :func:`mounting_range_m`): cells nearer than this are the
    radar's own mounting return (bumper, road under the radar): they are left out of the
    0 dB reference (the strongest cell shown beyond it), and the strongest of them is
    labelled "mounting return" (it may be above 0 dB and then shows saturated)."""
    rlo, rhi = _limits("range_lim_m", range_lim_m)
    vlo, vhi = _limits("velocity_lim_mps", velocity_lim_mps)
    if not (isinstance(dynamic_range_db, int | float | np.floating)
            and np.isfinite(dynamic_range_db) and dynamic_range_db > 0):
        raise ArgumentError("must be positive and finite", argument="dynamic_range_db",
                            value=dynamic_range_db)
    r, v = image.range_m, image.velocity_mps
    ri = np.flatnonzero((r >= rlo) & (r <= rhi))
    vi = np.flatnonzero((v >= vlo) & (v <= vhi))
    if ri.size == 0 or vi.size == 0:
        raise ArgumentError(
            f"with velocity_lim_mps = {velocity_lim_mps!r} selects no image cells "
            f"(image covers {r[0]:.3g}..{r[-1]:.3g} m, {v[0]:.3g}..{v[-1]:.3g} m/s)",
            argument="range_lim_m", value=range_lim_m)
    crop = np.asarray(image.power_db)[np.ix_(ri, vi)]
    ref = crop
    if mount_range_m is not None:
        if not (np.isfinite(mount_range_m) and mount_range_m >= 0):
            raise ArgumentError("must be a finite range >= 0 (m)", argument="mount_range_m",
                                value=mount_range_m)
        beyond = r[ri] >= mount_range_m
        if beyond.any():
            ref = crop[beyond]
    top = np.max(ref[np.isfinite(ref)]) if np.isfinite(ref).any() else 0.0
    dr = r[1] - r[0] if r.size > 1 else 1.0
    dv = v[1] - v[0] if v.size > 1 else 1.0
    fig = new_figure(figsize=figsize)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    im = ax.imshow(
        (crop - top).T, origin="lower", aspect="auto", cmap=IMAGE_CMAP,
        vmin=-dynamic_range_db, vmax=0.0,
        extent=(r[ri[0]] - dr / 2, r[ri[-1]] + dr / 2, v[vi[0]] - dv / 2, v[vi[-1]] + dv / 2),
        interpolation="nearest",
    )
    fig.colorbar(im, ax=ax, label="relative power [dB]" if mount_range_m is None else
                 f"power re strongest return beyond {mount_range_m:.1f} m [dB]")
    if detections is not None and len(detections):
        det = np.asarray(detections)
        ax.plot(det["range_m"], det["velocity_mps"], "o", mfc="none", mec="white", ms=9,
                mew=1.5, label="detections")
    for t in truth:
        ax.plot([t["range_centre_m"]], [t["v_rel_m_s"]], "s", mfc="none", mec="black", ms=11,
                mew=1.5, label="truth" if t is truth[0] else None, gid=f"truth:{t['name']}")
        ax.annotate(t["name"], (t["range_centre_m"], t["v_rel_m_s"]),
                    textcoords="offset points", xytext=(7, 7), fontsize=8, color="black",
                    fontweight="bold")
    if mount_range_m is not None:
        near = np.flatnonzero(r[ri] < mount_range_m)
        if near.size and np.isfinite(crop[near]).any():
            k = np.unravel_index(np.nanargmax(np.where(np.isfinite(crop[near]), crop[near],
                                                       -np.inf)), crop[near].shape)
            rm, vm = r[ri[near[k[0]]]], v[vi[k[1]]]
            ax.plot([rm], [vm], "D", mfc="none", mec="magenta", ms=9, mew=1.5,
                    gid="mounting_return", label="mounting return (not the 0 dB reference)")
            ax.annotate(f"radar's own mounting return\n({crop[near][k] - top:+.1f} dB)",
                        (rm, vm), textcoords="offset points", xytext=(8, -22), fontsize=7,
                        color="magenta")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize="small")
    ax.set_xlim(rlo, rhi)
    ax.set_ylim(vlo, vhi)
    ax.set_xlabel("range [m]")
    ax.set_ylabel("relative velocity [m/s]")
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return fig


def save_radar_image(image: RadarImage, path_stem, detections=None, *, inputs=(), **kwargs):
    """Plot (see ``plot_radar_image``) and write ``<stem>.png`` and ``<stem>.svg``, each
    atomically and byte-identically for identical input
    (:func:`clradcom.files.save_figure`; never over a file in ``inputs``).
    Returns the two paths."""
    stem = Path(path_stem)
    if stem.suffix.lower() in (".png", ".svg"):
        stem = stem.with_suffix("")
    fig = plot_radar_image(image, detections, **kwargs)
    paths = (stem.with_suffix(".png"), stem.with_suffix(".svg"))
    save_figure(fig, paths[0], inputs=inputs, dpi=150)
    save_figure(fig, paths[1], inputs=inputs)
    return paths


def plot_interference_images(images: dict, detections: dict, floor_clean: float,
                             range_max_m: float = 60.0, titles=None) -> Figure:
    """A two-radar run's images side by side on one colour scale (A's strongest echo at
    0 dB, down to 3 dB under the interference-free floor ``floor_clean`` so the rise of
    the floor shows), velocities within +-40 m/s, detections as circles.

    ``images``/``detections``: image key -> RadarImage / detections; ``titles``: key ->
    title in the order shown (default the four of
    :data:`clradcom.radar.report.INTERFERENCE_TITLES`; "clean" sets the scale).
    """
    titles = INTERFERENCE_TITLES if titles is None else titles
    keys = list(titles)
    for name, given in (("images", images), ("detections", detections)):
        missing = [k for k in ["clean", *keys] if k not in given]
        if missing:
            raise ArgumentError(f"has no {missing[0]!r} entry (wants {['clean', *keys]})",
                                argument=name, value=sorted(given))
    if not (isinstance(floor_clean, int | float | np.floating) and np.isfinite(floor_clean)
            and floor_clean > 0):
        raise ArgumentError("must be a positive, finite noise power", argument="floor_clean",
                            value=floor_clean)
    ref = images["clean"]
    r, v = ref.range_m, ref.velocity_mps
    ri = np.flatnonzero(r <= range_max_m)
    vi = np.flatnonzero(np.abs(v) <= 40.0)
    if ri.size == 0 or vi.size == 0:
        raise ArgumentError(f"selects no image cells (image covers {r[0]:.3g}..{r[-1]:.3g} "
                            "m)", argument="range_max_m", value=range_max_m)
    top = float(ref.power_db[np.ix_(ri, vi)].max())  # one colour scale: A's strongest echo
    # down to 3 dB under the interference-free floor, so the rise of the floor shows
    dyn_db = max(30.0, top - 10 * math.log10(floor_clean) + 3.0)
    fig = new_figure(figsize=(17.0, 4.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(1, len(keys), sharey=True))
    ext = (r[ri[0]], r[ri[-1]], v[vi[0]], v[vi[-1]])
    for ax, key in zip(axes, keys, strict=True):
        crop = images[key].power_db[np.ix_(ri, vi)] - top
        im = ax.imshow(crop.T, origin="lower", aspect="auto", cmap=IMAGE_CMAP, vmin=-dyn_db,
                       vmax=0.0, extent=ext, interpolation="nearest")
        det = detections[key]
        if len(det):
            ax.plot(det["range_m"], det["velocity_mps"], "o", mfc="none", mec="white",
                    ms=8, mew=1.2)
        ax.set_xlim(ext[0], ext[1])
        ax.set_ylim(ext[2], ext[3])
        ax.set_title(titles[key])
        ax.set_xlabel("range [m]")
    axes[0].set_ylabel("relative velocity [m/s]")
    fig.colorbar(im, ax=list(axes), label="power re A's strongest echo [dB]")
    return fig


def save_interference_images(images: dict, path_stem, detections: dict, floor_clean: float,
                             range_max_m: float = 60.0, titles=None, *, inputs=()):
    """Plot (see ``plot_interference_images``) and write ``<stem>.png`` and ``<stem>.svg``,
    each atomically and byte-identically for identical input
    (:func:`clradcom.files.save_figure`). Returns the two paths."""
    stem = Path(path_stem)
    fig = plot_interference_images(images, detections, floor_clean, range_max_m, titles)
    paths = (stem.with_suffix(".png"), stem.with_suffix(".svg"))
    save_figure(fig, paths[0], inputs=inputs, dpi=120)
    save_figure(fig, paths[1], inputs=inputs)
    return paths


def save_side_by_side(images: dict, detections: dict, path_stem, *, range_max_m: float,
                      velocity_max_mps: float, dynamic_range_db: float = 60.0, inputs=()):
    """Radar images of different frames side by side (``images``: title -> RadarImage,
    each on its own axes, cut to ``range_max_m`` and ±``velocity_max_mps``), each in dB
    re its own strongest cell there, down ``dynamic_range_db``; ``detections``: title ->
    detections drawn as circles. Writes ``<stem>.png`` and ``<stem>.svg``."""
    if not images or set(images) != set(detections):
        raise ArgumentError("must name the same images and detections", argument="images",
                            value=sorted(images))
    fig = new_figure(figsize=(6.0 * len(images) + 1.5, 4.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(1, len(images)))
    im = None
    for ax, (title, img) in zip(axes, images.items(), strict=True):
        ri = np.flatnonzero(img.range_m <= range_max_m)
        vi = np.flatnonzero(np.abs(img.velocity_mps) <= velocity_max_mps)
        if ri.size < 2 or vi.size < 2:
            raise ArgumentError(f"selects fewer than two cells of the {title} image",
                                argument="range_max_m", value=range_max_m)
        crop = img.power_db[np.ix_(ri, vi)]
        crop = crop - float(crop.max())
        ext = (img.range_m[ri[0]], img.range_m[ri[-1]], img.velocity_mps[vi[0]],
               img.velocity_mps[vi[-1]])
        im = ax.imshow(crop.T, origin="lower", aspect="auto", cmap=IMAGE_CMAP,
                       vmin=-dynamic_range_db, vmax=0.0, extent=ext, interpolation="nearest")
        det = detections[title]
        if len(det):
            ax.plot(det["range_m"], det["velocity_mps"], "o", mfc="none", mec="white",
                    ms=8, mew=1.2)
        ax.set_xlim(ext[0], ext[1])
        ax.set_ylim(ext[2], ext[3])
        ax.set_title(title)
        ax.set_xlabel("range [m]")
        ax.set_ylabel("relative velocity [m/s]")
    fig.colorbar(im, ax=list(axes), label="power re each image's strongest cell [dB]")
    stem = Path(path_stem)
    paths = (stem.with_suffix(".png"), stem.with_suffix(".svg"))
    save_figure(fig, paths[0], inputs=inputs, dpi=120)
    save_figure(fig, paths[1], inputs=inputs)
    return paths
