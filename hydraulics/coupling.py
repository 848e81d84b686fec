"""Coupling schemes between the hydraulic network and a mechanical plant.

A mechanical plant (1-DOF load, MuJoCo, XPBD) asks the coupling, before its
own step, for the actuator efforts as an affine function of the end-of-step
actuator velocities,

    effort(v⁺) = constant + slope · v⁺          (per actuator, diagonal slope),

steps its bodies with that law, and then hands back the realised motion so the
coupling can finish the hydraulic step.  Two schemes:

``explicit``
    Weak co-simulation (the seed report's scheme): the efforts come from the
    pressures at the start of the step (slope 0), and the network then
    advances with the velocities of the start of the step, integrating its own
    chamber volumes from them (zero-order hold).  Unconditionally unstable for
    an undamped oil column; kept as the baseline.
``implicit``
    Linearly implicit coupling: the network is solved by backward Euler for a
    predicted velocity and differentiated, so the backward-Euler law carries
    the oil-column stiffness −h·β·A²/V, the valve flow–pressure terms and the
    friction slope.  A plant that integrates ``slope·v⁺`` implicitly (MuJoCo's
    ``implicitfast`` with an affine actuator bias, or the 1-DOF load's closed
    form) then steps the coupled system stably.  The network is finished with
    the realised end positions and velocities (backward Euler on the oil).

    The pressure part of the law is blended between the start-of-step force
    F₀ (θ = 0: symplectic Euler, no numerical damping) and the backward-Euler
    law (θ = 1) by the θ-rule of :func:`blend_factor`, per actuator, from
    w = (ω·h)² = −slope·h/m_eff.  For the semi-implicit Euler of the plant, a
    spring taken with weight θ is stable iff w·(1 − 2θ) ≤ 4; θ = clip(1 − 2/w,
    0, 1) meets this with margin, leaves resolved oil columns (ω·h < √2)
    undamped, and tends to backward Euler (L-stable) for unresolved ones.
    Friction is always taken with θ = 1: its regularised Coulomb slope would
    make any explicit treatment chatter.  Without effective masses θ = 1.

    Newton's method of the finish starts from the linearised prediction
    m⁺ ≈ m_lin + (∂m/∂v)·(v⁺ − v_guess) (see ``implicit-linear``); this
    changes only the iterations (same equations and tolerance), typically
    saving one of about two and a half.  Plants pass the start-of-step
    velocity as ``velocity_guess`` (MuJoCo plant; the 1-DOF load passes its
    own prediction), which makes the linearisation's own Newton solve start
    near its root too.
``implicit-linear``
    Linearly implicit Euler (Rosenbrock–Euler / one Newton step) for the
    oil: the effort law is the one of ``implicit``, but the network is
    finished without a second nonlinear solve, from the backward-Euler
    prediction m_lin = m + h·ΣQ(p(m_lin, x + h·v_g), v_g) at the velocity
    guess v_g and its sensitivity ∂m/∂v (both from
    :meth:`StepperImplicitEuler.linearize`):

        m⁺ = m_lin + (∂m/∂v)·(v⁺ − v_g),    p⁺ = p(m⁺, x⁺),    x⁺ = x + h·v⁺.

    Order 1 like ``implicit`` (it is backward Euler with the flows linearised
    in v about v_g; the error of the linearisation is O(h·|v⁺ − v_g|²) per
    step, and v⁺ − v_g = O(h)).  It conserves oil to round-off in a closed
    network: m_lin does, and each column of ∂m/∂v = h·N·(dQ/dv) sums to
    zero because every branch flow leaves one node and enters another.  It
    ignores ``substeps`` (one linearisation per plant step; asking for more
    substeps is an error).  Reported branch flows are evaluated at the end
    state (p⁺, v⁺), for the energy ledger.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import laws
from .network import NetworkControl, NetworkModel, NetworkState
from .steppers import ActuatorMotion, StepperImplicitEuler, StepReport, StepStatus, make_stepper


@dataclass(frozen=True)
class EffortLaw:
    """Actuator effort during a step: effort = constant + slope·v⁺ (shape (actuator_count,)).

    ``lower``/``upper`` (optional) bound the effort: a plant that can bound a
    constraint force (XPBD) applies them; the law itself already respects them
    at the start of the step.
    """

    constant: np.ndarray  # N or N·m
    slope: np.ndarray  # N·s/m or N·m·s/rad (≤ 0 for a stable law)
    lower: np.ndarray | None = None  # N or N·m
    upper: np.ndarray | None = None

    def __call__(self, velocity):
        return self.constant + self.slope * velocity


def blend_factor(stiffness_slope, effective_mass, dt):
    """θ per actuator: clip(1 − 2/w, 0, 1) with w = (ω·h)² = −slope·h/m_eff (see module docstring).

    ``stiffness_slope`` [N·s/m] is the pressure part of ∂effort/∂v⁺ (≤ 0),
    ``effective_mass`` [kg] the inertia the actuator sees (1/(J·M⁻¹·Jᵀ)).
    """
    w = np.maximum(-np.asarray(stiffness_slope, float), 0.0) * dt / np.asarray(effective_mass, float)
    with np.errstate(divide="ignore"):
        return np.clip(1.0 - 2.0 / w, 0.0, 1.0)


class Coupling:
    """Base class; see the module docstring.  ``stepper`` finishes each step."""

    name = "base"

    def __init__(self, model: NetworkModel, stepper):
        self.model = model
        self.stepper = stepper

    def begin(
        self, state: NetworkState, control: NetworkControl, position, velocity, dt: float, *,
        effective_mass=None, velocity_guess=None,
    ) -> EffortLaw:
        """Effort law for the coming step, given the plant's actuator positions and velocities at its start.

        ``effective_mass`` (shape (actuator_count,), [kg or kg·m²]) lets the
        implicit scheme choose its θ per actuator; None means θ = 1.
        ``velocity_guess`` is where the implicit scheme linearises the
        end-of-step velocities; it defaults to zero, i.e. the actuators held at
        their start positions, which is always a valid state (a linearly
        implicit Euler step with the Jacobian at the start of the step).
        """
        raise NotImplementedError

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        """Advance the network over the step the plant has just taken; returns (state, report)."""
        raise NotImplementedError


class CouplingExplicit(Coupling):
    """Weak co-simulation: lagged efforts, zero-order-hold velocities."""

    name = "explicit"

    def begin(self, state, control, position, velocity, dt, *, effective_mass=None, velocity_guess=None):
        effort, _ = self.model.actuator_effort(state.node_pressure, np.asarray(velocity, float))
        return EffortLaw(effort, np.zeros_like(effort))

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        motion = ActuatorMotion.linear(state.actuator_position, velocity_start, dt)
        return self.stepper.step(state, control, motion, dt)


# A start velocity is used as the linearisation's guess of v⁺ only where the guessed displacement h·|v|
# changes each chamber volume of its cylinder by at most this fraction (a short chord of the pressure law):
# in an unresolved oscillation (the seed at 1200 Hz reverses ~1900 m/s every step) the start velocity is a
# bad guess of v⁺, and the law linearised there lets the machine gain energy.
GUESS_VOLUME_FRACTION = 0.01  # [-]


def start_velocity_guess(model: NetworkModel, position, velocity, dt: float) -> np.ndarray:
    """``velocity_guess`` from the start-of-step velocities [m/s or rad/s]: v, or 0 for a cylinder whose guessed
    displacement dt·|v| [m] would change a chamber volume by more than :data:`GUESS_VOLUME_FRACTION`."""
    position = np.asarray(position, float)
    guess = np.array(velocity, float)
    c = model.cylinder_actuator
    if len(c):
        cap, rod, _, _ = model.chamber_volumes(position)
        swept = dt * np.abs(guess[c])
        short = (swept * model.cylinder_cap_area <= GUESS_VOLUME_FRACTION * cap) & (
            swept * model.cylinder_rod_area <= GUESS_VOLUME_FRACTION * rod)
        guess[c] = np.where(short, guess[c], 0.0)
    return guess


def _usable(lin) -> bool:
    """A linearisation whose Newton solve converged to finite pressures and gradients."""
    return bool(
        lin.report.success and np.all(np.isfinite(lin.state.node_pressure)) and np.all(np.isfinite(lin.effort_velocity_gradient))
    )


class CouplingImplicit(Coupling):
    """Linearly implicit coupling through :meth:`StepperImplicitEuler.linearize`."""

    name = "implicit"

    def __init__(self, model, stepper):
        super().__init__(model, stepper)
        # the linearisation is a single backward-Euler step whatever the finishing stepper
        self.predictor = stepper if isinstance(stepper, StepperImplicitEuler) else StepperImplicitEuler(model)
        self.last_linearization = None

    def begin(self, state, control, position, velocity, dt, *, effective_mass=None, velocity_guess=None):
        model = self.model
        position = np.asarray(position, float).copy()
        start_velocity = np.asarray(velocity, float)
        velocity = np.zeros_like(position) if velocity_guess is None else np.array(velocity_guess, float)
        # keep the predicted cylinder positions inside the stroke (the end stops will)
        c = model.cylinder_actuator
        velocity[c] = np.clip(velocity[c], -position[c] / dt, (model.cylinder_stroke - position[c]) / dt)
        start = NetworkState(state.node_oil, state.node_pressure, state.valve_spool, position, velocity, state.time)
        try:
            lin = self.predictor.linearize(start, control, velocity, dt)
        except np.linalg.LinAlgError:
            if not np.any(velocity):
                raise
            lin = None
        if np.any(velocity) and (lin is None or not _usable(lin)):
            # an unresolved oscillation can make the guess useless (e.g. the seed at 1200 Hz reverses ~1900 m/s
            # each step, so x + h·v_guess empties a chamber): linearise at the held actuators instead
            velocity = np.zeros_like(velocity)
            velocity[c] = np.clip(velocity[c], -position[c] / dt, (model.cylinder_stroke - position[c]) / dt)
            start = NetworkState(state.node_oil, state.node_pressure, state.valve_spool, position, velocity, state.time)
            lin = self.predictor.linearize(start, control, velocity, dt)
        self.last_linearization = lin
        self._begun = (state, dt)  # finish() uses the linearisation only for this state and step
        # pressure part: backward-Euler law around the guess, blended with the start force by θ
        _, friction_slope_at_guess = model.friction_effort(velocity)
        pressure_slope = np.diag(lin.effort_velocity_gradient) - friction_slope_at_guess
        pressure_end = model.pressure_effort(lin.state.node_pressure)
        # the state's pressures already belong to its oil at this position (PBD mode); MuJoCo's tendon
        # lengths differ from the network's x + h·v⁺ by round-off, so there they are recomputed
        same_position = np.array_equal(position, state.actuator_position)
        pressure_start = model.pressure_effort(state.node_pressure if same_position else model.pressure(state.node_oil, position)[0])
        theta = np.ones_like(pressure_slope) if effective_mass is None else blend_factor(pressure_slope, effective_mass, dt)
        self.last_theta = theta
        # friction depends on velocity only: linearise it at the start velocity, the best guess of v⁺.
        # Its Stribeck region has a positive slope (negative damping); folded into the plant's
        # implicit mass matrix it can make it indefinite for light loads, so only the
        # dissipative part of the slope is taken implicitly.
        friction, friction_slope = model.friction_effort(start_velocity)
        friction_slope = np.minimum(friction_slope, 0.0)
        constant = (
            (1.0 - theta) * pressure_start
            + theta * (pressure_end - pressure_slope * velocity)
            + friction - friction_slope * start_velocity
        )
        return EffortLaw(constant, theta * pressure_slope + friction_slope)

    def predicted_oil(self, state, velocity_end, dt):
        """m_lin + (∂m/∂v)·(v⁺ − v_guess) [kg] from the linearisation of this step, or None if there is none."""
        lin = self.last_linearization
        begun = getattr(self, "_begun", None)
        if lin is None or lin.oil_velocity_gradient is None or begun is None or begun[0] is not state or begun[1] != dt:
            return None
        return lin.state.node_oil + lin.oil_velocity_gradient @ (np.asarray(velocity_end, float) - lin.velocity)

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        motion = ActuatorMotion(
            np.asarray(position_start, float), np.asarray(position_end, float),
            np.asarray(velocity_start, float), np.asarray(velocity_end, float),
        )
        guess = self.predicted_oil(state, velocity_end, dt)
        if guess is None or not self.stepper.implicit:
            return self.stepper.step(state, control, motion, dt)
        return self.stepper.step(state, control, motion, dt, oil_guess=guess)


class CouplingImplicitLinear(CouplingImplicit):
    """``implicit-linear``: the ``implicit`` effort law, finished by m⁺ = m_lin + (∂m/∂v)·(v⁺ − v_guess) (no Newton)."""

    name = "implicit-linear"

    def __init__(self, model, stepper):
        if getattr(stepper, "substeps", 1) != 1:
            raise ValueError(
                f"coupling 'implicit-linear' takes one linearly implicit step per plant step: "
                f"hydraulic substeps must be 1, got {stepper.substeps}"
            )
        super().__init__(model, stepper)

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        m = self.model
        oil = self.predicted_oil(state, velocity_end, dt)
        if oil is None:
            raise RuntimeError("coupling 'implicit-linear': finish() must follow begin() for the same state and dt")
        lin = self.last_linearization
        position_end = np.asarray(position_end, float).copy()
        velocity_end = np.asarray(velocity_end, float).copy()
        with np.errstate(all="ignore"):
            pressure, _ = m.pressure(oil, position_end)
            spool = lin.state.valve_spool
            flows = m.branch_flows(pressure, m.valve_areas(spool), control.pump_speed, velocity_end)
        report = StepReport(rhs_evaluations=1, branch_flow=flows.flow)
        if not np.all(np.isfinite(pressure)):
            bad = m.node_names[int(np.flatnonzero(~np.isfinite(pressure))[0])]
            report.status = StepStatus.NONFINITE
            report.message = f"pressure of node '{bad}' is not finite: {StepStatus.NONFINITE.value}"
            return state, report
        return NetworkState(oil, pressure, spool.copy(), position_end, velocity_end, state.time + dt), report


# Incompressible fidelity: the rod follows its metered flow with this stiffness relative to
# m_eff/h (the velocity error left after one step is about 1/(1 + gain) of the demand change).
INCOMPRESSIBLE_TRACKING_GAIN = 100.0  # [-]
# Force bound of an incompressible actuator in a circuit without relief valves, as a pressure.
INCOMPRESSIBLE_UNBOUNDED_PRESSURE = 1e12  # Pa


class CouplingIncompressible(Coupling):
    """``incompressible`` fidelity: no pressure states.

    A valve-controlled actuator with rigid oil (Merritt §5.2, quasi-static):
    with supply pressure p_s (the pump's compensator setting, or the highest
    relief setting for fixed pumps), tank pressure p_t and the metering edges
    a_in (P→inlet chamber) and a_out (outlet chamber→T) of the commanded
    direction, the actuator force is a quadratic damper

        F(v) = F_d − R·v·|v|,   F_d = ±(p_s·A_in − p_t·A_out),
        R = (ρ/2)·(A_in³/(C_d·a_in)² + A_out³/(C_d·a_out)²),

    (A_in = A_cap, A_out = A_rod extending, swapped retracting, D/2π for
    motors), linearised at the start velocity so the plant integrates its slope
    −2R|v| implicitly.  A closed valve locks the actuator with a stiff velocity
    tracker (K = gain·m_eff/h towards v = 0), and an actuator faster than its
    share of the pumps' delivery is tracked at that share.  The effort is bounded
    by the highest relief setting (``EffortLaw.lower/upper``; the plant clamps
    within its step, so the actuator stalls there).  Logged pressures are derived
    from the force.  **Limitations**: no oil-column compliance (no pressure peaks
    or oscillation), no leakage, energy terms of the network are not computed.
    """

    name = "incompressible"

    def __init__(self, model, stepper=None):
        super().__init__(model, stepper)
        n = model.actuator_count
        self.edges = np.full((n, 4), -1)  # per actuator: orifice branches P→in, out→T (extend), P→out, in→T (retract)
        for a in range(n):
            if model.actuator_kind[a] == 0:
                i = list(model.cylinder_actuator).index(a)
                inlet, outlet = model.cylinder_cap_node[i], model.cylinder_rod_node[i]
            else:
                i = list(model.motor_actuator).index(a)
                inlet, outlet = model.motor_a_node[i], model.motor_b_node[i]
            for b in range(model.branch_slices["orifice"].stop):
                if model.orifice_valve[b] < 0 or model.orifice_sign[b] == 0:
                    continue
                frm, to = model.branch_from[b], model.branch_to[b]
                if to == inlet:
                    self.edges[a, 0 if model.orifice_sign[b] > 0 else 2] = b
                elif frm == outlet:
                    self.edges[a, 1 if model.orifice_sign[b] > 0 else 3] = b
                elif to == outlet:
                    self.edges[a, 2 if model.orifice_sign[b] < 0 else 0] = b
                elif frm == inlet:
                    self.edges[a, 3 if model.orifice_sign[b] < 0 else 1] = b
        # without a relief valve nothing limits the force but the plant: bound it far beyond any load
        relief = np.max(model.relief_cracking) if len(model.relief_cracking) else INCOMPRESSIBLE_UNBOUNDED_PRESSURE
        compensators = model.pump_compensator[np.isfinite(model.pump_compensator)]
        self.supply_pressure = model.fluid.reference_pressure + (np.max(compensators) if len(compensators) else relief)
        self.extend_area = np.zeros(n)
        self.retract_area = np.zeros(n)
        self.extend_area[model.cylinder_actuator] = model.cylinder_cap_area
        self.retract_area[model.cylinder_actuator] = model.cylinder_rod_area
        rate = model.motor_displacement / (2.0 * np.pi)
        self.extend_area[model.motor_actuator] = rate
        self.retract_area[model.motor_actuator] = rate
        self.force_upper = relief * self.extend_area
        self.force_lower = -relief * self.retract_area

    def law(self, spool, pump_speed, velocity, effective_mass, dt) -> EffortLaw:
        """Effort law for the step (see class docstring)."""
        m = self.model
        rho = m.fluid.density
        p_s, p_t = self.supply_pressure, m.fluid.reference_pressure
        mass = np.ones_like(velocity) if effective_mass is None else np.where(np.isfinite(effective_mass), effective_mass, 1.0)
        gain = INCOMPRESSIBLE_TRACKING_GAIN * mass / dt
        if not np.any(self.edges >= 0):  # no metering valve reaches any actuator: rigid oil locks them all
            return EffortLaw(np.zeros_like(velocity), -gain, self.force_lower, self.force_upper)
        areas = m.valve_areas(spool)
        edge = np.maximum(self.edges, 0)
        coefficient = np.where(self.edges >= 0, m.orifice_cd[edge] * areas[edge], 0.0)
        valve = m.orifice_valve[edge[:, 0]]
        opening = np.where(self.edges[:, 0] >= 0, spool[np.maximum(valve, 0)] if len(spool) else 0.0, 0.0)
        direction = np.sign(opening) * (laws.metering_opening(np.abs(opening), m.valve_overlap[np.maximum(valve, 0)]) > 0)
        a_in = np.where(direction >= 0, self.extend_area, self.retract_area)
        a_out = np.where(direction >= 0, self.retract_area, self.extend_area)
        c_in = np.where(direction >= 0, coefficient[:, 0], coefficient[:, 2])
        c_out = np.where(direction >= 0, coefficient[:, 1], coefficient[:, 3])
        with np.errstate(divide="ignore", invalid="ignore"):
            resist = 0.5 * rho * (a_in**3 / c_in**2 + a_out**3 / c_out**2)
        drive = direction * (p_s * a_in - p_t * a_out)
        constant = drive + resist * velocity * np.abs(velocity)
        slope = -2.0 * resist * np.abs(velocity)
        # flow share of the pumps: demands beyond the delivery are scaled down together
        free_speed = np.sqrt(np.maximum(np.abs(drive), 0.0) / resist)
        demand = np.where(direction != 0, free_speed * a_in, 0.0)
        supply = float(np.sum(laws.pump_flow(m.pump_displacement, pump_speed, m.pump_efficiency)))
        share = demand * min(1.0, supply / demand.sum()) if demand.sum() > 0 else demand
        cap = np.where(a_in > 0, share / a_in, 0.0)
        track = (direction == 0) | ~np.isfinite(resist) | (np.abs(velocity) >= cap)
        target = direction * np.where(direction == 0, 0.0, cap)
        constant = np.where(track, gain * target, constant)
        slope = np.where(track, -gain, slope)
        return EffortLaw(constant, slope, self.force_lower, self.force_upper)

    def begin(self, state, control, position, velocity, dt, *, effective_mass=None, velocity_guess=None):
        self._spool = laws.spool_step(state.valve_spool, np.clip(control.valve_command, -1.0, 1.0), self.model.valve_time_constant, dt)
        self._law = self.law(self._spool, control.pump_speed, np.asarray(velocity, float), effective_mass, dt)
        return self._law

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        m = self.model
        effort = np.clip(self._law(np.asarray(velocity_end, float)), self.force_lower, self.force_upper)
        ref = m.fluid.reference_pressure
        pressure = np.full(m.node_count, ref)
        pressure[m.node_fixed] = m.node_fixed_pressure[m.node_fixed]
        for i, a in enumerate(m.cylinder_actuator):
            if effort[a] >= 0:
                pressure[m.cylinder_cap_node[i]] = ref + effort[a] / m.cylinder_cap_area[i]
            else:
                pressure[m.cylinder_rod_node[i]] = ref - effort[a] / m.cylinder_rod_area[i]
        for i, a in enumerate(m.motor_actuator):
            node = m.motor_a_node[i] if effort[a] >= 0 else m.motor_b_node[i]
            pressure[node] = ref + abs(effort[a]) * 2.0 * np.pi / m.motor_displacement[i]
        new = NetworkState(
            m.oil_from_pressure(pressure, np.asarray(position_end, float)), pressure, self._spool,
            np.asarray(position_end, float).copy(), np.asarray(velocity_end, float).copy(), state.time + dt,
        )
        return new, StepReport(branch_flow=np.zeros(len(m.branch_names)))


COUPLINGS = {
    "explicit": CouplingExplicit, "implicit": CouplingImplicit, "implicit-linear": CouplingImplicitLinear,
    "incompressible": CouplingIncompressible,
}
"""Coupling names → classes."""

DEFAULT_STEPPER = {
    "explicit": "explicit_euler", "implicit": "implicit_euler", "implicit-linear": "implicit_euler",
    "incompressible": "implicit_euler",
}
"""The hydraulic stepper each coupling uses unless told otherwise."""


def make_coupling(name: str, model: NetworkModel, *, stepper=None, substeps: int = 1, compiled: bool = False) -> Coupling:
    """Build a coupling scheme with its finishing stepper (default per :data:`DEFAULT_STEPPER`).

    ``compiled`` selects the numba-compiled backward Euler where it applies.
    """
    if name not in COUPLINGS:
        raise ValueError(f"unknown coupling {name!r}; choose from {sorted(COUPLINGS)}")
    stepper = make_stepper(stepper or DEFAULT_STEPPER[name], model, substeps=substeps, compiled=compiled)
    return COUPLINGS[name](model, stepper)


__all__ = ["EffortLaw", "Coupling", "CouplingExplicit", "CouplingImplicit", "CouplingImplicitLinear", "COUPLINGS",
           "make_coupling", "start_velocity_guess", "StepReport"]
