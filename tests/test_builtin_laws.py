"""The network's built-in branch kinds as law components: relief valves, check valves, fixed orifices, the laminar
resistances of hose lines and actuator leaks and the fixed and compensated pumps each have their law once, in their
module, and reach the network only through the law dispatch (:data:`hydraulics.components.BRANCH_LAWS`).

* Each law against the textbook formulas (``tests/reference/laws.py``: the relief's C¹ ramp, the check valve's
  linear opening through the orifice law in its textbook form, Hagen–Poiseuille) to 1e-12 relative, its terminal
  derivatives against central differences, no pilot derivative.
* The pumps' law (its shaft speed a scheduled input) against η_v·D·n and the compensator's linear destroking, to
  1e-12 relative; ∂Q/∂p_out against central differences; the kink hook's pieces; in a network, the pump's speed
  comes from the control vector by the pump's name and its power is pump work (``SOURCE``), not dissipation.
* In a network: the branch flows of a small rig (supply → check → volume → relief, fixed orifice and a π-line hose
  to tank) equal those formulas at any pressures; the relief's law piece switches where it cracks; the relief's
  settings are readable from the model (``relief_branches``, ``relief_cracking``, ``relief_gradient``).
"""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from hydraulics.circuit import parse_circuit
from hydraulics.components import CheckValve, LaminarResistance, Orifice, PumpCompensated, PumpFixed, ReliefValve
from hydraulics.components.pumps import law_piece as pump_piece
from hydraulics.components.relief import REGULARISATION
from hydraulics.fluid import Fluid
from hydraulics.network import NetworkModel
from reference import laws
from reference.circuits import bench, orifice, pump_into_volume

FLUID = Fluid(density=870.0, kinematic_viscosity=4.6e-5, reference_pressure=1.01325e5)
RELIEF = ReliefValve(cracking_pressure=5e6, gradient=1e-10)
CHECK = CheckValve(cracking_pressure=2e4, full_open_pressure=2e5, area=1e-5, leakage_area=1e-10)
ORIFICE = Orifice(area=1e-6, discharge_coefficient=0.62)
LAMINAR = LaminarResistance(conductance=3e-12)


def relief_by_hand(dp):
    return laws.relief_flow_with_derivative(dp, RELIEF.cracking_pressure, RELIEF.gradient,
                                            REGULARISATION * RELIEF.cracking_pressure)[0]


def check_by_hand(dp):
    area = laws.check_valve_area_with_derivative(dp, CHECK.cracking_pressure, CHECK.full_open_pressure, CHECK.area,
                                                 CHECK.leakage_area)[0]
    return laws.orifice_textbook(float(area), CHECK.discharge_coefficient, dp, FLUID)


CASES = [(RELIEF, relief_by_hand, [-1e6, 4.9e6, 5.0e6 + 2e3, 6e6]),  # closed, closed, blend, open
         (CHECK, check_by_hand, [-1e6, 1e4, 1e5, 1e6]),  # reverse (leakage), closed, opening, fully open
         (ORIFICE, lambda dp: laws.orifice_textbook(1e-6, 0.62, dp, FLUID), [-3e6, -10.0, 50.0, 2e6]),
         (LAMINAR, lambda dp: 3e-12 * dp, [-1e6, 1e5])]


@pytest.mark.parametrize("component, by_hand, drops", CASES, ids=lambda c: type(c).__name__ if hasattr(c, "PORTS") else "")
def test_law_equals_the_textbook_formula_with_its_derivatives(component, by_hand, drops):
    """Q(p_in, p_out) = the textbook value at Δp = p_in − p_out to 1e-12 relative; ∂Q/∂p_out = −∂Q/∂p_in, no pilot
    derivative, ∂Q/∂p_in against a central difference (step 1 Pa, inside each smooth piece)."""
    row = component.law_row(FLUID)
    law = type(component).BRANCH_LAW
    base = FLUID.reference_pressure
    for dp in drops:
        q, d_in, d_out, d_pilot = law(row, base + dp, base, 123.0)
        assert q == pytest.approx(float(by_hand(dp)), rel=1e-12, abs=1e-24)
        assert d_out == -d_in and d_pilot == 0.0
        numeric = (law(row, base + dp + 1.0, base, 0.0)[0] - law(row, base + dp - 1.0, base, 0.0)[0]) / 2.0
        assert d_in == pytest.approx(numeric, rel=1e-6, abs=1e-18)


RIG = bench(1.0e7) + """
[[component]]
name = "rig_volume"
type = "volume"
volume = 1.0e-4
ports = { port = "a" }

[[component]]
name = "relief"
type = "relief_valve"
cracking_pressure = 5.0e6
gradient = 1.0e-10
ports = { inlet = "a", outlet = "tank" }

[[component]]
name = "check"
type = "check_valve"
cracking_pressure = 2.0e4
full_open_pressure = 2.0e5
area = 1.0e-5
leakage_area = 1.0e-10
ports = { inlet = "supply", outlet = "a" }

[[component]]
name = "orifice"
type = "orifice"
area = 1.0e-6
discharge_coefficient = 0.62
ports = { a = "a", b = "b" }

[[component]]
name = "line"
type = "hose"
length = 2.0
inner_diameter = 0.01
ports = { a = "b", b = "tank" }
"""


@pytest.fixture(scope="module")
def rig():
    return NetworkModel.from_circuit(parse_circuit(tomllib.loads(RIG), "rig"), fidelity="lines")


def test_rig_flows_are_the_textbook_laws(rig):
    """Every branch of the rig carries its textbook flow at pressures on each piece of the relief and check laws."""
    m = rig
    assert m.branch_names[m.relief_branches] == ("relief",)
    assert m.relief_cracking.tolist() == [5e6] and m.relief_gradient.tolist() == [1e-10]
    viscosity = FLUID.density * FLUID.kinematic_viscosity
    line = laws.line_conductance(0.01, 2.0, viscosity)
    for p_a, p_b in ((3e6, 1e6), (1e7 - 1e5, 2e6), (9.99e6, 5e6)):
        p = np.full(m.node_count, FLUID.reference_pressure)
        p[m.node("supply")] = 1e7
        p[m.node("a")], p[m.node("b")] = p_a, p_b
        flows = m.branch_flows(p, m.valve_areas(np.zeros(0)), np.zeros(0), np.zeros(0))
        tank = FLUID.reference_pressure
        expected = {"relief": relief_by_hand(p_a - tank), "check": check_by_hand(1e7 - p_a),
                    "orifice": laws.orifice_textbook(1e-6, 0.62, p_a - p_b, FLUID),
                    "line.line": line * (p_b - tank)}
        got = dict(zip(m.branch_names, flows.flow))
        assert set(got) == set(expected)
        for name, value in expected.items():
            assert got[name] == pytest.approx(float(value), rel=1e-9, abs=1e-20), name


def test_relief_piece_switches_where_it_cracks(rig):
    """law_pieces of the relief branch: 0 below p_crack, 1 inside the blend width, 2 above it."""
    m = rig
    law = m.branch_slices["law"]
    j = m.relief_branches.start - law.start
    pieces = []
    for dp in (4.99e6, 5e6 + 0.5 * REGULARISATION * 5e6, 5.01e6):
        p = np.full(m.node_count, FLUID.reference_pressure)
        p[m.node("a")] += dp
        pieces.append(int(m.law_pieces(p)[j]))
    assert pieces == [0, 1, 2]
    assert math.isclose(m.law_parameter("relief_valve", "width")[0], REGULARISATION * 5e6)


FIXED = PumpFixed(displacement=1.2e-5, speed=40.0, volumetric_efficiency=0.95)
COMPENSATED = PumpCompensated(displacement=2e-5, speed=30.0, compensator_pressure=2e7, compensator_band=1e6)


@pytest.mark.parametrize("pump", [FIXED, COMPENSATED], ids=["fixed", "compensated"])
def test_pump_law_is_the_displacement_times_the_scheduled_speed(pump):
    """Q = η_v·D(p_out)·n with D(p_out) = D_max·clip((p_c + w − p_out)/w, 0, 1) (a fixed pump: p_c = inf, η_v its
    own) at the speed n passed as the law's input, to 1e-12 relative; only ∂Q/∂p_out is nonzero (central difference,
    1 Pa, inside each smooth piece); the kink hook numbers the pieces full (2), destroking (1), destroked (0)."""
    row, law = pump.law_row(FLUID), type(pump).BRANCH_LAW
    efficiency = getattr(pump, "volumetric_efficiency", 1.0)
    setting, band = getattr(pump, "compensator_pressure", math.inf), getattr(pump, "compensator_band", 1.0)
    base = FLUID.reference_pressure
    outlets = (base + 1e7, setting + 0.3 * band, setting + 2 * band) if math.isfinite(setting) else (base + 1e7, 3e7, 1e8)
    for speed in (pump.speed, 0.5 * pump.speed):
        inputs = np.array([speed])
        for p_out in outlets:
            displacement = laws.compensated_displacement_with_derivative(pump.displacement, p_out, setting, band)[0]
            q, d_in, d_out, d_pilot = law(row, base, p_out, 0.0, inputs)
            assert q == pytest.approx(float(laws.pump_flow(displacement, speed, efficiency)), rel=1e-12, abs=1e-24)
            assert d_in == 0.0 and d_pilot == 0.0
            numeric = (law(row, base, p_out + 1.0, 0.0, inputs)[0] - law(row, base, p_out - 1.0, 0.0, inputs)[0]) / 2
            assert d_out == pytest.approx(numeric, rel=1e-6, abs=1e-20)
    pieces = [pump_piece(row, row[:0], 0.0, base, p_out, 0.0) for p_out in outlets]
    assert pieces == ([2, 1, 0] if math.isfinite(setting) else [2, 2, 2])


def test_pump_in_a_network_reads_its_speed_by_name_and_is_a_source():
    """A fixed pump feeding a volume that an orifice drains to tank: its branch flow is D·n at the speed set by the
    pump's name (``control(pump=…)``), and the energy ledger books its power as pump work, the orifice's as loss."""
    from hydraulics.energy import branch_powers
    text = bench() + pump_into_volume(1.2e-5, 40.0, 1e-4) + orifice("orifice", "supply", "tank", 1e-6)
    m = NetworkModel.from_circuit(parse_circuit(tomllib.loads(text), "rig"))
    assert m.pump_names == ("pump",) and m.branch_names[m.pump_branches[0]] == "pump"
    pressure = np.full(m.node_count, FLUID.reference_pressure)
    pressure[m.node("supply")] += 5e6
    state = m.state(node_pressure=pressure)
    control = m.control(pump=25.0)
    flows = m.branch_flows(state.node_pressure, m.valve_areas(state.valve_spool), control.pump_speed,
                           state.actuator_velocity)
    q, drain = flows.flow[m.pump_branches[0]], flows.flow[m.branch_names.index("orifice")]
    assert q == pytest.approx(1.2e-5 * 25.0, rel=1e-12)
    powers = branch_powers(m, state, flows.flow)
    mu = m.fluid.pressure_potential(state.node_pressure)
    rise = mu[m.node("supply")] - mu[m.node("tank")]
    assert powers["pump"] == pytest.approx(q * rise, rel=1e-12)
    assert powers["dissipated"] == pytest.approx(drain * rise, rel=1e-12)
