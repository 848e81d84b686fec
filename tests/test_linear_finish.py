"""Coupling ``implicit-linear``: the linearly implicit (Rosenbrock–Euler) finish m⁺ = m_lin + (∂m/∂v)·(v⁺ − v_guess).

Physics checks: exact oil conservation in a sealed network, first-order convergence to the monolithic
reference on a 1-DOF lift, and agreement with the Newton finish (``implicit``) on the MuJoCo boom lift.
"""

import numpy as np
import pytest

from conftest import MODELS, network_from_toml
from hydraulics.coupling import CouplingImplicitLinear, make_coupling
from hydraulics.load import MassLoad, simulate, simulate_reference
from test_load import lift_model
from test_network import CLOSED


@pytest.mark.parametrize("compiled", [False, True])
def test_closed_network_conserves_oil_to_round_off(compiled):
    """Sealed volume → orifice → cylinder (leaking piston), rod driven with v⁺ ≠ v_guess: total oil constant to 1e-12."""
    m = network_from_toml(CLOSED)
    coupling = make_coupling("implicit-linear", m, compiled=compiled)
    assert isinstance(coupling, CouplingImplicitLinear)
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
        # the columns of ∂m/∂v sum to zero: the linearised flows only move oil between nodes
        g = coupling.last_linearization.oil_velocity_gradient
        assert abs(np.sum(g)) <= 1e-12 * np.sum(np.abs(g))
    assert abs(np.sum(state.node_oil) / total0 - 1) < 1e-12
    assert state.node_oil[n1] < 0.999 * oil_n1  # and oil really moved out of the charged volume
    assert state.node_pressure[n1] < 0.9 * 2e7


def test_first_order_convergence_on_1dof_lift():
    """Lift with a 200 kg load, valve half open: end position and pressures converge to the monolithic solve_ivp
    reference at order ≈ 1 (as the Newton finish), and the two finishes agree within 2× in error."""
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
    for coupling in ("implicit-linear", "implicit"):
        e = []
        for dt in dts:
            tr = simulate(m, load, state, dt=dt, duration=duration, coupling=coupling, inputs=inputs)
            assert tr.status == "complete"
            e.append((abs(tr.position[-1] - ref.position[-1]), np.max(np.abs(tr.node_pressure[-1] - ref.node_pressure[-1]))))
        errors[coupling] = np.array(e)
    lin = errors["implicit-linear"]
    for column in range(2):
        order = np.polyfit(np.log(dts), np.log(lin[:, column]), 1)[0]
        assert 0.8 <= order <= 1.6, (lin, order)
    assert np.all(lin <= 2.0 * errors["implicit"]) and np.all(lin[-1] < 0.1 * np.abs(ref.node_pressure[-1]).max())


def test_boom_lift_agrees_with_newton_finish_within_1_percent_of_stroke():
    """MuJoCo boom lift (valve opens at 1 s, end stop at ≈ 2.6 s), 3.5 s at 1 kHz: the linearly implicit finish and
    the Newton finish give the same stroke within 1 % of the stroke and the same relief pressure at the end stop."""
    pytest.importorskip("mujoco")
    from sim.plant_mujoco_fast import MujocoPlantFast
    from sim.scenario import load_scenario
    from sim.scene import load_scene

    scenario = load_scenario(MODELS / "boom" / "lift.scenario.toml")
    newton = MujocoPlantFast(load_scene(scenario))
    linear = MujocoPlantFast(load_scene(scenario), coupling="implicit-linear")
    assert linear.coupling.name == "implicit-linear" and newton.coupling.name == "implicit"
    stroke = newton.network.cylinder_stroke[0]
    worst, start = 0.0, newton.net_state.actuator_position[0]
    for _ in range(35):
        assert newton.advance(100).success and linear.advance(100).success
        worst = max(worst, abs(linear.net_state.actuator_position[0] - newton.net_state.actuator_position[0]))
    assert newton.net_state.actuator_position[0] - start > 0.15  # the boom really lifted
    assert worst < 0.01 * stroke, worst / stroke
    assert linear.last_report.newton_iterations == 0
    np.testing.assert_allclose(linear.net_state.node_pressure, newton.net_state.node_pressure, rtol=0.01, atol=2e4)
