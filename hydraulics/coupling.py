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
    own prediction).  The linearisation's own Newton solve starts from the
    secant prediction m + (m − m_prev) of the state's last oil change
    (``NetworkState.node_oil_change``, :func:`secant_oil_guess`; error O(h²)
    where the oil moves smoothly, against O(h) for m itself) wherever the
    velocity guess moves an actuator; again only the iterations change.  Over
    the first 2 s at 1 ms it cuts them from 2.17 to 0.92 per step on the boom
    and from 1.79 to 0.90 on the excavator (``tests/test_warm_start.py``).
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
``rosenbrock``
    Rosenbrock–Euler (W-method) throughout: ``implicit-linear`` whose
    linearisation takes one Newton step instead of solving backward Euler,
    the residual at x_g = x + h·v_g linearised about the start of the step
    (m, x), p₀ = p(m, x):

        J·[Δ | ∂m/∂v] = [h·ΣQ(p₀, v_g) + h·(∂Q/∂p)·(h·∂p/∂x)·v_g | −∂r/∂v],
        J = I − h·(∂Q/∂p)·diag(∂p/∂m),   m_lin = m + Δ;

    the effort law is taken at the linear prediction
    p_lin = p₀ + (∂p/∂m)·Δ + (h·∂p/∂x)·v_g and the finish is
    ``implicit-linear``'s.  No nonlinear solve in the step: one Jacobian, one
    elimination (for Δ and ∂m/∂v together) and two pressure evaluations
    (start, end); one in MuJoCo mode, whose plants end the step at the actuator
    positions MuJoCo integrated to (``position_end``; x + h·v⁺ differs from
    them by O(h²)), so the end pressures are the next step's p₀
    (:meth:`sim.plants.mujoco.MujocoPlant.end_position`; the bodies move as
    with either end, the law not depending on it).  Order 1; L-stable on the
    linear oil column; oil of a closed network conserved to round-off.  A step whose update leaves the
    Newton trust region, or that puts a relief, check valve or pump
    compensator on another piece of its law (:meth:`NetworkModel.law_pieces`),
    is solved by Newton instead (:meth:`StepperImplicitEuler.linearize`); so is a
    finish whose end pressures are not finite, put such a branch on another piece
    of its law than the start of the step, or leave a backward-Euler residual worth
    more than max(1 bar, 1 % of p) of pressure: ``implicit``'s Newton finish from the
    prediction m⁺ (:meth:`CouplingRosenbrock.finish`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _compiled
from .network import NetworkControl, NetworkModel, NetworkState
from .numerics import GUESS_VOLUME_FRACTION  # noqa: F401 (documented here)
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
    ``effective_mass`` [kg] the inertia the actuator sees (1/(J·M⁻¹·Jᵀ)), ``dt`` [s] the step
    (the compiled law: :func:`hydraulics._compiled._blend_factor`).

    Example: ``blend_factor([-4e6], [1e3], 1e-3)`` → w = 4, θ = 0.5.
    """
    slope = _compiled._f64(np.asarray(stiffness_slope, float).ravel())
    mass = _compiled._f64(np.broadcast_to(np.asarray(effective_mass, float), np.shape(stiffness_slope)).ravel())
    return _compiled.blend_factor_kernel(slope, mass, float(dt)).reshape(np.shape(stiffness_slope))


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
        effort, _ = self.model.actuator_effort(state.node_pressure, np.asarray(velocity, float), np.asarray(position, float))
        return EffortLaw(effort, np.zeros_like(effort))

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        motion = ActuatorMotion.linear(state.actuator_position, velocity_start, dt)
        return self.stepper.step(state, control, motion, dt)




def start_velocity_guess(model: NetworkModel, position, velocity, dt: float) -> np.ndarray:
    """``velocity_guess`` from the start-of-step velocities [m/s or rad/s]: v, or 0 for a cylinder whose guessed
    displacement dt·|v| [m] would change a chamber volume by more than :data:`GUESS_VOLUME_FRACTION`
    (the compiled rule: :func:`hydraulics._compiled._short_chord_guess`)."""
    F, I = _compiled.packed(model)
    return _compiled.start_velocity_guess_kernel(F, I, _compiled._f64(position), _compiled._f64(velocity), float(dt))


def secant_oil_guess(state: NetworkState):
    """Where the implicit couplings start a step's linearisation Newton solve [m³]: the secant prediction
    m + (m − m_prev) = ``node_oil + node_oil_change`` (error O(h²) where the oil moves smoothly, against O(h) for
    the start oil itself), or None (start from the start oil) for a state without a last step
    (:func:`hydraulics._compiled._secant_oil_guess`, which the compiled steps call on
    :meth:`NetworkState.flat_oil_change`)."""
    if state.node_oil_change is None:
        return None
    return _compiled.secant_oil_guess_kernel(_compiled._f64(state.node_oil), _compiled._f64(state.node_oil_change))


# How an implicit coupling linearises and finishes its step (``CouplingImplicit.scheme``; the compiled coupled
# steps of both plants branch on it): Newton linearisation and Newton finish (implicit), Newton linearisation and
# linear finish (implicit-linear), one-Newton-step linearisation and linear finish (rosenbrock).
SCHEMES = ("newton", "linear_finish", "rosenbrock")
SCHEME_NEWTON, SCHEME_LINEAR_FINISH, SCHEME_ROSENBROCK = range(len(SCHEMES))


class CouplingImplicit(Coupling):
    """Linearly implicit coupling through :meth:`StepperImplicitEuler.linearize_at_guess` (see module docstring).

    Example
    -------
    >>> coupling = make_coupling("implicit", model)                           # doctest: +SKIP
    >>> law = coupling.begin(state, control, x, v, 1e-3, effective_mass=m_eff)  # doctest: +SKIP
    >>> # ... the plant steps with effort = law.constant + law.slope·v⁺ ...
    >>> state, report = coupling.finish(state, control, x, x_end, v, v_end, 1e-3)  # doctest: +SKIP
    """

    name = "implicit"
    newton = True  # the linearisation solves its backward-Euler step by Newton (False: one Newton step, ``rosenbrock``)
    scheme = SCHEME_NEWTON

    def __init__(self, model, stepper):
        super().__init__(model, stepper)
        # the linearisation is a single backward-Euler step whatever the finishing stepper
        self.predictor = stepper if isinstance(stepper, StepperImplicitEuler) else StepperImplicitEuler(model)
        self.last_linearization = None

    def begin(self, state, control, position, velocity, dt, *, effective_mass=None, velocity_guess=None):
        model = self.model
        position = np.asarray(position, float).copy()
        start_velocity = np.asarray(velocity, float)
        guess = np.zeros_like(position) if velocity_guess is None else np.array(velocity_guess, float)
        start = NetworkState(state.node_oil, state.node_pressure, state.valve_spool, position, guess, state.time)
        # Newton starts from the secant prediction where the guess moves the actuators (the compiled rule
        # _compiled._linearize_at_guess: then again from the start oil, then at the held actuators if unusable)
        lin = self.predictor.linearize_at_guess(start, control, guess, dt, newton=self.newton,
                                                oil_warm=secant_oil_guess(state))
        self.last_linearization = lin
        self._begun = (state, dt)  # finish() uses the linearisation only for this state and step
        # the state's pressures already belong to its oil at this position (PBD mode); MuJoCo's tendon
        # lengths differ from the network's x + h·v⁺ by round-off, so there they are recomputed
        same_position = np.array_equal(position, state.actuator_position)
        pressure_start = model.pressure_effort(state.node_pressure if same_position else model.pressure(state.node_oil, position)[0])
        # pressure part: backward-Euler law around the guess, blended with the start force by θ; friction
        # linearised at the start velocity with its dissipative slope only (_compiled._effort_law_terms)
        blend = effective_mass is not None
        mass = np.ones_like(position) if effective_mass is None else np.broadcast_to(np.asarray(effective_mass, float), position.shape)
        C = _compiled
        F, I = self.predictor._F, self.predictor._I
        constant, slope, theta = C.effort_law_kernel(
            F, I, C._f64(lin.velocity), C._f64(lin.state.node_pressure), C._f64(lin.state.actuator_position),
            C._f64(start_velocity),
            C._f64(lin.effort_velocity_gradient), C._f64(pressure_start), C._f64(mass), float(dt), blend)
        self.last_theta = theta
        return EffortLaw(constant, slope)

    def predicted_oil(self, state, velocity_end, dt):
        """m_lin + (∂m/∂v)·(v⁺ − v_guess) [m³] from the linearisation of this step, or None if there is none."""
        lin = self.last_linearization
        begun = getattr(self, "_begun", None)
        if lin is None or lin.oil_velocity_gradient is None or begun is None or begun[0] is not state or begun[1] != dt:
            return None
        C = _compiled
        return C.predicted_oil_kernel(C._f64(lin.state.node_oil), C._f64(lin.oil_velocity_gradient), C._f64(lin.velocity),
                                      C._f64(velocity_end))

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
    scheme = SCHEME_LINEAR_FINISH

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
            raise RuntimeError(f"coupling {self.name!r}: finish() must follow begin() for the same state and dt")
        lin = self.last_linearization
        position_end = np.asarray(position_end, float).copy()
        velocity_end = np.asarray(velocity_end, float).copy()
        spool = lin.state.valve_spool
        C = _compiled
        pressure, flow = C.linear_finish_kernel(self.predictor._F, self.predictor._I, C._f64(oil), C._f64(spool),
                                                C._f64(position_end), C._f64(velocity_end), C._f64(control.pump_speed),
                                                dt)
        report = StepReport(rhs_evaluations=1, branch_flow=flow)
        if not np.all(np.isfinite(pressure)):
            bad = m.node_names[int(np.flatnonzero(~np.isfinite(pressure))[0])]
            report.status = StepStatus.NONFINITE
            report.message = f"pressure of node '{bad}' is not finite: {StepStatus.NONFINITE.value}"
            return state, report
        return NetworkState(oil, pressure, spool.copy(), position_end, velocity_end, state.time + dt,
                            oil - state.node_oil), report


class CouplingRosenbrock(CouplingImplicitLinear):
    """``rosenbrock``: ``implicit-linear`` with the linearisation's Newton solve replaced by one Newton step.

    The effort law and the finish of ``implicit-linear``, from the Rosenbrock–Euler (W-method)
    linearisation of :meth:`StepperImplicitEuler.linearize` (``newton=False``): no nonlinear
    solve anywhere in the step, one Jacobian and one elimination per step.
    """

    name = "rosenbrock"
    newton = False
    scheme = SCHEME_ROSENBROCK

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        """The linear finish, accepted where its end pressures are finite, every switching branch is on the piece
        of its law it was on at the start of the step (:meth:`NetworkModel.law_pieces` over the step from the
        linearisation's component states) and the backward-Euler residual of the end state is worth at most
        max(LINEAR_FINISH_PRESSURE, LINEAR_FINISH_FRACTION·|p|) of pressure on every free node
        (:func:`hydraulics._compiled._linear_finish_accepted`); otherwise the step is solved by Newton from the
        prediction m⁺, as ``implicit`` finishes it (a relief cracking within the step, or a valve slam at a step
        the oil column does not resolve: the linear finish overshoots there).  The report then counts the
        rejected evaluation with Newton's."""
        lin = self.last_linearization
        start_states = None if lin is None else lin.state.valve_spool.copy()  # (the finish advances them in place)
        new, report = super().finish(state, control, position_start, position_end, velocity_start, velocity_end, dt)
        C = _compiled
        if report.status != StepStatus.NONFINITE and C.linear_finish_accepted_kernel(
                self.predictor._F, self.predictor._I, C._f64(state.node_oil), C._f64(new.node_oil),
                C._f64(state.node_pressure), C._f64(new.node_pressure), C._f64(new.actuator_position),
                C._f64(report.branch_flow), start_states, float(dt)):
            return new, report
        new, newton = CouplingImplicit.finish(self, state, control, position_start, position_end, velocity_start,
                                              velocity_end, dt)
        newton.rhs_evaluations += 1
        return new, newton


def _f64(a):
    """A C-contiguous, writeable float64 copy-or-view of ``a`` (the one type the compiled kernels are built for)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


def _masses(effective_mass, count):
    """Effective masses as the kernels take them: NaN (unknown, the tracker then takes m_eff = 1) without any."""
    return np.full(count, np.nan) if effective_mass is None else _f64(np.broadcast_to(effective_mass, (count,)))


def derive_chamber_pressures(model: NetworkModel, effort, pressure, actuators, *, packed=None) -> None:
    """Write into ``pressure`` [Pa] the chamber (motor port) pressures of the masked ``actuators`` that carry
    ``effort`` [N or N·m] with rigid oil: the loaded side at p_ref + |effort|/area, the other at p_ref
    (:func:`hydraulics._compiled_rigid.chamber_pressures`).  ``packed``: the model's packed (F, I), when the
    caller keeps them.

    >>> derive_chamber_pressures(model, effort, pressure, model.actuator_rigid)  # doctest: +SKIP
    """
    from . import _compiled_rigid as K

    F, I = packed if packed is not None else _compiled.pack_network(model)
    out = _f64(pressure)
    K.chamber_pressures_entry(F, I, _f64(effort), out, np.ascontiguousarray(actuators, np.int64))
    pressure[...] = out


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
    share of the pumps' delivery is tracked at that share.  End stops: a cylinder
    that could reach an end of its stroke within the step (start or target speed
    times ``STOP_REACH`` = 2) tracks its target clipped to [−x/h, (stroke − x)/h],
    so rigid oil holds the rod at its end (the pump flow goes over the relief)
    against loads within the force bounds.  The effort is bounded
    by the highest relief setting (``EffortLaw.lower/upper``; the plant clamps
    within its step, so the actuator stalls there).  Logged pressures are derived
    from the force.  The equations are compiled once, in
    :func:`hydraulics._compiled_rigid.incompressible_law` and
    :func:`hydraulics._compiled_rigid.incompressible_finish` (the fast MuJoCo plant
    calls them inside its step too).  **Limitations**: no oil-column compliance (no
    pressure peaks or oscillation), no leakage, energy terms of the network are not
    computed.

    >>> coupling = make_coupling("incompressible", model)  # doctest: +SKIP
    >>> law = coupling.begin(state, control, x, v, 1e-3, effective_mass=m_eff)  # doctest: +SKIP
    """

    name = "incompressible"

    def __init__(self, model, stepper=None):
        from . import _compiled_rigid as K

        super().__init__(model, stepper)
        self.packed = _compiled.pack_network(model)
        self.table = K.pack_incompressible(model)
        self.edges = self.table.edges  # per actuator: orifice branches (columns K.EDGE_COLUMNS)
        self.supply_pressure = float(self.table.scalars[K.IS_SUPPLY])
        self.force_lower, self.force_upper = self.table.force_lower, self.table.force_upper

    def law(self, spool0, command, pump_speed, position, velocity, effective_mass, dt):
        """End spools [-] of the step and its effort law (see class docstring), from the start spools ``spool0`` and
        the actuators' start positions [m | rad] and velocities."""
        from . import _compiled_rigid as K

        F, I = self.packed
        velocity = _f64(velocity)
        spool, constant, slope, lower, upper = K.incompressible_law_entry(
            F, I, self.table, _f64(spool0), _f64(command), _f64(pump_speed), _f64(position), velocity,
            _masses(effective_mass, len(velocity)), float(dt))
        return spool, EffortLaw(constant, slope, lower, upper)

    def begin(self, state, control, position, velocity, dt, *, effective_mass=None, velocity_guess=None):
        self._spool, self._law = self.law(state.valve_spool, control.valve_command, control.pump_speed, position,
                                          velocity, effective_mass, dt)
        return self._law

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        from . import _compiled_rigid as K

        m, law = self.model, self._law
        F, I = self.packed
        position_end, velocity_end = _f64(position_end), _f64(velocity_end)
        _, pressure, oil = K.incompressible_finish_entry(F, I, law.constant, law.slope, law.lower, law.upper,
                                                         velocity_end, position_end)
        new = NetworkState(oil, pressure, self._spool, position_end.copy(), velocity_end.copy(), state.time + dt)
        return new, StepReport(branch_flow=np.zeros(len(m.branch_names)))


class CouplingMixed(Coupling):
    """Rigid (``incompressible``) actuators on a compressible network, around any other coupling (``inner``).

    The network (:meth:`NetworkModel.from_circuit` with some actuators ``incompressible``) has no
    pressure states on a rigid actuator's chambers; a rigid branch P → T of its valve carries the
    flow its rod displaces, Q = r(spool)·v (:meth:`NetworkModel.rigid_rates`), so the supply it
    shares with the compressible actuators sees every drop of its demand.  The compressible
    actuators get the ``inner`` coupling's law unchanged.  A rigid actuator's law is the metered
    rigid-oil force of :func:`hydraulics._compiled_rigid.metered_force` with the *live* supply
    pressure p_P instead of a fixed setting, plus its seal friction:

        F(v⁺) = d·(p_P(v⁺)·A_in − p_T·A_out) − R·v⁺·|v⁺| + F_friction(v⁺),

    with p_P(v⁺) = p_P,lin + (∂p_P/∂v)·(v⁺ − v_g) from the inner coupling's backward-Euler
    linearisation (so the supply's oil column, −h·β·A_in²/V_P in the slope, is implicit; θ = 1),
    or the start pressure for the explicit inner coupling.  A closed spool (or a rigid actuator
    without a valve) locks the actuator with the stiff velocity tracker of
    :class:`CouplingIncompressible`; the effort is bounded by the highest relief setting on its
    areas.  The flow share of the pumps needs no rule here: an over-demanded supply loses pressure.
    Logged chamber pressures of rigid actuators are derived from their effort
    (:func:`derive_chamber_pressures`).  The law is compiled once
    (:func:`hydraulics._compiled_rigid.mixed_law`).

    >>> coupling = make_coupling("implicit", model_with_rigid_actuators)  # doctest: +SKIP
    >>> coupling.name
    'implicit+rigid'
    """

    name = "mixed"

    def __init__(self, model, inner: Coupling):
        from . import _compiled_rigid as K

        super().__init__(model, inner.stepper)
        self.inner = inner
        self.name = f"{inner.name}+rigid"
        self.rigid = np.asarray(model.actuator_rigid, bool)
        self.packed = _compiled.pack_network(model)
        self.table = K.pack_rigid(model)
        self.supply_node = self.table.supply
        self.force_lower, self.force_upper = self.table.force_lower, self.table.force_upper
        self.blend = True  # pass effective masses to the inner coupling's θ-rule (the PBD plant turns this off)
        self.last_theta = np.ones(model.actuator_count)

    def _supply(self, state, control, dt):
        """Supply pressure p_P [Pa] of every rigid branch at the linearisation's velocities, its gradient
        ∂p_P/∂v of the branch's own actuator [Pa·s/m], and those velocities."""
        m = self.model
        lin = getattr(self.inner, "last_linearization", None)
        a = m.rigid_branch_actuator
        if lin is None or lin.oil_velocity_gradient is None:  # explicit inner coupling: the start pressure
            return _f64(state.node_pressure[self.supply_node]), np.zeros(len(a)), np.zeros(len(a))
        _, dpdm = m.pressure(lin.state.node_oil, lin.state.actuator_position)
        gradient = dpdm[self.supply_node] * lin.oil_velocity_gradient[self.supply_node, a]
        return _f64(lin.state.node_pressure[self.supply_node]), _f64(gradient), _f64(lin.velocity[a])

    def begin(self, state, control, position, velocity, dt, *, effective_mass=None, velocity_guess=None):
        from . import _compiled_rigid as K

        m = self.model
        if velocity_guess is None:
            # the rigid actuators' supply pressure is linearised about this guess: at the held actuators a supply
            # that an overrunning load drains to its cavitation floor would be extrapolated far below it
            velocity_guess = start_velocity_guess(m, position, velocity, dt)
        law = self.inner.begin(state, control, position, velocity, dt,
                               effective_mass=effective_mass if self.blend else None, velocity_guess=velocity_guess)
        self.last_theta = np.where(self.rigid, 1.0, getattr(self.inner, "last_theta", np.ones(m.actuator_count)))
        velocity = _f64(velocity)
        F, I = self.packed
        constant, slope, lower, upper = K.mixed_law_entry(
            F, I, self.table, _f64(state.valve_spool), _f64(control.valve_command), velocity,
            _masses(effective_mass, len(velocity)), float(dt), self._supply(state, control, dt),
            _f64(law.constant).copy(), _f64(law.slope).copy())
        self._law = EffortLaw(constant, slope, lower, upper)
        return self._law

    def finish(self, state, control, position_start, position_end, velocity_start, velocity_end, dt):
        new, report = self.inner.finish(state, control, position_start, position_end, velocity_start, velocity_end, dt)
        effort = np.clip(self._law(np.asarray(velocity_end, float)), self._law.lower, self._law.upper)
        hydraulic = effort - self.model.friction_effort(np.asarray(velocity_end, float))[0]
        new = new.copy()
        derive_chamber_pressures(self.model, hydraulic, new.node_pressure, self.rigid, packed=self.packed)
        return new, report


COUPLINGS = {
    "explicit": CouplingExplicit, "implicit": CouplingImplicit, "implicit-linear": CouplingImplicitLinear,
    "rosenbrock": CouplingRosenbrock, "incompressible": CouplingIncompressible,
}
"""Coupling names → classes."""

DEFAULT_STEPPER = {
    "explicit": "explicit_euler", "implicit": "implicit_euler", "implicit-linear": "implicit_euler",
    "rosenbrock": "implicit_euler", "incompressible": "implicit_euler",
}
"""The hydraulic stepper each coupling uses unless told otherwise."""


def make_coupling(name: str, model: NetworkModel, *, stepper=None, substeps: int = 1) -> Coupling:
    """Build a coupling scheme with its finishing stepper (default per :data:`DEFAULT_STEPPER`).

    A network with rigid actuators (``incompressible`` among compressible ones) gets the named
    coupling wrapped in :class:`CouplingMixed`.  Example: ``make_coupling("rosenbrock", model)``.
    """
    if name not in COUPLINGS:
        raise ValueError(f"unknown coupling {name!r}; choose from {sorted(COUPLINGS)}")
    stepper = make_stepper(stepper or DEFAULT_STEPPER[name], model, substeps=substeps)
    coupling = COUPLINGS[name](model, stepper)
    if name != "incompressible" and np.any(model.actuator_rigid):
        return CouplingMixed(model, coupling)
    return coupling


__all__ = ["EffortLaw", "Coupling", "CouplingExplicit", "CouplingImplicit", "CouplingImplicitLinear", "CouplingMixed",
           "CouplingRosenbrock", "COUPLINGS",
           "make_coupling", "start_velocity_guess", "StepReport"]
