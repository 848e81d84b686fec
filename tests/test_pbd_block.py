"""The PBD plant's block path (``PbdPlant.advance``: many steps in one compiled call, ``sim/plants/pbd_block.py``)
against steps one at a time (``block=False``: ``step()``, a block of one step), and the runner driving it.

* Seed, boom lift and excavator dig (through the teeth's first ground contact): after every block, body
  states, network state, efforts, the energy ledger, the last step's Newton counts, the controls, the clocks,
  the hinge hint and the per-step pressure extremes equal those of single steps to round-off (1e-9 of the
  largest magnitude, as ``tests/test_pbd_fast.py``), for blocks of several lengths.
* ``snapshot``/``restore`` (the runner's replay of a failed block) give back the same trajectory.
* The runner logs the same values through blocks (samples recorded inside them) as step by step
  (``tests/test_runner_fast.py``'s comparison).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from test_pbd_compiled import BOOM, DIG, SEED, assert_close, contact_candidates
from test_pbd_fast import _compare
from test_runner_fast import assert_logs_agree
from sim.plants.pbd import PbdPlant
from sim.run.runner import run
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene


@pytest.fixture(autouse=True)
def _quiet_xpbd_notes():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")
        yield


def _plant(path, block, **overrides):
    scenario = load_scenario(path).with_overrides(mode="pbd", **overrides)
    return PbdPlant(load_scene(scenario), block=block)


def _compare_block(ref, blk, r1, r2, what):
    _compare(ref, blk, r1, r2, what)
    assert ref.step_index == blk.step_index, what
    assert ref.state.time == pytest.approx(blk.state.time, rel=1e-12, abs=1e-12), what
    assert_close(ref.state.qpos_hint, blk.state.qpos_hint, f"{what} hint")
    assert_close(ref.control.pump_speed, blk.control.pump_speed, f"{what} pump speeds")
    for name in ("node_pressure_max", "node_pressure_min"):
        a = getattr(ref, name)
        assert_close(a, getattr(blk, name), f"{what} {name}", floor=np.max(np.abs(a)))
    assert_close(ref._x, blk._x, f"{what} actuator x")
    assert_close(ref._v, blk._v, f"{what} actuator v")
    assert_close(ref.joint_state()[0], blk.joint_state()[0], f"{what} joints")


@pytest.mark.parametrize("path, blocks, overrides", [
    (SEED, (1, 12, 7, 20), {}),
    (BOOM, (1, 5, 9, 15), dict(dt=1 / 60, pbd_substeps=10)),
    (DIG, (1, 10, 10, 33, 50, 16), dict(dt=1 / 60, pbd_substeps=10)),  # 120 steps: the teeth touch at ≈ 1.6 s
    (DIG, (1, 30, 89), dict(dt=1 / 60, pbd_substeps=10, coupling="rosenbrock", pbd_blend=True)),
], ids=["seed", "boom", "excavator", "excavator-rosenbrock-blend"])
def test_blocks_agree_with_single_steps(path, blocks, overrides):
    ref, blk = _plant(path, False, **overrides), _plant(path, True, **overrides)
    assert blk.fast and not ref.fast
    contacts = 0
    for n in blocks:
        for _ in range(n):
            r1 = ref.advance(1)
            contacts += contact_candidates(ref)
        r2 = blk.advance(n)
        _compare_block(ref, blk, r1, r2, f"{path.name} t={ref.time:.4f}")
    assert blk.frame_steps == ref.frame_steps == sum(blocks)  # every step ran compiled
    assert ref.node_pressure_max.max() > ref.node_pressure_min.max()  # the extremes moved
    if path == DIG:
        assert contacts > 0  # ground contacts were inside the compared blocks


def test_snapshot_restore_replays_the_same_steps():
    """Advance, snapshot, advance; restore (and the runner's share: step index, network, ledger, controls) and
    advance again: the same state bit for bit (the runner replays a failed block this way)."""
    plant = _plant(BOOM, True, dt=1 / 60, pbd_substeps=10)
    plant.advance(20)
    snap = plant.snapshot()
    kept = (plant.step_index, plant.net_state, plant.effort, plant.last_report, plant.node_pressure_max,
            plant.node_pressure_min, plant.control.valve_command.copy(), plant.control.pump_speed.copy(),
            [getattr(plant.energy, k) for k in ("pump_work", "motor_work", "dissipated_hydraulic",
                                                "dissipated_friction", "dissipated_mechanical")])
    plant.advance(30)
    first = (plant.state.x.copy(), plant.state.v.copy(), plant.net_state.node_pressure.copy(), plant.energy.pump_work)
    plant.restore(snap)
    (plant.step_index, plant.net_state, plant.effort, plant.last_report, plant.node_pressure_max,
     plant.node_pressure_min, cmd, speed, ledger) = kept
    plant.control.valve_command[:], plant.control.pump_speed[:] = cmd, speed
    for k, value in zip(("pump_work", "motor_work", "dissipated_hydraulic", "dissipated_friction",
                         "dissipated_mechanical"), ledger):
        setattr(plant.energy, k, value)
    plant.advance(30)
    again = (plant.state.x, plant.state.v, plant.net_state.node_pressure, plant.energy.pump_work)
    for a, b in zip(first, again):
        assert np.array_equal(a, b)
    assert not np.array_equal(first[0], snap[0])  # the boom moved over the replayed steps


@pytest.mark.parametrize("path, overrides", [
    (BOOM, {"duration": 1.5, "dt": 1 / 60, "pbd_substeps": 10}),  # logged every step (60 Hz frames, 100 Hz log)
    (SEED, {"duration": 0.05}),                                     # 1200 Hz, logged every 12th step
], ids=["boom", "seed"])
def test_runner_blocks_log_the_same_values_as_per_step(tmp_path, path, overrides, monkeypatch):
    overrides = dict(overrides, mode="pbd")
    recorded = []
    record_next = PbdPlant.record_next
    monkeypatch.setattr(PbdPlant, "record_next", lambda self, record, every=1: (recorded.append(len(record)),
                                                                                record_next(self, record, every)))
    fast = run(path, out=tmp_path / "blocks.mcap", overrides=overrides)
    assert sum(recorded) > 0  # the samples inside the blocks were recorded by the compiled block
    slow = run(path, out=tmp_path / "steps.mcap", overrides=overrides, fast=False)
    assert fast.status == slow.status == "complete" and fast.steps == slow.steps
    a, b = assert_logs_agree(fast.log_path, slow.log_path)
    assert a.metadata["hydroplant.run"]["stepping"] == "blocks"
    assert b.metadata["hydroplant.run"]["stepping"] == "per-step"
    assert fast.extremes_every_step and slow.extremes_every_step
    for node, peak in slow.peak_pressure.items():
        assert fast.peak_pressure[node] == pytest.approx(peak, rel=1e-9)
        assert fast.min_pressure[node] == pytest.approx(slow.min_pressure[node], rel=1e-9)
    for key in ("pump_work", "dissipated", "delta"):
        assert fast.energy[key] == pytest.approx(slow.energy[key], rel=1e-9, abs=1e-9)
