"""Initial states in static equilibrium with the load.

A machine released with arbitrary chamber pressures sags or jumps until the
oil columns take the load.  :func:`equilibrium_state` instead sets, for each
cylinder carrying an effort F at rest, the low-side chamber at a base
pressure and the other chamber at the pressure that balances F exactly

    p_cap·A_cap − p_rod·A_rod − p_amb·(A_cap − A_rod) = F,

(motors likewise with τ = D·(p_a − p_b)/(2π)), and brings every other node to
its steady state with the chambers held (backward-Euler pseudo-time steps).
"""

from __future__ import annotations

import numpy as np

from .network import NetworkControl, NetworkModel, NetworkState
from .steppers import ActuatorMotion, StepperImplicitEuler

STEADY_STEP = 0.05  # s, pseudo-time step of the steady-state solve
STEADY_STEPS = 400  # at most; stops when pressures change < STEADY_TOLERANCE
STEADY_TOLERANCE = 1.0  # Pa per pseudo-step


def balancing_pressures(model: NetworkModel, effort, base_pressure: float) -> dict:
    """Node index → absolute pressure [Pa] that makes each actuator carry ``effort`` at rest."""
    effort = np.asarray(effort, float)
    ambient = model.fluid.reference_pressure
    pinned = {}
    for i, a in enumerate(model.cylinder_actuator):
        f = effort[a]
        a_cap, a_rod = model.cylinder_cap_area[i], model.cylinder_rod_area[i]
        if f >= 0:
            p_rod = base_pressure
            p_cap = (f + p_rod * a_rod + ambient * (a_cap - a_rod)) / a_cap
        else:
            p_cap = base_pressure
            p_rod = (p_cap * a_cap - ambient * (a_cap - a_rod) - f) / a_rod
        pinned[int(model.cylinder_cap_node[i])] = p_cap
        pinned[int(model.cylinder_rod_node[i])] = p_rod
    for i, a in enumerate(model.motor_actuator):
        dp = 2.0 * np.pi * effort[a] / model.motor_displacement[i]
        high, low = (int(model.motor_a_node[i]), int(model.motor_b_node[i])) if dp >= 0 else (int(model.motor_b_node[i]), int(model.motor_a_node[i]))
        pinned[low] = base_pressure
        pinned[high] = base_pressure + abs(dp)
    return {k: v for k, v in pinned.items() if not model.node_fixed[k]}


def steady_state(model: NetworkModel, control: NetworkControl, state: NetworkState, pinned: dict) -> NetworkState:
    """Bring the free, unpinned nodes to steady state with actuators still and ``pinned`` nodes held [Pa]."""
    stepper = StepperImplicitEuler(model)
    position = state.actuator_position
    still = ActuatorMotion.held(position)
    nodes = np.array(sorted(pinned), int)
    values = np.array([pinned[k] for k in nodes])
    state = state.copy()
    state.valve_spool = np.clip(control.valve_command, -1.0, 1.0).astype(float)

    def pin(state):
        p = state.node_pressure.copy()
        p[nodes] = values
        oil = model.oil_from_pressure(p, position)
        state.node_oil[nodes] = oil[nodes]
        state.node_pressure = model.pressure(state.node_oil, position)[0]
        return state

    state = pin(state)
    for _ in range(STEADY_STEPS):
        new, report = stepper.step(state, control, still, STEADY_STEP)
        if not report.success:
            break
        new = pin(new)
        change = np.max(np.abs(new.node_pressure - state.node_pressure))
        state = new
        if change < STEADY_TOLERANCE:
            break
    state.time = 0.0
    state.node_oil_change = None  # an initial state: no last step (the pseudo-time steps and the pins are not one)
    return state


def equilibrium_state(
    model: NetworkModel,
    control: NetworkControl,
    position,
    effort,
    *,
    base_pressure: float,
    pressures: dict | None = None,
) -> NetworkState:
    """A state at rest at ``position`` whose actuators carry ``effort`` [N or N·m].

    ``pressures`` (net name → absolute pressure [Pa]) pins further nodes and
    overrides the balance where both name the same node.
    """
    pinned = balancing_pressures(model, effort, base_pressure)
    for net, value in (pressures or {}).items():
        pinned[model.node(net)] = value
    p = np.full(model.node_count, model.fluid.reference_pressure)
    for k, v in pinned.items():
        p[k] = v
    state = model.state(actuator_position=position, node_pressure=p)
    return steady_state(model, control, state, pinned)
