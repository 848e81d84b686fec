"""Second-order spool of the 4/3 valve (``dynamics = "second_order"``): its step response is the analytic one.

* The network stepped alone (a valve between a supply and two closed volumes, no actuator): after a command step
  u the spool follows s(t) = u·(1 − e^(−ζωt)·(cos ω_d t + ζω/ω_d·sin ω_d t)), ω_d = ω√(1 − ζ²), to 1e-12 at every
  step whatever the step length (the exact transition), with the overshoot e^(−ζπ/√(1−ζ²)); the first-order spool
  is unchanged (s = u·(1 − e^(−t/τ))).
* A spool driven beyond ±1 stops there at rest.
* From a scenario file, both modes: the logged spool (``/hydroplant/valves/<name>``) and its rate
  (``/hydroplant/component_states``) equal the analytic response.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from hydraulics.circuit import parse_circuit
from hydraulics.network import NetworkModel
from hydraulics.steppers import ActuatorMotion, StepperImplicitEuler
from sim.io.mcap_log import read_log
from sim.run.runner import run
from reference.circuits import bench

SCENES = Path(__file__).parent / "scenes"
OMEGA, ZETA = 2 * math.pi * 40.0, 0.4

CIRCUIT = """
[[component]]
name = "servo"
type = "valve_4_3"
max_area = 1.0e-6
dynamics = "{dynamics}"
natural_frequency = {omega}
damping_ratio = {zeta}
time_constant = 0.01
ports = {{ P = "supply", T = "tank", A = "a", B = "b" }}

[[component]]
name = "volume_a"
type = "volume"
volume = 1.0e-4
ports = {{ port = "a" }}

[[component]]
name = "volume_b"
type = "volume"
volume = 1.0e-4
ports = {{ port = "b" }}
"""


def circuit_text(dynamics="second_order"):
    return bench(5.0e6) + CIRCUIT.format(dynamics=dynamics, omega=OMEGA, zeta=ZETA)


def analytic(t, u):
    """Spool and rate of s̈ + 2ζω·ṡ + ω²·s = ω²·u from rest."""
    wd = OMEGA * math.sqrt(1 - ZETA**2)
    decay = np.exp(-ZETA * OMEGA * t)
    s = u * (1 - decay * (np.cos(wd * t) + ZETA * OMEGA / wd * np.sin(wd * t)))
    rate = u * decay * OMEGA**2 / wd * np.sin(wd * t)
    return s, rate


def step_response(text, command, h, steps):
    model = NetworkModel.from_circuit(parse_circuit(tomllib.loads(text)))
    stepper = StepperImplicitEuler(model)
    state = model.state()
    held = ActuatorMotion.held(state.actuator_position)
    control = model.control(servo=command)
    out = []
    for _ in range(steps):
        state, report = stepper.step(state, control, held, h)
        out.append(state.valve_spool.copy())
    return model, np.array(out)


@pytest.mark.parametrize("h", [1e-4, 2e-3])
def test_second_order_spool_follows_the_analytic_step_response(h):
    model, states = step_response(circuit_text(), 0.5, h, round(0.1 / h))
    assert model.component_state_names == ("servo", "servo.spool_rate")
    t = h * np.arange(1, len(states) + 1)
    s, rate = analytic(t, 0.5)
    assert np.allclose(states[:, 0], s, rtol=0, atol=1e-12)
    assert np.allclose(states[:, 1], rate, rtol=1e-9, atol=1e-9)
    if h == 1e-4:
        overshoot = states[:, 0].max() / 0.5 - 1
        assert overshoot == pytest.approx(math.exp(-ZETA * math.pi / math.sqrt(1 - ZETA**2)), rel=1e-3)


def test_first_order_spool_is_unchanged():
    model, states = step_response(circuit_text("first_order"), 0.5, 1e-3, 50)
    assert model.component_state_names == ("servo",)
    t = 1e-3 * np.arange(1, 51)
    assert np.allclose(states[:, 0], 0.5 * (1 - np.exp(-t / 0.01)), rtol=0, atol=1e-13)


def test_spool_stops_at_its_end():
    _, states = step_response(circuit_text(), 1.0, 1e-4, 300)
    assert states[:, 0].max() == 1.0 and states[:, 0].min() >= 0.0
    stopped = states[:, 0] == 1.0
    assert stopped.any() and np.all(states[stopped, 1] == 0.0)


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_scenario_logs_the_analytic_spool(mode, tmp_path):
    (tmp_path / "servo.circuit.toml").write_text(circuit_text(), encoding="utf-8")
    (tmp_path / "rig.xml").write_text((SCENES / "relief_rig.xml").read_text(encoding="utf-8"), encoding="utf-8")
    (tmp_path / "step.scenario.toml").write_text(
        '[scene]\nmjcf = "rig.xml"\ncircuit = "servo.circuit.toml"\n'
        '[run]\ndt = 0.001\nduration = 0.1\n'
        '[inputs]\nservo = { t = [0.0, 0.019999999, 0.02], value = [0.0, 0.0, 0.5] }\n'
        '[log]\nrate_hz = 1000\n', encoding="utf-8")
    result = run(tmp_path / "step.scenario.toml", out=tmp_path / "run.mcap", overrides={"mode": mode})
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    valve = log.topic("/hydroplant/valves/servo")
    states = log.topic("/hydroplant/component_states")
    late = valve.t >= 0.025
    # the command is sampled at each (sub)step's start: 0.5 from the step that starts at 0.02 s
    s, rate = analytic(valve.t[late] - 0.02, 0.5)
    assert np.allclose(valve["spool"][late], s, rtol=0, atol=1e-9)
    assert np.allclose(states["state.servo_spool_rate"][late], rate, rtol=1e-6, atol=1e-6)
