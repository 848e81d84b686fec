"""The counterbalance valve (hydraulics/components/counterbalance.py): its law and its characteristic on a boom.

* The law against hand-derived values (the textbook form of the orifice law and of the smooth step, not the
  packed row) and its three terminal derivatives against central finite differences: held, relief stage part
  open and fully open, check stage part open and fully open, with and without back-pressure ratio.
* Load holding (tests/scenes/counterbalance_hold.scenario.toml, both modes): with the directional valve centred
  (open centre: the cap line is open to tank) the boom sinks over 2 s only as far as the valve's leakage lets it.
* Opening against the pilot (tests/scenes/counterbalance_lower.scenario.toml, both modes): the rod line
  (pilot) pressurises slowly; the load starts to lower (flow through the valve above 1 mm/s of rod) at the
  pilot pressure p_X = (p_set − p_L)/r, within the valve's band w/r, with p_L the load pressure at that instant,
  and then comes down.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hydraulics.circuit import load_circuit
from hydraulics.components import CounterbalanceValve
from hydraulics.components.counterbalance import flow_with_derivatives as counterbalance_law
from hydraulics.fluid import Fluid
from sim.io.mcap_log import read_log
from sim.run.runner import run
from reference.laws import orifice_textbook

SCENES = Path(__file__).parent / "scenes"
FLUID = Fluid(density=870.0, kinematic_viscosity=4.6e-5, reference_pressure=1.01325e5)
P0 = FLUID.reference_pressure


def step(z):
    return 0.0 if z <= 0 else 1.0 if z >= 1 else 3 * z**2 - 2 * z**3


def by_hand(valve, p_load, p_valve, p_pilot):
    """Q from load to valve: relief stage opened by p_L + r·p_X − r_b·p_V (gauge), check stage by p_V − p_L."""
    z = ((p_load - P0) + valve.pilot_ratio * (p_pilot - P0) - valve.back_pressure_ratio * (p_valve - P0)
         - valve.setting_pressure) / valve.opening_band
    z_check = (p_valve - p_load - valve.check_cracking_pressure) / valve.check_opening_band
    area = valve.leakage_area + valve.area * step(z) + valve.check_area * step(z_check)
    return orifice_textbook(area, valve.discharge_coefficient, p_load - p_valve, FLUID)


VALVES = [CounterbalanceValve(setting_pressure=1.3e7, pilot_ratio=4.0, opening_band=1e6, area=2e-5),
          CounterbalanceValve(setting_pressure=1.3e7, pilot_ratio=8.0, back_pressure_ratio=1.5, opening_band=2e6,
                              area=2e-5, check_area=4e-5, check_cracking_pressure=3e5, check_opening_band=5e5)]
# (p_load, p_valve, p_pilot) [Pa abs]: held at 100 bar (pilot vented), relief part open by the pilot, fully open,
# check stage part open (first valve; the second's still shut), part open (second valve), fully open, held close
# to the setting by the load alone
POINTS = [(P0 + 1e7, P0, P0), (P0 + 1e7, P0 + 1e5, P0 + 7.9e5), (P0 + 1e7, P0, P0 + 3e6),
          (P0 + 5e6, P0 + 5.2e6, P0), (P0 + 5e6, P0 + 5.5e6, P0), (P0 + 5e6, P0 + 8e6, P0 + 1e6),
          (P0 + 1.25e7, P0 + 2e5, P0)]


@pytest.mark.parametrize("valve", VALVES)
@pytest.mark.parametrize("point", POINTS)
def test_flow_equals_hand_derived_value(valve, point):
    """Q(p_L, p_V, p_X) equals the hand-derived value to 1e-12 relative (1e-22 m³/s absolute when shut)."""
    q = counterbalance_law(valve.law_row(FLUID), *point)[0]
    assert q == pytest.approx(by_hand(valve, *point), rel=1e-12, abs=1e-22)


def test_regimes():
    """Held without pilot (leakage only, < 2e-9 m³/s at 100 bar), opened by the pilot (> 1e-3 m³/s), free flow
    valve→load through the check stage; the part-open points really are inside the bands."""
    valve = VALVES[0]
    row = valve.law_row(FLUID)
    assert 0 < counterbalance_law(row, *POINTS[0])[0] < 2e-9
    assert counterbalance_law(row, *POINTS[2])[0] > 1e-3
    assert counterbalance_law(row, *POINTS[5])[0] < -1e-3  # valve → load
    assert 0 < counterbalance_law(row, *POINTS[6])[0] < 2e-9  # 125 bar against a 130 bar setting: held
    assert 0 < (1e7 + 4 * 7.9e5 - 1.3e7) / 1e6 < 1  # relief stage part open at POINTS[1]
    assert 0 < (2e5 - 1e5) / 2e5 < 1 and 0 < (5e5 - 3e5) / 5e5 < 1  # check stages part open at POINTS[3], [4]


@pytest.mark.parametrize("valve", VALVES)
@pytest.mark.parametrize("point", POINTS)
def test_derivatives_match_finite_differences(valve, point):
    """∂Q/∂p_L, ∂Q/∂p_V, ∂Q/∂p_X against central differences (step 1 Pa, well inside each smooth piece)."""
    row = valve.law_row(FLUID)
    derivatives = counterbalance_law(row, *point)[1:]
    scale = max(abs(d) for d in derivatives)
    for j in range(3):
        hi, lo = list(point), list(point)
        hi[j] += 1.0
        lo[j] -= 1.0
        numeric = (counterbalance_law(row, *hi)[0] - counterbalance_law(row, *lo)[0]) / 2.0
        assert derivatives[j] == pytest.approx(numeric, rel=1e-6, abs=1e-9 * scale), f"terminal {j}"


def test_pilot_derivative_is_the_ratio_times_the_load_derivative_of_the_relief_stage():
    """On the relief stage alone (check shut), ∂Q/∂p_X = r·(∂Q/∂p_L − ∂Q/∂Δp): the pilot acts r times as hard as the
    load pressure on the poppet."""
    valve = VALVES[0]
    row = valve.law_row(FLUID)
    _, d_load, d_valve, d_pilot = counterbalance_law(row, *POINTS[1])
    # d_load = Q_Δ + D_r, d_valve = −Q_Δ (r_b = 0): D_r = d_load + d_valve
    assert d_pilot == pytest.approx(valve.pilot_ratio * (d_load + d_valve), rel=1e-12)
    assert d_pilot > 0


def _run(tmp, scenario, mode):
    result = run(SCENES / scenario, out=tmp / f"{mode}.mcap", overrides={"mode": mode}, progress=False)
    assert result.status == "complete", result.message
    return read_log(result.log_path)


@pytest.fixture(scope="module")
def holds(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cbv_hold")
    return {mode: _run(tmp, "counterbalance_hold.scenario.toml", mode) for mode in ("mujoco", "pbd")}


@pytest.fixture(scope="module")
def lowers(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cbv_lower")
    return {mode: _run(tmp, "counterbalance_lower.scenario.toml", mode) for mode in ("mujoco", "pbd")}


def _valve():
    return load_circuit(SCENES / "counterbalance.circuit.toml").component("boom_cbv").params


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_holds_the_load_with_the_valve_centred(holds, mode):
    """The cap holds the load pressure with the cap line at tank; over 2 s the rod sinks by what the valve's
    leakage flow at that pressure drop displaces (between 0.5 and 1.5 times, ± 10 nm): 19 nm measured."""
    log = holds[mode]
    nodes = log.topic("/hydroplant/nodes")
    cylinder = log.topic("/hydroplant/cylinders/boom_cyl")
    valve = _valve()
    p_load, p_line = nodes["pressure_pa.boom_cyl_cap"], nodes["pressure_pa.boom_cbv_valve"]
    assert np.all(p_load - P0 > 4.5e6) and np.all(p_line - P0 < 2e5)  # the valve alone holds ~50 bar
    assert np.all(p_load - P0 < valve.setting_pressure)
    leak = orifice_textbook(valve.leakage_area, valve.discharge_coefficient, float(np.max(p_load - p_line)), FLUID)
    cap_area = math.pi * 0.063**2 / 4
    x = cylinder["position_m"]
    sink = x[0] - x[-1]
    leaked = leak / cap_area * (cylinder.t[-1] - cylinder.t[0])
    assert 0.5 * leaked - 1e-8 < sink < 1.5 * leaked + 1e-8, (sink, leaked)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_opens_at_the_pilot_pressure_of_its_setting(lowers, mode):
    """The first logged sample where the valve passes more than 1 mm/s of rod (A_cap·1e-3 m³/s) from the load:
    there p_X lies in [(p_set − p_L)/r, (p_set − p_L + w)/r]; before it the rod has moved < 0.2 mm (oil
    compression only); by the end the load has come down by more than 2 cm."""
    log = lowers[mode]
    valve = _valve()
    nodes = log.topic("/hydroplant/nodes")
    flows = log.topic("/hydroplant/flows")
    cylinder = log.topic("/hydroplant/cylinders/boom_cyl")
    cap_area = math.pi * 0.063**2 / 4
    q = flows["flow_m3ps.boom_cbv"]
    opening = int(np.argmax(q > cap_area * 1e-3))
    assert opening > 0 and q[opening] > cap_area * 1e-3
    t_open = flows.t[opening]
    k = int(np.searchsorted(nodes.t, t_open))
    p_load = nodes["pressure_pa.boom_cyl_cap"][k] - P0
    p_pilot = nodes["pressure_pa.boom_cyl_rod"][k] - P0
    predicted = (valve.setting_pressure - p_load) / valve.pilot_ratio
    assert predicted < p_pilot < predicted + valve.opening_band / valve.pilot_ratio, (p_pilot, predicted)
    x = cylinder["position_m"]
    j = int(np.searchsorted(cylinder.t, t_open))
    assert x[0] - x[j] < 2e-4
    assert x[j] - x[-1] > 0.02
