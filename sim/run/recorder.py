"""What a run logs: the topics, their schemas, and one sample per logged step.

The same topics are written by every plant (MuJoCo or PBD), so two logs of a
scenario compare field by field.  Every numeric topic is a ROS 2 message in CDR
(schema encoding ``ros2msg``, see :mod:`sim.io.mcap_log`) with a
``builtin_interfaces/Time timestamp`` and SI-suffixed float64 fields (units in each
field's comment in the schema and in the channel metadata); the events and the
scene are JSON:

``/hydroplant/joint_states``       ``foxglove_msgs/msg/JointStates`` of the scalar joints
``/hydroplant/cylinders/<name>``   ``hydroplant_msgs/msg/CylinderState``: stroke, speed, pressures (also in bar, for
                                   plots), forces, stiffness
``/hydroplant/motors/<name>``      ``hydroplant_msgs/msg/MotorState``: angle, speed, port pressures, torque
``/hydroplant/valves/<name>``      ``hydroplant_msgs/msg/ValveState``: command and spool
``/hydroplant/pumps/<name>``       ``hydroplant_msgs/msg/PumpState``: speed, flow, outlet pressure, power
``/hydroplant/nodes``              ``hydroplant_msgs/msg/NodePressures``: ``pressure_pa.<node>`` of every node
``/hydroplant/flows``              ``hydroplant_msgs/msg/BranchFlows``: ``flow_m3ps.<branch>`` of every branch
``/hydroplant/component_states``   ``hydroplant_msgs/msg/ComponentStates``: ``state.<component>_<state>`` of every
                                   component with states of its own (a relief's poppet lift and speed, …)
``/hydroplant/controllers/<name>`` ``hydroplant_msgs/msg/ControllerState``: a PID's output, error, integrator,
                                   derivative term, measurement and setpoint (:mod:`hydraulics.controllers`)
``/hydroplant/energy``             ``hydroplant_msgs/msg/Energy``: energy terms and the balance residual
``/hydroplant/solver``             ``hydroplant_msgs/msg/Solver``: Newton iterations, residual, coupling θ
``/tf``                            ``foxglove_msgs/msg/FrameTransforms``: body poses for Foxglove's 3D panel, at the
                                   samples whose step is a multiple of ``tf_every`` (a display rate, see
                                   :attr:`sim.io.scenario.Scenario.tf_every`); the joints they follow are on every sample
``/hydroplant/scene``              ``foxglove.SceneUpdate`` (JSON): the bodies' geometry, once
``/hydroplant/scene/cylinders``    ``foxglove_msgs/msg/SceneUpdate`` (CDR): each cylinder's barrel and rod between its
                                   pins, barrel coloured by cap pressure, at the ``/tf`` samples
``/hydroplant/events``             ``foxglove.Log`` (JSON): divergence and other events

Node and branch names become ROS 2 field names with :func:`field_name`
(``"boom_valve.P-A"`` -> ``boom_valve_p_a``).
"""

from __future__ import annotations

import functools
import math
import re

import numpy as np

from hydraulics.controllers import LOGGED as CONTROLLER_COLUMNS, STATE_COLUMNS as CONTROLLER_STATE_COLUMNS
from sim.io.record_row import RECORD_ROW
from hydraulics.energy import stored_energy_at

from sim.io.foxglove_scene import CylinderPins, CylinderScene, FrameTransformsChannel, log_scene
from sim.io.mcap_log import LogLevel, LogWriter, flat_schema, log_message, log_schema


_sum = np.add.reduce


def field_name(name: str) -> str:
    """A component or node name as a ROS 2 field name: lower case, digits and single underscores,
    starting with a letter (``"boom_valve.P-A"`` -> ``"boom_valve_p_a"``, ``"2nd"`` -> ``"n_2nd"``)."""
    text = re.sub(r"_+", "_", re.sub(r"[^a-z0-9]", "_", name.lower())).strip("_")
    return text if text[:1].isalpha() else f"n_{text}".rstrip("_")


def _named_fields(prefix: str, names, description: str) -> dict[str, str]:
    """``{prefix.field_name(name): description}`` for every name, refusing two names with the same field name."""
    fields: dict[str, str] = {}
    for name in names:
        key = f"{prefix}.{field_name(name)}"
        if key in fields:
            raise ValueError(f"two components are both logged as field {key!r}; rename one (e.g. {name!r})")
        fields[key] = description.format(name)
    return fields


CYLINDER_FIELDS = {
    "position_m": "Rod extension from fully retracted [m]",
    "velocity_mps": "Rod speed, positive extending [m/s]",
    "p_cap_pa": "Cap-side absolute pressure [Pa]",
    "p_rod_pa": "Rod-side absolute pressure [Pa]",
    "force_n": "Force applied to the mechanics, positive extending [N]",
    "pressure_force_n": "p_cap*A_cap - p_rod*A_rod - p_amb*(A_cap - A_rod) at the end of the step [N]",
    "stiffness_npm": "Oil-column stiffness beta*(A_cap^2/V_cap + A_rod^2/V_rod) [N/m]",
    "theta": "Implicit weight of the coupling this step [-]",
    "p_cap_bar": "Cap-side absolute pressure in bar, p_cap_pa / 1e5 (for plots) [bar]",
    "p_rod_bar": "Rod-side absolute pressure in bar, p_rod_pa / 1e5 (for plots) [bar]",
}
PA_PER_BAR = 1e5
MOTOR_FIELDS = {
    "angle_rad": "Motor shaft angle [rad]",
    "speed_radps": "Motor shaft speed [rad/s]",
    "p_a_pa": "Port A absolute pressure [Pa]",
    "p_b_pa": "Port B absolute pressure [Pa]",
    "torque_nm": "Shaft torque applied to the mechanics [N*m]",
}
VALVE_FIELDS = {"command": "Spool command [-], -1..1 (a variable orifice's opening: 0..1)",
                "spool": "Spool position [-], -1..1 (a variable orifice's opening: 0..1)"}
PUMP_FIELDS = {
    "speed_rps": "Shaft speed [rev/s]",
    "flow_m3ps": "Delivered flow [m^3/s]",
    "p_out_pa": "Outlet absolute pressure [Pa]",
    "power_w": "Hydraulic power delivered [W]",
}
ENERGY_FIELDS = {
    "kinetic_j": "Kinetic energy of the bodies [J]",
    "potential_j": "Gravitational (and spring) potential energy [J]",
    "oil_j": "Elastic energy stored in the oil [J]",
    "pump_work_j": "Cumulative pump work [J]",
    "dissipated_hydraulic_j": "Cumulative loss in valves, orifices, reliefs, leaks [J]",
    "dissipated_friction_j": "Cumulative cylinder seal friction loss [J]",
    "dissipated_mechanical_j": "Cumulative loss in joints and contacts [J]",
    "residual_j": "Pump work - delta(kinetic+potential+oil) - dissipation: numerical dissipation [J]",
}
CONTROLLER_FIELDS = dict(zip(CONTROLLER_COLUMNS, (
    "Held output: valve command [-] or pump speed [rev/s]",
    "Error setpoint - measurement of the last sample [sensor unit: m, m/s, rad, rad/s, Pa, m^3/s or rev/s]",
    "Integral term, in the output's unit",
    "Derivative term, in the output's unit",
    "Measurement of the last sample [sensor unit]",
    "Setpoint of the last sample [sensor unit]",
)))
SOLVER_FIELDS = {
    "newton_iterations": "Newton iterations of the hydraulic step [-]",
    "residual_pa": "Final Newton residual expressed as pressure [Pa]",
    "theta_min": "Smallest implicit weight over actuators [-]",
}

# The ROS 2 message types of the fixed topics (the node and flow types depend on the circuit)
CYLINDER_STATE = flat_schema("hydroplant_msgs/msg/CylinderState", CYLINDER_FIELDS)
MOTOR_STATE = flat_schema("hydroplant_msgs/msg/MotorState", MOTOR_FIELDS)
VALVE_STATE = flat_schema("hydroplant_msgs/msg/ValveState", VALVE_FIELDS)
PUMP_STATE = flat_schema("hydroplant_msgs/msg/PumpState", PUMP_FIELDS)
ENERGY = flat_schema("hydroplant_msgs/msg/Energy", ENERGY_FIELDS)
SOLVER = flat_schema("hydroplant_msgs/msg/Solver", SOLVER_FIELDS)
CONTROLLER_STATE = flat_schema("hydroplant_msgs/msg/ControllerState", CONTROLLER_FIELDS)

# samples captured before their fields are derived and written, as one batch (the runner also derives at every periodic
# flush of the log): the runner's 2000-step blocks at 1 kHz (sim.run.runner.block_steps), the 2 s flush interval, so
# that logging every step runs whole blocks, each handed to the log as one batch (the run's log takes batches of this
# size, sim.run.runner.run)
RING_SIZE = 2000


@functools.lru_cache(maxsize=16)
def _record_offsets(dims: tuple) -> dict:
    """:meth:`RECORD_ROW.offsets <hydraulics.layout.Layout.offsets>` of the dimensions ``dims`` (sorted (name, value)
    pairs), worked out once per scene size (it evaluates the layout's expressions field by field)."""
    return RECORD_ROW.offsets(**dict(dims))


class RunRecorder:
    """Registers the channels of a plant on a :class:`LogWriter` and logs samples in batches.

    Per sample, :meth:`capture` copies only the plant's raw state (pressures, oil,
    actuator motion, efforts, controls, flows, energy ledger, joints, body poses)
    into a ring of ``ring_size`` rows (at most :data:`RING_SIZE` and the log's batch); a plant that records
    samples inside its blocks (:class:`~sim.plants.mujoco_fast.MujocoPlantFast`, same row layout:
    ``record_row``) writes them straight into the ring instead
    (:meth:`record_target`, then :meth:`commit_recorded`).  :meth:`derive` computes what the
    run's checks need of all pending samples at once (node volumes, stored oil energy, energy
    residual); :meth:`push` hands the ring itself to the log's :class:`~sim.io.mcap_log.Frame`
    (:meth:`~sim.io.log_writer.Frame.defer`; the next samples go into a spare ring), whose
    batch computes the other logged fields (chamber stiffness, pressure forces, pump powers,
    the cylinder scene) from it on the log's writer thread while the run goes on.  Both use
    the same functions a single sample uses: the node relations of
    :class:`~hydraulics.network.NetworkModel`, :func:`hydraulics.energy.stored_energy_at`,
    which broadcast over the rows, so values equal the per-sample ones to round-off, and
    the same whichever thread computes them.  Pending samples are pushed when the log
    closes (:meth:`LogWriter.on_close`), so an interrupted run keeps every sample it
    captured.

    ``tf_every`` [steps, ≥ 1]: ``/tf`` is written for the samples whose step index is a
    multiple of it (1: every sample); every other topic takes every sample.
    """

    def __init__(self, log: LogWriter, plant, *, ring_size: int | None = None, tf_every: int = 1):
        self.log = log
        self.plant = plant
        net = plant.network
        si = {"units": "SI"}
        self.pump_branches = net.pump_branches
        node_fields = _named_fields("pressure_pa", net.node_names, "Absolute pressure of node {} [Pa]")
        flow_fields = _named_fields("flow_m3ps", net.branch_names, "Flow of branch {}, positive from its first port [m^3/s]")
        own = len(net.valve_names)  # the component states after the valves' spools: the stateful components' own
        state_fields = {f"state.{field_name(name)}": f"State {name} of its component [{unit}]" for name, unit in
                        zip(net.component_state_names[own:], net.component_state_units[own:])}
        # One frame row per sample holds every columnar topic, /tf included (its channel reads xpos.ravel() then
        # xquat.ravel(), see FrameTransformsChannel, on the rows at multiples of tf_every): one commit per sample,
        # so an interrupt never splits a sample.
        nj, ncyl, nmot = len(plant.joint_names), len(net.cylinder_actuator), len(net.motor_actuator)
        nvalve, npump, nnode, nflow = len(net.valve_names), len(net.pump_names), len(node_fields), len(flow_fields)
        nbody = plant.model.nbody
        sizes = {"joints": 3 * nj, "cylinders": ncyl * len(CYLINDER_FIELDS), "motors": nmot * len(MOTOR_FIELDS),
                 "valves": nvalve * len(VALVE_FIELDS), "pumps": npump * len(PUMP_FIELDS), "nodes": nnode, "flows": nflow,
                 "states": len(state_fields), "energy": len(ENERGY_FIELDS), "solver": len(SOLVER_FIELDS),
                 "xpos": 3 * nbody, "xquat": 4 * nbody}
        pins = CylinderPins.of_scene(plant.scene) if ncyl else None
        sizes["cylinder_scene"] = CylinderScene.width(pins) if ncyl else 0
        bank = getattr(plant, "controllers", None)
        self._controller_names = tuple(bank.names) if bank is not None else ()
        nctl = len(self._controller_names)
        sizes["controllers"] = nctl * len(CONTROLLER_FIELDS)
        start = np.cumsum([0, *sizes.values()])
        block = {name: slice(int(start[i]), int(start[i + 1])) for i, name in enumerate(sizes)}
        self._block = block
        frame = self.frame = log.frame(int(start[-1]))

        def columns(name, index, width):
            first = block[name].start + index * width
            return np.arange(first, first + width)

        self.joints = (  # a scene without joints (a test bench of the circuit alone) has no joint states
            frame.joint_states_channel("/hydroplant/joint_states", plant.joint_names,
                                       columns=np.arange(block["joints"].start, block["joints"].stop), metadata=si)
            if nj else None
        )
        def per_item(kind, schema, fields, names):
            """One channel /hydroplant/<kind>/<name> per named item, on its columns of block ``kind``."""
            return [frame.channel(f"/hydroplant/{kind}/{name}", schema, fields=list(fields),
                                  columns=columns(kind, i, len(fields)), metadata=si)
                    for i, name in enumerate(names)]

        self.cylinders = per_item("cylinders", CYLINDER_STATE, CYLINDER_FIELDS,
                                  [net.actuator_names[a] for a in net.cylinder_actuator])
        self.motors = per_item("motors", MOTOR_STATE, MOTOR_FIELDS, [net.actuator_names[a] for a in net.motor_actuator])
        self.valves = per_item("valves", VALVE_STATE, VALVE_FIELDS, net.valve_names)
        self.pumps = per_item("pumps", PUMP_STATE, PUMP_FIELDS, net.pump_names)
        self.controllers = per_item("controllers", CONTROLLER_STATE, CONTROLLER_FIELDS, self._controller_names)
        self.nodes = frame.channel("/hydroplant/nodes", flat_schema("hydroplant_msgs/msg/NodePressures", node_fields),
                                   fields=list(node_fields), columns=columns("nodes", 0, nnode), metadata=si)
        self.flows = (
            frame.channel("/hydroplant/flows", flat_schema("hydroplant_msgs/msg/BranchFlows", flow_fields),
                          fields=list(flow_fields), columns=columns("flows", 0, nflow), metadata=si)
            if flow_fields else None
        )
        self.states = (
            frame.channel("/hydroplant/component_states",
                          flat_schema("hydroplant_msgs/msg/ComponentStates", state_fields), fields=list(state_fields),
                          columns=columns("states", 0, len(state_fields)), metadata=si)
            if state_fields else None
        )
        self.energy = frame.channel("/hydroplant/energy", ENERGY, fields=list(ENERGY_FIELDS),
                                    columns=columns("energy", 0, len(ENERGY_FIELDS)), metadata=si)
        self.solver = frame.channel("/hydroplant/solver", SOLVER, fields=list(SOLVER_FIELDS),
                                    columns=columns("solver", 0, len(SOLVER_FIELDS)), metadata=si)
        self.events = log.channel("/hydroplant/events", "foxglove.Log", log_schema())
        self.tf = FrameTransformsChannel(log, plant.model) if nbody > 1 else None  # the world alone moves nowhere
        if self.tf is not None:
            frame.adopt(self.tf.channel, np.arange(block["xpos"].start, block["xquat"].stop), every=tf_every)
        log_scene(log, plant.model)
        self.cylinder_scene = CylinderScene(frame, pins, block["cylinder_scene"], every=tf_every) if ncyl else None
        # index arrays of the samples (one numpy gather per topic family, no per-field Python)
        self._cyl = np.asarray(net.cylinder_actuator, dtype=np.intp)
        self._cyl_cap = np.asarray(net.cylinder_cap_node, dtype=np.intp)
        self._cyl_rod = np.asarray(net.cylinder_rod_node, dtype=np.intp)
        self._mot = np.asarray(net.motor_actuator, dtype=np.intp)
        self._mot_a = np.asarray(net.motor_a_node, dtype=np.intp)
        self._mot_b = np.asarray(net.motor_b_node, dtype=np.intp)
        self._pump_to = np.asarray(net.branch_to[self.pump_branches], dtype=np.intp)
        self._pump_from = np.asarray(net.branch_from[self.pump_branches], dtype=np.intp)
        self._no_flow = np.zeros(len(net.branch_names))
        self._no_controllers = np.zeros(0)
        self._nj = nj
        # The ring of raw samples: per sample one row of the plant's raw state, copied by one
        # np.concatenate; everything derived (volumes, stiffness, stored energy, efforts, pump
        # powers) is computed per batch in derive().
        # (node pressures and joints first and adjacent: captured_finite() sums one slice)
        # (sim.io.record_row.RECORD_ROW; "joints": its qpos and qvel, "poses": its xpos and xquat)
        # A MuJoCo plant's joints are read as the whole qpos/qvel (two plain copies) and selected per batch
        from sim.plants.mujoco import MujocoPlant

        self._mj = getattr(type(plant), "joint_state", None) is MujocoPlant.joint_state
        nq = nv = nj
        if self._mj:
            m = plant.model
            nq, nv = m.nq, m.nv
            self._joint_columns = np.concatenate([m.jnt_qposadr[plant.scalar_joints],
                                                  m.nq + m.jnt_dofadr[plant.scalar_joints]]).astype(np.intp)
        raw_dims = dict(n=nnode, nq=nq, nv=nv, na=net.actuator_count, nvalve=nvalve, nstate=net.component_state_count,
                        npump=npump, nb=nflow, nbody=nbody, nctl=nctl)
        self._rawcols = {name: slice(*span) for name, span in _record_offsets(tuple(sorted(raw_dims.items()))).items()}
        b = self._rawcols
        b["joints"], b["poses"] = slice(b["qpos"].start, b["qvel"].stop), slice(b["xpos"].start, b["xquat"].stop)
        capacity = max(1, min(RING_SIZE, RING_SIZE if ring_size is None else int(ring_size), log._batch_size))
        self._raw = np.zeros((capacity, max(span.stop for span in b.values())))  # (the last field stops at the size)
        self._raw_steps = np.zeros(capacity, dtype=np.int64)
        self._spare_rings: list[tuple[np.ndarray, np.ndarray]] = []  # rings whose rows are in the log, to fill again
        self._counting = np.arange(capacity, dtype=np.int64)
        self._nbody = nbody
        self._batch: tuple = ()  # derive()'s node volumes, oil energy and energy residual of the pending samples
        self._pending = self._derived = 0
        self.last: dict = {}
        if self._mj:
            d = plant.data
            self._mj_views = (d.qpos, d.qvel, d.xpos.reshape(-1), d.xquat.reshape(-1))
            assert all(np.shares_memory(v, a) for v, a in zip(self._mj_views[2:], plant.body_poses()))
        self._state_end = self._rawcols["joints"].stop  # node pressures, qpos, qvel: what MujocoPlant.finite() checks
        # A plant that records rows inside its blocks (MujocoPlantFast.advance(n, record, every), PbdPlant's
        # record_next) writes this same raw layout (MujocoPlantFast.record_row), straight into the ring.
        self.records = callable(getattr(plant, "record_next", None)) and getattr(plant, "record_width", None) == self._raw.shape[1]
        assert self._rawcols["p"].start == 0 and self._rawcols["joints"].start == self._rawcols["p"].stop
        log.on_close(self.push_pending)

    def event(self, step_index: int, level: LogLevel, text: str) -> None:
        """Write a foxglove.Log event (divergence, warnings)."""
        self.events.write(step_index, log_message(level, text))

    # ------------------------------------------------------------------ sampling
    def sample(self, step_index: int) -> dict:
        """Log one sample now (capture, derive, write); returns its energy terms (see :meth:`push`).

        The batched form is :meth:`capture` + :meth:`derive` + :meth:`push`; this is the three
        in a row, for callers that log rarely.
        """
        self.capture(step_index)
        self.derive()
        self.push()
        return self.last

    def capture(self, step_index: int) -> bool:
        """Copy the raw state of the plant for a sample at ``step_index`` into the ring; nothing is derived.

        Returns True when the pending samples should be derived and pushed now: the ring is
        full, or the sample crosses the log's next periodic flush (so the chunk that flush
        writes holds every sample before it, as when samples went straight to the log).
        """
        plant = self.plant
        state = plant.net_state
        kinetic, potential = plant.mechanical_energy()  # refreshes the kinematics body_poses() reads
        if self._mj:  # views of the MjData arrays, made once (MjData never moves them)
            q, qd, xpos, xquat = self._mj_views
        else:
            xpos, xquat = plant.body_poses()
            xpos, xquat = xpos.reshape(-1), xquat.reshape(-1)
            q, qd = plant.joint_state()
        control = plant.control
        report = plant.last_report
        e = plant.energy
        if report is None:
            flow, solver = self._no_flow, (0.0, 0.0)
        else:
            flow = report.branch_flow if len(report.branch_flow) else self._no_flow
            solver = (report.newton_iterations, report.residual)
        n = self._pending
        np.concatenate((state.node_pressure, q, qd, state.node_oil, state.actuator_position, state.actuator_velocity,
                        plant.effort, plant.theta, control.valve_command, state.valve_spool, control.pump_speed, flow,
                        solver, (kinetic, potential, e.pump_work, e.dissipated_hydraulic, e.dissipated_friction,
                                 e.dissipated_mechanical), xpos, xquat, self._controller_state()), out=self._raw[n])
        self._raw_steps[n] = step_index
        self._pending = n + 1  # last: an interrupt above leaves no half-captured sample
        return self._pending == len(self._raw) or step_index >= self.log._next_flush_step

    def _controller_state(self) -> np.ndarray:
        """The plant's controller states, flat (none without controllers)."""
        return self.plant.controller_state.reshape(-1) if self._controller_names else self._no_controllers

    @property
    def room(self) -> int:
        """Free rows of the ring: samples that can be captured or recorded before a :meth:`push`."""
        return len(self._raw) - self._pending

    def record_target(self, rows: int) -> np.ndarray:
        """The next ``rows`` free rows of the ring (a C-contiguous view), for a plant to record raw samples into
        (``plant.advance(n, record=..., every=...)``, see :attr:`records`); then :meth:`commit_recorded`."""
        if not self.records:
            raise TypeError("this plant does not record raw rows (no record_width matching the recorder's layout)")
        if rows > self.room:
            raise ValueError(f"{rows} rows requested, {self.room} free in the ring")
        return self._raw[self._pending:self._pending + rows]

    def commit_recorded(self, first: int, every: int, count: int, *, checked: bool = False) -> bool:
        """Accept the ``count`` rows a plant recorded into :meth:`record_target` as samples at steps ``first``,
        ``first + every``, ..., if their state is finite (node pressures, qpos, qvel, as :meth:`captured_finite`;
        ``checked``: the plant has checked it); returns whether they were accepted."""
        if count <= 0:
            return True
        n = self._pending
        if not checked and not math.isfinite(_sum(self._raw[n:n + count, :self._state_end], axis=None)):
            return False
        if count == 1:
            self._raw_steps[n] = first
        else:
            steps = self._raw_steps[n:n + count]
            np.multiply(self._counting[:count], every, out=steps)
            steps += first
        self._pending = n + count
        return True

    @property
    def due(self) -> bool:
        """Whether the pending samples should be derived and pushed now (as :meth:`capture` returns)."""
        n = self._pending
        return n == len(self._raw) or (n > 0 and self._raw_steps[n - 1] >= self.log._next_flush_step)

    def captured_finite(self) -> bool:
        """Whether the last captured sample's state is finite: node pressures, and every qpos/qvel of a MuJoCo
        plant (the same test as its ``finite()``, on the copy; other plants are asked)."""
        if not self._mj:
            return bool(self.plant.finite())
        # a sum is finite iff every term is (barring overflow beyond 1e308, which only costs the runner a replay)
        return math.isfinite(_sum(self._raw[self._pending - 1, :self._state_end]))

    def discard(self, count: int = 1) -> None:
        """Forget the last ``count`` captured or recorded samples (those not yet derived)."""
        self._pending = max(self._derived, self._pending - int(count))

    @property
    def pending(self) -> int:
        """Samples captured and not yet pushed to the log."""
        return self._pending

    def derive(self) -> dict | None:
        """Compute what the run's checks need of the pending samples, vectorised over them; None when none are pending.

        Returns the batch's energy terms as arrays over its samples (``step``,
        ``kinetic``, ``potential``, ``oil``, ``residual``, ``pump_work`` [J]) and the
        ``actuator_position`` [m | rad] and scalar ``joint_position`` [rad | m] rows, for
        checks before :meth:`push` (the runner's energy-growth check and plausibility monitor).
        The other logged fields are computed from the same rows when the log encodes them (:meth:`_fill`).
        """
        k = self._pending
        if k == 0:
            return None
        net, r, b = self.plant.network, self._raw[:k], self._rawcols
        p, oil, x = r[:, b["p"]], r[:, b["oil"]], r[:, b["x"]]
        volumes = net.node_volume_at(x, p)  # node relations broadcast over the rows
        kinetic, potential, pump_work, diss_h, diss_f, diss_m = r[:, b["energy"]].T
        oil_energy = stored_energy_at(net, oil, p, x, volumes)
        # EnergyLedger.residual, term by term
        residual = pump_work - (kinetic + potential + oil_energy - self.plant.energy.initial_total) - (diss_h + diss_f + diss_m)
        joints = r[:, b["joints"]]
        self._batch = (volumes, oil_energy, residual)
        self._derived = k
        return {"step": self._raw_steps[:k], "kinetic": kinetic, "potential": potential, "oil": oil_energy,
                "residual": residual, "pump_work": pump_work, "actuator_position": x,
                "joint_position": (joints[:, self._joint_columns] if self._mj else joints)[:, :self._nj]}

    def _fill(self, raw: np.ndarray, steps: np.ndarray, batch: tuple, count: int, rows: np.ndarray, lo: int,
              hi: int) -> None:
        """Write the frame rows of samples ``lo:hi`` of a pushed ring (``raw``, ``steps``; ``batch``: its
        :meth:`derive` arrays) into ``rows``; the ring is free again once its last sample (``count``) is written.

        Called by the log (:meth:`~sim.io.log_writer.Frame.defer`), usually on its writer thread: it reads only the
        pushed ring and the network's constant tables, never the plant's state.
        """
        net, r, b, block = self.plant.network, raw[lo:hi], self._rawcols, self._block
        k = hi - lo
        volumes, oil_energy, residual = tuple(v[lo:hi] for v in batch[0]), batch[1][lo:hi], batch[2][lo:hi]
        p, x, v = r[:, b["p"]], r[:, b["x"]], r[:, b["v"]]
        effort, theta, flow = r[:, b["effort"]], r[:, b["theta"]], r[:, b["flow"]]
        rows[:, block["xpos"].start:block["xquat"].stop] = r[:, b["poses"]]
        joints = r[:, b["joints"]]
        jp = block["joints"].start
        rows[:, jp:jp + 2 * self._nj] = joints[:, self._joint_columns] if self._mj else joints
        rows[:, jp + 2 * self._nj:block["joints"].stop] = np.nan  # joint efforts are not logged
        if len(self._cyl):
            cyl = self._cyl
            c = rows[:, block["cylinders"]].reshape(k, len(cyl), len(CYLINDER_FIELDS))
            c[:, :, 0], c[:, :, 1], c[:, :, 2], c[:, :, 3] = x[:, cyl], v[:, cyl], p[:, self._cyl_cap], p[:, self._cyl_rod]
            c[:, :, 4] = effort[:, cyl]
            c[:, :, 5] = net.pressure_effort(p)[:, cyl]
            c[:, :, 6] = net.chamber_stiffness(p, x, volumes).sum(axis=1)
            c[:, :, 7] = theta[:, cyl]
            c[:, :, 8], c[:, :, 9] = c[:, :, 2] / PA_PER_BAR, c[:, :, 3] / PA_PER_BAR
            rows[:, block["cylinders"]] = c.reshape(k, -1)
            nbody = self._nbody
            self.cylinder_scene.fill(rows, steps[lo:hi], r[:, b["poses"]][:, :3 * nbody].reshape(k, nbody, 3),
                                     r[:, b["poses"]][:, 3 * nbody:].reshape(k, nbody, 4), p[:, self._cyl_cap])
        if len(self._mot):
            mot = self._mot
            m = rows[:, block["motors"]].reshape(k, len(mot), len(MOTOR_FIELDS))
            m[:, :, 0], m[:, :, 1], m[:, :, 2], m[:, :, 3] = x[:, mot], v[:, mot], p[:, self._mot_a], p[:, self._mot_b]
            m[:, :, 4] = effort[:, mot]
            rows[:, block["motors"]] = m.reshape(k, -1)
        if self.valves:
            valves = rows[:, block["valves"]].reshape(k, len(self.valves), len(VALVE_FIELDS))
            valves[:, :, 0], valves[:, :, 1] = r[:, b["cmd"]], r[:, b["spool"]][:, :len(self.valves)]
            rows[:, block["valves"]] = valves.reshape(k, -1)
        if self.pumps:
            mu = net.fluid.pressure_potential(p)
            q_pump = flow[:, self.pump_branches]
            pumps = rows[:, block["pumps"]].reshape(k, len(self.pumps), len(PUMP_FIELDS))
            pumps[:, :, 0], pumps[:, :, 1], pumps[:, :, 2] = r[:, b["speed"]], q_pump, p[:, self._pump_to]
            pumps[:, :, 3] = q_pump * (mu[:, self._pump_to] - mu[:, self._pump_from])
            rows[:, block["pumps"]] = pumps.reshape(k, -1)
        if self._controller_names:
            nctl = len(self._controller_names)
            states = r[:, b["controllers"]].reshape(k, nctl, len(CONTROLLER_STATE_COLUMNS))
            rows[:, block["controllers"]] = states[:, :, :len(CONTROLLER_FIELDS)].reshape(k, -1)
        rows[:, block["nodes"]] = p
        if self.states is not None:
            rows[:, block["states"]] = r[:, b["spool"]][:, len(net.valve_names):]
        if self.flows is not None:
            rows[:, block["flows"]] = flow
        kinetic, potential, pump_work, diss_h, diss_f, diss_m = r[:, b["energy"]].T
        en = rows[:, block["energy"]]
        en[:, 0], en[:, 1], en[:, 2], en[:, 3] = kinetic, potential, oil_energy, pump_work
        en[:, 4], en[:, 5], en[:, 6], en[:, 7] = diss_h, diss_f, diss_m, residual
        rows[:, block["energy"]] = en
        s = rows[:, block["solver"]]
        s[:, 0], s[:, 1] = r[:, b["solver"]].T
        s[:, 2] = np.minimum(theta.min(axis=1), 1.0) if theta.shape[1] else 1.0
        rows[:, block["solver"]] = s
        if hi == count:
            self._spare_rings.append((raw, steps))  # (list.append is atomic; the ring is taken in the run's thread)

    def push(self, count: int | None = None) -> None:
        """Write the first ``count`` derived samples (all by default) to the log and empty the ring.

        Samples after ``count`` are dropped (a run cut at a divergence).  ``last``
        then holds the last written sample's energy terms [J] (``kinetic``,
        ``potential``, ``oil``, ``residual``, ``pump_work``, ``dissipated``),
        actuator positions and joint positions, for summaries.  The ring goes to the log
        (:meth:`~sim.io.log_writer.Frame.defer`, its fields computed there); later samples go into a spare ring.
        """
        if self._pending > self._derived:  # captured after derive() (or never derived): derive them too
            self.derive()
        k = self._derived
        count = k if count is None else max(0, min(int(count), k))
        if count > 0:
            i = count - 1
            r, b = self._raw, self._rawcols
            kinetic, potential, pump_work, diss_h, diss_f, diss_m = r[i, b["energy"]]
            _, oil_energy, residual = self._batch
            self.last = {"kinetic": float(kinetic), "potential": float(potential), "oil": float(oil_energy[i]),
                         "residual": float(residual[i]), "pump_work": float(pump_work),
                         "dissipated": float(diss_h + diss_f + diss_m),
                         "step": int(self._raw_steps[i]), "actuator_position": r[i, b["x"]].copy(),
                         "joint_position": (r[i, b["joints"]][self._joint_columns] if self._mj else r[i, b["joints"]])[:self._nj].copy()}
        # empty the ring first: a Ctrl-C (held back by defer until its rows are all buffered) must not leave them
        # pending for the close hook to write twice
        self._pending = self._derived = 0
        if count > 0:
            raw, steps, batch = self._raw, self._raw_steps, self._batch
            self._raw, self._raw_steps = (self._spare_rings.pop() if self._spare_rings  # (np.zeros: pages come as rows do)
                                          else (np.zeros(raw.shape), np.zeros(steps.shape, dtype=steps.dtype)))
            self.frame.defer(steps[:count], functools.partial(self._fill, raw, steps, batch, count))

    def push_pending(self) -> None:
        """Derive and write every pending sample (the log's close hook: an interrupted run keeps what it captured)."""
        if self._pending:
            self.derive()
            self.push()


__all__ = ["RunRecorder", "field_name"]
