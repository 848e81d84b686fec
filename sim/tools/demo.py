"""Hydraulics-only demo: the seed report's Figure 2 circuit lifting a 1-DOF mass, no MuJoCo.

Run with ``hydroplant demo``.  A 12 L/min pump feeds a closed-centre 4/3 valve
and a 50/28 mm cylinder lifting 200 kg; the valve opens at 0.5 s, the rod
reaches its end stop and the relief valve takes the pump flow.
"""

from __future__ import annotations

import math

import numpy as np

from hydraulics.circuit import load_circuit
from hydraulics.equilibrium import equilibrium_state
from hydraulics.load import MassLoad, simulate
from hydraulics.network import NetworkModel

from sim.io.examples import example_file

CIRCUIT = example_file("lift_1dof/lift.circuit.toml")
MASS = 200.0  # kg
GRAVITY = 9.81  # m/s²
BASE_PRESSURE = 1e6  # Pa absolute, rod side at rest


def main() -> int:
    model = NetworkModel.from_circuit(load_circuit(CIRCUIT))
    load = MassLoad(actuator="lift", mass=MASS, force=-MASS * GRAVITY)
    control = model.control()
    state = equilibrium_state(model, control, [0.3], [MASS * GRAVITY], base_pressure=BASE_PRESSURE)
    trajectory = simulate(model, load, state, dt=1e-3, duration=4.0, inputs={"valve": lambda t: 1.0 if t >= 0.5 else 0.0})
    area = math.pi * 0.05**2 / 4
    print(f"hydraulics-only demo: {CIRCUIT.name}, {MASS:g} kg on the rod, valve opens at 0.5 s  ({trajectory.status})")
    print(f"{'t [s]':>6} {'x [m]':>8} {'v [m/s]':>8} " + " ".join(f"{'p_' + n + ' [bar]':>16}" for n in model.node_names))
    for t in (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0):
        i = int(round(t / 1e-3))
        print(f"{t:6.2f} {trajectory.position[i]:8.4f} {trajectory.velocity[i]:8.4f} "
              + " ".join(f"{p / 1e5:16.2f}" for p in trajectory.node_pressure[i]))
    moving = trajectory.velocity[(trajectory.time > 1.0) & (trajectory.time < 1.5)]
    print(f"rod speed while lifting {moving.mean():.4f} m/s; pump flow / piston area = {2e-4 / area:.4f} m/s")
    return 0 if trajectory.status == "complete" else 3
