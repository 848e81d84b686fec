"""Reading input files safely: regular files of bounded size, never blocking, one-line errors.

Every file a run reads (scenario, circuit, MJCF and its includes and assets, inputs CSV) goes
through :func:`read_bytes` or :func:`read_text`, which refuse, with a
:class:`~hydraulics.components.CircuitError` (or the subclass the caller names) whose one-line
message names the file:

* a path that does not exist, holds a NUL byte, is too long, or ends in a symlink loop;
* anything that is not a regular file -- a directory, a FIFO, a socket, a character or block
  device (``/dev/zero``, ``/dev/stdin``): the type is read with ``stat`` before the file is
  opened, and the file is opened with ``O_NONBLOCK`` and checked again with ``fstat``, so a FIFO
  swapped in between never blocks the reader;
* a file larger than :data:`MAX_INPUT_BYTES` (64 MiB; the largest shipped input is ≈ 10 kB);
* for text: a NUL byte or bytes that are not UTF-8 (the byte offset is named).

Usage::

    from hydraulics.files import read_text
    text = read_text(path, "circuit")            # str, or CircuitError naming the file

Limitations: the checks guard against mistakes and hostile *inputs*; a file that is replaced
between the ``fstat`` and the last ``read`` by another process is read as it is then.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from .components import CircuitError

MAX_INPUT_BYTES = 64 * 1024 * 1024
"""Largest input file read [B] (64 MiB)."""

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def file_kind(mode: int) -> str:
    """Human name of the file type in ``st_mode``: "a regular file", "a directory", "a FIFO (named pipe)", ..."""
    if stat.S_ISREG(mode):
        return "a regular file"
    for test, name in _KINDS:
        if test(mode):
            return name
    return "not a regular file"


def _os_reason(exc: OSError) -> str:
    if exc.errno == errno.ENOENT:
        return "file not found"
    if exc.errno == errno.ELOOP:
        return "symbolic link loop (too many levels of symbolic links)"
    if exc.errno == errno.ENAMETOOLONG:
        return "file name too long"
    return f"cannot read ({exc.strerror or exc})"


def _stat(path: Path, what: str, error: type[CircuitError]) -> os.stat_result:
    try:
        return os.stat(path)
    except ValueError:  # an embedded NUL byte in the path
        raise error(f"{str(path)!r}: a file name may not hold a NUL byte ({what} file)") from None
    except FileNotFoundError:
        raise error(f"{path}: {what} file not found") from None
    except OSError as exc:
        raise error(f"{path}: {what} file: {_os_reason(exc)}") from None


def _require_regular(path, info: os.stat_result, what: str, error: type[CircuitError], limit: int) -> None:
    if not stat.S_ISREG(info.st_mode):
        raise error(f"{path}: {what} file is {file_kind(info.st_mode)}, not a regular file")
    if info.st_size > limit:
        raise error(f"{path}: {what} file is {info.st_size} B; at most {limit} B ({limit / 2**20:g} MiB) are read")


def read_bytes(path, what: str, error: type[CircuitError] = CircuitError, *, limit: int = MAX_INPUT_BYTES) -> bytes:
    """The contents of a regular file of at most ``limit`` bytes, or ``error`` naming the file.

    Parameters
    ----------
    path : str or os.PathLike
        The file (symlinks are followed; a loop is refused).
    what : str
        The kind of file for the messages ("scenario", "circuit", "MJCF", "inputs CSV").
    error : type
        :class:`CircuitError` or a subclass, raised with a one-line message.
    limit : int
        Largest size accepted [B] (default :data:`MAX_INPUT_BYTES`).
    """
    path = Path(path)
    _require_regular(path, _stat(path, what, error), what, error, limit)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise error(f"{path}: {what} file: {_os_reason(exc)}") from None
    try:
        _require_regular(path, os.fstat(fd), what, error, limit)  # (replaced between stat and open?)
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(1 << 20, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as exc:
        raise error(f"{path}: {what} file: {_os_reason(exc)}") from None
    finally:
        os.close(fd)
    if size > limit:
        raise error(f"{path}: {what} file grew beyond {limit} B ({limit / 2**20:g} MiB) while it was read")
    return b"".join(chunks)


def read_text(path, what: str, error: type[CircuitError] = CircuitError, *, limit: int = MAX_INPUT_BYTES) -> str:
    """The contents of a UTF-8 text file (see :func:`read_bytes`); NUL bytes and non-UTF-8 bytes refused."""
    data = read_bytes(path, what, error, limit=limit)
    nul = data.find(b"\0")
    if nul >= 0:
        raise error(f"{path}: {what} file holds a NUL byte at byte {nul}; it must be UTF-8 text")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: {what} file is not UTF-8 text (byte {exc.start}: {data[exc.start:exc.start + 1]!r})") from None


def resolve(path, what: str, error: type[CircuitError] = CircuitError) -> Path:
    """``path`` made absolute with its symlinks resolved, or ``error`` (symlink loop, NUL byte) naming it."""
    try:
        return Path(path).resolve()
    except ValueError:
        raise error(f"{str(path)!r}: a file name may not hold a NUL byte ({what} file)") from None
    except (RuntimeError, OSError):  # RuntimeError: Python's report of a symlink loop
        raise error(f"{path}: {what} file: symbolic link loop (too many levels of symbolic links)") from None


def check_regular(path, what: str, error: type[CircuitError] = CircuitError, *, limit: int = MAX_INPUT_BYTES) -> None:
    """Raise ``error`` unless ``path`` is a regular file of at most ``limit`` bytes (``stat`` only; nothing is opened)."""
    _require_regular(path, _stat(Path(path), what, error), what, error, limit)
