"""What every plant shares: the network's start state, the energy ledger, the control schedule.

A plant (MuJoCo or XPBD) owns its bodies; this base owns the hydraulic side
that is the same for all: the initial network state (in static equilibrium
with the load when the scenario asks), the operator inputs, and the energy
terms of the run.  Subclasses provide ``holding_efforts()``,
``mechanical_energy()``, ``joint_state()``, ``body_poses()``, ``finite()`` and
``step()``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydraulics.energy import branch_powers, stored_energy
from hydraulics.equilibrium import equilibrium_state
from hydraulics.load import apply_inputs

from sim.plants.controllers import ControllerBank


@dataclass
class EnergyLedger:
    """Running energy terms of a run [J]; see :mod:`hydraulics.energy`."""

    pump_work: float = 0.0
    motor_work: float = 0.0
    dissipated_hydraulic: float = 0.0
    dissipated_friction: float = 0.0
    dissipated_mechanical: float = 0.0
    initial_total: float = 0.0

    def residual(self, kinetic, potential, oil) -> float:
        """pump work − Δ(kinetic + potential + oil) − physical dissipation: the scheme's numerical loss."""
        dissipated = self.dissipated_hydraulic + self.dissipated_friction + self.dissipated_mechanical
        return self.pump_work - (kinetic + potential + oil - self.initial_total) - dissipated



class PlantBase:
    """Hydraulic bookkeeping shared by the plants (see module docstring)."""

    def start_network(self, position, velocity) -> None:
        """Network state, controls and energy ledger at t = 0 for actuators at ``position`` moving at ``velocity``."""
        scenario = self.scene.scenario
        self.step_index = 0
        self.control = self.network.control()
        apply_inputs(self.network, self.control, scenario.inputs, 0.0)
        if getattr(self, "controllers", None) is None:  # the scenario's PIDs (their state is reset in place: the
            self.controllers = ControllerBank(scenario, self.network, self.scene.mjmodel, self.dt)  # blocks hold it)
            self.python_controller = None  # a PythonController (sim.plants.controllers), asked per control period
        self.controllers.state[:] = 0.0
        self.holding_residual = None  # relative residual of the static balance (set by holding_efforts)
        if scenario.equilibrium:
            self.net_state = equilibrium_state(
                self.network, self.control, position, self.holding_efforts(),
                base_pressure=scenario.base_pressure, pressures=scenario.pressures,
            )
        else:
            p = np.full(self.network.node_count, self.network.fluid.reference_pressure)
            for net, value in scenario.pressures.items():
                p[self.network.node(net)] = value
            self.net_state = self.network.state(actuator_position=position, node_pressure=p)
        self.net_state.actuator_velocity = np.array(velocity, float)
        self.effort = self.network.actuator_effort(self.net_state.node_pressure, self.net_state.actuator_velocity,
                                                   self.net_state.actuator_position)[0]
        self.last_report = None
        self.theta = np.ones(self.network.actuator_count)
        self.energy = EnergyLedger()
        kinetic, potential = self.mechanical_energy()
        self.energy.initial_total = kinetic + potential + stored_energy(self.network, self.net_state)

    def reset_extremes(self) -> None:
        """Start the running per-step extremes from the current state: node pressures [Pa]
        (``node_pressure_max``/``node_pressure_min``) and actuator coordinates [m | rad]
        (``actuator_position_max``/``actuator_position_min``); plants that step in compiled blocks keep them
        over every successful step, for the runner's peaks and its plausibility monitor."""
        state = self.net_state
        self.node_pressure_max = state.node_pressure.copy()
        self.node_pressure_min = state.node_pressure.copy()
        self.actuator_position_max = np.array(state.actuator_position, float)
        self.actuator_position_min = np.array(state.actuator_position, float)

    @property
    def time(self) -> float:
        """Simulation time [s] (step index × dt, so runs line up exactly)."""
        return self.step_index * self.dt

    def apply_inputs(self) -> None:
        """Set the controls from the scenario's schedules at the current time."""
        apply_inputs(self.network, self.control, self.scene.scenario.inputs, self.time)

    @property
    def controller_state(self) -> np.ndarray:
        """The PID controllers' state, one row per controller (``hydraulics.controllers.STATE_COLUMNS``); written in
        place by the plant's steps."""
        return self.controllers.state

    def controller_sources(self):
        """What the controllers' sensors read at the current step's start: actuator positions [m | rad] and
        velocities, qpos, qvel (MuJoCo layout), node pressures [Pa], the last step's branch flows [m³/s]."""
        state, report = self.net_state, self.last_report
        flow = report.branch_flow if report is not None and len(report.branch_flow) else np.zeros(len(self.network.branch_names))
        qpos, qvel = self.generalized_state()
        return state.actuator_position, state.actuator_velocity, qpos, qvel, state.node_pressure, flow

    def generalized_state(self):
        """(qpos, qvel) of the whole model, MuJoCo's layout."""
        return self.data.qpos, self.data.qvel

    def _account(self, report, velocity, dt) -> None:
        """Add one step's pump work, hydraulic and friction losses to the ledger (at the ``incompressible`` level:
        the work of the applied efforts as supplied work, :func:`hydraulics._compiled._account_rigid_oil`)."""
        if getattr(self.coupling, "name", "") == "incompressible":
            self.energy.pump_work += dt * float(np.asarray(self.effort, float) @ velocity)
            return
        net = self.network
        powers = branch_powers(net, self.net_state, report.branch_flow)
        e = self.energy
        e.pump_work += dt * powers["pump"]
        e.motor_work += dt * powers["motor"]
        e.dissipated_hydraulic += dt * powers["dissipated"]
        friction, _ = net.friction_effort(velocity, self.net_state.node_pressure, self.net_state.actuator_position)
        e.dissipated_friction -= dt * float(friction @ velocity)
        if powers["rigid"]:
            # rigid actuators: what their branches deliver minus the work of their hydraulic force is metering loss
            rigid = net.actuator_rigid
            e.motor_work += dt * powers["rigid"]
            e.dissipated_hydraulic += dt * (powers["rigid"] - float((self.effort - friction)[rigid] @ velocity[rigid]))
