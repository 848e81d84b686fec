"""The package's XPBD substep (numba, ``sim/xpbd/compiled.py``) against the pure substep of the tests (the oracle,
``tests/reference/xpbd_substep.py``; its plant: ``tests/reference/xpbd_plant.py``).

Both evaluate the same equations in the same order, so runs of a few dozen steps must agree to
round-off: positions, orientations and velocities to 1e-9 of max(|value|, 1) in SI units, chamber pressures
and actuator efforts to 1e-9 of their largest magnitude.  Scenes: the seed cylinder, the boom lift, the
excavator dig (start of the cycle) and the excavator with its teeth in the ground (soft pyramidal contacts),
plus rigid-body scenes that exercise the remaining branches (hinge torque impulses, slide and ball joints,
connect equalities, Gauss-Seidel rows with bounds, body wrenches, box contacts, joint damping and limits).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from conftest import MODELS
from sim.plants.pbd import PbdPlant
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.xpbd import LengthConstraint, SolverXPBD, SubstepInputs, XpbdOptions
from reference.pbd_hooks import HooksPlant
from reference.xpbd_plant import pure_plant
from reference.xpbd_substep import ReferenceSolver
from test_xpbd_rigid import BOX, EXC_Q0, EXC_V0, EXCAVATOR, FOURBAR, PENDULUM, SLIDER, G, build

RTOL = 1e-9
SEED = MODELS / "seed_cylinder" / "closed.scenario.toml"
BOOM = MODELS / "boom" / "lift.scenario.toml"
DIG = MODELS / "excavator" / "dig.scenario.toml"
# stick angle at which the excavator's lowest tooth is 1 cm into the ground (boom 0.3, bucket 0.3 rad)
IN_CONTACT = {"swing": 0.0, "boom": 0.30, "stick": -0.3138, "bucket": 0.30}


@pytest.fixture(autouse=True)
def _quiet_xpbd_notes():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")  # notes on features XPBD does not model (none on the stock scenes)
        yield


def assert_close(a, b, what, floor=1.0):
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = max(float(np.max(np.abs(a), initial=0.0)), floor)
    err = float(np.max(np.abs(a - b), initial=0.0))
    assert err <= RTOL * scale, f"{what}: compiled vs pure differ by {err:.3e} (scale {scale:.3e})"


def assert_states_close(sa, sb, what):
    for f in ("x", "q", "v", "w"):
        assert_close(getattr(sa, f), getattr(sb, f), f"{what} {f}")


# ---------------------------------------------------------------------------- plants


def _plant(path, compiled, **overrides):
    """The package's plant (``compiled``) or the pure plant of the oracles."""
    scene = load_scene(load_scenario(path).with_overrides(mode="pbd", **overrides))
    return PbdPlant(scene) if compiled else pure_plant(HooksPlant(scene))


def contact_candidates(plant):
    """Contact candidates of the plant's next step (the solver's own test, which the compiled block repeats)."""
    solver = plant.solver
    return len(solver._collect_contacts(*solver._gather(plant.state), plant.dt))


@pytest.mark.parametrize("path, steps, overrides", [
    (SEED, 40, {}),
    (BOOM, 30, dict(dt=1 / 60, pbd_substeps=10)),
    (DIG, 30, dict(dt=1 / 60, pbd_substeps=10)),
    # in contact the pure run itself amplifies a 1e-13 rad perturbation of the stick to 4e-9 rad/s in 23
    # steps (the pyramids' active sets): 18 steps keep the comparison at round-off (≤ 3e-10 here)
    (DIG, 18, dict(dt=1 / 60, pbd_substeps=10, qpos=IN_CONTACT)),
], ids=["seed", "boom", "excavator", "excavator-contact"])
def test_compiled_plant_agrees_with_pure(path, steps, overrides):
    pure, fast = _plant(path, False, **overrides), _plant(path, True, **overrides)
    assert isinstance(pure.solver, ReferenceSolver) and type(fast.solver) is SolverXPBD
    contacts = 0
    for _ in range(steps):
        pure.step()
        fast.step()
        assert_states_close(pure.state, fast.state, f"{path.name} t={pure.time:.3f}")
        p = pure.net_state.node_pressure
        assert_close(p, fast.net_state.node_pressure, "node pressures", floor=np.max(np.abs(p)))
        assert_close(pure.effort, fast.effort, "efforts", floor=np.max(np.abs(pure.effort)))
        contacts = max(contacts, contact_candidates(pure))
    if "qpos" in overrides:
        assert contacts > 0
        # the teeth really pushed: the bucket was lifted out of its 1 cm penetration against gravity
        assert np.max(np.abs(fast.state.v)) > 1e-3


# ---------------------------------------------------------------------------- rigid-body scenes


def _run_pair(xml, n, dt, substeps, *, qpos=None, qvel=None, inputs=None, rows=(), **kw):
    m, xm = build(xml)
    out = []
    for kind in (ReferenceSolver, SolverXPBD):
        solver = kind(xm, XpbdOptions(substeps=substeps, **kw), length_constraints=rows)
        st = xm.state_from_qpos(qpos, qvel)
        forces = []
        for _ in range(n):
            solver.step(st, dt, inputs=inputs(xm) if callable(inputs) else inputs)
            forces += [f.row_force.copy() for f in solver.last_forces]
        out.append((st, solver, np.array(forces)))
    (sa, _, fa), (sb, solver, fb) = out
    assert_states_close(sa, sb, xml[:40])
    if len(rows):
        assert_close(fa, fb, "row forces", floor=np.max(np.abs(fa)))
    return xm, sa


def test_compiled_3d_chain_with_swing_torque():
    """Hinges, a slide and a ball joint, a hinge torque (impulse + workless pin impulse)."""
    def inputs(xm):
        jf = np.zeros(xm.njnt)
        jf[xm.joint_id("swing")] = 400.0
        return SubstepInputs(joint_force=jf)

    xm, st = _run_pair(EXCAVATOR, 30, 1 / 240, 20, qpos=EXC_Q0, qvel=EXC_V0, inputs=inputs)
    assert abs(xm.qpos_qvel(st)[1][0]) > 1.5  # the torque spun the swing up


def test_compiled_four_bar_connect_equality():
    _run_pair(FOURBAR, 60, 1 / 120, 20)


def test_compiled_length_row_through_a_loop_closure():
    """A compliant length row on the cylinder of tests/scenes/loop_arm.xml (barrel on a hinge, rod on a slide, the
    rod eye held by a connect): with the loop closed, each substep's backward pass ends with the rows again."""
    from pathlib import Path

    xml = (Path(__file__).parent / "scenes" / "loop_arm.xml").read_text()
    inputs = SubstepInputs(target_length=np.array([0.9434]), compliance=np.array([2e-8]))
    xm, st = _run_pair(xml, 30, 1 / 240, 10, inputs=inputs, rows=[LengthConstraint("lift_cyl_barrel", "lift_cyl_rod")])
    assert abs(xm.qpos_qvel(st)[0][xm.joint_id("arm_hinge")]) < 1e-3  # the row holds the arm up


def test_compiled_rope_rows_gauss_seidel_with_bounds():
    """Rows without mobility (Gauss-Seidel), unilateral bound: slack, then taut."""
    inputs = SubstepInputs(target_length=np.array([1.2]), compliance=np.array([0.0]), force_max=np.array([0.0]))
    _run_pair(SLIDER.format(g=-G, m=1.0, damping=0), 60, 1 / 120, 20, inputs=inputs,
              rows=[LengthConstraint("anchor", "tip")])


def test_compiled_explicit_row_force_and_slide_force():
    inputs = SubstepInputs(row_force=np.array([-1.5 * G]), joint_force=np.array([0.3 * G]))
    _run_pair(SLIDER.format(g=-G, m=2.0, damping=0), 30, 1 / 60, 10, inputs=inputs,
              rows=[LengthConstraint("anchor", "tip")])


def test_compiled_damped_pendulum_at_limit():
    xml = PENDULUM.format(d=0.5, m=1.0, ic=0.002, extra='damping="0.3" limited="true" range="-0.2 0.25"')
    _run_pair(xml, 60, 1 / 120, 20, qpos=[0.2], qvel=[3.0])


def test_compiled_box_lands_on_soft_pyramidal_contacts():
    """Tilted box dropped on the floor: the corners' soft pyramidal contacts, solved per body pair."""
    xml = BOX.format(mu=0.8, x0=0, z0=0.08, ex=6, ey=-4, sites="")
    xm, st = _run_pair(xml, 40, 1 / 60, 20)
    b = xm.body_id("box")
    assert abs(st.x[b, 2] - 0.05) < 1e-3  # it landed and rests on its largest face


ELLIPTIC = BOX.replace("<mujoco>", '<mujoco><option cone="elliptic"/>', 1)


@pytest.mark.parametrize("xml, options", [
    (ELLIPTIC.format(mu=0.8, x0=0, z0=0.08, ex=6, ey=-4, sites=""), {}),
    (BOX.format(mu=0.8, x0=0, z0=0.08, ex=6, ey=-4, sites="").replace('friction="0.8"/>', 'friction="0.8" condim="1"/>'), {}),
    (BOX.format(mu=0.0, x0=0, z0=0.08, ex=6, ey=-4, sites=""), {}),
    (BOX.format(mu=0.8, x0=0, z0=0.08, ex=6, ey=-4, sites=""), dict(soft_contacts=False)),
    (BOX.format(mu=0.8, x0=0, z0=0.08, ex=6, ey=-4, sites=""), dict(pyramid_friction=False)),
], ids=["elliptic", "condim-1", "frictionless", "rigid", "coulomb"])
def test_compiled_box_lands_on_every_other_contact_kind(xml, options):
    """The tilted box dropped on the floor with the contacts that are not soft pyramidal: a soft normal row with
    Coulomb friction (elliptic cone, condim 1, pyramids off), rigid rows (μ = 0 on the pyramidal cone: R = 0; soft
    contacts off); the package's solver and the oracle agree to round-off, and the box comes to rest on its
    largest face (within its soft penetration)."""
    xm, st = _run_pair(xml, 40, 1 / 60, 20, **options)
    b = xm.body_id("box")
    assert abs(st.x[b, 2] - 0.05) < 2e-3
    assert np.max(np.abs(st.v[b])) < 0.05  # [m/s]: at rest


def test_compiled_body_wrench():
    xml = """<mujoco><option gravity="0 0 0"/><worldbody>
      <body name="b" pos="0 0 1"><freejoint/>
        <inertial pos="0.1 0 0" mass="2" diaginertia="0.1 0.2 0.3"/></body>
      </worldbody></mujoco>"""

    def inputs(xm):
        wrench = np.zeros((xm.nbody, 6))
        wrench[xm.body_id("b")] = [1.0, -2.0, 0.5, 0.03, -0.02, 0.06]
        return SubstepInputs(body_wrench=wrench)

    xm, st = _run_pair(xml, 30, 1 / 60, 10, inputs=inputs)
    assert math.isclose(st.v[xm.body_id("b"), 0], 0.25, rel_tol=1e-9)  # F t / m
