"""The network's side of the PBD plant's compiled steps: each coupling's begin and finish per XPBD substep.

Per XPBD substep the compiled frame (:mod:`sim.plants.pbd_frame`) calls :func:`_begin_core` (the effort law
c + s·v⁺ of every actuator and its bounds) before the position solve and :func:`_finish_core` (the network's step
with the realised motion, and the energy ledger ``PlantBase._account``) after it, on the buffers of
:class:`NetworkBuffers`.  The couplings (:func:`coupling_kind`), each the kernels of :mod:`hydraulics._compiled`
and :mod:`hydraulics._compiled_rigid` that the fast MuJoCo plant's callback calls too:

* ``implicit`` (PBD mode's default) and its linear variants ``implicit-linear`` and ``rosenbrock`` (finish
  m⁺ = m_lin + (∂m/∂v)·(v⁺ − v_guess), ``_compiled._linear_finish``; rosenbrock also linearises by one Newton
  step) with the implicit-Euler stepper: θ = 1 or, with the plant's ``blend`` (scenario ``pbd_blend``), the θ-rule
  from the articulated effective masses; linearised at the substep's start velocities where their chord is short
  (``coupling.start_velocity_guess``, as MuJoCo mode; else at the held actuators), clipped into the stroke;
* ``explicit`` with the explicit-Euler stepper (and the seed's ``pbd-naive``): the start pressures' effort held,
  the network advanced by forward Euler from its own positions at the start velocities;
* the ``incompressible`` fidelity: the bounded metered law, pressures derived from the applied effort;
* rigid actuators in a compressible network around the first two (``CouplingMixed``).

One hydraulic substep per XPBD substep.  Any other stepper (the ``reference`` stepper, a coupling with another
stepper than its own) keeps the plant's Python hooks (:func:`eligible`).  Same equations and Newton iterations as
the Python couplings; the compiled steps agree with the Python hooks to round-off (``tests/test_pbd_fast.py``).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from hydraulics import _compiled as C
from hydraulics import _compiled_rigid as K
from hydraulics.coupling import (SCHEME_NEWTON, SCHEME_ROSENBROCK, CouplingExplicit, CouplingImplicit,
                                 CouplingIncompressible, CouplingMixed)
from hydraulics.fluid import potential_quadrature
from hydraulics.layout import Layout
from hydraulics.network import NetworkState
from hydraulics.steppers import StepperExplicitEuler, StepperImplicitEuler, StepReport, StepStatus

try:  # pragma: no branch
    import numba

    _NUMBA = C.compiled_available()
except ImportError:  # pragma: no cover
    _NUMBA = False

TOTALS = ("newton", "rhs", "jac", "status", "worst", "last_ok")
"""The frame's int counters (istats, indices ``I_*``) after _compiled's per-call entries (``C.ISTATS``): the step's
totals and failure."""
(I_NEWTON, I_RHS, I_JAC, I_STATUS, I_WORST, I_LAST_OK) = range(C.NIS, C.NIS + len(TOTALS))
NI = C.NIS + len(TOTALS)
LEDGER = ("pump", "motor", "diss_h", "diss_f", "residual", "fail_norm")
"""The float ledger (indices ``L_*``): pump work, motor work, hydraulic and friction dissipation [J] (the first four
in C._account's order), residual max, failing residual [Pa]."""
(L_PUMP, L_MOTOR, L_DISS_H, L_DISS_F, L_RESIDUAL, L_FAIL_NORM) = range(len(LEDGER))
NL = len(LEDGER)
STATUSES = ("ok", "newton", "nonfinite", "singular")
"""The step's outcome (``ST_*``)."""
ST_OK, ST_NEWTON, ST_NONFINITE, ST_SINGULAR = range(len(STATUSES))
KINDS = ("implicit", "explicit", "incompressible")
"""The coupling the compiled steps take (``KIND_*``, :func:`coupling_kind`)."""
KIND_IMPLICIT, KIND_EXPLICIT, KIND_INCOMPRESSIBLE = range(len(KINDS))

# The network's buffers for the compiled steps, made once per plant (:class:`NetworkBuffers`); n nodes,
# na actuators, nb branches, nvalve valves.
HydraulicBuffers = namedtuple("HydraulicBuffers", [
    "F", "I",  # the packed network (``StepperImplicitEuler``'s float64 and int64 arrays)
    "W",  # the kernels' scratch (``_compiled.work_size``)
    "keep",  # views of the float64 buffer that persists between begin and finish (:data:`KEEP`), carved once
    "istats",  # int counters, (NI,) (``I_*``)
    "ledger",  # energy ledger [J] and residuals [Pa], (NL,) (``L_*``)
    "quad",  # the fluid's potential quadrature (``hydraulics.fluid.potential_quadrature``)
    "oil",  # node oil [kg], (n,)
    "pressure",  # node pressure [Pa], (n,)
    "spool",  # valve spool position [-], (nvalve,)
    "position",  # actuator position [m or rad], (na,)
    "velocity",  # actuator velocity [m/s or rad/s], (na,)
    "flow",  # branch flow of the last substep [m³/s], (nb,)
    "constant",  # effort law constant c [N or N·m], (na,)
    "slope",  # effort law slope s [N·s/m or N·m·s/rad], (na,)
    "theta",  # θ of the last begin per actuator [-], (na,)
    "lower", "upper",  # effort bounds of the law [N or N·m] (±inf where unbounded), (na,)
    "incompressible",  # ``_compiled_rigid.IncompressibleTable`` (read by the incompressible coupling only)
    "rigid",  # ``_compiled_rigid.RigidTable`` of the rigid actuators (none: no rigid branch)
])


def coupling_kind(plant):
    """The ``KIND_*`` of the plant's coupling when the compiled steps reproduce it, else None: the implicit
    couplings with the compiled implicit-Euler stepper as their predictor, the explicit coupling with the
    explicit-Euler stepper (PBD mode's ``explicit`` and the seed's ``pbd-naive``), either with rigid actuators around
    it (``CouplingMixed``), and the ``incompressible`` fidelity; one hydraulic substep per XPBD substep."""
    coupling = plant.coupling
    inner = coupling.inner if type(coupling) is CouplingMixed else coupling
    stepper = getattr(coupling, "stepper", None)
    if not _NUMBA or getattr(stepper, "substeps", 1) != 1:
        return None
    if isinstance(inner, CouplingImplicit) and isinstance(stepper, StepperImplicitEuler) and inner.predictor is stepper:
        return KIND_IMPLICIT
    if type(inner) is CouplingExplicit and type(stepper) is StepperExplicitEuler:
        return KIND_EXPLICIT
    if type(coupling) is CouplingIncompressible:
        return KIND_INCOMPRESSIBLE
    return None


def eligible(plant) -> bool:
    """True when the plant's coupling is one the compiled steps reproduce (:func:`coupling_kind`)."""
    return coupling_kind(plant) is not None


if _NUMBA:
    def _kernel(function):
        return numba.njit(error_model="numpy", nogil=True, _nrt=False)(function)
else:  # pragma: no cover
    def _kernel(function):
        return function


KEEP = Layout("keep", ("n", "na", "nb", "nvalve"), (
    # the last substep's oil change [m³] (NetworkState.node_oil_change, the next substep's warm start; persists
    # across substeps and steps: NetworkBuffers.load / store move it)
    (("oil_change", "n"),)
    # what begin leaves for finish
    + C.LINEARIZATION_KEPT
    # begin's temporaries: effort-law terms per actuator, the linearisation's pressures and first-evaluation
    # pressures [Pa], effort gradient, positions, flows, warm-start oil
    + (("fg", "na"), ("fsg", "na"), ("end_const", "na"), ("end_slope", "na"), ("friction", "na"), ("damping", "na"),
       ("pressure_start", "na"), ("lin_p", "n"), ("p_first", "n"), ("gradient", "na", "na"), ("lin_x", "na"),
       ("lin_flow", "nb"), ("oil_warm", "n"))
    # finish's temporaries: predicted, end and start oil, end pressures, ledger temporaries; actuator temporaries;
    # flows and their terminal derivatives; end states
    + (("mpred", "n"), ("o2", "n"), ("p2", "n"), ("mu", "n"), ("start", "n"), ("dv", "na"), ("fric", "na"),
       ("xs", "na"), ("xb", "na"), ("xe", "na"), ("dflow", "nb", C._W_BR), ("fl", "nb"), ("sp2", "nvalve"))))
"""The float64 buffer S of the compiled steps (n nodes, na actuators, nb branches, nvalve component states)."""

KeepViews = KEEP.View
"""The views of :data:`KEEP` (``HydraulicBuffers.keep``), carved once per plant and carried into the compiled steps.
Bound here by name, so that the kernel cache can pickle the signatures of the kernels that take them."""
KeepViews.__module__ = __name__


def keep_size(n, na, nb, nvalve):
    """Length of the float64 buffer S: :data:`KEEP`."""
    return KEEP.size(n=n, na=na, nb=nb, nvalve=nvalve)


def work_size(F, I, n, na, nb, nr):
    """Length of the float64 scratch W for ``n`` nodes, ``na`` actuators, ``nb`` branches and ``nr`` rigid branches
    (``_compiled_rigid.coupled_work_size`` over the Newton kernels' ``_compiled.work_size``)."""
    return K.coupled_work_size(C.work_size(F, I), n, na, nb, nr)


@_kernel
def _begin_core(pnet, buffers, control, x, v, h, coupling, effective_mass):
    """The effort law c + s·v⁺ of every actuator for a substep of ``h`` [s] from the actuator positions ``x`` and
    velocities ``v`` (``buffers.constant``, ``buffers.slope``, bounds ``buffers.lower``/``upper``, θ per actuator
    ``buffers.theta``) on the ``HydraulicBuffers`` ``buffers``; returns False if singular.  ``control`` = (valve
    commands, pump speeds); ``coupling`` = (``KIND_*``, the implicit coupling's ``hydraulics.coupling.SCHEME_*``,
    blend): by kind

    * implicit: CouplingImplicit.begin at the start velocities ``v`` as the velocity guess
      (``start_velocity_guess``); rosenbrock linearises by one Newton step; with ``blend`` θ from
      ``effective_mass`` [kg or kg·m²] (``blend_factor``, the start force from the state's pressures, which belong
      to its oil at ``x``), else θ = 1;
    * explicit: CouplingExplicit.begin (:func:`hydraulics._compiled_rigid.explicit_law`), θ = 1;
    * incompressible: CouplingIncompressible.begin (:func:`hydraulics._compiled_rigid.incompressible_law` at the
      end spools, kept for the finish), θ = 1;

    and around the first two CouplingMixed.begin for the rigid actuators (``rigid_law``; NaN effective masses:
    unknown)."""
    W, ws, istats, oil, pres, spool = buffers.W, buffers.keep, buffers.istats, buffers.oil, buffers.pressure, buffers.spool
    const, slope, theta, lower, upper = buffers.constant, buffers.slope, buffers.theta, buffers.lower, buffers.upper
    cmd, speed = control
    kind, scheme, blend = coupling
    R = buffers.rigid
    oil_change, guess, lin_oil, lin_spool, doil = ws.oil_change, ws.guess, ws.lin_oil, ws.lin_spool, ws.doil
    if kind == KIND_INCOMPRESSIBLE:
        C._spool_end(pnet, spool, cmd, h, lin_spool)
        K.incompressible_law(pnet, buffers.incompressible, lin_spool, speed, (x, v), effective_mass, h,
                             W[:C._area_count(C._deref(pnet).ic)], (const, slope), (lower, upper))
        theta[:] = 1.0
        return True
    if kind == KIND_EXPLICIT:
        K.explicit_law(pnet, pres, x, v, (const, slope), W)
        theta[:] = 1.0
        if R.actuator.size:  # the rigid actuators' law at the start supply pressure
            K.rigid_law(pnet, R, spool, cmd, v, effective_mass, h, (pres, oil, x, doil, x), False, (const, slope),
                        (lower, upper), theta, W)
        return True
    fg, fsg, end_const, end_slope, friction = ws.fg, ws.fsg, ws.end_const, ws.end_slope, ws.friction
    damping, pressure_start, lin_p, p_first, gradient = ws.damping, ws.pressure_start, ws.lin_p, ws.p_first, ws.gradient
    lin_x, lin_flow, oil_warm = ws.lin_x, ws.lin_flow, ws.oil_warm
    C._secant_oil_guess(oil, oil_change, oil_warm)
    effort_end = fg  # overwritten by the guess's friction below
    # linearised at the start velocities where their chord is short (coupling.start_velocity_guess), kept inside the
    # stroke, else at the held actuators
    C._linearize_at_start_velocity(scheme != SCHEME_ROSENBROCK, pnet, W, C.StepStart(oil, spool, cmd, speed, x, v), h, guess,
                                   C.LinearizationOut(lin_oil, lin_p, lin_spool, lin_x, lin_flow, istats, effort_end,
                                                      gradient, p_first, doil), oil_warm)
    if istats[C.IS_SINGULAR]:
        return False
    C._effort_law_terms(pnet, guess, lin_p, lin_x, v, gradient, fg, fsg, end_const, end_slope, friction, damping)
    C._pressure_effort(pnet, pres, pressure_start)
    C._blended_law(blend, end_const, end_slope, pressure_start, friction, damping, v, effective_mass, h, theta, const,
                   slope)
    if R.actuator.size:  # the rigid actuators' law at the linearisation's supply pressure
        K.rigid_law(pnet, R, spool, cmd, v, effective_mass, h, (lin_p, lin_oil, lin_x, doil, guess), True,
                    (const, slope), (lower, upper), theta, W)
    return True


@_kernel
def _finish_core(pnet, buffers, control, motion, h, coupling, effort):
    """The network's step over the substep with the realised ``motion`` = (end positions, end velocities, start
    velocities) of the actuators, by the ``coupling`` (``KIND_*``, scheme, blend) of :func:`_begin_core`:
    CouplingImplicit.finish (``SCHEME_NEWTON``: backward Euler, Newton from the linearisation's predicted oil) or
    CouplingImplicitLinear.finish (the linear finishes), CouplingExplicit.finish (forward Euler from the network's own
    positions at the held start velocities) or CouplingIncompressible.finish (pressures and oil from the bounded
    effort), CouplingMixed.finish's rigid chamber pressures, then PlantBase._account with the applied ``effort``
    [N or N·m] (the rigid actuators' term).  On success the state arrays (oil, pressure, spool, position, velocity)
    become the end of the substep; counters and failure in ``istats``, ledger terms in ``ledger``, the branch
    flows in ``flow``."""
    W, ws, istats, ledger, quad = buffers.W, buffers.keep, buffers.istats, buffers.ledger, buffers.quad
    oil, pres, spool, pos, vel, flow = (buffers.oil, buffers.pressure, buffers.spool, buffers.position, buffers.velocity,
                                        buffers.flow)
    const, slope, lower, upper, R = buffers.constant, buffers.slope, buffers.lower, buffers.upper, buffers.rigid
    cmd, speed = control
    x_end, v_end, v_start = motion
    kind, scheme = coupling[0], coupling[1]
    n, na = oil.size, pos.size
    oil_change, guess, lin_oil, lin_spool, doil = ws.oil_change, ws.guess, ws.lin_oil, ws.lin_spool, ws.doil
    mpred, o2, p2, mu, start = ws.mpred, ws.o2, ws.p2, ws.mu, ws.start
    dv, fric, xs, xb, xe = ws.dv, ws.fric, ws.xs, ws.xb, ws.xe
    dflow, fl, sp2 = ws.dflow, ws.fl, ws.sp2  # dflow: branches × terminals
    C._copy(start, oil)
    norm = 0.0
    istats[I_LAST_OK] = 0
    bad = -1
    if kind == KIND_INCOMPRESSIBLE:
        K.incompressible_finish(pnet, const, slope, lower, upper, v_end, x_end, W[:n], dv, pres, oil)
        C._copy(spool, lin_spool)
        C._copy(pos, x_end)
        C._copy(vel, v_end)
        flow[:] = 0.0
    elif kind == KIND_EXPLICIT:
        bad, rhs = K.explicit_finish(pnet, W, (oil, pres, spool, pos, vel), flow, v_start, control, h, 1,
                                     (o2, p2, sp2, fl, dflow, istats[:I_NEWTON], xs, xb, xe))
        istats[I_RHS] += rhs
    else:
        C._predicted_oil(lin_oil, doil, guess, v_end, dv, mpred)
        newton = scheme == SCHEME_NEWTON
        if not newton:  # m⁺ = the prediction, at the linearisation's spools
            C._copy(o2, mpred)
            C._copy(sp2, lin_spool)
            istats[I_RHS] += 1
            if scheme == SCHEME_ROSENBROCK:  # accepted (CouplingRosenbrock.finish), else Newton from m⁺ below
                end, _ = C._linear_finish_scratch(W, 0, n, C._area_count(C._deref(pnet).ic))
                C._pressure(pnet, mpred, x_end, end.geo, p2, end.dpdm)
                C._valve_areas(pnet, sp2, end.area)
                C._branch_flows(pnet, p2, end.area, speed, v_end, fl, dflow, sp2, h)
                newton = not C._linear_finish_accepted(pnet, oil, mpred, pres, p2, end.dpdm, fl, mu, sp2, h)
                if not newton:
                    C._law_states_end(pnet, sp2, h, p2)
            else:
                C._linear_finish(pnet, W, mpred, sp2, x_end, v_end, speed, p2, fl, dflow, h)
            istats[C.IS_STATUS] = C._OK
        if newton:
            norm = C._step_core(pnet, W, C.StepStart(oil, spool, cmd, speed, x_end, v_end), h, True,
                                C.StepOut(o2, p2, sp2, fl, dflow, istats), mpred)
            istats[I_NEWTON] += istats[C.IS_NEWTON]
            istats[I_RHS] += istats[C.IS_RHS]
            istats[I_JAC] += istats[C.IS_JAC]
        if norm > ledger[L_RESIDUAL]:
            ledger[L_RESIDUAL] = norm
        C._copy(flow, fl)
        if istats[C.IS_STATUS] != C._OK:
            istats[I_STATUS], istats[I_WORST] = ST_NEWTON, istats[C.IS_WORST]
            ledger[L_FAIL_NORM] = norm
            bad = -2
        else:
            bad = C._commit_if_finite(oil, pres, spool, pos, vel, o2, p2, sp2, x_end, v_end)
    if bad >= 0:
        istats[I_STATUS], istats[I_WORST] = ST_NONFINITE, bad
    elif bad == -1:
        istats[I_LAST_OK] = 1
        for i in range(n):  # (none from the incompressible coupling: it has no oil states)
            oil_change[i] = oil[i] - start[i] if kind != KIND_INCOMPRESSIBLE else 0.0
        if R.actuator.size:  # CouplingMixed.finish: rigid chambers carry the clamped effort less friction
            K.rigid_finish(pnet, R, (const, slope), (lower, upper), v_end, pres, W[:3 * na])
    # energy ledger (PlantBase._account, energy.branch_powers) at the state's pressures
    if kind == KIND_INCOMPRESSIBLE:  # rigid oil: the efforts' work is the supplied work
        C._account_rigid_oil(ledger, L_PUMP, h, effort, v_end)
    else:
        C._account(pnet, ledger, L_PUMP, h, pres, pos, flow, v_end, quad, mu, fric, dv)
    if R.actuator.size:
        K.rigid_account(pnet, R, ledger, L_PUMP, h, flow, mu, effort, fric, v_end)


def _f64(a):
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


class NetworkBuffers:
    """The network's side of the PBD plant's compiled steps: its buffers (``HydraulicBuffers``), moved from and to
    the plant's ``net_state`` and ``energy`` around each block of steps (see module docstring).

    Usage: :meth:`load` (from ``plant.net_state`` / ``plant.energy``), the compiled steps
    (``sim.plants.pbd_block``), then :meth:`store` (back to ``net_state``, ``energy`` and the last step's
    :class:`StepReport`).
    """

    def __init__(self, plant):
        net = plant.network
        coupling = plant.coupling
        self.kind = kind = coupling_kind(plant)
        inner = coupling.inner if type(coupling) is CouplingMixed else coupling
        stepper = coupling.stepper
        self.network = net
        if kind == KIND_IMPLICIT:
            self._F, self._I = stepper._F, stepper._I
        elif kind == KIND_EXPLICIT:
            self._F, self._I = stepper.packed
        else:
            self._F, self._I = coupling.packed
        n, na = net.node_count, net.actuator_count
        nb, nvalve = len(net.branch_names), net.component_state_count  # (the component states: spools first)
        rigid = K.pack_rigid(net)
        self._W = np.zeros(work_size(self._F, self._I, n, na, nb, len(rigid.actuator)))
        self._S = np.zeros(keep_size(n, na, nb, nvalve))
        self._keep = KEEP.views(self._S, n=n, na=na, nb=nb, nvalve=nvalve)
        self._istats = np.zeros(NI, np.int64)
        self._ledger = np.zeros(NL)
        self._quad = potential_quadrature()
        self.oil, self.pressure, self.spool = np.zeros(n), np.zeros(n), np.zeros(nvalve)
        self.position, self.velocity = np.zeros(na), np.zeros(na)
        self.flow = np.zeros(nb)
        self.constant, self.slope = np.zeros(na), np.zeros(na)
        self.lower, self.upper = np.full(na, -np.inf), np.full(na, np.inf)
        self.theta = np.ones(na)  # the last begin's θ per actuator
        self.blend = bool(plant.blend)  # θ from the articulated effective masses (else θ = 1)
        self.scheme = inner.scheme if kind == KIND_IMPLICIT else SCHEME_NEWTON  # hydraulics.coupling.SCHEME_*
        table = coupling.table if kind == KIND_INCOMPRESSIBLE else K.pack_incompressible(net)
        self.buffers = HydraulicBuffers(self._F, self._I, self._W, self._keep, self._istats, self._ledger, self._quad,
                                        self.oil, self.pressure, self.spool, self.position, self.velocity, self.flow,
                                        self.constant, self.slope, self.theta, self.lower, self.upper, table, rigid)
        self._time = 0.0

    def load(self, state: NetworkState, energy) -> None:
        """Start a step from ``state`` and the ledger ``energy``."""
        self.oil[:] = state.node_oil
        self.pressure[:] = state.node_pressure
        self.spool[:] = state.valve_spool
        self.position[:] = state.actuator_position
        self.velocity[:] = state.actuator_velocity
        self._oil_change()[:] = state.flat_oil_change()
        self._time = float(state.time)
        self._istats[:] = 0
        self._istats[I_WORST] = -1
        L = self._ledger
        L[L_PUMP], L[L_MOTOR] = energy.pump_work, energy.motor_work
        L[L_DISS_H], L[L_DISS_F] = energy.dissipated_hydraulic, energy.dissipated_friction
        L[L_RESIDUAL] = L[L_FAIL_NORM] = 0.0

    def store(self, energy) -> tuple[NetworkState, StepReport]:
        """The network state after the step, the step's report; the ledger written back to ``energy``."""
        L = self._ledger
        energy.pump_work, energy.motor_work = float(L[L_PUMP]), float(L[L_MOTOR])
        energy.dissipated_hydraulic, energy.dissipated_friction = float(L[L_DISS_H]), float(L[L_DISS_F])
        s = self._istats
        report = StepReport(newton_iterations=int(s[I_NEWTON]), rhs_evaluations=int(s[I_RHS]),
                            jacobian_evaluations=int(s[I_JAC]), residual=float(L[L_RESIDUAL]), branch_flow=self.flow.copy())
        names = self.network.node_names
        if s[I_STATUS] == ST_NEWTON:
            worst = names[int(s[I_WORST])] if s[I_WORST] >= 0 else "?"
            report.status = StepStatus.NEWTON_FAILED
            report.message = f"{StepStatus.NEWTON_FAILED.value} (worst node '{worst}', residual {L[L_FAIL_NORM]:.3g} Pa)"
        elif s[I_STATUS] == ST_NONFINITE:
            report.status = StepStatus.NONFINITE
            report.message = f"pressure of node '{names[int(s[I_WORST])]}' is not finite: {StepStatus.NONFINITE.value}"
        state = NetworkState(self.oil.copy(), self.pressure.copy(), self.spool.copy(), self.position.copy(),
                             self.velocity.copy(), self._time, self._oil_change().copy())
        return state, report

    def _oil_change(self) -> np.ndarray:
        """The view of S holding the last substep's oil change [m³] (:data:`KEEP`)."""
        return self._keep.oil_change
