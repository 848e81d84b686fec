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
* The pump's shaft speed as a scheduled input (tests/scenes/ls_lift_speed.scenario.toml, halved while lifting), both
  modes: the flow is η_v·D·n·α at the scheduled n and the swash plate doubles to hold the margin.
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


PI_PUMP = PumpLoadSensing(displacement=1.2e-5, speed=40.0, margin=2e6, cutoff_pressure=2e7, regulator_band=5e5,
                          stroke_time=0.05, proportional_gain=2e-7, leakage=3e-13)


def swash_by_hand(pump, state, h, p_in, p_out, p_ls):
    """(α⁺, I⁺): the integral part moved at the clipped rate, plus the proportional part, each clipped to [0, 1]."""
    error = min(p_ls + pump.margin - p_out, pump.cutoff_pressure - (p_out - p_in))
    rate = np.clip(error / pump.regulator_band, -1, 1) / pump.stroke_time
    integral = float(np.clip(state[1] + h * rate, 0, 1))
    return float(np.clip(integral + pump.proportional_gain * error, 0, 1)), integral


# (alpha, p_out, p_ls) [-, Pa]: in the band below the margin, above it, saturated low, cut-off active, at the end
POINTS = [(0.4, P0 + 1.19e7, P0 + 1e7), (0.4, P0 + 1.21e7, P0 + 1e7), (0.4, P0 + 5e6, P0 + 1e7),
          (0.4, P0 + 1.999e7, P0 + 1.95e7), (0.999, P0 + 1.19e7, P0 + 1e7)]


@pytest.mark.parametrize("pump", [PUMP, PI_PUMP], ids=["integral", "pi-leaking"])
@pytest.mark.parametrize("point", POINTS)
def test_pump_law_equals_hand_value_and_its_derivatives(point, pump):
    alpha, p_out, p_ls = point
    row, h, speed = pump.law_row(FLUID), 1e-3, np.array(pump.input_start())
    state = np.array([alpha, alpha])
    q, d_in, d_out, d_ls = pump_law(row, state, h, P0, p_out, p_ls, speed)
    rate = pump.displacement * pump.speed
    expected = rate * swash_by_hand(pump, state, h, P0, p_out, p_ls)[0] - pump.leakage * (p_out - P0)
    assert q == pytest.approx(expected, rel=1e-14)
    for k, d in ((0, d_in), (1, d_out), (2, d_ls)):
        up, down = [P0, p_out, p_ls], [P0, p_out, p_ls]
        up[k] += 1.0
        down[k] -= 1.0
        numeric = (pump_law(row, state, h, *up, speed)[0] - pump_law(row, state, h, *down, speed)[0]) / 2
        assert d == pytest.approx(numeric, rel=1e-6, abs=1e-18)
    end = np.empty(2)
    step_end(row, state, h, P0, p_out, p_ls, end)
    assert tuple(end) == swash_by_hand(pump, state, h, P0, p_out, p_ls)


def test_pump_holds_the_margin_in_steady_state():
    """With the outlet exactly the margin above the LS line the swash plate stays where it is."""
    row, state = PUMP.law_row(FLUID), np.array([0.37, 0.37])
    end = np.empty(2)
    step_end(row, state, 0.1, P0, P0 + 1.2e7, P0 + 1e7, end)
    assert end[0] == 0.37


def test_leaking_pump_holds_the_margin_and_rings_down_as_designed():
    """The PI-regulated, leaking pump alone on its supply volume V, the LS line held at 100 bar: a supply 1 bar
    above its setting settles back to LS + margin, ringing with the decay rate of the linearised loop
    s²·V/β + s·(C_L + R·k_p) + R/(τ·w) = 0 (R = η_v·D·n), −Re(s) = (C_L + R·k_p)·β/(2V), within 2 %."""
    pump = PumpLoadSensing(displacement=2.14e-4, speed=100 / 3, margin=2e6, cutoff_pressure=3.3e7,
                           regulator_band=1e6, stroke_time=0.08, proportional_gain=1e-8, leakage=1.4e-11)
    volume, beta, h, p_ls = 2.5e-3, 1.5e9, 4e-6, P0 + 1e7
    row, rate, speed = pump.law_row(FLUID), pump.displacement * pump.speed, np.array(pump.input_start())
    setting = p_ls + pump.margin
    alpha = pump.leakage * (setting - P0) / rate  # the swash plate covering the leakage
    state, end = np.array([alpha, alpha]), np.empty(2)
    p, history = setting + 1e5, []
    for _ in range(50000):  # 0.2 s, backward Euler on p with Newton on the law's own derivative
        p_new = p
        for _ in range(20):
            q, _, d_out, _ = pump_law(row, state, h, P0, p_new, p_ls, speed)
            change = ((p_new - p) * volume / beta - h * q) / (volume / beta - h * d_out)
            p_new -= change
            if abs(change) < 1e-7:
                break
        step_end(row, state, h, P0, p_new, p_ls, end)
        state[:] = end
        p = p_new
        history.append(p - setting)
    history = np.asarray(history)
    assert abs(history[-1]) < 0.02 * 1e5  # e^(−σ·0.2 s) ≈ 0.6 % of the offset left
    a, b, c = volume / beta, pump.leakage + rate * pump.proportional_gain, rate / (pump.stroke_time * pump.regulator_band)
    assert b * b < 4 * a * c  # a complex pair: it rings
    crest = np.flatnonzero((history[1:-1] > history[:-2]) & (history[1:-1] >= history[2:]) & (history[1:-1] > 0)) + 1
    assert crest.size >= 3
    measured = np.log(history[crest[0]] / history[crest[2]]) / ((crest[2] - crest[0]) * h)
    assert measured == pytest.approx(b / (2 * a), rel=0.02)


def test_pump_kink_hook_numbers_regulator_and_cutoff():
    from hydraulics.components.pump_load_sensing import law_piece
    row, state = PUMP.law_row(FLUID), np.array([0.4, 0.4])
    inside = law_piece(row, state, 1e-3, P0, P0 + 1.2e7, P0 + 1e7)
    starved = law_piece(row, state, 1e-3, P0, P0 + 5e6, P0 + 1e7)
    cut = law_piece(row, state, 1e-3, P0, P0 + 2e7 + 1e5, P0 + 1.95e7)
    assert (inside, starved, cut) == (27 + 3 + 1, 27 + 6 + 1, 27 + 9 + 3 + 1)  # the integral off its ends


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


def run_both_modes(scenario, tmp):
    """``scenario`` (a file of tests/scenes) run to completion in MuJoCo and PBD mode: mode -> (result, log)."""
    out = {}
    for mode in ("mujoco", "pbd"):
        result = run(SCENES / scenario, out=tmp / f"{mode}.mcap", overrides={"mode": mode})
        assert result.status == "complete", result.message
        out[mode] = (result, read_log(result.log_path))
    return out


@pytest.fixture(scope="module")
def lifts(tmp_path_factory):
    return run_both_modes("ls_lift.scenario.toml", tmp_path_factory.mktemp("ls"))


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


@pytest.fixture(scope="module")
def ls_digs(tmp_path_factory):
    """models/excavator/dig_ls.scenario.toml run whole in both modes at its own settings, the monitor on."""
    tmp = tmp_path_factory.mktemp("dig_ls")
    scenario = ROOT / "models" / "excavator" / "dig_ls.scenario.toml"
    return {mode: run(scenario, out=tmp / f"{mode}.mcap", overrides={"mode": mode}) for mode in ("mujoco", "pbd")}


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_load_sensing_excavator_digs_with_the_margin_held(ls_digs, mode):
    """The whole 20 s dig completes; wherever the pump can hold its margin (the swash plate short of full
    displacement: the sections ask no more than the pump gives; the LS line short of the cut-off) the margin's
    median equals the setting within 1 % and 95 % of those samples are within 10 % of it (the rest: a spool
    opening or, all spools closed, the supply falling to standby through the pump's leakage), 90 % of all samples
    of the cycle; the energy balance closes within 1 % of the pump work."""
    pump = load_circuit(ROOT / "models" / "excavator" / "excavator_ls.circuit.toml").component("pump").params
    margin = pump.margin
    result = ls_digs[mode]
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    nodes = log.topic("/hydroplant/nodes")
    held = nodes["pressure_pa.supply"] - nodes["pressure_pa.ls"]
    swash = log.topic("/hydroplant/component_states")["state.pump_displacement_fraction"]
    able = (swash < 0.98) & (nodes["pressure_pa.ls"] - P0 + margin < pump.cutoff_pressure)
    within = np.abs(held - margin) <= 0.1 * margin
    assert able.mean() > 0.9
    assert np.median(held[able]) == pytest.approx(margin, rel=0.01)
    assert within[able].mean() > 0.95
    assert within.mean() > 0.9
    assert abs(result.energy["relative"]) < 0.01


def test_load_sensing_excavator_modes_agree_within_the_dig_targets(ls_digs, tmp_path):
    """The two modes' digs against each other on 0.1 s averages (``compare``'s filtered metric): strokes within
    2 % of each stroke and pressures within 5 % of the highest relief setting, the stock dig's targets (each mode
    against the converged reference: docs/validation.md)."""
    from sim.tools.compare import compare_existing

    result = compare_existing([ls_digs["mujoco"].log_path, ls_digs["pbd"].log_path], tmp_path / "cmp",
                              filter_window=0.1)
    (row,) = result.comparisons
    circuit = load_circuit(ROOT / "models" / "excavator" / "excavator_ls.circuit.toml")
    relief = max(getattr(c.params, "cracking_pressure", 0.0) for c in circuit.components)  # the port reliefs' 373 bar
    strokes = {n: s for n, s in row.filtered.items() if n.startswith("stroke ")}
    pressures = {n: s for n, s in row.filtered.items() if n.startswith("p_")}
    assert len(strokes) == 3 and len(pressures) == 8
    for name, stats in strokes.items():
        assert stats.max_abs < 0.02 * circuit.component(name.removeprefix("stroke ")).params.stroke, name
    for name, stats in pressures.items():
        assert stats.max_abs < 0.05 * relief, name


@pytest.fixture(scope="module")
def speed_lifts(tmp_path_factory):
    """tests/scenes/ls_lift_speed.scenario.toml (the pump's shaft speed scheduled by its name) in both modes."""
    return run_both_modes("ls_lift_speed.scenario.toml", tmp_path_factory.mktemp("ls_speed"))


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_scheduled_speed_reaches_the_load_sensing_law(speed_lifts, mode):
    """The shaft speed n is a scheduled input of the load-sensing pump (halved from 40 to 20 rev/s at 0.7–0.75 s
    while the boom lifts): the logged speed is the schedule's value within each step (held over the step, or over
    the last XPBD substep in PBD mode);
    the delivered flow is η_v·D·n·α (no leakage in this circuit) at every sample, with α the logged swash plate, to
    1e-7 relative (the step's flows and its end states agree to the Newton solve's tolerance, not to round-off);
    the regulator makes up for the halved speed — from 0.25 s after the change the supply holds the margin above
    the LS line within 10 % with the swash plate short of full stroke, at twice its displacement before the change
    within 10 % (the compensated section asks for the same flow), and the boom keeps rising."""
    pump = load_circuit(SCENES / "ls_boom.circuit.toml").component("pump").params
    _, log = speed_lifts[mode]
    pumps = log.topic("/hydroplant/pumps/pump")
    states = log.topic("/hydroplant/component_states")
    nodes = log.topic("/hydroplant/nodes")
    t = pumps.t
    assert np.array_equal(t, states.t) and np.array_equal(t, nodes.t)
    dt = 1e-3  # the scenario's step [s]
    start, end = (np.interp(t - delay, [0.0, 0.7, 0.75], [40.0, 40.0, 20.0]) for delay in (dt, 0.0))
    assert np.all((pumps["speed_rps"] <= start + 1e-9) & (pumps["speed_rps"] >= end - 1e-9))
    alpha = states["state.pump_displacement_fraction"]
    expected = pump.volumetric_efficiency * pump.displacement * pumps["speed_rps"] * alpha
    assert np.allclose(pumps["flow_m3ps"], expected, rtol=1e-7, atol=1e-12 * np.max(expected))
    before, after = (t >= 0.55) & (t <= 0.7), (t >= 1.0) & (t <= 1.4)
    assert alpha[after].max() < 0.98
    held = nodes["pressure_pa.supply"] - nodes["pressure_pa.ls"]
    assert np.all(np.abs(held[after] - pump.margin) < 0.1 * pump.margin)
    assert np.mean(alpha[after]) / np.mean(alpha[before]) == pytest.approx(2.0, rel=0.1)
    velocity = log.topic("/hydroplant/cylinders/boom_cyl")["velocity_mps"]
    assert velocity[after].min() > 0.01
