"""Scene pictures: the street from above, coloured by material, with the strongest paths
drawn; the colours every scene view shares (:func:`material_colors`)."""

from __future__ import annotations

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.figures import new_figure
from clradcom.files import save_figure

__all__ = ["MATERIAL_PALETTE", "material_colors", "plot_radio_map", "plot_top_view"]

#: Colours (RGB, 0-1) of the scene's materials in their scene order, repeating after the
#: last: muted, told apart from one another and from the paths' viridis colours.
MATERIAL_PALETTE = (
    (0.62, 0.62, 0.60),  # grey
    (0.80, 0.47, 0.35),  # brick
    (0.42, 0.60, 0.80),  # steel blue
    (0.55, 0.72, 0.45),  # leaf green
    (0.85, 0.75, 0.45),  # sand
    (0.65, 0.50, 0.75),  # lilac
    (0.45, 0.75, 0.75),  # teal
    (0.90, 0.60, 0.70),  # pink
    (0.50, 0.40, 0.30),  # umber
    (0.30, 0.30, 0.35),  # slate
)


def material_colors(n_materials: int) -> np.ndarray:
    """(n_materials, 3) float RGB in 0..1: material i gets MATERIAL_PALETTE[i mod 10]."""
    palette = np.asarray(MATERIAL_PALETTE, dtype=np.float64)
    return palette[np.arange(int(n_materials)) % len(palette)]


def plot_top_view(scene, snapshot, link=None, n_paths: int = 20, path=None, *, inputs=()):
    """Top view (x-y) of the scene's triangles coloured by material (legend with the
    material names), radars and a link's strongest paths.

    Triangles are drawn lowest first, so roofs and car bodies lie over the road they
    stand on. Returns the matplotlib Figure (shown inline in Jupyter); writes it to
    ``path`` when given, atomically and byte-identically for identical input
    (:func:`clradcom.files.save_figure`).
    """
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.patches import Patch

    if isinstance(n_paths, bool) or not isinstance(n_paths, int | np.integer) or n_paths < 1:
        raise ArgumentError("must be a positive integer", argument="n_paths", value=n_paths)

    fig = new_figure(figsize=(11, 5), layout="constrained")
    ax = fig.add_subplot()
    tri = scene.triangles
    colors = material_colors(len(scene.materials))
    order = np.argsort(tri[:, :, 2].max(axis=1), kind="stable")  # lowest first
    mat = np.asarray(scene.tri_material)[order]
    # vertical faces project to lines: their darker outline still shows them
    ax.add_collection(PolyCollection(tri[order, :, :2], facecolors=colors[mat],
                                     edgecolors=colors[mat] * 0.7, linewidths=0.2))
    used = sorted(set(np.unique(scene.tri_material).tolist()))
    handles = [Patch(facecolor=colors[m], edgecolor=colors[m] * 0.7,
                     label=scene.materials[m].name) for m in used]
    if link is None and len(snapshot.links):
        link = snapshot.links[0]
    n_drawn = 0
    if link is not None and link.paths.n_paths:
        p = link.paths
        strongest = np.argsort(-np.abs(p.gain), kind="stable")[:n_paths]
        db = 20.0 * np.log10(np.abs(p.gain[strongest]))
        segs = [p.points[i, :p.n_interactions[i] + 2, :2] for i in strongest]
        n_drawn = len(segs)
        lc = LineCollection(segs, array=db, cmap="viridis", linewidths=1.2)
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, label=f"path gain (dB), {link.tx_name}->{link.rx_name}")
    for r in scene.radars:
        ax.plot(*r.position[:2], marker="^", color="red")
        ax.annotate(r.name, r.position[:2], textcoords="offset points", xytext=(4, 4))
    pts = np.concatenate([tri.reshape(-1, 3)] + [r.position[None] for r in scene.radars])
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    pad = 0.05 * max(float((hi - lo).max()), 1.0)
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{scene.name}: top view, {n_drawn} strongest paths of {link.tx_name}->"
                 f"{link.rx_name}" if n_drawn else f"{scene.name}: top view (no paths: "
                 + ("no snapshot or link given)" if link is None else f"link {link.tx_name}->"
                    f"{link.rx_name} has none)"))
    if handles:
        fig.legend(handles=handles, title="material", loc="outside lower center",
                   ncols=min(len(handles), 6), fontsize="small")
    if path is not None:
        save_figure(fig, path, inputs=inputs, dpi=150)
    return fig


def plot_radio_map(scene, grid, values_db, *, label: str, title: str = "",
                   converged=None, cmap: str = "viridis", path=None, inputs=()):
    """A radio map (``values_db`` (ny, nx) over ``grid``, a :class:`clradcom.maps.MapGrid`)
    drawn over the scene's top view: the cells in a perceptually uniform colour map
    (viridis, or cividis) with a colour bar in dB labelled ``label``; cells without a
    value (NaN) left blank and those under the convergence rule (``converged`` False)
    drawn faded; the objects that stand above the map's layer outlined in grey; the radars
    marked and named. Returns the Figure; writes it to ``path`` when given
    (:func:`clradcom.files.save_figure`)."""
    from matplotlib.collections import PolyCollection

    values = np.asarray(values_db, dtype=np.float64)
    if values.shape != (grid.ny, grid.nx):
        raise ArgumentError(f"must be a (ny, nx) = ({grid.ny}, {grid.nx}) array",
                            argument="values_db", value=values.shape)
    if cmap not in ("viridis", "cividis", "magma", "inferno", "plasma"):
        raise ArgumentError("must be a perceptually uniform colour map (viridis, cividis, "
                            "magma, inferno, plasma)", argument="cmap", value=cmap)
    width = grid.nx * grid.cell_m
    height = grid.ny * grid.cell_m
    fig = new_figure(figsize=(min(14.0, 3.0 + 10.0 * max(width / height, 0.4)), 5),
                     layout="constrained")
    ax = fig.add_subplot()
    finite = values[np.isfinite(values)]
    shown = np.ma.masked_invalid(values)
    vmin, vmax = (np.percentile(finite, 1), finite.max()) if finite.size else (0.0, 1.0)
    image = ax.imshow(shown, origin="lower", extent=grid.extent(), cmap=cmap,
                      vmin=vmin, vmax=vmax, interpolation="nearest")
    if converged is not None:
        faded = np.zeros((grid.ny, grid.nx, 4))
        faded[..., :3] = 1.0
        faded[..., 3] = np.where(np.asarray(converged, bool) | ~np.isfinite(values), 0.0, 0.6)
        ax.imshow(faded, origin="lower", extent=grid.extent(), interpolation="nearest")
    fig.colorbar(image, ax=ax, label=label, shrink=0.9)
    tri = np.asarray(scene.triangles)
    if len(tri):
        above = tri[:, :, 2].max(axis=1) > grid.height_m - 0.5 * grid.thickness
        ax.add_collection(PolyCollection(tri[above, :, :2], facecolors="none",
                                         edgecolors=(0.3, 0.3, 0.3, 0.5), linewidths=0.3))
    for r in scene.radars:
        ax.plot(*r.position[:2], marker="^", color="red", markeredgecolor="white")
        ax.annotate(r.name, r.position[:2], textcoords="offset points", xytext=(4, 4),
                    color="red")
    left, right, bottom, top = grid.extent()
    ax.set_xlim(left, right)
    ax.set_ylim(bottom, top)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or f"{scene.name}: {label}")
    if path is not None:
        save_figure(fig, path, inputs=inputs, dpi=150)
    return fig
