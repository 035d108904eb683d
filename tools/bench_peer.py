#!/usr/bin/env python3
"""Peer benchmark: clradcom against Sionna RT on the same street, same link, same rays.

    pip install -e '.[peer]'              # Sionna RT; keep it out of the test venv
    apt-get install libllvm19             # Dr.Jit's CPU back end needs LLVM >= 16
    python tools/bench_peer.py                            # 1e5, 1e6, 1e7 rays
    python tools/bench_peer.py --rays 100000,1000000 --repeats 3 --tx A --rx D

Pure geometrical optics on both sides: line of sight and up to --max-reflections
specular reflections (no diffraction, scattering or refraction), one link (--tx ->
--rx), both antennas isotropic and V-polarised (the scene's patterns are replaced:
Sionna cannot take clradcom's), smooth surfaces (no roughness factor on either side),
the same number of rays launched from the transmitter over the whole sphere. The scene
(default the paper's street) is written as a Mitsuba XML scene
(:func:`clradcom.scene.export_xml.write_xml_scene`, 1 m thick slabs so that Sionna's
layered reflection is the half-space clradcom computes) and loaded by Sionna with
``merge_shapes=False`` so its object ids are clradcom's objects. Sionna keeps a path per
triangle sequence, so a reflection off a face split into coplanar triangles can come
back once per triangle: each tracer's repeats (same sequence, |delta tau| < 1 ps) are
counted and left out before matching.

One warm-up trace of each (kernel builds, Dr.Jit's JIT), then for every ray count the
two take turns --repeats times in this process; Sionna's time includes turning its lazy
results into numpy arrays (tau, a, interactions, objects), clradcom's the whole
``trace_scene``, once as a first trace (faces, BVH, device tables and wedges built:
:func:`clradcom.mechanisms.common.forget_geometries` first) and once as the next trace
of the same scene, which reuses them (:func:`clradcom.mechanisms.common.kept_geometry`),
and a third time with --expand rounds of candidate expansion
(:func:`clradcom.mechanisms.specular.expanded_paths`).
Printed per ray count: median times, clradcom / Sionna, paths found, and the path sets
matched one to one (:func:`clradcom.evaluation.peer.match_paths`: the same interaction
and object sequence, |delta tau| < 1 ps), with the matched gains compared (Sionna's
``a`` has no carrier phase; clradcom's gain has, so exp(+j 2 pi f_c tau) is taken out of
it first). Last, the union of every path either found at any ray count, and what each
run missed of it.
Errors in the options are one line on stderr, exit code 2; no Sionna RT is exit code 2
with the command that installs it.
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from clradcom.cli import positive_int, run_tool
from clradcom.device.runtime import get_runtime
from clradcom.evaluation.peer import distinct_paths, match_paths, sequences_of
from clradcom.mechanisms.common import forget_geometries
from clradcom.paths import InteractionType
from clradcom.scene.antenna import IsotropicPattern
from clradcom.scene.export_xml import write_xml_scene
from clradcom.scene.reader import load_scene
from clradcom.trace import TraceSettings, trace_scene

# Dr.Jit reads DRJIT_LIBLLVM_PATH when it is imported; LLVM 15 (Debian 12's default)
# aborts in its CPU back end, so point it at an LLVM 19 when the user has not
_LLVM = sorted(glob.glob("/usr/lib/*/libLLVM.so.19*") + glob.glob("/usr/lib/llvm-19/lib/"
                                                                  "libLLVM*.so*"))
if "DRJIT_LIBLLVM_PATH" not in os.environ and _LLVM:
    os.environ["DRJIT_LIBLLVM_PATH"] = _LLVM[0]
try:
    import mitsuba as mi

    mi.set_variant("llvm_ad_mono_polarized")
    import sionna.rt as srt
    from sionna.rt.constants import InteractionType as SionnaInteraction
except ImportError as exc:  # the peer extra is optional
    srt = None
    SIONNA_MISSING = f"{exc}: pip install -e '.[peer]' (and apt-get install libllvm19)"

REPO = Path(__file__).resolve().parent.parent
STREET = REPO / "scenes" / "street" / "street.toml"
DEFAULT_RAYS = (100_000, 1_000_000, 10_000_000)
#: Sionna's interaction codes -> clradcom's (both name a reflection 1)
SIONNA_TO_CLRADCOM = {}
if srt is not None:
    SIONNA_TO_CLRADCOM = {int(SionnaInteraction.SPECULAR): int(InteractionType.REFLECTION),
                          int(SionnaInteraction.DIFFRACTION): int(InteractionType.DIFFRACTION),
                          int(SionnaInteraction.DIFFUSE): int(InteractionType.SCATTERING)}


def ray_counts(text: str) -> tuple[int, ...]:
    """--rays: comma-separated positive integers (1e6 and 1_000_000 are read too)."""
    out = []
    for item in (t.strip() for t in text.split(",") if t.strip()):
        try:
            value = float(item.replace("_", ""))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{item!r} is not a number of rays") from None
        if not (value >= 1 and value == int(value)):
            raise argparse.ArgumentTypeError(f"{item!r} is not a positive integer")
        out.append(int(value))
    if not out:
        raise argparse.ArgumentTypeError(f"names no ray count: {text!r}")
    return tuple(out)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=STREET,
                    help="scene file (default scenes/street/street.toml)")
    ap.add_argument("--tx", default="A", help="transmitting radar's name (default A)")
    ap.add_argument("--rx", default="D", help="receiving radar's name (default D)")
    ap.add_argument("--rays", type=ray_counts, default=DEFAULT_RAYS,
                    help="rays per trace, comma-separated (default 1e5,1e6,1e7)")
    ap.add_argument("--max-reflections", type=positive_int, default=5,
                    help="most specular reflections per path (default 5)")
    ap.add_argument("--expand", type=positive_int, default=4, metavar="ROUNDS",
                    help="rounds of candidate expansion of the third clradcom trace "
                         "(SpecularSettings.expand_rounds; default 4)")
    ap.add_argument("--repeats", type=positive_int, default=1,
                    help="timed traces per tracer and ray count; medians (default 1)")
    ap.add_argument("--device", default=None, help="clradcom's OpenCL device (default: "
                                                   "the usual choice, PoCL without a GPU)")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if srt is None:
        print(f"bench_peer.py: error: Sionna RT is not installed ({SIONNA_MISSING})",
              file=sys.stderr)
        return 2
    return run_tool("bench_peer.py", run, args)


def isotropic_link_scene(scene, tx: str, rx: str):
    """The scene with every radar isotropic and V-polarised and every material smooth
    (Sionna's specular reflection has no roughness factor), and the link's indices."""
    materials = [dataclasses.replace(m, roughness_m=0.0) for m in scene.materials]
    radars = [dataclasses.replace(r, pattern=IsotropicPattern(),
                                  polarization=np.array([1.0 + 0j, 0j]), polarization_name="V")
              for r in scene.radars]
    return (dataclasses.replace(scene, radars=radars, materials=materials),
            scene.radar_index(tx),
            scene.radar_index(rx))


def sionna_scene(scene, xml: Path, tx_index: int, rx_index: int):
    sc = srt.load_scene(str(xml), merge_shapes=False)
    sc.frequency = float(scene.carrier_hz)
    for what in ("tx_array", "rx_array"):
        setattr(sc, what, srt.PlanarArray(num_rows=1, num_cols=1, pattern="iso",
                                          polarization="V"))
    sc.add(srt.Transmitter("tx", position=[float(v) for v in
                                           scene.radars[tx_index].position]))
    sc.add(srt.Receiver("rx", position=[float(v) for v in scene.radars[rx_index].position]))
    names = {int(o.object_id): name for name, o in sc.objects.items()}
    return sc, names


def sionna_trace(sc, solver, names: dict, rays: int, max_reflections: int) -> dict:
    """Sionna's paths of the one link as plain arrays: sequences, delays, gains."""
    paths = solver(sc, max_depth=max_reflections, max_num_paths_per_src=max(10**6, rays),
                   samples_per_src=rays, synthetic_array=True, los=True,
                   specular_reflection=True, diffuse_reflection=False, refraction=False,
                   diffraction=False, seed=1)
    valid = np.asarray(paths.valid.numpy()).reshape(-1).astype(bool)
    tau = np.asarray(paths.tau.numpy()).reshape(-1)[valid]
    a_re, a_im = (np.asarray(x.numpy()).reshape(-1) for x in paths.a)
    gain = (a_re + 1j * a_im)[valid]
    kinds = np.asarray(paths.interactions.numpy()).reshape(max_reflections, -1)[:, valid]
    objs = np.asarray(paths.objects.numpy()).reshape(max_reflections, -1)[:, valid]
    sequences = [tuple((SIONNA_TO_CLRADCOM.get(int(kinds[j, p]), -int(kinds[j, p])),
                        names[int(objs[j, p])])
                       for j in range(max_reflections) if kinds[j, p] != 0)
                 for p in range(len(tau))]
    return distinct({"sequences": sequences, "delay_s": tau.astype(np.float64),
                     "gain": gain})


def distinct(found: dict) -> dict:
    """``found`` without its repeats (:func:`clradcom.evaluation.peer.distinct_paths`),
    with their number under "repeats"."""
    keep = distinct_paths(found["sequences"], found["delay_s"])
    return {"sequences": [found["sequences"][i] for i in keep],
            "delay_s": found["delay_s"][keep], "gain": found["gain"][keep],
            "repeats": len(found["delay_s"]) - len(keep)}


def clradcom_trace(scene, settings, runtime, link) -> dict:
    snap = trace_scene(scene, settings, runtime=runtime, links=[link])
    p = snap.links[0].paths
    sequences = sequences_of(p.interaction, p.n_interactions, p.object_id,
                             snap.object_names)
    return distinct({"sequences": sequences, "delay_s": np.asarray(p.delay_s),
                     "gain": np.asarray(p.gain)})


def timed(fn, *args, **kw):
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    return time.perf_counter() - t0, out


def describe(seq) -> str:
    return " ".join(f"R:{name}" if kind == int(InteractionType.REFLECTION) else
                    f"{kind}:{name}" for kind, name in seq) or "LoS"


def run(args) -> int:
    scene, tx_index, rx_index = isotropic_link_scene(load_scene(args.scene), args.tx,
                                                     args.rx)
    runtime = get_runtime(args.device)
    settings = TraceSettings.preset("go", specular__max_reflections=args.max_reflections,
                                    diffraction__max_diffractions=0)
    folder = Path(tempfile.mkdtemp(prefix="bench_peer-"))
    xml = write_xml_scene(scene, folder, thickness_m=1.0)
    sc, names = sionna_scene(scene, xml, tx_index, rx_index)
    solver = srt.PathSolver()
    link = (tx_index, rx_index)
    print(f"scene {args.scene} ({len(scene.triangles)} triangles, {len(scene.objects)} "
          f"objects), link {args.tx} -> {args.rx}, up to {args.max_reflections} "
          f"reflections; clradcom on {runtime.info.describe()}; Sionna RT "
          f"{srt.__version__} on Mitsuba variant {mi.variant()}; load "
          f"{os.getloadavg()[0]:.2f}")
    warm = min(args.rays)
    clradcom_trace(scene, settings.replace(specular__rays=warm), runtime, link)
    sionna_trace(sc, solver, names, warm, args.max_reflections)
    rows, found = [], {}
    for rays in args.rays:
        st = settings.replace(specular__rays=rays)
        times: dict[str, list[float]] = {"clradcom": [], "cached": [], "expanded": [],
                                         "sionna": []}
        st_expand = st.replace(specular__expand_rounds=args.expand)
        for _ in range(args.repeats):
            forget_geometries()  # a first trace: faces, BVH, face tables, wedges built
            dt, ours = timed(clradcom_trace, scene, st, runtime, link)
            times["clradcom"].append(dt)
            # the next trace of the same geometry (clradcom.mechanisms.common.kept_geometry)
            dt, ours_cached = timed(clradcom_trace, scene, st, runtime, link)
            times["cached"].append(dt)
            dt, ours_expanded = timed(clradcom_trace, scene, st_expand, runtime, link)
            times["expanded"].append(dt)
            dt, theirs = timed(sionna_trace, sc, solver, names, rays, args.max_reflections)
            times["sionna"].append(dt)
        if not np.array_equal(ours["delay_s"], ours_cached["delay_s"]):
            print(f"  ! {rays} rays: the cached geometry gave other paths", file=sys.stderr)
        m = match_paths(ours["sequences"], ours["delay_s"], theirs["sequences"],
                        theirs["delay_s"])
        found[rays] = {"clradcom": ours, "clradcom + expansion": ours_expanded,
                       "Sionna": theirs}
        med = {k: float(np.median(v)) for k, v in times.items()}
        rows.append((rays, med, len(ours["delay_s"]), len(ours_expanded["delay_s"]),
                     len(theirs["delay_s"]), m))
        ours_a = ours["gain"][m.pairs[:, 0]] * np.exp(
            2j * np.pi * scene.carrier_hz * ours["delay_s"][m.pairs[:, 0]])
        theirs_a = theirs["gain"][m.pairs[:, 1]]
        db = 20 * np.log10(np.abs(ours_a) / np.abs(theirs_a)) if len(m.pairs) else np.zeros(0)
        print(f"\n{rays:.0e} rays: clradcom {med['clradcom']:.3f} s (geometry kept: "
              f"{med['cached']:.3f} s), Sionna {med['sionna']:.3f} s; clradcom / Sionna "
              f"{med['clradcom'] / med['sionna']:.2f} ({med['cached'] / med['sionna']:.2f} "
              f"kept); distinct paths {len(ours['delay_s'])} / {len(theirs['delay_s'])} (repeats "
              f"left out {ours['repeats']} / {theirs['repeats']}), matched "
              f"{len(m.pairs)}, max |dtau| "
              f"{np.abs(m.delay_error_s).max(initial=0) * 1e12:.3g} ps, |gain| clradcom "
              f"/ Sionna median {np.median(db) if len(db) else float('nan'):+.2f} dB "
              f"(max |.| {np.abs(db).max(initial=0):.2f} dB); with {args.expand} rounds of "
              f"expansion {med['expanded']:.3f} s, {len(ours_expanded['delay_s'])} paths; "
              f"load {os.getloadavg()[0]:.2f}")
        for who, idx, res in (("clradcom only", m.only_a, ours), ("Sionna only", m.only_b,
                                                                  theirs)):
            for i in idx:
                print(f"    {who}: {describe(res['sequences'][i])}  "
                      f"tau {res['delay_s'][i] * 1e9:.4f} ns")
    print("\n| rays | clradcom, first trace | next trace (geometry kept) | with expansion "
          "| Sionna | first / Sionna | next / Sionna | distinct paths clradcom / with "
          "expansion / Sionna | matched |")
    print("|---|---|---|---|---|---|---|---|---|")
    for rays, med, n_ours, n_expanded, n_theirs, m in rows:
        print(f"| {rays:.0e} | {med['clradcom']:.3f} s | {med['cached']:.3f} s | "
              f"{med['expanded']:.3f} s | {med['sionna']:.3f} s | "
              f"{med['clradcom'] / med['sionna']:.2f} | {med['cached'] / med['sionna']:.2f}"
              f" | {n_ours} / {n_expanded} / {n_theirs} | {len(m.pairs)} |")
    union_report(found)
    return 0


def union_report(found: dict) -> None:
    """Every distinct path found by either tracer at any ray count, and what each missed."""
    seqs, delays = [], []
    for runs in found.values():
        for res in runs.values():
            seqs += res["sequences"]
            delays += list(res["delay_s"])
    delays = np.asarray(delays)
    # the union: greedily keep a path unless one already kept matches it
    kept_seq, kept_tau = [], []
    for s, t in zip(seqs, delays, strict=True):
        if not kept_seq or not len(match_paths([s], [t], kept_seq, kept_tau).pairs):
            kept_seq.append(s)
            kept_tau.append(t)
    print(f"\nunion of all runs: {len(kept_seq)} distinct paths")
    for rays, runs in found.items():
        for who, res in runs.items():
            m = match_paths(kept_seq, kept_tau, res["sequences"], res["delay_s"])
            missed = [describe(kept_seq[i]) for i in m.only_a]
            print(f"  {who} at {rays:.0e} rays misses {len(missed)}"
                  + (": " + "; ".join(missed) if missed else ""))


if __name__ == "__main__":
    warnings.simplefilter("ignore")
    sys.exit(main())
