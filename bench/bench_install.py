"""Installed size of the default install and of each extra, in fresh virtual environments.

    python bench/bench_install.py [--only base tools ...] [--markdown]

The wheel is built from this checkout (``pip wheel --no-deps``); each row is a fresh venv (``python -m venv``)
into which ``pip install`` puts the wheel with the row's extras, resolved from the package index (pip's cache
makes a second run quick).  Reported: the size of the venv's ``site-packages`` beyond the empty venv's (bytes
of every file, as ``du --apparent-size``) and the distributions installed beyond the empty venv's own (pip,
setuptools), the wheel itself included.  The row ``every library required`` installs the wheel with ``--no-deps``
and the five default dependencies plus matplotlib, scipy and dask[distributed] as plain requirements: the
install a user would get if the tools' libraries were not extras.

Needs network access (or a filled pip cache) and about 4 GB of temporary disk; a few minutes.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
EVERY_LIBRARY = ("matplotlib>=3.8", "scipy>=1.11", "dask[distributed]>=2024.1")  # the tools' libraries as requirements

ROWS = {  # name -> (extras, extra plain requirements installed beside the wheel with --no-deps, or None)
    "base": ((), None),
    "tools": (("tools",), None),
    "dask": (("dask",), None),
    "live": (("live",), None),
    "gamepad": (("gamepad",), None),
    "hdf5": (("hdf5",), None),
    "all": (("all",), None),
    "dev": (("dev",), None),
    "every library required": ((), tuple(PROJECT["dependencies"]) + EVERY_LIBRARY),
}


def tree_size(path: Path) -> int:
    """Bytes of every regular file under ``path`` (symbolic links not followed)."""
    total = 0
    for folder, _, files in os.walk(path):
        for name in files:
            file = Path(folder, name)
            if not file.is_symlink():
                total += file.stat().st_size
    return total


def site_packages(venv: Path) -> Path:
    python = venv / "bin" / "python"
    out = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                         check=True, capture_output=True, text=True).stdout.strip()
    return Path(out)


def distributions(venv: Path) -> set[str]:
    python = venv / "bin" / "python"
    code = "import importlib.metadata as m; print('\\n'.join(sorted({d.metadata['Name'].lower() for d in m.distributions()})))"
    return set(subprocess.run([str(python), "-c", code], check=True, capture_output=True, text=True).stdout.split())


def pip(venv: Path, *args: str) -> None:
    subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "-qq", "install", "--disable-pip-version-check", *args],
                   check=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=list(ROWS), help="these rows only")
    parser.add_argument("--markdown", action="store_true")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="hydroplant-install-") as tmp:
        tmp = Path(tmp)
        source = tmp / "source"  # a copy: a build writes build/ and *.egg-info
        shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".git", ".venv", "logs", "__pycache__", "*.egg-info",
                                                                   "build", ".pytest_cache", ".hypothesis", ".cache"))
        subprocess.run([sys.executable, "-m", "pip", "wheel", "-qq", "--no-deps", "-w", str(tmp / "dist"), str(source)],
                       check=True)
        (wheel,) = (tmp / "dist").glob("hydroplant-*.whl")
        empty = tmp / "empty"
        subprocess.run([sys.executable, "-m", "venv", str(empty)], check=True)
        empty_size, empty_dists = tree_size(site_packages(empty)), distributions(empty)
        rows = []
        for name, (extras, plain) in ROWS.items():
            if args.only and name not in args.only:
                continue
            venv = tmp / "venv"
            shutil.rmtree(venv, ignore_errors=True)
            subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
            target = f"{wheel}[{','.join(extras)}]" if extras else str(wheel)
            if plain is None:
                pip(venv, target)
            else:
                pip(venv, "--no-deps", str(wheel))
                pip(venv, *plain)
            size = tree_size(site_packages(venv)) - empty_size
            count = len(distributions(venv) - empty_dists)
            what = f"hydroplant[{','.join(extras)}]" if extras else "hydroplant" if plain is None else "hydroplant + " + ", ".join(
                p.split(">")[0] for p in EVERY_LIBRARY)
            rows.append((name, what, size / 1e6, count))
            print(f"  {name}: {size / 1e6:.0f} MB, {count} packages", file=sys.stderr, flush=True)
            shutil.rmtree(venv)
    print(f"Fresh venvs, CPython {sys.version.split()[0]}, {sys.platform}; size of site-packages beyond an empty venv")
    print()
    if args.markdown:
        print("| install | pip install | size [MB] | packages |")
        print("|---|---|---:|---:|")
        for name, what, size, count in rows:
            print(f"| {name} | `{what}` | {size:.0f} | {count} |")
    else:
        for name, what, size, count in rows:
            print(f"{name:<24} {what:<60} {size:8.0f} MB {count:4d} packages")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
