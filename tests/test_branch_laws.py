"""Components that bring their own branch law: a three-port pilot-operated check valve and a two-port one-way
flow control valve, each one module plus its registry line (``hydraulics/components/``).

* Laws against hand-derived values (the textbook form of the orifice law, Q = C_d·A·sqrt(2/ρ)·Δp/(Δp² + p_tr²)^¼
  with p_tr = (ρ/2)·(Re_c·ν/(C_d·D_h))², not the packed k, c form) and their three terminal derivatives against
  central finite differences, on closed, opening and fully open poppets in both flow directions.
* A load-holding cylinder: with the valve centred the pilot-operated check valve holds the load (no sinking
  beyond the oil column's compression); commanded to lower, the pilot opens it and the load goes down.  The
  numpy oracle stepper (tests/reference/newton.py) and the package stepper give the same trajectory to round-off (the pilot terminal enters both
  Jacobians).
* Nothing outside the component's module and the registry names it.
"""

from __future__ import annotations

import math
import re
import tomllib

import numpy as np
import pytest

from conftest import ROOT
from hydraulics.circuit import parse_circuit
from hydraulics.components import (BRANCH_LAWS, COMPONENT_TYPES, CheckValve, LaminarResistance, Motor, Orifice,
                                   PilotCheckValve, PumpCompensated, PumpFixed, ReliefValve, ThrottleCheckValve)
from hydraulics.components.pilot_check import flow_with_derivatives as pilot_check_law
from hydraulics.components.throttle_check import flow_with_derivatives as throttle_check_law
from hydraulics.fluid import Fluid
from hydraulics.load import MassLoad, simulate
from hydraulics.network import NetworkModel
from reference.laws import orifice_textbook
from reference.circuits import bench

FLUID = Fluid(density=870.0, kinematic_viscosity=4.6e-5, reference_pressure=1.01325e5)


def pilot_check_by_hand(valve, p_a, p_b, p_x):
    z = (valve.pilot_area_ratio * (p_x - FLUID.reference_pressure) + p_a - p_b - valve.cracking_pressure) / valve.opening_band
    y = 0.0 if z <= 0 else 1.0 if z >= 1 else 3 * z**2 - 2 * z**3
    return orifice_textbook(valve.leakage_area + valve.area * y, valve.discharge_coefficient, p_a - p_b, FLUID)


VALVE = PilotCheckValve(cracking_pressure=2e5, opening_band=1e6, pilot_area_ratio=3.0, area=1e-5, leakage_area=1e-11)
# (p_a, p_b, p_x) [Pa]: reverse flow closed (no pilot), reverse flow piloted part open, fully open, forward free flow
# just above cracking, forward fully open
POINTS = [(2e6, 1e7, 1.01325e5), (2e6, 1e7, 2.9e6), (2e6, 1e7, 4e6), (1.3e6, 1e6, 1.01325e5), (9e6, 1e6, 1.01325e5)]


@pytest.mark.parametrize("point", POINTS)
def test_pilot_check_flow_equals_hand_derived_value(point):
    """Q(p_a, p_b, p_x) equals the hand-derived value to 1e-12 relative (1e-22 m³/s absolute when shut)."""
    q = pilot_check_law(VALVE.law_row(FLUID), *point)[0]
    assert q == pytest.approx(pilot_check_by_hand(VALVE, *point), rel=1e-12, abs=1e-22)


def test_pilot_check_regimes():
    """Closed without pilot (leakage only), opened by the pilot, free flow a→b above cracking."""
    row = VALVE.law_row(FLUID)
    closed = pilot_check_law(row, *POINTS[0])[0]
    piloted = pilot_check_law(row, *POINTS[2])[0]
    assert -1e-8 < closed < 0 and piloted < 1e4 * closed  # reverse flow: b → a
    z = (3.0 * (2.9e6 - 1.01325e5) + 2e6 - 1e7 - 2e5) / 1e6  # 0.196: the part-open point
    assert 0 < z < 1
    assert pilot_check_law(row, *POINTS[4])[0] > 1e-4  # forward: free flow


@pytest.mark.parametrize("point", POINTS)
def test_pilot_check_derivatives_match_finite_differences(point):
    """∂Q/∂p_a, ∂Q/∂p_b, ∂Q/∂p_x against central differences (step 1 Pa, well inside each smooth piece)."""
    row = VALVE.law_row(FLUID)
    derivatives = pilot_check_law(row, *point)[1:]
    step = 1.0  # Pa
    for j in range(3):
        hi, lo = list(point), list(point)
        hi[j] += step
        lo[j] -= step
        numeric = (pilot_check_law(row, *hi)[0] - pilot_check_law(row, *lo)[0]) / (2 * step)
        scale = max(abs(d) for d in derivatives)
        assert derivatives[j] == pytest.approx(numeric, rel=1e-6, abs=1e-9 * scale), f"terminal {j}"


def test_throttle_check_is_a_two_port_law_with_hand_values_and_derivatives():
    """The two-port component: free flow a→b through check and throttle, metered flow b→a through the throttle
    only; no pilot derivative; derivatives against central differences."""
    valve = ThrottleCheckValve(throttle_area=1e-6, area=1e-4, cracking_pressure=1e4, full_open_pressure=1e5)
    row = valve.law_row(FLUID)
    q, d_a, d_b, d_x = throttle_check_law(row, 1e6, 0.0, 123.0)
    assert q == pytest.approx(orifice_textbook(1e-6 + 1e-4, 0.7, 1e6, FLUID), rel=1e-12)
    assert d_x == 0.0 and d_b == -d_a
    assert throttle_check_law(row, 0.0, 1e6, 0.0)[0] == pytest.approx(orifice_textbook(1e-6, 0.7, -1e6, FLUID), rel=1e-12)
    for dp in (-1e6, 3e4, 2e6):
        g = throttle_check_law(row, dp, 0.0, 0.0)[1]
        numeric = (throttle_check_law(row, dp + 1.0, 0.0, 0.0)[0] - throttle_check_law(row, dp - 1.0, 0.0, 0.0)[0]) / 2.0
        assert g == pytest.approx(numeric, rel=1e-6)


# Law components that other code names, and why: the network makes the laminar resistances (hose lines, actuator
# leaks); the relief valves' settings bound the pressures (the stability guards, the run monitor and the
# incompressible level read NetworkModel.relief_cracking and relief_gradient, which network.py derives from the law
# rows; the scene check compares holding pressures with them); the throttle-check valve is a check valve whose
# closed area is the throttle (it calls the check valve's law).
# The pumps: their shaft speed is the vocabulary of the scheduled inputs (its range in the scenario, controllers, live
# play and the generated docs; the pump kinds in the scenario), the network reads their parameters
# (``NetworkModel.pump_displacement`` …) and the motors' torque is the pump module's ideal machine torque.
_PUMP_USERS = {"hydraulics/network.py", "hydraulics/_compiled.py", "sim/io/scenario.py"}
ALSO_NAMED_BY = {LaminarResistance: {"hydraulics/network.py"},
                 ReliefValve: {"hydraulics/network.py", "sim/tools/check.py"},
                 CheckValve: {"hydraulics/components/throttle_check.py"},
                 PumpFixed: _PUMP_USERS | {"hydraulics/circuit.py", "sim/plants/controllers.py", "sim/tools/docgen.py",
                                           "sim/run/play.py"},
                 PumpCompensated: _PUMP_USERS,
                 Motor: {"sim/run/recorder.py"}}  # (its log fields' descriptions: "Motor shaft angle [rad]", …)
# Law components whose module and type name are shared vocabulary: the orifice module is the law of every metering
# edge and poppet, and "orifice" is also the branch kind of the valves' metering edges; "motor" is also an actuator
# kind (its torque, its ledger of shaft work, its logs); only the class is checked.
CLASS_ONLY = (Orifice, Motor)


def test_each_component_lives_in_its_module_and_registry_line():
    """The package names each law-branch component (its class, its module in an import, its type in quotes) only
    in its own module and in the registry's module (and the files :data:`ALSO_NAMED_BY` lists)."""
    for cls in BRANCH_LAWS:
        module = cls.__module__.rsplit(".", 1)[1]
        kind = next((name for name, c in COMPONENT_TYPES.items() if c is cls), None)  # None: no circuit-file type
        pattern = rf"\b{cls.__name__}\b"
        if cls not in CLASS_ONLY:
            pattern += rf"|(import|from) \S*\b{module}\b|\.{module} import"
            pattern += rf"|[\"']{kind}[\"']" if kind else ""
        users = {path.relative_to(ROOT).as_posix() for package in ("hydraulics", "sim")
                 for path in (ROOT / package).rglob("*.py")
                 if re.search(pattern, path.read_text(encoding="utf-8"))}
        expected = {f"hydraulics/components/{module}.py", "hydraulics/components/__init__.py"}
        assert users == expected | ALSO_NAMED_BY.get(cls, set()), cls.__name__


CIRCUIT = bench(1.0e7) + """
[[component]]
name = "valve"
type = "valve_4_3"
max_area = 1.0e-5
leakage_area = 0.0
time_constant = 0.01
ports = { P = "supply", T = "tank", A = "line_a", B = "line_b" }

[[component]]
name = "line_a_volume"
type = "volume"
volume = 2.0e-4
ports = { port = "line_a" }

[[component]]
name = "hold"
type = "pilot_check_valve"
area = 2.0e-5
pilot_area_ratio = 3.0
leakage_area = 1.0e-12
ports = { a = "line_a", b = "cap", pilot = "line_b" }

[[component]]
name = "cylinder"
type = "cylinder"
bore = 0.05
rod_diameter = 0.03
stroke = 0.5
dead_volume_cap = 1.0e-5
dead_volume_rod = 1.0e-5
ports = { cap = "cap", rod = "line_b" }
"""
MASS = 1000.0  # kg, hanging on the rod: the cap side holds it
G = 9.81  # m/s²


def _load_holding(stepper, command):
    model = NetworkModel.from_circuit(parse_circuit(tomllib.loads(CIRCUIT), "load-holding"))
    pressure = np.full(model.node_count, FLUID.reference_pressure)
    cap_area = math.pi * 0.05**2 / 4
    pressure[model.node("cap")] += MASS * G / cap_area  # statics: the cap pressure carries the load
    pressure[model.node("supply")] = 1.0e7
    state = model.state(actuator_position=np.array([0.25]), node_pressure=pressure)
    load = MassLoad(actuator="cylinder", mass=MASS, force=-MASS * G)
    return model, simulate(model, load, state, dt=1e-3, duration=0.6, stepper=stepper, substeps=4,
                           inputs={"valve": lambda t: command if t >= 0.1 else 0.0})


@pytest.fixture(scope="module")
def runs():
    from reference.newton import StepperImplicitEulerOracle

    return {(name, command): _load_holding(stepper, command)
            for name, stepper in (("numpy", StepperImplicitEulerOracle), ("compiled", "implicit_euler"))  # 4 substeps: the poppet opens within a step
            for command in (0.0, -1.0)}


def test_pilot_check_holds_a_load_and_lowers_it_when_piloted(runs):
    """Valve centred: the cylinder creeps less than 1 µm over 0.5 s (leakage 1e-12 m²); valve at −1 (P→B, A→T):
    the rod-side pressure pilots the valve open and the load descends by more than 1 cm in 0.5 s."""
    model, held = runs["compiled", 0.0]
    assert held.status == "complete"
    settled = np.searchsorted(held.time, 0.1)
    assert abs(held.position[-1] - held.position[settled]) < 1e-6
    assert held.pressure(model, "cap")[-1] > 4e6 and held.pressure(model, "line_b")[-1] < 2e5  # held, not piloted
    model, lowered = runs["compiled", -1.0]
    assert lowered.status == "complete"
    assert lowered.position[-1] < lowered.position[settled] - 0.01
    assert lowered.pressure(model, "line_b")[-1] > 1e6  # the pilot pressure that opened it


@pytest.mark.parametrize("command", [0.0, -1.0])
def test_numpy_and_compiled_steppers_agree_with_a_pilot_terminal(runs, command):
    """Same trajectory to round-off: positions to 1e-9 m, pressures to 1e-7 relative, same Newton iterations."""
    (model, a), (_, b) = runs["numpy", command], runs["compiled", command]
    np.testing.assert_allclose(b.position, a.position, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.node_pressure, a.node_pressure, rtol=1e-7, atol=1e-3)
    np.testing.assert_array_equal(b.newton_iterations, a.newton_iterations)


def test_flow_jacobian_has_the_pilot_column(runs):
    """NetworkModel.flow_jacobian against central differences of the net inflow, pilot column included."""
    model, lowered = runs["compiled", -1.0]
    p = lowered.node_pressure[np.searchsorted(lowered.time, 0.2)].copy()
    pilot, cap, line_a = model.node("line_b"), model.node("cap"), model.node("line_a")
    # the pilot pressure that opens the poppet half-way (z = 1/2): ∂Q/∂p_pilot ≠ 0 there
    p[pilot] = FLUID.reference_pressure + (0.5 * 1e6 + 2e5 + p[cap] - p[line_a]) / 3.0
    spool = np.array([-1.0])
    control = model.control()
    areas = model.valve_areas(spool)
    v = np.zeros(model.actuator_count)
    flows = model.branch_flows(p, areas, control.pump_speed, v)
    jac = model.flow_jacobian(flows)
    assert jac[cap, pilot] != 0.0  # the cap's inflow depends on the pilot pressure
    for j in range(model.node_count):
        step = 1.0  # Pa
        hi, lo = p.copy(), p.copy()
        hi[j] += step
        lo[j] -= step
        numeric = (model.incidence @ model.branch_flows(hi, areas, control.pump_speed, v).flow
                   - model.incidence @ model.branch_flows(lo, areas, control.pump_speed, v).flow) / (2 * step)
        np.testing.assert_allclose(jac[:, j], numeric, rtol=1e-5, atol=1e-9 * np.abs(jac).max())
