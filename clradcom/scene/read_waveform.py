"""``[waveform]`` -> :class:`~clradcom.scene.records.WaveformSpec`: the radar frame a
scene asks for (N, M, Δf or T, the cyclic prefix in seconds or samples, the modulation).

Each value is checked on its own here (a positive integer, a positive or non-negative
number, a known modulation), each refusal naming the file, the key and the value. Whether
the values fit together, with the command's options and the paper's defaults filling the
gaps, is decided where the frame is built (docs/scene-format.md, "[waveform]").
"""

from __future__ import annotations

from clradcom.scene.fields import FieldReader
from clradcom.scene.records import MODULATIONS, WaveformSpec

__all__ = ["WAVEFORM_KEYS", "read_waveform"]

WAVEFORM_KEYS = ("subcarriers", "symbols", "subcarrier_spacing_hz", "useful_duration_s",
                 "cyclic_prefix_s", "cyclic_prefix_samples", "modulation")


def _positive_int(fields: FieldReader, tbl: dict, key: str, minimum: int) -> int | None:
    if key not in tbl:
        return None
    v = tbl[key]
    if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
        raise fields.err(f"waveform.{key}", v, "must be a positive integer" if minimum else
                         "must be an integer >= 0")
    return int(v)


def read_waveform(fields: FieldReader, data: dict) -> WaveformSpec | None:
    """The document's ``[waveform]`` table, or None when it has none."""
    if "waveform" not in data:
        return None
    tbl = data["waveform"]
    if not isinstance(tbl, dict):
        raise fields.err("waveform", tbl, "expected a table, written [waveform]")
    fields.check_keys(tbl, WAVEFORM_KEYS, "waveform")
    modulation = fields.get_str(tbl, "modulation", "waveform", default=None)
    if modulation is not None and modulation.lower() not in MODULATIONS:
        raise fields.err("waveform.modulation", modulation,
                         f"must be one of {', '.join(MODULATIONS)}")
    return WaveformSpec(
        subcarriers=_positive_int(fields, tbl, "subcarriers", 1),
        symbols=_positive_int(fields, tbl, "symbols", 1),
        subcarrier_spacing_hz=fields.get_float(tbl, "subcarrier_spacing_hz", "waveform",
                                               default=None, lo=0.0, lo_open=True,
                                               unit="Hz"),
        useful_duration_s=fields.get_float(tbl, "useful_duration_s", "waveform",
                                           default=None, lo=0.0, lo_open=True, unit="s"),
        cyclic_prefix_s=fields.get_float(tbl, "cyclic_prefix_s", "waveform", default=None,
                                         lo=0.0, unit="s"),
        cyclic_prefix_samples=_positive_int(fields, tbl, "cyclic_prefix_samples", 0),
        modulation=None if modulation is None else modulation.lower(),
    )
