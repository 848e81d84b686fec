"""Hysteresis of the relief valve with poppet dynamics: it cracks at its cracking pressure and reseats at its reseat
pressure.

* Law: a quasi-static sweep of the differential pressure up and down (first-order poppet, steps much longer than
  its lag) follows the opening characteristic (Δp − p_crack)/span rising and (Δp − p_reseat)/span falling, and
  holds its opening in between; the total derivative is the central difference, zero inside the band.
* Rig, both modes: a pump ramped up and down on a 2 L volume relieved by the valve; the supply pressure where the
  poppet first lifts equals the cracking pressure, and where the pump has stopped and the poppet seated, the
  reseat pressure (each within 1 %).  Without hysteresis the stopped pump leaves the cracking pressure.
* Published rule: Hopsan's relief valve (component library, *HydraulicPressureReliefValve* with the utility
  *ValveHysteresis*) holds its previous opening x inside [x_s − x_h/2, x_s + x_h/2] about the static opening x_s
  of the mid-band pressure, the filter keeping x within [0, full]; with the band w = p_crack − p_reseat that is
  x = clip(x_prev, (Δp − p_crack)/span, (Δp − p_reseat)/span), then clipped to [0, 1].  A quasi-static random
  sweep with minor loops inside the band and excursions past both ends opens as that rule does, step for step.
"""

from __future__ import annotations

import numpy as np
import pytest

from hydraulics.components import CircuitError, build_component
from hydraulics.components.relief_poppet import ReliefPoppet, flow_with_derivatives, law_piece, step_end
from hydraulics.fluid import Fluid
from reference.circuits import bench, pump_into_volume
from reference.scenes import BENCH
from sim.io.mcap_log import read_log
from sim.run.runner import run

FLUID = Fluid(density=870.0, kinematic_viscosity=4.6e-5, reference_pressure=1.0e5)
P0 = FLUID.reference_pressure
CRACK, FULL, RESEAT = 1.0e7, 1.5e7, 0.8e7


def valve(**changes) -> ReliefPoppet:
    values = dict(cracking_pressure=CRACK, full_open_pressure=FULL, reseat_pressure=RESEAT, area=2e-5,
                  dynamics="first_order", time_constant=1e-4)
    values.update(changes)
    return ReliefPoppet(**values)


def test_a_quasi_static_sweep_opens_on_one_characteristic_and_closes_on_the_other():
    row, state, span = valve().law_row(FLUID), np.zeros(3), FULL - CRACK
    up = np.linspace(0.0, 1.4e7, 141)
    openings_up = []
    for dp in up:
        step_end(row, state, 0.01, P0 + dp, P0, 0.0, state)
        openings_up.append(state[0])
    assert np.allclose(openings_up, np.clip((up - CRACK) / span, 0.0, 1.0), atol=1e-12)
    peak = state[0]
    down = up[::-1]
    openings_down = []
    for dp in down:
        step_end(row, state, 0.01, P0 + dp, P0, 0.0, state)
        openings_down.append(state[0])
    expected = np.minimum(peak, np.clip((down - RESEAT) / span, 0.0, 1.0))
    assert np.allclose(openings_down, expected, atol=1e-12)
    held = (down < 1.4e7) & (down > RESEAT + peak * span)
    assert held.any() and np.all(np.array(openings_down)[held] == peak)


def _published_rule(dp_sweep, crack, reseat, span):
    """The quasi-static opening of Hopsan's relief valve with hysteresis (its ValveHysteresis clip about the
    mid-band line, then its filter's limits), in normalised opening [-]: a slow reference for the test only."""
    x, out = 0.0, []
    for dp in dp_sweep:
        x = min(max(x, (dp - crack) / span), (dp - reseat) / span)
        x = min(max(x, 0.0), 1.0)
        out.append(x)
    return np.array(out)


def test_a_random_sweep_with_minor_loops_opens_as_the_published_play_rule():
    row, state, span = valve().law_row(FLUID), np.zeros(3), FULL - CRACK
    rng, t = np.random.default_rng(7), np.linspace(0.0, 1.0, 4000)
    # a slow swing far past both ends, with reversals smaller than the 2 MPa band riding on it
    dp = 1.1e7 + 0.9e7 * np.sin(2 * np.pi * 3 * t) + 1.2e6 * np.sin(2 * np.pi * 41 * t) + rng.normal(0.0, 2e5, t.size)
    assert dp.min() < RESEAT and dp.max() > FULL + (CRACK - RESEAT)
    openings = []
    for value in dp:
        step_end(row, state, 0.01, P0 + value, P0, 0.0, state)  # 100 time constants: the poppet on its target
        openings.append(state[0])
    expected = _published_rule(dp, CRACK, RESEAT, span)
    held = np.flatnonzero((np.diff(expected) == 0.0) & (expected[1:] > 0.0) & (expected[1:] < 1.0))
    assert len(held) > 50  # the sweep does dwell inside the band, part open
    np.testing.assert_allclose(openings, expected, rtol=0.0, atol=1e-12)


@pytest.mark.parametrize("opening", [0.15, 0.55, 0.95])
@pytest.mark.parametrize("dp", [0.87e7, 1.07e7, 1.22e7, 1.43e7])
def test_derivative_and_kink_hook_inside_and_outside_the_band(opening, dp):
    """dQ/dp_in equals the central difference (1 Pa) of the end-of-step flow away from the band's edges; inside the
    band (the opening held) only the orifice's own slope remains; the kink hook numbers the three band pieces apart."""
    row, h = valve(dynamics="second_order", natural_frequency=300.0, damping_ratio=0.7).law_row(FLUID), 1e-3
    state = np.array([opening, 0.0, opening])  # the play's memory at the opening: the poppet at rest on its target
    q, d_in, d_out, _ = flow_with_derivatives(row, state, h, P0 + dp, P0, 0.0)
    numeric = (flow_with_derivatives(row, state, h, P0 + dp + 1.0, P0, 0.0)[0]
               - flow_with_derivatives(row, state, h, P0 + dp - 1.0, P0, 0.0)[0]) / 2
    assert d_in == pytest.approx(numeric, rel=1e-5) and d_out == -d_in
    span = FULL - CRACK
    z_open, z_close = (dp - CRACK) / span, (dp - RESEAT) / span
    band = 0 if opening <= z_open else (1 if opening <= z_close else 2)
    assert law_piece(row, state, h, P0 + dp, P0, 0.0) // 9 == band


@pytest.mark.parametrize("h", [1e-3, 1e-4, 1e-5, 1e-6])
def test_an_underdamped_poppet_settles_on_the_characteristic_whatever_the_step(h):
    """At a constant 12 MPa (static opening 0.4) an underdamped poppet (ζ = 0.3) swings about its target and settles
    on it: its swings do not move the play's output (the target), for every step size."""
    row = valve(dynamics="second_order", natural_frequency=300.0, damping_ratio=0.3, reseat_pressure=0.9e7).law_row(FLUID)
    state = np.zeros(3)
    peak = 0.0
    for _ in range(int(round(0.2 / h))):
        step_end(row, state, h, P0 + 1.2e7, P0, 0.0, state)
        peak = max(peak, state[0])
    assert peak > 0.5 and state[0] == pytest.approx(0.4, abs=1e-6) and state[2] == pytest.approx(0.4, abs=1e-12)


def test_reseat_above_cracking_is_refused():
    with pytest.raises(CircuitError, match="field 'reseat_pressure'.*above cracking_pressure"):
        build_component("relief_valve_poppet", dict(cracking_pressure=CRACK, full_open_pressure=FULL,
                                                    reseat_pressure=1.1e7, area=2e-5), "rig.toml: component 'relief'")


RIG = bench() + pump_into_volume(1.0e-5, 0.0, 2.0e-3) + """
[[component]]
name = "relief"
type = "relief_valve_poppet"
cracking_pressure = 1.0e7
full_open_pressure = 1.5e7
area = 2.0e-5
leakage_area = 0.0
natural_frequency = 300.0
damping_ratio = 0.9
%s
ports = { inlet = "supply", outlet = "tank" }
"""
SCENARIO = """
[scene]
mjcf = "rig.xml"
circuit = "rig.circuit.toml"

[run]
mode = "%s"
dt = 0.001
duration = 3.0

[inputs]
pump = { t = [0.0, 1.0, 2.0], value = [0.0, 30.0, 0.0] }

[log]
rate_hz = 1000
"""


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
@pytest.mark.parametrize("reseat", [RESEAT, None])
def test_the_rig_cracks_at_the_cracking_pressure_and_reseats_at_the_reseat_pressure(tmp_path, mode, reseat):
    (tmp_path / "rig.xml").write_text(BENCH, encoding="utf-8")
    (tmp_path / "rig.circuit.toml").write_text(RIG % (f"reseat_pressure = {reseat!r}" if reseat else ""),
                                               encoding="utf-8")
    scenario = tmp_path / "rig.scenario.toml"
    scenario.write_text(SCENARIO % mode, encoding="utf-8")
    result = run(scenario, out=tmp_path / "rig.mcap")
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    supply = log.topic("/hydroplant/nodes")["pressure_pa.supply"] - P0
    opening = log.topic("/hydroplant/component_states")["state.relief_opening"]
    lifted = int(np.argmax(opening > 1e-4))
    assert opening[lifted] > 1e-4 and supply[lifted] == pytest.approx(CRACK, rel=1e-2)
    assert opening[-1] == 0.0
    assert supply[-1] == pytest.approx(reseat or CRACK, rel=1e-2)
