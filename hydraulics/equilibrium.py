"""Initial states in static equilibrium with the load.

A machine released with arbitrary chamber pressures sags or jumps until the
oil columns take the load.  :func:`equilibrium_state` instead sets, for each
cylinder carrying an effort F at rest, the low-side chamber at a base
pressure and the other chamber at the pressure that balances F exactly

    p_cap·A_cap − p_rod·A_rod − p_amb·(A_cap − A_rod) = F,

(motors likewise with τ = D·(p_a − p_b)/(2π)), and brings every other node to
its steady state with the chambers held (backward-Euler pseudo-time steps).

The efforts F come from the static balance of the mechanism with its
constraints (:func:`holding_efforts`): with the actuator moments J (v = J·q̇),
the constraint Jacobian G of the loop closures (and the joint limits that
carry load) and the generalized load Q = gravity/bias − passive forces at rest,

    Jᵀ·F + Gᵀ·λ = Q,

solved for (F, λ) by least squares; the relative residual
‖Jᵀ·F + Gᵀ·λ − Q‖/‖Q‖ says whether the actuators and constraints can hold
the pose at all.  Without the Gᵀ·λ term a closed loop (a cylinder on its own
barrel and rod bodies, an H-link) carries no load through its pins and F is
wrong.  :func:`constrained_inverse_inertia` is the matching dynamic quantity:
the inertia each actuator sees through the constrained system,

    1/m_eff = j·N·(Nᵀ·M·N)⁻¹·Nᵀ·jᵀ,   N = null space of G,

(Featherstone, *Rigid Body Dynamics Algorithms*, 2008, §8.1: motion restricted
to the constraint manifold).  These two take arrays only (no MuJoCo), so both
plants call them with their own kinematics.
"""

from __future__ import annotations

import numpy as np

from .network import NetworkControl, NetworkModel, NetworkState
from .steppers import ActuatorMotion, StepperImplicitEuler

STEADY_STEP = 0.05  # s, pseudo-time step of the steady-state solve
STEADY_STEPS = 400  # at most; stops when pressures change < STEADY_TOLERANCE
STEADY_TOLERANCE = 1.0  # Pa per pseudo-step
NULL_SPACE_RTOL = 1e-9  # singular values below this × the largest count as zero (constraint rank)


def null_space(matrix, rtol: float = NULL_SPACE_RTOL) -> np.ndarray:
    """Orthonormal basis (n × k) of the null space of ``matrix`` (m × n), by SVD; identity for m = 0."""
    matrix = np.atleast_2d(np.asarray(matrix, float))
    n = matrix.shape[1]
    if matrix.shape[0] == 0 or not np.any(matrix):
        return np.eye(n)
    _, sigma, vt = np.linalg.svd(matrix)
    rank = int(np.sum(sigma > rtol * sigma[0]))
    return vt[rank:].T


def _constraint_rows(constraint_jacobian, nv: int) -> np.ndarray:
    """The constraint Jacobian as rows of ``nv`` entries (none: zero rows; a model without degrees of freedom
    included)."""
    if constraint_jacobian is None or nv == 0:
        return np.zeros((0, nv))
    return np.asarray(constraint_jacobian, float).reshape(-1, nv)


def holding_efforts(moment, load, constraint_jacobian=None):
    """Actuator efforts F and constraint forces λ that hold a pose at rest: Jᵀ·F + Gᵀ·λ = Q (least squares).

    Parameters
    ----------
    moment : ndarray (actuators, nv)
        Actuator moments J [m or rad per unit q̇], v_actuator = J·q̇.
    load : ndarray (nv,)
        Generalized load Q to hold [N or N·m]: gravity and bias minus passive forces at rest.
    constraint_jacobian : ndarray (rows, nv), optional
        G of the equality constraints (and load-carrying joint limits); None or no rows: no constraints.

    Returns
    -------
    (effort (actuators,) [N or N·m], constraint_force (rows,), relative_residual [-])
        ``relative_residual`` = ‖Jᵀ·F + Gᵀ·λ − Q‖/‖Q‖ (0 when Q = 0).

    Example
    -------
    >>> F, lam, r = holding_efforts(np.array([[0.5, 0.0]]), np.array([10.0, -10.0]), np.array([[1.0, 1.0]]))
    """
    moment = np.atleast_2d(np.asarray(moment, float))
    load = np.asarray(load, float)
    nv = load.shape[0]
    G = _constraint_rows(constraint_jacobian, nv)
    A = np.vstack([moment, G]).T
    if A.shape[1] == 0:
        return np.zeros(0), np.zeros(0), 0.0 if not np.any(load) else 1.0
    solution, *_ = np.linalg.lstsq(A, load, rcond=None)
    scale = float(np.linalg.norm(load))
    residual = float(np.linalg.norm(A @ solution - load)) / scale if scale > 0 else 0.0
    na = moment.shape[0]
    return solution[:na], solution[na:], residual


def constrained_inverse_inertia(mass, moment, constraint_jacobian=None):
    """Response of each actuator through the constrained system: (1/m_eff [1/kg or 1/(kg·m²)], velocity field).

    1/m_eff,i = jᵢ·N·(Nᵀ·M·N)⁻¹·Nᵀ·jᵢᵀ with N the null space of the constraint
    Jacobian G (all of q̇ without constraints, then N = I and this is jᵢ·M⁻¹·jᵢᵀ).
    ``velocity`` (nv, actuators) is N·(Nᵀ·M·N)⁻¹·Nᵀ·jᵢᵀ, the generalized velocity a unit
    actuator impulse produces (for the damping the actuator sees).

    Example
    -------
    >>> inv, vel = constrained_inverse_inertia(np.diag([2.0, 3.0]), np.array([[1.0, 0.0]]), np.array([[1.0, -1.0]]))
    >>> float(1.0 / inv[0])  # both DOFs move together: 2 + 3 kg
    5.0
    """
    mass = np.asarray(mass, float)
    moment = np.atleast_2d(np.asarray(moment, float))
    nv = mass.shape[0]
    N = null_space(_constraint_rows(constraint_jacobian, nv))
    if N.shape[1] == 0:
        return np.zeros(moment.shape[0]), np.zeros((nv, moment.shape[0]))
    reduced = N.T @ mass @ N
    velocity = N @ np.linalg.solve(reduced, N.T @ moment.T)
    return np.einsum("ij,ji->i", moment, velocity), velocity


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
    state.valve_spool = state.valve_spool.copy()  # the valves' spools at their commands, other states kept
    state.valve_spool[:len(model.valve_names)] = model.valve_commands(control.valve_command)

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
