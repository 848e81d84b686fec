"""The pressure-reducing valve (hydraulics/components/pressure_reducing.py): its law and its characteristic.

* The law against hand-derived values (textbook orifice law and smooth step) and its derivatives against
  central finite differences: fully open, regulating, shut, reverse flow.
* Held outlet pressure (network): inlet at 120–250 bar, a load orifice from the outlet to tank drawing 0–20 L/min,
  a held cylinder on the outlet (the network keeps the nets an actuator reaches); the implicit stepper's steady
  state (hydraulics.equilibrium.steady_state) holds the outlet inside the regulation band [p_set − w, p_set] and equals
  the law's own fixed point (scalar root of Q_valve = Q_load) to 100 Pa.
* On the boom (tests/scenes/reducing_lift.scenario.toml, both modes): lifted to its top stop through the valve,
  the cap stays at the reduced pressure while the supply is at the 200 bar relief.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from hydraulics.circuit import load_circuit, parse_circuit
from hydraulics.components import PressureReducingValve
from hydraulics.components.pressure_reducing import flow_with_derivatives as reducing_law
from hydraulics.equilibrium import steady_state
from hydraulics.fluid import Fluid
from hydraulics.network import NetworkModel
from sim.io.mcap_log import read_log
from sim.run.runner import run
from reference.laws import orifice_textbook
from reference.circuits import bench

SCENES = Path(__file__).parent / "scenes"
FLUID = Fluid(density=870.0, kinematic_viscosity=4.6e-5, reference_pressure=1.01325e5)
P0 = FLUID.reference_pressure


def by_hand(valve, p_in, p_out):
    z = (valve.setting_pressure - (p_out - P0)) / valve.regulation_band
    y = 0.0 if z <= 0 else 1.0 if z >= 1 else 3 * z**2 - 2 * z**3
    return orifice_textbook(valve.leakage_area + valve.area * y, valve.discharge_coefficient, p_in - p_out, FLUID)


VALVE = PressureReducingValve(setting_pressure=9e6, regulation_band=5e5, area=1.5e-5)
# (p_in, p_out) [Pa abs]: fully open, regulating (z = 0.3), shut, reverse flow fully open, reverse flow shut
POINTS = [(P0 + 2e7, P0 + 5e6), (P0 + 2e7, P0 + 8.85e6), (P0 + 2e7, P0 + 9.2e6), (P0 + 2e6, P0 + 5e6),
          (P0 + 5e6, P0 + 9.5e6)]


@pytest.mark.parametrize("point", POINTS)
def test_flow_equals_hand_derived_value_and_derivatives_match(point):
    """Q equals the hand-derived value to 1e-12 relative; ∂Q/∂p_in, ∂Q/∂p_out against central differences (1 Pa);
    no pilot terminal."""
    row = VALVE.law_row(FLUID)
    q, d_in, d_out, d_x = reducing_law(row, *point, 0.0)
    assert q == pytest.approx(by_hand(VALVE, *point), rel=1e-12, abs=1e-22)
    assert d_x == 0.0
    scale = max(abs(d_in), abs(d_out))
    numeric_in = (reducing_law(row, point[0] + 1.0, point[1], 0.0)[0] - reducing_law(row, point[0] - 1.0, point[1], 0.0)[0]) / 2
    numeric_out = (reducing_law(row, point[0], point[1] + 1.0, 0.0)[0] - reducing_law(row, point[0], point[1] - 1.0, 0.0)[0]) / 2
    assert d_in == pytest.approx(numeric_in, rel=1e-6, abs=1e-9 * scale)
    assert d_out == pytest.approx(numeric_out, rel=1e-6, abs=1e-9 * scale)


def test_regulating_valve_closes_with_outlet_pressure():
    """Regulating: raising the outlet pressure closes the valve faster than the orifice alone (∂Q/∂p_out < −∂Q/∂p_in)."""
    _, d_in, d_out, _ = reducing_law(VALVE.law_row(FLUID), *POINTS[1], 0.0)
    assert d_in > 0 and d_out < -5 * d_in


CIRCUIT = """
[[component]]
name = "reducer"
type = "pressure_reducing_valve"
setting_pressure = 9.0e6
regulation_band = 5.0e5
area = 1.5e-5
ports = {{ inlet = "supply", outlet = "reduced" }}

[[component]]
name = "cylinder"
type = "cylinder"
bore = 0.05
rod_diameter = 0.03
stroke = 0.5
ports = {{ cap = "reduced", rod = "tank" }}

[[component]]
name = "consumer"
type = "orifice"
area = {load_area}
ports = {{ a = "reduced", b = "tank" }}
"""


@pytest.mark.parametrize("p_in", [1.2e7, 1.6e7, 2.5e7])
@pytest.mark.parametrize("load_area", [1e-9, 1e-6, 3e-6])
def test_outlet_pressure_held_over_inlet_pressure_and_flow(p_in, load_area):
    """Steady outlet inside [p_set − w, p_set] (gauge) for inlets 120–250 bar and loads drawing up to 20 L/min,
    and equal to the root of Q_valve(p_in, p_out) = Q_orifice(p_out − p_tank) to 100 Pa."""
    text = bench(P0 + p_in) + CIRCUIT.format(load_area=load_area)
    model = NetworkModel.from_circuit(parse_circuit(tomllib.loads(text), "reducing"))
    state = model.state(node_pressure=np.full(model.node_count, P0))
    steady = steady_state(model, model.control(), state, pinned={})
    p_out = steady.node_pressure[model.node("reduced")]
    assert VALVE.setting_pressure - VALVE.regulation_band < p_out - P0 < VALVE.setting_pressure
    row = VALVE.law_row(FLUID)

    def balance(p):
        return reducing_law(row, P0 + p_in, p, 0.0)[0] - orifice_textbook(load_area, 0.7, p - P0, FLUID)

    root = brentq(balance, P0 + 1.0, P0 + VALVE.setting_pressure, xtol=1e-3)
    assert p_out == pytest.approx(root, abs=100.0)
    flow = orifice_textbook(load_area, 0.7, p_out - P0, FLUID)
    assert flow < 3.4e-4 and (load_area < 3e-6 or flow > 2.9e-4)  # the widest load draws 17–20 L/min


@pytest.fixture(scope="module")
def lifts(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("reducing")
    out = {}
    for mode in ("mujoco", "pbd"):
        result = run(SCENES / "reducing_lift.scenario.toml", out=tmp / f"{mode}.mcap", overrides={"mode": mode},
                     progress=False)
        assert result.status == "complete", result.message
        out[mode] = read_log(result.log_path)
    return out


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_boom_at_its_stop_holds_the_reduced_pressure(lifts, mode):
    """Lifting, the valve limits the cap to its band (the boom accelerates on 85–90 bar instead of 200); after the
    rod reaches its top stop (last 0.3 s) the cap stays within [p_set − w, p_set + w/10] while the supply is at the
    relief (> 195 bar).  Above p_set the valve is shut: the excess (measured 0.2 bar) is the shut-in oil compressed as
    the rod settles back from its overshoot into the soft end stop."""
    valve = load_circuit(SCENES / "reducing.circuit.toml").component("boom_prv").params
    nodes = lifts[mode].topic("/hydroplant/nodes")
    cap = nodes["pressure_pa.boom_cyl_cap"] - P0
    lifting = (nodes.t >= 0.15) & (nodes.t <= 0.3)
    assert np.all(cap[lifting] > valve.setting_pressure - 2 * valve.regulation_band)
    assert np.all(cap[lifting] < valve.setting_pressure)
    late = nodes.t >= 0.5
    assert np.all(cap[late] > valve.setting_pressure - valve.regulation_band)
    assert np.all(cap[late] < valve.setting_pressure + 0.1 * valve.regulation_band)
    assert np.all(nodes["pressure_pa.supply"][late] - P0 > 1.95e7)
