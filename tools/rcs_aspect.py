#!/usr/bin/env python3
"""Monostatic RCS of the car model against aspect angle: pure GO versus PO + SBR.

A radar circles the PEC car (``clradcom.models.car_mesh`` or ``rounded_car``) at
range --range-m and height --height-m; aspect 0° looks at the nose (+x), 90° at the
left side, 180° at the rear.  No ground: the car's own returns only.

* GO: image-method paths up to --bounces reflections (candidates from a dense ray grid
  over the car, exact paths and fields as in ``clradcom.tracer``); a flat facet seen at
  its specular angle returns like an infinite mirror (pi R^2 at range R), any other
  facet nothing.
* PO + SBR: physical-optics facet integrals for the first bounce
  (``clradcom.po.po_paths``), shooting-and-bouncing ray tubes with PO radiation for
  bounces 2..--bounces (``clradcom.sbr.sbr_paths``).

RCS here is the apparent one at the stated range, sigma = |a|^2 (4 pi)^3 R^4 / lambda^2
with the coherent sum a of all paths, isotropic antennas, VV and HH from the
polarimetric matrix.  Writes rcs_aspect.csv and rcs_aspect.png into --out and prints
the run time of each method.

    python tools/rcs_aspect.py --out out/rcs [--range-m 20] [--step-deg 5] [--device SPEC]
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

from clradcom.device.runtime import get_runtime
from clradcom.mechanisms import specular as sp
from clradcom.mechanisms.physical_optics import po_paths
from clradcom.mechanisms.sbr import bounding_sphere, launch_tubes, sbr_paths
from clradcom.physics.em import C0
from clradcom.scene.models import car_mesh, rounded_car
from clradcom.scene.reader import scene_from_dict
from clradcom.trace import build_geometry, path_fields, specular_paths

CARRIER_HZ = 24e9
FLOOR_DBSM = -40.0  # plotted where a method returns nothing


def dbsm(m, R, lam):
    s = np.abs(m) ** 2 * (4 * np.pi) ** 3 * R**4 / lam**2
    with np.errstate(divide="ignore"):
        return 10 * np.log10(s)


def positive(kind):
    def parse(text):
        v = kind(text)
        if not v > 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return v
    return parse


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="folder for rcs_aspect.csv / .png")
    ap.add_argument("--model", choices=("car", "rounded"), default="car",
                    help="car: car_mesh() (default); rounded: rounded_car(face_centred=True)")
    ap.add_argument("--range-m", type=positive(float), default=20.0)
    ap.add_argument("--height-m", type=float, default=0.5,
                    help="radar height (default 0.5 m; the car stands on z = 0)")
    ap.add_argument("--start-deg", type=float, default=0.0)
    ap.add_argument("--stop-deg", type=float, default=180.0)
    ap.add_argument("--step-deg", type=positive(float), default=5.0)
    ap.add_argument("--bounces", type=int, choices=(1, 2, 3, 4, 5), default=3)
    ap.add_argument("--spacing-wavelengths", type=positive(float), default=0.5,
                    help="SBR ray-tube pitch at the car (default 0.5 wavelength)")
    ap.add_argument("--go-spacing-m", type=positive(float), default=0.01,
                    help="pitch of the GO candidate rays at the car (default 1 cm)")
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    if args.stop_deg < args.start_deg:
        ap.error(f"--stop-deg ({args.stop_deg}) is below --start-deg ({args.start_deg})")

    mesh = car_mesh() if args.model == "car" else rounded_car(face_centred=True)
    aspects = np.arange(args.start_deg, args.stop_deg + 1e-9, args.step_deg)
    R, h = args.range_m, args.height_m
    positions = [[R * np.cos(np.radians(a)), R * np.sin(np.radians(a)), h] for a in aspects]
    scene = scene_from_dict({
        "scene": {"name": "rcs_aspect", "carrier_hz": CARRIER_HZ},
        "objects": [{"name": "car", "material": "metal", "shape": "triangles",
                     "vertices": np.asarray(mesh.vertices).tolist(),
                     "faces": np.asarray(mesh.faces).tolist()}],
        "radars": [{"name": f"a{i:03d}", "position": p, "pattern": "isotropic"}
                   for i, p in enumerate(positions)]})
    lam = C0 / CARRIER_HZ
    rt = get_runtime(args.device)
    print(f"device : {rt.info.describe()}")
    print(f"car    : {args.model}, {len(scene.triangles)} triangles; radar at {R} m, "
          f"{h} m high; {len(aspects)} aspects; up to {args.bounces} bounces")
    geom = build_geometry(scene, rt)
    sphere = bounding_sphere(scene.triangles)
    # compile the kernels outside the timed loops
    po_paths(geom, scene.radars[0], scene.radars[0])

    rows = []
    t_go = t_po = t_sbr = 0.0
    n_tubes = 0
    for a, radar in zip(aspects, scene.radars, strict=True):
        dist = np.linalg.norm(np.asarray(radar.position) - sphere[0])
        t0 = time.perf_counter()
        grid = launch_tubes(radar.position, [sphere], args.go_spacing_m)
        seqs = sp.reflection_sequences(geom.caster, geom.faces.tri_face, radar.position,
                                       grid.directions, args.bounces)
        pg = specular_paths(geom, radar.position, radar.position, sp.unique_candidates(seqs),
                            line_of_sight=False)
        go = path_fields(geom, pg, radar, radar)
        t1 = time.perf_counter()
        po = po_paths(geom, radar, radar)
        t2 = time.perf_counter()
        sbr = sbr_paths(geom, radar, radar, objects=[0],
                        spacing_wavelengths=args.spacing_wavelengths, max_bounces=args.bounces)
        t3 = time.perf_counter()
        t_go, t_po, t_sbr = t_go + t1 - t0, t_po + t2 - t1, t_sbr + t3 - t2
        n_tubes += int(np.ceil(np.pi * (sphere[1] * dist / np.sqrt(dist**2 - sphere[1]**2))
                               ** 2 / (args.spacing_wavelengths * lam) ** 2))
        m_go, m_po, m_sbr = (p.matrix.sum(axis=0) for p in (go, po, sbr))
        row = {"aspect_deg": a}
        for pol, k in (("vv", 0), ("hh", 1)):
            row[f"go_{pol}_dbsm"] = dbsm(m_go[k, k], R, lam)
            row[f"po_sbr_{pol}_dbsm"] = dbsm(m_po[k, k] + m_sbr[k, k], R, lam)
            row[f"po_only_{pol}_dbsm"] = dbsm(m_po[k, k], R, lam)
        row.update(go_paths=len(go), po_facets=len(po), sbr_paths=len(sbr))
        rows.append(row)
        print(f"  {a:6.1f} deg  GO {row['go_vv_dbsm']:7.1f} dBsm ({len(go)} paths)   "
              f"PO+SBR {row['po_sbr_vv_dbsm']:6.1f} dBsm ({len(po)} facets, "
              f"{len(sbr)} SBR paths)", flush=True)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "rcs_aspect.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.3f}" if isinstance(v, float) else v) for k, v in r.items()})
    n = len(aspects)
    print(f"time GO      : {t_go:7.2f} s  ({t_go / n * 1e3:.0f} ms per aspect)")
    print(f"time PO      : {t_po:7.2f} s  ({t_po / n * 1e3:.0f} ms per aspect)")
    print(f"time SBR     : {t_sbr:7.2f} s  ({t_sbr / n * 1e3:.0f} ms per aspect, "
          f"~{n_tubes / n / 1e3:.0f} k tubes)")
    print(f"time PO+SBR  : {t_po + t_sbr:7.2f} s")
    plot(out / "rcs_aspect.png", rows, args, t_go, t_po + t_sbr)
    print(f"wrote {out / 'rcs_aspect.csv'} and {out / 'rcs_aspect.png'}")
    return 0


def plot(path, rows, args, t_go, t_po):
    from matplotlib.figure import Figure

    a = np.array([r["aspect_deg"] for r in rows])
    fig = Figure(figsize=(9, 5.5), layout="constrained")
    ax = fig.add_subplot()
    for key, style, label in (
            ("go_vv_dbsm", dict(color="tab:red", lw=1.0, marker="o", ms=3),
             f"GO image method, VV ({t_go:.1f} s)"),
            ("po_sbr_vv_dbsm", dict(color="tab:blue", lw=1.6),
             f"PO + SBR, VV ({t_po:.1f} s)"),
            ("po_sbr_hh_dbsm", dict(color="tab:blue", lw=1.0, ls="--"), "PO + SBR, HH"),
            ("po_only_vv_dbsm", dict(color="tab:gray", lw=0.8, ls=":"),
             "PO facets only (no SBR), VV")):
        y = np.array([r[key] for r in rows])
        ax.plot(a, np.maximum(y, FLOOR_DBSM), label=label, **style)
    ax.set_xlabel("aspect angle (deg; 0 = nose, 90 = side, 180 = rear)")
    ax.set_ylabel("monostatic RCS (dBsm)")
    ax.set_title(f"Car model ({args.model}), 24 GHz, radar at {args.range_m:g} m, "
                 f"{args.height_m:g} m high, up to {args.bounces} bounces")
    ax.set_ylim(bottom=FLOOR_DBSM - 2)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
