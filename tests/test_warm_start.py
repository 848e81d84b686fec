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
from sim.plant_mujoco import MujocoPlant
from sim.scenario import load_scenario
from sim.scene import load_scene

SECONDS = 2.0  # s of each scenario from its start (the excavator: approach and the start of the dig)
SCENES = {"boom": MODELS / "boom" / "lift.scenario.toml", "excavator": MODELS / "excavator" / "dig.scenario.toml"}


def _run(path):
    """Pressures [Pa] after every step, end strokes [m] and the linearisation's Newton iterations per step."""
    plant = MujocoPlant(load_scene(load_scenario(path)))
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
