"""MuJoCo plant: MuJoCo steps the bodies, the hydraulic network applies the actuator efforts.

Each step (``mj_step1`` → coupling → ``mj_step2`` → network):

1. ``mj_step1`` computes positions, velocities and the actuator moments at
   the start of the step; cylinder extension x = tendon length − closed
   length, motor angle = actuator length.
2. The coupling returns each actuator's effort law f = c + b₂·v⁺ for the
   step; the plant writes ``ctrl = c`` and ``actuator_biasprm[:, 2] = b₂``.
   With the ``implicitfast`` integrator MuJoCo folds −h·b₂ into its implicit
   mass matrix, so the oil-column stiffness is integrated implicitly.
3. ``mj_step2`` integrates the bodies.
4. The realised actuator velocities v⁺ = J(q)·q̇⁺ (with the moments MuJoCo used)
   and positions x + h·v⁺ finish the hydraulic step (``rosenbrock``: the positions
   MuJoCo integrated to, :meth:`MujocoPlant.end_position`).

The implicit couplings linearise the network at the start-of-step actuator
velocities (``velocity_guess = v``, zeroed for a cylinder whose guessed
displacement would change a chamber volume by more than 1 %:
:func:`hydraulics.coupling.start_velocity_guess`).  ``coupling`` (constructor argument)
overrides the scenario's coupling, e.g. ``"implicit-linear"`` for the
linearly implicit finish without a second Newton solve.

The effective mass the coupling needs to choose its θ per actuator is
1/(J·M⁻¹·Jᵀ) from MuJoCo's factorised mass matrix.  This plant never changes
the MJCF's bodies or joints; it only rewrites the bound actuators' gains.
"""

from __future__ import annotations

import mujoco
import numpy as np

from hydraulics import _compiled_rigid as K
from hydraulics.coupling import SCHEME_ROSENBROCK, CouplingMixed, make_coupling, start_velocity_guess
from hydraulics.steppers import StepStatus

from sim.plants.base import PlantBase
from sim.io.scene import Scene, initial_qpos_qvel

# MuJoCo joint types whose coordinate is one scalar (logged as joint states).
SCALAR_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
# MuJoCo answers a NaN or huge qpos / qvel / qacc (beyond mjMAXVAL) by resetting the data to the model's
# reference pose and counting one of these warnings; a plant must not step on from that pose silently.
BAD_STATE_WARNINGS = tuple(int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                                            mujoco.mjtWarning.mjWARN_BADQACC))


def mujoco_resets(data) -> int:
    """How many times MuJoCo has reset ``data`` for a bad qpos, qvel or qacc (see ``BAD_STATE_WARNINGS``)."""
    return sum(int(data.warning[w].number) for w in BAD_STATE_WARNINGS)


def mark_reset(report, before: int, data) -> None:
    """Turn ``report`` into a non-finite failure when MuJoCo reset ``data`` since the count ``before``."""
    if mujoco_resets(data) > before:
        report.status = StepStatus.NONFINITE
        report.message = ("MuJoCo reset the bodies to the reference pose (non-finite or huge qpos, qvel or qacc): "
                          f"{StepStatus.NONFINITE.value}")


class MujocoPlant(PlantBase):
    """Coupled MuJoCo + hydraulic network plant for one scene (see module docstring)."""

    mode = "mujoco"

    def __init__(self, scene: Scene, *, coupling: str | None = None):
        """``coupling`` overrides the scenario's ``run.coupling`` (e.g. ``"implicit-linear"``,
        see :mod:`hydraulics.coupling`); None keeps the scenario's."""
        self.scene = scene
        scenario = scene.scenario
        self.model = scene.mjmodel
        self.data = mujoco.MjData(self.model)
        self.model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
        self.network = scene.network
        self.binding = scene.binding
        self.dt = scenario.dt
        self.coupling = make_coupling(
            "incompressible" if self.network.fidelity == "incompressible" else (coupling or scenario.coupling),
            self.network, stepper=scenario.stepper, substeps=scenario.hydraulic_substeps,
        )
        inner = self.coupling.inner if type(self.coupling) is CouplingMixed else self.coupling
        # rosenbrock: the network's step ends at the actuator positions MuJoCo integrated to (see end_position)
        self.realised_end = getattr(inner, "scheme", None) == SCHEME_ROSENBROCK
        m = self.model
        self.scalar_joints = np.array([j for j in range(m.njnt) if int(m.jnt_type[j]) in SCALAR_JOINTS], int)
        self.joint_names = tuple(scene.joint_names[j] for j in self.scalar_joints)
        self._moment = np.zeros((len(self.binding.actuator_id), m.nv))
        self.reset()

    # ------------------------------------------------------------------ setup
    def reset(self) -> None:
        """Initial state from the scenario; chamber pressures balance the load if it asks for equilibrium."""
        m, d, scenario = self.model, self.data, self.scene.scenario
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:] = initial_qpos_qvel(self.scene)
        mujoco.mj_forward(m, d)
        self.start_network(*self.actuator_motion())

    def holding_efforts(self) -> np.ndarray:
        """Actuator efforts [N or N·m] that hold the current pose at rest, the MJCF's loop closures carrying their
        share (:func:`sim.plants.constraints.holding_efforts`; relative residual in ``holding_residual``)."""
        from sim.plants.constraints import actuator_moments, holding_efforts

        ids = self.binding.actuator_id
        if len(ids) == 0:  # a test rig: nothing to hold
            self.holding_residual = 0.0
            return np.zeros(0)
        effort, self.holding_residual = holding_efforts(self.model, self.data.qpos, lambda d: actuator_moments(self.model, d, ids),
                                                        contacts=self.scene.scenario.start_contacts == "include")
        return effort

    # -------------------------------------------------------------- kinematics
    def moments(self) -> np.ndarray:
        """Dense actuator moments J (actuator_count × nv) of the bound actuators: v_actuator = J·q̇."""
        d = self.data
        J = self._moment
        J[:] = 0.0
        for i, aid in enumerate(self.binding.actuator_id):
            adr, nnz = d.moment_rowadr[aid], d.moment_rownnz[aid]
            J[i, d.moment_colind[adr : adr + nnz]] = d.actuator_moment[adr : adr + nnz]
        return J

    def actuator_motion(self):
        """Cylinder extensions [m] / motor angles [rad] and their rates, from MuJoCo's actuator lengths."""
        ids = self.binding.actuator_id
        return self.data.actuator_length[ids] - self.binding.closed_length, self.data.actuator_velocity[ids].copy()

    def effective_mass(self, moment: np.ndarray) -> np.ndarray:
        """Inertia seen by each actuator, 1/(J·M⁻¹·Jᵀ)ᵢᵢ [kg or kg·m²]."""
        solved = np.zeros_like(moment)
        mujoco.mj_solveM(self.model, self.data, solved, moment)
        inverse = np.einsum("ij,ij->i", moment, solved)
        with np.errstate(divide="ignore"):
            return np.where(inverse > 0, 1.0 / inverse, np.inf)

    def mechanical_energy(self):
        """Kinetic and potential energy of the bodies [J] at the current state.

        Refreshes the position-dependent quantities first (``mj_fwdPosition``),
        which the next ``mj_step1`` recomputes anyway, so observing never
        changes the trajectory.
        """
        mujoco.mj_fwdPosition(self.model, self.data)
        mujoco.mj_energyPos(self.model, self.data)
        mujoco.mj_energyVel(self.model, self.data)
        return float(self.data.energy[1]), float(self.data.energy[0])

    # -------------------------------------------------------------------- step
    def step(self):
        """Advance one step of ``dt``; returns the hydraulic step report."""
        m, d, net = self.model, self.data, self.network
        dt = self.dt
        self.apply_inputs()
        if len(self.controllers):  # (the sources are gathered only for a scenario with PIDs)
            self.controllers.step(self.step_index, dt, self.controller_sources(), self.control)
        resets = mujoco_resets(d)
        mujoco.mj_step1(m, d)
        x, v = self.actuator_motion()
        moment = self.moments().copy()
        # linearise at the start-of-step velocities, the best guess of v⁺ (fewer Newton iterations), where it is
        # a short chord (coupling.start_velocity_guess)
        meff = self.effective_mass(moment)
        law = self.coupling.begin(self.net_state, self.control, x, v, dt, effective_mass=meff,
                                  velocity_guess=start_velocity_guess(self.network, x, v, dt))
        ids = self.binding.actuator_id
        applied = (law.constant, law.slope, law.lower, law.upper)
        if self.coupling.name == "incompressible":  # end stops: the end cap takes what pushes past an end
            F, I = self.coupling.packed
            applied = K.end_stop_hold_entry(F, I, self.coupling.table, np.asarray(x, float), np.asarray(v, float),
                                            np.asarray(meff, float), float(dt), *applied)
        d.ctrl[ids] = applied[0]
        m.actuator_biasprm[ids, 2] = applied[1]
        self._applied = (*applied, v)  # (the ledger's applied force)
        if law.lower is not None:
            # MuJoCo clamps within the step and keeps the implicit term only while unclamped:
            # exactly a velocity tracker that stalls at its force limit
            # (only actuators with finite bounds: the compressible ones of a mixed-fidelity network have none)
            bounded = np.isfinite(law.lower) | np.isfinite(law.upper)
            m.actuator_forcelimited[ids] = bounded
            m.actuator_forcerange[ids, 0] = np.where(bounded, applied[2], 0.0)
            m.actuator_forcerange[ids, 1] = np.where(bounded, applied[3], 0.0)
        mujoco.mj_step2(m, d)
        v_end = moment @ d.qvel
        x_end = self.end_position(x, v_end)
        self.net_state, report = self.coupling.finish(self.net_state, self.control, x, x_end, v, v_end, dt)
        if report.success:  # (a failed hydraulic step names its own cause)
            mark_reset(report, resets, d)
        self.effort = law(v_end) if law.lower is None else np.clip(law(v_end), law.lower, law.upper)
        self.theta = getattr(self.coupling, "last_theta", self.theta)
        self.last_report = report
        self._account(report, v_end, dt)
        self.step_index += 1
        return report

    def end_position(self, x, v_end) -> np.ndarray:
        """The actuator positions [m | rad] the network's step ends at, after ``mj_step2``: x + h·v⁺ from the start
        positions ``x`` and the realised velocities ``v_end``, or, with the ``rosenbrock`` coupling
        (:attr:`realised_end`), the positions MuJoCo integrated the bodies to (``mj_fwdPosition`` at the new
        ``qpos``, which the next ``mj_step1`` recomputes anyway: observing never changes the trajectory).  The
        two differ by O(h²) (the moment J is the slope of the actuator length); the realised ones make the end
        pressures p(m⁺, x⁺) the next step's start pressures, so that step evaluates the pressure law once."""
        if not self.realised_end:
            return x + self.dt * v_end
        mujoco.mj_fwdPosition(self.model, self.data)
        return self.actuator_motion()[0]

    def _account(self, report, velocity, dt) -> None:
        if self.coupling.name == "incompressible":  # rigid oil: the work of the forces MuJoCo applied is the supplied work
            c, k, lo, hi, start = self._applied
            force = c + k * velocity
            if lo is not None:  # (MujocoPlantFast._applied_power)
                at_start = c + k * start
                clamped = (at_start <= lo) | (at_start >= hi)  # (MuJoCo: a force at its bound counts as clamped)
                force = np.where(clamped, np.clip(at_start, lo, hi), force)
            self.energy.pump_work += dt * float(force @ velocity)
        else:
            super()._account(report, velocity, dt)
        d = self.data
        self.energy.dissipated_mechanical -= dt * float((d.qfrc_passive + d.qfrc_constraint) @ d.qvel)

    # ------------------------------------------------------------- observation
    def joint_state(self):
        """(positions, velocities) of the scalar joints [rad or m, rad/s or m/s]."""
        m, d = self.model, self.data
        return d.qpos[m.jnt_qposadr[self.scalar_joints]].copy(), d.qvel[m.jnt_dofadr[self.scalar_joints]].copy()

    def body_poses(self):
        """World positions [m] (nbody, 3) and quaternions (w, x, y, z) (nbody, 4) of all bodies.

        Valid after :meth:`mechanical_energy` (which refreshes the kinematics).
        """
        return self.data.xpos, self.data.xquat

    def finite(self) -> bool:
        d = self.data
        return bool(np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel)) and np.all(np.isfinite(self.net_state.node_pressure)))
