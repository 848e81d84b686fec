"""PBD mode with MuJoCo mode's θ-rule (``[run] pbd_blend``) and with the linear couplings (``rosenbrock``).

θ-rule: each cylinder row's pressure force is blended between its start-of-substep value and the
backward-Euler law by θ = clip(1 − 2/(ω·h)², 0, 1) (``hydraulics.coupling.blend_factor``, the
articulated effective mass of the row).  Where ω·h < √2 the force is explicit and XPBD's
prediction–projection is symplectic Euler: a blocked oil column keeps its amplitude and rings at
2·asin(ω·h/2)/h, instead of backward Euler's decay ln(1 + ω²h²)/(2h).  On the boom lift this
makes PBD mode as accurate as MuJoCo mode at the same step.

``rosenbrock`` per XPBD substep: the network linearised by one Newton step and finished linearly
(no Newton solve); the boom still lifts at pump flow / piston area, like MuJoCo mode.
"""

import math
import warnings

import numpy as np
import pytest
from scipy.optimize import curve_fit

from conftest import MODELS, scene_copy
from sim.tools.compare import richardson_first_order
from sim.plants.mujoco_fast import MujocoPlantFast
from sim.plants.pbd import PbdPlant
from sim.io.scenario import ScenarioError, load_scenario
from sim.io.scene import load_scene
from test_mujoco_plant import AREA, BETA, MASS

BOOM = MODELS / "boom" / "lift.scenario.toml"
BOOM_STROKE = 0.40  # m


@pytest.fixture(autouse=True)
def _quiet_xpbd_notes():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="XpbdModel:")
        yield


def test_blend_keeps_a_blocked_oil_column_ringing_like_symplectic_euler(tmp_path):
    """ω·h ≈ 0.8 < √2: θ = 0, no numerical damping (fitted decay < 2 % of backward Euler's) and the
    frequency of symplectic Euler, 2·asin(ω·h/2)/h, within 1 %."""
    x0, p0 = 2.0, 1.0e6  # m, Pa: equilibrium (P = 0) at x = x0·exp(p0/β)
    scene = scene_copy(tmp_path, "seed_cylinder", {"closed.scenario.toml": [
        ("qpos = { x = 1.0 }", f"qpos = {{ x = {x0} }}"), ("pressures = { cyl_cap = 2.2e9 }", f"pressures = {{ cyl_cap = {p0} }}")]})
    x_eq = x0 * math.exp(p0 / BETA)
    omega = math.sqrt(AREA * BETA / (MASS * x_eq))  # k = β·A²/V, V = A·x
    h = 0.8 / omega
    scenario = load_scenario(scene / "closed.scenario.toml").with_overrides(mode="pbd", dt=h, pbd_substeps=1, pbd_blend=True)
    plant = PbdPlant(load_scene(scenario))
    times, xs = [], []
    while plant.time < 0.04:
        plant.step()
        times.append(plant.time)
        xs.append(plant.net_state.actuator_position[0])
    assert np.all(plant.theta == 0.0)
    t, x = np.array(times), np.array(xs) - x_eq

    def damped(t, amplitude, rate, frequency, phase):
        return amplitude * np.exp(-rate * t) * np.cos(frequency * t + phase)

    (_, rate, frequency, _), _ = curve_fit(damped, t, x, p0=[x[0], 0.0, omega, 0.0])
    backward_euler = math.log(1.0 + (omega * h) ** 2) / (2.0 * h)
    symplectic = 2.0 * math.asin(omega * h / 2.0) / h
    print(f"\nω·h = {omega * h:.3f}: decay {rate:.3f} 1/s (backward Euler {backward_euler:.1f}), "
          f"frequency {frequency:.1f} vs symplectic Euler {symplectic:.1f} rad/s")
    assert abs(rate) < 0.02 * backward_euler
    assert frequency == pytest.approx(symplectic, rel=0.01)


def _boom_strokes(mode, dt, duration=2.4, **overrides):
    scenario = load_scenario(BOOM).with_overrides(mode=mode, dt=dt, **overrides)
    scene = load_scene(scenario)
    plant = PbdPlant(scene) if mode == "pbd" else MujocoPlantFast(scene)
    xs = []
    for _ in range(int(round(duration / dt))):
        plant.advance(1)
        xs.append(plant.net_state.actuator_position[0])
    return dt * np.arange(1, len(xs) + 1), np.array(xs)


def test_blend_makes_the_boom_lift_as_accurate_as_mujoco_mode():
    """Boom lift to t = 2.4 s (before its end stop) against MuJoCo mode at 0.25 ms: PBD at 1 ms × 1 substep with the
    θ-rule within 1.5× MuJoCo mode's error at 1 ms, and at least 5× more accurate than PBD at θ = 1."""
    t_ref, x_ref = _boom_strokes("mujoco", 2.5e-4)

    def error(run):
        t, x = run
        return float(np.max(np.abs(x - np.interp(t, t_ref, x_ref)))) / BOOM_STROKE

    mujoco = error(_boom_strokes("mujoco", 1e-3))
    blend = error(_boom_strokes("pbd", 1e-3, pbd_substeps=1, pbd_blend=True))
    theta_one = error(_boom_strokes("pbd", 1e-3, pbd_substeps=1))
    rosenbrock = error(_boom_strokes("pbd", 1e-3, pbd_substeps=1, pbd_blend=True, coupling="rosenbrock"))
    print(f"\nboom stroke error, % of stroke: MuJoCo 1 ms {100 * mujoco:.4f}, PBD θ-rule {100 * blend:.4f} "
          f"(rosenbrock {100 * rosenbrock:.4f}), PBD θ = 1 {100 * theta_one:.4f}")
    assert blend <= 1.5 * mujoco
    assert rosenbrock <= 1.5 * mujoco
    assert blend * 5 <= theta_one


@pytest.mark.parametrize("coupling, blend", [("rosenbrock", False), ("rosenbrock", True), ("implicit", True)])
def test_boom_lifts_at_pump_flow_over_piston_area(coupling, blend):
    """60 Hz × 20 substeps: while the stroke is between 0.25 and 0.35 m the rod moves at the pump flow / cap area
    within 2 % (oil is neither created nor lost by the linear finish) with the relief shut (cap pressure below it)."""
    scenario = load_scenario(BOOM).with_overrides(mode="pbd", dt=1 / 60, pbd_substeps=20, coupling=coupling, pbd_blend=blend)
    plant = PbdPlant(load_scene(scenario))
    net = plant.network
    cap = math.pi * 0.063**2 / 4  # m²
    pump = net.branch_names.index("pump")
    t, x, q, p_cap = [], [], [], []
    while plant.time < 3.0:
        report = plant.advance(1)
        assert report.success
        t.append(plant.time)
        x.append(plant.net_state.actuator_position[0])
        q.append(report.branch_flow[pump])
        p_cap.append(plant.net_state.node_pressure[net.node_names.index("boom_cyl_cap")])
    t, x, q = np.array(t), np.array(x), np.array(q)
    window = (x > 0.25) & (x < 0.35)
    assert window.sum() > 15
    speed = np.mean(np.gradient(x, t)[window])
    assert speed == pytest.approx(np.mean(q[window]) / cap, rel=0.02)
    assert np.max(np.array(p_cap)[window]) < np.max(net.relief_cracking) + net.fluid.reference_pressure


def test_linear_couplings_need_one_hydraulic_substep_and_pbd_naive_ignores_the_coupling():
    assert load_scenario(BOOM).with_overrides(mode="pbd", coupling="rosenbrock").coupling == "rosenbrock"
    for mode in ("mujoco", "pbd"):
        with pytest.raises(ScenarioError, match=r"run\.coupling.*hydraulic_substeps = 1 \(got 2; coupling = 'implicit'"):
            load_scenario(BOOM).with_overrides(mode=mode, coupling="implicit-linear", hydraulic_substeps=2)
    assert load_scenario(BOOM).with_overrides(mode="mujoco", coupling="implicit", hydraulic_substeps=2).hydraulic_substeps == 2
    # pbd-naive is always explicit: the scenario's coupling (the default one, say) does not stop it
    naive = load_scenario(BOOM).with_overrides(mode="pbd-naive", hydraulic_substeps=2)
    assert (naive.coupling, naive.hydraulic_substeps) == ("rosenbrock", 2)


def test_cli_pbd_blend_logs_the_rows_theta(tmp_path):
    """``hydroplant run --mode pbd --pbd-blend`` on the boom at 1 ms: the log's cylinder θ is 0 (the oil column is
    resolved, ω·h < √2) on every sample after the start (the t = 0 sample precedes any step: θ = 1 there) from the
    block path; without the flag it is 1 (backward Euler)."""
    from sim.cli import main
    from sim.io.mcap_log import read_log

    thetas = []
    for flags in (["--pbd-blend"], []):
        out = tmp_path / f"boom{len(flags)}.mcap"
        assert main(["run", str(BOOM), "--mode", "pbd", "--dt", "0.001", "--pbd-substeps", "1", "--duration", "0.5",
                     "--coupling", "rosenbrock", "--no-progress", "--out", str(out), *flags]) == 0
        thetas.append(read_log(out).topic("/hydroplant/cylinders/boom_cyl")["theta"])
    blended, backward = thetas
    assert len(blended) >= 50 and blended[0] == 1.0 and np.all(blended[1:] == 0.0)
    assert np.all(backward == 1.0)


EXCAVATOR = MODELS / "excavator" / "dig.scenario.toml"


def _excavator_strokes(mode, dt, duration, **overrides):
    scenario = load_scenario(EXCAVATOR).with_overrides(mode=mode, dt=dt, duration=duration, **overrides)
    scene = load_scene(scenario)
    plant = PbdPlant(scene) if mode == "pbd" else MujocoPlantFast(scene)
    cylinders = scene.network.cylinder_actuator
    xs = []
    for _ in range(int(round(duration / dt))):
        plant.advance(1)
        xs.append(plant.net_state.actuator_position[cylinders])
    return np.array(xs)


def test_blend_follows_mujoco_mode_when_a_friction_row_turns_explicit():
    """Excavator, 0–1.25 s: the valves open at 1.0 s and the cylinders break away.  At 1.112 s the bucket
    cylinder's seal friction enters its Stribeck dip, its slope ∂F/∂v crosses zero and the row turns from a
    compliant row into an explicit force.  That force acts through the articulated response, as in MuJoCo
    mode (as per-body forces projected by one joint iteration it kicked all three cylinders: 52–318 µm of
    stroke off MuJoCo mode at 0.25–2 ms substeps, not converging).  PBD at 1 ms × 4 substeps (h = 0.25 ms)
    against MuJoCo mode at 0.25 ms: every stroke within 2 µm the whole time."""
    duration = 1.25
    reference = _excavator_strokes("mujoco", 2.5e-4, duration)[3::4]  # at the PBD frames' ends
    pbd = _excavator_strokes("pbd", 1e-3, duration, pbd_substeps=4, pbd_blend=True)
    error = np.max(np.abs(pbd - reference))
    moved = np.max(np.abs(reference[-1] - reference[0]))
    print(f"\nexcavator 0–{duration} s, PBD θ-rule 1 ms × 4 against MuJoCo mode 0.25 ms: {1e6 * error:.3f} µm "
          f"(the cylinders moved up to {1e3 * moved:.1f} mm)")
    assert moved > 5e-3
    assert error < 2e-6


def test_excavator_approach_converges_at_first_order_in_the_substep_whatever_the_frame():
    """Excavator 0–1.5 s (the valves open at 1.0 s; the teeth reach the soil at 1.6 s) against a converged
    reference, the Richardson extrapolation 2·x(h/2) − x(h) of MuJoCo mode at h = 62.5 µs (MuJoCo mode is
    first order there: its 31.25 µs run is 6.5e-7 of stroke from the extrapolation, its 1 ms run 2.1e-5).
    PBD mode (rosenbrock, θ-rule) converges at first order in its substep (60 Hz frames × 20 → × 40: error
    ratio 0.5 ± 0.1); at a 1 ms substep its error does not depend on the frame the substeps share (1 ms × 1
    and 10 ms × 10 within 5 %) and is within 5 % of MuJoCo mode's at 1 ms; at 60 Hz × 18 (h = 0.93 ms) it is
    at least as accurate as MuJoCo mode at 1 ms, the setting ``bench/bench_pbd.py`` times against it."""
    duration = 1.5
    stroke = load_scene(load_scenario(EXCAVATOR)).network.cylinder_stroke

    def run(mode, dt, **overrides):
        x = _excavator_strokes(mode, dt, duration, **overrides)
        return dt * np.arange(1, len(x) + 1), x

    def at(run_, times):
        t, x = run_
        return np.column_stack([np.interp(times, t, x[:, c]) for c in range(x.shape[1])])

    t, fine = run("mujoco", 3.125e-5)
    t_coarse, coarse = run("mujoco", 6.25e-5)
    reference = np.column_stack([richardson_first_order(t, fine[:, c], t_coarse, coarse[:, c]) for c in range(fine.shape[1])])

    def error(run_):
        return float(np.max(np.abs(run_[1] - at((t, reference), run_[0])) / stroke))

    def pbd(dt, n):
        return error(run("pbd", dt, pbd_substeps=n, pbd_blend=True, coupling="rosenbrock"))

    mujoco = error(run("mujoco", 1e-3))
    errors = {(1e-3, 1): pbd(1e-3, 1), (1e-2, 10): pbd(1e-2, 10), (1 / 60, 18): pbd(1 / 60, 18),
              (1 / 60, 20): pbd(1 / 60, 20), (1 / 60, 40): pbd(1 / 60, 40)}
    print(f"\nexcavator 0–{duration} s, stroke error / stroke against the Richardson reference: MuJoCo mode 1 ms "
          f"{mujoco:.3e}; PBD rosenbrock θ-rule " + ", ".join(f"{1e3 * dt:.3g} ms × {n} {e:.3e}" for (dt, n), e in errors.items()))
    assert 0.4 < errors[(1 / 60, 40)] / errors[(1 / 60, 20)] < 0.6
    assert errors[(1e-2, 10)] == pytest.approx(errors[(1e-3, 1)], rel=0.05)
    assert errors[(1e-3, 1)] == pytest.approx(mujoco, rel=0.05)
    assert errors[(1 / 60, 18)] <= mujoco


def test_rosenbrock_linearises_a_turning_swing_motor_at_its_speed():
    """Excavator swing braking (the swing valve closes 8.75–9.05 s with the motor at ≈ 18 rad/s): PBD mode with
    ``rosenbrock`` at 1 ms × 1 substep follows MuJoCo mode's rosenbrock at 1 ms within 5 bar on the motor's A port.  Its one Newton step is
    taken about the substep's start velocities (``start_velocity_guess``, as MuJoCo mode), not about a held motor:
    from a held motor the linear finish extrapolated the valve's square-root law over 18 rad/s of motor flow and held
    the port at 303 bar until 9.0 s while MuJoCo mode's fell to 233 bar."""
    plants = {}
    for mode in ("mujoco", "pbd"):
        scenario = load_scenario(EXCAVATOR).with_overrides(mode=mode, dt=1e-3, coupling="rosenbrock", duration=9.1,
                                                           pbd_substeps=1 if mode == "pbd" else None)
        scene = load_scene(scenario)
        plants[mode] = PbdPlant(scene) if mode == "pbd" else MujocoPlantFast(scene)
    port = scene.network.node_names.index("swing_motor_a")
    worst, drop = 0.0, 0.0
    for mode, plant in plants.items():
        plant.advance(8900)
    for _ in range(150):  # 8.90–9.05 s
        p = {}
        for mode, plant in plants.items():
            assert plant.advance(1).success
            p[mode] = plant.net_state.node_pressure[port]
        worst = max(worst, abs(p["pbd"] - p["mujoco"]))
        drop = max(drop, 303e5 - p["mujoco"])
    print(f"\nswing motor A port, 8.90–9.05 s: PBD rosenbrock within {worst / 1e5:.2f} bar of MuJoCo mode's "
          f"(which falls {drop / 1e5:.0f} bar below 303 bar)")
    assert drop > 200e5
    assert worst < 5e5
