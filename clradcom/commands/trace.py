"""Run a scene end to end: trace every link, write the snapshot, run the radar.

    clradcom trace scenes/street/street.toml
    clradcom trace scenes/street/street.toml --preset fast --out out/quick

(``python tools/trace.py ...`` runs the same.) The physics is the preset's (--preset,
default "paper": 3e5 rays per transmitter with candidate expansion (the specular
paths of 1e6 rays or more), up to 5 reflections, 1 diffraction, PO + SBR
for conductors and bodies (|Gamma(0)|^2 >= -4 dB: metals of any conductivity, skin),
scattering from the trees; the same as trace_scene(scene) in Python); each option below
changes one knob of it.

Stages and what they write into the output folder (default: out/<scene name>/):

  1. trace      every transmitter -> receiver link with the OpenCL ray tracer
                (line of sight, specular reflections up to --reflections, single
                UTD edge diffraction, physical-optics returns of conductors and
                bodies (--optics NAME=po|both|go sets an object's own),
                Lambertian scattering from tiles of the trees); printed once
                first: which objects get which optics, and why
                -> snapshot.npz (documented in docs/snapshot-format.md)
  2. radar      for every radar that both transmits and receives: its own
                echoes (the monostatic link) drive the paper's OFDM frame
                (N = 1024, M = 256, 24 GHz), with thermal noise from the
                radar's tx_power_w and noise_figure_db, through the radar chain
                every tool shares (clradcom.radar.pipeline.radar_chain; a radar
                with an array: its TDM-MIMO cube, as clradcom cube)
                -> <radar>_image.png / .svg  range-Doppler image, detections marked
                -> <radar>_detections.csv    CFAR detections (range, velocity, power,
                                              SNR, aliased: 1 where only a path beyond
                                              the unambiguous range or velocity puts
                                              it there); those beyond the longest
                                              path, noise, are left out and printed
                -> <radar>_truth.csv         each moving object's set range and
                                              relative velocity beside the detection
                                              that matches it (or none)
                printed: the same table; for radar A of the paper's street
                (scenes/street/) the paper's Table III beside it, its set values
                and its own simulation's detections
  3. picture    scene_top.png: the scene from above, strongest paths drawn

Before anything is traced the run is checked whole: every option, the scene, the
radar stage's inputs (the waveform at the scene's carrier, each radar's noise figure
>= 0 dB), the memory the rays and the radar frame need (refused over the budget, half
the machine's memory or CLRADCOM_MEMORY_BUDGET, e.g. "24G"), and the output folder.
A radar with tx_power_w = 0 transmits nothing, so it has no echo: its image and tables
are left out, with a line saying so (its links are still traced into the snapshot).

The output folder is built beside the old one and swapped in when the run is done:
an interrupted or failed run leaves the old outputs as they were, and a finished one
never mixes them with new ones (files of this tool's names from an earlier run are
replaced as a whole; anything else in the folder, e.g. tools/tradeoff.py's tradeoff/,
is kept). Errors are one line on stderr, exit code 2. Warnings (e.g. a path
shorter than a wavelength) are shown once each as one line, with a count at the end.
A progress bar shows the tracer's links and mechanisms when stderr is a terminal
(--quiet turns it off).

The device is the default OpenCL device (a GPU where one exists, else PoCL's
CPU device); choose another with --device or CLRADCOM_DEVICE (list them with
`clradcom devices`).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from clradcom.commands.console import progress_bar, trace_steps
from clradcom.commands.options import (
    add_frame_arguments,
    add_waveform_arguments,
    command_parser,
    float_in,
    int_in,
    object_optics_pair,
    output_folder,
    positive_int,
    radar_waveforms,
    run_tool,
)
from clradcom.device.runtime import get_runtime
from clradcom.errors import ArgumentError, SceneError
from clradcom.files import staged_folder
from clradcom.mechanisms.common import ENGINES
from clradcom.mechanisms.optics import optics_summary
from clradcom.mechanisms.sbr import ACCURACY_DB_RANGE
from clradcom.plots import plot_top_view
from clradcom.presets import DEFAULT_PRESET, PRESETS
from clradcom.radar.pipeline import check_frame_memory, radar_chain
from clradcom.radar.plots import image_title, mounting_return_range_m, save_radar_image
from clradcom.radar.report import (
    DETECTION_COLUMNS,
    STATIC_RANGE_M,
    TRUTH_COLUMNS,
    detection_rows,
    display_range_db,
    match_tolerances,
    moving_objects,
    scene_reach_m,
    sorted_detections_line,
    static_returns_beyond,
    strongest_static_cell,
    truth_rows,
    truth_table_lines,
    write_table,
)
from clradcom.radar.synthesis import check_noise_figure
from clradcom.radar.truth import detection_truth, match_truth
from clradcom.scene.reader import load_scene
from clradcom.scene.records import SBR_SPACING_WAVELENGTHS, with_object_optics
from clradcom.snapshot import save_snapshot
from clradcom.trace import (
    StageTimes,
    TraceSettings,
    check_launch_memory,
    trace_scene,
)

#: the names this tool writes into its output folder (clradcom.files.staged_folder)
OUTPUTS = ("snapshot.npz", "*_image.png", "*_image.svg", "*_detections.csv", "*_truth.csv",
           "scene_top.png")
#: noise figure of a radar whose scene entry gives none
DEFAULT_NOISE_FIGURE_DB = 10.0


class Stopwatch:
    def __init__(self):
        self.t0 = time.perf_counter()
        self.rows = []

    def stage(self, name):
        sw = self

        class _Ctx:
            def __enter__(self):
                print(f"[{time.perf_counter() - sw.t0:7.2f} s] {name} ...", flush=True)
                self.start = time.perf_counter()

            def __exit__(self, *exc):
                sw.rows.append((name, time.perf_counter() - self.start))

        return _Ctx()


def preset_help() -> str:
    """The presets, one line each, for --help."""
    return "; ".join(f"{p.name}: {p.summary}" for p in PRESETS.values())


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    return command_parser(__doc__, add_arguments, prog)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``clradcom trace`` / tools/trace.py."""
    ap.add_argument("scene", help="scene file (TOML), e.g. scenes/street/street.toml")
    ap.add_argument("--out", type=output_folder, default=None,
                    help="output folder (default out/<scene name>)")
    ap.add_argument("--device", default=None,
                    help="OpenCL device: 'gpu', 'cpu', 'P:D' or part of its name")
    ap.add_argument("--preset", choices=tuple(PRESETS), default=DEFAULT_PRESET,
                    help=f"the tracer's physics (default {DEFAULT_PRESET}); the options "
                         f"below change one knob of it. {preset_help()}")
    ap.add_argument("--rays", type=positive_int, default=None,
                    help="rays launched per transmitter over its pattern (paper: 3e5, then "
                         "candidate expansion)")
    ap.add_argument("--expand-rounds", type=int_in(0, 16), default=None,
                    help="rounds of specular candidate expansion after the launch: paths "
                         "one reflection away from those found, confirmed exactly (paper: "
                         "4; 0: the launch's candidates only; docs/performance.md)")
    ap.add_argument("--reflections", type=int_in(0, 16), default=None,
                    help="maximum specular reflections per path (paper: 5)")
    ap.add_argument("--diffractions", type=int, choices=(0, 1, 2, 3), default=None,
                    help="UTD edge diffractions per path (paper: 1; 0 turns them off)")
    ap.add_argument("--diffraction-reflections", type=int_in(0, 16), default=None,
                    help="reflections allowed beside the edges of a diffracted path "
                         "(paper: 0; each one costs seconds on the street, see "
                         "tools/bench_paths.py)")
    ap.add_argument("--physical-optics", choices=("none", "pec", "sbr"), default=None,
                    help="sbr (paper): conductors and bodies (PEC, any metal, skin: "
                         "|Gamma(0)|^2 >= -4 dB) return their physical-optics facet "
                         "integrals instead of single GO mirror paths, and shooting-and-"
                         "bouncing-ray PO for their multi-bounce returns (what puts car D "
                         "where the paper has it); pec: facets only; none: pure GO (an "
                         "object's own `optics` key, or --optics, always wins)")
    ap.add_argument("--optics", type=object_optics_pair, action="append", default=[],
                    metavar="NAME=OPTICS",
                    help="an object's own optics, as its scene key `optics` would set it: "
                         "po (PO facets + SBR-PO), both (PO facets, GO multi-bounce) or go; "
                         "NAME may be a pattern (car*, 'buildings/*'); repeat for more "
                         "objects, later ones win")
    ap.add_argument("--sbr-spacing", type=float_in(*SBR_SPACING_WAVELENGTHS), default=None,
                    metavar="WAVELENGTHS",
                    help="pitch of the SBR ray tubes at each object, in wavelengths "
                         f"({SBR_SPACING_WAVELENGTHS[0]:g} to {SBR_SPACING_WAVELENGTHS[1]:g}; "
                         "default: chosen per object for --sbr-accuracy); an "
                         "object's own sbr_spacing_wavelengths key wins")
    ap.add_argument("--no-sbr-mirrors", action="store_true",
                    help="launch SBR tubes at the objects only, not also at their mirror "
                         "images in the road and facades (returns lit by one reflection "
                         "there)")
    ap.add_argument("--sbr-accuracy", type=float_in(*ACCURACY_DB_RANGE), default=None,
                    metavar="DB",
                    help="the error (dB) the SBR tube grid may add to a corner's return, "
                         "from which the pitch is chosen when --sbr-spacing is not given "
                         "(paper: 0.5; docs/po.md)")
    ap.add_argument("--no-scattering", action="store_true",
                    help="leave out single Lambertian scattering from tiles of materials with "
                         "a scattering coefficient (the trees)")
    ap.add_argument("--scattering-reflections", type=int, choices=(0, 1, 2), default=None,
                    help="specular reflections around a scattering tile: 0 (paper) direct "
                         "only, 1 one before or after it, 2 also one on each side")
    ap.add_argument("--engine", choices=ENGINES, default="device",
                    help="device (default): interactions resolved in OpenCL kernels; host: "
                         "the numpy reference the device engine is tested against")
    add_frame_arguments(ap)
    ap.add_argument("-q", "--quiet", action="store_true",
                    help="no progress bar (it is shown only when stderr is a terminal)")
    add_waveform_arguments(ap)


#: option -> TraceSettings field it sets (None: the preset's value stands)
SETTING_OPTIONS = {
    "rays": "specular__rays", "expand_rounds": "specular__expand_rounds",
    "reflections": "specular__max_reflections",
    "diffractions": "diffraction__max_diffractions",
    "diffraction_reflections": "diffraction__max_reflections",
    "physical_optics": "optics__mode", "sbr_spacing": "optics__sbr_spacing_wavelengths",
    "sbr_accuracy": "optics__sbr_accuracy_db",
    "scattering_reflections": "scattering__max_reflections",
}


def settings_from_args(args) -> TraceSettings:
    """The tracer settings of a parsed command line: the preset (--preset, default
    ``paper``) with the options given changed (tests and tools/bench_trace.py reuse the
    tool's defaults)."""
    changes = {field: getattr(args, option) for option, field in SETTING_OPTIONS.items()
               if getattr(args, option, None) is not None}
    if args.no_sbr_mirrors:
        changes["optics__sbr_mirrors"] = False
    if args.no_scattering:
        changes["scattering__enabled"] = False
    return TraceSettings.preset(getattr(args, "preset", DEFAULT_PRESET), engine=args.engine,
                                **changes)


def launch_rays(settings: TraceSettings, args) -> tuple[str, object]:
    """The option and value to name when the ray launch is over the memory budget."""
    if args.rays is not None:
        return "--rays", args.rays
    return "--preset", f"{getattr(args, 'preset', DEFAULT_PRESET)} " \
                       f"({settings.specular.rays} rays; give fewer with --rays)"


def radar_noise(scene, args) -> dict[int, float | None]:
    """Noise figure (None: no noise) of every radar whose own echoes are imaged, checked
    before tracing: a noise figure below 0 dB is refused naming the scene's key."""
    out = {}
    for i, radar in enumerate(scene.radars):
        if radar.role != "txrx":
            continue
        if args.no_noise:
            out[i] = None
            continue
        nf = radar.noise_figure_db
        if nf is None:
            out[i] = DEFAULT_NOISE_FIGURE_DB
            continue
        try:
            out[i] = check_noise_figure(nf)
        except ValueError as exc:
            raise SceneError(exc.reason, file=scene.source,
                             key=f"radars[{i}].noise_figure_db", value=nf) from None
    return out


def main(argv=None, prog: str = "trace.py") -> int:
    args = build_parser(prog).parse_args(argv)
    return run_tool(prog, run, args)


def run(args) -> int:
    sw = Stopwatch()
    # everything the run will refuse, before it starts
    settings = settings_from_args(args)
    option, value = launch_rays(settings, args)
    check_launch_memory(settings, argument=option, value=value)
    with sw.stage("load scene"):
        scene = load_scene(args.scene)
        if getattr(args, "optics", None):
            scene = with_object_optics(scene, args.optics, argument="--optics")
    frames, lines = radar_waveforms(scene, args, imaged_radars(scene))
    for line in lines:
        print(f"  {line}")
    for wf in frames.values():
        check_frame_memory(wf, args.synthesis)
    noise = radar_noise(scene, args)
    out = Path(args.out or Path("out") / scene.name)
    with staged_folder(out, inputs=scene.input_files, owned=OUTPUTS) as stage:
        with sw.stage("open OpenCL device"):
            runtime = get_runtime(args.device)
        print(f"  device: {runtime.info.describe()}")
        for line in optics_summary(scene, settings.optics.mode):
            print(f"  {line}")
        times = StageTimes()
        with sw.stage(f"trace {len(scene.triangles)} triangles, {settings.specular.rays} "
                      f"rays per tx ({describe_settings(args, settings)})"), \
                progress_bar(None, "trace", quiet=args.quiet, unit="link") as bar:
            try:
                snap = trace_scene(scene, settings, runtime=runtime, times=times,
                                   progress=lambda m: bar.write(f"    {m}"),
                                   steps=trace_steps(bar))
            except ValueError as exc:
                if isinstance(exc, SceneError | ArgumentError):
                    raise
                # a mechanism's refusal of something in this scene
                raise SceneError(str(exc), file=scene.source) from exc
        for k, v in times.seconds.items():
            print(f"    {k:<20} {v:7.2f} s")
        with sw.stage("write snapshot"):
            save_snapshot(stage / "snapshot.npz", snap)
        print(snap.summary())
        for link in snap:
            if link.tx_index != link.rx_index:
                continue
            radar = scene.radars[link.tx_index]
            if radar.tx_power_w == 0:
                print(f"  {radar.name}: tx_power_w = 0 W: it transmits nothing, so it has no "
                      "echo; no radar image or tables for it")
                continue
            radar_stage(sw, args, scene, frames[link.tx_index], link, radar,
                        noise[link.tx_index], stage)
        with sw.stage("top view"):
            mono = [lk for lk in snap if lk.tx_index == lk.rx_index]
            plot_top_view(scene, snap, mono[0] if mono else None, path=stage / "scene_top.png")
    print("\nstage timings:")
    for name, dt in sw.rows:
        print(f"  {dt:8.2f} s  {name}")
    print(f"outputs in {out}/")
    return 0


def imaged_radars(scene) -> list[int]:
    """The radars whose own echoes a run images: those that transmit and receive."""
    return [i for i, r in enumerate(scene.radars) if r.role == "txrx"]


def describe_settings(args, settings: TraceSettings) -> str:
    """``preset paper`` and the options that changed it, for the trace stage's line."""
    name = getattr(args, "preset", DEFAULT_PRESET)
    base = TraceSettings.preset(name).metadata()
    changed = [f"{k.removeprefix('settings.')}={v}" for k, v in settings.metadata().items()
               if base.get(k) != v]
    return f"preset {name}" + (f", {', '.join(changed)}" if changed else "")


def radar_stage(sw, args, scene, wf, link, radar, nf, stage) -> None:
    """One radar's own echoes: frame, image, detections, truth; printed and written."""
    with sw.stage(f"radar {radar.name}: synthesise ({args.synthesis}), process, CFAR"):
        res = radar_chain(link.paths, wf, radar=radar, seed=args.seed, method=args.synthesis,
                          tx_power_w=radar.tx_power_w if nf is not None else None,
                          noise_figure_db=nf)
        image, dets = res.image, res.detections
    with sw.stage(f"radar {radar.name}: image and tables"):
        truth = detection_truth(scene, radar.name, moving_objects(scene, radar))
        # colour down to the noise floor, so weak echoes beside the ground return show;
        # 0 dB: the strongest return beyond the radar's own mounting return, where it has
        # one
        save_radar_image(image, stage / f"{radar.name}_image", dets,
                         dynamic_range_db=display_range_db(image),
                         title=image_title(radar.name, scene.name), truth=truth,
                         mount_range_m=mounting_return_range_m(link.paths,
                                                               wf.range_resolution))
        write_table(stage / f"{radar.name}_detections.csv", detection_rows(dets, res.aliased),
                    DETECTION_COLUMNS)
        matches = match_truth(dets, truth, *match_tolerances(wf))
        rows = truth_rows(truth, matches)
        sorted_line = sorted_detections_line(res)
        print(f"  {radar.name}: {len(dets)} detections"
              + (f" ({sorted_line})" if sorted_line else "") + "; moving objects:")
        for line in truth_table_lines(radar.name, truth, rows):
            print(line)
        static = static_returns_beyond(dets, radar, STATIC_RANGE_M, wf.velocity_resolution)
        rng, above = strongest_static_cell(image, radar, STATIC_RANGE_M,
                                           scene_reach_m(scene, radar.position),
                                           wf.velocity_resolution)
        print(f"    static returns beyond {STATIC_RANGE_M:.0f} m at the radar's own speed "
              f"({np.linalg.norm(radar.velocity):.1f} m/s): {len(static)} detections"
              + (f", at {', '.join(f'{r:.1f}' for r in static[:6])} m" if static else "")
              + ("" if rng is None else f"; strongest cell {rng:.1f} m, {above:.1f} dB "
                 f"over the image's median"))
        write_table(stage / f"{radar.name}_truth.csv", rows, TRUTH_COLUMNS)

