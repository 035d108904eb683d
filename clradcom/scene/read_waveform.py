"""``[waveform]`` -> :class:`~clradcom.scene.records.WaveformSpec`: the radar frame a
scene asks for (N, M, Δf or T, the cyclic prefix in seconds or samples, the modulation).

Each value is checked on its own here (a positive integer, a positive or non-negative
number, a known modulation), each refusal naming the file, the key and the value. Whether
the values fit together, with the command's options and the paper's defaults filling the
gaps, is decided where the frame is built (docs/scene-format.md, "[waveform]").
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from clradcom.errors import SceneError
from clradcom.scene.fields import FieldReader, is_file
from clradcom.scene.records import FMCW_IF_TYPES, MODULATIONS, FmcwSpec, WaveformSpec

__all__ = ["FMCW_KEYS", "WAVEFORM_KEYS", "WAVEFORM_KINDS", "load_waveform_table",
           "read_waveform", "read_waveform_table"]

WAVEFORM_KEYS = ("kind", "subcarriers", "symbols", "subcarrier_spacing_hz",
                 "useful_duration_s", "cyclic_prefix_s", "cyclic_prefix_samples",
                 "modulation")
#: ``[waveform] kind``: the OFDM RadCom frame (the default) or an FMCW chirp sequence
WAVEFORM_KINDS = ("ofdm", "fmcw")
FMCW_KEYS = ("kind", "start_frequency_hz", "sweep_bandwidth_hz", "chirp_duration_s",
             "idle_duration_s", "chirps", "adc_sample_rate_hz", "samples_per_chirp",
             "adc_start_s", "if_type", "if_bandwidth_hz", "if_filter_order",
             "phase_noise_offsets_hz", "phase_noise_dbc_per_hz")


def _positive_int(fields: FieldReader, tbl: dict, key: str, minimum: int,
                  kp: str = "waveform") -> int | None:
    if key not in tbl:
        return None
    v = tbl[key]
    if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
        raise fields.err(f"{kp}.{key}", v, "must be a positive integer" if minimum == 1
                         else f"must be an integer >= {minimum}")
    return int(v)


def read_waveform(fields: FieldReader, data: dict) -> WaveformSpec | FmcwSpec | None:
    """The document's ``[waveform]`` table, or None when it has none."""
    if "waveform" not in data:
        return None
    return read_waveform_table(fields, data["waveform"], "waveform")


def read_waveform_table(fields: FieldReader, tbl, kp: str) -> WaveformSpec | FmcwSpec:
    """One waveform table (the scene's ``[waveform]``, or a radar's own
    ``[radars.waveform]``), every refusal naming ``kp`` and the key."""
    if not isinstance(tbl, dict):
        raise fields.err(kp, tbl, f"expected a table, written [{_header(kp)}]")
    kind = fields.get_str(tbl, "kind", kp, default="ofdm", choices=WAVEFORM_KINDS)
    if kind == "fmcw":
        return _read_fmcw(fields, tbl, kp)
    fields.check_keys(tbl, WAVEFORM_KEYS, kp)
    modulation = fields.get_str(tbl, "modulation", kp, default=None)
    if modulation is not None and modulation.lower() not in MODULATIONS:
        raise fields.err(f"{kp}.modulation", modulation,
                         f"must be one of {', '.join(MODULATIONS)}")
    return WaveformSpec(
        subcarriers=_positive_int(fields, tbl, "subcarriers", 1, kp),
        symbols=_positive_int(fields, tbl, "symbols", 1, kp),
        subcarrier_spacing_hz=fields.get_float(tbl, "subcarrier_spacing_hz", kp,
                                               default=None, lo=0.0, lo_open=True,
                                               unit="Hz"),
        useful_duration_s=fields.get_float(tbl, "useful_duration_s", kp,
                                           default=None, lo=0.0, lo_open=True, unit="s"),
        cyclic_prefix_s=fields.get_float(tbl, "cyclic_prefix_s", kp, default=None,
                                         lo=0.0, unit="s"),
        cyclic_prefix_samples=_positive_int(fields, tbl, "cyclic_prefix_samples", 0, kp),
        modulation=None if modulation is None else modulation.lower(),
    )


def _header(kp: str) -> str:
    """The TOML header of the table at ``kp``: ``waveform``, ``radars.waveform``."""
    return re.sub(r"\[\d+\]", "", kp)


def _read_fmcw(fields: FieldReader, tbl: dict, kp: str) -> FmcwSpec:
    fields.check_keys(tbl, FMCW_KEYS, kp)

    def positive(key, unit):
        return fields.get_float(tbl, key, kp, default=None, lo=0.0, lo_open=True,
                                unit=unit)

    if_type = fields.get_str(tbl, "if_type", kp, default=None, choices=FMCW_IF_TYPES)
    return FmcwSpec(
        start_frequency_hz=positive("start_frequency_hz", "Hz"),
        sweep_bandwidth_hz=positive("sweep_bandwidth_hz", "Hz"),
        chirp_duration_s=positive("chirp_duration_s", "s"),
        idle_duration_s=fields.get_float(tbl, "idle_duration_s", kp, default=None,
                                         lo=0.0, unit="s"),
        chirps=_positive_int(fields, tbl, "chirps", 1, kp),
        adc_sample_rate_hz=positive("adc_sample_rate_hz", "Hz"),
        samples_per_chirp=_positive_int(fields, tbl, "samples_per_chirp", 2, kp),
        adc_start_s=fields.get_float(tbl, "adc_start_s", kp, default=None, lo=0.0,
                                     unit="s"),
        if_type=if_type,
        if_bandwidth_hz=positive("if_bandwidth_hz", "Hz"),
        if_filter_order=_positive_int(fields, tbl, "if_filter_order", 1, kp),
        phase_noise_offsets_hz=_numbers(fields, tbl, "phase_noise_offsets_hz", "Hz", kp),
        phase_noise_dbc_per_hz=_numbers(fields, tbl, "phase_noise_dbc_per_hz", "dBc/Hz",
                                        kp),
    )


def _numbers(fields: FieldReader, tbl: dict, key: str, unit: str,
             kp: str = "waveform") -> tuple | None:
    """A non-empty array of finite numbers, as a tuple; None when the key is absent."""
    if key not in tbl:
        return None
    v = tbl[key]
    if not isinstance(v, list) or not v:
        raise fields.err(f"{kp}.{key}", v, f"expected a non-empty array of numbers "
                         f"({unit})")
    return tuple(fields.number(x, f"{kp}.{key}", f"a number ({unit})") for x in v)


def load_waveform_table(path) -> WaveformSpec | FmcwSpec:
    """A TOML file holding one ``[waveform]`` table (as a scene file writes it, either
    kind), for a command that runs a second radar frame beside the scene's; SceneError
    naming the file (and key) on anything else."""
    path = Path(path)
    if not is_file(path):
        raise SceneError("waveform file not found", file=path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, ValueError) as exc:
        raise SceneError(f"cannot read the waveform file ({exc})", file=path) from None
    fields = FieldReader(path)
    fields.check_keys(data, ("waveform",), "")
    spec = read_waveform(fields, data)
    if spec is None:
        raise SceneError("holds no [waveform] table", file=path)
    return spec
