"""The relief valve with poppet dynamics (hydraulics/components/relief_poppet.py): a component with states of its
own, declared in its module alone.

* The poppet's transition Φ(h) against the matrix exponential (under-, critically and over-damped, first order).
* The law's total pressure derivative (through the state advanced over the step) against central differences;
  the end states equal the law's.
* Small flow step (a 1 % pump step on a test rig without actuators, stepped by the network alone): the pressure's
  overshoot and 2 % settling time equal the linearised plant's analytic step response (the third-order system
  of node capacitance, valve gains and poppet, solved by the matrix exponential) within 1 %.
* Large flow step from the scenario file alone (tests/scenes/relief_step.scenario.toml, 12 → 18 L/min), both
  modes: overshoot and settling time within 1 % of the converged reference (the network stepped alone at 10 µs);
  the poppet's states are logged on ``/hydroplant/component_states``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from hydraulics.circuit import load_circuit
from hydraulics.components.relief_poppet import ReliefPoppet, flow_with_derivatives, step_end, transition
from hydraulics.fluid import Fluid
from hydraulics.network import NetworkModel
from hydraulics.steppers import ActuatorMotion, StepperImplicitEuler
from sim.io.mcap_log import read_log
from sim.run.runner import run
from reference.laws import orifice_textbook

SCENES = Path(__file__).parent / "scenes"
FLUID = Fluid(density=870.0, kinematic_viscosity=4.6e-5, reference_pressure=1.0e5)
P0 = FLUID.reference_pressure


def poppet(**changes):
    values = dict(cracking_pressure=1e7, full_open_pressure=1.5e7, area=2e-5, natural_frequency=314.159,
                  damping_ratio=0.7)
    values.update(changes)
    return ReliefPoppet(**values)


@pytest.mark.parametrize("zeta", [0.05, 0.7, 1.0, 1.0 + 1e-9, 3.0])
@pytest.mark.parametrize("h", [1e-5, 1e-3, 0.05])
def test_transition_is_the_matrix_exponential(zeta, h):
    """Φ(h) of ÿ + 2ζωẏ + ω²y = 0 equals expm(A·h) to 1e-12 (absolute, Φ is O(1) or smaller)."""
    omega = 314.159
    row = poppet(damping_ratio=zeta).law_row(FLUID)
    exact = expm(np.array([[0.0, 1.0], [-omega**2, -2 * zeta * omega]]) * h)
    assert np.allclose(np.array(transition(row, h)).reshape(2, 2), exact, rtol=1e-10, atol=1e-12 * max(1.0, omega**2 * h))


def test_first_order_transition():
    row = poppet(dynamics="first_order", time_constant=0.004).law_row(FLUID)
    assert transition(row, 0.001) == pytest.approx((np.exp(-0.25), 0.0, 0.0, 0.0), rel=1e-14)


STATES = [np.array([0.0, 0.0, 0.0]), np.array([0.3, 20.0, 0.0]), np.array([0.9, -40.0, 0.0])]


@pytest.mark.parametrize("dynamics", ["first_order", "second_order"])
@pytest.mark.parametrize("state", STATES)
@pytest.mark.parametrize("dp", [1.02e7, 1.1e7, 1.4e7])
def test_total_derivative_and_end_state(dynamics, state, dp):
    """dQ/dp_in = −dQ/dp_out equals the central difference (1 Pa) of the flow at the end of a 1 ms step (the
    poppet advanced by the end pressure); the end state equals the exact motion under that pressure."""
    valve = poppet(dynamics=dynamics)
    row = valve.law_row(FLUID)
    h = 1e-3
    q, d_in, d_out, d_x = flow_with_derivatives(row, state, h, P0 + dp, P0, 0.0)
    numeric = (flow_with_derivatives(row, state, h, P0 + dp + 1.0, P0, 0.0)[0]
               - flow_with_derivatives(row, state, h, P0 + dp - 1.0, P0, 0.0)[0]) / 2
    assert d_in == pytest.approx(numeric, rel=1e-5) and d_out == -d_in and d_x == 0.0
    end = np.empty(3)
    step_end(row, state, h, P0 + dp, P0, 0.0, end)
    z = (dp - valve.cracking_pressure) / (valve.full_open_pressure - valve.cracking_pressure)
    if dynamics == "first_order":
        expected = np.array([z + np.exp(-h / valve.time_constant) * (state[0] - z), 0.0, 0.0])
    else:
        w, zeta = valve.natural_frequency, valve.damping_ratio
        moved = np.array([z, 0.0]) + expm(np.array([[0.0, 1.0], [-w**2, -2 * zeta * w]]) * h) @ (state[:2] - [z, 0.0])
        expected = np.append(moved, 0.0)
    expected[0] = min(max(expected[0], 0.0), 1.0)
    if expected[0] in (0.0, 1.0):
        expected[1] = 0.0
    assert end == pytest.approx(expected, rel=1e-10, abs=1e-12)
    area = valve.leakage_area + valve.area * end[0]
    assert q == pytest.approx(orifice_textbook(area, valve.discharge_coefficient, dp, FLUID), rel=1e-12)


def test_poppet_seats_and_stops():
    """Below cracking the poppet stays on its seat (no flow beyond leakage); far above it sits at its stop."""
    row = poppet().law_row(FLUID)
    end = np.empty(3)
    step_end(row, np.zeros(3), 0.01, P0 + 5e6, P0, 0.0, end)
    assert tuple(end) == (0.0, 0.0, 0.0)
    step_end(row, np.array([0.99, 100.0, 0.0]), 0.01, P0 + 3e7, P0, 0.0, end)
    assert tuple(end) == (1.0, 0.0, 0.0)


def test_kink_hook_tells_seat_moving_and_stop_apart():
    """The network's law pieces (the poppet's kink hook) differ on the seat, lifting and at the stop, so a step that
    crosses one is not accepted from the start's linearisation."""
    model = NetworkModel.from_circuit(RIG)
    supply = model.node("supply")
    relief = model.law_branches("relief_valve_poppet").start - model.branch_slices["law"].start  # among the law pieces
    pieces = []
    for dp in (5e6, 1.2e7, 3e7):
        p = np.full(model.node_count, P0)
        p[supply] += dp
        pieces.append(int(model.law_pieces(p, h=0.01)[relief]))
    assert pieces == [3, 4, 5]


def test_incompressible_level_refuses_a_component_with_states():
    with pytest.raises(ValueError, match="component 'relief'.*states of its own.*'incompressible'"):
        NetworkModel.from_circuit(RIG, fidelity="incompressible")


def test_full_open_pressure_must_exceed_cracking():
    with pytest.raises(ValueError, match="full_open_pressure"):
        poppet(full_open_pressure=9e6).check("c.toml: component 'relief'")


# ---------------------------------------------------------------- the rig's step responses
RIG = load_circuit(SCENES / "relief_rig.circuit.toml")


def characteristic(t, p, p_start, p_end):
    """Overshoot (peak − p_end)/(p_end − p_start) [-] and the time after which p stays within 2 % of the step of
    p_end [s]."""
    step = p_end - p_start
    outside = np.flatnonzero(np.abs(p - p_end) > 0.02 * abs(step))
    return (p.max() - p_end) / step, (t[outside[-1] + 1] if len(outside) else t[0])


def network_step_response(speeds, h, duration):
    """The rig stepped by the network alone: steady at ``speeds[0]`` [rev/s], then ``speeds[1]`` for ``duration``
    [s] at steps of ``h``; returns the model, times [s], supply pressures [Pa] and the steady end state."""
    model = NetworkModel.from_circuit(RIG)
    stepper = StepperImplicitEuler(model)
    state = model.state()
    held = ActuatorMotion.held(state.actuator_position)
    for _ in range(10000):  # 1 s: steady
        state, _ = stepper.step(state, model.control(pump=speeds[0]), held, 1e-4)
    start = state.copy()
    supply = model.node("supply")
    times, pressures = [0.0], [state.node_pressure[supply]]
    control = model.control(pump=speeds[1])
    for k in range(round(duration / h)):
        state, _ = stepper.step(state, control, held, h)
        times.append((k + 1) * h)
        pressures.append(state.node_pressure[supply])
    settled = state
    for _ in range(10000):
        settled, _ = stepper.step(settled, control, held, 1e-4)
    return model, start, np.array(times), np.array(pressures), settled


def linear_step_response(model, start, speeds, times):
    """The supply pressure [Pa] of the rig linearised about the steady ``start``: C·δṗ = δQ_pump − K_c·δp − K_q·δy,
    δÿ + 2ζω·δẏ + ω²·δy = ω²·δp/(p_full − p_crack), solved exactly (matrix exponential)."""
    valve, pump = RIG.component("relief").params, RIG.component("pump").params
    supply = model.node("supply")
    p = start.node_pressure.copy()
    p_hi, p_lo = p.copy(), p.copy()
    p_hi[supply] += 1.0
    p_lo[supply] -= 1.0
    x = start.actuator_position
    capacitance = (model.oil_from_pressure(p_hi, x)[supply] - model.oil_from_pressure(p_lo, x)[supply]) / 2
    row = valve.law_row(model.fluid)
    y = start.valve_spool[model.component_state_names.index("relief.opening")]
    dp = p[supply] - p[model.node("tank")]
    q_of = lambda area, drop: flow_with_derivatives(np.r_[row[:2], area, 0.0, row[4:]], np.array([1.0, 0.0]), 0.0,
                                                    P0 + drop, P0, 0.0)[0]  # noqa: E731 (open area, no leakage)
    area = valve.leakage_area + valve.area * y
    kc = (q_of(area, dp + 1.0) - q_of(area, dp - 1.0)) / 2
    kq = (q_of(area + 1e-9, dp) - q_of(area - 1e-9, dp)) / 2e-9 * valve.area
    w, zeta, span = valve.natural_frequency, valve.damping_ratio, valve.full_open_pressure - valve.cracking_pressure
    a = np.array([[-kc / capacitance, -kq / capacitance, 0.0], [0.0, 0.0, 1.0], [w**2 / span, -w**2, -2 * zeta * w]])
    b = np.array([pump.displacement * (speeds[1] - speeds[0]) / capacitance, 0.0, 0.0])
    response = [np.linalg.solve(a, (expm(a * t) - np.eye(3)) @ b)[0] for t in times]
    return p[supply] + np.array(response), p[supply] - np.linalg.solve(a, b)[0]


def test_small_flow_step_matches_the_linearised_plant():
    """A 1 % pump step: overshoot and settling time of the network stepped alone at 10 µs within 1 % of the
    linearised plant's analytic response (the poppet opens from 9.2 % with ζ = 0.7, ω = 50 Hz: the loop through
    the node's compliance makes the pressure overshoot by about 77 %)."""
    speeds = (20.0, 20.2)
    model, start, times, pressures, settled = network_step_response(speeds, 1e-5, 0.25)
    analytic, analytic_end = linear_step_response(model, start, speeds, times)
    over_a, settle_a = characteristic(times, analytic, pressures[0], analytic_end)
    over, settle = characteristic(times, pressures, pressures[0], settled.node_pressure[model.node("supply")])
    assert 0.5 < over_a < 1.0
    assert over == pytest.approx(over_a, rel=0.01)
    assert settle == pytest.approx(settle_a, rel=0.01)


@pytest.fixture(scope="module")
def reference():
    """The large step (12 → 18 L/min) converged: the network alone at 10 µs."""
    model, start, times, pressures, settled = network_step_response((20.0, 30.0), 1e-5, 0.25)
    return times, pressures, settled.node_pressure[model.node("supply")]


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_scenario_flow_step_matches_the_converged_reference(reference, mode, tmp_path):
    """From the scenario file alone, in each mode: overshoot and settling time within 1 % of the converged
    reference, the steady pressure within 0.01 %; the poppet's opening is logged and rises with the flow."""
    times, pressures, p_end = reference
    over_ref, settle_ref = characteristic(times, pressures, pressures[0], p_end)
    result = run(SCENES / "relief_step.scenario.toml", out=tmp_path / f"{mode}.mcap", overrides={"mode": mode})
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    nodes = log.topic("/hydroplant/nodes")
    t, p = nodes.t, nodes["pressure_pa.supply"]
    step = t >= 0.05 - 1e-9
    over, settle = characteristic(t[step] - t[step][0], p[step], p[step][0], p_end)
    assert p[step][0] == pytest.approx(pressures[0], rel=1e-4)
    assert over == pytest.approx(over_ref, rel=0.01)
    assert settle == pytest.approx(settle_ref, rel=0.01)
    opening = log.topic("/hydroplant/component_states")["state.relief_opening"]
    assert 0.05 < opening[0] < opening[-1] < 0.5


def test_a_circuit_on_a_bench_without_joints_runs_logs_and_compares(tmp_path):
    """The rig's MJCF has no joint (no degree of freedom, the world body alone): both modes step the circuit and
    log it (no joint or body-pose topic), and ``compare`` of the two logs compares the node pressures: the supply
    agrees between the modes within 5 % of its range over the whole run."""
    import mujoco

    from sim.tools.compare import compare_existing

    model = mujoco.MjModel.from_xml_path(str(SCENES / "relief_rig.xml"))
    assert (model.njnt, model.nv, model.nbody) == (0, 0, 1)
    paths = {}
    for mode in ("mujoco", "pbd"):
        result = run(SCENES / "relief_step.scenario.toml", out=tmp_path / f"{mode}.mcap",
                     overrides={"mode": mode, "duration": 0.2})
        assert result.status == "complete", result.message
        paths[mode] = result.log_path
        log = read_log(result.log_path)
        assert "/hydroplant/joint_states" not in log and "/tf" not in log
        p = log.topic("/hydroplant/nodes")["pressure_pa.supply"]
        assert p[-1] > p[0] + 1e5  # the step raised the supply pressure
    result = compare_existing([paths["mujoco"], paths["pbd"]], tmp_path / "cmp")
    (row,) = result.comparisons
    assert set(row.signals) == {"p supply", "p tank"}
    supply = row.signals["p supply"]
    assert supply.samples > 100 and supply.max_abs < 0.05 * supply.ref_range
