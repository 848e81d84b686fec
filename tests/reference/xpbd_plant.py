"""The PBD plant's numpy per-step data and the pure plant: oracles of the compiled ``PbdPlant`` paths.

:func:`articulated` is the numpy form of ``PbdPlant.articulated`` (the compiled ``pbd_frame._articulated``):
from the joint-space mass matrix M, gravity force Q and actuator moments J of ``PbdPlant.joint_space``,
dq = M⁻¹·[Jᵀ, Q] and the group motions of dq (mobility of each cylinder row, motor responses, group gravity),
the effective masses 1/(J·M⁻¹·Jᵀ)ᵢᵢ and the motors' (M⁻¹)ⱼⱼ.

:func:`pure_plant` turns a :class:`~reference.pbd_hooks.HooksPlant` (the Python hooks)
into the pure plant: every XPBD substep in :class:`~reference.xpbd_substep.ReferenceSolver`, the numpy
observations of ``xpbd_model.py`` and the numpy ``articulated``.  Example::

    plant = pure_plant(HooksPlant(scene))
    plant.step()
"""

from __future__ import annotations

from functools import partial
from types import MethodType

import numpy as np

from sim.plants.pbd import GRAVITY_ARTICULATED

from .pbd_hooks import HooksPlant
from .xpbd_model import body_frames, kinetic_energy, potential_energy, qpos_qvel
from .xpbd_substep import ReferenceSolver

__all__ = ["articulated", "pure_plant"]


def articulated(plant):
    """``PbdPlant.articulated`` in numpy (sets the plant's ``_mobility``, ``_group_gravity``, ``_effective_mass``,
    ``_motor_response`` and ``_motor_inverse_inertia``; all None / zero off a tree of hinges and slides or with a
    singular mass matrix)."""
    self = plant
    self._mobility = self._group_gravity = self._effective_mass = self._motor_response = None
    self._motor_inverse_inertia = np.zeros(len(self.motors))
    if not self._tree:
        return
    mass, gravity, moment, jv, jw = self.joint_space(bodies=True)
    try:
        dq = np.linalg.solve(mass, np.column_stack([moment.T, gravity]))  # (nv, actuators + 1)
    except np.linalg.LinAlgError:
        return
    with np.errstate(divide="ignore"):
        self._effective_mass = 1.0 / np.einsum("ai,ia->a", moment, dq[:, :-1])
    dofs = self.xmodel.jnt_dofadr[self.motor_joint]
    self._motor_inverse_inertia = dq[dofs, self.motors] / self.motor_gear
    xm = self.xmodel
    # group centre-of-mass velocity = mass-weighted body COM velocities; groups share ω
    group_jv = np.zeros((xm.nv, xm.ngroup, 3))
    np.add.at(group_jv, (slice(None), xm.body_group), jv * self._body_mass[None, :, None])
    group_jv /= np.where(xm.group_mass > 0, xm.group_mass, 1.0)[None, :, None]
    group_jw = jw[:, xm.group_root]
    cols = np.r_[self.cylinders, self.motors, dq.shape[1] - 1]
    response = np.concatenate([np.einsum("ir,igk->rgk", dq[:, cols], group_jv),
                               np.einsum("ir,igk->rgk", dq[:, cols], group_jw)], axis=2)
    response[:, ~np.asarray(xm.group_dynamic)] = 0.0
    self._group_gravity = response[-1] if GRAVITY_ARTICULATED else None
    ncyl = len(self.cylinders)
    self._mobility = response[:ncyl] if ncyl else None
    self._motor_response = response[ncyl:ncyl + len(self.motors)] if len(self.motors) and GRAVITY_ARTICULATED else None


def pure_plant(plant, *, block_attach: bool = True):
    """``plant`` (a :class:`~reference.pbd_hooks.HooksPlant`) on the oracles, reset to its initial state; returns
    it."""
    assert isinstance(plant, HooksPlant), "pure_plant steps the Python hooks: pass a HooksPlant"
    xm = plant.xmodel
    xm.__dict__["body_frames"] = partial(body_frames, xm)
    xm.__dict__["qpos_qvel"] = partial(qpos_qvel, xm)
    xm.__dict__["energies"] = lambda state: (kinetic_energy(xm, state), potential_energy(xm, state))
    old = plant.solver
    plant.solver = ReferenceSolver(xm, old.options, length_constraints=old.rows, block_attach=block_attach)
    plant.articulated = MethodType(articulated, plant)
    plant.reset()
    return plant
