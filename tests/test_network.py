"""Network assembly, node relations, flow Jacobian and mass conservation."""

import numpy as np
import pytest

from conftest import MODELS, network_from_toml
from hydraulics.circuit import load_circuit
from hydraulics.network import NetworkModel
from hydraulics.steppers import STEPPERS, ActuatorMotion, make_stepper

# every branch kind on one network: orifice, valve edges, relief, check, pump,
# compensated pump, laminar leaks, motor, accumulator, compliant hose
ALL_KINDS = """
[fluid]
air_fraction = 0.002
[[component]]
name = "tank"
type = "tank"
ports = { port = "tank" }
[[component]]
name = "pump"
type = "pump_fixed"
displacement = 1e-5
speed = 20.0
ports = { inlet = "tank", outlet = "supply" }
[[component]]
name = "pump2"
type = "pump_compensated"
displacement = 1e-5
speed = 20.0
compensator_pressure = 1.5e7
ports = { inlet = "tank", outlet = "supply" }
[[component]]
name = "line"
type = "hose"
length = 2.0
inner_diameter = 0.012
wall_bulk_modulus = 5e8
ports = { a = "supply", b = "p" }
[[component]]
name = "relief"
type = "relief_valve"
cracking_pressure = 2e7
gradient = 2e-10
ports = { inlet = "supply", outlet = "tank" }
[[component]]
name = "acc"
type = "accumulator"
gas_volume = 5e-4
precharge_pressure = 5e6
ports = { port = "supply" }
[[component]]
name = "valve"
type = "valve_4_3"
max_area = 1e-5
centre = "open"
centre_area = 2e-6
ports = { P = "p", T = "tank", A = "a", B = "b" }
[[component]]
name = "check"
type = "check_valve"
area = 1e-5
ports = { inlet = "tank", outlet = "a" }
[[component]]
name = "orifice"
type = "orifice"
area = 1e-6
ports = { a = "b", b = "tank" }
[[component]]
name = "cyl"
type = "cylinder"
bore = 0.05
rod_diameter = 0.03
stroke = 0.4
dead_volume_cap = 1e-5
dead_volume_rod = 1e-5
leakage_conductance = 1e-12
ports = { cap = "a", rod = "b" }
[[component]]
name = "swing"
type = "motor"
displacement = 2e-5
leakage_conductance = 1e-12
ports = { a = "a", b = "mb" }
[[component]]
name = "mb_volume"
type = "volume"
volume = 1e-4
ports = { port = "mb" }
"""


@pytest.fixture
def all_kinds():
    return network_from_toml(ALL_KINDS)


def test_assembly_counts(all_kinds):
    """Hose ends merge into one node; tanks are fixed; every kind yields its branches."""
    m = all_kinds
    assert m.node("supply") == m.node("p")
    assert m.node_count == 5  # tank, supply(+p), a, b, mb
    assert m.node_fixed.sum() == 1
    assert set(m.actuator_names) == {"cyl", "swing"}
    assert len(m.branch_names) == 4 + 3 + 2 + 1 + 1 + 1 + 2 + 1


def test_pressure_inverts_oil_content(all_kinds):
    """m = V(x, p)·φ(p) holds with walls, accumulators and air; cavitation floors low oil."""
    m = all_kinds
    x = np.array([0.2, 0.0])
    p = np.array([1.01325e5, 1.8e7, 3e6, 1e6, 4e5, 1.01325e5])[: m.node_count]
    p = np.where(m.node_fixed, m.node_fixed_pressure, p)
    oil = m.oil_from_pressure(p, x)
    back, dpdm = m.pressure(oil, x)
    assert back == pytest.approx(p, rel=1e-10)
    k = m.node("a")
    fd = (m.pressure(oil + np.eye(m.node_count)[k] * 1e-12, x)[0][k] - back[k]) / 1e-12
    assert dpdm[k] == pytest.approx(fd, rel=1e-4)
    starved = oil.copy()
    starved[k] *= 0.5  # half the oil that fills the node at 30 bar: a vapour void
    assert m.pressure(starved, x)[0][k] == m.fluid.cavitation_pressure
    assert m.pressure(starved, x)[1][k] == 0.0


def test_flow_jacobian_matches_finite_differences(all_kinds):
    m = all_kinds
    x = np.array([0.2, 0.0])
    v = np.array([0.05, 3.0])
    p = np.where(m.node_fixed, m.node_fixed_pressure, np.array([0, 2.00001e7, 3e6, 1e6, 4e5, 0])[: m.node_count])
    for spool in (0.0, 0.4, -0.7):
        areas = m.valve_areas(np.array([spool]))
        speed = np.array([20.0, 20.0])
        flows = m.branch_flows(p, areas, speed, v)
        jac = m.flow_jacobian(flows)
        net = lambda p: m.incidence @ m.branch_flows(p, areas, speed, v).flow
        for k in m.free_nodes:
            dp = np.zeros(m.node_count)
            dp[k] = 1.0
            fd = (net(p + dp) - net(p - dp)) / 2.0
            assert jac[:, k] == pytest.approx(fd, rel=1e-5, abs=1e-16)


CLOSED = """
[fluid]
[[component]]
name = "v1"
type = "volume"
volume = 1e-3
ports = { port = "n1" }
[[component]]
name = "o"
type = "orifice"
area = 2e-6
ports = { a = "n1", b = "cap" }
[[component]]
name = "cyl"
type = "cylinder"
bore = 0.05
rod_diameter = 0.03
stroke = 0.4
dead_volume_cap = 2e-5
dead_volume_rod = 2e-5
leakage_conductance = 2e-12
ports = { cap = "cap", rod = "rod" }
"""


@pytest.mark.parametrize("stepper_name", ["explicit_euler", "implicit_euler"])
def test_closed_network_conserves_oil(stepper_name):
    """A sealed network with flows between volumes keeps its oil mass to 1e-9 relative over 20 000 steps."""
    m = network_from_toml(CLOSED)
    p0 = np.array([2e7, 1e6, 5e5])
    state = m.state(actuator_position=[0.2], node_pressure=p0)
    stepper = make_stepper(stepper_name, m)
    control = m.control()
    dt = 2e-5 if stepper_name == "explicit_euler" else 1e-3
    total0 = np.nansum(state.node_oil)
    for n in range(20_000):
        t = n * dt
        x = 0.2 + 2e-4 * np.sin(2 * np.pi * 2 * t)
        v = 2e-4 * 2 * np.pi * 2 * np.cos(2 * np.pi * 2 * t)
        state, report = stepper.step(state, control, ActuatorMotion.linear([x], [v], dt), dt)
        assert report.success
    assert abs(np.nansum(state.node_oil) / total0 - 1) < 1e-9
    # and the flows really moved oil: the charged volume has discharged into the cylinder
    assert state.node_pressure[m.node("n1")] < 0.75 * p0[0]


def test_linearization_matches_finite_difference():
    """∂effort/∂v⁺ from the implicit stepper equals the finite difference of predicted efforts."""
    m = NetworkModel.from_circuit(load_circuit(MODELS / "lift_1dof" / "lift.circuit.toml"))
    state = m.state(actuator_position=[0.2], node_pressure=np.array([1.01325e5, 1.5e7, 8e6, 2e6]))
    stepper = STEPPERS["implicit_euler"](m)
    control = m.control(valve=0.6)
    dt = 1e-3
    lin = stepper.linearize(state, control, np.array([0.05]), dt)
    dv = 1e-6
    plus = stepper.linearize(state, control, np.array([0.05 + dv]), dt).effort
    minus = stepper.linearize(state, control, np.array([0.05 - dv]), dt).effort
    assert lin.effort_velocity_gradient[0, 0] == pytest.approx((plus - minus)[0] / (2 * dv), rel=1e-4)
    # dominated by the oil-column stiffness h·β·A²/V of both chambers
    k = m.chamber_stiffness(lin.state.node_pressure, lin.state.actuator_position).sum()
    assert -lin.effort_velocity_gradient[0, 0] > 0.5 * dt * k
