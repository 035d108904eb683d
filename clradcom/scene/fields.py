"""Typed, checked reads of the values in a parsed TOML scene document.

:class:`FieldReader` knows the scene file's name and nothing else; each method reads one
value (a string, a flag, a number, a vector, an array of tables) and refuses a wrong one
with a :class:`~clradcom.errors.SceneError` that names the file, the key path
(``objects[2].velocity``) and the offending value.
"""

from __future__ import annotations

import difflib
import math
from pathlib import Path

import numpy as np

from clradcom.errors import SceneError

__all__ = ["REQUIRED", "FieldReader", "is_file", "key_path"]

#: Default of the ``get*`` methods meaning "the key must be there".
REQUIRED = object()


def is_file(path: Path) -> bool:
    """``path.is_file()``, False also for a name the OS refuses (too long, a NUL byte)."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def key_path(base: str, key: str) -> str:
    """``base.key``, or ``key`` alone at the top level (``base`` empty)."""
    return f"{base}.{key}" if base else key


class FieldReader:
    """Reads and checks values of one scene file's tables; every refusal names ``file``."""

    def __init__(self, file: Path, read_files: list[Path] | None = None):
        self.file = file
        #: every file the scene's reading opened (meshes, patterns, imports), shared
        #: with the readers of the files it imports: a run must never write over them
        self.read_files: list[Path] = [] if read_files is None else read_files

    def note_read(self, path: Path) -> None:
        """Record that the scene's reading opened ``path``."""
        if path not in self.read_files:
            self.read_files.append(path)

    def err(self, key, value, reason) -> SceneError:
        return SceneError(reason, file=self.file, key=key, value=value)

    def check_keys(self, tbl: dict, allowed, kp: str) -> None:
        """Refuse any key of ``tbl`` outside ``allowed``, with a "did you mean" hint."""
        for k in tbl:
            if not isinstance(k, str):  # only from scene_from_dict: TOML keys are strings
                raise self.err(kp or None, k, "keys must be strings")
            if k not in allowed:
                close = difflib.get_close_matches(k, allowed, n=1) if len(k) < 100 else []
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                where = f"{kp}.{k}" if kp else k
                raise self.err(where, tbl[k], f"unknown key '{k}'{hint}; allowed keys: "
                               f"{', '.join(allowed)}")

    def get(self, tbl, key, kp, default=REQUIRED):
        if key in tbl:
            return tbl[key]
        if default is REQUIRED:
            raise SceneError("missing required key", file=self.file, key=key_path(kp, key))
        return default

    def get_str(self, tbl, key, kp, default=REQUIRED, choices=None):
        v = self.get(tbl, key, kp, default)
        if v is default and key not in tbl:
            return v
        if not isinstance(v, str):
            raise self.err(key_path(kp, key), v, "expected a string")
        if choices is not None and v not in choices:
            raise self.err(key_path(kp, key), v, f"must be one of {', '.join(choices)}")
        return v

    def get_bool(self, tbl, key, kp, default=REQUIRED):
        v = self.get(tbl, key, kp, default)
        if key in tbl and not isinstance(v, bool):
            raise self.err(key_path(kp, key), v, "expected true or false")
        return v

    def number(self, v, key, what="a number"):
        """A finite int or float (not a bool) as float."""
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self.err(key, v, f"expected {what}")
        try:
            x = float(v)
        except OverflowError:  # an int of more than 308 digits
            raise self.err(key, v, "too large: beyond the range of a float "
                           "(about 1.8e308)") from None
        if not math.isfinite(x):
            raise self.err(key, v, "NaN or inf is not allowed")
        return x

    def get_float(self, tbl, key, kp, default=REQUIRED, *, lo=None, lo_open=False, hi=None,
                  unit=""):
        if key not in tbl:
            return self.get(tbl, key, kp, default)
        k = key_path(kp, key)
        x = self.number(tbl[key], k, f"a number{(' (' + unit + ')') if unit else ''}")
        if lo is not None and (x <= lo if lo_open else x < lo):
            raise self.err(k, tbl[key], f"must be {'>' if lo_open else '>='} {lo:g}")
        if hi is not None and x > hi:
            raise self.err(k, tbl[key], f"must be <= {hi:g}")
        return x

    def vector(self, v, key, n, unit=""):
        """An array of ``n`` finite numbers as a float64 array."""
        what = f"an array of {n} numbers" + (f" ({unit})" if unit else "")
        if not isinstance(v, list) or len(v) != n:
            raise self.err(key, v, f"expected {what}")
        for x in v:
            if isinstance(x, bool) or not isinstance(x, int | float):
                raise self.err(key, v, f"expected {what}")
        try:
            a = np.array(v, dtype=np.float64)
        except OverflowError:  # an int of more than 308 digits
            raise self.err(key, v, "too large: beyond the range of a float "
                           "(about 1.8e308)") from None
        if not np.all(np.isfinite(a)):
            raise self.err(key, v, "NaN or inf is not allowed")
        return a

    def get_vec3(self, tbl, key, kp, default=REQUIRED, unit=""):
        if key not in tbl:
            d = self.get(tbl, key, kp, default)
            return np.array(d, dtype=np.float64)
        return self.vector(tbl[key], key_path(kp, key), 3, unit)

    def array_of_tables(self, document: dict, key) -> list:
        """The ``[[key]]`` entries of the document (none when absent)."""
        v = document.get(key, [])
        if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
            raise self.err(key, v, f"expected an array of tables, written [[{key}]]")
        return v

    def unique_name(self, tbl, kp, seen: dict, what: str) -> str:
        """The entry's non-empty ``name``, refused when ``seen`` (name -> key path) has it."""
        name = self.get_str(tbl, "name", kp)
        if not name:
            raise self.err(key_path(kp, "name"), name, "must not be empty")
        if name in seen:
            raise self.err(key_path(kp, "name"), name,
                           f"duplicate {what} name (already used by {seen[name]})")
        seen[name] = kp
        return name
