"""MuJoCo plant whose coupled step runs entirely inside ``mj_step``: :class:`MujocoPlantFast`.

Same physics as :class:`~sim.plant_mujoco.MujocoPlant` with the implicit
coupling and the compiled backward-Euler stepper, but the per-step Python
orchestration is replaced by a numba ``cfunc`` installed as MuJoCo's control
callback, so ``mj_step(m, d, nstep=N)`` advances N coupled steps in C.

MuJoCo calls the control callback once per ``mj_step``, after positions,
velocities, actuator lengths/moments and the factorised mass matrix are
computed (end of ``mj_fwdVelocity``, before ``mj_fwdActuation``) — exactly the
state :class:`MujocoPlant` sees after ``mj_step1``.  In the callback of step k:

1. finish step k−1 (if pending): v⁺ = J_{k−1}·q̇ (q̇ is now the integrated
   velocity), x⁺ = x_{k−1} + h·v⁺, the compiled backward-Euler step of the
   network (``_compiled._step_kernel``, sub-stepped as ``Stepper._step``), the
   applied effort law(v⁺) and the energy ledger (pump/motor work, hydraulic,
   friction and mechanical dissipation);
2. dense moments J_k from MuJoCo's sparse ``actuator_moment``, M⁻¹·Jᵀ by
   MuJoCo's own ``mj_solveM`` (called through its C entry point), effective
   masses and θ as :func:`hydraulics.coupling.blend_factor`;
3. the effort law of :meth:`CouplingImplicit.begin` (``_compiled._linearize_kernel``)
   written to ``ctrl`` and ``actuator_biasprm[:, 2]``.

The last step of a block is finished from Python after ``mj_step`` returns
(the same compiled function), so ``net_state``, ``effort``, ``theta``,
``energy``, ``control``, ``last_report`` and ``step_index`` are coherent after
every :meth:`MujocoPlantFast.advance`.  Operator inputs are sampled for the
block's step times in Python beforehand (piecewise-linear schedules
vectorised, callables called per step).

Results agree with :class:`MujocoPlant` to round-off (θ is exact: the
effective masses come from the same ``mj_solveM`` at the same state); the only
differences are summation orders (J·q̇, energy sums).

**Global state / limitations**

* MuJoCo's control callback is process-global.  The plant installs its
  callback only around its own ``mj_step`` call and restores the previous one
  afterwards; the callback reads its buffers through one module-level pointer
  table, so two fast plants cannot step concurrently (from two threads) in one
  process — :meth:`advance` raises if re-entered.  Any other ``mj_step``/
  ``mj_forward`` of other models in the same process during a block would be
  routed to this callback: don't.
* A hydraulic step that fails (Newton not converged, non-finite pressure)
  freezes the network at its last good state for the rest of the block and
  the plant reports the failure with ``step_index`` at the failing step, like
  :class:`MujocoPlant`; MuJoCo's bodies, however, have been integrated to the
  end of the block (with the last effort law held), so ``qpos`` may be up to
  ``n − 1`` steps ahead of ``step_index`` after a failure.
* Only the implicit coupling with the compiled implicit-Euler stepper is
  accelerated; any other configuration (explicit / incompressible coupling,
  ``compiled = false``, another stepper, no numba) falls back to
  :meth:`MujocoPlant.step` in a Python loop (``fast`` is then False).
"""

from __future__ import annotations

import ctypes
import os
import threading

import mujoco
import numpy as np

from hydraulics import _compiled as C
from hydraulics.coupling import CouplingImplicit
from hydraulics.network import NetworkState
from hydraulics.steppers import StepReport, StepStatus

from .plant_mujoco import MujocoPlant
from .scenario import Schedule

try:  # pragma: no branch
    import numba
    from numba import carray, types
    from numba.extending import intrinsic

    _NUMBA = True
except ImportError:  # pragma: no cover
    _NUMBA = False


# ----------------------------------------------------------------------------
# Pointer table layout (int64).  Sizes and counters first, then addresses.
# ----------------------------------------------------------------------------
(
    C_NA, C_NV, C_NU, C_N, C_NB, C_NVALVE, C_NPUMP, C_NBIAS, C_SUBSTEPS, C_NCYL,
    C_K, C_PENDING, C_FAILED, C_STATUS, C_WORST, C_NEWTON, C_RHS, C_JAC,
    P_F, P_I, P_ACT, P_CLOSED, P_LENGTH, P_AVEL, P_MOMENT, P_ROWADR, P_ROWNNZ, P_COLIND, P_QVEL, P_CTRL, P_BIASPRM,
    P_PASSIVE, P_CONSTRAINT, P_J, P_MINVJ, P_OIL, P_PRESSURE, P_SPOOL, P_XPOS, P_XVEL, P_CMD, P_SPEED,
    P_XSTART, P_VSTART, P_CONST, P_SLOPE, P_THETA, P_MEFF, P_EFFORT, P_FLOW, P_PASSIVE_SAVED, P_FS, P_QUAD,
    NCTX,
) = range(54)

# float scalars (P_FS): step, residual of the last step, ledger terms
FS_DT, FS_NORM, FS_PUMP, FS_MOTOR, FS_DISS_H, FS_DISS_F, FS_DISS_M, FS_NQUAD = range(8)
NFS = 8
ST_OK, ST_NEWTON, ST_NONFINITE, ST_SINGULAR = range(4)

POTENTIAL_QUADRATURE_POINTS = 16  # must match hydraulics.fluid (entrained air only)

if _NUMBA:

    @intrinsic
    def _pf64(typingctx, addr):
        sig = types.CPointer(types.float64)(addr)

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(types.CPointer(types.float64)))

        return sig, codegen

    @intrinsic
    def _pi64(typingctx, addr):
        sig = types.CPointer(types.int64)(addr)

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(types.CPointer(types.int64)))

        return sig, codegen

    @intrinsic
    def _pi32(typingctx, addr):
        sig = types.CPointer(types.int32)(addr)

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(types.CPointer(types.int32)))

        return sig, codegen

    @intrinsic
    def _pvoid(typingctx, addr):
        sig = types.voidptr(addr)

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(types.voidptr))

        return sig, codegen

    _jit = C._jit
else:  # pragma: no cover
    def _jit(f):
        return f


@_jit
def _vf(ctx, slot, n):
    return carray(_pf64(ctx[slot]), (n,))


@_jit
def _mf(ctx, slot, rows, cols):
    return carray(_pf64(ctx[slot]), (rows, cols))


@_jit
def _vi32(ctx, slot, n):
    return carray(_pi32(ctx[slot]), (n,))


@_jit
def _vi64(ctx, slot, n):
    return carray(_pi64(ctx[slot]), (n,))


@_jit
def _packed(ctx):
    ihead = carray(_pi64(ctx[P_I]), (C._NFF + C._NIF + 2,))
    ilen = ihead[C._NFF + 1 + C._NIF]
    flen = ihead[C._NFF]
    return carray(_pf64(ctx[P_F]), (flen,)), carray(_pi64(ctx[P_I]), (ilen,))


@_jit
def _pressure_effort(net, p, out):
    # NetworkModel.pressure_effort
    out[:] = 0.0
    cyl, ci, mi = net.cyl, net.cyl_i, net.mot_i
    pref = net.sc[C.S_PREF]
    for c in range(cyl.shape[0]):
        out[ci[c, C.CI_ACT]] = C.cylinder_pressure_force_nb(p[ci[c, C.CI_CAP]], p[ci[c, C.CI_ROD]], cyl[c, C.CYL_CAP_AREA],
                                                            cyl[c, C.CYL_ROD_AREA], pref)
    for i in range(mi.shape[0]):
        out[mi[i, C.MI_ACT]] = C.pump_torque_nb(net.mot[i], p[mi[i, C.MI_A]] - p[mi[i, C.MI_B]])


@_jit
def _friction_effort(net, v, effort, slope):
    # NetworkModel.friction_effort
    effort[:] = 0.0
    slope[:] = 0.0
    cyl, ci = net.cyl, net.cyl_i
    for c in range(cyl.shape[0]):
        a = ci[c, C.CI_ACT]
        f, df = C.friction_force_with_derivative_nb(v[a], cyl[c, C.CYL_COULOMB], cyl[c, C.CYL_STATIC], cyl[c, C.CYL_STRIBECK],
                                                    cyl[c, C.CYL_VISCOUS], net.sc[C.S_VREG])
        effort[a] = -f
        slope[a] = -df


@_jit
def _potential(net, p, quad):
    # Fluid.pressure_potential
    sc = net.sc
    pref, beta = sc[C.S_PREF], sc[C.S_BETA]
    if sc[C.S_AIR] == 0.0:
        return beta * -np.expm1(-(p - pref) / beta)
    nq = quad.size // 2
    half = 0.5 * (p - pref)
    mid = 0.5 * (p + pref)
    s = 0.0
    for j in range(nq):
        phi, _ = C._fill(net, mid + half * quad[j])
        s += quad[nq + j] / phi
    return half * s


@_jit
def _finish_pending(ctx):
    """Finish the pending step with the realised velocities J_prev·q̇ (MujocoPlant.step after mj_step2)."""
    if ctx[C_PENDING] == 0:
        return
    ctx[C_PENDING] = 0
    if ctx[C_FAILED] >= 0:
        return
    na, nv, n, nb = ctx[C_NA], ctx[C_NV], ctx[C_N], ctx[C_NB]
    nvalve, npump = ctx[C_NVALVE], ctx[C_NPUMP]
    k = ctx[C_K] - 1
    F, I = _packed(ctx)
    net = C._unpack(F, I)
    fs = _vf(ctx, P_FS, NFS)
    dt = fs[FS_DT]
    J = _mf(ctx, P_J, na, nv)
    qvel = _vf(ctx, P_QVEL, nv)
    xs, vs = _vf(ctx, P_XSTART, na), _vf(ctx, P_VSTART, na)
    v_end = np.empty(na)
    x_end = np.empty(na)
    for i in range(na):
        s = 0.0
        for j in range(nv):
            s += J[i, j] * qvel[j]
        v_end[i] = s
        x_end[i] = xs[i] + dt * s
    cmd = _mf(ctx, P_CMD, ctx[C_K], nvalve)[k]
    speed = _mf(ctx, P_SPEED, ctx[C_K], npump)[k]
    oil, pres, spool = _vf(ctx, P_OIL, n), _vf(ctx, P_PRESSURE, n), _vf(ctx, P_SPOOL, nvalve)
    pos, vel = _vf(ctx, P_XPOS, na), _vf(ctx, P_XVEL, na)
    flow_out = _vf(ctx, P_FLOW, nb)
    substeps = ctx[C_SUBSTEPS]
    h = dt / substeps
    newton, rhs, jac = 0, 0, 0
    residual = 0.0
    status, worst = ST_OK, -1
    xe, ve = x_end, v_end
    for s in range(substeps):
        if substeps > 1:  # ActuatorMotion.part: linear interpolation to the substep end
            frac = (s + 1) / substeps
            xe = xs + frac * (x_end - xs)
            ve = vs + frac * (v_end - vs)
        o2, p2, sp2, fl, _, _, ist, norm = C._step_kernel(F, I, oil, spool, cmd, speed, xe, ve, h, True)
        newton += ist[C.IS_NEWTON]
        rhs += ist[C.IS_RHS]
        jac += ist[C.IS_JAC]
        if norm > residual:
            residual = norm
        flow_out[:] = fl
        if ist[C.IS_STATUS] != C._OK:
            status, worst = ST_NEWTON, ist[C.IS_WORST]
            break
        bad = -1
        for i in range(n):
            if not np.isfinite(p2[i]):
                bad = i
                break
        if bad >= 0:
            status, worst = ST_NONFINITE, bad
            break
        oil[:] = o2
        pres[:] = p2
        spool[:] = sp2
        pos[:] = xe
        vel[:] = ve
    ctx[C_NEWTON], ctx[C_RHS], ctx[C_JAC] = newton, rhs, jac
    ctx[C_STATUS], ctx[C_WORST] = status, worst
    fs[FS_NORM] = residual
    if status != ST_OK:
        ctx[C_FAILED] = k
    # applied effort: law(v⁺)
    const, slope, effort = _vf(ctx, P_CONST, na), _vf(ctx, P_SLOPE, na), _vf(ctx, P_EFFORT, na)
    for i in range(na):
        effort[i] = const[i] + slope[i] * v_end[i]
    # energy ledger (PlantBase._account, MujocoPlant._account)
    quad = _vf(ctx, P_QUAD, 2 * POTENTIAL_QUADRATURE_POINTS)
    mu = np.empty(n)
    for i in range(n):
        mu[i] = _potential(net, pres[i], quad)
    ic, br = net.ic, net.br
    pump = 0.0
    for b in range(ic[C.IC_P0], ic[C.IC_P1]):
        pump += flow_out[b] * (mu[br[b, 0]] - mu[br[b, 1]])
    motor = 0.0
    for b in range(ic[C.IC_M0], ic[C.IC_M1]):
        motor += flow_out[b] * (mu[br[b, 0]] - mu[br[b, 1]])
    dissipated = 0.0
    for b in range(ic[C.IC_O0], ic[C.IC_C1]):
        dissipated += flow_out[b] * (mu[br[b, 0]] - mu[br[b, 1]])
    fs[FS_PUMP] += dt * -pump
    fs[FS_MOTOR] += dt * motor
    fs[FS_DISS_H] += dt * dissipated
    friction, fslope = np.empty(na), np.empty(na)
    _friction_effort(net, v_end, friction, fslope)
    fw = 0.0
    for i in range(na):
        fw += friction[i] * v_end[i]
    fs[FS_DISS_F] -= dt * fw
    passive, constraint = _vf(ctx, P_PASSIVE_SAVED, nv), _vf(ctx, P_CONSTRAINT, nv)
    mw = 0.0
    for j in range(nv):
        mw += (passive[j] + constraint[j]) * qvel[j]
    fs[FS_DISS_M] -= dt * mw


@_jit
def _prepare(ctx):
    """Callback part 1: finish the previous step, then the dense moments J of the current one."""
    _finish_pending(ctx)
    na, nv = ctx[C_NA], ctx[C_NV]
    J = _mf(ctx, P_J, na, nv)
    act = _vi64(ctx, P_ACT, na)
    rowadr, rownnz = _vi32(ctx, P_ROWADR, ctx[C_NU]), _vi32(ctx, P_ROWNNZ, ctx[C_NU])
    nnz_total = 0
    for a in range(ctx[C_NU]):
        nnz_total = max(nnz_total, rowadr[a] + rownnz[a])
    colind = _vi32(ctx, P_COLIND, nnz_total)
    moment = _vf(ctx, P_MOMENT, nnz_total)
    J[:, :] = 0.0
    for i in range(na):
        aid = act[i]
        adr = rowadr[aid]
        for q in range(rownnz[aid]):
            J[i, colind[adr + q]] = moment[adr + q]


@_jit
def _begin(ctx):
    """Callback part 2 (after M⁻¹·Jᵀ): the effort law of CouplingImplicit.begin, written to ctrl and biasprm."""
    k = ctx[C_K]
    ctx[C_K] = k + 1
    if ctx[C_FAILED] >= 0:
        return  # hydraulics frozen after a failed step: hold the last law
    na, nv, nu, n = ctx[C_NA], ctx[C_NV], ctx[C_NU], ctx[C_N]
    nvalve, npump = ctx[C_NVALVE], ctx[C_NPUMP]
    F, I = _packed(ctx)
    net = C._unpack(F, I)
    fs = _vf(ctx, P_FS, NFS)
    dt = fs[FS_DT]
    act = _vi64(ctx, P_ACT, na)
    closed = _vf(ctx, P_CLOSED, na)
    length, avel = _vf(ctx, P_LENGTH, nu), _vf(ctx, P_AVEL, nu)
    J, MinvJ = _mf(ctx, P_J, na, nv), _mf(ctx, P_MINVJ, na, nv)
    xs, vs = _vf(ctx, P_XSTART, na), _vf(ctx, P_VSTART, na)
    meff, theta = _vf(ctx, P_MEFF, na), _vf(ctx, P_THETA, na)
    const, slope = _vf(ctx, P_CONST, na), _vf(ctx, P_SLOPE, na)
    for i in range(na):
        xs[i] = length[act[i]] - closed[i]
        vs[i] = avel[act[i]]
        inverse = 0.0
        for j in range(nv):
            inverse += J[i, j] * MinvJ[i, j]
        meff[i] = 1.0 / inverse if inverse > 0 else np.inf
    cmd = _mf(ctx, P_CMD, k + 1, nvalve)[k]
    speed = _mf(ctx, P_SPEED, k + 1, npump)[k]
    oil, spool = _vf(ctx, P_OIL, n), _vf(ctx, P_SPOOL, nvalve)
    # predicted end velocities: zero, clipped so the cylinders stay inside their stroke
    guess = np.zeros(na)
    cyl, ci = net.cyl, net.cyl_i
    for c in range(cyl.shape[0]):
        a = ci[c, C.CI_ACT]
        guess[a] = C._minimum(C._maximum(guess[a], -xs[a] / dt), (cyl[c, C.CYL_STROKE] - xs[a]) / dt)
    _, p_end, _, _, _, ist, _, _, gradient = C._linearize_kernel(F, I, oil, spool, cmd, speed, xs, guess, dt)
    if ist[C.IS_SINGULAR]:
        ctx[C_STATUS] = ST_SINGULAR
        ctx[C_FAILED] = k
        return
    fg, fslope_guess = np.empty(na), np.empty(na)
    _friction_effort(net, guess, fg, fslope_guess)
    pressure_end, pressure_start = np.empty(na), np.empty(na)
    _pressure_effort(net, p_end, pressure_end)
    geo, p0, dpdm = np.empty(n), np.empty(n), np.empty(n)
    C._pressure(net, oil, xs, geo, p0, dpdm)
    _pressure_effort(net, p0, pressure_start)
    friction, fslope = np.empty(na), np.empty(na)
    _friction_effort(net, vs, friction, fslope)
    ctrl, bias = _vf(ctx, P_CTRL, nu), _vf(ctx, P_BIASPRM, nu * ctx[C_NBIAS])
    for i in range(na):
        pslope = gradient[i, i] - fslope_guess[i]
        w = C._maximum(-pslope, 0.0) * dt / meff[i]
        th = C._clip(1.0 - 2.0 / w, 0.0, 1.0)
        theta[i] = th
        fs = min(fslope[i], 0.0)  # see CouplingImplicit.begin: no negative damping in the implicit matrix
        const[i] = (1.0 - th) * pressure_start[i] + th * (pressure_end[i] - pslope * guess[i]) + friction[i] - fs * vs[i]
        slope[i] = th * pslope + fs
        ctrl[act[i]] = const[i]
        bias[act[i] * ctx[C_NBIAS] + 2] = slope[i]
    _vf(ctx, P_PASSIVE_SAVED, nv)[:] = _vf(ctx, P_PASSIVE, nv)
    ctx[C_PENDING] = 1


# ----------------------------------------------------------------------------
# The process-wide callback (compiled once per process, on first use)
# ----------------------------------------------------------------------------
_CTX = np.zeros(NCTX, np.int64)  # the pointer table the callback reads; its address is baked into the cfunc
_CALLBACK = None
_LOCK = threading.Lock()


def _mj_solveM():
    """ctypes handle of MuJoCo's ``mj_solveM`` from the library the bindings loaded."""
    folder = os.path.dirname(mujoco.__file__)
    name = next(f for f in sorted(os.listdir(folder)) if f.startswith("libmujoco.so"))
    lib = ctypes.CDLL(os.path.join(folder, name))
    f = lib.mj_solveM
    f.argtypes = (ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int)
    f.restype = None
    return f


def callback():
    """The numba ``cfunc`` (MuJoCo ``mjfGeneric``) that couples one step; compiled on first use in a process."""
    global _CALLBACK
    if _CALLBACK is None:
        ctx_addr = int(_CTX.ctypes.data)
        solve = _mj_solveM()

        @numba.cfunc(types.void(types.voidptr, types.voidptr), error_model="numpy")
        def coupled_step(m, d):
            ctx = carray(_pi64(ctx_addr), (NCTX,))
            _prepare(ctx)
            solve(m, d, _pvoid(ctx[P_MINVJ]), _pvoid(ctx[P_J]), np.int32(ctx[C_NA]))
            _begin(ctx)

        _CALLBACK = coupled_step
    return _CALLBACK


def _finish_python():
    _finish_pending(_CTX)


# ----------------------------------------------------------------------------
# The plant
# ----------------------------------------------------------------------------
class MujocoPlantFast(MujocoPlant):
    """:class:`MujocoPlant` whose steps run inside ``mj_step`` (see module docstring).

    ``advance(n)`` takes n coupled steps in one ``mj_step(m, d, nstep=n)``;
    ``step()`` is ``advance(1)``.
    """

    def __init__(self, scene):
        super().__init__(scene)
        scenario = scene.scenario
        stepper = self.coupling.stepper
        self.fast = bool(
            _NUMBA and C.compiled_available() and isinstance(self.coupling, CouplingImplicit)
            and isinstance(stepper, C.StepperImplicitEulerCompiled) and self.coupling.predictor is stepper
        )
        if not self.fast:
            return
        m, d, net = self.model, self.data, self.network
        na, nv = net.actuator_count, m.nv
        self._F, self._I = stepper._F, stepper._I
        self._act = np.ascontiguousarray(self.binding.actuator_id, np.int64)
        self._closed = np.ascontiguousarray(self.binding.closed_length, np.float64)
        self._J = np.zeros((na, nv))
        self._MinvJ = np.zeros((na, nv))
        n = net.node_count
        self._oil, self._p = np.zeros(n), np.zeros(n)
        self._spool = np.zeros(len(net.valve_names))
        self._x, self._v = np.zeros(na), np.zeros(na)
        self._xs, self._vs = np.zeros(na), np.zeros(na)
        self._const, self._slope, self._theta, self._meff, self._effort = (np.zeros(na) for _ in range(5))
        self._flow = np.zeros(len(net.branch_names))
        self._passive = np.zeros(nv)
        self._fs = np.zeros(NFS)
        self._fs[FS_DT] = self.dt
        quad_nodes, quad_weights = np.polynomial.legendre.leggauss(POTENTIAL_QUADRATURE_POINTS)
        self._quad = np.concatenate([quad_nodes, quad_weights])
        self._capacity = 0
        self._cmd = self._speed = None
        self._inputs = self._input_plan()
        for a in (d.qvel, d.ctrl, d.actuator_length, d.actuator_velocity, d.actuator_moment, d.qfrc_passive,
                  d.qfrc_constraint, m.actuator_biasprm):
            assert a.flags.c_contiguous and a.dtype == np.float64
        ctx = np.zeros(NCTX, np.int64)
        ctx[C_NA], ctx[C_NV], ctx[C_NU], ctx[C_N], ctx[C_NB] = na, nv, m.nu, n, len(net.branch_names)
        ctx[C_NVALVE], ctx[C_NPUMP], ctx[C_NBIAS] = len(net.valve_names), len(net.pump_names), m.actuator_biasprm.shape[1]
        ctx[C_SUBSTEPS], ctx[C_NCYL] = stepper.substeps, len(net.cylinder_actuator)
        addresses = {
            P_F: self._F, P_I: self._I, P_ACT: self._act, P_CLOSED: self._closed, P_LENGTH: d.actuator_length,
            P_AVEL: d.actuator_velocity, P_MOMENT: d.actuator_moment, P_ROWADR: d.moment_rowadr, P_ROWNNZ: d.moment_rownnz,
            P_COLIND: d.moment_colind, P_QVEL: d.qvel, P_CTRL: d.ctrl, P_BIASPRM: m.actuator_biasprm,
            P_PASSIVE: d.qfrc_passive, P_CONSTRAINT: d.qfrc_constraint, P_J: self._J, P_MINVJ: self._MinvJ,
            P_OIL: self._oil, P_PRESSURE: self._p, P_SPOOL: self._spool, P_XPOS: self._x, P_XVEL: self._v,
            P_XSTART: self._xs, P_VSTART: self._vs, P_CONST: self._const, P_SLOPE: self._slope, P_THETA: self._theta,
            P_MEFF: self._meff, P_EFFORT: self._effort, P_FLOW: self._flow, P_PASSIVE_SAVED: self._passive, P_FS: self._fs,
            P_QUAD: self._quad,
        }
        assert d.moment_rowadr.dtype == np.int32 and d.moment_colind.dtype == np.int32
        for slot, array in addresses.items():
            ctx[slot] = array.ctypes.data
        self._keep = addresses  # the arrays must outlive the table
        self._ctx = ctx
        callback()

    # ------------------------------------------------------------------ inputs
    def _input_plan(self):
        """Per input: (is_valve, index, schedule) for vectorised sampling."""
        net = self.network
        plan = []
        for name, schedule in self.scene.scenario.inputs.items():
            if name in net.valve_names:
                plan.append((True, net.valve_names.index(name), schedule))
            elif name in net.pump_names:
                plan.append((False, net.pump_names.index(name), schedule))
            else:
                net.set_control(self.control, name, 0.0)  # raises the usual KeyError
        return plan

    def _sample_inputs(self, n):
        """Controls of the next n steps (rows), as PlantBase.apply_inputs at each step's time."""
        if n > self._capacity:
            self._capacity = max(n, 2 * self._capacity)
            self._cmd = np.zeros((self._capacity, len(self.network.valve_names)))
            self._speed = np.zeros((self._capacity, len(self.network.pump_names)))
        cmd, speed = self._cmd[:n], self._speed[:n]
        cmd[:] = self.control.valve_command
        speed[:] = self.control.pump_speed
        times = None
        for is_valve, index, schedule in self._inputs:
            if times is None:
                times = (np.arange(n) + self.step_index) * self.dt
            target = cmd if is_valve else speed
            if isinstance(schedule, Schedule):
                target[:, index] = np.interp(times, schedule.t, schedule.value)
            elif callable(schedule):
                target[:, index] = [schedule(t) for t in times]
            else:
                target[:, index] = schedule
        return cmd, speed

    # -------------------------------------------------------------------- step
    def step(self):
        """Advance one step of ``dt``; returns the hydraulic step report."""
        return self.advance(1)

    def advance(self, n: int):
        """Advance ``n`` coupled steps in one ``mj_step(m, d, nstep=n)``; returns the last step's report.

        Stops early only in the sense that a failed hydraulic step freezes the
        network (see module docstring); ``step_index`` then points at the failure.
        """
        n = int(n)
        if n < 1:
            raise ValueError(f"`n` must be >= 1, got {n!r}")
        if not self.fast:
            for _ in range(n):
                report = MujocoPlant.step(self)
                if not report.success:
                    break
            return report
        state = self.net_state
        self._oil[:] = state.node_oil
        self._p[:] = state.node_pressure
        self._spool[:] = state.valve_spool
        self._x[:] = state.actuator_position
        self._v[:] = state.actuator_velocity
        e = self.energy
        fs = self._fs
        fs[FS_PUMP], fs[FS_MOTOR], fs[FS_DISS_H] = e.pump_work, e.motor_work, e.dissipated_hydraulic
        fs[FS_DISS_F], fs[FS_DISS_M] = e.dissipated_friction, e.dissipated_mechanical
        cmd, speed = self._sample_inputs(n)
        ctx = self._ctx
        ctx[P_CMD], ctx[P_SPEED] = cmd.ctypes.data, speed.ctypes.data
        ctx[C_K], ctx[C_PENDING], ctx[C_FAILED], ctx[C_STATUS], ctx[C_WORST] = 0, 0, -1, ST_OK, -1
        if not _LOCK.acquire(blocking=False):
            raise RuntimeError("another MujocoPlantFast is stepping in this process (MuJoCo's control callback is global)")
        try:
            _CTX[:] = ctx
            previous = mujoco.get_mjcb_control()
            mujoco.set_mjcb_control(_CALLBACK.ctypes)
            try:
                mujoco.mj_step(self.model, self.data, nstep=n)
            finally:
                mujoco.set_mjcb_control(previous)
            _finish_python()
            out = _CTX.copy()
        finally:
            _LOCK.release()
        failed = int(out[C_FAILED])
        steps = n if failed < 0 else failed + 1
        last = steps - 1
        self.control.valve_command[:] = cmd[last]
        self.control.pump_speed[:] = speed[last]
        self.step_index += steps
        self.net_state = NetworkState(self._oil.copy(), self._p.copy(), self._spool.copy(), self._x.copy(), self._v.copy(),
                                      state.time + steps * self.dt)
        e.pump_work, e.motor_work, e.dissipated_hydraulic = float(fs[FS_PUMP]), float(fs[FS_MOTOR]), float(fs[FS_DISS_H])
        e.dissipated_friction, e.dissipated_mechanical = float(fs[FS_DISS_F]), float(fs[FS_DISS_M])
        self.effort = self._effort.copy()
        self.theta = self._theta.copy()
        report = StepReport(newton_iterations=int(out[C_NEWTON]), rhs_evaluations=int(out[C_RHS]),
                            jacobian_evaluations=int(out[C_JAC]), residual=float(fs[FS_NORM]), branch_flow=self._flow.copy())
        status, worst = int(out[C_STATUS]), int(out[C_WORST])
        names = self.network.node_names
        if status == ST_NEWTON:
            report.status = StepStatus.NEWTON_FAILED
            report.message = (f"{StepStatus.NEWTON_FAILED.value} (worst node '{names[worst] if worst >= 0 else '?'}', "
                              f"residual {report.residual:.3g} Pa)")
        elif status == ST_NONFINITE:
            report.status = StepStatus.NONFINITE
            report.message = f"pressure of node '{names[worst]}' is not finite: {StepStatus.NONFINITE.value}"
        elif status == ST_SINGULAR:
            report.status = StepStatus.NEWTON_FAILED
            report.message = "the coupling's linearisation is singular"
        self.last_report = report
        return report


__all__ = ["MujocoPlantFast", "callback"]
