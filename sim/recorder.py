"""What a run logs: the topics, their schemas, and one sample per logged step.

The same topics are written by every plant (MuJoCo or PBD), so two logs of a
scenario compare field by field.  Topics (all SI, units in each field's
description and in the channel metadata):

``/hydroplant/joint_states``            foxglove.JointStates of the scalar joints
``/hydroplant/cylinders/<name>``        stroke, speed, pressures, forces, stiffness
``/hydroplant/motors/<name>``           angle, speed, port pressures, torque
``/hydroplant/valves/<name>``           command and spool
``/hydroplant/pumps/<name>``            speed, flow, outlet pressure, power
``/hydroplant/nodes``                   every node's pressure
``/hydroplant/flows``                   every branch's flow
``/hydroplant/energy``                  energy terms and the balance residual
``/hydroplant/solver``                  Newton iterations, residual, coupling θ
``/tf``, ``/hydroplant/scene``          body poses and geometry for Foxglove's 3D panel
``/hydroplant/events``                  foxglove.Log: divergence and other events
"""

from __future__ import annotations

import re

import numpy as np

from hydraulics.energy import stored_energy

from .foxglove_scene import FrameTransformsChannel, log_scene
from .mcap_log import LogLevel, LogWriter, flat_schema, log_message, log_schema


def field_name(name: str) -> str:
    """A component or node name as a JSON field name (letters, digits, underscores)."""
    return re.sub(r"[^A-Za-z0-9_]", "_", name)


CYLINDER_FIELDS = {
    "position_m": "Rod extension from fully retracted [m]",
    "velocity_mps": "Rod speed, positive extending [m/s]",
    "p_cap_pa": "Cap-side absolute pressure [Pa]",
    "p_rod_pa": "Rod-side absolute pressure [Pa]",
    "force_n": "Force applied to the mechanics, positive extending [N]",
    "pressure_force_n": "p_cap*A_cap - p_rod*A_rod - p_amb*(A_cap - A_rod) at the end of the step [N]",
    "stiffness_npm": "Oil-column stiffness beta*(A_cap^2/V_cap + A_rod^2/V_rod) [N/m]",
    "theta": "Implicit weight of the coupling this step [-]",
}
MOTOR_FIELDS = {
    "angle_rad": "Motor shaft angle [rad]",
    "speed_radps": "Motor shaft speed [rad/s]",
    "p_a_pa": "Port A absolute pressure [Pa]",
    "p_b_pa": "Port B absolute pressure [Pa]",
    "torque_nm": "Shaft torque applied to the mechanics [N*m]",
}
VALVE_FIELDS = {"command": "Spool command [-], -1..1", "spool": "Spool position [-], -1..1"}
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
SOLVER_FIELDS = {
    "newton_iterations": "Newton iterations of the hydraulic step [-]",
    "residual_pa": "Final Newton residual expressed as pressure [Pa]",
    "theta_min": "Smallest implicit weight over actuators [-]",
}


class RunRecorder:
    """Registers the channels of a plant on a :class:`LogWriter` and appends samples."""

    def __init__(self, log: LogWriter, plant):
        self.log = log
        self.plant = plant
        net = plant.network
        si = {"units": "SI"}
        self.pump_branches = np.arange(net.branch_slices["pump"].start, net.branch_slices["pump"].stop)
        node_fields = {f"pressure_pa.{field_name(n)}": f"Absolute pressure of node {n} [Pa]" for n in net.node_names}
        flow_fields = {f"flow_m3ps.{field_name(b)}": f"Flow of branch {b}, positive from its first port [m^3/s]" for b in net.branch_names}
        # One frame row per sample holds every columnar topic, /tf included (its channel reads xpos.ravel() then
        # xquat.ravel(), see FrameTransformsChannel): one commit per sample, so an interrupt never splits a sample.
        nj, ncyl, nmot = len(plant.joint_names), len(net.cylinder_actuator), len(net.motor_actuator)
        nvalve, npump, nnode, nflow = len(net.valve_names), len(net.pump_names), len(node_fields), len(flow_fields)
        nbody = plant.model.nbody
        sizes = {"joints": 3 * nj, "cylinders": ncyl * len(CYLINDER_FIELDS), "motors": nmot * len(MOTOR_FIELDS),
                 "valves": nvalve * len(VALVE_FIELDS), "pumps": npump * len(PUMP_FIELDS), "nodes": nnode, "flows": nflow,
                 "energy": len(ENERGY_FIELDS), "solver": len(SOLVER_FIELDS), "xpos": 3 * nbody, "xquat": 4 * nbody}
        start = np.cumsum([0, *sizes.values()])
        block = {name: slice(int(start[i]), int(start[i + 1])) for i, name in enumerate(sizes)}
        self._block = block
        frame = self.frame = log.frame(int(start[-1]))

        def columns(name, index, width):
            first = block[name].start + index * width
            return np.arange(first, first + width)

        self.joints = frame.joint_states_channel("/hydroplant/joint_states", plant.joint_names,
                                                 columns=np.arange(block["joints"].start, block["joints"].stop), metadata=si)
        self.cylinders = [
            frame.channel(f"/hydroplant/cylinders/{net.actuator_names[a]}", "hydroplant.CylinderState",
                          flat_schema("hydroplant.CylinderState", CYLINDER_FIELDS), fields=list(CYLINDER_FIELDS),
                          columns=columns("cylinders", i, len(CYLINDER_FIELDS)), metadata=si)
            for i, a in enumerate(net.cylinder_actuator)
        ]
        self.motors = [
            frame.channel(f"/hydroplant/motors/{net.actuator_names[a]}", "hydroplant.MotorState",
                          flat_schema("hydroplant.MotorState", MOTOR_FIELDS), fields=list(MOTOR_FIELDS),
                          columns=columns("motors", i, len(MOTOR_FIELDS)), metadata=si)
            for i, a in enumerate(net.motor_actuator)
        ]
        self.valves = [
            frame.channel(f"/hydroplant/valves/{name}", "hydroplant.ValveState", flat_schema("hydroplant.ValveState", VALVE_FIELDS),
                          fields=list(VALVE_FIELDS), columns=columns("valves", i, len(VALVE_FIELDS)), metadata=si)
            for i, name in enumerate(net.valve_names)
        ]
        self.pumps = [
            frame.channel(f"/hydroplant/pumps/{name}", "hydroplant.PumpState", flat_schema("hydroplant.PumpState", PUMP_FIELDS),
                          fields=list(PUMP_FIELDS), columns=columns("pumps", i, len(PUMP_FIELDS)), metadata=si)
            for i, name in enumerate(net.pump_names)
        ]
        self.nodes = frame.channel("/hydroplant/nodes", "hydroplant.NodePressures", flat_schema("hydroplant.NodePressures", node_fields),
                                   fields=list(node_fields), columns=columns("nodes", 0, nnode), metadata=si)
        self.flows = (
            frame.channel("/hydroplant/flows", "hydroplant.BranchFlows", flat_schema("hydroplant.BranchFlows", flow_fields),
                          fields=list(flow_fields), columns=columns("flows", 0, nflow), metadata=si)
            if flow_fields else None
        )
        self.energy = frame.channel("/hydroplant/energy", "hydroplant.Energy", flat_schema("hydroplant.Energy", ENERGY_FIELDS),
                                    fields=list(ENERGY_FIELDS), columns=columns("energy", 0, len(ENERGY_FIELDS)), metadata=si)
        self.solver = frame.channel("/hydroplant/solver", "hydroplant.Solver", flat_schema("hydroplant.Solver", SOLVER_FIELDS),
                                    fields=list(SOLVER_FIELDS), columns=columns("solver", 0, len(SOLVER_FIELDS)), metadata=si)
        self.events = log.channel("/hydroplant/events", "foxglove.Log", log_schema())
        self.tf = FrameTransformsChannel(log, plant.model)
        frame.adopt(self.tf.channel, np.arange(block["xpos"].start, block["xquat"].stop))
        log_scene(log, plant.model)
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
        self._nj = nj

    def event(self, step_index: int, level: LogLevel, text: str) -> None:
        """Write a foxglove.Log event (divergence, warnings)."""
        self.events.write(step_index, log_message(level, text))

    def sample(self, step_index: int) -> dict:
        """Append one sample of every topic; returns the energy terms (for summaries).

        Values are gathered into one frame row (a numpy expression per topic
        family); the JSON is written later, in batches, by the log writer
        (:mod:`sim.mcap_log`).
        """
        plant = self.plant
        net = plant.network
        state = plant.net_state
        p = state.node_pressure
        block = self._block
        kinetic, potential = plant.mechanical_energy()
        xpos, xquat = plant.body_poses()
        row = self.frame.claim(step_index)
        row[block["xpos"]] = xpos.ravel()
        row[block["xquat"]] = xquat.ravel()
        q, qd = plant.joint_state()
        nj, j0 = self._nj, block["joints"].start
        row[j0:j0 + nj] = q
        row[j0 + nj:j0 + 2 * nj] = qd  # (efforts: never written, logged as null like JointStatesChannel.append)
        x, v = state.actuator_position, state.actuator_velocity
        effort = plant.effort
        if len(self._cyl):
            cyl = self._cyl
            c = row[block["cylinders"]].reshape(len(cyl), len(CYLINDER_FIELDS))
            c[:, 0], c[:, 1], c[:, 2], c[:, 3] = x[cyl], v[cyl], p[self._cyl_cap], p[self._cyl_rod]
            c[:, 4], c[:, 5] = effort[cyl], net.pressure_effort(p)[cyl]
            c[:, 6] = net.chamber_stiffness(p, x).sum(axis=0)
            c[:, 7] = plant.theta[cyl]
        if len(self._mot):
            mot = self._mot
            m = row[block["motors"]].reshape(len(mot), len(MOTOR_FIELDS))
            m[:, 0], m[:, 1], m[:, 2], m[:, 3], m[:, 4] = x[mot], v[mot], p[self._mot_a], p[self._mot_b], effort[mot]
        if self.valves:
            valves = row[block["valves"]].reshape(len(self.valves), len(VALVE_FIELDS))
            valves[:, 0], valves[:, 1] = plant.control.valve_command, state.valve_spool
        report = plant.last_report
        flow = report.branch_flow if report is not None and len(report.branch_flow) else self._no_flow
        if self.pumps:
            mu = net.fluid.pressure_potential(p)
            q_pump = flow[self.pump_branches]
            pumps = row[block["pumps"]].reshape(len(self.pumps), len(PUMP_FIELDS))
            pumps[:, 0], pumps[:, 1], pumps[:, 2] = plant.control.pump_speed, q_pump, p[self._pump_to]
            pumps[:, 3] = q_pump * (mu[self._pump_to] - mu[self._pump_from])
        row[block["nodes"]] = p
        if self.flows is not None:
            row[block["flows"]] = flow
        oil = stored_energy(net, state)
        e = plant.energy
        residual = e.residual(kinetic, potential, oil)
        row[block["energy"]] = (kinetic, potential, oil, e.pump_work, e.dissipated_hydraulic, e.dissipated_friction,
                                e.dissipated_mechanical, residual)
        theta = plant.theta
        row[block["solver"]] = (report.newton_iterations if report is not None else 0,
                                report.residual if report is not None else 0.0,
                                min(theta.min(), 1.0) if len(theta) else 1.0)
        self.frame.commit()
        return {"kinetic": kinetic, "potential": potential, "oil": oil, "residual": residual}


__all__ = ["RunRecorder", "field_name"]
