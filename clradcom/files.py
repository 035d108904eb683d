"""Writing output files so that nothing is lost and nothing is half-written.

* :func:`atomic_write` - the data go to an unnamed temporary file in the target's folder
  (Linux ``O_TMPFILE``; elsewhere a hidden named one), are fsynced, take the permissions
  of the file they replace, and only then appear under the target's name
  (``os.replace``). An interrupted or failed write leaves the old file as it was and no
  temporary file behind; a killed one leaves nothing either where ``O_TMPFILE`` exists.
* Never over an input: ``inputs`` lists the files a run read; a target that is one of
  them is refused before anything is written.
* :func:`staged_folder` - a run's whole output folder is built beside the old one and
  swapped in at the end, so a folder is never half old, half new. Given the names a run
  owns (``owned``), whatever else the old folder holds (another tool's subfolder, a
  user's notes) is carried into the new one instead of being dropped with it.
* :func:`save_figure` - matplotlib figures through :func:`atomic_write`, with the date
  and the random SVG ids fixed so that identical runs give identical bytes.
* :func:`write_csv`, :func:`write_text` - tables and text through :func:`atomic_write`.
"""

from __future__ import annotations

import contextlib
import csv
import fnmatch
import hashlib
import io
import os
import re
import secrets
import shutil
import socket
import stat
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from clradcom.errors import ArgumentError

__all__ = ["OutputError", "atomic_write", "save_figure", "staged_folder", "write_csv",
           "write_text"]

#: Salt of matplotlib's SVG ids (clip paths, glyphs): fixed for byte-identical SVGs.
SVG_HASH_SALT = "clradcom"


class LeftoverWarning(UserWarning):
    """A staging folder that a killed run left beside its output folder was removed (or,
    where it cannot be known to be dead, is named)."""


class OutputError(OSError):
    """An output could not be written; the message names the file and the cause, and the
    old file (if any) is left as it was."""


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def refuse_inputs(target: Path, inputs: Iterable[str | os.PathLike] = ()) -> None:
    """Refuse a target that is one of the run's input files."""
    for source in inputs:
        if _same_file(target, Path(source)):
            raise ArgumentError(f"refusing to overwrite an input file of this run "
                                f"({source}); choose another output", argument="output",
                                value=str(target))


def _mode_for(target: Path) -> int:
    """Permissions of the file being replaced, else 0666 less the umask."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _fsync_directory(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # pragma: no cover - e.g. Windows
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - some filesystems refuse directory fsync
        pass
    finally:
        os.close(fd)


def _temp_name(directory: Path, name: str) -> Path:
    return directory / f".{name}.{secrets.token_hex(6)}.tmp"


def _open_unnamed(directory: Path) -> int | None:
    """An unnamed file in ``directory`` (O_TMPFILE), or None where that is not available."""
    flag = getattr(os, "O_TMPFILE", 0)
    if not flag:
        return None
    try:
        return os.open(directory, flag | os.O_WRONLY, 0o600)
    except OSError:  # the file system does not support it
        return None


def _link_unnamed(fd: int, name: Path) -> None:
    """Give an O_TMPFILE file a name. os.link calls plain link(2), which does not follow
    /proc's fd link, unless a dir_fd is passed: then it is linkat(2) with
    AT_SYMLINK_FOLLOW, which does."""
    dir_fd = os.open(name.parent, os.O_RDONLY)
    try:
        os.link(f"/proc/self/fd/{fd}", name.name, dst_dir_fd=dir_fd, follow_symlinks=True)
    finally:
        os.close(dir_fd)


def atomic_write(path: str | os.PathLike, write: Callable[[io.BufferedWriter], None], *,
                 inputs: Iterable[str | os.PathLike] = ()) -> Path:
    """Write ``path`` atomically: ``write(fh)`` fills a binary file handle.

    Raises :class:`OutputError` (an ``OSError``) naming the file when the folder is
    missing or read-only, the disk is full, or anything else fails; the old file stays.
    """
    target = Path(path)
    refuse_inputs(target, inputs)
    directory = target.parent if str(target.parent) else Path(".")
    if target.is_dir():
        raise OutputError(f"{target}: is a folder, not a file")
    if not directory.is_dir():
        raise OutputError(f"{target}: the folder {directory} does not exist")
    mode = _mode_for(target)
    named: Path | None = None
    fd = _open_unnamed(directory)
    try:
        if fd is None:
            named = _temp_name(directory, target.name)
            fd = os.open(named, os.O_WRONLY | os.O_CREAT | os.O_EXCL
                         | getattr(os, "O_BINARY", 0), 0o600)
        with os.fdopen(fd, "wb") as fh:
            fd = None  # the file object owns it now
            write(fh)
            fh.flush()
            os.fchmod(fh.fileno(), mode)
            os.fsync(fh.fileno())
            if named is None:
                # give the finished file a name only now: a kill before this leaves nothing
                named = _temp_name(directory, target.name)
                _link_unnamed(fh.fileno(), named)
        os.replace(named, target)
        named = None
    except OSError as exc:
        raise OutputError(f"{target}: cannot write ({exc.strerror or exc}); "
                          f"nothing was changed") from exc
    finally:
        if fd is not None:
            os.close(fd)
        if named is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(named)
    _fsync_directory(directory)
    return target


def save_figure(figure, path: str | os.PathLike, *, inputs=(), **savefig_kw) -> Path:
    """Save a matplotlib figure atomically; PNG and SVG carry no date and fixed ids, so
    identical runs give identical bytes."""
    import matplotlib  # plotting is optional for the rest of the package

    target = Path(path)
    fmt = target.suffix.lstrip(".").lower() or "png"
    metadata = {"svg": {"Date": None}, "pdf": {"CreationDate": None}}.get(fmt)

    def write(fh):
        with matplotlib.rc_context({"svg.hashsalt": SVG_HASH_SALT}):
            figure.savefig(fh, format=fmt, metadata=metadata, **savefig_kw)

    return atomic_write(target, write, inputs=inputs)


def write_text(path: str | os.PathLike, text: str, *, inputs=(),
               encoding: str = "utf-8") -> Path:
    """Write a text file atomically (see :func:`atomic_write`); newlines as given."""
    data = text.encode(encoding)
    return atomic_write(path, lambda fh: fh.write(data), inputs=inputs)


def write_csv(path: str | os.PathLike, rows, header=None, *, inputs=()) -> Path:
    """Write a CSV file atomically: ``header`` (when given), then ``rows`` (sequences)
    as the :mod:`csv` module's default dialect writes them (``\\r\\n`` line ends)."""
    buffer = io.StringIO(newline="")
    writer = csv.writer(buffer)
    if header is not None:
        writer.writerow(header)
    writer.writerows(rows)
    return write_text(path, buffer.getvalue(), inputs=inputs)


class _SwapStuck(OutputError):
    """A failed swap could not be undone whole: the staging folder holds files that must
    not be removed (carried from the old folder, or the new outputs with the old folder
    moved aside)."""


def _owns(name: str, owned) -> bool:
    return any(fnmatch.fnmatchcase(name, pattern) for pattern in owned)


def _under(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _swap_in(staging: Path, target: Path, parent: Path, owned) -> None:
    """Carry what the run does not own from ``target`` into ``staging``, then swap
    ``staging`` in for ``target``. On any failure or interrupt everything carried is moved
    back and ``target`` is as it was; raises OutputError for a file system failure."""
    carried: list[str] = []
    old = None
    try:
        if target.exists() and owned is not None:
            for entry in sorted(target.iterdir()):
                if _owns(entry.name, owned) or (staging / entry.name).exists():
                    continue
                os.rename(entry, staging / entry.name)
                carried.append(entry.name)
        if target.exists():
            old = parent / f".{target.name}.{_run_tag()}-{secrets.token_hex(6)}.old"
            os.replace(target, old)
        os.replace(staging, target)
    except BaseException as exc:
        if not staging.exists():  # interrupted just after the swap: it is done
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
            raise
        restored = True
        if old is not None and not target.exists():
            try:
                os.replace(old, target)
            except OSError:
                restored = False
        stuck = list(carried) if not restored else []
        for name in (reversed(carried) if restored else ()):
            try:
                os.rename(staging / name, target / name)
            except OSError:
                stuck.append(name)
        if stuck or not restored:  # never remove the staging folder with such files in it
            where = "" if restored else f"; the old folder is in {old}"
            raise _SwapStuck(f"{target}: the new outputs could not be swapped in; they are "
                             f"in {staging}" + (f", with {', '.join(stuck)} of the old "
                                                f"folder" if stuck else "") + where) from exc
        if isinstance(exc, OSError):
            raise OutputError(f"{target}: cannot swap the new outputs in "
                              f"({exc.strerror or exc}); the old folder is as it was") from exc
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _host_tag() -> str:
    """8 hex digits of this machine's name: a process number means something only on
    the machine that gave it (output folders may be on a shared file system)."""
    return hashlib.sha256(socket.gethostname().encode()).hexdigest()[:8]


def _run_tag() -> str:
    """This run's part of a staging folder's name: ``<host>p<pid>``."""
    return f"{_host_tag()}p{os.getpid()}"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def _remove_leftovers(parent: Path, name: str) -> None:
    """Remove the staging (``.new``) and swapped-out (``.old``) folders that runs into
    ``parent/name`` on this machine left when they were killed (their process is gone),
    each named in a :class:`LeftoverWarning`; name those that cannot be known dead (made
    on another machine or by an older clradcom) without touching them."""
    own = re.compile(rf"^\.{re.escape(name)}\.([0-9a-f]{{8}})p(\d+)-[0-9a-f]{{12}}\.(new|old)$")
    older = re.compile(rf"^\.{re.escape(name)}\.[0-9a-f]{{12}}\.(new|old)$")
    host = _host_tag()
    try:
        entries = sorted(parent.iterdir())
    except OSError:
        return
    for entry in entries:
        m = own.match(entry.name)
        if m and m.group(1) == host and not _alive(int(m.group(2))) and entry.is_dir():
            shutil.rmtree(entry, ignore_errors=True)
            warnings.warn(f"removed {entry}: left by an earlier run into {parent / name} "
                          f"that was killed (process {m.group(2)} is gone)", LeftoverWarning,
                          stacklevel=4)
        elif ((m and m.group(1) != host) or older.match(entry.name)) and entry.is_dir():
            warnings.warn(f"{entry} was left by a run into {parent / name} that may have been "
                          "killed (on another machine, or by an older clradcom); remove it "
                          "if no run is writing there", LeftoverWarning, stacklevel=4)


@contextlib.contextmanager
def staged_folder(path: str | os.PathLike, *, inputs=(), owned=None) -> Iterator[Path]:
    """Build an output folder beside ``path`` and swap it in when the block ends.

    Yields the staging folder to write into. On success the old folder (if any) is
    replaced; on any error or interrupt the staging folder is removed and the old folder
    stays untouched.

    ``owned``: glob patterns of the names this run writes into the folder
    (``"*_image.png"``). Without it the old folder is replaced as a whole. With it, the
    entries of the old folder that match none of the patterns (another tool's
    subfolder, a user's notes) are moved into the new folder just before the swap, so
    only this run's own earlier outputs are replaced, all of them at once.

    Refused before anything is written (:class:`OutputError` or ``ArgumentError``): a
    ``path`` that exists and is not a folder, one that is or holds the current folder,
    and one holding an input of the run (``inputs``) that the swap would remove (with
    ``owned``: only inputs whose names it owns).
    """
    target = Path(os.path.abspath(path))
    if target.exists() and not target.is_dir():
        raise OutputError(f"{path}: exists and is not a folder; choose another output")
    try:
        cwd = Path(os.getcwd()).resolve()
    except OSError:  # the current folder was removed: it cannot be the target
        cwd = None
    if cwd is not None and _under(cwd, target.resolve()):
        raise OutputError(f"{path}: is the current folder or holds it; a run replaces its "
                          f"output folder, so choose a folder of its own")
    if target.exists():
        real = target.resolve()
        for source in inputs:
            src = Path(source).resolve()
            if real not in src.parents:
                continue
            top = src.relative_to(real).parts[0]
            if owned is None or _owns(top, owned):
                raise ArgumentError(f"the output folder holds an input of this run "
                                    f"({source}) that the run would replace; choose another "
                                    f"output folder", argument="output", value=str(path))
    parent = target.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        _remove_leftovers(parent, target.name)
        staging = parent / f".{target.name}.{_run_tag()}-{secrets.token_hex(6)}.new"
        staging.mkdir()
    except OSError as exc:
        raise OutputError(f"{path}: cannot create the output folder "
                          f"({exc.strerror or exc})") from exc
    try:
        yield staging
        _swap_in(staging, target, parent, owned)
    except _SwapStuck:
        raise  # the staging folder holds files that must stay: never remove it
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
