"""One whole PBD frame (all XPBD substeps of one plant step, with the hydraulic coupling) in one compiled call.

Per substep, in the order of the Python hooks around :meth:`sim.xpbd.SolverXPBD.step`
(``tests/reference/pbd_hooks.py``, whose results the frame equals to round-off):

1. the effort law c + s·v⁺ of every actuator and its bounds (``pbd_hydraulics._begin_core``, by the coupling's
   kind; θ = 1, or with ``blend`` from the step's effective masses, written to ``theta``).  With ``transport``
   (``sim.plants.pbd_block.block(transport=True)``), from the second substep on, the step's articulated
   responses (row mobilities, group gravity + motor responses) are carried to the substep's pose through joint
   space (``compiled.transport``, as ``SolverXPBD.transport_response``);
2. cylinder rows: compliant rows α = −h/s, ℓ* = ℓ₀ − h·c/s where s < −1e-9, their multipliers bounded by the law's
   effort bounds; otherwise (and every row in the seed's ``naive`` scheme) explicit row forces
   clip(c + s·v₀, lower, upper); motors: backward Euler on the joint, effort
   (c + s·v)/(1 + max(−s, 0)·gear²·h·(M⁻¹)ⱼⱼ), clipped to the bounds;
3. the loads: with the step's joint-space data (trees of hinges and slides with a regular mass matrix), gravity,
   the motor efforts and the explicit row forces enter as group accelerations through the articulated response
   (the naive scheme's row forces as forces on the rows' two groups); without it (other joints, a singular mass
   matrix) plain XPBD: gravity on every body, hinge motors as torque impulses, slide motors and explicit row
   forces as forces on the two groups, effective masses unknown (θ = 1);
4. the XPBD substep (``compiled.substep_core``) and the body write-back (``compiled.scatter``);
5. realised ℓ, v⁺ = (ℓ − ℓ₀)/h and motor joint rates (hinges: relative angular velocity along the axis;
   slides: relative velocity of the child's frame origin along it) finish the network step and the energy
   ledger (``pbd_hydraulics._finish_core``); the actuator efforts' work on the bodies h·f·(v₀ + v⁺)/2.

The operator inputs are sampled for every substep beforehand (rows of ``cmd``/``speed``).

The frame is compiled into the block's entry point (:mod:`sim.plants.pbd_block`, :func:`compile_helpers`);
the articulated response's own entry point (:func:`articulated`, called by the hooks path) is cached under a
sha256 of this file, ``pbd_hydraulics.py``, ``compiled.py`` and the hydraulic kernel sources
(``hydraulics._jit.SOURCES``, and numba's version) as a closure variable.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

from hydraulics import _compiled as C
from hydraulics.layout import slots

from sim.xpbd import compiled as XC
from sim.plants import pbd_hydraulics as H

OUT = slots(("WORK", "SUBSTEPS_OK"))
"""Entries of ``ActuatorState.out`` (float64): the frame's work of the efforts on the bodies [J], its successful
hydraulic substeps."""

IMPLICIT_SLOPE_LIMIT = -1e-9  # [N·s/m]: a law slope above this is an explicit row force, not a compliant row

# frame status
FRAME_OK, FRAME_SINGULAR = 0, 1

# ---------------------------------------------------------------------------- named layouts
# nb bodies, ng rigid groups, nj joints (= DOFs), na actuators, nr cylinder rows, nm motors (hinge or slide).

RigidState = namedtuple("RigidState", [
    "x", "q", "v", "w",  # COM position [m], orientation (w, x, y, z), velocity [m/s], angular velocity [rad/s]
])

Actuation = namedtuple("Actuation", [
    "cyl",  # actuator of each cylinder row, (nr,)
    "closed",  # closed length of each cylinder row [m], (nr,)
    "row_group",  # groups (a, b) of each cylinder row, (nr, 2)
    "row_vec",  # site offsets in the group frames [m], (nr, 2, 3)
    "mot",  # actuator of each motor, (nm,)
    "gear",  # motor gear [-], (nm,)
    "mjoint",  # joint of each motor, (nm,)
    "mhinge",  # the motor's joint is a hinge (else a slide), (nm,)
    "mbody",  # body of each motor joint, (nm,)
    "mparent",  # its parent body, (nm,)
    "maxis",  # motor joint axis in the body's inertial frame, (nm, 3)
    "morigin",  # the motor body's frame origin in its inertial frame [m] (slides: the point whose rate counts), (nm, 3)
    "islands",  # ``compiled.Islands`` of the mechanism (rows, motors and groups by island)
])

ActuatorState = namedtuple("ActuatorState", [
    "x",  # actuator position [m or rad], (na,)
    "v",  # actuator velocity [m/s or rad/s], (na,)
    "ell",  # cylinder row length [m], (nr,)
    "effort",  # actuator effort [N or N·m], (na,)
    "motor_effort",  # motor effort [N·m], (nm,)
    "out",  # work of the efforts on the bodies [J], successful hydraulic substeps: (len(OUT),) by OUT
])

Articulated = namedtuple("Articulated", [
    "mobility",  # group motion per unit row multiplier, (nr, ng, 6)
    "group_gravity",  # group accelerations of q̈ = M⁻¹·Q_gravity, (ng, 6)
    "motor_response",  # group accelerations per unit motor effort, (nm, ng, 6)
    "motor_inverse_inertia",  # (M⁻¹)ⱼⱼ of each motor joint, (nm,)
    "effective_mass",  # 1/(J·M⁻¹·Jᵀ)ᵢᵢ per actuator [kg or kg·m²], (na,)
])

ArticulatedModel = namedtuple("ArticulatedModel", [
    "iquat", "ipos",  # inertial frame of each body, (nb, 4), (nb, 3)
    "jnt_body", "jnt_axis", "jnt_pos",  # joint body, axis and anchor in the body frame, (nj,), (nj, 3), (nj, 3)
    "hinge",  # joint is a hinge (else a slide), (nj,)
    "subtree",  # body b moves with joint j, (nj, nb)
    "body_mass", "inertia",  # [kg], principal inertia [kg·m²], (nb,), (nb, 3)
    "armature",  # joint armature [kg·m² or kg], (nj,)
    "gravity",  # [m/s²], (3,)
    "site_body", "site_pos",  # sites: body, position in the body's inertial frame [m]
    "row_sites",  # sites (a, b) of each cylinder row, (nr, 2)
    "cyl", "mot", "mot_dof", "gear",  # actuators of the rows and motors, motor DOFs and gears
    "body_group", "group_mass", "group_root", "group_dynamic",  # rigid groups
    "islands",  # ``compiled.Islands``: the joints, bodies, groups, rows and motors of each island
])

FrameSettings = namedtuple("FrameSettings", [
    "h",  # substep [s]
    "substeps",  # substeps per frame, int
    "iterations", "symmetric", "linear_damping", "angular_damping",  # as ``compiled.SubstepOptions``
    "soft_contacts", "pyramid_friction", "velocity_sweeps",  # as ``compiled.SubstepOptions``
    "kind",  # the coupling's ``pbd_hydraulics.KIND_*``
    "scheme",  # the implicit coupling's ``hydraulics.coupling.SCHEME_*``
    "blend",  # θ from the effective masses (else θ = 1), bool
    "naive",  # the seed's scheme: every cylinder row an explicit force on its two rigid groups, bool
])

FrameWork = namedtuple("FrameWork", [
    "target", "compliance", "lower", "upper", "active", "implicit", "row_force",  # per cylinder row
    "force", "torque", "group_acceleration", "joint_torque",  # the substep's loads
    "lam", "length", "rate",  # row outputs
    "x_end", "v_end",  # actuator end states
    "G", "P0", "mobility",  # transport: group Jacobian, its pseudo-inverse at the start, transported mobility
    "substep",  # ``compiled.SubstepWork``
    "unknown_mass",  # NaN per actuator: the effective masses of a frame without joint-space data, (na,)
])


def frame_work(nr, na, ng, nj, mob_shape, ntl, ncap):
    """The ``FrameWork`` of ``_frame`` (made once per block by ``pbd_block``)
    for ``nr`` length rows, ``na`` actuators, ``ng`` groups, ``nj`` joints, the row mobility's shape, ``ntl`` tendon
    limits and up to ``ncap`` contact candidates."""
    return FrameWork(np.empty(nr), np.empty(nr), np.full(nr, -np.inf), np.full(nr, np.inf), np.empty(nr, np.int64),
                     np.empty(nr, np.bool_), np.zeros(nr), np.zeros((ng, 3)), np.zeros((ng, 3)), np.empty((ng, 6)),
                     np.zeros(nj), np.empty(nr), np.empty(nr), np.empty(nr), np.empty(na), np.empty(na),
                     np.zeros((ng, 6, nj)), np.zeros((nj, ng * 6)), np.empty(mob_shape),
                     XC.substep_work(ng, nj, ntl, ncap, nr), np.full(na, np.nan))


@njit(inline="always")
def _add_through_response(gg, isl, ptr, members, effort, response):
    """gg[g] += Σ_k effort[k]·response[k, g] [6-vectors per group], island by island: the members k of each island
    (``members[ptr[i]:ptr[i + 1]]``: its motors or rows) move only that island's groups, so nothing outside it is
    visited."""
    for island in range(ptr.shape[0] - 1):
        k0, k1 = ptr[island], ptr[island + 1]
        for t in range(isl.group_ptr[island], isl.group_ptr[island + 1]):
            g = isl.groups[t]
            for c in range(6):
                s = 0.0
                for u in range(k0, k1):
                    k = members[u]
                    s += effort[k] * response[k, g, c]
                gg[g, c] += s


@njit(inline="always")
def _pair_force(g1, g2, r1, r2, f, Fe, Te):
    """The world force ``f`` [N] on group ``g2`` at its offset ``r2`` and −``f`` on ``g1`` at ``r1`` (world offsets
    from the groups' centres of mass [m]) added to the per-group forces and torques ``Fe``, ``Te``."""
    t2 = XC._cross(r2, f)
    t1 = XC._cross(r1, f)
    for c in range(3):
        Fe[g2, c] += f[c]
        Te[g2, c] += t2[c]
        Fe[g1, c] -= f[c]
        Te[g1, c] -= t1[c]


def _frame(hyd, cmd, speed, groups, bodies, model, articulated, contacts, actuation, actuators, settings, fwork,
           variant):
    """One frame (see the module docstring).

    ``hyd``: the network's ``pbd_hydraulics.HydraulicBuffers``; ``cmd``/``speed``: valve commands and pump speeds
    of every substep (substeps, nvalve/npump); ``groups``/``bodies``: the ``RigidState`` of the rigid groups and of
    the bodies (written in place); ``model``: ``compiled.GroupModel``; ``articulated``: the step's ``Articulated``
    data; ``contacts``: the frame's candidates (``compiled.ContactRows``); ``actuation``, ``actuators``: the
    ``Actuation`` layout and the ``ActuatorState`` (updated); ``settings``: ``FrameSettings``; ``fwork``: the
    ``FrameWork`` (:func:`frame_work`, for at least this frame's contacts; overwritten); ``variant`` = (transport,
    articulated contacts, joint space): carry the articulated responses to each substep's pose, solve the contacts
    with the articulated response, and whether ``articulated`` holds this frame's joint-space data (else the
    free-body response of plain XPBD: gravity per body, explicit forces and motor efforts on the groups).
    Returns ``FRAME_OK`` or ``FRAME_SINGULAR``."""
    transport, art_contacts, joint_space = variant
    net = C._unpack(hyd.F, hyd.I)
    pnet = C._ref(net)
    Xg, Qg, Vg, Wg = groups.x, groups.q, groups.v, groups.w
    bx, bq, bv, bw = bodies.x, bodies.q, bodies.v, bodies.w
    IM, jt, jg, jvec = model.IM, model.jt, model.jg, model.jvec
    h, substeps = settings.h, settings.substeps
    coupling = (settings.kind, settings.scheme, settings.blend and joint_space)
    naive = settings.naive
    mob, gg0, mresp, minv = (articulated.mobility, articulated.group_gravity, articulated.motor_response,
                             articulated.motor_inverse_inertia)
    meff = articulated.effective_mass if joint_space else fwork.unknown_mass
    cyl, closed, mot, gear = actuation.cyl, actuation.closed, actuation.mot, actuation.gear
    mjoint, mhinge, mbody, mparent = actuation.mjoint, actuation.mhinge, actuation.mbody, actuation.mparent
    maxis, morigin, rgroup, rvec = actuation.maxis, actuation.morigin, actuation.row_group, actuation.row_vec
    x, v, ell0, effort, motor_effort, out = (actuators.x, actuators.v, actuators.ell, actuators.effort,
                                             actuators.motor_effort, actuators.out)
    const, slope, lower, upper, istats = hyd.constant, hyd.slope, hyd.lower, hyd.upper, hyd.istats
    options = XC.SubstepOptions(settings.iterations, settings.symmetric, settings.linear_damping,
                                settings.angular_damping, art_contacts, settings.soft_contacts,
                                settings.pyramid_friction, settings.velocity_sweeps)
    na = x.size
    nr = cyl.size
    nm = mot.size
    ng = Xg.shape[0]
    tgt, at, lo, hi, act, implicit, rforce = (fwork.target, fwork.compliance, fwork.lower, fwork.upper, fwork.active,
                                              fwork.implicit, fwork.row_force)
    Fe, Te, gg, tau = fwork.force, fwork.torque, fwork.group_acceleration, fwork.joint_torque
    lam, ell, rate, x_end, v_end = fwork.lam, fwork.length, fwork.rate, fwork.x_end, fwork.v_end
    Gk, P0, mobk, swork = fwork.G, fwork.P0, fwork.mobility, fwork.substep
    isl = actuation.islands
    # hinge motors' torques as impulses where there is no joint-space response (a runtime bool: one signature)
    use_tau = False
    if not joint_space:
        for i in range(nm):
            if mhinge[i]:
                use_tau = True
    loads = XC.SubstepLoads(joint_space, gg, Fe, Te, use_tau, tau)
    row_out = XC.RowOutputs(lam, ell, rate)
    for r in range(nr):
        lo[r], hi[r], rforce[r] = -np.inf, np.inf, 0.0
    tau[:] = 0.0  # (G, P0, and the substep's G, M⁻¹ are written where they are used: group_jacobian, ...)
    if not joint_space:
        gg[:, :] = 0.0
    hh = h * h
    work = 0.0
    out[OUT.SUBSTEPS_OK] = 0.0
    # articulated responses carried to each substep's pose (SolverXPBD.transport_response)
    nj = jt.shape[0]
    carry = (joint_space and transport and nj > 0 and substeps > 1 and XC.group_jacobian(Xg, Qg, IM, jt, jg, jvec, Gk)
             and XC.jacobian_pinv(Gk, P0))
    for k in range(substeps):
        control = (cmd[k], speed[k])
        if not H._begin_core(pnet, hyd, control, x, v, h, coupling, meff):
            out[OUT.WORK] = work
            return FRAME_SINGULAR
        nact = 0
        any_force = False
        for r in range(nr):
            a = cyl[r]
            c, s = const[a], slope[a]
            implicit[r] = s < IMPLICIT_SLOPE_LIMIT and not naive
            if implicit[r]:
                tgt[r] = ell0[r] - h * c / s
                at[r] = (-h / s) / hh
                lo[r], hi[r] = lower[a] * hh, upper[a] * hh
                rforce[r] = 0.0
                act[nact] = r
                nact += 1
            else:
                tgt[r] = np.nan
                at[r] = 0.0
                rforce[r] = C._clip(c + s * v[a], lower[a], upper[a])
                if rforce[r] != 0.0:
                    any_force = True
        for i in range(nm):
            a = mot[i]
            damping = max(-slope[a], 0.0) * gear[i] ** 2 * h * minv[i]
            motor_effort[i] = C._clip((const[a] + slope[a] * v[a]) / (1.0 + damping), lower[a], upper[a])
        if joint_space:  # motor efforts through the articulated response (zero outside the motor's island), gravity
            gg[:, :] = gg0
            if nm:
                _add_through_response(gg, isl, isl.motor_ptr, isl.motors, motor_effort, mresp)
        Fe[:, :] = 0.0
        Te[:, :] = 0.0
        if not joint_space:  # as joint forces: hinge torques as impulses, slide forces on the two groups
            for i in range(nm):
                j = mjoint[i]
                if mhinge[i]:
                    tau[j] = gear[i] * motor_effort[i]
                    continue
                g1, g2 = jg[j, 0], jg[j, 1]
                axis = XC._rot(XC._q4(Qg, g1), XC._v3(jvec[j], 2))
                f = gear[i] * motor_effort[i]
                d = (Xg[g2, 0] - Xg[g1, 0], Xg[g2, 1] - Xg[g1, 1], Xg[g2, 2] - Xg[g1, 2])
                _pair_force(g1, g2, d, (0.0, 0.0, 0.0), (f * axis[0], f * axis[1], f * axis[2]), Fe, Te)
        if any_force and joint_space and not naive:  # explicit row forces through the articulated response
            _add_through_response(gg, isl, isl.row_ptr, isl.rows, rforce, mob)
        elif any_force:  # explicit row forces on the rows' two groups (plain XPBD, the seed's scheme)
            for r in range(nr):
                if rforce[r] == 0.0:
                    continue
                ga, gb = rgroup[r, 0], rgroup[r, 1]
                ra = XC._rot(XC._q4(Qg, ga), XC._v3(rvec[r], 0))
                rb = XC._rot(XC._q4(Qg, gb), XC._v3(rvec[r], 1))
                d = (Xg[gb, 0] + rb[0] - Xg[ga, 0] - ra[0], Xg[gb, 1] + rb[1] - Xg[ga, 1] - ra[1],
                     Xg[gb, 2] + rb[2] - Xg[ga, 2] - ra[2])
                f = rforce[r] / np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
                _pair_force(ga, gb, ra, rb, (f * d[0], f * d[1], f * d[2]), Fe, Te)
        row_mobility = mob  # the step's responses as given (read only)
        if carry and k > 0:
            XC.group_jacobian(Xg, Qg, IM, jt, jg, jvec, Gk)
            for r in range(nr):
                XC.transport(Gk, P0, mob[r], mobk[r])
            XC.transport(Gk, P0, gg, gg)
            row_mobility = mobk
        rows = XC.SubstepRows(rgroup, rvec, act[:nact], tgt, at, lo, hi, nact > 0 and joint_space, row_mobility, isl)
        XC.substep_core(Xg, Qg, Vg, Wg, model, rows, contacts, loads, options, h, row_out, swork)
        XC.scatter(Xg, Qg, Vg, Wg, model.body_group, model.in_group_quat, model.in_group_pos, bx, bq, bv, bw)
        # end of the substep: realised motion
        for a in range(na):
            x_end[a] = x[a]
            v_end[a] = v[a]
        for r in range(nr):
            a = cyl[r]
            x_end[a] = ell[r] - closed[r]
            v_end[a] = (ell[r] - ell0[r]) / h
        for i in range(nm):
            b, p = mbody[i], mparent[i]
            ax = XC._rot(XC._q4(bq, b), XC._v3(maxis, i))
            if mhinge[i]:
                rate_j = (bw[b, 0] - bw[p, 0]) * ax[0] + (bw[b, 1] - bw[p, 1]) * ax[1] + (bw[b, 2] - bw[p, 2]) * ax[2]
            else:  # relative velocity of the child's body-frame origin along the axis
                o = XC._rot(XC._q4(bq, b), XC._v3(morigin, i))
                rb = (o[0], o[1], o[2])
                rp = (bx[b, 0] + o[0] - bx[p, 0], bx[b, 1] + o[1] - bx[p, 1], bx[b, 2] + o[2] - bx[p, 2])
                wb = XC._cross(XC._v3(bw, b), rb)
                wp = XC._cross(XC._v3(bw, p), rp)
                rate_j = 0.0
                for c in range(3):
                    rate_j += ((bv[b, c] + wb[c]) - (bv[p, c] + wp[c])) * ax[c]
            a = mot[i]
            v_end[a] = gear[i] * rate_j
            x_end[a] = x[a] + h * v_end[a]
        for a in range(na):
            effort[a] = 0.0
        for r in range(nr):
            effort[cyl[r]] = lam[r] / hh if implicit[r] else rforce[r]
        for i in range(nm):
            effort[mot[i]] = motor_effort[i]
        H._finish_core(pnet, hyd, control, (x_end, v_end, v), h, coupling, effort)
        out[OUT.SUBSTEPS_OK] += istats[H.I_LAST_OK]
        # v_next: cylinder speeds as the bodies now move; work trapezoidal in the actuator speeds
        for r in range(nr):
            v_end[cyl[r]] = rate[r]
        s = 0.0
        for a in range(na):
            s += effort[a] * (v[a] + v_end[a])
        work += 0.5 * h * s
        for r in range(nr):
            ell0[r] = ell[r]
        for a in range(na):
            x[a] = x_end[a]
            v[a] = v_end[a]
    out[OUT.WORK] = work
    return FRAME_OK


# every source compiled into the frame (this file, pbd_hydraulics.py, compiled.py, the hydraulic kernel sources), taken at
# import: part of the cache key
SOURCE_SHA256 = C.source_sha256(__file__, H.__file__, XC.__file__, *C.SOURCES)


_frame_jit = _frame_work_jit = None


def compile_helpers() -> None:
    """Make ``_frame_jit`` and ``_frame_work_jit`` exist: the frame compiled into the block's entry point
    (:func:`sim.plants.pbd_block.block`), not cached on its own (the block's cache key covers this file)."""
    global _frame_jit, _frame_work_jit
    if _frame_jit is None:
        import numba

        _frame_jit = numba.njit(error_model="numpy")(_frame)
        _frame_work_jit = numba.njit(error_model="numpy")(frame_work)


# ---------------------------------------------------------------------------- articulated response


def articulated_work(nb, nj, na, ng):
    """The work arrays of ``_articulated_into`` for ``nb`` bodies, ``nj`` joints, ``na`` actuators and ``ng`` groups
    (made once per block by ``pbd_block``): body frames, joint axes and anchors, joint-to-body Jacobians, mass
    matrix, right-hand sides, moment arms, the eliminated matrix, the group Jacobians and an island's actuator
    columns."""
    return (np.empty((nb, 3)), np.empty((nb, 4)), np.empty((nj, 3)), np.empty((nj, 3)), np.empty((nj, nb, 3)),
            np.empty((nj, nb, 3)), np.empty((nj, nj)), np.empty((nj, na + 1)), np.empty((na, nj)), np.empty((nj, nj)),
            np.empty((nj, ng, 3)), np.empty(na + 1, np.int64))


def _articulated(x, q, model, out):
    """``PbdPlant.articulated`` for trees of hinges and slides (one DOF per joint, joint j = DOF j) at the body
    state x [m], q (nb, 3), (nb, 4) on the ``ArticulatedModel`` ``model``, into the ``Articulated`` ``out``;
    returns False when the mass matrix is singular (outputs untouched).  ``_articulated_into`` on fresh work
    arrays."""
    work = _articulated_work_jit(x.shape[0], model.jnt_body.shape[0], out.effective_mass.size, model.group_mass.size)
    return _articulated_into_jit(work, x, q, model, out)


@njit(inline="always")
def _island_columns(isl, island, cyl, mot, na, cols):
    """The actuator columns of island ``island`` (its rows' and motors' actuators, then the gravity column ``na``)
    into ``cols``; returns how many."""
    n = 0
    for t in range(isl.row_ptr[island], isl.row_ptr[island + 1]):
        cols[n] = cyl[isl.rows[t]]
        n += 1
    for t in range(isl.motor_ptr[island], isl.motor_ptr[island + 1]):
        cols[n] = mot[isl.motors[t]]
        n += 1
    cols[n] = na
    return n + 1


def _articulated_into(work, x, q, model, out):
    """``_articulated`` on the work arrays ``work`` (:func:`articulated_work`; overwritten): no allocation.

    Island by island (``model.islands``, ``compiled.islands``): a joint moves only its island's bodies, so the mass
    matrix M, the moment arms Jᵀ and Δq = M⁻¹·[Jᵀ, Q_gravity] are block diagonal by island and each island's
    block is built and eliminated on its own — the operations of the whole matrix without its zero blocks, so
    the results equal the whole matrix's (``compiled.single_island``) — in O(Σ nᵢ²) for nᵢ joints, bodies and
    actuators of island i.  The outputs' entries outside a column's island (mobility and responses of the groups
    of other islands) are not written: zero in the buffers the plant makes."""
    body_iquat, body_ipos, jnt_body, jnt_axis, jnt_pos = model.iquat, model.ipos, model.jnt_body, model.jnt_axis, model.jnt_pos
    hinge, subtree, body_mass, inertia, armature = model.hinge, model.subtree, model.body_mass, model.inertia, model.armature
    gravity, site_body, site_pos, row_sites = model.gravity, model.site_body, model.site_pos, model.row_sites
    cyl, mot, mot_dof, gear = model.cyl, model.mot, model.mot_dof, model.gear
    body_group, group_mass, group_root, group_dynamic = model.body_group, model.group_mass, model.group_root, model.group_dynamic
    isl = model.islands
    jptr, jl, bptr, bl, gptr, gl = isl.joint_ptr, isl.joints, isl.body_ptr, isl.bodies, isl.group_ptr, isl.groups
    rptr, rl, mptr, ml, jisl = isl.row_ptr, isl.rows, isl.motor_ptr, isl.motors, isl.joint_island
    nisl = jptr.size - 1
    mobility, group_gravity, motor_response = out.mobility, out.group_gravity, out.motor_response
    motor_inverse_inertia, effective_mass = out.motor_inverse_inertia, out.effective_mass
    nb = x.shape[0]
    nj = jnt_body.shape[0]
    na = effective_mass.size
    nm = mot.size
    xb, qb, axis, anchor, jv, jwl, mass, rhs, moment, M, gjv, cols = work
    for b in range(nb):
        qc = (body_iquat[b, 0], -body_iquat[b, 1], -body_iquat[b, 2], -body_iquat[b, 3])
        qq = XC._qmul(XC._q4(q, b), qc)
        XC._setq(qb, b, qq)
        r = XC._rot(qq, XC._v3(body_ipos, b))
        for c in range(3):
            xb[b, c] = x[b, c] - r[c]
    for j in range(nj):
        jb = jnt_body[j]
        qq = XC._q4(qb, jb)
        a = XC._rot(qq, XC._v3(jnt_axis, j))
        p = XC._rot(qq, XC._v3(jnt_pos, j))
        for c in range(3):
            axis[j, c] = a[c]
            anchor[j, c] = xb[jb, c] + p[c]
    for j in range(nj):  # joint-to-body Jacobians on the joint's island's bodies (the others never read)
        island = jisl[j]
        aj = XC._v3(axis, j)
        for t in range(bptr[island], bptr[island + 1]):
            b = bl[t]
            for c in range(3):
                jv[j, b, c] = 0.0
                jwl[j, b, c] = 0.0
            if not subtree[j, b]:
                continue
            if hinge[j]:
                lever = (x[b, 0] - anchor[j, 0], x[b, 1] - anchor[j, 1], x[b, 2] - anchor[j, 2])
                cr = XC._cross(aj, lever)
                wl = XC._rotinv(XC._q4(q, b), aj)
                for c in range(3):
                    jv[j, b, c] = cr[c]
                    jwl[j, b, c] = wl[c]
            else:
                for c in range(3):
                    jv[j, b, c] = aj[c]
    for island in range(nisl):
        j0, j1, b0, b1 = jptr[island], jptr[island + 1], bptr[island], bptr[island + 1]
        for ti in range(j0, j1):  # (every entry of the island's mass block and gravity column is written below)
            i = jl[ti]
            for tk in range(j0, j1):
                k = jl[tk]
                if not (subtree[i, jnt_body[k]] or subtree[k, jnt_body[i]]):
                    mass[i, k] = 0.0  # sibling branches: no body moves with both
                    continue
                s = 0.0
                for t in range(b0, b1):
                    b = bl[t]
                    s += body_mass[b] * (jv[i, b, 0] * jv[k, b, 0] + jv[i, b, 1] * jv[k, b, 1] + jv[i, b, 2] * jv[k, b, 2])
                for t in range(b0, b1):
                    b = bl[t]
                    s += (inertia[b, 0] * jwl[i, b, 0] * jwl[k, b, 0] + inertia[b, 1] * jwl[i, b, 1] * jwl[k, b, 1]
                          + inertia[b, 2] * jwl[i, b, 2] * jwl[k, b, 2])
                mass[i, k] = s + armature[i] if i == k else s
            s = 0.0
            for t in range(b0, b1):
                b = bl[t]
                s += body_mass[b] * (jv[i, b, 0] * gravity[0] + jv[i, b, 1] * gravity[1] + jv[i, b, 2] * gravity[2])
            rhs[i, na] = s
        for t in range(mptr[island], mptr[island + 1]):  # motor moment arms: the gear on the motor's joint
            i = ml[t]
            for tk in range(j0, j1):
                moment[mot[i], jl[tk]] = 0.0
            moment[mot[i], mot_dof[i]] = gear[i]
        for t in range(rptr[island], rptr[island + 1]):  # cylinder rows: n·(∂B/∂q − ∂A/∂q)
            r = rl[t]
            sa, sb = row_sites[r, 0], row_sites[r, 1]
            ba, bb = site_body[sa], site_body[sb]
            pa = XC._rot(XC._q4(q, ba), XC._v3(site_pos, sa))
            pb = XC._rot(XC._q4(q, bb), XC._v3(site_pos, sb))
            A = (x[ba, 0] + pa[0], x[ba, 1] + pa[1], x[ba, 2] + pa[2])
            B = (x[bb, 0] + pb[0], x[bb, 1] + pb[1], x[bb, 2] + pb[2])
            d = (B[0] - A[0], B[1] - A[1], B[2] - A[2])
            ln = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            n = (d[0] / ln, d[1] / ln, d[2] / ln)
            for tk in range(j0, j1):
                j = jl[tk]
                aj = XC._v3(axis, j)
                jb_ = (0.0, 0.0, 0.0)
                ja_ = (0.0, 0.0, 0.0)
                if subtree[j, bb]:
                    jb_ = XC._cross(aj, (B[0] - anchor[j, 0], B[1] - anchor[j, 1], B[2] - anchor[j, 2])) if hinge[j] else aj
                if subtree[j, ba]:
                    ja_ = XC._cross(aj, (A[0] - anchor[j, 0], A[1] - anchor[j, 1], A[2] - anchor[j, 2])) if hinge[j] else aj
                moment[cyl[r], j] = n[0] * (jb_[0] - ja_[0]) + n[1] * (jb_[1] - ja_[1]) + n[2] * (jb_[2] - ja_[2])
        nc = _island_columns(isl, island, cyl, mot, na, cols)
        for ti in range(j0, j1):
            i = jl[ti]
            for u in range(nc - 1):
                rhs[i, cols[u]] = moment[cols[u], i]
        # dq = M⁻¹·[Jᵀ, Q_gravity] on the island's block: Gaussian elimination with partial pivoting
        for ti in range(j0, j1):
            for tk in range(j0, j1):
                M[jl[ti], jl[tk]] = mass[jl[ti], jl[tk]]
        for tc in range(j0, j1):
            col = jl[tc]
            piv = col
            for tr in range(tc + 1, j1):
                r = jl[tr]
                if abs(M[r, col]) > abs(M[piv, col]):
                    piv = r
            if M[piv, col] == 0.0 or not np.isfinite(M[piv, col]):
                return False
            if piv != col:
                for tk in range(j0, j1):
                    c = jl[tk]
                    M[col, c], M[piv, c] = M[piv, c], M[col, c]
                for u in range(nc):
                    c = cols[u]
                    rhs[col, c], rhs[piv, c] = rhs[piv, c], rhs[col, c]
            for tr in range(tc + 1, j1):
                r = jl[tr]
                f = M[r, col] / M[col, col]
                if f != 0.0:
                    for tk in range(tc, j1):
                        c = jl[tk]
                        M[r, c] -= f * M[col, c]
                    for u in range(nc):
                        c = cols[u]
                        rhs[r, c] -= f * rhs[col, c]
        for tc in range(j1 - 1, j0 - 1, -1):  # back substitution, U's zeros skipped (sibling branches)
            col = jl[tc]
            for tk in range(tc + 1, j1):
                k = jl[tk]
                uu = M[col, k]
                if uu != 0.0:
                    for u in range(nc):
                        c = cols[u]
                        rhs[col, c] -= uu * rhs[k, c]
            for u in range(nc):
                c = cols[u]
                rhs[col, c] = rhs[col, c] / M[col, col]
    dq = rhs
    for a in range(na):  # an actuator of no island's joints moves nothing: 1/0
        effective_mass[a] = np.inf
    for island in range(nisl):
        nc = _island_columns(isl, island, cyl, mot, na, cols)
        for u in range(nc - 1):
            a = cols[u]
            s = 0.0
            for ti in range(jptr[island], jptr[island + 1]):
                i = jl[ti]
                s += moment[a, i] * dq[i, a]
            effective_mass[a] = 1.0 / s if s != 0.0 else np.inf
    for i in range(nm):
        motor_inverse_inertia[i] = dq[mot_dof[i], mot[i]] / gear[i]
    for island in range(nisl):  # group-COM Jacobians: the mass-weighted body rows of each group
        for ti in range(jptr[island], jptr[island + 1]):
            i = jl[ti]
            for t in range(gptr[island], gptr[island + 1]):
                g = gl[t]
                for c in range(3):
                    gjv[i, g, c] = 0.0
            for t in range(bptr[island], bptr[island + 1]):
                b = bl[t]
                g = body_group[b]
                if g == 0:
                    continue  # a static body (whole-model island): no Jacobian
                for c in range(3):
                    gjv[i, g, c] += jv[i, b, c] * body_mass[b]
            for t in range(gptr[island], gptr[island + 1]):
                g = gl[t]
                gm = group_mass[g] if group_mass[g] > 0 else 1.0
                for c in range(3):
                    gjv[i, g, c] /= gm
    # the responses: Σ over the island's joints that move with the column (dq ≠ 0), in the joints' order
    for island in range(nisl):
        j0, j1, g0, g1 = jptr[island], jptr[island + 1], gptr[island], gptr[island + 1]
        nc = _island_columns(isl, island, cyl, mot, na, cols)
        nr_ = rptr[island + 1] - rptr[island]
        for u in range(nc):
            col = cols[u]
            if u < nr_:
                target = mobility[rl[rptr[island] + u]]
            elif u < nc - 1:
                target = motor_response[ml[mptr[island] + u - nr_]]
            else:
                target = group_gravity
            for t in range(g0, g1):
                g = gl[t]
                for c in range(6):
                    target[g, c] = 0.0
            for ti in range(j0, j1):
                i = jl[ti]
                d = dq[i, col]
                if d == 0.0:
                    continue
                for t in range(g0, g1):
                    g = gl[t]
                    if not group_dynamic[g]:
                        continue
                    for c in range(3):
                        target[g, c] += d * gjv[i, g, c]
                    if hinge[i] and subtree[i, group_root[g]]:
                        for c in range(3):
                            target[g, 3 + c] += d * axis[i, c]
    return True


_ARTICULATED = None
_articulated_jit = _articulated_into_jit = _articulated_work_jit = None


def _articulated_entry(fingerprint):
    import numba

    def articulated_step(*args):
        if fingerprint is None:  # never: only makes the fingerprint a closure variable (numba's cache key)
            return False
        return _articulated_jit(*args)

    return numba.njit(cache=True, error_model="numpy")(articulated_step)


def articulated():
    """The compiled ``_articulated`` (numba's disk cache; the key includes the sources' fingerprint)."""
    global _ARTICULATED, _articulated_jit, _articulated_into_jit, _articulated_work_jit
    if _ARTICULATED is None:
        import numba

        _articulated_into_jit = numba.njit(error_model="numpy")(_articulated_into)
        _articulated_work_jit = numba.njit(error_model="numpy")(articulated_work)
        _articulated_jit = numba.njit(error_model="numpy")(_articulated)
        _ARTICULATED = _articulated_entry(SOURCE_SHA256)
    return _ARTICULATED
