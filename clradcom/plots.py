"""Scene pictures: the street from above with the strongest paths drawn."""

from __future__ import annotations

import numpy as np

from clradcom.errors import ArgumentError
from clradcom.files import save_figure


def plot_top_view(scene, snapshot, link=None, n_paths: int = 20, path=None, *, inputs=()):
    """Top view (x-y) of the scene's triangles, radars and a link's strongest paths.

    Returns the matplotlib Figure; writes it to ``path`` when given, atomically and
    byte-identically for identical input (:func:`clradcom.files.save_figure`).
    """
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.figure import Figure

    if isinstance(n_paths, bool) or not isinstance(n_paths, int | np.integer) or n_paths < 1:
        raise ArgumentError("must be a positive integer", argument="n_paths", value=n_paths)

    fig = Figure(figsize=(11, 5), layout="constrained")
    ax = fig.add_subplot()
    tri = scene.triangles
    # vertical faces project to lines; draw every triangle's outline faintly
    ax.add_collection(PolyCollection(tri[:, :, :2], facecolors="0.85", edgecolors="0.6",
                                     linewidths=0.2))
    if link is None and len(snapshot.links):
        link = snapshot.links[0]
    if link is not None and link.paths.n_paths:
        p = link.paths
        order = np.argsort(-np.abs(p.gain))[:n_paths]
        db = 20.0 * np.log10(np.abs(p.gain[order]))
        segs = [p.points[i, :p.n_interactions[i] + 2, :2] for i in order]
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
    ax.set_title(f"{scene.name}: top view, {n_paths} strongest paths")
    if path is not None:
        save_figure(fig, path, inputs=inputs, dpi=150)
    return fig
