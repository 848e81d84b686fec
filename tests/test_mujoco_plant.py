"""MuJoCo mode: seed cylinder against the seed's equations, boom holding/sinking/lifting, relief at the end stop."""

import math

import mujoco
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from conftest import MODELS, scene_copy
from sim.io.mcap_log import read_log
from sim.run.runner import run
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene

SEED = MODELS / "seed_cylinder" / "closed.scenario.toml"
BETA, AREA, MASS = 2.2e9, 0.03**2, 1.0  # the seed report's Figure 3 numbers


def seed_reference(times):
    """The seed report's equations solved by scipy: m·x'' = P·A, dP/dt = −(β/x)·dx/dt (independent of our code)."""

    def rhs(t, y):
        x, v, p = y
        return [v, p * AREA / MASS, -BETA / x * v]

    sol = solve_ivp(rhs, (0, times[-1]), [1.0, 0.0, BETA], method="DOP853", rtol=1e-12, atol=[1e-12, 1e-9, 1e-3], t_eval=times)
    return sol.y


def test_seed_fine_dt_matches_scipy_reference(tmp_path):
    """At fine dt the MuJoCo-mode run matches the seed's equations: stroke and pressure within 0.5 % of their ranges."""
    result = run(SEED, out=tmp_path / "seed.mcap", overrides={"dt": 1e-5, "duration": 0.02})
    assert result.status == "complete"
    log = read_log(result.log_path)
    cyl = log.topic("/hydroplant/cylinders/cyl")
    x_ref, _, p_ref = seed_reference(cyl.t)
    x, p = cyl["position_m"], cyl["p_cap_pa"]
    assert np.max(np.abs(x - x_ref)) < 0.005 * np.ptp(x_ref)
    assert np.max(np.abs(p - p_ref)) < 0.005 * np.ptp(p_ref)
    assert np.ptp(x_ref) > 3.0  # the run covered a full swing from 1 m to ~4.9 m


def test_seed_1200hz_implicit_bounded_explicit_diverges(tmp_path):
    """At the seed's 1200 Hz the implicit coupling stays bounded for the whole 0.1 s; explicit diverges."""
    implicit = run(SEED, out=tmp_path / "imp.mcap")
    assert implicit.status == "complete"
    cyl = read_log(implicit.log_path).topic("/hydroplant/cylinders/cyl")
    assert len(cyl.t) == 121 and cyl.t[-1] == pytest.approx(0.1)
    assert np.all(np.abs(cyl["position_m"]) < 10) and np.all(np.isfinite(cyl["p_cap_pa"]))
    explicit = run(SEED, out=tmp_path / "exp.mcap", overrides={"coupling": "explicit"})
    assert explicit.status == "diverged"
    assert explicit.simulated_time < 0.1
    assert read_log(explicit.log_path).status == "diverged"


NO_LEAK = {"boom.circuit.toml": [("leakage_area = 1.0e-11", "leakage_area = 0.0")]}


def boom_holding_pressure(scenario_path):
    """Cap pressure that holds the boom, from geometry: F = τ_gravity / moment arm, rod side at the base pressure."""
    scene = load_scene(load_scenario(scenario_path))
    m = scene.mjmodel
    d = mujoco.MjData(m)
    d.qpos[0] = scene.scenario.qpos["boom_hinge"]
    mujoco.mj_forward(m, d)
    boom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "boom")
    arm = d.subtree_com[boom][0] - d.xanchor[0][0]  # horizontal lever of the boom + payload weight [m]
    torque = m.body_subtreemass[boom] * 9.81 * arm
    force = torque / d.actuator_moment[0]
    net = scene.network
    a_cap, a_rod = net.cylinder_cap_area[0], net.cylinder_rod_area[0]
    return (force + scene.scenario.base_pressure * a_rod + net.fluid.reference_pressure * (a_cap - a_rod)) / a_cap


def test_boom_holds_still_at_geometric_equilibrium_pressure(tmp_path):
    """Valves closed, no leakage: drift < 0.1 mm over 10 s, cap pressure = the pressure geometry says."""
    scene = scene_copy(tmp_path, "boom", NO_LEAK)
    result = run(scene / "hold.scenario.toml", out=tmp_path / "hold.mcap", overrides={"dt": 2e-3})
    assert result.status == "complete"
    cyl = read_log(result.log_path).topic("/hydroplant/cylinders/boom_cyl")
    assert np.ptp(cyl["position_m"]) < 1e-4
    assert cyl["p_cap_pa"][0] == pytest.approx(boom_holding_pressure(scene / "hold.scenario.toml"), rel=1e-3)


def test_boom_sinks_at_leakage_flow_over_area(tmp_path):
    """A leak from the cap line to tank: sink speed = leak flow / piston area within 5 %."""
    leak = """
[[component]]
name = "cap_leak"
type = "orifice"
area = 2.0e-8
ports = { a = "boom_valve_a", b = "tank" }
"""
    edits = dict(NO_LEAK)
    scene = scene_copy(tmp_path, "boom", edits)
    circuit = scene / "boom.circuit.toml"
    circuit.write_text(circuit.read_text() + leak)
    result = run(scene / "hold.scenario.toml", out=tmp_path / "leak.mcap", overrides={"dt": 2e-3, "duration": 4.0})
    assert result.status == "complete"
    log = read_log(result.log_path)
    cyl = log.topic("/hydroplant/cylinders/boom_cyl")
    flow = log.topic("/hydroplant/flows")["flow_m3ps.cap_leak"]
    a_cap = math.pi * 0.063**2 / 4
    window = cyl.t > 1.0
    sink = -np.gradient(cyl["position_m"], cyl.t)[window]
    assert np.mean(sink) > 1e-5  # it really sinks
    assert np.mean(sink) == pytest.approx(np.mean(flow[window]) / a_cap, rel=0.05)


def test_boom_lift_speed_and_relief_at_end_stop(tmp_path):
    """Lift speed = delivered pump flow / piston area within 2 %; at the end stop the relief holds its setting."""
    scenario = MODELS / "boom" / "lift.scenario.toml"
    result = run(scenario, out=tmp_path / "lift.mcap", overrides={"dt": 2e-3})
    assert result.status == "complete"
    log = read_log(result.log_path)
    cyl = log.topic("/hydroplant/cylinders/boom_cyl")
    pump = log.topic("/hydroplant/pumps/pump")
    supply = log.topic("/hydroplant/nodes")["pressure_pa.supply"]
    a_cap = math.pi * 0.063**2 / 4
    x = cyl["position_m"]
    moving = (x > 0.25) & (x < 0.35)
    assert moving.sum() > 20
    speed = np.gradient(x, cyl.t)[moving]
    relief_closed = supply[moving] - 1.01325e5 < 2.0e7
    assert relief_closed.all()
    assert np.mean(speed) == pytest.approx(np.mean(pump["flow_m3ps"][moving]) / a_cap, rel=0.02)
    at_stop = x >= 0.4 - 1e-3
    assert at_stop[-1]
    late = cyl.t > cyl.t[np.argmax(at_stop)] + 0.5
    dp = supply[late] - 1.01325e5
    override = np.max(pump["flow_m3ps"]) / 5.0e-10
    assert np.all(dp >= 2.0e7) and np.all(dp <= 2.0e7 + 1.05 * override)
