"""``hydroplant stability`` from a working directory with relative paths, and its end-stop event on a loop-closure model.

A relative scenario path and a relative (or the default) ``--out`` must not be joined twice
(the variants' folders are written below it), and the end-stop pose must stay
on the MJCF's loop closures (no NaN chamber pressure at its start).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim import cli
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.plants.constraints import equality_rows
from sim.plants.mujoco import MujocoPlant
from sim.tools import stability as st

ROOT = Path(__file__).parent.parent
HOLD = Path(__file__).parent / "scenes" / "hold.scenario.toml"


@pytest.fixture
def stability_cli(monkeypatch):
    if "sim.tools.stability" not in cli.TOOL_MODULES:
        monkeypatch.setattr(cli, "TOOL_MODULES", (*cli.TOOL_MODULES, "sim.tools.stability"))
    return cli.main


@pytest.mark.parametrize("out", [["--out", "maps/boom"], []], ids=["relative-out", "default-out"])
def test_stability_runs_from_a_working_directory_with_relative_paths(stability_cli, tmp_path, monkeypatch, out):
    shutil.copytree(ROOT / "models" / "boom", tmp_path / "models" / "boom")
    monkeypatch.chdir(tmp_path)
    code = stability_cli(["stability", "models/boom/lift.scenario.toml", "--quick", "--dt", "1e-3", "--sweeps", "beta",
                          "--methods", "mujoco:implicit", "--workers", "1", *out])
    assert code == 0
    folder = tmp_path / (out[1] if out else "logs/stability-boom-lift")
    assert (folder / "stability.csv").is_file() and (folder / "summary.txt").is_file()
    assert not (folder / folder.relative_to(tmp_path)).exists()  # the path was not joined twice


def test_end_stop_pose_stays_on_the_loop_closure(tmp_path):
    facts = st.scene_facts(HOLD)
    config = next(c for c in st.grid_configs(facts, st.QUICK_GRID) if c.event == "end_stop")
    path = st.write_variant(facts, config, tmp_path / "variant")
    scene = load_scene(load_scenario(path))
    plant = MujocoPlant(scene)
    assert np.all(np.isfinite(plant.net_state.node_pressure))
    d = mujoco.MjData(scene.mjmodel)
    d.qpos[:] = plant.data.qpos
    mujoco.mj_forward(scene.mjmodel, d)
    _, violation, _ = equality_rows(scene.mjmodel, d)
    assert np.max(np.abs(violation)) < 1e-8
    stroke = scene.network.cylinder_stroke[0]
    x, v = plant.actuator_motion()
    expected = max(stroke - facts.full_speed["lift_cyl"] * st.END_STOP_HIT * facts.duration, 0.5 * stroke)
    assert x[0] == pytest.approx(expected, abs=1e-6)
    assert v[0] == pytest.approx(facts.full_speed["lift_cyl"], rel=1e-6)
