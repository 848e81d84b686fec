"""Compiled hydraulic hooks of the PBD plant: the implicit coupling's begin/finish and the energy ledger per substep.

:class:`sim.plants.pbd.PbdPlant` calls, per XPBD substep,
``CouplingImplicit.begin`` (the effort law c + s·v⁺ of every actuator),
``CouplingImplicit.finish`` (one backward-Euler step of the network with the
realised motion, Newton started from the linearisation's predicted oil) and
``PlantBase._account`` (pump/motor work, hydraulic and friction losses).  In
Python with :class:`~hydraulics.steppers.StepperImplicitEuler` these
cost ≈ 300 µs per substep, most of it Python and numpy call overhead.
:class:`FastHydraulics` does the same arithmetic in two numba calls per
substep with buffers allocated once, calling the allocation-free cores of
:mod:`hydraulics._compiled` (``_linearize_core``, ``_step_core``) and the
pieces of the coupled step it shares with :mod:`sim.plants.mujoco_fast`
(``_take_linearization``, ``_linearize_at_start_velocity``, ``_effort_law_terms``,
``_predicted_oil``, ``_commit_if_finite``, ``_account``).  Same
equations, same Newton iterations; the results agree with the Python hooks to
round-off (summation orders of the ledger and of the oil prediction).

Scope: the ``implicit`` coupling (PBD mode's default) and its linear variants
``implicit-linear`` and ``rosenbrock`` (finish m⁺ = m_lin + (∂m/∂v)·(v⁺ − v_guess),
``_compiled._linear_finish``; rosenbrock also linearises by one Newton step, the
``scheme`` argument) at the ``compressible`` fidelity with the compiled
implicit-Euler stepper and one hydraulic substep per XPBD substep, where θ = 1
or, with the plant's ``blend`` (scenario ``pbd_blend``), the θ-rule from the
articulated effective masses, and the linearisation is at the substep's start velocities
where their chord is short (``coupling.start_velocity_guess``, as MuJoCo mode; else at the
held actuators), clipped into the stroke.  Any other configuration keeps the Python
hooks (:func:`eligible`).

Caching: numba caches a function by its own file only, so the two entry points
carry a sha256 of this file and of the hydraulic kernel sources (``hydraulics._jit.SOURCES``, and the numba
version) as a closure variable, which is part of numba's cache key (as
:mod:`sim.plants.mujoco_fast` does); the helpers below are not cached on their
own and exist only inside the entry points.  One signature each.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from hydraulics import _compiled as C
from hydraulics.coupling import SCHEME_NEWTON, SCHEME_ROSENBROCK
from hydraulics.fluid import potential_quadrature
from hydraulics.network import NetworkState
from hydraulics.steppers import StepperImplicitEuler, StepReport, StepStatus

try:  # pragma: no branch
    import numba

    _NUMBA = C.compiled_available()
except ImportError:  # pragma: no cover
    _NUMBA = False

# int counters (istats of the frame): _compiled's 6 per-call slots, then the step's totals and failure
(I_NEWTON, I_RHS, I_JAC, I_STATUS, I_WORST, I_LAST_OK) = range(6, 12)
NI = 12
# float ledger: pump work, motor work, hydraulic and friction dissipation [J], residual max, failing residual
(L_PUMP, L_MOTOR, L_DISS_H, L_DISS_F, L_RESIDUAL, L_FAIL_NORM) = range(6)  # the first four in C._account's order
NL = 6
ST_OK, ST_NEWTON, ST_NONFINITE, ST_SINGULAR = range(4)

# The network's buffers for the compiled hooks, made once per plant (:class:`FastHydraulics`); n nodes,
# na actuators, nb branches, nvalve valves.
HydraulicBuffers = namedtuple("HydraulicBuffers", [
    "F", "I",  # the packed network (``StepperImplicitEuler``'s float64 and int64 arrays)
    "W",  # the kernels' scratch (``_compiled.work_size``)
    "S",  # what persists between begin and finish (:func:`keep_size`)
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
])


def eligible(plant) -> bool:
    """True when the plant's coupling is the one :class:`FastHydraulics` reproduces (see module docstring)."""
    from hydraulics.coupling import CouplingImplicit, CouplingImplicitLinear, CouplingRosenbrock

    coupling = plant.coupling
    stepper = getattr(coupling, "stepper", None)
    return bool(
        _NUMBA and not plant.naive and not plant.incompressible
        and type(coupling) in (CouplingImplicit, CouplingImplicitLinear, CouplingRosenbrock)
        and isinstance(stepper, StepperImplicitEuler) and stepper.substeps == 1
        and coupling.predictor is stepper
    )


if _NUMBA:
    def _kernel(function):
        return numba.njit(error_model="numpy", nogil=True, _nrt=False)(function)
else:  # pragma: no cover
    def _kernel(function):
        return function


def _begin_temporaries(n, na, nb, nvalve):
    return na * 7 + 3 * n + na * na + na + nb


def keep_size(n, na, nb, nvalve):
    """Length of the float64 buffer S: the last substep's oil change [m³] (``NetworkState.node_oil_change``, the
    next substep's warm start, which persists across substeps and steps; :meth:`FastHydraulics.load` / ``store``
    move it), what begin leaves for finish (``C._take_linearization``), then begin's and finish's temporaries."""
    return n + (na + n + nvalve + n * na) + _begin_temporaries(n, na, nb, nvalve) + (5 * n + 2 * na + (1 + C._W_BR) * nb + nvalve)


_begin_temporaries_nb = _kernel(_begin_temporaries)


@_kernel
def _kept(pnet, buffers):
    """The sizes (nodes n, actuators na, branches nb, valves nvalve) and the head of ``buffers.S`` that begin and
    finish share (see :func:`keep_size`): the last substep's oil change [m³], then what begin leaves for finish
    (``C._take_linearization``: guess, linearisation oil, spools and oil slopes); ``o`` is the offset after them."""
    ic = C._deref(pnet).ic
    n, na, nb = ic[C.IC_N], ic[C.IC_NA], ic[C.IC_NB]
    nvalve = buffers.spool.size
    oil_change, o = C._take(buffers.S, 0, n)
    guess, lin_oil, lin_spool, doil, o = C._take_linearization(buffers.S, o, n, na, nvalve)
    return n, na, nb, nvalve, oil_change, guess, lin_oil, lin_spool, doil, o


@_kernel
def _begin_core(pnet, buffers, cmd, speed, x, v, h, scheme, blend, effective_mass):
    """CouplingImplicit.begin at the start velocities ``v`` as the velocity guess (``start_velocity_guess``): the effort
    law (``buffers.constant``, ``buffers.slope``) and its θ per actuator (``buffers.theta``), on the
    ``HydraulicBuffers`` ``buffers``; returns False if singular.  ``scheme``: the coupling's ``hydraulics.coupling.SCHEME_*`` (rosenbrock linearises
    by one Newton step); ``blend``: θ from ``effective_mass`` [kg or kg·m²] (``blend_factor``, the start force
    from the state's pressures ``pres`` [Pa], which belong to ``oil`` at ``x``), else θ = 1."""
    W, S, istats, oil, pres, spool = buffers.W, buffers.S, buffers.istats, buffers.oil, buffers.pressure, buffers.spool
    const, slope, theta = buffers.constant, buffers.slope, buffers.theta
    n, na, nb, nvalve, oil_change, guess, lin_oil, lin_spool, doil, o = _kept(pnet, buffers)
    fg, o = C._take(S, o, na)
    fsg, o = C._take(S, o, na)
    end_const, o = C._take(S, o, na)
    end_slope, o = C._take(S, o, na)
    friction, o = C._take(S, o, na)
    damping, o = C._take(S, o, na)
    pressure_start, o = C._take(S, o, na)
    lin_p, o = C._take(S, o, n)
    p_first, o = C._take(S, o, n)
    g, o = C._take(S, o, na * na)
    gradient = C._matrix(g, na, na)
    lin_x, o = C._take(S, o, na)
    lin_flow, o = C._take(S, o, nb)
    oil_warm, o = C._take(S, o, n)
    C._secant_oil_guess(oil, oil_change, oil_warm)
    effort_end = fg  # overwritten by the guess's friction below
    # linearised at the start velocities where their chord is short (coupling.start_velocity_guess), kept inside the
    # stroke, else at the held actuators
    C._linearize_at_start_velocity(scheme != SCHEME_ROSENBROCK, pnet, W, C.StepStart(oil, spool, cmd, speed, x, v), h, guess,
                                   C.LinearizationOut(lin_oil, lin_p, lin_spool, lin_x, lin_flow, istats, effort_end,
                                                      gradient, p_first, doil), oil_warm)
    if istats[C.IS_SINGULAR]:
        return False
    C._effort_law_terms(pnet, guess, lin_p, v, gradient, fg, fsg, end_const, end_slope, friction, damping)
    C._pressure_effort(pnet, pres, pressure_start)
    C._blended_law(blend, end_const, end_slope, pressure_start, friction, damping, v, effective_mass, h, theta, const,
                   slope)
    return True


@_kernel
def _finish_core(pnet, buffers, cmd, speed, x_end, v_end, h, scheme):
    """CouplingImplicit.finish (``scheme`` SCHEME_NEWTON) or CouplingImplicitLinear.finish (the linear finishes)
    + PlantBase._account on the ``HydraulicBuffers`` ``buffers``: on success the state arrays (oil, pressure, spool,
    position, velocity) become the end of the substep; counters and failure in ``istats``, ledger terms in
    ``ledger``, the branch flows in ``flow``."""
    W, S, istats, ledger, quad = buffers.W, buffers.S, buffers.istats, buffers.ledger, buffers.quad
    oil, pres, spool, pos, vel, flow = (buffers.oil, buffers.pressure, buffers.spool, buffers.position, buffers.velocity,
                                        buffers.flow)
    n, na, nb, nvalve, oil_change, guess, lin_oil, lin_spool, doil, o = _kept(pnet, buffers)
    o += _begin_temporaries_nb(n, na, nb, nvalve)
    mpred, o = C._take(S, o, n)
    o2, o = C._take(S, o, n)
    p2, o = C._take(S, o, n)
    mu, o = C._take(S, o, n)
    dv, o = C._take(S, o, na)
    fric, o = C._take(S, o, na)
    dflow, o = C._take2(S, o, nb, C._W_BR)  # branches × terminals
    fl, o = C._take(S, o, nb)
    sp2, o = C._take(S, o, nvalve)
    change, o = C._take(S, o, n)
    C._predicted_oil(lin_oil, doil, guess, v_end, dv, mpred)
    if scheme == SCHEME_NEWTON:
        norm = C._step_core(pnet, W, C.StepStart(oil, spool, cmd, speed, x_end, v_end), h, True,
                            C.StepOut(o2, p2, sp2, fl, dflow, istats), mpred)
        istats[I_NEWTON] += istats[C.IS_NEWTON]
        istats[I_RHS] += istats[C.IS_RHS]
        istats[I_JAC] += istats[C.IS_JAC]
    else:  # m⁺ = the prediction, at the linearisation's spools
        C._copy(o2, mpred)
        C._copy(sp2, lin_spool)
        C._linear_finish(pnet, W, mpred, sp2, x_end, v_end, speed, p2, fl, dflow)
        norm = 0.0
        istats[C.IS_STATUS] = C._OK
        istats[I_RHS] += 1
    if norm > ledger[L_RESIDUAL]:
        ledger[L_RESIDUAL] = norm
    C._copy(flow, fl)
    istats[I_LAST_OK] = 0
    if istats[C.IS_STATUS] != C._OK:
        istats[I_STATUS], istats[I_WORST] = ST_NEWTON, istats[C.IS_WORST]
        ledger[L_FAIL_NORM] = norm
    else:
        for i in range(n):
            change[i] = o2[i] - oil[i]
        bad = C._commit_if_finite(oil, pres, spool, pos, vel, o2, p2, sp2, x_end, v_end)
        if bad >= 0:
            istats[I_STATUS], istats[I_WORST] = ST_NONFINITE, bad
        else:
            istats[I_LAST_OK] = 1
            C._copy(oil_change, change)
    # energy ledger (PlantBase._account, energy.branch_powers) at the state's pressures
    C._account(pnet, ledger, L_PUMP, h, pres, flow, v_end, quad, mu, fric, dv)


# this file and the hydraulic kernel sources (everything compiled into the entry points), taken at import: part of the
# cache key
SOURCE_SHA256 = C.source_sha256(__file__, *C.SOURCES)


def _entry_points(fingerprint):
    """The two cached entry points; ``fingerprint`` is a closure variable, hence part of numba's cache key."""

    def begin(buffers, cmd, speed, x, v, h, scheme, blend, effective_mass):
        if fingerprint is None:  # never: only makes the fingerprint a closure variable
            return False
        net = C._unpack(buffers.F, buffers.I)
        pnet = C._ref(net)
        return _begin_core(pnet, buffers, cmd, speed, x, v, h, scheme, blend, effective_mass)

    def finish(buffers, cmd, speed, x_end, v_end, h, scheme):
        if fingerprint is None:
            return
        net = C._unpack(buffers.F, buffers.I)
        pnet = C._ref(net)
        _finish_core(pnet, buffers, cmd, speed, x_end, v_end, h, scheme)

    jit = numba.njit(cache=True, error_model="numpy", nogil=True)
    return jit(begin), jit(finish)


_ENTRIES = None


def entry_points():
    """(begin, finish), compiled or loaded from numba's disk cache on first use."""
    global _ENTRIES
    if _ENTRIES is None:
        _ENTRIES = _entry_points(SOURCE_SHA256)
    return _ENTRIES


def _f64(a):
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


class FastHydraulics:
    """The PBD plant's per-substep hydraulics in compiled code (see module docstring).

    Usage per step: :meth:`load` (from ``plant.net_state`` / ``plant.energy``),
    then per substep :meth:`begin` and :meth:`finish`, then :meth:`store`
    (back to ``net_state``, ``energy`` and the step's :class:`StepReport`).
    """

    def __init__(self, plant):
        net = plant.network
        stepper = plant.coupling.stepper
        self.network = net
        self._F, self._I = stepper._F, stepper._I
        n, na = net.node_count, net.actuator_count
        nb, nvalve = len(net.branch_names), len(net.valve_names)
        self._W = np.zeros(C.work_size(self._F, self._I))
        self._S = np.zeros(keep_size(n, na, nb, nvalve))
        self._istats = np.zeros(NI, np.int64)
        self._ledger = np.zeros(NL)
        self._quad = potential_quadrature()
        self.oil, self.pressure, self.spool = np.zeros(n), np.zeros(n), np.zeros(nvalve)
        self.position, self.velocity = np.zeros(na), np.zeros(na)
        self.flow = np.zeros(nb)
        self.constant, self.slope = np.zeros(na), np.zeros(na)
        self.theta = np.ones(na)  # the last begin's θ per actuator
        self.blend = bool(plant.blend)  # θ from the articulated effective masses (else θ = 1)
        self.scheme = plant.coupling.scheme  # hydraulics.coupling.SCHEME_*
        self.buffers = HydraulicBuffers(self._F, self._I, self._W, self._S, self._istats, self._ledger, self._quad,
                                        self.oil, self.pressure, self.spool, self.position, self.velocity, self.flow,
                                        self.constant, self.slope, self.theta)
        self._begin, self._finish = entry_points()
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

    def begin(self, control, x, v, h, effective_mass=None):
        """The effort law (constant [N or N·m], slope [N·s/m or N·m·s/rad]) of this substep (arrays reused);
        θ from ``effective_mass`` [kg or kg·m², per actuator] where the plant blends (and it is given)."""
        blend = self.blend and effective_mass is not None
        meff = _f64(effective_mass) if blend else self.theta  # (not read without blend)
        ok = self._begin(self.buffers, _f64(control.valve_command), _f64(control.pump_speed), _f64(x), _f64(v), float(h),
                         self.scheme, blend, meff)
        if not ok:
            raise np.linalg.LinAlgError("Matrix is singular.")
        return self.constant, self.slope

    def finish(self, control, x_end, v_end, h) -> None:
        """Finish the substep with the realised end positions and velocities; ledger included."""
        self._finish(self.buffers, _f64(control.valve_command), _f64(control.pump_speed), _f64(x_end), _f64(v_end),
                     float(h), self.scheme)
        if self._istats[I_LAST_OK]:
            self._time += h

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
        """The view of S holding the last substep's oil change [m³] (see :func:`keep_size`)."""
        return self._S[:self.network.node_count]
