"""The radar point cloud as files and as a picture: CSV and PLY (ASCII, one vertex per
detection with its radial velocity, power and SNR), and a bird's-eye view of the
detections over the scene's outline with the true objects marked. Every file goes
through :mod:`clradcom.files` (atomic, byte-identical for identical content)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from clradcom.errors import ArgumentError
from clradcom.files import save_figure, write_csv, write_text
from clradcom.radar.cube import POINT_DTYPE

__all__ = ["POINT_COLUMNS", "bird_eye_figure", "ply_text", "read_point_cloud_ply",
           "save_bird_eye", "write_point_cloud_csv", "write_point_cloud_ply"]

#: CSV header and PLY vertex properties, in order (m, m, m, m/s positive approaching, dB, dB)
POINT_COLUMNS = POINT_DTYPE.names


def _points(points):
    p = np.asarray(points)
    if p.dtype != POINT_DTYPE:
        raise ArgumentError("must be a clradcom.radar.cube.POINT_DTYPE array (from "
                            "point_cloud)", argument="points", value=p.dtype)
    return p


def write_point_cloud_csv(path, points, *, inputs=()) -> Path:
    """The points as CSV: header :data:`POINT_COLUMNS`, one row per point (repr floats)."""
    p = _points(points)
    rows = [[repr(float(r[c])) for c in POINT_COLUMNS] for r in p]
    return write_csv(path, rows, header=list(POINT_COLUMNS), inputs=inputs)


def ply_text(points) -> str:
    """ASCII PLY 1.0 text: one ``vertex`` element with double properties
    :data:`POINT_COLUMNS` (x, y, z first, as point-cloud readers expect)."""
    p = _points(points)
    head = ["ply", "format ascii 1.0", "comment clradcom radar point cloud",
            f"element vertex {p.size}"]
    head += [f"property double {c}" for c in POINT_COLUMNS]
    head.append("end_header")
    body = [" ".join(repr(float(r[c])) for c in POINT_COLUMNS) for r in p]
    return "\n".join(head + body) + "\n"


def write_point_cloud_ply(path, points, *, inputs=()) -> Path:
    return write_text(path, ply_text(points), inputs=inputs)


def read_point_cloud_ply(path) -> np.ndarray:
    """Read back a file of :func:`write_point_cloud_ply` (ASCII, these properties)."""
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    if not lines or lines[0] != "ply" or "end_header" not in lines:
        raise ArgumentError("not an ASCII PLY file", argument="path", value=str(path))
    end = lines.index("end_header")
    props = [ln.split()[2] for ln in lines[:end] if ln.startswith("property ")]
    count = next(int(ln.split()[2]) for ln in lines[:end] if ln.startswith("element vertex"))
    if tuple(props) != POINT_COLUMNS:
        raise ArgumentError(f"properties {props} are not {list(POINT_COLUMNS)}",
                            argument="path", value=str(path))
    out = np.zeros(count, POINT_DTYPE)
    vals = np.array([[float(x) for x in ln.split()] for ln in lines[end + 1:end + 1 + count]])
    for k, c in enumerate(POINT_COLUMNS):
        out[c] = vals[:, k] if count else []
    return out


def bird_eye_figure(points, triangles=None, truth=(), radar_xy=None, *, xlim=None,
                    ylim=None, title="Radar point cloud") -> Figure:
    """Top view (x, y): the scene's triangles projected as a grey outline, the points
    coloured by radial velocity (sized by SNR), the true objects (``truth``: rows of
    :func:`clradcom.radar.truth.detection_truth`, their ``centre_m`` and ``name``) as
    black crosses, the radar as a triangle."""
    p = _points(points)
    fig = Figure(figsize=(7.0, 6.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    if triangles is not None:
        tri = np.asarray(triangles, float)[:, :, :2]
        ax.add_collection(PolyCollection(tri, facecolors="0.88", edgecolors="0.6",
                                         linewidths=0.2, zorder=1))
    if p.size:
        sizes = 8 + 2 * np.clip(p["snr_db"], 0, 40)
        sc = ax.scatter(p["x"], p["y"], c=p["velocity_mps"], s=sizes, cmap="coolwarm",
                        zorder=3, edgecolors="k", linewidths=0.3)
        fig.colorbar(sc, ax=ax, label="radial velocity (m/s, + approaching)")
    for row in truth:
        c = row["centre_m"]
        ax.plot(c[0], c[1], "kx", ms=10, mew=2, zorder=4)
        ax.annotate(row["name"], (c[0], c[1]), textcoords="offset points", xytext=(5, 5),
                    fontsize=8, zorder=4)
    if radar_xy is not None:
        ax.plot(radar_xy[0], radar_xy[1], "k^", ms=9, zorder=4)
    if xlim is not None:
        ax.set_xlim(*xlim)
    if ylim is not None:
        ax.set_ylim(*ylim)
    if xlim is None and ylim is None:
        ax.autoscale_view()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    return fig


def save_bird_eye(path, points, triangles=None, truth=(), radar_xy=None, *, inputs=(),
                  **kwargs) -> Path:
    return save_figure(bird_eye_figure(points, triangles, truth, radar_xy, **kwargs), path,
                       inputs=inputs, dpi=120)
