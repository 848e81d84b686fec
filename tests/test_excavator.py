"""Excavator dig-and-dump cycle in MuJoCo mode: 20 s at 1 kHz, physical pressures, energy balance."""

import numpy as np
import pytest

from conftest import MODELS
from hydraulics.circuit import load_circuit
from sim.io.mcap_log import read_log
from sim.run.runner import run

DIG = MODELS / "excavator" / "dig.scenario.toml"


def pressure_bounds():
    """[cavitation pressure, highest relief setting + its override at full pump flow] in Pa absolute."""
    circuit = load_circuit(MODELS / "excavator" / "excavator.circuit.toml")
    pump = circuit.component("pump").params
    q_max = pump.displacement * pump.speed
    high = max(r.params.cracking_pressure + q_max / r.params.gradient for r in circuit.by_kind("relief_valve"))
    return circuit.fluid.cavitation_pressure, high + circuit.fluid.reference_pressure


@pytest.fixture(scope="module")
def dig(tmp_path_factory):
    return run(DIG, out=tmp_path_factory.mktemp("dig") / "dig.mcap")


def test_dig_cycle_runs_20s_with_physical_pressures(dig):
    assert dig.status == "complete", dig.message
    assert dig.simulated_time == pytest.approx(20.0)
    low, high = pressure_bounds()
    log = read_log(dig.log_path)
    nodes = log.topic("/hydroplant/nodes")
    for name in log.topic("/hydroplant/nodes").messages[0]["pressure_pa"]:
        p = nodes[f"pressure_pa.{name}"]
        assert np.all(np.isfinite(p)), name
        assert np.all(p >= low - 1e-6) and np.all(p <= high), (name, p.min(), p.max())
    assert min(dig.min_pressure.values()) >= low and max(dig.peak_pressure.values()) <= high


def test_dig_cycle_moves_the_machine(dig):
    """The schedule digs, lifts, swings about 90° and back."""
    joints = read_log(dig.log_path).topic("/hydroplant/joint_states")
    swing = joints["position/swing"]
    assert np.max(swing) > np.radians(60)
    assert abs(swing[-1]) < np.radians(15)
    assert np.ptp(joints["position/boom"]) > 0.2 and np.ptp(joints["position/stick"]) > 0.5


def test_dig_cycle_energy_balance(dig):
    """pump work = Δ(kinetic + potential + oil) + physical dissipation, residual within 1 % of pump work at 1 kHz."""
    energy = dig.energy
    print(f"\nexcavator 1 kHz energy residual: {energy['residual']:.4g} J = {energy['relative']:.3%} of pump work {energy['pump_work']:.4g} J")
    assert energy["pump_work"] > 1e5
    assert abs(energy["relative"]) < 0.01
