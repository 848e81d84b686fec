"""Physics tests of the rigid-body XPBD solver (sim.xpbd).

MuJoCo is used only as a reference (mj_step with RK4 at ~1e-4 s) and for kinematics
comparisons; the XPBD solver never calls MuJoCo dynamics.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from sim.xpbd import LengthConstraint, SolverXPBD, SubstepInputs, XpbdModel, XpbdOptions
from reference.xpbd_substep import ReferenceSolver

G = 9.81


def build(xml: str):
    m = mujoco.MjModel.from_xml_string(xml)
    return m, XpbdModel.from_mjmodel(m)


def mujoco_reference(m, qpos, qvel, frame_dt, nframes, sub=42):
    """qpos after each frame, RK4 at frame_dt/sub (≈1e-4 s for 1/240 s frames)."""
    m.opt.timestep = frame_dt / sub
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    d.qvel[:] = qvel
    out = np.zeros((nframes, m.nq))
    for n in range(nframes):
        for _ in range(sub):
            mujoco.mj_step(m, d)
        out[n] = d.qpos
    return out


def run_xpbd(xm, solver, qpos, qvel, dt, nframes):
    st = xm.state_from_qpos(qpos, qvel)
    out = np.zeros((nframes, xm.nq))
    for n in range(nframes):
        solver.step(st, dt)
        out[n] = xm.qpos_qvel(st)[0]
    return out, st


def crossing_times(t, y):
    """Upward zero crossings of y(t), linearly interpolated."""
    i = np.nonzero((y[:-1] < 0) & (y[1:] >= 0))[0]
    return t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])


# ---------------------------------------------------------------------------
# scenes

PENDULUM = """
<mujoco><compiler angle="radian"/><option><flag contact="disable"/></option>
<worldbody>
  <body name="bob" pos="0 0 1">
    <joint name="pin" type="hinge" axis="0 1 0" {extra}/>
    <inertial pos="0 0 -{d}" mass="{m}" diaginertia="{ic} {ic} {ic}"/>
    <geom type="capsule" fromto="0 0 0 0 0 -{d}" size="0.005" mass="0" contype="0" conaffinity="0"/>
  </body>
</worldbody></mujoco>"""

DOUBLE = """
<mujoco><option><flag contact="disable"/></option>
<worldbody>
  <site name="w_pin" pos="0 0 2"/>
  <body name="l1" pos="0 0 2">
    <joint name="j1" type="hinge" axis="0 1 0"/>
    <inertial pos="0.02 0 -0.5" mass="1.0" diaginertia="0.08 0.08 0.002"/>
    <site name="l1_top" pos="0 0 0"/>
    <site name="l1_pin" pos="0 0 -1"/>
    <body name="l2" pos="0 0 -1" euler="0 15 0">
      <joint name="j2" type="hinge" axis="0 1 0"/>
      <inertial pos="0 0 -0.4" mass="0.7" quat="0.95 0.1 0.2 0.2" diaginertia="0.03 0.028 0.004"/>
      <site name="l2_top" pos="0 0 0"/>
      <body name="l2_weight" pos="0.05 0 -0.8" euler="10 30 0">
        <inertial pos="0.02 0 0" mass="0.3" diaginertia="0.001 0.002 0.003"/>
      </body>
    </body>
  </body>
</worldbody></mujoco>"""


# ---------------------------------------------------------------------------


def test_kinematics_roundtrip_matches_mujoco():
    m, xm = build(DOUBLE)
    d = mujoco.MjData(m)
    qpos, qvel = np.array([0.4, -1.1]), np.array([0.7, -1.3])
    d.qpos[:], d.qvel[:] = qpos, qvel
    mujoco.mj_forward(m, d)  # reference kinematics only
    st = xm.state_from_qpos(qpos, qvel)
    assert np.allclose(st.x, d.xipos, atol=1e-12)
    assert np.allclose(xm.site_positions(st), d.site_xpos, atol=1e-12)
    for s in range(m.nsite):
        vel = np.zeros(6)
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, s, vel, 0)
        assert np.allclose(xm.site_velocities(st)[s], vel[3:], atol=1e-12)
    q2, v2 = xm.qpos_qvel(st)
    assert np.allclose(q2, qpos, atol=1e-12) and np.allclose(v2, qvel, atol=1e-12)
    assert xm.ngroup == 3  # l2_weight merged into l2


def test_hinge_angle_unwraps_over_many_turns():
    m, xm = build(PENDULUM.format(d=0.5, m=1.0, ic=0.002, extra="").replace(
        "<option>", '<option gravity="0 0 0">'))
    st = xm.state_from_qpos([3.0], [10.0])
    solver = SolverXPBD(xm, XpbdOptions(substeps=40))
    dt, integral, v_prev = 1 / 60, 0.0, 10.0
    for _ in range(120):
        solver.step(st, dt)
        v = xm.qpos_qvel(st)[1][0]
        integral += 0.5 * (v + v_prev) * dt
        v_prev = v
    q = xm.qpos_qvel(st)[0][0]
    assert q > 3.0 + 3 * 2 * math.pi  # several turns, continuously unwrapped
    assert abs((q - 3.0) / integral - 1) < 0.01
    # XPBD's projection dissipates orbital energy at ≈ (3/8) ω³ h per unit time
    assert 0.85 * 10.0 < v_prev < 10.0


def test_single_pendulum_period_and_mujoco():
    mass, dist, ic = 2.0, 0.5, 0.004
    m, xm = build(PENDULUM.format(d=dist, m=mass, ic=ic, extra=""))
    inertia = ic + mass * dist**2
    T_analytic = 2 * math.pi * math.sqrt(inertia / (mass * G * dist))
    dt, n = 1 / 240, int(4.5 / (1 / 240))
    amp = 0.05
    xp, _ = run_xpbd(xm, SolverXPBD(xm, XpbdOptions(substeps=50)), [amp], [0.0], dt, n)
    t = dt * np.arange(1, n + 1)
    tc = crossing_times(t, xp[:, 0])
    T_xpbd = np.mean(np.diff(tc))
    assert len(tc) >= 3
    # small-amplitude correction T(θ0) ≈ T0 (1 + θ0²/16) is 1.6e-4, well inside 1 %
    assert abs(T_xpbd / T_analytic - 1) < 0.01
    ref = mujoco_reference(m, [amp], [0.0], dt, n)
    assert np.max(np.abs(xp - ref)) < 0.01 * amp


def test_double_pendulum_matches_mujoco():
    m, xm = build(DOUBLE)
    q0, v0 = np.array([0.05, -0.03]), np.array([0.0, 0.1])
    dt, n = 1 / 240, 480
    xp, _ = run_xpbd(xm, SolverXPBD(xm, XpbdOptions(substeps=50)), q0, v0, dt, n)
    ref = mujoco_reference(m, q0, v0, dt, n)
    amp = np.max(np.abs(ref), axis=0)
    assert np.all(np.max(np.abs(xp - ref), axis=0) < 0.01 * amp)


def test_joint_drift_double_pendulum_20s():
    m, xm = build(DOUBLE)
    st = xm.state_from_qpos([1.2, -0.8], [0.0, 2.0])
    solver = SolverXPBD(xm, XpbdOptions(substeps=20))
    ids = [xm.site_id(s) for s in ("w_pin", "l1_top", "l1_pin", "l2_top")]
    worst = 0.0
    e0 = xm.kinetic_energy(st) + xm.potential_energy(st)
    swing = 0.0
    for _ in range(20 * 60):
        solver.step(st, 1 / 60)
        p = xm.site_positions(st)[ids]
        worst = max(worst, np.linalg.norm(p[0] - p[1]), np.linalg.norm(p[2] - p[3]))
        swing = max(swing, abs(xm.qpos_qvel(st)[0][1]))
    assert worst < 1e-4
    assert swing > 0.5  # it really swung
    e1 = xm.kinetic_energy(st) + xm.potential_energy(st)
    assert e1 <= e0 + 1e-6  # XPBD may dissipate, never create energy


def test_block_attachment_drifts_less_than_the_scalar_projection():
    """The pins projected with the 3×3 block update (the package's ``compiled._attach``) against the scalar XPBD
    projection along the error direction (the oracle's ``block_attach=False``): double pendulum, 3 s at 60 Hz × 20,
    worst pin separation 4.0e-5 m vs 5.5e-5 m; the oracle with the block update follows the package's solver."""
    m, xm = build(DOUBLE)
    ids = [xm.site_id(s) for s in ("w_pin", "l1_top", "l1_pin", "l2_top")]
    drift, end = {}, {}
    for name, solver in (("package", SolverXPBD(xm, XpbdOptions(substeps=20))),
                         ("block", ReferenceSolver(xm, XpbdOptions(substeps=20))),
                         ("scalar", ReferenceSolver(xm, XpbdOptions(substeps=20), block_attach=False))):
        st = xm.state_from_qpos([1.2, -0.8], [0.0, 2.0])
        worst = 0.0
        for _ in range(3 * 60):
            solver.step(st, 1 / 60)
            p = xm.site_positions(st)[ids]
            worst = max(worst, np.linalg.norm(p[0] - p[1]), np.linalg.norm(p[2] - p[3]))
        drift[name], end[name] = worst, st.x.copy()
    np.testing.assert_allclose(end["block"], end["package"], rtol=0, atol=1e-9)
    assert drift["block"] < 1e-4 and drift["scalar"] > 1.25 * drift["block"], drift


EXCAVATOR = """
<mujoco><compiler angle="radian"/><option><flag contact="disable"/></option>
<worldbody>
  <body name="house" pos="0 0 0.5">
    <joint name="swing" type="hinge" axis="0 0 1"/>
    <geom type="box" size="0.6 0.4 0.3" density="500"/>
    <body name="boom" pos="0.4 0 0.3">
      <joint name="boom" type="hinge" axis="0 1 0" pos="0.02 0 0"/>
      <geom type="capsule" fromto="0 0 0 1.5 0 1.0" size="0.08" density="800"/>
      <body name="stick" pos="1.5 0 1.0">
        <joint name="stick" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 1.0 0 -1.0" size="0.06" density="800"/>
        <body name="tele" pos="0.5 0 -0.5" euler="0 0.785 0">
          <joint name="tele" type="slide" axis="0 0 -1"/>
          <geom type="box" size="0.05 0.05 0.2" density="1000"/>
          <body name="wrist" pos="0 0 -0.2">
            <joint name="wrist" type="ball" pos="0 0 0.01"/>
            <geom type="sphere" size="0.1" pos="0.1 0.05 -0.15" density="1000"/>
            <site name="tip" pos="0.1 0.05 -0.25"/>
          </body>
        </body>
      </body>
    </body>
  </body>
</worldbody></mujoco>"""
EXC_Q0 = np.array([0.2, -0.3, 0.4, 0.05, 0.98, 0.1, -0.1, 0.1])
EXC_V0 = np.array([1.5, 0.5, -0.5, 0.2, 0.3, -0.2, 0.5])


def test_kinematics_3d_chain_slide_ball_matches_mujoco():
    m, xm = build(EXCAVATOR)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = EXC_Q0, EXC_V0
    mujoco.mj_forward(m, d)
    st = xm.state_from_qpos(EXC_Q0, EXC_V0)
    assert np.allclose(st.x, d.xipos, atol=1e-12)
    for b in range(1, m.nbody):
        vel = np.zeros(6)
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, b, vel, 0)
        assert np.allclose(vel[:3], st.w[b], atol=1e-12)
        assert np.allclose(vel[3:], st.v[b], atol=1e-12)
    q, v = xm.qpos_qvel(st)
    qref = EXC_Q0.copy()
    qref[4:] /= np.linalg.norm(qref[4:])
    assert np.allclose(q, qref, atol=1e-12) and np.allclose(v, EXC_V0, atol=1e-12)


def test_3d_chain_with_swing_torque_matches_mujoco():
    """Swing / boom / stick hinges, a slide and a ball joint in 3D, driven by a swing
    torque: XPBD (60 substeps at 1/240 s) vs MuJoCo RK4 at ~1e-4 s over 0.5 s."""
    m, xm = build(EXCAVATOR)
    tau = 400.0
    dt, n = 1 / 240, 120
    solver = SolverXPBD(xm, XpbdOptions(substeps=60))
    st = xm.state_from_qpos(EXC_Q0, EXC_V0)
    jf = np.zeros(xm.njnt)
    jf[xm.joint_id("swing")] = tau
    xp = np.zeros((n, xm.nq))
    for i in range(n):
        solver.step(st, dt, inputs=SubstepInputs(joint_force=jf))
        xp[i] = xm.qpos_qvel(st)[0]
    m.opt.timestep = dt / 42
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = EXC_Q0, EXC_V0
    d.qfrc_applied[m.jnt_dofadr[xm.joint_id("swing")]] = tau
    ref = np.zeros_like(xp)
    for i in range(n):
        for _ in range(42):
            mujoco.mj_step(m, d)
        ref[i] = d.qpos
    motion = np.max(np.abs(ref - ref[0]), axis=0)
    err = np.max(np.abs(xp - ref), axis=0)
    assert np.all(err[:4] < 0.01 * motion[:4])   # hinge angles and slide
    assert np.all(err[4:] < 0.01 * np.max(motion[4:]))  # ball quaternion


BOX = """
<mujoco><worldbody>
  <geom name="floor" type="plane" size="5 5 0.1" friction="{mu}"/>
  <body name="box" pos="{x0} 0 {z0}" euler="{ex} {ey} 0">
    <freejoint/>
    <geom type="box" size="0.1 0.15 0.05" density="1000" friction="{mu}"/>
    {sites}
  </body>
</worldbody></mujoco>"""
_CORNERS = "\n".join(
    f'<site name="c{i}" pos="{sx * 0.1} {sy * 0.15} {sz * 0.05}"/>'
    for i, (sx, sy, sz) in enumerate((a, b, c) for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)))


def test_box_rests_on_ground():
    m, xm = build(BOX.format(mu=0.8, x0=0, z0=0.08, ex=6, ey=-4, sites=_CORNERS))
    st = xm.state_from_qpos()
    solver = SolverXPBD(xm, XpbdOptions(substeps=20))
    worst_pen = 0.0
    for n in range(120):
        solver.step(st, 1 / 60)
        if n > 30:  # after landing
            worst_pen = max(worst_pen, -xm.site_positions(st)[:, 2].min())
    b = xm.body_id("box")
    assert worst_pen < 1e-3
    assert -xm.site_positions(st)[:, 2].min() < 1e-3
    assert np.linalg.norm(st.v[b]) < 1e-3
    assert np.max(np.abs(xm.site_velocities(st))) < 1e-3
    assert abs(st.x[b, 2] - 0.05) < 1e-3  # lying flat on its largest face


def test_box_sliding_friction_stops_at_v2_over_2mug():
    mu, v0 = 0.5, 2.0
    m, xm = build(BOX.format(mu=mu, x0=0, z0=0.05, ex=0, ey=0, sites=""))
    qvel = np.zeros(6)
    qvel[0] = v0
    st = xm.state_from_qpos(None, qvel)
    solver = SolverXPBD(xm, XpbdOptions(substeps=20))
    for _ in range(90):
        solver.step(st, 1 / 60)
    b = xm.body_id("box")
    assert np.linalg.norm(st.v[b]) < 1e-3
    assert abs(st.x[b, 0] / (v0**2 / (2 * mu * G)) - 1) < 0.03


def test_contype_conaffinity_respected():
    xml = """<mujoco><worldbody><geom type="plane" size="5 5 .1"/>
      <body name="a" pos="0 0 .5"><freejoint/><geom type="sphere" size=".1"/></body>
      <body name="b" pos="1 0 .5"><freejoint/><geom type="capsule" size=".1 .2" euler="90 0 0"
            contype="2" conaffinity="2"/></body>
      <body name="c" pos="2 0 .5"><freejoint/><geom type="capsule" size=".05 .2" euler="0 30 0"/></body>
    </worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    with pytest.warns(UserWarning, match="other than plane"):  # sphere–capsule pair a–c
        xm = XpbdModel.from_mjmodel(m)
    st = xm.state_from_qpos()
    solver = SolverXPBD(xm, XpbdOptions(substeps=10))
    for _ in range(60):
        solver.step(st, 1 / 60)
    a, b, c = (xm.body_id(n) for n in "abc")
    assert abs(st.x[a, 2] - 0.1) < 1e-3  # sphere rests on the plane
    assert st.x[b, 2] < -0.5  # no declared pair with the plane: falls through
    assert abs(st.x[c, 2] - 0.05) < 2e-3  # capsule ends on the plane: lies flat


SLIDER = """
<mujoco><option gravity="0 0 {g}"><flag contact="disable"/></option>
<worldbody>
  <site name="anchor" pos="0 0 2"/>
  <body name="slider" pos="0 0 1">
    <joint name="s" type="slide" axis="0 0 1" damping="{damping}"/>
    <inertial pos="0 0 0" mass="{m}" diaginertia="0.01 0.01 0.01"/>
    <site name="tip" pos="0 0 0"/>
  </body>
</worldbody></mujoco>"""


def test_slide_with_compliant_length_row_static_and_frequency():
    mass, alpha = 2.0, 1e-3
    inputs = SubstepInputs(target_length=np.array([1.0]), compliance=np.array([alpha]))
    # static deflection (joint damping settles it)
    m, xm = build(SLIDER.format(g=-G, m=mass, damping=60))
    solver = SolverXPBD(xm, XpbdOptions(substeps=20), length_constraints=[LengthConstraint("anchor", "tip")])
    st = xm.state_from_qpos()
    for _ in range(2 * 240):
        solver.step(st, 1 / 240, inputs=inputs)
    defl = -xm.qpos_qvel(st)[0][0]
    assert abs(defl / (mass * G * alpha) - 1) < 0.01
    f = solver.last_forces[-1].row_force[0]
    assert abs(f / (-mass * G) - 1) < 0.01  # tension: negative = pulling the sites together
    assert abs(solver.last_forces[-1].row_length[0] - (1 + mass * G * alpha)) < 1e-5
    # free oscillation about the equilibrium
    m, xm = build(SLIDER.format(g=-G, m=mass, damping=0))
    solver = SolverXPBD(xm, XpbdOptions(substeps=20), length_constraints=[LengthConstraint("anchor", "tip")])
    st = xm.state_from_qpos()
    dt, n = 1 / 240, 360
    y = np.zeros(n)
    for i in range(n):
        solver.step(st, dt, inputs=inputs)
        y[i] = xm.qpos_qvel(st)[0][0] + mass * G * alpha
    tc = crossing_times(dt * np.arange(1, n + 1), y)
    omega = 2 * math.pi / np.mean(np.diff(tc))
    assert len(tc) >= 4
    assert abs(omega / math.sqrt(1 / (alpha * mass)) - 1) < 0.01


@pytest.mark.parametrize("substeps", [1, 2, 5])
def test_numerical_damping_is_backward_euler(substeps):
    mass, alpha, dt = 1.0, 1e-4, 0.01
    omega = math.sqrt(1 / (alpha * mass))  # 100 rad/s
    xml = """<mujoco><option gravity="0 0 0"/><worldbody><site name="anchor" pos="0 0 0"/>
      <body name="ball" pos="1.1 0 0"><freejoint/>
        <inertial pos="0 0 0" mass="1" diaginertia="0.1 0.1 0.1"/><site name="c"/></body>
      </worldbody></mujoco>"""
    m, xm = build(xml)
    solver = SolverXPBD(xm, XpbdOptions(substeps=substeps), length_constraints=[LengthConstraint("anchor", "c")])
    inputs = SubstepInputs(target_length=np.array([1.0]), compliance=np.array([alpha]))
    st = xm.state_from_qpos()
    b = xm.body_id("ball")
    n = 30
    logamp = np.zeros(n)
    for i in range(n):
        solver.step(st, dt, inputs=inputs)
        logamp[i] = 0.5 * math.log((st.x[b, 0] - 1.0) ** 2 + (st.v[b, 0] / omega) ** 2)
    rate = -np.polyfit(dt * np.arange(1, n + 1), logamp, 1)[0]
    h = dt / substeps
    predicted = math.log(1 + (omega * h) ** 2) / (2 * h)
    assert abs(rate / predicted - 1) < 0.05
    assert np.allclose(st.x[b, 1:], 0.0, atol=1e-12)


def test_hinge_limit_holds():
    """The rigid limit option (``soft_limits=False``) stops a pendulum thrown at 8 rad/s at the limit
    within 1 mrad (the default soft limits: tests/test_xpbd_soft_limit.py)."""
    lim = 0.4
    m, xm = build(PENDULUM.format(d=0.5, m=1.0, ic=0.002,
                                  extra=f'limited="true" range="{-lim} {lim}"'))
    solver = SolverXPBD(xm, XpbdOptions(substeps=20, soft_limits=False))

    class Watch:
        worst = 0.0

        def before_substep(self, k, h, state):
            return None

        def after_substep(self, k, h, state, forces):
            Watch.worst = max(Watch.worst, abs(xm.qpos_qvel(state)[0][0]))

    st = xm.state_from_qpos([0.0], [8.0])
    for _ in range(3 * 60):
        solver.step(st, 1 / 60, hooks=Watch())
    assert lim - 0.01 < Watch.worst < lim + 1e-3


FOURBAR = """
<mujoco><option><flag contact="disable"/></option>
<worldbody>
  <site name="ground_pin" pos="0.4 0 -0.3"/>
  <body name="crank">
    <joint type="hinge" axis="0 1 0"/>
    <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/>
    <body name="coupler" pos="0.2 0 0">
      <joint type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.5" size="0.02"/>
      <body name="rocker" pos="0 0 0.5">
        <joint type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 -0.8" size="0.02"/>
        <site name="rocker_end" pos="0.2 0 -0.8"/>
      </body>
    </body>
  </body>
</worldbody>
<equality><connect site1="rocker_end" site2="ground_pin"/></equality>
</mujoco>"""


def test_connect_equality_closes_four_bar():
    m, xm = build(FOURBAR)
    st = xm.state_from_qpos()
    solver = SolverXPBD(xm, XpbdOptions(substeps=20))
    s1, s2 = xm.site_id("rocker_end"), xm.site_id("ground_pin")
    e0 = xm.kinetic_energy(st) + xm.potential_energy(st)
    worst, travel, emax = 0.0, 0.0, -np.inf
    for _ in range(3 * 120):
        solver.step(st, 1 / 120)
        p = xm.site_positions(st)
        worst = max(worst, np.linalg.norm(p[s1] - p[s2]))
        travel = max(travel, abs(xm.qpos_qvel(st)[0][0]))
        emax = max(emax, xm.kinetic_energy(st) + xm.potential_energy(st))
    assert worst < 1e-4
    assert travel > 1.0
    # XPBD dissipates (O(h), notably through the toggle positions) but never gains energy
    assert emax < e0 + 1e-3


def test_joint_damping_matches_mujoco():
    m, xm = build(PENDULUM.format(d=0.5, m=1.0, ic=0.002, extra='damping="0.3"'))
    dt, n = 1 / 240, 480
    xp, _ = run_xpbd(xm, SolverXPBD(xm, XpbdOptions(substeps=40)), [0.3], [0.0], dt, n)
    ref = mujoco_reference(m, [0.3], [0.0], dt, n)
    assert np.max(np.abs(xp - ref)) < 0.01 * 0.3
    assert np.max(np.abs(xp[-120:])) < 0.5 * 0.3  # it did decay


def test_hooks_explicit_row_force_and_joint_torque():
    # explicit row force equal to the weight holds the slider still
    mass = 2.0
    m, xm = build(SLIDER.format(g=-G, m=mass, damping=0))
    solver = SolverXPBD(xm, XpbdOptions(substeps=10), length_constraints=[LengthConstraint("anchor", "tip")])
    calls = []

    class Hooks:
        def before_substep(self, k, h, state):
            calls.append(k)
            return SubstepInputs(row_force=np.array([-mass * G]))  # pull up (tension)

        def after_substep(self, k, h, state, forces):
            assert not forces.row_active[0] and forces.row_force[0] == 0.0

    st = xm.state_from_qpos()
    for _ in range(60):
        solver.step(st, 1 / 60, hooks=Hooks())
    assert calls[:10] == list(range(10)) and len(calls) == 600
    assert abs(xm.qpos_qvel(st)[0][0]) < 1e-9
    # a slide joint force equal to the weight holds it as well
    st = xm.state_from_qpos()
    for _ in range(60):
        solver.step(st, 1 / 60, inputs=SubstepInputs(joint_force=np.array([mass * G])))
    assert abs(xm.qpos_qvel(st)[0][0]) < 1e-9
    # hinge torque m g d holds a horizontal pendulum
    m, xm = build(PENDULUM.format(d=0.5, m=1.0, ic=0.002, extra=""))
    solver = SolverXPBD(xm, XpbdOptions(substeps=20))
    st = xm.state_from_qpos([math.pi / 2], [0.0])
    tau = 1.0 * G * 0.5  # gravity torque is −m g d at +90°
    for _ in range(60):
        solver.step(st, 1 / 60, inputs=SubstepInputs(joint_force=np.array([tau])))
    # residual: nonlinear projection bias of a torque about the COM, O(h⁴)
    assert abs(xm.qpos_qvel(st)[0][0] - math.pi / 2) < 1e-4
    st = xm.state_from_qpos([math.pi / 2], [0.0])
    for _ in range(10):
        solver.step(st, 1 / 60)
    assert xm.qpos_qvel(st)[0][0] < math.pi / 2 - 0.1  # without the torque it falls


def test_unilateral_row_bounds_rope():
    # a rope (force ≤ 0: it can only pull) of length 1.2 m: slack at start, then catches
    m, xm = build(SLIDER.format(g=-G, m=1.0, damping=0))
    solver = SolverXPBD(xm, XpbdOptions(substeps=20), length_constraints=[LengthConstraint("anchor", "tip")])
    inputs = SubstepInputs(target_length=np.array([1.2]), compliance=np.array([0.0]),
                           force_max=np.array([0.0]))
    st = xm.state_from_qpos()
    forces, lengths = [], []
    for _ in range(120):
        solver.step(st, 1 / 120, inputs=inputs)
        forces += [f.row_force[0] for f in solver.last_forces]
        lengths += [f.row_length[0] for f in solver.last_forces]
    forces, lengths = np.array(forces), np.array(lengths)
    assert np.all(forces <= 0.0)
    assert np.all(forces[lengths < 1.2 - 1e-9] == 0.0)  # slack: no force
    assert lengths.max() < 1.2 + 1e-9  # rigid once taut
    assert forces.min() < -1.0


def test_body_wrench_free_body():
    xml = """<mujoco><option gravity="0 0 0"/><worldbody>
      <body name="b" pos="0 0 1"><freejoint/>
        <inertial pos="0.1 0 0" mass="2" diaginertia="0.1 0.2 0.3"/></body>
      </worldbody></mujoco>"""
    m, xm = build(xml)
    b = xm.body_id("b")
    wrench = np.zeros((xm.nbody, 6))
    wrench[b] = [1.0, -2.0, 0.5, 0.0, 0.0, 0.06]  # torque about the principal z axis
    st = xm.state_from_qpos()
    solver = SolverXPBD(xm, XpbdOptions(substeps=10))
    for _ in range(60):
        solver.step(st, 1 / 60, inputs=SubstepInputs(body_wrench=wrench))
    assert np.allclose(st.v[b], wrench[b, :3] / 2.0, rtol=1e-9)
    assert np.allclose(st.w[b], [0.0, 0.0, 0.06 / 0.3], atol=1e-9)
    assert np.allclose(st.x[b] - [0.1, 0, 1], 0.5 * wrench[b, :3] / 2.0, rtol=1e-2)


BOOM = """<mujoco><option><flag contact="disable"/></option><worldbody>
  <site name="base" pos="0.5 0 -1"/>
  <body name="boom"><joint name="pin" type="hinge" axis="0 1 0" damping="{b}"/>
    <inertial pos="2 0 0" mass="1000" diaginertia="10 1333.33 1333.33"/>
    <site name="eye" pos="1 0 0"/></body></worldbody></mujoco>"""


def test_boom_held_by_two_stiff_chamber_rows():
    """A 1000 kg boom on a hinge held by one cylinder modelled as two compliant rows on
    the same site pair (cap: pushes, rod: pulls), k = 3e7 N/m in total: static row force
    and sag, and the oscillation frequency √(k a²/I_pin)."""
    k = 3e7
    L0 = math.sqrt(0.25 + 1.0)
    arm = 1.0 / L0                      # moment arm of the cylinder about the pin
    I_pin = 1333.33 + 1000 * 4.0
    tau = 1000 * G * 2.0
    ac, ar = 1.5 / k, 3.0 / k           # 1/ac + 1/ar = k
    lc = L0 + 1e-3                      # the two chambers pre-loaded against each other
    lr = (L0 * k - lc / ac) * ar
    inputs = SubstepInputs(target_length=np.array([lc, lr]), compliance=np.array([ac, ar]))
    rows = [LengthConstraint("base", "eye", "cap"), LengthConstraint("base", "eye", "rod")]
    # static: joint damping settles it
    m, xm = build(BOOM.format(b=3e5))
    solver = SolverXPBD(xm, XpbdOptions(substeps=20), length_constraints=rows)
    st = xm.state_from_qpos()
    for _ in range(240):
        solver.step(st, 1 / 240, inputs=inputs)
    f = solver.last_forces[-1].row_force
    assert f[0] > 0 > f[1]  # cap pushes, rod pulls (pre-load)
    assert abs(f.sum() / (tau / arm) - 1) < 0.01
    assert abs(xm.qpos_qvel(st)[0][0] / (tau / (k * arm**2)) - 1) < 0.01  # +θ is downward
    # undamped: frequency
    m, xm = build(BOOM.format(b=0))
    solver = SolverXPBD(xm, XpbdOptions(substeps=20), length_constraints=rows)
    st = xm.state_from_qpos()
    dt, n = 1 / 240, 240
    th = np.zeros(n)
    for i in range(n):
        solver.step(st, dt, inputs=inputs)
        th[i] = xm.qpos_qvel(st)[0][0]
    tc = crossing_times(dt * np.arange(1, n + 1), th - tau / (k * arm**2))
    omega = 2 * math.pi / np.mean(np.diff(tc))
    assert abs(omega / math.sqrt(k * arm**2 / I_pin) - 1) < 0.01


# ---------------------------------------------------------------------------
# compliant contacts with MuJoCo's soft-contact law

SPHERE_ON_PLANE = """<mujoco><option timestep="{dt}" cone="{cone}"/><worldbody>
  <geom type="plane" size="5 5 .1" friction="{mu}" {sol}/>
  <body name="a" pos="0 0 {z0}"><freejoint/>
    <geom type="sphere" size=".1" mass="{mass}" condim="{condim}" friction="{mu}" {sol}/></body>
</worldbody></mujoco>"""


def _sphere_runs(xml, settle_steps, dt_xpbd, frames, substeps=20):
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    every = round(dt_xpbd / m.opt.timestep)
    z_mj = []
    for i in range(settle_steps):
        mujoco.mj_step(m, d)
        if (i + 1) % every == 0:
            z_mj.append(d.qpos[2] - 0.1)
    xm = XpbdModel.from_mjmodel(m)
    st = xm.state_from_qpos()
    solver = SolverXPBD(xm, XpbdOptions(substeps=substeps))
    z_x = []
    for _ in range(frames):
        solver.step(st, dt_xpbd)
        z_x.append(st.x[xm.body_id("a"), 2] - 0.1)
    return np.array(z_mj), np.array(z_x)


@pytest.mark.parametrize("cone, condim, mu, mass, sol", [
    ("pyramidal", 3, 0.6, 2.0, ""),
    ("pyramidal", 1, 0.6, 40.0, ""),
    ("elliptic", 3, 0.6, 2.0, ""),
    ("pyramidal", 3, 1.0, 5.0, 'solref="0.05 0.7" solimp="0.8 0.9 0.01 0.5 2"'),
    ("pyramidal", 3, 0.6, 5.0, 'solref="-20000 -300"'),
])
def test_soft_contact_static_penetration_matches_mujoco(cone, condim, mu, mass, sol):
    """A sphere resting on the ground sinks by MuJoCo's static penetration r = −F·R/(k·d) (solref, solimp, cone,
    condim and the body's effective mass from MuJoCo's body_invweight0) to 0.1 %."""
    xml = SPHERE_ON_PLANE.format(dt=0.001, cone=cone, mu=mu, mass=mass, condim=condim, sol=sol, z0=0.1)
    z_mj, z_x = _sphere_runs(xml, 4000, 1 / 60, 240)
    assert z_mj[-1] < -1e-5  # MuJoCo's contact is soft
    assert z_x[-1] == pytest.approx(z_mj[-1], rel=1e-3)


def test_soft_contact_impact_matches_mujoco():
    """A 2 m/s drop: the deepest penetration (≈14 mm with the default solref, a ~20 ms critically damped contact) and the
    rebound history match MuJoCo within 5 % of the peak; the rigid contact of [RB] stays an order of magnitude shallower."""
    xml = SPHERE_ON_PLANE.format(dt=0.0005, cone="pyramidal", mu=0.6, mass=3.0, condim=3, sol="", z0=0.3)
    z_mj, z_x = _sphere_runs(xml, 2000, 0.01, 100)
    peak = -z_mj.min()
    assert peak > 0.01
    assert -z_x.min() == pytest.approx(peak, rel=0.05)
    assert np.max(np.abs(z_x - z_mj)) < 0.05 * peak
    m = mujoco.MjModel.from_xml_string(xml)
    xm = XpbdModel.from_mjmodel(m)
    st = xm.state_from_qpos()
    rigid = SolverXPBD(xm, XpbdOptions(substeps=20, soft_contacts=False))
    deepest = 0.0
    for _ in range(100):
        rigid.step(st, 0.01)
        deepest = max(deepest, 0.1 - st.x[xm.body_id("a"), 2])
    assert deepest < 0.1 * peak


def test_soft_contact_box_rests_at_mujoco_penetration():
    """A box dropped slightly tilted lands on its four corners (one pyramidal contact each, solved together) and comes to
    rest at MuJoCo's resting height to 1e-9 m, without creeping."""
    xml = BOX.format(mu=0.8, x0=0, z0=0.08, ex=6, ey=-4, sites="")
    m = mujoco.MjModel.from_xml_string(xml)
    m.opt.timestep = 1 / 1200
    d = mujoco.MjData(m)
    for _ in range(2400):
        mujoco.mj_step(m, d)
    xm = XpbdModel.from_mjmodel(m)
    st = xm.state_from_qpos()
    solver = SolverXPBD(xm, XpbdOptions(substeps=20))
    for _ in range(120):
        solver.step(st, 1 / 60)
    b = xm.body_id("box")
    assert 0.05 - d.qpos[2] > 1e-5  # MuJoCo's contact is soft
    assert st.x[b, 2] == pytest.approx(d.qpos[2], abs=1e-9)
    assert np.linalg.norm(st.v[b]) < 1e-6
