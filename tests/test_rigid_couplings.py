"""The compiled explicit, incompressible and rigid-actuator couplings (hydraulics._compiled_rigid) against their
numpy oracles (tests/reference/rigid_couplings.py): on random inputs, and plants stepped on either to round-off."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import MODELS
from hydraulics import _compiled as C
from hydraulics import _compiled_rigid as K
from hydraulics.circuit import load_circuit
from hydraulics.coupling import CouplingIncompressible, CouplingMixed, make_coupling
from hydraulics.network import NetworkModel
from sim.io.scenario import Schedule, load_scenario
from sim.io.scene import load_scene
from sim.plants.mujoco import MujocoPlant
from reference import rigid_couplings as R

EXCAVATOR = MODELS / "excavator" / "excavator.circuit.toml"
RIGID_FRONT = {"stick_cyl": "incompressible", "bucket_cyl": "incompressible", "swing_motor": "incompressible"}
RTOL = 1e-12  # kernel vs oracle, same arithmetic up to summation order and libm
PROPERTY = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def close(a, b, rtol=RTOL, scale=None):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert a.shape == b.shape
    assert np.array_equal(np.isnan(a), np.isnan(b)) and np.array_equal(np.isinf(a), np.isinf(b))
    finite = np.isfinite(a)
    s = np.abs(b[finite]).max(initial=0.0) if scale is None else scale
    np.testing.assert_allclose(a[finite], b[finite], rtol=rtol, atol=rtol * s)


@pytest.fixture(scope="module")
def models():
    circuit = load_circuit(EXCAVATOR)
    return {
        "excavator/incompressible": NetworkModel.from_circuit(circuit, fidelity="incompressible"),
        "excavator/rigid front": NetworkModel.from_circuit(circuit, actuator_fidelity=RIGID_FRONT),
        "excavator/rigid boom": NetworkModel.from_circuit(circuit, actuator_fidelity={"boom_cyl": "incompressible"}),
        "excavator": NetworkModel.from_circuit(circuit),
        "boom/incompressible": NetworkModel.from_circuit(load_circuit(MODELS / "boom" / "boom.circuit.toml"),
                                                         fidelity="incompressible"),
    }


def floats(n, lo, hi):
    return st.lists(st.floats(lo, hi, allow_nan=False), min_size=n, max_size=n).map(np.array)


@given(data=st.data())
@PROPERTY
def test_incompressible_law_matches_oracle(models, data):
    name = data.draw(st.sampled_from(["excavator/incompressible", "boom/incompressible"]))
    m = models[name]
    na, nv, npump = m.actuator_count, len(m.valve_names), len(m.pump_names)
    spool = data.draw(floats(nv, -1.0, 1.0))
    command = data.draw(floats(nv, -1.5, 1.5))
    speed = data.draw(floats(npump, 0.0, 60.0))
    velocity = data.draw(floats(na, -2.0, 2.0))
    mass = data.draw(floats(na, 1.0, 1e5))
    dt = data.draw(st.sampled_from([1e-4, 1e-3, 1e-2, 1 / 30]))
    # positions anywhere in and a little past the stroke, so that the end stops engage in some draws
    position = data.draw(floats(na, -0.05, 1.6))
    coupling = CouplingIncompressible(m)
    spool_end, law = coupling.law(spool, command, speed, position, velocity, mass, dt)
    expected_spool = R.spool_step(spool, np.clip(command, -1, 1), m.valve_time_constant, dt)
    close(spool_end, expected_spool)
    expected = R.incompressible_law(m, expected_spool, speed, position, velocity, mass, dt)
    for got, want in zip((law.constant, law.slope, law.lower, law.upper), expected):
        close(got, want, scale=np.abs(want[np.isfinite(want)]).max(initial=1.0))


@given(data=st.data())
@PROPERTY
def test_mixed_law_matches_oracle(models, data):
    name = data.draw(st.sampled_from(["excavator/rigid front", "excavator/rigid boom"]))
    m = models[name]
    na, nv, nr = m.actuator_count, len(m.valve_names), len(m.rigid_branch_actuator)
    spool0 = data.draw(floats(nv, -1.0, 1.0))
    command = data.draw(floats(nv, -1.5, 1.5))
    velocity = data.draw(floats(na, -2.0, 2.0))
    mass = data.draw(floats(na, 1.0, 1e5))
    constant, slope = data.draw(floats(na, -1e5, 1e5)), data.draw(floats(na, -1e7, 0.0))
    p_supply = data.draw(floats(nr, 0.0, 4e7))
    dp_dv = data.draw(floats(nr, -1e10, 0.0))
    v_guess = data.draw(floats(nr, -1.0, 1.0))
    dt = data.draw(st.sampled_from([1e-4, 1e-3, 1e-2]))
    F, I = C.pack_network(m)
    got = K.mixed_law_entry(F, I, K.pack_rigid(m), spool0, command, velocity, mass, dt, (p_supply, dp_dv, v_guess),
                            constant.copy(), slope.copy())
    want = R.mixed_law(m, constant, slope, spool0, command, velocity, mass, dt, p_supply, dp_dv, v_guess)
    for g, w in zip(got, want):
        close(g, w, scale=np.abs(w[np.isfinite(w)]).max(initial=1.0))


@given(data=st.data())
@PROPERTY
def test_explicit_substep_matches_oracle(models, data):
    name = data.draw(st.sampled_from(["excavator", "excavator/rigid front"]))
    m = models[name]
    na, nv, npump = m.actuator_count, len(m.valve_names), len(m.pump_names)
    x = data.draw(floats(na, 0.1, 0.5))
    velocity = data.draw(floats(na, -0.5, 0.5))
    pressure = np.full(m.node_count, m.fluid.reference_pressure)
    pressure[m.free_nodes] = data.draw(floats(len(m.free_nodes), 2e5, 3e7))
    state = m.state(actuator_position=x, node_pressure=pressure)
    spool, command = data.draw(floats(nv, -1.0, 1.0)), data.draw(floats(nv, -1.0, 1.0))
    speed = data.draw(floats(npump, 0.0, 40.0))
    h = data.draw(st.sampled_from([1e-6, 1e-5]))
    x_end = x + h * velocity
    F, I = C.pack_network(m)
    start = C.StepStart(state.node_oil, spool, command, speed, x, velocity)
    got = K.explicit_step_entry(F, I, start, x_end, h)
    want = R.explicit_substep(m, state.node_oil, spool, command, speed, x, x_end, velocity, h)
    free = m.free_nodes
    close(got[0][free], want[0][free], rtol=1e-13)
    close(got[1], want[1], rtol=1e-10)
    close(got[2], want[2])
    # flows: the leakage of closed edges near Δp = 0 feels the pressures' round-off (~1e-8 Pa at 1e7 Pa)
    np.testing.assert_allclose(got[3], want[3], rtol=1e-9, atol=1e-8 * np.abs(want[3]).max() + 1e-18)


@given(data=st.data())
@PROPERTY
def test_chamber_pressures_match_oracle(models, data):
    m = models[data.draw(st.sampled_from(sorted(["excavator/rigid front", "excavator/incompressible"])))]
    effort = data.draw(floats(m.actuator_count, -1e6, 1e6))
    mask = np.array(data.draw(st.lists(st.booleans(), min_size=m.actuator_count, max_size=m.actuator_count)))
    got = np.full(m.node_count, 7.0)
    from hydraulics.coupling import derive_chamber_pressures

    derive_chamber_pressures(m, effort, got, mask)
    close(got, R.chamber_pressures(m, effort, np.full(m.node_count, 7.0), mask), rtol=1e-15)


# ----------------------------------------------------------------------------
# Scenes: the per-step plant against the same plant on the oracles
# ----------------------------------------------------------------------------
def ramp(t0, t1, value):
    return Schedule(np.array([0.0, t0, t1]), np.array([0.0, 0.0, value]))


DIG = {"boom_valve": ramp(0.01, 0.05, -0.35), "stick_valve": ramp(0.01, 0.06, 0.8), "bucket_valve": ramp(0.02, 0.07, 0.5),
       "swing_valve": ramp(0.01, 0.05, 1.0)}
SCENES = {
    "excavator/incompressible": (MODELS / "excavator" / "dig.scenario.toml", dict(fidelity="incompressible"), DIG, None, 200),
    "boom/incompressible": (MODELS / "boom" / "lift.scenario.toml", dict(fidelity="incompressible"),
                            {"boom_valve": ramp(0.01, 0.05, 1.0)}, None, 200),
    "excavator/implicit+rigid": (MODELS / "excavator" / "dig.scenario.toml", dict(actuator_fidelity=RIGID_FRONT), DIG, None,
                                 150),
    "excavator/explicit+rigid": (MODELS / "excavator" / "dig.scenario.toml",
                                 dict(actuator_fidelity=RIGID_FRONT, dt=2e-5), DIG, "explicit", 150),
    "boom/explicit": (MODELS / "boom" / "lift.scenario.toml", dict(dt=2e-5), {"boom_valve": ramp(0.0, 0.002, 1.0)},
                      "explicit", 200),
}


def scene_plants(case, plant=MujocoPlant):
    path, overrides, inputs, coupling, steps = SCENES[case]
    scenario = load_scenario(path).with_overrides(**overrides)
    scenario = scenario.with_overrides(inputs={**scenario.inputs, **inputs})
    return scenario, coupling, steps


def compare_laws(got, want):
    for g, w in ((got.constant, want.constant), (got.slope, want.slope), (got.lower, want.lower), (got.upper, want.upper)):
        if w is None:
            assert g is None
            continue
        close(g, w, rtol=1e-9, scale=np.abs(w[np.isfinite(w)]).max(initial=1.0))


@pytest.mark.parametrize("case", list(SCENES))
def test_plant_steps_agree_with_oracles_step_by_step(case):
    """Every step of a plant on the compiled couplings: the oracle coupling, given the same start, returns the same
    effort law (bounds included) and the same end state, to round-off.  (Plants stepped apart diverge after a
    round-off flips one of the incompressible law's switches, see the next test.)"""
    scenario, coupling, steps = scene_plants(case)
    plant = MujocoPlant(load_scene(scenario), coupling=coupling)
    compiled, oracle = plant.coupling, R.oracle_coupling(plant.coupling)
    if "rigid" in case:
        assert isinstance(compiled, CouplingMixed)
    counts = {"begin": 0, "finish": 0}

    def begin(*args, **kwargs):
        got, want = compiled.begin(*args, **kwargs), oracle.begin(*args, **kwargs)
        compare_laws(got, want)
        counts["begin"] += 1
        return got

    def finish(*args):
        (got, report), (want, expected) = compiled.finish(*args), oracle.finish(*args)
        scale = np.abs(want.node_pressure).max()
        np.testing.assert_allclose(got.node_pressure, want.node_pressure, rtol=1e-9, atol=1e-12 * scale)
        close(got.node_oil, want.node_oil, rtol=1e-9)
        # (leakage across Δp ~ 1e-4 Pa feels the pressures' round-off, β·ε ~ 2e-7 Pa: 1e-12 m³/s is 1e-9 of a pump)
        np.testing.assert_allclose(report.branch_flow, expected.branch_flow, rtol=1e-8, atol=1e-12)
        counts["finish"] += 1
        return got, report

    class Probe:  # the plant's coupling, its begin and finish checked against the oracle's
        def __getattr__(self, name):
            return getattr(compiled, name)

    probe = Probe()
    probe.begin, probe.finish = begin, finish
    plant.coupling = probe
    for _ in range(steps):
        assert plant.step().success
    assert counts == {"begin": steps, "finish": steps}
    assert np.any(plant.data.qvel != 0)


@pytest.mark.parametrize("case", [c for c in SCENES if "explicit" in c])
def test_plant_on_compiled_couplings_matches_plant_on_oracles(case):
    scenario, coupling, steps = scene_plants(case)
    a = MujocoPlant(load_scene(scenario), coupling=coupling)
    b = MujocoPlant(load_scene(scenario), coupling=coupling)
    b.coupling = R.oracle_coupling(b.coupling)
    assert a.coupling.name == b.coupling.name
    if "rigid" in case:
        assert isinstance(a.coupling, CouplingMixed)
    for _ in range(steps):
        assert a.step().success and b.step().success
    scale = np.abs(b.net_state.node_pressure).max()
    np.testing.assert_allclose(a.net_state.node_pressure, b.net_state.node_pressure, rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(a.data.qpos, b.data.qpos, rtol=0, atol=1e-10)
    np.testing.assert_allclose(a.effort, b.effort, rtol=0, atol=1e-9 * (np.abs(b.effort).max() + 1.0))
    assert np.any(a.data.qvel != 0)
