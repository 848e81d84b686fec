"""``rosenbrock``'s finish: linear where accepted, Newton (``implicit``'s finish) where not.

The boom's valve slam at 1/30 s (ω_h·dt ≈ 1.5) closes the valve within one step: the linear finish
m⁺ = m_lin + (∂m/∂v)·(v⁺ − v_g) then leaves a backward-Euler residual worth tens of bar (against under 5 kPa in 99 %
of the steps of the 1 kHz excavator dig), and uncorrected it drives the cap pressure past its ceiling;
:class:`hydraulics.coupling.CouplingRosenbrock` solves such a step by Newton from m⁺.  Checked here: the compiled
MuJoCo callback (``sim/plants/mujoco_fast.py``) and PBD mode's compiled substeps (``sim/plants/pbd_hydraulics.py``)
take the same decisions as the Python coupling step by step, the Newton finish does run there, and the map's cell keeps every node within the physical pressure ceiling times the
map's margin, as ``implicit`` does.
"""

import math

import numpy as np
import pytest

from conftest import MODELS
from hydraulics._compiled import compiled_available
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.plants.mujoco import MujocoPlant
from sim.tools import stability as st

pytestmark = pytest.mark.skipif(not compiled_available(), reason="numba is not installed")

BOOM = MODELS / "boom" / "lift.scenario.toml"
SLAM = st.Config("nominal", None, "valve_slam")
DT = 1.0 / 30.0  # s
PRESSURE_RTOL, PRESSURE_ATOL = 1e-9, 1e-2  # -, Pa (tests/test_fast_plant.py)


@pytest.fixture(scope="module")
def facts():
    return st.scene_facts(BOOM, st.DEFAULT_GRID)


def test_fast_plant_takes_the_python_couplings_newton_finishes(facts, tmp_path):
    """Step by step over the slam: the same end pressures, and the same steps finished by Newton (counters), in the
    compiled callback as in :class:`CouplingRosenbrock`; at least one step is."""
    from sim.plants.mujoco_fast import MujocoPlantFast

    scenario = load_scenario(st.write_variant(facts, SLAM, tmp_path / SLAM.id)).with_overrides(dt=DT)
    reference = MujocoPlant(load_scene(scenario), coupling="rosenbrock")
    fast = MujocoPlantFast(load_scene(scenario), coupling="rosenbrock")
    assert fast.fast
    newton_steps = 0
    for _ in range(int(math.ceil(facts.duration / DT))):
        a, b = reference.step(), fast.step()
        assert a.success and b.success, (a.message, b.message)
        assert (a.newton_iterations, a.rhs_evaluations, a.jacobian_evaluations) == (
            b.newton_iterations, b.rhs_evaluations, b.jacobian_evaluations), reference.time
        np.testing.assert_allclose(fast.net_state.node_pressure, reference.net_state.node_pressure,
                                   rtol=PRESSURE_RTOL, atol=PRESSURE_ATOL)
        newton_steps += a.newton_iterations > 0
    assert newton_steps > 0


@pytest.mark.parametrize("substeps, blend", [(1, False), (2, True)])
def test_pbd_compiled_substeps_take_the_python_couplings_newton_finishes(facts, tmp_path, substeps, blend):
    """PBD mode over the slam at 1/30 s frames (θ = 1 with one substep, the θ-rule with two): the compiled substeps
    against the Python hooks (``tests/reference/pbd_hooks.py``) frame by frame, the same counters and states, and at
    least one frame finished by Newton, so the compiled fallback itself is what agrees."""
    from test_pbd_fast import _compare
    from reference.pbd_hooks import HooksPlant
    from sim.plants.pbd import PbdPlant

    path = st.write_variant(facts, SLAM, tmp_path / SLAM.id)
    scenario = load_scenario(path).with_overrides(mode="pbd", dt=DT, pbd_substeps=substeps, coupling="rosenbrock",
                                                  pbd_blend=blend)
    reference, fast = HooksPlant(load_scene(scenario)), PbdPlant(load_scene(scenario))
    assert fast.fast and not reference.fast
    newton_frames = 0
    for _ in range(int(math.ceil(facts.duration / DT))):
        a, b = reference.step(), fast.step()
        _compare(reference, fast, a, b, f"slam × {substeps} t={reference.time:.4f}")
        newton_frames += a.newton_iterations > 0
    assert newton_frames > 0


def test_slam_at_30hz_stays_within_the_pressure_ceiling(facts, tmp_path):
    """The map's cell (its duration): every node's peak within its physical ceiling (relief + override, + the spike of a
    trapped moving load) times the map's margin, and not diverged."""
    path = st.write_variant(facts, SLAM, tmp_path / SLAM.id)
    info = st.variant_info(path, facts.full_flow)
    point = {
        "config": SLAM.id, "sweep": SLAM.sweep, "value": SLAM.value, "event": SLAM.event, "scenario": str(path),
        "omega_h": info["omega_h"], "actuators": info["actuators"], "log_rate_hz": 1.0 / DT,
        "pressure_ceiling": info["pressure_ceiling"], "node_ceilings": info["node_ceilings"],
        "method": "mujoco:rosenbrock", "mode": "mujoco", "coupling": "rosenbrock", "pbd_blend": False, "dt": DT,
        "duration": facts.duration, "reference": False, "truncated": False, "log": str(tmp_path / "slam.mcap"),
        "keep_log": False,
    }
    row = st.classify(st.run_point(point), None, facts, st.DEFAULT_GRID.tolerance)
    assert row["status"] == "complete", row["message"]
    assert row["class"] != st.CLASS_DIVERGED, row["message"]
    for node, peak in row["peak_pressure"].items():
        assert np.isfinite(peak) and peak <= row["node_ceilings"][node] * st.PRESSURE_BOUND_MARGIN, (node, peak)
