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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import laws
from .network import NetworkControl, NetworkModel, NetworkState
from .steppers import ActuatorMotion, StepperImplicitEuler, StepReport, make_stepper


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
        lin = self.predictor.linearize(start, control, velocity, dt)
        self.last_linearization = lin
        # pressure part: backward-Euler law around the guess, blended with the start force by θ
        _, friction_slope_at_guess = model.friction_effort(velocity)
        pressure_slope = np.diag(lin.effort_velocity_gradient) - friction_slope_at_guess
        pressure_end = model.pressure_effort(lin.state.node_pressure)
        pressure_start = model.pressure_effort(model.pressure(state.node_oil, position)[0])
        theta = np.ones_like(pressure_slope) if effective_mass is None else blend_factor(pressure_slope, effective_mass, dt)
        self.last_theta = theta
        # friction depends on velocity only: linearise it at the start velocity, the best guess of v⁺
        friction, friction_slope = model.friction_effort(start_velocity)
        constant = (
            (1.0 - theta) * pressure_start
            + theta * (pressure_end - pressure_slope * velocity)
            + friction - friction_slope * start_velocity
        )
        return EffortLaw(constant, theta * pressure_slope + friction_slope)

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        motion = ActuatorMotion(
            np.asarray(position_start, float), np.asarray(position_end, float),
            np.asarray(velocity_start, float), np.asarray(velocity_end, float),
        )
        return self.stepper.step(state, control, motion, dt)


# Incompressible fidelity: the rod follows its metered flow with this stiffness relative to
# m_eff/h (the velocity error left after one step is about 1/(1 + gain) of the demand change).
INCOMPRESSIBLE_TRACKING_GAIN = 100.0  # [-]
# Pressure drop at which a valve's rated (metered) flow is taken.
NOMINAL_VALVE_DROP = 1.0e6  # Pa


class CouplingIncompressible(Coupling):
    """``incompressible`` fidelity: no pressure states.

    Each actuator's speed follows the flow its valve meters, Q = y(s)·C_d·A_max·
    sqrt(2·Δp_nom/ρ) (y the edge opening, Δp_nom = ``NOMINAL_VALVE_DROP``), all
    demands scaled down together when they exceed the pumps' delivery; v = Q/A_cap
    extending, −Q/A_rod retracting, ω = 2π·Q/D for motors.  The law is a stiff
    velocity tracker, f = K·(v_target − v⁺) with K = gain·m_eff/h, bounded by
    the force the highest relief setting allows (``EffortLaw.lower/upper``; the
    plant clamps within its step, so the actuator stalls there).  The
    logged pressures are derived from the force: the loaded chamber carries it,
    the other sits at the reference pressure.  **Limitations**: no oil-column
    compliance, no valve pressure–flow dependence, no pump flow limit other than
    the proportional sharing; energy terms of the network are not computed.
    """

    name = "incompressible"

    def __init__(self, model, stepper=None):
        super().__init__(model, stepper)
        fluid = model.fluid
        n = model.actuator_count
        self.valve_of = np.full(n, -1)
        self.valve_sign = np.zeros(n)
        for a in range(n):
            if model.actuator_kind[a] == 0:
                i = list(model.cylinder_actuator).index(a)
                extend_node = model.cylinder_cap_node[i]
            else:
                i = list(model.motor_actuator).index(a)
                extend_node = model.motor_a_node[i]
            for b, name in enumerate(model.branch_names[model.branch_slices["orifice"]]):
                if model.orifice_valve[b] >= 0 and name.endswith(".P-A") and model.branch_to[b] == extend_node:
                    self.valve_of[a], self.valve_sign[a] = model.orifice_valve[b], 1.0
                elif model.orifice_valve[b] >= 0 and name.endswith(".P-B") and model.branch_to[b] == extend_node:
                    self.valve_of[a], self.valve_sign[a] = model.orifice_valve[b], -1.0
        edge = {v: b for b, v in enumerate(model.orifice_valve) if v >= 0 and model.orifice_sign[b] > 0}
        self.rated_flow = np.zeros(len(model.valve_names))
        for v, b in edge.items():
            self.rated_flow[v] = model.orifice_cd[b] * model.orifice_max_area[b] * np.sqrt(2.0 * NOMINAL_VALVE_DROP / fluid.density)
        relief = np.max(model.relief_cracking, initial=0.0)
        self.extend_area = np.zeros(n)
        self.retract_area = np.zeros(n)
        self.extend_area[model.cylinder_actuator] = model.cylinder_cap_area
        self.retract_area[model.cylinder_actuator] = model.cylinder_rod_area
        rate = model.motor_displacement / (2.0 * np.pi)
        self.extend_area[model.motor_actuator] = rate
        self.retract_area[model.motor_actuator] = rate
        self.force_upper = relief * self.extend_area
        self.force_lower = -relief * self.retract_area

    def targets(self, spool, pump_speed):
        """Target actuator velocities [m/s or rad/s] for the given spool positions and pump speeds."""
        m = self.model
        has = self.valve_of >= 0
        s = np.where(has, spool[np.maximum(self.valve_of, 0)], 0.0) * self.valve_sign
        opening = laws.metering_opening(np.abs(s), m.valve_overlap[np.maximum(self.valve_of, 0)]) * has
        demand = opening * self.rated_flow[np.maximum(self.valve_of, 0)]
        supply = float(np.sum(laws.pump_flow(m.pump_displacement, pump_speed, m.pump_efficiency)))
        total = demand.sum()
        if total > supply > 0:
            demand *= supply / total
        return np.where(s >= 0, demand / self.extend_area, -demand / self.retract_area)

    def begin(self, state, control, position, velocity, dt, *, effective_mass=None, velocity_guess=None):
        spool = laws.spool_step(state.valve_spool, np.clip(control.valve_command, -1.0, 1.0), self.model.valve_time_constant, dt)
        target = self.targets(spool, control.pump_speed)
        mass = np.ones_like(target) if effective_mass is None else np.where(np.isfinite(effective_mass), effective_mass, 1.0)
        gain = INCOMPRESSIBLE_TRACKING_GAIN * mass / dt
        self._spool = spool
        self._law = EffortLaw(gain * target, -gain, self.force_lower, self.force_upper)
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


COUPLINGS = {"explicit": CouplingExplicit, "implicit": CouplingImplicit, "incompressible": CouplingIncompressible}
"""Coupling names → classes."""

DEFAULT_STEPPER = {"explicit": "explicit_euler", "implicit": "implicit_euler", "incompressible": "implicit_euler"}
"""The hydraulic stepper each coupling uses unless told otherwise."""


def make_coupling(name: str, model: NetworkModel, *, stepper=None, substeps: int = 1) -> Coupling:
    """Build a coupling scheme with its finishing stepper (default per :data:`DEFAULT_STEPPER`)."""
    if name not in COUPLINGS:
        raise ValueError(f"unknown coupling {name!r}; choose from {sorted(COUPLINGS)}")
    stepper = make_stepper(stepper or DEFAULT_STEPPER[name], model, substeps=substeps)
    return COUPLINGS[name](model, stepper)


__all__ = ["EffortLaw", "Coupling", "CouplingExplicit", "CouplingImplicit", "COUPLINGS", "make_coupling", "StepReport"]
