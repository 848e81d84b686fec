"""MuJoCo's soft-constraint law, as the XPBD solver takes it over a substep.

MuJoCo's constraint regulariser (impedance d(r) from ``solimp``, stiffness k and damping b from ``solref``,
R = (1 − d)/d·invweight) for contacts and limits, and the compliant XPBD row that takes the law over a step
h as MuJoCo's semi-implicit step does (``mujoco_step_target``), written independently of the compiled
substep's ``compiled._impedance``, ``_contact_law`` and ``_soft_limit_target``: the oracle of those kernels
(``tests/test_xpbd_soft_limit.py``) and the law of the pure substep (``xpbd_substep.py``).

References: MuJoCo documentation, Computation, "Soft constraints" (impedance, reference acceleration).
"""

from __future__ import annotations

__all__ = ["mujoco_contact_law", "mujoco_impedance", "mujoco_limit_law", "mujoco_step_target", "soft_limit_target"]


def soft_limit_target(value, rate, lo, hi, solref, solimp, invweight, h):
    """(side ±1, target, α̃) of the one-sided compliant row of a soft limit at ``value`` moving at ``rate``
    under MuJoCo's law (``mujoco_limit_law``), or None inside [``lo``, ``hi``] (see ``SolverXPBD._soft_limit_targets``)."""
    if value > hi:
        side, r, rd = 1.0, hi - value, -rate
    elif value < lo:
        side, r, rd = -1.0, value - lo, rate
    else:
        return None
    kd, b, R = mujoco_limit_law(solref, solimp, invweight, r, timestep=h)
    rs = mujoco_step_target(r, rd, kd, b, h)
    return side, hi - rs if side > 0.0 else lo + rs, R


def mujoco_step_target(r, rate, kd, b, h):
    """Target r* [m or rad] of the compliant row C = r⁺ − r*, α̃ = R, that takes MuJoCo's soft law
    R·f = −(a + b·ṙ + k·d·r) over a step h as MuJoCo does: a·h = ṙ⁺ − ṙ⁻, ṙ⁺·h = r⁺ − r⁻ and the reference
    acceleration −b·ṙ⁻ − k·d·r⁻ at the step's start (``r`` = r⁻, ``rate`` = ṙ⁻), so

        r* = r⁻ + h·ṙ⁻ − h²·(b·ṙ⁻ + k·d·r⁻),   f = −(r⁺ − r*)/(R·h²).

    Semi-implicit like MuJoCo's own step (stable for timeconst ≥ 2·h, the safety clamp applied with h); a
    backward-Euler step of the law (k·d and b taken at r⁺, ṙ⁺) damps an impact more: the boom's end stop at
    2 ms frames returned 175 µm off MuJoCo mode at 0.25 ms with it, 37 µm (MuJoCo mode at 2 ms: 37 µm) with
    this step."""
    return r + h * rate - h * h * (b * rate + kd * r)


def mujoco_impedance(solimp, pos):
    """MuJoCo's constraint impedance d(r) ∈ (0, 1) at violation ``pos`` [m] (``getimpedance`` in
    engine_core_constraint.c, margin 0): dmin at r = 0 rising to dmax at |r| ≥ width along the
    sigmoid of (midpoint, power)."""
    dmin, dmax, width, mid, power = (float(v) for v in solimp)
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


def mujoco_contact_law(solref, solimp, condim, tran, mu, pos, *, cone=0, impratio=1.0, timestep=0.0):
    """Normal law of one MuJoCo soft contact, (k·d [1/s²], b [1/s], R [1/kg]), such that

        R·f = −(a + b·v + k·d·r),

    f [N] the normal force (+ pushes apart), r [m] the gap (< 0 penetrating), v, a its rate
    and acceleration.  From MuJoCo's soft-constraint model (Computation chapter, "Soft
    contact model"; ``mj_makeImpedance``/``mj_diagApprox`` in engine_core_constraint.c):

    * solref = (timeconst, dampratio) > 0, with timeconst ≥ 2·timestep:
      k = 1/(dmax²·timeconst²·dampratio²), b = 2/(dmax·timeconst);
      direct format (−stiffness, −damping): k = stiffness/dmax², b = damping/dmax;
    * impedance d = d(r) from solimp (``mujoco_impedance``); aref = −b·v − k·d·r;
    * regulariser R = (1 − d)/d·Â with Â MuJoCo's diagonal approximation of J·M⁻¹·Jᵀ from
      the bodies' ``body_invweight0`` (``tran`` = Σ of the translational parts) — the
      effective mass of the contact is 1/Â;
    * each constraint row obeys f_row = (aref_row − a_row)/R_row (the unconstrained
      minimiser of MuJoCo's convex problem for an active row).  Frictionless (condim 1) and
      elliptic cones: the normal row has Â = tran.  Pyramidal cones (MuJoCo's default):
      2(condim − 1) edge rows n ± μ·t share Rpy = 2·μ_r²·R₀, R₀ = (1 − d)/d·tran·(1 + μ²),
      μ_r = μ/√impratio, and carry the normal force together; with every edge active their
      sum is the normal law above with R = Rpy/(2(condim − 1)).

    Static load F on a contact: penetration r = −F·R/(k·d), i.e. a stiffness k·d/R
    (per unit Â: d²/((1 − d)·dmax²·timeconst²·dampratio²) for the frictionless case);
    free vibration of the effective mass: a + b·v + k·d·r = −R·f with R·f the (1−d)/d share.
    Returns R = 0 (rigid) for μ = 0 on a pyramidal cone (MuJoCo's Rpy vanishes there).
    """
    tc, zeta = float(solref[0]), float(solref[1])
    d = mujoco_impedance(solimp, pos)
    dmax = min(max(float(solimp[1]), 1e-4), 0.9999)
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


def mujoco_limit_law(solref, solimp, invweight, pos, *, timestep=0.0):
    """Law of one MuJoCo soft joint (or tendon) limit, (k·d [1/s²], b [1/s], R), such that

        R·f = −(a + b·v + k·d·r),

    r [rad or m] the limit distance (hi − q or q − lo, < 0 beyond the limit), v, a its rate and
    acceleration, f [N·m or N] the generalized limit force (≥ 0, pushes back into the range).  MuJoCo's
    soft-constraint model (``mj_makeImpedance``/``mj_diagApprox``, engine_core_constraint.c) for a
    limit row: k, b from solref as for contacts (timeconst ≥ 2·timestep), impedance d = d(r) from solimp
    (width in the joint's units), R = (1 − d)/d·Â with Â = ``dof_invweight0`` of the joint's dof
    (``tendon_invweight0`` of a tendon).  Static load τ: r = −τ·R/(k·d), a stiffness
    k·d²/((1 − d)·Â) = d²/((1 − d)·Â·dmax²·timeconst²·dampratio²) for the (timeconst, dampratio) form.
    It is the frictionless contact law (``mujoco_contact_law`` with condim 1 and ``tran`` = Â).
    """
    return mujoco_contact_law(solref, solimp, 1, float(invweight), 0.0, pos, timestep=timestep)
