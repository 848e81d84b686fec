"""The scenario's controllers bound to a plant: the compiled PID bank and the Python controller callable.

:class:`ControllerBank` resolves the ``[controllers.NAME]`` tables of type ``pid`` (:class:`sim.io.scenario.PidSpec`)
against the network and the MuJoCo model (sensor and output indices, output limits, sample period in steps) into
the packed parameter table of :mod:`hydraulics.controllers`, holds the controllers' state (columns
``hydraulics.controllers.STATE_COLUMNS``; the plant logs and snapshots it) and samples the setpoint schedules for
a block of steps.  The compiled blocks of both modes call :func:`hydraulics.controllers.update` at the start of
every step (MuJoCo mode: in the control callback before the step's effort law; PBD mode: before the frame's
substeps, the command held over them); the per-step MuJoCo plant calls :meth:`ControllerBank.step`.

:class:`PythonController` is a user's own controller ``controller(t, sensors) -> commands``: asked once per
control period with ``sensors`` a dict ``{"KIND:NAME": value}`` of the step's start state (the same sensors as the
PID's, :data:`hydraulics.controllers.SENSOR_KINDS`), it returns ``{input name: value}``, held until its next call;
the plant then steps in blocks of one control period (:func:`advance_controlled`).

Example
-------
>>> # plant = make_plant(load_scene(load_scenario("servo.scenario.toml")))
>>> # plant.python_controller = PythonController(plant, lambda t, s: {"valve": 50 * (0.25 - s["stroke:cyl"])},
>>> #                                            sensors=["stroke:cyl"], rate=1000.0)
"""

from __future__ import annotations

import dataclasses
import importlib
import math

import mujoco
import numpy as np

from hydraulics import controllers as CT
from hydraulics.components import COMPONENT_TYPES

from sim.io.scenario import VALVE_COMMAND_RANGE, PidSpec, PythonSpec, ScenarioError

_PUMP_SPEED = {f.name: f.metadata for f in dataclasses.fields(COMPONENT_TYPES["pump_fixed"])}["speed"]
PUMP_SPEED_RANGE = (float(_PUMP_SPEED["low"]), float(_PUMP_SPEED["high"]))  # rev/s


def period_steps(rate, dt) -> int:
    """Plant steps per control period at ``rate`` [Hz] (None: every step): round(1/(rate·dt)), at least 1."""
    return 1 if rate is None else max(1, int(round(1.0 / (rate * dt))))


def resolve_sensor(kind: str, name: str, network, model, where: str) -> int:
    """Index of sensor ``kind:name`` in the arrays :func:`hydraulics.controllers.sensor_value` reads; a name that is
    not in the circuit or the model raises :class:`ScenarioError` naming ``where`` and the names allowed."""
    if kind in ("stroke", "speed"):
        names = network.actuator_names
    elif kind in ("joint", "joint_speed"):
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        scalar = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
        if j < 0 or int(model.jnt_type[j]) not in scalar:
            joints = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(model.njnt)
                      if int(model.jnt_type[i]) in scalar]
            raise ScenarioError(f"{where}: no hinge or slide joint '{name}' in the model; joints: {joints}")
        return int(model.jnt_qposadr[j] if kind == "joint" else model.jnt_dofadr[j])
    elif kind == "pressure":
        if name not in network.net_node:
            raise ScenarioError(f"{where}: no net '{name}' in the circuit; nets: {sorted(network.net_node)}")
        return int(network.net_node[name])
    elif kind == "flow":
        names = network.branch_names
    else:
        names = network.pump_names
    if name not in names:
        raise ScenarioError(f"{where}: no {'pump' if kind == 'pump_speed' else 'actuator' if kind in ('stroke', 'speed') else 'branch'} "
                            f"'{name}' in the circuit; allowed: {list(names)}")
    return list(names).index(name)


def resolve_output(name: str, network, where: str):
    """(output kind index, index, (low, high) range) of the input ``name``: a valve [-] (its type's
    ``COMMAND_RANGE``) or a pump [rev/s]."""
    if name in network.valve_names:
        kind = network.circuit.component(name).kind
        return 0, network.valve_names.index(name), getattr(COMPONENT_TYPES[kind], "COMMAND_RANGE", VALVE_COMMAND_RANGE)
    if name in network.pump_names:
        return 1, network.pump_names.index(name), PUMP_SPEED_RANGE
    raise ScenarioError(f"{where}, field 'output': no valve or pump called '{name}'; inputs: "
                        f"{sorted(network.valve_names + network.pump_names)}")


class ControllerBank:
    """The PID controllers of a scenario bound to one plant (module docstring).

    ``names`` (tuple), ``table`` (packed, :data:`hydraulics.controllers.PID_COLUMNS`), ``state`` (float64
    (count, len(STATE_COLUMNS)), updated in place by the compiled blocks), ``setpoints`` (the schedules).
    """

    def __init__(self, scenario, network, model, dt: float):
        specs = {k: v for k, v in scenario.controllers.items() if isinstance(v, PidSpec)}
        self.names = tuple(specs)
        self.setpoints = tuple(s.setpoint for s in specs.values())
        count = len(specs)
        columns = {name: np.zeros(count) for name in CT.PID_COLUMNS}
        for i, (name, spec) in enumerate(specs.items()):
            where = f"{scenario.path}, [controllers.{name}]"
            kind, index, (low, high) = resolve_output(spec.output, network, where)
            sensor = resolve_sensor(*spec.sensor, network, model, f"{where}, field 'sensor'")
            lo = low if spec.low is None else spec.low
            hi = high if spec.high is None else spec.high
            if not (low <= lo < hi <= high):
                raise ScenarioError(f"{where}, fields 'low', 'high': [{lo:g}, {hi:g}] must lie within the range "
                                    f"[{low:g}, {high:g}] of input '{spec.output}'")
            every = period_steps(spec.rate, dt)
            h = every * dt
            tracking = spec.tracking_time
            if tracking is None:
                tracking = abs(spec.kp / spec.ki) if spec.kp != 0.0 and spec.ki != 0.0 else h
            values = dict(kp=spec.kp, ki=spec.ki, kd=spec.kd, derivative_filter=spec.derivative_filter, low=lo, high=hi,
                          anti_windup=CT.ANTI_WINDUP.index(spec.anti_windup), tracking_gain=min(1.0, h / tracking),
                          every=every, sensor_kind=CT.SENSOR_KINDS.index(spec.sensor[0]), sensor_index=sensor,
                          output_kind=kind, output_index=index)
            for key, value in values.items():
                columns[key][i] = value
        self.table = CT.pack(count, **columns)
        self.state = CT.initial_state(count)
        self.outputs = tuple(s.output for s in specs.values())

    def __len__(self) -> int:
        return len(self.names)

    def setpoint_rows(self, times, out: np.ndarray | None = None) -> np.ndarray:
        """Setpoints at ``times`` [s], one row per time, one column per controller (into ``out`` when given)."""
        out = np.empty((len(times), len(self.names))) if out is None else out
        for i, schedule in enumerate(self.setpoints):
            out[:, i] = np.interp(times, schedule.t, schedule.value)
        return out

    def step(self, step_index: int, dt: float, sources, control) -> None:
        """One step's controllers from Python (the per-step plants): ``sources`` = (actuator positions, velocities,
        qpos, qvel, node pressures, branch flows) of the step's start; writes ``control``'s commands in place."""
        if not len(self.names):
            return
        setpoint = self.setpoint_rows(np.array([step_index * dt]))[0]
        sources = tuple(np.ascontiguousarray(a, float) for a in sources)
        CT.update(self.table, self.state, setpoint, step_index, dt, sources, control.valve_command, control.pump_speed)


class PythonController:
    """A user's controller ``function(t, sensors) -> commands`` on ``plant`` (module docstring).

    ``sensors``: ``"KIND:NAME"`` strings (:data:`hydraulics.controllers.SENSOR_KINDS`); ``rate`` [Hz] (None: every
    step); ``outputs``: the inputs it may set (None: any valve or pump that has no schedule and no PID).  Cost: one
    Python call per control period plus a compiled block per period (``docs/controllers.md``)."""

    def __init__(self, plant, function, *, sensors=(), rate: float | None = None, outputs=None, where: str = "controller"):
        if not callable(function):
            raise TypeError(f"{where}: the controller must be callable as controller(t, sensors), got {function!r}")
        net, model = plant.network, plant.scene.mjmodel
        self.function = function
        self.every = period_steps(rate, plant.dt)
        self.sensors = []
        for text in sensors:
            kind, _, name = str(text).partition(":")
            if kind not in CT.SENSOR_KINDS:
                raise ScenarioError(f"{where}: sensor {text!r}: KIND must be one of {list(CT.SENSOR_KINDS)}")
            self.sensors.append((str(text), CT.SENSOR_KINDS.index(kind), resolve_sensor(kind, name, net, model, where)))
        scenario = plant.scene.scenario
        taken = set(scenario.inputs) | {s.output for s in scenario.controllers.values() if isinstance(s, PidSpec)}
        allowed = [n for n in net.valve_names + net.pump_names if n not in taken]
        outputs = allowed if outputs is None else list(outputs)
        self.outputs = {}
        for name in outputs:
            if name not in allowed:
                raise ScenarioError(f"{where}: output '{name}' is not a valve or pump free of schedules and PIDs; "
                                    f"free inputs: {allowed}")
            kind, index, _ = resolve_output(name, net, where)
            self.outputs[name] = (kind, index)

    def call(self, plant) -> None:
        """Ask the controller at the plant's current step and hold its commands in ``plant.control``."""
        sources = tuple(np.ascontiguousarray(a, float) for a in plant.controller_sources())
        speed = plant.control.pump_speed
        values = {text: float(CT.sensor_value(kind, index, sources, speed)) for text, kind, index in self.sensors}
        commands = self.function(plant.time, values)
        if not isinstance(commands, dict):
            raise TypeError(f"the controller returned {type(commands).__name__}, expected a dict of input name: value")
        for name, value in commands.items():
            if name not in self.outputs:
                raise KeyError(f"the controller set '{name}', which is not one of its outputs {sorted(self.outputs)}")
            value = float(value)
            if not math.isfinite(value):
                raise ValueError(f"the controller set '{name}' to {value!r} at t = {plant.time!r} s")
            kind, index = self.outputs[name]
            (plant.control.valve_command if kind == 0 else plant.control.pump_speed)[index] = value


def load_python_controllers(plant) -> PythonController | None:
    """The scenario's ``type = "python"`` controller (``python = "module:function"``) bound to ``plant``, or None."""
    specs = [(k, v) for k, v in plant.scene.scenario.controllers.items() if isinstance(v, PythonSpec)]
    if not specs:
        return None
    if len(specs) > 1:
        raise ScenarioError(f"{plant.scene.scenario.path}: at most one controller of type 'python' per scenario")
    name, spec = specs[0]
    where = f"{plant.scene.scenario.path}, [controllers.{name}]"
    module, _, attribute = spec.python.partition(":")
    try:
        function = getattr(importlib.import_module(module), attribute)
    except (ImportError, AttributeError) as exc:
        raise ScenarioError(f"{where}, field 'python': cannot load {spec.python!r}: {exc}") from None
    return PythonController(plant, function, sensors=spec.sensors, rate=spec.rate, outputs=spec.outputs, where=where)


def advance_controlled(plant, advance, n: int, record, every: int):
    """``n`` steps of ``advance(m, record, every)`` in blocks of one control period of ``plant.python_controller``,
    the controller asked at the start of each; the samples the blocks leave out (a block's last step) are written
    with ``plant.record_row``, so the rows equal one uncontrolled call's.  Returns the last report."""
    controller = plant.python_controller
    done = rows = 0
    finite = True
    report = None
    while done < n:
        controller.call(plant)
        m = min(n - done, controller.every - plant.step_index % controller.every)
        target = None if record is None else record[rows:]
        report = advance(m, target, every)
        rows += plant.recorded
        finite = finite and plant.recorded_finite
        done += m
        if not report.success:
            break
        if record is not None and done < n and plant.step_index % every == 0:  # the block's last step is a sample
            plant.record_row(record[rows])
            finite = finite and plant.finite()
            rows += 1
    plant.recorded, plant.recorded_finite = rows, finite
    return report


__all__ = ["ControllerBank", "PythonController", "advance_controlled", "load_python_controllers", "period_steps"]
