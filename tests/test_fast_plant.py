"""MujocoPlantFast (coupled steps inside mj_step) agrees with MujocoPlant step by step, to round-off."""

import mujoco
import numpy as np
import pytest

from conftest import MODELS
from hydraulics._compiled import compiled_available
from sim.plants.mujoco import MujocoPlant
from sim.io.scenario import Schedule, load_scenario
from sim.io.scene import load_scene

pytestmark = pytest.mark.skipif(not compiled_available(), reason="numba is not installed")

QPOS_ATOL = 1e-9  # rad or m
STROKE_ATOL = 1e-10  # m
PRESSURE_RTOL, PRESSURE_ATOL = 1e-9, 1e-2  # -, Pa
ENERGY_RTOL, ENERGY_ATOL = 1e-8, 1e-6  # -, J


def ramp(t0, t1, value):
    return Schedule(np.array([0.0, t0, t1]), np.array([0.0, 0.0, value]))


# valves move within the first few hundred steps
CASES = {
    "seed": (MODELS / "seed_cylinder" / "closed.scenario.toml", {}, 120),
    "boom": (MODELS / "boom" / "lift.scenario.toml", {"boom_valve": ramp(0.02, 0.08, 1.0)}, 300),
    "excavator": (
        MODELS / "excavator" / "dig.scenario.toml",
        {"boom_valve": ramp(0.02, 0.08, -0.35), "stick_valve": ramp(0.03, 0.1, 0.8),
         "bucket_valve": ramp(0.05, 0.12, 0.5), "swing_valve": ramp(0.02, 0.1, 1.0)},
        300,
    ),
    # two hydraulic substeps per MuJoCo step (the callback interpolates the actuator motion)
    "boom/2 substeps": (MODELS / "boom" / "lift.scenario.toml", {"boom_valve": ramp(0.02, 0.08, 1.0)}, 150),
}
OVERRIDES = {"boom/2 substeps": {"hydraulic_substeps": 2}}
# the linearly implicit finish (coupling "implicit-linear", plant constructor argument), and with a
# one-Newton-step linearisation too (coupling "rosenbrock")
for _name in ("seed", "boom", "excavator"):
    for _coupling in ("implicit-linear", "rosenbrock"):
        CASES[f"{_name}/{_coupling}"] = CASES[_name]
COUPLING = {name: name.split("/")[1] for name in CASES if name.endswith(("/implicit-linear", "/rosenbrock"))}


def plants(case):
    from sim.plants.mujoco_fast import MujocoPlantFast

    path, inputs, steps = CASES[case]
    scenario = load_scenario(path)
    if inputs:
        scenario = scenario.with_overrides(inputs={**scenario.inputs, **inputs})
    # the implicit coupling in the scenario; the linear couplings through the plants' constructor argument
    scenario = scenario.with_overrides(coupling="implicit", **OVERRIDES.get(case, {}))
    coupling = COUPLING.get(case)
    reference = MujocoPlant(load_scene(scenario), coupling=coupling)
    fast = MujocoPlantFast(load_scene(scenario), coupling=coupling)
    assert fast.fast and fast.coupling.name == reference.coupling.name == (coupling or "implicit")
    return reference, fast, steps


def assert_same(reference, fast, newton_scale=False):
    """``newton_scale``: the warm start and the flows compared on the scale of the Newton tolerance (lines at rest:
    the leakage flows of ~1e-8 m³/s and the hose segments' oil changes follow pressures that both plants accept
    within the tolerance, 1e-2 Pa, without a Newton iteration, from starts that differ at that level)."""
    a, b = reference, fast
    change_rtol = 0.1 if newton_scale else 1e-8
    assert a.step_index == b.step_index and a.time == b.time
    np.testing.assert_allclose(b.data.qpos, a.data.qpos, rtol=0, atol=QPOS_ATOL)
    np.testing.assert_allclose(b.net_state.actuator_position, a.net_state.actuator_position, rtol=0, atol=STROKE_ATOL)
    np.testing.assert_allclose(b.net_state.node_pressure, a.net_state.node_pressure, rtol=PRESSURE_RTOL, atol=PRESSURE_ATOL)
    np.testing.assert_allclose(b.net_state.valve_spool, a.net_state.valve_spool, rtol=0, atol=1e-12)
    # the warm start of the next linearisation (NetworkState.node_oil_change) is carried across blocks
    # (a difference of two oils: its round-off is the oils', ~1e-16·|m|)
    free = np.isfinite(a.net_state.node_oil)
    change, oil = np.broadcast_to(a.net_state.flat_oil_change(), free.shape)[free], a.net_state.node_oil[free]
    np.testing.assert_allclose(b.net_state.node_oil_change[free], change, rtol=0,
                               atol=change_rtol * np.abs(change).max() + 1e-14 * np.abs(oil).max())
    np.testing.assert_allclose(b.control.valve_command, a.control.valve_command, rtol=0, atol=0)
    np.testing.assert_allclose(b.theta, a.theta, rtol=0, atol=1e-9)
    scale = np.abs(a.effort).max() + 1.0
    np.testing.assert_allclose(b.effort, a.effort, rtol=0, atol=1e-9 * scale)
    for name in ("pump_work", "motor_work", "dissipated_hydraulic", "dissipated_friction", "dissipated_mechanical"):
        np.testing.assert_allclose(getattr(b.energy, name), getattr(a.energy, name), rtol=ENERGY_RTOL, atol=ENERGY_ATOL)
    assert b.last_report.success
    assert b.last_report.newton_iterations == a.last_report.newton_iterations
    flow_atol = 1e-3 * np.abs(a.last_report.branch_flow).max(initial=0.0) if newton_scale else 1e-12
    np.testing.assert_allclose(b.last_report.branch_flow, a.last_report.branch_flow, rtol=1e-8, atol=flow_atol)


@pytest.mark.parametrize("case", list(CASES))
def test_fast_plant_matches_python_plant(case):
    """Uneven blocks (1, 7, 50, …) so block boundaries fall everywhere; compared after every block."""
    reference, fast, steps = plants(case)
    blocks = [1, 7, 50, 1, 13, 100]
    done, i = 0, 0
    moved = False
    peak, low = reference.net_state.node_pressure.copy(), reference.net_state.node_pressure.copy()
    while done < steps:
        n = min(blocks[i % len(blocks)], steps - done)
        i += 1
        for _ in range(n):
            reference.step()
            np.maximum(peak, reference.net_state.node_pressure, out=peak)
            np.minimum(low, reference.net_state.node_pressure, out=low)
        report = fast.advance(n)
        done += n
        assert report.success
        assert_same(reference, fast)
        # running extremes over every step, not only the block ends
        np.testing.assert_allclose(fast.node_pressure_max, peak, rtol=PRESSURE_RTOL, atol=PRESSURE_ATOL)
        np.testing.assert_allclose(fast.node_pressure_min, low, rtol=PRESSURE_RTOL, atol=PRESSURE_ATOL)
        moved |= bool(np.any(fast.control.valve_command != 0))
    assert moved or case.startswith("seed")
    if case in OVERRIDES:
        assert fast.coupling.stepper.substeps == 2
    assert mujoco.get_mjcb_control() is None  # the callback is only installed inside advance()


def test_step_is_advance_one_and_callback_restored():
    reference, fast, _ = plants("boom")

    def other(m, d):  # a Python callback someone else installed
        pass

    mujoco.set_mjcb_control(other)
    try:
        for _ in range(5):
            reference.step()
            fast.step()
        assert mujoco.get_mjcb_control() is other
    finally:
        mujoco.set_mjcb_control(None)
    assert_same(reference, fast)


def test_newton_failure_reported_at_the_same_step(monkeypatch):
    """With the Newton limit cut to 1 (packed at construction) a valve slam fails in the same step and with the same
    message in both plants; the fast plant's network state, time and step index point at that step."""
    from hydraulics import numerics
    from sim.plants.mujoco_fast import MujocoPlantFast

    monkeypatch.setattr(numerics, "NEWTON_MAX_ITERATIONS", 1)
    scenario = load_scenario(MODELS / "boom" / "lift.scenario.toml")
    slam = Schedule(np.array([0.0, 0.01, 0.011]), np.array([0.0, 0.0, 1.0]))
    scenario = scenario.with_overrides(inputs={**scenario.inputs, "boom_valve": slam}, coupling="implicit")
    reference, fast = MujocoPlant(load_scene(scenario)), MujocoPlantFast(load_scene(scenario))
    assert fast.fast
    for _ in range(100):
        expected = reference.step()
        if not expected.success:
            break
    assert not expected.success
    report = fast.advance(100)
    assert not report.success and report.status == expected.status and report.message == expected.message
    assert fast.step_index == reference.step_index and fast.time == reference.time == fast.net_state.time
    np.testing.assert_allclose(fast.net_state.node_pressure, reference.net_state.node_pressure, rtol=PRESSURE_RTOL,
                               atol=PRESSURE_ATOL)
    assert mujoco.get_mjcb_control() is None


@pytest.mark.parametrize("every", [1, 3])
def test_recorded_rows_are_the_state_after_each_step(every):
    """advance(n, record, every) copies, from inside the compiled loop, exactly (bit for bit) the row record_row()
    gives after each recorded step when the same steps are taken one advance(1) at a time: network state, qpos/qvel,
    efforts, θ, controls, flows, Newton counters, MuJoCo's energies and body poses (excavator, valves moving)."""
    _, a, _ = plants("excavator")
    _, b, _ = plants("excavator")
    width = a.record_width
    a.advance(20)
    b.advance(20)
    blocks = [7, 1, 2, 40, 13]
    for i, n in enumerate(blocks):
        rows = a.record_rows(a.step_index, n, every)
        assert rows == sum(1 for s in range(a.step_index + 1, a.step_index + n) if s % every == 0)
        record = np.full((rows + 1, width), -1.0)
        if i % 2:  # through record_next(), for callers of a wrapped advance(n)
            a.record_next(record, every)
            a.advance(n)
        else:
            a.advance(n, record, every)
        assert a.recorded == rows and a.recorded_finite and a.end_finite == a.finite() is True
        expected = np.empty((rows, width))
        r = 0
        for _ in range(n):
            b.advance(1)
            if r < rows and b.step_index % every == 0:
                b.record_row(expected[r])
                r += 1
        assert r == rows and a.step_index == b.step_index
        assert np.array_equal(record[:rows], expected, equal_nan=True)
        assert np.all(record[rows:] == -1.0)  # nothing past the recorded rows
        end_a, end_b = np.empty(width), np.empty(width)
        a.record_row(end_a)
        b.record_row(end_b)
        assert np.array_equal(end_a, end_b, equal_nan=True)  # blocks and single steps: the same arithmetic
    assert a.advance(5).success and a.recorded == 0  # record_next() applies to one call only
    with pytest.raises(ValueError, match="record"):
        a.advance(5, np.zeros((4, width + 1)), 1)
    with pytest.raises(ValueError, match="record"):
        a.advance(5, np.zeros((3, width)), 1)  # 4 rows needed
    assert mujoco.get_mjcb_control() is None


def test_rosenbrock_steps_end_where_mujoco_put_the_actuators():
    """rosenbrock: a step ends at the actuator coordinates MuJoCo integrated the bodies to, with the pressure law's
    pressures of the end oil there, in both plants (the next step's start evaluation, which the compiled step then
    does not repeat); x + h·v⁺ (the other couplings' end) differs from them by O(h²) only, through the linkage's
    curvature: at 1 ms on the excavator by more than round-off and by less than 1 µm."""
    reference, fast, steps = plants("excavator/rosenbrock")
    net = fast.network
    gap = 0.0
    for n in (1, 1, 7, 50, 13, 1, 40):
        x_start = fast.net_state.actuator_position.copy()
        for _ in range(n):
            reference.step()
        fast.advance(n)
        for plant in (reference, fast):
            state = plant.net_state
            x, _ = plant.actuator_motion()  # MuJoCo's coordinates at the current qpos
            assert np.array_equal(state.actuator_position, x)
            np.testing.assert_allclose(state.node_pressure, net.pressure(state.node_oil, x)[0], rtol=1e-13, atol=0)
        if n == 1:  # one step from x_start: the end x + h·v⁺ the other couplings take
            gap = max(gap, np.abs(fast.net_state.actuator_position
                                  - (x_start + fast.dt * fast.net_state.actuator_velocity)).max())
        assert_same(reference, fast)
    assert 1e-15 < gap < 1e-6


# The explicit coupling, the incompressible fidelity (its effort bounds are MuJoCo's force ranges, set inside the
# callback), rigid actuators around the explicit and implicit couplings and a `lines` network step inside the
# callback too: (scenario, overrides, inputs, coupling, steps).
DIG_INPUTS = CASES["excavator"][1]
RIGID_FRONT = {"stick_cyl": "incompressible", "bucket_cyl": "incompressible", "swing_motor": "incompressible"}
OTHER_CASES = {
    "boom/explicit": (MODELS / "boom" / "lift.scenario.toml", {"dt": 2e-5}, {"boom_valve": ramp(0.0, 0.002, 1.0)},
                      "explicit", 300),
    "boom/explicit/2 substeps": (MODELS / "boom" / "lift.scenario.toml", {"dt": 4e-5, "hydraulic_substeps": 2},
                                 {"boom_valve": ramp(0.0, 0.004, 1.0)}, "explicit", 150),
    "boom/incompressible": (MODELS / "boom" / "lift.scenario.toml", {"fidelity": "incompressible"},
                            {"boom_valve": ramp(0.02, 0.08, 1.0)}, None, 300),
    "excavator/incompressible": (MODELS / "excavator" / "dig.scenario.toml", {"fidelity": "incompressible"}, DIG_INPUTS,
                                 None, 300),
    "excavator/incompressible at 30 Hz": (MODELS / "excavator" / "dig.scenario.toml",
                                          {"fidelity": "incompressible", "dt": 1 / 30}, {}, None, 60),
    "push/incompressible": (MODELS / "excavator" / "push.scenario.toml", {"dt": 1e-2}, {}, None, 200),
    "excavator/lines": (MODELS / "excavator" / "dig.scenario.toml", {"fidelity": "lines"}, DIG_INPUTS, None, 150),
    # rigid stick, bucket and swing among compressible actuators, around the explicit coupling
    "excavator/explicit+rigid": (
        MODELS / "excavator" / "dig.scenario.toml", {"dt": 2e-5, "actuator_fidelity": RIGID_FRONT},
        {"boom_valve": ramp(0.0, 0.001, -0.35), "stick_valve": ramp(0.0, 0.001, 0.8),
         "bucket_valve": ramp(0.0, 0.002, 0.5), "swing_valve": ramp(0.0, 0.001, 1.0)}, "explicit", 200),
    # the same rigid front around the implicit couplings: the supply pressure from the inner linearisation
    "excavator/implicit+rigid": (MODELS / "excavator" / "dig.scenario.toml", {"actuator_fidelity": RIGID_FRONT},
                                 DIG_INPUTS, None, 300),
    "excavator/rosenbrock+rigid": (MODELS / "excavator" / "dig.scenario.toml", {"actuator_fidelity": RIGID_FRONT},
                                   DIG_INPUTS, "rosenbrock", 300),
    "boom/implicit-linear, rigid boom": (MODELS / "boom" / "lift.scenario.toml",
                                         {"actuator_fidelity": {"boom_cyl": "incompressible"}},
                                         {"boom_valve": ramp(0.02, 0.08, 1.0)}, "implicit-linear", 300),
}


def other_plants(case):
    from sim.plants.mujoco_fast import MujocoPlantFast

    path, overrides, inputs, coupling, steps = OTHER_CASES[case]
    scenario = load_scenario(path).with_overrides(coupling=coupling or "implicit", **overrides)
    if inputs:
        scenario = scenario.with_overrides(inputs={**scenario.inputs, **inputs})
    reference = MujocoPlant(load_scene(scenario), coupling=coupling)
    fast = MujocoPlantFast(load_scene(scenario), coupling=coupling)
    assert fast.fast and fast.coupling.name == reference.coupling.name
    return reference, fast, steps


@pytest.mark.parametrize("case", list(OTHER_CASES))
def test_fast_plant_matches_python_plant_for_the_other_couplings(case):
    """As test_fast_plant_matches_python_plant, and the force ranges MuJoCo clamps the efforts to agree."""
    reference, fast, steps = other_plants(case)
    blocks = [1, 7, 50, 1, 13, 100]
    done, i = 0, 0
    clamped = False
    while done < steps:
        n = min(blocks[i % len(blocks)], steps - done)
        i += 1
        for _ in range(n):
            assert reference.step().success
        assert fast.advance(n).success
        done += n
        # (lines: the hose segments' small oil changes agree to the Newton tolerance's share, not to round-off)
        assert_same(reference, fast, newton_scale=case.endswith("lines"))
        np.testing.assert_array_equal(fast.model.actuator_forcelimited, reference.model.actuator_forcelimited)
        np.testing.assert_allclose(fast.model.actuator_forcerange, reference.model.actuator_forcerange, rtol=1e-9,
                                   atol=1e-9 * (np.abs(reference.model.actuator_forcerange).max() + 1.0))
        # (a stalled tracker keeps its force at the start speed TRACKER_BOUND_MARGIN inside its bound, so MuJoCo keeps
        # its implicit term: the stalled boom creeps at 1 mm/s with its force within 3e-5 of the bound)
        clamped |= bool(np.any(reference.model.actuator_forcelimited)) and bool(np.any(
            np.isclose(reference.effort, reference.model.actuator_forcerange[reference.binding.actuator_id].T, rtol=1e-4)))
    if case == "push/incompressible":
        assert clamped  # the boom stalls at its bound
    assert np.any(fast.data.qvel != 0)
    assert mujoco.get_mjcb_control() is None
