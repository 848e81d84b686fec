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

from dataclasses import dataclass, replace
from typing import Optional, Protocol, Sequence

import numpy as np

from sim.xpbd.model import JNT_FREE, JNT_HINGE, JNT_SLIDE, XpbdModel, XpbdState
from sim.xpbd.quat import np_cross, np_quat_rotate

__all__ = ["LengthConstraint", "SubstepInputs", "SubstepForces", "SubstepHooks", "SolverXPBD", "XpbdOptions"]


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
    velocity_sweeps: int = 4
    """Projected Gauss-Seidel sweeps of the contact velocity pass [-]."""
    symmetric: bool = True
    """Forward + backward Gauss-Seidel per iteration."""
    soft_contacts: bool = True
    """MuJoCo's soft-contact law (else the rigid contacts of [RB])."""
    pyramid_friction: bool = True
    """Soft pyramidal friction rows (MuJoCo's default cone) on soft contacts."""
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
                   rows are solved together (``compiled._solve_rows_block``): W = ∂C/∂λ is formed from
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


def substep_inputs(before, k: int, h: float, state, inputs):
    """The inputs of substep ``k`` (of ``h`` [s]): what the ``before_substep`` hook ``before`` returns for it, or the
    step's ``inputs`` when there is no hook or it returns ``None``."""
    if before is not None:
        given = before(k, h, state)
        if given is not None:
            return given
    return inputs


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
      (see ``compiled.substep_core``); it costs about 2× per iteration.  With loop closures (equalities) the
      backward pass ends with the length rows once more: the equalities and joints solved after the rows move
      their ends, and a row's law (a cylinder's c + s·v⁺, whose friction slope makes it stiff) then no longer
      holds for the motion the substep realises (without this pass a loop held with seal friction creeps and
      its pressure rises 10 % in 1.5 s, ``tests/test_loop_closure.py``).
    * Pin/connect attachments are projected with the 3×3 block form of the XPBD update
      (``compiled._attach``: Δλ = −K⁻¹·d with K the 3×3 point mobility of the pair) rather than the
      scalar projection along the error direction: less pin drift (double pendulum at 60 Hz × 20:
      4.0e-5 m against 5.5e-5 m; ``tests/test_xpbd_rigid.py``).
    * ``soft_limits`` (default True): joint limits (hinge, slide) and the limits of straight two-site
      spatial tendons follow MuJoCo's soft-constraint law of the MJCF (solreflimit/solimplimit,
      R = (1 − d)/d·dof_invweight0 or tendon_invweight0; ``compiled._contact_law``), taken over the substep as
      MuJoCo takes it over its step, as the soft contacts are (r* = r + h·ṙ − h²·(b·ṙ + k·d·r); ``compiled._soft_limit_target``,
      ``_tendon_limit_targets``): a limit
      acts in a substep that starts beyond it, as a one-sided compliant row.  A hinge beyond its soft
      limit is solved as one 6-row block (pin and axis rigid, the angle compliant,
      ``compiled._hinge_soft_limit``); when a tendon limit is active too (the boom's cylinder end stop,
      where MuJoCo activates the joint and the tendon limit together) all active limits of a hinge/slide
      tree are solved as one articulated block (``compiled._solve_limits_block``: W = J·M⁻¹·Jᵀ + α̃, active set),
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
      group masses and inertias at the predicted pose, ``compiled.articulated_inverse``).  With the
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
      ``compiled.transport``), as the response of the same joint-space motion Δq = M⁻¹·Jᵀ.  Without it
      a 60 Hz frame applies the row and gravity responses in directions up to one frame old: a
      swinging machine (≈ 1 rad/s, 17 mrad per frame) then gets cylinder and gravity
      corrections tilted out of its moving boom plane, and its pressures converge with the
      substeps to a frame-rate-dependent limit (excavator dig, 7–20 s: 0.1 s-averaged pressure
      error 4.6 → 10 % of relief from × 40 to × 320 substeps at 60 Hz, 3.6 % at 19.2 kHz × 1).
      M⁻¹ and the rows' moment arms stay those of the step's start (they do not depend on the
      swing angle).  Other joint types or a singular Jacobian: no transport.  Off by default:
      at 60 Hz × 10–40 the frame-old responses happen to offset part of backward Euler's
      numerical damping (swing phase 14 % / 4.6 % with them, 24 % / 7.7 % without), so the
      coarse settings' errors grow while the fine ones' shrink; the plant's compiled block
      selects the same behaviour from ``transport_response`` (``pbd_block.block(transport=...)``).
    * Every substep runs in ``compiled.substep_core`` (numba, ``cache=True``, one signature) on flat
      arrays; the hooks are still called per substep.  The per-step group gather and contact-candidate
      test are compiled too (``compiled.gather``, ``compiled.contact_candidates``).  Every contact kind
      (soft pyramidal, soft normal with Coulomb friction on an elliptic cone or condim 1, rigid) runs
      compiled.  ``NUMBA_DISABLE_JIT=1`` runs the same kernels as plain Python (for debugging).  An
      independent pure-Python substep in the tests (``tests/reference/xpbd_substep.py``) is the oracle:
      both agree to round-off (``tests/test_pbd_compiled.py``).

    Joint damping (MJCF ``damping``) is applied implicitly at the velocity level:
    rate ← rate/(1 + b h w), w the generalized inverse mass of the joint pair.
    Contacts (``soft_contacts``, default True) are compliant in the normal direction with
    MuJoCo's soft-contact law of the geom pair (solref/solimp/condim/cone from the compiled
    MjModel, effective mass from its ``body_invweight0``; ``compiled._contact_law``,
    ``compiled._contact_targets``): a resting body sinks by the same static penetration as in
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
        self.options = o
        self.substeps = int(o.substeps)
        self.iterations = int(o.iterations)
        self.linear_damping = float(o.linear_damping)
        self.angular_damping = float(o.angular_damping)
        self.contact_margin = float(o.contact_margin)
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
        self._flat = self._flat_model()  # the model on flat arrays for ``compiled.substep_core``

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

    def _scatter(self, X, Q, V, W, state):
        """Write the group state X, Q, V, W back to ``state``'s bodies (``compiled.scatter``)."""
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
        c = self._contact_arrays()  # rows of the per-contact arrays made once
        idx = np.array(self._cidx, dtype=np.int64)
        return ContactRows(c["cg"][idx], c["cvec"][idx], c["crad"][idx], c["mu"][idx], c["solref"][idx],
                           c["solimp"][idx], c["condim"][idx], c["tran"][idx])

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
        """The rigid groups' state (X, Q, V, W) at their centres of mass from the bodies of ``state``
        (``compiled.gather``); group 0 (static) at rest at the origin."""
        from sim.xpbd.compiled import gather

        a = self.model._nb_arrays()
        ng = len(a["root"])
        x, q, v, w = np.empty((ng, 3)), np.empty((ng, 4)), np.empty((ng, 3)), np.empty((ng, 3))
        gather(_f64(state.x), _f64(state.q), _f64(state.v), _f64(state.w), a["root"], a["from_root_quat"],
               a["from_root_pos"], x, q, v, w)
        return x, q, v, w

    # ------------------------------------------------------------------ contacts
    def _collect_contacts(self, x, q, v, w, dt):
        """Contact candidates for the whole step ([RB] Algorithm 2, CollectCollisionPairs)."""
        m = self.model
        self._cidx = []
        if len(m.contact_group) == 0:
            return []
        from sim.xpbd.compiled import contact_candidates

        c = self._contact_arrays()
        n = contact_candidates(_f64(x), _f64(q), _f64(v), _f64(w), c["group"], c["plane"], c["plane_group"],
                               c["local"], c["radius"], c["plane_origin"], c["plane_normal"],
                               self.contact_margin, float(dt), c["out"])
        idx = c["out"][:n].tolist()
        self._cidx = idx
        return [c["tuples"][i] for i in idx]

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
                aw = np_quat_rotate(q[g1], np.asarray(self._joints[j][5]))
                if t == JNT_HINGE:
                    continue  # applied as a joint-space impulse, the compiled substep's hinge torque impulses
                elif t == JNT_SLIDE:
                    f = jf[j] * aw
                    F[g2] += f
                    F[g1] -= f
                    T[g1] -= np_cross(x[g2] - x[g1], f)
                else:
                    raise ValueError("joint_force only supported for hinge and slide joints")
        if inp.row_force is not None and self._rows:
            rf = np.asarray(inp.row_force, dtype=float)
            for i in np.nonzero(rf)[0]:
                ga, gb, ra, rb = self._rows[i][:4]
                ra = np_quat_rotate(q[ga], np.asarray(ra))
                rb = np_quat_rotate(q[gb], np.asarray(rb))
                d = (x[gb] + rb) - (x[ga] + ra)
                f = rf[i] * d / np.linalg.norm(d)
                F[gb] += f
                T[gb] += np_cross(rb, f)
                F[ga] -= f
                T[ga] -= np_cross(ra, f)
        if inp.body_wrench is not None:
            bw = np.asarray(inp.body_wrench, dtype=float)
            g = m.body_group
            com = x[g] + np_quat_rotate(q[g], m.body_in_group_pos)
            np.add.at(F, g, bw[:, :3])
            np.add.at(T, g, bw[:, 3:] + np_cross(com - x[g], bw[:, :3]))
        return F.tolist(), T.tolist()

    # ------------------------------------------------------------------ step
    def step(self, state: XpbdState, dt: float, *, hooks: Optional[SubstepHooks] = None,
             inputs: Optional[SubstepInputs] = None) -> XpbdState:
        """Advance ``state`` (in place) by ``dt``.

        ``hooks.before_substep(k, h, state)`` may return a ``SubstepInputs`` for substep k
        (otherwise ``inputs`` is used for every substep); ``hooks.after_substep(k, h,
        state, forces)`` receives the updated state and the row forces.  The per-substep
        ``SubstepForces`` of the last step are also kept in ``self.last_forces``.
        """
        from sim.xpbd.compiled import (RowOutputs, SubstepLoads, SubstepOptions, SubstepRows, single_island, substep_core,
                                       substep_work)

        x, q, v, w = self._gather(state)
        contacts = self._flat_contacts(self._collect_contacts(x, q, v, w, dt))
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
        # a row mobility given from outside: no structure assumed, the rows' block solved whole
        whole = single_island(m.nbody, ng, nj, nr, 0)
        Gk = P0 = None
        if self.transport_response and nj:  # compiled.group_jacobian / jacobian_pinv / transport
            from sim.xpbd.compiled import group_jacobian, jacobian_pinv, transport

            Gk = np.zeros((ng, 6, nj))
            P0 = np.zeros((nj, ng * 6))
            if not (group_jacobian(X, Q, fm.IM, fm.jt, fm.jg, fm.jvec, Gk) and jacobian_pinv(Gk, P0)):
                P0 = None
        for k in range(self.substeps):
            inp = substep_inputs(before, k, h, state, inputs)
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
            F, T = self._external(inp, X, Q) if inp is not None else (None, None)
            F = zeros_g if F is None else np.array(F, dtype=np.float64)
            T = zeros_g if T is None else np.array(T, dtype=np.float64)
            use_tau = inp is not None and inp.joint_force is not None
            tau = _f64(inp.joint_force) if use_tau else no_tau
            use_gg = inp is not None and inp.group_gravity is not None
            gg = _f64(inp.group_gravity) if use_gg else no_gg
            lam = np.zeros(nr)
            ell = np.zeros(nr)
            rate = np.zeros(nr)
            substep_core(X, Q, V, W, fm, SubstepRows(rg, rvec, act, tgt, at, lo, hi, use_block, mob, whole), contacts,
                         SubstepLoads(use_gg, gg, F, T, use_tau, tau), options, float(h), RowOutputs(lam, ell, rate), work)
            if after is not None or nr:
                active = np.zeros(nr, dtype=bool)
                active[act] = True
                if after is not None:
                    self._scatter(X, Q, V, W, state)
                    state.time = t0 + (k + 1) * h
                forces = SubstepForces(lam / (h * h), lam, ell, rate, active)
                self.last_forces.append(forces)
                if after is not None:
                    after(k, h, state, forces)
        self._scatter(X, Q, V, W, state)
        state.time = t0 + dt
        state.qpos_hint = m.qpos_qvel(state)[0]
        return state


_NO_CONTACTS = tuple(np.zeros(shape, dtype) for shape, dtype in (  # ``_flat_contacts`` of no candidate (shared: zero-size)
    ((0, 2), np.int64), ((0, 4, 3), np.float64), (0, np.float64), (0, np.float64), ((0, 2), np.float64),
    ((0, 5), np.float64), (0, np.int64), (0, np.float64)))


def _f64(a):
    """A C-contiguous, writeable float64 array: the one array type ``compiled.substep_core`` is compiled for."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


