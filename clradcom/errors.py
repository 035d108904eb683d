"""Errors and warnings raised for bad user input.

Every refusal of a scene file (or a file it refers to) is a :class:`SceneError`
that names the file, the key path inside it (``objects[2].velocity``) and the
offending value, so a user can find and fix the line without a traceback.
"""

from __future__ import annotations

import os
import reprlib
from pathlib import Path

__all__ = ["SceneError", "SceneWarning", "ValidityRangeWarning", "NOVALUE", "PhysicsWarning",
           "CyclicPrefixWarning", "TileSizeWarning", "FresnelZoneWarning",
           "AliasingWarning", "NearFieldWarning", "SurfaceContactWarning",
           "BoundaryWarning", "CausticWarning", "SnapshotError", "ArgumentError",
           "ArgumentTypeError", "MemoryBudgetError", "TaskError"]


class _NoValue:
    """Marker for "no value to report" (distinct from a value of ``None``)."""

    def __repr__(self) -> str:  # pragma: no cover - trivial
        return "<no value>"

    def __reduce__(self):
        # one marker in every process: an error pickled from a Dask worker keeps it
        return "NOVALUE"


NOVALUE = _NoValue()


#: Shortened repr for values too deep (or too odd) for repr() itself.
_REPR = reprlib.Repr()
_REPR.maxlevel = 3


def _short(value: object, limit: int = 80) -> str:
    try:
        text = repr(value)
    except Exception:  # noqa: BLE001 - a value nested too deep for repr (RecursionError)
        text = _REPR.repr(value)
    if len(text) > limit:
        text = text[: limit - 3] + "..."
    return text


class SceneError(ValueError):
    """A scene file (or a mesh/pattern file it names) was refused.

    Attributes
    ----------
    file : str or None
        The file the problem is in (scene file, mesh file or pattern file).
    key : str or None
        Key path inside the file, e.g. ``objects[2].velocity``; ``None`` when the
        problem is not tied to a key (a TOML syntax error, say).
    value : object
        The offending value (``NOVALUE`` when there is none, e.g. a missing key).
    line : int or None
        Line number when known (TOML syntax errors).
    reason : str
        What is wrong and, where possible, how to fix it.
    """

    def __init__(
        self,
        reason: str,
        *,
        file: str | Path | None = None,
        key: str | None = None,
        value: object = NOVALUE,
        line: int | None = None,
    ) -> None:
        self.reason = reason
        self.file = None if file is None else str(file)
        self.key = key
        self.value = value
        self.line = line
        super().__init__(str(self))

    def __str__(self) -> str:
        where = self.file if self.file is not None else "<scene>"
        if self.line is not None:
            where = f"{where}:{self.line}"
        parts = [where]
        if self.key is not None:
            if self.value is NOVALUE:
                parts.append(self.key)
            else:
                parts.append(f"{self.key} = {_short(self.value)}")
        elif self.value is not NOVALUE:
            parts.append(f"value {_short(self.value)}")
        return ": ".join(parts) + ": " + self.reason

    def __reduce__(self):  # keep pickling (multiprocessing) working
        return (
            _rebuild,
            (self.reason, self.file, self.key, self.value, self.line),
        )


def _rebuild(reason, file, key, value, line):  # pragma: no cover - pickling helper
    return SceneError(reason, file=file, key=key, value=value, line=line)


class SceneWarning(UserWarning):
    """Something in a scene was accepted but deserves attention (e.g. a material
    model evaluated outside its validated frequency range)."""


class DeviceFallbackWarning(UserWarning):
    """A stage of a trace asked to run on the OpenCL device ran on the host instead (the
    device lacks a feature, or the work is one the host does faster): the result is the
    same, the time is not. Given once per stage and reason; the snapshot's
    ``engine.<stage>`` metadata records where each stage ran (clradcom.device.engines)."""


class PhysicsWarning(UserWarning):
    """A result was computed where the model behind it stops being valid (docs/stability.md).

    The subclasses name the case, so a user can silence or escalate one of them alone
    (``warnings.simplefilter("error", CyclicPrefixWarning)``)."""


class ValidityRangeWarning(SceneWarning, PhysicsWarning):
    """A scene value is legal but lies outside the range where the tracer's methods and
    models hold (a carrier outside 1-300 GHz, a speed above 1e-3 c, geometry beyond what
    float32 resolves to a wavelength; docs/scene-format.md "Physical bounds"). Both a
    :class:`SceneWarning` and a :class:`PhysicsWarning`, so either filter catches it."""


class CyclicPrefixWarning(PhysicsWarning):
    """Paths delayed beyond the cyclic prefix went through the frequency-domain channel
    model, which has no inter-symbol interference: their echoes come out too strong and
    clean.  ``synthesize_time_domain`` models the ISI."""


class AliasingWarning(PhysicsWarning):
    """A path's delay lies beyond the unambiguous range (tau >= 1/delta_f) or its Doppler
    beyond the unambiguous velocity (|f_D| > 1/(2 T_sym)): it shows in the radar image
    wrapped to r mod r_max, or v wrapped into [-v_max, v_max)."""


class TileSizeWarning(PhysicsWarning):
    """Diffuse-scattering tiles coarser than their accuracy bound (docs/scattering.md "Tile
    size rule"): an explicit ``tile_size_m`` larger than the rule allows at a surface's
    nearest point to the antennas, so a tile there is no point scatterer and the coherent
    sum's speckle and the delay spread are off. The message names the surface (object),
    the bound and the distance it holds for."""


class FresnelZoneWarning(PhysicsWarning):
    """PO facets lie closer to an antenna than their Fraunhofer distance 2D^2/lambda: the
    facet integral drops the quadratic phase across them there (docs/po.md, "Facets near
    an antenna"); OpticsSettings.po_split = "fresnel" splits them into their far field."""


class NearFieldWarning(PhysicsWarning):
    """A path is shorter than a wavelength: the far-field spreading lambda/(4 pi L) that
    its gain uses grows without bound as L -> 0 and means nothing there."""


class SurfaceContactWarning(PhysicsWarning):
    """A transmitter or receiver lies on a reflecting face: the reflection off that face
    coincides with the line of sight and the image method cannot place it. The tracer
    adds it as the limit of the two merging rays where the line of sight exists
    (``tracer.surface_contact_paths``: the total tends to (1 + r) x LOS); with both
    antennas on the face, or the line of sight blocked, it is left out (geometrical
    optics has no surface wave)."""


class BoundaryWarning(PhysicsWarning):
    """A diffracted path lies exactly on a shadow or reflection boundary of its edge
    (within rounding): the UTD term there is the mean of its two one-sided limits, which
    pairs with a geometrical-optics field of one half, but the tracer keeps or drops the
    GO path whole, so the total field at this point is off by half the GO field. A
    fraction of a wavelength either side the total is continuous; move the antenna."""


class CausticWarning(PhysicsWarning):
    """An antenna lies on an edge's line (the edge seen end-on): the diffracted rays'
    Keller cone collapses onto the edge, a caustic where UTD has no unique limit (it
    depends on the direction of approach); the path is left out there."""


class SnapshotError(ValueError):
    """A snapshot (in memory or on disk) was refused.

    ``file`` is the snapshot file (``None`` for an object being built in memory), ``key``
    the field or npz key (``link2/delay_s[3]``), ``reason`` what is wrong.
    """

    def __init__(self, reason: str, *, file: str | os.PathLike | None = None,
                 key: str | None = None) -> None:
        self.reason = reason
        self.file = None if file is None else str(file)
        self.key = key
        super().__init__(str(self))

    def __str__(self) -> str:
        parts = [p for p in (self.file, self.key) if p is not None]
        return ": ".join([*parts, self.reason])

    def __reduce__(self):  # keep pickling (multiprocessing) working
        return (_rebuild_error, (self.reason, self.file, self.key))


def _rebuild_error(reason, file, key):  # pragma: no cover - pickling helper
    return SnapshotError(reason, file=file, key=key)


class _ArgumentMixin:
    """Names the argument (a function parameter, a settings field, a CLI option) and the
    refused value in the message: ``rays = -1: must be >= 1``."""

    def _setup(self, reason: str, argument: str | None, value: object) -> str:
        self.reason = reason
        self.argument = argument
        self.value = value
        if argument is None:
            return reason
        if value is NOVALUE:
            return f"{argument}: {reason}"
        return f"{argument} = {_short(value)}: {reason}"


class ArgumentError(_ArgumentMixin, ValueError):
    """A library call's argument (or a settings field, or a command-line option) has a
    value that is refused. ``argument`` names it, ``value`` is what was given."""

    def __init__(self, reason: str, *, argument: str | None = None,
                 value: object = NOVALUE) -> None:
        super().__init__(self._setup(reason, argument, value))

    def __reduce__(self):
        return (_rebuild_argument, (type(self), self.reason, self.argument, self.value))


class ArgumentTypeError(_ArgumentMixin, TypeError):
    """A library call's argument has the wrong type (a path where a Scene is expected)."""

    def __init__(self, reason: str, *, argument: str | None = None,
                 value: object = NOVALUE) -> None:
        super().__init__(self._setup(reason, argument, value))

    def __reduce__(self):
        return (_rebuild_argument, (type(self), self.reason, self.argument, self.value))


class MemoryBudgetError(ArgumentError):
    """A computation would allocate more memory than allowed; the message gives the
    estimate and the argument or option to change."""


def _rebuild_argument(cls, reason, argument, value):  # pragma: no cover - pickling helper
    return cls(reason, argument=argument, value=value)


class TaskError(RuntimeError):
    """A task of a distributed run (:mod:`clradcom.distributed`) failed past its retry
    bound (``key`` names it). Defined here so that the commands' error boundary knows it
    without loading Dask."""

    def __init__(self, message: str, *, key: str):
        self.key = key
        super().__init__(message)
