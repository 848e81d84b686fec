"""``incompressible`` for some actuators while others stay compressible: rigid actuators on a compressible network.

A rigid actuator's chambers hold no pressure state; the rigid branch P → T of its valve draws the flow its
rod displaces from the supply it shares with the compressible actuators (hydraulics.coupling.CouplingMixed).
"""

import numpy as np
import pytest

from conftest import MODELS, scene_copy
from hydraulics.circuit import load_circuit
from hydraulics.components import CircuitError
from hydraulics.network import NetworkModel
from sim.io.mcap_log import read_log
from sim.run.runner import run
from sim.io.scenario import ScenarioError, load_scenario
from sim.run.guards import check_scenario
from sim.tools.inspect import describe
from sim.io.scene import load_scene

EXCAVATOR = MODELS / "excavator" / "excavator.circuit.toml"
RIGID_FRONT = {"stick_cyl": "incompressible", "bucket_cyl": "incompressible", "swing_motor": "incompressible"}


@pytest.fixture(scope="module")
def circuit():
    return load_circuit(EXCAVATOR)


def test_rigid_actuators_have_no_pressure_states(circuit):
    """Stick, bucket and swing rigid: only the supply and the boom chambers are pressure nodes; the rigid
    actuators' valve edges, port reliefs and make-up checks are not built, one rigid branch each replaces them."""
    full = NetworkModel.from_circuit(circuit)
    mixed = NetworkModel.from_circuit(circuit, actuator_fidelity=RIGID_FRONT)
    free = [mixed.node_names[k] for k in mixed.free_nodes]
    assert free == ["supply", "boom_cyl_cap", "boom_cyl_rod"]
    assert mixed.state_count == 3 + len(mixed.valve_names) == full.state_count - 6
    assert mixed.fidelity == "compressible" and list(mixed.actuator_rigid) == [False, True, True, True]
    assert [n for n in mixed.branch_names if n.endswith(".rigid")] == ["stick_cyl.rigid", "bucket_cyl.rigid", "swing_motor.rigid"]
    assert not any(n.startswith(("stick", "bucket", "swing")) and not n.endswith(".rigid") for n in mixed.branch_names)
    s = mixed.branch_slices["rigid"]
    assert {mixed.node_names[k] for k in mixed.branch_from[s]} == {"supply"}
    assert {mixed.node_names[k] for k in mixed.branch_to[s]} == {"tank"}
    # the rigid rate follows the spool: cap area extending, minus the rod area retracting, 0 inside the overlap
    stick = circuit.component("stick_cyl").params
    spool = np.zeros(len(mixed.valve_names))
    k = mixed.valve_names.index("stick_valve")
    for value, rate in ((0.5, stick.cap_area), (-0.5, -stick.rod_area), (0.05, 0.0)):
        spool[k] = value
        assert mixed.rigid_rates(spool)[0] == pytest.approx(rate, rel=1e-12)


def test_one_rigid_cylinder_leaves_the_others_as_they_were(circuit):
    full = NetworkModel.from_circuit(circuit)
    mixed = NetworkModel.from_circuit(circuit, actuator_fidelity={"boom_cyl": "incompressible"})
    assert int((~mixed.node_fixed).sum()) == int((~full.node_fixed).sum()) - 2
    assert sorted(set(full.branch_names) - set(mixed.branch_names)) == sorted(
        ["boom_valve.P-A", "boom_valve.B-T", "boom_valve.P-B", "boom_valve.A-T", "boom_port_relief_cap", "boom_port_relief_rod"])
    assert set(mixed.branch_names) - set(full.branch_names) == {"boom_cyl.rigid"}


def test_rigid_actuator_joined_to_a_pressure_node_is_refused(tmp_path):
    """An orifice from the supply straight into the stick's cap net cannot be rigid: the error names the component,
    both nets and the way out."""
    d = scene_copy(tmp_path, "excavator")
    path = d / "excavator.circuit.toml"
    path.write_text(path.read_text() + '\n[[component]]\nname = "bleed"\ntype = "orifice"\narea = 1e-6\n'
                    'ports = { a = "supply", b = "stick_cyl_cap" }\n')
    with pytest.raises(CircuitError, match=r"component 'bleed' joins net 'stick_cyl_cap' of actuator 'stick_cyl'.*"
                                           r"net 'supply'.*give 'stick_cyl' the fidelity 'compressible'"):
        NetworkModel.from_circuit(load_circuit(path), actuator_fidelity={"stick_cyl": "incompressible"})
    scenario = load_scenario(d / "dig.scenario.toml").with_overrides(actuator_fidelity={"stick_cyl": "incompressible"})
    with pytest.raises(ScenarioError, match=r"dig.scenario.toml, \[fidelity\].*'bleed'"):
        load_scene(scenario)


def test_default_incompressible_with_one_compressible_override_is_a_mixed_scene():
    scenario = load_scenario(MODELS / "excavator" / "dig.scenario.toml").with_overrides(
        fidelity="incompressible", actuator_fidelity={"boom_cyl": "compressible"})
    scene = load_scene(scenario)
    assert scene.network.fidelity == "compressible" and list(scene.network.actuator_rigid) == [False, True, True, True]
    assert scene.scenario.fidelity_label == "compressible (bucket_cyl: incompressible, stick_cyl: incompressible, swing_motor: incompressible)"


SHARE = """
[scene]
mjcf = "excavator.xml"
circuit = "excavator.circuit.toml"

[run]
mode = "{mode}"
dt = {dt}
duration = 1.6
pbd_substeps = 10

[initial]
qpos = {{ swing = 0.0, boom = 0.30, stick = -0.50, bucket = 0.30 }}
equilibrium = true

[inputs]
pump = {{ t = [0.0], value = [10.0] }}
boom_valve = {{ t = [0.0, 0.2, 0.4], value = [0.0, 0.0, 1.0] }}
bucket_valve = {{ t = [0.0, 0.2, 0.4], value = [0.0, 0.0, 1.0] }}
"""


def _flows(result, circuit, after=0.8):
    """Mean cap-side flow A_cap·Δx/Δt [m³/s] of the boom and the bucket from ``after`` to the end of the run
    (end points, not a fit: the light bucket bounces at ~5 Hz on the supply's oil column)."""
    log = read_log(result.log_path)
    flows = {}
    for name in ("boom_cyl", "bucket_cyl"):
        cyl = log.topic(f"/hydroplant/cylinders/{name}")
        t_end = float(cyl.t[-1])
        start, end = np.interp([after, t_end], cyl.t, cyl["position_m"])
        flows[name] = circuit.component(name).params.cap_area * (end - start) / (t_end - after)
    return flows


@pytest.fixture(scope="module")
def compressible_share(tmp_path_factory, circuit):
    """Boom up and bucket curl together, every actuator compressible (MuJoCo mode, 1 kHz)."""
    d = scene_copy(tmp_path_factory.mktemp("share"), "excavator")
    (d / "share.scenario.toml").write_text(SHARE.format(mode="mujoco", dt=0.001))
    result = run(d / "share.scenario.toml", out=d / "compressible.mcap")
    assert result.status == "complete"
    return _flows(result, circuit)


@pytest.mark.parametrize("mode, dt", [("mujoco", 0.001), ("pbd", 1 / 60)])
def test_rigid_bucket_and_compressible_boom_share_the_pump(tmp_path, circuit, compressible_share, mode, dt):
    """Boom (compressible) up and bucket (rigid) curling at once on a pump turned down to 600 rpm.

    The light bucket takes most of the 2.14e-3 m³/s: the supply settles near the bucket's load pressure, below
    what holds the boom, so the boom first sinks through its open valve and then creeps up (the circuit has no
    load-holding checks).  Nothing in the rigid law rations the flow: the compressible supply node, fed by the
    pump and drained through the rigid branch, finds the split.  Both actuators' steady flows agree with the
    all-compressible model within 3 % of the pump's flow, and together they use the pump's flow (within 5 %).
    """
    d = scene_copy(tmp_path, "excavator")
    path = d / "share.scenario.toml"
    path.write_text(SHARE.format(mode=mode, dt=dt) + '\n[fidelity]\nbucket_cyl = "incompressible"\n')
    result = run(path, out=tmp_path / "share.mcap")
    assert result.status == "complete"
    assert "bucket_cyl_cap" not in result.peak_pressure  # no pressure state for the rigid bucket
    pump = circuit.component("pump").params
    q_pump = pump.displacement * 10.0
    flows = _flows(result, circuit)
    for name, flow in flows.items():
        assert abs(flow - compressible_share[name]) < 0.03 * q_pump, (name, flows, compressible_share)
    assert sum(flows.values()) == pytest.approx(q_pump, rel=0.05)
    assert flows["bucket_cyl"] > 0.5 * q_pump


def test_all_incompressible_hands_out_no_more_than_the_pump_delivers(tmp_path, circuit, compressible_share):
    """The same boom-up + bucket-curl at the all-``incompressible`` level: its rule shares the pump by demand
    (not by load, so the split differs from the compressible model's), but the shares add up to the pump's flow
    (a pump-limited actuator switching between its metering damper and the share tracker would overshoot its
    share each step, 1.43× the pump's flow in total)."""
    d = scene_copy(tmp_path, "excavator")
    path = d / "share.scenario.toml"
    path.write_text(SHARE.format(mode="mujoco", dt=0.001) + '\n[fidelity]\ndefault = "incompressible"\n')
    result = run(path, out=tmp_path / "share.mcap")
    assert result.status == "complete"
    flows = _flows(result, circuit)
    q_pump = circuit.component("pump").params.displacement * 10.0
    assert sum(flows.values()) == pytest.approx(q_pump, rel=0.02), flows
    assert flows["boom_cyl"] > 2 * compressible_share["boom_cyl"]  # the demand rule is not the load split


@pytest.mark.parametrize("mode, dt, warned", [
    ("mujoco", 1 / 30, {"stick_cyl", "bucket_cyl"}), ("mujoco", 0.005, {"bucket_cyl"}), ("mujoco", 0.002, set()),
    ("pbd", 1 / 60, set())])
def test_guard_names_the_step_a_rigid_supply_column_needs(mode, dt, warned):
    """A rigid actuator's column is the supply net: ω = √(β_eff·A_cap²/(V_P·m_eff)); the guard warns where ω·h > 0.5
    (the measured limit, sim/run/guards.py), with the dt that resolves it."""
    scenario = load_scenario(MODELS / "excavator" / "dig.scenario.toml").with_overrides(
        mode=mode, coupling="implicit", dt=dt, actuator_fidelity=RIGID_FRONT, pbd_substeps=10)
    report = check_scenario(scenario)
    rows = {row.actuator: row for row in report.rows}
    scene = load_scene(scenario)
    net = scene.network
    supply = net.node("supply")
    p = net.state().node_pressure
    beta = net.effective_bulk_modulus(p, net.state().actuator_position)[supply]
    volume = net.node_volume_at(net.state().actuator_position, p)[0][supply]
    bucket = rows["bucket_cyl"]
    area = load_circuit(EXCAVATOR).component("bucket_cyl").params.cap_area
    assert bucket.stiffness == pytest.approx(beta * area**2 / volume, rel=0.05)  # at the start pressures, not ref
    assert {w.split(" ")[0] for w in report.warnings} == warned
    for name in warned:
        assert any(w.startswith(name) and "use dt <=" in w for w in report.warnings)
    if mode == "mujoco" and dt == 0.002:  # inspect names the step: 0.5/ω of the stiffest rigid column (the bucket)
        text = describe(scenario.path, {"actuator_fidelity": RIGID_FRONT, "dt": dt, "coupling": "implicit"})
        limit = min(0.5 / row.omega_h for row in report.rows if row.rigid)
        assert limit == pytest.approx(0.5 / bucket.omega_h)
        assert f"largest stable dt for implicit: {limit:.3g} s (the rigid actuators' supply column)" in text


@pytest.mark.parametrize("mode, dt", [("mujoco", 0.002), ("pbd", 1 / 60)])
def test_mixed_dig_through_soil_contact_creates_no_energy(tmp_path, circuit, mode, dt):
    """Boom compressible, stick, bucket and swing rigid: the first 3.5 s of the dig (teeth into the soil at ~2 s)
    at 2 ms (MuJoCo) and a 1/60 s frame × 10 XPBD substeps (the largest steps the guard passes): complete, logged pressures inside [cavitation floor,
    highest relief + override], and the energy residual ≥ 0 (numerical loss; the rigid trackers brake without
    metering the kinetic energy they take)."""
    scenario = load_scenario(MODELS / "excavator" / "dig.scenario.toml").with_overrides(
        mode=mode, dt=dt, duration=3.5, actuator_fidelity=RIGID_FRONT, pbd_substeps=10, pbd_iterations=4)
    result = run(scenario, out=tmp_path / f"{mode}.mcap")
    assert result.status == "complete" and result.simulated_time == pytest.approx(3.5, abs=dt)
    relief = max(r.params.cracking_pressure for r in circuit.by_kind("relief_valve"))
    ceiling = circuit.fluid.reference_pressure + 1.1 * relief
    log = read_log(result.log_path)
    for name in ("boom_cyl", "stick_cyl", "bucket_cyl"):
        cyl = log.topic(f"/hydroplant/cylinders/{name}")
        assert np.all(np.isfinite(cyl["position_m"]))
        assert np.all(np.minimum(cyl["p_cap_pa"], cyl["p_rod_pa"]) >= circuit.fluid.pressure_floor - 1.0)
        assert np.all(np.maximum(cyl["p_cap_pa"], cyl["p_rod_pa"]) <= ceiling)
    assert result.energy["relative"] > -0.01
