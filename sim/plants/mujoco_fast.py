"""MuJoCo plant whose coupled step runs entirely inside ``mj_step``: :class:`MujocoPlantFast`.

Same physics as :class:`~sim.plants.mujoco.MujocoPlant` with the implicit
couplings and the compiled backward-Euler stepper, the ``explicit`` coupling
(forward Euler, :class:`~hydraulics.steppers.StepperExplicitEuler`) or the
``incompressible`` fidelity, but the per-step Python orchestration is replaced
by a numba ``cfunc`` installed as MuJoCo's control callback, so
``mj_step(m, d, nstep=N)`` advances N coupled steps in C.  The coupling the
callback steps is ``C_KIND`` (``KIND_*``); the steps below are the implicit
one's.  ``explicit``: the law is the start pressures' effort plus friction
(slope 0) and the finish is :func:`hydraulics._compiled_rigid.explicit_substep`
from the network's own positions at the held start velocities.
``incompressible``: the law of :func:`hydraulics._compiled_rigid.incompressible_law`,
its bounds written to MuJoCo's ``actuator_forcerange`` (``actuator_forcelimited``
where finite, as :meth:`MujocoPlant.step` does: MuJoCo clamps within its step),
at an end of the stroke as :func:`hydraulics._compiled_rigid.end_stop_hold` applies
it (the end cap takes what pushes past the end), and the finish
:func:`hydraulics._compiled_rigid.incompressible_finish` (pressures derived from
the hydraulic law's clamped effort); the ledger's supplied work is that of the
forces MuJoCo applied (``_applied_power``).

MuJoCo calls the control callback once per ``mj_step``, after positions,
velocities, actuator lengths/moments and the factorised mass matrix are
computed (end of ``mj_fwdVelocity``, before ``mj_fwdActuation``) — exactly the
state :class:`MujocoPlant` sees after ``mj_step1``.  In the callback of step k:

1. finish step k−1 (if pending): v⁺ = J_{k−1}·q̇ (q̇ is now the integrated
   velocity), x⁺ = x_{k−1} + h·v⁺, the compiled backward-Euler step of the
   network (``_compiled._step_core``, sub-stepped as ``Stepper._step``), the
   applied effort law(v⁺) and the energy ledger (pump/motor work, hydraulic,
   friction and mechanical dissipation);
2. dense moments J_k from MuJoCo's sparse ``actuator_moment``, M⁻¹·Jᵀ by
   MuJoCo's own ``mj_solveM`` (called through its C entry point), effective
   masses and θ as :func:`hydraulics.coupling.blend_factor`;
3. the effort law of :meth:`CouplingImplicit.begin` (``_compiled._linearize_core``)
   written to ``ctrl`` and ``actuator_biasprm[:, 2]``, linearised at the
   start velocities (:func:`hydraulics.coupling.start_velocity_guess`, with
   the same fallback to the held actuators when that linearisation fails).
   The start pressures p(m, x) are the linearisation's first Newton
   evaluation whenever the velocity guess is zero (x + h·0 = x exactly), so
   they are then not recomputed.  The predicted oil m_lin, the guess and
   ∂m⁺/∂v stay in the scratch buffer for step 1 of the next callback, which
   starts the finish's Newton from m_lin + (∂m/∂v)·(v⁺ − v_guess)
   (``implicit``) or takes that value as the end oil (``implicit-linear``,
   ``C_LINEAR``; see :mod:`hydraulics.coupling`).  With ``rosenbrock`` the
   linearisation is one Newton step (``_compiled._linearize_one_step_core``), so
   the step has no nonlinear solve at all, and the step ends at MuJoCo's actuator
   positions (:meth:`MujocoPlant.end_position`; the block's last step after an
   ``mj_fwdPosition`` from Python): its end pressures p(m⁺, x⁺), kept in the scratch
   with their geometric volumes and ∂p/∂m (``PLANT_SCRATCH``: geo, p0, dpdm, known), are the next
   step's start pressures, so each step evaluates the pressure law once.  A finish after
   such a step (``begun``: its linearisation accepted from the known start, no rigid
   actuator's law using the work buffer since) takes the valve areas of the step's spools
   and the law pieces at its start pressures from the linearisation's scratch
   (``_compiled.ONE_STEP_SCRATCH``: area, pieces) instead of evaluating them again.

**Cost and caching.**  The callback allocates nothing: every temporary lives
in buffers the plant allocates once (``_work`` for the ``_compiled`` cores,
``_scratch`` for this module's, see :func:`scratch_size`), and the kernels run
without numba's reference counting (``_compiled._kernel``).  The views of the
plant's arrays (:class:`Kept`) are made by a block's first call and
stored in the plant's ``kept_views`` buffer (:func:`kept_words`), which the
block's other calls read.  The callback is a
thin ``cfunc`` around :func:`_coupled_step` compiled with ``cache=True``: it
bakes in no process-specific address — the pointer table is the external
symbol ``CTX_SYMBOL`` and ``mj_solveM`` the external function
``SOLVEM_SYMBOL``, both registered with ``llvmlite.binding.add_symbol`` before
the callback is loaded — so numba's disk cache (the keyed folder of :mod:`hydraulics.kernel_cache`) holds it
and a new process loads it in milliseconds instead of compiling it (≈ 3 s the
first time after a change of this file or of the hydraulic kernel sources, ``hydraulics._jit.SOURCES``).
numba keys a cached function by its own file only, so the callback carries a
sha256 of both source files as a closure variable (part of numba's cache key),
and this module's other numba functions are not cached on their own: they
exist only inside the callback.  The last step of a block is finished by
calling the same callback from Python in finish-only mode (``C_MODE``).

The last step of a block is finished from Python after ``mj_step`` returns
(through the same callback), so ``net_state``, ``effort``, ``theta``,
``energy``, ``control``, ``last_report`` and ``step_index`` are coherent after
every :meth:`MujocoPlantFast.advance`.  Operator inputs are sampled for the
block's step times in Python beforehand (piecewise-linear schedules
vectorised, callables called per step).

The effort-law terms, the oil prediction, the commit of a finite step and
the energy ledger are the kernels of :mod:`hydraulics._compiled` that
:mod:`sim.plants.pbd_hydraulics` (the PBD plant's compiled coupling) calls too
(``_effort_law_terms``, ``_predicted_oil``, ``_commit_if_finite``,
``_account``; see there).

Results agree with :class:`MujocoPlant` to round-off (θ is exact: the
effective masses come from the same ``mj_solveM`` at the same state); the only
differences are summation orders (J·q̇, energy sums).

**Recording.**  ``advance(n, record, every)`` (or :meth:`MujocoPlantFast.record_next` before
``advance(n)``) copies the raw state after every step whose index becomes a multiple of
``every`` into the next row of ``record``, from the callback of the following step (``_record``):
MuJoCo has then already computed that state's ``xpos``, ``xquat`` and ``energy``, so the row is
bit for bit :meth:`MujocoPlantFast.record_row` after that step, without returning to Python.
The runner's recorder passes rows of its ring (same layout), so logging every step, or every
tenth, needs no ``advance`` per sample.

**API**: ``advance(n)`` runs
n coupled steps and returns the last step's :class:`StepReport` (``success``,
``message``, ``status``; Newton counters of the last step); ``step()`` is
``advance(1)``; after each call ``net_state``, ``effort``, ``theta``,
``energy``, ``control``, ``last_report``, ``step_index`` and ``time`` describe
the same instant; ``net_state`` (its arrays), ``effort``, ``theta``, ``last_report`` and the pressure and
actuator-coordinate extremes are replaced by new objects by each compiled ``advance``, never written into (the runner's snapshot of a block keeps
them by reference), while ``control``'s arrays are updated in place.  The constructor takes ``coupling`` (as
:class:`MujocoPlant`) to override the scenario's coupling.  New: ``node_pressure_max`` / ``node_pressure_min`` [Pa], the
running extremes of every successful step's end pressures since
:meth:`reset` (initial pressures included; the runner folds them into its
peaks, so they cover every step, not only the logged ones; assigning them is
allowed, :meth:`advance` continues from the assigned values), and in the same way
``actuator_position_max`` / ``actuator_position_min`` [m | rad] of the actuator coordinates
(the plausibility monitor's stroke check per block, :mod:`sim.run.monitor`); module-level
:func:`scratch_size`, :func:`kept_words`, ``CTX_SYMBOL``, ``SOLVEM_SYMBOL``, ``MODE_*``.

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
* Accelerated: the implicit couplings (``implicit``, ``implicit-linear``, ``rosenbrock``) with the
  compiled implicit-Euler stepper, the ``explicit`` coupling with the explicit-Euler stepper, either with
  rigid actuators around it (:class:`~hydraulics.coupling.CouplingMixed`: the law of :func:`_rigid_law`
  over the inner one's), and the ``incompressible`` fidelity.  Any other stepper falls back to
  :meth:`MujocoPlant.step` in a Python loop (``fast`` is then False); the per-step plant calls the same kernels.
"""

from __future__ import annotations

import ctypes
import math
import os
import threading
from collections import namedtuple

import mujoco
import numpy as np

from hydraulics import _compiled as C
from hydraulics import _compiled_rigid as K
from hydraulics import controllers as CT
from hydraulics.coupling import (SCHEME_ROSENBROCK, CouplingExplicit, CouplingImplicit, CouplingIncompressible,
                                 CouplingMixed)
from hydraulics.fluid import POTENTIAL_QUADRATURE_POINTS, potential_quadrature
from hydraulics.layout import Layout, PointerTable
from sim.io import record_row
from sim.io.record_row import RECORD_ROW
from hydraulics.network import NetworkState
from hydraulics.steppers import StepperExplicitEuler, StepperImplicitEuler, StepReport, StepStatus

from sim.plants.controllers import advance_controlled
from sim.plants.inputs import input_plan, sample_inputs
from sim.plants.mujoco import MujocoPlant, mark_reset, mujoco_resets

try:  # pragma: no branch
    import llvmlite.binding as llvm_binding
    import numba
    from llvmlite import ir as llvm_ir
    from numba import carray, types
    from numba.extending import intrinsic

    _NUMBA = True
except ImportError:  # pragma: no cover
    _NUMBA = False


# ----------------------------------------------------------------------------
# The pointer table (int64): counters, the arrays' dimensions, the arrays' addresses.
# ----------------------------------------------------------------------------
FLOAT_SCALARS = ("dt", "norm", "pump", "motor", "diss_h", "diss_f", "diss_m", "nquad")
"""The float scalars (SLOT.P_FS, indices ``FS_*``): step [s], residual of the last step [Pa], then the ledger terms
[J] in C._account's order."""
FS_DT, FS_NORM, FS_PUMP, FS_MOTOR, FS_DISS_H, FS_DISS_F, FS_DISS_M, FS_NQUAD = range(len(FLOAT_SCALARS))
NFS = len(FLOAT_SCALARS)
POINTERS = PointerTable("fast_plant", (
    # counters and flags of the block: steps done, a step pending its finish, the failed step, its outcome
    "C_SUBSTEPS", "C_K", "C_PENDING", "C_FAILED", "C_STATUS", "C_WORST", "C_NEWTON", "C_RHS", "C_JAC", "C_MODE",
    "C_LINEAR", "C_KIND", "C_NR", "C_STEP0", "C_END_FINITE",
    # the record (MujocoPlantFast.advance): every how many steps, the first recorded step, rows written, bad rows
    "C_REC_EVERY", "C_REC_FIRST", "C_REC_COUNT", "C_REC_BAD",
    # 1 once the block's first call has stored its views (Kept) in kept_views; the bytes they take (MODE_SIZE)
    "C_KEPT", "C_KEPT_BYTES"),
    # na actuators, nv dofs, nu MuJoCo actuators, n nodes, nb branches, nvalve valves, npump pumps, nbias bias
    # parameters per MuJoCo actuator, nstate component states, nnz entries of MuJoCo's sparse actuator moments, rows of
    # the block's inputs, nf/ni packed network floats/ints, nw/ns work/scratch floats, ntf/nti coupling table
    # floats/ints, nq MuJoCo coordinates, nbody bodies, nctl controllers, rec_rows × rec_width the block's record
    ("na", "nv", "nu", "n", "nb", "nvalve", "npump", "nbias", "nstate", "nnz", "rows", "nf", "ni", "nw", "ns", "ntf",
     "nti", "nq", "nbody", "nctl", "rec_rows", "rec_width", "nkept"), (
    # the packed network (hydraulics._compiled) and the coupling table of SLOT.C_KIND (hydraulics._compiled_rigid)
    ("F", "float64", "nf"), ("I", "int64", "ni"), ("TF", "float64", "ntf"), ("TI", "int64", "nti"),
    # MuJoCo's model and data: actuator lengths and velocities, sparse moments, qvel, ctrl, biasprm, passive and
    # constraint forces, force limits, qpos, body poses, (potential, kinetic) energy
    ("length", "float64", "nu"), ("avel", "float64", "nu"), ("moment", "float64", "nnz"), ("rowadr", "int32", "nu"),
    ("rownnz", "int32", "nu"), ("colind", "int32", "nnz"), ("qvel", "float64", "nv"), ("ctrl", "float64", "nu"),
    ("bias", "float64", "nu * nbias"), ("passive", "float64", "nv"), ("constraint", "float64", "nv"),
    ("flimited", "bool", "nu"), ("frange", "float64", "2 * nu"), ("qpos", "float64", "nq"),
    ("bxpos", "float64", "nbody", 3), ("bxquat", "float64", "nbody", 4), ("energy", "float64", 2),
    # the actuators: MuJoCo actuator of each, closed length; dense moments J and M⁻¹·Jᵀ; start positions and
    # velocities; the effort law (const + slope·v within [lower, upper]), θ, effective masses, applied effort;
    # passive forces at the step's start
    ("act", "int64", "na"), ("closed", "float64", "na"), ("J", "float64", "na", "nv"), ("MinvJ", "float64", "na", "nv"),
    ("xs", "float64", "na"), ("vs", "float64", "na"), ("const", "float64", "na"), ("slope", "float64", "na"),
    ("lower", "float64", "na"), ("upper", "float64", "na"), ("theta", "float64", "na"), ("meff", "float64", "na"),
    ("effort", "float64", "na"), ("passive_saved", "float64", "nv"),
    # the network state, the step's oil change and flows, the running extremes
    ("oil", "float64", "n"), ("pres", "float64", "n"), ("spool", "float64", "nstate"), ("pos", "float64", "na"),
    ("vel", "float64", "na"), ("flow", "float64", "nb"), ("oil_change", "float64", "n"), ("pmax", "float64", "n"),
    ("pmin", "float64", "n"), ("xmax", "float64", "na"), ("xmin", "float64", "na"),
    # float scalars (FLOAT_SCALARS), the potential's quadrature, the kernels' work and the plant's scratch, counters
    ("fs", "float64", NFS), ("quad", "float64", 2 * POTENTIAL_QUADRATURE_POINTS), ("W", "float64", "nw"),
    ("S", "float64", "ns"), ("istats", "int64", C.NIS),
    # per block: every step's valve commands and pump speeds, the controllers (hydraulics.controllers) and their
    # setpoints, the record
    ("cmd", "float64", "rows", "nvalve"), ("speed", "float64", "rows", "npump"),
    ("ctl_table", "float64", "nctl", len(CT.PID_COLUMNS)), ("ctl_state", "float64", "nctl", len(CT.STATE_COLUMNS)),
    ("ctl_set", "float64", "rows", "nctl"), ("rec", "float64", "rec_rows", "rec_width"),
    # the block's views (Kept), stored by its first call for the others (nkept: kept_words())
    ("kept_views", "int64", "nkept")))
"""The control callback's int64 table (:class:`hydraulics.layout.PointerTable`): ``SLOT.<name>`` is an entry's index
(C_*: counters and dimensions, P_*: addresses), :func:`_views` the arrays it points to."""
SLOT = POINTERS.SLOT
NCTX = len(POINTERS)
KINDS = ("implicit", "explicit", "incompressible")
"""SLOT.C_KIND: the coupling the callback steps (``KIND_*``)."""
KIND_IMPLICIT, KIND_EXPLICIT, KIND_INCOMPRESSIBLE = range(len(KINDS))
STATUSES = ("ok", "newton", "nonfinite", "singular")
"""SLOT.C_STATUS: the step's outcome (``ST_*``)."""
ST_OK, ST_NEWTON, ST_NONFINITE, ST_SINGULAR = range(len(STATUSES))
MODES = ("step", "finish", "size")
"""SLOT.C_MODE: a coupled step (from mj_step), only finish the pending step, or only write the bytes of the
views (:class:`Kept`) to SLOT.C_KEPT_BYTES (``MODE_*``)."""
MODE_STEP, MODE_FINISH, MODE_SIZE = range(len(MODES))

# Symbols the cached callback resolves when it is loaded (registered below with llvmlite):
# the pointer table and MuJoCo's mj_solveM.  Nothing process-specific is baked into the
# compiled code, so numba's disk cache can hold it.
CTX_SYMBOL = "hydroplant_fast_plant_ctx"
SOLVEM_SYMBOL = "hydroplant_mj_solveM"


PLANT_SCRATCH = Layout("plant_scratch", ("n", "na", "nb", "nvalve"), (
    # _finish_pending's temporaries: end velocities and positions, substep motion [m, m/s | rad, rad/s]; end oil,
    # pressures, ledger temporaries; flows and their terminal derivatives; end states; predicted, start, initial oil
    ("v_end", "na"), ("x_end", "na"), ("xe", "na"), ("ve", "na"), ("o2", "n"), ("p2", "n"), ("mu", "n"),
    ("fl", "nb"), ("dfl", "nb", C._W_BR), ("sp2", "nvalve"), ("mpred", "n"), ("mstart", "n"), ("minit", "n"))
    # what _begin keeps for _finish_pending (until the step is finished)
    + C.LINEARIZATION_KEPT
    # _begin's temporaries: effort-law terms per actuator; start volumes, pressures p₀ and ∂p/∂m (also the
    # rosenbrock finish's end evaluation, the known flag below); the linearisation's outputs; warm-start oil
    + (("fg", "na"), ("fslope_guess", "na"), ("end_const", "na"), ("end_slope", "na"), ("pressure_start", "na"),
       ("friction", "na"), ("damping", "na"), ("effort_end", "na"), ("geo", "n"), ("p0", "n"), ("dpdm", "n"),
       ("lin_p", "n"), ("gradient", "na", "na"), ("lin_x", "na"), ("lin_flow", "nb"), ("oil_warm", "n"),
       # 1 when the finish just before wrote p(m, x) at the positions this step starts from into geo, p0, dpdm; 2
       # when it also left its flows there in fl, dfl (see C._linearize_one_step_from's ``known``)
       ("known", 1),
       # 1 when _begin's one-step linearisation from the known start was accepted and the work buffer still holds
       # its valve areas and start law pieces (ONE_STEP_SCRATCH) for the finish
       ("begun", 1)))
"""The plant's float64 scratch (SLOT.P_S), n nodes, na actuators, nb branches, nvalve component states."""


def scratch_size(na, n, nb, nstate):
    """Length of the plant's float64 scratch (SLOT.P_S): :data:`PLANT_SCRATCH`."""
    return PLANT_SCRATCH.size(n=n, na=na, nb=nb, nvalve=nstate)


Kept = namedtuple("Kept", ("net", "V", "S", "T", "R"))
Kept.__doc__ = """What the callback's functions read, kept for a block: views of the plant's memory, the packed network
(``net``, ``C._unpack``), the pointer table's arrays (``V``, :data:`POINTERS`), the plant scratch's fields (``S``,
:data:`PLANT_SCRATCH`) and the coupling tables (``T`` of the incompressible coupling, ``R`` of the rigid actuators;
only ``SLOT.C_KIND``'s is read).  Made by :func:`_make_views` in the first call of a block and stored in the
plant's ``kept_views`` (the arrays stay where they are for the block), the other calls read them there: making
them slices ~180 arrays, about 4000 instructions per step.  The functions take a pointer to them (``C._ref``'s
type), as numba passes a tuple argument field by field (~700 machine words per call)."""


_JIT = _NUMBA and C.JIT_ENABLED  # False under NUMBA_DISABLE_JIT=1: the callback runs as Python (below)

if _JIT:

    def _pointer_cast(nbtype):
        """A numba intrinsic that turns an integer address into a pointer of type ``nbtype``."""

        @intrinsic
        def cast(typingctx, addr):
            def codegen(context, builder, signature, args):
                return builder.inttoptr(args[0], context.get_value_type(nbtype))

            return nbtype(addr), codegen

        return cast

    _pf64 = _pointer_cast(types.CPointer(types.float64))
    _pi64 = _pointer_cast(types.CPointer(types.int64))
    _pi32 = _pointer_cast(types.CPointer(types.int32))
    _pu8 = _pointer_cast(types.CPointer(types.uint8))
    _pvoid = _pointer_cast(types.voidptr)
    _carray = carray

    @intrinsic
    def _ctx_address(typingctx):
        """Address of the process's pointer table: an external int64 symbol resolved at load time."""
        sig = types.int64()

        def codegen(context, builder, signature, args):
            module = builder.module
            table = module.globals.get(CTX_SYMBOL)
            if table is None:
                table = llvm_ir.GlobalVariable(module, llvm_ir.IntType(64), CTX_SYMBOL)
                table.linkage = "external"
            return builder.ptrtoint(table, llvm_ir.IntType(64))

        return sig, codegen

    def _made_type(typingctx, make, ctx):
        """The type of what the compiled function ``make`` returns for ``ctx`` (typed, never called)."""
        return make.get_call_type(typingctx, (ctx,), {}).return_type

    @intrinsic
    def _keep(typingctx, address, value):
        """Store ``value`` at the integer ``address`` (a buffer of at least :func:`_kept_bytes` of it)."""
        def codegen(context, builder, signature, args):
            builder.store(args[1], builder.inttoptr(args[0], context.get_data_type(value).as_pointer()))
            return context.get_dummy_value()

        return types.void(address, value), codegen

    @intrinsic
    def _kept(typingctx, address, make, ctx):
        """A pointer (the type of ``C._ref``'s) to the value ``make(ctx)`` returns, stored at ``address`` by
        :func:`_keep`."""
        pointer = types.CPointer(_made_type(typingctx, make, ctx))

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(pointer))

        return pointer(address, make, ctx), codegen

    @intrinsic
    def _kept_bytes(typingctx, make, ctx):
        """The bytes :func:`_keep` writes for the value ``make(ctx)`` returns."""
        value = _made_type(typingctx, make, ctx)

        def codegen(context, builder, signature, args):
            return context.get_constant(types.int64, context.get_abi_sizeof(context.get_data_type(value)))

        return types.int64(make, ctx), codegen

    @intrinsic
    def _member_ref(typingctx, pointer, index):
        """A pointer to member ``index`` (a constant) of the tuple behind ``pointer`` (the type of ``C._ref``'s),
        as ``C._ref`` of that member would be, without copying it."""
        if not (isinstance(pointer, types.CPointer) and isinstance(pointer.dtype, types.BaseTuple)
                and isinstance(index, types.IntegerLiteral)):
            return None
        position = index.literal_value

        def codegen(context, builder, signature, args):
            zero, member = llvm_ir.Constant(llvm_ir.IntType(32), 0), llvm_ir.Constant(llvm_ir.IntType(32), position)
            return builder.gep(args[0], [zero, member], inbounds=True)

        return types.CPointer(pointer.dtype.types[position])(pointer, index), codegen

    _mj_solveM_nb = types.ExternalFunction(
        SOLVEM_SYMBOL, types.void(types.voidptr, types.voidptr, types.voidptr, types.voidptr, types.int32)
    )
    # Not cached on their own: they are only ever compiled into the control callback, whose cache
    # key includes a fingerprint of this file and of the hydraulic kernel sources (see callback()).
    # (numba's cache of a function does not notice changes of the functions it calls in other files.)
    def _jit(function):
        return numba.njit(error_model="numpy", nogil=True)(function)

    def _kernel(function):
        return numba.njit(error_model="numpy", nogil=True, _nrt=False)(function)

    def _inline(function):
        """:func:`_jit` inlined into its callers at numba IR level: for the helpers of the callback that return a
        tuple of views (numba returns a tuple through a zero-filled stack slot, a ``memset`` of kilobytes per step
        when LLVM does not inline the call)."""
        return numba.njit(error_model="numpy", nogil=True, inline="always")(getattr(function, "py_func", function))
else:  # the same callback as Python (NUMBA_DISABLE_JIT=1, for debugging): ctypes pointers, mujoco.mj_solveM
    def _pointer_cast(ctype):
        def cast(addr):
            return ctypes.cast(int(addr), ctypes.POINTER(ctype))

        return cast

    _pf64 = _pointer_cast(ctypes.c_double)
    _pi64 = _pointer_cast(ctypes.c_int64)
    _pi32 = _pointer_cast(ctypes.c_int32)
    _pu8 = _pointer_cast(ctypes.c_uint8)

    def _pvoid(addr):
        return int(addr)

    def _carray(pointer, shape):
        """``carray``; zeros for a null pointer (an entry not set for this block, never read)."""
        return carray(pointer, shape) if pointer else np.zeros(shape, np.dtype(pointer._type_))

    def _ctx_address():
        return int(_CTX.ctypes.data)

    def _mj_solveM_nb(m, d, x, y, n):
        """mj_solveM(m, d, x, y, n) on the addresses ``x`` (out) and ``y`` (n × nv each) through the bindings."""
        shape = (int(n), m.nv)
        mujoco.mj_solveM(m, d, carray(_pf64(x), shape), carray(_pf64(y), shape))

    def _jit(f):
        return f

    _kernel = _inline = _jit
    _KEPT = {}  # address → the value stored there

    def _keep(address, value):
        _KEPT[int(address)] = value

    def _kept(address, make, ctx):
        return _KEPT[int(address)]

    def _kept_bytes(make, ctx):
        return 8

    def _member_ref(pointer, index):
        return pointer[index]


_plant_scratch = _inline(PLANT_SCRATCH.carver(C._matrix))


# the arrays of the pointer table as views (built inline in the callback, in reference-counted code: the kernels below
# run without numba's reference counting and cannot create arrays)
_views = _inline(POINTERS.viewer(_carray, {"float64": _pf64, "int64": _pi64, "int32": _pi32, "bool": _pu8}))


@_kernel
def _widen(values, high, low, n):
    """Running extremes of ``values[:n]``: ``high[i]`` rises to ``values[i]`` where it is above, ``low[i]`` falls to it
    where it is below (a NaN changes neither)."""
    for i in range(n):
        if values[i] > high[i]:
            high[i] = values[i]
        if values[i] < low[i]:
            low[i] = values[i]


@_kernel
def _finish_pending(ctx, pnet, views):
    """Finish the pending step with the realised velocities J_prev·q̇ (MujocoPlant.step after mj_step2); ``views``:
    a pointer to the :class:`Kept`."""
    if ctx[SLOT.C_PENDING] == 0:
        return
    ctx[SLOT.C_PENDING] = 0
    if ctx[SLOT.C_FAILED] >= 0:
        return
    na, nv, n, nb = ctx[SLOT.C_NA], ctx[SLOT.C_NV], ctx[SLOT.C_N], ctx[SLOT.C_NB]
    nvalve, npump = ctx[SLOT.C_NVALVE], ctx[SLOT.C_NPUMP]
    k = ctx[SLOT.C_K] - 1
    kept = C._deref(views)
    V, ws, R = kept.V, kept.S, kept.R
    fs = V.fs
    dt = fs[FS_DT]
    J = V.J
    qvel = V.qvel
    xs, vs = V.xs, V.vs
    W = V.W
    istats = V.istats
    v_end, x_end, xe, ve, o2, p2, mu = ws.v_end, ws.x_end, ws.xe, ws.ve, ws.o2, ws.p2, ws.mu
    fl, dfl, sp2, mpred, mstart, minit = ws.fl, ws.dfl, ws.sp2, ws.mpred, ws.mstart, ws.minit  # dfl: branches × terminals
    # what _begin left for this step: velocity guess, predicted oil and spool, ∂m⁺/∂v
    guess, lin_oil, lin_spool, doil = ws.guess, ws.lin_oil, ws.lin_spool, ws.doil
    for i in range(na):
        s = 0.0
        for j in range(nv):
            s += J[i, j] * qvel[j]
        v_end[i] = s
        x_end[i] = xs[i] + dt * s
    # linearised prediction m_lin + (∂m/∂v)·(v⁺ − v_guess) (CouplingImplicit.predicted_oil)
    C._predicted_oil(lin_oil, doil, guess, v_end, ve, mpred)
    cmd = V.cmd[k]
    speed = V.speed[k]
    oil, pres, spool = V.oil, V.pres, V.spool
    pos, vel = V.pos, V.vel
    flow_out = V.flow
    substeps = ctx[SLOT.C_SUBSTEPS]
    h = dt / substeps
    newton, rhs, jac = 0, 0, 0
    residual = 0.0
    status, worst = ST_OK, -1
    C._copy(mstart, oil)
    kind = ctx[SLOT.C_KIND]
    if kind == KIND_EXPLICIT:  # CouplingExplicit.finish (x_end, xe, ve: free in this branch and until the ledger)
        worst, rhs = K.explicit_finish(pnet, W, (oil, pres, spool, pos, vel), flow_out, vs, (cmd, speed), dt,
                                       substeps, (o2, p2, sp2, fl, dfl, istats, x_end, xe, ve))
        status = ST_NONFINITE if worst >= 0 else ST_OK
        substeps = 0
    elif kind == KIND_INCOMPRESSIBLE:  # CouplingIncompressible.finish: pressures and oil from the clamped effort
        K.incompressible_finish(pnet, V.const, V.slope, V.lower, V.upper, v_end, x_end, W[:n], V.effort, pres, oil)
        C._copy(spool, lin_spool)
        C._copy(pos, x_end)
        C._copy(vel, v_end)
        for b in range(nb):
            flow_out[b] = 0.0
        substeps = 0
    elif ctx[SLOT.C_LINEAR]:  # implicit-linear, rosenbrock: m⁺ = prediction, end pressures and flows (CouplingImplicitLinear.finish)
        substeps = 0
        rhs = 1
        C._copy(sp2, lin_spool)
        linear = True
        if ctx[SLOT.C_LINEAR] == SCHEME_ROSENBROCK:  # x⁺: MuJoCo's positions (MujocoPlant.end_position), so that
            geo0, p0, dpdm0, known = ws.geo, ws.p0, ws.dpdm, ws.known  # p(m⁺, x⁺) is the next step's p₀
            act, length, closed = V.act, V.length, V.closed
            for i in range(na):
                x_end[i] = length[act[i]] - closed[i]
            C._pressure(pnet, mpred, x_end, geo0, p0, dpdm0)  # (C._linear_finish, its pressures kept for _begin)
            C._copy(p2, p0)
            ic = C._deref(pnet).ic
            one, _ = C._one_step_scratch(W, 0, n, na, nb, ic[C.IC_NF], C._area_count(ic), ic[C.IC_NJQ], ic[C.IC_NLU])
            begun = ws.begun[0] != 0.0
            ws.begun[0] = 0.0
            if not begun:  # (else _begin's linearisation left the areas of these spools there)
                C._valve_areas(pnet, sp2, one.area)
            C._branch_flows(pnet, p2, one.area, speed, v_end, fl, dfl, sp2, dt)
            # accepted (CouplingRosenbrock.finish), else Newton from m⁺ below (mu: scratch until the ledger); the law
            # pieces at the start pressures pres are those _begin's linearisation evaluated there, if begun
            if begun:
                linear = C._linear_finish_accepted_at(pnet, oil, mpred, one.pieces, p2, dpdm0, fl, mu, sp2, dt)
            else:
                linear = C._linear_finish_accepted(pnet, oil, mpred, pres, p2, dpdm0, fl, mu, sp2, dt)
            if linear:
                C._law_states_end(pnet, sp2, dt, p2)
                # (_commit_if_finite below clears it on failure; 2: the flows fl, dfl at p₀ with the areas still in W,
                # every law branch there on its start piece: what the next linearisation may keep)
                known[0] = (2.0 if begun else 1.0) if ctx[SLOT.C_MODE] == MODE_STEP else 0.0
            else:
                known[0] = 0.0
                substeps = 1
        else:
            C._linear_finish(pnet, W, mpred, sp2, x_end, v_end, speed, p2, fl, dfl, dt)
        if linear:
            C._copy(flow_out, fl)
            bad = C._commit_if_finite(oil, pres, spool, pos, vel, mpred, p2, sp2, x_end, v_end)
            if bad >= 0:
                status, worst = ST_NONFINITE, bad
                ws.known[0] = 0.0  # (no known start evaluation)
    for s in range(substeps):
        if substeps > 1:  # ActuatorMotion.part: linear interpolation to the substep end
            frac = (s + 1) / substeps
            for i in range(na):
                xe[i] = xs[i] + frac * (x_end[i] - xs[i])
                ve[i] = vs[i] + frac * (v_end[i] - vs[i])
            for i in range(n):  # Stepper._step: Newton starts from m + frac·(guess − m)
                minit[i] = mstart[i] + frac * (mpred[i] - mstart[i])
        else:
            C._copy(xe, x_end)
            C._copy(ve, v_end)
            C._copy(minit, mpred)
        norm = C._step_core(pnet, W, C.StepStart(oil, spool, cmd, speed, xe, ve), h, True,
                            C.StepOut(o2, p2, sp2, fl, dfl, istats), minit)
        newton += istats[C.IS_NEWTON]
        rhs += istats[C.IS_RHS]
        jac += istats[C.IS_JAC]
        if norm > residual:
            residual = norm
        C._copy(flow_out, fl)
        if istats[C.IS_STATUS] != C._OK:
            status, worst = ST_NEWTON, istats[C.IS_WORST]
            break
        bad = C._commit_if_finite(oil, pres, spool, pos, vel, o2, p2, sp2, xe, ve)
        if bad >= 0:
            status, worst = ST_NONFINITE, bad
            break
    if R.actuator.size and status == ST_OK:  # CouplingMixed.finish: rigid chambers carry the clamped effort less friction
        K.rigid_finish(pnet, R, (V.const, V.slope), (V.lower, V.upper), v_end, pres, W)
    ctx[SLOT.C_NEWTON], ctx[SLOT.C_RHS], ctx[SLOT.C_JAC] = newton, rhs, jac
    ctx[SLOT.C_STATUS], ctx[SLOT.C_WORST] = status, worst
    fs[FS_NORM] = residual
    if status != ST_OK:
        ctx[SLOT.C_FAILED] = k
    else:  # the step's oil change (NetworkState.node_oil_change), running extremes of the end-of-step pressures
        oil_change = V.oil_change  # and actuator coordinates
        for i in range(n):  # (none from the incompressible coupling: it has no oil states)
            oil_change[i] = oil[i] - mstart[i] if kind != KIND_INCOMPRESSIBLE else 0.0
        _widen(pres, V.pmax, V.pmin, n)
        _widen(pos, V.xmax, V.xmin, na)
    # applied effort: law(v⁺)
    const, slope, effort = V.const, V.slope, V.effort
    for i in range(na):  # (bounds ±inf but for the incompressible law)
        effort[i] = C._clip(const[i] + slope[i] * v_end[i], V.lower[i], V.upper[i])
    # energy ledger (PlantBase._account, MujocoPlant._account); xe, ve are free again
    if kind == KIND_INCOMPRESSIBLE:  # rigid oil: the work of the forces MuJoCo applied is the supplied work
        fs[FS_PUMP] += dt * _applied_power(ctx, views, v_end)
    else:
        C._account(pnet, fs, FS_PUMP, dt, pres, pos, flow_out, v_end, V.quad, mu, xe, ve)
    if R.actuator.size:  # rigid branches (PlantBase._account): their delivery less the hydraulic force's work
        K.rigid_account(pnet, R, fs, FS_PUMP, dt, flow_out, mu, effort, xe, v_end)
    passive, constraint = V.passive_saved, V.constraint
    mw = 0.0
    for j in range(nv):
        mw += (passive[j] + constraint[j]) * qvel[j]
    fs[FS_DISS_M] -= dt * mw


@_kernel
def _prepare(ctx, views):
    """Dense moments J of the current step from MuJoCo's sparse actuator_moment."""
    na, nv = ctx[SLOT.C_NA], ctx[SLOT.C_NV]
    V = C._deref(views).V
    J = V.J
    act = V.act
    rowadr, rownnz, colind, moment = V.rowadr, V.rownnz, V.colind, V.moment
    J[:, :] = 0.0
    for i in range(na):
        aid = act[i]
        adr = rowadr[aid]
        for q in range(rownnz[aid]):
            J[i, colind[adr + q]] = moment[adr + q]


@_kernel
def _applied_power(ctx, views, v_end):
    """Σ F·v⁺ [W] of the forces MuJoCo applied over the step just taken (its ctrl, bias slope and force range, still
    those of that step): F = clip(c + k·v) when the force at the start velocity v was at or beyond a bound (MuJoCo
    then drops the implicit term), else c + k·v⁺ (the implicit term taken at the end velocity).  At the ``incompressible`` level the
    hydraulic effort is that law clipped at v⁺; the two differ where MuJoCo's implicit term passes a bound."""
    V = C._deref(views).V
    act, ctrl, bias, vs = V.act, V.ctrl, V.bias, V.vs
    nbias = ctx[SLOT.C_NBIAS]
    power = 0.0
    for i in range(v_end.size):
        a = act[i]
        c, k = ctrl[a], bias[a * nbias + 2]
        force = c + k * v_end[i]
        if V.flimited[a]:
            lo, hi = V.frange[2 * a], V.frange[2 * a + 1]
            start = c + k * vs[i]
            if start <= lo or start >= hi:  # (MuJoCo's own test: a force at its bound counts as clamped)
                force = C._clip(start, lo, hi)
        power += force * v_end[i]
    return power


@_kernel
def _write_bounds(act, lower, upper, flimited, frange):
    """MujocoPlant.step: the actuators with a finite bound are force-limited to [lower, upper] (MuJoCo clamps within
    its step), the others not."""
    for i in range(lower.size):
        a = act[i]
        bounded = math.isfinite(lower[i]) or math.isfinite(upper[i])
        flimited[a] = 1 if bounded else 0
        frange[2 * a] = lower[i] if bounded else 0.0
        frange[2 * a + 1] = upper[i] if bounded else 0.0


@_kernel
def _rigid_law(pnet, views, cmd, dt, lin, implicit, W):
    """CouplingMixed.begin (:func:`hydraulics._compiled_rigid.rigid_law`) over the step's law in the views' ``V``, its
    bounds written to MuJoCo's force ranges."""
    kept = C._deref(views)
    V, R = kept.V, kept.R
    K.rigid_law(pnet, R, V.spool, cmd, V.vs, V.meff, dt, lin, implicit, (V.const, V.slope), (V.lower, V.upper),
                V.theta, W)
    _write_bounds(V.act, V.lower, V.upper, V.flimited, V.frange)


@_kernel
def _begin(ctx, pnet, views):
    """After M⁻¹·Jᵀ: the effort law of the step (CouplingImplicit.begin; CouplingExplicit.begin or
    CouplingIncompressible.begin with the table ``T`` by ``SLOT.C_KIND``), written to ctrl and biasprm (and the
    incompressible law's bounds to MuJoCo's force ranges); ``views``: a pointer to the :class:`Kept`."""
    k = ctx[SLOT.C_K]
    ctx[SLOT.C_K] = k + 1
    if ctx[SLOT.C_FAILED] >= 0:
        return  # hydraulics frozen after a failed step: hold the last law
    na, nv, nu, n = ctx[SLOT.C_NA], ctx[SLOT.C_NV], ctx[SLOT.C_NU], ctx[SLOT.C_N]
    nb, nvalve, npump = ctx[SLOT.C_NB], ctx[SLOT.C_NVALVE], ctx[SLOT.C_NPUMP]
    kept = C._deref(views)
    V, ws, T, R = kept.V, kept.S, kept.T, kept.R
    fs = V.fs
    dt = fs[FS_DT]
    act = V.act
    closed = V.closed
    length, avel = V.length, V.avel
    J, MinvJ = V.J, V.MinvJ
    xs, vs = V.xs, V.vs
    meff, theta = V.meff, V.theta
    const, slope = V.const, V.slope
    W = V.W
    istats = V.istats
    # kept for _finish_pending
    guess, lin_oil, lin_spool, doil = ws.guess, ws.lin_oil, ws.lin_spool, ws.doil
    fg, fslope_guess, end_const, end_slope = ws.fg, ws.fslope_guess, ws.end_const, ws.end_slope
    pressure_start, friction, damping, effort_end = ws.pressure_start, ws.friction, ws.damping, ws.effort_end
    geo, p0, dpdm, lin_p, gradient = ws.geo, ws.p0, ws.dpdm, ws.lin_p, ws.gradient
    lin_x, lin_flow, oil_warm = ws.lin_x, ws.lin_flow, ws.oil_warm
    for i in range(na):
        xs[i] = length[act[i]] - closed[i]
        vs[i] = avel[act[i]]
        inverse = 0.0
        for j in range(nv):
            inverse += J[i, j] * MinvJ[i, j]
        meff[i] = 1.0 / inverse if inverse > 0 else np.inf
    cmd = V.cmd[k]
    speed = V.speed[k]
    oil, spool = V.oil, V.spool
    ctrl, bias = V.ctrl, V.bias
    kind = ctx[SLOT.C_KIND]
    if kind != KIND_IMPLICIT:
        if kind == KIND_EXPLICIT:  # CouplingExplicit.begin: the start pressures' effort and friction, slope 0
            K.explicit_law(pnet, V.pres, xs, vs, (const, slope), W)
            if R.actuator.size:  # CouplingMixed around it: the rigid actuators' law at the start supply pressure
                _rigid_law(pnet, views, cmd, dt, (V.pres, oil, xs, doil, xs), False, W)
                for i in range(na):
                    theta[i] = 1.0
        else:  # CouplingIncompressible.begin: end spools (kept for the finish) and the bounded law
            C._spool_end(pnet, spool, cmd, dt, lin_spool)
            ic = C._deref(pnet).ic
            K.incompressible_law(pnet, T, lin_spool, speed, (xs, vs), meff, dt, W[:C._area_count(ic)], (const, slope),
                                 (V.lower, V.upper))
            _write_bounds(act, V.lower, V.upper, V.flimited, V.frange)
        for i in range(na):
            ctrl[act[i]] = const[i]
            bias[act[i] * ctx[SLOT.C_NBIAS] + 2] = slope[i]
        if kind == KIND_INCOMPRESSIBLE:  # end stops: the end cap takes what pushes past an end (V keeps the hydraulic law)
            for i in range(na):
                c, s, lo, hi = K.end_stop_hold(pnet, T, i, (xs, vs), meff, dt, (const[i], slope[i]), (V.lower[i], V.upper[i]))
                ctrl[act[i]] = c
                bias[act[i] * ctx[SLOT.C_NBIAS] + 2] = s
                V.frange[2 * act[i]] = lo
                V.frange[2 * act[i] + 1] = hi
        C._copy(V.passive_saved, V.passive)
        ctx[SLOT.C_PENDING] = 1
        return
    C._secant_oil_guess(oil, V.oil_change, oil_warm)
    # predicted end velocities: the start velocities where their chord is short (coupling.start_velocity_guess),
    # clipped so the cylinders stay inside their stroke; the held actuators where that linearisation is useless
    out = C.LinearizationOut(lin_oil, lin_p, lin_spool, lin_x, lin_flow, istats, effort_end, gradient, p0, doil)
    known = ws.known
    done, held = False, False
    ws.begun[0] = 0.0
    if known[0] != 0.0:  # rosenbrock after a finished step: p₀, geo and ∂p/∂m are its end evaluation
        # (_linearize_at_start_velocity's one-step path, its pressure law not evaluated again; with the finish's
        # flows there, at step k − 1's scheduled inputs, where that step was linearised in W: C._kept_branch_flows)
        level = 2 if (known[0] == 2.0 and k > 0) else 1
        known[0] = 0.0
        C._short_chord_guess(pnet, xs, vs, dt, guess)
        held = C._clipped_guess_is_held(pnet, xs, dt, guess)
        done = (C._linearize_one_step_from(pnet, W, C.StepStart(oil, spool, cmd, speed, xs, guess), dt, out, level,
                                           geo, dpdm, (ws.fl, ws.dfl, V.speed[max(k - 1, 0)]))
                and (held or C._linearization_usable(istats, lin_p, gradient)))
        # its valve areas and start law pieces (at p₀ = the pressures the finish starts from) stay in W for the
        # finish, unless a rigid actuator's law below uses W
        ws.begun[0] = 1.0 if (done and R.actuator.size == 0) else 0.0
    if not done:
        held = C._linearize_at_start_velocity(ctx[SLOT.C_LINEAR] != SCHEME_ROSENBROCK, pnet, W,
                                              C.StepStart(oil, spool, cmd, speed, xs, vs), dt, guess, out, oil_warm)
    if istats[C.IS_SINGULAR]:
        ctx[SLOT.C_STATUS] = ST_SINGULAR
        ctx[SLOT.C_FAILED] = k
        return
    C._effort_law_terms(pnet, guess, lin_p, lin_x, vs, gradient, fg, fslope_guess, end_const, end_slope, friction,
                        damping)
    if not held and not C._one_step_accepted(istats):
        # the linearisation's first evaluation was at x + dt·guess ≠ x: the start pressures separately
        # (rosenbrock's one step evaluates at x itself)
        C._pressure(pnet, oil, xs, geo, p0, dpdm)
    C._pressure_effort(pnet, p0, pressure_start)
    C._blended_law(True, end_const, end_slope, pressure_start, friction, damping, vs, meff, dt, theta, const, slope)
    if R.actuator.size:  # CouplingMixed around it: the rigid actuators' law at the linearisation's supply pressure
        _rigid_law(pnet, views, cmd, dt, (lin_p, lin_oil, lin_x, doil, guess), True, W)
    for i in range(na):
        ctrl[act[i]] = const[i]
        bias[act[i] * ctx[SLOT.C_NBIAS] + 2] = slope[i]
    C._copy(V.passive_saved, V.passive)
    ctx[SLOT.C_PENDING] = 1


_record_views = _inline(RECORD_ROW.carver(C._matrix))


@_inline
def _record_due(ctx):
    """Whether the step just finished is one to record (:func:`_record`), read from the context alone: the callback
    calls the copying function on recorded steps only (a call passes the plant's views, ~400 machine words, which
    costs a block that records one sample in a thousand steps 0.3 µs on each of them)."""
    count = ctx[SLOT.C_REC_COUNT]
    j = ctx[SLOT.C_K] - 1  # block-local index of the step just finished
    first = ctx[SLOT.C_REC_FIRST]
    return not (count >= ctx[SLOT.C_REC_ROWS] or j < first or ctx[SLOT.C_FAILED] >= 0
                or (j - first) % ctx[SLOT.C_REC_EVERY] != 0)


@_jit
def _record(ctx, views):
    """Copy the state at the end of the step just finished into the next row of the record (see
    :meth:`MujocoPlantFast.advance`); called when :func:`_record_due`.

    In the callback of step k+1, after step k is finished, MuJoCo has already run the position and
    velocity stages (``mj_fwdPosition``, ``mj_energyPos``, ``mj_fwdVelocity``, ``mj_energyVel``) at the
    state that ends step k: ``xpos``, ``xquat`` and ``energy`` are those :meth:`MujocoPlant.mechanical_energy`
    would compute after step k.
    """
    count = ctx[SLOT.C_REC_COUNT]
    j = ctx[SLOT.C_K] - 1  # block-local index of the step just finished
    V = C._deref(views).V
    row = V.rec[count]
    fs = V.fs
    nbody, nctl = ctx[SLOT.C_NBODY], ctx[SLOT.C_NCTL]
    r, _ = _record_views(row, 0, ctx[SLOT.C_N], ctx[SLOT.C_NQ], ctx[SLOT.C_NV], ctx[SLOT.C_NA], ctx[SLOT.C_NVALVE],
                         V.spool.size, ctx[SLOT.C_NPUMP], ctx[SLOT.C_NB], nbody, nctl)  # (RECORD_ROW)
    C._copy(r.p, V.pres)
    C._copy(r.qpos, V.qpos)
    C._copy(r.qvel, V.qvel)
    C._copy(r.oil, V.oil)
    C._copy(r.x, V.pos)
    C._copy(r.v, V.vel)
    C._copy(r.effort, V.effort)
    C._copy(r.theta, V.theta)
    C._copy(r.cmd, V.cmd[j])
    C._copy(r.spool, V.spool)
    C._copy(r.speed, V.speed[j])
    C._copy(r.flow, V.flow)
    energy = V.energy  # MuJoCo's (potential, kinetic)
    r.solver[0], r.solver[1] = ctx[SLOT.C_NEWTON], fs[FS_NORM]
    r.energy[0], r.energy[1], r.energy[2] = energy[1], energy[0], fs[FS_PUMP]
    r.energy[3], r.energy[4], r.energy[5] = fs[FS_DISS_H], fs[FS_DISS_F], fs[FS_DISS_M]
    C._copy2(r.xpos, V.bxpos)
    C._copy2(r.xquat, V.bxquat)
    C._copy2(r.controllers, V.ctl_state)
    ctx[SLOT.C_REC_COUNT] = count + 1
    if not _state_finite(ctx, views):
        ctx[SLOT.C_REC_BAD] += 1


@_jit
def _state_finite(ctx, views):
    """Whether node pressures, qpos and qvel are all finite (MujocoPlant.finite())."""
    V = C._deref(views).V
    s = 0.0
    for x in V.pres:
        s += x * 0.0
    for x in V.qpos:
        s += x * 0.0
    for x in V.qvel:
        s += x * 0.0
    return s == 0.0


# the packed network and the coupling tables as views, built inline in the callback (see _inline)
_unpack = _inline(C._unpack)
_unflatten_incompressible = _inline(K.unflatten_incompressible)
_unflatten_rigid = _inline(K.unflatten_rigid)


@_inline
def _make_views(ctx):
    """The views (:class:`Kept`) of the arrays the table ``ctx`` points to (inlined: a tuple returned through a call
    is a zero-filled stack slot per call site, ~20000 instructions of ``memset`` per step)."""
    V = _views(ctx)
    na = ctx[SLOT.C_NA]
    T = _unflatten_incompressible(V.TF, V.TI, na)  # (TF, TI hold the table of SLOT.C_KIND's coupling: T or R)
    R = _unflatten_rigid(V.TF, V.TI, na, ctx[SLOT.C_NR])
    S, _ = _plant_scratch(V.S, 0, ctx[SLOT.C_N], na, ctx[SLOT.C_NB], V.spool.size)
    return Kept(_unpack(V.F, V.I), V, S, T, R)


@_jit
def _coupled_step(address, m, d):
    """The whole callback: finish step k−1, moments, M⁻¹·Jᵀ (MuJoCo's mj_solveM), effort law of step k."""
    ctx = carray(_pi64(address), (NCTX,))
    if ctx[SLOT.C_MODE] == MODE_SIZE:
        ctx[SLOT.C_KEPT_BYTES] = _kept_bytes(_make_views, ctx)
        return
    if 8 * ctx[SLOT.C_NKEPT] < _kept_bytes(_make_views, ctx):  # (never: the plant's buffer holds them)
        views = C._ref(_make_views(ctx))
    else:
        if ctx[SLOT.C_KEPT] == 0:  # the block's first call: its views, read by the other calls from the buffer
            _keep(ctx[SLOT.P_KEPT_VIEWS], _make_views(ctx))
            ctx[SLOT.C_KEPT] = 1
        views = _kept(ctx[SLOT.P_KEPT_VIEWS], _make_views, ctx)
    pnet = _member_ref(views, 0)  # the packed network, Kept.net
    _finish_pending(ctx, pnet, views)
    if ctx[SLOT.C_MODE] == MODE_FINISH:  # called from Python after the block: finish its last step only
        ctx[SLOT.C_END_FINITE] = _state_finite(ctx, views)
        return
    if ctx[SLOT.P_REC] != 0 and _record_due(ctx):
        _record(ctx, views)
    _prepare(ctx, views)
    _mj_solveM_nb(m, d, _pvoid(ctx[SLOT.P_MINVJ]), _pvoid(ctx[SLOT.P_J]), np.int32(ctx[SLOT.C_NA]))
    if ctx[SLOT.C_NCTL] > 0 and ctx[SLOT.C_FAILED] < 0:
        _control(ctx, views)
    _begin(ctx, pnet, views)


@_jit
def _control(ctx, views):
    """The controllers of step k (:func:`hydraulics.controllers.update`) from the step's start state (the network's
    actuator motion, pressures and last flows, MuJoCo's qpos/qvel), writing row k of the commands before the step's
    effort law (``_begin``) reads it."""
    k = ctx[SLOT.C_K]
    V = C._deref(views).V
    sources = (V.pos, V.vel, V.qpos, V.qvel, V.pres, V.flow)  # CT.SOURCES
    CT.update(V.ctl_table, V.ctl_state, V.ctl_set[k], ctx[SLOT.C_STEP0] + k, V.fs[FS_DT], sources, V.cmd[k], V.speed[k])


def _callback_function(fingerprint):
    """The callback's Python source; ``fingerprint`` (a closure variable, hence part of numba's cache key) is the
    hash of the sources compiled into it."""

    def coupled_step_c(m, d):
        if fingerprint is None:  # never: only makes the fingerprint a closure variable
            return
        _coupled_step(_ctx_address(), m, d)

    return coupled_step_c


# this file and the hydraulic kernel sources (everything the callback compiles in), taken at import: part of the cache key
SOURCE_SHA256 = C.source_sha256(__file__, CT.__file__, record_row.__file__, *C.SOURCES)


# ----------------------------------------------------------------------------
# The process-wide callback (loaded from numba's disk cache, or compiled once, on first use)
# ----------------------------------------------------------------------------
_CTX = np.zeros(NCTX, np.int64)  # the pointer table the callback reads (symbol CTX_SYMBOL)
_CALLBACK = None
_CALLBACK_POINTER = None  # its ctypes function pointer, for mujoco.set_mjcb_control
_BLOCK_START = ([SLOT.C_K, SLOT.C_PENDING, SLOT.C_FAILED, SLOT.C_STATUS, SLOT.C_WORST, SLOT.C_KEPT],
                (0, 0, -1, ST_OK, -1, 0))
"""The entries a block starts from: no step done or pending, none failed, no views kept (its first call makes
them: an array may have moved since the last block)."""
_KEPT_WORDS = None
_OUTCOME = [SLOT.C_FAILED, SLOT.C_STATUS, SLOT.C_WORST, SLOT.C_NEWTON, SLOT.C_RHS, SLOT.C_JAC]
_LOCK = threading.Lock()


def _mj_solveM_address():
    """Address of MuJoCo's ``mj_solveM`` in the library the bindings loaded."""
    folder = os.path.dirname(mujoco.__file__)
    name = next(f for f in sorted(os.listdir(folder)) if f.startswith("libmujoco.so"))
    lib = ctypes.CDLL(os.path.join(folder, name))
    return ctypes.cast(lib.mj_solveM, ctypes.c_void_p).value


def callback():
    """The numba ``cfunc`` (MuJoCo ``mjfGeneric``) that couples one step.

    Loaded from numba's disk cache (:mod:`hydraulics.kernel_cache`), or compiled on first use
    (≈ 3 s, once per change of this file or of :mod:`hydraulics._compiled`).
    """
    global _CALLBACK, _CALLBACK_POINTER
    if _CALLBACK is None and not _JIT:  # NUMBA_DISABLE_JIT=1: MuJoCo calls the Python function
        def coupled_step_python(m, d):
            _coupled_step(_ctx_address(), m, d)

        _CALLBACK = _CALLBACK_POINTER = coupled_step_python
    if _CALLBACK is None:
        llvm_binding.add_symbol(CTX_SYMBOL, int(_CTX.ctypes.data))
        llvm_binding.add_symbol(SOLVEM_SYMBOL, _mj_solveM_address())
        _CALLBACK = numba.cfunc(types.void(types.voidptr, types.voidptr), error_model="numpy", cache=True)(
            _callback_function(SOURCE_SHA256))
        _CALLBACK_POINTER = _CALLBACK.ctypes
    return _CALLBACK


def kept_words() -> int:
    """int64 words of a plant's ``kept_views`` buffer: the bytes of the :class:`Kept`, as the callback
    reports them (``MODE_SIZE``: it reads nothing else), rounded up."""
    global _KEPT_WORDS
    if _KEPT_WORDS is None:
        callback()
        with _LOCK:
            mode = _CTX[SLOT.C_MODE]
            _CTX[SLOT.C_MODE] = MODE_SIZE
            try:
                _CALLBACK_POINTER(None, None)
            finally:
                _CTX[SLOT.C_MODE] = mode
            _KEPT_WORDS = -(-int(_CTX[SLOT.C_KEPT_BYTES]) // 8)
    return _KEPT_WORDS


def _finish_python():
    """Finish the block's last step (after mj_step returned) through the callback itself, in finish-only mode."""
    _CTX[SLOT.C_MODE] = MODE_FINISH
    try:
        _CALLBACK_POINTER(None, None)
    finally:
        _CTX[SLOT.C_MODE] = MODE_STEP


# ----------------------------------------------------------------------------
# The plant
# ----------------------------------------------------------------------------
class MujocoPlantFast(MujocoPlant):
    """:class:`MujocoPlant` whose steps run inside ``mj_step`` (see module docstring).

    ``advance(n)`` takes n coupled steps in one ``mj_step(m, d, nstep=n)``;
    ``step()`` is ``advance(1)``.
    """

    def __init__(self, scene, *, coupling: str | None = None):
        self._record_next = None
        self._in_control = False
        self.recorded, self.recorded_finite, self.end_finite = 0, True, True
        super().__init__(scene, coupling=coupling)
        scenario = scene.scenario
        coupling = self.coupling
        stepper = coupling.stepper
        kind = None
        inner = coupling.inner if type(coupling) is CouplingMixed else coupling  # rigid actuators around it
        if (isinstance(inner, CouplingImplicit) and isinstance(stepper, StepperImplicitEuler)
                and inner.predictor is stepper):
            kind, (self._F, self._I) = KIND_IMPLICIT, (stepper._F, stepper._I)
        elif type(inner) is CouplingExplicit and type(stepper) is StepperExplicitEuler:
            kind, (self._F, self._I) = KIND_EXPLICIT, stepper.packed
        elif type(coupling) is CouplingIncompressible:
            kind, (self._F, self._I) = KIND_INCOMPRESSIBLE, coupling.packed
        self.fast = bool(_NUMBA and kind is not None)
        if not self.fast:
            return
        m, d, net = self.model, self.data, self.network
        na, nv = net.actuator_count, m.nv
        # the callback views both tables in these arrays (only SLOT.C_KIND's is read): long enough for either
        nr = len(net.rigid_branch_actuator)
        if kind == KIND_INCOMPRESSIBLE:
            self._TF, self._TI = K.flatten_incompressible(coupling.table, K.table_sizes(na, nr))
        else:  # its rigid actuators (none without CouplingMixed)
            self._TF, self._TI = K.flatten_rigid(K.pack_rigid(net), K.table_sizes(na, nr))
        self._lower, self._upper = np.full(na, -np.inf), np.full(na, np.inf)
        self._act = np.ascontiguousarray(self.binding.actuator_id, np.int64)
        self._closed = np.ascontiguousarray(self.binding.closed_length, np.float64)
        self._J = np.zeros((na, nv))
        self._MinvJ = np.zeros((na, nv))
        n = net.node_count
        self._oil, self._p, self._oil_change = np.zeros(n), np.zeros(n), np.zeros(n)
        self._spool = net.component_state_start.copy()  # the component states (valve spools first)
        self._x, self._v = np.zeros(na), np.zeros(na)
        self._xs, self._vs = np.zeros(na), np.zeros(na)
        self._const, self._slope, self._theta, self._meff, self._effort = (np.zeros(na) for _ in range(5))
        self._flow = np.zeros(len(net.branch_names))
        self._passive = np.zeros(nv)
        self._work = np.zeros(K.coupled_work_size(C.work_size(self._F, self._I), n, na, len(net.branch_names), nr))
        self._scratch = np.zeros(scratch_size(na, n, len(net.branch_names), net.component_state_count))
        self._kept_views = np.zeros(kept_words(), np.int64)
        self._istats = np.zeros(C.NIS, np.int64)
        self._pmax, self._pmin = np.zeros(n), np.zeros(n)
        self._xmax, self._xmin = np.zeros(na), np.zeros(na)
        self._fs = np.zeros(NFS)
        self._fs[FS_DT] = self.dt
        self._quad = potential_quadrature()
        self._capacity = 0
        self._cmd = self._speed = None
        self._inputs = input_plan(net, self.control, scenario.inputs)
        ctx = np.zeros(NCTX, np.int64)
        ctx[SLOT.C_SUBSTEPS] = stepper.substeps
        ctx[SLOT.C_LINEAR] = inner.scheme if kind == KIND_IMPLICIT else 0  # hydraulics.coupling.SCHEME_*
        ctx[SLOT.C_KIND] = kind
        ctx[SLOT.C_NR] = nr if kind != KIND_INCOMPRESSIBLE else 0
        self._record_width = self.record_width
        arrays = dict(
            F=self._F, I=self._I, TF=self._TF, TI=self._TI, length=d.actuator_length, avel=d.actuator_velocity,
            moment=d.actuator_moment, rowadr=d.moment_rowadr, rownnz=d.moment_rownnz, colind=d.moment_colind, qvel=d.qvel,
            ctrl=d.ctrl, bias=m.actuator_biasprm, passive=d.qfrc_passive, constraint=d.qfrc_constraint,
            flimited=m.actuator_forcelimited, frange=m.actuator_forcerange, qpos=d.qpos, bxpos=d.xpos, bxquat=d.xquat,
            energy=d.energy, act=self._act, closed=self._closed, J=self._J, MinvJ=self._MinvJ, xs=self._xs, vs=self._vs,
            const=self._const, slope=self._slope, lower=self._lower, upper=self._upper, theta=self._theta, meff=self._meff,
            effort=self._effort, passive_saved=self._passive, oil=self._oil, pres=self._p, spool=self._spool, pos=self._x,
            vel=self._v, flow=self._flow, oil_change=self._oil_change, pmax=self._pmax, pmin=self._pmin, xmax=self._xmax,
            xmin=self._xmin, fs=self._fs, quad=self._quad, W=self._work, S=self._scratch, istats=self._istats,
            ctl_table=self.controllers.table, ctl_state=self.controllers.state, kept_views=self._kept_views)
        # (checked against POINTERS: dtype, contiguity, size; cmd, speed, ctl_set: _sample_inputs; rec: advance)
        POINTERS.register(ctx, arrays, na=na, nv=nv, nu=m.nu, n=n, nb=len(net.branch_names), nvalve=len(net.valve_names),
                          npump=len(net.pump_names), nbias=m.actuator_biasprm.shape[1], nstate=net.component_state_count,
                          nnz=d.actuator_moment.size, rows=0, nf=self._F.size, ni=self._I.size, nw=self._work.size,
                          ns=self._scratch.size, ntf=self._TF.size, nti=self._TI.size, nq=m.nq, nbody=m.nbody,
                          nctl=len(self.controllers), rec_rows=0, rec_width=self._record_width,
                          nkept=self._kept_views.size)
        ctx[SLOT.P_REC] = 0  # set by advance() for a block that records
        self._keep = arrays  # the arrays must outlive the table
        self._ctx = ctx
        callback()

    def reset(self) -> None:
        """As :meth:`MujocoPlant.reset`; the running pressure and actuator-coordinate extremes restart from the
        initial state (:meth:`PlantBase.reset_extremes`)."""
        super().reset()
        self.reset_extremes()

    # ------------------------------------------------------------------ inputs
    def _sample_inputs(self, n):
        """Controls of the next n steps (rows), as PlantBase.apply_inputs at each step's time."""
        if n > self._capacity:
            self._capacity = max(n, 2 * self._capacity)
            self._cmd = np.zeros((self._capacity, len(self.network.valve_names)))
            self._speed = np.zeros((self._capacity, len(self.network.pump_names)))
            self._step_numbers = np.arange(self._capacity)
            self._setpoint = np.zeros((self._capacity, len(self.controllers)))
            # the callback reads rows of the whole buffers (row stride = capacity rows)
            POINTERS.register(self._ctx, dict(cmd=self._cmd, speed=self._speed, ctl_set=self._setpoint),
                              rows=self._capacity)
        cmd, speed = self._cmd[:n], self._speed[:n]
        cmd[:] = self.control.valve_command
        speed[:] = self.control.pump_speed
        if self._inputs:
            times = (self._step_numbers[:n] + self.step_index) * self.dt  # = (np.arange(n) + step_index)·dt
            sample_inputs(self._inputs, times, cmd, speed)
        if len(self.controllers):
            self.controllers.setpoint_rows((self._step_numbers[:n] + self.step_index) * self.dt, self._setpoint[:n])
        return cmd, speed

    # -------------------------------------------------------------------- step
    def step(self):
        """Advance one step of ``dt``; returns the hydraulic step report."""
        return self.advance(1)

    # ------------------------------------------------------------------ record
    @property
    def record_width(self) -> int:
        """Floats per row of :meth:`advance`'s ``record`` (see :meth:`record_row` for the layout); worked out once per
        plant (the layout's sizes are the model's and the network's, fixed when the plant is built)."""
        width = getattr(self, "_record_width", None)
        if width is not None:
            return width
        m, net = self.model, self.network
        return RECORD_ROW.size(n=net.node_count, nq=m.nq, nv=m.nv, na=net.actuator_count, nvalve=len(net.valve_names),
                               nstate=net.component_state_count, npump=len(net.pump_names), nb=len(net.branch_names),
                               nbody=m.nbody, nctl=self.controller_state.shape[0])

    def record_row(self, out: np.ndarray) -> None:
        """Write the current state into ``out`` (``record_width`` floats), as :meth:`advance` records a step.

        Layout, SI units: node pressures [Pa], ``qpos``, ``qvel``, node oil [m³ at reference density],
        actuator positions [m|rad], velocities, efforts [N|N·m], θ [-], valve commands, component states (valve spools
        [-] first),
        pump speeds [rev/s], branch flows [m³/s], Newton iterations and residual [Pa] of the last step,
        kinetic and potential energy [J], pump work, hydraulic, friction and mechanical dissipation [J],
        body positions ``xpos`` (nbody×3) [m] and quaternions ``xquat`` (nbody×4), the controllers' states
        (``hydraulics.controllers.STATE_COLUMNS`` per controller).  Refreshes the kinematics
        (:meth:`mechanical_energy`), as observing always does.
        """
        state, e, report = self.net_state, self.energy, self.last_report
        kinetic, potential = self.mechanical_energy()
        d = self.data
        if report is None:
            flow, solver = np.zeros(len(self.network.branch_names)), (0.0, 0.0)
        else:
            flow, solver = report.branch_flow, (report.newton_iterations, report.residual)
        np.concatenate((state.node_pressure, d.qpos, d.qvel, state.node_oil, state.actuator_position,
                        state.actuator_velocity, self.effort, self.theta, self.control.valve_command, state.valve_spool,
                        self.control.pump_speed, flow, solver, (kinetic, potential, e.pump_work, e.dissipated_hydraulic,
                                                              e.dissipated_friction, e.dissipated_mechanical),
                        d.xpos.reshape(-1), d.xquat.reshape(-1), self.controller_state.reshape(-1)), out=out)

    @staticmethod
    def record_rows(step_index: int, n: int, every: int) -> int:
        """Rows :meth:`advance` (n, record, every) records from ``step_index``: the steps s < ``step_index + n``
        after which the step index is a multiple of ``every`` (the block's last step is never recorded)."""
        first = (every - (step_index + 1) % every) % every  # block-local index of the first recorded step
        return 0 if first > n - 2 else (n - 2 - first) // every + 1

    def record_next(self, record: np.ndarray, every: int = 1) -> None:
        """Make the next :meth:`advance` call that is given no ``record`` record into ``record`` every ``every`` steps.

        The same as passing them to that call; for callers that go through a wrapped ``advance(n)``
        (instrumentation, fault injection) and so cannot pass them.
        """
        self._record_next = (record, every)

    # -------------------------------------------------------------------- step
    def advance(self, n: int, record: np.ndarray | None = None, every: int = 1):
        """Advance ``n`` coupled steps in one ``mj_step(m, d, nstep=n)``; returns the last step's report.

        Stops early only in the sense that a failed hydraulic step freezes the
        network (see module docstring); ``step_index`` then points at the failure.

        With ``record`` (float64, C-contiguous, shape (≥ rows, :attr:`record_width`)), the state at
        the end of every step after which ``step_index`` is a multiple of ``every`` (all but the
        block's last step; ``rows`` = :meth:`record_rows`) is copied into the next row of
        ``record``, as :meth:`record_row` would copy it after that step, from inside the compiled
        loop: a caller that samples every few steps need not stop MuJoCo at each sample.
        ``recorded`` then holds the number of rows written (fewer after a failed step: the rows
        from the failed step on are not written), ``recorded_finite`` whether their node pressures,
        ``qpos`` and ``qvel`` are all finite, and ``end_finite`` the same of the state after the
        block (:meth:`finite`, computed in the compiled loop).
        """
        n = int(n)
        if n < 1:
            raise ValueError(f"`n` must be >= 1, got {n!r}")
        if record is None and self._record_next is not None:
            record, every = self._record_next
        self._record_next = None
        every = int(every)
        if every < 1:
            raise ValueError(f"`every` must be >= 1, got {every!r}")
        if self.python_controller is not None and not self._in_control:  # blocks of one control period
            self._in_control = True
            try:
                return advance_controlled(self, self.advance, n, record, every)
            finally:
                self._in_control = False
        self.recorded = 0
        self.recorded_finite = True
        rows = 0
        if record is not None:
            first = (every - (self.step_index + 1) % every) % every  # block-local index of the first recorded step
            rows = 0 if first > n - 2 else (n - 2 - first) // every + 1  # record_rows()
            width = self._record_width if self.fast else self.record_width
            flags = getattr(record, "flags", None)
            if not (isinstance(record, np.ndarray) and record.dtype == np.float64 and record.ndim == 2
                    and flags.c_contiguous and flags.writeable and record.shape[1] == width and record.shape[0] >= rows):
                raise ValueError(f"`record` must be a writable C-contiguous float64 array of shape (>= {rows}, {width}), "
                                 f"got {getattr(record, 'dtype', type(record).__name__)} {getattr(record, 'shape', '')}")
        if not self.fast:
            for _ in range(n):
                report = MujocoPlant.step(self)
                if not report.success:
                    break
                self.node_pressure_max = np.maximum(self.node_pressure_max, self.net_state.node_pressure)
                self.node_pressure_min = np.minimum(self.node_pressure_min, self.net_state.node_pressure)
                self.actuator_position_max = np.maximum(self.actuator_position_max, self.net_state.actuator_position)
                self.actuator_position_min = np.minimum(self.actuator_position_min, self.net_state.actuator_position)
                if self.recorded < rows and self.step_index % every == 0:
                    self.record_row(record[self.recorded])
                    self.recorded += 1
                    self.recorded_finite = self.recorded_finite and self.finite()
            self.end_finite = self.finite()
            return report
        state = self.net_state
        self._oil[:] = state.node_oil
        self._oil_change[:] = state.flat_oil_change()
        self._p[:] = state.node_pressure
        self._spool[:] = state.valve_spool
        self._x[:] = state.actuator_position
        self._v[:] = state.actuator_velocity
        self._pmax[:] = self.node_pressure_max
        self._pmin[:] = self.node_pressure_min
        self._xmax[:] = self.actuator_position_max
        self._xmin[:] = self.actuator_position_min
        self._theta[:] = self.theta  # (only the implicit law sets θ; the others keep it)
        e = self.energy
        fs = self._fs
        fs[FS_PUMP], fs[FS_MOTOR], fs[FS_DISS_H] = e.pump_work, e.motor_work, e.dissipated_hydraulic
        fs[FS_DISS_F], fs[FS_DISS_M] = e.dissipated_friction, e.dissipated_mechanical
        cmd, speed = self._sample_inputs(n)
        ctx = self._ctx
        ctx[SLOT.C_STEP0] = self.step_index
        ctx[_BLOCK_START[0]] = _BLOCK_START[1]
        if rows:
            POINTERS.register(ctx, dict(rec=record[:rows]), rec_rows=rows)
            ctx[[SLOT.C_REC_EVERY, SLOT.C_REC_FIRST, SLOT.C_REC_COUNT, SLOT.C_REC_BAD]] = every, first, 0, 0
        if not _LOCK.acquire(blocking=False):
            raise RuntimeError("another MujocoPlantFast is stepping in this process (MuJoCo's control callback is global)")
        resets = mujoco_resets(self.data)
        try:
            _CTX[:] = ctx
            previous = mujoco.get_mjcb_control()
            mujoco.set_mjcb_control(_CALLBACK_POINTER)
            try:
                mujoco.mj_step(self.model, self.data, nstep=n)
            finally:
                mujoco.set_mjcb_control(previous)
            if self.realised_end:  # the last step ends at MuJoCo's positions too (MujocoPlant.end_position)
                mujoco.mj_fwdPosition(self.model, self.data)
            _finish_python()
            failed, status, worst, newton, rhs, jac = _CTX[_OUTCOME].tolist()
            if rows:
                self.recorded, bad = _CTX[[SLOT.C_REC_COUNT, SLOT.C_REC_BAD]].tolist()
                self.recorded_finite = bad == 0
            self.end_finite = bool(_CTX[SLOT.C_END_FINITE])
        finally:
            ctx[SLOT.P_REC] = _CTX[SLOT.P_REC] = ctx[SLOT.C_REC_ROWS] = _CTX[SLOT.C_REC_ROWS] = 0
            _LOCK.release()
        steps = n if failed < 0 else failed + 1
        last = steps - 1
        self.control.valve_command[:] = cmd[last]
        self.control.pump_speed[:] = speed[last]
        self.step_index += steps
        self.net_state = NetworkState(self._oil.copy(), self._p.copy(), self._spool.copy(), self._x.copy(), self._v.copy(),
                                      state.time + steps * self.dt, self._oil_change.copy())
        e.pump_work, e.motor_work, e.dissipated_hydraulic = float(fs[FS_PUMP]), float(fs[FS_MOTOR]), float(fs[FS_DISS_H])
        e.dissipated_friction, e.dissipated_mechanical = float(fs[FS_DISS_F]), float(fs[FS_DISS_M])
        self.effort = self._effort.copy()
        self.theta = self._theta.copy()
        self.node_pressure_max = self._pmax.copy()
        self.node_pressure_min = self._pmin.copy()
        self.actuator_position_max = self._xmax.copy()
        self.actuator_position_min = self._xmin.copy()
        report = StepReport(newton_iterations=newton, rhs_evaluations=rhs, jacobian_evaluations=jac,
                            residual=float(fs[FS_NORM]), branch_flow=self._flow.copy())
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
        if report.success:  # (a reset inside the block: the runner replays it step by step to find the step)
            mark_reset(report, resets, self.data)
        self.last_report = report
        return report


__all__ = ["MujocoPlantFast", "callback"]
