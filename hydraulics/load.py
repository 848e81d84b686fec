"""A 1-DOF mechanical load on one actuator, so a circuit can be stepped without MuJoCo.

The load is a mass on the rod of one cylinder (or the shaft of one motor)
with a constant external force, end stops at the stroke ends, and the other
actuators of the circuit held still.  :func:`simulate` couples it to the
network with any coupling scheme; :func:`simulate_reference` integrates the
whole system (mass, oil contents, spools) with ``solve_ivp`` as a monolithic
stiff ODE, for references.

Units: mass [kg], force [N], position [m], velocity [m/s], time [s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .coupling import make_coupling
from .extras import require
from .network import ACTUATOR_CYLINDER, NetworkModel, NetworkState
from .steppers import refuse_component_states

COUPLING_VELOCITY_TOLERANCE = 1e-6  # relative change of the end velocity that ends coupling iterations


@dataclass(frozen=True, kw_only=True)
class MassLoad:
    """A point mass driven by one actuator."""

    actuator: str
    """Name of the cylinder (or motor) that drives the mass."""
    mass: float
    """Mass [kg] (or inertia [kg·m²] on a motor shaft)."""
    force: float = 0.0
    """Constant external force along the rod [N], positive extending (e.g. −m·g for a lifted load)."""

    def __post_init__(self):
        if not (math.isfinite(self.mass) and self.mass > 0):
            raise ValueError(f"`mass` must be positive and finite, got {self.mass!r} kg")
        if not math.isfinite(self.force):
            raise ValueError(f"`force` must be finite, got {self.force!r} N")


@dataclass
class Trajectory:
    """Sampled run of a 1-DOF load (arrays over samples)."""

    time: np.ndarray  # (n,) [s]
    position: np.ndarray  # (n,) [m]
    velocity: np.ndarray  # (n,) [m/s]
    node_pressure: np.ndarray  # (n, node_count) [Pa]
    effort: np.ndarray  # (n,) [N]
    node_oil: np.ndarray  # (n, node_count) [m³]
    status: str = "complete"
    message: str = ""
    newton_iterations: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

    def pressure(self, model: NetworkModel, net: str) -> np.ndarray:
        """Pressure history [Pa] of the node holding ``net``."""
        return self.node_pressure[:, model.node(net)]


def _schedule_value(schedule, t):
    return schedule(t) if callable(schedule) else schedule


def apply_inputs(model: NetworkModel, control, inputs: dict, t: float):
    """Set named controls from ``inputs`` (values or callables of time) at time ``t`` [s]."""
    for name, schedule in inputs.items():
        model.set_control(control, name, _schedule_value(schedule, t))


def simulate(
    model: NetworkModel,
    load: MassLoad,
    state: NetworkState,
    *,
    dt: float,
    duration: float,
    coupling: str = "implicit",
    stepper: str | None = None,
    substeps: int = 1,
    inputs: dict | None = None,
    position=None,
    velocity: float = 0.0,
    coupling_iterations: int = 1,
) -> Trajectory:
    """Step the load and the network together at a fixed ``dt`` [s] for ``duration`` [s].

    ``inputs`` maps valve/pump names to values or functions of time.  The
    mechanics is backward Euler in the effort law the coupling returns, with
    inelastic end stops at 0 and the stroke.  With ``coupling_iterations`` > 1
    the implicit coupling is re-linearised at the velocity just found until it
    stops changing: Newton's method on the coupled backward-Euler step, for
    steps far beyond the oil column's time scale.  A failed or non-finite step
    ends the run early with ``status = "diverged"``.
    """
    inputs = inputs or {}
    refuse_component_states(model, "simulate_reference")
    a = model.actuator(load.actuator)
    is_cylinder = model.actuator_kind[a] == ACTUATOR_CYLINDER
    stroke = model.cylinder_stroke[list(model.cylinder_actuator).index(a)] if is_cylinder else math.inf
    coupler = make_coupling(coupling, model, stepper=stepper, substeps=substeps)
    control = model.control()
    x = state.actuator_position.copy()
    if position is not None:
        x[a] = position
    v = np.zeros(model.actuator_count)
    v[a] = velocity
    steps = int(round(duration / dt))
    out = {k: [] for k in ("t", "x", "v", "p", "f", "m", "it")}

    def record(t, state, effort, iterations):
        out["t"].append(t)
        out["x"].append(x[a])
        out["v"].append(v[a])
        out["p"].append(state.node_pressure.copy())
        out["f"].append(effort)
        out["m"].append(state.node_oil.copy())
        out["it"].append(iterations)

    effort0, _ = model.actuator_effort(state.node_pressure, v, x)
    record(0.0, state, effort0[a], 0)
    status, message = "complete", ""
    for n in range(steps):
        t = n * dt
        apply_inputs(model, control, inputs, t)
        effective_mass = np.full(model.actuator_count, load.mass)
        x_start, v_start = x.copy(), v.copy()
        guess = None
        for _ in range(coupling_iterations):
            law = coupler.begin(state, control, x_start, v_start, dt, effective_mass=effective_mass, velocity_guess=guess)
            # backward Euler of m·v̇ = constant + slope·v⁺ + F_ext, with inelastic end stops
            v_new = (load.mass * v_start[a] + dt * (law.constant[a] + load.force)) / (load.mass - dt * law.slope[a])
            x_new = x_start[a] + dt * v_new
            if x_new > stroke or x_new < 0.0:
                x_new = min(max(x_new, 0.0), stroke)
                v_new = 0.0
            previous = 0.0 if guess is None else guess[a]
            guess = np.zeros(model.actuator_count)
            guess[a] = (x_new - x_start[a]) / dt
            if abs(guess[a] - previous) <= COUPLING_VELOCITY_TOLERANCE * (1.0 + abs(guess[a])):
                break
        x[a], v[a] = x_new, v_new
        state, report = coupler.finish(state, control, x_start, x, v_start, v, dt)
        effort = law(v)[a]
        if not report.success or not np.isfinite(x_new) or not np.all(np.isfinite(state.node_pressure)):
            status, message = "diverged", f"t = {t + dt:.6g} s: {report.message or 'non-finite state'}"
            break
        record((n + 1) * dt, state, effort, report.newton_iterations)
    return Trajectory(
        np.array(out["t"]), np.array(out["x"]), np.array(out["v"]), np.array(out["p"]), np.array(out["f"]),
        np.array(out["m"]), status, message, np.array(out["it"]),
    )


def simulate_reference(
    model: NetworkModel,
    load: MassLoad,
    state: NetworkState,
    *,
    duration: float,
    sample_times=None,
    inputs: dict | None = None,
    position=None,
    velocity: float = 0.0,
    rtol: float = 1e-10,
    method: str = "Radau",
) -> Trajectory:
    """Monolithic stiff ODE solution of load + network with ``solve_ivp``.

    States: rod position and velocity, free-node oil contents and spools
    (τ·ṡ = u − s; τ = 0 spools follow their command).  End stops are not
    modelled: keep the reference inside the stroke.
    """
    inputs = inputs or {}
    refuse_component_states(model, "simulate_reference")
    a = model.actuator(load.actuator)
    free = model.free_nodes
    nf = len(free)
    nv = len(model.valve_names)
    x_all = state.actuator_position.copy()
    if position is not None:
        x_all[a] = position
    tau = model.valve_time_constant
    control = model.control()
    oil = state.node_oil.copy()

    def unpack(t, y):
        x_all[a] = y[0]
        vel = np.zeros(model.actuator_count)
        vel[a] = y[1]
        oil[free] = y[2 : 2 + nf]
        apply_inputs(model, control, inputs, t)
        command = model.valve_commands(control.valve_command)
        spool = np.where(tau > 0, y[2 + nf :], command)
        return vel, spool, command

    def rhs(t, y):
        vel, spool, command = unpack(t, y)
        pressure, _ = model.pressure(oil, x_all)
        flows = model.branch_flows(pressure, model.valve_areas(spool), control.pump_speed, vel)
        effort, _ = model.actuator_effort(pressure, vel, x_all)
        dy = np.empty_like(y)
        dy[0] = y[1]
        dy[1] = (effort[a] + load.force) / load.mass
        dy[2 : 2 + nf] = (model.incidence @ flows.flow)[free]
        dy[2 + nf :] = np.where(tau > 0, (command - spool) / np.where(tau > 0, tau, 1.0), 0.0)
        return dy

    y0 = np.concatenate([[x_all[a], velocity], state.node_oil[free], state.valve_spool])
    volume, _ = model.node_volume_at(x_all, state.node_pressure)
    beta = model.effective_bulk_modulus(state.node_pressure, x_all)
    atol = np.concatenate([[1e-12, 1e-12], (1e-3 * volume / beta)[free], np.full(nv, 1e-12)])
    # (here: scipy.integrate costs ~0.35 s of every start-up, and scipy comes with the [tools] extra)
    solve_ivp = require("scipy.integrate", "tools", "simulate_reference").solve_ivp

    sol = solve_ivp(rhs, (0.0, duration), y0, method=method, rtol=rtol, atol=atol, t_eval=sample_times, dense_output=False)
    pressures, efforts, oils = [], [], []
    for t, y in zip(sol.t, sol.y.T):
        vel, _, _ = unpack(t, y)
        pressure, _ = model.pressure(oil, x_all)
        pressures.append(pressure)
        efforts.append(model.actuator_effort(pressure, vel, x_all)[0][a])
        oils.append(oil.copy())
    return Trajectory(
        sol.t, sol.y[0], sol.y[1], np.array(pressures), np.array(efforts), np.array(oils),
        "complete" if sol.success else "failed", sol.message,
    )
