"""Load sensing: the load-sensing pump (a component with a state, its swash plate) and the pressure compensator
(a three-port law), each one module and a registry line.

* The pump's law: the swash plate integrates the regulator error (margin or cut-off, whichever is lower) at a
  rate limited by its stroke time; the total derivatives of the end-of-step flow against central differences;
  saturation at the plate's ends and the regulator's band; the end state equals the law's.
* The compensator's law against the hand-derived regulated orifice with the load pressure as reference, its three
  derivatives against central differences.
* The boom on a load-sensing pump with a pre-compensated section (tests/scenes/ls_lift.scenario.toml), both modes:
  while lifting (from 0.4 s after the spool opened; the load pressure still swings between 40 and 85 bar as the
  boom bounces on its oil column), the supply stands the margin above the LS line within 10 % and the metering
  edge's drop stays inside the compensator's band; the pump's work enters the energy ledger as pump work and the balance closes.
* The load-sensing excavator (models/excavator/dig_ls.scenario.toml), both modes: the whole dig completes with the
  margin regulated (median at the setting, 85 % of the regulating samples within 10 %).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT
from hydraulics.circuit import load_circuit
from hydraulics.components import PressureCompensator, PumpLoadSensing
from hydraulics.components.pressure_compensator import flow_with_derivatives as compensator_law
from hydraulics.components.pump_load_sensing import flow_with_derivatives as pump_law
from hydraulics.components.pump_load_sensing import step_end
from hydraulics.fluid import Fluid
from sim.io.mcap_log import read_log
from sim.run.runner import run
from reference.laws import orifice_textbook

SCENES = Path(__file__).parent / "scenes"
FLUID = Fluid(density=870.0, kinematic_viscosity=4.6e-5, reference_pressure=1.01325e5)
P0 = FLUID.reference_pressure
PUMP = PumpLoadSensing(displacement=1.2e-5, speed=40.0, margin=2e6, cutoff_pressure=2e7, regulator_band=5e5,
                       stroke_time=0.05)


def swash_by_hand(alpha, h, p_in, p_out, p_ls):
    error = min(p_ls + PUMP.margin - p_out, PUMP.cutoff_pressure - (p_out - p_in))
    rate = np.clip(error / PUMP.regulator_band, -1, 1) / PUMP.stroke_time
    return float(np.clip(alpha + h * rate, 0, 1))


# (alpha, p_out, p_ls) [-, Pa]: in the band below the margin, above it, saturated low, cut-off active, at the end
POINTS = [(0.4, P0 + 1.19e7, P0 + 1e7), (0.4, P0 + 1.21e7, P0 + 1e7), (0.4, P0 + 5e6, P0 + 1e7),
          (0.4, P0 + 1.999e7, P0 + 1.95e7), (0.999, P0 + 1.19e7, P0 + 1e7)]


@pytest.mark.parametrize("point", POINTS)
def test_pump_law_equals_hand_value_and_its_derivatives(point):
    alpha, p_out, p_ls = point
    row, h = PUMP.law_row(FLUID), 1e-3
    state = np.array([alpha])
    q, d_in, d_out, d_ls = pump_law(row, state, h, P0, p_out, p_ls)
    rate = PUMP.displacement * PUMP.speed
    assert q == pytest.approx(rate * swash_by_hand(alpha, h, P0, p_out, p_ls), rel=1e-14)
    for k, d in ((0, d_in), (1, d_out), (2, d_ls)):
        up, down = [P0, p_out, p_ls], [P0, p_out, p_ls]
        up[k] += 1.0
        down[k] -= 1.0
        numeric = (pump_law(row, state, h, *up)[0] - pump_law(row, state, h, *down)[0]) / 2
        assert d == pytest.approx(numeric, rel=1e-6, abs=1e-18)
    end = np.empty(1)
    step_end(row, state, h, P0, p_out, p_ls, end)
    assert end[0] == swash_by_hand(alpha, h, P0, p_out, p_ls)


def test_pump_holds_the_margin_in_steady_state():
    """With the outlet exactly the margin above the LS line the swash plate stays where it is."""
    row, state = PUMP.law_row(FLUID), np.array([0.37])
    end = np.empty(1)
    step_end(row, state, 0.1, P0, P0 + 1.2e7, P0 + 1e7, end)
    assert end[0] == 0.37


def test_pump_kink_hook_numbers_regulator_and_cutoff():
    from hydraulics.components.pump_load_sensing import law_piece
    row, state = PUMP.law_row(FLUID), np.array([0.4])
    inside = law_piece(row, state, 1e-3, P0, P0 + 1.2e7, P0 + 1e7)
    starved = law_piece(row, state, 1e-3, P0, P0 + 5e6, P0 + 1e7)
    cut = law_piece(row, state, 1e-3, P0, P0 + 2e7 + 1e5, P0 + 1.95e7)
    assert (inside, starved, cut) == (3 + 1, 6 + 1, 9 + 3 + 1)


COMPENSATOR = PressureCompensator(pressure_difference=1e6, regulation_band=2e5, area=3e-5)
# (p_in, p_out, p_load): open (outlet 5 bar above the load), regulating, shut, reverse
CPOINTS = [(P0 + 1.5e7, P0 + 1.05e7, P0 + 1e7), (P0 + 1.5e7, P0 + 1.09e7, P0 + 1e7), (P0 + 1.5e7, P0 + 1.11e7, P0 + 1e7),
           (P0 + 9e6, P0 + 1.05e7, P0 + 1e7)]


@pytest.mark.parametrize("point", CPOINTS)
def test_compensator_law_equals_hand_value_and_derivatives(point):
    row = COMPENSATOR.law_row(FLUID)
    p_in, p_out, p_load = point
    z = (COMPENSATOR.pressure_difference - (p_out - p_load)) / COMPENSATOR.regulation_band
    y = 0.0 if z <= 0 else 1.0 if z >= 1 else 3 * z**2 - 2 * z**3
    q, d_in, d_out, d_load = compensator_law(row, *point)
    expected = orifice_textbook(COMPENSATOR.leakage_area + COMPENSATOR.area * y, COMPENSATOR.discharge_coefficient,
                                p_in - p_out, FLUID)
    assert q == pytest.approx(expected, rel=1e-12, abs=1e-22)
    for k, d in ((0, d_in), (1, d_out), (2, d_load)):
        up, down = list(point), list(point)
        up[k] += 1.0
        down[k] -= 1.0
        numeric = (compensator_law(row, *up)[0] - compensator_law(row, *down)[0]) / 2
        assert d == pytest.approx(numeric, rel=1e-6, abs=1e-9 * max(abs(d_in), abs(d_out)))


@pytest.fixture(scope="module")
def lifts(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ls")
    out = {}
    for mode in ("mujoco", "pbd"):
        result = run(SCENES / "ls_lift.scenario.toml", out=tmp / f"{mode}.mcap", overrides={"mode": mode})
        assert result.status == "complete", result.message
        out[mode] = (result, read_log(result.log_path))
    return out


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_lifting_holds_the_margin_and_the_metering_drop(lifts, mode):
    circuit = load_circuit(SCENES / "ls_boom.circuit.toml")
    margin = circuit.component("pump").params.margin
    compensator = circuit.component("boom_compensator").params
    setting, band = compensator.pressure_difference, compensator.regulation_band
    result, log = lifts[mode]
    nodes = log.topic("/hydroplant/nodes")
    cylinder = log.topic("/hydroplant/cylinders/boom_cyl")
    lifting = (nodes.t >= 0.6) & (nodes.t <= 1.2)  # 0.4 s after the spool opened: past the LS loop's first swings
    moving = cylinder["velocity_mps"][(cylinder.t >= 0.6) & (cylinder.t <= 1.2)]
    assert moving.min() > 0.01  # the boom rises the whole time
    supply, ls = nodes["pressure_pa.supply"][lifting], nodes["pressure_pa.ls"][lifting]
    gallery, cap = nodes["pressure_pa.boom_gallery"][lifting], nodes["pressure_pa.boom_cyl_cap"][lifting]
    assert np.all(np.abs(supply - ls - margin) < 0.1 * margin)
    drop = gallery - cap
    assert np.all((drop > setting - band) & (drop < setting))  # inside the compensator's regulation band
    swash = log.topic("/hydroplant/component_states")["state.pump_displacement_fraction"]
    assert 0.05 < swash[-1] < 1.0
    energy = result.energy
    assert energy["pump_work"] > 0 and abs(energy["residual"]) < 0.01 * energy["pump_work"]


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_load_sensing_excavator_digs_with_the_margin_held(mode, tmp_path):
    """models/excavator/dig_ls.scenario.toml, the whole 20 s dig with the monitor on: it completes; while the pump
    regulates (swash plate off its ends, the LS line below the cut-off) the margin's median equals the setting within
    1 % and 85 % of the samples are within 10 % of it (the rest: the transients of spools opening and closing); the
    energy balance closes within 1 % of the pump work."""
    scenario = ROOT / "models" / "excavator" / "dig_ls.scenario.toml"
    margin = load_circuit(scenario.parent / "excavator_ls.circuit.toml").component("pump").params.margin
    result = run(scenario, out=tmp_path / "dig.mcap", overrides={"mode": mode})
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    nodes = log.topic("/hydroplant/nodes")
    held = nodes["pressure_pa.supply"] - nodes["pressure_pa.ls"]
    swash = log.topic("/hydroplant/component_states")["state.pump_displacement_fraction"]
    regulating = (swash > 0.02) & (swash < 0.98) & (nodes["pressure_pa.ls"] < 3.0e7)
    assert regulating.mean() > 0.5
    assert np.median(held[regulating]) == pytest.approx(margin, rel=0.01)
    assert np.mean(np.abs(held[regulating] - margin) <= 0.1 * margin) > 0.85
    assert abs(result.energy["relative"]) < 0.01
