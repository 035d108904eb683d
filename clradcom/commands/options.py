"""What every command shares (``clradcom <command>`` and the scripts in tools/):

* option types for argparse and :func:`run_tool`, the error boundary (defined in
  :mod:`clradcom.commands.arguments`, which loads neither the tracer nor Dask, and
  re-exported here);
* :func:`add_waveform_arguments` / :func:`run_waveform`: the frame of every command that
  makes one (trace, radar, cube, interference, comms, tradeoff), from the options, the
  scene's ``[waveform]`` and the paper's defaults, in that order of precedence, with the
  cyclic prefix rounded to whole samples and the rounding stated; refusals name the
  option or the scene's file and key, and the value;
* :func:`command_parser` / :func:`parse_command`: a command's parser from its docstring
  and its ``add_arguments``, and the parse with its own ``check_args``;
* :func:`preset_settings`, :func:`read_snapshot`, :func:`trace_into`: what the commands
  that take "a scene to trace or a snapshot" share.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np

from clradcom.commands.arguments import (
    TOOL_ERRORS,
    finite_float,
    float_in,
    int_in,
    list_of,
    noise_figure_db,
    non_negative_float,
    non_negative_int,
    output_folder,
    positive_float,
    positive_int,
    run_tool,
    seed,
)
from clradcom.commands.console import progress_bar, trace_steps
from clradcom.device.runtime import (
    get_runtime,
)
from clradcom.errors import (
    ArgumentError,
    SceneError,
    SnapshotError,
)
from clradcom.mechanisms.common import ENGINES
from clradcom.presets import DEFAULT_PRESET, PRESETS
from clradcom.radar.fmcw import FmcwWaveform
from clradcom.radar.pipeline import SYNTHESIS_METHODS, check_frame_memory
from clradcom.radar.synthesis import check_noise_figure
from clradcom.radar.waveform import Waveform, round_cyclic_prefix
from clradcom.scene.motion import MAX_TIME_STEPS
from clradcom.scene.records import MODULATIONS, OPTICS, FmcwSpec
from clradcom.snapshot import Snapshot, load_snapshot, save_snapshot
from clradcom.trace import TraceSettings, trace_scene


def object_optics_pair(text) -> tuple[str, str]:
    """``NAME=OPTICS``: an object (its name, or an fnmatch pattern such as ``car*``) and
    its optics, one of :data:`~clradcom.scene.records.OPTICS`."""
    name, sep, optics = str(text).partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"must be NAME=OPTICS with OPTICS one of "
                                         f"{', '.join(OPTICS)} (e.g. carA=po), got {text!r}")
    if optics.strip() not in OPTICS:
        raise argparse.ArgumentTypeError(f"must be NAME=OPTICS with OPTICS one of "
                                         f"{', '.join(OPTICS)}, got {text!r}")
    return name.strip(), optics.strip()


# ----------------------------------------------------------------------------------------
# the frame from the options, the scene's [waveform] and the paper
# ----------------------------------------------------------------------------------------
#: option of each waveform parameter (the attribute argparse gives it)
WAVEFORM_OPTIONS = {"subcarriers": "--subcarriers", "symbols": "--symbols",
                    "subcarrier_spacing": "--subcarrier-spacing",
                    "cyclic_prefix": "--cyclic-prefix", "cp_samples": "--cp-samples",
                    "modulation": "--modulation"}


def add_sequence_arguments(ap: argparse.ArgumentParser, *,
                           count_help: str = "number of instants") -> None:
    """--start, --step and --count: the instants of a moving scene, over its [time]
    table (:func:`sequence_times`)."""
    ap.add_argument("--start", type=finite_float, default=None,
                    help="first instant (s; default the [time] table's start_s, else 0)")
    ap.add_argument("--step", type=positive_float, default=None, help="time step (s)")
    ap.add_argument("--count", type=int_in(1, MAX_TIME_STEPS), default=None, help=count_help)


def sequence_times(scene, args) -> np.ndarray:
    """The instants (s) of a sequence: --start/--step/--count where given, else the
    scene's [time] table; one instant needs no step. Refused naming --step when neither
    gives a step and a count."""
    axis = scene.time_axis
    start = args.start if args.start is not None else (axis.start_s if axis else 0.0)
    step = args.step if args.step is not None else (axis.step_s if axis else None)
    count = args.count if args.count is not None else (axis.count if axis else None)
    if count == 1 and step is None:
        step = 1.0
    if step is None or count is None:
        raise ArgumentError(f"{args.scene} has no [time] table: give --step and --count",
                            argument="--step", value=None)
    return start + step * np.arange(count, dtype=np.float64)


def add_tracer_arguments(ap: argparse.ArgumentParser, *,
                         device_help: str = "OpenCL device: 'gpu', 'cpu', 'P:D' or part of "
                                            "its name") -> None:
    """The tracer's knobs of a command that traces a sequence: --preset, --rays,
    --reflections, --no-scattering, --engine and --device (read by
    :func:`clradcom.commands.trace.settings_from_args`)."""
    ap.add_argument("--preset", choices=tuple(PRESETS), default=DEFAULT_PRESET,
                    help="the tracer's physics (default %(default)s)")
    ap.add_argument("--rays", type=int_in(1, 10**9), default=None,
                    help="rays launched per transmitter")
    ap.add_argument("--reflections", type=int_in(0, 16), default=None,
                    help="most specular reflections per path")
    ap.add_argument("--no-scattering", action="store_true", help="no diffuse scattering")
    ap.add_argument("--engine", choices=ENGINES, default="device",
                    help="device (default) or host (the numpy reference)")
    ap.add_argument("--device", default=None, help=device_help)
    ap.set_defaults(no_sbr_mirrors=False)


def add_scene_or_snapshot_arguments(ap: argparse.ArgumentParser, tool: str) -> None:
    """The inputs and output of a command that traces a scene or reads a snapshot of one
    (:func:`check_two_radars` refuses both or neither): the scene file, --snapshot,
    --out (default out/``tool``), and the tracer's --device, --preset and --rays for the
    scene."""
    ap.add_argument("scene", nargs="?", help="scene file (TOML) to trace, e.g. "
                    "scenes/street/street.toml; leave out when giving --snapshot")
    ap.add_argument("--snapshot", help="an existing snapshot.npz (from clradcom trace)")
    ap.add_argument("--out", type=output_folder, default=f"out/{tool}",
                    help=f"output folder (default out/{tool})")
    ap.add_argument("--device", default=None, help="OpenCL device for tracing a scene")
    ap.add_argument("--preset", choices=tuple(PRESETS), default=DEFAULT_PRESET,
                    help=f"the tracer's physics when tracing a scene (default "
                         f"{DEFAULT_PRESET}, as clradcom trace; see clradcom presets)")
    ap.add_argument("--rays", type=positive_int, default=None,
                    help="rays per transmitter when tracing a scene (default: the "
                         "preset's, 1e6 for paper)")


def check_two_radars(ap: argparse.ArgumentParser, args, first: str, second: str) -> None:
    """What argparse alone cannot refuse in a command between two radars of a scene or a
    snapshot: exactly one of the scene file and --snapshot, and two different radars
    (the options ``first`` and ``second``, e.g. "--tx" and "--rx")."""
    if (args.scene is None) == (args.snapshot is None):
        ap.error("give either a scene file or --snapshot (exactly one)")
    a = getattr(args, first.lstrip("-").replace("-", "_"))
    if a == getattr(args, second.lstrip("-").replace("-", "_")):
        ap.error(f"{second} must be another radar than {first} ({a!r})")


def scene_radar_indices(scene, args, *options: str) -> list[int]:
    """The indices in ``scene.radars`` of the radars that ``options`` (e.g. "--tx",
    "--rx") name; one the scene lacks refused naming the option and the scene's radars."""
    names = [r.name for r in scene.radars]
    picked = [getattr(args, o.lstrip("-").replace("-", "_")) for o in options]
    for option, name in zip(options, picked, strict=True):
        if name not in names:
            raise ArgumentError(f"{args.scene} has no radar of that name (radars: "
                                f"{sorted(names)})", argument=option, value=name)
    return [names.index(name) for name in picked]


def scene_noise_figure(scene, index: int, fallback: float) -> float:
    """Radar ``index``'s noise figure in dB (``fallback``, the option's, where the scene
    gives none), refused by its scene key where it is not a usable one."""
    nf = scene.radars[index].noise_figure_db
    nf = fallback if nf is None else nf
    try:
        check_noise_figure(nf)
    except ArgumentError as exc:
        raise SceneError(exc.reason, file=scene.source,
                         key=f"radars[{index}].noise_figure_db", value=nf) from None
    return nf


def check_exact_frame_memory(wf: Waveform) -> None:
    """The frame of an exact time-domain synthesis with two copies fits in memory; else
    refused naming --subcarriers x --symbols."""
    check_frame_memory(wf, "exact", copies=2, argument="--subcarriers x --symbols",
                       value=f"{wf.n_subcarriers} x {wf.n_symbols}",
                       advice="choose fewer --subcarriers or --symbols")


def add_frame_arguments(ap, *, seed_help: str = "seed of the random OFDM data (an "
                        "integer >= 0; the noise uses seed + 1)") -> None:
    """--synthesis, --seed and --no-noise: how a radar frame is made from the paths
    (``ap``: a parser or an argument group)."""
    ap.add_argument("--synthesis", choices=SYNTHESIS_METHODS, default="fast",
                    help="fast: frequency-domain model; exact: time-domain with ICI/ISI")
    ap.add_argument("--seed", type=seed, default=0, help=seed_help)
    ap.add_argument("--no-noise", action="store_true", help="leave thermal noise out")


def add_waveform_arguments(ap: argparse.ArgumentParser, *,
                           modulations: tuple[str, ...] = MODULATIONS,
                           modulation_help: str = "the radar's random symbols") -> None:
    """The options that set the radar frame; each left out falls back to the scene's
    ``[waveform]``, then to the paper's Table I. ``modulations``: the choices of
    ``--modulation`` (a command that decodes fewer, such as comms, narrows them;
    :func:`run_waveform` then refuses a scene's other modulation by its key)."""
    g = ap.add_argument_group("waveform (over the scene's [waveform], over the paper's "
                              "Table I)")
    g.add_argument("--subcarriers", type=positive_int, default=None,
                   help="N, subcarriers (paper: 1024)")
    g.add_argument("--symbols", type=positive_int, default=None,
                   help="M, OFDM symbols per frame (paper: 256)")
    g.add_argument("--subcarrier-spacing", type=positive_float, default=None, metavar="HZ",
                   help="Δf in Hz (paper: 90909); T = 1/Δf")
    g.add_argument("--cyclic-prefix", type=non_negative_float, default=None,
                   metavar="SECONDS", help="T_CP in seconds, rounded to the nearest whole "
                   "sample at f_s = NΔf (paper: 1.375e-6)")
    g.add_argument("--cp-samples", type=non_negative_int, default=None,
                   help="the cyclic prefix in samples at f_s = NΔf")
    g.add_argument("--modulation", choices=modulations, default=None,
                   help=f"{modulation_help} (paper: qpsk)")


class _Sources:
    """Where each waveform parameter came from, to name it in a refusal."""

    def __init__(self, scene, snapshot, radar=None):
        self.scene, self.snapshot, self.where = scene, snapshot, {}
        self.spec, self.prefix = (None, "waveform") if scene is None \
            else scene.radar_waveform(radar)

    def pick(self, name, args, attrs, spec_keys, default):
        """The first of: the options ``attrs``, the scene's ``spec_keys``, ``default``;
        returns {attr or key: value} of the source that gave any."""
        given = {a: getattr(args, a, None) for a in attrs}
        given = {a: v for a, v in given.items() if v is not None}
        if given:
            self.where[name] = ("option", given)
            return given
        spec = self.spec
        if spec is not None:
            given = {k: getattr(spec, k) for k in spec_keys}
            given = {k: v for k, v in given.items() if v is not None}
            if given:
                self.where[name] = ("scene", given)
                return given
        self.where[name] = ("default", default)
        return dict(default)

    def refuse(self, name, reason, which=None):
        """The error naming the option or scene key that gave ``name``."""
        kind, given = self.where[name]
        keys = [which] if which in given else list(given)
        if kind == "option":
            value = given[keys[0]] if len(keys) == 1 else ", ".join(
                f"{WAVEFORM_OPTIONS[k]} {given[k]!r}" for k in keys)
            return ArgumentError(reason, argument=" and ".join(WAVEFORM_OPTIONS[k]
                                                                for k in keys), value=value)
        if kind == "scene":
            value = given[keys[0]] if len(keys) == 1 else {k: given[k] for k in keys}
            return SceneError(reason, file=self.scene.source,
                              key=" and ".join(f"{self.prefix}.{k}" for k in keys),
                              value=value)
        return ArgumentError(f"the paper's default {reason}; set it with an option or in "
                             "the scene's [waveform]", argument=name,
                             value=next(iter(given.values())))


def run_waveform(carrier_hz: float, args, *, scene=None, snapshot=None,
                 modulations: tuple[str, ...] | None = None,
                 fmcw: bool = False,
                 radar: int | None = None) -> tuple[Waveform | FmcwWaveform, str]:
    """The radar frame of a run and the line that states it (with the cyclic prefix's
    rounding): each parameter from the options in ``args`` (those of
    :func:`add_waveform_arguments`; absent attributes count as not given), else the
    scene's ``[waveform]`` (``scene.waveform``), else the paper's Table I. A refusal
    names the option (ArgumentError) or the scene's file and key (SceneError) and the
    value: N or M not positive, T against Δf, a cyclic prefix given in seconds and in
    samples that disagree, one not shorter than the symbol, an unknown modulation (or one
    outside ``modulations`` when given), a carrier below half the bandwidth. A scene
    whose ``[waveform]`` is ``kind = "fmcw"`` gives its chirp sequence
    (:func:`fmcw_run_waveform`) where the command runs one (``fmcw``), else is refused
    by that key. ``radar`` (an index into ``scene.radars``): that radar's frame, from
    its own ``waveform`` table where it has one (refusals then name
    ``radars[i].waveform.<key>``), else the scene's."""
    spec, prefix = (None, "waveform") if scene is None else scene.radar_waveform(radar)
    if isinstance(spec, FmcwSpec):
        if not fmcw:
            raise SceneError("this command runs the OFDM radar only (trace, radar, cube and "
                             "drive run an FMCW one)", file=scene.source,
                             key=f"{prefix}.kind", value="fmcw")
        return fmcw_run_waveform(carrier_hz, args, scene, spec=spec, key_prefix=prefix)
    paper = Waveform()
    src = _Sources(scene, snapshot, radar)
    n = src.pick("subcarriers", args, ["subcarriers"], ["subcarriers"],
                 {"subcarriers": paper.n_subcarriers})
    n = next(iter(n.values()))
    m = src.pick("symbols", args, ["symbols"], ["symbols"], {"symbols": paper.n_symbols})
    m = next(iter(m.values()))
    for name, value in (("subcarriers", n), ("symbols", m)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise src.refuse(name, "must be a positive integer")
    spacing = src.pick("spacing", args, ["subcarrier_spacing"],
                       ["subcarrier_spacing_hz", "useful_duration_s"],
                       {"subcarrier_spacing": paper.subcarrier_spacing_hz})
    df = spacing.get("subcarrier_spacing", spacing.get("subcarrier_spacing_hz"))
    useful = spacing.get("useful_duration_s")
    if df is None:  # the scene gave T alone
        df = 1.0 / useful
        useful = None
    modulation = next(iter(src.pick("modulation", args, ["modulation"], ["modulation"],
                                    {"modulation": paper.modulation}).values()))
    if modulations is not None and modulation not in modulations:
        raise src.refuse("modulation", f"is not one this command decodes "
                         f"({', '.join(modulations)})")
    fs = n * df
    cp = src.pick("cyclic_prefix", args, ["cyclic_prefix", "cp_samples"],
                  ["cyclic_prefix_s", "cyclic_prefix_samples"],
                  {"cyclic_prefix": paper.cp_s})
    cp_s = cp.get("cyclic_prefix", cp.get("cyclic_prefix_s"))
    cp_n = cp.get("cp_samples", cp.get("cyclic_prefix_samples"))
    rate = f"{fs / 1e6:.6g} MHz = N·Δf = {n} × {df / 1e3:.6g} kHz"
    if cp_s is not None:
        rounded = round_cyclic_prefix(cp_s, fs)
        if cp_n is not None and cp_n != rounded:
            raise src.refuse("cyclic_prefix", f"disagree: {cp_s!r} s is {cp_s * fs:.4f} "
                             f"samples at {rate}, which rounds to {rounded}, not {cp_n}")
        n_cp = rounded
        statement = (f"cyclic prefix {cp_s * 1e6:.6g} µs → {n_cp} samples = "
                     f"{n_cp / fs * 1e6:.4f} µs at {rate} (rounded to the nearest whole "
                     "sample, halves up)")
    else:
        n_cp = cp_n
        statement = (f"cyclic prefix {n_cp} samples = {n_cp / fs * 1e6:.4f} µs at {rate}")
    if n_cp >= n:
        raise src.refuse("cyclic_prefix", f"gives {n_cp} samples, not shorter than the "
                         f"symbol it precedes (N = {n} samples, T = 1/Δf = "
                         f"{1e6 / df:.6g} µs)")
    kw = dict(carrier_hz=carrier_hz, n_subcarriers=n, n_symbols=m,
              subcarrier_spacing_hz=df, cp_s=n_cp / fs, modulation=modulation,
              useful_duration_s=useful)
    try:
        wf = Waveform(**kw)
    except ArgumentError as exc:
        if exc.argument == "carrier_hz" and scene is not None:
            raise SceneError(f"the radar's carrier {exc.reason}", file=scene.source,
                             key="scene.carrier_hz", value=carrier_hz) from None
        if exc.argument == "carrier_hz" and snapshot is not None:
            raise SnapshotError(f"carrier_hz = {carrier_hz!r}: {exc.reason}", file=snapshot,
                                key="meta/carrier_hz") from None
        name = {"n_subcarriers": "subcarriers", "n_symbols": "symbols",
                "subcarrier_spacing_hz": "spacing", "useful_duration_s": "spacing",
                "modulation": "modulation", "cp_s": "cyclic_prefix"}.get(exc.argument)
        if name is None:
            raise
        raise src.refuse(name, exc.reason, which=exc.argument) from None
    head = (f"waveform: f_c {carrier_hz / 1e9:.6g} GHz, N {n}, M {m}, Δf "
            f"{df / 1e3:.6g} kHz, {wf.modulation}; Δr {wf.range_resolution:.4g} m, "
            f"Δv {wf.velocity_resolution:.4g} m/s")
    return wf, f"{head}\n  {statement}"


def refuse_radar_waveforms(scene, command: str) -> None:
    """For a command that builds one frame for the whole scene: a radar's own waveform
    table, which it would not read, refused by its key (never silently the scene's)."""
    for i, r in enumerate(scene.radars):
        if r.waveform is not None:
            raise SceneError(f"clradcom {command} builds one frame for the scene and does "
                             "not read a radar's own waveform; give the frame in the "
                             "scene's [waveform]", file=scene.source,
                             key=f"radars[{i}].waveform", value=r.waveform.hash_params())


def radar_waveforms(scene, args, indices, *, fmcw: bool = True) -> tuple[dict, list[str]]:
    """Each radar's frame (:func:`run_waveform` with ``radar``) for the radars
    ``indices`` of ``scene``: ({index: waveform}, the lines that state them). Where no
    radar has its own ``waveform`` table, one line, as for a single frame; else one per
    radar, led by its name."""
    indices = list(indices)
    if not indices:  # nothing to image: the frame is still checked and stated
        return {}, [run_waveform(scene.carrier_hz, args, scene=scene, fmcw=fmcw)[1]]
    frames = {i: run_waveform(scene.carrier_hz, args, scene=scene, fmcw=fmcw, radar=i)
              for i in indices}
    if all(scene.radars[i].waveform is None for i in indices):
        lines = [next(iter(frames.values()))[1]] if frames else []
    else:
        lines = [f"{scene.radars[i].name}: {line}" for i, (_, line) in frames.items()]
    return {i: wf for i, (wf, _) in frames.items()}, lines


#: ``[waveform] kind = "fmcw"`` key -> :class:`FmcwWaveform` field
FMCW_SCENE_KEYS = {"start_frequency_hz": "start_hz", "sweep_bandwidth_hz": "sweep_bandwidth_hz",
                   "chirp_duration_s": "chirp_s", "idle_duration_s": "idle_s",
                   "chirps": "n_chirps", "adc_sample_rate_hz": "adc_rate_hz",
                   "samples_per_chirp": "samples_per_chirp", "adc_start_s": "adc_start_s",
                   "if_type": "if_type", "if_bandwidth_hz": "if_bandwidth_hz",
                   "if_filter_order": "if_filter_order",
                   "phase_noise_offsets_hz": "phase_noise_offsets_hz",
                   "phase_noise_dbc_per_hz": "phase_noise_dbc_per_hz"}


def fmcw_run_waveform(carrier_hz: float, args, scene, *, spec=None,
                      source=None, key_prefix: str = "waveform") -> tuple[FmcwWaveform, str]:
    """:func:`run_waveform` for a scene whose ``[waveform]`` is ``kind = "fmcw"``: the
    chirp sequence from the table (FmcwWaveform's defaults for the keys it leaves out),
    traced at the scene's carrier. An OFDM option given with it is refused by name; a
    contradiction is a SceneError naming the file, the key and the value (the
    ``scene.carrier_hz`` where the sweep does not contain it). ``spec``/``source``: an
    FMCW table read from another file (``args`` None: no options to refuse);
    ``key_prefix``: the key refusals name (``radars[i].waveform`` for a radar's own)."""
    for attr, option in WAVEFORM_OPTIONS.items():
        if args is not None and getattr(args, attr, None) is not None:
            table = "[waveform]" if key_prefix == "waveform" else key_prefix
            raise ArgumentError(f'sets the OFDM frame, but the scene\'s {table} is '
                                'kind = "fmcw"; set the chirp sequence in the scene file',
                                argument=option, value=getattr(args, attr))
    spec = scene.waveform if spec is None else spec
    source = scene.source if source is None else source
    given = spec.given()
    kw = {FMCW_SCENE_KEYS[k]: v for k, v in given.items()}
    try:
        wf = FmcwWaveform(traced_carrier_hz=carrier_hz, **kw)
    except ArgumentError as exc:
        if exc.argument == "traced_carrier_hz":
            raise SceneError(exc.reason, file=scene.source, key="scene.carrier_hz",
                             value=carrier_hz) from None
        key = {v: k for k, v in FMCW_SCENE_KEYS.items()}.get(exc.argument)
        if key is None:
            raise
        if key not in given:  # a default contradicts the file's other keys
            raise SceneError(f"(left out: the default {exc.value!r}) {exc.reason}; set "
                             f"{key_prefix}.{key}", file=source, key=f"{key_prefix}.{key}",
                             value=exc.value) from None
        raise SceneError(exc.reason, file=source, key=f"{key_prefix}.{key}",
                         value=given[key]) from None
    line = (f"waveform: FMCW, traced at f_c {carrier_hz / 1e9:.6g} GHz: sweep "
            f"{wf.start_hz / 1e9:.6g} GHz + {wf.sweep_bandwidth_hz / 1e6:.6g} MHz in "
            f"{wf.chirp_s * 1e6:.6g} µs (S {wf.slope / 1e12:.6g} MHz/µs), {wf.n_chirps} "
            f"chirps every {wf.chirp_interval * 1e6:.6g} µs, {wf.samples_per_chirp} "
            f"{wf.if_type} samples at {wf.adc_rate_hz / 1e6:.6g} MHz; Δr "
            f"{wf.range_resolution:.4g} m, r_max {wf.max_range:.4g} m, Δv "
            f"{wf.velocity_resolution:.4g} m/s, v_max ±{wf.max_velocity:.4g} m/s")
    return wf, f"{line}\n  IF filter: Butterworth order {wf.if_filter_order}, cutoff " \
               f"{wf.if_cutoff_hz / 1e6:.6g} MHz (range {wf.if_range:.4g} m)"


__all__ = ["TOOL_ERRORS", "WAVEFORM_OPTIONS", "add_waveform_arguments", "run_waveform",
           "radar_waveforms", "refuse_radar_waveforms",
           "fmcw_run_waveform",
           "finite_float", "float_in", "int_in", "list_of",
           "noise_figure_db", "non_negative_float", "non_negative_int", "output_folder",
           "positive_float", "positive_int", "run_tool", "seed"]


# ----------------------------------------------------------------------------------------
# the parser of a command, and a scene to trace or a snapshot
# ----------------------------------------------------------------------------------------
def command_parser(doc: str | None, add_arguments: Callable[[argparse.ArgumentParser], None],
                   prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of a command: its module's docstring as the description (kept as
    written) and the options ``add_arguments`` adds."""
    ap = argparse.ArgumentParser(prog=prog, description=doc,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(ap)
    return ap


def parse_command(ap: argparse.ArgumentParser, argv, check_args=None):
    """``argv`` parsed by ``ap``, then ``check_args(ap, args)`` (what argparse alone
    cannot refuse) where the command has one."""
    args = ap.parse_args(argv)
    if check_args is not None:
        check_args(ap, args)
    return args


def preset_settings(args) -> TraceSettings:
    """The preset (``--preset``, else the default) with ``--rays`` when given."""
    changes = {} if args.rays is None else {"specular__rays": args.rays}
    return TraceSettings.preset(getattr(args, "preset", DEFAULT_PRESET), **changes)


def read_snapshot(path) -> Snapshot:
    """The snapshot at ``path``; a file that cannot be read is a SnapshotError naming it."""
    try:
        return load_snapshot(path)
    except OSError as exc:
        raise SnapshotError(f"cannot read it ({exc.strerror or exc})", file=path) from None


def check_snapshot_scene(snap: Snapshot, scene, snapshot_path, scene_path) -> None:
    """Refuse a snapshot traced from another scene than ``scene`` (their content hashes
    differ): its paths would be drawn or processed over geometry they never met."""
    if snap.scene_hash:
        if snap.scene_hash != scene.content_hash():
            raise SnapshotError(f"was traced from another scene than {scene_path} (its "
                                "scene hash differs); trace this scene again with clradcom "
                                "trace", file=snapshot_path, key="scene_hash")
        return
    # no hash (written by hand or by another tool): its radars must be the scene's
    names = [r.name for r in scene.radars]
    for link in snap:
        for role, name, index in (("tx", link.tx_name, link.tx_index),
                                  ("rx", link.rx_name, link.rx_index)):
            if index >= len(names) or names[index] != name:
                have = f"radar {index} is {names[index]!r}" if index < len(names) else \
                    f"it has {len(names)} radar(s)"
                raise SnapshotError(
                    f"has no scene hash, and its link {link.label} names {role} {name!r} "
                    f"as radar {index} where {scene_path} does not ({have}); give the scene "
                    "it was traced from", file=snapshot_path, key="links")


def trace_into(stage: Path, scene, settings: TraceSettings, args) -> Snapshot:
    """Trace ``scene`` on ``--device`` with a progress bar (off with ``--quiet``) and keep
    the snapshot in the output folder being staged, as ``snapshot.npz``."""
    runtime = get_runtime(args.device)
    print(f"tracing {args.scene} on {runtime.info.describe()} ...", flush=True)
    with progress_bar(None, "trace", quiet=getattr(args, "quiet", False), unit="link") as bar:
        snap = trace_scene(scene, settings, runtime=runtime, steps=trace_steps(bar))
    save_snapshot(Path(stage) / "snapshot.npz", snap)
    return snap
