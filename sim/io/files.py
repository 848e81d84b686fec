"""Files a run reads and writes: safe reading (re-exported from :mod:`hydraulics.files`) and output checks.

Reading: :func:`read_bytes`, :func:`read_text` (regular files of at most :data:`MAX_INPUT_BYTES`,
never blocking on a FIFO or device, one-line errors naming the file).

Writing: :func:`check_output` decides, before a run starts, whether a log may be written at a
path.  It is refused, with a :class:`~hydraulics.components.CircuitError` whose one-line message
names the path, when the path

* is empty, holds a NUL byte, or its name (or the name of its ``.partial``) is longer than the
  file system allows;
* is anything but a regular file: a directory, a device (``/dev/null``), a FIFO, a socket or a
  symbolic link -- even with ``overwrite``;
* is one of the run's inputs (``protected``: scenario, circuit, MJCF, its includes and assets,
  inputs CSV) -- even with ``overwrite``;
* exists and ``overwrite`` is False; or its ``.partial`` exists (a run writing it now, or a
  killed run whose data ``hydroplant log recover`` can rescue) and ``overwrite`` is False;
* lies in a folder that is not a folder or that this process cannot write.

The writer itself (:class:`sim.io.mcap_log.LogWriter`) creates the ``.partial`` exclusively, so a
second run racing past these checks is still refused.

Tools that write a fixed set of files into a folder (``compare``, ``tradeoff``) check every name
first with :func:`check_outputs` (a name that is a link, a folder or one of the command's inputs is
refused before any work) and write each with :func:`write_output`: a new file created exclusively
beside the target and renamed over it, so a link or hard link planted in the folder is replaced,
never written through.

Usage::

    from sim.io.files import check_output
    path = check_output("logs/lift.mcap", protected=[scenario.path, scenario.circuit])
    write_output("logs/compare/report.md", lambda f: f.write(b"# Report"), what="report")
"""

from __future__ import annotations

import errno
import os
import stat
import secrets
from collections.abc import Callable
from pathlib import Path

from hydraulics.components import CircuitError
from hydraulics.files import MAX_INPUT_BYTES, file_kind, read_bytes, read_text, resolve

__all__ = ["MAX_INPUT_BYTES", "PARTIAL_SUFFIX", "check_output", "check_outputs", "free_path", "read_bytes", "read_text",
           "resolve", "write_output"]

PARTIAL_SUFFIX = ".partial"  # as sim.io.mcap_log.PARTIAL_SUFFIX (not imported: that module loads the MCAP stack)


def _lstat(path: Path):
    try:
        return os.lstat(path)
    except FileNotFoundError:
        return None
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            raise CircuitError(f"{path}: log file name too long") from None
        if exc.errno == errno.ENOTDIR:
            raise CircuitError(f"{path}: a part of the log's folder is not a folder") from None
        raise CircuitError(f"{path}: cannot use as a log file ({exc.strerror or exc})") from None


def _same_file(path: Path, others) -> Path | None:
    for other in others:
        try:
            if os.path.samefile(path, other):
                return Path(other)
        except (OSError, ValueError):
            continue
    return None


def _name_max(folder: Path) -> int:
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        return 255


def check_output(path, protected=(), *, overwrite: bool = False, what: str = "log") -> Path:
    """``path`` as a :class:`Path` if a new ``what`` file may be written there, else :class:`CircuitError` (see the module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    protected : iterable of paths
        Files that are never written over (the run's inputs).
    overwrite : bool
        Allow replacing an existing regular file (not a protected one) and its ``.partial``.
    what : str
        The kind of file, for the messages.
    """
    text = os.fspath(path)
    if text == "":
        raise CircuitError(f"--out {text!r}: an empty file name; name the {what} file, e.g. logs/run.mcap")
    if "\0" in text:
        raise CircuitError(f"--out {text!r}: a file name may not hold a NUL byte")
    path = Path(text)
    partial = path.with_name(path.name + PARTIAL_SUFFIX)
    folder = path.parent
    protected = list(protected)
    for candidate in (path, partial):
        info = _lstat(candidate)
        if info is None:
            continue
        if not stat.S_ISREG(info.st_mode):
            kind = "a symbolic link" if stat.S_ISLNK(info.st_mode) else file_kind(info.st_mode)
            raise CircuitError(f"{candidate}: is {kind}, not a regular file; a {what} is never written over it "
                               "(not even with --overwrite); name a new file")
        same = _same_file(candidate, protected)
        if same is not None:
            raise CircuitError(f"{candidate}: is an input of this run ({same}); a {what} is never written over it "
                               "(not even with --overwrite); name another file")
        if not overwrite:
            if candidate == path:
                raise CircuitError(f"{path}: exists; pass --overwrite to replace it, or name a new file")
            raise CircuitError(f"{partial}: exists (a run is writing {path} now, or one was killed): rescue it with "
                               f"'hydroplant log recover {partial}', or pass --overwrite to replace it")
    # the folder: the nearest existing ancestor must be a writable folder (missing folders are created)
    existing = folder
    while True:
        info = _lstat(existing) if str(existing) else None
        if info is not None or existing == existing.parent:
            break
        existing = existing.parent
    target = existing if str(existing) else Path(".")
    if not target.is_dir():
        raise CircuitError(f"{path}: {target} is not a folder")
    if not os.access(target, os.W_OK | os.X_OK):
        raise CircuitError(f"{path}: the folder {target} is not writable")
    limit = _name_max(target)
    if len(os.fsencode(partial.name)) > limit:
        raise CircuitError(f"{path}: file name too long: {len(os.fsencode(path.name))} B, at most "
                           f"{limit - len(PARTIAL_SUFFIX)} B (the file is written as NAME{PARTIAL_SUFFIX} first)")
    return path


def free_path(path) -> Path:
    """``path``, or ``stem-2.suffix``, ``stem-3.suffix``, ... : the first name such that neither it nor its ``.partial`` exists."""
    path = Path(path)
    candidate, n = path, 1
    while any(os.path.lexists(p) for p in (candidate, candidate.with_name(candidate.name + PARTIAL_SUFFIX))):
        n += 1
        candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
    return candidate


def check_outputs(folder, names, protected=(), *, what: str = "output") -> list[Path]:
    """The paths ``folder/name`` a tool will write, each checked by :func:`check_output` (``overwrite=True``: the
    tool's own files are replaced; links, folders, devices and the ``protected`` inputs are refused)."""
    folder = Path(folder)
    return [check_output(folder / name, protected, overwrite=True, what=what) for name in names]


def write_output(path, write: Callable, *, what: str = "output") -> Path:
    """Write a file through ``write(binary_stream)`` without ever following a link at ``path``.

    ``path`` is checked by :func:`check_output` (``overwrite=True``); the data goes to a new file
    created exclusively in the same folder, which is then renamed over ``path`` (``os.replace``
    replaces a link or hard link itself, not what it points to). On any error the new file is
    removed and ``path`` is left as it was.
    """
    path = check_output(path, overwrite=True, what=what)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o666)
    try:
        with os.fdopen(fd, "wb") as stream:
            write(stream)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)  # (ours: created exclusively above)
        raise
    return path
