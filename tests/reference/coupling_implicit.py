"""The implicit couplings' pieces in numpy: oracles of the compiled rules that :mod:`hydraulics.coupling` calls.

Each function is the numpy formulation of one compiled kernel of :mod:`hydraulics._compiled`:

* :func:`blend_factor` — θ = clip(1 − 2/w, 0, 1), w = (ω·h)² = max(−slope, 0)·h/m_eff (``_blend_factor``);
* :func:`start_velocity_guess` — v, or 0 for a cylinder whose chord h·|v| changes a chamber volume by more
  than GUESS_VOLUME_FRACTION (``_short_chord_guess``);
* :func:`secant_oil_guess` — m + Δm_last, or None (``_secant_oil_guess``);
* :func:`usable` — converged, finite pressures and gradients (``_linearization_usable``);
* :func:`predicted_oil` — m_lin + (∂m/∂v)·(v⁺ − v_g) (``_predicted_oil``);
* :func:`effort_law` — the blended backward-Euler effort law c + s·v⁺ (``_effort_law_terms``, ``_blended_law``);
* :func:`linear_finish` — p⁺ = p(m⁺, x⁺) and the flows there (``_linear_finish``).

:class:`CouplingImplicitOracle` (and its ``implicit-linear`` / ``rosenbrock`` variants) assembles them with the
numpy Newton of :mod:`reference.newton` into the coupling as a whole, for scene comparisons.

Example
-------
>>> coupling = CouplingImplicitOracle(model, StepperImplicitEulerOracle(model))  # doctest: +SKIP
"""

from __future__ import annotations

import numpy as np

from hydraulics import coupling as _coupling
from hydraulics.coupling import EffortLaw
from hydraulics.network import NetworkState
from hydraulics.steppers import ActuatorMotion, StepReport, StepStatus

from .newton import StepperImplicitEulerOracle


def blend_factor(stiffness_slope, effective_mass, dt):
    """θ per actuator: clip(1 − 2/w, 0, 1) with w = −slope·h/m_eff (slope [N·s/m], mass [kg], dt [s])."""
    w = np.maximum(-np.asarray(stiffness_slope, float), 0.0) * dt / np.asarray(effective_mass, float)
    with np.errstate(divide="ignore", over="ignore"):
        return np.clip(1.0 - 2.0 / w, 0.0, 1.0)


def start_velocity_guess(model, position, velocity, dt):
    """v [m/s or rad/s], or 0 for a cylinder whose guessed chord dt·|v| changes a chamber volume by more than
    ``hydraulics.coupling.GUESS_VOLUME_FRACTION``."""
    position = np.asarray(position, float)
    guess = np.array(velocity, float)
    c = model.cylinder_actuator
    if len(c):
        cap, rod, _, _ = model.chamber_volumes(position)
        swept = dt * np.abs(guess[c])
        fraction = _coupling.GUESS_VOLUME_FRACTION
        short = (swept * model.cylinder_cap_area <= fraction * cap) & (swept * model.cylinder_rod_area <= fraction * rod)
        guess[c] = np.where(short, guess[c], 0.0)
    return guess


def secant_oil_guess(state: NetworkState):
    """m + (m − m_prev) [m³], or None for a state without a last step."""
    return None if state.node_oil_change is None else state.node_oil + state.node_oil_change


def usable(lin) -> bool:
    """A linearisation (not None) whose Newton solve converged to finite pressures and gradients."""
    return lin is not None and bool(
        lin.report.success and np.all(np.isfinite(lin.state.node_pressure)) and np.all(np.isfinite(lin.effort_velocity_gradient))
    )


def predicted_oil(lin, velocity_end):
    """m_lin + (∂m/∂v)·(v⁺ − v_guess) [m³] of the linearisation ``lin``."""
    return lin.state.node_oil + lin.oil_velocity_gradient @ (np.asarray(velocity_end, float) - lin.velocity)


def effort_law(model, lin, start_velocity, pressure_start, effective_mass, dt):
    """(constant, slope, θ) of the implicit effort law: the pressure part of the backward-Euler law at the guess
    blended with the start pressure force ``pressure_start`` [N] by θ (θ = 1 without effective masses), plus the
    friction linearised at the start velocity with its dissipative slope only, its seal load at the linearisation's
    end pressures."""
    velocity = lin.velocity
    p_end, x_end = lin.state.node_pressure, lin.state.actuator_position
    _, friction_slope_at_guess = model.friction_effort(velocity, p_end, x_end)
    pressure_slope = np.diag(lin.effort_velocity_gradient) - friction_slope_at_guess
    pressure_end = model.pressure_effort(lin.state.node_pressure)
    theta = np.ones_like(pressure_slope) if effective_mass is None else blend_factor(pressure_slope, effective_mass, dt)
    friction, friction_slope = model.friction_effort(start_velocity, p_end, x_end)
    friction_slope = np.minimum(friction_slope, 0.0)
    constant = ((1.0 - theta) * pressure_start + theta * (pressure_end - pressure_slope * velocity)
                + friction - friction_slope * start_velocity)
    return constant, theta * pressure_slope + friction_slope, theta


def linear_finish(model, oil, spool, position_end, velocity_end, pump_speed):
    """(p⁺ [Pa], branch flows [m³/s]) at the predicted oil ``oil`` and the end positions and velocities."""
    with np.errstate(all="ignore"):
        pressure, _ = model.pressure(oil, position_end)
        flows = model.branch_flows(pressure, model.valve_areas(spool), pump_speed, velocity_end)
    return pressure, flows.flow


class CouplingImplicitOracle(_coupling.Coupling):
    """``implicit`` coupling in numpy on :class:`StepperImplicitEulerOracle` (the package's
    :class:`hydraulics.coupling.CouplingImplicit` calls compiled kernels for the same rules)."""

    name = "implicit"
    newton = True

    def __init__(self, model, stepper=None):
        super().__init__(model, stepper if stepper is not None else StepperImplicitEulerOracle(model))
        self.predictor = self.stepper
        self.last_linearization = None

    def _linearize_or_none(self, start, control, velocity, dt, oil_guess):
        try:
            return self.predictor.linearize(start, control, velocity, dt, newton=self.newton, oil_guess=oil_guess)
        except np.linalg.LinAlgError:
            if not np.any(velocity):
                raise
            return None

    def begin(self, state, control, position, velocity, dt, *, effective_mass=None, velocity_guess=None):
        model = self.model
        position = np.asarray(position, float).copy()
        start_velocity = np.asarray(velocity, float)
        velocity = np.zeros_like(position) if velocity_guess is None else np.array(velocity_guess, float)
        c = model.cylinder_actuator
        velocity[c] = np.clip(velocity[c], -position[c] / dt, (model.cylinder_stroke - position[c]) / dt)
        start = NetworkState(state.node_oil, state.node_pressure, state.valve_spool, position, velocity, state.time)
        warm = secant_oil_guess(state) if np.any(velocity) else None
        lin = self._linearize_or_none(start, control, velocity, dt, warm)
        if warm is not None and not usable(lin):
            lin = self._linearize_or_none(start, control, velocity, dt, None)
        if np.any(velocity) and not usable(lin):
            velocity = np.zeros_like(velocity)
            velocity[c] = np.clip(velocity[c], -position[c] / dt, (model.cylinder_stroke - position[c]) / dt)
            start = NetworkState(state.node_oil, state.node_pressure, state.valve_spool, position, velocity, state.time)
            lin = self.predictor.linearize(start, control, velocity, dt, newton=self.newton)
        self.last_linearization = lin
        self._begun = (state, dt)
        same_position = np.array_equal(position, state.actuator_position)
        pressure_start = model.pressure_effort(state.node_pressure if same_position else model.pressure(state.node_oil, position)[0])
        constant, slope, theta = effort_law(model, lin, start_velocity, pressure_start, effective_mass, dt)
        self.last_theta = theta
        return EffortLaw(constant, slope)

    def predicted_oil(self, state, velocity_end, dt):
        lin = self.last_linearization
        begun = getattr(self, "_begun", None)
        if lin is None or lin.oil_velocity_gradient is None or begun is None or begun[0] is not state or begun[1] != dt:
            return None
        return predicted_oil(lin, velocity_end)

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        motion = ActuatorMotion(np.asarray(position_start, float), np.asarray(position_end, float),
                                np.asarray(velocity_start, float), np.asarray(velocity_end, float))
        guess = self.predicted_oil(state, velocity_end, dt)
        if guess is None:
            return self.stepper.step(state, control, motion, dt)
        return self.stepper.step(state, control, motion, dt, oil_guess=guess)


class CouplingImplicitLinearOracle(CouplingImplicitOracle):
    """``implicit-linear`` in numpy: finished by m⁺ = m_lin + (∂m/∂v)·(v⁺ − v_guess), no Newton."""

    name = "implicit-linear"

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        oil = self.predicted_oil(state, velocity_end, dt)
        lin = self.last_linearization
        position_end = np.asarray(position_end, float).copy()
        velocity_end = np.asarray(velocity_end, float).copy()
        spool = lin.state.valve_spool
        pressure, flow = linear_finish(self.model, oil, spool, position_end, velocity_end, control.pump_speed)
        report = StepReport(rhs_evaluations=1, branch_flow=flow)
        if not np.all(np.isfinite(pressure)):
            report.status = StepStatus.NONFINITE
            return state, report
        return NetworkState(oil, pressure, spool.copy(), position_end, velocity_end, state.time + dt,
                            oil - state.node_oil), report


def linear_finish_accepted(model, state, new, flow, spool, dt):
    """Whether ``rosenbrock``'s linear finish from ``state`` to ``new`` (branch flows ``flow`` [m³/s] at the end) is
    accepted (``_linear_finish_accepted``): finite end pressures, every switching branch on its start piece
    (``model.law_pieces`` over ``dt`` [s] from the component states ``spool``), and every free node's backward-Euler
    residual r = m⁺ − m − dt·N·Q worth |r|·∂p/∂m ≤ max(LINEAR_FINISH_PRESSURE, LINEAR_FINISH_FRACTION·|p⁺|)."""
    from hydraulics import _compiled

    p = new.node_pressure
    if not np.all(np.isfinite(p)):
        return False
    if not np.array_equal(model.law_pieces(state.node_pressure, spool, dt), model.law_pieces(p, spool, dt)):
        return False
    free = model.free_nodes
    _, dpdm = model.pressure(new.node_oil, new.actuator_position)
    residual = new.node_oil[free] - state.node_oil[free] - dt * (model.incidence @ flow)[free]
    allowed = np.maximum(_compiled.LINEAR_FINISH_PRESSURE, _compiled.LINEAR_FINISH_FRACTION * np.abs(p[free]))
    return bool(np.all(np.abs(residual) * dpdm[free] <= allowed))


class CouplingRosenbrockOracle(CouplingImplicitLinearOracle):
    """``rosenbrock`` in numpy: ``implicit-linear`` with the one-Newton-step linearisation, its finish by Newton where
    :func:`linear_finish_accepted` rejects the linear one."""

    name = "rosenbrock"
    newton = False

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        spool = self.last_linearization.state.valve_spool.copy()
        new, report = super().finish(state, control, position_start, position_end, velocity_start, velocity_end, dt)
        if report.success and linear_finish_accepted(self.model, state, new, report.branch_flow, spool, dt):
            return new, report
        new, report = CouplingImplicitOracle.finish(self, state, control, position_start, position_end, velocity_start,
                                                    velocity_end, dt)
        report.rhs_evaluations += 1
        return new, report


ORACLES = {"implicit": CouplingImplicitOracle, "implicit-linear": CouplingImplicitLinearOracle,
           "rosenbrock": CouplingRosenbrockOracle}
"""Coupling names → oracle classes."""
