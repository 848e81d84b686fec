"""The built wheel, installed outside the repository, carries every module and the example scenes.

The wheel is built from this checkout and installed with ``--no-deps`` into a fresh virtual
environment whose only other path is the test interpreter's own site-packages (added by a
``.pth`` line, so the dependencies are found but the checkout's editable install is not
processed).  Every command then runs from a directory outside the repository, so a module or
data file missing from the wheel fails here and not on a user's machine.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("hydraulics", "sim", "hydroplant")


def _shipped_sources() -> set[str]:
    """Paths (inside the wheel) of every module of the packages and every example scene file."""
    modules = {p.relative_to(ROOT).as_posix() for package in PACKAGES for p in (ROOT / package).rglob("*.py")
               if "__pycache__" not in p.parts}
    examples = {"sim/examples/" + p.relative_to(ROOT / "models").as_posix() for p in (ROOT / "models").rglob("*")
                if p.is_file() and p.suffix in (".xml", ".toml", ".md", ".csv", ".stl", ".obj")}
    schemas = {p.relative_to(ROOT).as_posix() for p in (ROOT / "sim" / "schemas").glob("*.schema.json")}
    return modules | examples | schemas


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(python, hydroplant script, working folder) of a fresh venv holding only the built wheel."""
    base = tmp_path_factory.mktemp("wheel")
    source, dist = base / "source", base / "dist"  # built from a copy: a build writes build/ and *.egg-info
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".git", ".venv", "logs", "__pycache__", "*.egg-info",
                                                               "build", ".pytest_cache", ".hypothesis", ".cache"))
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(dist), str(source)],
                           check=True, capture_output=True, text=True, cwd=base)
    (wheel,) = dist.glob("hydroplant-*.whl")
    env_dir = base / "venv"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             check=True, capture_output=True, text=True).stdout.strip()
    Path(purelib, "test-dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet", "--no-deps",
                    str(wheel)], check=True, capture_output=True, cwd=base)
    work = base / "elsewhere"
    work.mkdir()
    return wheel, python, env_dir / "bin" / "hydroplant", work, build.stdout + build.stderr


def _run(installed, *args, timeout=600):
    wheel, python, script, work, _ = installed
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR")}
    result = subprocess.run([str(script), *args], cwd=work, env=env, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, f"hydroplant {' '.join(args)} exited {result.returncode}:\n{result.stderr[-2000:]}"
    return result.stdout


def test_wheel_holds_every_module_and_example(installed):
    """Nothing of hydraulics/, sim/ or models/ is left out of the wheel."""
    names = set(zipfile.ZipFile(installed[0]).namelist())
    missing = sorted(_shipped_sources() - names)
    assert not missing, f"missing from the wheel: {missing}"


def test_the_build_prints_no_warning_and_the_wheel_carries_the_licence(installed):
    """setuptools warns of nothing (a scene folder missing from the packages would be 'ignored'; a deprecated
    setting would be named); pip's own notes about the index (upper-case ``WARNING:``) are not the build's."""
    wheel, output = installed[0], installed[4]
    assert not re.search(r"would be ignored|Warning:|!!", output), output[-3000:]
    names = zipfile.ZipFile(wheel).namelist()
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names), names[-10:]


def test_installed_package_is_imported_from_the_wheel(installed):
    """The venv imports the installed copy, not the checkout."""
    wheel, python, script, work, _ = installed
    where = subprocess.run([str(python), "-c", "import sim, hydraulics; print(sim.__file__); print(hydraulics.__file__)"],
                           cwd=work, capture_output=True, text=True, check=True).stdout.split()
    assert all(str(ROOT) not in path for path in where), where


def test_installed_commands_run_outside_the_repository(installed):
    """--version, examples, compile, demo and a run of a shipped example in both modes, from another folder."""
    assert _run(installed, "--version").strip() == "hydroplant 0.1.0"
    names = _run(installed, "examples")
    assert "excavator/dig" in names and "seed_cylinder/closed" in names
    _run(installed, "compile")
    demo = _run(installed, "demo")
    assert "rod speed while lifting" in demo
    work = installed[3]
    for mode in ("mujoco", "pbd"):
        out = work / f"boom-{mode}.mcap"
        _run(installed, "run", "--example", "boom/lift", "--mode", mode, "--duration", "0.2", "--no-progress",
             "--out", str(out))
        assert out.stat().st_size > 10_000
    doc = subprocess.run([str(installed[1]), "-m", "hydroplant", "log", "info", str(out), "--json"], cwd=work,
                         capture_output=True, text=True, check=True).stdout
    check = ("import json, sys, jsonschema, sim.jsonout as j; jsonschema.validate(json.loads(sys.stdin.read()), "
             "j.schema('log-info')); print(j.__file__)")
    where = subprocess.run([str(installed[1]), "-c", check], input=doc, cwd=work, capture_output=True, text=True,
                           check=True).stdout
    assert str(ROOT) not in where  # python -m hydroplant and the schemas, both from the wheel
