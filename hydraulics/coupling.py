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

from .network import NetworkControl, NetworkModel, NetworkState
from .steppers import ActuatorMotion, StepperImplicitEuler, StepReport, make_stepper


@dataclass(frozen=True)
class EffortLaw:
    """Actuator effort during a step: effort = constant + slope·v⁺ (shape (actuator_count,))."""

    constant: np.ndarray  # N or N·m
    slope: np.ndarray  # N·s/m or N·m·s/rad (≤ 0 for a stable law)

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


COUPLINGS = {"explicit": CouplingExplicit, "implicit": CouplingImplicit}
"""Coupling names → classes."""

DEFAULT_STEPPER = {"explicit": "explicit_euler", "implicit": "implicit_euler"}
"""The hydraulic stepper each coupling uses unless told otherwise."""


def make_coupling(name: str, model: NetworkModel, *, stepper=None, substeps: int = 1) -> Coupling:
    """Build a coupling scheme with its finishing stepper (default per :data:`DEFAULT_STEPPER`)."""
    if name not in COUPLINGS:
        raise ValueError(f"unknown coupling {name!r}; choose from {sorted(COUPLINGS)}")
    stepper = make_stepper(stepper or DEFAULT_STEPPER[name], model, substeps=substeps)
    return COUPLINGS[name](model, stepper)


__all__ = ["EffortLaw", "Coupling", "CouplingExplicit", "CouplingImplicit", "COUPLINGS", "make_coupling", "StepReport"]
