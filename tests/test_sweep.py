"""Sweeps: content hashes, resuming an interrupted sweep, and the same error table from a process pool and Dask."""

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from conftest import MODELS
from sim.tools.sweep import SweepError, content_hash, point_key, run_sweep

SEED = MODELS / "seed_cylinder" / "closed.scenario.toml"


def square(point):
    """Sweep function for the tests: leaves a marker file per call; fails while ``point['fail']`` exists."""
    marker_dir = Path(point["markers"])
    (marker_dir / f"{point['x']}-{os.getpid()}-{len(list(marker_dir.iterdir()))}").touch()
    if point["x"] == point.get("fail_at") and Path(point["fail"]).exists():
        raise RuntimeError("interrupted")
    return {"y": point["x"] ** 2, "half": point["x"] / 2}


def calls(marker_dir, x):
    return sum(1 for p in Path(marker_dir).iterdir() if p.name.split("-")[0] == str(x))


def test_content_hash_and_point_key(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.write_bytes(b"ab")
    b.write_bytes(b"ab")
    assert content_hash(a) == content_hash(b) == content_hash(b"ab")  # contents, not names
    assert content_hash(b"ab", b"c") != content_hash(b"a", b"bc")
    with pytest.raises(FileNotFoundError):
        content_hash(tmp_path / "missing")
    assert point_key({"x": 1, "y": 2}, square) == point_key({"y": 2, "x": 1}, square)  # sorted JSON
    assert point_key({"x": 1}, square) != point_key({"x": 1.5}, square)
    with pytest.raises(TypeError, match="JSON-serialisable"):
        run_sweep(square, [{"x": float("nan")}])


def test_interrupted_sweep_resumes_without_recomputing_finished_points(tmp_path):
    markers, cache = tmp_path / "markers", tmp_path / "cache"
    markers.mkdir()
    flag = tmp_path / "fail"
    flag.touch()
    points = [{"x": x, "markers": str(markers), "fail": str(flag), "fail_at": 2} for x in range(5)]
    with pytest.raises(SweepError, match="interrupted"):
        run_sweep(square, points, workers=1, cache_dir=cache)  # one at a time: 0 and 1 finish, 2 fails
    assert len(list(cache.glob("*.json"))) == 2
    flag.unlink()
    results = run_sweep(square, points, workers=2, cache_dir=cache)
    assert [r["y"] for r in results] == [0, 1, 4, 9, 16]
    assert [calls(markers, x) for x in range(5)] == [1, 1, 2, 1, 1]  # 0 and 1 came from the cache
    again = run_sweep(square, points, workers=2, cache_dir=cache)
    assert again == results and [calls(markers, x) for x in range(5)] == [1, 1, 2, 1, 1]
    cached = json.loads(next(cache.glob("*.json")).read_text())
    assert set(cached) == {"version", "key", "point", "made_by", "result", "digest"}


def test_seed_sweep_gives_the_same_error_table_on_a_process_pool_and_on_dask(tmp_path):
    """4 settings of the seed cylinder (20 ms): a real LocalCluster(2 processes) and the process pool agree on every
    error (not on timings)."""
    from dask.distributed import LocalCluster

    from sim.run.runner import run
    from sim.io.scenario import load_scenario
    from sim.tools.tradeoff import error_table, evaluate

    scenario = load_scenario(SEED).with_overrides(duration=0.02)
    fine = run(scenario, out=tmp_path / "fine.mcap", overrides={"dt": 1 / 9600}).log_path
    settings = [{"mode": "mujoco", "coupling": c, "dt": dt, "hydraulic_substeps": 1, "pbd_substeps": 20, "pbd_iterations": 1}
                for c in ("implicit", "explicit") for dt in (1 / 1200, 1 / 2400)]
    pool = evaluate(scenario, settings, fine, repeats=1, workers=2, cache_dir=tmp_path / "pool")
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cluster:
        dask = evaluate(scenario, settings, fine, repeats=1, scheduler=cluster.scheduler_address, cache_dir=tmp_path / "dask")
    assert error_table(pool) == error_table(dask)
    assert [r["status"] for r in pool][:2] == ["complete", "complete"]
    implicit = pool[:2]
    assert implicit[1]["stroke_max_m"] < implicit[0]["stroke_max_m"]  # the finer step is closer to the fine run
    assert all(r["wall_per_sim_s"] > 0 for r in pool + dask)


def test_code_hash_follows_the_simulation_source_only(tmp_path):
    """A cached result keyed on the code is invalid after a change to the simulation code, not after a tool's."""
    from sim.tools.sweep import code_hash

    for package in ("hydraulics", "sim"):
        (tmp_path / package).mkdir()
    (tmp_path / "hydraulics" / "laws.py").write_text("A = 1\n")
    (tmp_path / "sim" / "runner.py").write_text("B = 1\n")
    (tmp_path / "sim" / "compare.py").write_text("C = 1\n")
    before = code_hash(tmp_path)
    (tmp_path / "sim" / "compare.py").write_text("C = 2\n")  # an analysis tool: same results
    assert code_hash(tmp_path) == before
    (tmp_path / "hydraulics" / "laws.py").write_text("A = 2\n")
    assert code_hash(tmp_path) != before
    assert len(code_hash()) == 64


def test_reference_key_includes_the_code_and_the_fidelity(monkeypatch):
    import sim.tools.reference as reference
    from sim.io.scenario import load_scenario

    scenario = load_scenario(MODELS / "boom" / "lift.scenario.toml")
    settings = reference.ReferenceSettings()
    key = reference.reference_key(scenario, settings)
    assert reference.reference_key(scenario.with_overrides(actuator_fidelity={"boom_cyl": "lines"}), settings) != key
    monkeypatch.setattr(reference, "code_hash", lambda: "0" * 64)
    assert reference.reference_key(scenario, settings) != key


def test_fidelity_is_a_sweep_dimension():
    from sim.io.scenario import load_scenario
    from sim.tools.tradeoff import setting_label, sweep_settings

    scenario = load_scenario(MODELS / "excavator" / "dig.scenario.toml")
    quick = sweep_settings(scenario, quick=True, modes=["mujoco"])
    assert {s["fidelity"] for s in quick} == {"compressible", "incompressible"}
    frame_rate = [s for s in quick if s["fidelity"] == "incompressible" and s["dt"] > 0.02]
    assert len(frame_rate) == 1 and frame_rate[0]["dt"] == pytest.approx(0.03)  # 3 log periods of 10 ms
    assert setting_label(frame_rate[0], scenario.fidelity) == "mujoco implicit dt 30 ms [incompressible]"
    full = sweep_settings(scenario, modes=["mujoco", "pbd"])
    assert {s["fidelity"] for s in full} == {"compressible", "incompressible", "lines"}
    assert any(s["mode"] == "pbd" and s["fidelity"] == "incompressible" for s in full)
    assert sweep_settings(scenario, quick=True, modes=["mujoco"], fidelities=["compressible"]) == \
        [s for s in quick if s["fidelity"] == "compressible"]


def test_tradeoff_rows_show_when_incompressible_is_good_enough(tmp_path):
    """Boom lift (valve opened at 1.0–1.3 s), 2 s against a fine compressible run: the incompressible model
    lifts at Q/A like the oil-column model (stroke within 1 cm at 2 ms) but has no chamber pressures to
    speak of (error > 50 bar), and the lines model is as good as the lumped one."""
    from sim.run.runner import run
    from sim.io.scenario import load_scenario
    from sim.tools.tradeoff import evaluate

    scenario = load_scenario(MODELS / "boom" / "lift.scenario.toml").with_overrides(duration=2.0)
    fine = run(scenario, out=tmp_path / "fine.mcap", overrides={"dt": 2.5e-4}).log_path
    settings = [{"mode": "mujoco", "coupling": "implicit", "fidelity": f, "dt": dt, "hydraulic_substeps": 1,
                 "pbd_substeps": 20, "pbd_iterations": 1}
                for f, dt in (("compressible", 1e-3), ("incompressible", 2e-3), ("incompressible", 0.03), ("lines", 1e-3))]
    rows = evaluate(scenario, settings, fine, repeats=1, workers=1, cache_dir=tmp_path / "cache")
    by = {r["label"]: r for r in rows}
    assert set(by) == {"mujoco implicit dt 1 ms", "mujoco implicit dt 2 ms [incompressible]",
                       "mujoco implicit dt 30 ms [incompressible]", "mujoco implicit dt 1 ms [lines]"}
    assert all(r["status"] == "complete" for r in rows)
    assert [r["fidelity"] for r in rows] == ["compressible", "incompressible", "incompressible", "lines"]
    lumped, fast, frame, lines = (by[k] for k in sorted(by, key=list(by).index))
    assert lumped["stroke_max_m"] < 1e-3 and lines["stroke_max_m"] < 1e-3
    assert fast["stroke_max_m"] < 0.01  # good enough for a centimetre question
    assert frame["stroke_max_m"] > fast["stroke_max_m"]
    assert fast["pressure_max_pa"] > 50e5 > lumped["pressure_max_pa"]  # not for a pressure question


def test_tradeoff_errors_on_filtered_signals_see_through_chatter():
    """error_rows with a filter window: a run that chatters ±5 mm at 50 Hz around a 1 mm offset of the reference
    has a point-wise stroke error of 6 mm and a 0.1 s-averaged one of the offset alone (1 mm: the window holds
    whole chatter periods)."""
    from sim.tools.compare import Signal
    from sim.io.scenario import load_scenario
    from sim.tools.tradeoff import error_rows, sweep_points

    scenario = load_scenario(MODELS / "boom" / "lift.scenario.toml")
    setting = {"mode": "mujoco", "coupling": "implicit", "dt": 1e-3, "hydraulic_substeps": 1, "pbd_substeps": 20,
               "pbd_iterations": 1}
    points = sweep_points(scenario, [setting], repeats=1)
    t = np.linspace(0.0, 2.0, 4001)
    reference = {"stroke boom_cyl": Signal("stroke boom_cyl", "stroke", t, 0.3 + 0.1 * t)}
    run = 0.3 + 0.1 * t + 1e-3 + 5e-3 * np.sign(np.sin(2 * np.pi * 50.0 * t + 0.1))
    result = {"status": "complete", "diverged_at_s": math.nan, "wall_per_sim_s": 1.0, "wall_per_sim_s_runs": [1.0],
              "energy": {}, "signals": {"stroke boom_cyl": {"t": t.tolist(), "y": run.tolist()}}}
    pointwise, = error_rows(points, [result], reference)
    filtered, = error_rows(points, [result], reference, filter_window=0.1)
    assert pointwise["stroke_max_m"] == pytest.approx(6e-3, rel=1e-6)
    assert filtered["stroke_max_m"] == pytest.approx(1e-3, abs=2e-4)


def test_a_scene_bundle_is_its_content_and_works_from_any_folder(tmp_path):
    """The bundle of a scene holds every input file under the scene folder's name; moving the scene changes neither
    its digest nor the sweep points' keys; written out elsewhere it loads with every file inside the copy; a scene
    naming a file by an absolute path is refused (it would not exist on a worker)."""
    import shutil

    from sim.io.scenario import ScenarioError, load_scenario
    from sim.tools.sweep import materialise, scene_bundle
    from sim.tools.tradeoff import run_point, sweep_points

    first, second = tmp_path / "a" / "seed_cylinder", tmp_path / "b" / "c" / "seed_cylinder"
    shutil.copytree(SEED.parent, first)
    shutil.copytree(SEED.parent, second)
    bundle, rel = scene_bundle(first / SEED.name)
    assert rel == "seed_cylinder/closed.scenario.toml"
    assert [name for name, _ in bundle.files] == ["seed_cylinder/closed.scenario.toml", "seed_cylinder/seed_cylinder.circuit.toml",
                                                  "seed_cylinder/seed_cylinder.xml"]
    assert dict(bundle.files)["seed_cylinder/seed_cylinder.xml"] == (SEED.parent / "seed_cylinder.xml").read_bytes()
    assert scene_bundle(second / SEED.name)[0].digest == bundle.digest
    setting = {"mode": "mujoco", "coupling": "implicit", "dt": 1e-3, "hydraulic_substeps": 1, "pbd_substeps": 20, "pbd_iterations": 1}
    keys = [point_key(sweep_points(load_scenario(s / SEED.name), [setting], repeats=1)[0], run_point) for s in (first, second)]
    assert keys[0] == keys[1]
    (second / "seed_cylinder.xml").write_text((second / "seed_cylinder.xml").read_text() + "\n")
    assert scene_bundle(second / SEED.name)[0].digest != bundle.digest  # one byte more: another scene

    folder = materialise(bundle, tmp_path / "worker")
    assert folder.is_relative_to(tmp_path / "worker") and materialise(bundle, tmp_path / "elsewhere") == folder  # once
    copy = load_scenario(folder / rel)
    assert copy.mjcf == folder / "seed_cylinder" / "seed_cylinder.xml" and copy.circuit.parent == folder / "seed_cylinder"

    text = (first / SEED.name).read_text().replace('mjcf = "seed_cylinder.xml"', f'mjcf = "{first / "seed_cylinder.xml"}"')
    (first / SEED.name).write_text(text)
    with pytest.raises(ScenarioError, match="absolute path"):
        scene_bundle(first / SEED.name)
