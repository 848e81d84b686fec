"""Time steppers of a hydraulic network behind one interface.

Every stepper advances a :class:`~hydraulics.network.NetworkState` over ``dt``
given the controls and the motion of the actuators during the step
(:class:`ActuatorMotion`), which the mechanics (a 1-DOF load, MuJoCo, the XPBD
solver) supplies.  Subclasses implement ``_substep`` only; the base class owns
sub-stepping, the spool update, time, counters and the failure status (as in
scipy's ``OdeSolver`` family).

* :class:`StepperExplicitEuler` — forward Euler, order 1, conditionally stable:
  a node of volume V behind an orifice of slope G is stable only for
  h < 2V/(β·G).  Kept as the baseline the seed report used.
* :class:`StepperImplicitEuler` — backward Euler with Newton's method on the
  node oil contents and the analytic Jacobian, order 1, L-stable, in compiled
  kernels (:mod:`hydraulics._compiled`; ``NUMBA_DISABLE_JIT=1`` runs them as
  Python, and ``tests/reference/newton.py`` keeps a numpy oracle).  Also
  provides :meth:`StepperImplicitEuler.linearize`, the sensitivity of the
  actuator efforts (and of the end oil contents, ∂m⁺/∂v) to the actuator
  velocities used by implicit coupling; the linearly implicit finish built
  on it (coupling ``implicit-linear``) is described in
  :mod:`hydraulics.coupling`.  ``step(..., oil_guess=m)`` starts Newton's
  method from a prediction of the end oil (same equations and tolerance).
* :class:`StepperReference` — ``scipy.integrate.solve_ivp`` (Radau) at tight
  tolerance inside each step, for references.

Oil moves only through branch flows, so every stepper conserves the total oil
content of a closed network to round-off.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from . import _compiled
from .extras import require
from .network import BranchFlows, NetworkControl, NetworkModel, NetworkState
from .numerics import (LINE_SEARCH_HALVINGS, NEWTON_MAX_ITERATIONS, NEWTON_PRESSURE_TOLERANCE,  # noqa: F401 (documented here)
                       NEWTON_RELATIVE_TOLERANCE, SUFFICIENT_DECREASE, TRUST_FRACTION, TRUST_PRESSURE)

REFERENCE_RTOL = 1e-10  # solve_ivp relative tolerance of StepperReference
REFERENCE_PRESSURE_ATOL = 1e-3  # Pa, absolute tolerance expressed in pressure


class StepStatus(enum.Enum):
    """Outcome of a step."""

    SUCCESS = "success"
    NEWTON_FAILED = "Newton's method did not converge; reduce dt or add hydraulic substeps"
    NONFINITE = "a pressure became NaN or infinite; the step size is beyond the stepper's stability limit"


@dataclass
class ActuatorMotion:
    """Motion of the actuators over one step (all shape (actuator_count,)).

    Cylinder positions are rod extensions [m] and velocities [m/s]; motor
    positions are shaft angles [rad] and velocities [rad/s].  Explicit steppers
    use the start values, implicit ones the end values.
    """

    position_start: np.ndarray
    position_end: np.ndarray
    velocity_start: np.ndarray
    velocity_end: np.ndarray

    @classmethod
    def held(cls, position, velocity=None) -> "ActuatorMotion":
        """Actuators held at ``position`` (or moving at a constant ``velocity`` whose displacement the caller ignores)."""
        position = np.asarray(position, float)
        velocity = np.zeros_like(position) if velocity is None else np.asarray(velocity, float)
        return cls(position, position, velocity, velocity)

    @classmethod
    def linear(cls, position_start, velocity, dt) -> "ActuatorMotion":
        """Constant velocity [m/s or rad/s] over ``dt`` [s] from ``position_start``."""
        position_start = np.asarray(position_start, float)
        velocity = np.asarray(velocity, float)
        return cls(position_start, position_start + dt * velocity, velocity, velocity)

    def at(self, fraction: float) -> tuple:
        """Linearly interpolated (position, velocity) at ``fraction`` ∈ [0, 1] of the step."""
        return (
            self.position_start + fraction * (self.position_end - self.position_start),
            self.velocity_start + fraction * (self.velocity_end - self.velocity_start),
        )

    def hermite(self, fraction: float, dt: float) -> tuple:
        """Cubic Hermite (position, velocity) at ``fraction`` of a step of ``dt`` [s]: exact for cubic motions."""
        s = fraction
        x0, x1, v0, v1 = self.position_start, self.position_end, self.velocity_start * dt, self.velocity_end * dt
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
        return h00 * x0 + h10 * v0 + h01 * x1 + h11 * v1, (d00 * x0 + d10 * v0 + d01 * x1 + d11 * v1) / dt

    def part(self, k: int, count: int) -> "ActuatorMotion":
        """Motion over substep ``k`` of ``count``."""
        x0, v0 = self.at(k / count)
        x1, v1 = self.at((k + 1) / count)
        return ActuatorMotion(x0, x1, v0, v1)


@dataclass
class StepReport:
    """What a step did: status, message, work counters and end-of-step branch flows [m³/s]."""

    status: StepStatus = StepStatus.SUCCESS
    message: str = ""
    newton_iterations: int = 0
    rhs_evaluations: int = 0
    jacobian_evaluations: int = 0
    residual: float = 0.0
    branch_flow: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def success(self) -> bool:
        return self.status is StepStatus.SUCCESS

    def absorb(self, other: "StepReport") -> None:
        """Accumulate the counters of a substep and keep its status and flows."""
        self.newton_iterations += other.newton_iterations
        self.rhs_evaluations += other.rhs_evaluations
        self.jacobian_evaluations += other.jacobian_evaluations
        self.residual = max(self.residual, other.residual)
        self.branch_flow = other.branch_flow
        if not other.success:
            self.status, self.message = other.status, other.message


@dataclass(frozen=True)
class Linearization:
    """Actuator effort as an affine function of the end-of-step actuator velocities.

    effort(v) ≈ ``effort`` + ``effort_velocity_gradient`` @ (v − ``velocity``),
    m⁺(v) ≈ ``state.node_oil`` + ``oil_velocity_gradient`` @ (v − ``velocity``).
    """

    velocity: np.ndarray  # (actuator_count,) where the step was linearised
    effort: np.ndarray  # (actuator_count,) [N or N·m]
    effort_velocity_gradient: np.ndarray  # (actuator_count, actuator_count) [N·s/m ...]
    state: NetworkState  # the predicted end-of-step state at ``velocity``
    report: StepReport
    # (node_count, actuator_count) [m³·s/m or m³·s/rad]: ∂m⁺/∂v of the backward-Euler step (zero rows for fixed nodes);
    # the columns of a closed network sum to zero (the flows' linearisation is conservative)
    oil_velocity_gradient: np.ndarray | None = None


class Stepper:
    """Base class: advance a network by ``dt`` in ``substeps`` equal substeps.

    Parameters
    ----------
    model : NetworkModel
        The network.
    substeps : int, keyword-only
        Number of equal substeps per call of :meth:`step` (≥ 1); the actuator
        motion is interpolated linearly across them.
    """

    name = "base"
    order = None
    implicit = False

    def __init__(self, model: NetworkModel, *, substeps: int = 1):
        if int(substeps) != substeps or substeps < 1:
            raise ValueError(f"`substeps` must be an integer >= 1, got {substeps!r}")
        self.model = model
        self.substeps = int(substeps)
        self.free = model.free_nodes
        self.rhs_count = 0
        self.jacobian_count = 0

    def step(self, state: NetworkState, control: NetworkControl, motion: ActuatorMotion, dt: float, *, oil_guess=None):
        """Advance ``state`` by ``dt`` [s]; ``state`` is not modified.

        ``oil_guess`` (optional, shape (node_count,) [m³]) is a prediction of
        the end-of-step oil contents; implicit steppers start Newton's method
        from it (substep k of S from m + (k+1)/S·(guess − m)).  It changes
        only the iterations, not the equations or the tolerance.

        Returns
        -------
        state : NetworkState
            The state at the end of the step, with the step's oil change as its
            ``node_oil_change`` (the next step's warm start).
        report : StepReport
            Status and counters; on failure the returned state is the last good
            substep's, keeping ``state``'s ``node_oil_change``, and
            ``report.message`` says what to change.
        """
        if not dt > 0:
            raise ValueError(f"`dt` must be positive, got {dt!r}")
        with np.errstate(all="ignore"):  # non-finite results are detected and reported below
            return self._step(state, control, motion, dt, oil_guess)

    def _step(self, state, control, motion, dt, oil_guess=None):
        h = dt / self.substeps
        current = state
        report = StepReport()
        for k in range(self.substeps):
            sub = motion if self.substeps == 1 else motion.part(k, self.substeps)
            guess = oil_guess
            if oil_guess is not None and self.substeps > 1:
                guess = state.node_oil + ((k + 1) / self.substeps) * (oil_guess - state.node_oil)
            new, sub_report = self._substep(current, control, sub, h) if guess is None else self._substep(
                current, control, sub, h, guess)
            report.absorb(sub_report)
            if sub_report.success and not np.all(np.isfinite(new.node_pressure)):
                bad = self.model.node_names[int(np.flatnonzero(~np.isfinite(new.node_pressure))[0])]
                report.status = StepStatus.NONFINITE
                report.message = f"pressure of node '{bad}' is not finite: {StepStatus.NONFINITE.value}"
            if not report.success:  # the last good substep, with the start's warm start (as the compiled steps keep it)
                current.node_oil_change = state.node_oil_change
                return current, report
            current = new
        current.node_oil_change = current.node_oil - state.node_oil
        return current, report

    def _spool_end(self, state, control, h):
        """Spools [-] after ``h`` [s] of τ·ds/dt = u − s with the commands u held to their ranges
        (:func:`hydraulics.components.valve_4_3.spool_step`)."""
        nv = len(self.model.valve_names)
        spool = state.valve_spool.copy()  # (then the law components' states, advanced by the step's kernel)
        spool[:nv] = _compiled.spool_steps(state.valve_spool[:nv], self.model.valve_commands(control.valve_command),
                                           self.model.valve_time_constant, h)
        return spool

    def _net_inflow(self, flows):
        return self.model.incidence @ flows.flow

    def _finish(self, state, oil, spool, motion, h, flows) -> NetworkState:
        """End-of-substep state: oil moved by the flows, pressures from the new geometry."""
        pressure, _ = self.model.pressure(oil, motion.position_end)
        return NetworkState(oil, pressure, spool, motion.position_end.copy(), motion.velocity_end.copy(), state.time + h)

    def _substep(self, state, control, motion, h):
        raise NotImplementedError


class StepperExplicitEuler(Stepper):
    """Forward Euler on the oil contents: m⁺ = m + h·ΣQ(p(m, x_start), v_start).

    Order 1.  Inputs held over the step (zero-order hold), which is what a
    weak co-simulation does: flows at the start spools, positions and
    velocities, end pressures p(m⁺, x_end), spools advanced exactly.  Rigid
    branches (rigid actuators of a compressible network) carry r(s)·v.  One
    compiled kernel (:func:`hydraulics._compiled_rigid.explicit_substep`, also
    stepped inside the fast MuJoCo plant's callback).  **Limitations**:
    unstable for stiff nodes (small volumes, large bulk modulus, large orifice
    slopes): a node of volume V behind an orifice of slope G needs h < 2V/(β·G).

    >>> stepper = make_stepper("explicit_euler", model)  # doctest: +SKIP
    >>> state, report = stepper.step(state, control, ActuatorMotion.held(x), 1e-5)  # doctest: +SKIP
    """

    name = "explicit_euler"
    order = 1

    def __init__(self, model: NetworkModel, *, substeps: int = 1):
        super().__init__(model, substeps=substeps)
        self.packed = _compiled.pack_network(model)

    def _substep(self, state, control, motion, h, oil_guess=None):  # oil_guess: not needed (explicit)
        from . import _compiled as C
        from . import _compiled_rigid as K

        F, I = self.packed
        f64 = C._f64
        start = C.StepStart(f64(state.node_oil), f64(state.valve_spool), f64(control.valve_command),
                            f64(control.pump_speed), f64(motion.position_start), f64(motion.velocity_start))
        oil, pressure, spool, flow = K.explicit_step_entry(F, I, start, f64(motion.position_end), float(h))
        self.rhs_count += 1
        new = NetworkState(oil, pressure, spool, np.array(motion.position_end, float),
                           np.array(motion.velocity_start, float), state.time + h)
        return new, StepReport(rhs_evaluations=1, branch_flow=flow)


class StepperImplicitEuler(Stepper):
    """Backward Euler: m⁺ = m + h·ΣQ(p(m⁺, x_end), v_end), solved by Newton's method in compiled kernels.

    Order 1, L-stable: bounded for any step, bulk modulus and dead volume.  On the free nodes,

        r(m⁺) = m⁺ − m − h·ΣQ(p(m⁺, x⁺), v⁺) = 0,   J = I − h·(∂Q/∂p)·diag(∂p/∂m),

    with the analytic Jacobian (cavitating nodes have ∂p/∂m = 0: their pressure is pinned at the floor).
    Each Newton update Δ = −J⁻¹·r is cut to the trust region (a node may fill its vapour void and then move
    by at most max(TRUST_PRESSURE, TRUST_FRACTION·|p|)) and halved (at most LINE_SEARCH_HALVINGS times)
    until the residual scaled to pressure, max|r·β_eff/V| [Pa], falls by the factor 1 − SUFFICIENT_DECREASE·step.
    Converged when that norm, or the pressure change of a full update, is below
    NEWTON_PRESSURE_TOLERANCE + NEWTON_RELATIVE_TOLERANCE·max|p|; then the oil moves by the converged flows
    only, m⁺ = m + h·ΣQ (a closed network conserves oil to round-off).  References: Hairer & Wanner, *Solving
    ODEs II*, §IV.8 (Newton for implicit Runge–Kutta); Dennis & Schnabel, *Numerical Methods for
    Unconstrained Optimization*, §6.3 (backtracking).

    The network is packed once at construction (:func:`hydraulics._compiled.pack_network`, with the tuning
    constants of this module as they are then); a whole (sub)step — spool update, Newton solve, end
    pressures — or a whole linearisation is one call of a compiled kernel
    (:func:`hydraulics._compiled._step_core`, :func:`hydraulics._compiled._linearize_core`,
    :func:`hydraulics._compiled._linearize_one_step_core`), loaded from numba's disk cache (≈ 0.2 s per
    process) or compiled when the cache is cold (≈ 15–20 s, once).  ``NUMBA_DISABLE_JIT=1`` runs the same
    kernels as Python.  The Newton matrix is factored over its sparse pattern with the free nodes numbered
    hub last (:func:`hydraulics._compiled.elimination_order`: no fill-in on an arrowhead circuit;
    :func:`hydraulics._compiled.sparse_pattern`: the symbolic analysis, done once), in the operations and order of
    dense Gaussian elimination with partial pivoting, which takes over where pivoting would exchange rows.

    **Limitations**: order 1 (the step error is O(h²) per step); a failed Newton solve (after
    NEWTON_MAX_ITERATIONS) is reported, not retried with a smaller step.

    Example
    -------
    >>> from hydraulics.circuit import load_circuit                          # doctest: +SKIP
    >>> model = NetworkModel.from_circuit(load_circuit("models/boom/boom.circuit.toml"))  # doctest: +SKIP
    >>> stepper = StepperImplicitEuler(model)                                # doctest: +SKIP
    >>> state = model.state()                                                # doctest: +SKIP
    >>> state, report = stepper.step(state, model.control(), ActuatorMotion.held(state.actuator_position), 1e-3)  # doctest: +SKIP
    """

    name = "implicit_euler"
    order = 1
    implicit = True

    def __init__(self, model: NetworkModel, *, substeps: int = 1):
        super().__init__(model, substeps=substeps)
        self._F, self._I = _compiled.pack_network(model)

    def _make_report(self, istats, norm, flow) -> StepReport:
        C = _compiled
        report = StepReport(
            newton_iterations=int(istats[C.IS_NEWTON]),
            rhs_evaluations=int(istats[C.IS_RHS]),
            jacobian_evaluations=int(istats[C.IS_JAC]),
            residual=float(norm),
            branch_flow=flow,
        )
        if istats[C.IS_STATUS] != C._OK:
            worst = self.model.node_names[int(istats[C.IS_WORST])] if istats[C.IS_WORST] >= 0 else "?"
            report.status = StepStatus.NEWTON_FAILED
            report.message = f"{StepStatus.NEWTON_FAILED.value} (worst node '{worst}', residual {norm:.3g} Pa)"
        self.rhs_count += report.rhs_evaluations
        self.jacobian_count += report.jacobian_evaluations
        return report

    def _substep(self, state, control, motion, h, oil_guess=None):
        f64 = _compiled._f64
        oil0 = f64(state.node_oil)
        oil, pressure, spool, flow, _, istats, norm = _compiled._step_kernel(
            self._F, self._I, oil0, f64(state.valve_spool), f64(control.valve_command),
            f64(control.pump_speed), f64(motion.position_end), f64(motion.velocity_end), float(h), True,
            oil0 if oil_guess is None else f64(oil_guess),
        )
        report = self._make_report(istats, norm, flow)
        new = NetworkState(oil, pressure, spool, np.array(motion.position_end, float), np.array(motion.velocity_end, float),
                           state.time + h)
        return new, report

    def _solve(self, state, control, position, velocity, spool, h, oil_guess=None):
        """Newton solve of the backward-Euler oil balance at the end ``position``, ``velocity`` and ``spool`` from
        ``oil_guess`` (default: the start contents); returns (oil [m³], :class:`BranchFlows`, report)."""
        C = _compiled
        oil0 = C._f64(state.node_oil)
        oil, _, _, flow, dflow, istats, norm = C._step_kernel(
            self._F, self._I, oil0, C._f64(spool), C._f64(control.valve_command), C._f64(control.pump_speed),
            C._f64(position), C._f64(velocity), float(h), False, oil0 if oil_guess is None else C._f64(oil_guess),
        )
        flows = BranchFlows(flow, dflow[:, C.T_FROM].copy(), dflow[:, C.T_TO].copy(), dflow[:, C.T_PILOT].copy())
        return oil, flows, self._make_report(istats, norm, flow)

    def linearize(self, state: NetworkState, control: NetworkControl, velocity, dt: float, *,
                  newton: bool = True, oil_guess=None) -> Linearization:
        """Predict one backward-Euler step with end velocities ``velocity`` and differentiate the efforts.

        The actuators are assumed to end at x = x_state + dt·v.  Returns the
        efforts at ``velocity`` and ∂effort/∂v (pressure part through the
        network, including the oil-column stiffness h·β·A²/V and valve terms,
        plus the friction slope), and ∂m⁺/∂v = −J⁻¹·∂r/∂v,
        ∂r/∂v = −dt·((∂Q/∂p)·dt·∂p/∂x + ∂Q/∂v).

        ``newton=False`` is the **Rosenbrock–Euler (W-method) linearisation**: no Newton
        iteration, one step of it from the start oil m, the residual at x = x₀ + dt·v linearised
        about the start of the step (m, x₀), p₀ = p(m, x₀):

            J·[Δ | ∂m/∂v] = [dt·ΣQ(p₀, v) + dt·(∂Q/∂p)·(dt·∂p/∂x)·v | −∂r/∂v],   J = I − dt·(∂Q/∂p)·diag(∂p/∂m),
            m_lin = m + Δ,   p_lin = p₀ + (∂p/∂m)·Δ + (dt·∂p/∂x)·v,

        one elimination for the prediction and its velocity gradient; the efforts and
        ∂effort/∂v are those of the linear prediction.  Order 1 like backward Euler
        (it is backward Euler with the flows linearised about the start of the step), and
        L-stable on the linear oil column; the predicted oil of a closed network is
        conserved to round-off (1ᵀ·(I − dt·J) = 1ᵀ when every flow leaves one node and
        enters another).  Where Δ leaves the Newton solve's trust region (a pressure would
        move by more than max(TRUST_PRESSURE, TRUST_FRACTION·|p|) outside a vapour void: a
        pump filling a small volume past its relief's cracking pressure in one step, a
        valve slam), where the prediction puts a relief, check valve or pump compensator on
        another piece of its law (:meth:`NetworkModel.law_pieces`: a kink the start's Jacobian
        does not see), or where the matrix is singular, the step is solved by Newton instead
        (``newton=True``), whose line search handles such a switch.

        ``oil_guess`` (shape (node_count,) [m³]) is where the Newton solve starts (default: the
        start oil); like :meth:`step`'s, it changes only the iterations.  Raises
        ``numpy.linalg.LinAlgError`` where the Newton-solved step's matrix is singular.
        """
        C = _compiled
        velocity = C._f64(np.asarray(velocity, float).reshape(self.model.actuator_count))
        oil0 = C._f64(state.node_oil)
        oil, pressure, spool, position, flow, istats, norm, effort, gradient, doil = C._linearize_kernel(
            self._F, self._I, oil0, C._f64(state.valve_spool), C._f64(control.valve_command),
            C._f64(control.pump_speed), C._f64(state.actuator_position), velocity, float(dt), bool(newton),
            oil0 if oil_guess is None else C._f64(oil_guess),
        )
        report = self._make_report(istats, norm, flow)
        if istats[C.IS_SINGULAR]:
            raise np.linalg.LinAlgError("Matrix is singular.")
        predicted = NetworkState(oil, pressure, spool, position, velocity.copy(), state.time + dt)
        return Linearization(velocity.copy(), effort, gradient, predicted, report, doil)

    def linearize_at_guess(self, state: NetworkState, control: NetworkControl, velocity_guess, dt: float, *,
                           newton: bool = True, oil_warm=None) -> Linearization:
        """:meth:`linearize` at the implicit couplings' velocity guess, guarded (one compiled call,
        :func:`hydraulics._compiled._linearize_at_guess`).

        The guess [m/s or rad/s] is first clipped so that x + dt·v stays inside each cylinder's stroke.  Where it
        moves an actuator, Newton starts from ``oil_warm`` [m³] (e.g. the secant prediction; None: the start
        oil) and, if that linearisation is not usable (not converged, singular, or not finite), again from the
        start oil; if still not usable (an unresolved oscillation can make x + dt·v empty a chamber) the
        step is linearised at the held actuators (guess 0, clipped) instead.  The returned ``velocity`` is the
        guess used.  Raises ``numpy.linalg.LinAlgError`` where the last linearisation is singular.
        """
        C = _compiled
        oil0 = C._f64(state.node_oil)
        guess = C._f64(np.asarray(velocity_guess, float).reshape(self.model.actuator_count))
        oil, pressure, spool, position, flow, istats, effort, gradient, doil, used, norm = C.linearize_at_guess_kernel(
            self._F, self._I, oil0, C._f64(state.valve_spool), C._f64(control.valve_command),
            C._f64(control.pump_speed), C._f64(state.actuator_position), guess, float(dt), bool(newton),
            oil0 if oil_warm is None else C._f64(oil_warm),
        )
        report = self._make_report(istats, norm, flow)
        if istats[C.IS_SINGULAR]:
            raise np.linalg.LinAlgError("Matrix is singular.")
        predicted = NetworkState(oil, pressure, spool, position, used.copy(), state.time + dt)
        return Linearization(used, effort, gradient, predicted, report, doil)


class StepperReference(Stepper):
    """``solve_ivp`` (Radau, rtol 1e-10) on ṁ = ΣQ within each step, with the analytic Jacobian.

    The actuator motion is a cubic Hermite interpolant of the end positions and
    velocities (exact for motions up to cubic in time), and the spool
    follows its exact first-order response.  Order: set by the tolerance (not
    by dt).  Use for references and tests, not for real time.
    """

    name = "reference"
    order = None
    implicit = True

    def __init__(self, model: NetworkModel, *, substeps: int = 1):
        require("scipy.integrate", "tools", "the 'reference' stepper")  # when the run is built, not at its first step
        refuse_component_states(model, "the 'reference' stepper")
        super().__init__(model, substeps=substeps)

    def _substep(self, state, control, motion, h, oil_guess=None):  # oil_guess: not used (solve_ivp)
        m = self.model
        free = self.free
        tau = m.valve_time_constant
        oil = state.node_oil.copy()
        report = StepReport()

        def spool_at(t):
            return _compiled.spool_steps(state.valve_spool, m.valve_commands(control.valve_command), tau, t) if t > 0 else state.valve_spool

        def evaluate(t, y):
            x, v = motion.hermite(t / h, h)
            oil[free] = y
            pressure, dpdm = m.pressure(oil, x)
            flows = m.branch_flows(pressure, m.valve_areas(spool_at(t)), control.pump_speed, v)
            return flows, dpdm

        def rhs(t, y):
            report.rhs_evaluations += 1
            return self._net_inflow(evaluate(t, y)[0])[free]

        def jac(t, y):
            report.jacobian_evaluations += 1
            flows, dpdm = evaluate(t, y)
            return m.flow_jacobian(flows)[np.ix_(free, free)] * dpdm[free][None, :]

        if len(free):
            x0, _ = motion.at(0.0)
            volume, _ = m.node_volume_at(x0, state.node_pressure)
            beta = m.effective_bulk_modulus(state.node_pressure, x0)
            atol = (REFERENCE_PRESSURE_ATOL * volume / beta)[free]
            # (here: scipy.integrate costs ~0.35 s of every start-up, and scipy comes with the [tools] extra)
            solve_ivp = require("scipy.integrate", "tools", "the 'reference' stepper").solve_ivp

            sol = solve_ivp(rhs, (0.0, h), state.node_oil[free], method="Radau", jac=jac, rtol=REFERENCE_RTOL, atol=atol)
            if not sol.success:
                report.status = StepStatus.NEWTON_FAILED
                report.message = f"solve_ivp failed: {sol.message}"
                return state, report
            oil[free] = sol.y[:, -1]
        flows, _ = evaluate(h, oil[free]) if len(free) else (None, None)
        spool_end = spool_at(h)
        if flows is None:
            flows = m.branch_flows(state.node_pressure, m.valve_areas(spool_end), control.pump_speed, motion.velocity_end)
        report.branch_flow = flows.flow
        return self._finish(state, oil, spool_end, motion, h, flows), report


def refuse_component_states(model: NetworkModel, what: str) -> None:
    """Raise :class:`ValueError` when ``model`` has components with states of their own (``what`` integrates the
    valves' spools only)."""
    own = model.component_state_names[len(model.valve_names):]
    if own:
        raise ValueError(f"{what} integrates no component states; the circuit has {list(own)} (use the implicit "
                         "stepper with a small step as the reference)")


STEPPERS = {cls.name: cls for cls in (StepperExplicitEuler, StepperImplicitEuler, StepperReference)}
"""Stable names → stepper classes; any :class:`Stepper` subclass is accepted too."""


def make_stepper(name_or_class, model: NetworkModel, **options) -> Stepper:
    """Instantiate a stepper from its registry name (:data:`STEPPERS`) or class; ``options`` go to its constructor.

    Example: ``make_stepper("implicit_euler", model, substeps=2)``.
    """
    if isinstance(name_or_class, str):
        if name_or_class not in STEPPERS:
            raise ValueError(f"unknown stepper {name_or_class!r}; choose from {sorted(STEPPERS)}")
        name_or_class = STEPPERS[name_or_class]
    return name_or_class(model, **options)
