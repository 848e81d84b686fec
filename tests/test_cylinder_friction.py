"""Pressure-dependent seal friction of the cylinder (``friction_pressure_coefficient`` k_p).

The friction level F_c + F_p, F_p = k_p·(p_cap,g·A_cap + p_rod,g·A_rod) (gauge pressures), so that the breakaway
force of a pressurised cylinder is F_s + F_p.

* The law and its derivatives: the network's friction effort at given pressures equals the oracle's; the implicit
  stepper's ∂effort/∂v⁺ holds the friction's pressure dependence (central difference of the linearised effort).
* Held load and breakaway (scenario, both modes): a 200 kg load on a vertical slide, its 50 mm cylinder's cap fed
  from a pressure source p_s through a 2 mm² orifice, the rod side on the tank, F_c = F_s = 500 N, k_p = 0.05.
  In steady motion at v (rod pressure at ambient):

      p·A − m·g = (F_c + k_p·p·A)·tanh(v/v_reg),   A·v·φ(p) = Q_orifice(p_s − p)     (p gauge cap pressure)

  Below the breakaway pressure p_b = (m·g + F_c)/(A·(1 − k_p)) the load is held: it creeps at the regularised
  friction's v = v_reg·artanh((p·A − m·g)/(F_c + k_p·p·A)) (sub-millimetre per second); above it the rod slides at
  p = p_b (tanh = 1) and the orifice law's speed.  Without the pressure term the creep speed is 35 % higher and the
  sliding pressure 5 % lower, so both checks see k_p.
"""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
from scipy.optimize import brentq

from reference import laws
from reference import network_eval as ref
from reference.laws import orifice_textbook
from reference.circuits import bench, lift_cylinder, orifice, pressure_source
from reference.scenes import vertical_lift
from hydraulics.circuit import load_circuit, parse_circuit
from hydraulics.components import CircuitError
from hydraulics.components.cylinder import FRICTION_REGULARISATION_VELOCITY
from hydraulics.network import NetworkModel
from hydraulics.steppers import STEPPERS
from sim.io.mcap_log import read_log
from sim.run.runner import run
from conftest import MODELS

MASS = 200.0  # kg
BORE = 0.05  # m
AREA = math.pi / 4 * BORE**2  # m²
ORIFICE = 2.0e-6  # m²
CD = 0.7
G = 9.81
COULOMB = 500.0  # N
KP = 0.05  # -
BREAKAWAY = (MASS * G + COULOMB) / (AREA * (1.0 - KP))  # Pa gauge: cap pressure that starts the load up



def _circuit(source, kp=KP):
    return (bench() + pressure_source(source) + orifice("feed", "supply", "cap", ORIFICE, CD)
            + lift_cylinder(BORE, coulomb_friction=COULOMB, friction_pressure_coefficient=kp))


def test_friction_effort_and_breakaway_at_pressure():
    """At p_cap = 80 bar, p_rod = 30 bar (gauge) the sliding friction is F_c + k_p·(p_cap·A_cap + p_rod·A_rod) and the
    breakaway (Stribeck peak, v ≪ v_s) F_s + the same seal load; the network agrees with the oracle."""
    text = _circuit(0.0).replace('ports = { cap = "cap", rod = "tank" }', 'static_friction = 800.0\nstribeck_velocity = 0.5\n'
                                 'ports = { cap = "cap", rod = "rod" }')
    m = NetworkModel.from_circuit(parse_circuit(tomllib.loads(text), "friction"))
    p_ref = m.fluid.reference_pressure
    p = np.full(m.node_count, p_ref)
    p[m.node("cap")], p[m.node("rod")] = p_ref + 8e6, p_ref + 3e6
    rod_area = math.pi / 4 * (BORE**2 - 0.028**2)
    seal = KP * (8e6 * AREA + 3e6 * rod_area)
    assert seal == pytest.approx(laws.seal_load(p_ref + 8e6, p_ref + 3e6, AREA, rod_area, p_ref, KP), rel=1e-12)
    v_break = 20 * FRICTION_REGULARISATION_VELOCITY  # tanh = 1, exp(−(v/v_s)²) = 0.998
    effort, _ = m.friction_effort(np.array([v_break]), p)
    stribeck = math.exp(-(v_break / 0.5) ** 2)
    assert -effort[0] == pytest.approx(COULOMB + seal + (800.0 - COULOMB) * stribeck, rel=1e-12)
    assert -effort[0] > 799.0 + seal  # breakaway: F_s + F_p (1 254 N, of which the seals' 454 N)
    fast, _ = m.friction_effort(np.array([-5.0]), p)
    assert fast[0] == pytest.approx(COULOMB + seal, rel=1e-9)  # sliding: F_c + F_p, opposing the motion
    for v in (-0.3, -2e-4, 0.0, 7e-4, 0.02):
        for k, o in zip(m.friction_effort(np.array([v]), p), ref.friction_effort(m, np.array([v]), p)):
            np.testing.assert_allclose(k, o, rtol=1e-12, atol=1e-9)
    # a chamber below ambient presses no seal
    p[m.node("rod")] = 0.5e5
    assert -m.friction_effort(np.array([5.0]), p)[0][0] == pytest.approx(COULOMB + KP * 8e6 * AREA, rel=1e-12)


def test_law_derivatives():
    """dF_f/dv and dF_f/dF_p of the law against central differences; F_p's slopes are k_p·A of the pressed chambers."""
    args = (500.0, 800.0, 0.01, 2000.0)
    for v in (-0.2, -1e-3, 0.0, 2e-4, 0.005):
        f, df, dload = laws.friction_force_with_derivative(v, *args, 300.0)
        h = 1e-3
        numeric = (laws.friction_force_with_derivative(v, *args, 300.0 + h)[0]
                   - laws.friction_force_with_derivative(v, *args, 300.0 - h)[0]) / (2 * h)
        assert dload == pytest.approx(numeric, rel=1e-7, abs=1e-12)


def test_linearization_holds_the_friction_pressure_dependence():
    """∂effort/∂v⁺ of the implicit stepper equals the finite difference of its efforts with the seal friction's
    pressure dependence (k_p = 0.05 on the lift's 50/28 mm cylinder, F_c = 150 N), which moves it by more than 1 %."""
    text = (MODELS / "lift_1dof" / "lift.circuit.toml").read_text()
    gradients = []
    for kp in (0.05, 0.0):
        edited = text.replace('type = "cylinder"', f'type = "cylinder"\nfriction_pressure_coefficient = {kp}', 1)
        m = NetworkModel.from_circuit(parse_circuit(tomllib.loads(edited), "lift"))
        state = m.state(actuator_position=[0.2], node_pressure=np.array([1.01325e5, 1.5e7, 8e6, 2e6]))
        stepper = STEPPERS["implicit_euler"](m)
        control = m.control(valve=0.6)
        dt, v, dv = 1e-3, 0.05, 1e-6
        lin = stepper.linearize(state, control, np.array([v]), dt)
        plus = stepper.linearize(state, control, np.array([v + dv]), dt).effort
        minus = stepper.linearize(state, control, np.array([v - dv]), dt).effort
        assert lin.effort_velocity_gradient[0, 0] == pytest.approx((plus - minus)[0] / (2 * dv), rel=1e-4)
        gradients.append(lin.effort_velocity_gradient[0, 0])
    assert abs(gradients[0] / gradients[1] - 1.0) > 0.01


def test_incompressible_fidelity_refuses_pressure_dependent_friction():
    with pytest.raises(CircuitError, match="component 'lift', field 'friction_pressure_coefficient'"):
        NetworkModel.from_circuit(parse_circuit(tomllib.loads(_circuit(1e6)), "c.toml"), fidelity="incompressible")
    NetworkModel.from_circuit(parse_circuit(tomllib.loads(_circuit(1e6, kp=0.0)), "c.toml"), fidelity="incompressible")


def steady_state(source, fluid, kp=KP):
    """(v [m/s], p [Pa gauge]) of the module docstring's steady motion with the source at ``source`` [Pa gauge]."""
    vreg = FRICTION_REGULARISATION_VELOCITY

    def pressure(v):  # the force balance solved for p
        t = math.tanh(v / vreg)
        return (MASS * G + COULOMB * t) / (AREA * (1.0 - kp * t))

    def residual(v):
        p = pressure(v)
        return AREA * v * float(fluid.fill_ratio(fluid.reference_pressure + p)[0]) - orifice_textbook(ORIFICE, CD, source - p, fluid)

    v = brentq(residual, 0.0, 1.0, xtol=1e-15, rtol=1e-13)
    return v, pressure(v)


def _run(tmp_path, mode, source):
    (tmp_path / "lift.xml").write_text(vertical_lift(mass=MASS, inertia=0.1, gravity=G))
    (tmp_path / "lift.circuit.toml").write_text(_circuit(source))
    path = tmp_path / "lift.scenario.toml"
    path.write_text(f'[scene]\nmjcf = "lift.xml"\ncircuit = "lift.circuit.toml"\n[run]\nmode = "{mode}"\n'
                    'dt = 0.001\nduration = 0.8\n[initial]\nqpos = { z = 0.55 }\nequilibrium = true\n[log]\nrate_hz = 200\n')
    result = run(path, out=tmp_path / "run.mcap", progress=False)
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    cyl, nodes = log.topic("/hydroplant/cylinders/lift"), log.topic("/hydroplant/nodes")
    window = cyl.t >= 0.4
    speed = float(np.polyfit(cyl.t[window], cyl["position_m"][window], 1)[0])
    fluid = load_circuit(tmp_path / "lift.circuit.toml").fluid
    p_cap = float(np.mean(nodes["pressure_pa.cap"][nodes.t >= 0.4])) - fluid.reference_pressure
    return speed, p_cap, fluid


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_a_load_below_breakaway_is_held_at_the_regularised_creep(tmp_path, mode):
    """Source at 0.9·p_b (11.9 bar): the load creeps up at v_reg·artanh(…) = 0.682 mm/s within 1e-4 (the
    friction without its pressure term would give 0.922 mm/s; measured 4e-11 MuJoCo, 6e-9 PBD), the cap at the
    force balance's pressure within 1e-6 (measured 2e-11)."""
    source = 0.9 * BREAKAWAY
    speed, p_cap, fluid = _run(tmp_path, mode, source)
    v, p = steady_state(source, fluid)
    v_plain, _ = steady_state(source, fluid, kp=0.0)
    assert 0.5e-3 < v < 0.9e-3 and v_plain > 1.3 * v
    assert speed == pytest.approx(v, rel=1e-4), (speed, v)
    assert p_cap == pytest.approx(p, rel=1e-6), (p_cap, p)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_above_breakaway_the_rod_slides_at_the_pressure_raised_friction(tmp_path, mode):
    """Source at 2·p_b: the cap sits at p_b = (m·g + F_c)/(A·(1 − k_p)) = 13.2 bar within 1e-6 (12.5 bar without
    the pressure term; measured 3e-14 MuJoCo, 5e-11 PBD) and the rod rises at the orifice law's speed, 39.2 mm/s,
    within 1e-4 (40.2 mm/s without; measured 3e-14, 2e-11)."""
    source = 2.0 * BREAKAWAY
    speed, p_cap, fluid = _run(tmp_path, mode, source)
    v, p = steady_state(source, fluid)
    assert p == pytest.approx(BREAKAWAY, rel=1e-9) and v > 0.02
    assert p_cap == pytest.approx(BREAKAWAY, rel=1e-6), (p_cap, BREAKAWAY)
    assert speed == pytest.approx(v, rel=1e-4), (speed, v)
