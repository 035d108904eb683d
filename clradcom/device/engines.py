"""Where each stage of a trace actually ran: the device or the host, and why not the
device.

A trace asks for an engine (``TraceSettings.engine``: "device" or "host"); a stage of
the device engine may still run on the host, in whole or in part (a device without a
feature, a batch too small to be worth a launch). No such move is silent: the stage
calls :func:`record` with the engine it used and, for the host, the reason; a move to
the host gives one :class:`~clradcom.errors.DeviceFallbackWarning` per stage and reason,
and :func:`clradcom.trace.trace_scene` writes what each stage used into the snapshot's
metadata as ``engine.<stage>`` (:meth:`EngineLog.metadata`).
"""

from __future__ import annotations

import contextvars
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

from clradcom.errors import ArgumentError, DeviceFallbackWarning

__all__ = ["STAGES", "EngineLog", "engine_log", "record"]

#: the stages that can run on either engine, and what each one is
STAGES = {
    "specular.candidates": "ray launch and the face sequences of the specular candidates",
    "specular.image_points": "image-method reflection points of the candidates",
    "visibility.segments": "sight of path segments (candidates, edges, antennas)",
    "visibility.surface_sight": "sight lines from surfaces (PO facets, tiles, footprints)",
    "physical_optics.windows": "SBR launch windows over silhouettes and mirror images",
    "physical_optics.tubes": "SBR tubes shot, bounced and radiated",
    "scattering.tiles": "scattering tiles, their sight and fields",
    "diffraction.edge_sight": "which diffracting edges each antenna may see",
}

ENGINES = ("device", "host")


class EngineLog:
    """The engines each stage used during one trace: ``uses[stage]`` is a dict engine ->
    the reasons given for it (empty for the device)."""

    def __init__(self):
        self.uses: dict[str, dict[str, set[str]]] = {}
        self._lock = threading.Lock()

    def add(self, stage: str, engine: str, reason: str = "") -> None:
        with self._lock:
            reasons = self.uses.setdefault(stage, {}).setdefault(engine, set())
            if reason:
                reasons.add(reason)

    def engine_of(self, stage: str) -> str:
        """"device", "host" or "device+host" (part of the stage on each); "" if unused."""
        used = self.uses.get(stage, {})
        return "+".join(e for e in ENGINES if e in used)

    def metadata(self) -> dict[str, str]:
        """``engine.<stage>``: the engine(s), and for the host its reasons after a colon."""
        out = {}
        for stage in sorted(self.uses):
            text = self.engine_of(stage)
            reasons = sorted(self.uses[stage].get("host", ()))
            if reasons:
                text += ": " + "; ".join(reasons)
            out[f"engine.{stage}"] = text
        return out


_current: contextvars.ContextVar[EngineLog | None] = contextvars.ContextVar(
    "clradcom_engine_log", default=None)


@contextmanager
def engine_log() -> Iterator[EngineLog]:
    """Collect :func:`record` calls in this context (one trace) into a new EngineLog."""
    log = EngineLog()
    token = _current.set(log)
    try:
        yield log
    finally:
        _current.reset(token)


def record(stage: str, engine: str, reason: str = "", *, fallback: bool = True) -> None:
    """Note that ``stage`` (a key of :data:`STAGES`) ran, or ran partly, on ``engine``.
    ``engine == "host"`` with ``fallback`` (the device engine was asked for) warns once
    with the stage's name and ``reason``; the host reference engine itself records with
    ``fallback=False``."""
    if stage not in STAGES:
        raise ArgumentError(f"must be one of {', '.join(STAGES)}", argument="stage",
                            value=stage)
    if engine not in ENGINES:
        raise ArgumentError(f"must be one of {', '.join(ENGINES)}", argument="engine",
                            value=engine)
    log = _current.get()
    if log is not None:
        log.add(stage, engine, reason if engine == "host" else "")
    if engine == "host" and fallback:
        warnings.warn(f"{stage} ({STAGES[stage]}) runs on the host, not the OpenCL "
                      f"device: {reason or 'no reason given'}", DeviceFallbackWarning,
                      stacklevel=2)
