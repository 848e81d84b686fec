"""Backward-Euler Newton solve and its linearisations in numpy: the oracle of the compiled stepper.

:class:`StepperImplicitEulerOracle` solves the same equations as
:class:`hydraulics.steppers.StepperImplicitEuler` with the same Newton logic, trust region, line
search, tolerances and iteration limits (read from :mod:`hydraulics.numerics` at call time), written
with the vectorised :class:`~hydraulics.network.NetworkModel` methods and LAPACK solves instead of the
compiled kernels on the packed network.  The tests compare the two step by step, to round-off.

Backward Euler on the node oil contents m (free nodes):

    r(m⁺) = m⁺ − m − h·ΣQ(p(m⁺, x⁺), v⁺) = 0,   J = ∂r/∂m⁺ = I − h·(∂Q/∂p)·diag(∂p/∂m),

Newton updates Δ = −J⁻¹·r, each cut to the trust region (:meth:`_trust_step`) and then halved until the
max-norm of the residual scaled to pressure (β_eff/V per node, :meth:`_pressure_scale`) falls by the
sufficient-decrease factor.  Converged when that norm, or the last full update's pressure change, is below
NEWTON_PRESSURE_TOLERANCE + NEWTON_RELATIVE_TOLERANCE·max|p|.  The oil is then moved by the converged flows
only, m⁺ = m + h·ΣQ, so a closed network conserves oil to round-off.

Example
-------
>>> oracle = StepperImplicitEulerOracle(model)            # doctest: +SKIP
>>> state, report = oracle.step(state, control, ActuatorMotion.held(x), 1e-3)  # doctest: +SKIP
"""

from __future__ import annotations

import numpy as np

from hydraulics import numerics
from hydraulics.network import NetworkState
from hydraulics.steppers import Linearization, Stepper, StepReport, StepStatus


class StepperImplicitEulerOracle(Stepper):
    """Backward Euler m⁺ = m + h·ΣQ(p(m⁺, x_end), v_end) by Newton's method, in numpy (see module docstring).

    Order 1, L-stable.  **Limitations**: slow (vectorised numpy per Newton iteration); for tests only.
    """

    name = "implicit_euler_oracle"
    order = 1
    implicit = True

    def _solve(self, state, control, position, velocity, spool, h, oil_guess=None):
        """Newton solve of the backward-Euler oil balance from ``oil_guess`` (default: the start contents);
        returns (oil, flows, report)."""
        m = self.model
        free = self.free
        areas = m.valve_areas(spool)
        oil0 = state.node_oil
        oil = oil0.copy() if oil_guess is None else np.array(oil_guess, float)
        report = StepReport()

        def evaluate(oil):
            pressure, dpdm = m.pressure(oil, position)
            flows = m.branch_flows(pressure, areas, control.pump_speed, velocity)
            residual = oil[free] - oil0[free] - h * self._net_inflow(flows)[free]
            report.rhs_evaluations += 1
            return pressure, dpdm, flows, residual

        pressure, dpdm, flows, residual = evaluate(oil)
        scale = self._pressure_scale(position, pressure)
        norm = np.max(np.abs(residual * scale), initial=0.0)

        def tolerance(pressure):
            return numerics.NEWTON_PRESSURE_TOLERANCE + numerics.NEWTON_RELATIVE_TOLERANCE * np.max(
                np.abs(pressure[free]), initial=0.0)

        converged = not len(free) or norm < tolerance(pressure)
        halvings = numerics.LINE_SEARCH_HALVINGS
        for iteration in range(numerics.NEWTON_MAX_ITERATIONS):
            if converged:
                break
            jq = m.flow_jacobian(flows)[np.ix_(free, free)]
            jacobian = np.eye(len(free)) - h * jq * dpdm[free][None, :]
            report.jacobian_evaluations += 1
            try:
                delta = np.linalg.solve(jacobian, -residual)
            except (np.linalg.LinAlgError, ValueError):
                break
            report.newton_iterations += 1
            step = self._trust_step(oil, delta, position, pressure)
            for halving in range(halvings):
                trial = oil.copy()
                trial[free] += step * delta
                t_pressure, t_dpdm, t_flows, t_residual = evaluate(trial)
                t_norm = np.max(np.abs(t_residual * scale))
                if np.isfinite(t_norm) and (t_norm <= (1.0 - numerics.SUFFICIENT_DECREASE * step) * norm
                                            or halving == halvings - 1):
                    break
                step *= 0.5
            full = step == 1.0
            change = np.max(np.abs(t_pressure[free] - pressure[free]), initial=0.0)
            oil, pressure, dpdm, flows, residual, norm = trial, t_pressure, t_dpdm, t_flows, t_residual, t_norm
            converged = norm < tolerance(pressure) or (change < tolerance(pressure) and full)
        report.residual = float(norm)
        if not converged:
            worst = self.model.node_names[int(free[np.argmax(np.abs(residual * scale))])] if len(free) else "?"
            report.status = StepStatus.NEWTON_FAILED
            report.message = f"{StepStatus.NEWTON_FAILED.value} (worst node '{worst}', residual {norm:.3g} Pa)"
        # Oil moves only by the converged flows: exact conservation whatever the tolerance.
        oil = oil0.copy()
        oil[free] += h * self._net_inflow(flows)[free]
        report.branch_flow = flows.flow
        self.rhs_count += report.rhs_evaluations
        self.jacobian_count += report.jacobian_evaluations
        return oil, flows, report

    def _trust_step(self, oil, delta, position, pressure):
        """Largest fraction ≤ 1 of the Newton update that keeps every node inside the trust region: a node may
        fill its vapour void and then change by at most max(TRUST_PRESSURE, TRUST_FRACTION·|p|) [Pa]."""
        m = self.model
        free = self.free
        fluid = m.fluid
        volume, _ = m.node_volume_at(position, pressure)
        phi_floor = fluid.fill_ratio(max(fluid.pressure_floor, -fluid.bulk_modulus))[0]
        void = np.maximum(volume[free] * phi_floor - oil[free], 0.0)
        allowed = void + volume[free] * np.maximum(numerics.TRUST_PRESSURE, numerics.TRUST_FRACTION * np.abs(pressure[free])) / (
            m.effective_bulk_modulus(pressure, position)[free]
        )
        with np.errstate(divide="ignore"):
            ratio = np.where(np.abs(delta) > 0, allowed / np.abs(delta), np.inf)
        return float(min(1.0, np.min(ratio, initial=np.inf)))

    def _pressure_scale(self, position, pressure):
        """β_eff/V of each free node [Pa/m³]: converts an oil residual to a pressure."""
        m = self.model
        volume, _ = m.node_volume_at(position, pressure)
        beta = m.effective_bulk_modulus(pressure, position)
        return beta[self.free] / volume[self.free]

    def _substep(self, state, control, motion, h, oil_guess=None):
        spool_end = self._spool_end(state, control, h)
        oil, flows, report = self._solve(state, control, motion.position_end, motion.velocity_end, spool_end, h, oil_guess)
        return self._finish(state, oil, spool_end, motion, h, flows), report

    def linearize(self, state: NetworkState, control, velocity, dt: float, *, newton: bool = True,
                  oil_guess=None) -> Linearization:
        """The oracle of :meth:`hydraulics.steppers.StepperImplicitEuler.linearize` (same equations; see there):
        backward Euler at x = x_state + dt·v solved by Newton (``newton``) or one Newton step about the start
        of the step (Rosenbrock–Euler, ``newton=False``, falling back to Newton where the step leaves the trust
        region, crosses a kink of a valve law or meets a singular matrix), differentiated in v."""
        m = self.model
        free = self.free
        velocity = np.asarray(velocity, float)
        position = state.actuator_position + dt * velocity
        spool = self._spool_end(state, control, dt)
        areas = m.valve_areas(spool)
        # where the Jacobian is taken: the end of the Newton solve, or the start of the step (one step)
        at = position if newton else state.actuator_position
        if newton:
            oil, _, report = self._solve(state, control, position, velocity, spool, dt, oil_guess)
            pressure, dpdm = m.pressure(oil, position)
            flows = m.branch_flows(pressure, areas, control.pump_speed, velocity)
        else:
            oil = state.node_oil.copy()
            pressure, dpdm = m.pressure(oil, at)
            flows = m.branch_flows(pressure, areas, control.pump_speed, velocity)
            report = StepReport(newton_iterations=1 if len(free) else 0, rhs_evaluations=1, jacobian_evaluations=1,
                                branch_flow=flows.flow)
            self.rhs_count += 1
            self.jacobian_count += 1
        phi, _ = m.fluid.fill_ratio(pressure)
        # ∂p/∂x at fixed oil: −φ·∂V/∂x·∂p/∂m
        dpdx = -(dpdm * phi)[:, None] * m.volume_position_gradient(at)
        jq = m.flow_jacobian(flows)
        drdv = -dt * (jq @ (dt * dpdx) + m.flow_velocity_gradient(areas))[free]
        jacobian = np.eye(len(free)) - dt * jq[np.ix_(free, free)] * dpdm[free][None, :]
        dpdv = dt * dpdx
        oil_gradient = np.zeros((len(oil), m.actuator_count))
        if len(free):
            if newton:
                columns = -drdv
            else:  # dt·ΣQ(p₀, v) + dt·(∂Q/∂p)·(dt·∂p/∂x)·v
                shift = dt * (jq @ (dt * dpdx))[free] @ velocity
                columns = np.column_stack([dt * self._net_inflow(flows)[free] + shift, -drdv])
            try:
                solution = np.linalg.solve(jacobian, columns)
            except np.linalg.LinAlgError:
                if newton:
                    raise
                return self.linearize(state, control, velocity, dt, newton=True, oil_guess=oil_guess)
            if not newton:
                delta, solution = solution[:, 0], solution[:, 1:]
                if self._trust_step(oil, delta, at, pressure) < 1.0:
                    return self.linearize(state, control, velocity, dt, newton=True, oil_guess=oil_guess)
                start = pressure
                oil[free] += delta
                pressure = pressure + dt * dpdx @ velocity
                pressure[free] += dpdm[free] * delta
                if not np.array_equal(m.law_pieces(start), m.law_pieces(pressure)):  # a kink of a valve law crossed
                    return self.linearize(state, control, velocity, dt, newton=True, oil_guess=oil_guess)
            dpdv[free] += dpdm[free][:, None] * solution
            oil_gradient[free] = solution
        effort, friction_slope = m.actuator_effort(pressure, velocity)
        gradient = m.effort_pressure_gradient() @ dpdv + np.diag(friction_slope)
        predicted = NetworkState(oil, pressure, spool, position, velocity.copy(), state.time + dt)
        return Linearization(velocity.copy(), effort, gradient, predicted, report, oil_gradient)
