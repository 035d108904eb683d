#!/usr/bin/env python3
"""The SBR pitch rule against the corners' closed forms: error (dB) per size and target.

    python tools/sbr_pitch.py [--sizes 1,2,3,...] [--accuracies 0.25,0.5,1] [--device SPEC]

For the 90 degree dihedral (square plates, or --width-ratio times the fold) and the square
trihedral (clradcom.evaluation.corners), at each size (in wavelengths at 24 GHz) and each
``sbr_accuracy_db`` target, the pitch that clradcom.mechanisms.sbr.spacing_for_accuracy
chooses, and the monostatic RCS error against the closed form: the SBR part (bounces 2
and 3, what the closed form describes) and the total with the first bounce's PO facets,
the worse of VV and HH each. Prints a markdown table (docs/po.md shows it) and the worst
|error| / target per corner; exit code 1 if an SBR part misses its target.
"""

from __future__ import annotations

import argparse
import sys
import time

from clradcom.commands.options import list_of, positive_float, run_tool
from clradcom.device.runtime import get_runtime
from clradcom.evaluation.corners import CORNERS, pitch_sweep
from clradcom.physics.em import C0

SIZES = [1, 1.5, 2, 3, 4.5, 7, 10, 15, 24, 37, 50, 70, 100]
ACCURACIES = [0.25, 0.5, 1.0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=list_of(positive_float, "size"), default=SIZES,
                    help="corner sizes in wavelengths (fold and edge)")
    ap.add_argument("--accuracies", type=list_of(positive_float, "accuracy"),
                    default=ACCURACIES, help="sbr_accuracy_db targets")
    ap.add_argument("--corners", type=list_of(str, "corner"), default=list(CORNERS))
    ap.add_argument("--width-ratio", type=positive_float, default=1.0,
                    help="dihedral plate width / fold length")
    ap.add_argument("--engine", choices=("device", "host"), default="device")
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    return run_tool("sbr_pitch.py", run, args)


def run(args) -> int:
    runtime = get_runtime(args.device)
    lam = C0 / 24e9
    t0 = time.perf_counter()
    rows = pitch_sweep(args.corners, args.sizes, args.accuracies, runtime,
                       width_ratio=args.width_ratio, engine=args.engine)
    print(f"# {runtime.info.describe()}, engine {args.engine}, dihedral width ratio "
          f"{args.width_ratio:g}, {time.perf_counter() - t0:.1f} s")
    print("| corner | size (λ) | target (dB) | pitch (λ) | SBR part VV / HH (dB) "
          "| total VV / HH (dB) |")
    print("|---|---|---|---|---|---|")
    worst: dict[str, float] = {}
    for e in rows:
        print(f"| {e.kind} | {e.size_m / lam:g} | {e.accuracy_db:g} | "
              f"{e.spacing_m / lam:.3f} | {e.sbr_db[0]:+.3f} / {e.sbr_db[1]:+.3f} | "
              f"{e.total_db[0]:+.3f} / {e.total_db[1]:+.3f} |")
        worst[e.kind] = max(worst.get(e.kind, 0.0), abs(e.worst_sbr_db) / e.accuracy_db)
    for kind, w in worst.items():
        print(f"{kind}: worst |SBR part error| / target = {w:.2f}")
    return 0 if all(w <= 1.0 for w in worst.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
