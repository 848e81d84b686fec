"""Couplings ``implicit-linear`` (the linearly implicit finish m⁺ = m_lin + (∂m/∂v)·(v⁺ − v_guess)) and
``rosenbrock`` (the same finish of a linearisation that takes one Newton step: no nonlinear solve in the step).

Physics checks, for both: exact oil conservation in a sealed network, first-order convergence to the monolithic
reference on a 1-DOF lift, agreement with the Newton finish (``implicit``) on the MuJoCo boom lift; for
``rosenbrock`` also the stiff limit (ω·h ≈ 70 with a pump filling a 1e-6 m³ supply past its relief in one step:
the one Newton step leaves the trust region there and the step is solved by Newton; it settles).
"""

import numpy as np
import pytest

from conftest import MODELS, network_from_toml
from hydraulics.coupling import CouplingImplicitLinear, make_coupling
from hydraulics.load import MassLoad, simulate, simulate_reference
from reference.coupling_implicit import ORACLES
from test_load import lift_model
from test_network import CLOSED


LINEAR = ["implicit-linear", "rosenbrock"]


@pytest.mark.parametrize("coupling_name", LINEAR)
@pytest.mark.parametrize("oracle", [False, True], ids=["package", "oracle"])
def test_closed_network_conserves_oil_to_round_off(oracle, coupling_name):
    """Sealed volume → orifice → cylinder (leaking piston), rod driven with v⁺ ≠ v_guess: total oil constant to 1e-12,
    with the package's coupling (compiled kernels) and with its numpy oracle."""
    m = network_from_toml(CLOSED)
    coupling = ORACLES[coupling_name](m) if oracle else make_coupling(coupling_name, m)
    assert (oracle or isinstance(coupling, CouplingImplicitLinear)) and coupling.name == coupling_name
    state = m.state(actuator_position=[0.2], node_pressure=np.array([2e7, 1e6, 5e5]))
    control = m.control()
    dt = 1e-3
    total0 = np.sum(state.node_oil)
    n1 = m.node("n1")
    oil_n1 = state.node_oil[n1]
    for n in range(3000):
        t = n * dt
        x, v = 0.2 + 2e-3 * np.sin(2 * np.pi * 2 * t), np.array([2e-3 * 2 * np.pi * 2 * np.cos(2 * np.pi * 2 * t)])
        v_end = np.array([2e-3 * 2 * np.pi * 2 * np.cos(2 * np.pi * 2 * (t + dt))])
        coupling.begin(state, control, [x], v, dt, velocity_guess=v)  # v⁺ − v_guess = O(dt): the gradient is used
        state, report = coupling.finish(state, control, [x], [x] + dt * v_end, v, v_end, dt)
        assert report.success and report.newton_iterations == 0
        iterations = coupling.last_linearization.report.newton_iterations
        assert iterations == 1 if coupling_name == "rosenbrock" else iterations >= 1  # rosenbrock: one Newton step
        # the columns of ∂m/∂v sum to zero: the linearised flows only move oil between nodes
        g = coupling.last_linearization.oil_velocity_gradient
        assert abs(np.sum(g)) <= 1e-12 * np.sum(np.abs(g))
    assert abs(np.sum(state.node_oil) / total0 - 1) < 1e-12
    assert state.node_oil[n1] < 0.999 * oil_n1  # and oil really moved out of the charged volume
    assert state.node_pressure[n1] < 0.9 * 2e7


@pytest.mark.parametrize("linear", LINEAR)
def test_first_order_convergence_on_1dof_lift(linear):
    """Lift with a 200 kg load, valve half open: end position and pressures converge to the monolithic solve_ivp
    reference at order ≈ 1 (as the Newton finish), and the two schemes agree within 2× in error."""
    m = lift_model()
    p0 = np.where(m.node_fixed, m.node_fixed_pressure, 0.0)
    p0[m.node("supply")], p0[m.node("cap")], p0[m.node("rod")] = 3e6, 2.5e6, 2e5
    state = m.state(actuator_position=[0.2], node_pressure=p0)
    load = MassLoad(actuator="lift", mass=200.0, force=-200.0 * 9.81)
    inputs = {"valve": 0.5, "pump": 5.0}
    duration = 0.02
    ref = simulate_reference(m, load, state, duration=duration, sample_times=np.array([0.0, duration]), inputs=inputs)
    dts = np.array([4e-4, 2e-4, 1e-4])
    errors = {}
    for coupling in (linear, "implicit"):
        e = []
        for dt in dts:
            tr = simulate(m, load, state, dt=dt, duration=duration, coupling=coupling, inputs=inputs)
            assert tr.status == "complete"
            e.append((abs(tr.position[-1] - ref.position[-1]), np.max(np.abs(tr.node_pressure[-1] - ref.node_pressure[-1]))))
        errors[coupling] = np.array(e)
    lin = errors[linear]
    for column in range(2):
        order = np.polyfit(np.log(dts), np.log(lin[:, column]), 1)[0]
        assert 0.8 <= order <= 1.6, (lin, order)
    assert np.all(lin <= 2.0 * errors["implicit"]) and np.all(lin[-1] < 0.1 * np.abs(ref.node_pressure[-1]).max())


@pytest.mark.parametrize("linear", LINEAR)
def test_boom_lift_agrees_with_newton_finish_within_1_percent_of_stroke(linear):
    """MuJoCo boom lift (valve opens at 1 s, end stop at ≈ 2.6 s), 3.5 s at 1 kHz: the linearly implicit finish and
    the Newton finish give the same stroke within 1 % of the stroke and the same relief pressure at the end stop."""
    pytest.importorskip("mujoco")
    from sim.plants.mujoco_fast import MujocoPlantFast
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene

    scenario = load_scenario(MODELS / "boom" / "lift.scenario.toml")
    newton = MujocoPlantFast(load_scene(scenario), coupling="implicit")
    name, linear = linear, MujocoPlantFast(load_scene(scenario), coupling=linear)
    assert linear.fast and linear.coupling.name == name and newton.coupling.name == "implicit"
    stroke = newton.network.cylinder_stroke[0]
    worst, start = 0.0, newton.net_state.actuator_position[0]
    for _ in range(35):
        assert newton.advance(100).success and linear.advance(100).success
        worst = max(worst, abs(linear.net_state.actuator_position[0] - newton.net_state.actuator_position[0]))
    assert newton.net_state.actuator_position[0] - start > 0.15  # the boom really lifted
    assert worst < 0.01 * stroke, worst / stroke
    assert linear.last_report.newton_iterations == 0
    np.testing.assert_allclose(linear.net_state.node_pressure, newton.net_state.node_pressure, rtol=0.01, atol=2e4)


def test_rosenbrock_settles_in_the_stiff_limit():
    """dt = 1/60 s, β = 2.2e9 Pa, 1e-6 m³ dead volumes (ω·h ≈ 70): one Newton step per step is enough, as for
    backward Euler: the load sinks onto its oil column, stays within it and settles at the static balance."""
    from test_load import STIFF

    m = network_from_toml(STIFF)
    load = MassLoad(actuator="cyl", mass=100.0, force=-981.0)
    state = m.state(actuator_position=[0.002])
    tr = simulate(m, load, state, dt=1 / 60, duration=3.0, coupling="rosenbrock")
    assert tr.status == "complete"
    p = tr.node_pressure[:, [m.node("supply"), m.node("cap"), m.node("rod")]]
    assert np.all(p >= m.fluid.cavitation_pressure) and np.all(p - 1.01325e5 <= 2e7 + 1.05e6)
    assert np.all(np.abs(tr.position - 0.002) < 5e-4)
    late = tr.time > 1.0
    assert np.all(np.abs(tr.velocity[late]) < 1e-6)
    assert tr.effort[-1] == pytest.approx(981.0, rel=0.01)

