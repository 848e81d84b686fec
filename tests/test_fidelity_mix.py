"""Fidelity per actuator: the scene's default level, overridden per cylinder or motor in the scenario.

``compressible`` and ``lines`` mix in one network (the hoses of a ``lines`` actuator become
π-lines, the others stay lumped into their chambers); ``incompressible`` among them: tests/test_fidelity_rigid.py.
"""

import numpy as np
import pytest

from conftest import MODELS, scene_copy
from hydraulics.circuit import load_circuit
from hydraulics.components import CircuitError
from hydraulics.network import NetworkModel
from sim.run.runner import run
from sim.io.scenario import ScenarioError, load_scenario
from sim.io.scene import load_scene

EXCAVATOR = MODELS / "excavator" / "excavator.circuit.toml"
FOUR_ACTUATORS = ("boom_cyl", "stick_cyl", "bucket_cyl", "swing_motor")


@pytest.fixture(scope="module")
def circuit():
    return load_circuit(EXCAVATOR)


@pytest.mark.parametrize("default, overrides, extra_nodes, lines", [
    ("compressible", {}, 0, ()),
    ("compressible", {"boom_cyl": "lines"}, 2, ("boom_hose_a", "boom_hose_b")),
    ("compressible", {"boom_cyl": "lines", "swing_motor": "lines"}, 4, ("boom_hose_a", "boom_hose_b", "swing_hose_a", "swing_hose_b")),
    ("lines", {"boom_cyl": "compressible"}, 6, ("stick_hose_a", "stick_hose_b", "bucket_hose_a", "bucket_hose_b", "swing_hose_a", "swing_hose_b")),
    ("lines", {}, 8, ("boom_hose_a", "boom_hose_b", "stick_hose_a", "stick_hose_b", "bucket_hose_a", "bucket_hose_b", "swing_hose_a", "swing_hose_b")),
])
def test_state_counts_per_mixed_configuration(circuit, default, overrides, extra_nodes, lines):
    """Each hose made a line adds one pressure node (its valve end); the oil volume stays the same."""
    lumped = NetworkModel.from_circuit(circuit)
    model = NetworkModel.from_circuit(circuit, fidelity=default, actuator_fidelity=overrides)
    assert int((~lumped.node_fixed).sum()) == 9  # supply + 2 chambers x 3 cylinders + 2 motor ports
    assert int((~model.node_fixed).sum()) == 9 + extra_nodes
    assert model.state_count == lumped.state_count + extra_nodes
    assert model.hose_lines == lines
    assert sum(name.endswith(".line") for name in model.branch_names) == len(lines)
    assert model.node_volume.sum() == pytest.approx(lumped.node_volume.sum(), rel=1e-12)
    expected = tuple(overrides.get(a, default) for a in FOUR_ACTUATORS)
    assert model.actuator_fidelity == expected
    assert model.fidelity == ("lines" if lines else "compressible")


def test_incompressible_for_every_actuator_is_the_incompressible_network(circuit):
    """(Some actuators only: rigid actuators of a compressible network, tests/test_fidelity_rigid.py.)"""
    every = {name: "incompressible" for name in FOUR_ACTUATORS}
    model = NetworkModel.from_circuit(circuit, fidelity="lines", actuator_fidelity=every)
    assert model.fidelity == "incompressible" and model.hose_lines == ()


def test_scenario_fidelity_table(tmp_path):
    d = scene_copy(tmp_path, "excavator")
    path = d / "dig.scenario.toml"
    path.write_text(path.read_text() + '\n[fidelity]\ndefault = "compressible"\nboom_cyl = "lines"\n')
    scenario = load_scenario(path)
    assert scenario.fidelity == "compressible" and scenario.actuator_fidelity == {"boom_cyl": "lines"}
    assert scenario.fidelity_label == "compressible (boom_cyl: lines)"
    scene = load_scene(scenario)
    assert scene.network.hose_lines == ("boom_hose_a", "boom_hose_b")
    # every actuator overridden to incompressible: the scene is incompressible (the plants' switch)
    every = scenario.with_overrides(actuator_fidelity={name: "incompressible" for name in FOUR_ACTUATORS})
    assert load_scene(every).scenario.fidelity == "incompressible"
    with pytest.raises(ScenarioError, match="field 'fidelity.arm_cyl'"):
        load_scene(scenario.with_overrides(actuator_fidelity={"arm_cyl": "lines"}))


@pytest.fixture(scope="module")
def dig_runs(tmp_path_factory):
    """The dig cycle for 2 s at 1 kHz: all compressible, boom + bucket as lines, all lines."""
    out = tmp_path_factory.mktemp("mix")
    base = load_scenario(MODELS / "excavator" / "dig.scenario.toml").with_overrides(duration=2.0, coupling="implicit")
    settings = {
        "compressible": base,
        "mixed": base.with_overrides(actuator_fidelity={"boom_cyl": "lines", "bucket_cyl": "lines"}),
        "lines": base.with_overrides(fidelity="lines"),
    }
    return {label: run(s, out=out / f"{label}.mcap") for label, s in settings.items()}


def test_mixed_excavator_digs_for_two_seconds_stably(dig_runs):
    """Complete, pressures inside [cavitation floor, highest relief + override], energy closes within 1 %."""
    r = dig_runs["mixed"]
    assert r.status == "complete" and r.simulated_time == pytest.approx(2.0)
    network = NetworkModel.from_circuit(load_circuit(EXCAVATOR))
    floor = network.fluid.pressure_floor
    ceiling = network.fluid.reference_pressure + float(np.max(network.relief_cracking)) * 1.1
    assert min(r.min_pressure.values()) >= floor - 1.0
    assert max(r.peak_pressure.values()) <= ceiling
    assert {"boom_valve_a", "boom_valve_b", "bucket_valve_a", "bucket_valve_b"} <= set(r.peak_pressure)
    assert abs(r.energy["relative"]) < 0.01
    assert all(np.isfinite(v) for v in r.final_strokes.values())


def test_lines_on_two_cylinders_move_them_like_the_all_lines_model(dig_runs):
    """The overridden cylinders follow the all-lines run far closer than the all-compressible run does."""
    lines = dig_runs["lines"].final_strokes
    for cylinder in ("boom_cyl", "bucket_cyl"):
        mixed_error = abs(dig_runs["mixed"].final_strokes[cylinder] - lines[cylinder])
        lumped_error = abs(dig_runs["compressible"].final_strokes[cylinder] - lines[cylinder])
        assert mixed_error < 0.5 * lumped_error, (cylinder, mixed_error, lumped_error)
        assert mixed_error < 1e-3  # m


def test_pbd_mode_steps_the_mixed_network(tmp_path):
    """PBD mode builds the same mixed network (11 pressure nodes) and stays with the MuJoCo-mode strokes."""
    base = load_scenario(MODELS / "excavator" / "dig.scenario.toml").with_overrides(
        duration=0.005, actuator_fidelity={"boom_cyl": "lines"})
    strokes = {}
    for mode in ("pbd", "mujoco"):
        r = run(base.with_overrides(mode=mode), out=tmp_path / f"{mode}.mcap")
        assert r.status == "complete"
        assert {"boom_valve_a", "boom_valve_b"} <= set(r.peak_pressure) and len(r.peak_pressure) == 11
        strokes[mode] = r.final_strokes
    for name, x in strokes["pbd"].items():
        assert x == pytest.approx(strokes["mujoco"][name], abs=1e-3)


def test_incompressible_closed_cylinder_without_valves_is_rigid(tmp_path):
    """The seed's closed cylinder (no valve, no relief) at 'incompressible': rigid oil locks the rod (a circuit
    without metering edges is valid at this level)."""
    scenario = load_scenario(MODELS / "seed_cylinder" / "closed.scenario.toml").with_overrides(
        fidelity="incompressible", duration=0.05)
    for mode in ("mujoco", "pbd"):
        r = run(scenario.with_overrides(mode=mode), out=tmp_path / f"{mode}.mcap")
        assert r.status == "complete"
        assert r.final_strokes["cyl"] == pytest.approx(1.0, abs=1e-4)  # released at x = 1 m; the 1 kg piston cannot move
