"""Where numba keeps the compiled kernels: one folder per content key, compiled for a generic CPU.

The package's kernels (numba, ``cache=True``) are compiled once and loaded from numba's disk cache afterwards.
Before numba is imported (``import hydraulics`` runs :func:`configure` first; ``import sim`` imports
``hydraulics``), this module sets two of numba's documented environment variables:

* ``NUMBA_CPU_NAME=generic`` (unless already set): the kernels are compiled for the machine's architecture
  without the features of this particular CPU (numba then also takes ``NUMBA_CPU_FEATURES`` as empty), so a
  cache built on one x86-64 machine loads on any other (the run-time cost is measured in
  ``docs/benchmarks.md``, "The first run on a cold kernel cache").
* ``NUMBA_CACHE_DIR`` (unless already set, which is then used as is): the folder ``kernels-KEY`` whose ``KEY``
  (:func:`cache_key`) is a digest of the kernel sources' *content* (:data:`SOURCES`: every file whose functions
  or module constants are compiled into a kernel) and of the toolchain (:class:`Toolchain`: Python, numba,
  llvmlite and numpy versions, CPU name and features, platform).  A cache built for other sources, another
  toolchain or another CPU target therefore sits in another folder and is never looked up; file time stamps
  play no part in finding the folder.  Inside it numba still checks each kernel file's time stamp and size,
  so a cache built for the very files of this installation loads (a fresh clone or install builds it:
  ``hydroplant compile``, run by ``make`` after pip), and a cache whose files were since touched is
  recompiled, announced on stderr (:mod:`sim.run.compile_watch`).

The folder lies inside the virtual environment when Python runs in one (``PREFIX/var/cache/hydroplant``:
removing the environment removes it), else in the user's cache folder (``$XDG_CACHE_HOME/hydroplant``,
``~/.cache/hydroplant``; ``~/Library/Caches/hydroplant`` on macOS, ``%LOCALAPPDATA%\\hydroplant`` on Windows).
If numba was imported before ``hydraulics`` (a program that imports numba first), its settings are left as
they are: the kernels then compile for this CPU into numba's own cache.

``hydroplant compile`` records what it built in the folder (:data:`MANIFEST`: key, toolchain, kernel groups and
the sources' stamps); :func:`fits` tells whether that record covers this installation as it is now.

Example
-------
>>> from hydraulics import kernel_cache
>>> state = kernel_cache.CURRENT
>>> state.cpu
'generic'
>>> state.folder.endswith(state.key) or not state.keyed
True
"""

from __future__ import annotations

import glob
import hashlib
import json
import os
import platform
import sys
from dataclasses import asdict, dataclass

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
"""The folder holding the packages ``hydraulics`` and ``sim`` (the repository, or ``site-packages``)."""

SOURCES = (
    "hydraulics/__init__.py", "hydraulics/_jit.py", "hydraulics/_compiled.py", "hydraulics/_compiled_rigid.py",
    "hydraulics/controllers.py",
    "hydraulics/components/*.py", "hydraulics/coupling.py", "hydraulics/fluid.py", "hydraulics/network.py",
    "hydraulics/layout.py", "hydraulics/numerics.py", "hydraulics/steppers.py",
    "sim/io/__init__.py", "sim/io/log_schemas.py", "sim/io/log_writer.py", "sim/io/mcap_file.py", "sim/io/record_row.py",
    "sim/plants/__init__.py", "sim/plants/controllers.py", "sim/plants/inputs.py", "sim/plants/mujoco.py",
    "sim/plants/mujoco_fast.py",
    "sim/plants/pbd_block.py", "sim/plants/pbd_frame.py", "sim/plants/pbd_hydraulics.py",
    "sim/xpbd/__init__.py", "sim/xpbd/compiled.py",
)
"""The kernel sources, relative to :data:`ROOT` (glob patterns): every module that defines a compiled function and
every module of the package those import (numba compiles the globals a kernel reads, constants of other modules
included, into the kernel).  ``tests/test_kernel_cache.py`` checks the list against the modules' imports."""

MANIFEST = "hydroplant-kernels.json"
"""The record ``hydroplant compile`` writes into the cache folder once every group is compiled (or loaded)."""

PREFIX = "kernels-"
"""Name of a keyed cache folder: ``PREFIX + KEY``."""


@dataclass(frozen=True)
class Toolchain:
    """What, besides the sources, decides the compiled code."""

    python: str
    """Interpreter implementation and version, e.g. ``cpython-3.11.7``."""
    numba: str
    """numba's version."""
    llvmlite: str
    """llvmlite's version (numba's LLVM)."""
    numpy: str
    """numpy's version (the compiled code calls its C interface)."""
    cpu: str
    """The CPU name LLVM compiles for (``generic``: the architecture's baseline)."""
    features: str
    """The CPU features LLVM compiles for (empty for ``generic``; ``host`` when numba takes this CPU's own)."""
    platform: str
    """Operating system and architecture, e.g. ``linux-x86_64``."""


@dataclass(frozen=True)
class KernelCache:
    """The kernel cache this process uses (:data:`CURRENT`)."""

    folder: str
    """numba's cache folder (``NUMBA_CACHE_DIR``); empty when numba's own default applies."""
    key: str
    """Content key of this installation's kernel sources and toolchain (:func:`cache_key`)."""
    keyed: bool
    """True when :attr:`folder` is the keyed folder chosen here; False when ``NUMBA_CACHE_DIR`` was set by the user
    (used as is) or numba was imported first."""
    toolchain: Toolchain
    """The toolchain the key covers."""

    @property
    def cpu(self) -> str:
        return self.toolchain.cpu


def source_files(root: str = ROOT, patterns=SOURCES) -> list[str]:
    """The kernel source files under ``root`` (``patterns`` expanded), sorted by their path relative to it."""
    files = set()
    for pattern in patterns:
        files.update(glob.glob(os.path.join(root, pattern)))
    return sorted(files, key=lambda path: os.path.relpath(path, root).replace(os.sep, "/"))


def _installed_version(name: str) -> str:
    """The installed version of distribution ``name``, from its ``NAME-VERSION.dist-info`` folder beside the package
    (the installed-project layout of the Python packaging specifications; cheaper than importing
    ``importlib.metadata``), else from ``importlib.metadata``; ``"missing"`` when not installed."""
    import importlib.util

    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        return "missing"
    site = os.path.dirname(list(spec.submodule_search_locations)[0])
    try:
        entries = os.listdir(site)
    except OSError:
        entries = []
    for entry in entries:
        stem, _, version = entry.removesuffix(".dist-info").partition("-")
        if entry.endswith(".dist-info") and stem.lower().replace("-", "_") == name:
            return version
    import importlib.metadata

    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def toolchain(environ=os.environ) -> Toolchain:
    """This process's toolchain; the CPU from ``NUMBA_CPU_NAME``/``NUMBA_CPU_FEATURES`` in ``environ`` as numba will
    read them (unset name: ``host``, this CPU; ``generic`` with no features given: none)."""
    cpu = environ.get("NUMBA_CPU_NAME") or "host"
    features = environ.get("NUMBA_CPU_FEATURES")
    if features is None:
        features = "" if cpu.lower() == "generic" else "host"
    return Toolchain(python=f"{sys.implementation.name}-{'.'.join(map(str, sys.version_info[:3]))}",
                     numba=_installed_version("numba"), llvmlite=_installed_version("llvmlite"),
                     numpy=_installed_version("numpy"), cpu=cpu, features=features,
                     platform=f"{sys.platform}-{platform.machine().lower()}")


def cache_key(files, root: str, chain: Toolchain) -> str:
    """sha256 (first 20 hex digits) of the files' paths relative to ``root`` and contents, and of ``chain``.

    Content only: touching a file (a fresh clone, a checkout, a copy) keeps the key; any changed byte, another
    toolchain or another CPU target changes it.  An unreadable file counts by its path alone."""
    digest = hashlib.sha256()
    for path in files:
        digest.update(os.path.relpath(path, root).replace(os.sep, "/").encode() + b"\0")
        try:
            with open(path, "rb") as f:
                digest.update(hashlib.sha256(f.read()).digest())
        except OSError:
            digest.update(b"unreadable")
    digest.update(json.dumps(asdict(chain), sort_keys=True).encode())
    return digest.hexdigest()[:20]


def cache_root(environ=os.environ) -> str:
    """The folder holding the keyed cache folders: inside the virtual environment if Python runs in one, else the
    user's cache folder (see the module docstring)."""
    if sys.prefix != sys.base_prefix:
        return os.path.join(sys.prefix, "var", "cache", "hydroplant")
    if sys.platform == "win32":
        base = environ.get("LOCALAPPDATA") or os.path.expanduser(r"~\AppData\Local")
    elif sys.platform == "darwin":
        base = os.path.expanduser("~/Library/Caches")
    else:
        base = environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
    return os.path.join(base, "hydroplant")


def stamps(files, root: str = ROOT) -> dict[str, list]:
    """{path relative to ``root``: [modification time in ns, size in bytes]}: what numba checks before it loads a
    kernel compiled from a file."""
    out = {}
    for path in files:
        try:
            stat = os.stat(path)
            out[os.path.relpath(path, root).replace(os.sep, "/")] = [stat.st_mtime_ns, stat.st_size]
        except OSError:
            pass
    return out


def configure(environ=os.environ) -> KernelCache:
    """Choose numba's cache folder and CPU target in ``environ`` before numba is imported (see the module
    docstring); the choice, as :class:`KernelCache`.  Creates the keyed folder (a folder that cannot be created
    leaves numba's default in place)."""
    if "numba" in sys.modules:  # too late to choose: numba read its environment when it was imported
        chain = toolchain(environ)
        return KernelCache(folder=environ.get("NUMBA_CACHE_DIR", ""), key=cache_key(source_files(), ROOT, chain),
                           keyed=False, toolchain=chain)
    environ.setdefault("NUMBA_CPU_NAME", "generic")
    chain = toolchain(environ)
    key = cache_key(source_files(), ROOT, chain)
    given = environ.get("NUMBA_CACHE_DIR", "")
    keyed = os.path.join(cache_root(environ), PREFIX + key)
    if given and os.path.abspath(given) != os.path.abspath(keyed):
        return KernelCache(folder=given, key=key, keyed=False, toolchain=chain)
    try:
        os.makedirs(keyed, exist_ok=True)
    except OSError:
        return KernelCache(folder="", key=key, keyed=False, toolchain=chain)
    environ["NUMBA_CACHE_DIR"] = keyed
    return KernelCache(folder=keyed, key=key, keyed=True, toolchain=chain)


def read_manifest(folder: str) -> dict | None:
    """The record ``hydroplant compile`` left in ``folder``, or None."""
    try:
        with open(os.path.join(folder, MANIFEST), encoding="utf-8") as f:
            record = json.load(f)
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def fits(cache: KernelCache, groups, root: str = ROOT) -> bool:
    """True when ``cache``'s folder holds a complete build of ``groups`` for these very source files (under
    ``root``): same key and source folder, and every kernel source with the time stamp and size it had when it was
    built (numba then loads every kernel instead of compiling it)."""
    if not cache.folder:
        return False
    record = read_manifest(cache.folder)
    return bool(record and record.get("key") == cache.key and record.get("root") == root
                and set(groups) <= set(record.get("groups", ()))
                and record.get("stamps") == stamps(source_files(root), root))


def write_manifest(cache: KernelCache, groups, root: str = ROOT) -> None:
    """Record in ``cache``'s folder that ``groups`` were compiled (or loaded) for the sources under ``root`` as they
    are now."""
    if not cache.folder:
        return
    record = read_manifest(cache.folder) or {}
    done = set(groups) | (set(record.get("groups", ())) if record.get("key") == cache.key else set())
    record = {"key": cache.key, "root": root, "python": sys.executable, "toolchain": asdict(cache.toolchain),
              "groups": sorted(done), "stamps": stamps(source_files(root), root)}
    path = os.path.join(cache.folder, MANIFEST)
    with open(path + ".tmp", "w", encoding="utf-8") as f:
        json.dump(record, f, indent=1)
    os.replace(path + ".tmp", path)


def superseded(cache: KernelCache, root: str = ROOT) -> list[str]:
    """Keyed folders beside ``cache``'s that ``hydroplant compile`` built for this same source folder (``root``) and
    interpreter with other sources or another toolchain: caches no run of this installation can load any more."""
    if not cache.keyed:
        return []
    parent = os.path.dirname(cache.folder)
    out = []
    for name in sorted(os.listdir(parent)):
        folder = os.path.join(parent, name)
        if not name.startswith(PREFIX) or folder == cache.folder:
            continue
        record = read_manifest(folder)
        if record and record.get("root") == root and record.get("python") == sys.executable:
            out.append(folder)
    return out


def describe(cache: KernelCache) -> str:
    """Why a kernel is being compiled, in a few words for the run's announcement."""
    if not cache.folder:
        return "numba's own cache"
    record = read_manifest(cache.folder)
    if record is None:
        return f"no prebuilt kernel cache in {cache.folder}"
    if record.get("stamps") != stamps(source_files()):
        return f"the kernel sources' time stamps differ from the build in {cache.folder}"
    return f"kernels missing from {cache.folder}"


CURRENT = configure()
"""The kernel cache of this process, chosen when ``hydraulics`` is first imported."""
