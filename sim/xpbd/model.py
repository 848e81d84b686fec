"""Immutable XPBD scene (``XpbdModel``) and time-varying state (``XpbdState``).

The scene is read from a compiled ``mujoco.MjModel``; no MuJoCo dynamics (mj_step /
mj_forward / mj_inverse) is ever called.  Forward kinematics from qpos/qvel is done here
in numpy following MuJoCo's conventions (``mj_kinematics``): a body frame is its parent's
frame composed with (body_pos, body_quat), then its joint (hinge: rotation by qpos−qpos0
about jnt_axis through jnt_pos; slide: translation by qpos−qpos0 along jnt_axis; ball:
rotation by the qpos quaternion about jnt_pos; free: absolute pose).

Rigid groups
------------
Bodies welded to their parent (no joint) are merged with it into one rigid *group*
(MuJoCo's ``body_weldid``): composite mass, centre of mass and inertia tensor,
re-diagonalized.  The solver integrates groups; group 0 (the world plus everything welded
to it, and mocap bodies) is static with infinite mass.  ``XpbdState`` is nevertheless
indexed by MuJoCo body id (row 0 = world).

State convention (per MuJoCo body b, world frame, SI units)
----------------------------------------------------------
* ``x[b]``  centre of mass [m]                (MuJoCo ``xipos``)
* ``q[b]``  orientation of the inertial frame (w, x, y, z)  (MuJoCo ``ximat``, i.e.
  body frame ⊗ ``body_iquat``)
* ``v[b]``  linear velocity of the centre of mass [m/s]
* ``w[b]``  angular velocity [rad/s], world frame
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Optional

import mujoco
import numpy as np

from sim.xpbd.quat import np_cross, np_quat_conj, np_quat_mul, np_quat_rotate

__all__ = ["XpbdModel", "XpbdState", "JNT_FREE", "JNT_BALL", "JNT_SLIDE", "JNT_HINGE"]

JNT_FREE, JNT_BALL, JNT_SLIDE, JNT_HINGE = 0, 1, 2, 3
EQ_CONNECT, EQ_WELD = 0, 1

_GEOM_PLANE = int(mujoco.mjtGeom.mjGEOM_PLANE)
_GEOM_SPHERE = int(mujoco.mjtGeom.mjGEOM_SPHERE)
_GEOM_CAPSULE = int(mujoco.mjtGeom.mjGEOM_CAPSULE)
_GEOM_BOX = int(mujoco.mjtGeom.mjGEOM_BOX)
_CONTACT_GEOMS = (_GEOM_SPHERE, _GEOM_CAPSULE, _GEOM_BOX)

_IDQ = np.array([1.0, 0.0, 0.0, 0.0])


# ---------------------------------------------------------------------------
# pose helpers (single poses, numpy)


def _rot(q, v):
    """R(q)·v of one quaternion and vector (``quat.np_quat_rotate``)."""
    return np_quat_rotate(np.asarray(q, dtype=float), np.asarray(v, dtype=float))


def _qmul(a, b):
    """The quaternion product a ⊗ b (``quat.np_quat_mul``)."""
    return np_quat_mul(np.asarray(a, dtype=float), np.asarray(b, dtype=float))


def _compose(pa, qa, pb, qb):
    """Pose a ∘ pose b."""
    return np.asarray(pa) + _rot(qa, pb), _qmul(qa, qb)


def _inverse(p, q):
    qc = np_quat_conj(q)
    return -_rot(qc, p), qc


def _mat2quat(mat):
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(mat, dtype=float).reshape(9))
    return q / np.linalg.norm(q)


def _f64(a):
    """``a`` as a C-contiguous float64 array (no copy when it already is one)."""
    return np.ascontiguousarray(a, dtype=np.float64)


def _frozen(a, dtype=float):
    a = np.array(a, dtype=dtype)
    a.setflags(write=False)
    return a


# ---------------------------------------------------------------------------


@dataclass
class XpbdState:
    """Time-varying rigid-body state, indexed by MuJoCo body id (row 0 = world).

    See the module docstring for frames and units.  Rows of bodies welded to a parent
    are kept consistent by the solver; when a state is edited by hand only the row of
    each rigid group's root body (``XpbdModel.group_root``) is read.  ``qpos_hint`` holds
    the last known generalized coordinates; it is used only to unwrap hinge angles
    (multi-turn) when reading back ``qpos`` and is refreshed by ``SolverXPBD.step``.
    """

    x: np.ndarray
    q: np.ndarray
    v: np.ndarray
    w: np.ndarray
    qpos_hint: np.ndarray
    time: float = 0.0

    def copy(self) -> "XpbdState":
        return XpbdState(self.x.copy(), self.q.copy(), self.v.copy(), self.w.copy(),
                         self.qpos_hint.copy(), self.time)


@dataclass(frozen=True, eq=False)
class XpbdModel:
    """Immutable XPBD scene built from a compiled MuJoCo model (``from_mjmodel``).

    Array fields are read-only numpy arrays.  Frames: "G frame" = principal inertia frame
    of a rigid group (origin at its centre of mass); static group 0 uses the world frame.
    """

    # sizes
    nbody: int
    ngroup: int
    njnt: int
    nq: int
    nv: int
    nsite: int
    # names
    body_names: tuple
    jnt_names: tuple
    site_names: tuple
    tendon_names: tuple
    # bodies (MuJoCo body ids)
    body_parent: np.ndarray
    body_group: np.ndarray
    body_mass: np.ndarray
    body_pos: np.ndarray          # body frame in parent body frame
    body_quat: np.ndarray
    body_ipos: np.ndarray         # inertial frame in body frame
    body_iquat: np.ndarray
    body_in_group_pos: np.ndarray  # inertial frame of body in its G frame
    body_in_group_quat: np.ndarray
    body_frame_in_group_pos: np.ndarray  # body frame in G frame
    body_frame_in_group_quat: np.ndarray
    # groups
    group_root: np.ndarray
    group_dynamic: np.ndarray
    group_mass: np.ndarray
    group_inertia: np.ndarray      # principal moments
    group_inv_mass: np.ndarray     # 0 for static groups
    group_inv_inertia: np.ndarray  # 0 for static groups
    group_from_root_pos: np.ndarray  # G frame in the root body's inertial frame
    group_from_root_quat: np.ndarray
    # joints (MuJoCo joint ids)
    jnt_type: np.ndarray
    jnt_body: np.ndarray
    jnt_g1: np.ndarray             # parent group
    jnt_g2: np.ndarray             # child group
    jnt_r1: np.ndarray             # anchor in G1 frame
    jnt_r2: np.ndarray             # anchor in G2 frame
    jnt_a1: np.ndarray             # axis in G1 frame
    jnt_a2: np.ndarray             # axis in G2 frame
    jnt_qoff: np.ndarray           # q_G2 = q_G1 ⊗ qoff at the zero configuration
    jnt_limited: np.ndarray
    jnt_lo: np.ndarray             # range − qpos0 (hinge/slide)
    jnt_hi: np.ndarray
    jnt_range: np.ndarray
    jnt_damping: np.ndarray
    jnt_qposadr: np.ndarray
    jnt_dofadr: np.ndarray
    jnt_pos: np.ndarray            # anchor in body frame (MuJoCo)
    jnt_axis: np.ndarray           # axis in body frame (MuJoCo)
    qpos0: np.ndarray
    # equalities (active connect / weld only)
    eq_type: np.ndarray
    eq_g1: np.ndarray
    eq_g2: np.ndarray
    eq_r1: np.ndarray
    eq_r2: np.ndarray
    eq_qoff: np.ndarray
    # sites
    site_body: np.ndarray
    site_group: np.ndarray
    site_pos_inertial: np.ndarray  # in the body's inertial frame
    site_pos_group: np.ndarray     # in the G frame
    # tendons: tuple of tuples of site ids (spatial tendons made of sites only; else ())
    tendon_sites: tuple
    # contacts: points of sphere/capsule/box geoms against planes
    contact_group: np.ndarray      # group of the point
    contact_local: np.ndarray      # point (sphere centre / box corner) in its G frame
    contact_radius: np.ndarray
    contact_plane: np.ndarray      # index into plane_*
    contact_mu: np.ndarray
    contact_geom: np.ndarray       # MuJoCo geom id of the point
    plane_group: np.ndarray
    plane_origin: np.ndarray       # in the plane group's G frame
    plane_normal: np.ndarray
    plane_geom: np.ndarray
    # physics options
    gravity: np.ndarray
    unsupported: tuple = field(default=())
    # MuJoCo soft-contact parameters per contact point (see ``contact_soft_params``);
    # None = rigid contacts (a model built without them)
    contact_solref: Optional[np.ndarray] = None   # (nc, 2) timeconst [s], dampratio [-] (or −stiffness, −damping)
    contact_solimp: Optional[np.ndarray] = None   # (nc, 5) dmin, dmax, width [m], midpoint, power
    contact_condim: Optional[np.ndarray] = None   # (nc,) 1, 3, 4 or 6
    contact_tran: Optional[np.ndarray] = None     # (nc,) MuJoCo's diagApprox translation part Σ body_invweight0 [1/kg]
    contact_cone: int = 0                         # mjCONE_PYRAMIDAL (0) or mjCONE_ELLIPTIC (1)
    contact_impratio: float = 1.0
    contact_timestep: float = 0.0                 # MJCF timestep [s] (MuJoCo's timeconst ≥ 2·timestep safety)
    # MuJoCo soft joint limits (``XpbdOptions(soft_limits=True)``): per joint solref/solimp of the limit and
    # MuJoCo's diagonal approximation of its effective inverse inertia (dof_invweight0 [1/(kg·m²)] for a
    # hinge, [1/kg] for a slide); None = rigid limits (a model built without them)
    # rotor inertia [kg·m²] of each joint as modelled (MuJoCo's dof_armature on hinges whose parent is static, in
    # their child group's inertia; 0 elsewhere); the plant's joint-space mass matrix adds it to its diagonal
    jnt_armature: Optional[np.ndarray] = None     # (nj,)
    jnt_solref: Optional[np.ndarray] = None       # (nj, 2) timeconst [s], dampratio [-] (or −stiffness, −damping)
    jnt_solimp: Optional[np.ndarray] = None       # (nj, 5) dmin, dmax, width [rad or m], midpoint, power
    jnt_invweight: Optional[np.ndarray] = None    # (nj,) dof_invweight0 of the joint's (first) dof
    # limited spatial tendons of two sites (MuJoCo's tendon limits): tendon ids, range [m], solref/solimp of the
    # limit and tendon_invweight0 [1/kg]
    tendon_limit_ids: tuple = field(default=())
    tendon_limit_range: Optional[np.ndarray] = None    # (ntl, 2) [m]
    tendon_limit_solref: Optional[np.ndarray] = None   # (ntl, 2)
    tendon_limit_solimp: Optional[np.ndarray] = None   # (ntl, 5), width in m
    tendon_limit_invweight: Optional[np.ndarray] = None  # (ntl,) [1/kg]

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_mjmodel(cls, m: mujoco.MjModel, *, warn: bool = True) -> "XpbdModel":
        notes: list[str] = []
        nbody, njnt = m.nbody, m.njnt
        parent = np.array(m.body_parentid, dtype=int)
        weld = np.array(m.body_weldid, dtype=int)
        dis = int(m.opt.disableflags)

        def disabled(name):
            bit = getattr(mujoco.mjtDisableBit, name, None)
            return bit is not None and bool(dis & int(bit))

        # ---- groups
        mocap = np.array(m.body_mocapid) >= 0
        roots = []
        for b in range(nbody):
            if weld[b] == b and b != 0 and not mocap[b]:
                roots.append(b)
        group_of_root = {0: 0}
        for i, r in enumerate(roots):
            group_of_root[r] = i + 1
        body_group = np.zeros(nbody, dtype=int)
        for b in range(1, nbody):
            body_group[b] = 0 if mocap[b] else group_of_root.get(weld[b], 0)
            if mocap[b]:
                notes.append(f"mocap body {b} treated as static at its model pose")
        ngroup = len(roots) + 1

        # world poses of all body frames at qpos0 (static bodies never move)
        xpos0, xquat0 = _fk_positions(m, np.array(m.qpos0))

        T_GB_pos = np.zeros((nbody, 3))
        T_GB_quat = np.tile(_IDQ, (nbody, 1))
        T_GI_pos = np.zeros((nbody, 3))
        T_GI_quat = np.tile(_IDQ, (nbody, 1))
        g_mass = np.zeros(ngroup)
        g_inertia = np.zeros((ngroup, 3))
        g_from_root_pos = np.zeros((ngroup, 3))
        g_from_root_quat = np.tile(_IDQ, (ngroup, 1))
        g_root = np.array([0] + roots, dtype=int)
        ipos = np.array(m.body_ipos)
        iquat = np.array(m.body_iquat)

        for b in range(nbody):
            if body_group[b] == 0:
                T_GB_pos[b], T_GB_quat[b] = xpos0[b], xquat0[b]
        # joint armature (MuJoCo's rotor inertia on the dof, dof_armature [kg·m²]) on a hinge whose parent is
        # static: the child group turns about the fixed axis at the joint rate, so the rotor is the rank-one
        # inertia armature·a·aᵀ of that group (exact); on other joints it is ignored (a note)
        armature = np.zeros(njnt)
        rotor = {}  # group root body -> rotor inertia (3×3) [kg·m²] in the root body's frame
        for j in range(njnt):
            b, arm = int(m.jnt_bodyid[j]), float(m.dof_armature[m.jnt_dofadr[j]])
            if arm > 0 and m.jnt_type[j] == JNT_HINGE and body_group[parent[b]] == 0 and body_group[b] != 0 and weld[b] == b:
                a = np.array(m.jnt_axis[j], dtype=float)
                a /= np.linalg.norm(a)
                rotor[b] = rotor.get(b, np.zeros((3, 3))) + arm * np.outer(a, a)
                armature[j] = arm
        for gi, r in enumerate(roots, start=1):
            members = [b for b in range(nbody) if body_group[b] == gi]
            # body frames relative to the root body frame
            rel = {r: (np.zeros(3), _IDQ.copy())}
            for b in members:
                if b == r:
                    continue
                pp, pq = rel[parent[b]]
                rel[b] = _compose(pp, pq, m.body_pos[b], m.body_quat[b])
            if len(members) == 1 and r not in rotor:
                if m.body_mass[r] <= 0 or np.any(m.body_inertia[r] <= 0):
                    raise ValueError(f"moving body {m.body(r).name!r} has no mass/inertia")
                Gp, Gq = ipos[r].copy(), iquat[r].copy()
                M, Id = float(m.body_mass[r]), np.array(m.body_inertia[r])
            else:
                M = float(sum(m.body_mass[b] for b in members))
                if M <= 0:
                    raise ValueError(f"rigid group rooted at body {m.body(r).name or r!r} has no mass")
                coms, rots = {}, {}
                for b in members:
                    coms[b], qI = _compose(rel[b][0], rel[b][1], ipos[b], iquat[b])
                    R = np.zeros(9)
                    mujoco.mju_quat2Mat(R, qI)
                    rots[b] = R.reshape(3, 3)
                c = sum(m.body_mass[b] * coms[b] for b in members) / M
                Ifull = np.zeros((3, 3))
                for b in members:
                    d = coms[b] - c
                    Ifull += rots[b] @ np.diag(m.body_inertia[b]) @ rots[b].T
                    Ifull += m.body_mass[b] * (d @ d * np.eye(3) - np.outer(d, d))
                Ifull += rotor.get(r, 0.0)
                evals, evecs = np.linalg.eigh(Ifull)
                if np.linalg.det(evecs) < 0:
                    evecs[:, 2] *= -1.0
                if np.any(evals <= 0):
                    raise ValueError(f"rigid group rooted at body {m.body(r).name or r!r} has singular inertia")
                Gp, Gq = c, _mat2quat(evecs)
                Id = evals
            g_mass[gi] = M
            g_inertia[gi] = Id
            iGp, iGq = _inverse(Gp, Gq)          # root body frame in G
            for b in members:
                T_GB_pos[b], T_GB_quat[b] = _compose(iGp, iGq, rel[b][0], rel[b][1])
            # G in the root's inertial frame: inv(I_r in B_r) ∘ (G in B_r)
            ip, iq = _inverse(ipos[r], iquat[r])
            g_from_root_pos[gi], g_from_root_quat[gi] = _compose(ip, iq, Gp, Gq)
        for b in range(nbody):
            T_GI_pos[b], T_GI_quat[b] = _compose(T_GB_pos[b], T_GB_quat[b], ipos[b], iquat[b])

        dyn = np.arange(ngroup) > 0
        inv_mass = np.where(dyn, 1.0 / np.where(dyn, g_mass, 1.0), 0.0)
        inv_inertia = np.where(dyn[:, None], 1.0 / np.where(dyn[:, None], g_inertia, 1.0), 0.0)

        def point_in_group(b, p):
            return T_GB_pos[b] + _rot(T_GB_quat[b], p)

        # ---- joints
        jnt_type = np.array(m.jnt_type, dtype=int)
        jb = np.array(m.jnt_bodyid, dtype=int)
        counts = np.bincount(jb, minlength=nbody)
        if np.any(counts > 1):
            bad = [m.body(b).name or str(b) for b in np.nonzero(counts > 1)[0]]
            raise NotImplementedError(f"bodies with more than one joint are not supported: {bad}")
        J = {k: [] for k in ("g1", "g2", "r1", "r2", "a1", "a2", "qoff", "lo", "hi")}
        limited = np.array(m.jnt_limited, dtype=bool) & (not disabled("mjDSBL_LIMIT"))
        damping = np.zeros(njnt)
        qpos0 = np.array(m.qpos0)
        for j in range(njnt):
            b = jb[j]
            p = parent[b]
            g1, g2 = body_group[p], body_group[b]
            zp, zq = _compose(T_GB_pos[p], T_GB_quat[p], m.body_pos[b], m.body_quat[b])
            ip, iq = _inverse(T_GB_pos[b], T_GB_quat[b])
            offp, offq = _compose(zp, zq, ip, iq)       # G2 in G1 at zero configuration
            t = jnt_type[j]
            if t == JNT_SLIDE:
                r2 = np.zeros(3)
            else:
                r2 = point_in_group(b, m.jnt_pos[j])
            r1 = offp + _rot(offq, r2)
            a2 = _rot(T_GB_quat[b], m.jnt_axis[j])
            a1 = _rot(offq, a2)
            lo = hi = 0.0
            if t in (JNT_HINGE, JNT_SLIDE):
                adr = m.jnt_qposadr[j]
                lo = m.jnt_range[j, 0] - qpos0[adr]
                hi = m.jnt_range[j, 1] - qpos0[adr]
                if not disabled("mjDSBL_DAMPER"):
                    damping[j] = m.dof_damping[m.jnt_dofadr[j]]
                if t == JNT_HINGE and limited[j] and (lo <= -math.pi or hi >= math.pi):
                    notes.append(f"hinge {j}: limits beyond ±π about qpos0 are not enforced correctly")
            elif t == JNT_BALL:
                if limited[j]:
                    notes.append(f"ball joint {j}: limits ignored")
                    limited[j] = False
                if not disabled("mjDSBL_DAMPER"):
                    damping[j] = m.dof_damping[m.jnt_dofadr[j]]
            elif t == JNT_FREE:
                if g1 != 0:
                    raise NotImplementedError(f"free joint {m.joint(j).name or j!r}: free joints must be on children of the world")
                limited[j] = False
                if np.any(m.dof_damping[m.jnt_dofadr[j]:m.jnt_dofadr[j] + 6] != 0):
                    notes.append(f"free joint {j}: damping ignored")
            for key, val in zip(J, (g1, g2, r1, r2, a1, a2, offq, lo, hi)):
                J[key].append(val)
            dofs = range(m.jnt_dofadr[j], m.jnt_dofadr[j] + {0: 6, 1: 3, 2: 1, 3: 1}[t])
            if any(m.dof_armature[d] != 0 for d in dofs) and armature[j] == 0:
                notes.append(f"joint {j}: armature ignored (modelled on hinges whose parent is static)")
            if any(m.dof_frictionloss[d] != 0 for d in dofs):
                notes.append(f"joint {j}: frictionloss ignored")
            if m.jnt_stiffness[j] != 0:
                notes.append(f"joint {j}: stiffness ignored")

        # ---- equalities
        E = {k: [] for k in ("type", "g1", "g2", "r1", "r2", "qoff")}
        if m.neq and not disabled("mjDSBL_EQUALITY"):
            for e in range(m.neq):
                if not m.eq_active0[e]:
                    notes.append(f"equality {e} inactive at load: ignored")
                    continue
                et, ot = int(m.eq_type[e]), int(m.eq_objtype[e])
                o1, o2 = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
                data = np.array(m.eq_data[e])
                site = ot == int(mujoco.mjtObj.mjOBJ_SITE)
                if et == int(mujoco.mjtEq.mjEQ_CONNECT):
                    if site:
                        b1, b2 = m.site_bodyid[o1], m.site_bodyid[o2]
                        r1 = point_in_group(b1, m.site_pos[o1])
                        r2 = point_in_group(b2, m.site_pos[o2])
                    else:
                        b1, b2 = o1, o2
                        r1 = point_in_group(b1, data[0:3])
                        r2 = point_in_group(b2, data[3:6])
                    qoff = _IDQ.copy()
                    kind = EQ_CONNECT
                elif et == int(mujoco.mjtEq.mjEQ_WELD) and not site:
                    b1, b2 = o1, o2
                    r2 = point_in_group(b2, data[0:3])
                    r1 = point_in_group(b1, data[3:6])
                    qoff = _qmul(_qmul(T_GB_quat[b1], data[6:10] / np.linalg.norm(data[6:10])),
                                 np_quat_conj(T_GB_quat[b2]))
                    kind = EQ_WELD
                else:
                    notes.append(f"equality {e} of type {et} not supported: ignored")
                    continue
                for key, val in zip(E, (kind, body_group[b1], body_group[b2], r1, r2, qoff)):
                    E[key].append(val)

        # ---- sites
        nsite = m.nsite
        sb = np.array(m.site_bodyid, dtype=int)
        s_inert = np.zeros((nsite, 3))
        s_group = np.zeros((nsite, 3))
        for s in range(nsite):
            b = sb[s]
            s_inert[s] = _rot(np_quat_conj(iquat[b]), m.site_pos[s] - ipos[b])
            s_group[s] = point_in_group(b, m.site_pos[s])

        # ---- tendons
        tsites = []
        for t in range(m.ntendon):
            adr, num = m.tendon_adr[t], m.tendon_num[t]
            types = m.wrap_type[adr:adr + num]
            if np.all(types == int(mujoco.mjtWrap.mjWRAP_SITE)):
                tsites.append(tuple(int(i) for i in m.wrap_objid[adr:adr + num]))
            else:
                tsites.append(())
        # limited tendons of two sites on different rigid groups (soft length limits); others are noted
        tl_ids = []
        tendon_limited = np.array(m.tendon_limited, dtype=bool) & (not disabled("mjDSBL_LIMIT"))
        for t in range(m.ntendon):
            if not tendon_limited[t]:
                continue
            ts = tsites[t]
            if len(ts) == 2 and body_group[sb[ts[0]]] != body_group[sb[ts[1]]]:
                tl_ids.append(t)
            else:
                notes.append(f"tendon {t}: limit ignored (only straight two-site tendons between rigid groups)")

        # ---- contacts (sphere / capsule / box against planes)
        C = {k: [] for k in ("group", "local", "radius", "plane", "mu", "geom", "solref", "solimp", "condim", "tran")}
        P = {k: [] for k in ("group", "origin", "normal", "geom")}
        if not disabled("mjDSBL_CONTACT"):
            pairs = _contact_pairs(m, body_group, weld, parent, disabled("mjDSBL_FILTERPARENT"), notes)
            plane_index = {}
            for gp, gd, mu, solref, solimp, condim in pairs:
                bp, bd = m.geom_bodyid[gp], m.geom_bodyid[gd]
                tran = float(m.body_invweight0[bp, 0] + m.body_invweight0[bd, 0])
                if body_group[bp] == body_group[bd] or (body_group[bp] == 0 and body_group[bd] == 0):
                    continue
                if gp not in plane_index:
                    plane_index[gp] = len(P["geom"])
                    o = point_in_group(bp, m.geom_pos[gp])
                    nrm = _rot(_qmul(T_GB_quat[bp], m.geom_quat[gp]), [0.0, 0.0, 1.0])
                    for key, val in zip(P, (body_group[bp], o, nrm, gp)):
                        P[key].append(val)
                gq = m.geom_quat[gd]
                size = m.geom_size[gd]
                t = m.geom_type[gd]
                if t == _GEOM_SPHERE:
                    pts, rad = [np.zeros(3)], size[0]
                elif t == _GEOM_CAPSULE:
                    pts, rad = [np.array([0, 0, size[1]]), np.array([0, 0, -size[1]])], size[0]
                else:
                    pts = [np.array([sx, sy, sz]) * size for sx in (-1, 1) for sy in (-1, 1)
                           for sz in (-1, 1)]
                    rad = 0.0
                for pl in pts:
                    pb = m.geom_pos[gd] + _rot(gq, pl)
                    for key, val in zip(C, (body_group[bd], point_in_group(bd, pb), rad,
                                            plane_index[gp], mu, gd, solref, solimp, condim, tran)):
                        C[key].append(val)

        gravity = np.zeros(3) if disabled("mjDSBL_GRAVITY") else np.array(m.opt.gravity)
        if np.any(m.body_gravcomp != 0):
            notes.append("body gravcomp ignored")

        def names(objtype, n):
            return tuple(mujoco.mj_id2name(m, objtype, i) or "" for i in range(n))

        def arr(lst, shape, dtype=float):
            return _frozen(np.array(lst, dtype=dtype).reshape(shape), dtype)

        nj = njnt
        ne = len(E["type"])
        nc = len(C["geom"])
        npl = len(P["geom"])
        model = cls(
            nbody=nbody, ngroup=ngroup, njnt=njnt, nq=m.nq, nv=m.nv, nsite=nsite,
            body_names=names(mujoco.mjtObj.mjOBJ_BODY, nbody),
            jnt_names=names(mujoco.mjtObj.mjOBJ_JOINT, njnt),
            site_names=names(mujoco.mjtObj.mjOBJ_SITE, nsite),
            tendon_names=names(mujoco.mjtObj.mjOBJ_TENDON, m.ntendon),
            body_parent=_frozen(parent, int), body_group=_frozen(body_group, int),
            body_mass=_frozen(m.body_mass), body_pos=_frozen(m.body_pos),
            body_quat=_frozen(m.body_quat), body_ipos=_frozen(ipos), body_iquat=_frozen(iquat),
            body_in_group_pos=_frozen(T_GI_pos), body_in_group_quat=_frozen(T_GI_quat),
            body_frame_in_group_pos=_frozen(T_GB_pos), body_frame_in_group_quat=_frozen(T_GB_quat),
            group_root=_frozen(g_root, int), group_dynamic=_frozen(dyn, bool),
            group_mass=_frozen(g_mass), group_inertia=_frozen(g_inertia),
            group_inv_mass=_frozen(inv_mass), group_inv_inertia=_frozen(inv_inertia),
            group_from_root_pos=_frozen(g_from_root_pos),
            group_from_root_quat=_frozen(g_from_root_quat),
            jnt_type=_frozen(jnt_type, int), jnt_body=_frozen(jb, int),
            jnt_g1=arr(J["g1"], (nj,), int), jnt_g2=arr(J["g2"], (nj,), int),
            jnt_r1=arr(J["r1"], (nj, 3)), jnt_r2=arr(J["r2"], (nj, 3)),
            jnt_a1=arr(J["a1"], (nj, 3)), jnt_a2=arr(J["a2"], (nj, 3)),
            jnt_qoff=arr(J["qoff"], (nj, 4)), jnt_limited=_frozen(limited, bool),
            jnt_lo=arr(J["lo"], (nj,)), jnt_hi=arr(J["hi"], (nj,)),
            jnt_range=_frozen(m.jnt_range), jnt_damping=_frozen(damping), jnt_armature=_frozen(armature),
            jnt_qposadr=_frozen(m.jnt_qposadr, int), jnt_dofadr=_frozen(m.jnt_dofadr, int),
            jnt_pos=_frozen(m.jnt_pos), jnt_axis=_frozen(m.jnt_axis), qpos0=_frozen(qpos0),
            eq_type=arr(E["type"], (ne,), int), eq_g1=arr(E["g1"], (ne,), int),
            eq_g2=arr(E["g2"], (ne,), int), eq_r1=arr(E["r1"], (ne, 3)),
            eq_r2=arr(E["r2"], (ne, 3)), eq_qoff=arr(E["qoff"], (ne, 4)),
            site_body=_frozen(sb, int), site_group=_frozen(body_group[sb], int),
            site_pos_inertial=_frozen(s_inert), site_pos_group=_frozen(s_group),
            tendon_sites=tuple(tsites),
            contact_group=arr(C["group"], (nc,), int), contact_local=arr(C["local"], (nc, 3)),
            contact_radius=arr(C["radius"], (nc,)), contact_plane=arr(C["plane"], (nc,), int),
            contact_mu=arr(C["mu"], (nc,)), contact_geom=arr(C["geom"], (nc,), int),
            plane_group=arr(P["group"], (npl,), int), plane_origin=arr(P["origin"], (npl, 3)),
            plane_normal=arr(P["normal"], (npl, 3)), plane_geom=arr(P["geom"], (npl,), int),
            gravity=_frozen(gravity), unsupported=tuple(notes),
            contact_solref=arr(C["solref"], (nc, 2)), contact_solimp=arr(C["solimp"], (nc, 5)),
            contact_condim=arr(C["condim"], (nc,), int), contact_tran=arr(C["tran"], (nc,)),
            contact_cone=int(m.opt.cone), contact_impratio=float(m.opt.impratio),
            contact_timestep=float(m.opt.timestep),
            jnt_solref=arr(m.jnt_solref, (nj, 2)), jnt_solimp=arr(m.jnt_solimp, (nj, 5)),
            jnt_invweight=arr([float(m.dof_invweight0[m.jnt_dofadr[j]]) for j in range(nj)], (nj,)),
            tendon_limit_ids=tuple(tl_ids),
            tendon_limit_range=arr([m.tendon_range[t] for t in tl_ids], (len(tl_ids), 2)),
            tendon_limit_solref=arr([m.tendon_solref_lim[t] for t in tl_ids], (len(tl_ids), 2)),
            tendon_limit_solimp=arr([m.tendon_solimp_lim[t] for t in tl_ids], (len(tl_ids), 5)),
            tendon_limit_invweight=arr([float(m.tendon_invweight0[t]) for t in tl_ids], (len(tl_ids),)),
        )
        if warn and notes:
            warnings.warn("XpbdModel: " + "; ".join(notes), stacklevel=2)
        return model

    # ------------------------------------------------------------------ lookups
    def site_id(self, site) -> int:
        if isinstance(site, (int, np.integer)):
            return int(site)
        return self.site_names.index(site)

    def joint_id(self, joint) -> int:
        if isinstance(joint, (int, np.integer)):
            return int(joint)
        return self.jnt_names.index(joint)

    def body_id(self, body) -> int:
        if isinstance(body, (int, np.integer)):
            return int(body)
        return self.body_names.index(body)

    def tendon_site_pair(self, tendon) -> tuple[int, int]:
        """(site_a, site_b) of a two-site spatial tendon (by id or name)."""
        t = tendon if isinstance(tendon, (int, np.integer)) else self.tendon_names.index(tendon)
        s = self.tendon_sites[t]
        if len(s) != 2:
            raise ValueError(f"tendon {tendon!r} is not a spatial tendon through exactly two sites")
        return s

    # ------------------------------------------------------------------ state I/O
    def state_from_qpos(self, qpos=None, qvel=None) -> XpbdState:
        """Build a state from MuJoCo generalized coordinates (defaults: qpos0, zero qvel)."""
        qpos = np.array(self.qpos0 if qpos is None else qpos, dtype=float)
        qvel = np.zeros(self.nv) if qvel is None else np.asarray(qvel, dtype=float)
        xpos, xquat, vo, w = self._fk(qpos, qvel)
        x = xpos + np_quat_rotate(xquat, self.body_ipos)
        q = np_quat_mul(xquat, self.body_iquat)
        v = vo + np_cross(w, x - xpos)
        # static bodies: exactly their model pose
        st = self.body_group == 0
        x[st] = self.body_in_group_pos[st]
        q[st] = self.body_in_group_quat[st]
        v[st] = 0.0
        w[st] = 0.0
        return XpbdState(x, q, v, w, qpos.copy(), 0.0)

    def _fk(self, qpos, qvel):
        """Body-frame poses and velocities (origin velocity, world ω) from qpos/qvel."""
        nb = self.nbody
        xpos = np.zeros((nb, 3))
        xquat = np.tile(_IDQ, (nb, 1))
        vo = np.zeros((nb, 3))
        w = np.zeros((nb, 3))
        jnt_of_body = {int(b): j for j, b in enumerate(self.jnt_body)}
        for b in range(1, nb):
            p = self.body_parent[b]
            xpos[b] = xpos[p] + _rot(xquat[p], self.body_pos[b])
            xquat[b] = _qmul(xquat[p], self.body_quat[b])
            w[b] = w[p]
            j = jnt_of_body.get(b)
            vj = np.zeros(3)  # joint contribution to the origin velocity
            if j is not None:
                t, qa, da = self.jnt_type[j], self.jnt_qposadr[j], self.jnt_dofadr[j]
                if t == JNT_FREE:
                    xpos[b] = qpos[qa:qa + 3]
                    xquat[b] = qpos[qa + 3:qa + 7] / np.linalg.norm(qpos[qa + 3:qa + 7])
                    vo[b] = qvel[da:da + 3]
                    w[b] = _rot(xquat[b], qvel[da + 3:da + 6])
                    continue
                if t == JNT_SLIDE:
                    ax = _rot(xquat[b], self.jnt_axis[j])
                    xpos[b] = xpos[b] + ax * (qpos[qa] - self.qpos0[qa])
                    vj = ax * qvel[da]
                else:
                    anchor = xpos[b] + _rot(xquat[b], self.jnt_pos[j])
                    if t == JNT_HINGE:
                        ax = _rot(xquat[b], self.jnt_axis[j])
                        ang = qpos[qa] - self.qpos0[qa]
                        qloc = np.r_[math.cos(ang / 2),
                                     math.sin(ang / 2) * np.asarray(self.jnt_axis[j])]
                        xquat[b] = _qmul(xquat[b], qloc)
                        wj = ax * qvel[da]
                    else:  # ball
                        qloc = qpos[qa:qa + 4] / np.linalg.norm(qpos[qa:qa + 4])
                        xquat[b] = _qmul(xquat[b], qloc)
                        wj = _rot(xquat[b], qvel[da:da + 3])
                    xpos[b] = anchor - _rot(xquat[b], self.jnt_pos[j])
                    w[b] = w[b] + wj
                    vj = np.cross(wj, xpos[b] - anchor)
            vo[b] = vo[p] + np.cross(w[p], xpos[b] - xpos[p]) + vj
        return xpos, xquat, vo, w

    # The per-step observations below (body frames, generalized coordinates, energies) are compiled kernels
    # (``compiled.body_frames``, ``qpos_qvel``, ``energies``); under NUMBA_DISABLE_JIT=1 they run as Python.

    def _nb_arrays(self):
        """Contiguous int64/float64 copies of the model arrays the compiled observations read (made once)."""
        a = self.__dict__.get("_nb")
        if a is None:
            from sim.xpbd import compiled

            f = lambda v, *shape: np.ascontiguousarray(np.array(v, dtype=np.float64).reshape(*shape))  # noqa: E731
            i = lambda v: np.ascontiguousarray(np.array(v, dtype=np.int64).reshape(-1))  # noqa: E731
            a = dict(iquat=f(self.body_iquat, -1, 4), ipos=f(self.body_ipos, -1, 3), parent=i(self.body_parent),
                     body_quat=f(self.body_quat, -1, 4), body_pos=f(self.body_pos, -1, 3),
                     jnt_type=i(self.jnt_type), jnt_body=i(self.jnt_body), jnt_qposadr=i(self.jnt_qposadr),
                     jnt_dofadr=i(self.jnt_dofadr), jnt_axis=f(self.jnt_axis, -1, 3), qpos0=f(self.qpos0, -1),
                     root=i(self.group_root), from_root_quat=f(self.group_from_root_quat, -1, 4),
                     from_root_pos=f(self.group_from_root_pos, -1, 3), group_mass=f(self.group_mass, -1),
                     group_inertia=f(self.group_inertia, -1, 3), gravity=f(self.gravity, 3),
                     body_frames=compiled.body_frames, qpos_qvel=compiled.qpos_qvel, energies=compiled.energies)
            a["tree"] = compiled.BodyTree(*(a[name] for name in compiled.BodyTree._fields))
            self.__dict__["_nb"] = a
        return a

    def body_frames(self, state: XpbdState):
        """World poses of the MuJoCo body frames (xpos [m] (nbody, 3), xquat (nbody, 4)) from a state."""
        a = self._nb_arrays()
        xb, qb = np.empty((self.nbody, 3)), np.empty((self.nbody, 4))
        a["body_frames"](_f64(state.x), _f64(state.q), a["iquat"], a["ipos"], xb, qb)
        return xb, qb

    def qpos_qvel(self, state: XpbdState):
        """MuJoCo generalized coordinates (qpos (nq,), qvel (nv,)) from relative body poses.

        Hinge: qpos0 + twist angle of the child's rotation relative to its zero-angle pose
        about the joint axis (unwrapped to the branch nearest ``state.qpos_hint``); rate
        = (ω_child − ω_parent)·axis.  Slide: qpos0 + displacement of the child body origin
        from its zero pose along the axis; rate = relative velocity along the axis.
        Ball: relative quaternion / child-frame relative angular velocity.  Free: body
        origin + body quaternion / world linear velocity of the origin + local ω.
        """
        a = self._nb_arrays()
        xb, qb = np.empty((self.nbody, 3)), np.empty((self.nbody, 4))
        qpos, qvel = np.empty(len(a["qpos0"])), np.empty(self.nv)
        a["qpos_qvel"](_f64(state.x), _f64(state.q), _f64(state.v), _f64(state.w), _f64(state.qpos_hint),
                       a["tree"], xb, qb, qpos, qvel)
        return qpos, qvel

    def site_positions(self, state: XpbdState) -> np.ndarray:
        """World positions of all sites, (nsite, 3)."""
        b = self.site_body
        return state.x[b] + np_quat_rotate(state.q[b], self.site_pos_inertial)

    def site_velocities(self, state: XpbdState) -> np.ndarray:
        """World velocities of all sites (material points), (nsite, 3)."""
        b = self.site_body
        r = np_quat_rotate(state.q[b], self.site_pos_inertial)
        return state.v[b] + np_cross(state.w[b], r)

    def energies(self, state: XpbdState) -> tuple[float, float]:
        """(kinetic, potential) energy of the dynamic groups [J] in one pass (see the two methods below)."""
        a = self._nb_arrays()
        return a["energies"](_f64(state.x), _f64(state.q), _f64(state.v), _f64(state.w), a["root"],
                             a["from_root_quat"], a["from_root_pos"], a["group_mass"], a["group_inertia"], a["gravity"])

    def kinetic_energy(self, state: XpbdState) -> float:
        """Σ ½ m v² + ½ ωᵀ I ω over dynamic groups [J] (all groups at once)."""
        return self.energies(state)[0]

    def potential_energy(self, state: XpbdState) -> float:
        """Gravitational potential −Σ m g·x over dynamic groups [J] (all groups at once)."""
        return self.energies(state)[1]


# ---------------------------------------------------------------------------


def _fk_positions(m, qpos):
    """Body-frame world poses at qpos (MuJoCo kinematics conventions, numpy)."""
    nb = m.nbody
    xpos = np.zeros((nb, 3))
    xquat = np.tile(_IDQ, (nb, 1))
    for b in range(1, nb):
        p = m.body_parentid[b]
        xpos[b] = xpos[p] + _rot(xquat[p], m.body_pos[b])
        xquat[b] = _qmul(xquat[p], m.body_quat[b])
        for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]):
            t, qa = m.jnt_type[j], m.jnt_qposadr[j]
            if t == JNT_FREE:
                xpos[b] = qpos[qa:qa + 3]
                xquat[b] = qpos[qa + 3:qa + 7] / np.linalg.norm(qpos[qa + 3:qa + 7])
            elif t == JNT_SLIDE:
                xpos[b] += _rot(xquat[b], m.jnt_axis[j]) * (qpos[qa] - m.qpos0[qa])
            else:
                anchor = xpos[b] + _rot(xquat[b], m.jnt_pos[j])
                if t == JNT_HINGE:
                    ang = qpos[qa] - m.qpos0[qa]
                    qloc = np.r_[math.cos(ang / 2), math.sin(ang / 2) * m.jnt_axis[j]]
                else:
                    qloc = qpos[qa:qa + 4] / np.linalg.norm(qpos[qa:qa + 4])
                xquat[b] = _qmul(xquat[b], qloc)
                xpos[b] = anchor - _rot(xquat[b], m.jnt_pos[j])
    return xpos, xquat


def _contact_pairs(m, body_group, weld, parent, no_filterparent, notes):
    """(plane geom, contact geom, μ, solref, solimp, condim) pairs honouring contype/conaffinity,
    the parent filter, <exclude> and explicit <pair> elements.

    The contact parameters of a geom pair follow MuJoCo's ``mj_contactParam``: the geom of
    higher ``priority`` wins; at equal priority friction and condim are the maxima and
    solref/solimp are mixed with weight solmix₁/(solmix₁ + solmix₂) (solref by element-wise
    minimum when either is in the direct, negative format).  With the ``override`` enable
    flag, ``opt.o_solref``/``o_solimp``/``o_friction`` replace them.
    """
    excl = set(int(s) for s in np.asarray(m.exclude_signature).ravel())
    out = {}
    override = bool(int(m.opt.enableflags) & int(mujoco.mjtEnableBit.mjENBL_OVERRIDE))

    def params(g1, g2):
        p1, p2 = m.geom_priority[g1], m.geom_priority[g2]
        if p1 != p2:
            g = g1 if p1 > p2 else g2
            mu, solref, solimp, condim = (float(m.geom_friction[g, 0]), np.array(m.geom_solref[g], float),
                                          np.array(m.geom_solimp[g], float), int(m.geom_condim[g]))
        else:
            mu = float(max(m.geom_friction[g1, 0], m.geom_friction[g2, 0]))
            condim = int(max(m.geom_condim[g1], m.geom_condim[g2]))
            s1, s2 = float(m.geom_solmix[g1]), float(m.geom_solmix[g2])
            if s1 < 1e-15 and s2 < 1e-15:
                mix = 0.5
            elif s1 < 1e-15:
                mix = 0.0
            elif s2 < 1e-15:
                mix = 1.0
            else:
                mix = s1 / (s1 + s2)
            r1, r2 = np.array(m.geom_solref[g1], float), np.array(m.geom_solref[g2], float)
            solref = mix * r1 + (1 - mix) * r2 if (r1[0] > 0 and r2[0] > 0) else np.minimum(r1, r2)
            solimp = mix * np.array(m.geom_solimp[g1], float) + (1 - mix) * np.array(m.geom_solimp[g2], float)
        if override:
            mu = float(m.opt.o_friction[0])
            solref, solimp = np.array(m.opt.o_solref, float), np.array(m.opt.o_solimp, float)
        return mu, solref, solimp, condim

    skipped = 0
    for g1 in range(m.ngeom):
        for g2 in range(g1 + 1, m.ngeom):
            b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
            if not ((m.geom_contype[g1] & m.geom_conaffinity[g2]) or
                    (m.geom_contype[g2] & m.geom_conaffinity[g1])):
                continue
            w1, w2 = weld[b1], weld[b2]
            if w1 == w2:
                continue
            wp1, wp2 = weld[parent[w1]], weld[parent[w2]]
            if not no_filterparent and w1 != 0 and w2 != 0 and (w1 == wp2 or w2 == wp1):
                continue
            lo, hi = min(b1, b2), max(b1, b2)
            if ((lo << 16) + hi) in excl or ((hi << 16) + lo) in excl:
                continue
            if body_group[b1] == 0 and body_group[b2] == 0:
                continue
            t1, t2 = m.geom_type[g1], m.geom_type[g2]
            if t1 == _GEOM_PLANE and t2 in _CONTACT_GEOMS:
                out[(g1, g2)] = params(g1, g2)
            elif t2 == _GEOM_PLANE and t1 in _CONTACT_GEOMS:
                out[(g2, g1)] = params(g1, g2)
            else:
                skipped += 1
    for i in range(m.npair):
        g1, g2 = int(m.pair_geom1[i]), int(m.pair_geom2[i])
        t1, t2 = m.geom_type[g1], m.geom_type[g2]
        pair = (float(m.pair_friction[i, 0]), np.array(m.pair_solref[i], float), np.array(m.pair_solimp[i], float),
                int(m.pair_dim[i]))
        if t1 == _GEOM_PLANE and t2 in _CONTACT_GEOMS:
            out[(g1, g2)] = pair
        elif t2 == _GEOM_PLANE and t1 in _CONTACT_GEOMS:
            out[(g2, g1)] = pair
        else:
            skipped += 1
    if skipped:
        notes.append(f"{skipped} colliding geom pair(s) other than plane vs sphere/capsule/box ignored")
    return [(gp, gd) + tuple(p) for (gp, gd), p in out.items()]
