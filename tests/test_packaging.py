"""What the distribution promises: a light default install with the tools' libraries in extras, a licence, and a
first run whose compilation is announced and kept out of the reported timings.

* ``pyproject.toml`` and the installed metadata: the default dependencies are the five the runs need, every
  extra is declared (``all`` holds the others, ``dev`` holds ``all``), the licence is MIT with its file.
* Without matplotlib (an import blocker in a subprocess: ``sys.modules["matplotlib"] = None`` makes the import
  fail as if it were not installed) ``compare``, ``tradeoff`` and ``stability`` print one line naming the
  extra and exit with status 2; ``run`` needs none of the extras' libraries.
* The kernels a run calls are compiled or loaded before its clock starts: no numba compiler call (its
  ``"numba:compiler_lock"`` event, broadcast for every compilation and every load from the disk cache) happens in
  the timed loop of a fresh process, whereas with ``warm=False`` the loop loads them itself.
* :class:`sim.run.compile_watch.CompileWatch` announces a compilation once and says nothing when nothing compiles.
"""

from __future__ import annotations

import io
import json
import re
import subprocess
import sys
import tomllib
from importlib import metadata

import pytest

from conftest import MODELS, ROOT
from hydraulics.extras import EXTRAS, MissingExtra, require

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
PROJECT = PYPROJECT["project"]
BASE = {"numpy", "mujoco", "mcap", "zstandard", "numba"}
OPTIONAL = {"matplotlib", "scipy", "dask", "distributed", "bokeh", "foxglove", "pygame", "h5py"}


def _name(requirement: str) -> str:
    """The distribution name of a requirement string (``dask[distributed]>=2024.1`` → ``dask``)."""
    return re.match(r"[A-Za-z0-9_.-]+", requirement).group(0).lower()


def test_the_default_install_is_what_a_run_needs():
    assert {_name(r) for r in PROJECT["dependencies"]} == BASE


def test_every_extra_is_declared_and_all_and_dev_hold_them():
    extras = PROJECT["optional-dependencies"]
    assert {_name(r) for r in extras["tools"]} == {"matplotlib", "scipy"}
    assert {_name(r) for r in extras["dask"]} == {"dask", "bokeh"}
    assert "distributed" in extras["dask"][0]
    for extra in ("live", "gamepad", "hdf5"):
        assert extras[extra], extra
    (everything,) = extras["all"]
    assert set(re.search(r"\[(.*)\]", everything).group(1).split(",")) == set(EXTRAS) == {"tools", "dask", "live",
                                                                                           "gamepad", "hdf5"}
    assert "hydroplant[all]" in extras["dev"]
    assert {"pytest", "pytest-xdist", "hypothesis", "mcap-ros2-support", "jsonschema"} <= {_name(r) for r in extras["dev"]}


def test_the_licence_is_mit_with_its_file():
    assert PROJECT["license"] == "MIT" and PROJECT["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert text.startswith("MIT License") and "Copyright (c) 2026 the hydroplant developers" in text
    assert PROJECT["classifiers"]


def test_the_installed_metadata_carries_the_extras_and_the_licence():
    """The metadata of the installed distribution (the venv's editable install, rebuilt when pyproject changes)."""
    meta = metadata.metadata("hydroplant")
    assert meta["License-Expression"] == "MIT"
    assert set(meta.get_all("Provides-Extra")) >= {"tools", "dask", "live", "gamepad", "hdf5", "all", "dev"}
    required = [r for r in metadata.requires("hydroplant") if "extra ==" not in r]
    assert {_name(r) for r in required} == BASE


def test_every_scene_folder_is_a_data_package_of_the_wheel():
    """Each folder of models/ is listed as a package (else setuptools warns that it 'would be ignored') with its
    data files."""
    setuptools = PYPROJECT["tool"]["setuptools"]
    folders = {p.name for p in MODELS.iterdir() if p.is_dir() and not p.name.startswith((".", "__"))}
    packages = {p.removeprefix("sim.examples.") for p in setuptools["packages"] if p.startswith("sim.examples.")}
    assert packages == folders
    assert all(f"sim.examples.{f}" in setuptools["package-data"] for f in folders)


def test_require_names_the_extra_in_one_line():
    assert require("json", "tools", "x") is json
    with pytest.raises(MissingExtra) as error:
        require("hydroplant_no_such_module", "dask", "hydroplant tradeoff --workers 2")
    assert str(error.value) == "hydroplant tradeoff --workers 2 needs the [dask] extra: pip install 'hydroplant[dask]'"


def _without(modules, argv, timeout=600):
    """``hydroplant argv`` in a fresh process where importing any of ``modules`` fails (not installed)."""
    blocker = f"import sys\nfor m in {sorted(modules)!r}: sys.modules[m] = None\nfrom sim.cli import main\n" \
              f"raise SystemExit(main({list(argv)!r}))"
    return subprocess.run([sys.executable, "-c", blocker], cwd=ROOT, capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("command", ["compare", "tradeoff", "stability"])
def test_a_tool_without_matplotlib_says_which_extra_in_one_line(command, tmp_path):
    done = _without(["matplotlib"], [command, str(MODELS / "boom" / "lift.scenario.toml"), "--out", str(tmp_path / "o")])
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines() == [f"hydroplant: error: hydroplant {command} needs the [tools] extra: "
                                        "pip install 'hydroplant[tools]'"]
    assert not (tmp_path / "o").exists()  # refused before any run


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_run_needs_none_of_the_extras(tmp_path, mode):
    out = tmp_path / "lift.mcap"
    done = _without(OPTIONAL, ["run", "--example", "boom/lift", "--mode", mode, "--duration", "0.05", "--no-progress",
                               "--out", str(out)])
    assert done.returncode == 0, done.stderr
    assert out.stat().st_size > 10_000 and "status        complete" in done.stdout


PROBE = """
import json, sys, time
from numba.core import event
from sim.io.scenario import load_scenario
from sim.run import runner

calls = {"loop": 0}

class Count(event.Listener):
    def on_start(self, e):
        calls["loop"] += 1
    def on_end(self, e):
        pass

loop = runner._run_loop
def counted(*args):  # the run's own loop is the last one (the warm-up's runs first)
    calls["loop"] = 0
    with event.install_listener("numba:compiler_lock", Count()):
        return loop(*args)
runner._run_loop = counted
start = time.perf_counter()
scenario = load_scenario(sys.argv[1]).with_overrides(mode=sys.argv[4], duration=0.1)
result = runner.run(scenario, out=sys.argv[2], warm=sys.argv[3] == "warm")
total = time.perf_counter() - start
print(json.dumps({"loop": calls["loop"], "total": total, "wall": result.wall_time, "compile": result.compile_time,
                  "compiled": result.kernels_compiled, "status": result.status, "summary": result.summary_text()}))
"""


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_the_run_timing_starts_after_the_kernels_are_compiled_or_loaded(tmp_path, mode):
    """In a fresh process nothing is compiled or loaded inside the timed loop of a warmed run (the compiler is not
    entered once), while without the warm-up the loop loads kernels itself (the block in PBD mode); the warm-up's time is reported apart, both figures lie inside the call's own duration, and a
    process after the first compiles nothing (every kernel of a run is in the disk cache, none is compiled anew in
    every process)."""
    scenario = MODELS / "boom" / "lift.scenario.toml"
    out = {}
    for warm in ("cold", "warm"):  # (the first fills the disk cache if anything is missing)
        done = subprocess.run([sys.executable, "-c", PROBE, str(scenario), str(tmp_path / f"{warm}.mcap"), warm, mode],
                              cwd=ROOT, capture_output=True, text=True, timeout=1800)
        assert done.returncode == 0, done.stderr
        out[warm] = json.loads(done.stdout.strip().splitlines()[-1])
    warm, cold = out["warm"], out["cold"]
    assert warm["status"] == cold["status"] == "complete"
    # (the probe's own check, PBD mode: without the warm-up its loop loads the block; in MuJoCo mode a cold loop may
    # load nothing itself, the log's derived fields being filled on the log's writer thread)
    assert warm["loop"] == 0 and (cold["loop"] > 0 or mode == "mujoco"), (warm["loop"], cold["loop"])
    assert warm["compile"] > 0 and warm["wall"] + warm["compile"] <= warm["total"]
    assert warm["compiled"] == 0
    assert warm["summary"].splitlines()[4].endswith(f"kernels loaded in {warm['compile']:.1f} s, excluded)")


def test_compile_watch_announces_a_compilation_once_and_nothing_else():
    numba = pytest.importorskip("numba")
    if numba.config.DISABLE_JIT:
        pytest.skip("NUMBA_DISABLE_JIT=1: nothing is compiled")
    from sim.run.compile_watch import CompileWatch

    @numba.njit
    def inner(x):
        return x * 2.0

    @numba.njit
    def outer(x):
        return inner(x) + 1.0

    stream = io.StringIO()
    with CompileWatch("boom/lift", "pbd", stream=stream) as watch:
        assert outer(1.0) == 3.0
    lines = stream.getvalue().splitlines()
    assert watch.count == 2  # outer and the callee it compiles in
    assert lines[0] == ("hydroplant: compiling kernels for boom/lift (pbd), first run only; later runs load them "
                        "from the cache")
    assert "`hydroplant compile` builds every mode's kernels" in lines[1]  # why, and how to avoid it
    assert re.fullmatch(r"hydroplant: 2 functions compiled in \d+ s", lines[2]) and len(lines) == 3
    quiet = io.StringIO()
    with CompileWatch("boom/lift", "pbd", stream=quiet) as again:
        assert outer(2.0) == 5.0  # compiled already: no event, no line
    assert again.count == 0 and quiet.getvalue() == ""
