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
* With a Dask scheduler the cache is written by the calling process, so ``cache_dir`` need
  not be visible to remote workers; whatever files ``func`` reads must be.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

__all__ = ["SweepError", "code_hash", "content_hash", "finite_or_none", "point_key", "run_sweep"]

CACHE_VERSION = 1  # bump when the cache file layout changes


class SweepError(RuntimeError):
    """A point of a sweep failed; the message names the point."""


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
            data = path.read_bytes()
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


def _read_cached(path: Path, point: dict):
    """The cached result, or None when the file is missing, unreadable or of another point."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("point") != json.loads(_canonical(point)) or "result" not in data:
        return None
    return data["result"]


def _write_cached(path: Path, point: dict, result: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump({"point": point, "result": result}, f, sort_keys=True)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def run_sweep(func: Callable[[dict], dict], points: Sequence[dict], *, scheduler=None, workers: int | None = None,
              cache_dir=None, progress: Callable[[int, int], None] | None = None) -> list[dict]:
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
        Directory of ``<key>.json`` result files; points found there are not recomputed.
        ``None``: no cache.
    progress : callable, optional
        ``progress(done, total)`` after every finished point (cached ones included).

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
    if cache is not None:
        for key, point in zip(keys, points):
            if key not in results:
                cached = _read_cached(cache / f"{key}.json", point)
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
        if cache is not None:
            _write_cached(cache / f"{key}.json", todo[key], result)
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
    client = Client(scheduler) if own else scheduler
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


def finite_or_none(value: float):
    """``value`` as a float, or None when it is NaN/inf (for strict-JSON results)."""
    value = float(value)
    return value if math.isfinite(value) else None
