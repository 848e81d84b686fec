"""Sweeps on a real Dask cluster: a scheduler and two workers as separate processes on 127.0.0.1.

The workers run in folders outside the repository (working directory, ``--local-directory`` and
``TMPDIR`` their own), so they can only run a scene from the content the client ships them.  While the
points run, the client's copy of the scene is renamed away: the local pool then fails to find it (which
shows the hiding works), the cluster does not (which shows the workers read the shipped content, not the
client's path).  The cluster's rows equal the local pool's in every field but the timings; a setting
that cannot run fails on its worker with its error text in the rows, the CSV and the report, and is not
cached.  A scheduler without workers is one line and exit status 2 after ``--worker-timeout``.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
import time
import urllib.request
from contextlib import contextmanager
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from conftest import MODELS  # noqa: E402

from sim.tools import sweep  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
START_TIMEOUT = 60.0  # s: for the scheduler file and for both workers to join
STOP_TIMEOUT = 5.0  # s: per process, after terminate, before kill
SETTINGS = [{"mode": "mujoco", "coupling": c, "dt": dt, "hydraulic_substeps": 1, "pbd_substeps": 20, "pbd_iterations": 1}
            for c, dt in (("implicit", 1 / 1200), ("implicit", 1 / 2400), ("explicit", 1 / 2400))]
BROKEN = {**SETTINGS[0], "hydraulic_substeps": 0}  # refused by the scenario's validation on the worker
BROKEN_TEXT = "ScenarioError: seed_cylinder/closed.scenario.toml (command-line override): field 'run.hydraulic_substeps': 0"


def _stop(processes) -> None:
    for process in processes:
        if process.poll() is None:
            process.terminate()
    for process in processes:
        try:
            process.wait(timeout=STOP_TIMEOUT)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=STOP_TIMEOUT)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cluster").resolve()
    assert not folder.is_relative_to(ROOT)  # nothing of the cluster lives in the repository
    return folder


@pytest.fixture(scope="module")
def scheduler(base):
    """``dask scheduler`` on 127.0.0.1 (port and dashboard port chosen by the system); yields its address."""
    folder = base / "scheduler"
    folder.mkdir()
    info = folder / "scheduler.json"
    with open(folder / "log.txt", "w") as log:
        process = subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0",
                                    "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(info)],
                                   cwd=folder, stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while not (info.is_file() and info.stat().st_size) and time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.2)
        assert info.is_file(), (folder / "log.txt").read_text()
        yield json.loads(info.read_text())["address"]
    finally:
        _stop([process])


@pytest.fixture(scope="module")
def workers(scheduler, base):
    """Two ``dask worker`` processes (one thread each), each with its own working, local and temporary folder."""
    from dask.distributed import Client

    processes, folders = [], []
    try:
        for name in ("w1", "w2"):
            folder = base / name
            for sub in ("cwd", "local", "tmp"):
                (folder / sub).mkdir(parents=True)
            env = {**os.environ, "TMPDIR": str(folder / "tmp")}
            env.pop("PYTHONPATH", None)  # the installed package, not a path of the repository
            with open(folder / "log.txt", "w") as log:
                processes.append(subprocess.Popen(
                    [sys.executable, "-m", "dask", "worker", scheduler, "--name", name, "--nthreads", "1", "--no-nanny",
                     "--local-directory", str(folder / "local"), "--no-dashboard", "--death-timeout", str(START_TIMEOUT)],
                    cwd=folder / "cwd", env=env, stdout=log, stderr=subprocess.STDOUT))
            folders.append(folder)
        with Client(scheduler, timeout=START_TIMEOUT) as client:
            client.wait_for_workers(2, timeout=START_TIMEOUT)
        yield folders
    finally:
        _stop(processes)


@contextmanager
def hidden(*folders):
    """The folders renamed away (nothing left at their paths) inside the block."""
    for folder in folders:
        folder.rename(folder.with_name(folder.name + "-hidden"))
    try:
        yield
    finally:
        for folder in folders:
            folder.with_name(folder.name + "-hidden").rename(folder)


def hiding_sweeps(monkeypatch, module, *folders):
    """Make ``module.run_sweep`` run with ``folders`` hidden: after the client bundled the files, before any point runs."""
    real = sweep.run_sweep

    def run_sweep(*args, **kwargs):
        with hidden(*folders):
            return real(*args, **kwargs)

    monkeypatch.setattr(module, "run_sweep", run_sweep)


def materialised(folder: Path, relative: str) -> list[Path]:
    """The copies of a bundled file a worker wrote below its local directory."""
    return sorted((folder / "local").rglob(f"hydroplant-scene-*/{relative}"))


def test_no_workers_is_one_line(capsys):
    """A scheduler without workers: the CLI waits ``--worker-timeout`` seconds, then one line and exit 2."""
    from dask.distributed import LocalCluster

    from sim import cli

    with LocalCluster(n_workers=0, processes=False, protocol="tcp://", host="127.0.0.1", dashboard_address=None) as empty:
        scheduler = empty.scheduler_address
        code = cli.main(["tradeoff", str(MODELS / "seed_cylinder" / "closed.scenario.toml"), "--quick", "--scheduler", scheduler,
                         "--worker-timeout", "0.5"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2
    assert err == [f"hydroplant: error: no Dask workers joined {scheduler} within 0.5 s (start them with: dask worker {scheduler})"]


def test_tradeoff_on_the_cluster_equals_the_local_pool(workers, scheduler, tmp_path, monkeypatch):
    import sim.tools.tradeoff as tradeoff
    from sim.io.scenario import load_scenario
    from sim.run.runner import run

    scene = tmp_path / "client" / "seed_cylinder"
    shutil.copytree(MODELS / "seed_cylinder", scene)
    scenario = load_scenario(scene / "closed.scenario.toml").with_overrides(duration=0.02)
    fine = run(scenario, out=tmp_path / "fine.mcap", overrides={"dt": 1 / 9600}).log_path
    settings = [*SETTINGS, BROKEN]
    local = tradeoff.evaluate(scenario, settings, fine, repeats=1, workers=1, cache_dir=tmp_path / "local")

    hiding_sweeps(monkeypatch, tradeoff, scene)
    blind = tradeoff.evaluate(scenario, settings[:1], fine, repeats=1, workers=1, cache_dir=tmp_path / "blind")
    assert blind[0]["status"] == "error" and "closed.scenario.toml" in blind[0]["error"]  # the client's files are gone
    remote = tradeoff.evaluate(scenario, settings, fine, repeats=1, scheduler=scheduler, cache_dir=tmp_path / "remote",
                               worker_timeout=30)

    assert [r["status"] for r in remote] == [r["status"] for r in local]
    assert [r["status"] for r in remote][:2] == ["complete", "complete"] and remote[3]["status"] == "error"
    assert tradeoff.error_table(remote) == tradeoff.error_table(local)  # settings and errors; not the timings
    assert remote[1]["stroke_max_m"] < remote[0]["stroke_max_m"]  # the finer step is closer to the fine run
    assert all(r["wall_per_sim_s"] > 0 for r in remote[:2])
    for folder in workers:  # each worker wrote the shipped scene into its own local directory (its warm-up ran there)
        assert materialised(folder, "seed_cylinder/closed.scenario.toml")
        assert not list((folder / "cwd").iterdir())

    # the failure: its error text in the rows, the CSV and the report; not cached
    assert remote[3]["error"].startswith(BROKEN_TEXT), remote[3]["error"]
    assert local[3]["error"] == remote[3]["error"]  # the file named relative to the scene's folder on both
    table = tradeoff.write_csv(remote, tmp_path / "tradeoff.csv")
    with open(table, newline="") as f:
        errors = [row["error"] for row in csv.DictReader(f)]
    assert errors == ["", "", "", remote[3]["error"]]
    assert f"(error: {BROKEN_TEXT}" in tradeoff.pareto_table(remote)
    points, _ = tradeoff.sweep_plan(scenario, settings, repeats=1)
    cached = {p.stem for p in (tmp_path / "remote").glob("*.json")}
    assert cached == {sweep.point_key(p, tradeoff.run_point) for p in points[:3]}
    assert all(str(tmp_path) not in json.dumps(p) for p in points)  # no path of the client in a point (its cache key)


def test_stability_on_the_cluster_equals_the_local_pool(workers, scheduler, tmp_path, monkeypatch):
    """The boom's mass sweep (its variants carry a mass-scaled MJCF): the same classes, errors and pressures.
    A step of 2 s, beyond the scenario's range, cannot be run: its error text is in the rows, the CSV and the
    summary, and it is not cached."""
    from dataclasses import replace

    from sim.tools import stability as st

    scene = tmp_path / "client" / "boom"
    shutil.copytree(MODELS / "boom", scene)
    grid = replace(st.QUICK_GRID, dts=(1e-3, 2.0), sweeps=("mass",), methods=("mujoco-implicit",))
    local = st.stability_map(scene / "lift.scenario.toml", grid=grid, out_dir=tmp_path / "local", workers=1)
    hiding_sweeps(monkeypatch, sweep, scene, tmp_path / "remote" / "variants")
    remote = st.stability_map(scene / "lift.scenario.toml", grid=grid, out_dir=tmp_path / "remote", scheduler=scheduler,
                              worker_timeout=30)

    timing = {"wall_time"}
    assert [{k: v for k, v in r.items() if k not in timing} for r in remote.rows] == \
        [{k: v for k, v in r.items() if k not in timing} for r in local.rows]
    assert {r["config"] for r in remote.rows} == {"nominal-valve_slam", "mass-0.01-valve_slam", "mass-100-valve_slam"}
    assert all(r["status"] == "complete" for r in remote.rows if r["dt"] < 1)
    assert remote.summary() == local.summary()
    failed = [r for r in remote.rows if r["status"] == "error"]
    assert [r["dt"] for r in failed] == [2.0] * 3
    text = "ScenarioError: {}/{}.scenario.toml (command-line override): field 'run.dt': 2.0 is not in [1e-09, 1] s"
    assert all(r["error"] == text.format(r["config"], r["config"]) for r in failed)
    assert all(f"dt 2 s: {r['error']}" in remote.summary() for r in failed)
    with open(tmp_path / "remote" / "stability.csv", newline="") as f:
        assert sorted(row["error"] for row in csv.DictReader(f) if row["error"]) == sorted(r["error"] for r in failed)
    assert len(list((tmp_path / "remote" / "cache").glob("*.json"))) == len(remote.rows) - len(failed)
    import jsonschema

    from sim.jsonout import schema

    document = st.result_json(remote, 4)  # the --json document: the same error texts, counted as errors
    jsonschema.validate(document, schema("stability"))
    assert document["status"] == "partial" and document["errors"] == len(failed)
    assert [r["error"] for r in document["runs"]] == [r["error"] for r in remote.rows]
    shipped = [path for folder in workers for path in materialised(folder, "mass-100-valve_slam/model/boom-mass.xml")]
    assert shipped and all(p.read_bytes() == shipped[0].read_bytes() for p in shipped)


def test_the_dashboard_is_served(scheduler):
    """With bokeh (the ``[dask]`` extra) the scheduler serves its dashboard; the client reports the link."""
    pytest.importorskip("bokeh")
    from dask.distributed import Client

    with Client(scheduler, timeout=START_TIMEOUT) as client:
        link = client.dashboard_link
    assert link and link.startswith("http://127.0.0.1:")
    with urllib.request.urlopen(link, timeout=30) as response:
        body = response.read()
    assert response.status == 200 and b"needs bokeh" not in body.lower() and b"bokeh" in body.lower()
