"""Compiled (numba ``nopython``) XPBD substep of :class:`sim.xpbd.solver.SolverXPBD`.

``substep_core`` advances the rigid groups by one substep h in place, on flat arrays:
prediction (gravity or given group accelerations, external forces, gyroscopic term,
hinge torque impulses), ``iterations`` position passes (symmetric Gauss-Seidel by default:
joints with limits (MuJoCo's soft limit law: a 6-row block with the angle compliant at a hinge limit, a
compliant row at a slide limit; or the rigid 6-row lock block), soft tendon limits (all active limits
in one articulated block when a tendon limit is active), connect/weld equalities, the
length rows — as one block with their articulated mobility or by Gauss-Seidel — and soft
pyramidal plane contacts solved per body pair with an active set, with the articulated
response of a hinge/slide tree (``articulated_inverse``) or the free-body one), the velocity update,
implicit joint damping and global damping.  An independent pure-Python substep with the same
order of operations (``tests/reference/xpbd_substep.py``) is its oracle in the tests; the results
agree to round-off (``tests/test_pbd_compiled.py``).  ``NUMBA_DISABLE_JIT=1`` runs these kernels
as Python.  Units and sign conventions as in ``solver.py``: positions [m], quaternions (w, x, y, z),
velocities [m/s], [rad/s], multipliers λ [N·s²] (row force λ/h² [N], + pushes the sites apart).

Contacts: MuJoCo's soft pyramidal edge rows (pyramidal cone, condim ≥ 3), a soft
normal row with [RB]'s Coulomb friction (elliptic cone, condim 1), or rigid rows (``soft_contacts``
off, or μ = 0 on a pyramidal cone) with [RB]'s velocity pass.

Names in brackets like ``ReferenceSubstep._solve_joints``, ``xpbd_kernels.point_mobility`` or
``xpbd_laws.mujoco_step_target`` point to the same equation in the oracle of the tests (``tests/reference/``).

Arguments come in named layouts (namedtuples of arrays, built once per solver or plant): the
static ``GroupModel`` and ``BodyTree``, per substep ``SubstepRows``, ``SubstepLoads``,
``ContactRows``, ``SubstepOptions``, the outputs ``RowOutputs`` and the scratch ``SubstepWork``
(``substep_work``).  numba passes a namedtuple as its fields, so a layout costs nothing at run time.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

_EPS = 1e-14
JNT_FREE, JNT_BALL, JNT_SLIDE, JNT_HINGE = 0, 1, 2, 3
EQ_CONNECT, EQ_WELD = 0, 1
# kind of a contact candidate in a substep (``_contact_targets``): no force (a soft contact that does not penetrate
# at the substep's start), soft pyramidal edge rows, a soft normal row with Coulomb friction, a rigid normal row
CONTACT_IDLE, CONTACT_PYRAMID, CONTACT_SOFT, CONTACT_RIGID = 0, 1, 2, 3
# columns of the limit table ``jlim`` (``SolverXPBD._limit_table``): limited, solref (2), solimp (5), invweight;
# the rows after the joints' are tendon limits with also lo, hi [m], groups a, b and the site offsets ra, rb
LIMIT_COLS = 19


# ---------------------------------------------------------------------------- named layouts
# The kernels take these tuples of arrays (built once per solver or plant; numba passes a namedtuple as its
# fields) instead of long positional argument lists.  Shapes: ng rigid groups, nj joints, ne equalities,
# nr length rows, nc contact candidates, nb bodies.

GroupModel = namedtuple("GroupModel", [
    "IM",  # inverse mass of each group [1/kg], (ng,); 0 = static
    "II",  # inverse principal inertia of each group [1/(kg·m²)], (ng, 3)
    "GI",  # principal inertia of each group [kg·m²], (ng, 3)
    "gravity",  # [m/s²], (3,)
    "jt",  # joint type (JNT_*), (nj,)
    "jg",  # joint groups (g1, g2), (nj, 2)
    "jvec",  # joint anchors r1, r2 [m] and axes a1, a2 in the group frames, (nj, 4, 3)
    "jqoff",  # joint rest orientation offset (w, x, y, z), (nj, 4)
    "jlim",  # limit table (SolverXPBD._limit_table), (nj + tendon limits, LIMIT_COLS)
    "jlo",  # lower joint limit [rad or m], (nj,)
    "jhi",  # upper joint limit [rad or m], (nj,)
    "jdamp",  # joint damping [N·m·s/rad or N·s/m], (nj,)
    "et",  # equality type (EQ_*), (ne,)
    "eg",  # equality groups, (ne, 2)
    "evec",  # equality anchors [m], (ne, 2, 3)
    "eqoff",  # weld orientation offsets, (ne, 4)
    "body_group",  # group of each body, (nb,)
    "in_group_quat",  # body orientation in its group's frame, (nb, 4)
    "in_group_pos",  # body COM position in its group's frame [m], (nb, 3)
    "contact_cone",  # MuJoCo cone (0 pyramidal, 1 elliptic), int
    "contact_impratio",  # MuJoCo impratio [-], float
])

SubstepRows = namedtuple("SubstepRows", [
    "group",  # groups (a, b) of each length row, (nr, 2)
    "vec",  # site offsets ra, rb in the group frames [m], (nr, 2, 3)
    "active",  # indices of the rows solved this substep, (k,)
    "target",  # target length ℓ* [m], (nr,)
    "compliance",  # α̃ = α/h² [m/(N·s²)], (nr,)
    "lower",  # lower bound on λ [N·s²], (nr,)
    "upper",  # upper bound on λ [N·s²], (nr,)
    "use_block",  # solve the active rows as one block through ``mobility`` (bool)
    "mobility",  # articulated row mobility, (nr, ng, 6)
    "islands",  # ``Islands``: the rows' and groups' islands (one block per island)
])

Islands = namedtuple("Islands", [  # parts of the mechanism that do not move one another, in compressed rows
    "joint_ptr", "joints",  # joints of island i: joints[joint_ptr[i]:joint_ptr[i + 1]], ascending
    "body_ptr", "bodies",  # its moving bodies (rigid group > 0), ascending
    "group_ptr", "groups",  # its moving rigid groups, ascending
    "row_ptr", "rows",  # its length rows, ascending
    "motor_ptr", "motors",  # its motors (indices into the plant's motor list), ascending
    "joint_island",  # island of each joint, (nj,)
])

SubstepLoads = namedtuple("SubstepLoads", [
    "use_group_acceleration",  # bool: ``group_acceleration`` replaces gravity
    "group_acceleration",  # group accelerations (linear [m/s²], angular [rad/s²]), (ng, 6)
    "force",  # external world force on each group [N], (ng, 3)
    "torque",  # external world torque on each group [N·m], (ng, 3)
    "use_joint_torque",  # bool: apply ``joint_torque`` as impulses
    "joint_torque",  # hinge torques [N·m], (nj,)
])

ContactRows = namedtuple("ContactRows", [
    "group",  # (body group, plane group), (nc, 2)
    "vec",  # r2 local, plane origin, plane normal, tangent t₁ (plane group frame), (nc, 4, 3)
    "radius",  # [m], (nc,)
    "mu",  # friction coefficient [-], (nc,)
    "solref",  # MuJoCo solref, (nc, 2)
    "solimp",  # MuJoCo solimp, (nc, 5)
    "condim",  # (nc,)
    "tran",  # effective inverse weight of the contact (body_invweight0 sum) [1/kg], (nc,)
])

SubstepOptions = namedtuple("SubstepOptions", [
    "iterations",  # position passes per substep, int
    "symmetric",  # forward + backward Gauss-Seidel per pass, bool
    "linear_damping",  # global linear damping c [1/s]
    "angular_damping",  # global angular damping c [1/s]
    "articulated_contacts",  # contact pyramids with the articulated response, bool
    "soft_contacts",  # MuJoCo's soft-contact law (else rigid normal rows), bool
    "pyramid_friction",  # soft pyramidal edge rows where the cone is pyramidal and condim ≥ 3, bool
    "velocity_sweeps",  # projected Gauss-Seidel sweeps of the contact velocity pass, int
])

RowOutputs = namedtuple("RowOutputs", [
    "lam",  # multiplier λ of every row [N·s²], (nr,)
    "length",  # ℓ after the substep [m], (nr,)
    "rate",  # dℓ/dt after the substep [m/s], (nr,)
])

ContactWork = namedtuple("ContactWork", [  # per contact candidate, for up to ncap candidates
    "active",  # 1: the soft pyramid's edge rows are live, (ncap,)
    "local",  # the pyramid's contact points r1, r2 in the group frames [m], (ncap, 2, 3)
    "edge",  # the pyramid's edge rows (ê, target, α̃, 1/|e|), (ncap, 4, 6)
    "lam",  # the edge rows' multipliers [N·s²], (ncap, 4)
    "kind",  # CONTACT_* of each candidate, (ncap,)
    "row",  # soft normal row: target gap r* [m], α̃ = R, (ncap, 2)
    "normal_lam", "friction_lam",  # normal and static-friction multipliers [N·s²], (ncap,)
    "fixed",  # body-fixed contact points r1, r2 (group frames) [m] once touching, (ncap, 2, 3)
    "seen",  # 1 once the normal row acted in this substep, (ncap,)
    "order", "count",  # the touching candidates in the order they first acted, (ncap,), (1,)
    "impulse",  # velocity pass: accumulated friction (3) and normal (1) impulses [N·s], (ncap, 4)
    "grouped", "members",  # pyramid pass: 1 once a candidate joined its body pair's block; that block's candidates,
    # (ncap,), (ncap,)
])

RowBlockWork = namedtuple("RowBlockWork", [  # the length rows' block system, for up to nr active rows
    "matrix", "augmented",  # one island's block and its augmented copy, (nr, nr), (nr, nr + 1)
    "vectors",  # (4, nr): rhs, live flags, Δλ (by position in the active rows), the island's solution
    "index",  # (2, nr) int: position of each row among the active rows (−1: inactive), the island's positions
])

SubstepWork = namedtuple("SubstepWork", [
    "joint_soft", "joint_lam", "tendon_soft", "tendon_lam",  # soft limit rows and their λ
    "contacts",  # ``ContactWork``
    "X_start", "Q_start",  # group poses at the prediction
    "block_soft", "block_mu",  # the articulated limit block
    "rows",  # ``RowBlockWork``
    "G", "Minv",  # articulated contacts: group Jacobian (ng, 6, nj), joint-space M⁻¹ (nj, nj)
])

BodyTree = namedtuple("BodyTree", [
    "iquat", "ipos",  # inertial frame of each body (quaternion, position [m]), (nb, 4), (nb, 3)
    "parent", "body_quat", "body_pos",  # MuJoCo body tree, (nb,), (nb, 4), (nb, 3)
    "jnt_type", "jnt_body", "jnt_qposadr", "jnt_dofadr", "jnt_axis",  # MuJoCo joints
    "qpos0",  # reference configuration, (nq,)
])

def islands(body_parent, body_group, jnt_body, row_bodies, motor_joint) -> Islands:
    """The ``Islands`` of a mechanism: its moving bodies (rigid group > 0) joined to their moving parents (the
    kinematic trees hanging from static bodies) and to the other moving end of each length row; a row or joint
    with no moving body is an island of its own.

    No body of one island moves with a joint of another, so the joint-space mass matrix, the rows' articulated
    mobility (Δq = M⁻¹·Jᵀ) and the rows' block matrix are block diagonal by island: the kernels that take the
    ``Islands`` (``_solve_rows_block``, ``sim.plants.pbd_frame._articulated_into``) visit each island's joints,
    bodies, groups and rows only, O(Σ nᵢ²) instead of O(n²): linear in the number of islands for islands of
    bounded size (N identical machines side by side).  :func:`single_island` puts everything into one island
    (the whole blocks).

    ``body_parent``, ``body_group`` (nb,); ``jnt_body`` (nj,); ``row_bodies`` (nr, 2) the bodies of each row's
    two sites; ``motor_joint`` (nm,) each motor's joint.

    >>> isl = islands([0, 0, 1, 0], [0, 1, 1, 2], [1, 3], [[0, 1], [0, 3]], [1])
    >>> isl.joint_island.tolist(), isl.rows.tolist(), isl.row_ptr.tolist(), isl.motor_ptr.tolist()
    ([0, 1], [0, 1], [0, 1, 2], [0, 0, 1])
    """
    body_parent, body_group = np.asarray(body_parent, np.int64), np.asarray(body_group, np.int64)
    jnt_body, motor_joint = np.asarray(jnt_body, np.int64), np.asarray(motor_joint, np.int64)
    row_bodies = np.asarray(row_bodies, np.int64).reshape(-1, 2)
    nb, nj, nr = body_parent.size, jnt_body.size, row_bodies.shape[0]
    link = list(range(nb + nj + nr))  # union-find: bodies, then a node per joint, then a node per row

    def find(a):
        while link[a] != a:
            link[a] = link[link[a]]
            a = link[a]
        return a

    def join(a, b):
        a, b = find(a), find(b)
        if a != b:
            link[max(a, b)] = min(a, b)

    moving = body_group > 0
    for b in range(nb):
        if moving[b] and moving[body_parent[b]]:
            join(b, int(body_parent[b]))
    for j in range(nj):
        if moving[jnt_body[j]]:
            join(nb + j, int(jnt_body[j]))
    for r in range(nr):
        for b in row_bodies[r]:
            if moving[b]:
                join(nb + nj + r, int(b))
    label = {}
    for node in [b for b in range(nb) if moving[b]] + list(range(nb, nb + nj + nr)):
        label.setdefault(find(node), len(label))
    body_island = [label[find(b)] if moving[b] else -1 for b in range(nb)]
    joint_island = [label[find(nb + j)] for j in range(nj)]
    row_island = [label[find(nb + nj + r)] for r in range(nr)]
    motor_island = [joint_island[j] for j in motor_joint]
    group_island = {}
    for b in range(nb):
        if moving[b]:
            group_island[int(body_group[b])] = body_island[b]
    n = len(label)

    def rows_of(island_of):
        members = [[] for _ in range(n)]
        for index, island in enumerate(island_of):
            if island >= 0:
                members[island].append(index)
        ptr = np.zeros(n + 1, np.int64)
        ptr[1:] = np.cumsum([len(m) for m in members])
        flat = np.array([i for m in members for i in m], np.int64)
        return ptr, flat

    ngroup = int(body_group.max()) + 1 if nb else 0
    groups = [group_island.get(g, -1) for g in range(ngroup)]
    return Islands(*rows_of(joint_island), *rows_of(body_island), *rows_of(groups), *rows_of(row_island),
                   *rows_of(motor_island), np.array(joint_island, np.int64))


def single_island(nb, ng, nj, nr, nm) -> Islands:
    """One island holding every body, moving group (1 … ng − 1), joint, row and motor: the
    kernels then solve the whole blocks (no structure assumed of a row mobility given from outside)."""
    def one(first, n):
        return np.array([0, max(n - first, 0)], np.int64), np.arange(first, max(n, first), dtype=np.int64)

    return Islands(*one(0, nj), *one(0, nb), *one(1, ng), *one(0, nr), *one(0, nm), np.zeros(nj, np.int64))


# Kernels that allocate nothing are compiled without numba's reference counting (``_nrt=False``): in a
# reference-counted function every array argument and view costs an NRT_incref/NRT_decref pair.  On the excavator
# at 1 ms × 1 substep those pairs are 24 % of a PBD step's samples (perf) if every helper counts, 15 % if these do not.
# A function that allocates, or calls one that does, sets the counting explicitly (``_counted``): numba compiles a
# callee with its caller's ``_nrt`` unless the callee sets it.  A non-counting caller may then call a counted one as
# long as no array crosses back, so ``substep_core`` and ``_solve_contacts`` read their named tuples for free.
_leaf = njit(cache=True, _nrt=False)
_counted = njit(cache=True, _nrt=True)

# ---------------------------------------------------------------------------- algebra on tuples


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def _mat_from_quat(q):
    """Rotation matrix of the unit quaternion q = (w, x, y, z) as three row tuples, ``R[i][j]``
    (``xpbd_kernels._mat_from_quat``; tuples, so the per-constraint helpers allocate nothing)."""
    w, x, y, z = q
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))


@njit(cache=True, inline="always")
def _sandwich(R, m00, m01, m02, m11, m12, m22):
    """R M Rᵀ of the symmetric M (entries m..) as three row tuples (rows R[i] of the rotation)."""
    RM = ((R[0][0] * m00 + R[0][1] * m01 + R[0][2] * m02, R[0][0] * m01 + R[0][1] * m11 + R[0][2] * m12,
           R[0][0] * m02 + R[0][1] * m12 + R[0][2] * m22),
          (R[1][0] * m00 + R[1][1] * m01 + R[1][2] * m02, R[1][0] * m01 + R[1][1] * m11 + R[1][2] * m12,
           R[1][0] * m02 + R[1][1] * m12 + R[1][2] * m22),
          (R[2][0] * m00 + R[2][1] * m01 + R[2][2] * m02, R[2][0] * m01 + R[2][1] * m11 + R[2][2] * m12,
           R[2][0] * m02 + R[2][1] * m12 + R[2][2] * m22))
    return ((_dot(RM[0], R[0]), _dot(RM[0], R[1]), _dot(RM[0], R[2])),
            (_dot(RM[1], R[0]), _dot(RM[1], R[1]), _dot(RM[1], R[2])),
            (_dot(RM[2], R[0]), _dot(RM[2], R[1]), _dot(RM[2], R[2])))


@njit(cache=True, inline="always")
def _madd(A, B):
    """A + B of two 3×3 row-tuple matrices."""
    return ((A[0][0] + B[0][0], A[0][1] + B[0][1], A[0][2] + B[0][2]),
            (A[1][0] + B[1][0], A[1][1] + B[1][1], A[1][2] + B[1][2]),
            (A[2][0] + B[2][0], A[2][1] + B[2][1], A[2][2] + B[2][2]))


@njit(cache=True, inline="always")
def _qmul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


@njit(cache=True, inline="always")
def _qconj(q):
    return (q[0], -q[1], -q[2], -q[3])


@njit(cache=True, inline="always")
def _rot(q, v):
    w, x, y, z = q
    vx, vy, vz = v
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx))


@njit(cache=True, inline="always")
def _rotinv(q, v):
    w = q[0]
    x, y, z = -q[1], -q[2], -q[3]
    vx, vy, vz = v
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx))


@njit(cache=True, inline="always")
def _qadd(q, d, s):
    dx, dy, dz = d
    w, x, y, z = q
    hs = 0.5 * s
    nw = w + hs * (-dx * x - dy * y - dz * z)
    nx = x + hs * (dx * w + dy * z - dz * y)
    ny = y + hs * (-dx * z + dy * w + dz * x)
    nz = z + hs * (dx * y - dy * x + dz * w)
    inv = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    return (nw * inv, nx * inv, ny * inv, nz * inv)


@njit(cache=True, inline="always")
def _v3(A, i):
    return (A[i, 0], A[i, 1], A[i, 2])


@njit(cache=True, inline="always")
def _q4(A, i):
    return (A[i, 0], A[i, 1], A[i, 2], A[i, 3])


@njit(cache=True, inline="always")
def _setq(A, i, q):
    A[i, 0] = q[0]
    A[i, 1] = q[1]
    A[i, 2] = q[2]
    A[i, 3] = q[3]


@njit(cache=True, inline="always")
def _winv(q, invI, v):
    l = _rotinv(q, v)
    return _rot(q, (invI[0] * l[0], invI[1] * l[1], invI[2] * l[2]))


@_leaf
def _pos_w(invm, invI, q, r, n):
    if invm == 0.0:
        return 0.0
    c = _rotinv(q, _cross(r, n))
    return invm + invI[0] * c[0] * c[0] + invI[1] * c[1] * c[1] + invI[2] * c[2] * c[2]


@_leaf
def _ang_w(invI, q, n):
    c = _rotinv(q, n)
    return invI[0] * c[0] * c[0] + invI[1] * c[1] * c[1] + invI[2] * c[2] * c[2]


@_leaf
def _apply_pos(X, Q, IM, II, b, r, p, sign):
    invm = IM[b]
    if invm == 0.0:
        return
    X[b, 0] = X[b, 0] + sign * invm * p[0]
    X[b, 1] = X[b, 1] + sign * invm * p[1]
    X[b, 2] = X[b, 2] + sign * invm * p[2]
    q = _q4(Q, b)
    d = _winv(q, _v3(II, b), _cross(r, p))
    _setq(Q, b, _qadd(q, d, sign))


@_leaf
def _apply_ang(Q, IM, II, b, p, sign):
    if IM[b] == 0.0:
        return
    q = _q4(Q, b)
    d = _winv(q, _v3(II, b), p)
    _setq(Q, b, _qadd(q, d, sign))


@_leaf
def _apply_vel(V, W, Q, IM, II, b, r, p, sign):
    invm = IM[b]
    if invm == 0.0:
        return
    V[b, 0] = V[b, 0] + sign * invm * p[0]
    V[b, 1] = V[b, 1] + sign * invm * p[1]
    V[b, 2] = V[b, 2] + sign * invm * p[2]
    d = _winv(_q4(Q, b), _v3(II, b), _cross(r, p))
    W[b, 0] = W[b, 0] + sign * d[0]
    W[b, 1] = W[b, 1] + sign * d[1]
    W[b, 2] = W[b, 2] + sign * d[2]


@_leaf
def _apply_lock_impulse(X, Q, IM, II, g1, g2, r1w, r2w, z):
    """Apply a hinge lock's 6-vector z = (positional P, angular L) to g2 and its opposite to g1."""
    P = (z[0], z[1], z[2])
    L = (z[3], z[4], z[5])
    _apply_pos(X, Q, IM, II, g2, r2w, P, 1.0)
    _apply_ang(Q, IM, II, g2, L, 1.0)
    _apply_pos(X, Q, IM, II, g1, r1w, P, -1.0)
    _apply_ang(Q, IM, II, g1, L, -1.0)


@_leaf
def _apply_angvel(W, Q, IM, II, b, p, sign):
    if IM[b] == 0.0:
        return
    d = _winv(_q4(Q, b), _v3(II, b), p)
    W[b, 0] = W[b, 0] + sign * d[0]
    W[b, 1] = W[b, 1] + sign * d[1]
    W[b, 2] = W[b, 2] + sign * d[2]


@_leaf
def _point_vel(V, W, b, r):
    c = _cross(_v3(W, b), r)
    return (V[b, 0] + c[0], V[b, 1] + c[1], V[b, 2] + c[2])


@_leaf
def _solve_pos(X, Q, IM, II, b1, b2, r1, r2, n, c, at, lam, lo, hi):
    w = _pos_w(IM[b1], _v3(II, b1), _q4(Q, b1), r1, n) + _pos_w(IM[b2], _v3(II, b2), _q4(Q, b2), r2, n)
    den = w + at
    dlam = 0.0 if den <= 0.0 else (-c - at * lam) / den
    new = lam + dlam
    if new < lo:
        new = lo
    elif new > hi:
        new = hi
    dlam = new - lam
    if dlam == 0.0:
        return 0.0
    p = (dlam * n[0], dlam * n[1], dlam * n[2])
    _apply_pos(X, Q, IM, II, b2, r2, p, 1.0)
    _apply_pos(X, Q, IM, II, b1, r1, p, -1.0)
    return dlam


@_leaf
def _solve_ang(Q, IM, II, b1, b2, n, theta):
    w = 0.0
    if IM[b1] != 0.0:
        w += _ang_w(_v3(II, b1), _q4(Q, b1), n)
    if IM[b2] != 0.0:
        w += _ang_w(_v3(II, b2), _q4(Q, b2), n)
    dlam = 0.0 if w <= 0.0 else -theta / w
    if dlam == 0.0:
        return 0.0
    p = (dlam * n[0], dlam * n[1], dlam * n[2])
    _apply_ang(Q, IM, II, b2, p, 1.0)
    _apply_ang(Q, IM, II, b1, p, -1.0)
    return dlam


_ZERO33 = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


@_leaf
def _mobility(invm, invI, q, r):
    """Point mobility (1/m) E − [r]× I⁻¹ [r]× (``xpbd_kernels.point_mobility``) as three row tuples, and False
    (with zeros) if the body is static."""
    if invm == 0.0:
        return False, _ZERO33
    x, y, z = _rotinv(q, r)
    a, b, c = invI
    m00 = b * z * z + c * y * y + invm
    m11 = a * z * z + c * x * x + invm
    m22 = a * y * y + b * x * x + invm
    m01 = -c * x * y
    m02 = -b * x * z
    m12 = -a * y * z
    return True, _sandwich(_mat_from_quat(q), m00, m01, m02, m11, m12, m22)


@_leaf
def _solve3(K, b):
    a00, a01, a02 = K[0]
    a10, a11, a12 = K[1]
    a20, a21, a22 = K[2]
    c00 = a11 * a22 - a12 * a21
    c01 = a12 * a20 - a10 * a22
    c02 = a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    if det == 0.0:
        return False, (0.0, 0.0, 0.0)
    inv = 1.0 / det
    b0, b1, b2 = b
    return True, (inv * (c00 * b0 + (a02 * a21 - a01 * a22) * b1 + (a01 * a12 - a02 * a11) * b2),
                  inv * (c01 * b0 + (a00 * a22 - a02 * a20) * b1 + (a02 * a10 - a00 * a12) * b2),
                  inv * (c02 * b0 + (a01 * a20 - a00 * a21) * b1 + (a00 * a11 - a01 * a10) * b2))


@_leaf
def _pair_mobility(IM, II, Q, b1, b2, r1, r2):
    """Summed point mobilities of two bodies (row tuples, for ``_solve3``); False if both are static."""
    h1, K1 = _mobility(IM[b1], _v3(II, b1), _q4(Q, b1), r1)
    h2, K2 = _mobility(IM[b2], _v3(II, b2), _q4(Q, b2), r2)
    if not h1:
        return h2, K2
    if not h2:
        return h1, K1
    return True, _madd(K1, K2)


@_counted
def _solve_dense(A, b, x):
    """A x = b by Gaussian elimination with partial pivoting (``xpbd_substep._solve_dense``); False if singular."""
    n = b.shape[0]
    return _solve_dense_in(A, b, x, np.empty((n, n + 1)))


@_leaf
def _solve_dense_in(A, b, x, M):
    """``_solve_dense`` with the augmented matrix M (n, n + 1) given as work space."""
    n = b.shape[0]
    for i in range(n):
        for j in range(n):
            M[i, j] = A[i, j]
        M[i, n] = b[i]
    for c in range(n):
        p = c
        best = abs(M[c, c])
        for r in range(c + 1, n):
            if abs(M[r, c]) > best:
                best = abs(M[r, c])
                p = r
        if best < 1e-300:
            return False
        if p != c:
            for cc in range(n + 1):
                tmp = M[c, cc]
                M[c, cc] = M[p, cc]
                M[p, cc] = tmp
        piv = M[c, c]
        for r in range(c + 1, n):
            f = M[r, c] / piv
            if f != 0.0:
                for cc in range(c, n + 1):
                    M[r, cc] -= f * M[c, cc]
    for r in range(n - 1, -1, -1):
        acc = M[r, n]
        for cc in range(r + 1, n):
            acc -= M[r, cc] * x[cc]
        x[r] = acc / M[r, r]
    return True


# ---------------------------------------------------------------------------- joints


@_leaf
def _attach(X, Q, IM, II, g1, g2, r1, r2):
    r1w = _rot(_q4(Q, g1), r1)
    r2w = _rot(_q4(Q, g2), r2)
    d = (X[g2, 0] + r2w[0] - X[g1, 0] - r1w[0], X[g2, 1] + r2w[1] - X[g1, 1] - r1w[1],
         X[g2, 2] + r2w[2] - X[g1, 2] - r1w[2])
    if d[0] != 0.0 or d[1] != 0.0 or d[2] != 0.0:
        ok, K = _pair_mobility(IM, II, Q, g1, g2, r1w, r2w)
        if not ok:
            return
        ok, p = _solve3(K, (-d[0], -d[1], -d[2]))
        if not ok:
            return
        _apply_pos(X, Q, IM, II, g2, r2w, p, 1.0)
        _apply_pos(X, Q, IM, II, g1, r1w, p, -1.0)


@_leaf
def _align_axes(Q, IM, II, g1, g2, a1, a2):
    a1w = _rot(_q4(Q, g1), a1)
    a2w = _rot(_q4(Q, g2), a2)
    e = _cross(a1w, a2w)
    s = math.sqrt(_dot(e, e))
    if s > _EPS:
        th = math.atan2(s, _dot(a1w, a2w))
        _solve_ang(Q, IM, II, g1, g2, (e[0] / s, e[1] / s, e[2] / s), th)


@_leaf
def _fix_orientation(Q, IM, II, g1, g2, qoff):
    qe = _qmul(_q4(Q, g2), _qconj(_qmul(_q4(Q, g1), qoff)))
    if qe[0] < 0.0:
        qe = (-qe[0], -qe[1], -qe[2], -qe[3])
    s = math.sqrt(qe[1] * qe[1] + qe[2] * qe[2] + qe[3] * qe[3])
    if s > _EPS:
        th = 2.0 * math.atan2(s, qe[0])
        _solve_ang(Q, IM, II, g1, g2, (qe[1] / s, qe[2] / s, qe[3] / s), th)


@_leaf
def _body_block(K, invm, invI, q, r):
    """K += 6×6 response of body point r to (positional impulse, angular impulse) (``xpbd_kernels._body_block``)."""
    Ii = _sandwich(_mat_from_quat(q), invI[0], 0.0, 0.0, invI[1], 0.0, invI[2])  # R diag(I⁻¹) Rᵀ
    # S = [r]×: rows (0, −r2, r1), (r2, 0, −r0), (−r1, r0, 0); SI = S·Ii, IS = Ii·S, SIS = SI·S
    S = ((0.0, -r[2], r[1]), (r[2], 0.0, -r[0]), (-r[1], r[0], 0.0))
    for i in range(3):
        for j in range(3):
            si = S[i][0] * Ii[0][j] + S[i][1] * Ii[1][j] + S[i][2] * Ii[2][j]
            is_ = Ii[i][0] * S[0][j] + Ii[i][1] * S[1][j] + Ii[i][2] * S[2][j]
            sis = 0.0
            for k in range(3):
                sis += (S[i][0] * Ii[0][k] + S[i][1] * Ii[1][k] + S[i][2] * Ii[2][k]) * S[k][j]
            K[i, j] += (invm if i == j else 0.0) - sis
            K[i, 3 + j] += -si
            K[3 + i, j] += is_
            K[3 + i, 3 + j] += Ii[i][j]


@_counted
def _hinge_limit(X, Q, IM, II, g1, g2, r1, r2, a1, qoff, lo, hi):
    q1 = _q4(Q, g1)
    aw = _rot(q1, a1)
    qt = _qmul(q1, qoff)
    qe = _qmul(_q4(Q, g2), _qconj(qt))
    s = qe[1] * aw[0] + qe[2] * aw[1] + qe[3] * aw[2]
    ang = 2.0 * math.atan2(s, qe[0])
    if ang > math.pi:
        ang -= 2.0 * math.pi
    elif ang <= -math.pi:
        ang += 2.0 * math.pi
    if ang < lo:
        viol = ang - lo
    elif ang > hi:
        viol = ang - hi
    else:
        return False
    target = ang - viol
    r1w, r2w, c_pin, c_ang, K = _lock_system(X, Q, IM, II, g1, g2, r1, r2, aw, target, qt)
    rhs = np.empty(6)
    rhs[0], rhs[1], rhs[2] = -c_pin[0], -c_pin[1], -c_pin[2]
    rhs[3], rhs[4], rhs[5] = -c_ang[0], -c_ang[1], -c_ang[2]
    z = np.empty(6)
    if not _solve_dense(K, rhs, z):
        return True
    _apply_lock_impulse(X, Q, IM, II, g1, g2, r1w, r2w, z)
    return True


@_leaf
def _slide_axis(X, Q, IM, II, g1, g2, r1, a1, limited, lo, hi):
    q1 = _q4(Q, g1)
    r1w = _rot(q1, r1)
    aw = _rot(q1, a1)
    d = (X[g2, 0] - X[g1, 0] - r1w[0], X[g2, 1] - X[g1, 1] - r1w[1], X[g2, 2] - X[g1, 2] - r1w[2])
    dist = _dot(d, aw)
    perp = (d[0] - dist * aw[0], d[1] - dist * aw[1], d[2] - dist * aw[2])
    pl = math.sqrt(_dot(perp, perp))
    zero = (0.0, 0.0, 0.0)
    if pl > _EPS:
        _solve_pos(X, Q, IM, II, g1, g2, (X[g2, 0] - X[g1, 0], X[g2, 1] - X[g1, 1], X[g2, 2] - X[g1, 2]),
                   zero, (perp[0] / pl, perp[1] / pl, perp[2] / pl), pl, 0.0, 0.0, -math.inf, math.inf)
    if limited:
        q1 = _q4(Q, g1)
        r1w = _rot(q1, r1)
        aw = _rot(q1, a1)
        dist = (X[g2, 0] - X[g1, 0] - r1w[0]) * aw[0] + (X[g2, 1] - X[g1, 1] - r1w[1]) * aw[1] + \
            (X[g2, 2] - X[g1, 2] - r1w[2]) * aw[2]
        viol = dist - lo if dist < lo else (dist - hi if dist > hi else 0.0)
        if viol != 0.0:
            _solve_pos(X, Q, IM, II, g1, g2, (X[g2, 0] - X[g1, 0], X[g2, 1] - X[g1, 1], X[g2, 2] - X[g1, 2]),
                       zero, aw, viol, 0.0, 0.0, -math.inf, math.inf)


@_leaf
def _twist(Q, g1, g2, aw, qoff):
    qt = _qmul(_q4(Q, g1), qoff)
    qe = _qmul(_q4(Q, g2), _qconj(qt))
    s = qe[1] * aw[0] + qe[2] * aw[1] + qe[3] * aw[2]
    ang = 2.0 * math.atan2(s, qe[0])
    if ang > math.pi:
        ang -= 2.0 * math.pi
    elif ang <= -math.pi:
        ang += 2.0 * math.pi
    return ang


@_leaf
def _limit_targets(X, Q, V, W, jt, jg, jvec, jqoff, jlim, jlo, jhi, h, jsoft):
    """``ReferenceSubstep._soft_limit_targets``: jsoft[j] = (side ±1 or 0 = inactive, q*, α̃) of each soft limit."""
    for j in range(jt.shape[0]):
        jsoft[j, 0] = 0.0
        if jlim[j, 0] == 0.0 or not (jlim[j, 8] > 0.0) or (jt[j] != JNT_HINGE and jt[j] != JNT_SLIDE):
            continue
        g1, g2 = jg[j, 0], jg[j, 1]
        q1 = _q4(Q, g1)
        aw = _rot(q1, _v3(jvec[j], 2))
        if jt[j] == JNT_HINGE:
            qv = _twist(Q, g1, g2, aw, _q4(jqoff, j))
            qd = (W[g2, 0] - W[g1, 0]) * aw[0] + (W[g2, 1] - W[g1, 1]) * aw[1] + (W[g2, 2] - W[g1, 2]) * aw[2]
        else:
            r1w = _rot(q1, _v3(jvec[j], 0))
            d = (X[g2, 0] - X[g1, 0] - r1w[0], X[g2, 1] - X[g1, 1] - r1w[1], X[g2, 2] - X[g1, 2] - r1w[2])
            qv = _dot(d, aw)
            v1 = _point_vel(V, W, g1, r1w)
            wa = _cross(_v3(W, g1), aw)
            qd = (V[g2, 0] - v1[0]) * aw[0] + (V[g2, 1] - v1[1]) * aw[1] + (V[g2, 2] - v1[2]) * aw[2] + _dot(d, wa)
        _soft_limit_target(jlim[j], qv, qd, jlo[j], jhi[j], h, jsoft[j])


@_leaf
def _soft_limit_target(params, value, rate, lo, hi, h, out):
    """A soft limit beyond [``lo``, ``hi``] at ``value`` moving at ``rate``: out = (side ±1, target, α̃) of its
    one-sided compliant row under MuJoCo's law of the limit row ``params`` (solref, solimp, invweight0); ``out``
    is left as it is inside the range."""
    if value > hi:
        side, r, rd = 1.0, hi - value, -rate
    elif value < lo:
        side, r, rd = -1.0, value - lo, rate
    else:
        return
    kd, b, R = _contact_law(params[1:3], params[3:8], 1, params[8], 0.0, r, 0, 1.0, h)
    rs = r + h * rd - h * h * (b * rd + kd * r)  # MuJoCo's semi-implicit step (xpbd_laws.mujoco_step_target)
    out[0] = side
    out[1] = hi - rs if side > 0.0 else lo + rs
    out[2] = R


@_leaf
def _tendon_geometry(X, Q, jlim, i):
    ga, gb = int(jlim[i, 11]), int(jlim[i, 12])
    raw = _rot(_q4(Q, ga), (jlim[i, 13], jlim[i, 14], jlim[i, 15]))
    rbw = _rot(_q4(Q, gb), (jlim[i, 16], jlim[i, 17], jlim[i, 18]))
    d = (X[gb, 0] + rbw[0] - X[ga, 0] - raw[0], X[gb, 1] + rbw[1] - X[ga, 1] - raw[1],
         X[gb, 2] + rbw[2] - X[ga, 2] - raw[2])
    ell = math.sqrt(_dot(d, d))
    den = ell if ell > 0.0 else 1.0
    return ga, gb, raw, rbw, ell, (d[0] / den, d[1] / den, d[2] / den)


@_leaf
def _tendon_limit_targets(X, Q, V, W, nj, jlim, h, tsoft):
    """``ReferenceSubstep._tendon_limit_targets``: tsoft[t] = (side ±1 or 0, ℓ* [m], α̃) of each tendon limit."""
    for t in range(jlim.shape[0] - nj):
        i = nj + t
        tsoft[t, 0] = 0.0
        if jlim[i, 0] == 0.0 or not (jlim[i, 8] > 0.0):
            continue
        ga, gb, raw, rbw, ell, n = _tendon_geometry(X, Q, jlim, i)
        vb = _point_vel(V, W, gb, rbw)
        va = _point_vel(V, W, ga, raw)
        rate = (vb[0] - va[0]) * n[0] + (vb[1] - va[1]) * n[1] + (vb[2] - va[2]) * n[2]
        _soft_limit_target(jlim[i], ell, rate, jlim[i, 9], jlim[i, 10], h, tsoft[t])


@_counted
def _solve_tendon_limits(X, Q, IM, II, nj, jlim, tsoft, tlam, art, G, Minv, reverse):
    """Soft tendon limit rows (``ReferenceSubstep._solve_tendon_limits``): C = ℓ − ℓ*, compliance α̃, λ ≤ 0 at an
    upper limit (≥ 0 at a lower one); with the articulated response (``art``: W = J·M⁻¹·Jᵀ, the groups
    moved by G·M⁻¹·Jᵀ·Δλ) or the free-body one of the two groups."""
    nt = jlim.shape[0] - nj
    for k in range(nt):
        t = nt - 1 - k if reverse else k
        side = tsoft[t, 0]
        if side == 0.0:
            continue
        i = nj + t
        ga, gb, raw, rbw, ell, n = _tendon_geometry(X, Q, jlim, i)
        c = ell - tsoft[t, 1]
        at = tsoft[t, 2]
        lam = tlam[t]
        lo = -math.inf if side > 0.0 else 0.0
        hi = 0.0 if side > 0.0 else math.inf
        if not art:
            tlam[t] += _solve_pos(X, Q, IM, II, ga, gb, raw, rbw, n, c, at, lam, lo, hi)
            continue
        nq = G.shape[2]
        J = np.zeros(nq)
        for sd in range(2):
            b = ga if sd == 0 else gb
            if IM[b] == 0.0:
                continue
            sg = -1.0 if sd == 0 else 1.0
            r = raw if sd == 0 else rbw
            for q in range(nq):
                vk = _cross((G[b, 3, q], G[b, 4, q], G[b, 5, q]), r)
                J[q] += sg * (n[0] * (G[b, 0, q] + vk[0]) + n[1] * (G[b, 1, q] + vk[1]) + n[2] * (G[b, 2, q] + vk[2]))
        MJ = np.zeros(nq)
        w = 0.0
        for q in range(nq):
            acc = 0.0
            for l in range(nq):
                acc += Minv[q, l] * J[l]
            MJ[q] = acc
            w += J[q] * acc
        den = w + at
        if not (den > 0.0):
            continue
        new = lam + (-c - at * lam) / den
        if new < lo:
            new = lo
        elif new > hi:
            new = hi
        dl = new - lam
        tlam[t] = new
        if dl == 0.0:
            continue
        for g in range(X.shape[0]):
            if IM[g] == 0.0:
                continue
            dx = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
            for cc in range(6):
                for q in range(nq):
                    dx[cc] += G[g, cc, q] * MJ[q] * dl
            X[g, 0] += dx[0]
            X[g, 1] += dx[1]
            X[g, 2] += dx[2]
            if dx[3] != 0.0 or dx[4] != 0.0 or dx[5] != 0.0:
                _setq(Q, g, _qadd(_q4(Q, g), (dx[3], dx[4], dx[5]), 1.0))


@_counted
def _solve_limits_block(X, Q, IM, jt, jg, jvec, jqoff, jlim, bsoft, tsoft, mu, G, Minv):
    """All active soft limits (joints' and tendons') of a hinge/slide tree together
    (``ReferenceSubstep._solve_limits_block``): rows C = q − q* (joint) or ℓ − ℓ* (tendon) taken in their pushing
    direction, W = J·M⁻¹·Jᵀ + diag(α̃), Δμ = W⁻¹(−C − α̃μ) with an active set over μ ≥ 0, every group moved
    by G·M⁻¹·Jᵀ·Δμ."""
    nj = jt.shape[0]
    nt = tsoft.shape[0]
    nq = G.shape[2]
    n = 0
    for j in range(nj):
        if bsoft[j, 0] != 0.0:
            n += 1
    for t in range(nt):
        if tsoft[t, 0] != 0.0:
            n += 1
    if n == 0:
        return
    rid = np.empty(n, np.int64)
    Jr = np.zeros((n, nq))
    C = np.empty(n)
    at = np.empty(n)
    lam = np.empty(n)
    a = 0
    for j in range(nj):
        side = bsoft[j, 0]
        if side == 0.0:
            continue
        g1, g2 = jg[j, 0], jg[j, 1]
        q1 = _q4(Q, g1)
        aw = _rot(q1, _v3(jvec[j], 2))
        if jt[j] == JNT_HINGE:
            qv = _twist(Q, g1, g2, aw, _q4(jqoff, j))
        else:
            r1w = _rot(q1, _v3(jvec[j], 0))
            qv = (X[g2, 0] - X[g1, 0] - r1w[0]) * aw[0] + (X[g2, 1] - X[g1, 1] - r1w[1]) * aw[1] + \
                (X[g2, 2] - X[g1, 2] - r1w[2]) * aw[2]
        rid[a] = j
        Jr[a, j] = -side
        C[a] = -side * (qv - bsoft[j, 1])
        at[a] = bsoft[j, 2]
        lam[a] = mu[j]
        a += 1
    for t in range(nt):
        side = tsoft[t, 0]
        if side == 0.0:
            continue
        i = nj + t
        ga, gb, raw, rbw, ell, nv = _tendon_geometry(X, Q, jlim, i)
        for sd in range(2):
            b = ga if sd == 0 else gb
            if IM[b] == 0.0:
                continue
            sg = -side if sd == 0 else side
            r = raw if sd == 0 else rbw
            for q in range(nq):
                vk = _cross((G[b, 3, q], G[b, 4, q], G[b, 5, q]), r)
                Jr[a, q] -= sg * (nv[0] * (G[b, 0, q] + vk[0]) + nv[1] * (G[b, 1, q] + vk[1]) + nv[2] * (G[b, 2, q] + vk[2]))
        rid[a] = i
        C[a] = -side * (ell - tsoft[t, 1])
        at[a] = tsoft[t, 2]
        lam[a] = mu[i]
        a += 1
    MJ = np.zeros((nq, n))
    for k in range(nq):
        for c in range(n):
            acc = 0.0
            for l in range(nq):
                acc += Minv[k, l] * Jr[c, l]
            MJ[k, c] = acc
    A = np.zeros((n, n))
    rhs = np.empty(n)
    for r in range(n):
        for c in range(n):
            acc = 0.0
            for k in range(nq):
                acc += Jr[r, k] * MJ[k, c]
            A[r, c] = acc
        A[r, r] += at[r]
        rhs[r] = -C[r] - at[r] * lam[r]
    dlam = np.zeros(n)
    if not _nonnegative_increment(A, rhs, lam, dlam):
        return
    dq = np.zeros(nq)
    for r in range(n):
        new = max(lam[r] + dlam[r], 0.0)
        d = new - lam[r]
        mu[rid[r]] = new
        for k in range(nq):
            dq[k] += MJ[k, r] * d
    _move_groups(X, Q, IM, G, dq)


@_leaf
def _axis_basis(a):
    ax, ay, az = abs(a[0]), abs(a[1]), abs(a[2])
    if ax <= ay and ax <= az:
        e = (1.0, 0.0, 0.0)
    elif ay <= az:
        e = (0.0, 1.0, 0.0)
    else:
        e = (0.0, 0.0, 1.0)
    d = e[0] * a[0] + e[1] * a[1] + e[2] * a[2]
    p = (e[0] - d * a[0], e[1] - d * a[1], e[2] - d * a[2])
    n = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    p1 = (p[0] / n, p[1] / n, p[2] / n)
    return p1, _cross(a, p1)


@_counted
def _lock_system(X, Q, IM, II, g1, g2, r1, r2, aw, target, qt):
    """A hinge held at angle ``target``: world lever arms, pin error [m], rotation error [rad] (axis·angle) and
    the 6×6 effective-mass block of pin + rotation (``ReferenceSubstep._lock_errors`` and the oracle's lock blocks)."""
    r1w = _rot(_q4(Q, g1), r1)
    r2w = _rot(_q4(Q, g2), r2)
    c_pin = (X[g2, 0] + r2w[0] - X[g1, 0] - r1w[0], X[g2, 1] + r2w[1] - X[g1, 1] - r1w[1],
             X[g2, 2] + r2w[2] - X[g1, 2] - r1w[2])
    sn, cs = math.sin(0.5 * target), math.cos(0.5 * target)
    q2t = _qmul((cs, sn * aw[0], sn * aw[1], sn * aw[2]), qt)
    qe = _qmul(_q4(Q, g2), _qconj(q2t))
    if qe[0] < 0.0:
        qe = (-qe[0], -qe[1], -qe[2], -qe[3])
    vn = math.sqrt(qe[1] * qe[1] + qe[2] * qe[2] + qe[3] * qe[3])
    if vn > _EPS:
        th = 2.0 * math.atan2(vn, qe[0]) / vn
        c_ang = (th * qe[1], th * qe[2], th * qe[3])
    else:
        c_ang = (0.0, 0.0, 0.0)
    K = np.zeros((6, 6))
    if IM[g1] != 0.0:
        _body_block(K, IM[g1], _v3(II, g1), _q4(Q, g1), r1w)
    if IM[g2] != 0.0:
        _body_block(K, IM[g2], _v3(II, g2), _q4(Q, g2), r2w)
    return r1w, r2w, c_pin, c_ang, K


@_counted
def _hinge_soft_limit(X, Q, IM, II, g1, g2, r1, r2, a1, qoff, side, target, at, lam):
    """``ReferenceSubstep._hinge_soft_limit`` / ``xpbd_kernels.solve_soft_lock_block``; returns Δλ."""
    q1 = _q4(Q, g1)
    aw = _rot(q1, a1)
    qt = _qmul(q1, qoff)
    r1w, r2w, c_pin, c_ang, K = _lock_system(X, Q, IM, II, g1, g2, r1, r2, aw, target, qt)
    for i in range(3):
        for k in range(3):
            K[3 + i, 3 + k] += at * aw[i] * aw[k]
    rhs = np.empty(6)
    rhs[0], rhs[1], rhs[2] = -c_pin[0], -c_pin[1], -c_pin[2]
    for i in range(3):
        rhs[3 + i] = -c_ang[i] - at * lam * aw[i]
    z = np.empty(6)
    if not _solve_dense(K, rhs, z):
        return 0.0
    dl = aw[0] * z[3] + aw[1] * z[4] + aw[2] * z[5]
    if side * (lam + dl) > 0.0:  # would pull: axial impulse fixed at −λ
        p1, p2 = _axis_basis(aw)
        T = np.eye(6)
        for i in range(3):
            T[3 + i, 3], T[3 + i, 4], T[3 + i, 5] = aw[i], p1[i], p2[i]
        M = T.T @ K @ T
        r = T.T @ rhs
        for k in range(6):
            M[3, k] = 0.0
        M[3, 3] = 1.0
        r[3] = -lam
        zt = np.empty(6)
        if not _solve_dense(M, r, zt):
            return 0.0
        z = T @ zt
        dl = -lam
    _apply_lock_impulse(X, Q, IM, II, g1, g2, r1w, r2w, z)
    return dl


@_leaf
def _slide_soft_limit(X, Q, IM, II, g1, g2, r1, a1, side, target, at, lam):
    """The soft limit row of a slide (``ReferenceSubstep._slide_axis`` with ``sl``); returns Δλ."""
    q1 = _q4(Q, g1)
    r1w = _rot(q1, r1)
    aw = _rot(q1, a1)
    dist = (X[g2, 0] - X[g1, 0] - r1w[0]) * aw[0] + (X[g2, 1] - X[g1, 1] - r1w[1]) * aw[1] + \
        (X[g2, 2] - X[g1, 2] - r1w[2]) * aw[2]
    lo = -math.inf if side > 0.0 else 0.0
    hi = 0.0 if side > 0.0 else math.inf
    return _solve_pos(X, Q, IM, II, g1, g2, (X[g2, 0] - X[g1, 0], X[g2, 1] - X[g1, 1], X[g2, 2] - X[g1, 2]),
                      (0.0, 0.0, 0.0), aw, dist - target, at, lam, lo, hi)


@_counted
def _solve_joints(X, Q, IM, II, jt, jg, jvec, jqoff, jlim, jlo, jhi, reverse, jsoft, jlam):
    """Joint rows (``ReferenceSubstep._solve_joints``); jvec[j] = (r1, r2, a1, a2) as (4, 3).  A soft limit
    (jlim[j, 8] > 0) acts where jsoft[j, 0] ≠ 0 (its multiplier accumulates in jlam[j]); a rigid one is
    projected."""
    nj = jt.shape[0]
    for k in range(nj):
        j = nj - 1 - k if reverse else k
        t, g1, g2 = jt[j], jg[j, 0], jg[j, 1]
        r1, r2, a1, a2 = _v3(jvec[j], 0), _v3(jvec[j], 1), _v3(jvec[j], 2), _v3(jvec[j], 3)
        soft = jlim[j, 0] != 0.0 and jlim[j, 8] > 0.0
        rigid = jlim[j, 0] != 0.0 and not soft
        side = jsoft[j, 0] if soft else 0.0
        if t == JNT_HINGE:
            if side != 0.0:
                jlam[j] += _hinge_soft_limit(X, Q, IM, II, g1, g2, r1, r2, a1, _q4(jqoff, j), side, jsoft[j, 1],
                                             jsoft[j, 2], jlam[j])
                continue
            if rigid and _hinge_limit(X, Q, IM, II, g1, g2, r1, r2, a1, _q4(jqoff, j), jlo[j], jhi[j]):
                continue
            if reverse:
                _attach(X, Q, IM, II, g1, g2, r1, r2)
                _align_axes(Q, IM, II, g1, g2, a1, a2)
            else:
                _align_axes(Q, IM, II, g1, g2, a1, a2)
                _attach(X, Q, IM, II, g1, g2, r1, r2)
        elif t == JNT_SLIDE:
            if reverse:
                _slide_axis(X, Q, IM, II, g1, g2, r1, a1, rigid, jlo[j], jhi[j])
                if side != 0.0:
                    jlam[j] += _slide_soft_limit(X, Q, IM, II, g1, g2, r1, a1, side, jsoft[j, 1], jsoft[j, 2], jlam[j])
                _fix_orientation(Q, IM, II, g1, g2, _q4(jqoff, j))
            else:
                _fix_orientation(Q, IM, II, g1, g2, _q4(jqoff, j))
                _slide_axis(X, Q, IM, II, g1, g2, r1, a1, rigid, jlo[j], jhi[j])
                if side != 0.0:
                    jlam[j] += _slide_soft_limit(X, Q, IM, II, g1, g2, r1, a1, side, jsoft[j, 1], jsoft[j, 2], jlam[j])
        elif t == JNT_BALL:
            _attach(X, Q, IM, II, g1, g2, r1, r2)


@_leaf
def _solve_eqs(X, Q, IM, II, et, eg, evec, eqoff, reverse):
    ne = et.shape[0]
    for k in range(ne):
        e = ne - 1 - k if reverse else k
        if et[e] == EQ_WELD:
            _fix_orientation(Q, IM, II, eg[e, 0], eg[e, 1], _q4(eqoff, e))
        _attach(X, Q, IM, II, eg[e, 0], eg[e, 1], _v3(evec[e], 0), _v3(evec[e], 1))


# ---------------------------------------------------------------------------- length rows


@_leaf
def _row_geometry(X, Q, rg, rvec, i):
    ga, gb = rg[i, 0], rg[i, 1]
    raw = _rot(_q4(Q, ga), _v3(rvec[i], 0))
    rbw = _rot(_q4(Q, gb), _v3(rvec[i], 1))
    d = (X[gb, 0] + rbw[0] - X[ga, 0] - raw[0], X[gb, 1] + rbw[1] - X[ga, 1] - raw[1],
         X[gb, 2] + rbw[2] - X[ga, 2] - raw[2])
    return ga, gb, raw, rbw, d


@_leaf
def _solve_rows(X, Q, IM, II, rg, rvec, act, tgt, at, lo, hi, lam, reverse):
    n = act.shape[0]
    for k in range(n):
        i = act[n - 1 - k] if reverse else act[k]
        ga, gb, raw, rbw, d = _row_geometry(X, Q, rg, rvec, i)
        ell = math.sqrt(_dot(d, d))
        if ell < _EPS:
            continue
        lam[i] += _solve_pos(X, Q, IM, II, ga, gb, raw, rbw, (d[0] / ell, d[1] / ell, d[2] / ell), ell - tgt[i],
                             at[i], lam[i], lo[i], hi[i])


@_leaf
def _still(mob, row, group):
    """True when row ``row``'s unit impulse does not move group ``group`` (its mobility there is zero)."""
    for c in range(6):
        if mob[row, group, c] != 0.0:
            return False
    return True


@_leaf
def _island_members(isl, island, position, members):
    """The positions among the active rows (``position``: −1 for an inactive row) of island ``island``'s active
    rows, in the islands' row order, into ``members``; returns how many."""
    n = 0
    for t in range(isl.row_ptr[island], isl.row_ptr[island + 1]):
        m = position[isl.rows[t]]
        if m >= 0:
            members[n] = m
            n += 1
    return n


@_leaf
def _solve_rows_block(X, Q, IM, II, rg, rvec, act, tgt, at, lo, hi, lam, mob, isl, work):
    """The active cylinder rows as one block through their articulated mobility ``mob``; ``work``: the
    ``RowBlockWork`` (for at least ``len(act)`` rows).

    The block W Δλ = −C − α̃λ with W[m, j] = n_m·(Δp_b − Δp_a) of row m's sites per unit λ of row j is block
    diagonal by ``isl`` (``Islands``: row j's impulse moves only its island's groups), so each island's block is
    solved on its own — the same eliminations as the whole block's, without the zero entries between islands —
    and the groups of each island are moved by its rows' Δλ.  Work O(Σ kᵢ²) for kᵢ active rows in island i.
    The rows of an island are taken in ``isl.rows`` order (ascending, as ``act``).  A singular island block falls
    back to Gauss-Seidel over all active rows (``_solve_rows``), before any row's λ changed."""
    k = act.shape[0]
    rhs_all, sol_all = work.vectors[0], work.vectors[3]
    live = work.vectors[1, :k]  # 1.0 for a row with a usable direction
    dlam = work.vectors[2, :k]
    position, members = work.index[0], work.index[1]
    for r in range(rg.shape[0]):
        position[r] = -1
    for m in range(k):
        position[act[m]] = m
        live[m] = 0.0
        dlam[m] = 0.0
    nisl = isl.row_ptr.shape[0] - 1
    anylive = False
    for island in range(nisl):
        n = _island_members(isl, island, position, members)
        if n == 0:
            continue
        A = work.matrix[:n, :n]
        rhs = rhs_all[:n]
        x = sol_all[:n]
        M = work.augmented[:n, :n + 1]
        for a in range(n):
            rhs[a] = 0.0
            x[a] = 0.0
            for b in range(n):
                A[a, b] = 0.0
        here = False
        for a in range(n):
            i = act[members[a]]
            ga, gb, raw, rbw, d = _row_geometry(X, Q, rg, rvec, i)
            ell = math.sqrt(_dot(d, d))
            if ell < _EPS:
                A[a, a] = 1.0
                continue
            nv = (d[0] / ell, d[1] / ell, d[2] / ell)
            for b in range(n):
                jj = act[members[b]]
                if _still(mob, jj, ga) and _still(mob, jj, gb):
                    continue  # row jj's impulse moves neither of row i's groups: A[a, b] = 0
                cb = _cross((mob[jj, gb, 3], mob[jj, gb, 4], mob[jj, gb, 5]), rbw)
                ca = _cross((mob[jj, ga, 3], mob[jj, ga, 4], mob[jj, ga, 5]), raw)
                A[a, b] = (nv[0] * (mob[jj, gb, 0] + cb[0] - mob[jj, ga, 0] - ca[0])
                           + nv[1] * (mob[jj, gb, 1] + cb[1] - mob[jj, ga, 1] - ca[1])
                           + nv[2] * (mob[jj, gb, 2] + cb[2] - mob[jj, ga, 2] - ca[2]))
            A[a, a] += at[i]
            rhs[a] = -(ell - tgt[i]) - at[i] * lam[i]
            live[members[a]] = 1.0
            here = True
        if not here:
            continue
        if not _solve_dense_in(A, rhs, x, M):
            _solve_rows(X, Q, IM, II, rg, rvec, act, tgt, at, lo, hi, lam, False)
            return
        for a in range(n):
            dlam[members[a]] = x[a]
        anylive = True
    if not anylive:
        return
    for m in range(k):
        i = act[m]
        if live[m] != 0.0:
            new = min(max(lam[i] + dlam[m], lo[i]), hi[i])
        else:
            new = lam[i]
        dlam[m] = new - lam[i]
        lam[i] = new
    for island in range(nisl):
        n = _island_members(isl, island, position, members)
        if n == 0:
            continue
        for t in range(isl.group_ptr[island], isl.group_ptr[island + 1]):
            g = isl.groups[t]
            if IM[g] == 0.0:
                continue
            m0 = m1 = m2 = m3 = m4 = m5 = 0.0
            for a in range(n):
                dl = dlam[members[a]]
                if dl != 0.0:
                    r = act[members[a]]
                    m0 += dl * mob[r, g, 0]
                    m1 += dl * mob[r, g, 1]
                    m2 += dl * mob[r, g, 2]
                    m3 += dl * mob[r, g, 3]
                    m4 += dl * mob[r, g, 4]
                    m5 += dl * mob[r, g, 5]
            X[g, 0] = X[g, 0] + m0
            X[g, 1] = X[g, 1] + m1
            X[g, 2] = X[g, 2] + m2
            if m3 != 0.0 or m4 != 0.0 or m5 != 0.0:
                _setq(Q, g, _qadd(_q4(Q, g), (m3, m4, m5), 1.0))


# ---------------------------------------------------------------------------- soft pyramidal contacts


@_leaf
def _impedance(solimp, pos):
    """MuJoCo's constraint impedance d(r) ∈ (0, 1) at violation ``pos`` [m or rad] (``getimpedance`` in
    engine_core_constraint.c, margin 0): dmin at r = 0 rising to dmax at |r| ≥ width along the sigmoid of
    (midpoint, power) of ``solimp`` = (dmin, dmax, width, midpoint, power)."""
    dmin, dmax, width, mid, power = solimp[0], solimp[1], solimp[2], solimp[3], solimp[4]
    dmin, dmax = min(max(dmin, 1e-4), 0.9999), min(max(dmax, 1e-4), 0.9999)
    mid, power = min(max(mid, 1e-4), 0.9999), max(power, 1.0)
    if dmin == dmax or width <= 1e-15:
        return 0.5 * (dmin + dmax)
    x = abs(pos) / width
    if x >= 1.0 or x <= 0.0:
        return dmax if x >= 1.0 else dmin
    if power == 1.0:
        y = x
    elif x <= mid:
        y = x**power / mid ** (power - 1.0)
    else:
        y = 1.0 - (1.0 - x) ** power / (1.0 - mid) ** (power - 1.0)
    return dmin + y * (dmax - dmin)


@_leaf
def _contact_law(solref, solimp, condim, tran, mu, pos, cone, impratio, timestep):
    """Normal law of one MuJoCo soft contact, (k·d [1/s²], b [1/s], R [1/kg]), such that R·f = −(a + b·v + k·d·r),
    f [N] the normal force (+ pushes apart), r [m] the gap (< 0 penetrating), v, a its rate and acceleration
    (MuJoCo's soft-constraint model, Computation chapter; ``mj_makeImpedance``/``mj_diagApprox``):

    * solref = (timeconst, dampratio) > 0, timeconst ≥ 2·``timestep``: k = 1/(dmax²·timeconst²·dampratio²),
      b = 2/(dmax·timeconst); direct format (−stiffness, −damping): k = stiffness/dmax², b = damping/dmax;
    * impedance d = d(r) (``_impedance``); R = (1 − d)/d·Â with Â = ``tran`` (Σ of the bodies' translational
      ``body_invweight0``), the effective inverse mass of the contact;
    * condim 1 or the elliptic cone (``cone`` = 1): R = (1 − d)/d·tran.  Pyramidal cone: 2(condim − 1) edge rows
      n ± μ·t share Rpy = 2·μ_r²·R₀, R₀ = (1 − d)/d·tran·(1 + μ²), μ_r = μ/√impratio; returned is their sum's
      R = Rpy/(2(condim − 1)) (0, rigid, for μ = 0).

    A limit row is the frictionless case with Â = dof_invweight0 (``_soft_limit_target``).  Static load F:
    penetration r = −F·R/(k·d)."""
    tc, zeta = solref[0], solref[1]
    d = _impedance(solimp, pos)
    dmax = min(max(solimp[1], 1e-4), 0.9999)
    if tc > 0.0:
        tc = max(tc, 2.0 * timestep)
        k = 1.0 / max(1e-15, dmax * dmax * tc * tc * zeta * zeta)
        b = 2.0 / max(1e-15, dmax * tc)
    else:
        k = -tc / max(1e-15, dmax * dmax)
        b = -zeta / max(1e-15, dmax)
    r0 = (1.0 - d) / d * tran
    if condim == 1 or cone == 1:
        R = r0
    else:
        r0 *= 1.0 + mu * mu
        R = 2.0 * mu * mu / max(impratio, 1e-15) * r0 / (2.0 * (condim - 1))
    return k * d, b, R


@_leaf
def _contact_normal(X, Q, IM, II, contacts, cw, ci):
    """Normal row of a soft (non-pyramidal) or rigid candidate ``ci`` ([RB] Sec. 3.5; ``ReferenceSubstep._contact_normal``):
    C = d ≥ 0 at the deepest point (rigid), or the compliant C = d − r* with α̃ = R and λ ≥ 0 (soft).  The first time
    it acts in the substep its body-fixed points are kept for friction and the velocity pass."""
    cg, cvec = contacts.group, contacts.vec
    g2, g1 = cg[ci, 0], cg[ci, 1]
    rad = contacts.radius[ci]
    q1, q2 = _q4(Q, g1), _q4(Q, g2)
    n = _rot(q1, _v3(cvec[ci], 2))
    o = _rot(q1, _v3(cvec[ci], 1))
    r2c = _rot(q2, _v3(cvec[ci], 0))
    p = (X[g2, 0] + r2c[0], X[g2, 1] + r2c[1], X[g2, 2] + r2c[2])
    d = (p[0] - X[g1, 0] - o[0]) * n[0] + (p[1] - X[g1, 1] - o[1]) * n[1] + (p[2] - X[g1, 2] - o[2]) * n[2] - rad
    lam_n = cw.normal_lam
    soft = cw.kind[ci] == CONTACT_SOFT
    c = 0.0
    if soft:
        c = d - cw.row[ci, 0]
        if c >= 0.0 and lam_n[ci] <= 0.0:
            return
    elif d >= 0.0:
        return
    s2 = (p[0] - rad * n[0], p[1] - rad * n[1], p[2] - rad * n[2])  # surface point
    s1 = (s2[0] - d * n[0], s2[1] - d * n[1], s2[2] - d * n[2])  # on the plane
    r1 = (s1[0] - X[g1, 0], s1[1] - X[g1, 1], s1[2] - X[g1, 2])
    r2 = (s2[0] - X[g2, 0], s2[1] - X[g2, 1], s2[2] - X[g2, 2])
    if not cw.seen[ci]:
        a1, a2 = _rotinv(q1, r1), _rotinv(q2, r2)
        for k in range(3):
            cw.fixed[ci, 0, k] = a1[k]
            cw.fixed[ci, 1, k] = a2[k]
        cw.seen[ci] = 1
        m = cw.count[0]
        cw.order[m] = ci
        cw.count[0] = m + 1
    if soft:
        lam_n[ci] += _solve_pos(X, Q, IM, II, g1, g2, r1, r2, n, c, cw.row[ci, 1], lam_n[ci], 0.0, math.inf)
    else:
        lam_n[ci] += _solve_pos(X, Q, IM, II, g1, g2, r1, r2, n, d, 0.0, 0.0, -math.inf, math.inf)


@_leaf
def _contact_static_friction(X, Q, IM, II, contacts, cw, Xp, Qp, ci):
    """Static friction of a touching candidate ([RB] Sec. 3.5; ``ReferenceSubstep._contact_static_friction``): cancel the
    relative tangential motion of its points over the substep while the multiplier stays inside the cone
    λ_t < μ λ_n."""
    mu, ln = contacts.mu[ci], cw.normal_lam[ci]
    if mu <= 0.0 or ln <= 0.0:
        return
    g2, g1 = contacts.group[ci, 0], contacts.group[ci, 1]
    r1l, r2l = _v3(cw.fixed[ci], 0), _v3(cw.fixed[ci], 1)
    q1, q2 = _q4(Q, g1), _q4(Q, g2)
    r1w = _rot(q1, r1l)
    r2w = _rot(q2, r2l)
    r1p = _rot(_q4(Qp, g1), r1l)
    r2p = _rot(_q4(Qp, g2), r2l)
    dp = ((X[g2, 0] + r2w[0] - Xp[g2, 0] - r2p[0]) - (X[g1, 0] + r1w[0] - Xp[g1, 0] - r1p[0]),
          (X[g2, 1] + r2w[1] - Xp[g2, 1] - r2p[1]) - (X[g1, 1] + r1w[1] - Xp[g1, 1] - r1p[1]),
          (X[g2, 2] + r2w[2] - Xp[g2, 2] - r2p[2]) - (X[g1, 2] + r1w[2] - Xp[g1, 2] - r1p[2]))
    n = _rot(q1, _v3(contacts.vec[ci], 2))
    dn = _dot(dp, n)
    dt = (dp[0] - dn * n[0], dp[1] - dn * n[1], dp[2] - dn * n[2])
    c = math.sqrt(_dot(dt, dt))
    if c <= _EPS:
        return
    t = (dt[0] / c, dt[1] / c, dt[2] / c)
    w = _pos_w(IM[g1], _v3(II, g1), q1, r1w, t) + _pos_w(IM[g2], _v3(II, g2), q2, r2w, t)
    if w <= 0.0:
        return
    dlt = c / w
    if cw.friction_lam[ci] + dlt < mu * ln:
        cw.friction_lam[ci] += dlt
        _solve_pos(X, Q, IM, II, g1, g2, r1w, r2w, t, c, 0.0, 0.0, -math.inf, math.inf)


@_leaf
def _contact_velocities(V, W, Q, IM, II, contacts, cw, h, sweeps):
    """Velocity pass of the touching non-pyramidal candidates ([RB] Sec. 3.6; ``ReferenceSubstep._solve_velocities``):
    ``sweeps`` projected Gauss-Seidel sweeps, in the order the candidates first acted, of dynamic friction (the
    accumulated impulse clamped to μ·λ_n/h) and, on rigid rows, restitution e = 0 (accumulated normal impulse
    ≥ −λ_n/h; a soft row's damping is in its position law)."""
    count = cw.count[0]
    imp = cw.impulse
    cg, cvec, cmu = contacts.group, contacts.vec, contacts.mu
    for m in range(count):
        ci = cw.order[m]
        for k in range(4):
            imp[ci, k] = 0.0
    for _ in range(sweeps):
        for m in range(count):
            ci = cw.order[m]
            g2, g1 = cg[ci, 0], cg[ci, 1]
            mu, ln = cmu[ci], cw.normal_lam[ci]
            q1, q2 = _q4(Q, g1), _q4(Q, g2)
            n = _rot(q1, _v3(cvec[ci], 2))
            r1 = _rot(q1, _v3(cw.fixed[ci], 0))
            r2 = _rot(q2, _v3(cw.fixed[ci], 1))
            if mu > 0.0 and ln > 0.0:
                va = _point_vel(V, W, g2, r2)
                vb = _point_vel(V, W, g1, r1)
                vr = (va[0] - vb[0], va[1] - vb[1], va[2] - vb[2])
                vn = _dot(vr, n)
                vt = (vr[0] - vn * n[0], vr[1] - vn * n[1], vr[2] - vn * n[2])
                vtl = math.sqrt(_dot(vt, vt))
                if vtl > _EPS:
                    t = (vt[0] / vtl, vt[1] / vtl, vt[2] / vtl)
                    w = _pos_w(IM[g1], _v3(II, g1), q1, r1, t) + _pos_w(IM[g2], _v3(II, g2), q2, r2, t)
                    if w > 0.0:
                        j = -vtl / w
                        old = (imp[ci, 0], imp[ci, 1], imp[ci, 2])
                        new = (old[0] + j * t[0], old[1] + j * t[1], old[2] + j * t[2])
                        cap = mu * ln / h
                        mag = math.sqrt(_dot(new, new))
                        if mag > cap:
                            sc = cap / mag
                            new = (new[0] * sc, new[1] * sc, new[2] * sc)
                        p = (new[0] - old[0], new[1] - old[1], new[2] - old[2])
                        imp[ci, 0], imp[ci, 1], imp[ci, 2] = new
                        _apply_vel(V, W, Q, IM, II, g2, r2, p, 1.0)
                        _apply_vel(V, W, Q, IM, II, g1, r1, p, -1.0)
            if cw.kind[ci] == CONTACT_SOFT:
                continue  # compliant normal: its damping is in the position law
            va = _point_vel(V, W, g2, r2)
            vb = _point_vel(V, W, g1, r1)
            vn = (va[0] - vb[0]) * n[0] + (va[1] - vb[1]) * n[1] + (va[2] - vb[2]) * n[2]
            if vn == 0.0:
                continue
            w = _pos_w(IM[g1], _v3(II, g1), q1, r1, n) + _pos_w(IM[g2], _v3(II, g2), q2, r2, n)
            if w > 0.0:
                old_n = imp[ci, 3]
                new_n = max(old_n - vn / w, -ln / h)
                jn = new_n - old_n
                imp[ci, 3] = new_n
                p = (jn * n[0], jn * n[1], jn * n[2])
                _apply_vel(V, W, Q, IM, II, g2, r2, p, 1.0)
                _apply_vel(V, W, Q, IM, II, g1, r1, p, -1.0)


@_leaf
def _contact_targets(X, Q, V, W, contacts, cone, impratio, soft, pyramid, h, cw):
    """The kind (``CONTACT_*``) and rows of every candidate (``ContactRows``) for the substep
    (``ReferenceSubstep._soft_contact_targets``), into ``cw`` (``ContactWork``).

    Rigid (``options.soft_contacts`` off, or R = 0: μ = 0 on a pyramidal cone): the normal row of [RB].  Soft and
    not penetrating at the substep's start: no force.  Soft pyramidal (``options.pyramid_friction``, condim ≥ 3,
    MuJoCo's pyramidal cone): contact_active[ci] = 1, contact_local[ci] = (r1 local, r2 local),
    contact_edge[ci, j] = (ê (3), target Δ*/|e| [m], α̃ = R_e/|e|², 1/|e|).  Other soft contacts (elliptic cone,
    condim 1): one compliant normal row, contact_row[ci] = (r* = ``mujoco_step_target`` [m], α̃ = R), with the
    Coulomb friction of [RB] (``_contact_static_friction`` and the velocity pass).  ``soft``, ``pyramid``:
    ``SubstepOptions.soft_contacts``, ``pyramid_friction``; ``cone``, ``impratio``: MuJoCo's (``GroupModel``);
    ``cw``: the ``ContactWork``."""
    cg, cvec, crad, cmu = contacts.group, contacts.vec, contacts.radius, contacts.mu
    csolref, csolimp, ccondim, ctran = contacts.solref, contacts.solimp, contacts.condim, contacts.tran
    active, clocal, edge = cw.active, cw.local, cw.edge
    kind, row = cw.kind, cw.row
    for ci in range(cg.shape[0]):
        active[ci] = 0
        if not soft:
            kind[ci] = CONTACT_RIGID
            continue
        g2, g1 = cg[ci, 0], cg[ci, 1]
        r2l, ol, nl, t1l = _v3(cvec[ci], 0), _v3(cvec[ci], 1), _v3(cvec[ci], 2), _v3(cvec[ci], 3)
        rad, mu = crad[ci], cmu[ci]
        q1, q2 = _q4(Q, g1), _q4(Q, g2)
        n = _rot(q1, nl)
        o = _rot(q1, ol)
        r2 = _rot(q2, r2l)
        p = (X[g2, 0] + r2[0], X[g2, 1] + r2[1], X[g2, 2] + r2[2])
        gap = (p[0] - X[g1, 0] - o[0]) * n[0] + (p[1] - X[g1, 1] - o[1]) * n[1] + (p[2] - X[g1, 2] - o[2]) * n[2] - rad
        kd, b, R = _contact_law(csolref[ci], csolimp[ci], ccondim[ci], ctran[ci], mu, min(gap, 0.0),
                                cone, impratio, h)
        if R <= 0.0:
            kind[ci] = CONTACT_RIGID
            continue
        if gap >= 0.0:  # MuJoCo instantiates a contact only once it penetrates (margin 0)
            kind[ci] = CONTACT_IDLE
            continue
        if not (pyramid and ccondim[ci] >= 3 and cone == 0):
            r1 = (p[0] - X[g1, 0], p[1] - X[g1, 1], p[2] - X[g1, 2])
            va = _point_vel(V, W, g2, r2)
            vb = _point_vel(V, W, g1, r1)
            rate = (va[0] - vb[0]) * n[0] + (va[1] - vb[1]) * n[1] + (va[2] - vb[2]) * n[2]
            kind[ci] = CONTACT_SOFT
            row[ci, 0] = gap + h * rate - h * h * (b * rate + kd * gap)  # xpbd_laws.mujoco_step_target
            row[ci, 1] = R
            continue
        kind[ci] = CONTACT_PYRAMID
        ne = 2 * (ccondim[ci] - 1)
        r_edge = R * ne
        rel = (p[0] - rad * n[0], p[1] - rad * n[1], p[2] - rad * n[2])
        r1c = (rel[0] - X[g1, 0], rel[1] - X[g1, 1], rel[2] - X[g1, 2])
        r2c = (rel[0] - X[g2, 0], rel[1] - X[g2, 1], rel[2] - X[g2, 2])
        va = _point_vel(V, W, g2, r2c)
        vb = _point_vel(V, W, g1, r1c)
        vr = (va[0] - vb[0], va[1] - vb[1], va[2] - vb[2])
        t1 = _rot(q1, t1l)
        t2 = _cross(n, t1)
        j = 0
        for tk in range(2):
            t = t1 if tk == 0 else t2
            for sk in range(2):
                sgn = 1.0 if sk == 0 else -1.0
                e = (n[0] + sgn * mu * t[0], n[1] + sgn * mu * t[1], n[2] + sgn * mu * t[2])
                le = math.sqrt(_dot(e, e))
                ve = _dot(vr, e)
                target = h * ve - h * h * (b * ve + kd * gap)
                edge[ci, j, 0] = e[0] / le
                edge[ci, j, 1] = e[1] / le
                edge[ci, j, 2] = e[2] / le
                edge[ci, j, 3] = target / le
                edge[ci, j, 4] = r_edge / (le * le)
                edge[ci, j, 5] = 1.0 / le
                j += 1
        a1 = _rotinv(q1, r1c)
        a2 = _rotinv(q2, r2c)
        for c in range(3):
            clocal[ci, 0, c] = a1[c]
            clocal[ci, 1, c] = a2[c]
        active[ci] = 1


@_counted
def _contact_pyramids(X, Q, Xp, Qp, IM, II, g1, g2, cis, clocal, edge, lam_e, art, G, Minv):
    """All edge rows of the candidates ``cis`` between groups g1 (plane) and g2, solved together with an
    active set over λ ≥ 0 (``ReferenceSubstep._contact_pyramids``).  ``art``: with the articulated response of
    the mechanism (group Jacobian G, joint-space M⁻¹): W = J·M⁻¹·Jᵀ and the groups move by G·M⁻¹·Jᵀ·Δλ."""
    npt = cis.shape[0]
    n = 4 * npt
    pts = np.empty((npt, 2, 3))
    E = np.empty((n, 3))
    tgt = np.empty(n)
    alpha = np.empty(n)
    lam = np.empty(n)
    disp_rows = np.empty(n)
    for pi in range(npt):
        ci = cis[pi]
        r1l, r2l = _v3(clocal[ci], 0), _v3(clocal[ci], 1)
        r1w = _rot(_q4(Q, g1), r1l)
        r2w = _rot(_q4(Q, g2), r2l)
        r1p = _rot(_q4(Qp, g1), r1l)
        r2p = _rot(_q4(Qp, g2), r2l)
        disp = ((X[g2, 0] + r2w[0] - Xp[g2, 0] - r2p[0]) - (X[g1, 0] + r1w[0] - Xp[g1, 0] - r1p[0]),
                (X[g2, 1] + r2w[1] - Xp[g2, 1] - r2p[1]) - (X[g1, 1] + r1w[1] - Xp[g1, 1] - r1p[1]),
                (X[g2, 2] + r2w[2] - Xp[g2, 2] - r2p[2]) - (X[g1, 2] + r1w[2] - Xp[g1, 2] - r1p[2]))
        for c in range(3):
            pts[pi, 0, c] = r1w[c]
            pts[pi, 1, c] = r2w[c]
        for j in range(4):
            row = 4 * pi + j
            e = (edge[ci, j, 0], edge[ci, j, 1], edge[ci, j, 2])
            E[row, 0], E[row, 1], E[row, 2] = e
            tgt[row] = edge[ci, j, 3]
            alpha[row] = edge[ci, j, 4]
            lam[row] = lam_e[ci, j]
            disp_rows[row] = _dot(disp, e)
    A = np.zeros((n, n))
    nj = G.shape[2]
    Jc = np.zeros((n, nj))
    if art:  # J[i, k] = ê_i·(v_g2,k(p) − v_g1,k(p)), v_g,k(p) = G_lin + G_ang × r
        for row in range(n):
            e = _v3(E, row)
            for side in range(2):
                b = g1 if side == 0 else g2
                if IM[b] == 0.0:
                    continue
                sg = -1.0 if side == 0 else 1.0
                r = _v3(pts[row // 4], side)
                for k in range(nj):
                    vk = _cross((G[b, 3, k], G[b, 4, k], G[b, 5, k]), r)
                    Jc[row, k] += sg * (e[0] * (G[b, 0, k] + vk[0]) + e[1] * (G[b, 1, k] + vk[1]) + e[2] * (G[b, 2, k] + vk[2]))
        MJ = np.zeros((nj, n))
        for k in range(nj):
            for j in range(n):
                acc = 0.0
                for l in range(nj):
                    acc += Minv[k, l] * Jc[j, l]
                MJ[k, j] = acc
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for k in range(nj):
                    acc += Jc[i, k] * MJ[k, j]
                A[i, j] = acc
    for side in range(2):
        b = g1 if side == 0 else g2
        if IM[b] == 0.0 or art:
            continue
        q = _q4(Q, b)
        invI = _v3(II, b)
        ang = np.empty((n, 3))
        for row in range(n):
            r = _v3(pts[row // 4], side)
            a = _rotinv(q, _cross(r, _v3(E, row)))  # principal frame: (r × e)ᵀ I⁻¹ (r × e')
            ang[row, 0], ang[row, 1], ang[row, 2] = a
        for i in range(n):
            for j in range(n):
                A[i, j] += IM[b] * (E[i, 0] * E[j, 0] + E[i, 1] * E[j, 1] + E[i, 2] * E[j, 2]) + \
                    (invI[0] * ang[i, 0] * ang[j, 0] + invI[1] * ang[i, 1] * ang[j, 1] + invI[2] * ang[i, 2] * ang[j, 2])
    rhs = np.empty(n)
    for i in range(n):
        rhs[i] = -(disp_rows[i] - tgt[i]) - alpha[i] * lam[i]
        A[i, i] += alpha[i]
    dlam = np.zeros(n)
    if not _nonnegative_increment(A, rhs, lam, dlam):
        return
    if art:
        dq = np.zeros(nj)
        for pi in range(npt):
            ci = cis[pi]
            for j in range(4):
                row = 4 * pi + j
                new = max(lam[row] + dlam[row], 0.0)
                d = new - lam[row]
                lam_e[ci, j] = new
                for k in range(nj):
                    dq[k] += MJ[k, row] * d
        _move_groups(X, Q, IM, G, dq)
        return
    for pi in range(npt):
        ci = cis[pi]
        imp = [0.0, 0.0, 0.0]
        for j in range(4):
            row = 4 * pi + j
            new = max(lam[row] + dlam[row], 0.0)
            d = new - lam[row]
            lam_e[ci, j] = new
            for c in range(3):
                imp[c] += d * E[row, c]
        p = (imp[0], imp[1], imp[2])
        _apply_pos(X, Q, IM, II, g2, _v3(pts[pi], 1), p, 1.0)
        _apply_pos(X, Q, IM, II, g1, _v3(pts[pi], 0), p, -1.0)


@_leaf
def _solve_contacts(X, Q, Xp, Qp, IM, II, contacts, cw, reverse, art, G, Minv):
    """One pass over the candidates (``ReferenceSubstep._solve_contacts``; ``cw`` the ``ContactWork``, Xp, Qp the group
    poses at the prediction): the normal rows of the non-pyramidal ones, the pyramids per body pair (``art``: with
    the articulated response G, M⁻¹), then the static friction of every touching non-pyramidal candidate."""
    cg = contacts.group
    nc = cg.shape[0]
    kind = cw.kind
    for k in range(nc):
        ci = nc - 1 - k if reverse else k
        if kind[ci] == CONTACT_SOFT or kind[ci] == CONTACT_RIGID:
            _contact_normal(X, Q, IM, II, contacts, cw, ci)
    active, clocal, edge, lam_e = cw.active, cw.local, cw.edge, cw.lam
    done = cw.grouped[:nc]
    done[:] = 0
    for k in range(nc):
        ci = nc - 1 - k if reverse else k
        if done[ci] or not active[ci]:
            continue
        g2, g1 = cg[ci, 0], cg[ci, 1]
        cnt = 0
        for k2 in range(k, nc):
            cj = nc - 1 - k2 if reverse else k2
            if active[cj] and cg[cj, 0] == g2 and cg[cj, 1] == g1:
                cnt += 1
        cis = cw.members[:cnt]
        cnt = 0
        for k2 in range(k, nc):
            cj = nc - 1 - k2 if reverse else k2
            if active[cj] and cg[cj, 0] == g2 and cg[cj, 1] == g1:
                cis[cnt] = cj
                done[cj] = 1
                cnt += 1
        _contact_pyramids(X, Q, Xp, Qp, IM, II, g1, g2, cis, clocal, edge, lam_e, art, G, Minv)
    for k in range(nc):
        ci = nc - 1 - k if reverse else k
        if cw.seen[ci]:
            _contact_static_friction(X, Q, IM, II, contacts, cw, Xp, Qp, ci)


# ---------------------------------------------------------------------------- the substep


@_counted
def substep_work(ng, nj, ntl, ncap, nr):
    """The ``SubstepWork`` of ``substep_core`` for ``ng`` groups, ``nj`` joints, ``ntl`` tendon limits, up to ``ncap``
    contact candidates and ``nr`` length rows (made once by a caller that runs many substeps)."""
    contacts = ContactWork(np.zeros(ncap, np.int64), np.zeros((ncap, 2, 3)), np.zeros((ncap, 4, 6)),
                           np.zeros((ncap, 4)), np.zeros(ncap, np.int64), np.zeros((ncap, 2)), np.zeros(ncap),
                           np.zeros(ncap), np.zeros((ncap, 2, 3)), np.zeros(ncap, np.int64), np.zeros(ncap, np.int64),
                           np.zeros(1, np.int64), np.zeros((ncap, 4)), np.zeros(ncap, np.int64),
                           np.zeros(ncap, np.int64))
    rows = RowBlockWork(np.zeros((nr, nr)), np.zeros((nr, nr + 1)), np.zeros((4, nr)), np.zeros((2, nr), np.int64))
    return SubstepWork(np.zeros((nj, 3)), np.zeros(nj), np.zeros((ntl, 3)), np.zeros(ntl), contacts, np.zeros((ng, 3)),
                       np.zeros((ng, 4)), np.zeros((nj, 3)), np.zeros(nj + ntl), rows,
                       np.zeros((ng, 6, nj)), np.zeros((nj, nj)))


@_leaf
def substep_core(X, Q, V, W, model, rows, contacts, loads, options, h, out, work):
    """One XPBD substep of length h [s] in place on the group arrays X, Q, V, W (see module docstring).

    ``model``: the ``GroupModel``; ``rows``: the ``SubstepRows`` (``active`` the rows solved, target/compliance/
    lower/upper per row: ℓ* [m], α̃ = α/h², bounds on λ [N·s²]; ``mobility`` (nrows, ngroup, 6) the articulated
    mobility, used with ``use_block``).  ``loads``: the ``SubstepLoads`` (group accelerations replacing gravity,
    external world forces/torques, hinge torques applied as impulses).  ``contacts``: the step's candidates
    (``ContactRows``).  Limits: ``model.jlim`` (``SolverXPBD._limit_table``): soft limits (MuJoCo's law, rows set
    up from the state at the substep's start) or, for a joint with invweight 0, the rigid projection.
    ``out``: the ``RowOutputs`` (λ of every row, ℓ [m], dℓ/dt [m/s] of every row after the substep).
    With ``options.articulated_contacts`` the contact pyramids are solved with the articulated response of a
    hinge/slide tree (``articulated_inverse`` at the predicted pose, into ``work.G`` (ngroup, 6, njnt) and
    ``work.Minv`` (njnt, njnt)); otherwise (or for other joints) with the free-body response of the touching
    groups.  ``work``: the ``SubstepWork`` of ``substep_work`` (for at least this substep's contacts and rows),
    overwritten.
    """
    IM, II, GI, gravity = model.IM, model.II, model.GI, model.gravity
    jt, jg, jvec, jqoff, jlim = model.jt, model.jg, model.jvec, model.jqoff, model.jlim
    jlo, jhi, jdamp = model.jlo, model.jhi, model.jdamp
    et, eg, evec, eqoff = model.et, model.eg, model.evec, model.eqoff
    rg, rvec, act, tgt, at, lo, hi = rows.group, rows.vec, rows.active, rows.target, rows.compliance, rows.lower, rows.upper
    use_block, mob, isl = rows.use_block, rows.mobility, rows.islands
    use_gg, gg, F, T = loads.use_group_acceleration, loads.group_acceleration, loads.force, loads.torque
    use_tau, tau = loads.use_joint_torque, loads.joint_torque
    iterations, symmetric, art_contacts = options.iterations, options.symmetric, options.articulated_contacts
    lam_rows, ell, rate = out.lam, out.length, out.rate
    Gc, Minv = work.G, work.Minv
    ng = X.shape[0]
    nr = rg.shape[0]
    nc = contacts.group.shape[0]
    cg = contacts.group
    # soft joint limit rows of the substep, from the state at its start (before the torque impulses)
    nj = jt.shape[0]
    ntl = jlim.shape[0] - nj
    jsoft, jlam, tsoft, tlam = work.joint_soft, work.joint_lam, work.tendon_soft, work.tendon_lam
    cw = work.contacts
    active_w, clocal_w, edge_w, lam_e_w = cw.active, cw.local, cw.edge, cw.lam
    Xp, Qp, bsoft, mu = work.X_start, work.Q_start, work.block_soft, work.block_mu
    jsoft[:, :] = 0.0
    jlam[:] = 0.0
    tsoft[:, :] = 0.0
    tlam[:] = 0.0
    _limit_targets(X, Q, V, W, jt, jg, jvec, jqoff, jlim, jlo, jhi, h, jsoft)
    _tendon_limit_targets(X, Q, V, W, nj, jlim, h, tsoft)
    tact = False
    for t in range(ntl):
        if tsoft[t, 0] != 0.0:
            tact = True
    # hinge torques: angular impulse τ h a plus the workless pin impulse (xpbd_kernels.apply_joint_torque_impulse)
    if use_tau:
        for j in range(jt.shape[0]):
            if tau[j] == 0.0 or jt[j] != JNT_HINGE:
                continue
            g1, g2 = jg[j, 0], jg[j, 1]
            q1, q2 = _q4(Q, g1), _q4(Q, g2)
            aw = _rot(q1, _v3(jvec[j], 2))
            s = tau[j] * h
            L = (s * aw[0], s * aw[1], s * aw[2])
            r1, r2 = _rot(q1, _v3(jvec[j], 0)), _rot(q2, _v3(jvec[j], 1))
            d2 = _winv(q2, _v3(II, g2), L) if IM[g2] != 0.0 else (0.0, 0.0, 0.0)
            d1 = _winv(q1, _v3(II, g1), L) if IM[g1] != 0.0 else (0.0, 0.0, 0.0)
            c2 = _cross(d2, r2)
            c1 = _cross(d1, r1)
            mis = (c2[0] + c1[0], c2[1] + c1[1], c2[2] + c1[2])
            _apply_angvel(W, Q, IM, II, g2, L, 1.0)
            _apply_angvel(W, Q, IM, II, g1, L, -1.0)
            ok, K = _pair_mobility(IM, II, Q, g1, g2, r1, r2)
            if not ok:
                continue
            ok, P = _solve3(K, (-mis[0], -mis[1], -mis[2]))
            if not ok:
                continue
            _apply_vel(V, W, Q, IM, II, g2, r2, P, 1.0)
            _apply_vel(V, W, Q, IM, II, g1, r1, P, -1.0)
    # soft contact rows of the substep
    active, clocal, edge, lam_e = active_w[:nc], clocal_w[:nc], edge_w[:nc], lam_e_w[:nc]
    active[:] = 0
    clocal[:, :, :] = 0.0
    edge[:, :, :] = 0.0
    lam_e[:, :] = 0.0
    cw.normal_lam[:nc] = 0.0
    cw.friction_lam[:nc] = 0.0
    cw.seen[:nc] = 0
    cw.count[0] = 0
    if nc:
        _contact_targets(X, Q, V, W, contacts, model.contact_cone, model.contact_impratio, options.soft_contacts,
                         options.pyramid_friction, h, cw)
    for g in range(ng):
        for c in range(3):
            Xp[g, c] = X[g, c]
        for c in range(4):
            Qp[g, c] = Q[g, c]
    # predict
    for g in range(1, ng):
        q = _q4(Q, g)
        if use_gg:
            acc = (gg[g, 0], gg[g, 1], gg[g, 2])
            al = _rotinv(q, (gg[g, 3], gg[g, 4], gg[g, 5]))
            ta = _rot(q, (GI[g, 0] * al[0], GI[g, 1] * al[1], GI[g, 2] * al[2]))
            tq = (T[g, 0] + ta[0], T[g, 1] + ta[1], T[g, 2] + ta[2])
        else:
            acc = (gravity[0], gravity[1], gravity[2])
            tq = (T[g, 0], T[g, 1], T[g, 2])
        invm = IM[g]
        for c in range(3):
            V[g, c] = V[g, c] + h * (acc[c] + F[g, c] * invm)
            X[g, c] = X[g, c] + h * V[g, c]
        wl = _rotinv(q, _v3(W, g))
        gy = _cross(wl, (GI[g, 0] * wl[0], GI[g, 1] * wl[1], GI[g, 2] * wl[2]))
        tl = _rotinv(q, tq)
        tl = (tl[0] - gy[0], tl[1] - gy[1], tl[2] - gy[2])
        wl = (wl[0] + h * II[g, 0] * tl[0], wl[1] + h * II[g, 1] * tl[1], wl[2] + h * II[g, 2] * tl[2])
        wn = _rot(q, wl)
        W[g, 0], W[g, 1], W[g, 2] = wn
        _setq(Q, g, _qadd(q, wn, h))
    art = False
    if (nc and art_contacts) or tact:
        art = articulated_inverse(X, Q, IM, GI, jt, jg, jvec, Gc, Minv)
    cart = art and art_contacts
    blk = tact and art  # every active soft limit in one articulated block (joint rows out of the joint pass)
    bsoft[:, :] = 0.0
    mu[:] = 0.0
    if blk:
        for j in range(nj):
            for c in range(3):
                bsoft[j, c] = jsoft[j, c]
            jsoft[j, 0] = 0.0
    for r in range(nr):
        lam_rows[r] = 0.0
    for _ in range(iterations):
        for sweep in range(2 if symmetric else 1):
            rev = sweep == 1  # passed as a runtime bool: one compiled signature per solver (a literal True/False is two)
            if not rev:
                _solve_joints(X, Q, IM, II, jt, jg, jvec, jqoff, jlim, jlo, jhi, rev, jsoft, jlam)
                if blk:
                    _solve_limits_block(X, Q, IM, jt, jg, jvec, jqoff, jlim, bsoft, tsoft, mu, Gc, Minv)
                elif tact:
                    _solve_tendon_limits(X, Q, IM, II, nj, jlim, tsoft, tlam, False, Gc, Minv, rev)
                _solve_eqs(X, Q, IM, II, et, eg, evec, eqoff, rev)
                if act.shape[0]:
                    if use_block:
                        _solve_rows_block(X, Q, IM, II, rg, rvec, act, tgt, at, lo, hi, lam_rows, mob, isl, work.rows)
                    else:
                        _solve_rows(X, Q, IM, II, rg, rvec, act, tgt, at, lo, hi, lam_rows, rev)
                if nc:
                    _solve_contacts(X, Q, Xp, Qp, IM, II, contacts, cw, rev, cart, Gc, Minv)
            else:
                if nc:
                    _solve_contacts(X, Q, Xp, Qp, IM, II, contacts, cw, rev, cart, Gc, Minv)
                if act.shape[0]:
                    if use_block:
                        _solve_rows_block(X, Q, IM, II, rg, rvec, act, tgt, at, lo, hi, lam_rows, mob, isl, work.rows)
                    else:
                        _solve_rows(X, Q, IM, II, rg, rvec, act, tgt, at, lo, hi, lam_rows, rev)
                _solve_eqs(X, Q, IM, II, et, eg, evec, eqoff, rev)
                if blk:
                    _solve_limits_block(X, Q, IM, jt, jg, jvec, jqoff, jlim, bsoft, tsoft, mu, Gc, Minv)
                elif tact:
                    _solve_tendon_limits(X, Q, IM, II, nj, jlim, tsoft, tlam, False, Gc, Minv, rev)
                _solve_joints(X, Q, IM, II, jt, jg, jvec, jqoff, jlim, jlo, jhi, rev, jsoft, jlam)
                # with loop closures the equalities and joints just solved move the rows' ends after the rows: a
                # last row pass makes each row's end length the one its law c + s·v⁺ was solved for
                if act.shape[0] and et.shape[0]:
                    if use_block:
                        _solve_rows_block(X, Q, IM, II, rg, rvec, act, tgt, at, lo, hi, lam_rows, mob, isl, work.rows)
                    else:
                        _solve_rows(X, Q, IM, II, rg, rvec, act, tgt, at, lo, hi, lam_rows, False)
    # velocity update
    ih = 1.0 / h
    for g in range(1, ng):
        for c in range(3):
            V[g, c] = (X[g, c] - Xp[g, c]) * ih
        dq = _qmul(_q4(Q, g), _qconj(_q4(Qp, g)))
        s = 2.0 * ih if dq[0] >= 0.0 else -2.0 * ih
        W[g, 0], W[g, 1], W[g, 2] = s * dq[1], s * dq[2], s * dq[3]
    # velocity pass: the touching non-pyramidal contacts (soft pyramidal ones have none); implicit joint damping
    if cw.count[0] > 0:
        _contact_velocities(V, W, Q, IM, II, contacts, cw, h, options.velocity_sweeps)
    for j in range(jt.shape[0]):
        b = jdamp[j]
        t = jt[j]
        if not (b > 0.0) or t == JNT_FREE:
            continue
        g1, g2 = jg[j, 0], jg[j, 1]
        q1, q2 = _q4(Q, g1), _q4(Q, g2)
        if t == JNT_HINGE or t == JNT_BALL:
            rel = (W[g2, 0] - W[g1, 0], W[g2, 1] - W[g1, 1], W[g2, 2] - W[g1, 2])
            if t == JNT_HINGE:
                n = _rot(q1, _v3(jvec[j], 2))
                rt = _dot(rel, n)
            else:
                rt = math.sqrt(_dot(rel, rel))
                if rt <= _EPS:
                    continue
                n = (rel[0] / rt, rel[1] / rt, rel[2] / rt)
            wsum = (_ang_w(_v3(II, g1), q1, n) if IM[g1] else 0.0) + (_ang_w(_v3(II, g2), q2, n) if IM[g2] else 0.0)
            if wsum <= 0.0:
                continue
            jimp = rt * b * h / (1.0 + b * h * wsum)
            p = (jimp * n[0], jimp * n[1], jimp * n[2])
            _apply_angvel(W, Q, IM, II, g2, p, -1.0)
            _apply_angvel(W, Q, IM, II, g1, p, 1.0)
        else:
            n = _rot(q1, _v3(jvec[j], 2))
            r1w = (X[g2, 0] - X[g1, 0], X[g2, 1] - X[g1, 1], X[g2, 2] - X[g1, 2])
            zero = (0.0, 0.0, 0.0)
            v1 = _point_vel(V, W, g1, r1w)
            rt = (V[g2, 0] - v1[0]) * n[0] + (V[g2, 1] - v1[1]) * n[1] + (V[g2, 2] - v1[2]) * n[2]
            wsum = _pos_w(IM[g1], _v3(II, g1), q1, r1w, n) + _pos_w(IM[g2], _v3(II, g2), q2, zero, n)
            if wsum <= 0.0:
                continue
            jimp = rt * b * h / (1.0 + b * h * wsum)
            p = (jimp * n[0], jimp * n[1], jimp * n[2])
            _apply_vel(V, W, Q, IM, II, g2, zero, p, -1.0)
            _apply_vel(V, W, Q, IM, II, g1, r1w, p, 1.0)
    cl = 1.0 / (1.0 + options.linear_damping * h)
    ca = 1.0 / (1.0 + options.angular_damping * h)
    for g in range(1, ng):
        if cl != 1.0:
            for c in range(3):
                V[g, c] = cl * V[g, c]
        if ca != 1.0:
            for c in range(3):
                W[g, c] = ca * W[g, c]
    # row kinematics after the substep
    for i in range(nr):
        ga, gb, raw, rbw, d = _row_geometry(X, Q, rg, rvec, i)
        l = math.sqrt(_dot(d, d))
        ell[i] = l
        den = l if l > 0.0 else 1.0
        n = (d[0] / den, d[1] / den, d[2] / den)
        vb = _point_vel(V, W, gb, rbw)
        va = _point_vel(V, W, ga, raw)
        rate[i] = (vb[0] - va[0]) * n[0] + (vb[1] - va[1]) * n[1] + (vb[2] - va[2]) * n[2]


@_leaf
def scatter(X, Q, V, W, body_group, in_group_quat, in_group_pos, x, q, v, w):
    """Group poses/velocities → every body's COM pose and velocity (the oracle: ``ReferenceSolver._scatter``), in place."""
    for b in range(body_group.shape[0]):
        g = body_group[b]
        qg = _q4(Q, g)
        qb = _qmul(qg, _q4(in_group_quat, b))
        _setq(q, b, qb)
        r = _rot(qg, _v3(in_group_pos, b))
        for c in range(3):
            x[b, c] = X[g, c] + r[c]
        d = (x[b, 0] - X[g, 0], x[b, 1] - X[g, 1], x[b, 2] - X[g, 2])
        cr = _cross(_v3(W, g), d)
        for c in range(3):
            w[b, c] = W[g, c]
            v[b, c] = V[g, c] + cr[c]


# ---------------------------------------------------------------------------- per-step conversions
# The conversions done once per step outside the substep, fused per body / joint / group /
# contact: the group gather (inverse of ``scatter``), the contact-candidate test, generalized
# coordinates, body frames and energies.  Same equations and operation order as the numpy
# oracles (``ReferenceSolver._gather`` / ``_collect_contacts``, ``xpbd_model.qpos_qvel`` etc.);
# agreement to round-off in ``tests/test_pbd_fast.py``.


@njit(cache=True, inline="always")
def _vadd(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@njit(cache=True, inline="always")
def _vsub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@_leaf
def gather(x, q, v, w, root, from_root_quat, from_root_pos, X, Q, V, W):
    """Rigid-group poses and velocities (centre of mass [m], principal-frame quaternion, [m/s], [rad/s])
    from the body rows of their root bodies (the oracle: ``ReferenceSolver._gather``); group 0 is the static world."""
    for g in range(root.shape[0]):
        r = root[g]
        qr = _q4(q, r)
        qg = _qmul(qr, _q4(from_root_quat, g))
        xr = _v3(x, r)
        xg = _vadd(xr, _rot(qr, _v3(from_root_pos, g)))
        wg = _v3(w, r)
        vg = _vadd(_v3(v, r), _cross(wg, _vsub(xg, xr)))
        for k in range(3):
            X[g, k] = xg[k]
            V[g, k] = vg[k]
            W[g, k] = wg[k]
        for k in range(4):
            Q[g, k] = qg[k]
    for k in range(3):
        X[0, k] = 0.0
        V[0, k] = 0.0
        W[0, k] = 0.0
    Q[0, 0], Q[0, 1], Q[0, 2], Q[0, 3] = 1.0, 0.0, 0.0, 0.0


@_leaf
def contact_candidates(X, Q, V, W, group, plane, plane_group, local, radius, plane_origin, plane_normal,
                          margin0, dt, out):
    """Indices of the contact points whose gap to their plane is below margin0 + 2·dt·|v_rel| [m]
    (the oracle: ``ReferenceSolver._collect_contacts``), written to ``out``; returns their number."""
    n = 0
    for i in range(group.shape[0]):
        g = group[i]
        pl = plane[i]
        pg = plane_group[pl]
        xg = _v3(X, g)
        xp = _v3(X, pg)
        qp = _q4(Q, pg)
        P = _vadd(xg, _rot(_q4(Q, g), _v3(local, i)))
        nrm = _rot(qp, _v3(plane_normal, pl))
        o = _vadd(xp, _rot(qp, _v3(plane_origin, pl)))
        d = _dot(_vsub(P, o), nrm) - radius[i]
        va = _vadd(_v3(V, g), _cross(_v3(W, g), _vsub(P, xg)))
        vb = _vadd(_v3(V, pg), _cross(_v3(W, pg), _vsub(P, xp)))
        vr = _vsub(va, vb)
        margin = margin0 + 2.0 * dt * math.sqrt(_dot(vr, vr))
        if d < margin:
            out[n] = i
            n += 1
    return n


@_leaf
def body_frames(x, q, iquat, ipos, xb, qb):
    """World poses of the body frames (xpos [m], xquat) from the inertial-frame state (``body_frames``)."""
    for b in range(x.shape[0]):
        qf = _qmul(_q4(q, b), (iquat[b, 0], -iquat[b, 1], -iquat[b, 2], -iquat[b, 3]))
        xf = _vsub(_v3(x, b), _rot(qf, _v3(ipos, b)))
        for k in range(3):
            xb[b, k] = xf[k]
        for k in range(4):
            qb[b, k] = qf[k]


@_leaf
def qpos_qvel(x, q, v, w, hint, tree, xb, qb, qpos, qvel):
    """MuJoCo generalized coordinates from the body state (``XpbdModel.qpos_qvel``; also fills the body
    frames ``xb``, ``qb``) on the ``BodyTree`` ``tree``.  Joint types: 0 free, 1 ball, 2 slide, 3 hinge."""
    iquat, ipos, body_parent, body_quat, body_pos = tree.iquat, tree.ipos, tree.parent, tree.body_quat, tree.body_pos
    jnt_type, jnt_body, jnt_qposadr, jnt_dofadr = tree.jnt_type, tree.jnt_body, tree.jnt_qposadr, tree.jnt_dofadr
    jnt_axis, qpos0 = tree.jnt_axis, tree.qpos0
    body_frames(x, q, iquat, ipos, xb, qb)
    for k in range(qpos.shape[0]):
        qpos[k] = qpos0[k]
    for k in range(qvel.shape[0]):
        qvel[k] = 0.0
    for j in range(jnt_type.shape[0]):
        b = jnt_body[j]
        p = body_parent[b]
        t, qa, da = jnt_type[j], jnt_qposadr[j], jnt_dofadr[j]
        xbb = _v3(xb, b)
        qbb = _q4(qb, b)
        wb = _v3(w, b)
        vob = _vadd(_v3(v, b), _cross(wb, _vsub(xbb, _v3(x, b))))
        if t == 0:  # free
            for k in range(3):
                qpos[qa + k] = xbb[k]
                qvel[da + k] = vob[k]
            for k in range(4):
                qpos[qa + 3 + k] = qbb[k]
            wl = _rotinv(qbb, wb)
            for k in range(3):
                qvel[da + 3 + k] = wl[k]
            continue
        qbp = _q4(qb, p)
        zq = _qmul(qbp, _q4(body_quat, b))
        axis = _v3(jnt_axis, j)
        if t == 2:  # slide
            zp = _vadd(_v3(xb, p), _rot(qbp, _v3(body_pos, b)))
            ax = _rot(qbb, axis)
            qpos[qa] = qpos0[qa] + _dot(_vsub(xbb, zp), ax)
            vp = _vadd(_v3(v, p), _cross(_v3(w, p), _vsub(xbb, _v3(x, p))))
            qvel[da] = _dot(_vsub(vob, vp), ax)
            continue
        qloc = _qmul((zq[0], -zq[1], -zq[2], -zq[3]), qbb)
        wrel = _vsub(wb, _v3(w, p))
        if t == 3:  # hinge: twist about the axis, unwrapped to the branch nearest the hint
            ang = 2.0 * math.atan2(qloc[1] * axis[0] + qloc[2] * axis[1] + qloc[3] * axis[2], qloc[0])
            ref = hint[qa] - qpos0[qa]
            ang = ref + ((ang - ref + math.pi) % (2.0 * math.pi) - math.pi)
            qpos[qa] = qpos0[qa] + ang
            ax = _rot(qbb, axis)
            qvel[da] = _dot(wrel, ax)
        else:  # ball
            s = 1.0 if qloc[0] >= 0 else -1.0
            for k in range(4):
                qpos[qa + k] = s * qloc[k]
            wl = _rotinv(qbb, wrel)
            for k in range(3):
                qvel[da + k] = wl[k]


@_leaf
def energies(x, q, v, w, root, from_root_quat, from_root_pos, group_mass, group_inertia, gravity):
    """(kinetic Σ ½mv² + ½ωᵀIω, potential −Σ m g·x) over the dynamic groups [J] (``kinetic_energy``,
    ``potential_energy``)."""
    kin = 0.0
    pot = 0.0
    grav = (gravity[0], gravity[1], gravity[2])
    for g in range(1, root.shape[0]):
        r = root[g]
        qr = _q4(q, r)
        qg = _qmul(qr, _q4(from_root_quat, g))
        wr = _v3(w, r)
        wl = _rotinv(qg, wr)
        xr = _v3(x, r)
        xg = _vadd(xr, _rot(qr, _v3(from_root_pos, g)))
        vg = _vadd(_v3(v, r), _cross(wr, _vsub(xg, xr)))
        m = group_mass[g]
        kin += 0.5 * m * _dot(vg, vg) + 0.5 * (group_inertia[g, 0] * (wl[0] * wl[0]) + group_inertia[g, 1] * (wl[1] * wl[1])
                                                  + group_inertia[g, 2] * (wl[2] * wl[2]))
        pot += m * _dot(xg, grav)
    return kin, -pot


# ---------------------------------------------------------------------------- articulated response transport
# The articulated responses a plant hands the solver per step (``SubstepInputs.row_mobility``,
# ``group_gravity``: group displacements / accelerations in the world frame, from
# Δq = M⁻¹·Jᵀ at the step's start pose) are carried to each substep's pose through the joint
# space: dq = G₀⁺·R₀ (G the group Jacobian of the hinge/slide tree, exact since R₀ lies in
# G₀'s range), R_k = G_k·dq.  ``ReferenceSubstep._transported`` is the numpy oracle.


@_counted
def group_jacobian(X, Q, IM, jt, jg, jvec, G):
    """G[g, :, i] = (COM velocity [m/s], angular velocity [rad/s]) of group g per unit rate of joint i.

    Hinges: (a × (x_g − p), a) for every dynamic group in the joint's subtree (a the world axis,
    p the anchor on the parent); slides: (a, 0).  Returns False (G undefined) unless every
    joint is a hinge or a slide and every group is the child of at most one joint (a tree).
    """
    ng = X.shape[0]
    nj = jt.shape[0]
    parent = np.full(ng, -1, np.int64)
    for j in range(nj):
        if jt[j] != JNT_HINGE and jt[j] != JNT_SLIDE:
            return False
        g2 = jg[j, 1]
        if parent[g2] >= 0:
            return False
        parent[g2] = j
    G[:, :, :] = 0.0
    for j in range(nj):
        g1 = jg[j, 0]
        q1 = _q4(Q, g1)
        a = _rot(q1, (jvec[j, 2, 0], jvec[j, 2, 1], jvec[j, 2, 2]))
        r1 = _rot(q1, (jvec[j, 0, 0], jvec[j, 0, 1], jvec[j, 0, 2]))
        p = (X[g1, 0] + r1[0], X[g1, 1] + r1[1], X[g1, 2] + r1[2])
        for g in range(ng):
            if IM[g] == 0.0:
                continue
            b = g
            inside = False
            for _ in range(nj + 1):  # walk up the tree from g
                pj = parent[b]
                if pj < 0:
                    break
                if pj == j:
                    inside = True
                    break
                b = jg[pj, 0]
            if not inside:
                continue
            if jt[j] == JNT_HINGE:
                lin = _cross(a, (X[g, 0] - p[0], X[g, 1] - p[1], X[g, 2] - p[2]))
                for c in range(3):
                    G[g, c, j] = lin[c]
                    G[g, 3 + c, j] = a[c]
            else:
                for c in range(3):
                    G[g, c, j] = a[c]
    return True


@_leaf
def _move_groups(X, Q, IM, G, dq):
    """Move every dynamic group by G·dq: the joint-space displacement ``dq`` through the group Jacobian G."""
    nq = len(dq)
    for g in range(X.shape[0]):
        if IM[g] == 0.0:
            continue
        d0 = d1 = d2 = d3 = d4 = d5 = 0.0
        for k in range(nq):
            d0 += G[g, 0, k] * dq[k]
            d1 += G[g, 1, k] * dq[k]
            d2 += G[g, 2, k] * dq[k]
            d3 += G[g, 3, k] * dq[k]
            d4 += G[g, 4, k] * dq[k]
            d5 += G[g, 5, k] * dq[k]
        X[g, 0] += d0
        X[g, 1] += d1
        X[g, 2] += d2
        if d3 != 0.0 or d4 != 0.0 or d5 != 0.0:
            _setq(Q, g, _qadd(_q4(Q, g), (d3, d4, d5), 1.0))


@_counted
def _nonnegative_increment(A, rhs, lam, dlam):
    """Δλ of the one-sided block A·Δλ = rhs with λ + Δλ ≥ 0 (active set: a row whose total would turn negative is
    released to Δλ = −λ and the rest re-solved, at most n + 1 times); False if a free sub-block is singular."""
    n = len(rhs)
    free = np.empty(n, np.bool_)
    for r in range(n):
        free[r] = rhs[r] > 0.0 or lam[r] > 0.0
    for _ in range(n + 1):
        nf = 0
        for r in range(n):
            if not free[r]:
                dlam[r] = -lam[r]
            else:
                nf += 1
        if nf:
            idx = np.empty(nf, np.int64)
            k = 0
            for r in range(n):
                if free[r]:
                    idx[k] = r
                    k += 1
            Af = np.empty((nf, nf))
            bf = np.empty(nf)
            for u in range(nf):
                sacc = rhs[idx[u]]
                for r in range(n):
                    if not free[r]:
                        sacc -= A[idx[u], r] * dlam[r]
                bf[u] = sacc
                for c in range(nf):
                    Af[u, c] = A[idx[u], idx[c]]
            xf = np.empty(nf)
            if not _solve_dense(Af, bf, xf):
                return False
            for u in range(nf):
                dlam[idx[u]] = xf[u]
        neg = False
        for r in range(n):
            if free[r] and lam[r] + dlam[r] < 0.0:
                free[r] = False
                neg = True
        if not neg:
            break
    return True


@_leaf
def _gauss_jordan(A, n):
    """Reduce the square block A[:, :n] of the augmented matrix A (n, n + k) to the identity in place
    (partial pivoting), so A[:, n:] becomes its inverse times the right-hand sides; False if singular."""
    width = A.shape[1]
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(A[i, i]))
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if not abs(A[p, c]) > 1e-12 * scale:
            return False
        if p != c:
            for k in range(width):
                A[c, k], A[p, k] = A[p, k], A[c, k]
        piv = A[c, c]
        for k in range(width):
            A[c, k] /= piv
        for r in range(n):
            if r != c and A[r, c] != 0.0:
                f = A[r, c]
                for k in range(width):
                    A[r, k] -= f * A[c, k]
    return True


@_counted
def jacobian_pinv(G, P):
    """P = (GᵀG)⁻¹Gᵀ (nj, ng·6) of the group Jacobian (least squares); False if GᵀG is singular."""
    ng, _, nj = G.shape
    m = ng * 6
    A = np.empty((nj, nj + m))
    for i in range(nj):
        for k in range(nj):
            s = 0.0
            for g in range(ng):
                for c in range(6):
                    s += G[g, c, i] * G[g, c, k]
            A[i, k] = s
        for g in range(ng):
            for c in range(6):
                A[i, nj + g * 6 + c] = G[g, c, i]
    if not _gauss_jordan(A, nj):
        return False
    for i in range(nj):
        for k in range(m):
            P[i, k] = A[i, nj + k]
    return True


@_counted
def transport(G, P, src, dst):
    """dst = G·(P·src) for one response (ng, 6): the joint-space motion of ``src`` at G's pose
    (``src`` and ``dst`` may be the same array)."""
    ng, _, nj = G.shape
    dq = np.zeros(nj)
    for i in range(nj):
        s = 0.0
        for g in range(ng):
            for c in range(6):
                s += P[i, g * 6 + c] * src[g, c]
        dq[i] = s
    for g in range(ng):
        for c in range(6):
            s = 0.0
            for i in range(nj):
                s += G[g, c, i] * dq[i]
            dst[g, c] = s


@_counted
def articulated_inverse(X, Q, IM, GI, jt, jg, jvec, G, Minv):
    """G (``group_jacobian``) and M⁻¹ (njnt, njnt) of the joint-space mass matrix
    M = Σ_g m_g·G_linᵀG_lin + G_angᵀ·I_g·G_ang (group masses and principal inertias GI about the
    group's centre of mass); False unless a hinge/slide tree with a regular M."""
    if not group_jacobian(X, Q, IM, jt, jg, jvec, G):
        return False
    ng, _, nj = G.shape
    if nj == 0:
        return False
    A = np.zeros((nj, 2 * nj))
    wl = np.empty((nj, 3))
    for g in range(ng):
        if IM[g] == 0.0:
            continue
        m = 1.0 / IM[g]
        q = _q4(Q, g)
        for k in range(nj):
            w = _rotinv(q, (G[g, 3, k], G[g, 4, k], G[g, 5, k]))
            wl[k, 0], wl[k, 1], wl[k, 2] = w
        for k in range(nj):
            for l in range(nj):
                A[k, l] += m * (G[g, 0, k] * G[g, 0, l] + G[g, 1, k] * G[g, 1, l] + G[g, 2, k] * G[g, 2, l]) + \
                    GI[g, 0] * wl[k, 0] * wl[l, 0] + GI[g, 1] * wl[k, 1] * wl[l, 1] + GI[g, 2] * wl[k, 2] * wl[l, 2]
    for k in range(nj):
        A[k, nj + k] = 1.0
    if not _gauss_jordan(A, nj):
        return False
    for k in range(nj):
        for l in range(nj):
            Minv[k, l] = A[k, nj + l]
    return True
