"""Rigid-body XPBD solver (Müller et al. 2020, Algorithm 2) with compliant length rows.

Sign conventions
----------------
* Length row i between sites a and b: ℓ = |p_b − p_a|, n = (p_b − p_a)/ℓ,
  C = ℓ − ℓ*.  Its multiplier λ and force f = λ/h² [N] are **positive when the row
  pushes the sites apart** (compression, e.g. cap-side pressure P·A) and negative when it
  pulls them together (tension).  The force on site b is f·n, on site a −f·n.  A linear
  spring gives f = −(ℓ − ℓ*)/α.  Bounds ``force_min`` ≤ f ≤ ``force_max`` are applied to
  the accumulated multiplier (λ = f h²) of the substep, e.g. ``force_min = A·P_vap``
  models cavitation of a chamber pushing the sites apart.
* ``row_force`` (explicit external force along the row) uses the same sign.
* ``joint_force[j]`` is a generalized force along +qpos of MuJoCo joint j: a torque [N·m]
  about the hinge axis applied to the child (reaction on the parent), or a force [N]
  along the slide axis.
* ``body_wrench[b]`` = (force [N], torque [N·m]) in world frame, force at body b's COM.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Optional, Protocol, Sequence

import numpy as np

from sim.xpbd import kernels as K
from sim.xpbd.kernels import (
    angular_inverse_mass,
    apply_angular_velocity_impulse,
    apply_velocity_impulse,
    cross,
    np_cross,
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
from sim.xpbd.model import EQ_WELD, JNT_BALL, JNT_FREE, JNT_HINGE, JNT_SLIDE, XpbdModel, XpbdState

__all__ = ["LengthConstraint", "SubstepInputs", "SubstepForces", "SubstepHooks", "SolverXPBD", "XpbdOptions",
           "mujoco_contact_law", "mujoco_impedance", "mujoco_limit_law"]

_EPS = 1e-14
_INF = math.inf
_PYRAMID = "pyramid"  # marker of a soft pyramidal contact in SubstepWork.contact_soft


@dataclass(frozen=True, kw_only=True)
class XpbdOptions:
    """The scheme options of :class:`SolverXPBD` (see its docstring for what each changes).

    Examples
    --------
    >>> XpbdOptions(substeps=10, articulated_contacts=False).iterations
    1
    """

    substeps: int = 20
    """XPBD substeps per step [-]; must be >= 1."""
    iterations: int = 1
    """Position passes per substep [-]; must be >= 1."""
    linear_damping: float = 0.0
    """Global linear damping c of v ← v/(1 + c·h) [1/s]."""
    angular_damping: float = 0.0
    """Global angular damping c of ω ← ω/(1 + c·h) [1/s]."""
    contact_margin: float = 1e-3
    """Contact candidate distance added to 2·dt·|v_rel| [m]."""
    block_attach: bool = True
    """Project pin/connect attachments with the 3×3 block update."""
    velocity_sweeps: int = 4
    """Projected Gauss-Seidel sweeps of the contact velocity pass [-]."""
    symmetric: bool = True
    """Forward + backward Gauss-Seidel per iteration."""
    soft_contacts: bool = True
    """MuJoCo's soft-contact law (else the rigid contacts of [RB])."""
    pyramid_friction: bool = True
    """Soft pyramidal friction rows (MuJoCo's default cone) on soft contacts."""
    compiled: bool = True
    """Run the substeps in ``compiled.substep_core``."""
    transport_response: bool = False
    """Carry the articulated responses to each substep's pose."""
    articulated_contacts: bool = True
    """Solve the contact pyramids with the mechanism's articulated response."""
    soft_limits: bool = True
    """MuJoCo's soft joint and tendon limits (else rigid limits)."""

    def __post_init__(self):
        for name in ("substeps", "iterations"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)!r}")


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


@dataclass(frozen=True)
class LengthConstraint:
    """A length row between two MuJoCo sites (ids or names). C = |p_b − p_a| − ℓ*."""

    site_a: int | str
    site_b: int | str
    name: str = ""


@dataclass
class SubstepInputs:
    """Inputs for one substep (all optional; arrays are indexed by row / joint / body).

    target_length  (nrows,) ℓ* [m]; NaN (or None for all rows) = row inactive.
    compliance     (nrows,) α [m/N]; 0 = rigid (default).
    force_min/max  (nrows,) bounds on the row force λ/h² [N] (default ∓inf).
    row_force      (nrows,) explicit force along the row [N], + pushes the sites apart.
    joint_force    (njnt,) generalized force per MuJoCo joint (hinge torque / slide force).
    body_wrench    (nbody, 6) world force at COM and torque per MuJoCo body.
    row_mobility   (nrows, ngroup, 6) articulated response of the mechanism to each row:
                   displacement of every rigid group's centre of mass [m] and its rotation
                   vector [rad] (world frame) per unit multiplier of the row [1/(N·s²)], i.e.
                   the body motion of Δq = M⁻¹ Jᵀ (J: row length rates per joint velocity, M:
                   joint-space mass matrix); rows 0 for static groups.  When given, the active
                   rows are solved together (``_solve_rows_block``): W = ∂C/∂λ is formed from
                   these displacements at the current geometry, Δλ = −(W + α̃)⁻¹ (C + α̃ λ)
                   ([XPBD] eq. 16 restricted to the rows), and the groups are moved by
                   Σ mobility·Δλ, which keeps the joints satisfied to first order (the joint
                   projections clean up the rest).  A stiff row inside an articulated chain
                   then gets the response of the whole mechanism in one iteration, whereas its
                   free-body inverse mass makes Gauss-Seidel converge slowly and leaves the row
                   force far below its compliant law.  Bounds are applied per row after the
                   block solve.
    group_gravity  (ngroup, 6) acceleration [m/s²] and angular acceleration [rad/s²] (world
                   frame) of each rigid group that replaces the uniform gravity in the
                   prediction, e.g. the articulated response of gravity (the body motion of
                   q̈ = M⁻¹ Q_gravity).  The prediction is then consistent with the joints to
                   first order, so one projection pass does not leave the load-dependent joint
                   error (and velocity noise) that the free fall of every body under uniform
                   gravity does.
    """

    target_length: Optional[np.ndarray] = None
    compliance: Optional[np.ndarray] = None
    force_min: Optional[np.ndarray] = None
    force_max: Optional[np.ndarray] = None
    row_force: Optional[np.ndarray] = None
    joint_force: Optional[np.ndarray] = None
    body_wrench: Optional[np.ndarray] = None
    row_mobility: Optional[np.ndarray] = None
    group_gravity: Optional[np.ndarray] = None


@dataclass
class SubstepForces:
    """Per-substep results for the length rows.

    row_force   λ/h² [N] (+ pushes the sites apart); 0 for inactive rows.
    row_lambda  accumulated multiplier λ of the substep [N·s²].
    row_length  ℓ after the substep [m];  row_rate  dℓ/dt after the substep [m/s].
    row_active  which rows were solved.
    """

    row_force: np.ndarray
    row_lambda: np.ndarray
    row_length: np.ndarray
    row_rate: np.ndarray
    row_active: np.ndarray


class SubstepHooks(Protocol):
    def before_substep(self, k: int, h: float, state: XpbdState) -> Optional[SubstepInputs]: ...

    def after_substep(self, k: int, h: float, state: XpbdState, forces: SubstepForces) -> None: ...


def _soft_limit_target(value, rate, lo, hi, solref, solimp, invweight, h):
    """(side ±1, target, α̃) of the one-sided compliant row of a soft limit at ``value`` moving at ``rate``
    under MuJoCo's law (``mujoco_limit_law``), or None inside [``lo``, ``hi``] (see ``_soft_limit_targets``)."""
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


def _move_groups(X, Q, IM, G, dq):
    """Move every dynamic group by G·dq: the joint-space displacement ``dq`` through the group Jacobian G."""
    for g in range(1, len(X)):
        if IM[g] == 0.0:
            continue
        d = G[g] @ dq
        X[g] = [X[g][0] + d[0], X[g][1] + d[1], X[g][2] + d[2]]
        if d[3] != 0.0 or d[4] != 0.0 or d[5] != 0.0:
            Q[g] = K._quat_add_rotation(Q[g], (float(d[3]), float(d[4]), float(d[5])), 1.0)


class SolverXPBD:
    """Substepped rigid-body XPBD ([RB] Algorithm 2).

    Per step: contact candidates are gathered once; then for each of ``substeps``
    substeps of length h = dt/substeps: predict (gravity, external forces, gyroscopic
    term), ``iterations`` position passes over joints, equalities, length rows and
    contacts (λ reset each substep), velocity update from the position change, velocity
    pass (dynamic friction, zero restitution, implicit joint damping), global damping
    v ← v/(1 + c h).  ``step`` updates the state in place and returns it.

    Options (:class:`XpbdOptions`, the second argument) and where they depart from the paper's single forward
    sweep:

    * ``symmetric`` (default True): each iteration is a forward + backward Gauss-Seidel
      pass.  Forward-only sweeps can be unstable with light bodies between joints
      (see ``_solve_positions``); it costs about 2× per iteration.
    * ``block_attach`` (default True): pin/connect attachments are projected with the
      3×3 block form of the XPBD update (``kernels.solve_attachment_block``) instead of
      the scalar projection along the error direction; about 5× smaller pin drift.
    * ``soft_limits`` (default True): joint limits (hinge, slide) and the limits of straight two-site
      spatial tendons follow MuJoCo's soft-constraint law of the MJCF (solreflimit/solimplimit,
      R = (1 − d)/d·dof_invweight0 or tendon_invweight0; ``mujoco_limit_law``), taken over the substep as
      MuJoCo takes it over its step, as the soft contacts are (``mujoco_step_target``; ``_soft_limit_targets``,
      ``_tendon_limit_targets``): a limit
      acts in a substep that starts beyond it, as a one-sided compliant row.  A hinge beyond its soft
      limit is solved as one 6-row block (pin and axis rigid, the angle compliant,
      ``kernels.solve_soft_lock_block``); when a tendon limit is active too (the boom's cylinder end stop,
      where MuJoCo activates the joint and the tendon limit together) all active limits of a hinge/slide
      tree are solved as one articulated block (``_solve_limits_block``: W = J·M⁻¹·Jᵀ + α̃, active set),
      which Gauss-Seidel over the two nearly parallel rows does not reproduce (13 % too deep statically).
      A boom pressed into its end stop then rests at MuJoCo's penetration (within 0.01 %) and an impact
      overtravels as in MuJoCo (``tests/test_xpbd_soft_limit.py``); the boom lift's stroke error against
      MuJoCo mode at 0.25 ms falls with the substeps after the end stop (0.179 → 0.030 % of stroke from
      × 5 to × 40 at 60 Hz) instead of staying at 0.244 % with rigid limits.  ``soft_limits=False``: the
      rigid projection — a hinge beyond its limit as one 6-row block (pin + axis + clamped angle), since
      an angular correction about the COM is otherwise undone by the pin; tendon limits ignored.
    * Hinge torques are applied as joint-space impulses (couple + workless pin impulse).
    * ``velocity_sweeps``: projected Gauss-Seidel sweeps of the contact velocity pass
      (Coulomb-clamped accumulated impulses).
    * ``contact_margin`` [m]: candidate distance added to 2·dt·|v_rel|.
    * ``articulated_contacts`` (default True): on a tree of hinges and slides the soft
      pyramidal contacts are solved with the response of the whole mechanism, as MuJoCo's
      contact problem is (its a = J·M⁻¹·Jᵀ·f + a₀): W = J·M⁻¹·Jᵀ of the edge rows and every
      group moved by G·M⁻¹·Jᵀ·Δλ (G the group Jacobian, M the joint-space mass matrix of the
      group masses and inertias at the predicted pose, ``_articulated_inverse``).  With the
      free-body response of the touching body (``False``, the behaviour before), the edge rows
      see the body as if it were free and the joint projection takes part of the correction
      back; for MuJoCo's stiff soft contact (R ≈ 5–10 % of the effective inverse mass) this
      changes the impact at any substep: a hinged arm striking the ground sinks 52 % deeper than
      in MuJoCo (with: within 0.3 %, ``tests/test_xpbd_articulated_contact.py``), and the
      excavator's teeth stick-slip in the soil with a lag (dig-phase pressures 5.5 % of relief
      from the converged reference on 0.1 s averages at any substep with one iteration; with:
      2.2 % at 1 kHz × 20).  Other joint types (free, ball): the free-body response.
    * ``transport_response`` (default False): the articulated responses of ``SubstepInputs``
      (``row_mobility``, ``group_gravity``; world-frame group motions a plant computes once per
      step at the step's start pose) are carried to every later substep's pose through joint
      space, R_k = G_k·G₀⁺·R₀ (G the group Jacobian of a tree of hinges and slides,
      ``_transport``), as the response of the same joint-space motion Δq = M⁻¹·Jᵀ.  Without it
      a 60 Hz frame applies the row and gravity responses in directions up to one frame old: a
      swinging machine (≈ 1 rad/s, 17 mrad per frame) then gets cylinder and gravity
      corrections tilted out of its moving boom plane, and its pressures converge with the
      substeps to a frame-rate-dependent limit (excavator dig, 7–20 s: 0.1 s-averaged pressure
      error 4.6 → 10 % of relief from × 40 to × 320 substeps at 60 Hz, 3.6 % at 19.2 kHz × 1).
      M⁻¹ and the rows' moment arms stay those of the step's start (they do not depend on the
      swing angle).  Other joint types or a singular Jacobian: no transport.  Off by default:
      at 60 Hz × 10–40 the frame-old responses happen to offset part of backward Euler's
      numerical damping (swing phase 14 % / 4.6 % with them, 24 % / 7.7 % without), so the
      coarse settings' errors grow while the fine ones' shrink; the plant's compiled frame
      selects the same behaviour with ``frame_nb.frame(transport=...)``.
    * ``compiled`` (default True): every substep runs in ``compiled.substep_core`` (numba,
      ``cache=True``, one signature), a port of this class's substep on flat arrays with the
      same operations in the same order; the hooks are still called per substep.  This
      pure-Python path stays the reference (``compiled=False``; agreement to round-off in
      ``tests/test_pbd_compiled.py``) and is used with ``block_attach=False``.  Every contact kind
      (soft pyramidal, soft normal with Coulomb friction on an elliptic cone or condim 1, rigid) runs compiled.
      ``compiled_steps`` counts the steps the compiled path took.  On the compiled path the
      per-step group gather and contact-candidate test are compiled too (``compiled.gather``,
      ``compiled.contact_candidates``; same values as the numpy code, tests/test_pbd_fast.py).

    Joint damping (MJCF ``damping``) is applied implicitly at the velocity level:
    rate ← rate/(1 + b h w), w the generalized inverse mass of the joint pair.
    Contacts (``soft_contacts``, default True) are compliant in the normal direction with
    MuJoCo's soft-contact law of the geom pair (solref/solimp/condim/cone from the compiled
    MjModel, effective mass from its ``body_invweight0``; ``mujoco_contact_law``,
    ``_soft_contact_targets``): a resting body sinks by the same static penetration as in
    MuJoCo and an impact has the same time constant.  Friction stays Coulomb (static and
    dynamic, [RB] Sec. 3.5–3.6), not MuJoCo's soft pyramid.  ``soft_contacts=False`` gives
    the rigid contacts of [RB].
    Not modelled: armature (except on hinges whose parent is static: ``XpbdModel.jnt_armature``), frictionloss, joint stiffness, gravcomp, actuators, contacts
    other than sphere/capsule/box vs plane, soft equalities (rigid), limits of tendons that are not
    straight two-site spatial tendons between different rigid groups.
    """

    def __init__(self, model: XpbdModel, options: Optional[XpbdOptions] = None, *,
                 length_constraints: Sequence[LengthConstraint] = ()):
        o = XpbdOptions() if options is None else options
        if not isinstance(o, XpbdOptions):
            raise TypeError(f"`options` must be an XpbdOptions, got {type(o).__name__}")
        self.model = model
        self.substeps = int(o.substeps)
        self.iterations = int(o.iterations)
        self.linear_damping = float(o.linear_damping)
        self.angular_damping = float(o.angular_damping)
        self.contact_margin = float(o.contact_margin)
        self.block_attach = bool(o.block_attach)
        self.velocity_sweeps = int(o.velocity_sweeps)
        self.symmetric = bool(o.symmetric)
        self.soft_contacts = bool(o.soft_contacts) and model.contact_solref is not None
        self.pyramid_friction = bool(o.pyramid_friction) and self.soft_contacts
        self.transport_response = bool(o.transport_response)
        self.articulated_contacts = bool(o.articulated_contacts)
        # contact tangent t₁ of each plane (its geom x axis in the plane's group frame), t₂ = n × t₁
        self._plane_tangent = []
        for nrm in np.asarray(model.plane_normal, float).reshape(-1, 3):
            axis = np.array([1.0, 0.0, 0.0]) if abs(nrm[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            t = axis - (axis @ nrm) * nrm
            self._plane_tangent.append(tuple(float(c) for c in t / np.linalg.norm(t)))
        self._cidx: list[int] = []  # model contact index of each candidate of the step
        self._rows: list[tuple] = []
        self.rows: list[LengthConstraint] = []
        for lc in length_constraints:
            self.add_length_constraint(lc)
        m = model
        self._IM = [float(a) for a in m.group_inv_mass]
        self._GI = [tuple(float(b) for b in a) for a in m.group_inertia]
        self._gravity = tuple(float(a) for a in m.gravity)
        self._II = [tuple(float(b) for b in a) for a in m.group_inv_inertia]
        tup = lambda a: tuple(float(b) for b in a)  # noqa: E731
        self._joints = []
        for j in range(m.njnt):
            self._joints.append((int(m.jnt_type[j]), int(m.jnt_g1[j]), int(m.jnt_g2[j]),
                                 tup(m.jnt_r1[j]), tup(m.jnt_r2[j]), tup(m.jnt_a1[j]),
                                 tup(m.jnt_a2[j]), tup(m.jnt_qoff[j]), bool(m.jnt_limited[j]),
                                 float(m.jnt_lo[j]), float(m.jnt_hi[j]),
                                 float(m.jnt_damping[j])))
        self._eqs = [(int(m.eq_type[e]), int(m.eq_g1[e]), int(m.eq_g2[e]), tup(m.eq_r1[e]),
                      tup(m.eq_r2[e]), tup(m.eq_qoff[e])) for e in range(len(m.eq_type))]
        self._damped = [jt for jt in self._joints if jt[11] > 0.0 and jt[0] != JNT_FREE]
        # soft joint limits: (solref, solimp, dof_invweight0) per limited hinge/slide, None = rigid projection
        self.soft_limits = bool(o.soft_limits) and m.jnt_invweight is not None
        self._jlaw = [None] * m.njnt
        if self.soft_limits:
            for j in range(m.njnt):
                if bool(m.jnt_limited[j]) and int(m.jnt_type[j]) in (JNT_HINGE, JNT_SLIDE) and m.jnt_invweight[j] > 0.0:
                    self._jlaw[j] = (tup(m.jnt_solref[j]), tup(m.jnt_solimp[j]), float(m.jnt_invweight[j]))
        # soft tendon limits (two-site spatial tendons): (ga, gb, ra, rb, lo, hi, solref, solimp, tendon_invweight0)
        self._tlaw = []
        if self.soft_limits and m.tendon_limit_invweight is not None:
            for k, t in enumerate(m.tendon_limit_ids):
                sa, sb = m.tendon_sites[t]
                if not m.tendon_limit_invweight[k] > 0.0:
                    continue
                self._tlaw.append((int(m.site_group[sa]), int(m.site_group[sb]), tup(m.site_pos_group[sa]),
                                   tup(m.site_pos_group[sb]), float(m.tendon_limit_range[k][0]),
                                   float(m.tendon_limit_range[k][1]), tup(m.tendon_limit_solref[k]),
                                   tup(m.tendon_limit_solimp[k]), float(m.tendon_limit_invweight[k])))
        self.last_forces: list[SubstepForces] = []
        # compiled path (numba, ``compiled.substep_core``): same equations on flat arrays; the pure
        # path above stays the reference (``tests/test_pbd_compiled.py``)
        self.compiled = bool(o.compiled) and self.block_attach
        self._flat = self._flat_model() if self.compiled else None
        self.compiled_steps = 0  # steps taken by the compiled path (the others fell back to the pure one)

    def _flat_model(self):
        """Writable contiguous copies of the model for ``compiled.substep_core`` (one numba signature): the
        ``compiled.GroupModel``."""
        from sim.xpbd.compiled import GroupModel

        m = self.model
        f64 = lambda a, shape: np.ascontiguousarray(np.array(a, dtype=np.float64).reshape(shape))  # noqa: E731
        nj, ne = m.njnt, len(m.eq_type)
        jvec = np.zeros((nj, 4, 3))
        if nj:
            jvec[:, 0], jvec[:, 1] = f64(m.jnt_r1, (nj, 3)), f64(m.jnt_r2, (nj, 3))
            jvec[:, 2], jvec[:, 3] = f64(m.jnt_a1, (nj, 3)), f64(m.jnt_a2, (nj, 3))
        evec = np.zeros((ne, 2, 3))
        if ne:
            evec[:, 0], evec[:, 1] = f64(m.eq_r1, (ne, 3)), f64(m.eq_r2, (ne, 3))
        return GroupModel(
            IM=f64(m.group_inv_mass, (-1,)), II=f64(m.group_inv_inertia, (-1, 3)), GI=f64(m.group_inertia, (-1, 3)),
            gravity=f64(m.gravity, (3,)),
            jt=np.array(m.jnt_type, dtype=np.int64).reshape(nj),
            jg=np.array(np.column_stack([np.asarray(m.jnt_g1).reshape(nj), np.asarray(m.jnt_g2).reshape(nj)]), dtype=np.int64),
            jvec=jvec, jqoff=f64(m.jnt_qoff, (nj, 4)),
            jlim=self._limit_table(), jlo=f64(m.jnt_lo, (nj,)), jhi=f64(m.jnt_hi, (nj,)), jdamp=f64(m.jnt_damping, (nj,)),
            et=np.array(m.eq_type, dtype=np.int64).reshape(ne),
            eg=np.array(np.column_stack([np.asarray(m.eq_g1).reshape(ne), np.asarray(m.eq_g2).reshape(ne)]), dtype=np.int64),
            evec=evec, eqoff=f64(m.eq_qoff, (ne, 4)),
            body_group=np.array(m.body_group, dtype=np.int64), in_group_quat=f64(m.body_in_group_quat, (-1, 4)),
            in_group_pos=f64(m.body_in_group_pos, (-1, 3)),
            contact_cone=int(m.contact_cone), contact_impratio=float(m.contact_impratio),
        )

    def _limit_table(self):
        """The limits as one float array for ``compiled.substep_core`` (``jlim``, shape (njnt + ntendonlimits,
        LIMIT_COLS)): per joint [limited (1/0), solref (2), solimp (5), dof_invweight0], invweight 0 = rigid
        projection; then per soft tendon limit the same and [lo, hi [m], group a, group b, ra (3), rb (3)]."""
        from sim.xpbd.compiled import LIMIT_COLS

        m = self.model
        nj = m.njnt
        tab = np.zeros((nj + len(self._tlaw), LIMIT_COLS))
        for j in range(nj):
            tab[j, 0] = 1.0 if bool(m.jnt_limited[j]) else 0.0
            law = self._jlaw[j]
            if law is not None:
                tab[j, 1:3], tab[j, 3:8], tab[j, 8] = law[0], law[1], law[2]
        for k, (ga, gb, ra, rb, lo, hi, solref, solimp, invw) in enumerate(self._tlaw):
            tab[nj + k, 0] = 1.0
            tab[nj + k, 1:3], tab[nj + k, 3:8], tab[nj + k, 8] = solref, solimp, invw
            tab[nj + k, 9:11], tab[nj + k, 11:13], tab[nj + k, 13:16], tab[nj + k, 16:19] = (lo, hi), (ga, gb), ra, rb
        return tab

    def _scatter_compiled(self, X, Q, V, W, state):
        from sim.xpbd.compiled import scatter

        fm = self._flat
        out = (state.x, state.q, state.v, state.w)
        if all(a.dtype == np.float64 and a.flags.c_contiguous and a.flags.writeable for a in out):
            scatter(X, Q, V, W, fm.body_group, fm.in_group_quat, fm.in_group_pos, *out)  # in place
            return
        x, q, v, w = (np.empty((self.model.nbody, k)) for k in (3, 4, 3, 3))
        scatter(X, Q, V, W, fm.body_group, fm.in_group_quat, fm.in_group_pos, x, q, v, w)
        state.x[:], state.q[:], state.v[:], state.w[:] = x, q, v, w

    def _flat_rows(self):
        nr = len(self._rows)
        rg = np.array([[r[0], r[1]] for r in self._rows], dtype=np.int64).reshape(nr, 2)
        rvec = np.array([[r[2], r[3]] for r in self._rows], dtype=np.float64).reshape(nr, 2, 3)
        return rg, rvec

    def _contact_arrays(self):
        """Per contact point of the model, made once: the inputs of ``compiled.contact_candidates``, the
        candidate tuples ``_collect_contacts`` returns, and the rows of ``_flat_contacts``."""
        c = getattr(self, "_contact_cache", None)
        if c is not None:
            return c
        m = self.model
        nc = len(m.contact_group)
        f = lambda v, *shape: np.ascontiguousarray(np.array(v, dtype=np.float64).reshape(*shape))  # noqa: E731
        i = lambda v: np.ascontiguousarray(np.array(v, dtype=np.int64).reshape(-1))  # noqa: E731
        g, pl = i(m.contact_group), i(m.contact_plane)
        pg = i(m.plane_group)[pl] if nc else np.zeros(0, np.int64)
        c = dict(group=g, plane=pl, plane_group=i(m.plane_group), local=f(m.contact_local, -1, 3),
                 radius=f(m.contact_radius, -1), plane_origin=f(m.plane_origin, -1, 3),
                 plane_normal=f(m.plane_normal, -1, 3), out=np.zeros(nc, np.int64))
        c["tuples"] = [(int(g[k]), tuple(map(float, m.contact_local[k])), float(m.contact_radius[k]),
                        int(pg[k]), tuple(map(float, m.plane_origin[pl[k]])),
                        tuple(map(float, m.plane_normal[pl[k]])), float(m.contact_mu[k])) for k in range(nc)]
        if nc:  # the rows of ``_flat_contacts`` (solref, solimp, tran are not read without soft contacts)
            soft = m.contact_solref is not None
            c["cg"] = np.column_stack([g, pg]).astype(np.int64)
            c["cvec"] = np.array([[c["tuples"][k][1], c["tuples"][k][4], c["tuples"][k][5], self._plane_tangent[int(pl[k])]]
                                  for k in range(nc)], dtype=np.float64).reshape(nc, 4, 3)
            c["crad"] = f(m.contact_radius, -1)
            c["condim"] = i(m.contact_condim if soft else np.ones(nc))
            c["mu"] = f(m.contact_mu, -1)
            c["tran"] = f(m.contact_tran if soft else np.zeros(nc), -1)
            c["solref"] = f(m.contact_solref if soft else np.zeros((nc, 2)), nc, 2)
            c["solimp"] = f(m.contact_solimp if soft else np.zeros((nc, 5)), nc, 5)
            c["eligible"] = np.ones(nc, bool)  # every contact kind runs in the compiled substep
        self._contact_cache = c
        return c

    def _flat_contacts(self, cands):
        """The step's contact candidates as ``compiled.ContactRows`` for ``compiled.substep_core`` (every kind:
        soft pyramidal, soft normal with Coulomb friction, rigid)."""
        from sim.xpbd.compiled import ContactRows

        m = self.model
        nc = len(cands)
        if nc == 0:
            return ContactRows(*_NO_CONTACTS)
        if self.compiled:  # rows of the per-contact arrays made once (same values as below)
            c = self._contact_arrays()
            idx = np.array(self._cidx, dtype=np.int64)
            return ContactRows(c["cg"][idx], c["cvec"][idx], c["crad"][idx], c["mu"][idx], c["solref"][idx],
                               c["solimp"][idx], c["condim"][idx], c["tran"][idx])
        idx = np.array(self._cidx, dtype=np.int64)
        soft = m.contact_solref is not None
        condim = np.array(m.contact_condim if soft else np.ones(len(m.contact_mu)), dtype=np.int64)[idx]
        mu = np.array(m.contact_mu, dtype=np.float64)[idx]
        tran = np.array(m.contact_tran if soft else np.zeros(len(m.contact_mu)), dtype=np.float64)[idx]
        cg = np.array([[c[0], c[3]] for c in cands], dtype=np.int64)
        planes = np.asarray(m.contact_plane)[idx]
        cvec = np.array([[c[1], c[4], c[5], self._plane_tangent[int(pl)]] for c, pl in zip(cands, planes)], dtype=np.float64)
        crad = np.array([c[2] for c in cands], dtype=np.float64)
        solref = np.array(m.contact_solref, dtype=np.float64)[idx] if soft else np.zeros((nc, 2))
        solimp = np.array(m.contact_solimp, dtype=np.float64)[idx] if soft else np.zeros((nc, 5))
        return ContactRows(cg, cvec, crad, mu, np.ascontiguousarray(solref.reshape(nc, 2)),
                           np.ascontiguousarray(solimp.reshape(nc, 5)), condim, tran)

    # ------------------------------------------------------------------ rows
    def add_length_constraint(self, lc: LengthConstraint) -> int:
        """Register a length row; returns its index."""
        m = self.model
        sa, sb = m.site_id(lc.site_a), m.site_id(lc.site_b)
        ga, gb = int(m.site_group[sa]), int(m.site_group[sb])
        if ga == gb:
            raise ValueError("length constraint between sites of the same rigid group")
        self._rows.append((ga, gb, tuple(map(float, m.site_pos_group[sa])),
                           tuple(map(float, m.site_pos_group[sb])), sa, sb))
        self.rows.append(lc)
        return len(self._rows) - 1

    @property
    def nrows(self) -> int:
        return len(self._rows)

    def row_lengths(self, state: XpbdState):
        """(ℓ, dℓ/dt) of every row for a state."""
        if not self._rows:
            return np.zeros(0), np.zeros(0)
        sa = [r[4] for r in self._rows]
        sb = [r[5] for r in self._rows]
        p = self.model.site_positions(state)
        v = self.model.site_velocities(state)
        d = p[sb] - p[sa]
        ell = np.linalg.norm(d, axis=1)
        n = d / np.where(ell > 0, ell, 1.0)[:, None]
        return ell, np.einsum("ij,ij->i", v[sb] - v[sa], n)

    # ------------------------------------------------------------------ gather / scatter
    def _gather(self, state):
        if self.compiled:  # one compiled pass (compiled.gather, same equations)
            from sim.xpbd.compiled import gather

            m, a = self.model, self.model._nb_arrays()
            ng = len(a["root"])
            x, q, v, w = np.empty((ng, 3)), np.empty((ng, 4)), np.empty((ng, 3)), np.empty((ng, 3))
            gather(_f64(state.x), _f64(state.q), _f64(state.v), _f64(state.w), a["root"], a["from_root_quat"],
                        a["from_root_pos"], x, q, v, w)
            return x, q, v, w
        m = self.model
        r = m.group_root
        qr = state.q[r]
        q = K.np_quat_mul(qr, m.group_from_root_quat)
        x = state.x[r] + K.np_quat_rotate(qr, m.group_from_root_pos)
        w = state.w[r].copy()
        v = state.v[r] + np_cross(w, x - state.x[r])
        x[0], q[0], v[0], w[0] = 0.0, (1.0, 0.0, 0.0, 0.0), 0.0, 0.0
        return x, q, v, w

    def _scatter(self, x, q, v, w, state):
        m = self.model
        g = m.body_group
        qg = q[g]
        state.q[:] = K.np_quat_mul(qg, m.body_in_group_quat)
        state.x[:] = x[g] + K.np_quat_rotate(qg, m.body_in_group_pos)
        state.w[:] = w[g]
        state.v[:] = v[g] + np_cross(w[g], state.x - x[g])

    # ------------------------------------------------------------------ contacts
    def _collect_contacts(self, x, q, v, w, dt):
        """Contact candidates for the whole step ([RB] Algorithm 2, CollectCollisionPairs)."""
        m = self.model
        self._cidx = []
        if len(m.contact_group) == 0:
            return []
        if self.compiled:  # the candidate test in one compiled pass (compiled.contact_candidates)
            from sim.xpbd.compiled import contact_candidates

            c = self._contact_arrays()
            n = contact_candidates(_f64(x), _f64(q), _f64(v), _f64(w), c["group"], c["plane"], c["plane_group"],
                                        c["local"], c["radius"], c["plane_origin"], c["plane_normal"],
                                        self.contact_margin, float(dt), c["out"])
            idx = c["out"][:n].tolist()
            self._cidx = idx
            return [c["tuples"][i] for i in idx]
        g = m.contact_group
        pl = m.contact_plane
        pg = m.plane_group[pl]
        P = x[g] + K.np_quat_rotate(q[g], m.contact_local)
        n = K.np_quat_rotate(q[pg], m.plane_normal[pl])
        o = x[pg] + K.np_quat_rotate(q[pg], m.plane_origin[pl])
        d = np.einsum("ij,ij->i", P - o, n) - m.contact_radius
        vrel = (v[g] + np_cross(w[g], P - x[g])) - (v[pg] + np_cross(w[pg], P - x[pg]))
        margin = self.contact_margin + 2.0 * dt * np.linalg.norm(vrel, axis=1)
        idx = np.nonzero(d < margin)[0]
        self._cidx = [int(i) for i in idx]
        return [(int(g[i]), tuple(map(float, m.contact_local[i])), float(m.contact_radius[i]),
                 int(pg[i]), tuple(map(float, m.plane_origin[pl[i]])),
                 tuple(map(float, m.plane_normal[pl[i]])), float(m.contact_mu[i]))
                for i in idx]

    # ------------------------------------------------------------------ external forces
    def _external(self, inp, X, Q):
        """Per-group world force and torque lists (None when there are none)."""
        if inp is None or (inp.joint_force is None and inp.row_force is None
                           and inp.body_wrench is None):
            return None, None
        m = self.model
        ng = m.ngroup
        F = np.zeros((ng, 3))
        T = np.zeros((ng, 3))
        x = np.asarray(X)
        q = np.asarray(Q)
        if inp.joint_force is not None:
            jf = np.asarray(inp.joint_force, dtype=float)
            for j in np.nonzero(jf)[0]:
                t, g1, g2 = self._joints[j][0], self._joints[j][1], self._joints[j][2]
                aw = np.asarray(quat_rotate(Q[g1], self._joints[j][5]))
                if t == JNT_HINGE:
                    continue  # applied as a joint-space impulse, see _apply_hinge_torques
                elif t == JNT_SLIDE:
                    f = jf[j] * aw
                    F[g2] += f
                    F[g1] -= f
                    T[g1] -= cross(x[g2] - x[g1], f)
                else:
                    raise ValueError("joint_force only supported for hinge and slide joints")
        if inp.row_force is not None and self._rows:
            rf = np.asarray(inp.row_force, dtype=float)
            for i in np.nonzero(rf)[0]:
                ga, gb, ra, rb = self._rows[i][:4]
                ra = np.asarray(quat_rotate(Q[ga], ra))
                rb = np.asarray(quat_rotate(Q[gb], rb))
                d = (x[gb] + rb) - (x[ga] + ra)
                f = rf[i] * d / np.linalg.norm(d)
                F[gb] += f
                T[gb] += cross(rb, f)
                F[ga] -= f
                T[ga] -= cross(ra, f)
        if inp.body_wrench is not None:
            bw = np.asarray(inp.body_wrench, dtype=float)
            g = m.body_group
            com = x[g] + K.np_quat_rotate(q[g], m.body_in_group_pos)
            np.add.at(F, g, bw[:, :3])
            np.add.at(T, g, bw[:, 3:] + np_cross(com - x[g], bw[:, :3]))
        return F.tolist(), T.tolist()

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

    # ------------------------------------------------------------------ position solve
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
        solves the rows together with their articulated response.
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
            out[j] = _soft_limit_target(qv, qd, lo, hi, law[0], law[1], law[2], h)
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
            out[k] = _soft_limit_target(ell, rate, lo, hi, solref, solimp, invw, h)
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
        if sl is not None:
            side, target, at = sl
            q1 = Q[g1]
            x1, x2 = X[g1], X[g2]
            r1w = quat_rotate(q1, r1)
            aw = quat_rotate(q1, a1)
            dist = (x2[0] - x1[0] - r1w[0]) * aw[0] + (x2[1] - x1[1] - r1w[1]) * aw[1] + \
                (x2[2] - x1[2] - r1w[2]) * aw[2]
            sw.joint_lam[j] += solve_positional(X, Q, IM, II, g1, g2, (x2[0] - x1[0], x2[1] - x1[1], x2[2] - x1[2]),
                                              zero, aw, dist - target, at, sw.joint_lam[j],
                                              -_INF if side > 0.0 else 0.0, 0.0 if side > 0.0 else _INF)
        elif limited:
            q1 = Q[g1]
            x1, x2 = X[g1], X[g2]
            r1w = quat_rotate(q1, r1)
            aw = quat_rotate(q1, a1)
            dist = (x2[0] - x1[0] - r1w[0]) * aw[0] + (x2[1] - x1[1] - r1w[1]) * aw[1] + \
                (x2[2] - x1[2] - r1w[2]) * aw[2]
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

    # ------------------------------------------------------------------ velocity solve
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

    # ------------------------------------------------------------------ articulated response transport
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

    # ------------------------------------------------------------------ step
    def step(self, state: XpbdState, dt: float, *, hooks: Optional[SubstepHooks] = None,
             inputs: Optional[SubstepInputs] = None) -> XpbdState:
        """Advance ``state`` (in place) by ``dt``.

        ``hooks.before_substep(k, h, state)`` may return a ``SubstepInputs`` for substep k
        (otherwise ``inputs`` is used for every substep); ``hooks.after_substep(k, h,
        state, forces)`` receives the updated state and the row forces.  The per-substep
        ``SubstepForces`` of the last step are also kept in ``self.last_forces``.
        """
        m = self.model
        h = dt / self.substeps
        x, q, v, w = self._gather(state)
        cands = self._collect_contacts(x, q, v, w, dt)
        if self.compiled:
            flat_contacts = self._flat_contacts(cands)
            if flat_contacts is not None:
                return self._step_compiled(state, dt, hooks, inputs, x, q, v, w, flat_contacts)
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
            inp = inputs
            if before is not None:
                r = before(k, h, state)
                if r is not None:
                    inp = r
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

    def _step_compiled(self, state, dt, hooks, inputs, x, q, v, w, contacts):
        """``step`` with every substep in ``compiled.substep_core`` (same order of operations as the pure loop)."""
        from sim.xpbd.compiled import RowOutputs, SubstepLoads, SubstepOptions, SubstepRows, substep_core, substep_work

        m = self.model
        fm = self._flat
        h = dt / self.substeps
        X, Q, V, W = (np.ascontiguousarray(a, dtype=np.float64) for a in (x, q, v, w))
        ng = X.shape[0]
        nr = len(self._rows)
        nj = m.njnt
        rg, rvec = self._flat_rows()
        before = getattr(hooks, "before_substep", None)
        after = getattr(hooks, "after_substep", None)
        t0 = state.time
        self.last_forces = []
        zeros_r = np.zeros(nr)
        minus_inf, plus_inf = np.full(nr, -np.inf), np.full(nr, np.inf)
        no_mob = np.zeros((0, ng, 6))
        no_gg = np.zeros((ng, 6))
        zeros_g = np.zeros((ng, 3))
        no_tau = np.zeros(nj)
        options = SubstepOptions(self.iterations, self.symmetric, self.linear_damping, self.angular_damping,
                                 self.articulated_contacts, self.soft_contacts, self.pyramid_friction,
                                 self.velocity_sweeps)
        work = substep_work(ng, nj, len(fm.jlim) - nj, len(contacts.group), nr)  # the substeps' work arrays
        Gk = P0 = None
        if self.transport_response and nj:  # compiled.group_jacobian / jacobian_pinv / transport
            from sim.xpbd.compiled import group_jacobian, jacobian_pinv, transport

            Gk = np.zeros((ng, 6, nj))
            P0 = np.zeros((nj, ng * 6))
            if not (group_jacobian(X, Q, fm.IM, fm.jt, fm.jg, fm.jvec, Gk) and jacobian_pinv(Gk, P0)):
                P0 = None
        for k in range(self.substeps):
            inp = inputs
            if before is not None:
                r = before(k, h, state)
                if r is not None:
                    inp = r
            if P0 is not None and k and inp is not None and (inp.row_mobility is not None or inp.group_gravity is not None):
                group_jacobian(X, Q, fm.IM, fm.jt, fm.jg, fm.jvec, Gk)
                mob = None
                if inp.row_mobility is not None:
                    src = _f64(inp.row_mobility)
                    mob = np.empty_like(src)
                    for i in range(src.shape[0]):
                        transport(Gk, P0, src[i], mob[i])
                gg = None
                if inp.group_gravity is not None:
                    gg = _f64(inp.group_gravity).copy()
                    transport(Gk, P0, gg, gg)
                inp = replace(inp, row_mobility=mob, group_gravity=gg)
            if nr and inp is not None and inp.target_length is not None:  # as _row_setup
                tgt = _f64(inp.target_length)
                alpha = zeros_r if inp.compliance is None else np.asarray(inp.compliance, np.float64)
                lo = minus_inf if inp.force_min is None else _f64(np.asarray(inp.force_min, np.float64) * h * h)
                hi = plus_inf if inp.force_max is None else _f64(np.asarray(inp.force_max, np.float64) * h * h)
                act = np.nonzero(np.isfinite(tgt) & np.isfinite(alpha))[0].astype(np.int64)
                at = _f64(alpha / (h * h))
            else:
                act = np.zeros(0, np.int64)
                tgt = at = lo = hi = zeros_r
            use_block = len(act) > 0 and inp.row_mobility is not None
            mob = _f64(inp.row_mobility) if use_block else no_mob
            F, T = self._external(inp, X.tolist(), Q.tolist()) if inp is not None else (None, None)
            F = zeros_g if F is None else np.array(F, dtype=np.float64)
            T = zeros_g if T is None else np.array(T, dtype=np.float64)
            use_tau = inp is not None and inp.joint_force is not None
            tau = _f64(inp.joint_force) if use_tau else no_tau
            use_gg = inp is not None and inp.group_gravity is not None
            gg = _f64(inp.group_gravity) if use_gg else no_gg
            lam = np.zeros(nr)
            ell = np.zeros(nr)
            rate = np.zeros(nr)
            substep_core(X, Q, V, W, fm, SubstepRows(rg, rvec, act, tgt, at, lo, hi, use_block, mob), contacts,
                         SubstepLoads(use_gg, gg, F, T, use_tau, tau), options, float(h), RowOutputs(lam, ell, rate), work)
            if after is not None or nr:
                active = np.zeros(nr, dtype=bool)
                active[act] = True
                if after is not None:
                    self._scatter_compiled(X, Q, V, W, state)
                    state.time = t0 + (k + 1) * h
                forces = SubstepForces(lam / (h * h), lam, ell, rate, active)
                self.last_forces.append(forces)
                if after is not None:
                    after(k, h, state, forces)
        self._scatter_compiled(X, Q, V, W, state)
        state.time = t0 + dt
        state.qpos_hint = m.qpos_qvel(state)[0]
        self.compiled_steps += 1
        return state

    def _row_kinematics(self, x, q, v, w):
        nr = len(self._rows)
        if nr == 0:
            return np.zeros(0), np.zeros(0)
        ga = [r[0] for r in self._rows]
        gb = [r[1] for r in self._rows]
        ra = K.np_quat_rotate(q[ga], np.array([r[2] for r in self._rows]))
        rb = K.np_quat_rotate(q[gb], np.array([r[3] for r in self._rows]))
        d = x[gb] + rb - x[ga] - ra
        ell = np.linalg.norm(d, axis=1)
        n = d / np.where(ell > 0, ell, 1.0)[:, None]
        dv = (v[gb] + np_cross(w[gb], rb)) - (v[ga] + np_cross(w[ga], ra))
        return ell, np.einsum("ij,ij->i", dv, n)


_NO_CONTACTS = tuple(np.zeros(shape, dtype) for shape, dtype in (  # ``_flat_contacts`` of no candidate (shared: zero-size)
    ((0, 2), np.int64), ((0, 4, 3), np.float64), (0, np.float64), (0, np.float64), ((0, 2), np.float64),
    ((0, 5), np.float64), (0, np.int64), (0, np.float64)))


def _f64(a):
    """A C-contiguous, writeable float64 array: the one array type ``compiled.substep_core`` is compiled for."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


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
