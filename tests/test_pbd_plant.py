"""PBD mode (XPBD bodies, cylinders as compliant rows whose multipliers carry the chamber forces).

Seed cylinder: the seed's explicit scheme diverges at 1200 Hz, XPBD stays bounded and converges
to the seed's own equations (first order).  Boom: holds still, lifts and holds pressure like MuJoCo
mode.  Excavator: runs the dig cycle and matches MuJoCo mode before the bucket reaches the ground.
Blocked oil column: XPBD's numerical damping is exactly backward Euler's.
"""

import math
import warnings

import numpy as np
import pytest
from scipy.optimize import curve_fit

from conftest import MODELS, scene_copy
from sim.cli import main
from sim.io.mcap_log import read_log
from sim.plants.pbd import PbdPlant, make_pbd_plant
from sim.run.runner import run
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.xpbd import SubstepInputs
from test_excavator import pressure_bounds
from test_mujoco_plant import AREA, BETA, MASS, NO_LEAK, SEED, seed_reference

BOOM_CAP_AREA = math.pi * 0.063**2 / 4  # m²
DIG = MODELS / "excavator" / "dig.scenario.toml"
RELIEF = 3.43e7  # Pa, excavator main relief setting


@pytest.fixture(autouse=True)
def _quiet_xpbd_notes():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")  # notes on features XPBD does not model (none on the stock scenes)
        yield


# ---------------------------------------------------------------------------- seed cylinder


def test_make_pbd_plant_picks_the_scheme():
    naive = make_pbd_plant(load_scene(load_scenario(SEED).with_overrides(mode="pbd-naive")))
    xpbd = make_pbd_plant(load_scene(load_scenario(SEED).with_overrides(mode="pbd")))
    assert naive.coupling.name == "explicit" and naive.coupling.stepper.name == "explicit_euler"
    assert xpbd.coupling.name == "implicit" and xpbd.solver.substeps == 20


def test_seed_1200hz_naive_diverges_xpbd_bounded(tmp_path):
    """The seed's scheme (explicit pressures, explicit row forces) diverges at 1200 Hz; XPBD stays bounded for 0.1 s."""
    naive = run(SEED, out=tmp_path / "naive.mcap", overrides={"mode": "pbd-naive"})
    assert naive.status == "diverged" and naive.simulated_time < 0.1
    assert read_log(naive.log_path).status == "diverged"
    xpbd = run(SEED, out=tmp_path / "xpbd.mcap", overrides={"mode": "pbd"})
    assert xpbd.status == "complete"
    cyl = read_log(xpbd.log_path).topic("/hydroplant/cylinders/cyl")
    assert len(cyl.t) == 121 and cyl.t[-1] == pytest.approx(0.1)
    assert np.all(np.abs(cyl["position_m"]) < 10) and np.all(np.isfinite(cyl["p_cap_pa"]))
    assert np.all(np.abs(cyl["p_cap_pa"]) <= BETA * (1 + 1e-9))  # backward Euler never overshoots the initial state


def test_seed_converges_to_scipy_reference_first_order(tmp_path):
    """More substeps → the seed's equations (m·x'' = P·A, dP/dt = −(β/x)·dx/dt): order ≈ 1 over the first 10 ms."""
    substeps = [40, 80, 160, 320]
    errors = []
    for n in substeps:
        result = run(SEED, out=tmp_path / f"seed{n}.mcap", overrides={"mode": "pbd", "pbd_substeps": n, "duration": 0.01})
        assert result.status == "complete"
        cyl = read_log(result.log_path).topic("/hydroplant/cylinders/cyl")
        x_ref, _, p_ref = seed_reference(cyl.t)
        errors.append((np.max(np.abs(cyl["position_m"] - x_ref)), np.max(np.abs(cyl["p_cap_pa"] - p_ref)), np.ptp(x_ref), np.ptp(p_ref)))
    ex = np.array([e[0] for e in errors])
    order = np.log2(ex[:-1] / ex[1:])
    print(f"\nseed XPBD stroke error vs substeps {substeps}: {ex} m; observed order {np.round(order, 3)}")
    assert np.all(order >= 0.8)
    x_err, p_err, x_range, p_range = errors[-1]
    assert x_err < 0.01 * x_range and p_err < 0.01 * p_range  # 320 substeps at 1200 Hz: within 1 % of the swing


# ---------------------------------------------------------------------------- boom


@pytest.mark.parametrize("articulated", [False, True])
def test_articulated_rows_and_gravity_hold_a_loaded_boom(articulated):
    """XPBD solver inputs ``row_mobility`` + ``group_gravity``: a boom on a stiff row (oil column 1.8e7 N/m plus a seal
    stiction slope of 5e5 N·s/m, as the coupling's law has) holds still at its static force in one iteration per substep;
    with free-body masses and uniform gravity plain XPBD leaves the row force tens of % low and the boom sinks."""
    plant = PbdPlant(load_scene(load_scenario(MODELS / "boom" / "hold.scenario.toml").with_overrides(mode="pbd")))
    hold = plant.holding_efforts()[0]
    q0 = plant.xmodel.qpos_qvel(plant.state)[0]
    plant.articulated()
    state = plant.xmodel.state_from_qpos(q0)
    ell0 = plant.solver.row_lengths(state)[0]
    stiffness, stiction = 1.8e7, 5e5

    class Law:
        def before_substep(self, k, h, st):
            ell = plant.solver.row_lengths(st)[0]
            constant, slope = hold - stiffness * (ell - ell0), -h * stiffness - stiction
            return SubstepInputs(target_length=ell - h * constant / slope, compliance=np.atleast_1d(-h / slope),
                                 row_mobility=plant._mobility if articulated else None,
                                 group_gravity=plant._group_gravity if articulated else None)

    forces = []
    for _ in range(30):  # 0.5 s at 60 Hz × 20 substeps
        plant.solver.step(state, 1 / 60, hooks=Law())
        forces.append(plant.solver.last_forces[-1].row_force[0])
    error = np.abs(np.array(forces) - hold) / hold
    drift = abs(plant.xmodel.qpos_qvel(state)[0][0] - q0[0])
    if articulated:
        assert np.max(error) < 1e-5 and drift < 1e-8
    else:
        assert np.min(error) > 0.1 and drift > 1e-3


def test_boom_holds_still_like_mujoco(tmp_path):
    """Valves closed, no leakage: no drift over 5 s, cap pressure = MuJoCo mode's within 2 % (it is the geometric one)."""
    scene = scene_copy(tmp_path, "boom", NO_LEAK)
    hold = scene / "hold.scenario.toml"
    pbd = run(hold, out=tmp_path / "pbd.mcap", overrides={"mode": "pbd", "dt": 1 / 50, "pbd_substeps": 10, "duration": 5.0})
    mj = run(hold, out=tmp_path / "mj.mcap", overrides={"dt": 2e-3, "duration": 5.0})
    assert pbd.status == mj.status == "complete"
    cyl = read_log(pbd.log_path).topic("/hydroplant/cylinders/boom_cyl")
    ref = read_log(mj.log_path).topic("/hydroplant/cylinders/boom_cyl")
    assert np.ptp(cyl["position_m"]) < 1e-4
    assert np.mean(cyl["p_cap_pa"]) == pytest.approx(np.mean(ref["p_cap_pa"]), rel=0.02)
    assert np.ptp(cyl["p_cap_pa"]) < 0.01 * np.mean(cyl["p_cap_pa"])


def test_boom_lift_speed_and_pressure_like_mujoco(tmp_path):
    """Lift at 60 Hz × 20 substeps: rod speed = MuJoCo mode's and = pump flow / piston area within 2 %; same lifting pressure."""
    lift = MODELS / "boom" / "lift.scenario.toml"
    pbd = run(lift, out=tmp_path / "pbd.mcap", overrides={"mode": "pbd", "dt": 1 / 60, "pbd_substeps": 20, "duration": 3.0})
    mj = run(lift, out=tmp_path / "mj.mcap", overrides={"dt": 2e-3, "duration": 3.0})
    assert pbd.status == mj.status == "complete"

    def moving(result):
        log = read_log(result.log_path)
        cyl = log.topic("/hydroplant/cylinders/boom_cyl")
        x = cyl["position_m"]
        window = (x > 0.25) & (x < 0.35)
        assert window.sum() > 15
        speed = np.gradient(x, cyl.t)[window]
        flow = log.topic("/hydroplant/pumps/pump")["flow_m3ps"][window]
        return np.mean(speed), np.mean(flow) / BOOM_CAP_AREA, np.mean(cyl["p_cap_pa"][window])

    speed, expected, p_cap = moving(pbd)
    speed_mj, _, p_cap_mj = moving(mj)
    print(f"\nboom lift speed: PBD {speed:.5f} m/s, MuJoCo {speed_mj:.5f} m/s, pump flow/area {expected:.5f} m/s")
    assert speed == pytest.approx(speed_mj, rel=0.02)
    assert speed == pytest.approx(expected, rel=0.02)
    assert p_cap == pytest.approx(p_cap_mj, rel=0.02)


# ---------------------------------------------------------------------------- excavator


def test_excavator_dig_runs_with_physical_pressures(tmp_path):
    """The first 4 s of the dig cycle (approach, teeth hit the ground at 1.6 s, dig) at 60 Hz × 10 substeps: no NaN, pressures physical."""
    result = run(DIG, out=tmp_path / "dig.mcap", overrides={"mode": "pbd", "dt": 1 / 60, "pbd_substeps": 10, "duration": 4.0})
    assert result.status == "complete", result.message
    low, high = pressure_bounds()
    nodes = read_log(result.log_path).topic("/hydroplant/nodes")
    for name in nodes.messages[0]["pressure_pa"]:
        p = nodes[f"pressure_pa.{name}"]
        assert np.all(np.isfinite(p)), name
        assert np.all(p >= low - 1e-6) and np.all(p <= high), (name, p.min(), p.max())
    joints = read_log(result.log_path).topic("/hydroplant/joint_states")
    assert np.ptp(joints["position/boom"]) > 0.1 and np.ptp(joints["position/stick"]) > 0.3


def test_excavator_matches_mujoco_before_ground_contact(tmp_path):
    """Fine PBD (250 Hz × 8 substeps) vs MuJoCo mode over the first 1.5 s (hold, valves open at 1.0–1.3 s, approach; the
    teeth reach the ground only at 1.6 s, where the two contact models differ): strokes within 2 % of stroke, pressures
    within 5 % of the 343 bar relief."""
    pbd = run(DIG, out=tmp_path / "pbd.mcap", overrides={"mode": "pbd", "dt": 1 / 250, "pbd_substeps": 8, "duration": 1.5})
    mj = run(DIG, out=tmp_path / "mj.mcap", overrides={"duration": 1.5})
    assert pbd.status == mj.status == "complete"
    mj_log, pbd_log = read_log(mj.log_path), read_log(pbd.log_path)
    net = load_scene(load_scenario(DIG)).network
    for i, name in enumerate(net.actuator_names[k] for k in net.cylinder_actuator):
        ref, cyl = mj_log.topic(f"/hydroplant/cylinders/{name}"), pbd_log.topic(f"/hydroplant/cylinders/{name}")
        stroke = net.cylinder_stroke[i]
        dx = np.max(np.abs(cyl["position_m"] - np.interp(cyl.t, ref.t, ref["position_m"])))
        dp = max(np.max(np.abs(cyl[f] - np.interp(cyl.t, ref.t, ref[f]))) for f in ("p_cap_pa", "p_rod_pa"))
        print(f"\n{name}: stroke error {dx * 1e3:.2f} mm ({dx / stroke:.3%} of stroke), pressure error {dp / 1e5:.2f} bar ({dp / RELIEF:.2%} of relief)")
        assert np.ptp(cyl["position_m"]) > 0.05  # it moved
        assert dx < 0.02 * stroke and dp < 0.05 * RELIEF


def test_excavator_strokes_match_mujoco_through_ground_contact(tmp_path):
    """60 Hz × 20 substeps vs MuJoCo mode (1 kHz) over the first 3 s: the teeth hit the ground at 1.6 s and drag from 2.5 s.
    With the MuJoCo-equivalent soft pyramidal contacts (same solref/solimp, effective mass and pyramid edges) the strokes
    stay within 2 % of stroke (rigid Coulomb contacts: 4.3 % over the dig).  Pressures are not compared pointwise here:
    in the contact phase MuJoCo mode's own pressures change by up to 48 % of the relief setting between dt = 1 ms and
    0.25 ms (teeth stick-slip), see the PBD helper's report."""
    pbd = run(DIG, out=tmp_path / "pbd.mcap", overrides={"mode": "pbd", "dt": 1 / 60, "pbd_substeps": 20, "duration": 3.0})
    mj = run(DIG, out=tmp_path / "mj.mcap", overrides={"duration": 3.0})
    assert pbd.status == mj.status == "complete"
    mj_log, pbd_log = read_log(mj.log_path), read_log(pbd.log_path)
    net = load_scene(load_scenario(DIG)).network
    for i, name in enumerate(net.actuator_names[k] for k in net.cylinder_actuator):
        ref, cyl = mj_log.topic(f"/hydroplant/cylinders/{name}"), pbd_log.topic(f"/hydroplant/cylinders/{name}")
        dx = np.max(np.abs(cyl["position_m"] - np.interp(cyl.t, ref.t, ref["position_m"])))
        print(f"\n{name}: stroke error {dx * 1e3:.2f} mm ({dx / net.cylinder_stroke[i]:.3%} of stroke) over 0-3 s")
        assert dx < 0.02 * net.cylinder_stroke[i]


def test_cli_runs_pbd_mode_with_the_mujoco_topics(tmp_path, capsys):
    """``hydroplant run SCENARIO --mode pbd --pbd-substeps N --iterations K`` writes the same topics and fields as MuJoCo mode."""
    lift = MODELS / "boom" / "lift.scenario.toml"
    assert main(["run", str(lift), "--mode", "pbd", "--pbd-substeps", "8", "--iterations", "2", "--dt", "0.02", "--duration", "0.4",
                 "--out", str(tmp_path / "pbd.mcap"), "--no-progress"]) == 0
    assert "mode          pbd" in capsys.readouterr().out
    assert main(["run", str(lift), "--duration", "0.4", "--out", str(tmp_path / "mj.mcap"), "--no-progress"]) == 0
    pbd, mj = read_log(tmp_path / "pbd.mcap"), read_log(tmp_path / "mj.mcap")
    assert set(pbd.topics) == set(mj.topics)
    meta = pbd.metadata["hydroplant.run"]
    assert meta["mode"] == "pbd" and meta["pbd_substeps"] == "8" and meta["pbd_iterations"] == "2"
    for topic in set(mj.topics) - {"/hydroplant/events", "/hydroplant/scene"}:
        a, b = mj.topic(topic).messages[-1], pbd.topic(topic).messages[-1]
        assert type(a) is type(b) and (set(a) == set(b) if isinstance(a, dict) else True), topic
    assert np.all(np.isfinite(pbd.topic("/tf").messages[-1]["transforms"][0]["translation"]["x"]))


# ---------------------------------------------------------------------------- numerical damping


@pytest.mark.parametrize("dt, substeps", [(2e-4, 1), (8e-4, 4)])
def test_blocked_oil_column_decays_like_backward_euler(tmp_path, dt, substeps):
    """A mass on a closed oil column (seed cylinder near rest, 1 mm swing): the amplitude decays at ln(1 + ω²h²)/(2h) within 5 %."""
    x0, p0 = 2.0, 1.0e6  # m, Pa: equilibrium (P = 0) at x = x0·exp(p0/β)
    scene = scene_copy(tmp_path, "seed_cylinder", {"closed.scenario.toml": [
        ("qpos = { x = 1.0 }", f"qpos = {{ x = {x0} }}"), ("pressures = { cyl_cap = 2.2e9 }", f"pressures = {{ cyl_cap = {p0} }}")]})
    scenario = load_scenario(scene / "closed.scenario.toml").with_overrides(mode="pbd", dt=dt, pbd_substeps=substeps)
    plant = PbdPlant(load_scene(scenario))
    h = dt / substeps
    x_eq = x0 * math.exp(p0 / BETA)
    omega = math.sqrt(AREA * BETA / (MASS * x_eq))  # k = β·A²/V, V = A·x
    times, xs = [], []
    while plant.time < 0.04:
        plant.step()
        times.append(plant.time)
        xs.append(plant.net_state.actuator_position[0])
    t, x = np.array(times), np.array(xs) - x_eq

    def damped(t, amplitude, rate, frequency, phase):
        return amplitude * np.exp(-rate * t) * np.cos(frequency * t + phase)

    (amplitude, rate, frequency, _), _ = curve_fit(damped, t, x, p0=[x[0], 50.0, omega, 0.0])
    predicted = math.log(1.0 + (omega * h) ** 2) / (2.0 * h)
    print(f"\nω·h = {omega * h:.3f}: decay {rate:.2f} 1/s, backward Euler {predicted:.2f} 1/s; frequency {frequency:.1f} vs atan(ωh)/h = {math.atan(omega * h) / h:.1f} rad/s")
    assert rate == pytest.approx(predicted, rel=0.05)
    assert frequency == pytest.approx(math.atan(omega * h) / h, rel=0.01)


# ---------------------------------------------------------------------------- start state


@pytest.mark.parametrize("scenario", [MODELS / "boom" / "hold.scenario.toml", DIG])
def test_start_pressures_equal_mujoco_mode(scenario):
    """Equilibrium start: the same holding efforts and chamber pressures as MuJoCo mode at t = 0, and after the first
    steps (t = 0+, 10 ms at 1 kHz) every chamber within 1 % of MuJoCo mode's (no sag into the oil columns)."""
    sc = load_scenario(scenario)
    from sim.plants.mujoco import MujocoPlant

    mj = MujocoPlant(load_scene(sc))
    pbd = PbdPlant(load_scene(sc.with_overrides(mode="pbd", dt=1e-3, pbd_substeps=4)))
    net = mj.network
    chambers = np.r_[net.cylinder_cap_node, net.cylinder_rod_node]
    assert pbd.holding_efforts() == pytest.approx(mj.holding_efforts(), rel=1e-6, abs=1e-6)
    assert pbd.net_state.node_pressure == pytest.approx(mj.net_state.node_pressure, rel=1e-9)
    for _ in range(10):
        mj.step()
        pbd.step()
    p_mj, p_pbd = mj.net_state.node_pressure[chambers], pbd.net_state.node_pressure[chambers]
    assert np.all(np.abs(p_pbd - p_mj) < 0.01 * p_mj)
    x_mj, x_pbd = mj.net_state.actuator_position, pbd.net_state.actuator_position
    assert np.max(np.abs(x_pbd - x_mj)) < 1e-6  # m: no sag


def test_joint_space_mass_matrix_is_mujocos_with_the_swing_armature():
    """The XPBD model's joint-space mass matrix equals MuJoCo's (mj_fullM) on the excavator at its start pose and at
    a swung, folded pose, to 1e-9 relative, the swing's 320 kg·m² armature included (it is a rotor inertia of the
    upper group, whose parent is static); without it the swing's diagonal would be 0.16 % low."""
    import mujoco

    plant = PbdPlant(load_scene(load_scenario(DIG).with_overrides(mode="pbd")))
    m = plant.model
    d = mujoco.MjData(m)
    assert plant.xmodel.jnt_armature[0] == pytest.approx(m.dof_armature[0]) and m.dof_armature[0] == 320.0
    for pose in (None, np.array([0.7, -0.4, 0.6, -0.8])):
        if pose is not None:
            plant.state = plant.xmodel.state_from_qpos(pose)
        mass, _, _ = plant.joint_space()
        d.qpos[:] = plant.xmodel.qpos_qvel(plant.state)[0]
        mujoco.mj_forward(m, d)
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        assert mass == pytest.approx(full, rel=1e-9, abs=1e-9 * np.max(np.abs(full)))


def test_motor_torque_acts_on_the_articulated_mechanism():
    """A swing-motor effort accelerates the swing joint by gear·effort·(M⁻¹)ⱼⱼ (the articulated response that the
    motor's implicit damping assumes), not by the house's free-body inertia: one 1 ms step from rest within 0.5 %."""
    plant = PbdPlant(load_scene(load_scenario(DIG).with_overrides(mode="pbd")))
    plant.articulated()
    mass, _, _ = plant.joint_space()
    j = int(plant.motor_joint[0])
    dof = int(plant.xmodel.jnt_dofadr[j])
    effort = 400.0  # N·m at the motor
    inputs = SubstepInputs(group_gravity=plant._group_gravity + effort * plant._motor_response[0])
    state = plant.state
    h = 1e-3
    plant.solver.substeps = 1
    plant.solver.step(state, h, inputs=inputs)
    rate = plant.xmodel.qpos_qvel(state)[1][dof]
    expected = h * plant.motor_gear[0] * effort * np.linalg.inv(mass)[dof, dof]
    assert rate == pytest.approx(expected, rel=5e-3)
