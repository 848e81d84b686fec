"""Cost of one hydraulic network step (µs) on the excavator circuit (3 cylinders + swing motor), per stepper.

No MuJoCo: the actuators follow a prescribed smooth motion while the valves
move, so every stepper does the work of a dig cycle.

    python bench/bench_network.py [--steps N]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from hydraulics.circuit import load_circuit
from hydraulics.network import NetworkModel
from hydraulics.steppers import STEPPERS, ActuatorMotion

CIRCUIT = Path(__file__).resolve().parents[1] / "models/excavator/excavator.circuit.toml"
DT = 1e-3  # s


def run(stepper, model, steps):
    x0 = np.where(model.actuator_kind == 0, 0.5, 0.0)
    state = model.state(actuator_position=x0, node_pressure=np.full(model.node_count, 5e6))
    control = model.control()
    newton = 0
    start = time.perf_counter()
    for n in range(steps):
        t = n * DT
        control.valve_command[:] = 0.8 * np.sin(2 * np.pi * 0.5 * t + np.arange(len(model.valve_names)))
        v = 0.05 * np.cos(2 * np.pi * 0.5 * t + np.arange(model.actuator_count))
        state, report = stepper.step(state, control, ActuatorMotion.linear(state.actuator_position, v, DT), DT)
        newton += report.newton_iterations
    return (time.perf_counter() - start) / steps * 1e6, newton / steps


def _warm_up(model):
    state = model.state()
    return state, model.control(), ActuatorMotion.held(state.actuator_position), DT


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=500)
    args = parser.parse_args(argv)
    model = NetworkModel.from_circuit(load_circuit(CIRCUIT))
    print(f"excavator circuit: {model.node_count} nodes ({len(model.free_nodes)} with pressure states), "
          f"{len(model.branch_names)} branches, {model.actuator_count} actuators, dt = {DT} s")
    print(f"{'stepper':<26} {'us/step':>10} {'Newton it/step':>15}")
    STEPPERS["implicit_euler"](model).step(*_warm_up(model))  # load or compile the kernels outside the timing
    for name, cls in STEPPERS.items():
        steps = args.steps if name != "reference" else max(10, args.steps // 20)
        us, iterations = run(cls(model), model, steps)
        print(f"{name:<26} {us:10.1f} {iterations:15.2f}")


if __name__ == "__main__":
    main()
