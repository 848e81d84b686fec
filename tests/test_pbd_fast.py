"""The PBD plant's compiled steps (``sim/plants/pbd_block.py``) against its Python hooks.

The compiled steps run each coupling's begin and finish (``sim/plants/pbd_hydraulics.py``) and the XPBD substep
(``sim/plants/pbd_frame.py``) in one call; the Python hooks call the couplings' Python methods around
``SolverXPBD.step`` (the reference).  Same equations and Newton iterations, so a few dozen steps must agree to
round-off: body states to 1e-9 of max(|value|, 1) SI, pressures, efforts, oil and the energy ledger to 1e-9 of
their largest magnitude, identical Newton counts.  Every compiled coupling (implicit, implicit-linear, rosenbrock
with and without the θ-rule, explicit, the seed's pbd-naive, incompressible, rigid actuators around implicit and
explicit) on the seed, boom and excavator, and mechanisms unlike them: a free base welded to the world (H-link),
a connect loop closure, a motor on a slide joint with and without a pendulum on a ball joint.

The compiled per-step conversions outside the frame (``sim/xpbd/compiled.py``: ``gather``, ``contact_candidates``,
``qpos_qvel``, ``body_frames``, ``energies``) and ``PbdPlant.articulated`` (``pbd_frame._articulated``) against
their numpy oracles (``tests/reference/xpbd_model.py``, ``xpbd_substep.py``, ``xpbd_plant.py``), to 1e-12 SI, on
the excavator through its first ground contact and on a chain of free, ball, slide and hinge joints (round trip
qpos/qvel → body state → qpos/qvel).
"""

from __future__ import annotations

import copy
import warnings
from pathlib import Path

import numpy as np
import pytest

from test_pbd_compiled import BOOM, DIG, SEED, assert_close, assert_states_close
from hydraulics.coupling import SCHEME_NEWTON
from sim.plants.pbd import PbdPlant
from sim.io.scenario import Schedule, ScenarioError, load_scenario
from sim.io.scene import load_scene
from reference import xpbd_model as oracle
from reference.pbd_hooks import HooksPlant
from reference.xpbd_plant import articulated as articulated_numpy
from reference.xpbd_substep import ReferenceSolver

SCENES = Path(__file__).parent / "scenes"
FLOW_FLOOR = 1e-4  # m³/s (6 L/min, the circuits' flow scale): near-closed valves' tiny flows carry the pressures' round-off
# A linear finish (implicit-linear, rosenbrock) has no Newton solve that smooths the round-off of the predicted oil:
# 5e-13 m³/s seen on the excavator, so its flows are compared on the pumps' flow scale (60 L/min).
LINEAR_FLOW_FLOOR = 1e-3  # m³/s
LEDGER = ("pump_work", "motor_work", "dissipated_hydraulic", "dissipated_friction", "dissipated_mechanical")


@pytest.fixture(autouse=True)
def _quiet_xpbd_notes():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")
        yield


def test_compiled_steps_take_every_compiled_coupling_and_refuse_the_others():
    for overrides in ({}, dict(coupling="explicit"), dict(fidelity="incompressible"), dict(coupling="rosenbrock")):
        plant = PbdPlant(load_scene(load_scenario(BOOM).with_overrides(mode="pbd", **overrides)))
        assert plant.fast and plant._net.kind is not None, overrides
    # a coupling with another stepper than its own has no PBD step: refused, naming the file and the field
    scenario = load_scenario(BOOM).with_overrides(mode="pbd", coupling="explicit", stepper="implicit_euler")
    with pytest.raises(ScenarioError, match=r"lift\.scenario\.toml, field 'run\.stepper': PBD mode steps"):
        PbdPlant(load_scene(scenario))
    assert HooksPlant(load_scene(scenario)).step().success  # (the Python hooks take it)


def test_cli_refuses_a_stepper_pbd_mode_has_no_step_for(tmp_path, capsys):
    """``hydroplant run`` in PBD mode with the ``reference`` stepper: exit 2, one line naming the file and the
    field, no log written."""
    from sim import cli

    for f in BOOM.parent.iterdir():
        if f.is_file():
            (tmp_path / f.name).write_bytes(f.read_bytes())
    scenario = tmp_path / BOOM.name
    scenario.write_text(scenario.read_text().replace("[run]\n", '[run]\nstepper = "reference"\n', 1))
    try:
        code = cli.main(["run", str(scenario), "--mode", "pbd", "--out", str(tmp_path / "run.mcap")])
    except SystemExit as exc:
        code = exc.code
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1, (code, err)
    assert f"{scenario}, field 'run.stepper'" in err[0] and "'reference' has no PBD step" in err[0]
    assert not list(tmp_path.glob("*.mcap*"))


def _ramp(t0, t1, value):
    return Schedule(np.array([0.0, t0, t1]), np.array([0.0, 0.0, value]))


RIGID_FRONT = {"stick_cyl": "incompressible", "bucket_cyl": "incompressible", "swing_motor": "incompressible"}
DIG_INPUTS = {"boom_valve": _ramp(0.01, 0.05, -0.35), "stick_valve": _ramp(0.01, 0.06, 0.8),
              "bucket_valve": _ramp(0.02, 0.07, 0.5), "swing_valve": _ramp(0.01, 0.05, 1.0)}
WINCH, WINCH_PENDULUM = SCENES / "winch.scenario.toml", SCENES / "winch_pendulum.scenario.toml"
COMPILED_CASES = {  # scenario, overrides, inputs, steps
    "seed": (SEED, {}, None, 40),
    "boom": (BOOM, dict(dt=1 / 60, pbd_substeps=10), None, 30),
    "excavator": (DIG, dict(dt=1 / 60, pbd_substeps=10), None, 30),
    "boom-rosenbrock-blend": (BOOM, dict(dt=1e-3, pbd_substeps=2, coupling="rosenbrock", pbd_blend=True), None, 30),
    "excavator-linear-blend": (DIG, dict(dt=1 / 60, pbd_substeps=10, coupling="implicit-linear", pbd_blend=True),
                               None, 30),
    "excavator-rosenbrock-blend": (DIG, dict(dt=1 / 60, pbd_substeps=10, coupling="rosenbrock", pbd_blend=True),
                                   None, 30),
    "seed-naive": (SEED, dict(mode="pbd-naive", dt=1e-5), None, 40),
    "boom-explicit": (BOOM, dict(dt=2e-5, coupling="explicit"), {"boom_valve": _ramp(0.0, 0.002, 1.0)}, 40),
    "excavator-incompressible": (DIG, dict(fidelity="incompressible", dt=1 / 60, pbd_substeps=10), DIG_INPUTS, 12),
    "excavator-implicit+rigid": (DIG, dict(actuator_fidelity=RIGID_FRONT, dt=1e-3, pbd_substeps=2), DIG_INPUTS, 80),
    "excavator-explicit+rigid": (DIG, dict(actuator_fidelity=RIGID_FRONT, dt=2e-5, coupling="explicit"), DIG_INPUTS,
                                 40),
    # other mechanisms: a free base welded to the world (H-link), a connect loop closure, slide motors
    "hlink": (SCENES / "hlink.scenario.toml", dict(dt=1 / 60, pbd_substeps=10), None, 12),
    "loop-closure": (SCENES / "hold.scenario.toml", dict(dt=1 / 60, pbd_substeps=10), None, 12),
    "winch": (WINCH, {}, None, 200),
    "winch-pendulum": (WINCH_PENDULUM, {}, None, 200),
    "winch-pendulum-incompressible": (WINCH_PENDULUM, dict(fidelity="incompressible", dt=1 / 60, pbd_substeps=10),
                                      None, 12),
    "winch-pendulum-explicit": (WINCH_PENDULUM, dict(coupling="explicit", dt=1e-4), None, 200),
    "hlink-naive": (SCENES / "hlink.scenario.toml", dict(mode="pbd-naive", dt=1e-5), None, 40),
}


@pytest.mark.parametrize("case", list(COMPILED_CASES))
def test_compiled_steps_agree_with_python_hooks(case):
    """Whole steps in one compiled call (``sim/plants/pbd_block.py``) against the Python hooks with the
    couplings' Python methods, for every coupling the compiled steps cover and mechanisms unlike ours."""
    path, overrides, inputs, steps = COMPILED_CASES[case]
    overrides = dict(overrides)
    scenario = load_scenario(path).with_overrides(mode=overrides.pop("mode", "pbd"), **overrides)
    if inputs:
        scenario = scenario.with_overrides(inputs={**scenario.inputs, **inputs})
    naive = scenario.mode == "pbd-naive"
    ref = HooksPlant(load_scene(scenario), naive=naive)
    fast = PbdPlant(load_scene(scenario), naive=naive)
    assert not ref.fast and fast.fast
    for _ in range(steps):
        r1, r2 = ref.step(), fast.step()
        _compare(ref, fast, r1, r2, f"{case} t={ref.time:.4f}")
    assert fast.frame_steps == steps


def _compare(ref, fast, r1, r2, what):
    linear = getattr(ref.coupling, "scheme", SCHEME_NEWTON) != SCHEME_NEWTON
    floor = LINEAR_FLOW_FLOOR if linear else FLOW_FLOOR
    assert r1.success and r2.success, what
    assert (r1.newton_iterations, r1.rhs_evaluations, r1.jacobian_evaluations) == (
        r2.newton_iterations, r2.rhs_evaluations, r2.jacobian_evaluations), what
    assert_states_close(ref.state, fast.state, what)
    a, b = ref.net_state, fast.net_state
    assert_close(a.node_pressure, b.node_pressure, f"{what} pressures", floor=np.max(np.abs(a.node_pressure)))
    free = np.isfinite(a.node_oil)
    assert np.array_equal(free, np.isfinite(b.node_oil)), what
    assert_close(a.node_oil[free], b.node_oil[free], f"{what} oil", floor=np.max(np.abs(a.node_oil[free])))
    # the warm start is one step's oil change, dt·(net inflow): compared on the flows' scale times the step
    # (none: no oil states at the incompressible fidelity)
    change, other = (np.broadcast_to(state.flat_oil_change(), state.node_oil.shape)[free] for state in (a, b))
    assert_close(change, other, f"{what} oil change",
                 floor=max(np.max(np.abs(change)), ref.dt * floor))
    assert_close(a.valve_spool, b.valve_spool, f"{what} spools")
    assert_close(a.actuator_position, b.actuator_position, f"{what} positions")
    assert_close(a.actuator_velocity, b.actuator_velocity, f"{what} velocities")
    assert a.time == pytest.approx(b.time, rel=1e-12, abs=1e-12)
    assert_close(ref.effort, fast.effort, f"{what} efforts", floor=np.max(np.abs(ref.effort), initial=0.0))
    assert_close(ref.theta, fast.theta, f"{what} θ")
    assert_close(r1.branch_flow, r2.branch_flow, f"{what} flows", floor=max(np.max(np.abs(r1.branch_flow), initial=0.0), floor))
    assert_close(ref.control.valve_command, fast.control.valve_command, f"{what} commands")
    # dissipated_mechanical is the efforts' work minus Δ(kinetic + potential): its round-off scales with those
    scale = max(max(abs(getattr(ref.energy, k)) for k in LEDGER), abs(ref.energy.initial_total), abs(ref._mechanical))
    for k in LEDGER:
        assert_close(getattr(ref.energy, k), getattr(fast.energy, k), f"{what} energy {k}", floor=max(scale, 1.0))


# ---------------------------------------------------------------------------- per-step observations


def _observations_agree(xm, solver, state, dt, what):
    """compiled.gather etc. against the numpy reference on one state: group gather, contact candidates and their
    flat rows, generalized coordinates, body frames, energies (1e-12 of max(|value|, 1) SI)."""
    tol = dict(rtol=0.0, atol=1e-12)
    qpos, qvel = xm.qpos_qvel(state)
    qpos_ref, qvel_ref = oracle.qpos_qvel(xm, state)
    scale = max(1.0, np.max(np.abs(qvel_ref), initial=0.0))
    np.testing.assert_allclose(qpos, qpos_ref, err_msg=f"{what} qpos", **tol)
    np.testing.assert_allclose(qvel / scale, qvel_ref / scale, err_msg=f"{what} qvel", **tol)
    for a, b in zip(xm.body_frames(state), oracle.body_frames(xm, state)):
        np.testing.assert_allclose(a, b, err_msg=f"{what} body frames", **tol)
    kin, pot = xm.energies(state)
    kin_ref, pot_ref = oracle.kinetic_energy(xm, state), oracle.potential_energy(xm, state)
    e_scale = max(1.0, abs(kin_ref), abs(pot_ref))
    assert abs(kin - kin_ref) <= 1e-12 * e_scale and abs(pot - pot_ref) <= 1e-12 * e_scale, what
    assert (xm.kinetic_energy(state), xm.potential_energy(state)) == (kin, pot)
    out = []
    for s in (solver, ReferenceSolver(xm, solver.options, length_constraints=solver.rows)):
        g = s._gather(state)
        cands = s._collect_contacts(*g, dt)
        out.append((g, cands, list(s._cidx)))
    (g1, c1, i1), (g2, c2, i2) = out
    for a, b in zip(g1, g2):
        np.testing.assert_allclose(a, b, err_msg=f"{what} gather", **tol)
    assert c1 == c2 and i1 == i2, what
    mine, ref = copy.deepcopy(state), copy.deepcopy(state)
    solver._scatter(*g1, mine)  # compiled.scatter against the numpy oracle's
    ReferenceSolver._scatter(solver, *g1, ref)
    for f in ("x", "q", "v", "w"):
        np.testing.assert_allclose(getattr(mine, f), getattr(ref, f), err_msg=f"{what} scatter {f}", **tol)
    return len(i1)


def test_compiled_observations_agree_with_numpy_through_contact():
    """The excavator dig at 60 Hz × 10 until its teeth are in the ground (≈ 1.6 s): the compiled per-step
    conversions give the numpy reference's values at every 5th step."""
    plant = PbdPlant(load_scene(load_scenario(DIG).with_overrides(mode="pbd", dt=1 / 60, pbd_substeps=10)))
    xm = plant.xmodel
    candidates = 0
    for k in range(150):
        assert plant.step().success
        if k % 5 == 0:
            candidates += _observations_agree(xm, plant.solver, plant.state, plant.dt, f"t={plant.time:.3f}")
            _articulated_agrees(plant, f"t={plant.time:.3f}")
    assert candidates > 0  # contact candidates were compared


def _articulated_agrees(plant, what):
    """``PbdPlant.articulated`` (compiled) against the numpy oracle at the plant's state (1e-12 relative)."""
    names = ("_mobility", "_group_gravity", "_effective_mass", "_motor_response", "_motor_inverse_inertia")
    plant.articulated()
    got = [getattr(plant, n) for n in names]
    articulated_numpy(plant)
    ref = [getattr(plant, n) for n in names]
    plant.articulated()  # the plant's own data again
    for name, a, b in zip(names, got, ref):
        assert (a is None) == (b is None), f"{what} {name}"
        if a is not None:
            scale = max(1.0, float(np.max(np.abs(b[np.isfinite(b)]), initial=0.0)))
            np.testing.assert_allclose(a / scale, b / scale, rtol=0, atol=1e-12, err_msg=f"{what} {name}")


_JOINTS_MJCF = """
<mujoco>
  <worldbody>
    <body name="free" pos="0 0 1"><freejoint/><geom type="box" size=".2 .1 .05" mass="3"/>
      <body name="ball" pos=".3 0 0" quat="0.9 0.1 0.3 0.2"><joint type="ball" pos="-.05 0 0"/>
        <geom type="capsule" fromto="0 0 0 .3 0 0" size=".03" mass="1"/>
        <body name="slide" pos=".3 .1 0" quat="0.8 0.2 -0.1 0.4"><joint type="slide" axis="0.3 0.5 0.8"/>
          <geom type="sphere" size=".05" pos=".02 .01 0" mass=".5"/>
          <body name="hinge" pos="0 .2 0"><joint type="hinge" axis="0 0.6 0.8" pos=".05 0 0"/>
            <geom type="box" size=".1 .02 .02" pos=".1 0 0" mass=".7"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_compiled_generalized_coordinates_round_trip_every_joint_type():
    """Free, ball, slide and hinge joints: qpos/qvel → body state (forward kinematics) → qpos/qvel recovers
    them (hinge angles beyond ±π unwrapped by the hint), compiled and numpy alike."""
    import mujoco

    from sim.xpbd.model import XpbdModel

    xm = XpbdModel.from_mjmodel(mujoco.MjModel.from_xml_string(_JOINTS_MJCF), warn=False)
    rng = np.random.default_rng(7)
    for trial in range(20):
        qpos = np.array(xm.qpos0, dtype=float)
        qpos[:3] += rng.normal(size=3)
        free_q = rng.normal(size=4)
        qpos[3:7] = free_q / np.linalg.norm(free_q)
        ball_q = rng.normal(size=4)
        ball_q[0] = abs(ball_q[0])
        qpos[7:11] = ball_q / np.linalg.norm(ball_q)
        qpos[11] = rng.uniform(-0.5, 0.5)  # slide [m]
        qpos[12] = rng.uniform(-9.0, 9.0)  # hinge [rad], multi-turn
        qvel = rng.normal(size=xm.nv)
        state = xm.state_from_qpos(qpos, qvel)
        got = xm.qpos_qvel(state)
        ref = oracle.qpos_qvel(xm, state)
        for a, b, c, name in zip(got, ref, (qpos, qvel), ("qpos", "qvel")):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12, err_msg=f"trial {trial} {name} compiled vs numpy")
            np.testing.assert_allclose(a, c, rtol=0, atol=1e-9, err_msg=f"trial {trial} {name} round trip")
