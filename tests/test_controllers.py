"""Controllers as inputs: the PID law, its scenario syntax, and closed loops in the compiled blocks of both modes.

* Law (:func:`hydraulics.controllers.pid_update`): the integrator of a constant error grows by ki·h·e per sample;
  clamping stops it while the output is saturated; back-calculation settles it where ki·e = (h/T_t)·... exactly
  I* = high − kp·e + ki·T_t·e; the derivative acts on the measurement through its first-order filter.
* Position servo from a scenario file alone (tests/scenes/servo.scenario.toml: a first-order valve, τ = 50 ms,
  driving a double-rod cylinder with no load, v = K·s with K = C_d·A_max·sqrt((p_s − p_t)/ρ)/A): with P control
  the loop is x/r = K·kp/(τs² + s + K·kp), ζ = 1/(2·sqrt(τ·K·kp)), ω_n = sqrt(K·kp/τ); overshoot
  exp(−πζ/sqrt(1 − ζ²)) and peak time π/(ω_n·sqrt(1 − ζ²)) held within 1 % in both modes.  With PI the loop is
  third order (τs³ + s² + K·kp·s + K·ki); its step response is computed exactly (matrix exponential) and matched
  the same way (`tests/scenes/servo_pi.scenario.toml`).
* Limits and anti-windup on a saturating step; the sample rate holds the output between samples.
* A Python callable ``controller(t, sensors)`` running the same law gives the compiled PID's run to round-off.
* Snapshot/resume continues the loop bit for bit; the controllers' channels are logged.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from hydraulics import controllers as CT
from sim.io.mcap_log import read_log
from sim.io.scenario import ScenarioError, load_scenario
from sim.io.scene import load_scene
from sim.plants.controllers import PythonController
from sim.run import snapshot
from sim.run.runner import make_plant, run

SCENES = Path(__file__).parent / "scenes"
SERVO = SCENES / "servo.scenario.toml"
STEP_TIME, X0, STEP = 0.05, 0.2, 0.01  # s, m, m: the scenario's setpoint step
TAU = 0.05  # s: the valve's time constant
AREA = math.pi * (0.063**2 - 0.035**2) / 4  # m²
GAIN = 0.7 * 1e-5 * math.sqrt((1e7 - 1.01325e5) / 870.0) / AREA  # K [m/s per unit spool]


def _row(**changes):
    values = dict(kp=2.0, ki=0.0, kd=0.0, derivative_filter=0.0, low=-1.0, high=1.0, anti_windup=CT.WINDUP_NONE,
                  tracking_gain=0.0, every=1, sensor_kind=0, sensor_index=0, output_kind=0, output_index=0)
    values.update(changes)
    return CT.pack(1, **values)[0]


def _samples(p, errors, h):
    """Run the law over ``errors`` (measurement = −e, setpoint 0); returns the outputs and the last state."""
    state = CT.initial_state(1)[0]
    out = []
    for e in errors:
        u, raw, integrator, derivative = CT.pid_update(p, state, e, -e, h)
        state[CT.S_OUTPUT], state[CT.S_INTEGRATOR], state[CT.S_DERIVATIVE] = u, integrator, derivative
        state[CT.S_MEASUREMENT], state[CT.S_SAMPLED] = -e, 1.0
        out.append(u)
    return np.array(out), state


def test_law_integrates_clamps_and_tracks():
    h = 1e-3
    # unsaturated: u_k = kp·e + k·ki·h·e (forward Euler: the k-th output holds k earlier samples)
    out, state = _samples(_row(kp=2.0, ki=10.0, high=100.0, low=-100.0), [0.5] * 20, h)
    assert out == pytest.approx(2.0 * 0.5 + np.arange(20) * 10.0 * h * 0.5, rel=1e-12)
    # saturated at high = 1: without anti-windup the integrator grows on, with clamping it stops where it was
    errors = [1.0] * 400
    _, free = _samples(_row(kp=2.0, ki=10.0), errors, h)
    _, clamped = _samples(_row(kp=2.0, ki=10.0, anti_windup=CT.WINDUP_CLAMP), errors, h)
    assert free[CT.S_INTEGRATOR] == pytest.approx(400 * 10.0 * h, rel=1e-12)
    assert clamped[CT.S_INTEGRATOR] == 0.0  # kp·e = 2 > 1 from the first sample: never integrates
    # back-calculation: I settles where ki·h·e + (h/Tt)·(high − kp·e − I) = 0
    tt = 0.05
    _, back = _samples(_row(kp=0.5, ki=10.0, anti_windup=CT.WINDUP_BACK, tracking_gain=h / tt), [1.0] * 3000, h)
    assert back[CT.S_INTEGRATOR] == pytest.approx(1.0 - 0.5 + 10.0 * tt, rel=1e-9)
    # derivative on the measurement, filtered: D_k = (Tf·D_{k−1} − kd·Δy)/(Tf + h) for a ramp y = −e = c·k
    c, kd, tf = 1e-3, 0.2, 0.01
    out, _ = _samples(_row(kp=0.0, kd=kd, derivative_filter=tf, high=1e3, low=-1e3), [-c * k for k in range(200)], h)
    steady = -kd * c / h
    assert out[0] == 0.0 and out[-1] == pytest.approx(steady, rel=1e-6)
    assert out[1] == pytest.approx(steady * h / (tf + h), rel=1e-12)


def _write(tmp_path, text):
    source = SERVO.read_text()
    for name in ("servo.xml", "servo.circuit.toml"):
        (tmp_path / name).write_text((SCENES / name).read_text())
    path = tmp_path / "s.scenario.toml"
    path.write_text(source.split("[controllers.stroke]")[0] + text)
    return path


@pytest.mark.parametrize("text, message", [
    ('[controllers.c]\ntype = "pid"\noutput = "valve"\nsensor = "height:cyl"\nsetpoint = 0.2\n',
     r"\[controllers.c\]: field 'sensor': 'height:cyl': KIND must be one of"),
    ('[controllers.c]\ntype = "pid"\noutput = "valve"\nsensor = "stroke:cyl"\nsetpoint = 0.2\nkp = 1e13\n',
     r"\[controllers.c\]: field 'kp': 10000000000000.0 is not a number in \[-1000000000000.0, 1000000000000.0\]"),
    ('[controllers.c]\ntype = "pid"\noutput = "valve"\nsensor = "stroke:cyl"\nsetpoint = 0.2\nrate = 0\n',
     r"field 'rate': 0.0 is not a number in \[1e-06, 1000000000.0\]"),
    ('[controllers.c]\ntype = "pid"\noutput = "valve"\nsensor = "stroke:cyl"\nsetpoint = 0.2\nlow = 0.5\nhigh = 0.5\n',
     r"fields 'low', 'high': 0.5 must be below 0.5"),
    ('[controllers.c]\ntype = "pid"\noutput = "valve"\nsensor = "stroke:cyl"\nsetpoint = 0.2\nanti_windup = "x"\n',
     r"field 'anti_windup': 'x' is not one of \['none', 'clamp', 'back_calculation'\]"),
    ('[inputs]\nvalve = 0.0\n[controllers.c]\ntype = "pid"\noutput = "valve"\nsensor = "stroke:cyl"\nsetpoint = 0.2\n',
     r"input 'valve' is driven by this controller and also has a schedule"),
])
def test_scenario_errors_name_file_and_field(tmp_path, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(ScenarioError, match=message) as info:
        load_scenario(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("text, message", [
    ('[controllers.c]\ntype = "pid"\noutput = "pump"\nsensor = "stroke:cyl"\nsetpoint = 0.2\n',
     r"field 'output': no valve or pump called 'pump'"),
    ('[controllers.c]\ntype = "pid"\noutput = "valve"\nsensor = "pressure:nowhere"\nsetpoint = 0.2\n',
     r"field 'sensor': no net 'nowhere' in the circuit"),
    ('[controllers.c]\ntype = "pid"\noutput = "valve"\nsensor = "stroke:cyl"\nsetpoint = 0.2\nhigh = 2.0\n',
     r"fields 'low', 'high': \[-1, 2\] must lie within the range \[-1, 1\] of input 'valve'"),
])
def test_scene_errors_name_the_controller(tmp_path, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(ScenarioError, match=message):
        make_plant(load_scene(load_scenario(path)))


def _trace(plant, scenario, block=1):
    x, u = [], []
    while plant.step_index < scenario.step_count:
        assert plant.advance(block).success
        x.append(plant.net_state.actuator_position[0])
        u.append(plant.control.valve_command[0])
    return np.arange(1, len(x) + 1) * scenario.dt * block, np.array(x), np.array(u)


def _scenario(mode, **changes):
    scenario = load_scenario(SERVO).with_overrides(mode=mode)
    if changes:
        spec = dataclasses.replace(scenario.controllers["stroke"], **changes)
        scenario = dataclasses.replace(scenario, controllers={"stroke": spec})
    return scenario


def _peak(t, x):
    i = int(np.argmax(x))
    return (x[i] - X0 - STEP) / STEP, t[i] - STEP_TIME


@pytest.fixture(scope="module", params=["mujoco", "pbd"])
def mode(request):
    return request.param


def test_servo_p_matches_second_order(mode):
    """P on the stroke: overshoot and peak time of ζ, ω_n from the parameters within 1 %."""
    scenario = _scenario(mode)
    kp = scenario.controllers["stroke"].kp
    t, x, _ = _trace(make_plant(load_scene(scenario)), scenario, block=2)
    zeta = 1.0 / (2.0 * math.sqrt(TAU * GAIN * kp))
    wn = math.sqrt(GAIN * kp / TAU)
    overshoot, peak_time = _peak(t, x)
    assert overshoot == pytest.approx(math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2)), rel=0.01)
    assert peak_time == pytest.approx(math.pi / (wn * math.sqrt(1 - zeta**2)), rel=0.01)
    assert x[-1] == pytest.approx(X0 + STEP, abs=2e-3 * STEP)  # an integrating plant: no steady-state error


def test_servo_pi_matches_third_order(mode):
    """PI on the stroke: the closed loop τs³ + s² + K·kp·s + K·ki, stepped exactly; overshoot and peak time within 1 %."""
    scenario = load_scenario(SCENES / "servo_pi.scenario.toml").with_overrides(mode=mode)
    kp, ki = scenario.controllers["stroke"].kp, scenario.controllers["stroke"].ki
    t, x, _ = _trace(make_plant(load_scene(scenario)), scenario, block=2)
    # states (x, s, ∫e): x' = K·s, s' = (kp·(r − x) + ki·∫e − s)/τ, ∫e' = r − x
    a = np.array([[0.0, GAIN, 0.0], [-kp / TAU, -1.0 / TAU, ki / TAU], [-1.0, 0.0, 0.0]])
    b = np.array([0.0, kp / TAU, 1.0])
    times = np.arange(1, 20001) * 5e-5
    big = expm(np.block([[a, b[:, None]], [np.zeros((1, 4))]]) * 5e-5)
    z, exact = np.zeros(3), []
    for _ in times:
        z = big[:3, :3] @ z + big[:3, 3] * STEP
        exact.append(z[0])
    exact = np.array(exact)
    i = int(np.argmax(exact))
    overshoot, peak_time = _peak(t, x)
    assert overshoot == pytest.approx((exact[i] - STEP) / STEP, rel=0.01)
    assert peak_time == pytest.approx(times[i], rel=0.01)


def test_limits_windup_and_rate():
    """A 50 mm step saturates the valve: the output stays within [low, high]; clamping overshoots less than no
    anti-windup; at 100 Hz the output changes only every 10th step."""
    big = dict(kp=20.0, ki=400.0, setpoint=dataclasses.replace(_scenario("mujoco").controllers["stroke"].setpoint,
                                                               value=np.array([0.2, 0.2, 0.25])))
    runs = {}
    for windup in ("none", "clamp", "back_calculation"):
        scenario = _scenario("mujoco", anti_windup=windup, low=-0.6, high=0.6, **big)
        runs[windup] = _trace(make_plant(load_scene(scenario)), scenario)
    for t, x, u in runs.values():
        assert u.max() == pytest.approx(0.6) and u.min() >= -0.6
    over = {k: v[1].max() - 0.25 for k, v in runs.items()}
    assert over["clamp"] < 0.5 * over["none"] and over["back_calculation"] < 0.5 * over["none"]
    scenario = _scenario("mujoco", rate=100.0)
    _, _, u = _trace(make_plant(load_scene(scenario)), scenario)
    changes = np.flatnonzero(np.diff(u)) + 1  # step indices (u[i] is step i's command) where the output changed
    assert len(changes) > 10 and np.all(changes % 10 == 0)


def test_python_callable_equals_compiled_pid():
    """controller(t, sensors) with the textbook P law, every step, gives the compiled PID's run to round-off."""
    scenario = _scenario("mujoco")
    kp = scenario.controllers["stroke"].kp
    setpoint = scenario.controllers["stroke"].setpoint
    compiled = _trace(make_plant(load_scene(scenario)), scenario, block=50)
    free = dataclasses.replace(scenario, controllers={})
    plant = make_plant(load_scene(free))

    def law(t, sensors):
        return {"valve": min(1.0, max(-1.0, kp * (setpoint(t) - sensors["stroke:cyl"])))}

    plant.python_controller = PythonController(plant, law, sensors=["stroke:cyl"])
    python = _trace(plant, free, block=50)
    np.testing.assert_allclose(python[1], compiled[1], rtol=0, atol=1e-12)


def test_snapshot_resume_is_bit_identical(mode):
    scenario = _scenario(mode, ki=200.0, rate=500.0).with_overrides(duration=0.2)
    plant = make_plant(load_scene(scenario))
    plant.advance(123)
    state = snapshot.decode(snapshot.encode(snapshot.capture(plant)))
    plant.advance(177)
    other = make_plant(load_scene(scenario))
    snapshot.restore(other, state)
    other.advance(177)
    assert np.array_equal(other.controller_state, plant.controller_state)
    assert np.array_equal(other.net_state.actuator_position, plant.net_state.actuator_position)
    assert np.array_equal(other.net_state.node_pressure, plant.net_state.node_pressure)


def test_controller_channel_logged(tmp_path, mode):
    result = run(SERVO, out=tmp_path / "servo.mcap", overrides={"mode": mode, "duration": 0.3}, progress=False)
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    ctl, valve = log.topic("/hydroplant/controllers/stroke"), log.topic("/hydroplant/valves/valve")
    np.testing.assert_array_equal(ctl["output"], valve["command"])
    cyl = log.topic("/hydroplant/cylinders/cyl")
    after = ctl.t > STEP_TIME + 0.01
    assert np.all(ctl["setpoint"][after] == 0.21)
    # the logged error is the setpoint less the stroke at the start of the logged step's successor
    np.testing.assert_allclose(ctl["error"], ctl["setpoint"] - ctl["measurement"], rtol=0, atol=1e-15)
    assert np.max(np.abs(cyl["position_m"][after] - ctl["measurement"][after])) < 2e-4


def proportional(t, sensors):
    """The servo scenario's P law (kp = 57.7 /m, the setpoint stepping to 0.21 m at 0.05 s), for a scenario's
    ``python = "test_controllers:proportional"``."""
    setpoint = 0.21 if t >= 0.05 - 1e-12 else 0.2
    return {"valve": min(1.0, max(-1.0, 57.7 * (setpoint - sensors["stroke:cyl"])))}


def test_python_controller_from_a_scenario(tmp_path, mode):
    """``type = "python"`` in a scenario file: run by the runner (logged in blocks of one period), the same strokes
    as the compiled PID to round-off."""
    path = _write(tmp_path, '[controllers.mine]\ntype = "python"\npython = "test_controllers:proportional"\n'
                            'sensors = ["stroke:cyl"]\noutputs = ["valve"]\n[log]\nrate_hz = 2000\n')
    logs = {}
    for label, scenario in (("python", path), ("pid", SERVO)):
        result = run(scenario, out=tmp_path / f"{label}.mcap", overrides={"mode": mode, "duration": 0.3},
                     progress=False)
        assert result.status == "complete", result.message
        logs[label] = read_log(result.log_path).topic("/hydroplant/cylinders/cyl")
    np.testing.assert_array_equal(logs["python"].t, logs["pid"].t)
    np.testing.assert_allclose(logs["python"]["position_m"], logs["pid"]["position_m"], rtol=0, atol=1e-12)


def test_joint_sensor_servoes_like_the_stroke(mode):
    """The carriage's slide joint is the cylinder's stroke (joint transmission): servoing ``joint:x`` (MuJoCo's qpos,
    PBD's generalized coordinates) reaches the same peak as servoing ``stroke:cyl`` within 0.1 % of the step."""
    peaks = {}
    for sensor in (("stroke", "cyl"), ("joint", "x")):
        scenario = _scenario(mode, sensor=sensor).with_overrides(duration=0.4)
        t, x, _ = _trace(make_plant(load_scene(scenario)), scenario, block=4)
        peaks[sensor[0]] = _peak(t, x)
    assert peaks["joint"][0] == pytest.approx(peaks["stroke"][0], abs=1e-3)
    assert peaks["joint"][1] == pytest.approx(peaks["stroke"][1], abs=2e-3)
