#!/usr/bin/env python3
"""Specular path sets from fewer rays: launch settings against a dense reference launch.

    python tools/bench_specular_sets.py                       # the street, main job
    python tools/bench_specular_sets.py --times 0,0.1,0.35,0.9 --settings 1e6,3e5:4,2e5:4
    python tools/bench_specular_sets.py --reference 1e7 --repeats 5

The street (or --scene) at the main job's specular search (tools/trace.py's defaults:
its reflections and antennas) with edges, physical optics and scattering left out, every
link. Each of --settings (RAYS or RAYS:ROUNDS of candidate expansion; the first is the
baseline, default the old main job's 1e6-ray launch) and the --reference launch (default
1e7 rays) traces the scene moved to each of --times; printed per time and setting: the
paths found, those of the reference and of the baseline it misses (with their object
sequences) and those beyond the reference (matched one to one: same interaction and
object sequence, |d tau| < 1 ps, clradcom.evaluation.peer). Then, at the first time,
the settings take turns --repeats times in this process (the geometry kept, one
untimed trace each first): medians of the candidate and specular stages
(clradcom.trace.StageTimes) and their sum over the baseline's. Options in error are one
line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from clradcom.cli import positive_int, run_tool
from clradcom.device.runtime import get_runtime
from clradcom.evaluation.peer import match_paths, sequences_of
from clradcom.scene.motion import scene_at
from clradcom.scene.reader import load_scene
from clradcom.trace import StageTimes, TraceSettings, trace_scene

REPO = Path(__file__).resolve().parent.parent
STREET = REPO / "scenes" / "street" / "street.toml"
STAGES = ("specular candidates", "specular")


def launch_setting(text: str) -> tuple[int, int | None]:
    """RAYS or RAYS:ROUNDS (rays as 3e5 or 300000; ROUNDS of candidate expansion)."""
    rays, _, rounds = text.strip().partition(":")
    try:
        n = float(rays)
        r = int(rounds) if rounds else None
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not RAYS or RAYS:ROUNDS") from None
    if not (n >= 1 and n == int(n)) or (r is not None and not 0 <= r <= 16):
        raise argparse.ArgumentTypeError(f"{text!r}: rays a positive whole number, rounds "
                                         "0 to 16")
    return int(n), r


def setting_list(text: str) -> list[tuple[int, int | None]]:
    items = [launch_setting(t) for t in text.split(",") if t.strip()]
    if not items:
        raise argparse.ArgumentTypeError(f"names no setting: {text!r}")
    return items


def time_list(text: str) -> list[float]:
    try:
        out = [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a list of times in s") from None
    if not out or not all(np.isfinite(out)):
        raise argparse.ArgumentTypeError(f"{text!r} is not a list of finite times in s")
    return out


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="bench_specular_sets.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=STREET, help="scene file (default the street)")
    ap.add_argument("--settings", type=setting_list, default=setting_list("1e6,3e5:4"),
                    help="RAYS[:ROUNDS],... the first is the baseline (default 1e6,3e5:4)")
    ap.add_argument("--reference", type=launch_setting, default=launch_setting("1e7"),
                    help="the dense launch held as complete (default 1e7)")
    ap.add_argument("--times", type=time_list, default=time_list("0,0.9"),
                    help="scene times in s, comma-separated (default 0,0.9)")
    ap.add_argument("--repeats", type=positive_int, default=3,
                    help="timed turns of each setting (default 3)")
    ap.add_argument("--device", default=None, help="OpenCL device (default: the default)")
    return ap


def specular_search(rays: int, rounds: int | None) -> TraceSettings:
    """The main job's specular search with ``rays`` and ``rounds``, nothing else."""
    main = TraceSettings.preset()
    return dataclasses.replace(
        TraceSettings.preset("go", diffraction__max_diffractions=0),
        specular=dataclasses.replace(main.specular, rays=rays, expand_rounds=rounds))


def name_of(setting) -> str:
    rays, rounds = setting
    return f"{rays:.0e}" + (f" + {rounds} rounds" if rounds else "")


def link_sets(snap):
    """Per link: its paths' (interaction, object) sequences, delays and name."""
    return [(sequences_of(lk.paths.interaction, lk.paths.n_interactions, lk.paths.object_id,
                          snap.object_names), lk.paths.delay_s, f"{lk.tx_name}->{lk.rx_name}")
            for lk in snap.links]


def spelled(link: str, sequence) -> str:
    return f"{link}: " + (" > ".join(name for _, name in sequence) or "line of sight")


def run(args) -> int:
    runtime = get_runtime(args.device)
    base_scene = load_scene(args.scene)
    print(f"device: {runtime.info.describe()}\nscene: {args.scene}")
    for t in args.times:
        scene = scene_at(base_scene, t)
        ref = link_sets(trace_scene(scene, specular_search(*args.reference), runtime=runtime))
        found = [link_sets(trace_scene(scene, specular_search(*s), runtime=runtime))
                 for s in args.settings]
        print(f"\nt = {t:g} s: reference {name_of(args.reference)} finds "
              f"{sum(len(d) for _, d, _ in ref)} paths")
        for setting, sets in zip(args.settings, found, strict=True):
            n = lost_ref = lost_base = beyond = 0
            lost = []
            for (seq, d, link), (rseq, rd, _), (bseq, bd, _) in zip(sets, ref, found[0],
                                                                  strict=True):
                m = match_paths(rseq, rd, seq, d)
                n += len(d)
                lost_ref += len(m.only_a)
                beyond += len(m.only_b)
                lost += [spelled(link, rseq[i]) for i in m.only_a]
                lost_base += len(match_paths(bseq, bd, seq, d).only_a)
            print(f"  {name_of(setting):18s} {n:4d} paths, misses {lost_ref} of the "
                  f"reference's and {lost_base} of {name_of(args.settings[0])}'s, {beyond} "
                  f"beyond the reference" + ("".join(f"\n      misses {x}" for x in lost)))
    scene = scene_at(base_scene, args.times[0])
    runs = [specular_search(*s) for s in args.settings]
    for s in runs:
        trace_scene(scene, s, runtime=runtime)
    seconds = {i: [] for i in range(len(runs))}
    for _ in range(args.repeats):
        for i, s in enumerate(runs):
            st = StageTimes()
            t0 = time.perf_counter()
            trace_scene(scene, s, runtime=runtime, times=st)
            seconds[i].append([st.seconds.get(k, 0.0) for k in STAGES]
                              + [time.perf_counter() - t0])
    print(f"\nt = {args.times[0]:g} s, medians of {args.repeats} turns each:")
    base = None
    for i, setting in enumerate(args.settings):
        cand, spec, whole = np.median(np.array(seconds[i]), axis=0)
        total = float(np.median(np.array(seconds[i])[:, :2].sum(axis=1)))
        base = total if base is None else base
        print(f"  {name_of(setting):18s} candidates {cand:.3f} s, specular {spec:.3f} s, "
              f"both {total:.3f} s ({total / base:.2f} of the baseline), trace {whole:.3f} s")
    return 0


def main(argv=None) -> int:
    return run_tool("bench_specular_sets.py", run, build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
