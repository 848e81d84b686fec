"""The numpy observations of an ``XpbdModel``: the oracle of the compiled ``body_frames``, ``qpos_qvel`` and
``energies`` (``sim/xpbd/compiled.py``).  Functions of (model, state); ``self`` is the ``XpbdModel``.

Example: ``qpos, qvel = qpos_qvel(xm, state)`` equals ``xm.qpos_qvel(state)`` to round-off.
"""

from __future__ import annotations

import math

import numpy as np

from sim.xpbd.model import JNT_FREE, JNT_HINGE, JNT_SLIDE
from sim.xpbd.quat import np_cross, np_quat_conj, np_quat_mul, np_quat_rotate, np_quat_rotate_inv

from .xpbd_kernels import quat_conj, quat_mul, quat_rotate, quat_rotate_inv

__all__ = ["body_frames", "qpos_qvel", "kinetic_energy", "potential_energy"]


def _rot(q, v):
    return np.asarray(quat_rotate(q, v))


def _qmul(a, b):
    return np.asarray(quat_mul(a, b))


def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def body_frames(self, state):
    """World poses of the MuJoCo body frames (xpos, xquat) of ``state``: frame = inertial frame ⊗ iquat⁻¹."""
    qb = np_quat_mul(state.q, np_quat_conj(self.body_iquat))
    xb = state.x - np_quat_rotate(qb, self.body_ipos)
    return xb, qb


def qpos_qvel(self, state):
    """MuJoCo (qpos, qvel) from the relative body poses (see ``XpbdModel.qpos_qvel``)."""
    xb, qb = body_frames(self, state)
    qpos = np.array(self.qpos0, dtype=float)
    qvel = np.zeros(self.nv)
    hint = state.qpos_hint
    for j in range(self.njnt):
        b = self.jnt_body[j]
        p = self.body_parent[b]
        t, qa, da = self.jnt_type[j], self.jnt_qposadr[j], self.jnt_dofadr[j]
        vob = state.v[b] + np_cross(state.w[b], xb[b] - state.x[b])
        if t == JNT_FREE:
            qpos[qa:qa + 3] = xb[b]
            qpos[qa + 3:qa + 7] = qb[b]
            qvel[da:da + 3] = vob
            qvel[da + 3:da + 6] = np.asarray(quat_rotate_inv(qb[b], state.w[b]))
            continue
        zq = _qmul(qb[p], self.body_quat[b])            # child frame at zero
        if t == JNT_SLIDE:
            zp = xb[p] + _rot(qb[p], self.body_pos[b])
            ax = _rot(qb[b], self.jnt_axis[j])
            qpos[qa] = self.qpos0[qa] + (xb[b] - zp) @ ax
            vp = state.v[p] + np_cross(state.w[p], xb[b] - state.x[p])
            qvel[da] = (vob - vp) @ ax
            continue
        qloc = _qmul(quat_conj(zq), qb[b])
        if t == JNT_HINGE:
            ang = 2.0 * math.atan2(qloc[1:] @ self.jnt_axis[j], qloc[0])
            ref = hint[qa] - self.qpos0[qa]
            ang = ref + _wrap(ang - ref)
            qpos[qa] = self.qpos0[qa] + ang
            ax = _rot(qb[b], self.jnt_axis[j])
            qvel[da] = (state.w[b] - state.w[p]) @ ax
        else:  # ball
            qpos[qa:qa + 4] = qloc if qloc[0] >= 0 else -qloc
            qvel[da:da + 3] = np.asarray(quat_rotate_inv(qb[b], state.w[b] - state.w[p]))
    return qpos, qvel


def kinetic_energy(self, state) -> float:
    """Σ ½ m v² + ½ ωᵀ I ω over the dynamic groups [J]."""
    if self.ngroup <= 1:
        return 0.0
    r = np.asarray(self.group_root[1:])
    qr = state.q[r]
    qg = np_quat_mul(qr, np.asarray(self.group_from_root_quat[1:]))
    w = state.w[r]
    wl = np_quat_rotate_inv(qg, w)
    xg = state.x[r] + np_quat_rotate(qr, np.asarray(self.group_from_root_pos[1:]))
    vg = state.v[r] + np_cross(w, xg - state.x[r])
    m = np.asarray(self.group_mass[1:])
    inertia = np.asarray(self.group_inertia[1:])
    return float(np.sum(0.5 * m * np.einsum("gk,gk->g", vg, vg) + 0.5 * np.einsum("gk,gk->g", inertia, wl * wl)))


def potential_energy(self, state) -> float:
    """−Σ m g·x over the dynamic groups [J]."""
    if self.ngroup <= 1:
        return 0.0
    r = np.asarray(self.group_root[1:])
    xg = state.x[r] + np_quat_rotate(state.q[r], np.asarray(self.group_from_root_pos[1:]))
    return float(-np.sum(np.asarray(self.group_mass[1:]) * (xg @ np.asarray(self.gravity))))
