"""Soft joint limits of the XPBD solver follow MuJoCo's soft-constraint law (solref/solimp).

MuJoCo is the reference (mj_forward for its constraint parameters, mj_step for the motion); the
XPBD solver never calls MuJoCo dynamics.  Units SI: angles [rad], torques [N·m], lengths [m].
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim.xpbd import SolverXPBD, SubstepInputs, XpbdModel, XpbdOptions
from reference.xpbd_laws import mujoco_limit_law
from reference.xpbd_substep import ReferenceSolver

# a 10 kg arm along +x hinged at the origin (axis +y: gravity turns it towards +φ), upper limit at φ = 0
ARM = """
<mujoco><compiler angle="radian"/><option timestep="{dt}"><flag contact="disable"/></option>
<worldbody>
  <body name="arm" pos="0 0 1">
    <joint name="pin" type="hinge" axis="0 1 0" limited="true" range="-1 0" {extra}/>
    <inertial pos="1 0 0" mass="10" diaginertia="0.01 0.5 0.5"/>
  </body>
</worldbody></mujoco>"""

# a 5 kg slider on a vertical slide, lower limit at z = 0 (gravity presses it down)
SLIDER = """
<mujoco><option timestep="{dt}"><flag contact="disable"/></option>
<worldbody>
  <body name="slider" pos="0 0 1">
    <joint name="z" type="slide" axis="0 0 1" limited="true" range="0 1" {extra}/>
    <inertial pos="0 0 0" mass="5" diaginertia="0.01 0.01 0.01"/>
  </body>
</worldbody></mujoco>"""


def mujoco_run(m, qpos, qvel, torque, duration):
    """MuJoCo mode: (t, qpos) every step with a constant generalized force."""
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    d.qvel[:] = qvel
    d.qfrc_applied[:] = torque
    n = int(round(duration / m.opt.timestep))
    out = np.zeros(n)
    for i in range(n):
        mujoco.mj_step(m, d)
        out[i] = d.qpos[0]
    return out


def xpbd_run(xm, qpos, qvel, torque, duration, dt=1 / 60, substeps=20, compiled=True, watch=True):
    """XPBD: qpos after every substep (``watch``) or every frame, with a constant joint force."""
    solver = (SolverXPBD if compiled else ReferenceSolver)(xm, XpbdOptions(substeps=substeps))
    st = xm.state_from_qpos([qpos], [qvel])
    inp = SubstepInputs(joint_force=np.array([float(torque)]))
    out = []

    class Hooks:
        def before_substep(self, k, h, state):
            return inp

        def after_substep(self, k, h, state, forces):
            if watch:
                out.append(xm.qpos_qvel(state)[0][0])

    for _ in range(int(round(duration / dt))):
        solver.step(st, dt, hooks=Hooks())
    return np.array(out), st, solver


@pytest.mark.parametrize("pose", [0.0004, 0.003])
def test_limit_law_is_mujocos(pose):
    """(k·d, b, R) of ``mujoco_limit_law`` equal MuJoCo's efc_KBIP (K·I, B) and efc_R of the limit row, in
    the impedance's transition (0.4 mrad < width 1 mrad) and beyond it, for the MJCF's solref/solimp."""
    m = mujoco.MjModel.from_xml_string(ARM.format(dt=0.001, extra='solreflimit="0.03 0.8" solimplimit="0.8 0.97 0.001 0.4 3"'))
    xm = XpbdModel.from_mjmodel(m, warn=False)
    d = mujoco.MjData(m)
    d.qpos[0] = pose
    mujoco.mj_forward(m, d)
    assert d.nefc == 1 and d.efc_type[0] == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT
    K, B, imp, _ = d.efc_KBIP[0]
    kd, b, R = mujoco_limit_law(xm.jnt_solref[0], xm.jnt_solimp[0], xm.jnt_invweight[0], float(d.efc_pos[0]),
                                timestep=m.opt.timestep)
    assert kd == pytest.approx(K * imp, rel=1e-9)
    assert b == pytest.approx(B, rel=1e-9)
    assert R == pytest.approx(float(d.efc_R[0]), rel=1e-9)


BOOM = Path(__file__).resolve().parents[1] / "models/boom/boom.xml"


def boom_model(joint=True, tendon=True, dt=1e-4):
    xml = BOOM.read_text()
    if not tendon:
        xml = xml.replace('spatial name="boom_cyl" limited="true"', 'spatial name="boom_cyl" limited="false"')
    if not joint:
        xml = xml.replace('limited="true" range="-0.2448 0.7710"', 'limited="false" range="-0.2448 0.7710"')
    m = mujoco.MjModel.from_xml_string(xml)
    m.opt.timestep = dt
    return m, XpbdModel.from_mjmodel(m, warn=False)


@pytest.mark.parametrize("rows", ["joint", "tendon", "both"])
def test_boom_pressed_into_end_stop_matches_mujoco(rows):
    """The boom (models/boom/boom.xml, 350 kg) pressed into its end stop by 15 kN·m settles at MuJoCo's
    penetration within 1 %: with the joint limit only (0.26 mrad), the cylinder tendon's limit only
    (0.77 mrad) and both, as in the MJCF (0.22 mrad: MuJoCo solves the two rows together, so do we —
    ``SolverXPBD._solve_limits_block``).  The impact from 0.770 rad at rest overshoots as MuJoCo's at the
    same step (1/1200 s) within 0.5 %: the law is taken over a step as MuJoCo takes it
    (``mujoco_step_target``; a backward-Euler step of it overshot 3–6 % more)."""
    m, xm = boom_model(joint=rows != "tendon", tendon=rows != "joint")
    ref = mujoco_run(m, 0.770, 0.0, 15000.0, 1.0) - 0.771
    q, _, _ = xpbd_run(xm, 0.770, 0.0, 15000.0, 1.0, substeps=20)
    q = q - 0.771
    assert ref[-1] > 2e-4
    assert q[-1] == pytest.approx(ref[-1], rel=0.01)
    h = 1 / 1200  # s
    m, xm = boom_model(joint=rows != "tendon", tendon=rows != "joint", dt=h)
    ref = mujoco_run(m, 0.770, 0.0, 15000.0, 0.3) - 0.771
    q, _, _ = xpbd_run(xm, 0.770, 0.0, 15000.0, 0.3, dt=h, substeps=1)
    q = q - 0.771
    assert ref.max() > 5e-4
    assert q.max() == pytest.approx(ref.max(), rel=0.005)


def test_boom_end_stop_compiled_equals_pure():
    """The package's solver and the pure oracle agree to 1e-9 through the boom's impact on its joint + tendon limits."""
    _, xm = boom_model()
    qc, _, sc = xpbd_run(xm, 0.768, 0.3, 15000.0, 0.2, compiled=True)
    qp, _, sp = xpbd_run(xm, 0.768, 0.3, 15000.0, 0.2, compiled=False)
    assert isinstance(sp, ReferenceSolver) and not isinstance(sc, ReferenceSolver)
    assert qc.max() > 0.7712
    assert np.max(np.abs(qc - qp)) < 1e-9


def test_boom_end_stop_rows():
    """At the boom's end stop MuJoCo activates the joint limit and the cylinder tendon's limit together;
    the XPBD model carries both laws' parameters."""
    m = mujoco.MjModel.from_xml_path(str(BOOM))
    d = mujoco.MjData(m)
    d.qpos[0] = 0.772
    mujoco.mj_forward(m, d)
    assert sorted(int(t) for t in d.efc_type) == [int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT),
                                                  int(mujoco.mjtConstraint.mjCNSTR_LIMIT_TENDON)]
    xm = XpbdModel.from_mjmodel(m, warn=False)
    j = [i for i in range(d.nefc) if d.efc_type[i] == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT][0]
    _, _, R = mujoco_limit_law(xm.jnt_solref[0], xm.jnt_solimp[0], xm.jnt_invweight[0], float(d.efc_pos[j]))
    assert R == pytest.approx(float(d.efc_R[j]), rel=1e-9)
    assert xm.tendon_limit_ids == (0,)
    assert xm.tendon_limit_invweight[0] == pytest.approx(float(m.tendon_invweight0[0]))


@pytest.mark.parametrize("torque", [0.0, 2000.0])
def test_static_penetration_matches_mujoco(torque):
    """The arm pressed into its upper limit by gravity (98 N·m: penetration 0.2 mrad, inside the
    impedance's width) and by gravity + 2000 N·m (4 mrad, beyond it) settles at MuJoCo's penetration
    within 1 %, at 60 Hz × 20 substeps."""
    m = mujoco.MjModel.from_xml_string(ARM.format(dt=0.001, extra=""))
    xm = XpbdModel.from_mjmodel(m, warn=False)
    ref = mujoco_run(m, 0.0, 0.0, torque, 1.0)[-1]
    _, st, _ = xpbd_run(xm, 0.0, 0.0, torque, 1.0, watch=False)
    pen = xm.qpos_qvel(st)[0][0]
    assert ref > 1e-4
    assert pen == pytest.approx(ref, rel=0.01)


def test_slide_static_penetration_matches_mujoco():
    """A 5 kg slider resting on its lower slide limit sinks by MuJoCo's penetration within 1 %."""
    m = mujoco.MjModel.from_xml_string(SLIDER.format(dt=0.001, extra=""))
    xm = XpbdModel.from_mjmodel(m, warn=False)
    ref = mujoco_run(m, 0.0, 0.0, -500.0, 1.0)[-1]
    _, st, _ = xpbd_run(xm, 0.0, 0.0, -500.0, 1.0, watch=False)
    assert ref < -1e-4
    assert xm.qpos_qvel(st)[0][0] == pytest.approx(ref, rel=0.01)


def test_impact_overtravel_matches_mujoco_and_converges():
    """The arm swung at 3 rad/s into its upper limit: the overtravel beyond the limit approaches MuJoCo's
    (dt 0.05 ms) as the substeps grow, within 3 % at 60 Hz × 40 (the rigid projection: none)."""
    m = mujoco.MjModel.from_xml_string(ARM.format(dt=5e-5, extra=""))
    xm = XpbdModel.from_mjmodel(m, warn=False)
    peak_ref = mujoco_run(m, -0.2, 3.0, 0.0, 0.3).max()
    assert peak_ref > 1e-3
    errs = []
    for n in (10, 40):
        q, _, _ = xpbd_run(xm, -0.2, 3.0, 0.0, 0.3, substeps=n)
        errs.append(abs(q.max() / peak_ref - 1.0))
    assert errs[1] < 0.03
    assert errs[1] < errs[0]


@pytest.mark.parametrize("scene", ["hinge", "slide"])
def test_soft_limit_compiled_equals_pure(scene):
    """The package's solver and the pure oracle agree to 1e-9 through an impact on a soft limit and the rebound."""
    xml = ARM if scene == "hinge" else SLIDER
    m = mujoco.MjModel.from_xml_string(xml.format(dt=0.001, extra='solreflimit="0.01 0.3"'))
    xm = XpbdModel.from_mjmodel(m, warn=False)
    q0, v0, tq = (-0.1, 3.0, 0.0) if scene == "hinge" else (0.05, -1.0, 0.0)
    qc, _, sc = xpbd_run(xm, q0, v0, tq, 0.25, compiled=True)
    qp, _, sp = xpbd_run(xm, q0, v0, tq, 0.25, compiled=False)
    assert isinstance(sp, ReferenceSolver) and not isinstance(sc, ReferenceSolver)
    assert (qc.max() > 0.0) if scene == "hinge" else (qc.min() < 0.0)  # it went beyond the limit
    assert np.max(np.abs(qc - qp)) < 1e-9
