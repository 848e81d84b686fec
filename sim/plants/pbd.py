"""PBD plant: our XPBD solver steps the bodies, the hydraulic network sets the cylinder rows.

MuJoCo only compiles the MJCF here (geometry, inertia, names for the log); the
bodies are stepped by :class:`sim.xpbd.SolverXPBD` (``pbd_substeps`` substeps
of h = dt/substeps per step, ``pbd_iterations`` Gauss-Seidel passes each) and
no MuJoCo dynamics function is ever called.

Cylinders as compliant rows
---------------------------
Each cylinder is a length row between its two pins (the sites of its spatial
tendon), ℓ = |p_rod − p_barrel|, x = ℓ − closed length.  Every substep:

1. ``coupling.begin(net_state, control, x, v, h)`` returns the effort law
   f(v⁺) = c + s·v⁺ of each actuator for the substep (f > 0 extends).
2. With v⁺ = (ℓ − ℓ₀)/h (ℓ₀ the length at the start of the substep) this law
   is the compliant XPBD row f = −(ℓ − ℓ*)/α with

       α = −h/s [m/N],   ℓ* = ℓ₀ − h·c/s,

   (the row's force, λ/h², is positive when it pushes the pins apart, like
   the effort).  The chamber pressure is thus carried by the row's Lagrange
   multiplier, and because the law is the backward-Euler linearisation of the
   network (oil-column stiffness −h·β·A²/V, valve and friction slopes),
   XPBD's update is backward Euler for the coupled bodies + oil column:
   stable for any h, with its numerical damping ln(1 + ω²h²)/(2h).
   A law with s ≥ 0 (the explicit coupling) is applied as an explicit row
   force c + s·v₀.  Effort bounds of the law (``lower``/``upper``, the
   incompressible fidelity's relief limits) bound the multiplier.
   Cavitation and the other physical bounds are the network's.
3. After the position solve the realised ℓ and v⁺ finish the hydraulic step
   (``coupling.finish``), so the oil moves with the motion the bodies made.
   With the linear couplings (``implicit-linear``, ``rosenbrock``) the finish is
   m⁺ = m_lin + (∂m/∂v)·(v⁺ − v_guess), and rosenbrock linearises by one Newton
   step: no Newton solve in the substep.

θ-rule (scenario ``pbd_blend``, ``--pbd-blend``): the law's pressure part is
blended with the start-of-substep force by θ = clip(1 − 2/(ω·h)², 0, 1) per row,
``hydraulics.coupling.blend_factor`` with the articulated effective mass, as in
MuJoCo mode.  Where the oil column is resolved (ω·h < √2, θ = 0) the pressure
force is explicit and the prediction–projection is symplectic Euler: no
numerical damping (``tests/test_pbd_blend.py``: a blocked oil column rings at
2·asin(ω·h/2)/h; the boom lift at 1 ms × 1 substep is as accurate as MuJoCo
mode at 1 ms, 20× more than at θ = 1).  The default θ = 1 keeps the pressure
the row's multiplier and XPBD's update backward Euler.

Articulated response (``articulated``, once per step, trees of hinges and
slides): the rows are solved together with the response of the whole
mechanism, Δq = M⁻¹·Jᵀ·Δλ (``SubstepInputs.row_mobility``), and gravity
enters the prediction as q̈ = M⁻¹·Q_gravity (``SubstepInputs.group_gravity``),
both from the XPBD model's own kinematics; explicit row forces (a row whose
slope is not below ``pbd_frame.IMPLICIT_SLOPE_LIMIT``: θ = 0 with a friction slope of zero in
the seal's Stribeck dip) enter the prediction the same way, q̈ = M⁻¹·Jᵀ·f, like the
motors' efforts.  With the free-body inverse masses
of plain XPBD, one Gauss-Seidel iteration leaves a stiff row (oil column, the
seal-stiction slope of ~10⁶ N·s/m) far below its law, and the free fall of
every body under uniform gravity leaves load-dependent joint errors that the
stiff rows turn into pressure noise: a loaded boom sinks and bounces.
Other joint types fall back to plain XPBD rows and gravity.

The operator inputs (the scenario's schedules) are evaluated at every
substep's start time, so a 60 Hz frame does not hold the valve commands for
16 ms; the logged commands are those of the last substep.

Motors (joint actuators, gear = motor angle per joint angle) apply the torque
gear·(c + s·ω⁺) on their joint (``joint_force``), with ω⁺ from backward Euler
on the joint alone (its articulated inverse inertia (M⁻¹)ⱼⱼ): an implicit
joint damping −gear²·s, exact for the swing drive, which no other joint moves.

End stops are the joint limits and the cylinder tendons' limits, both soft
with MuJoCo's law from the MJCF's solreflimit/solimplimit (``SolverXPBD.soft_limits``);
at the boom's end stop both act and are solved together, as in MuJoCo.  At the ``incompressible`` fidelity the
rows are stiff velocity trackers whose multipliers are bounded by the supply-limited force; a mechanism
jammed against its ground contacts (``push.scenario.toml``) holds the stall force and comes to rest with one
Gauss-Seidel iteration (``tests/test_pbd_fidelity.py``).

Compiled path
-------------
Whole steps run in one compiled call (``sim/plants/pbd_block.py``: per step the articulated data, contacts,
all substeps with the coupling and the XPBD substep (``sim/plants/pbd_frame.py``, the coupling's begin and
finish in ``sim/plants/pbd_hydraulics.py``), the clocks, the mechanical ledger and the pressure and
actuator-coordinate extremes; operator inputs sampled for every substep beforehand) for every coupling the
compiled steps reproduce (``pbd_hydraulics.coupling_kind``: the implicit couplings, ``explicit`` and
``pbd-naive``, the ``incompressible`` fidelity, rigid actuators in a compressible network), any mechanism
(trees of hinges and slides with the articulated response, other joints and loop closures with plain XPBD's
free-body response), hinge and slide motors and any contact kind (soft pyramidal or elliptic, rigid).
``frame_steps`` counts these steps; ``solver.last_forces`` is then left empty.  ``NUMBA_DISABLE_JIT=1`` runs
the same kernels as plain Python.

A coupling the compiled steps do not reproduce (the ``reference`` stepper, a coupling with another stepper
than its own) is refused with the scenario's field named.  The same steps written in numpy around
``SolverXPBD.step``'s substep hooks, with the couplings' Python methods, are the oracle in
``tests/reference/pbd_hooks.py``: both agree to round-off (``tests/test_pbd_fast.py``).

:meth:`advance` (n) steps n times with the :class:`~sim.plants.mujoco_fast.MujocoPlantFast`
interface.  Where the compiled steps apply (:attr:`fast`), n steps are one compiled call, and the
log samples inside it are recorded from it into the runner's ring (:meth:`record_next`), so the
runner drives this plant in blocks like the fast MuJoCo plant; :meth:`step` is a block of one
step (``tests/test_pbd_block.py`` compares blocks of many and of one); ``block=False``
(``run(..., fast=False)``) keeps ``advance`` per step.

``pbd-naive`` (the seed report's scheme)
----------------------------------------
Explicit coupling with the explicit-Euler hydraulic stepper: the pressures
are integrated separately with the velocities at the start of each substep
and applied as explicit row forces (the position solve only keeps the joints
together, where classic PBD and XPBD coincide: every remaining row is rigid).
Unconditionally unstable for an undamped oil column.

Energy
------
``PlantBase._account`` per substep (pump work, hydraulic and friction
losses).  ``dissipated_mechanical`` is the balance of the bodies: the work of
the actuator efforts on them, h·f·(v₀ + v⁺)/2 per substep (exact for a free
mass under a force held over the substep), minus Δ(kinetic + potential) over
each step.  XPBD cannot separate joint damping, contact losses and the
(small, O(h)) energy error of its joint projections, so all three are in this
term; the oil column's backward-Euler loss stays in the residual.  Not
modelled by the XPBD solver (see ``sim/xpbd/solver.py``): joint armature except on
hinges whose parent is static (the excavator swing's 320 kg·m² is modelled: a rotor
inertia of the upper group, and on the joint-space diagonal; elsewhere a warning says so),
frictionloss, joint stiffness, contacts other than sphere/capsule/box against
planes; its joint and two-site tendon limits follow MuJoCo's soft limit law; its contacts are soft in the normal
direction with MuJoCo's law for the scene's solref/solimp (``sim.xpbd.compiled._contact_law``),
with friction from the same soft pyramid, and each contact sees the articulated response of the
whole mechanism (J·M⁻¹·Jᵀ, as MuJoCo's contact problem), not that of the touching body alone
(``XpbdOptions(articulated_contacts=True)``; a hinged arm striking the ground peaks at 24.91 mm
penetration against MuJoCo's 24.98 mm, the free-body response sank 37.9 mm).  The articulated
data (row mobilities, gravity and motor responses) is computed once per frame; at 60 Hz frames it
goes stale within the frame (``transport_response`` carries it to each substep, off by default).
"""

from __future__ import annotations

import math

import numpy as np

from hydraulics.coupling import make_coupling
from hydraulics.network import ACTUATOR_CYLINDER

from sim.plants.controllers import advance_controlled
from sim.plants.inputs import input_plan, sample_inputs
from sim.plants.base import PlantBase
from sim.plants.mujoco_fast import MujocoPlantFast
from sim.io.record_row import RECORD_ROW
from sim.io.scenario import ScenarioError
from sim.io.scene import Scene, initial_qpos_qvel
from sim.xpbd import LengthConstraint, SolverXPBD, XpbdModel, XpbdOptions
from sim.plants.pbd_hydraulics import NetworkBuffers
from sim.plants.pbd_hydraulics import eligible as fast_eligible
from sim.xpbd.quat import np_cross, np_quat_rotate, np_quat_rotate_inv
from sim.xpbd.model import JNT_HINGE, JNT_SLIDE

# MuJoCo joint types whose coordinate is one scalar (logged as joint states).
SCALAR_JOINTS = (JNT_HINGE, JNT_SLIDE)
# A law slope above this (N·s/m) is applied as an explicit force rather than as a compliant row.
GRAVITY_ARTICULATED = True


class PbdPlant(PlantBase):
    """Coupled XPBD + hydraulic network plant for one scene (see module docstring).

    ``naive`` selects the seed report's scheme (``pbd-naive``).
    """

    mode = "pbd"

    def __init__(self, scene: Scene, *, naive: bool = False, block: bool = True):
        self.scene = scene
        self.block = bool(block)  # advance(n) in compiled blocks of many steps (see ``fast``)
        scenario = scene.scenario
        self.incompressible = scene.network.fidelity == "incompressible"
        self.rigid = bool(np.any(scene.network.actuator_rigid))  # some actuators incompressible (CouplingMixed)
        if naive and (self.incompressible or self.rigid):
            raise ScenarioError(
                f"{scenario.path}, field 'run.fidelity': 'incompressible' has no pressure states for the seed's "
                "explicit scheme (mode 'pbd-naive'); use mode = \"pbd\" or fidelity = \"compressible\""
            )
        self.naive = bool(naive)
        self.mode = "pbd-naive" if naive else "pbd"
        self.model = scene.mjmodel  # geometry and names only (log, scene); never stepped
        self.network = net = scene.network
        self.binding = binding = scene.binding
        self.dt = scenario.dt
        self.coupling = make_coupling(
            "explicit" if naive else "incompressible" if self.incompressible else scenario.coupling, net,
            stepper="explicit_euler" if naive else scenario.stepper, substeps=1,
        )
        # θ-rule of MuJoCo mode (scenario pbd_blend) or θ = 1 (backward Euler, the pressure is the row's multiplier)
        self.blend = bool(scenario.pbd_blend) and not naive
        if self.rigid:
            self.coupling.blend = self.blend  # without blend the masses only size the rigid actuators' trackers
        m = self.model
        try:
            self.xmodel = xm = XpbdModel.from_mjmodel(m)
        except (ValueError, NotImplementedError) as exc:
            raise ScenarioError(f"{scenario.mjcf}: PBD mode cannot step this model: {exc}; use mode \"mujoco\"") from None
        # cylinders: one length row each, in network cylinder order
        self.cylinders = np.array([a for a in range(net.actuator_count) if net.actuator_kind[a] == ACTUATOR_CYLINDER], int)
        rows = [LengthConstraint(*xm.tendon_site_pair(int(binding.tendon_id[a])), name=net.actuator_names[a]) for a in self.cylinders]
        options = XpbdOptions(substeps=scenario.pbd_substeps, iterations=scenario.pbd_iterations)
        self.solver = SolverXPBD(xm, options, length_constraints=rows)
        self.closed_length = binding.closed_length[self.cylinders]
        # motors: joint actuators, effort = motor torque, joint torque = gear × effort
        self.motors = np.array([a for a in range(net.actuator_count) if net.actuator_kind[a] != ACTUATOR_CYLINDER], int)
        self.motor_joint = np.array([int(m.actuator_trnid[binding.actuator_id[a], 0]) for a in self.motors], int)
        self.motor_gear = np.array([float(m.actuator_gear[binding.actuator_id[a], 0]) for a in self.motors])
        for j in self.motor_joint:
            if int(xm.jnt_type[j]) not in SCALAR_JOINTS:
                raise ScenarioError(f"{scenario.mjcf}: motor joint '{xm.jnt_names[j]}' must be a hinge or slide joint in PBD mode")
        self.scalar_joints = np.array([j for j in range(xm.njnt) if int(xm.jnt_type[j]) in SCALAR_JOINTS], int)
        self.joint_names = tuple(scene.joint_names[j] for j in self.scalar_joints)
        # joint-space kinematics (hinge/slide trees): subtree membership of every body per joint
        nb = xm.nbody
        below = np.zeros((nb, nb), bool)  # below[a, b]: body b is a or hangs below a
        for b in range(1, nb):
            a = b
            while a > 0:
                below[a, b] = True
                a = int(xm.body_parent[a])
        self._subtree = below[xm.jnt_body]  # (njnt, nbody)
        self._hinge = np.asarray(xm.jnt_type) == JNT_HINGE
        self._tree = bool(np.all(np.isin(xm.jnt_type, SCALAR_JOINTS))) and xm.nv == xm.njnt
        self._body_mass = np.where(xm.body_group > 0, xm.body_mass, 0.0)
        self._body_inertia = np.array(m.body_inertia)
        self._row_sites = np.array([xm.tendon_site_pair(int(binding.tendon_id[a])) for a in self.cylinders], int).reshape(-1, 2)
        self._mobility = self._group_gravity = self._effective_mass = self._motor_response = None
        self._motor_inverse_inertia = np.zeros(len(self.motors))
        # joint axes in the child's inertial frame, body-frame origins in the inertial frames
        iquat_conj = np.asarray(xm.body_iquat) * np.array([1.0, -1.0, -1.0, -1.0])
        self._axis_inertial = np_quat_rotate(iquat_conj[xm.jnt_body], np.asarray(xm.jnt_axis))
        self._origin_inertial = np_quat_rotate(iquat_conj, -np.asarray(xm.body_ipos))
        # whole steps in compiled calls (sim/plants/pbd_block.py, the network's buffers in pbd_hydraulics.py)
        self._net = self._network_buffers()
        self.frame_steps = 0  # steps that ran compiled whole
        self._record_next = None  # (rows, every) for the next advance() (record_next)
        self.recorded, self.recorded_finite, self.end_finite = 0, True, True
        self.reset()

    # ------------------------------------------------------------------ setup
    def reset(self) -> None:
        """Initial state from the scenario; chamber pressures balance the load if it asks for equilibrium."""
        qpos, qvel = initial_qpos_qvel(self.scene)
        self.state = self.xmodel.state_from_qpos(qpos, qvel)
        self._ell, ell_rate = self.solver.row_lengths(self.state)
        x, v = self._actuator_motion(qpos, qvel, ell_rate)
        self._x, self._v = x, v
        self.start_network(x, v)
        self._mechanical = sum(self.mechanical_energy())
        self.reset_extremes()  # running extremes of pressures and actuator coordinates over every successful step

    def _actuator_motion(self, qpos, qvel, ell_rate):
        """Cylinder extensions [m] / motor angles [rad] and their rates at the current state."""
        n = self.network.actuator_count
        x, v = np.zeros(n), np.zeros(n)
        x[self.cylinders] = self._ell - self.closed_length
        v[self.cylinders] = ell_rate
        xm = self.xmodel
        x[self.motors] = self.motor_gear * qpos[xm.jnt_qposadr[self.motor_joint]]
        v[self.motors] = self.motor_gear * qvel[xm.jnt_dofadr[self.motor_joint]]
        return x, v

    def joint_space(self, *, bodies=False):
        """Joint-space quantities at the current XPBD state, from the XPBD kinematics only.

        Returns (mass matrix M (nv, nv) [kg, kg·m, kg·m²], gravity generalized
        force (nv,) [N or N·m], actuator moments J (actuator_count, nv):
        v_actuator = J·q̇), and with ``bodies`` also the centre-of-mass and
        angular Jacobians of every body, (nv, nbody, 3) each.  For trees of
        hinge and slide joints the Jacobians are analytic (joint axis × lever
        from the joint anchor) and M = Σ_b m_b·Jvᵀ·Jv + Jwᵀ·I_b·Jw; otherwise
        (mass None) the body and site velocities for a unit velocity of each
        DOF are used (``XpbdModel.state_from_qpos``).  A motor's moment is its gear.
        """
        xm, st = self.xmodel, self.state
        nv = xm.nv
        moment = np.zeros((self.network.actuator_count, nv))
        moment[self.motors, xm.jnt_dofadr[self.motor_joint]] = self.motor_gear
        if not self._tree:
            qpos, _ = xm.qpos_qvel(st)
            gravity = np.zeros(nv)
            for i in range(nv):
                unit = np.zeros(nv)
                unit[i] = 1.0
                s = xm.state_from_qpos(qpos, unit)
                gravity[i] = float(self._body_mass @ (s.v @ xm.gravity))
                moment[self.cylinders, i] = self.solver.row_lengths(s)[1]
            return (None, gravity, moment, None, None) if bodies else (None, gravity, moment)
        xb, qb = xm.body_frames(st)
        jb = xm.jnt_body
        axis = np_quat_rotate(qb[jb], xm.jnt_axis)  # (njnt, 3) world joint axes
        anchor = xb[jb] + np_quat_rotate(qb[jb], xm.jnt_pos)
        hinge = self._hinge[:, None, None]

        def point_jacobian(points, point_body):
            """∂(world point)/∂q, shape (njnt, npoints, 3), for points fixed to ``point_body``."""
            lever = points[None, :, :] - anchor[:, None, :]
            jac = np.where(hinge, np_cross(np.broadcast_to(axis[:, None, :], lever.shape), lever), axis[:, None, :])
            return jac * self._subtree[:, point_body, None]

        # joints are ordered by DOF (one each on a tree of hinges and slides)
        jv = point_jacobian(st.x, np.arange(xm.nbody))  # COM Jacobians (nv, nbody, 3)
        jw = np.where(hinge, axis[:, None, :], 0.0) * self._subtree[:, :, None]
        jw_local = np_quat_rotate_inv(st.q[None, :, :], jw)  # in each body's principal frame
        inertia = self._body_inertia * (self._body_mass > 0)[:, None]
        mass = np.einsum("b,ibk,jbk->ij", self._body_mass, jv, jv) + np.einsum("bk,ibk,jbk->ij", inertia, jw_local, jw_local)
        mass[np.diag_indices(nv)] += xm.jnt_armature  # rotor inertia of the joints (XpbdModel.jnt_armature)
        gravity = np.einsum("b,ibk,k->i", self._body_mass, jv, xm.gravity)
        if len(self.cylinders):
            sites = xm.site_positions(st)
            a, b = self._row_sites[:, 0], self._row_sites[:, 1]
            d = sites[b] - sites[a]
            n = d / np.linalg.norm(d, axis=1)[:, None]
            rel = point_jacobian(sites[b], xm.site_body[b]) - point_jacobian(sites[a], xm.site_body[a])
            moment[self.cylinders] = np.einsum("rk,jrk->rj", n, rel)
        return (mass, gravity, moment, jv, jw) if bodies else (mass, gravity, moment)

    def holding_efforts(self) -> np.ndarray:
        """Actuator efforts [N or N·m] that hold the current pose at rest, the MJCF's loop closures carrying their share.

        Jᵀ·F + Gᵀ·λ = −Q_gravity by least squares (:func:`hydraulics.equilibrium.holding_efforts`) with G the
        equality Jacobian from the XPBD kinematics (:func:`sim.plants.constraints.frame_equality_jacobian`) and,
        where that cannot hold the load, the joints resting on a range end (:func:`sim.plants.constraints.hold_with_stops`);
        relative residual in ``holding_residual``.
        """
        from sim.plants.constraints import frame_equality_jacobian, hold_with_stops, joint_stop_rows

        _, gravity, moment = self.joint_space()
        xm = self.xmodel
        qpos, _ = xm.qpos_qvel(self.state)
        G = frame_equality_jacobian(self.model, lambda q: xm.body_frames(xm.state_from_qpos(q)), qpos) if self.model.neq else None
        effort, self.holding_residual = hold_with_stops(moment, -gravity, G, joint_stop_rows(self.model, qpos))
        return effort

    # -------------------------------------------------------------------- step
    def _network_buffers(self):
        """The network's buffers of the compiled steps (``pbd_hydraulics.NetworkBuffers``); a coupling they do not
        reproduce is refused (:class:`ScenarioError`, naming the scenario's fields)."""
        if not fast_eligible(self):
            scenario = self.scene.scenario
            stepper = getattr(getattr(self.coupling, "stepper", None), "name", "its stepper")
            raise ScenarioError(
                f"{scenario.path}, field 'run.stepper': PBD mode steps the implicit couplings and the incompressible "
                "fidelity with 'implicit_euler' and the explicit coupling with 'explicit_euler'; coupling "
                f"{scenario.coupling!r} with {stepper!r} has no PBD step (unset 'run.stepper', or use mode \"mujoco\")")
        return NetworkBuffers(self)

    def step(self):
        """Advance one step of ``dt`` (``pbd_substeps`` XPBD substeps, one hydraulic step each) in one compiled call;
        returns the report."""
        return self._advance_block(1)[1]

    @property
    def fast(self) -> bool:
        """Whether :meth:`advance` runs whole blocks of many steps in one compiled call (``block`` not switched off).
        The runner then drives this plant in blocks (``sim.run.runner._Loop.blocks``)."""
        return bool(self.block)

    def advance(self, n: int):
        """``n`` steps (stops at the first failed one); returns the last step's report (MujocoPlantFast's interface).

        With :attr:`fast`, in one compiled call (:meth:`_advance_block`); otherwise one :meth:`step` at a time.
        """
        n = int(n)
        record, every = self._record_next if self._record_next is not None else (None, 1)
        self._record_next = None
        self.recorded, self.recorded_finite = 0, True
        report = None
        if self.python_controller is not None:  # blocks of one control period (sim.plants.controllers)
            report = advance_controlled(self, lambda m, rows, ev: self._advance_block(m, rows, ev)[1] if self.fast
                                        else self._steps(m), n, record if self.fast else None, every)
        elif self.fast:
            report = self._advance_block(n, record, every)[1]
        else:
            for _ in range(n):
                report = self.step()
                if not report.success:
                    break
        self.end_finite = self.finite()
        return report

    def _steps(self, n):
        report = None
        for _ in range(n):
            report = self.step()
            if not report.success:
                break
        return report

    def record_row(self, out: np.ndarray) -> None:
        """Write the current state into ``out`` (:attr:`record_width` floats) in the layout the compiled block
        records (``RunRecorder.capture``'s raw row)."""
        state, e, report = self.net_state, self.energy, self.last_report
        kinetic, potential = self.mechanical_energy()
        xpos, xquat = self.body_poses()
        q, qd = self.joint_state()
        if report is None:
            flow, solver = np.zeros(len(self.network.branch_names)), (0.0, 0.0)
        else:
            flow, solver = report.branch_flow, (report.newton_iterations, report.residual)
        np.concatenate((state.node_pressure, q, qd, state.node_oil, state.actuator_position, state.actuator_velocity,
                        self.effort, self.theta, self.control.valve_command, state.valve_spool, self.control.pump_speed,
                        flow, solver, (kinetic, potential, e.pump_work, e.dissipated_hydraulic, e.dissipated_friction,
                                       e.dissipated_mechanical), np.reshape(xpos, -1), np.reshape(xquat, -1),
                        self.controller_state.reshape(-1)), out=out)

    # ------------------------------------------------------------------ record
    record_rows = staticmethod(MujocoPlantFast.record_rows)  # the same rows as MujocoPlantFast.advance records

    @property
    def record_width(self) -> int:
        """Floats per recorded row: ``RunRecorder.capture``'s raw layout for a plant with ``joint_state`` (node
        pressures and oil, scalar-joint positions and rates, 4 per actuator, 2 per valve, 1 per pump and branch,
        2 solver and 6 energy terms, 7 per body)."""
        net, nj = self.network, len(self.scalar_joints)
        return RECORD_ROW.size(n=net.node_count, nq=nj, nv=nj, na=net.actuator_count, nvalve=len(net.valve_names),
                               nstate=net.component_state_count, npump=len(net.pump_names), nb=len(net.branch_names),
                               nbody=self.xmodel.nbody, nctl=self.controller_state.shape[0])

    def record_next(self, record: np.ndarray, every: int = 1) -> None:
        """Make the next :meth:`advance` record the samples after every step whose index becomes a multiple of
        ``every`` (all but its last step; :meth:`record_rows` rows) into the rows of ``record``, from the compiled
        block, as the runner's recorder would capture them (as ``MujocoPlantFast.record_next``).  ``recorded``
        then holds the rows written (fewer when the block stopped early: the caller replays), ``recorded_finite``
        whether their pressures and joints were finite, ``end_finite`` :meth:`finite` after the call."""
        width = self.record_width
        flags = getattr(record, "flags", None)
        if not (isinstance(record, np.ndarray) and record.dtype == np.float64 and record.ndim == 2 and flags.c_contiguous
                and flags.writeable and record.shape[1] == width):
            raise ValueError(f"`record` must be a writable C-contiguous float64 array of shape (rows, {width})")
        if int(every) < 1:
            raise ValueError(f"`every` must be >= 1, got {every!r}")
        self._record_next = (record, int(every))

    def _advance_block(self, n: int, record=None, every: int = 1):
        """Up to ``n`` steps in one compiled call (``pbd_block``: it stops after a failed step); returns (steps done,
        the last step's report or None for no step).

        Same results as ``n`` calls of :meth:`step` to round-off (``tests/test_pbd_block.py``); with ``record``
        the samples of :meth:`record_next`.
        """
        from sim.plants.pbd_block import CLOCK, REC

        ctx = self._block_context()
        rec = ctx["rec"]
        rows = self.record_rows(self.step_index, n, every) if record is not None else 0
        if rows > (0 if record is None else len(record)):
            raise ValueError(f"`record` has {len(record)} rows, {rows} needed")
        rec[:] = 0
        rec[REC.ROWS], rec[REC.EVERY], rec[REC.FIRST] = rows, every, self.step_index
        fc = ctx["frame"]
        solver, st, net, e = self.solver, self.state, self._net, self.energy
        nsub = solver.substeps
        h = self.dt / nsub
        cmd, speed = self._block_inputs(ctx, n, h)
        net.load(self.net_state, e)
        fc["x"][:], fc["v"][:], fc["ell"][:] = self._x, self._v, self._ell  # (the views of fc["actuators"])
        clock = ctx["clock"]
        clock[CLOCK.TIME], clock[CLOCK.NET_TIME] = st.time, net._time
        clock[CLOCK.DISSIPATED], clock[CLOCK.MECHANICAL] = e.dissipated_mechanical, self._mechanical
        hint = ctx["hint"]
        hint[:] = st.qpos_hint
        pmax, pmin, xmax, xmin = ctx["pmax"], ctx["pmin"], ctx["xmax"], ctx["xmin"]
        pmax[:], pmin[:] = self.node_pressure_max, self.node_pressure_min
        xmax[:], xmin[:] = self.actuator_position_max, self.actuator_position_min
        from sim.plants.pbd_block import BLOCK_SINGULAR, BlockTrack, Control, Recording, block
        from sim.plants.pbd_frame import RigidState

        kernel = block(solver.transport_response, solver.articulated_contacts)  # (a dict lookup once compiled)
        done, status = kernel(n, float(self.dt), cmd, speed, net.buffers, RigidState(st.x, st.q, st.v, st.w),
                                     fc["actuators"], BlockTrack(clock, hint, pmax, pmin, xmax, xmin), ctx["plant"], ctx["buffers"],
                                     self._frame_settings(h), Recording(ctx["no_record"] if record is None else record, rec),
                                     self._block_control(ctx, n))
        self.recorded, self.recorded_finite = int(rec[REC.COUNT]), not rec[REC.BAD]
        if status == BLOCK_SINGULAR:
            raise np.linalg.LinAlgError("Matrix is singular.")
        if done == 0:
            return 0, None
        last = done * nsub - 1  # the controls of the last substep taken (as after the hooks)
        self.control.valve_command[:] = cmd[last]
        self.control.pump_speed[:] = speed[last]
        net._time = float(clock[CLOCK.NET_TIME])
        self.net_state, self._report = net.store(e)
        self.last_report = self._report
        e.dissipated_mechanical, self._mechanical = float(clock[CLOCK.DISSIPATED]), float(clock[CLOCK.MECHANICAL])
        self._x, self._v, self._ell = fc["x"].copy(), fc["v"].copy(), fc["ell"].copy()
        self.effort = fc["actuators"].effort.copy()
        self._motor_effort = fc["actuators"].motor_effort.copy()
        self.theta = net.theta.copy()
        self.node_pressure_max, self.node_pressure_min = pmax.copy(), pmin.copy()
        self.actuator_position_max, self.actuator_position_min = xmax.copy(), xmin.copy()
        st.time = float(clock[CLOCK.TIME])
        st.qpos_hint = hint.copy()
        solver.last_forces = []
        self.frame_steps += done
        self.step_index += done
        return done, self._report

    def _block_control(self, ctx, n):
        """The compiled block's ``Control``: the PID table, state and the setpoints of the next ``n`` steps; the
        buffers' qpos/qvel set to the current state (the controllers' joint sensors read them before the first
        frame)."""
        from sim.plants.pbd_block import Control

        bank = self.controllers
        if len(bank):
            qpos, qvel = self._qpos_qvel()
            ctx["buffers"].qpos[:], ctx["buffers"].qvel[:] = qpos, qvel
            if len(ctx.get("setpoint", ())) < n:
                ctx["setpoint"] = np.zeros((max(n, 2 * len(ctx.get("setpoint", ()))), len(bank)))
            bank.setpoint_rows((np.arange(n) + self.step_index) * self.dt, ctx["setpoint"][:n])
            return Control(bank.table, bank.state, ctx["setpoint"])
        return Control(bank.table, bank.state, ctx.setdefault("setpoint", np.zeros((1, 0))))

    def generalized_state(self):
        """(qpos, qvel) of the whole model, MuJoCo's layout, from the bodies' state."""
        return self._qpos_qvel()

    def _block_inputs(self, ctx, n, h):
        """Rows of valve commands and pump speeds for every substep of the next ``n`` steps (step k, substep s:
        row k·substeps + s, at time (step_index + k)·dt + s·h, as ``apply_inputs`` at every substep's start)."""
        nsub = self.solver.substeps
        rows = n * nsub
        if rows > len(ctx["cmd"]):
            size = max(rows, 2 * len(ctx["cmd"]))
            ctx["cmd"] = np.zeros((size, len(self.network.valve_names)))
            ctx["speed"] = np.zeros((size, len(self.network.pump_names)))
        cmd, speed = ctx["cmd"][:rows], ctx["speed"][:rows]
        cmd[:] = self.control.valve_command
        speed[:] = self.control.pump_speed
        plan = self._frame_context()["inputs"]
        if plan:
            frames = (np.arange(n) + self.step_index) * self.dt  # = self.time of each step
            times = (frames[:, None] + np.arange(nsub)[None, :] * h).reshape(-1)
            sample_inputs(plan, times, cmd, speed)
        return cmd, speed

    def _block_context(self):
        """Buffers and constant arguments of the compiled block (made once; see ``sim/plants/pbd_block.py``)."""
        ctx = getattr(self, "_block_ctx", None)
        if ctx is not None:
            return ctx
        from sim.plants.pbd_block import CLOCK, REC, BlockBuffers, BlockPlant, ContactCandidates
        from sim.plants.pbd_frame import Articulated, RigidState
        from sim.xpbd.compiled import ContactRows

        fc = self._frame_context()
        a = fc["articulated"]
        solver, xm = self.solver, self.xmodel
        nb = xm._nb_arrays()
        ng, nq = xm.ngroup, len(nb["qpos0"])
        c = solver._contact_arrays() if len(xm.contact_group) else None
        nc = 0 if c is None else len(c["group"])
        if c is None:
            c = dict(group=np.zeros(0, np.int64), plane=np.zeros(0, np.int64), plane_group=np.zeros(0, np.int64),
                     local=np.zeros((0, 3)), radius=np.zeros(0), plane_origin=np.zeros((0, 3)), plane_normal=np.zeros((0, 3)),
                     out=np.zeros(0, np.int64))
        known = "cg" in c
        rows = [c["cg"], c["cvec"], c["crad"], c["mu"], c["solref"], c["solimp"], c["condim"], c["tran"]] if known else [
            np.zeros((nc, 2), np.int64), np.zeros((nc, 4, 3)), np.zeros(nc), np.zeros(nc), np.zeros((nc, 2)),
            np.zeros((nc, 5)), np.zeros(nc, np.int64), np.zeros(nc)]
        rows = [np.ascontiguousarray(r) for r in rows]
        candidates = ContactCandidates(
            _i64(c["group"]), _i64(c["plane"]), _i64(c["plane_group"]), _c64(c["local"]), _c64(c["radius"]),
            _c64(c["plane_origin"]), _c64(c["plane_normal"]), float(solver.contact_margin))
        plant = BlockPlant(solver._flat, nb["tree"], nb["root"], nb["from_root_quat"], nb["from_root_pos"],
                           nb["group_mass"], nb["group_inertia"], candidates, ContactRows(*rows), fc["articulated_model"],
                           bool(self._tree), fc["actuation"], _i64(xm.jnt_qposadr[self.scalar_joints]),
                           _i64(xm.jnt_dofadr[self.scalar_joints]))
        buffers = BlockBuffers(
            RigidState(np.zeros((ng, 3)), np.zeros((ng, 4)), np.zeros((ng, 3)), np.zeros((ng, 3))),
            ContactRows(*(np.zeros_like(r) for r in rows)), np.zeros(nc, np.int64),
            Articulated(*(np.zeros_like(getattr(a, name)) for name in Articulated._fields)),
            np.zeros((xm.nbody, 3)), np.zeros((xm.nbody, 4)), np.zeros(nq), np.zeros(xm.nv))
        ctx = dict(frame=fc, plant=plant,
                   buffers=buffers,
                   cmd=np.zeros((0, len(self.network.valve_names))), speed=np.zeros((0, len(self.network.pump_names))),
                   clock=np.zeros(len(CLOCK)), hint=np.zeros(nq), pmax=np.zeros(self.network.node_count),
                   pmin=np.zeros(self.network.node_count), xmax=np.zeros(self.network.actuator_count),
                   xmin=np.zeros(self.network.actuator_count), rec=np.zeros(len(REC), np.int64),
                   no_record=np.zeros((0, self.record_width)))
        self._block_ctx = ctx
        return ctx

    def snapshot(self):
        """What :meth:`advance` changes besides what the runner's ``_Snapshot`` keeps (step index, network state,
        ledger, controls, efforts, extremes): the body state, the actuator motion and the mechanical-energy
        baseline; for :meth:`restore`."""
        st = self.state
        return (st.x.copy(), st.q.copy(), st.v.copy(), st.w.copy(), st.qpos_hint.copy(), st.time, self._x, self._v,
                self._ell, self._mechanical, self.frame_steps)

    def restore(self, snap) -> None:
        """Back to a :meth:`snapshot` (the runner restores the step index, network state and ledger)."""
        st = self.state
        x, q, v, w, hint, st.time, self._x, self._v, self._ell, self._mechanical, self.frame_steps = snap
        st.x[:], st.q[:], st.v[:], st.w[:] = x, q, v, w
        st.qpos_hint = hint.copy()
        self.__dict__.pop("_observation_memo", None)

    def articulated(self):
        """Per-step joint-space data for the solver and the coupling (trees of hinges and slides; else None).

        Sets ``self._mobility`` (rows, ngroup, 6): the displacement of each
        rigid group's centre of mass [m] and its rotation vector [rad] per unit
        row multiplier, the body motion of Δq = M⁻¹·Jᵀ (``SubstepInputs.row_mobility``):
        each iteration then solves the rows with the response of the whole
        mechanism rather than of the free bodies, whereas with free-body masses
        one Gauss-Seidel iteration leaves a stiff row (oil column, seal-stiction
        slope) far below its law and a loaded boom sinks.
        ``self._group_gravity`` (ngroup, 6): the group accelerations of
        q̈ = M⁻¹·Q_gravity (``SubstepInputs.group_gravity``), so the prediction
        does not let every body fall freely and leave the load to the joint
        projection (which, in one pass, leaves load-dependent joint errors
        that the stiff rows turn into pressure noise).
        ``self._effective_mass``: 1/(J·M⁻¹·Jᵀ)ᵢᵢ per actuator [kg or kg·m²]
        (the coupling's θ choice / the incompressible law), and
        ``self._motor_inverse_inertia``: (M⁻¹)ⱼⱼ of each motor joint.
        Computed once per step (the pose changes little within it); M holds the
        armature the XPBD model carries (``XpbdModel.jnt_armature``), not joint damping or contacts.
        """
        self._mobility = self._group_gravity = self._effective_mass = self._motor_response = None
        self._motor_inverse_inertia = np.zeros(len(self.motors))
        if not self._tree:
            return
        ctx = self._articulated_context()
        a = ctx["articulated"]
        st = self.state
        if not ctx["articulated_kernel"](_c64(st.x), _c64(st.q), ctx["articulated_model"], a):
            return  # singular mass matrix: no articulated data
        self._effective_mass = a.effective_mass.copy()
        self._motor_inverse_inertia = a.motor_inverse_inertia.copy()
        self._group_gravity = a.group_gravity.copy() if GRAVITY_ARTICULATED else None
        self._mobility = a.mobility.copy() if len(self.cylinders) else None
        self._motor_response = a.motor_response.copy() if len(self.motors) and GRAVITY_ARTICULATED else None

    def _frame_settings(self, h):
        """The compiled frame's ``pbd_frame.FrameSettings`` for substeps of ``h`` [s]."""
        from sim.plants.pbd_frame import FrameSettings

        solver, net = self.solver, self._net
        return FrameSettings(float(h), solver.substeps, solver.iterations, solver.symmetric, solver.linear_damping,
                             solver.angular_damping, solver.soft_contacts, solver.pyramid_friction,
                             solver.velocity_sweeps, net.kind, net.scheme, net.blend, self.naive)

    def _frame_context(self):
        """The actuators' layout and state of the compiled frame and the input plan (made once)."""
        ctx = getattr(self, "_frame_ctx", None)
        if ctx is not None:
            return ctx
        from sim.plants.pbd_frame import OUT as FRAME_OUT
        from sim.plants.pbd_frame import Actuation, ActuatorState

        xm, net = self.xmodel, self.network
        na, nr, nm = net.actuator_count, len(self.cylinders), len(self.motors)
        rg, rvec = self.solver._flat_rows()
        mb = np.array([int(xm.jnt_body[j]) for j in self.motor_joint], np.int64)
        actuation = Actuation(
            cyl=_i64(self.cylinders), closed=_c64(self.closed_length), row_group=rg, row_vec=_c64(rvec),
            mot=_i64(self.motors), gear=_c64(self.motor_gear), mjoint=_i64(self.motor_joint),
            mhinge=np.ascontiguousarray(self._hinge[self.motor_joint], np.bool_), mbody=mb,
            mparent=np.array([int(xm.body_parent[b]) for b in mb], np.int64),
            maxis=_c64(np.asarray(self._axis_inertial).reshape(-1, 3)[self.motor_joint].reshape(-1, 3)),
            morigin=_c64(np.asarray(self._origin_inertial).reshape(-1, 3)[mb].reshape(-1, 3)), islands=self._islands())
        actuators = ActuatorState(x=np.zeros(na), v=np.zeros(na), ell=np.zeros(nr), effort=np.zeros(na),
                                  motor_effort=np.zeros(nm), out=np.zeros(len(FRAME_OUT)))
        ctx = dict(inputs=input_plan(net, self.control, self.scene.scenario.inputs), x=actuators.x, v=actuators.v,
                   ell=actuators.ell, actuators=actuators, actuation=actuation)
        ctx.update(self._articulated_context())
        self._frame_ctx = ctx
        return ctx

    def _articulated_context(self):
        """The compiled ``articulated`` kernel (``pbd_frame._articulated``), its ``ArticulatedModel`` and its output
        buffers ``Articulated`` (made once)."""
        ctx = getattr(self, "_articulated_ctx", None)
        if ctx is not None:
            return ctx
        from sim.plants.pbd_frame import Articulated, ArticulatedModel, articulated

        xm, na = self.xmodel, self.network.actuator_count
        ng, nr, nm = xm.ngroup, len(self.cylinders), len(self.motors)
        ctx = dict(articulated_kernel=articulated())
        ctx["articulated_model"] = ArticulatedModel(
            iquat=_c64(xm.body_iquat), ipos=_c64(xm.body_ipos), jnt_body=_i64(xm.jnt_body),
            jnt_axis=_c64(xm.jnt_axis), jnt_pos=_c64(xm.jnt_pos), hinge=np.ascontiguousarray(self._hinge, np.bool_),
            subtree=np.ascontiguousarray(self._subtree, np.bool_), body_mass=_c64(self._body_mass),
            inertia=_c64(self._body_inertia * (self._body_mass > 0)[:, None]), armature=_c64(xm.jnt_armature),
            gravity=_c64(xm.gravity), site_body=_i64(xm.site_body), site_pos=_c64(xm.site_pos_inertial),
            row_sites=np.ascontiguousarray(self._row_sites, np.int64), cyl=_i64(self.cylinders), mot=_i64(self.motors),
            mot_dof=_i64(xm.jnt_dofadr[self.motor_joint]), gear=_c64(self.motor_gear), body_group=_i64(xm.body_group),
            group_mass=_c64(xm.group_mass), group_root=_i64(xm.group_root),
            group_dynamic=np.ascontiguousarray(xm.group_dynamic, np.bool_), islands=self._islands())
        ctx["articulated"] = Articulated(mobility=np.zeros((nr, ng, 6)), group_gravity=np.zeros((ng, 6)),
                                         motor_response=np.zeros((nm, ng, 6)), motor_inverse_inertia=np.zeros(nm),
                                         effective_mass=np.zeros(na))
        self._articulated_ctx = ctx
        return ctx

    def _islands(self):
        """The mechanism's ``compiled.Islands`` (kinematic trees joined by the cylinder rows; made once): the
        articulated response and the rows' block are solved island by island."""
        isl = getattr(self, "_islands_memo", None)
        if isl is None:
            from sim.xpbd.compiled import islands

            xm = self.xmodel
            isl = self._islands_memo = islands(xm.body_parent, xm.body_group, xm.jnt_body,
                                               np.asarray(xm.site_body)[self._row_sites], self.motor_joint)
        return isl

    # ------------------------------------------------------------- observation
    def _state_key(self):
        """Identity of the current body state (the observations below are memoised on it: the step and the
        log sample of the same instant share them)."""
        s = self.state
        return (id(s), s.x.tobytes(), s.q.tobytes(), s.v.tobytes(), s.w.tobytes())

    def _memo(self, name, compute):
        key = self._state_key()
        memo = self.__dict__.setdefault("_observation_memo", {})
        hit = memo.get(name)
        if hit is not None and hit[0] == key:
            return hit[1]
        value = compute()
        memo[name] = (key, value)
        return value

    def mechanical_energy(self):
        """Kinetic and potential (gravity) energy of the bodies [J] at the current state (XPBD model)."""
        return self._memo("energy", lambda: self.xmodel.energies(self.state))

    def _qpos_qvel(self):
        return self._memo("qpos_qvel", lambda: self.xmodel.qpos_qvel(self.state))

    def joint_state(self):
        """(positions, velocities) of the scalar joints [rad or m, rad/s or m/s]."""
        xm = self.xmodel
        qpos, qvel = self._qpos_qvel()
        return qpos[xm.jnt_qposadr[self.scalar_joints]], qvel[xm.jnt_dofadr[self.scalar_joints]]

    def body_poses(self):
        """World positions [m] (nbody, 3) and quaternions (w, x, y, z) (nbody, 4) of the MuJoCo body frames."""
        return self.xmodel.body_frames(self.state)

    def finite(self) -> bool:
        """Whether the body state and the node pressures are finite (a sum is finite iff every term is, barring
        overflow beyond 1e308, itself a blow-up; as the recorder's ``captured_finite``)."""
        s = self.state
        return math.isfinite(float(s.x.sum()) + float(s.q.sum()) + float(s.v.sum()) + float(s.w.sum())
                             + float(self.net_state.node_pressure.sum()))


def _writeable(a, dtype):
    """``a`` as a C-contiguous, writeable array of ``dtype`` (one numba signature: the model's arrays are read-only)."""
    a = np.ascontiguousarray(a, dtype=dtype)
    return a if a.flags.writeable else a.copy()


def _c64(a):
    """:func:`_writeable` float64."""
    return _writeable(a, np.float64)


def _i64(a):
    """:func:`_writeable` int64."""
    return _writeable(a, np.int64)


def fast_path(plant: PbdPlant) -> str:
    """How ``plant`` is stepped (one line, MJCF names): compiled blocks of steps or compiled steps one at a time
    (``block=False``), and whether the mechanism has the articulated (joint-space) response or plain XPBD's
    free-body one, and why."""
    xm = plant.xmodel
    path = ("compiled blocks of steps (the fastest path)" if plant.fast
            else "compiled steps one at a time (blocks switched off: block=False)")
    if not plant._tree:
        other = [f"'{xm.jnt_names[j]}'" for j in range(xm.njnt) if int(xm.jnt_type[j]) not in SCALAR_JOINTS]
        path += ("; joints " + ", ".join(other) + " are not hinges or slides" if other
                 else "; the joints do not form a tree of hinges and slides")
        path += ": free-body (plain XPBD) response, no articulated one"
    return path


def make_pbd_plant(scene: Scene, *, block: bool = True) -> PbdPlant:
    """The plant for modes "pbd" (the scenario's coupling, default implicit) and "pbd-naive" (explicit, the seed's
    scheme); ``block=False`` keeps :meth:`PbdPlant.advance` (and so the runner) one step at a time."""
    mode = scene.scenario.mode
    if mode not in ("pbd", "pbd-naive"):
        raise ValueError(f"make_pbd_plant: mode {mode!r} is not a PBD mode")
    return PbdPlant(scene, naive=mode == "pbd-naive", block=block)


__all__ = ["PbdPlant", "make_pbd_plant"]
