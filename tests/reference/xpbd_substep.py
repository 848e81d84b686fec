"""The pure-Python XPBD substep: the oracle of the package's compiled substep (``sim/xpbd/compiled.py``).

:class:`ReferenceSolver` is a :class:`sim.xpbd.solver.SolverXPBD` whose ``step`` runs every substep through the
passes of :class:`ReferenceSubstep`, written independently of ``compiled.substep_core`` on Python lists and the
tuple kernels of ``xpbd_kernels.py``, with numpy group gather/scatter and contact candidates.  The tests compare
the package's solver with it (agreement to round-off: ``tests/test_pbd_compiled.py``).  Per substep its data (soft
limit and contact rows, multipliers, articulated responses) travel in a :class:`SubstepWork` passed to every pass.
Sign conventions and references as in :mod:`sim.xpbd.solver`.

``ReferenceSolver(model, options, length_constraints=..., block_attach=False)`` projects pin/connect
attachments with the scalar XPBD update along the error direction instead of the 3×3 block update the
package uses (more pin drift: 5.5e-5 against 4.0e-5 m on a double pendulum at 60 Hz × 20,
``tests/test_xpbd_rigid.py``), kept here for that comparison.

Example
-------
>>> solver = ReferenceSolver(xm, XpbdOptions(substeps=10))   # doctest: +SKIP
>>> solver.step(state, 1 / 60)                                # doctest: +SKIP
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from sim.xpbd.model import EQ_WELD, JNT_BALL, JNT_HINGE, JNT_SLIDE
from sim.xpbd.quat import np_cross, np_quat_mul, np_quat_rotate
from sim.xpbd.solver import SolverXPBD, SubstepForces, substep_inputs

from . import xpbd_kernels as K
from .xpbd_kernels import (
    angular_inverse_mass,
    apply_angular_velocity_impulse,
    apply_velocity_impulse,
    cross,
    dot,
    limit_violation,
    point_velocity,
    positional_inverse_mass,
    predict_body,
    quat_conj,
    quat_mul,
    quat_rotate,
    quat_rotate_inv,
    solve_angular,
    solve_positional,
    twist_angle,
    update_velocity_body,
)
from .xpbd_laws import mujoco_contact_law, mujoco_step_target, soft_limit_target

_EPS = 1e-14
_INF = math.inf
_PYRAMID = "pyramid"  # marker of a soft pyramidal contact in SubstepWork.contact_soft


@dataclass
class SubstepWork:
    """What one substep of the pure path sets up from its start state and its passes update: made per substep by
    :meth:`SolverXPBD.step` and passed explicitly to the position and velocity passes (never kept on the solver).
    The compiled path's counterpart is ``compiled.SubstepWork``."""

    joint_soft: Optional[list] = None
    """Per joint, its soft limit row (side ±1, target q* [rad or m], α̃) or None; None: no soft limits."""
    joint_lam: list = field(default_factory=list)
    """Accumulated multiplier of each joint's soft limit row."""
    tendon_soft: Optional[list] = None
    """Per soft tendon limit, its row (side, ℓ* [m], α̃) or None; None: no tendon limits."""
    tendon_lam: list = field(default_factory=list)
    """Accumulated multiplier of each tendon limit row."""
    block_soft: Optional[list] = None
    """The joint limit rows solved in the articulated limit block (``_solve_limits_block``), or None."""
    block_mu: list = field(default_factory=list)
    """Pushing multipliers μ ≥ 0 of the limit block's rows (joints, then tendon limits)."""
    contact_soft: Optional[list] = None
    """Per contact candidate, its soft row (``_soft_contact_targets``) or None (rigid); None: rigid contacts."""
    contact_articulated: Optional[tuple] = None
    """(G, M⁻¹) of the articulated contacts, or None (free-body response)."""
    limit_articulated: Optional[tuple] = None
    """(G, M⁻¹) for the soft tendon limits, or None (free-body response)."""
    edge_lam: list = field(default_factory=list)
    """Per candidate, the multipliers of its pyramid edge rows (or None)."""


def _move_groups(X, Q, IM, G, dq):
    """Move every dynamic group by G·dq: the joint-space displacement ``dq`` through the group Jacobian G."""
    for g in range(1, len(X)):
        if IM[g] == 0.0:
            continue
        d = G[g] @ dq
        X[g] = [X[g][0] + d[0], X[g][1] + d[1], X[g][2] + d[2]]
        if d[3] != 0.0 or d[4] != 0.0 or d[5] != 0.0:
            Q[g] = K._quat_add_rotation(Q[g], (float(d[3]), float(d[4]), float(d[5])), 1.0)


def _solve_dense(A, b):
    """Solve the small dense system A x = b (lists; Gaussian elimination with partial
    pivoting); None if singular.  For the handful of rows of ``_solve_rows_block``."""
    n = len(b)
    M = [list(A[i]) + [b[i]] for i in range(n)]
    for c in range(n):
        p = max(range(c, n), key=lambda r: abs(M[r][c]))
        if abs(M[p][c]) < 1e-300:
            return None
        if p != c:
            M[c], M[p] = M[p], M[c]
        piv = M[c][c]
        for r in range(c + 1, n):
            f = M[r][c] / piv
            if f != 0.0:
                Mr, Mc = M[r], M[c]
                for cc in range(c, n + 1):
                    Mr[cc] -= f * Mc[cc]
    x = [0.0] * n
    for r in range(n - 1, -1, -1):
        acc = M[r][n]
        for cc in range(r + 1, n):
            acc -= M[r][cc] * x[cc]
        x[r] = acc / M[r][r]
    return x


class ReferenceSubstep:
    """The pure substep passes (a base of :class:`ReferenceSolver`: they read the solver's model tables ``_IM``,
    ``_II``, ``_joints``, ``_eqs``, ``_rows``, ``_jlaw``, ``_tlaw`` and options)."""

    def _step_reference(self, state, dt, hooks, inputs, x, q, v, w, cands):
        """``SolverXPBD.step`` in pure Python (the oracle of ``compiled.substep_core``): the group state
        x, q, v, w gathered at the step's start and its contact candidates ``cands``."""
        m = self.model
        h = dt / self.substeps
        X, Q, V, W = x.tolist(), q.tolist(), v.tolist(), w.tolist()
        nr = len(self._rows)
        before = getattr(hooks, "before_substep", None)
        after = getattr(hooks, "after_substep", None)
        dyn = range(1, m.ngroup)
        IM, II, GI = self._IM, self._II, self._GI
        grav = self._gravity
        t0 = state.time
        self.last_forces = []
        need_vel = bool(cands) or bool(self._damped)
        cl = 1.0 / (1.0 + self.linear_damping * h)
        ca = 1.0 / (1.0 + self.angular_damping * h)
        P0 = self._transport_start(X, Q)
        for k in range(self.substeps):
            inp = substep_inputs(before, k, h, state, inputs)
            if P0 is not None and k:
                inp = self._transported(inp, X, Q, P0)
            rowdata = self._row_setup(inp, h)
            block = None
            if rowdata and inp.row_mobility is not None:
                block = np.asarray(inp.row_mobility, dtype=float)[[r[0] for r in rowdata]].tolist()
            F, T = self._external(inp, X, Q)
            # soft limits from the state at the substep's start (before the torque impulses: the applied torques
            # are part of MuJoCo's unconstrained acceleration, not of the rate v⁻ of its law)
            sw = SubstepWork()  # this substep's rows and multipliers, passed to every pass below
            sw.joint_soft = self._soft_limit_targets(X, Q, V, W, h) if self.soft_limits else None
            sw.joint_lam = [0.0] * len(self._joints)
            sw.tendon_soft = self._tendon_limit_targets(X, Q, V, W, h) if self._tlaw else None
            sw.tendon_lam = [0.0] * len(self._tlaw)
            tact = sw.tendon_soft is not None and any(ts is not None for ts in sw.tendon_soft)
            if inp is not None and inp.joint_force is not None:
                self._apply_hinge_torques(inp, V, W, Q, h)
            sw.contact_soft = self._soft_contact_targets(sw, X, Q, V, W, cands, h) if (cands and self.soft_contacts) else None
            Xp, Qp = X[:], Q[:]
            gg = None if inp is None or inp.group_gravity is None else np.asarray(inp.group_gravity, float).tolist()
            for g in dyn:  # predict
                acc, tq = grav, None if T is None else T[g]
                if gg is not None:  # given group accelerations instead of uniform gravity
                    acc = gg[g][:3]
                    al = quat_rotate_inv(Q[g], gg[g][3:])
                    ta = quat_rotate(Q[g], (GI[g][0] * al[0], GI[g][1] * al[1], GI[g][2] * al[2]))
                    tq = ta if tq is None else (tq[0] + ta[0], tq[1] + ta[1], tq[2] + ta[2])
                X[g], Q[g], V[g], W[g] = predict_body(
                    X[g], Q[g], V[g], W[g], GI[g], II[g], IM[g], acc,
                    None if F is None else F[g], tq, h)
            # articulated contacts: G and M⁻¹ at the predicted pose (compiled.articulated_inverse)
            art = self._articulated_inverse(X, Q) if ((cands and self.articulated_contacts) or tact) else None
            sw.contact_articulated = art if self.articulated_contacts else None
            sw.limit_articulated = art
            sw.block_soft = None
            if tact and art is not None:  # every active soft limit in one articulated block (_solve_limits_block)
                sw.block_soft, sw.joint_soft = sw.joint_soft, [None] * len(self._joints)
                sw.block_mu = [0.0] * (len(self._joints) + len(self._tlaw))
            lam_rows = [0.0] * nr
            lam_n = [0.0] * len(cands)
            lam_t = [0.0] * len(cands)
            cinfo: dict = {}
            for _ in range(self.iterations):
                if self.symmetric:
                    self._solve_positions(sw, X, Q, rowdata, lam_rows, cands, lam_n, lam_t, cinfo,
                                          Xp, Qp, reverse=False, block=block)
                    self._solve_positions(sw, X, Q, rowdata, lam_rows, cands, lam_n, lam_t, cinfo,
                                          Xp, Qp, reverse=True, block=block)
                else:
                    self._solve_positions(sw, X, Q, rowdata, lam_rows, cands, lam_n, lam_t, cinfo,
                                          Xp, Qp, reverse=False, block=block)
            for g in dyn:  # velocity update
                V[g], W[g] = update_velocity_body(X[g], Q[g], Xp[g], Qp[g], h)
            if need_vel:
                self._solve_velocities(sw, V, W, Q, X, cinfo, lam_n, cands, h)
            if cl != 1.0:
                for g in dyn:
                    V[g] = [cl * V[g][0], cl * V[g][1], cl * V[g][2]]
            if ca != 1.0:
                for g in dyn:
                    W[g] = [ca * W[g][0], ca * W[g][1], ca * W[g][2]]
            if after is not None or nr:
                lam = np.array(lam_rows)
                active = np.zeros(nr, dtype=bool)
                if rowdata:
                    active[[r[0] for r in rowdata]] = True
                x, q, v, w = np.array(X), np.array(Q), np.array(V), np.array(W)
                if after is not None:
                    self._scatter(x, q, v, w, state)
                    state.time = t0 + (k + 1) * h
                ell, rate = self._row_kinematics(x, q, v, w)
                forces = SubstepForces(lam / (h * h), lam, ell, rate, active)
                self.last_forces.append(forces)
                if after is not None:
                    after(k, h, state, forces)
        self._scatter(np.array(X), np.array(Q), np.array(V), np.array(W), state)
        state.time = t0 + dt
        state.qpos_hint = m.qpos_qvel(state)[0]
        return state

    def _apply_hinge_torques(self, inp, V, W, Q, h):
        """Hinge torques τ (``joint_force``) as the impulse τ h a about the parent's axis
        plus the workless pin impulse that keeps the pins together
        (``kernels.apply_joint_torque_impulse``)."""
        jf = np.asarray(inp.joint_force, dtype=float)
        for j in np.nonzero(jf)[0]:
            t, g1, g2, r1, r2, a1 = self._joints[j][:6]
            if t != JNT_HINGE:
                continue
            aw = quat_rotate(Q[g1], a1)
            s = jf[j] * h
            K.apply_joint_torque_impulse(V, W, Q, self._IM, self._II, g1, g2,
                                         quat_rotate(Q[g1], r1), quat_rotate(Q[g2], r2),
                                         (s * aw[0], s * aw[1], s * aw[2]))

    def _row_setup(self, inp, h):
        nr = len(self._rows)
        if nr == 0 or inp is None or inp.target_length is None:
            return None
        tgt = np.asarray(inp.target_length, dtype=float)
        alpha = np.zeros(nr) if inp.compliance is None else np.asarray(inp.compliance, float)
        lo = np.full(nr, -np.inf) if inp.force_min is None else np.asarray(inp.force_min, float) * h * h
        hi = np.full(nr, np.inf) if inp.force_max is None else np.asarray(inp.force_max, float) * h * h
        active = np.isfinite(tgt) & np.isfinite(alpha)
        at = alpha / (h * h)
        return [(i, float(tgt[i]), float(at[i]), float(lo[i]), float(hi[i]))
                for i in np.nonzero(active)[0]]

    def _solve_positions(self, sw, X, Q, rowdata, lam_rows, cands, lam_n, lam_t, cinfo, Xp, Qp,
                         reverse=False, block=None):
        """One Gauss-Seidel pass over joints, equalities, length rows and contacts.

        With ``reverse`` the whole sequence (and the rows inside each joint) is traversed
        backwards.  With ``symmetric`` (default) every iteration is a forward followed by
        a backward pass (symmetric Gauss-Seidel).  A forward-only sweep can make the
        error→velocity feedback of XPBD unstable: the residual recurrence per substep is
        C_{k+1} = B (2 C_k − C_{k−1}) with B the sweep's iteration matrix, which is stable
        for eigenvalues of B in [0, 1) (guaranteed for a symmetric sweep) but not for the
        negative or complex eigenvalues a one-sided sweep can have.  This shows up when
        a light body sits between two joints (a slender arm carrying a slider, a cylinder
        rod), and more substeps do not cure it.

        ``block`` (the active rows' group mobilities, see ``SubstepInputs.row_mobility``)
        solves the rows together with their articulated response.  With loop closures (equalities) the
        backward pass ends with the rows once more: the equalities and joints solved after them move the
        rows' ends, and a row's law c + s·v⁺ holds only for the end length it was solved for.
        """
        if not reverse:
            self._solve_joints(sw, X, Q, self._joints)
            if sw.block_soft is not None:
                self._solve_limits_block(sw, X, Q)
            elif sw.tendon_soft is not None:
                self._solve_tendon_limits(sw, X, Q, False)
            self._solve_eqs(X, Q, self._eqs)
            if rowdata:
                if block is None:
                    self._solve_rows(X, Q, rowdata, lam_rows)
                else:
                    self._solve_rows_block(X, Q, rowdata, lam_rows, block)
            if cands:
                self._solve_contacts(sw, X, Q, range(len(cands)), cands, lam_n, lam_t, cinfo, Xp, Qp)
        else:
            if cands:
                self._solve_contacts(sw, X, Q, range(len(cands) - 1, -1, -1), cands, lam_n, lam_t,
                                     cinfo, Xp, Qp)
            if rowdata:
                if block is None:
                    self._solve_rows(X, Q, rowdata[::-1], lam_rows)
                else:
                    self._solve_rows_block(X, Q, rowdata, lam_rows, block)
            self._solve_eqs(X, Q, self._eqs[::-1])
            if sw.block_soft is not None:
                self._solve_limits_block(sw, X, Q)
            elif sw.tendon_soft is not None:
                self._solve_tendon_limits(sw, X, Q, True)
            self._solve_joints(sw, X, Q, self._joints, reverse=True)
            if rowdata and self._eqs:  # loop closures: the rows' ends as their laws were solved for
                if block is None:
                    self._solve_rows(X, Q, rowdata, lam_rows)
                else:
                    self._solve_rows_block(X, Q, rowdata, lam_rows, block)

    def _solve_joints(self, sw, X, Q, joints, reverse=False):
        """Joint rows ([RB] Sec. 3.4); ``reverse`` traverses the joints backwards and also reverses the row
        order inside a joint.  Limits: MuJoCo's soft limit law (``_soft_limit_targets``) when the joint's
        limit is soft, else the rigid projection ([RB] Algorithm 3)."""
        n = len(joints)
        soft = sw.joint_soft
        for jj in range(n):
            j = n - 1 - jj if reverse else jj
            (t, g1, g2, r1, r2, a1, a2, qoff, limited, lo, hi, _) = joints[j]
            sl = None
            if limited and soft is not None and self._jlaw[j] is not None:
                limited = False  # soft limit: only where it was violated at the substep's start
                sl = soft[j]
            if t == JNT_HINGE:
                if sl is not None:
                    sw.joint_lam[j] += self._hinge_soft_limit(X, Q, g1, g2, r1, r2, a1, qoff, sl, sw.joint_lam[j])
                    continue
                if limited and self._hinge_limit(X, Q, g1, g2, r1, r2, a1, qoff, lo, hi):
                    continue
                if reverse:
                    self._attach(X, Q, g1, g2, r1, r2)
                    self._align_axes(Q, g1, g2, a1, a2)
                else:
                    self._align_axes(Q, g1, g2, a1, a2)
                    self._attach(X, Q, g1, g2, r1, r2)
            elif t == JNT_SLIDE:
                if reverse:
                    self._slide_axis(sw, X, Q, g1, g2, r1, a1, limited, lo, hi, sl, j)
                    self._fix_orientation(Q, g1, g2, qoff)
                else:
                    self._fix_orientation(Q, g1, g2, qoff)
                    self._slide_axis(sw, X, Q, g1, g2, r1, a1, limited, lo, hi, sl, j)
            elif t == JNT_BALL:
                self._attach(X, Q, g1, g2, r1, r2)

    def _soft_limit_targets(self, X, Q, V, W, h):
        """Per joint, the compliant limit row of the substep: (side, q* [rad or m], α̃), or None.

        MuJoCo's soft limit law R·f = −(a + b·v + k·d·r) (``mujoco_limit_law``: the joint's solref/solimp,
        R = (1 − d)/d·dof_invweight0) on the limit distance r = hi − q (side +1) or q − lo (side −1),
        < 0 when violated, taken over the substep as MuJoCo takes it over its step, exactly as the soft
        contacts (``_soft_contact_targets``, ``mujoco_step_target``): r* = r⁻ + h·ṙ⁻ − h²·(b·ṙ⁻ + k·d·r⁻) and
        the generalized force f = −(r⁺ − r*)/(R·h²) ≥ 0, an XPBD row of compliance α = R·h² (α̃ = R).  As in
        MuJoCo (margin 0) a limit acts only in a substep that starts beyond it.  MuJoCo's safety clamp
        timeconst ≥ 2·timestep is applied with the substep h.
        """
        out = [None] * len(self._joints)
        for j, (t, g1, g2, r1, r2, a1, a2, qoff, limited, lo, hi, _) in enumerate(self._joints):
            law = self._jlaw[j]
            if law is None:
                continue
            q1 = Q[g1]
            aw = quat_rotate(q1, a1)
            if t == JNT_HINGE:
                qv = twist_angle(quat_mul(Q[g2], quat_conj(quat_mul(q1, qoff))), aw)
                qd = (W[g2][0] - W[g1][0]) * aw[0] + (W[g2][1] - W[g1][1]) * aw[1] + (W[g2][2] - W[g1][2]) * aw[2]
            else:
                r1w = quat_rotate(q1, r1)
                d = (X[g2][0] - X[g1][0] - r1w[0], X[g2][1] - X[g1][1] - r1w[1], X[g2][2] - X[g1][2] - r1w[2])
                qv = dot(d, aw)
                v1 = point_velocity(V, W, g1, r1w)
                wa = cross(W[g1], aw)
                qd = (V[g2][0] - v1[0]) * aw[0] + (V[g2][1] - v1[1]) * aw[1] + (V[g2][2] - v1[2]) * aw[2] + dot(d, wa)
            out[j] = soft_limit_target(qv, qd, lo, hi, law[0], law[1], law[2], h)
        return out

    def _solve_limits_block(self, sw, X, Q):
        """All active soft limits of a hinge/slide tree in one block, when a tendon limit is active: MuJoCo
        solves the rows of a joint limit and a tendon limit reached together (the boom's cylinder end stop)
        as one problem, and Gauss-Seidel over two nearly parallel compliant rows with λ reset every substep
        settles elsewhere (the boom pressed by 15 kN·m: 13 % too deep).  Rows C = q − q* (joint, J = e_j) or
        ℓ − ℓ* (tendon), taken in their pushing direction (μ = −side·λ ≥ 0); W = J·M⁻¹·Jᵀ + diag(α̃),
        Δμ = W⁻¹(−C − α̃·μ) with an active set over μ ≥ 0 (as the contact pyramids); every group moves by
        G·M⁻¹·Jᵀ·Δμ, and the joint projections clean up the second-order error."""
        G, Minv = sw.limit_articulated
        IM = self._IM
        nq = G.shape[2]
        rows = []  # (id, J', C', α̃, μ)
        for j, sl in enumerate(sw.block_soft):
            if sl is None:
                continue
            side, target, at = sl
            t, g1, g2, r1, r2, a1, a2, qoff = self._joints[j][:8]
            q1 = Q[g1]
            aw = quat_rotate(q1, a1)
            if t == JNT_HINGE:
                qv = twist_angle(quat_mul(Q[g2], quat_conj(quat_mul(q1, qoff))), aw)
            else:
                r1w = quat_rotate(q1, r1)
                qv = (X[g2][0] - X[g1][0] - r1w[0]) * aw[0] + (X[g2][1] - X[g1][1] - r1w[1]) * aw[1] + \
                    (X[g2][2] - X[g1][2] - r1w[2]) * aw[2]
            Jr = np.zeros(nq)
            Jr[j] = -side
            rows.append((j, Jr, -side * (qv - target), at, sw.block_mu[j]))
        nj = len(self._joints)
        for k, sl in enumerate(sw.tendon_soft):
            if sl is None:
                continue
            side, target, at = sl
            ga, gb, raw, rbw, ell, n = self._tendon_geometry(X, Q, k)
            Jr = np.zeros(nq)
            for b, sg, r in ((ga, -1.0, raw), (gb, 1.0, rbw)):
                if IM[b] == 0.0:
                    continue
                v = G[b, :3, :] + np.cross(G[b, 3:, :].T, r).T
                Jr -= side * sg * (np.asarray(n) @ v)
            rows.append((nj + k, Jr, -side * (ell - target), at, sw.block_mu[nj + k]))
        if not rows:
            return
        Jm = np.array([r[1] for r in rows])
        C = np.array([r[2] for r in rows])
        at = np.array([r[3] for r in rows])
        lam = np.array([r[4] for r in rows])
        MJ = Minv @ Jm.T
        A = Jm @ MJ + np.diag(at)
        rhs = -C - at * lam
        n = len(rows)
        free = (rhs > 0.0) | (lam > 0.0)
        dlam = np.zeros(n)
        for _ in range(n + 1):
            dlam[~free] = -lam[~free]
            if free.any():
                idx = np.nonzero(free)[0]
                bf = rhs[idx] - A[np.ix_(idx, np.nonzero(~free)[0])] @ dlam[~free]
                try:
                    dlam[idx] = np.linalg.solve(A[np.ix_(idx, idx)], bf)
                except np.linalg.LinAlgError:
                    return
            neg = free & (lam + dlam < 0.0)
            if not neg.any():
                break
            free &= ~neg
        new = np.maximum(lam + dlam, 0.0)
        for (rid, *_), v in zip(rows, new):
            sw.block_mu[rid] = float(v)
        dq = MJ @ (new - lam)
        _move_groups(X, Q, IM, G, dq)

    def _tendon_geometry(self, X, Q, k):
        ga, gb, ra, rb = self._tlaw[k][:4]
        raw = quat_rotate(Q[ga], ra)
        rbw = quat_rotate(Q[gb], rb)
        d = (X[gb][0] + rbw[0] - X[ga][0] - raw[0], X[gb][1] + rbw[1] - X[ga][1] - raw[1],
             X[gb][2] + rbw[2] - X[ga][2] - raw[2])
        ell = math.sqrt(dot(d, d))
        den = ell if ell > 0.0 else 1.0
        return ga, gb, raw, rbw, ell, (d[0] / den, d[1] / den, d[2] / den)

    def _tendon_limit_targets(self, X, Q, V, W, h):
        """Per soft tendon limit (MuJoCo's limit of a straight two-site spatial tendon), the compliant row of
        the substep: (side, ℓ* [m], α̃), or None — the law of ``_soft_limit_targets`` on the tendon length ℓ
        with the tendon's solreflimit/solimplimit and R = (1 − d)/d·tendon_invweight0.  MuJoCo applies it
        together with a joint limit where both are reached (the boom's cylinder end stop)."""
        out = [None] * len(self._tlaw)
        for k, (ga, gb, ra, rb, lo, hi, solref, solimp, invw) in enumerate(self._tlaw):
            ga, gb, raw, rbw, ell, n = self._tendon_geometry(X, Q, k)
            vb = point_velocity(V, W, gb, rbw)
            va = point_velocity(V, W, ga, raw)
            rate = (vb[0] - va[0]) * n[0] + (vb[1] - va[1]) * n[1] + (vb[2] - va[2]) * n[2]
            out[k] = soft_limit_target(ell, rate, lo, hi, solref, solimp, invw, h)
        return out

    def _solve_tendon_limits(self, sw, X, Q, reverse):
        """Soft tendon limit rows C = ℓ − ℓ* (compliance α̃, λ ≤ 0 at an upper limit, ≥ 0 at a lower one) with
        the articulated response of a hinge/slide tree (W = J·M⁻¹·Jᵀ, every group moved by G·M⁻¹·Jᵀ·Δλ, as the
        articulated contacts) or else the free-body response of the two groups."""
        IM, II = self._IM, self._II
        nt = len(self._tlaw)
        for kk in range(nt):
            k = nt - 1 - kk if reverse else kk
            sl = sw.tendon_soft[k]
            if sl is None:
                continue
            side, target, at = sl
            ga, gb, raw, rbw, ell, n = self._tendon_geometry(X, Q, k)
            c = ell - target
            lam = sw.tendon_lam[k]
            lo, hi = (-_INF, 0.0) if side > 0.0 else (0.0, _INF)
            if sw.limit_articulated is None:
                sw.tendon_lam[k] += solve_positional(X, Q, IM, II, ga, gb, raw, rbw, n, c, at, lam, lo, hi)
                continue
            G, Minv = sw.limit_articulated
            J = np.zeros(G.shape[2])
            for b, sg, r in ((ga, -1.0, raw), (gb, 1.0, rbw)):
                if IM[b] == 0.0:
                    continue
                v = G[b, :3, :] + np.cross(G[b, 3:, :].T, r).T  # (3, njnt): point velocity per joint rate
                J += sg * (np.asarray(n) @ v)
            MJ = Minv @ J
            den = float(J @ MJ) + at
            if not den > 0.0:
                continue
            new = min(max(lam + (-c - at * lam) / den, lo), hi)
            dl = new - lam
            sw.tendon_lam[k] = new
            if dl == 0.0:
                continue
            dq = MJ * dl
            _move_groups(X, Q, IM, G, dq)

    def _hinge_soft_limit(self, X, Q, g1, g2, r1, r2, a1, qoff, sl, lam):
        """Hinge beyond a soft limit: pin and axis rigid, the angle compliant towards its target, in one
        6-row block (``kernels.solve_soft_lock_block``); the accumulated multiplier λ [N·m·s²] along the
        axis stays ≤ 0 at an upper, ≥ 0 at a lower limit.  Returns Δλ."""
        side, target, at = sl
        q1 = Q[g1]
        aw = quat_rotate(q1, a1)
        qt = quat_mul(q1, qoff)
        r1w, r2w, c_pin, c_ang = self._lock_errors(X, Q, g1, g2, r1, r2, aw, target, qt)
        return K.solve_soft_lock_block(X, Q, self._IM, self._II, g1, g2, r1w, r2w, c_pin, c_ang, aw, at, lam, side)

    def _align_axes(self, Q, g1, g2, a1, a2):
        """Hinge axis alignment, Δq = a₁ × a₂ ([RB] eq. 20), α = 0."""
        a1w = quat_rotate(Q[g1], a1)
        a2w = quat_rotate(Q[g2], a2)
        e = cross(a1w, a2w)
        s = math.sqrt(dot(e, e))
        if s > _EPS:
            th = math.atan2(s, dot(a1w, a2w))
            solve_angular(Q, self._IM, self._II, g1, g2, (e[0] / s, e[1] / s, e[2] / s), th)

    def _hinge_limit(self, X, Q, g1, g2, r1, r2, a1, qoff, lo, hi):
        """Hinge angle limit ([RB] Algorithm 3).  φ is the twist of the child's rotation
        relative to its zero pose about the parent's axis; if outside [lo, hi] the whole
        joint is projected at the clamped angle (``_hinge_at_limit``).  Returns True then."""
        q1 = Q[g1]
        aw = quat_rotate(q1, a1)
        qt = quat_mul(q1, qoff)
        ang = twist_angle(quat_mul(Q[g2], quat_conj(qt)), aw)
        viol = limit_violation(ang, lo, hi)
        if viol == 0.0:
            return False
        self._hinge_at_limit(X, Q, g1, g2, r1, r2, aw, ang - viol, qt)
        return True

    def _slide_axis(self, sw, X, Q, g1, g2, r1, a1, limited, lo, hi, sl=None, j=-1):
        """Prismatic joint: keep the child's COM on the parent's axis (perpendicular offset
        → 0) and its axial position within [lo, hi] ([RB] Sec. 3.4.3).  The lever arm on
        the parent is taken at the slider, which is the exact gradient of both rows.  ``sl``: the soft
        limit row of the substep (``_soft_limit_targets``; λ of joint ``j`` ≤ 0 at an upper limit)."""
        IM, II = self._IM, self._II
        q1 = Q[g1]
        x1, x2 = X[g1], X[g2]
        r1w = quat_rotate(q1, r1)
        aw = quat_rotate(q1, a1)
        d = (x2[0] - x1[0] - r1w[0], x2[1] - x1[1] - r1w[1], x2[2] - x1[2] - r1w[2])
        dist = dot(d, aw)
        perp = (d[0] - dist * aw[0], d[1] - dist * aw[1], d[2] - dist * aw[2])
        pl = math.sqrt(dot(perp, perp))
        zero = (0.0, 0.0, 0.0)
        if pl > _EPS:
            solve_positional(X, Q, IM, II, g1, g2, (x2[0] - x1[0], x2[1] - x1[1], x2[2] - x1[2]),
                             zero, (perp[0] / pl, perp[1] / pl, perp[2] / pl), pl)
        if sl is None and not limited:
            return
        # the axial position after the perpendicular row moved the bodies
        q1 = Q[g1]
        x1, x2 = X[g1], X[g2]
        r1w = quat_rotate(q1, r1)
        aw = quat_rotate(q1, a1)
        dist = (x2[0] - x1[0] - r1w[0]) * aw[0] + (x2[1] - x1[1] - r1w[1]) * aw[1] + \
            (x2[2] - x1[2] - r1w[2]) * aw[2]
        if sl is not None:
            side, target, at = sl
            sw.joint_lam[j] += solve_positional(X, Q, IM, II, g1, g2, (x2[0] - x1[0], x2[1] - x1[1], x2[2] - x1[2]),
                                              zero, aw, dist - target, at, sw.joint_lam[j],
                                              -_INF if side > 0.0 else 0.0, 0.0 if side > 0.0 else _INF)
        else:
            viol = limit_violation(dist, lo, hi)
            if viol != 0.0:
                solve_positional(X, Q, IM, II, g1, g2,
                                 (x2[0] - x1[0], x2[1] - x1[1], x2[2] - x1[2]), zero, aw, viol)

    def _solve_eqs(self, X, Q, eqs):
        """Connect (attach) and weld (attach + fixed orientation) equalities."""
        for (t, g1, g2, r1, r2, qoff) in eqs:
            if t == EQ_WELD:
                self._fix_orientation(Q, g1, g2, qoff)
            self._attach(X, Q, g1, g2, r1, r2)

    def _row_geometry(self, i, X, Q):
        """Row i at the current poses: its groups, world-frame anchor offsets, the vector d between
        the anchors [m] and its length ℓ [m]."""
        ga, gb, ra, rb = self._rows[i][:4]
        raw = quat_rotate(Q[ga], ra)
        rbw = quat_rotate(Q[gb], rb)
        xa, xb = X[ga], X[gb]
        d = (xb[0] + rbw[0] - xa[0] - raw[0], xb[1] + rbw[1] - xa[1] - raw[1],
             xb[2] + rbw[2] - xa[2] - raw[2])
        return ga, gb, raw, rbw, d, math.sqrt(dot(d, d))

    def _solve_rows(self, X, Q, rowdata, lam_rows):
        """Compliant length rows: C = ℓ − ℓ*, Δλ = (−C − α̃λ)/(w + α̃), λ clamped to its
        bounds ([XPBD] eq. 18, [RB] eqs. 2–9)."""
        IM, II = self._IM, self._II
        for (i, tgt, at, lo, hi) in rowdata:
            ga, gb, raw, rbw, d, ell = self._row_geometry(i, X, Q)
            if ell < _EPS:
                continue
            lam_rows[i] += solve_positional(X, Q, IM, II, ga, gb, raw, rbw,
                                            (d[0] / ell, d[1] / ell, d[2] / ell), ell - tgt,
                                            at, lam_rows[i], lo, hi)

    def _solve_rows_block(self, X, Q, rowdata, lam_rows, mobility):
        """Active rows solved together with their articulated response ``mobility`` (nested
        lists [row][group] of 6 floats, see ``SubstepInputs.row_mobility``): W[i, j] = ∂C_i/∂λ_j
        from the group displacements at the current geometry, (W + α̃) Δλ = −C − α̃λ, λ clamped
        to its bounds, then every group moved by Σ_j mobility[j]·Δλ_j."""
        k = len(rowdata)
        A = [[0.0] * k for _ in range(k)]
        rhs = [0.0] * k
        live = [False] * k
        for m, (i, tgt, at, lo, hi) in enumerate(rowdata):
            ga, gb, raw, rbw, d, ell = self._row_geometry(i, X, Q)
            if ell < _EPS:
                A[m][m] = 1.0
                continue
            n = (d[0] / ell, d[1] / ell, d[2] / ell)
            row = A[m]
            for j in range(k):  # n·(δp_b − δp_a) per unit multiplier of row j
                mb, ma = mobility[j][gb], mobility[j][ga]
                cb = cross((mb[3], mb[4], mb[5]), rbw)
                ca = cross((ma[3], ma[4], ma[5]), raw)
                row[j] = (n[0] * (mb[0] + cb[0] - ma[0] - ca[0]) + n[1] * (mb[1] + cb[1] - ma[1] - ca[1])
                          + n[2] * (mb[2] + cb[2] - ma[2] - ca[2]))
            row[m] += at
            rhs[m] = -(ell - tgt) - at * lam_rows[i]
            live[m] = True
        if not any(live):
            return
        dlam = _solve_dense(A, rhs)
        if dlam is None:
            self._solve_rows(X, Q, rowdata, lam_rows)
            return
        for m, (i, tgt, at, lo, hi) in enumerate(rowdata):
            new = min(max(lam_rows[i] + dlam[m], lo), hi) if live[m] else lam_rows[i]
            dlam[m] = new - lam_rows[i]
            lam_rows[i] = new
        for g in range(1, len(X)):
            if self._IM[g] == 0.0:
                continue
            mv = [0.0] * 6
            for j in range(k):
                dl = dlam[j]
                if dl != 0.0:
                    mj = mobility[j][g]
                    for c in range(6):
                        mv[c] += dl * mj[c]
            x = X[g]
            X[g] = [x[0] + mv[0], x[1] + mv[1], x[2] + mv[2]]
            if mv[3] != 0.0 or mv[4] != 0.0 or mv[5] != 0.0:
                Q[g] = K._quat_add_rotation(Q[g], (mv[3], mv[4], mv[5]), 1.0)

    def _solve_contacts(self, sw, X, Q, order, cands, lam_n, lam_t, cinfo, Xp, Qp):
        """Normal pass over all contact candidates, then the static-friction pass (soft pyramidal
        contacts: their edge rows, ``_contact_pyramid``, carry normal force and friction together)."""
        soft = sw.contact_soft
        pyramids: dict = {}
        for ci in order:
            if soft is not None and soft[ci] is not None and soft[ci][0] == _PYRAMID:
                pyramids.setdefault((cands[ci][3], cands[ci][0]), []).append(ci)
            else:
                self._contact_normal(sw, X, Q, ci, cands[ci], lam_n, cinfo)
        for (g1, g2), cis in pyramids.items():
            self._contact_pyramids(sw, X, Q, g1, g2, cis, lam_n, Xp, Qp)
        for ci in order:
            if ci in cinfo:
                self._contact_static_friction(X, Q, ci, cands[ci], lam_n, lam_t, cinfo, Xp, Qp)

    def _contact_pyramids(self, sw, X, Q, g1, g2, cis, lam_n, Xp, Qp):
        """Soft pyramidal contacts between groups g1 (plane) and g2: the edge rows e = n ± μ·t_k of
        every contact (``_soft_contact_targets``) as XPBD rows on the displacement of the contact
        points along ê over the substep, C = ê·Δp − Δ*, compliance α̃, λ ≥ 0 (MuJoCo's pyramid
        edges are unilateral), all solved together: (W + α̃) Δλ = −C − α̃λ with
        W_ij = Σ_bodies [w·ê_i·ê_j + (r_i × ê_i)ᵀ I⁻¹ (r_j × ê_j)], by an active set over λ ≥ 0
        (as MuJoCo solves its contact problem exactly).  A Gauss-Seidel sweep over these nearly
        parallel, stiff rows converges slowly: one iteration leaves a resting box sinking too
        deep and creeping."""
        IM, II = self._IM, self._II
        pts, E, tgt, alpha, lam, inv_le, owner = [], [], [], [], [], [], []
        disp_rows = []
        for ci in cis:
            _, r1l, r2l, edges = sw.contact_soft[ci]
            r1w = quat_rotate(Q[g1], r1l)
            r2w = quat_rotate(Q[g2], r2l)
            r1p = quat_rotate(Qp[g1], r1l)
            r2p = quat_rotate(Qp[g2], r2l)
            x1, x2, x1p, x2p = X[g1], X[g2], Xp[g1], Xp[g2]
            disp = [(x2[k] + r2w[k] - x2p[k] - r2p[k]) - (x1[k] + r1w[k] - x1p[k] - r1p[k]) for k in range(3)]
            pts.append((r1w, r2w))
            lam_e = sw.edge_lam[ci]
            for j, (e, target, at, il) in enumerate(edges):
                E.append(e)
                tgt.append(target)
                alpha.append(at)
                lam.append(lam_e[j])
                inv_le.append(il)
                owner.append((len(pts) - 1, ci, j))
                disp_rows.append(dot(disp, e))
        Ea = np.array(E)
        W = np.zeros((len(E), len(E)))
        art = sw.contact_articulated
        if art is not None:  # articulated response: W = J·M⁻¹·Jᵀ, J_ik = ê_i·(v_g2,k(p) − v_g1,k(p))
            G, Minv = art
            J = np.zeros((len(E), G.shape[2]))
            for side, b, sg in ((0, g1, -1.0), (1, g2, 1.0)):
                if IM[b] == 0.0:
                    continue
                r = np.array([pts[o[0]][side] for o in owner])
                for row in range(len(E)):
                    v = G[b, :3, :] + np.cross(G[b, 3:, :].T, r[row]).T  # (3, njnt): point velocity per joint rate
                    J[row] += sg * (Ea[row] @ v)
            MJ = Minv @ J.T
            W = J @ MJ
        for side, b in ((0, g1), (1, g2)):
            if IM[b] == 0.0 or art is not None:
                continue
            r = np.array([pts[o[0]][side] for o in owner])
            ang = np.cross(r, Ea)
            Rm = np.array(K._mat_from_quat(Q[b]))
            Iinv = (Rm * np.asarray(II[b])) @ Rm.T
            W += IM[b] * (Ea @ Ea.T) + ang @ Iinv @ ang.T
        alpha = np.array(alpha)
        lam = np.array(lam)
        rhs = -(np.array(disp_rows) - np.array(tgt)) - alpha * lam
        A = W + np.diag(alpha)
        n = len(E)
        free = (rhs > 0.0) | (lam > 0.0)
        dlam = np.zeros(n)
        for _ in range(n + 1):
            dlam[~free] = -lam[~free]
            if np.any(free):
                b = rhs[free] - A[np.ix_(free, ~free)] @ dlam[~free]
                try:
                    dlam[free] = np.linalg.solve(A[np.ix_(free, free)], b)
                except np.linalg.LinAlgError:
                    return
            negative = free & (lam + dlam < 0.0)
            if not np.any(negative):
                break
            free &= ~negative
        new = np.maximum(lam + dlam, 0.0)
        dlam = new - lam
        if art is not None:  # every group moves by G·M⁻¹·Jᵀ·Δλ
            for row, (pi, ci, j) in enumerate(owner):
                sw.edge_lam[ci][j] = float(new[row])
            dq = MJ @ dlam
            _move_groups(X, Q, IM, G, dq)
            for ci in cis:
                edges = sw.contact_soft[ci][3]
                lam_n[ci] = sum(sw.edge_lam[ci][j] * edges[j][3] for j in range(len(edges)))
            return
        impulse = [[0.0, 0.0, 0.0] for _ in pts]
        for row, (pi, ci, j) in enumerate(owner):
            sw.edge_lam[ci][j] = float(new[row])
            for k in range(3):
                impulse[pi][k] += float(dlam[row]) * E[row][k]
        for pi, (r1w, r2w) in enumerate(pts):
            K.apply_positional_impulse(X, Q, IM, II, g2, r2w, impulse[pi], 1.0)
            K.apply_positional_impulse(X, Q, IM, II, g1, r1w, impulse[pi], -1.0)
        for ci in cis:
            edges = sw.contact_soft[ci][3]
            lam_n[ci] = sum(sw.edge_lam[ci][j] * edges[j][3] for j in range(len(edges)))

    def _attach(self, X, Q, g1, g2, r1, r2):
        """Attach two body points ([RB] Sec. 3.4.2): C = |p2 − p1|, α = 0."""
        r1w = quat_rotate(Q[g1], r1)
        r2w = quat_rotate(Q[g2], r2)
        x1, x2 = X[g1], X[g2]
        d = (x2[0] + r2w[0] - x1[0] - r1w[0], x2[1] + r2w[1] - x1[1] - r1w[1],
             x2[2] + r2w[2] - x1[2] - r1w[2])
        if self.block_attach:
            if d[0] != 0.0 or d[1] != 0.0 or d[2] != 0.0:
                K.solve_attachment_block(X, Q, self._IM, self._II, g1, g2, r1w, r2w, d)
            return
        c = math.sqrt(dot(d, d))
        if c > _EPS:
            solve_positional(X, Q, self._IM, self._II, g1, g2, r1w, r2w,
                             (d[0] / c, d[1] / c, d[2] / c), c)

    @staticmethod
    def _lock_errors(X, Q, g1, g2, r1, r2, aw, target, qt):
        """World lever arms, pin error [m] and rotation error [rad] (axis·angle) of a hinge held at angle ``target``."""
        r1w = quat_rotate(Q[g1], r1)
        r2w = quat_rotate(Q[g2], r2)
        x1, x2 = X[g1], X[g2]
        c_pin = (x2[0] + r2w[0] - x1[0] - r1w[0], x2[1] + r2w[1] - x1[1] - r1w[1],
                 x2[2] + r2w[2] - x1[2] - r1w[2])
        s, c = math.sin(0.5 * target), math.cos(0.5 * target)
        q2t = quat_mul((c, s * aw[0], s * aw[1], s * aw[2]), qt)
        qe = quat_mul(Q[g2], quat_conj(q2t))
        if qe[0] < 0.0:
            qe = (-qe[0], -qe[1], -qe[2], -qe[3])
        vn = math.sqrt(qe[1] * qe[1] + qe[2] * qe[2] + qe[3] * qe[3])
        if vn > _EPS:
            th = 2.0 * math.atan2(vn, qe[0]) / vn
            c_ang = (th * qe[1], th * qe[2], th * qe[3])
        else:
            c_ang = (0.0, 0.0, 0.0)
        return r1w, r2w, c_pin, c_ang

    def _hinge_at_limit(self, X, Q, g1, g2, r1, r2, aw, target, qt):
        """Hinge beyond a limit: project pin, axis and angle (clamped to ``target``)
        together with one 6-row block solve (see ``kernels.solve_lock_block``)."""
        r1w, r2w, c_pin, c_ang = self._lock_errors(X, Q, g1, g2, r1, r2, aw, target, qt)
        K.solve_lock_block(X, Q, self._IM, self._II, g1, g2, r1w, r2w, c_pin, c_ang)

    def _fix_orientation(self, Q, g1, g2, qoff):
        """Fixed relative orientation q2 = q1 ⊗ qoff ([RB] eqs. 18–19)."""
        qe = quat_mul(Q[g2], quat_conj(quat_mul(Q[g1], qoff)))
        if qe[0] < 0.0:
            qe = (-qe[0], -qe[1], -qe[2], -qe[3])
        s = math.sqrt(qe[1] * qe[1] + qe[2] * qe[2] + qe[3] * qe[3])
        if s > _EPS:
            th = 2.0 * math.atan2(s, qe[0])
            solve_angular(Q, self._IM, self._II, g1, g2, (qe[1] / s, qe[2] / s, qe[3] / s), th)

    def _soft_contact_targets(self, sw, X, Q, V, W, cands, h):
        """Per contact candidate, the compliant normal row of the substep: (r* [m], α̃ [m/(N·s²)·s²]).

        MuJoCo's soft contact law R·f = −(a + b·v + k·d·r) (``mujoco_contact_law``, from the
        geom pair's solref/solimp/condim and MuJoCo's effective-mass approximation) taken over
        the substep as MuJoCo takes it over its step (``mujoco_step_target``: the reference
        acceleration at the substep's start, a = (v⁺ − v⁻)/h, v⁺ = (r⁺ − r⁻)/h):

            r* = r⁻ + h·v⁻ − h²·(b·v⁻ + k·d·r⁻),  f = −(r⁺ − r*)/(R·h²),

        an XPBD row C = r − r* with compliance α = R·h² [m/N] (α̃ = R) and λ ≥ 0 (the pyramid
        edges below take the same step).  The regulariser's term R·f ∝ a is MuJoCo's own (the
        "virtual mass" of a soft constraint).  A contact that does not
        penetrate at the substep's start exerts no force in it (r* = −∞), as MuJoCo creates
        contacts only for dist < margin (0) at the start of its step.  MuJoCo's safety clamp
        timeconst ≥ 2·timestep is applied with the substep h (the step that integrates the law
        here), so a scene's solref keeps its meaning at any frame rate.  None for a rigid row (R = 0).
        """
        m = self.model
        out = []
        sw.edge_lam = [None] * len(cands)
        for ci, (g2, r2l, rad, g1, ol, nl, mu) in enumerate(cands):
            i = self._cidx[ci]
            n = quat_rotate(Q[g1], nl)
            o = quat_rotate(Q[g1], ol)
            r2 = quat_rotate(Q[g2], r2l)
            p = (X[g2][0] + r2[0], X[g2][1] + r2[1], X[g2][2] + r2[2])
            gap = (p[0] - X[g1][0] - o[0]) * n[0] + (p[1] - X[g1][1] - o[1]) * n[1] + (p[2] - X[g1][2] - o[2]) * n[2] - rad
            r1 = (p[0] - X[g1][0], p[1] - X[g1][1], p[2] - X[g1][2])
            va = point_velocity(V, W, g2, r2)
            vb = point_velocity(V, W, g1, r1)
            rate = (va[0] - vb[0]) * n[0] + (va[1] - vb[1]) * n[1] + (va[2] - vb[2]) * n[2]
            kd, b, R = mujoco_contact_law(m.contact_solref[i], m.contact_solimp[i], int(m.contact_condim[i]),
                                          float(m.contact_tran[i]), float(m.contact_mu[i]), min(gap, 0.0),
                                          cone=m.contact_cone, impratio=m.contact_impratio, timestep=h)
            if R <= 0.0:
                out.append(None)
                continue
            if gap >= 0.0:  # MuJoCo instantiates a contact only once it penetrates (margin 0)
                out.append((-math.inf, 0.0))
                continue
            condim = int(m.contact_condim[i])
            if self.pyramid_friction and condim >= 3 and m.contact_cone == 0:
                # edge rows e = n ± μ·t_k: R_e·f_e = −(e·a + b·e·v + k·d·r), semi-implicit as MuJoCo
                # (aref from the state at the substep's start), on the displacement along e
                ne = 2 * (condim - 1)
                r_edge = R * ne
                rel = (p[0] - rad * n[0], p[1] - rad * n[1], p[2] - rad * n[2])  # surface point
                r1c = (rel[0] - X[g1][0], rel[1] - X[g1][1], rel[2] - X[g1][2])
                r2c = (rel[0] - X[g2][0], rel[1] - X[g2][1], rel[2] - X[g2][2])
                va = point_velocity(V, W, g2, r2c)
                vb = point_velocity(V, W, g1, r1c)
                vr = (va[0] - vb[0], va[1] - vb[1], va[2] - vb[2])
                t1 = quat_rotate(Q[g1], self._plane_tangent[int(m.contact_plane[i])])  # the plane's own tangent
                t2 = cross(n, t1)
                edges = []
                for t in (t1, t2):
                    for sgn in (1.0, -1.0):
                        e = (n[0] + sgn * mu * t[0], n[1] + sgn * mu * t[1], n[2] + sgn * mu * t[2])
                        le = math.sqrt(dot(e, e))
                        ve = dot(vr, e)
                        target = h * ve - h * h * (b * ve + kd * gap)
                        edges.append(((e[0] / le, e[1] / le, e[2] / le), target / le, r_edge / (le * le), 1.0 / le))
                sw.edge_lam[ci] = [0.0] * len(edges)
                out.append((_PYRAMID, quat_rotate_inv(Q[g1], r1c), quat_rotate_inv(Q[g2], r2c), edges))
                continue
            out.append((mujoco_step_target(gap, rate, kd, b, h), R))
        return out

    def _contact_normal(self, sw, X, Q, ci, cand, lam_n, cinfo):
        """Plane contact, normal part ([RB] Sec. 3.5): C = d ≥ 0 at the deepest point."""
        g2, r2l, rad, g1, ol, nl, mu = cand
        q1, q2 = Q[g1], Q[g2]
        x1, x2 = X[g1], X[g2]
        n = quat_rotate(q1, nl)
        o = quat_rotate(q1, ol)
        r2c = quat_rotate(q2, r2l)
        p = (x2[0] + r2c[0], x2[1] + r2c[1], x2[2] + r2c[2])
        d = (p[0] - x1[0] - o[0]) * n[0] + (p[1] - x1[1] - o[1]) * n[1] + \
            (p[2] - x1[2] - o[2]) * n[2] - rad
        soft = None if sw.contact_soft is None else sw.contact_soft[ci]
        if soft is not None:  # MuJoCo-equivalent compliant normal: f = −(d − r*)/α ≥ 0
            c = d - soft[0]
            if c >= 0.0 and lam_n[ci] <= 0.0:
                return
        elif d >= 0.0:
            return
        s2 = (p[0] - rad * n[0], p[1] - rad * n[1], p[2] - rad * n[2])  # surface point
        s1 = (s2[0] - d * n[0], s2[1] - d * n[1], s2[2] - d * n[2])     # on the plane
        r1 = (s1[0] - x1[0], s1[1] - x1[1], s1[2] - x1[2])
        r2 = (s2[0] - x2[0], s2[1] - x2[1], s2[2] - x2[2])
        if ci not in cinfo:  # body-fixed contact points, kept for friction and velocities
            cinfo[ci] = (quat_rotate_inv(q1, r1), quat_rotate_inv(q2, r2), nl)
        if soft is not None:
            lam_n[ci] += solve_positional(X, Q, self._IM, self._II, g1, g2, r1, r2, n, c, soft[1], lam_n[ci], 0.0)
            return
        lam_n[ci] += solve_positional(X, Q, self._IM, self._II, g1, g2, r1, r2, n, d)

    def _contact_static_friction(self, X, Q, ci, cand, lam_n, lam_t, cinfo, Xp, Qp):
        """Static friction ([RB] Sec. 3.5): cancel the relative tangential motion of the
        contact points over the substep if the needed multiplier stays inside the cone
        λ_t < μ_s λ_n (μ_s = μ_d = geom friction[0])."""
        g2, _, _, g1, _, _, mu = cand
        r1l, r2l, nl = cinfo[ci]
        if mu <= 0.0 or lam_n[ci] <= 0.0:
            return
        IM, II = self._IM, self._II
        q1, q2 = Q[g1], Q[g2]
        r1w = quat_rotate(q1, r1l)
        r2w = quat_rotate(q2, r2l)
        r1p = quat_rotate(Qp[g1], r1l)
        r2p = quat_rotate(Qp[g2], r2l)
        x1, x2, x1p, x2p = X[g1], X[g2], Xp[g1], Xp[g2]
        dp = [(x2[k] + r2w[k] - x2p[k] - r2p[k]) - (x1[k] + r1w[k] - x1p[k] - r1p[k])
              for k in range(3)]
        n = quat_rotate(q1, nl)
        dn = dot(dp, n)
        dt_ = (dp[0] - dn * n[0], dp[1] - dn * n[1], dp[2] - dn * n[2])
        c = math.sqrt(dot(dt_, dt_))
        if c <= _EPS:
            return
        t = (dt_[0] / c, dt_[1] / c, dt_[2] / c)
        w = positional_inverse_mass(IM[g1], II[g1], q1, r1w, t) + \
            positional_inverse_mass(IM[g2], II[g2], q2, r2w, t)
        if w <= 0.0:
            return
        dlt = c / w
        if lam_t[ci] + dlt < mu * lam_n[ci]:
            lam_t[ci] += dlt
            solve_positional(X, Q, IM, II, g1, g2, r1w, r2w, t, c)

    def _solve_velocities(self, sw, V, W, Q, X, cinfo, lam_n, cands, h):
        """Velocity pass ([RB] Sec. 3.6): contacts, then implicit joint damping.

        Contacts use ``velocity_sweeps`` projected Gauss-Seidel sweeps.  Per contact:
        dynamic friction ([RB] eq. 30) as an impulse that cancels the tangential
        velocity, with the accumulated friction impulse clamped to μ f_n h = μ λ_n / h
        (Coulomb cone); then restitution with e = 0 ([RB] eq. 34, Δv = −v_n n), with the
        accumulated normal impulse clamped so the contact never pulls harder than the
        position solve pushed (j_n ≥ −λ_n/h).  One sweep, as in the paper, leaves a bias
        when several coplanar points of one body touch.
        """
        IM, II = self._IM, self._II
        if cinfo:
            items = list(cinfo.items())
            acc_t = {ci: (0.0, 0.0, 0.0) for ci, _ in items}
            acc_n = {ci: 0.0 for ci, _ in items}
            for _ in range(self.velocity_sweeps):
                for ci, (r1l, r2l, nl) in items:
                    g2, _, _, g1, _, _, mu = cands[ci]
                    if sw.contact_soft is not None and sw.contact_soft[ci] is not None and sw.contact_soft[ci][0] == _PYRAMID:
                        continue
                    ln = lam_n[ci]
                    q1, q2 = Q[g1], Q[g2]
                    n = quat_rotate(q1, nl)
                    r1 = quat_rotate(q1, r1l)
                    r2 = quat_rotate(q2, r2l)
                    if mu > 0.0 and ln > 0.0:
                        va = point_velocity(V, W, g2, r2)
                        vb = point_velocity(V, W, g1, r1)
                        vr = (va[0] - vb[0], va[1] - vb[1], va[2] - vb[2])
                        vn = dot(vr, n)
                        vt = (vr[0] - vn * n[0], vr[1] - vn * n[1], vr[2] - vn * n[2])
                        vtl = math.sqrt(dot(vt, vt))
                        if vtl > _EPS:
                            t = (vt[0] / vtl, vt[1] / vtl, vt[2] / vtl)
                            w = positional_inverse_mass(IM[g1], II[g1], q1, r1, t) + \
                                positional_inverse_mass(IM[g2], II[g2], q2, r2, t)
                            if w > 0.0:
                                j = -vtl / w
                                old = acc_t[ci]
                                new = (old[0] + j * t[0], old[1] + j * t[1], old[2] + j * t[2])
                                cap = mu * ln / h
                                mag = math.sqrt(dot(new, new))
                                if mag > cap:
                                    sc = cap / mag
                                    new = (new[0] * sc, new[1] * sc, new[2] * sc)
                                p = (new[0] - old[0], new[1] - old[1], new[2] - old[2])
                                acc_t[ci] = new
                                apply_velocity_impulse(V, W, Q, IM, II, g2, r2, p, 1.0)
                                apply_velocity_impulse(V, W, Q, IM, II, g1, r1, p, -1.0)
                    if sw.contact_soft is not None and sw.contact_soft[ci] is not None:
                        continue  # compliant normal: its damping is in the position law
                    va = point_velocity(V, W, g2, r2)
                    vb = point_velocity(V, W, g1, r1)
                    vn = (va[0] - vb[0]) * n[0] + (va[1] - vb[1]) * n[1] + (va[2] - vb[2]) * n[2]
                    if vn == 0.0:
                        continue
                    w = positional_inverse_mass(IM[g1], II[g1], q1, r1, n) + \
                        positional_inverse_mass(IM[g2], II[g2], q2, r2, n)
                    if w > 0.0:
                        old = acc_n[ci]
                        new = max(old - vn / w, -ln / h)
                        jn = new - old
                        acc_n[ci] = new
                        p = (jn * n[0], jn * n[1], jn * n[2])
                        apply_velocity_impulse(V, W, Q, IM, II, g2, r2, p, 1.0)
                        apply_velocity_impulse(V, W, Q, IM, II, g1, r1, p, -1.0)
        # joint damping, implicit: rate_new = rate / (1 + b h w)
        for (t, g1, g2, r1, r2, a1, a2, qoff, limited, lo, hi, b) in self._damped:
            q1, q2 = Q[g1], Q[g2]
            if t == JNT_HINGE or t == JNT_BALL:
                w1, w2 = W[g1], W[g2]
                rel = (w2[0] - w1[0], w2[1] - w1[1], w2[2] - w1[2])
                if t == JNT_HINGE:
                    n = quat_rotate(q1, a1)
                    rate = dot(rel, n)
                else:
                    rate = math.sqrt(dot(rel, rel))
                    if rate <= _EPS:
                        continue
                    n = (rel[0] / rate, rel[1] / rate, rel[2] / rate)
                wsum = (angular_inverse_mass(II[g1], q1, n) if IM[g1] else 0.0) + \
                       (angular_inverse_mass(II[g2], q2, n) if IM[g2] else 0.0)
                if wsum <= 0.0:
                    continue
                jimp = rate * b * h / (1.0 + b * h * wsum)
                p = (jimp * n[0], jimp * n[1], jimp * n[2])
                apply_angular_velocity_impulse(W, Q, IM, II, g2, p, -1.0)
                apply_angular_velocity_impulse(W, Q, IM, II, g1, p, 1.0)
            else:  # slide
                n = quat_rotate(q1, a1)
                x1, x2 = X[g1], X[g2]
                r1w = (x2[0] - x1[0], x2[1] - x1[1], x2[2] - x1[2])
                zero = (0.0, 0.0, 0.0)
                v1 = point_velocity(V, W, g1, r1w)
                v2 = V[g2]
                rate = (v2[0] - v1[0]) * n[0] + (v2[1] - v1[1]) * n[1] + (v2[2] - v1[2]) * n[2]
                wsum = positional_inverse_mass(IM[g1], II[g1], q1, r1w, n) + \
                    positional_inverse_mass(IM[g2], II[g2], q2, zero, n)
                if wsum <= 0.0:
                    continue
                jimp = rate * b * h / (1.0 + b * h * wsum)
                p = (jimp * n[0], jimp * n[1], jimp * n[2])
                apply_velocity_impulse(V, W, Q, IM, II, g2, zero, p, -1.0)
                apply_velocity_impulse(V, W, Q, IM, II, g1, r1w, p, 1.0)

    def _group_jacobian(self, X, Q):
        """G (ngroup, 6, njnt): COM velocity [m/s] and angular velocity [rad/s] of every dynamic
        group per unit rate of each joint (hinge: (a × (x_g − p), a) for the groups of its
        subtree, a the world axis and p the anchor on the parent; slide: (a, 0)); None unless the
        joints are hinges and slides of a tree (numpy reference of ``compiled.group_jacobian``)."""
        ng, nj = len(X), len(self._joints)
        parent = [-1] * ng
        for j, jt in enumerate(self._joints):
            if jt[0] not in (JNT_HINGE, JNT_SLIDE) or parent[jt[2]] >= 0:
                return None
            parent[jt[2]] = j
        G = np.zeros((ng, 6, nj))
        for j, (t, g1, _, r1, _, a1) in enumerate(jt[:6] for jt in self._joints):
            a = np.asarray(quat_rotate(Q[g1], a1))
            p = np.asarray(X[g1]) + np.asarray(quat_rotate(Q[g1], r1))
            for g in range(ng):
                if self._IM[g] == 0.0:
                    continue
                b, inside = g, False
                for _ in range(nj + 1):
                    pj = parent[b]
                    if pj < 0:
                        break
                    if pj == j:
                        inside = True
                        break
                    b = self._joints[pj][1]
                if not inside:
                    continue
                if t == JNT_HINGE:
                    G[g, :3, j] = np.cross(a, np.asarray(X[g]) - p)
                    G[g, 3:, j] = a
                else:
                    G[g, :3, j] = a
        return G

    def _articulated_inverse(self, X, Q):
        """(G, M⁻¹) of a hinge/slide tree at the pose (X, Q): M = Σ_g m_g·G_linᵀG_lin + G_angᵀ·I_g·G_ang
        (``compiled.articulated_inverse``), or None (other joints, no joints, singular M)."""
        if not self._joints:
            return None
        G = self._group_jacobian(X, Q)
        if G is None:
            return None
        nj = G.shape[2]
        M = np.zeros((nj, nj))
        for g in range(len(X)):
            if self._IM[g] == 0.0:
                continue
            lin = G[g, :3]
            R = np.array(K._mat_from_quat(Q[g]))
            wl = R.T @ G[g, 3:]  # joint rates' angular velocities in the group's principal frame
            M += lin.T @ lin / self._IM[g] + wl.T @ (np.asarray(self._GI[g])[:, None] * wl)
        if not np.linalg.svd(M, compute_uv=False)[-1] > 1e-12 * np.max(np.abs(np.diag(M))):
            return None
        return G, np.linalg.inv(M)

    def _transport_start(self, X, Q):
        """P₀ = (G₀ᵀG₀)⁻¹G₀ᵀ at the step's start pose, or None (no transport: option off, not a
        hinge/slide tree, no joints, singular)."""
        if not self.transport_response or not self._joints:
            return None
        G = self._group_jacobian(X, Q)
        if G is None:
            return None
        A = G.reshape(-1, G.shape[2])
        N = A.T @ A
        if not np.linalg.svd(N, compute_uv=False)[-1] > 1e-12 * np.max(np.abs(np.diag(N))):
            return None
        return np.linalg.solve(N, A.T)

    def _transported(self, inp, X, Q, P0):
        """``inp`` with its articulated responses carried to the pose (X, Q) (``transport_response``)."""
        if inp is None or (inp.row_mobility is None and inp.group_gravity is None):
            return inp
        G = self._group_jacobian(X, Q)
        mob, gg = inp.row_mobility, inp.group_gravity
        if mob is not None:
            mob = np.asarray(mob, float)
            dq = mob.reshape(mob.shape[0], -1) @ P0.T  # (rows, njnt)
            mob = np.einsum("gci,ri->rgc", G, dq)
        if gg is not None:
            gg = G @ (P0 @ np.asarray(gg, float).reshape(-1))
        return replace(inp, row_mobility=mob, group_gravity=gg)

    def _row_kinematics(self, x, q, v, w):
        nr = len(self._rows)
        if nr == 0:
            return np.zeros(0), np.zeros(0)
        ga = [r[0] for r in self._rows]
        gb = [r[1] for r in self._rows]
        ra = np_quat_rotate(q[ga], np.array([r[2] for r in self._rows]))
        rb = np_quat_rotate(q[gb], np.array([r[3] for r in self._rows]))
        d = x[gb] + rb - x[ga] - ra
        ell = np.linalg.norm(d, axis=1)
        n = d / np.where(ell > 0, ell, 1.0)[:, None]
        dv = (v[gb] + np_cross(w[gb], rb)) - (v[ga] + np_cross(w[ga], ra))
        return ell, np.einsum("ij,ij->i", dv, n)


class ReferenceSolver(ReferenceSubstep, SolverXPBD):
    """:class:`SolverXPBD` stepping through the pure substep (the oracle); same constructor plus ``block_attach``
    (False: the scalar pin projection)."""

    def __init__(self, model, options=None, *, length_constraints=(), block_attach: bool = True):
        super().__init__(model, options, length_constraints=length_constraints)
        self.block_attach = bool(block_attach)

    def step(self, state, dt, *, hooks=None, inputs=None):
        """``SolverXPBD.step`` with every substep in pure Python."""
        x, q, v, w = self._gather(state)
        cands = self._collect_contacts(x, q, v, w, dt)
        return self._step_reference(state, dt, hooks, inputs, x, q, v, w, cands)

    def _gather(self, state):
        """Group state at the centres of mass from the bodies (numpy; oracle of ``compiled.gather``)."""
        m = self.model
        r = m.group_root
        qr = state.q[r]
        q = np_quat_mul(qr, m.group_from_root_quat)
        x = state.x[r] + np_quat_rotate(qr, m.group_from_root_pos)
        w = state.w[r].copy()
        v = state.v[r] + np_cross(w, x - state.x[r])
        x[0], q[0], v[0], w[0] = 0.0, (1.0, 0.0, 0.0, 0.0), 0.0, 0.0
        return x, q, v, w

    def _scatter(self, x, q, v, w, state):
        """Body state from the groups (numpy; oracle of ``compiled.scatter``)."""
        m = self.model
        g = m.body_group
        qg = q[g]
        state.q[:] = np_quat_mul(qg, m.body_in_group_quat)
        state.x[:] = x[g] + np_quat_rotate(qg, m.body_in_group_pos)
        state.w[:] = w[g]
        state.v[:] = v[g] + np_cross(w[g], state.x - x[g])

    def _collect_contacts(self, x, q, v, w, dt):
        """Contact candidates for the whole step ([RB] Algorithm 2, CollectCollisionPairs; numpy oracle of
        ``compiled.contact_candidates``): gap below the margin + 2·dt·|v_rel|."""
        m = self.model
        self._cidx = []
        if len(m.contact_group) == 0:
            return []
        g = m.contact_group
        pl = m.contact_plane
        pg = m.plane_group[pl]
        P = x[g] + np_quat_rotate(q[g], m.contact_local)
        n = np_quat_rotate(q[pg], m.plane_normal[pl])
        o = x[pg] + np_quat_rotate(q[pg], m.plane_origin[pl])
        d = np.einsum("ij,ij->i", P - o, n) - m.contact_radius
        vrel = (v[g] + np_cross(w[g], P - x[g])) - (v[pg] + np_cross(w[pg], P - x[pg]))
        margin = self.contact_margin + 2.0 * dt * np.linalg.norm(vrel, axis=1)
        idx = np.nonzero(d < margin)[0]
        self._cidx = [int(i) for i in idx]
        return [(int(g[i]), tuple(map(float, m.contact_local[i])), float(m.contact_radius[i]),
                 int(pg[i]), tuple(map(float, m.plane_origin[pl[i]])),
                 tuple(map(float, m.plane_normal[pl[i]])), float(m.contact_mu[i]))
                for i in idx]
