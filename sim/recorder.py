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
        self.joints = log.joint_states_channel("/hydroplant/joint_states", plant.joint_names, metadata=si)
        self.cylinders = [
            log.channel(f"/hydroplant/cylinders/{net.actuator_names[a]}", "hydroplant.CylinderState",
                        flat_schema("hydroplant.CylinderState", CYLINDER_FIELDS), fields=list(CYLINDER_FIELDS), metadata=si)
            for a in net.cylinder_actuator
        ]
        self.motors = [
            log.channel(f"/hydroplant/motors/{net.actuator_names[a]}", "hydroplant.MotorState",
                        flat_schema("hydroplant.MotorState", MOTOR_FIELDS), fields=list(MOTOR_FIELDS), metadata=si)
            for a in net.motor_actuator
        ]
        self.valves = [
            log.channel(f"/hydroplant/valves/{name}", "hydroplant.ValveState", flat_schema("hydroplant.ValveState", VALVE_FIELDS),
                        fields=list(VALVE_FIELDS), metadata=si)
            for name in net.valve_names
        ]
        self.pumps = [
            log.channel(f"/hydroplant/pumps/{name}", "hydroplant.PumpState", flat_schema("hydroplant.PumpState", PUMP_FIELDS),
                        fields=list(PUMP_FIELDS), metadata=si)
            for name in net.pump_names
        ]
        node_fields = {f"pressure_pa.{field_name(n)}": f"Absolute pressure of node {n} [Pa]" for n in net.node_names}
        self.nodes = log.channel("/hydroplant/nodes", "hydroplant.NodePressures", flat_schema("hydroplant.NodePressures", node_fields),
                                 fields=list(node_fields), metadata=si)
        flow_fields = {f"flow_m3ps.{field_name(b)}": f"Flow of branch {b}, positive from its first port [m^3/s]" for b in net.branch_names}
        self.flows = (
            log.channel("/hydroplant/flows", "hydroplant.BranchFlows", flat_schema("hydroplant.BranchFlows", flow_fields),
                        fields=list(flow_fields), metadata=si)
            if flow_fields else None
        )
        self.energy = log.channel("/hydroplant/energy", "hydroplant.Energy", flat_schema("hydroplant.Energy", ENERGY_FIELDS),
                                  fields=list(ENERGY_FIELDS), metadata=si)
        self.solver = log.channel("/hydroplant/solver", "hydroplant.Solver", flat_schema("hydroplant.Solver", SOLVER_FIELDS),
                                  fields=list(SOLVER_FIELDS), metadata=si)
        self.events = log.channel("/hydroplant/events", "foxglove.Log", log_schema())
        self.tf = FrameTransformsChannel(log, plant.model)
        log_scene(log, plant.model)
        self.pump_branches = np.arange(net.branch_slices["pump"].start, net.branch_slices["pump"].stop)

    def event(self, step_index: int, level: LogLevel, text: str) -> None:
        """Write a foxglove.Log event (divergence, warnings)."""
        self.events.write(step_index, log_message(level, text))

    def sample(self, step_index: int) -> dict:
        """Append one sample of every topic; returns the energy terms (for summaries)."""
        plant = self.plant
        net = plant.network
        state = plant.net_state
        p = state.node_pressure
        kinetic, potential = plant.mechanical_energy()
        q, qd = plant.joint_state()
        self.joints.append(step_index, q, qd)
        xpos, xquat = plant.body_poses()
        self.tf.append(step_index, xpos, xquat)
        x, v = state.actuator_position, state.actuator_velocity
        pressure_effort, _ = net.actuator_effort(p, np.zeros_like(v))
        if len(net.cylinder_actuator):
            stiffness = net.chamber_stiffness(p, x).sum(axis=0)
        for i, a in enumerate(net.cylinder_actuator):
            self.cylinders[i].append(step_index, (
                x[a], v[a], p[net.cylinder_cap_node[i]], p[net.cylinder_rod_node[i]], plant.effort[a],
                pressure_effort[a], stiffness[i], plant.theta[a],
            ))
        for i, a in enumerate(net.motor_actuator):
            self.motors[i].append(step_index, (x[a], v[a], p[net.motor_a_node[i]], p[net.motor_b_node[i]], plant.effort[a]))
        for i, channel in enumerate(self.valves):
            channel.append(step_index, (plant.control.valve_command[i], state.valve_spool[i]))
        report = plant.last_report
        flow = report.branch_flow if report is not None and len(report.branch_flow) else np.zeros(len(net.branch_names))
        mu = net.fluid.pressure_potential(p)
        for i, channel in enumerate(self.pumps):
            b = self.pump_branches[i]
            q_pump = flow[b]
            channel.append(step_index, (plant.control.pump_speed[i], q_pump, p[net.branch_to[b]],
                                        q_pump * (mu[net.branch_to[b]] - mu[net.branch_from[b]])))
        self.nodes.append(step_index, p)
        if self.flows is not None:
            self.flows.append(step_index, flow)
        oil = stored_energy(net, state)
        e = plant.energy
        residual = e.residual(kinetic, potential, oil)
        self.energy.append(step_index, (kinetic, potential, oil, e.pump_work, e.dissipated_hydraulic, e.dissipated_friction,
                                        e.dissipated_mechanical, residual))
        iterations = report.newton_iterations if report is not None else 0
        self.solver.append(step_index, (iterations, report.residual if report is not None else 0.0, float(np.min(plant.theta, initial=1.0))))
        return {"kinetic": kinetic, "potential": potential, "oil": oil, "residual": residual}


__all__ = ["RunRecorder", "field_name"]
