"""The PBD plant's compiled hydraulic hooks (``sim/xpbd/hydraulics_nb.py``) against the Python hooks.

Both run the compiled XPBD substep; only the coupling (effort law, network finish, energy ledger) differs:
``FastHydraulics`` (the default on the compiled path) or ``CouplingImplicit.begin/finish`` + ``PlantBase._account``
(the reference, also what ``--pure`` runs).  Same equations and Newton iterations, so a few dozen steps must
agree to round-off: body states to 1e-9 of max(|value|, 1) SI, pressures, efforts, oil and the energy ledger to
1e-9 of their largest magnitude, identical Newton counts.  Scenes: seed, boom lift, excavator dig.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from test_pbd_compiled import BOOM, DIG, SEED, assert_close, assert_states_close
from sim.plant_pbd import PbdPlant
from sim.scenario import load_scenario
from sim.scene import load_scene

FLOW_FLOOR = 1e-4  # m³/s (6 L/min, the circuits' flow scale): near-closed valves' tiny flows carry the pressures' round-off
LEDGER = ("pump_work", "motor_work", "dissipated_hydraulic", "dissipated_friction", "dissipated_mechanical")


@pytest.fixture(autouse=True)
def _quiet_xpbd_notes():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")
        yield


def _plant(path, fast, compiled=True, **overrides):
    scenario = load_scenario(path).with_overrides(mode="pbd", compiled=compiled, **overrides)
    return PbdPlant(load_scene(scenario), fast_hydraulics=fast, frame=False)


def test_fast_hooks_are_the_default_only_on_the_compiled_path():
    assert _plant(BOOM, None)._fast is not None
    assert _plant(BOOM, None, compiled=False)._fast is None
    assert _plant(BOOM, None, coupling="explicit")._fast is None  # another coupling keeps the Python hooks


@pytest.mark.parametrize("path, steps, overrides", [
    (SEED, 40, {}),
    (BOOM, 30, dict(dt=1 / 60, pbd_substeps=10)),
    (DIG, 30, dict(dt=1 / 60, pbd_substeps=10)),
], ids=["seed", "boom", "excavator"])
def test_fast_hooks_agree_with_python_hooks(path, steps, overrides):
    ref, fast = _plant(path, False, **overrides), _plant(path, True, **overrides)
    assert ref._fast is None and fast._fast is not None
    for _ in range(steps):
        r1, r2 = ref.step(), fast.step()
        _compare(ref, fast, r1, r2, f"{path.name} t={ref.time:.4f}")
    assert fast.frame_steps == 0


@pytest.mark.parametrize("path, steps, overrides", [
    (SEED, 40, {}),
    (BOOM, 30, dict(dt=1 / 60, pbd_substeps=10)),
    (DIG, 30, dict(dt=1 / 60, pbd_substeps=10)),
], ids=["seed", "boom", "excavator"])
def test_compiled_frame_agrees_with_python_hooks(path, steps, overrides):
    """The whole step in one compiled call (``sim/xpbd/frame_nb.py``) against the Python hooks."""
    ref = _plant(path, False, **overrides)
    scenario = load_scenario(path).with_overrides(mode="pbd", compiled=True, **overrides)
    fast = PbdPlant(load_scene(scenario), frame=True)
    assert ref._fast is None and fast.frame_compiled
    for _ in range(steps):
        r1, r2 = ref.step(), fast.step()
        _compare(ref, fast, r1, r2, f"{path.name} t={ref.time:.4f}")
    assert fast.frame_steps == steps


def _compare(ref, fast, r1, r2, what):
    assert r1.success and r2.success, what
    assert (r1.newton_iterations, r1.rhs_evaluations, r1.jacobian_evaluations) == (
        r2.newton_iterations, r2.rhs_evaluations, r2.jacobian_evaluations), what
    assert_states_close(ref.state, fast.state, what)
    a, b = ref.net_state, fast.net_state
    assert_close(a.node_pressure, b.node_pressure, f"{what} pressures", floor=np.max(np.abs(a.node_pressure)))
    free = np.isfinite(a.node_oil)
    assert np.array_equal(free, np.isfinite(b.node_oil)), what
    assert_close(a.node_oil[free], b.node_oil[free], f"{what} oil", floor=np.max(np.abs(a.node_oil[free])))
    assert_close(a.valve_spool, b.valve_spool, f"{what} spools")
    assert_close(a.actuator_position, b.actuator_position, f"{what} positions")
    assert_close(a.actuator_velocity, b.actuator_velocity, f"{what} velocities")
    assert a.time == pytest.approx(b.time, rel=1e-12, abs=1e-12)
    assert_close(ref.effort, fast.effort, f"{what} efforts", floor=np.max(np.abs(ref.effort), initial=0.0))
    assert_close(r1.branch_flow, r2.branch_flow, f"{what} flows", floor=max(np.max(np.abs(r1.branch_flow), initial=0.0), FLOW_FLOOR))
    assert_close(ref.control.valve_command, fast.control.valve_command, f"{what} commands")
    # dissipated_mechanical is the efforts' work minus Δ(kinetic + potential): its round-off scales with those
    scale = max(max(abs(getattr(ref.energy, k)) for k in LEDGER), abs(ref.energy.initial_total), abs(ref._mechanical))
    for k in LEDGER:
        assert_close(getattr(ref.energy, k), getattr(fast.energy, k), f"{what} energy {k}", floor=max(scale, 1.0))
