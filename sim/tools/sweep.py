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
  not be visible to remote workers.
* Scene files travel as content: :func:`scene_bundle` reads every input file of a scenario (the
  scenario, circuit, MJCF with its includes and assets, inputs CSV) into a :class:`Bundle` (relative
  paths and bytes, named by a content digest).  A point names its bundle (``"bundle": digest``) and
  its files relative to the bundle (``"scenario": "boom/lift.scenario.toml"``), so its cache key holds
  no path of this machine.  When the point runs, ``func`` sees ``point["bundle_root"]`` (the folder
  holding the bundle; :func:`point_file` joins the two): on the local pool the folder the files were
  read from; on a Dask worker a private folder in the worker's local directory (``dask worker
  --local-directory``) into which the bundle was written once (:func:`materialise`), reused by every
  later point of that bundle.  Bundles are sent to the workers once (``client.scatter``).  Text
  fields of a result lose the bundle folder's prefix (an error names ``boom/lift.scenario.toml``, on
  every engine alike), and fields the function copied back unchanged from the added ones are dropped,
  so that a result does not depend on where it was computed.
* On a cluster, :func:`run_sweep` waits at most ``worker_timeout`` seconds for a worker
  (:class:`SchedulerError` otherwise), prints the dashboard link, and runs ``warm_up(points)`` once
  on every worker before the points (e.g. to compile the kernels, so that no point's timing includes
  compilation).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import sys
import tempfile
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from hydraulics.components import CircuitError
from hydraulics.files import read_bytes, read_text

__all__ = ["Bundle", "Cluster", "SchedulerError", "SweepError", "check_scheduler", "check_workers", "code_hash", "content_hash", "entry_digest",
           "finite_or_none", "func_code_hash", "materialise", "point_file", "point_key", "run_sweep", "scene_bundle"]

CACHE_VERSION = 2  # bump when the cache file layout changes
FAILED_STATUS = "error"  # a result with this "status" is not cached


class SweepError(RuntimeError):
    """A point of a sweep failed; the message names the point."""


class SchedulerError(CircuitError):
    """The Dask scheduler named by ``scheduler`` cannot be reached (bad input: the command line exits 2)."""


SCHEDULER_TIMEOUT = 10.0  # s to connect to a Dask scheduler
WORKER_TIMEOUT = 60.0  # s to wait for the first Dask worker to join the scheduler
BUNDLE_ROOT = "bundle_root"  # point field set when the point runs: the folder holding its bundle's files


@dataclass(frozen=True)
class Cluster:
    """Where a sweep's points run: the workers of a Dask scheduler, or a local process pool.

    Example: ``Cluster("tcp://host:8786", worker_timeout=120)``; ``Cluster(workers=2)``.
    """

    scheduler: str | None = None
    """Dask scheduler address ``tcp://host:port``; ``None``: a local process pool."""
    workers: int | None = None
    """Local worker processes (``None``: the CPU count); not used with a scheduler."""
    worker_timeout: float = WORKER_TIMEOUT
    """Longest wait for a first Dask worker to join the scheduler [s]."""


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


@dataclass(frozen=True)
class Bundle:
    """The input files of a scene as content, to run it where its files are not (a Dask worker).

    ``files``: ``((relative POSIX path, bytes), ...)`` sorted by path; ``digest``: :func:`bundle_digest`
    of them; ``source``: the folder on this machine they were read from (local runs read the files
    there; a worker writes them into a folder of its own, :func:`materialise`).
    """

    files: tuple
    digest: str
    source: str


def bundle_digest(files) -> str:
    """SHA-256 (hex) of a bundle's ``(relative path, bytes)`` pairs, in order: its name and cache identity."""
    return content_hash(*(item for rel, data in files for item in (rel.encode(), data)))


def _safe_relative(rel: str) -> PurePosixPath:
    path = PurePosixPath(rel)
    if path.is_absolute() or ".." in path.parts or not path.parts:
        raise ValueError(f"bundle path {rel!r} must be relative and stay inside the bundle")
    return path


def _write_bundle(files, root: Path) -> None:
    for rel, data in files:
        target = root.joinpath(*_safe_relative(rel).parts)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)


def scene_bundle(scenario) -> tuple[Bundle, str]:
    """Every input file of ``scenario`` (:func:`sim.io.scene.input_paths`) as a :class:`Bundle`.

    The files keep their layout below the parent of their common folder (so the scene folder keeps its
    name, :attr:`~sim.io.scenario.Scenario.scene_name`).  Returns the bundle and the scenario's path in
    it.  Raises :class:`~sim.io.scenario.ScenarioError` when the files do not work from another folder
    (a scene file naming another by an absolute path): the bundle is written into a temporary folder and
    loaded from there to check that every input resolves inside it.

    Example::

        bundle, rel = scene_bundle(load_scenario("models/boom/lift.scenario.toml"))
        rel  # "boom/lift.scenario.toml"
    """
    from sim.io.scenario import ScenarioError, as_scenario
    from sim.io.scene import input_paths

    scenario = as_scenario(scenario)
    paths = list(dict.fromkeys(Path(p) for p in input_paths(scenario)))
    common = Path(os.path.commonpath([str(p.parent) for p in paths]))
    root = common.parent
    files = tuple(sorted((p.relative_to(root).as_posix(), read_bytes(p, "scene input")) for p in paths))
    rel = Path(scenario.path).relative_to(root).as_posix()
    with tempfile.TemporaryDirectory(prefix="hydroplant-bundle-check-") as tmp:
        copy = Path(tmp).resolve()
        _write_bundle(files, copy)
        try:
            moved = input_paths(as_scenario(copy / rel))
        except ScenarioError as exc:
            raise ScenarioError(f"{scenario.path}: the scene does not work when its files are copied to another folder "
                                f"(a cluster run ships them as content): {exc}") from None
        outside = [p for p in moved if not Path(p).resolve().is_relative_to(copy)]
        if outside:
            raise ScenarioError(f"{scenario.path}: the scene names {outside[0]} by an absolute path; a cluster run ships "
                                "the scene as content and needs every file named relative to the file that names it")
    return Bundle(files, bundle_digest(files), str(root)), rel


_MATERIALISED: dict = {}  # bundle digest -> TemporaryDirectory holding its files (one per worker process)
_MATERIALISE_LOCK = threading.Lock()


def materialise(bundle: Bundle, base=None) -> Path:
    """The folder holding ``bundle``'s files in this process: written once per digest into a new private
    temporary folder below ``base`` (default: the system's temporary folder), reused afterwards.

    The files' digest is checked before use; the folder is removed when the process exits.
    """
    with _MATERIALISE_LOCK:
        held = _MATERIALISED.get(bundle.digest)
        if held is not None and Path(held.name).is_dir():
            return Path(held.name)
        if bundle_digest(bundle.files) != bundle.digest:
            raise ValueError(f"bundle {bundle.digest[:12]}: its files do not match its digest")
        if base is not None:
            Path(base).mkdir(parents=True, exist_ok=True)
        folder = tempfile.TemporaryDirectory(prefix=f"hydroplant-scene-{bundle.digest[:12]}-", dir=base,
                                             ignore_cleanup_errors=True)  # (the worker may remove its directory first)
        _write_bundle(bundle.files, Path(folder.name))
        _MATERIALISED[bundle.digest] = folder
        return Path(folder.name)


def point_file(point: dict, name: str = "scenario") -> str:
    """The path of a point's file ``point[name]``: below ``point["bundle_root"]`` when the point names a bundle."""
    root = point.get(BUNDLE_ROOT)
    return str(Path(root) / point[name]) if root is not None else point[name]


def _located(point: dict, root, context: dict | None) -> dict:
    extra = dict(context or {})
    if root is not None:
        extra[BUNDLE_ROOT] = str(root)
    return {**point, **extra}


def _run_located(func, point: dict, root, context: dict | None):
    """``func`` at ``point`` with ``context`` and the bundle root added; fields it copies back unchanged are dropped,
    and the bundle root is cut from its text fields, so a result does not depend on where it was computed."""
    located = _located(point, root, context)
    result = func(located)
    if isinstance(result, dict):
        added = {k: v for k, v in located.items() if k not in point}
        result = {k: v for k, v in result.items() if not (k in added and v == added[k])}
        if root is not None and Path(root).parent != Path(root):  # (not when the bundle is the whole file system)
            prefix = str(root).rstrip(os.sep) + os.sep
            result = {k: v.replace(prefix, "") if isinstance(v, str) else v for k, v in result.items()}
    return result


def _run_local_point(func, point: dict, source, context: dict | None):
    """A point in this machine's process pool: the bundle's files are read where they are (``source``)."""
    return _run_located(func, point, source, context)


def _worker_directory():
    """The local directory of the Dask worker running this task (``dask worker --local-directory``), if any."""
    try:
        from dask.distributed import get_worker

        return get_worker().local_directory
    except (ImportError, ValueError):
        return None


def _run_remote_point(func, point: dict, bundle: Bundle | None, context: dict | None):
    """A point on a Dask worker: the bundle's files written once into the worker's local directory."""
    root = materialise(bundle, _worker_directory()) if bundle is not None else None
    return _run_located(func, point, root, context)


def _remote_warm_up(warm_up, points: list, bundles: dict, context: dict | None) -> str:
    """``warm_up`` on one worker with the points located there; returns the worker's address."""
    located = []
    for point in points:
        bundle = bundles.get(point.get("bundle"))
        root = materialise(bundle, _worker_directory()) if bundle is not None else None
        located.append(_located(point, root, context))
    warm_up(located)
    try:
        from dask.distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return ""


def run_sweep(func: Callable[[dict], dict], points: Sequence[dict], *, scheduler=None, workers: int | None = None,
              cache_dir=None, progress: Callable[[int, int], None] | None = None, fresh: bool = False,
              bundles: Sequence[Bundle] = (), context: dict | None = None, worker_timeout: float = WORKER_TIMEOUT,
              warm_up: Callable[[list], None] | None = None) -> list[dict]:
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
    bundles : sequence of Bundle
        The scene files the points name by ``"bundle": digest`` (:func:`scene_bundle`).
    context : dict, optional
        Fields added to every point when it runs but not part of its key (e.g. an output folder of
        this machine); fields a result copies back unchanged are dropped from it.
    worker_timeout : float
        Seconds to wait for a first Dask worker (:class:`SchedulerError` after that).
    warm_up : callable, optional
        ``warm_up(points)``, run once on every Dask worker before the points (the points located there).

    Returns
    -------
    list of dict
        The results, in the order of ``points``.

    Raises
    ------
    SweepError
        When ``func`` raises at a point; points finished before are cached.
    SchedulerError
        When the scheduler cannot be reached or no worker joins within ``worker_timeout``.
    """
    points = list(points)
    by_digest = {b.digest: b for b in bundles}
    for i, point in enumerate(points):
        if not isinstance(point, dict):
            raise TypeError(f"point {i} must be a dict, got {type(point).__name__}")
        _canonical(point)
        if point.get("bundle") is not None and point["bundle"] not in by_digest:
            raise ValueError(f"point {i} names bundle {point['bundle']!r}, which is not among `bundles`")
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
            _run_dask(func, todo, scheduler, finished, bundles=by_digest, context=context, worker_timeout=worker_timeout,
                      warm_up=warm_up)
        elif (workers or os.cpu_count() or 1) == 1:
            for key, point in todo.items():
                try:
                    result = _run_local_point(func, point, _source(point, by_digest), context)
                except Exception as exc:
                    raise SweepError(f"sweep point {point!r} failed: {type(exc).__name__}: {exc}") from exc
                finished(key, result)
        else:
            _run_pool(func, todo, min(workers or os.cpu_count() or 1, len(todo)), finished, by_digest, context)
    return [results[key] for key in keys]


def _source(point: dict, bundles: dict):
    bundle = bundles.get(point.get("bundle"))
    return bundle.source if bundle is not None else None


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


def _run_pool(func, todo: dict, workers: int, finished, bundles: dict, context: dict | None) -> None:
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = {pool.submit(_run_local_point, func, point, _source(point, bundles), context): key
                   for key, point in todo.items()}
        try:
            _collect(as_completed(futures), futures, todo, finished)
        except BaseException:
            for future in futures:
                future.cancel()
            raise


def _run_dask(func, todo: dict, scheduler, finished, *, bundles: dict, context: dict | None, worker_timeout: float,
              warm_up=None) -> None:
    from dask.distributed import Client, wait
    from dask.distributed import as_completed as dask_completed

    own = not isinstance(scheduler, Client)
    client = _connect(scheduler) if own else scheduler
    try:
        _await_workers(client, client.scheduler_info().get("address") or str(scheduler), worker_timeout)
        if own and client.dashboard_link:
            print(f"Dask dashboard: {client.dashboard_link}", file=sys.stderr, flush=True)
        keys = list(todo)
        needed = {todo[k].get("bundle") for k in keys} - {None}
        # each bundle travels once to every worker (later workers fetch it from a peer)
        remote = {d: client.scatter(bundles[d], broadcast=True, hash=False) for d in sorted(needed)}
        if warm_up is not None:
            workers = list(client.scheduler_info()["workers"])
            warm = [client.submit(_remote_warm_up, warm_up, [todo[k] for k in keys], remote, context, workers=[w],
                                  allow_other_workers=False, pure=False) for w in workers]
            wait(warm)
            for future in warm:
                if future.status == "error":
                    exc = future.exception()
                    raise SweepError(f"warm-up on a Dask worker failed: {type(exc).__name__}: {exc}")
        # pure=False with explicit keys: every point runs once, named by its cache key.
        futures = client.map(functools.partial(_run_remote_point, func, context=context), [todo[k] for k in keys],
                             [remote.get(todo[k].get("bundle")) for k in keys],
                             key=[f"hydroplant-sweep-{k}" for k in keys], pure=False)
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


def check_workers(address: str, timeout: float = WORKER_TIMEOUT) -> None:
    """Raise :class:`SchedulerError` unless the Dask scheduler at ``address`` has a worker within ``timeout`` seconds.

    Checked before a long computation on this machine (a reference run) so that a cluster without workers is
    one line at once: ``no Dask workers joined tcp://host:8786 within 60 s (start them with: dask worker tcp://host:8786)``.
    """
    client = _connect(address)
    try:
        _await_workers(client, address, timeout)
    finally:
        client.close()


def _connect(address: str):
    """A :class:`dask.distributed.Client` of the scheduler at ``address``, or :class:`SchedulerError`."""
    from dask.distributed import Client

    try:
        return Client(address, timeout=SCHEDULER_TIMEOUT)
    except (OSError, TimeoutError, ValueError) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise SchedulerError(f"--scheduler {address}: no Dask scheduler reachable within {SCHEDULER_TIMEOUT:g} s "
                             f"({reason:.200})") from None


def _await_workers(client, address: str, timeout: float) -> None:
    try:
        client.wait_for_workers(1, timeout=timeout)
    except TimeoutError:
        raise SchedulerError(f"no Dask workers joined {address} within {timeout:g} s "
                             f"(start them with: dask worker {address})") from None


def finite_or_none(value: float):
    """``value`` as a float, or None when it is NaN/inf (for strict-JSON results)."""
    value = float(value)
    return value if math.isfinite(value) else None
