"""The PBD plant's Python hooks: the oracle of its compiled steps.

:class:`HooksPlant` is :class:`sim.plants.pbd.PbdPlant` stepped the slow way: per step the articulated data
(``PbdPlant.articulated``), then ``SolverXPBD.step`` with this plant as its hooks: before every substep the
coupling's Python ``begin`` (the effort law c + s·v⁺) turned into compliant rows (α = −h/s, ℓ* = ℓ₀ − h·c/s where
s < −1e-9, the law's bounds on their multipliers) or explicit row forces, motor efforts by backward Euler on the
joint; after it the coupling's Python ``finish`` with the realised motion and ``PlantBase._account``.  The
numpy formulation of the same steps as ``sim/plants/pbd_frame.py`` and ``pbd_hydraulics.py`` (one numba call per
block there), so the two agree to round-off (``tests/test_pbd_fast.py``), and it takes any coupling and stepper
(the ``reference`` stepper included), which the package's PBD mode refuses.  Example::

    plant = HooksPlant(scene)
    plant.step()

With :func:`reference.xpbd_plant.pure_plant` it runs on the numpy XPBD substep and observations as well.
"""

from __future__ import annotations

import numpy as np

from hydraulics.coupling import start_velocity_guess
from hydraulics.load import apply_inputs
from hydraulics.steppers import StepReport
from sim.plants.pbd import PbdPlant
from sim.plants.pbd_frame import IMPLICIT_SLOPE_LIMIT
from sim.xpbd import SubstepInputs
from sim.xpbd.quat import np_quat_rotate

__all__ = ["HooksPlant"]


class HooksPlant(PbdPlant):
    """:class:`PbdPlant` stepped by its Python hooks (see module docstring); ``advance`` is one :meth:`step` at a time."""

    def __init__(self, scene, *, naive: bool = False):
        super().__init__(scene, naive=naive, block=False)
        self._joint_force = np.zeros(self.xmodel.njnt)

    def _network_buffers(self):
        return None  # no compiled steps: any coupling and stepper

    @property
    def fast(self) -> bool:
        return False

    def step(self):
        """One step of ``dt``: ``pbd_substeps`` XPBD substeps with the hooks, one hydraulic step each."""
        self.apply_inputs()
        self._report = StepReport()
        self._work = 0.0
        self.articulated()
        self.solver.step(self.state, self.dt, hooks=self)
        return self._end_step()

    def _end_step(self):
        self.theta = getattr(self.coupling, "last_theta", self.theta)
        self.last_report = self._report
        mechanical = sum(self.mechanical_energy())
        self.energy.dissipated_mechanical += self._work - (mechanical - self._mechanical)
        self._mechanical = mechanical
        if self._report.success:  # running extremes of every successful step (new arrays: the runner keeps references)
            p, x = self.net_state.node_pressure, self.net_state.actuator_position
            self.node_pressure_max = np.maximum(self.node_pressure_max, p)
            self.node_pressure_min = np.minimum(self.node_pressure_min, p)
            self.actuator_position_max = np.maximum(self.actuator_position_max, x)
            self.actuator_position_min = np.minimum(self.actuator_position_min, x)
        self.step_index += 1
        return self._report

    def before_substep(self, k, h, state):
        """XPBD hook: the coupling's effort law for this substep as compliant rows (or explicit row forces) and joint torques."""
        if k:  # the scenario's schedules at the substep's time (step() set them at the frame's start)
            apply_inputs(self.network, self.control, self.scene.scenario.inputs, self.time + k * h)
        x, v = self._x, self._v
        law = self.coupling.begin(self.net_state, self.control, x, v, h,
                                  effective_mass=self._effective_mass if self.incompressible or self.rigid or self.blend
                                  else None, velocity_guess=start_velocity_guess(self.network, x, v, h))
        law_constant, law_slope, law_lower, law_upper = law.constant, law.slope, law.lower, law.upper
        cyl = self.cylinders
        c, s = law_constant[cyl], law_slope[cyl]
        implicit = (s < IMPLICIT_SLOPE_LIMIT) & (not self.naive)
        with np.errstate(divide="ignore", invalid="ignore"):
            target = np.where(implicit, self._ell - h * c / s, np.nan)  # ℓ* = ℓ₀ − h·c/s
            compliance = np.where(implicit, -h / s, 0.0)  # α = −h/s
        force = c + s * v[cyl]
        lower = upper = None
        if law_lower is not None:  # (an implicit row's bounds bound its multiplier, not an explicit force)
            lower, upper = law_lower[cyl], law_upper[cyl]
            force = np.clip(force, lower, upper)
        force = np.where(implicit, 0.0, force)
        self._implicit, self._row_explicit = implicit, force
        # motors: backward Euler on the joint alone, ω⁺ = ω + h·w·τ with w = (M⁻¹)ⱼⱼ, τ = gear·(c + s·gear·ω⁺)
        mot = self.motors
        damping = np.maximum(-law_slope[mot], 0.0) * self.motor_gear**2 * h * self._motor_inverse_inertia
        self._motor_effort = (law_constant[mot] + law_slope[mot] * v[mot]) / (1.0 + damping)
        if law_lower is not None:
            self._motor_effort = np.clip(self._motor_effort, law_lower[mot], law_upper[mot])
        jf = self._joint_force
        group_acceleration = self._group_gravity
        if self._motor_response is not None:
            # motor torques act on the whole mechanism (q̈ = M⁻¹·Jᵀ·effort, like gravity): the implicit
            # joint damping above uses the articulated (M⁻¹)ⱼⱼ, so the response must be the articulated one
            group_acceleration = group_acceleration + np.einsum("m,mgk->gk", self._motor_effort, self._motor_response)
            joint_force = None
        else:
            jf[self.motor_joint] = self.motor_gear * self._motor_effort
            joint_force = jf if len(mot) else None
        row_force = force if np.any(force) else None
        if row_force is not None and self._articulated_rows():
            # explicit row forces act on the whole mechanism too (q̈ = M⁻¹·Jᵀ·f, the rows' mobilities): as
            # per-body forces projected by one joint iteration, a row switching between its compliant and
            # its explicit form (a friction slope crossing zero) kicked the mechanism
            group_acceleration = group_acceleration + np.einsum("r,rgk->gk", force, self._mobility)
            row_force = None
        return SubstepInputs(
            target_length=target if len(cyl) else None, compliance=compliance, force_min=lower, force_max=upper,
            row_force=row_force, joint_force=joint_force,
            row_mobility=self._mobility, group_gravity=group_acceleration,
        )

    def _articulated_rows(self) -> bool:
        """Whether explicit cylinder-row forces enter through the articulated response (group accelerations
        f·M⁻¹·Jᵀ, as the motors' efforts and gravity) rather than as forces on the two rigid groups: whenever the
        step has the articulated data, except in the seed's ``pbd-naive`` scheme (per-body forces, classic PBD)."""
        return self._mobility is not None and self._group_gravity is not None and not self.naive

    def after_substep(self, k, h, state, forces):
        """XPBD hook: finish the hydraulic step with the realised cylinder lengths and motor speeds."""
        x, v = self._x, self._v
        cyl, mot = self.cylinders, self.motors
        ell = forces.row_length
        x_end, v_end = x.copy(), v.copy()
        x_end[cyl] = ell - self.closed_length
        v_end[cyl] = (ell - self._ell) / h
        v_end[mot] = self.motor_gear * self._joint_rates(state, self.motor_joint)
        x_end[mot] = x[mot] + h * v_end[mot]
        self.net_state, report = self.coupling.finish(self.net_state, self.control, x, x_end, v, v_end, h)
        self._report.absorb(report)
        effort = np.zeros(self.network.actuator_count)
        effort[cyl] = np.where(self._implicit, forces.row_force, self._row_explicit)
        effort[mot] = self._motor_effort
        self.effort = effort
        # next substep starts here; cylinder speeds as the bodies now move (after the velocity pass)
        v_next = v_end.copy()
        v_next[cyl] = forces.row_rate
        # work of the efforts on the bodies, trapezoidal in the actuator speeds (exact for a free mass)
        self._work += 0.5 * h * float(effort @ (v + v_next))
        self._account(report, v_end, h)
        self._ell = ell
        self._x, self._v = x_end, v_next

    def _joint_rates(self, state, joints):
        """Rates of hinge [rad/s] / slide [m/s] joints from the XPBD state (child relative to parent)."""
        xm = self.xmodel
        out = np.zeros(len(joints))
        for i, j in enumerate(joints):
            b = int(xm.jnt_body[j])
            p = int(xm.body_parent[b])
            axis = np_quat_rotate(state.q[b], self._axis_inertial[j])  # world axis
            if self._hinge[j]:
                out[i] = float((state.w[b] - state.w[p]) @ axis)
            else:  # relative velocity of the child's body-frame origin along the axis
                origin = state.x[b] + np_quat_rotate(state.q[b], self._origin_inertial[b])
                vb = state.v[b] + np.cross(state.w[b], origin - state.x[b])
                vp = state.v[p] + np.cross(state.w[p], origin - state.x[p])
                out[i] = float((vb - vp) @ axis)
        return out

