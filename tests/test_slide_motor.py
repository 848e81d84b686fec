"""A hydraulic motor on a slide joint (tests/scenes/winch.xml: a 200 kg carriage on a 20° incline hauled through a
drum, gear 100 rad of motor per metre), in both modes.

* Held in equilibrium with the valve closed: the carriage does not move (< 1 µm in 0.05 s), the motor's pressure
  difference is m·g·sin 20°·2π/(D·gear).
* Hauling with the valve open: the pump's flow Q drives the motor, so the carriage moves at no more than
  Q·2π/(D·gear) = 1.257 m/s on average (least-squares slope over 0.3–1.2 s, through the ringing of the oil column
  against the carriage) and not much less: the relief passes a little at the ringing's pressure peaks (measured
  1.231 m/s, 2 % under).
* PBD mode's slide motor (its rate from the bodies' velocities, its effort as a force on the two groups or through
  the articulated response) follows MuJoCo mode's trajectory within 1 mm over the 1.2 s.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hydraulics.circuit import load_circuit
from sim.io.mcap_log import read_log
from sim.run.runner import run

SCENES = Path(__file__).parent / "scenes"
WINCH = SCENES / "winch.scenario.toml"
MASS, SLOPE, GEAR = 200.0, math.radians(20.0), 100.0  # the carriage [kg], the incline, rad of motor per metre


def _haul(tmp_path, mode):
    result = run(WINCH, out=tmp_path / f"{mode}.mcap", overrides={"mode": mode, "duration": 1.2}, progress=False)
    assert result.status == "complete", result.message
    states = read_log(result.log_path).topic("/hydroplant/joint_states")
    return result, states.t, states["position/haul"]


@pytest.fixture(scope="module")
def hauls(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("winch")
    return {mode: _haul(tmp, mode) for mode in ("mujoco", "pbd")}


@pytest.mark.parametrize("mode", ["mujoco", "pbd"])
def test_the_winch_holds_then_hauls_at_the_pump_flow(hauls, mode):
    circuit = load_circuit(SCENES / "winch.circuit.toml")
    pump, motor = circuit.component("pump").params, circuit.component("winch_motor").params
    result, t, x = hauls[mode]
    assert np.max(np.abs(x[t <= 0.05])) < 1e-6  # the valve opens at 0.05 s
    nodes = read_log(result.log_path).topic("/hydroplant/nodes")
    holding = MASS * 9.81 * math.sin(SLOPE) / GEAR * 2.0 * math.pi / motor.displacement  # Δp [Pa]
    dp = nodes["pressure_pa.winch_a"][0] - nodes["pressure_pa.winch_b"][0]
    assert dp == pytest.approx(holding, rel=1e-3)
    speed = pump.displacement * pump.speed * 2.0 * math.pi / (motor.displacement * GEAR)  # m/s
    window = (t >= 0.3) & (t <= 1.2)
    slope = np.polyfit(t[window], x[window], 1)[0]
    assert 0.95 * speed < slope < 1.005 * speed, (slope, speed)


def test_pbd_slide_motor_follows_mujoco_mode(hauls):
    _, t, x = hauls["mujoco"]
    _, tp, xp = hauls["pbd"]
    assert np.max(np.abs(np.interp(t, tp, xp) - x)) < 1e-3
