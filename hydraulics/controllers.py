"""Feedback controllers of the scenario inputs: the discrete PID law, its packed parameter table and its states.

A controller drives one input (a 4/3 valve's spool command [-] or a pump's shaft speed [rev/s]) from one sensor
at its own sample period h = ``every``·dt (``every`` ≥ 1 plant steps), reading the sensor at the start of a step
and writing the command the step's hydraulics use; between samples the output is held (zero-order hold).

Law (parallel PID, Åström & Murray, *Feedback Systems* 2nd ed., §11.5), at sample k with setpoint r_k and
measurement y_k (sign convention: error e = r − y; positive gains raise the output while the measurement is below
the setpoint, so a valve whose positive command extends a cylinder servoes its stroke with positive gains; a
loop whose output lowers its measurement needs negative gains)::

    P_k = kp·e_k
    D_k = (T_f·D_{k−1} − kd·(y_k − y_{k−1}))/(T_f + h)     derivative of the measurement (no kick at a setpoint
                                                          step), first-order filter T_f (0: unfiltered); D_0 = 0
    v_k = P_k + I_k + D_k,      u_k = clip(v_k, low, high)
    I_{k+1} = I_k + ki·h·e_k                              (anti_windup "none")
              I_k if v_k is beyond a limit and ki·e_k drives it further, else as above      ("clamp")
              I_k + ki·h·e_k + (h/T_t)·(u_k − v_k)        ("back_calculation", tracking time T_t ≥ h)

The integrator I is held in output units (the integral term itself), so gains may change between runs without a
bump.  Forward-Euler integration: u_k uses the errors up to k − 1 in I_k.

Layouts: :data:`PID_COLUMNS` (one row of the parameter table per controller, packed by :func:`pack`) and
:data:`STATE_COLUMNS` (one row of the state per controller, logged and snapshotted as is); the column indices
below are derived from those tuples, never counted by hand.  Sensors: :data:`SENSOR_KINDS`; outputs:
:data:`OUTPUT_KINDS`.

Limitations: one sensor and one output per controller; the PID runs once per plant step at most (PBD mode:
per step, its command held over the XPBD substeps); a flow sensor reads the branch flows of the previous step.

Example
-------
>>> row = pack(1, kp=2.0, ki=0.0, kd=0.0, derivative_filter=0.0, low=-1.0, high=1.0, anti_windup=WINDUP_CLAMP,
...            tracking_gain=0.0, every=1, sensor_kind=0, sensor_index=0, output_kind=0, output_index=0)[0]
>>> state = initial_state(1)[0]
>>> pid_update(row, state, 0.25, 0.0, 1e-3)[0]
0.5
"""

from __future__ import annotations

import numpy as np

from ._jit import kernel
from .components.parameters import table

SENSOR_KINDS = ("stroke", "speed", "joint", "joint_speed", "pressure", "flow", "pump_speed")
"""Sensors, written ``"KIND:NAME"`` in a scenario: an actuator's coordinate [m | rad] and its rate [m/s | rad/s]
(``stroke``/``speed`` of a cylinder or motor of the circuit, as the network steps it), a scalar joint's
coordinate and rate (``joint``/``joint_speed``, MuJoCo's qpos/qvel), a net's absolute pressure [Pa], a branch's
flow of the previous step [m³/s] (``flow:BRANCH``, a branch name as in the log, e.g. ``valve.P-A``) and a pump's
shaft speed [rev/s] (its current command)."""
OUTPUT_KINDS = ("valve", "pump")
"""What a controller drives: a 4/3 valve's spool command [-] or a pump's shaft speed [rev/s]."""
ANTI_WINDUP = ("none", "clamp", "back_calculation")
"""Anti-windup schemes of the integrator (see the module docstring)."""
WINDUP_NONE, WINDUP_CLAMP, WINDUP_BACK = range(len(ANTI_WINDUP))

PID_COLUMNS = ("kp", "ki", "kd", "derivative_filter", "low", "high", "anti_windup", "tracking_gain", "every",
               "sensor_kind", "sensor_index", "output_kind", "output_index")
"""Parameter table, one row per controller: gains kp [out/unit], ki [out/(unit·s)], kd [out·s/unit], derivative
filter T_f [s], output limits low ≤ high, anti-windup scheme (index into :data:`ANTI_WINDUP`), tracking gain
h/T_t [-] of back-calculation, sample period ``every`` [steps], sensor (index into :data:`SENSOR_KINDS`, index of
the actuator, joint address, node, branch or pump) and output (index into :data:`OUTPUT_KINDS`, valve or pump
index)."""
_P = {name: j for j, name in enumerate(PID_COLUMNS)}
KP, KI, KD, TF, LOW, HIGH = _P["kp"], _P["ki"], _P["kd"], _P["derivative_filter"], _P["low"], _P["high"]
WINDUP, TRACK, EVERY = _P["anti_windup"], _P["tracking_gain"], _P["every"]
SENSOR_KIND, SENSOR_INDEX, OUTPUT_KIND, OUTPUT_INDEX = (_P["sensor_kind"], _P["sensor_index"], _P["output_kind"],
                                                        _P["output_index"])

STATE_COLUMNS = ("output", "error", "integrator", "derivative", "measurement", "setpoint", "sampled")
"""Controller state, one row per controller: the held output u (valve command [-] or pump speed [rev/s]), the last
sample's error e = r − y, integrator I (output units), derivative term D (output units), measurement y and
setpoint r (sensor units), and 1 once sampled (the derivative's previous measurement exists)."""
_S = {name: j for j, name in enumerate(STATE_COLUMNS)}
S_OUTPUT, S_ERROR, S_INTEGRATOR, S_DERIVATIVE = _S["output"], _S["error"], _S["integrator"], _S["derivative"]
S_MEASUREMENT, S_SETPOINT, S_SAMPLED = _S["measurement"], _S["setpoint"], _S["sampled"]
LOGGED = ("output", "error", "integrator", "derivative", "measurement", "setpoint")
"""State columns logged per controller (the first ones of :data:`STATE_COLUMNS`)."""
assert STATE_COLUMNS[:len(LOGGED)] == LOGGED


def pack(count: int, **columns) -> np.ndarray:
    """The parameter table, shape (count, len(:data:`PID_COLUMNS`)): ``columns`` names exactly the columns, each a
    scalar or ``count`` values (:func:`hydraulics.components.parameters.table`)."""
    return table(PID_COLUMNS, count, **columns)


def initial_state(count: int) -> np.ndarray:
    """The state of ``count`` controllers before their first sample: all zeros (columns :data:`STATE_COLUMNS`)."""
    return np.zeros((count, len(STATE_COLUMNS)))


@kernel
def pid_update(p, state, error, measurement, h):
    """One sample of the PID law (module docstring): parameter row ``p`` (:data:`PID_COLUMNS`), state row ``state``
    (:data:`STATE_COLUMNS`, read only), error e = r − y and measurement y [sensor units], sample period ``h`` [s].

    Returns (output u, unsaturated output v, integrator I_{k+1}, derivative term D_k); a pure function."""
    if state[S_SAMPLED] > 0.0:
        derivative = (p[TF] * state[S_DERIVATIVE] - p[KD] * (measurement - state[S_MEASUREMENT])) / (p[TF] + h)
    else:
        derivative = 0.0
    integrator = state[S_INTEGRATOR]
    raw = p[KP] * error + integrator + derivative
    out = min(max(raw, p[LOW]), p[HIGH])
    increment = p[KI] * h * error
    scheme = p[WINDUP]
    if scheme == WINDUP_CLAMP:
        if (raw > p[HIGH] and increment > 0.0) or (raw < p[LOW] and increment < 0.0):
            increment = 0.0
    elif scheme == WINDUP_BACK:
        increment += p[TRACK] * (out - raw)
    return out, raw, integrator + increment, derivative


SOURCES = ("position", "velocity", "qpos", "qvel", "pressure", "flow")
"""What the sensors read, in this order (the ``sources`` tuple): actuator positions [m | rad] and velocities, qpos
and qvel (MuJoCo's layout), node pressures [Pa], branch flows [m³/s]; pump speeds come with the commands."""
assert SOURCES == tuple({"stroke": "position", "speed": "velocity", "joint": "qpos", "joint_speed": "qvel",
                         "pressure": "pressure", "flow": "flow"}[k] for k in SENSOR_KINDS[:len(SOURCES)])


@kernel
def sensor_value(kind, index, sources, speed):
    """The measurement of sensor ``kind`` (:data:`SENSOR_KINDS`) at ``index`` from the step's start state
    ``sources`` (:data:`SOURCES`) or the pump speeds ``speed`` [rev/s]."""
    if kind == 0:
        return sources[0][index]
    if kind == 1:
        return sources[1][index]
    if kind == 2:
        return sources[2][index]
    if kind == 3:
        return sources[3][index]
    if kind == 4:
        return sources[4][index]
    if kind == 5:
        return sources[5][index]
    return speed[index]


@kernel
def update(table_, state, setpoint, step, dt, sources, cmd, speed):
    """Every controller of ``table_`` at plant step ``step`` (dt [s]): those whose period divides ``step`` sample
    their sensor (``sources``: :data:`SOURCES` at the step's start) against ``setpoint[i]`` and update their
    ``state`` row; every one writes its held output into ``cmd`` (valve commands) or ``speed`` (pump speeds), the
    inputs of the step's hydraulics."""
    for i in range(table_.shape[0]):
        p = table_[i]
        s = state[i]
        every = int(p[EVERY])
        if step % every == 0:
            y = sensor_value(int(p[SENSOR_KIND]), int(p[SENSOR_INDEX]), sources, speed)
            r = setpoint[i]
            e = r - y
            out, raw, integrator, derivative = pid_update(p, s, e, y, every * dt)
            s[S_OUTPUT], s[S_ERROR], s[S_INTEGRATOR], s[S_DERIVATIVE] = out, e, integrator, derivative
            s[S_MEASUREMENT], s[S_SETPOINT], s[S_SAMPLED] = y, r, 1.0
    update_outputs(table_, state, cmd, speed)


@kernel
def update_outputs(table_, state, cmd, speed):
    """Write every controller's held output into ``cmd`` (valve commands) or ``speed`` (pump speeds)."""
    for i in range(table_.shape[0]):
        p = table_[i]
        if p[OUTPUT_KIND] == 0.0:
            cmd[int(p[OUTPUT_INDEX])] = state[i, S_OUTPUT]
        else:
            speed[int(p[OUTPUT_INDEX])] = state[i, S_OUTPUT]


__all__ = ["ANTI_WINDUP", "LOGGED", "OUTPUT_KINDS", "PID_COLUMNS", "SENSOR_KINDS", "SOURCES", "STATE_COLUMNS", "initial_state",
           "pack", "pid_update", "sensor_value", "update", "update_outputs"]
