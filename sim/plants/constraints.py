"""The MJCF's equality constraints (loop closures) at a pose: their Jacobian, violation, and a pose on them.

Outside models close their kinematic loops with ``<equality><connect>`` (a
cylinder's rod body pinned to the link it pushes, the second bar of an H-link)
and weld a free base to the world with ``<weld>``.  Statics and the inertia an
actuator sees must include them (:mod:`hydraulics.equilibrium`), and a start
pose must satisfy them, or the pins carry no load and the first steps snap the
loop shut.  Everything here uses MuJoCo's kinematics (``mj_forward`` fills the
constraint rows; no step is taken).

* :func:`equality_rows`: G (rows × nv), violation r [m or rad] and the
  equality's MJCF name per row, from MuJoCo's constraint rows
  (``efc_type == mjCNSTR_EQUALITY``; ``efc_pos`` is the violation).
* :func:`limit_rows`: the active joint- and tendon-limit rows (the limits that can carry load).
* :func:`project_pose`: Gauss–Newton on r(q) = 0 moving only the joints the
  user did not set, Δq = −G_free⁺·r (least-norm); a pose it cannot close
  raises :class:`~sim.io.scenario.ScenarioError` naming the equality.
* :func:`holding_efforts` / :func:`inverse_inertia`: the MuJoCo-side inputs of
  :func:`hydraulics.equilibrium.holding_efforts` and
  :func:`hydraulics.equilibrium.constrained_inverse_inertia`.

Example::

    d = mujoco.MjData(m); d.qpos[:] = q; mujoco.mj_forward(m, d)
    G, r, names = equality_rows(m, d)
"""

from __future__ import annotations

import mujoco
import numpy as np

from hydraulics.equilibrium import constrained_inverse_inertia
from hydraulics.equilibrium import holding_efforts as solve_holding

EQUALITY_TOLERANCE = 1e-6  # m (connect) or rad (weld): a start pose the free joints cannot bring closer is refused
PROJECTION_TARGET = 1e-12  # m or rad: the projection stops below this violation
PROJECTION_ITERATIONS = 50  # Gauss-Newton iterations of project_pose
BACKTRACK_HALVINGS = 20  # step halvings per iteration when a full step does not reduce the violation
HOLDING_RESIDUAL_WARN = 1e-6  # relative residual of the static balance above which the start is not in equilibrium
LIMIT_CONTACT = 1e-9  # rad or m: a joint this close to a range end rests on its stop

_EQUALITY = int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)
_LIMITS = (int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT), int(mujoco.mjtConstraint.mjCNSTR_LIMIT_TENDON))


def _dense_efc(m, d) -> np.ndarray:
    """MuJoCo's constraint Jacobian efc_J as a dense (nefc × nv) array (sparse or dense storage)."""
    nefc = int(d.nefc)
    if not nefc:
        return np.zeros((0, m.nv))
    if mujoco.mj_isSparse(m):
        dense = np.zeros((nefc, m.nv))
        mujoco.mju_sparse2dense(dense, d.efc_J, d.efc_J_rownnz[:nefc], d.efc_J_rowadr[:nefc], d.efc_J_colind)
        return dense
    return np.array(d.efc_J[: nefc * m.nv]).reshape(nefc, m.nv)


def actuator_moments(m, d, actuator_id) -> np.ndarray:
    """Dense moments J (len(actuator_id) × nv) of the given MuJoCo actuators (after ``mj_forward``): v = J·q̇."""
    J = np.zeros((len(actuator_id), m.nv))
    for i, aid in enumerate(actuator_id):
        adr, nnz = d.moment_rowadr[aid], d.moment_rownnz[aid]
        J[i, d.moment_colind[adr : adr + nnz]] = d.actuator_moment[adr : adr + nnz]
    return J


def equality_name(m, e: int) -> str:
    """The MJCF name of equality ``e``, or a description by type and objects when it has none."""
    name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_EQUALITY, e)
    if name:
        return name
    kind = mujoco.mjtEq(int(m.eq_type[e])).name.removeprefix("mjEQ_").lower()
    obj = mujoco.mjtObj(int(m.eq_objtype[e]))
    names = [mujoco.mj_id2name(m, obj, int(i)) or str(int(i)) for i in (m.eq_obj1id[e], m.eq_obj2id[e])]
    return f"{kind} {names[0]}-{names[1]}"


def equality_rows(m, d):
    """(G (rows × nv), violation r (rows,) [m or rad], equality name per row) of the active equalities (after mj_forward)."""
    rows = np.flatnonzero(np.asarray(d.efc_type[: d.nefc]) == _EQUALITY)
    if not len(rows):
        return np.zeros((0, m.nv)), np.zeros(0), ()
    G = _dense_efc(m, d)[rows]
    names = tuple(equality_name(m, int(e)) for e in d.efc_id[rows])
    return G, np.array(d.efc_pos[rows]), names


def joint_stop_rows(m, qpos, skip=()) -> np.ndarray:
    """Rows (n × nv) of the limited hinges and slides at an end of their range in ``qpos`` (within ``LIMIT_CONTACT``),
    each oriented so that a positive force pushes back into the range; joints in ``skip`` left out."""
    scalar = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    rows = []
    for j in range(m.njnt):
        if j in skip or not m.jnt_limited[j] or int(m.jnt_type[j]) not in scalar:
            continue
        value = float(qpos[m.jnt_qposadr[j]])
        for end, sign in ((float(m.jnt_range[j][0]), 1.0), (float(m.jnt_range[j][1]), -1.0)):
            if abs(value - end) <= LIMIT_CONTACT:
                row = np.zeros(m.nv)
                row[m.jnt_dofadr[j]] = sign
                rows.append(row)
    return np.array(rows, float).reshape(len(rows), m.nv)


def limit_rows(m, d) -> np.ndarray:
    """Rows (n × nv) of the limits that can carry load at this pose (after mj_forward).

    MuJoCo's active joint- and tendon-limit rows, and every limited hinge or slide at
    an end of its range (:func:`joint_stop_rows`; MuJoCo counts a limit active only
    once it is passed).  Each row is oriented so that a positive force pushes back
    into the range: a stop pushes, it never pulls.
    """
    rows = np.flatnonzero(np.isin(np.asarray(d.efc_type[: d.nefc]), _LIMITS))
    active = {int(d.efc_id[r]) for r in rows if int(d.efc_type[r]) == _LIMITS[0]}
    mujoco_rows = _dense_efc(m, d)[rows] if len(rows) else np.zeros((0, m.nv))
    return np.vstack([mujoco_rows, joint_stop_rows(m, d.qpos, active)])


def hold_with_stops(moment, load, equalities, stops):
    """:func:`hydraulics.equilibrium.holding_efforts` with the equality rows, then, if they cannot hold the load,
    with the stop rows that push too (active set: a stop that would have to pull leaves).  Returns (effort, residual)."""
    effort, _, residual = solve_holding(moment, load, equalities)
    G = np.zeros((0, len(load))) if equalities is None else equalities
    if residual > HOLDING_RESIDUAL_WARN:
        while len(stops):
            with_stops, force, with_residual = solve_holding(moment, load, np.vstack([G, stops]))
            pulling = force[len(G):] < 0.0
            if not np.any(pulling):
                return with_stops, with_residual
            stops = stops[~pulling]
    return effort, residual


def _forward(m, d, qpos, qvel=None):
    d.qpos[:] = qpos
    d.qvel[:] = 0.0 if qvel is None else qvel
    mujoco.mj_forward(m, d)


def held_dofs(m, joint_names) -> np.ndarray:
    """Boolean mask (nv,) of the DOFs of the named joints (the ones the user set: the projection keeps them)."""
    held = np.zeros(m.nv, bool)
    for name in joint_names:
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j >= 0:
            held[m.jnt_dofadr[j]] = True
    return held


def project_pose(m, qpos, qvel, held, *, where: str = ""):
    """qpos, qvel on the equality constraints, moving only DOFs not in ``held`` (least-norm Gauss–Newton).

    Returns ``(qpos, qvel, moved)`` with ``moved`` the largest |Δq| of any DOF.
    Raises :class:`~sim.io.scenario.ScenarioError` (prefixed by ``where``) naming
    the worst equality when the free DOFs cannot close it (the set joints
    contradict the loop, or it cannot be closed at all).
    """
    from sim.io.scenario import ScenarioError

    if not m.neq:
        return qpos, qvel, 0.0
    d = mujoco.MjData(m)
    q = np.array(qpos, float)
    free = ~np.asarray(held, bool)
    names = ()
    r = np.zeros(0)
    for _ in range(PROJECTION_ITERATIONS):
        _forward(m, d, q)
        G, r, names = equality_rows(m, d)
        if not len(r) or np.max(np.abs(r)) < PROJECTION_TARGET:
            break
        step = np.zeros(m.nv)
        step[free] = -np.linalg.lstsq(G[:, free], r, rcond=None)[0]
        if not np.any(step):
            break
        size = np.linalg.norm(r)
        for _ in range(BACKTRACK_HALVINGS):  # halve a step that would not reduce the violation
            trial = q.copy()
            mujoco.mj_integratePos(m, trial, step, 1.0)
            _forward(m, d, trial)
            if np.linalg.norm(equality_rows(m, d)[1]) < size:
                break
            step *= 0.5
        q = trial
    else:
        _forward(m, d, q)
        G, r, names = equality_rows(m, d)
    if len(r) and np.max(np.abs(r)) >= EQUALITY_TOLERANCE:
        worst = int(np.argmax(np.abs(r)))
        set_joints = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.dof_jntid[i])) for i in np.flatnonzero(~free)]
        raise ScenarioError(
            f"{where}equality '{names[worst]}' is violated by {abs(r[worst]):.3g} (m or rad) at the start pose and the joints "
            f"not set in [initial] cannot close it" + (f" with {set_joints} held" if set_joints else "")
            + "; set fewer joints of that loop, or values that close it"
        )
    moved = np.zeros(m.nv)
    mujoco.mj_differentiatePos(m, moved, 1.0, np.asarray(qpos, float), q)
    v = np.array(qvel, float)
    _forward(m, d, q)
    G, _, _ = equality_rows(m, d)
    if len(G) and np.any(G @ v):
        fix = np.zeros(m.nv)
        fix[free] = -np.linalg.lstsq(G[:, free], G @ v, rcond=None)[0]
        v = v + fix
    return q, v, float(np.max(np.abs(moved), initial=0.0))


def static_load(m, d, contacts: bool = False) -> np.ndarray:
    """Generalized load Q [N or N·m] the actuators and equalities must hold at rest (after mj_forward with qvel = 0).

    MuJoCo's inverse dynamics with q̈ = 0 (``qfrc_inverse``): gravity and bias minus
    passive forces, minus what the soft limits (and, with ``contacts``, the soft contacts)
    already carry at their penetration; the equality rows carry nothing there (at rest on
    the constraint their reference acceleration is 0), so their share is solved for.
    Without ``contacts`` the contacts of the pose are left out (a start pose's mesh overlaps
    would otherwise prop the machine up; :func:`start_contacts` names them).  ``d`` then holds
    the pose without its contact rows.
    """
    flags = m.opt.disableflags
    if not contacts:
        m.opt.disableflags = flags | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    try:
        if not contacts:
            mujoco.mj_forward(m, d)
        d.qacc[:] = 0.0
        mujoco.mj_inverse(m, d)
    finally:
        m.opt.disableflags = flags
    return np.array(d.qfrc_inverse)


def start_contacts(m, qpos) -> tuple:
    """The contacts MuJoCo finds at ``qpos`` at rest: ((geom, geom, normal force [N]), …), the force being what each
    carries at its penetration (MuJoCo's inverse dynamics with q̈ = 0)."""
    d = mujoco.MjData(m)
    _forward(m, d, qpos)
    if not d.ncon:
        return ()
    d.qacc[:] = 0.0
    mujoco.mj_inverse(m, d)
    out, wrench = [], np.zeros(6)
    for i in range(d.ncon):
        mujoco.mj_contactForce(m, d, i, wrench)
        names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(g)) or f"#{int(g)}" for g in d.contact.geom[i]]
        out.append((names[0], names[1], float(wrench[0])))
    return tuple(out)


def holding_efforts(m, qpos, moment_of, contacts: bool = False):
    """Actuator efforts [N or N·m] that hold ``qpos`` at rest with the equalities (and, if needed, the limits) carrying load.

    ``moment_of(d)`` returns the dense moments J (actuators × nv) after mj_forward; ``contacts``: whether the
    contacts of the pose carry load (:func:`static_load`).
    Returns ``(effort, relative_residual)`` (:func:`hydraulics.equilibrium.holding_efforts`).
    The active joint and tendon limits join the balance only when the actuators
    and equalities alone cannot hold the pose (a mechanism resting on its stop).
    """
    d = mujoco.MjData(m)
    _forward(m, d, qpos)
    J = moment_of(d)
    G, _, _ = equality_rows(m, d)
    stops = limit_rows(m, d)
    load = static_load(m, d, contacts)
    return hold_with_stops(J, load, G, stops)


def impedance(solimp, violation: float) -> float:
    """MuJoCo's constraint impedance d ∈ (0, 1) at a violation [m or rad] (solimp = d₀, d_max, width, midpoint,
    power; MuJoCo's documentation, "Solver parameters"): d₀ at no violation, d_max beyond ``width``, joined by the
    two-piece power sigmoid."""
    d0, dmax, width, mid, power = (float(v) for v in solimp[:5])
    x = min(abs(violation) / width, 1.0) if width > 0 else 1.0
    if power == 1.0 or x in (0.0, 1.0):
        y = x
    elif x <= mid:
        y = x**power / mid ** (power - 1.0)
    else:
        y = 1.0 - (1.0 - x) ** power / (1.0 - mid) ** (power - 1.0)
    return d0 + y * (dmax - d0)


def closure_gaps(m, qpos, moment_of) -> dict:
    """How far each ``connect`` equality opens [m] when the machine rests at ``qpos``: {name: (gap [m], force [N])}.

    MuJoCo's equalities are soft.  At rest (no velocity, no acceleration) an equality row with force f satisfies
    f = a_ref/R with a_ref = −K·d·r (MuJoCo's documentation, "Solver parameters": K = 1/(d_max²·τ²·ζ²) from
    ``solref`` = (τ, ζ), R = (1 − d)/d·A_ii the regulariser, d the impedance of ``solimp``), so it holds its load
    open by r = f·(1 − d)·A_ii/(K·d²).  The force f is the closure's share of the static load
    (:func:`hydraulics.equilibrium.holding_efforts`, with the actuators' efforts); d is taken at the gap itself
    (a fixed point: once the gap exceeds ``solimp``'s width, d = d_max).  Checked against runs: the loop_arm with
    MuJoCo's default settings and 20 kg barrel / 60 kg rod is predicted to open 2.74 mm and opens 2.88 mm after 3 s
    of hold (the arm sags 3.5 mrad meanwhile); with 0.5 kg bodies 106 mm predicted, 107 mm run.
    """
    d = mujoco.MjData(m)
    _forward(m, d, qpos)
    rows = np.flatnonzero(np.asarray(d.efc_type[: d.nefc]) == _EQUALITY)
    if not len(rows):
        return {}
    stiffness, impedance0 = d.efc_KBIP[rows, 0].copy(), d.efc_KBIP[rows, 2].copy()
    diagonal = d.efc_R[rows] * impedance0 / (1.0 - impedance0)  # A_ii of MuJoCo's diagonal approximation
    ids = np.array(d.efc_id[rows])
    G, _, _ = equality_rows(m, d)
    _, force, _ = solve_holding(moment_of(d), static_load(m, d), G)
    out = {}
    for e in sorted(set(int(i) for i in ids)):
        if int(m.eq_type[e]) != int(mujoco.mjtEq.mjEQ_CONNECT):
            continue
        mine = ids == e
        f, k, a = np.abs(force[mine]), stiffness[mine], diagonal[mine]
        gap = 0.0
        for _ in range(50):
            imp = impedance(m.eq_solimp[e], gap)
            new = float(np.linalg.norm(f * (1.0 - imp) * a / (k * imp)))
            if abs(new - gap) <= 1e-12:
                break
            gap = new
        out[equality_name(m, e)] = (gap, float(np.linalg.norm(f)))
    return out


def inverse_inertia(m, qpos, moment_of, *, constrained: bool = True):
    """(1/m_eff (actuators,), velocity field (nv, actuators)) through the equality-constrained system at ``qpos``.

    ``constrained=False`` ignores the equalities: the inertia of the bodies the pins sit on alone
    (the rod body of a cylinder modelled with barrel and rod bodies), the mass of its local mode.
    """
    d = mujoco.MjData(m)
    _forward(m, d, qpos)
    mass = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, mass)
    G, _, _ = equality_rows(m, d) if constrained else (None, None, None)
    return constrained_inverse_inertia(mass, moment_of(d), G)


# ------------------------------------------------------------------- PBD mode: the XPBD model's own kinematics
def _rotate(quat, vec) -> np.ndarray:
    out = np.zeros(3)
    mujoco.mju_rotVecQuat(out, np.asarray(vec, float), np.asarray(quat, float))
    return out


def frame_equality_residual(m, xpos, xquat) -> np.ndarray:
    """Residual of the active connect and weld equalities from world body-frame poses (PBD mode's kinematics).

    connect: anchor on body 1 − anchor on body 2 [m] (3 rows); weld: the same for
    body 2's anchor and its image in body 1's relative pose, and the orientation
    error 2·vec(q₂⁻¹·q₁·q_rel) [rad] (6 rows).  Zero on the same manifold as MuJoCo's rows,
    with the same row space, which is all the statics and the constrained inertia need.
    """
    rows = []
    site = int(mujoco.mjtObj.mjOBJ_SITE)
    for e in range(m.neq):
        if not m.eq_active0[e]:
            continue
        kind, data = int(m.eq_type[e]), np.asarray(m.eq_data[e], float)
        o1, o2 = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
        if kind == int(mujoco.mjtEq.mjEQ_CONNECT):
            if int(m.eq_objtype[e]) == site:
                b1, b2, a1, a2 = int(m.site_bodyid[o1]), int(m.site_bodyid[o2]), m.site_pos[o1], m.site_pos[o2]
            else:
                b1, b2, a1, a2 = o1, o2, data[0:3], data[3:6]
            rows.append(xpos[b1] + _rotate(xquat[b1], a1) - xpos[b2] - _rotate(xquat[b2], a2))
        elif kind == int(mujoco.mjtEq.mjEQ_WELD) and int(m.eq_objtype[e]) != site:
            b1, b2 = o1, o2
            anchor2 = xpos[b2] + _rotate(xquat[b2], data[0:3])
            image1 = xpos[b1] + _rotate(xquat[b1], data[3:6] + _rotate(data[6:10] / np.linalg.norm(data[6:10]), data[0:3]))
            q1rel = np.zeros(4)
            mujoco.mju_mulQuat(q1rel, np.asarray(xquat[b1], float), data[6:10] / np.linalg.norm(data[6:10]))
            conj2, err = np.zeros(4), np.zeros(4)
            mujoco.mju_negQuat(conj2, np.asarray(xquat[b2], float))
            mujoco.mju_mulQuat(err, conj2, q1rel)
            rows.append(np.r_[image1 - anchor2, 2.0 * np.sign(err[0] or 1.0) * err[1:]])
    return np.concatenate(rows) if rows else np.zeros(0)


def frame_equality_jacobian(m, frames_of, qpos, step: float = 1e-6) -> np.ndarray:
    """G (rows × nv) of :func:`frame_equality_residual` by central differences of ``frames_of(qpos) -> (xpos, xquat)``."""
    G = []
    for i in range(m.nv):
        sides = []
        for sign in (1.0, -1.0):
            q = np.array(qpos, float)
            dv = np.zeros(m.nv)
            dv[i] = sign * step
            mujoco.mj_integratePos(m, q, dv, 1.0)
            sides.append(frame_equality_residual(m, *frames_of(q)))
        G.append((sides[0] - sides[1]) / (2.0 * step))
    return np.array(G).T.reshape(-1, m.nv) if G else np.zeros((0, m.nv))
