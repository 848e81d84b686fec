"""1-DOF loads on circuits without MuJoCo: steady speed, relief, Merritt frequency, stiffness, convergence order."""

import math

import numpy as np
import pytest

from conftest import MODELS, network_from_toml
from hydraulics.circuit import load_circuit
from hydraulics.load import MassLoad, simulate, simulate_reference
from hydraulics.network import NetworkModel
from hydraulics.steppers import ActuatorMotion, make_stepper

LIFT = MODELS / "lift_1dof" / "lift.circuit.toml"


def lift_model():
    return NetworkModel.from_circuit(load_circuit(LIFT))


def test_pump_through_open_valve_gives_rod_speed_q_over_a():
    """A light load is lifted at the pump flow divided by the piston area (within 1 %)."""
    m = lift_model()
    load = MassLoad(actuator="lift", mass=50.0, force=-50.0 * 9.81)
    state = m.state(actuator_position=[0.05])
    tr = simulate(m, load, state, dt=2e-3, duration=2.0, inputs={"valve": 1.0})
    assert tr.status == "complete"
    q = 1e-5 * 20.0  # D·n [m^3/s]
    area = math.pi * 0.05**2 / 4
    steady = tr.velocity[(tr.time > 1.0) & (tr.time < 1.9)]
    assert steady.std() < 1e-4
    assert steady.mean() == pytest.approx(q / area, rel=0.01)


def test_relief_caps_pressure_at_end_stop():
    """Past the end stop the whole pump flow crosses the relief valve: p ≤ p_crack + Q/G."""
    m = lift_model()
    load = MassLoad(actuator="lift", mass=50.0, force=-500.0)
    state = m.state(actuator_position=[0.45])
    tr = simulate(m, load, state, dt=2e-3, duration=2.0, inputs={"valve": 1.0})
    assert tr.position[-1] == pytest.approx(0.5)  # at the end stop
    supply = tr.pressure(m, "supply")
    crack, override = 2e7, 2e-4 / 2e-10  # Pa
    settled = supply[tr.time > 1.5]
    assert np.all(settled > crack)
    assert np.all(settled - 1.01325e5 <= crack + 1.01 * override)  # differential setting, 1 % for the blend
    assert np.max(supply) - 1.01325e5 <= crack + 1.05 * override


BLOCKED = """
[fluid]
bulk_modulus = 1.5e9
[[component]]
name = "cyl"
type = "cylinder"
bore = 0.05
rod_diameter = 0.028
stroke = 0.5
dead_volume_cap = 2e-5
dead_volume_rod = 2e-5
ports = { cap = "cap", rod = "rod" }
[[component]]
name = "hose_cap"
type = "volume"
volume = 1.9e-4
ports = { port = "cap" }
[[component]]
name = "hose_rod"
type = "volume"
volume = 1.9e-4
ports = { port = "rod" }
"""


def test_blocked_cylinder_oscillates_at_merritt_frequency():
    """Both ports blocked: small oscillations at ω_h² = (β/m)(A_c²/V_c + A_r²/V_r) within 2 %."""
    m = network_from_toml(BLOCKED)
    mass, x0 = 500.0, 0.25
    a_c, a_r = m.cylinder_cap_area[0], m.cylinder_rod_area[0]
    p_rod = 2e6
    p_cap = (mass * 9.81 + p_rod * a_r + 1.01325e5 * (a_c - a_r)) / a_c  # static balance
    state = m.state(actuator_position=[x0], node_pressure=np.array([p_cap, p_rod]))
    load = MassLoad(actuator="cyl", mass=mass, force=-mass * 9.81)
    tr = simulate(m, load, state, dt=1e-4, duration=0.3, velocity=1e-3)
    v_c = 2e-5 + a_c * x0 + 1.9e-4
    v_r = 2e-5 + a_r * (0.5 - x0) + 1.9e-4
    omega = math.sqrt(1.5e9 / mass * (a_c**2 / v_c + a_r**2 / v_r))
    crossings = tr.time[1:][np.diff(np.sign(tr.velocity)) != 0]
    measured = math.pi / np.mean(np.diff(crossings))  # half a period between zero crossings
    assert measured == pytest.approx(omega, rel=0.02)
    # and it holds its position: the oscillation is about the static equilibrium
    assert abs(tr.position.mean() - x0) < 1e-5


STIFF = """
[fluid]
bulk_modulus = 2.2e9
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
name = "supply_volume"
type = "volume"
volume = 1e-6
ports = { port = "supply" }
[[component]]
name = "relief"
type = "relief_valve"
cracking_pressure = 2e7
gradient = 2e-10
ports = { inlet = "supply", outlet = "tank" }
[[component]]
name = "valve"
type = "valve_4_3"
max_area = 1.2e-5
time_constant = 0.02
leakage_area = 0.0
ports = { P = "supply", T = "tank", A = "cap", B = "rod" }
[[component]]
name = "cyl"
type = "cylinder"
bore = 0.05
rod_diameter = 0.028
stroke = 0.5
dead_volume_cap = 1e-6
dead_volume_rod = 1e-6
ports = { cap = "cap", rod = "rod" }
"""


def test_large_step_stiff_oil_implicit_settles_explicit_blows_up():
    """dt = 1/60 s, β = 2.2e9 Pa, 1e-6 m³ dead volumes, pump running: implicit settles, explicit diverges.

    The load starts off equilibrium (chambers at ambient pressure) and sinks
    onto its oil column; the oil-column frequency is ≈ 4e3 rad/s, so ω·h ≈ 70.
    """
    m = network_from_toml(STIFF)
    load = MassLoad(actuator="cyl", mass=100.0, force=-981.0)
    state = m.state(actuator_position=[0.002])
    k = m.chamber_stiffness(state.node_pressure, state.actuator_position).sum()
    assert math.sqrt(k / 100.0) / 60 > 50  # ω·h ≈ 70: far beyond explicit stability (ω·h < 2)
    imp = simulate(m, load, state, dt=1 / 60, duration=3.0, coupling="implicit")
    assert imp.status == "complete"
    p = imp.node_pressure[:, [m.node("supply"), m.node("cap"), m.node("rod")]]
    assert np.all(p >= m.fluid.cavitation_pressure) and np.all(p - 1.01325e5 <= 2e7 + 1.05e6)
    assert np.all(np.abs(imp.position - 0.002) < 5e-4)  # bounded: no excursion beyond the oil column's compression
    late = imp.time > 1.0
    assert np.all(np.abs(imp.velocity[late]) < 1e-6)  # settled
    cap = imp.node_pressure[late][:, m.node("cap")]
    assert np.ptp(cap) < 0.01 * cap.mean()
    # static balance at the end: cap·A_cap − rod·A_rod − p_amb·(A_cap − A_rod) = m·g
    assert imp.effort[-1] == pytest.approx(981.0, rel=0.01)
    exp = simulate(m, load, state, dt=1 / 60, duration=3.0, coupling="explicit")
    assert exp.status == "diverged"


SMOOTH_T = 0.1


def smooth_problem():
    m = lift_model()
    p0 = np.where(m.node_fixed, m.node_fixed_pressure, 0.0)
    p0[m.node("supply")], p0[m.node("cap")], p0[m.node("rod")] = 3e6, 2.5e6, 2e5
    state = m.state(actuator_position=[0.2], node_pressure=p0)
    control = m.control(valve=0.5, pump=5.0)

    def motion(t, dt):
        x = lambda t: 0.2 + 0.015 * t - 0.0075 / (2 * np.pi * 5) * np.cos(2 * np.pi * 5 * t)
        v = lambda t: 0.015 * (1 + 0.5 * np.sin(2 * np.pi * 5 * t))
        return ActuatorMotion(np.array([x(t)]), np.array([x(t + dt)]), np.array([v(t)]), np.array([v(t + dt)]))

    return m, state, control, motion


def run_smooth(name, dt):
    m, state, control, motion = smooth_problem()
    stepper = make_stepper(name, m)
    for n in range(int(round(SMOOTH_T / dt))):
        state, report = stepper.step(state, control, motion(n * dt, dt), dt)
        assert report.success
    return state.node_pressure[m.free_nodes]


@pytest.fixture(scope="module")
def smooth_reference():
    return run_smooth("reference", 5e-3)


@pytest.mark.parametrize("name", ["explicit_euler", "implicit_euler"])
def test_convergence_order(name, smooth_reference):
    """Halving dt on a smooth problem: measured order of each first-order stepper ≥ 0.9."""
    dts = np.array([4e-4, 2e-4, 1e-4, 5e-5])
    errors = np.array([np.max(np.abs(run_smooth(name, dt) - smooth_reference)) for dt in dts])
    order = np.polyfit(np.log(dts), np.log(errors), 1)[0]
    assert order >= 0.9, (errors, order)
    assert make_stepper(name, lift_model()).order == 1


def test_reference_stepper_is_step_size_independent(smooth_reference):
    """The solve_ivp reference gives the same answer at another outer step (within 1 Pa)."""
    assert run_smooth("reference", 1e-2) == pytest.approx(smooth_reference, abs=1.0)


def test_reference_agrees_with_fine_implicit_seed():
    """The monolithic reference and the coupled implicit scheme agree on the seed closed cylinder at fine dt."""
    seed = """
[fluid]
bulk_modulus = 2.2e9
reference_pressure = 0.0
cavitation = false
[[component]]
name = "tank"
type = "tank"
pressure = 0.0
ports = { port = "tank" }
[[component]]
name = "cyl"
type = "cylinder"
bore = 0.033851375012865375
rod_diameter = 0.0169
stroke = 10.0
ports = { cap = "cyl_cap", rod = "tank" }
"""
    m = network_from_toml(seed)
    p = np.zeros(m.node_count)
    p[m.node("cyl_cap")] = 2.2e9
    state = m.state(actuator_position=[1.0], node_pressure=p)
    load = MassLoad(actuator="cyl", mass=1.0)
    # the seed's closed-chamber law P = β(1 − ln x) holds exactly in the network's state
    assert m.pressure(state.node_oil, np.array([2.0]))[0][m.node("cyl_cap")] == pytest.approx(2.2e9 * (1 - math.log(2.0)))
    times = np.linspace(0, 0.01, 11)
    ref = simulate_reference(m, load, state, duration=0.01, sample_times=times)
    fine = simulate(m, load, state, dt=2e-6, duration=0.01)
    assert np.interp(times, fine.time, fine.position) == pytest.approx(ref.position, abs=0.005 * np.ptp(ref.position))
