"""Constraint-projection kernels for rigid-body XPBD on Python tuples: the oracle of ``sim/xpbd/compiled.py``.

The same equations as the compiled substep's kernels, written independently on Python floats and tuples for
the pure substep of ``tests/reference/xpbd_substep.py``; the tests compare the package's solver with it.

References
----------
* [XPBD]  Macklin, Müller, Chentanez, "XPBD: Position-Based Simulation of Compliant
  Constrained Dynamics", MIG 2016.
* [RB]    Müller, Macklin, Chentanez, Jeschke, Kim, "Detailed Rigid Body Simulation with
  Extended Position Based Dynamics", SCA/CGF 2020 (equation numbers as in the paper).

Conventions
-----------
* Quaternions are (w, x, y, z), unit length, and rotate body-frame vectors to the world.
* A body's pose is the pose of its *principal* inertia frame: position = centre of mass,
  orientation such that the inertia tensor is diagonal (``invI`` holds the diagonal of I⁻¹).
* A scalar constraint C between body 1 and body 2 is always written so that its gradient
  with respect to the world point ``p2`` on body 2 is ``+n`` and with respect to ``p1`` on
  body 1 is ``-n``.  The correction impulse ``p = Δλ n`` is added to body 2 and subtracted
  from body 1, so the constraint force on body 2 is ``f = λ n / h²`` ([RB] eq. 10).
  For angular constraints ``theta`` is the rotation (about ``n``) by which body 2 is
  rotated away from where the constraint wants it, relative to body 1.

Two kinds of functions live here:

* pure scalar functions on Python floats / tuples (the equations), and
* ``solve_*`` / ``apply_*`` helpers that apply a correction *in place* to per-body
  Python lists ``X`` (positions), ``Q`` (quaternions), ``V``, ``W`` (velocities) with
  per-body inverse mass ``IM`` and inverse inertia diagonals ``II``.  Python lists of
  floats are used in the substep loop because per-element numpy access on tiny arrays
  is much slower; the vectorized numpy helpers (``np_*``) are the package's (``sim.xpbd.quat``).
"""

from __future__ import annotations

import math

import numpy as np


__all__ = [
    "cross",
    "dot",
    "quat_mul",
    "quat_conj",
    "quat_rotate",
    "quat_rotate_inv",
    "positional_inverse_mass",
    "angular_inverse_mass",
    "xpbd_delta_lambda",
    "apply_positional_impulse",
    "apply_angular_impulse",
    "solve_positional",
    "solve_angular",
    "twist_angle",
    "limit_violation",
    "apply_velocity_impulse",
    "apply_angular_velocity_impulse",
    "point_velocity",
    "point_mobility",
    "solve_attachment_block",
    "solve_lock_block",
    "apply_joint_torque_impulse",
    "predict_body",
    "update_velocity_body",
]

_INF = math.inf

# ---------------------------------------------------------------------------
# small vector / quaternion algebra on tuples


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    )


def quat_mul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_conj(q):
    return (q[0], -q[1], -q[2], -q[3])


def quat_rotate(q, v):
    """R(q) v."""
    w, x, y, z = q
    vx, vy, vz = v
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (
        vx + w * tx + (y * tz - z * ty),
        vy + w * ty + (z * tx - x * tz),
        vz + w * tz + (x * ty - y * tx),
    )


def quat_rotate_inv(q, v):
    """R(q)ᵀ v."""
    w, x, y, z = q
    x, y, z = -x, -y, -z
    vx, vy, vz = v
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (
        vx + w * tx + (y * tz - z * ty),
        vy + w * ty + (z * tx - x * tz),
        vz + w * tz + (x * ty - y * tx),
    )


def _quat_add_rotation(q, d, s):
    """q ← normalize(q + s·½[d, 0] q): small world-frame rotation d ([RB] eqs. 8–9, 15–16)."""
    dx, dy, dz = d
    w, x, y, z = q
    hs = 0.5 * s
    nw = w + hs * (-dx * x - dy * y - dz * z)
    nx = x + hs * (dx * w + dy * z - dz * y)
    ny = y + hs * (-dx * z + dy * w + dz * x)
    nz = z + hs * (dx * y - dy * x + dz * w)
    inv = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    return [nw * inv, nx * inv, ny * inv, nz * inv]


def _world_inv_inertia_times(q, invI, v):
    """I⁻¹_world v = R diag(invI) Rᵀ v."""
    l = quat_rotate_inv(q, v)
    return quat_rotate(q, (invI[0] * l[0], invI[1] * l[1], invI[2] * l[2]))


# ---------------------------------------------------------------------------
# the XPBD equations


def positional_inverse_mass(invm, invI, q, r, n):
    """Generalized inverse mass of a positional correction along ``n`` at offset ``r``.

    [RB] eqs. (2)–(3):  w = 1/m + (r × n)ᵀ I⁻¹ (r × n), evaluated in the body's principal
    frame (``invI`` is the diagonal of I⁻¹ there, ``q`` the body orientation).
    Returns 0 for static bodies (``invm == 0``).
    """
    if invm == 0.0:
        return 0.0
    c = quat_rotate_inv(q, cross(r, n))
    return invm + invI[0] * c[0] * c[0] + invI[1] * c[1] * c[1] + invI[2] * c[2] * c[2]


def angular_inverse_mass(invI, q, n):
    """Generalized inverse mass of a rotation about the unit axis ``n``: [RB] eq. (13),
    w = nᵀ I⁻¹ n (principal frame)."""
    c = quat_rotate_inv(q, n)
    return invI[0] * c[0] * c[0] + invI[1] * c[1] * c[1] + invI[2] * c[2] * c[2]


def xpbd_delta_lambda(c, lam, w, alpha_tilde):
    """Multiplier increment of one compliant constraint.

    [XPBD] eq. (18) / [RB] eqs. (4) and (14):
        Δλ = (−c − α̃ λ) / (w₁ + w₂ + α̃),   α̃ = α / h²,
    where ``w`` = w₁ + w₂ is the generalized inverse mass and ``c`` the constraint value.
    """
    den = w + alpha_tilde
    if den <= 0.0:
        return 0.0
    return (-c - alpha_tilde * lam) / den


def apply_positional_impulse(X, Q, IM, II, b, r, p, sign=1.0):
    """Apply the positional impulse ``sign·p`` at world offset ``r`` of body ``b`` (in place).

    [RB] eqs. (6)–(9): x ← x + p/m,  q ← q + ½ [I⁻¹ (r × p), 0] q  (then normalized).
    """
    invm = IM[b]
    if invm == 0.0:
        return
    x = X[b]
    X[b] = [x[0] + sign * invm * p[0], x[1] + sign * invm * p[1], x[2] + sign * invm * p[2]]
    q = Q[b]
    d = _world_inv_inertia_times(q, II[b], cross(r, p))
    Q[b] = _quat_add_rotation(q, d, sign)


def apply_angular_impulse(Q, IM, II, b, p, sign=1.0):
    """Apply the angular impulse ``sign·p`` to body ``b`` (in place).

    [RB] eqs. (15)–(16): q ← q + ½ [I⁻¹ p, 0] q (then normalized).
    """
    if IM[b] == 0.0:
        return
    q = Q[b]
    d = _world_inv_inertia_times(q, II[b], p)
    Q[b] = _quat_add_rotation(q, d, sign)


def apply_lock_impulse(X, Q, IM, II, b1, b2, r1, r2, z):
    """Apply a hinge lock's 6-vector z = (positional P, angular L) to body b2 and its opposite to b1."""
    P = (float(z[0]), float(z[1]), float(z[2]))
    L = (float(z[3]), float(z[4]), float(z[5]))
    apply_positional_impulse(X, Q, IM, II, b2, r2, P, 1.0)
    apply_angular_impulse(Q, IM, II, b2, L, 1.0)
    apply_positional_impulse(X, Q, IM, II, b1, r1, P, -1.0)
    apply_angular_impulse(Q, IM, II, b1, L, -1.0)


def solve_positional(X, Q, IM, II, b1, b2, r1, r2, n, c, alpha_tilde=0.0, lam=0.0,
                     lam_min=-_INF, lam_max=_INF):
    """One Gauss-Seidel projection of a positional constraint ([RB] Sec. 3.3.1).

    ``c`` is the constraint value, ``n`` its unit gradient w.r.t. the point ``p2`` on body
    ``b2`` (the gradient w.r.t. ``p1`` on ``b1`` is −n); ``r1``, ``r2`` are world offsets of
    the points from the centres of mass.  Computes w₁, w₂ ([RB] eqs. 2–3), Δλ ([RB] eq. 4),
    clamps the accumulated λ + Δλ to [lam_min, lam_max] (unilateral rows), applies
    p = Δλ n to body 2 and −p to body 1 ([RB] eqs. 6–9) and returns the applied Δλ.
    """
    w = positional_inverse_mass(IM[b1], II[b1], Q[b1], r1, n) + \
        positional_inverse_mass(IM[b2], II[b2], Q[b2], r2, n)
    dlam = xpbd_delta_lambda(c, lam, w, alpha_tilde)
    new = lam + dlam
    if new < lam_min:
        new = lam_min
    elif new > lam_max:
        new = lam_max
    dlam = new - lam
    if dlam == 0.0:
        return 0.0
    p = (dlam * n[0], dlam * n[1], dlam * n[2])
    apply_positional_impulse(X, Q, IM, II, b2, r2, p, 1.0)
    apply_positional_impulse(X, Q, IM, II, b1, r1, p, -1.0)
    return dlam


def solve_angular(Q, IM, II, b1, b2, n, theta, alpha_tilde=0.0, lam=0.0):
    """One Gauss-Seidel projection of an angular constraint ([RB] Sec. 3.3.2, eqs. 11–17).

    ``theta`` is the rotation angle about the unit axis ``n`` by which body 2 is rotated
    away from its target relative to body 1.  Δλ = (−θ − α̃λ)/(w₁ + w₂ + α̃), p = Δλ n is
    applied to body 2 and −p to body 1.  Returns Δλ (torque = λ n / h², [RB] eq. 17).
    """
    w = 0.0
    if IM[b1] != 0.0:
        w += angular_inverse_mass(II[b1], Q[b1], n)
    if IM[b2] != 0.0:
        w += angular_inverse_mass(II[b2], Q[b2], n)
    dlam = xpbd_delta_lambda(theta, lam, w, alpha_tilde)
    if dlam == 0.0:
        return 0.0
    p = (dlam * n[0], dlam * n[1], dlam * n[2])
    apply_angular_impulse(Q, IM, II, b2, p, 1.0)
    apply_angular_impulse(Q, IM, II, b1, p, -1.0)
    return dlam


def twist_angle(q_err, axis):
    """Angle of the rotation ``q_err`` about the unit ``axis`` (swing-twist decomposition).

    Equivalent to φ of [RB] Algorithm 3 (φ = asin((n₁×n₂)·n), corrected for n₁·n₂ < 0)
    but computed from the relative quaternion; result is wrapped to (−π, π].
    """
    s = q_err[1] * axis[0] + q_err[2] * axis[1] + q_err[3] * axis[2]
    a = 2.0 * math.atan2(s, q_err[0])
    if a > math.pi:
        a -= 2.0 * math.pi
    elif a <= -math.pi:
        a += 2.0 * math.pi
    return a


def limit_violation(value, lo, hi):
    """Amount by which ``value`` lies outside [lo, hi] (0 inside): the limit branch of
    [RB] Algorithm 3 (and the prismatic limit of Sec. 3.4.3)."""
    if value < lo:
        return value - lo
    if value > hi:
        return value - hi
    return 0.0


# ---------------------------------------------------------------------------
# velocity level ([RB] Sec. 3.6)


def point_velocity(V, W, b, r):
    """Velocity of the material point at world offset ``r`` of body ``b``: v + ω × r."""
    v = V[b]
    c = cross(W[b], r)
    return (v[0] + c[0], v[1] + c[1], v[2] + c[2])


def apply_velocity_impulse(V, W, Q, IM, II, b, r, p, sign=1.0):
    """Apply the velocity-level impulse ``sign·p`` at world offset ``r`` of body ``b``.

    [RB] Sec. 3.6 (eq. 33): v ← v + p/m,  ω ← ω + I⁻¹ (r × p).
    """
    invm = IM[b]
    if invm == 0.0:
        return
    v = V[b]
    V[b] = [v[0] + sign * invm * p[0], v[1] + sign * invm * p[1], v[2] + sign * invm * p[2]]
    d = _world_inv_inertia_times(Q[b], II[b], cross(r, p))
    w = W[b]
    W[b] = [w[0] + sign * d[0], w[1] + sign * d[1], w[2] + sign * d[2]]


def apply_angular_velocity_impulse(W, Q, IM, II, b, p, sign=1.0):
    """ω ← ω + sign · I⁻¹ p (pure angular impulse)."""
    if IM[b] == 0.0:
        return
    d = _world_inv_inertia_times(Q[b], II[b], p)
    w = W[b]
    W[b] = [w[0] + sign * d[0], w[1] + sign * d[1], w[2] + sign * d[2]]


# ---------------------------------------------------------------------------
# batched per-body steps (numpy, shape (n, 3) / (n, 4))


# ---------------------------------------------------------------------------
# per-body steps of [RB] Algorithm 2 (scalar; bodies are few)


def predict_body(x, q, v, w, inertia, inv_inertia, inv_mass, accel, force, torque, h):
    """Prediction step of [RB] Algorithm 2 for one dynamic body; returns (x, q, v, ω).

    v ← v + h (a + f/m);  x ← x + h v;
    ω ← ω + h I⁻¹ (τ − ω × (I ω))   (evaluated in the principal frame);
    q ← normalize(q + h ½ [ω, 0] q).
    ``accel`` is a uniform acceleration (gravity); ``force`` / ``torque`` are world-frame
    (or None).
    """
    if force is None:
        vn = [v[0] + h * accel[0], v[1] + h * accel[1], v[2] + h * accel[2]]
    else:
        vn = [v[0] + h * (accel[0] + force[0] * inv_mass), v[1] + h * (accel[1] + force[1] * inv_mass),
              v[2] + h * (accel[2] + force[2] * inv_mass)]
    xn = [x[0] + h * vn[0], x[1] + h * vn[1], x[2] + h * vn[2]]
    wl = quat_rotate_inv(q, w)
    g = cross(wl, (inertia[0] * wl[0], inertia[1] * wl[1], inertia[2] * wl[2]))
    if torque is None:
        tl = (-g[0], -g[1], -g[2])
    else:
        tl = quat_rotate_inv(q, torque)
        tl = (tl[0] - g[0], tl[1] - g[1], tl[2] - g[2])
    wl = (wl[0] + h * inv_inertia[0] * tl[0], wl[1] + h * inv_inertia[1] * tl[1],
          wl[2] + h * inv_inertia[2] * tl[2])
    wn = quat_rotate(q, wl)
    qn = _quat_add_rotation(q, wn, h)
    return xn, qn, vn, list(wn)


def update_velocity_body(x, q, x_prev, q_prev, h):
    """Velocity update of [RB] Algorithm 2: v = (x − x_prev)/h;  Δq = q q_prev⁻¹;
    ω = 2 [Δq_x, Δq_y, Δq_z]/h, negated if Δq_w < 0.  Returns (v, ω)."""
    ih = 1.0 / h
    v = [(x[0] - x_prev[0]) * ih, (x[1] - x_prev[1]) * ih, (x[2] - x_prev[2]) * ih]
    dq = quat_mul(q, quat_conj(q_prev))
    s = 2.0 * ih if dq[0] >= 0.0 else -2.0 * ih
    return v, [s * dq[1], s * dq[2], s * dq[3]]


# ---------------------------------------------------------------------------
# block (vector) form of the XPBD update for a point-to-point attachment


def _mat_from_quat(q):
    w, x, y, z = q
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def point_mobility(invm, invI, q, r):
    """3×3 mobility K = (1/m) E − [r]× I⁻¹ [r]× of a body point at world offset ``r``
    (world frame, as a tuple of rows): the point displacement per unit positional impulse
    at that point ([RB] eqs. 2–3 generalized to all directions: w(n) = nᵀ K n)."""
    if invm == 0.0:
        return None
    x, y, z = quat_rotate_inv(q, r)
    a, b, c = invI
    m00 = b * z * z + c * y * y + invm
    m11 = a * z * z + c * x * x + invm
    m22 = a * y * y + b * x * x + invm
    m01 = -c * x * y
    m02 = -b * x * z
    m12 = -a * y * z
    R = _mat_from_quat(q)
    # K = R M Rᵀ
    RM = [[R[i][0] * m00 + R[i][1] * m01 + R[i][2] * m02,
           R[i][0] * m01 + R[i][1] * m11 + R[i][2] * m12,
           R[i][0] * m02 + R[i][1] * m12 + R[i][2] * m22] for i in range(3)]
    return [[RM[i][0] * R[j][0] + RM[i][1] * R[j][1] + RM[i][2] * R[j][2] for j in range(3)]
            for i in range(3)]


def _solve3(K, b):
    """Solve the 3×3 system K p = b (Cramer's rule); None if singular."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = K
    c00 = a11 * a22 - a12 * a21
    c01 = a12 * a20 - a10 * a22
    c02 = a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    if det == 0.0:
        return None
    inv = 1.0 / det
    b0, b1, b2 = b
    return (
        inv * (c00 * b0 + (a02 * a21 - a01 * a22) * b1 + (a01 * a12 - a02 * a11) * b2),
        inv * (c01 * b0 + (a00 * a22 - a02 * a20) * b1 + (a02 * a10 - a00 * a12) * b2),
        inv * (c02 * b0 + (a01 * a20 - a00 * a21) * b1 + (a00 * a11 - a01 * a10) * b2),
    )


def solve_attachment_block(X, Q, IM, II, b1, b2, r1, r2, d):
    """Point-to-point attachment C = p2 − p1 = d (3 rows, α = 0), block form.

    XPBD eqs. (16)–(17) for the three rows together: [J M⁻¹ Jᵀ] Δλ = −C with
    J M⁻¹ Jᵀ = K₁ + K₂ (``point_mobility``), then the impulse p = Δλ is applied to body
    2 and −p to body 1 with [RB] eqs. (6)–(9).  Unlike the scalar projection along
    n = d/|d| ([RB] Sec. 3.4.2) this closes the gap exactly to first order even when the
    mobility is strongly anisotropic (e.g. a heavy point mass far from the pin).
    Returns the impulse (tuple) or None.
    """
    K1 = point_mobility(IM[b1], II[b1], Q[b1], r1)
    K2 = point_mobility(IM[b2], II[b2], Q[b2], r2)
    if K1 is None:
        K = K2
    elif K2 is None:
        K = K1
    else:
        K = [[K1[i][j] + K2[i][j] for j in range(3)] for i in range(3)]
    if K is None:
        return None
    p = _solve3(K, (-d[0], -d[1], -d[2]))
    if p is None:
        return None
    apply_positional_impulse(X, Q, IM, II, b2, r2, p, 1.0)
    apply_positional_impulse(X, Q, IM, II, b1, r1, p, -1.0)
    return p


def _skew(r):
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


def _body_block(invm, invI, q, r):
    """6×6 response [δp; δθ] = A [P; L] of body point r to a positional impulse P at the
    point plus an angular impulse L (world frame)."""
    R = np.array(_mat_from_quat(q))
    Iinv = (R * np.asarray(invI)) @ R.T
    S = _skew(r)
    A = np.empty((6, 6))
    A[:3, :3] = invm * np.eye(3) - S @ Iinv @ S
    A[:3, 3:] = -S @ Iinv
    A[3:, :3] = Iinv @ S
    A[3:, 3:] = Iinv
    return A


def solve_lock_block(X, Q, IM, II, b1, b2, r1, r2, c_pin, c_ang):
    """Lock all six relative DOF in one block projection (α = 0).

    Rows: C_pin = p2 − p1 (3) and C_ang = rotation vector of body 2 away from its target
    orientation relative to body 1 (3).  XPBD eqs. (16)–(17) in block form:
    (A₁ + A₂) [P; L] = −[C_pin; C_ang]; body 2 receives (P at r2, L), body 1 the
    opposite ([RB] eqs. 6–9, 15–16).  Used for a hinge at its limit, where the scalar
    angular limit correction about the centre of mass would be undone by the pin.
    """
    K = np.zeros((6, 6))
    if IM[b1] != 0.0:
        K += _body_block(IM[b1], II[b1], Q[b1], r1)
    if IM[b2] != 0.0:
        K += _body_block(IM[b2], II[b2], Q[b2], r2)
    rhs = -np.array([c_pin[0], c_pin[1], c_pin[2], c_ang[0], c_ang[1], c_ang[2]])
    try:
        z = np.linalg.solve(K, rhs)
    except np.linalg.LinAlgError:
        return
    apply_lock_impulse(X, Q, IM, II, b1, b2, r1, r2, z)


def _soft_lock_system(K, aw, at, lam, c_pin, c_ang):
    """The 6-row system of ``solve_soft_lock_block`` (K + α̃·a aᵀ on the angular block, right-hand side
    −[C_pin; C_ang + α̃·λ·a]) as lists."""
    A = [[float(K[i][j]) for j in range(6)] for i in range(6)]
    for i in range(3):
        for j in range(3):
            A[3 + i][3 + j] += at * aw[i] * aw[j]
    rhs = [-c_pin[0], -c_pin[1], -c_pin[2],
           -c_ang[0] - at * lam * aw[0], -c_ang[1] - at * lam * aw[1], -c_ang[2] - at * lam * aw[2]]
    return A, rhs


def axis_basis(a):
    """Two unit vectors p₁, p₂ completing the unit vector a to a right-handed orthonormal basis
    (p₁ ⟂ a from the coordinate axis least aligned with a, p₂ = a × p₁)."""
    ax, ay, az = abs(a[0]), abs(a[1]), abs(a[2])
    e = (1.0, 0.0, 0.0) if (ax <= ay and ax <= az) else ((0.0, 1.0, 0.0) if ay <= az else (0.0, 0.0, 1.0))
    d = e[0] * a[0] + e[1] * a[1] + e[2] * a[2]
    p = (e[0] - d * a[0], e[1] - d * a[1], e[2] - d * a[2])
    n = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    p1 = (p[0] / n, p[1] / n, p[2] / n)
    return p1, cross(a, p1)


def solve_soft_lock_block(X, Q, IM, II, b1, b2, r1, r2, c_pin, c_ang, aw, at, lam, side):
    """A hinge beyond a soft limit: pin (3 rows) and axis alignment (2 rows) rigid, the angle about the
    unit axis ``aw`` compliant (α̃ = ``at``, accumulated multiplier ``lam`` [N·m·s²] along +aw), in one
    6-row block (XPBD eq. 16 in block form, as ``solve_lock_block``):

        (A₁ + A₂ + α̃·[0 0; 0 a aᵀ]) [P; L] = −[C_pin; C_ang + α̃·λ·a],

    C_ang the rotation vector of body 2 away from its target orientation (the limit row's target angle).
    One-sided: the new λ + a·L must be ≤ 0 at an upper limit (``side`` +1), ≥ 0 at a lower one (−1);
    otherwise the block is solved again with the axial impulse fixed at a·L = −λ (λ → 0: pin and axis
    rows only, in the basis (a, p₁, p₂) of ``axis_basis``).  Body 2 receives (P at r2, L), body 1 the
    opposite.  Returns the applied Δλ = a·L.
    """
    K = np.zeros((6, 6))
    if IM[b1] != 0.0:
        K += _body_block(IM[b1], II[b1], Q[b1], r1)
    if IM[b2] != 0.0:
        K += _body_block(IM[b2], II[b2], Q[b2], r2)
    A, rhs = _soft_lock_system(K, aw, at, lam, c_pin, c_ang)
    try:
        z = np.linalg.solve(np.array(A), np.array(rhs))
    except np.linalg.LinAlgError:
        return 0.0
    dl = float(aw[0] * z[3] + aw[1] * z[4] + aw[2] * z[5])
    if side * (lam + dl) > 0.0:  # would pull: fix the axial impulse at −λ
        p1, p2 = axis_basis(aw)
        T = np.eye(6)
        T[3:, 3], T[3:, 4], T[3:, 5] = aw, p1, p2
        M = T.T @ np.array(A) @ T
        r = T.T @ np.array(rhs)
        M[3, :] = 0.0
        M[3, 3] = 1.0
        r[3] = -lam
        try:
            zt = np.linalg.solve(M, r)
        except np.linalg.LinAlgError:
            return 0.0
        z = T @ zt
        dl = -lam
    apply_lock_impulse(X, Q, IM, II, b1, b2, r1, r2, z)
    return dl


def apply_joint_torque_impulse(V, W, Q, IM, II, b1, b2, r1, r2, L):
    """Apply the angular impulse ``L`` to body 2 and −L to body 1 (a hinge torque τ·h·a),
    together with the internal impulse at the pin that keeps the relative pin velocity
    unchanged: (K₁ + K₂) P = −(Δv_pin2 − Δv_pin1).  The pin impulse is workless for the
    constrained system; it only removes the spin about the centre of mass that the
    position projection would otherwise have to undo nonlinearly."""
    d2 = _world_inv_inertia_times(Q[b2], II[b2], L) if IM[b2] != 0.0 else (0.0, 0.0, 0.0)
    d1 = _world_inv_inertia_times(Q[b1], II[b1], L) if IM[b1] != 0.0 else (0.0, 0.0, 0.0)
    c2 = cross(d2, r2)
    c1 = cross(d1, r1)
    mis = (c2[0] + c1[0], c2[1] + c1[1], c2[2] + c1[2])  # Δv_pin2 − Δv_pin1 (d1 enters with −)
    apply_angular_velocity_impulse(W, Q, IM, II, b2, L, 1.0)
    apply_angular_velocity_impulse(W, Q, IM, II, b1, L, -1.0)
    K1 = point_mobility(IM[b1], II[b1], Q[b1], r1)
    K2 = point_mobility(IM[b2], II[b2], Q[b2], r2)
    if K1 is None:
        K = K2
    elif K2 is None:
        K = K1
    else:
        K = [[K1[i][j] + K2[i][j] for j in range(3)] for i in range(3)]
    if K is None:
        return
    P = _solve3(K, (-mis[0], -mis[1], -mis[2]))
    if P is None:
        return
    apply_velocity_impulse(V, W, Q, IM, II, b2, r2, P, 1.0)
    apply_velocity_impulse(V, W, Q, IM, II, b1, r1, P, -1.0)
