"""Parameter sweeps: one function over many points, in parallel, cached, resumable.

::

    from sim.tools.sweep import run_sweep, content_hash

    def simulate(point: dict) -> dict:          # top level, so that it pickles
        ...
        return {"error_m": ..., "wall_s": ...}

    points = [{"dt": dt, "scene": content_hash("models/boom/boom.xml")} for dt in (1e-3, 5e-4)]
    results = run_sweep(simulate, points, cache_dir=".cache/sweeps/boom")

* ``func(point) -> dict`` runs in worker processes: a
  :class:`concurrent.futures.ProcessPoolExecutor` by default, or the workers of a Dask
  cluster when ``scheduler="tcp://host:port"`` (:class:`dask.distributed.Client`,
  ``client.map`` / ``as_completed``).  Points and results must be JSON-serialisable.
* Results come back in point order and are passed through JSON (``json.loads(json.dumps(r))``)
  whether they were computed now, on another engine, or read from the cache, so a sweep
  returns identical values either way (for a deterministic ``func``).
* Cache: each finished point is written at once to ``cache_dir/<key>.json`` (atomically:
  temporary file + rename), where ``key`` is :func:`point_key` -- a SHA-256 of the sorted
  JSON of the point and of the function's qualified name.  Whatever else a result depends on
  (scene files, a reference log, code) the caller puts into the point, e.g. as
  :func:`content_hash` values.  A sweep that is interrupted (Ctrl-C, a killed job, a crashed
  worker) and started again recomputes only the points without a cache file.
* Each cache file carries what made it -- the point, the key, the function's name and a hash
  of its code (:func:`func_code_hash`: the simulation source, :func:`code_hash`, and the
  function's own module) -- and a SHA-256 ``digest`` of all that and the result
  (:func:`entry_digest`).  On reading, every one of them is checked against the present point
  and code; a file that fails any check (damaged, made by other code, or a file put there by
  hand under the right name) is ignored and its point computed again.  The digest is a
  content hash, not a signature: it catches damage, stale and planted entries, not someone who
  recomputes it.
* A point whose result has ``"status": "error"`` (the function caught a failure and reported
  it, e.g. :func:`sim.tools.tradeoff.run_point`) is returned but not cached, so that a rerun
  tries it again; a point whose function raises stops the sweep (:class:`SweepError`).
* With a Dask scheduler the cache is written by the calling process, so ``cache_dir`` need
  not be visible to remote workers; whatever files ``func`` reads must be.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import tempfile
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from hydraulics.components import CircuitError
from hydraulics.files import read_bytes, read_text

__all__ = ["SchedulerError", "SweepError", "check_scheduler", "code_hash", "content_hash", "entry_digest", "finite_or_none", "func_code_hash",
           "point_key", "run_sweep"]

CACHE_VERSION = 2  # bump when the cache file layout changes
FAILED_STATUS = "error"  # a result with this "status" is not cached


class SweepError(RuntimeError):
    """A point of a sweep failed; the message names the point."""


class SchedulerError(CircuitError):
    """The Dask scheduler named by ``scheduler`` cannot be reached (bad input: the command line exits 2)."""


SCHEDULER_TIMEOUT = 10.0  # s to connect to a Dask scheduler


def content_hash(*items) -> str:
    """SHA-256 (hex) of the contents of files and byte strings, in order.

    Parameters
    ----------
    *items : str, os.PathLike, bytes or bytearray
        Paths (their file contents are hashed, not their names) or raw bytes.

    Returns
    -------
    str
        64 hex digits; the same contents in the same order give the same hash.
    """
    digest = hashlib.sha256()
    for item in items:
        if isinstance(item, (bytes, bytearray, memoryview)):
            data = bytes(item)
        elif isinstance(item, (str, os.PathLike)):
            path = Path(item)
            if not path.is_file():
                raise FileNotFoundError(f"content_hash: {path} is not a file")
            data = read_bytes(path, "hashed")  # bounded size, never blocking
        else:
            raise TypeError(f"content_hash takes paths or bytes, got {type(item).__name__}: {item!r}")
        digest.update(len(data).to_bytes(8, "little"))  # so that ("ab", "c") != ("a", "bc")
        digest.update(data)
    return digest.hexdigest()


CODE_PACKAGES = ("hydraulics", "sim")
"""Packages whose source code a simulation result depends on (see :func:`code_hash`)."""
ANALYSIS_FILES = frozenset({"compare.py", "tradeoff.py", "sweep.py", "reference.py", "cli.py", "inspect.py", "demo.py"})
"""Files of those packages that analyse or launch runs but do not change a run's result."""


def code_hash(root=None, packages=CODE_PACKAGES, exclude=ANALYSIS_FILES) -> str:
    """SHA-256 (hex) of the simulation source: every ``*.py`` below ``packages`` but ``exclude``, by relative path.

    Put it into sweep points and reference keys so that a cached result is not reused
    after the code that computed it has changed.  ``root`` defaults to the directory
    holding this package (the project root).
    """
    root = Path(root) if root is not None else Path(__file__).resolve().parents[2]
    files = sorted(p for package in packages for p in (root / package).rglob("*.py")
                   if p.name not in exclude and "__pycache__" not in p.parts)
    return content_hash(*(p.relative_to(root).as_posix().encode() for p in files), *files)


def _canonical(value) -> str:
    """Sorted, compact JSON; rejects NaN/inf and non-JSON types with the offending value named."""
    try:
        return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"sweep points and results must be JSON-serialisable (finite floats only): {exc}: {value!r}") from None


def _func_name(func: Callable) -> str:
    return f"{getattr(func, '__module__', '?')}:{getattr(func, '__qualname__', repr(func))}"


def point_key(point: dict, func: Callable | None = None) -> str:
    """Cache key of a point: SHA-256 of its sorted JSON (and of ``func``'s qualified name)."""
    payload = {"point": point, "func": _func_name(func) if func is not None else None, "version": CACHE_VERSION}
    return hashlib.sha256(_canonical(payload).encode()).hexdigest()


def _roundtrip(result) -> dict:
    """The result as it will read back from a cache file (NaN/inf allowed, as in Python's json)."""
    if not isinstance(result, dict):
        raise TypeError(f"the sweep function must return a dict, got {type(result).__name__}")
    return json.loads(json.dumps(result, sort_keys=True))


def func_code_hash(func: Callable, code: str | None = None) -> str:
    """SHA-256 of the code behind ``func``'s results: :func:`code_hash` (or ``code``) and the source of ``func``'s module."""
    module = sys.modules.get(getattr(func, "__module__", None) or "")
    source = getattr(module, "__file__", None)
    items = [(code or code_hash()).encode(), _func_name(func).encode()]
    if source and Path(source).is_file():
        items.append(Path(source))
    return content_hash(*items)


def entry_digest(entry: dict) -> str:
    """SHA-256 of a cache entry's fields but ``digest`` (sorted JSON, NaN and inf as Python writes them)."""
    body = {k: v for k, v in entry.items() if k != "digest"}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _read_cached(path: Path, point: dict, key: str, made_by: dict):
    """The cached result, or None when the file is missing, unreadable, of another point or code, or fails its digest."""
    try:
        data = json.loads(read_text(path, "sweep cache"))
    except (CircuitError, ValueError, RecursionError):
        return None
    if not isinstance(data, dict) or set(data) != {"version", "key", "point", "made_by", "result", "digest"}:
        return None
    if (data["version"] != CACHE_VERSION or data["key"] != key or data["point"] != json.loads(_canonical(point))
            or data["made_by"] != made_by or not isinstance(data["result"], dict) or data["digest"] != entry_digest(data)):
        return None
    return data["result"]


def _write_cached(path: Path, point: dict, result: dict, key: str, made_by: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    entry = {"version": CACHE_VERSION, "key": key, "point": point, "made_by": made_by, "result": result}
    entry["digest"] = entry_digest(entry)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(entry, f, sort_keys=True)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def run_sweep(func: Callable[[dict], dict], points: Sequence[dict], *, scheduler=None, workers: int | None = None,
              cache_dir=None, progress: Callable[[int, int], None] | None = None, fresh: bool = False) -> list[dict]:
    """Evaluate ``func`` at every point, in parallel, with a per-point result cache.

    Parameters
    ----------
    func : callable
        ``func(point: dict) -> dict``, a picklable top-level function; deterministic if the
        results are to be identical between engines and reruns.
    points : sequence of dict
        JSON-serialisable points. Equal points are computed once.
    scheduler : str or dask.distributed.Client, optional
        ``"tcp://host:port"`` of a Dask scheduler (or a connected Client). Default: a local
        process pool.
    workers : int, optional
        Process-pool size (default ``os.cpu_count()``); ``1`` runs the points one after the
        other in this process. Ignored with a scheduler.
    cache_dir : str or Path, optional
        Directory of ``<key>.json`` result files; points found there (and passing their checks,
        see the module docstring) are not recomputed. ``None``: no cache.
    progress : callable, optional
        ``progress(done, total)`` after every finished point (cached ones included).
    fresh : bool
        Read nothing from the cache: every point is computed (and its result cached).

    Returns
    -------
    list of dict
        The results, in the order of ``points``.

    Raises
    ------
    SweepError
        When ``func`` raises at a point; points finished before are cached.
    """
    points = list(points)
    for i, point in enumerate(points):
        if not isinstance(point, dict):
            raise TypeError(f"point {i} must be a dict, got {type(point).__name__}")
        _canonical(point)
    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise ValueError(f"`workers` must be a positive integer, got {workers!r}")
    keys = [point_key(p, func) for p in points]
    cache = Path(cache_dir) if cache_dir is not None else None
    results: dict[str, dict] = {}
    made_by = {"func": _func_name(func), "code": func_code_hash(func)} if cache is not None else {}
    if cache is not None and not fresh:
        for key, point in zip(keys, points):
            if key not in results:
                cached = _read_cached(cache / f"{key}.json", point, key, made_by)
                if cached is not None:
                    results[key] = cached
    todo = {}
    for key, point in zip(keys, points):
        if key not in results and key not in todo:
            todo[key] = point
    total = len(set(keys))
    done = len(results)
    if progress is not None and done:
        progress(done, total)

    def finished(key, result):
        nonlocal done
        result = _roundtrip(result)
        if cache is not None and result.get("status") != FAILED_STATUS:
            _write_cached(cache / f"{key}.json", todo[key], result, key, made_by)
        results[key] = result
        done += 1
        if progress is not None:
            progress(done, total)

    if todo:
        if scheduler is not None:
            _run_dask(func, todo, scheduler, finished)
        elif (workers or os.cpu_count() or 1) == 1:
            for key, point in todo.items():
                try:
                    result = func(point)
                except Exception as exc:
                    raise SweepError(f"sweep point {point!r} failed: {type(exc).__name__}: {exc}") from exc
                finished(key, result)
        else:
            _run_pool(func, todo, min(workers or os.cpu_count() or 1, len(todo)), finished)
    return [results[key] for key in keys]


def _collect(completed, key_of: dict, todo: dict, finished) -> None:
    """Hand each future's result to ``finished(key, result)`` as it completes.

    ``completed`` yields the futures in completion order (``as_completed`` of the
    process pool or of dask), ``key_of`` maps a future to its cache key. A point
    that raised becomes a :class:`SweepError` naming the point.
    """
    for future in completed:
        key = key_of[future]
        try:
            result = future.result()
        except Exception as exc:
            raise SweepError(f"sweep point {todo[key]!r} failed: {type(exc).__name__}: {exc}") from exc
        finished(key, result)


def _run_pool(func, todo: dict, workers: int, finished) -> None:
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = {pool.submit(func, point): key for key, point in todo.items()}
        try:
            _collect(as_completed(futures), futures, todo, finished)
        except BaseException:
            for future in futures:
                future.cancel()
            raise


def _run_dask(func, todo: dict, scheduler, finished) -> None:
    from dask.distributed import Client
    from dask.distributed import as_completed as dask_completed

    own = not isinstance(scheduler, Client)
    if own:
        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT)
        except (OSError, TimeoutError, ValueError) as exc:
            reason = " ".join(str(exc).split()) or type(exc).__name__
            raise SchedulerError(f"--scheduler {scheduler}: no Dask scheduler reachable within {SCHEDULER_TIMEOUT:g} s "
                                 f"({reason:.200})") from None
    else:
        client = scheduler
    try:
        keys = list(todo)
        # pure=False with explicit keys: every point runs once, named by its cache key.
        futures = client.map(func, [todo[k] for k in keys], key=[f"hydroplant-sweep-{k}" for k in keys], pure=False)
        by_future = dict(zip(futures, keys))
        try:
            _collect(dask_completed(futures), by_future, todo, finished)
        except BaseException:
            client.cancel(futures)
            raise
    finally:
        if own:
            client.close()


def check_scheduler(address: str, timeout: float = SCHEDULER_TIMEOUT) -> None:
    """Raise :class:`SchedulerError` unless something accepts a TCP connection at a ``tcp://host:port`` address.

    A quick probe before a long computation, so that a closed port or a wrong host is reported at once,
    in one line; other schemes (``tls://``, ``inproc://``, ...) are left to Dask.
    """
    import socket
    from urllib.parse import urlsplit

    if not address.startswith("tcp://"):
        return
    try:
        parts = urlsplit(address)
        host, port = parts.hostname, parts.port
    except ValueError as exc:
        raise SchedulerError(f"--scheduler {address}: not an address like tcp://host:8786 ({exc})") from None
    if not host or port is None:
        raise SchedulerError(f"--scheduler {address}: not an address like tcp://host:8786 (host and port needed)")
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise SchedulerError(f"--scheduler {address}: no Dask scheduler reachable ({reason})") from None


def finite_or_none(value: float):
    """``value`` as a float, or None when it is NaN/inf (for strict-JSON results)."""
    value = float(value)
    return value if math.isfinite(value) else None
