"""The implicit coupling's secant warm start (NetworkState.node_oil_change): fewer Newton iterations, same solution.

The linearisation's backward-Euler solve starts from m + (m − m_prev) instead of the start oil m.  The start
changes only the iterations: the runs with and without it must agree to the Newton tolerance (0.01 Pa per step),
while the iterations drop (measured over the first 2 s: boom 2.17 → 0.92 per step, excavator 1.79 → 0.90).
"""

import numpy as np
import pytest

import hydraulics.coupling as coupling
from conftest import MODELS
from hydraulics.steppers import NEWTON_PRESSURE_TOLERANCE
from sim.plants.mujoco import MujocoPlant
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene

SECONDS = 2.0  # s of each scenario from its start (the excavator: approach and the start of the dig)
SCENES = {"boom": MODELS / "boom" / "lift.scenario.toml", "excavator": MODELS / "excavator" / "dig.scenario.toml"}


def _run(path):
    """Pressures [Pa] after every step, end strokes [m] and the linearisation's Newton iterations per step."""
    plant = MujocoPlant(load_scene(load_scenario(path)), coupling="implicit")
    pressures, iterations = [], []
    for _ in range(int(round(SECONDS / plant.dt))):
        start = plant.net_state
        report = plant.step()
        assert report.success, report.message
        end = plant.net_state
        free = np.isfinite(end.node_oil)
        # the state carries its own step's oil change, bit for bit
        np.testing.assert_array_equal(end.node_oil_change[free], end.node_oil[free] - start.node_oil[free])
        pressures.append(end.node_pressure.copy())
        iterations.append(plant.coupling.last_linearization.report.newton_iterations)
    return np.array(pressures), end.actuator_position.copy(), np.array(iterations)


@pytest.mark.parametrize("scene", list(SCENES))
def test_secant_start_saves_iterations_and_keeps_the_solution(scene, monkeypatch):
    warm_p, warm_x, warm_it = _run(SCENES[scene])
    monkeypatch.setattr(coupling, "secant_oil_guess", lambda state: None)  # every linearisation from the start oil
    cold_p, cold_x, cold_it = _run(SCENES[scene])
    assert cold_it.mean() > 1.5  # the comparison means something: the cold start needs iterations
    assert warm_it.mean() <= 0.6 * cold_it.mean(), (warm_it.mean(), cold_it.mean())
    # same solution: the two runs differ by what the Newton tolerance allows, accumulated over 2000 steps
    assert np.max(np.abs(warm_p - cold_p)) < 100 * NEWTON_PRESSURE_TOLERANCE
    np.testing.assert_allclose(warm_x, cold_x, rtol=0, atol=1e-9)


def _strokes_and_pressures(plant, steps, set_change):
    """Steps ``plant`` one at a time, ``set_change(state)`` replacing its warm start before each step; returns the
    pressures [Pa] and strokes [m] after every step."""
    out = []
    for _ in range(steps):
        set_change(plant.net_state)
        report = plant.step()
        assert report.success, report.message
        out.append(np.concatenate([plant.net_state.node_pressure, plant.net_state.actuator_position]))
    return np.array(out)


@pytest.mark.parametrize("fast", [False, True])
def test_an_unusable_warm_start_falls_back_to_the_start_oil(fast, monkeypatch):
    """A warm start whose linearisation is unusable (here NaN, the worst case) is retried from the start oil before
    the coupling gives up the velocity guess: the run is then the cold run, bit for bit, in the pure coupling and in
    the compiled step alike (the warm start changes the iterations only, never the law)."""
    from sim.plants.mujoco_fast import MujocoPlantFast

    make = (lambda s: MujocoPlantFast(s)) if fast else (lambda s: MujocoPlant(s))
    scenario = load_scenario(SCENES["excavator"]).with_overrides(coupling="implicit")
    n = load_scene(scenario).network.node_count

    def poisoned(state):
        state.node_oil_change = np.full(n, np.nan)

    def cold(state):
        state.node_oil_change = np.zeros(n)  # the start oil itself (the flat form of "none known")

    steps = 400  # the approach: every actuator's guess moves from the second step on
    a = _strokes_and_pressures(make(load_scene(scenario)), steps, poisoned)
    b = _strokes_and_pressures(make(load_scene(scenario)), steps, cold)
    assert np.all(np.isfinite(a))
    np.testing.assert_array_equal(a, b)


def test_initial_and_failed_states_carry_no_made_up_oil_change():
    """The equilibrium start has no last step (node_oil_change None); a step that fails in its second substep returns
    the first substep's state with the start's oil change (as the compiled steps keep it), not that substep's."""
    from hydraulics.network import NetworkControl
    from hydraulics.steppers import ActuatorMotion, StepperImplicitEuler, StepReport, StepStatus

    plant = MujocoPlant(load_scene(load_scenario(SCENES["boom"])))
    assert plant.net_state.node_oil_change is None
    net = plant.network
    start = plant.net_state.copy()
    start.node_oil_change = np.where(np.isfinite(start.node_oil), 1e-9, np.nan)
    control = NetworkControl(np.ones(len(net.valve_names)), np.ones(len(net.pump_names)))
    motion = ActuatorMotion.linear(start.actuator_position, np.full(net.actuator_count, 0.05), 1e-3)
    stepper = StepperImplicitEuler(net, substeps=3)
    whole, report = stepper.step(start, control, motion, 1e-3)
    assert report.success
    free = np.isfinite(start.node_oil)
    np.testing.assert_array_equal(whole.node_oil_change[free], whole.node_oil[free] - start.node_oil[free])
    substep, calls = stepper._substep, []

    def second_fails(*args, **kwargs):
        calls.append(1)
        new, sub = substep(*args, **kwargs)
        return new, (StepReport(status=StepStatus.NEWTON_FAILED, message="injected") if len(calls) == 2 else sub)

    stepper._substep = second_fails
    partial, report = stepper.step(start, control, motion, 1e-3)
    assert not report.success and len(calls) == 2
    assert not np.array_equal(partial.node_oil[free], start.node_oil[free])  # the first substep's state
    np.testing.assert_array_equal(partial.node_oil_change, start.node_oil_change)
