"""Articulated responses carried to every substep's pose (``XpbdOptions(transport_response=True)``,
``sim.plants.pbd_block.block(transport=True)``, ``sim.xpbd.compiled.transport``).

The PBD plant computes the articulated response of the mechanism (row mobilities, group gravity,
motor responses: the group motions of Δq = M⁻¹·Jᵀ, world frame) once per step.  With transport,
each substep applies the same joint-space motion at its own pose, R_k = G_k·G₀⁺·R₀.  Physics checked:

* the group Jacobian G is the derivative of the group positions / orientations with respect to
  the joint coordinates (central differences of the forward kinematics);
* a rigid rotation of the excavator about its vertical swing axis leaves M, the cylinder moment
  arms and the gravity torques unchanged, so the transported responses equal the responses the
  plant computes at the rotated pose (to round-off);
* swinging at 0.5 rad/s, a 60 Hz frame with 50 substeps gives the pressures of 3 kHz frames with
  the same substep much more closely with transport than without (the frame-old responses tilt
  the cylinder and gravity corrections out of the moving boom plane);
* compiled steps, Python hooks and the pure reference agree to round-off with transport on.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from test_pbd_compiled import DIG, assert_states_close
from test_pbd_fast import _compare
from sim.plants.pbd import PbdPlant
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.xpbd import compiled as XC
from reference.pbd_hooks import HooksPlant
from reference.xpbd_plant import pure_plant
from reference.xpbd_substep import ReferenceSolver

SWING = {"swing": 0.5}  # rad/s: the dig's swing speed (≈ 90° in ~3 s)


@pytest.fixture(autouse=True)
def _quiet_xpbd_notes():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")
        yield


def _plant(transport, *, path="compiled", **overrides):
    """The package's plant (``path`` "compiled"), its Python hooks ("hooks") or the pure plant of the oracles
    ("pure", ``tests/reference``)."""
    scenario = load_scenario(DIG).with_overrides(mode="pbd", **overrides)
    if path == "compiled":
        plant = PbdPlant(load_scene(scenario))
    elif path == "hooks":
        plant = HooksPlant(load_scene(scenario))
    else:
        plant = pure_plant(HooksPlant(load_scene(scenario)))
    plant.solver.transport_response = transport  # (the compiled block of the plant's steps follows it)
    return plant


def _jacobian(plant, state):
    solver = plant.solver
    fm = solver._flat
    x, q, _, _ = solver._gather(state)
    G = np.zeros((x.shape[0], 6, len(fm.jt)))
    assert XC.group_jacobian(x, q, fm.IM, fm.jt, fm.jg, fm.jvec, G)
    return G, x, q


def _oracle(plant):
    """The pure solver of the oracles on the plant's model, with the articulated response transport."""
    ref = ReferenceSolver(plant.xmodel, plant.solver.options, length_constraints=plant.solver.rows)
    ref.transport_response = True
    return ref


def _responses(plant):
    plant.articulated()
    return [*plant._mobility, plant._group_gravity, *plant._motor_response]


def test_group_jacobian_is_the_derivative_of_the_forward_kinematics():
    plant = _plant(False)
    xm = plant.xmodel
    qpos = plant.joint_state()[0].copy()
    G, _, _ = _jacobian(plant, plant.state)
    G_pure = _oracle(plant)._group_jacobian(*[a.tolist() for a in plant.solver._gather(plant.state)[:2]])
    np.testing.assert_allclose(G_pure, G, rtol=0, atol=1e-12)
    eps = 1e-6
    for j in range(xm.njnt):
        poses = []
        for s in (1.0, -1.0):
            qp = qpos.copy()
            qp[xm.jnt_qposadr[j]] += s * eps
            poses.append(plant.solver._gather(xm.state_from_qpos(qp))[:2])
        (xa, qa), (xb, qb) = poses
        lin = (xa - xb) / (2 * eps)
        dq = np.array([(a * np.array([1, -1, -1, -1])) for a in qb])  # conj(q_b)
        rel = np.array([_qmul(a, b) for a, b in zip(qa, dq)])  # q_a ⊗ q_b⁻¹ ≈ exp(ω·2ε/2)
        ang = 2.0 * rel[:, 1:] / (2 * eps)
        dyn = xm.group_dynamic
        np.testing.assert_allclose(G[dyn, :3, j], lin[dyn], atol=1e-6)
        np.testing.assert_allclose(G[dyn, 3:, j], ang[dyn], atol=1e-6)


def _qmul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def test_transport_of_a_rigid_swing_is_the_response_at_the_rotated_pose():
    start = _plant(True)
    qpos0 = start.joint_state()[0]
    names = list(start.joint_names)
    rotated_q = {n: float(v) for n, v in zip(names, qpos0)}
    rotated_q["swing"] = 0.7  # rad
    rotated = _plant(False, qpos=rotated_q, equilibrium=False)
    G0, x0, q0 = _jacobian(start, start.state)
    P0 = np.zeros((G0.shape[2], G0.shape[0] * 6))
    assert XC.jacobian_pinv(G0, P0)
    G1, _, _ = _jacobian(rotated, rotated.state)
    P_pure = _oracle(start)._transport_start(x0.tolist(), q0.tolist())
    np.testing.assert_allclose(P_pure, P0, rtol=0, atol=1e-9 * np.max(np.abs(P0)))
    for r0, r1 in zip(_responses(start), _responses(rotated)):
        out = np.zeros_like(r0)
        XC.transport(G1, P0, r0, out)
        scale = np.max(np.abs(r1))
        assert np.max(np.abs(out - r1)) <= 1e-9 * scale
        # the response itself did turn (by 0.7 rad): without transport it would be this far off
        assert np.max(np.abs(r0 - r1)) > 0.1 * scale


def _pressures(dt, substeps, transport, duration=0.5):
    plant = _plant(transport, dt=dt, pbd_substeps=substeps, qvel=SWING)
    every = round((1 / 60) / dt)
    out = []
    for k in range(round(duration / dt)):
        assert plant.step().success
        if (k + 1) % every == 0:
            out.append(plant.net_state.node_pressure.copy())
    names = plant.network.node_names
    front = [names.index(f"{c}_cyl_{s}") for c in ("boom", "stick", "bucket") for s in ("cap", "rod")]
    return np.array(out)[:, front]


def test_transport_makes_a_60hz_frame_match_fine_frames_while_swinging():
    fine = _pressures(1 / 3000, 1, False)  # 3 kHz frames of one substep: nothing is older than a substep
    err_old = np.max(np.abs(_pressures(1 / 60, 50, False) - fine))  # same substep, responses one frame old
    err_new = np.max(np.abs(_pressures(1 / 60, 50, True) - fine))
    assert err_new < 0.3 * err_old, (err_new, err_old)  # measured 0.0073 vs 0.046 bar


def test_transported_frame_agrees_with_hooks_and_pure():
    # a gentle swing + boom motion: at 0.5 rad/s the closed swing valve's cross-over relief switches, which
    # amplifies round-off (compiled vs pure 1e-4 after 15 steps with or without transport); at 0.1 rad/s the swing
    # motor (≈ 18 rad/s), linearised at its own speed, differs between the paths by 1e-8 relative from frame 7 (its
    # Newton solves end within their tolerance, not at round-off); at 0.02 rad/s the paths agree to 1e-9 for 27
    # frames
    frames = 24
    overrides = dict(dt=1 / 60, pbd_substeps=10, qvel={"swing": 0.02, "boom": 0.05})
    fast = _plant(True, **overrides)
    hooks = _plant(True, path="hooks", **overrides)
    pure = _plant(True, path="pure", **overrides)
    plain = _plant(False, **overrides)
    assert fast.fast and not hooks.fast and isinstance(pure.solver, ReferenceSolver)
    for _ in range(frames):
        r_fast, r_hooks, r_pure = fast.step(), hooks.step(), pure.step()
        plain.step()
        _compare(hooks, fast, r_hooks, r_fast, f"frame vs hooks t={fast.time:.4f}")
        assert_states_close(pure.state, fast.state, f"frame vs pure t={fast.time:.4f}")
    assert fast.frame_steps == frames
    # transport is exercised: the state differs from the untransported run far above round-off
    assert np.max(np.abs(plain.state.x - fast.state.x)) > 1e-6  # measured 1.38e-6 m
